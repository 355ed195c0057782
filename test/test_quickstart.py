"""The README's quick start: its main job (``grass-nrsfm demo``) runs as documented and its
outputs hold what it prints, read back by a library that did not write them (rosbags).

The figures for the embedded sequence (bending sheet, orbit, 60 x 3,000): whole sequence e3D
0.0821 (rigid factorisation 0.3036; the results page's accuracy table, row synthetic_bending:
surface='auto' takes it for a sheet, record 0738). The
live figures are not one number: they move with the input's rounding (docs/decisions/0450):
over 12 draws (the bag's float32 tracks, each perturbed by 1e-9 relative) 0.222-0.258 as
tracked on arrival (its first 30 frames before the first model) and 0.102-0.155 refined by the
windows; the bounds take the largest.
From images (40 rendered frames of a textured bending sheet, 320 x 240, tracked by
DenseTracker at step 5, front end at d55895a: 454 tracks alive in every frame): tracking
error median 0.45 px, p95 1.98 px against the renderer's truth; e3D whole sequence 0.0794
(0.0988 from the true projections of the same points, rigid factorisation 0.1404), live
0.1011 as tracked on arrival, 0.0798 refined. The bounds below are those figures + 15 %, the
rule test_accuracy uses; from images, where a better tracker may change the solver's e3D
either way, the bounds are relative: e3D from the tracks at most 1.2 times e3D from perfect
tracks (issue #39's bar), the live figures against the whole-sequence one.
"""
import os
from pathlib import Path
import re
import subprocess
import sys

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.typesys import get_typestore, Stores

from grass_nrsfm_ros.nrsfm import e3d

REPO = Path(__file__).resolve().parents[1]
WHOLE_E3D, LIVE_E3D, REFINED_E3D = 0.0821, 0.258, 0.155
IMAGE_MEDIAN_PX, IMAGE_P95_PX = 0.45, 1.98


def readme_command(marker):
    """The shell line of the fenced block after ``<!-- marker -->`` in README.md."""
    lines = (REPO / 'README.md').read_text().splitlines()
    at = lines.index(f'<!-- {marker} -->')
    assert lines[at + 1].startswith('```'), f'no code block after <!-- {marker} -->'
    return lines[at + 2]


def test_readme_quick_start_is_two_commands_and_ci_runs_the_second():
    demo, tests = readme_command('demo-command'), readme_command('test-command')
    setup = 'python3 -m venv .venv && .venv/bin/pip install -q -e ".[ros,test]"'
    assert demo == f'{setup} && .venv/bin/grass-nrsfm demo'
    assert tests.startswith(f'{setup} && .venv/bin/python -m pytest')
    ci = (REPO / '.ci' / 'run').read_text()
    assert '<!-- test-command -->' in ci and 'bash -c "$TEST_COMMAND"' in ci
    assert "'grass-nrsfm = grass_nrsfm_ros.cli:main'" in (REPO / 'setup.py').read_text()


def demo_command(output):
    """The installed ``grass-nrsfm`` (what the README runs) or, in a source tree that is not
    installed, the same entry point through ``python -m``."""
    installed = Path(sys.executable).with_name('grass-nrsfm')
    program = [str(installed)] if installed.exists() else [
        sys.executable, '-m', 'grass_nrsfm_ros.cli']
    return program + ['demo', '-o', str(output)]


def printed(pattern, text):
    match = re.search(pattern, text)
    assert match, f'{pattern!r} not in the demo output:\n{text}'
    return [float(g) for g in match.groups()]


