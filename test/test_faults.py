"""Faults: the node killed or stopped mid-work, a recording target that fails, peers that come
and go, and bags from outside that are broken. The node runs in its own process (test/rosutil),
with the rigid test solver of test/doubles.py unless a test needs a slow one.

Figures (exit times, counts) are recorded as the test-suite property ``reliability_faults``
(JSON); ``python -m bench.reliability`` collects them into bench/results/reliability_faults.json.
The tests write no file."""
import json
import os
from pathlib import Path
import resource
import signal
import subprocess
import sys
import time

from mcap.exceptions import McapError
from mcap.records import Message
from mcap.stream_reader import StreamReader
import numpy as np
import pytest

from doubles import bending_sheet
from grass_nrsfm_ros import bag, cloud
from grass_nrsfm_ros.nrsfm.measurement import as_frames

REPO = Path(__file__).resolve().parents[1]
FIGURES = {}
T0 = 1_700_000_000_000_000_000
PERIOD_NS = 33_333_333
SLOW_LAUNCH = ('import sys; from doubles import SlowSolver; '
               'from grass_nrsfm_ros.node import main; '
               'sys.exit(main(solver_factory=SlowSolver))')
STUBBORN_LAUNCH = SLOW_LAUNCH.replace('SlowSolver', 'StubbornSolver')


def frames(F, P=60, seed=0, id_offset=0, first=0):
    """``F`` tracks clouds (rclpy) of a rigid-ish synthetic scene, stamps 30 Hz from ``first``."""
    from std_msgs.msg import Header          # here: ROS 2 messages; the bag tests need none

    W, _, ids = bending_sheet(F=F, P=P, seed=seed)
    out = []
    for f in range(F):
        ns = T0 + (first + f) * PERIOD_NS
        header = Header(frame_id='camera')
        header.stamp.sec, header.stamp.nanosec = divmod(ns, 10 ** 9)
        out.append(cloud.encode_tracks(ids + id_offset, as_frames(W, 2)[f].T, header))
    return out


#: the feed period of the peer-churn tests. At 30 Hz (a window every 0.17 s with stride 5) and
#: a CPU-bound process on the other core, the node fell behind and skipped windows as designed,
#: so fewer frames than the tests wait for were published: 12 of 12 runs of the three tests
#: failed (4 each, no reruns); at 10 Hz, 12 of 12 passed. Load is not what they check.
CHURN_PERIOD = 0.1


def idle_after(values, received):
    """Whether diagnostics ``values`` count ``received`` messages and no solve running or
    waiting."""
    return (int(values.get('messages received', 0)) >= received
            and values.get('solver busy') == 'False')


def messages_on_disk(bag_dir):
    """Complete messages in a recording being written, read as ``recover`` reads: each .mcap
    up to its first incomplete record."""
    count = 0
    for path in bag.mcap_files(bag_dir):
        with open(path, 'rb') as fh:
            try:
                for record in StreamReader(fh).records:
                    count += isinstance(record, Message)
            except (McapError, ValueError, KeyError):
                pass                                 # the chunk being written
    return count


def figure(name, **values):
    FIGURES[name] = values
    print(f'{name}: {values}')


@pytest.fixture(scope='module', autouse=True)
def fault_figures(record_testsuite_property):
    """After the module: the figures as the suite property ``reliability_faults`` (kept only
    with ``--junitxml``, as bench/reliability.py runs it)."""
    yield
    if FIGURES:
        record_testsuite_property('reliability_faults', json.dumps(FIGURES, sort_keys=True))


def ros():
    """rosutil, or skip without rclpy."""
    pytest.importorskip('rclpy')
    import rosutil
    return rosutil


# -- stopping ------------------------------------------------------------------------------------
@pytest.mark.ros
@pytest.mark.parametrize('launch', [SLOW_LAUNCH, STUBBORN_LAUNCH],
                         ids=['cancellable', 'stubborn'])
