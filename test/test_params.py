"""Parameters: one spec per name, the params file shared by the node and the CLI, and the
node's declared descriptors."""
from pathlib import Path

import numpy as np
import pytest

from grass_nrsfm_ros import params
from grass_nrsfm_ros.nrsfm import GrassmannNRSfM, SOLVER_PARAMS

CONFIG = Path(__file__).resolve().parents[1] / 'config' / 'params.yaml'
README = Path(__file__).resolve().parents[1] / 'README.md'


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
    ('warm_start: warm',
     r"warm_start='warm': expected one of \['resume', 'model'\]"),
    ('window_size: 10\nwindow_stride: 11', 'window_stride=11 exceeds window_size=10'),
    ('- 1', 'expected a mapping'),
])
def test_bad_values_name_file_parameter_and_reason(tmp_path, text, message):
    path = tmp_path / 'bad.yaml'
    path.write_text(text)
    with pytest.raises(ValueError, match=message) as err:
        params.load_config(path)
    assert str(path) in str(err.value)


def test_schema_types_ranges_and_choices():
    specs = {p.name: p for p in params.all_params()}
    gamma, K_s, rho = specs['solver.gamma'], specs['solver.K_s'], specs['solver.rho']
    assert gamma.type is float and gamma.range[0] == 0.0 and gamma.check(0) == 0.0
    with pytest.raises(ValueError, match=r'solver.gamma=-1.0: outside \[0.0'):
        gamma.check(-1.0)
    assert K_s.type is None and K_s.check('auto') == 'auto' and K_s.check(np.int64(3)) == 3
    with pytest.raises(ValueError, match='expected one of'):
        K_s.check('sometimes')
    with pytest.raises(ValueError, match='outside'):
        K_s.check(0)
    with pytest.raises(ValueError, match=r'outside \(1.0'):           # rho > 1, open bound
        rho.check(1.0)
    assert specs['solver.random_state'].check(None) is None
    assert specs['solver.spatial'].group == 'research' and specs['solver.gamma'].group == 'solver'
    assert params.solver_kwargs({'solver.gamma': 0.1, 'solver.K_s': None, 'window_size': 3}) \
        == {'gamma': 0.1}


def test_schema_is_the_solvers_signature():
    """The solver takes exactly the schema's parameters, with the schema's defaults."""
    solver = GrassmannNRSfM()
    assert solver.get_params() == {p.name: p.default for p in SOLVER_PARAMS}
    assert GrassmannNRSfM.parameter_specs == {p.name: p for p in SOLVER_PARAMS}
    with pytest.raises(TypeError, match='zeta_weight'):
        GrassmannNRSfM(zeta_weight=1.0)                  # deleted: it had no effect


def test_cross_parameter_rules(tmp_path):
    path = tmp_path / 'beta.yaml'
    path.write_text('solver:\n  beta0: 10.0\n  beta_max: 1.0\n')
    with pytest.raises(ValueError, match='beta_max'):
        params.load_config(path)
    with pytest.raises(ValueError, match='window_stride=11 exceeds window_size=10'):
        params.check_window(window_size=10, window_stride=11)


def test_readme_table_is_current():
    """README.md's parameter table (regenerate: python -m grass_nrsfm_ros.params --readme
    README.md)."""
    text = README.read_text()
    assert params.README_BEGIN in text and params.README_END in text
    assert params.readme_with_table(text) == text


def test_readme_table_rewrite(tmp_path):
    path = tmp_path / 'README.md'
    path.write_text(f'# x\n{params.README_BEGIN}\nstale table\n{params.README_END}\nafter\n')
    params.main(['--readme', str(path)])
    text = path.read_text()
    assert 'stale table' not in text and '| `window_size` | `30` | int in [3, 100000] |' in text
    assert '`gamma`, `smoothness`' in text and 'research switches' in text
    assert text.endswith(f'{params.README_END}\nafter\n')
    with pytest.raises(ValueError, match='markers'):
        params.readme_with_table('no markers')


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
        windows = node.pipeline.windowing
        assert windows.window_size == 20 and windows.window_stride == 10
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