def clouds(bag_path, topic):
    """``{stamp_ns: (ids: (P,), xyz: (P, 3))}`` of ``topic``, decoded with rosbags and the
    message's own PointFields (none of this package's readers)."""

    types = {7: '<f4', 8: '<f8', 6: '<u4'}
    out = {}
    with AnyReader([bag_path], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        wanted = [c for c in reader.connections if c.topic == topic]
        assert wanted, f'no {topic} in {bag_path}'
        for connection, _, raw in reader.messages(connections=wanted):
            msg = reader.deserialize(raw, connection.msgtype)
            dtype = np.dtype({'names': [f.name for f in msg.fields],
                              'formats': [types[f.datatype] for f in msg.fields],
                              'offsets': [f.offset for f in msg.fields],
                              'itemsize': msg.point_step})
            points = np.frombuffer(bytes(msg.data), dtype=dtype, count=msg.width)
            stamp = msg.header.stamp.sec * 10 ** 9 + msg.header.stamp.nanosec
            xyz = np.stack([points[c].astype(np.float64) for c in 'xyz'], axis=1)
            out[stamp] = (points['track_id'].astype(np.int64), xyz)
    return out


def test_demo_runs_and_its_outputs_hold_what_it_prints(tmp_path):
    """The quick start's main job end to end (about 30 s): whole-sequence and streamed e3D
    below the README's figures + 15 % and below rigid factorisation; the npz, the bag (read
    by rosbags) and the PNG hold the same reconstruction."""
    out = tmp_path / 'demo'
    env = {**os.environ, 'PYTHONPATH': str(REPO), 'OPENBLAS_NUM_THREADS': '1'}
    run = subprocess.run(demo_command(out), capture_output=True, text=True, timeout=600,
                         cwd=tmp_path, env=env)
    assert run.returncode == 0, run.stdout + run.stderr
    whole, rigid = printed(r'whole sequence: e3D ([\d.]+) \(rigid factorisation ([\d.]+)\)',
                           run.stdout)
    frames_out, frames_in, live, refined_out, refined = printed(
        r'(\d+)/(\d+) frames, e3D ([\d.]+) as tracked on arrival .*?; (\d+) refined, '
        r'e3D ([\d.]+)', run.stdout)
    assert whole < 1.15 * WHOLE_E3D and whole < rigid
    assert live < 1.15 * LIVE_E3D and live < rigid
    assert refined < 1.15 * REFINED_E3D and refined < rigid
    assert frames_out == frames_in == refined_out == 60

    saved = np.load(out / 'reconstruction.npz')
    assert saved['S'].shape == saved['S_gt'].shape == (180, 3000)
    assert e3d(saved['S'], saved['S_gt']) == pytest.approx(whole, abs=5e-5)

    truth = clouds(out / 'reconstruction_bag', '/ground_truth')
    for topic, figure in (('/points', live), ('/points/refined', refined)):
        estimate = clouds(out / 'reconstruction_bag', topic)
        assert sorted(estimate) == sorted(truth) and len(estimate) == 60
        S, S_gt = [], []
        for stamp in sorted(estimate):
            (ids, xyz), (gt_ids, gt_xyz) = estimate[stamp], truth[stamp]
            order = np.argsort(gt_ids)
            S.append(xyz.T)
            S_gt.append(gt_xyz[order[np.searchsorted(gt_ids, ids, sorter=order)]].T)
        assert e3d(np.vstack(S), np.vstack(S_gt)) == pytest.approx(figure, abs=5e-5)

    assert (out / 'last_frame.png').read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'

    # the demo starts from images: the front end's tracking error, then the solver and the
    # live pipeline, before the embedded tracks
    assert run.stdout.index('from images:') < run.stdout.index('whole sequence: e3D')
    complete, median, p95 = printed(r'from images: .*?, (\d+) in every frame; tracking error '
                                    r'median ([\d.]+) px, p95 ([\d.]+) px', run.stdout)
    assert complete >= 300
    assert median < 1.15 * IMAGE_MEDIAN_PX and p95 < 1.15 * IMAGE_P95_PX
    whole, perfect, rigid, live, refined = printed(
        r'from images: whole sequence e3D ([\d.]+) \(perfect tracks of the same points ([\d.]+), '
        r'rigid factorisation ([\d.]+)\); live e3D ([\d.]+) as tracked on arrival, ([\d.]+) '
        r'refined', run.stdout)
    assert whole <= 1.2 * perfect and perfect < 0.15
    assert live < 2 * whole and refined < 1.15 * whole