def test_sigterm_during_a_solve_exits_within_2s_and_finalises_the_recording(
        ros_env, tmp_path, launch):
    rosutil = ros()
    log = tmp_path / 'node.log'
    args = ['-p', 'window_size:=5', '-p', 'window_stride:=5', '-p', 'min_tracks:=10',
            '-p', f'record_path:={tmp_path}/rec']
    with rosutil.node_with_feeder(ros_env, log, args, launch=launch) as (proc, feeder):
        rosutil.publish(feeder, frames(7))
        assert feeder.wait_for(lambda: feeder.diagnostic_values().get('solver busy') == 'True',
                               20), log.read_text()      # the first window (5 frames)
        assert proc.poll() is None
        start = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(20)
        seconds = time.monotonic() - start
    text = log.read_text()
    figure(f'sigterm_during_solve_{"stubborn" if "Stubborn" in launch else "cancellable"}',
           exit_seconds=round(seconds, 3), exit_code=code)
    assert seconds < 2.0, text
    assert code == 0, text
    assert 'Traceback' not in text
    assert (tmp_path / 'rec' / 'metadata.yaml').exists(), text     # finalised, not recovered
    counts = {t: n for t, (_, n) in bag.topics(tmp_path / 'rec').items()}
    assert sum(n for t, n in counts.items() if t.endswith('/tracks')) == 7
    # every frame was tracked and published on arrival; the cancelled solve refined none
    assert sum(n for t, n in counts.items() if t.endswith('/points')) == 7
    assert sum(n for t, n in counts.items() if t.endswith('/points/refined')) == 0


@pytest.mark.ros
def test_kill_9_during_recording_leaves_a_recoverable_bag(ros_env, tmp_path):
    rosutil = ros()
    log = tmp_path / 'node.log'
    args = ['-p', f'record_path:={tmp_path}/rec']
    with rosutil.node_with_feeder(ros_env, log, args) as (proc, feeder):
        messages = frames(90)
        rosutil.publish(feeder, messages)
        counts = feeder.accounted(len(messages))
        assert counts is not None, log.read_text()
        published = counts['frames published']
        refined = int(feeder.diagnostic_values()['frames refined'])
        assert published > 0 and feeder.wait_for(lambda: len(feeder.points) == published, 10)
        # the recorder flushes within its period (1 s) but says so to no one: poll the file
        assert feeder.wait_for(
            lambda: messages_on_disk(tmp_path / 'rec') == 90 + published + refined, 10), \
            messages_on_disk(tmp_path / 'rec')
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
    assert not (tmp_path / 'rec' / 'metadata.yaml').exists()
    out = subprocess.run([sys.executable, '-m', 'grass_nrsfm_ros.cli', 'recover',
                          str(tmp_path / 'rec')], capture_output=True, text=True, cwd=REPO,
                         env=ros_env, timeout=60)
    assert out.returncode == 0, out.stderr
    counts = {t: n for t, (_, n) in bag.topics(tmp_path / 'rec_recovered').items()}
    tracks = sum(n for t, n in counts.items() if t.endswith('/tracks'))
    points = sum(n for t, n in counts.items() if t.endswith('/points'))
    figure('kill_9_recording', sent=len(messages), published=published,
           recovered_tracks=tracks, recovered_points=points)
    assert tracks == len(messages)        # everything was flushed before the kill
    assert points == published
    assert sum(n for t, n in counts.items() if t.endswith('/points/refined')) == refined


# -- the recording target fails ------------------------------------------------------------------
def _limit_file_size():
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)              # writes past it -> EFBIG
    resource.setrlimit(resource.RLIMIT_FSIZE, (256 * 1024, 256 * 1024))


