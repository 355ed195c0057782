"""The tracker node's ROS-free parts: its parameter schema and rendered params file, the
region from ``mask`` and ``roi``, and the diagnostics key/values (grass_nrsfm_ros.tracker_params,
grass_nrsfm_ros.tracker_stats)."""
from pathlib import Path

import numpy as np
import pytest

from grass_nrsfm_ros import tracker_params
from grass_nrsfm_ros.tracker_stats import OK, TrackerStats, WARN

cv2 = pytest.importorskip('cv2')
CONFIG = Path(__file__).resolve().parents[1] / 'config' / 'tracker.yaml'


def test_config_file_is_the_rendered_defaults():
    """config/tracker.yaml (regenerate: python -m grass_nrsfm_ros.tracker_params)."""
    assert CONFIG.read_text() == tracker_params.render_yaml()
    yaml = pytest.importorskip('yaml')
    section = yaml.safe_load(CONFIG.read_text())[tracker_params.FILE_KEY]
    assert tracker_params.validate(section['ros__parameters']) == tracker_params.defaults()


@pytest.mark.parametrize('values, match', [
    ({'step': 0}, r'step=0: outside \[1, 1024\]'),
    ({'method': 'farneback'}, "method='farneback': expected one of"),
    ({'roi': [1, 2, 3]}, r'roi=\[1, 2, 3\]: expected \[x0, y0, x1, y1\]'),
    ({'roi': [10, 0, 5, 4]}, 'needs 0 <= x0 <= x1'),
    ({'roi': [0.5, 0, 5, 4]}, 'expected'),
    ({'stepp': 4}, "unknown tracker parameter 'stepp'"),
])
def test_bad_parameters_name_the_parameter(values, match):
    with pytest.raises(ValueError, match=match):
        tracker_params.validate(values)


def test_region_from_mask_and_roi(tmp_path):
    assert tracker_params.load_region('', []) is None
    assert tracker_params.load_region('', [1, 2, 30, 40]) == (1, 2, 30, 40)
    mask = np.zeros((48, 64), np.uint8)
    mask[10:30, 20:50] = 255
    path = tmp_path / 'mask.png'
    cv2.imwrite(str(path), mask)
    region = tracker_params.load_region(str(path), [])
    assert region.dtype == bool and np.array_equal(region, mask > 0)
    cut = tracker_params.load_region(str(path), [0, 0, 29, 63])
    assert cut.sum() == 20 * 10 and cut[10:30, 20:30].all()
    with pytest.raises(ValueError, match='no non-zero pixel inside roi'):
        tracker_params.load_region(str(path), [0, 0, 5, 5])
    with pytest.raises(ValueError, match='no such file'):
        tracker_params.load_region(str(tmp_path / 'none.png'), [])
    (tmp_path / 'text.png').write_text('not a PNG')
    with pytest.raises(ValueError, match='cannot read it as an image'):
        tracker_params.load_region(str(tmp_path / 'text.png'), [])
    assert tracker_params.validate({'roi': None})['roi'] == []      # unset in rclpy


def frame_counts(alive, born=0, lost=0, failed=0, left=0):
    return dict(alive=alive, born=born, lost=lost, failed=failed, left=left, reanchored=0)


def test_diagnostics_rates_counts_and_latencies():
    stats = TrackerStats(now=100.0)
    report = stats.report(100.5)
    values = dict(report.values)
    assert report.level == OK and report.message == 'waiting for images'
    assert values['latency p50 ms'] == '' and values['rate hz'] == '0.00'
    for f in range(30):
        stats.received()
        stats.tracked(frame_counts(500 - f, born=500 if f == 0 else 0, lost=1, failed=f % 2),
                      processing_s=0.010 + 0.001 * f, delay_s=0.020)
    stats.received()
    stats.skipped('black')
    report = stats.report(101.5, extra=[('camera', 'no camera_info')])
    values = dict(report.values)
    assert report.level == WARN and report.message == \
        'images skipped in the last 1.0 s: 1 black'
    assert values['rate hz'] == '30.00' and values['images rate hz'] == '31.00'
    assert (values['tracks alive'], values['tracks born'], values['tracks lost'],
            values['failed checks']) == ('471', '500', '30', '15')
    assert values['frames skipped (black)'] == '1' and values['frames published'] == '30'
    assert float(values['latency p50 ms']) == pytest.approx(24.5, abs=0.01)
    assert float(values['stamp to tracks p95 ms']) == pytest.approx(20.0)
    assert values['camera'] == 'no camera_info'
    # a new period: no skips in it, OK again; totals kept
    stats.received()
    stats.tracked(frame_counts(470), 0.01, 0.02)
    report = stats.report(102.5)
    assert report.level == OK and report.message == 'tracking'
    assert dict(report.values)['frames skipped (black)'] == '1'
    assert dict(report.values)['rate hz'] == '1.00'
