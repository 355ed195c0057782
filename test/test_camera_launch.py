"""launch/camera.launch.py: imported against stubs of the ``launch`` / ``launch_ros`` modules
that record what it builds (the launch packages are not on PyPI): the tracker feeds the
reconstruction node in one namespace, every argument is declared and used, the default
parameter files exist and name only known parameters. Where ``launch_ros`` is importable, the
description is also built with the real classes."""
from pathlib import Path

from launch_stubs import install_stubs, launch_entities, load_launch
import pytest
import yaml

from grass_nrsfm_ros import params, tracker_params

REPO = Path(__file__).resolve().parents[1]
LAUNCH_FILE = REPO / 'launch' / 'camera.launch.py'
ARGUMENTS = {'namespace', 'image', 'camera_info', 'tracker_params_file', 'params_file', 'rviz',
             'dds_profile'}


@pytest.fixture
def stubbed(monkeypatch):
    """The stub classes by name, installed in sys.modules as the launch packages."""
    return install_stubs(monkeypatch)


def test_camera_launch_chains_tracker_and_node_in_one_namespace(stubbed):
    entities, declared, used = launch_entities(LAUNCH_FILE, stubbed)
    assert set(declared) == ARGUMENTS
    assert used == ARGUMENTS
    config = stubbed['LaunchConfiguration']
    share = stubbed['FindPackageShare']('grass_nrsfm_ros')
    for argument, name in (('tracker_params_file', 'tracker.yaml'),
                           ('params_file', 'params.yaml')):
        assert declared[argument] == stubbed['PathJoinSubstitution']([share, 'config', name])
        assert (REPO / 'config' / name).is_file()
    nodes = {n.kwargs['executable']: n.kwargs for n in entities
             if isinstance(n, stubbed['Node'])}
    tracker, node = nodes['tracker'], nodes['node']
    assert tracker['package'] == node['package'] == 'grass_nrsfm_ros'
    assert tracker['name'] == tracker_params.TRACKER_NODE_NAME
    assert node['name'] == params.NODE_NAME
    assert tracker['namespace'] == node['namespace'] == config('namespace')
    assert dict(tracker['remappings']) == {'image': config('image'),
                                           'camera_info': config('camera_info')}
    # 'tracks' is the tracker's output, in the namespace; the intrinsics are the tracker's
    assert dict(node['remappings']) == {'camera_info': config('camera_info')}
    assert tracker['parameters'] == [config('tracker_params_file')]
    assert node['parameters'] == [config('params_file')]
    assert nodes['rviz2']['condition'] == stubbed['IfCondition'](config('rviz'))
    assert declared['rviz'] == 'false' and declared['image'] == 'image'
    assert declared['dds_profile'] == stubbed['EnvironmentVariable'](
        'FASTRTPS_DEFAULT_PROFILES_FILE', default_value=[
            stubbed['PathJoinSubstitution']([share, 'config', 'fastdds_large_images.xml'])])
    assert (REPO / 'config' / 'fastdds_large_images.xml').is_file()
    profile, = [e for e in entities if isinstance(e, stubbed['SetEnvironmentVariable'])]
    assert profile.args == ('FASTRTPS_DEFAULT_PROFILES_FILE', config('dds_profile'))
    assert entities.index(profile) < entities.index(next(
        n for n in entities if isinstance(n, stubbed['Node'])))   # set before the nodes start


def test_default_tracker_params_apply_in_any_namespace():
    """config/tracker.yaml's key is /**/<tracker>: a bare node name would leave a namespaced
    tracker (camera.launch.py's namespace) on its defaults."""
    data = yaml.safe_load((REPO / 'config' / 'tracker.yaml').read_text())
    assert list(data) == [f'/**/{tracker_params.TRACKER_NODE_NAME}']
    assert set(data[f'/**/{tracker_params.TRACKER_NODE_NAME}']['ros__parameters']) == \
        {p.name for p in tracker_params.TRACKER_PARAMS}


def test_camera_launch_with_the_real_launch_packages():
    launch = pytest.importorskip('launch')
    pytest.importorskip('launch_ros')
    description = load_launch(LAUNCH_FILE).generate_launch_description()
    assert isinstance(description, launch.LaunchDescription)
    assert {a.name for a in description.get_launch_arguments()} == ARGUMENTS