@pytest.mark.ros
def test_full_recording_target_gives_one_error_and_reconstruction_goes_on(ros_env, tmp_path):
    """The recording fails (RLIMIT_FSIZE: EFBIG) after ~45 frames: one error line, and every
    frame is still reconstructed or counted. (Was xfail: 'the rigid test solver stalls, 60 of
    150 published'. Not reproduced since the rigid stand-in solves windows without context
    frames: 150/150 in 3 of 3 runs with the old node, 140 + 10 counted lost with 3 CPU hogs.
    The likely mechanism, a solve longer than the 1.5 s quiet period of ``accounted`` read as
    the end, is closed: the node reports 'solver busy' and ``accounted`` waits for it.)"""
    rosutil = ros()
    log = tmp_path / 'node.log'
    args = ['-p', f'record_path:={tmp_path}/rec']
    with rosutil.node_with_feeder(ros_env, log, args,
                                  preexec_fn=_limit_file_size) as (proc, feeder):
        messages = frames(150, P=200)     # ~2.4 kB per tracks cloud, 3.2 kB per points cloud
        rosutil.publish(feeder, messages)
        counts = feeder.accounted(len(messages))
        assert counts is not None, log.read_text()
        status = feeder.diagnostics[-1].status[0]
        assert proc.poll() is None
    text = log.read_text()
    errors = [line for line in text.splitlines() if 'recording to' in line]
    error_at = next(i for i, line in enumerate(text.splitlines()) if 'recording to' in line)
    figure('full_recording_target', sent=len(messages), **counts, error_lines=len(errors))
    assert len(errors) == 1 and 'File too large' in errors[0], text
    # 256 kB hold ~45 frames of tracks and points: most frames came after the error
    assert counts['frames published'] >= 100, (counts, text.splitlines()[error_at:])
    # every frame accounted for: 150 frames close windows at 30, 40, ..., 150, so none pending
    assert counts['frames pending'] == 0, counts
    assert counts['messages received'] == len(messages) == (
        counts['dropped messages'] + counts['frames published'] + counts['frames lost']), counts
    assert 'recording failed' in status.message
    assert 'Traceback' not in text


# -- peers come and go ---------------------------------------------------------------------------
@pytest.mark.ros
def test_subscriber_that_disappears_causes_no_error_and_publishing_goes_on(ros_env, tmp_path):
    rosutil = ros()
    from sensor_msgs.msg import PointCloud2      # here: ROS 2; the bag tests need none

    log = tmp_path / 'node.log'
    args = ['-p', 'window_size:=10', '-p', 'window_stride:=5']
    with rosutil.node_with_feeder(ros_env, log, args) as (proc, feeder):
        other = []
        sub = feeder.node.create_subscription(PointCloud2, 'points', other.append, 100)
        messages = frames(120)
        rosutil.publish(feeder, messages[:40], CHURN_PERIOD)
        assert feeder.wait_for(lambda: len(other) >= 30, 20)
        feeder.node.destroy_subscription(feeder.points_sub)      # both subscribers leave
        feeder.node.destroy_subscription(sub)
        seen = len(other)
        rosutil.publish(feeder, messages[40:80], CHURN_PERIOD)
        assert feeder.wait_for(lambda: idle_after(feeder.diagnostic_values(), 80), 20), \
            log.read_text()                       # those 40 frames solved with no one listening
        sub = feeder.node.create_subscription(PointCloud2, 'points', other.append, 100)
        created = time.monotonic()
        assert feeder.wait_for(lambda: int(feeder.node_reports(created).get(
            'points subscribers', 0)) >= 1, 10)   # the node's writer matched the new reader
        rosutil.publish(feeder, messages[80:], CHURN_PERIOD)
        assert feeder.wait_for(lambda: int(feeder.diagnostic_values().get(
            'frames published', 0)) >= 115, 20), log.read_text()
        assert proc.poll() is None
        values = feeder.diagnostic_values()
    text = log.read_text()
    # 'solves are falling behind' is about CPU load (seen with both cores busy), and 'no camera
    # intrinsics' is said once for pixel tracks without K: neither is about subscribers; any
    # other warning or error fails the test
    expected = ('solves are falling behind', 'no camera intrinsics')
    warnings = [line for line in text.splitlines() if ('WARN' in line or 'ERROR' in line)
                and not any(reason in line for reason in expected)]
    assert text.count('no camera intrinsics') == 1, text
    figure('subscriber_disappears', sent=len(messages), published=int(values['frames published']),
           received_after_return=len(other) - seen, warning_lines=len(warnings))
    assert warnings == [], text
    assert len(other) - seen >= 30            # published again once someone listens


