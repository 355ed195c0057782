"""The installed layout that `ros2 run grass_nrsfm_ros node` and `ros2 run grass_nrsfm_ros tracker`
resolve (built with colcon into a temporary folder), both executables starting and stopping
cleanly, and a plain pip install that puts no `node` on PATH."""
import os
from pathlib import Path
import random
import shutil
import signal
import subprocess
import sys
import threading

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGE = 'grass_nrsfm_ros'
COLCON = Path(sys.executable).parent / 'colcon'
SOURCES = ('setup.py', 'setup.cfg', 'package.xml', 'README.md', 'resource', 'config', 'launch',
           PACKAGE)


def copy_package(dest):
    """The package's sources (no tests, no build output) in ``dest``."""
    dest.mkdir(parents=True)
    for name in SOURCES:
        src = REPO / name
        if src.is_dir():
            shutil.copytree(src, dest / name, ignore=shutil.ignore_patterns('__pycache__'))
        elif src.exists():
            shutil.copy2(src, dest / name)
    return dest


@pytest.fixture(scope='module')
def colcon_install(tmp_path_factory):
    if not COLCON.exists():
        pytest.skip(f'colcon not installed beside {sys.executable}')
    ws = tmp_path_factory.mktemp('ws')
    copy_package(ws / 'src' / PACKAGE)
    listed = subprocess.run([str(COLCON), 'list', '-t'], cwd=ws, capture_output=True, text=True)
    assert '(ros.ament_python)' in listed.stdout, listed.stdout + listed.stderr
    build = subprocess.run([str(COLCON), 'build'], cwd=ws, capture_output=True, text=True,
                           timeout=300)
    assert build.returncode == 0, build.stdout + build.stderr
    return ws / 'install' / PACKAGE


def ros_run_lookup(prefix, name='node'):
    """What `ros2 run` does: executables called ``name`` under <prefix>/lib/<package>."""
    found = []
    for root, dirs, files in os.walk(prefix / 'lib' / PACKAGE):
        dirs[:] = sorted(d for d in dirs if not d.startswith('.'))
        found += [Path(root) / f for f in sorted(files)
                  if f == name and os.access(Path(root) / f, os.X_OK)]
    return found


def test_colcon_layout_resolves_like_ros2_run(colcon_install, monkeypatch):
    from ament_index_python.packages import get_package_prefix     # comes with ROS 2
    monkeypatch.setenv('AMENT_PREFIX_PATH', str(colcon_install))
    prefix = Path(get_package_prefix(PACKAGE))
    assert prefix == colcon_install
    assert len(ros_run_lookup(prefix)) == 1
    assert len(ros_run_lookup(prefix, 'tracker')) == 1
    assert (prefix / 'share' / PACKAGE / 'package.xml').is_file()
    assert (prefix / 'share' / PACKAGE / 'config' / 'params.yaml').is_file()
    assert (prefix / 'share' / PACKAGE / 'launch' / 'grass_nrsfm.launch.py').is_file()


@pytest.mark.parametrize('name, arguments, started', [
    ('node', ['params.yaml', '-p', 'window_size:=20'], 'window 20, stride 10'),
    ('tracker', ['tracker.yaml', '-p', 'step:=6'], 'step 6 px, the whole image')])
def test_installed_executable_starts_and_stops_on_sigint(colcon_install, tmp_path, name,
                                                         arguments, started):
    (node,) = ros_run_lookup(colcon_install, name)
    site = next(colcon_install.glob('lib/python*/site-packages'))
    env = {**os.environ, 'AMENT_PREFIX_PATH': str(colcon_install), 'PYTHONPATH': str(site),
           'ROS_DOMAIN_ID': str(random.randint(0, 101)),
           'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST', 'ROS_LOG_DIR': str(tmp_path)}
    params, *arguments = arguments
    params = colcon_install / 'share' / PACKAGE / 'config' / params
    proc = subprocess.Popen([str(node), '--ros-args', '--params-file', str(params), *arguments,
                             '-r', '__ns:=/install_test'],
                            cwd=tmp_path, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    head = read_until(proc, started, timeout=60)     # its start-up line
    assert proc.poll() is None, head
    proc.send_signal(signal.SIGINT)
    out, _ = proc.communicate(timeout=15)
    out = head + out
    assert proc.returncode == 0, out
    assert started in out
    assert 'Traceback' not in out


def read_until(proc, text, timeout):
    """``proc``'s output up to the line holding ``text`` (all of it if the process ends first);
    the process is killed after ``timeout`` s without that line."""
    watchdog = threading.Timer(timeout, proc.kill)
    watchdog.start()
    lines = []
    try:
        for line in proc.stdout:
            lines.append(line)
            if text in line:
                break
    finally:
        watchdog.cancel()
    return ''.join(lines)


def test_pip_install_puts_no_node_on_path(tmp_path):
    src = copy_package(tmp_path / 'src')
    target = tmp_path / 'target'
    pip = subprocess.run([sys.executable, '-m', 'pip', 'install', '-q', '--no-deps',
                          '--target', str(target),
                          str(src)], capture_output=True, text=True, timeout=300)
    assert pip.returncode == 0, pip.stdout + pip.stderr
    assert (target / 'bin' / 'grass-nrsfm').is_file()
    assert not (target / 'bin' / 'node').exists()
    assert not list(target.glob('lib/*/node'))
