"""Parameters: one spec per name, the params file shared by the node and the CLI, and the
node's declared descriptors."""
from pathlib import Path

import pytest

from grass_nrsfm_ros import params

CONFIG = Path(__file__).resolve().parents[1] / 'config' / 'params.yaml'


def test_config_file_is_the_rendered_defaults():
    """config/params.yaml lists every parameter (regenerate: python -m grass_nrsfm_ros.params)."""
    assert CONFIG.read_text() == params.render_yaml()
    assert params.load_config(CONFIG) == params.defaults()


def test_names_are_unique():
    names = [p.name for p in params.all_params()]
    assert len(names) == len(set(names))


def test_ros_layout_and_flat_mapping(tmp_path):
    ros = tmp_path / 'ros.yaml'
    ros.write_text('grass_nrsfm:\n  ros__parameters:\n    window_size: 20\n'
                   '    metres_per_pixel: 2\n')
    flat = tmp_path / 'flat.yaml'
    flat.write_text('window_stride: 5\nframe_id: cam_optical\n')
    config = params.load_config(ros)
    assert config['window_size'] == 20 and config['metres_per_pixel'] == 2.0
    assert isinstance(config['metres_per_pixel'], float)
    assert params.load_config(flat)['frame_id'] == 'cam_optical'
    assert params.window_kwargs(params.load_config(flat))['window_stride'] == 5


@pytest.mark.parametrize('text, message', [
    ('window_sise: 20', "unknown parameter 'window_sise'; did you mean 'window_size'"),
    ('window_size: 2', r'window_size=2: outside \[3, 100000\]'),
    ('window_size: 20.5', 'window_size=20.5: expected int, got float'),
    ('metres_per_pixel: .nan', 'must be finite'),
    ('warm_start: true', 'warm_start=True: expected str, got bool'),
    ('warm_start: warm', r"warm_start='warm': expected one of \['model', 'full', 'off'\]"),
    ('window_size: 10\nwindow_stride: 11', 'window_stride=11 exceeds window_size=10'),
    ('- 1', 'expected a mapping'),
])
def test_bad_values_name_file_parameter_and_reason(tmp_path, text, message):
    path = tmp_path / 'bad.yaml'
    path.write_text(text)
    with pytest.raises(ValueError, match=message) as err:
        params.load_config(path)
    assert str(path) in str(err.value)


class TinySolver:
    """A solver-shaped class, to check the introspection of its parameters."""

    parameter_specs = {'gamma': ('nuclear norm weight', 'float in [0, 1]'),
                       'K': ('rotation rank', "'auto' or int >= 1"),
                       'max_iterations': ('iteration cap', 'int >= 1'),
                       'seed': ('random seed', 'int or None')}

    def __init__(self, gamma=1e-3, K='auto', max_iterations=200, seed=None):
        pass


def test_solver_parameters_from_signature_and_specs():
    specs = {p.name: p for p in params.solver_params(TinySolver)}
    assert list(specs) == ['solver.gamma', 'solver.K', 'solver.max_iterations', 'solver.seed']
    assert specs['solver.gamma'].range == (0.0, 1.0) and specs['solver.gamma'].type is float
    assert specs['solver.gamma'].description == 'nuclear norm weight [float in [0, 1]]'
    assert specs['solver.K'].type is None and specs['solver.K'].check(2) == 2
    with pytest.raises(ValueError, match='expected one of'):
        specs['solver.K'].check('sometimes')
    assert specs['solver.max_iterations'].type is int
    assert specs['solver.max_iterations'].range[0] == 1
    with pytest.raises(ValueError, match='outside'):
        specs['solver.max_iterations'].check(0)
    with pytest.raises(ValueError, match='outside'):
        specs['solver.gamma'].check(2.0)
    assert params.solver_kwargs({'solver.gamma': 0.1, 'solver.seed': None, 'window_size': 3}) \
        == {'gamma': 0.1}


def test_node_declares_parameters_from_the_file(monkeypatch, tmp_path):
    rclpy = pytest.importorskip('rclpy')
    from rclpy.parameter import Parameter

    from grass_nrsfm_ros.node import ReconstructionNode
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'OFF')
    monkeypatch.setenv('ROS_LOG_DIR', str(tmp_path))
    context = rclpy.Context()
    rclpy.init(args=['--ros-args', '--params-file', str(CONFIG), '-p', 'window_size:=20',
                     '-p', 'frame_id:=cam'], context=context)
    try:
        node = ReconstructionNode(context=context)
        assert node.pipeline.window_size == 20 and node.pipeline.window_stride == 10
        assert node.get_parameter('frame_id').value == 'cam'
        described = node.describe_parameters(['window_size', 'metres_per_pixel'])
        assert described[0].read_only and described[0].integer_range[0].from_value == 3
        assert not described[1].read_only
        bad, good, read_only = node.set_parameters([
            Parameter('metres_per_pixel', value=-1.0), Parameter('metres_per_pixel', value=0.5),
            Parameter('window_size', value=40)])
        assert not bad.successful and good.successful and not read_only.successful
        assert node.pipeline.metres_per_pixel == 0.5
        node.close()
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