@pytest.mark.ros
@pytest.mark.parametrize('stamps', ['later', 'restarted'])
def test_publisher_restarting_with_new_ids_starts_a_new_sequence(ros_env, tmp_path, stamps):
    """A tracker restarts: new publisher, new track ids; its stamps go on ('later') or start
    again from an earlier time ('restarted', e.g. a replayed log)."""
    rosutil = ros()

    log = tmp_path / 'node.log'
    args = ['-p', 'window_size:=10', '-p', 'window_stride:=5']
    with rosutil.node_with_feeder(ros_env, log, args) as (proc, feeder):
        rosutil.publish(feeder, frames(40), CHURN_PERIOD)
        assert feeder.wait_for(lambda: len(feeder.points) >= 40, 20), log.read_text()
        feeder.new_publisher()
        first = 60 if stamps == 'later' else -1000
        rosutil.publish(feeder, frames(40, seed=1, id_offset=1_000_000, first=first), CHURN_PERIOD)
        assert feeder.wait_for(lambda: len(feeder.points) >= 80, 20), log.read_text()
        assert feeder.wait_for(
            lambda: feeder.diagnostic_values().get('sequences') == '2', 5), log.read_text()
    new = [m for m in feeder.points if cloud.decode_points(m)[0].min() >= 1_000_000]
    figure(f'publisher_restart_{stamps}', published_new_sequence=len(new))
    assert len(new) == 40
    assert 'all track ids changed' in log.read_text()


