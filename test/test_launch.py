"""launch/grass_nrsfm.launch.py: the launch packages are not on PyPI, so the file is imported
against stubs of the ``launch`` / ``launch_ros`` modules that record what it builds; every
argument it uses is declared and every parameter it sets exists in the node's schema. Where
``launch_ros`` is importable, the description is also built with the real classes."""
from pathlib import Path

from launch_stubs import install_stubs, launch_entities, load_launch
import pytest

from grass_nrsfm_ros import params

REPO = Path(__file__).resolve().parents[1]
LAUNCH_FILE = REPO / 'launch' / 'grass_nrsfm.launch.py'
ARGUMENTS = {'namespace', 'params_file', 'tracks', 'points', 'record_path', 'rviz'}


@pytest.fixture
def stubbed(monkeypatch):
    """The stub classes by name, installed in sys.modules as the launch packages."""
    return install_stubs(monkeypatch)


def test_launch_file_builds_and_names_only_known_parameters(stubbed):
    entities, declared, used = launch_entities(LAUNCH_FILE, stubbed)
    assert set(declared) == ARGUMENTS
    assert declared['rviz'] == 'false' and declared['record_path'] == ''
    share = stubbed['FindPackageShare']('grass_nrsfm_ros')
    assert declared['params_file'] == stubbed['PathJoinSubstitution'](
        [share, 'config', 'params.yaml'])
    assert used <= set(declared) and used == ARGUMENTS

    nodes = {n.kwargs['package']: n for n in entities if isinstance(n, stubbed['Node'])}
    node = nodes['grass_nrsfm_ros']
    assert node.kwargs['executable'] == 'node' and node.kwargs['name'] == params.NODE_NAME
    schema = {p.name for p in params.all_params()}
    named = {k for p in node.kwargs['parameters'] if isinstance(p, dict) for k in p}
    assert named and named <= schema
    assert dict(node.kwargs['remappings']) == {
        'tracks': stubbed['LaunchConfiguration']('tracks'),
        'points': stubbed['LaunchConfiguration']('points')}
    rviz = nodes['rviz2']
    assert rviz.kwargs['condition'] == stubbed['IfCondition'](
        stubbed['LaunchConfiguration']('rviz'))
    config = rviz.kwargs['arguments'][1].args[0]
    assert (REPO / Path(*config[1:])).is_file()           # config/grass_nrsfm.rviz
    assert (REPO / 'config' / 'params.yaml').is_file()


def test_launch_file_with_the_real_launch_packages():
    launch = pytest.importorskip('launch')
    pytest.importorskip('launch_ros')
    description = load_launch(LAUNCH_FILE).generate_launch_description()
    assert isinstance(description, launch.LaunchDescription)
    assert {a.name for a in description.get_launch_arguments()} == ARGUMENTS
