"""The node's /diagnostics values, built without ROS from a pipeline's snapshot."""
import numpy as np

from doubles import bending_sheet, RigidALS
from grass_nrsfm_ros import diagnostics
from grass_nrsfm_ros.nrsfm.measurement import as_frames
from grass_nrsfm_ros.pipeline import make_pipeline, reconstruct_live


def run(F=45):
    W, _, ids = bending_sheet(F=F, P=60)
    pipeline = make_pipeline({'context_frames': 20, 'key_frames': 0}, RigidALS)
    _, _, updates = reconstruct_live(pipeline, range(F), [(ids, uv.T) for uv in as_frames(W, 2)])
    return pipeline, updates


def test_values_account_for_every_frame_and_window():
    pipeline, updates = run()
    solved = [u for u in updates if u.kind == 'solved']
    snap = diagnostics.snapshot(pipeline, latencies=[0.001, 0.003], counts={'messages': 46,
                                'dropped_messages': 1}, last_solve=solved[-1].figures)
    values = diagnostics.values(snap)
    assert all(isinstance(v, str) for v in values.values())
    assert values['messages received'] == '46' and values['dropped messages'] == '1'
    assert values['frames tracked'] == values['frames published'] == '45'
    assert values['windows solved'] == str(len(solved))
    # every accepted frame refined or (at the end of the sequence) released: none left
    assert values['frames refined'] == '45' and values['frames awaiting refinement'] == '0'
    assert values['frames not refined'] == '0' and values['frames lost'] == '0'
    assert values['first model after frames'] == '30'
    assert values['frames from a sheet model'] == '0'                # orthographic pixels
    assert values['started from'] == 'resumed'
    assert float(values['tracking latency p95 ms']) == np.percentile([1.0, 3.0], 95)
    assert 'mapping process' not in values                       # inline: no child
    assert diagnostics.summary(snap) == ('ok', 'ok')
    assert diagnostics.summary(snap, 'disk full') == ('warn', 'recording failed: disk full')


def test_values_before_any_frame_are_blank_not_missing():
    pipeline = make_pipeline({}, RigidALS)
    values = diagnostics.values(diagnostics.snapshot(pipeline))
    assert values['tracking latency p50 ms'] == '' and values['model age frames'] == ''
    assert values['first model after frames'] == '' and values['windows solved'] == '0'
    assert values['sequences'] == '1' and values['solver busy'] == 'False'