# -- bags from outside ---------------------------------------------------------------------------
@pytest.fixture(scope='module')
def broken_bags(tmp_path_factory):
    """A good bag and broken ones: ``{name: path}``."""
    root = tmp_path_factory.mktemp('bags')
    W = np.random.default_rng(0).uniform(0, 640, (2 * 40, 30))
    bag.tracks_bag_from_arrays(W, T0 + np.arange(40) * PERIOD_NS, root / 'good')
    data = (root / 'good' / 'good_0.mcap').read_bytes()
    (root / 'cut.mcap').write_bytes(data[:len(data) // 2])
    (root / 'junk.mcap').write_bytes(b'not a bag at all' * 10)
    (root / 'junk.bag').write_bytes(b'#ROSBAG V2.0\n' + b'\xff' * 50)
    truncated = root / 'truncated'
    truncated.mkdir()
    (truncated / 'metadata.yaml').write_text(
        (root / 'good' / 'metadata.yaml').read_text().replace('good_0', 'truncated_0'))
    (truncated / 'truncated_0.mcap').write_bytes(data[:len(data) * 2 // 3])
    nometa = root / 'nometa'
    nometa.mkdir()
    (nometa / 'nometa_0.mcap').write_bytes(data)
    return {'good': root / 'good', 'cut': root / 'cut.mcap', 'junk': root / 'junk.mcap',
            'junk_ros1': root / 'junk.bag', 'truncated': truncated, 'nometa': nometa}


CASES = {'cut': 'cannot read bag', 'junk': 'cannot read bag', 'junk_ros1': 'cannot read bag',
         'truncated': 'recover', 'nometa': 'no metadata.yaml', 'missing_topic': "no topic '/nope'"}


@pytest.mark.parametrize('command', ['replay', 'reconstruct'])
@pytest.mark.parametrize('case', CASES)
def test_broken_bags_give_one_clear_line_and_exit_2(broken_bags, tmp_path, command, case,
                                                    monkeypatch):
    if command == 'replay':
        pytest.importorskip('rclpy')
    path = broken_bags['good' if case == 'missing_topic' else case]
    extra = ['--topic', '/nope'] if case == 'missing_topic' else []
    extra += ['-o', str(tmp_path / 'out'), '--quiet'] if command == 'reconstruct' else \
        ['--rate', '100']
    env = {**os.environ, 'PYTHONPATH': str(REPO), 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'OFF',
           'ROS_LOG_DIR': str(tmp_path / 'log')}
    out = subprocess.run([sys.executable, '-m', 'grass_nrsfm_ros.cli', command, str(path),
                          *extra], capture_output=True, text=True, cwd=REPO, env=env,
                         timeout=60)
    lines = out.stderr.strip().splitlines()
    assert out.returncode == 2, (out.stdout, out.stderr)
    assert len(lines) == 1, out.stderr
    assert lines[0].startswith(f'grass-nrsfm {command}: error: ') and CASES[case] in lines[0]
    assert 'Traceback' not in out.stdout + out.stderr
    assert not (tmp_path / 'out').exists()          # no half-written output
    FIGURES.setdefault('broken_bags_rejected', []).append(f'{command} {case}')


# -- load ----------------------------------------------------------------------------------------
LOAD_SECONDS, LOAD_POINTS, LOAD_RATE = 20, 2000, 30
FRAME_BYTES_PER_POINT = 20      # a buffered frame: uint32 id + float64 u, v per point


def _short_load(tmp_path, record):
    """bench/load.py shortened for CI: the rigid stand-in solver (no context frames), a
    publisher with depth 100 as in the tests above."""
    pytest.importorskip('rclpy')
    from bench import load                   # here: it needs rclpy (rosutil)
    return load.run(seconds=LOAD_SECONDS, points=LOAD_POINTS, rate=LOAD_RATE, solver='rigid',
                    record=record, tmp=tmp_path, depth=100, log=lambda *a: None)


def _check_load(figures):
    assert 'error' not in figures, figures
    assert figures['frames unaccounted'] == 0, figures
    assert figures['messages received'] == figures['sent'], figures
    # memory flat once the buffers are full (window + context frames received) and two windows
    # solved: a leak of one buffered frame per message would make RSS climb by
    # FRAME_BYTES_PER_POINT x points x rate (68.7 MB/min here); the least-squares slope after
    # warm-up must stay under half of that. The slope, not the peak: a solve's working set
    # coming and going once (a 14 MB peak on CI, at 365f355) is not a leak, and moves the slope
    # by at most ~18 MB/min over these 17 s. Measured slopes -5.7, 1.0, 4.1 MB/min (three runs).
    rss = figures['rss_mb']
    assert rss['warmup_end_s'] is not None and rss['slope_mb_per_min'] is not None, rss
    leak_mb_per_min = LOAD_RATE * LOAD_POINTS * FRAME_BYTES_PER_POINT * 60 / 2 ** 20
    assert rss['slope_mb_per_min'] < 0.5 * leak_mb_per_min, (rss, leak_mb_per_min)


def _figure(name, figures):
    rss = figures.get('rss_mb', {})
    figure(name, **{k: v for k, v in figures.items() if k != 'rss_mb'},
           rss_growth_after_warmup_mb=rss.get('growth_after_warmup'),
           rss_slope_mb_per_min=rss.get('slope_mb_per_min'),
           rss_warmup_end_s=rss.get('warmup_end_s'), rss_start_mb=rss.get('start'),
           rss_end_mb=rss.get('end'))


@pytest.mark.ros
def test_short_load_every_frame_accounted_memory_flat(ros_env, tmp_path):
    figures = _short_load(tmp_path, record=False)
    _figure('load_short_no_recording', figures)
    _check_load(figures)


@pytest.mark.ros
def test_short_load_with_recording_loses_nothing(ros_env, tmp_path):
    figures = _short_load(tmp_path, record=True)
    _figure('load_short_recording', figures)
    _check_load(figures)
    assert figures['recording_complete'], figures
