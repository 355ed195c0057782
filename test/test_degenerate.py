"""Degenerate scenes: rigid, planar, collinear, a static camera, duplicated frames, every point
at one pixel, too few tracks or frames, all tracks replaced mid-window.

The contract: a solver returns finite shapes and rotations or raises a ValueError that says
why; the pipeline (and the node) publishes finite clouds or nothing, and accounts for every
frame (published, lost or pending)."""
from functools import partial

import numpy as np
import pytest

from doubles import NaNSolver, RigidALS
from grass_nrsfm_ros import cloud
from grass_nrsfm_ros.nrsfm import GrassmannNRSfM, rotation
from grass_nrsfm_ros.nrsfm.measurement import as_frames, from_frames, to_camera
from grass_nrsfm_ros.nrsfm.synthetic import camera_rotations, make_sequence
from grass_nrsfm_ros.pipeline import make_pipeline
from grass_nrsfm_ros.windowing import FrameError

F, P = 30, 150


def project(S_world, R, shift=(320.0, 240.0)):
    """``W: (2F, P)`` pixels of ``S_world: (3F, P)`` seen by ``R: (F, 3, 3)``, 100 px per unit."""
    S = as_frames(to_camera(R, S_world), 3)[:, :2, :] * 100.0
    return from_frames(S + np.asarray(shift)[None, :, None])


def scene(name):
    """``W: (2F, P)`` of a degenerate scene."""
    rng = np.random.default_rng(0)
    orbit = camera_rotations('orbit', F, np.random.default_rng(1))
    if name == 'static_camera':
        return make_sequence('bending', F, P, camera='static').W
    if name == 'duplicated_frames':                      # every frame twice
        W = make_sequence('bending', F // 2, P).W
        return from_frames(np.repeat(as_frames(W, 2), 2, axis=0))
    if name == 'too_few_tracks':
        return make_sequence('bending', F, 3).W
    if name == 'too_few_frames':
        return make_sequence('bending', 2, P).W
    if name == 'one_pixel':
        return np.full((2 * F, P), 100.0)
    shape = {'rigid': make_sequence('bending', 1, P).S_world,
             'planar': np.vstack([rng.uniform(-1, 1, (2, P)), np.zeros((1, P))]),
             'collinear': np.outer([1.0, 0.5, 0.2], rng.uniform(-1, 1, P)),
             'static_rigid': make_sequence('bending', 1, P).S_world}[name]
    R = np.tile(np.eye(3), (F, 1, 1)) if name == 'static_rigid' else orbit
    return project(np.tile(shape, (F, 1)), R)


SCENES = ('rigid', 'planar', 'collinear', 'static_camera', 'static_rigid', 'duplicated_frames',
          'one_pixel', 'too_few_tracks', 'too_few_frames')


def solvers():
    """``{name: fit(W) -> (S, R)}`` for every solver."""
    out = {'rigid_factorisation': lambda W: rotation.rigid_factorisation(W)[::-1],
           'estimate_rotations': lambda W: (None, rotation.estimate_rotations(W).R)}

    def grassmann(W):
        res = GrassmannNRSfM(max_iter=60).fit(W)
        return res.S, res.R
    out['GrassmannNRSfM'] = grassmann
    return out


def outcome(fit, W):
    """'finite' or 'ExceptionType: message'; fails on non-finite output or a silent error."""
    try:
        S, R = fit(W)
    except ValueError as exc:          # InvalidInputError and the rotation step's errors
        assert str(exc).strip(), type(exc)
        return f'{type(exc).__name__}: {exc}'
    for name, value in (('S', S), ('R', R)):
        if value is not None:
            assert np.isfinite(value).all(), f'non-finite {name}'
    return 'finite'


@pytest.mark.parametrize('name', SCENES)
def test_solvers_return_finite_results_or_a_reason(name):
    W = scene(name)
    results = {solver: outcome(fit, W) for solver, fit in solvers().items()}
    print(name, results)
    if name in ('too_few_tracks', 'too_few_frames') and 'GrassmannNRSfM' in results:
        assert results['GrassmannNRSfM'].startswith('InvalidInputError'), results


# -- the pipeline ------------------------------------------------------------------------------
def run_pipeline(W, ids=None, factory=None, **config):
    """Feed ``W`` frame by frame to an inline LivePipeline (``refined_from: first_window``);
    return (refined results, pipeline, refused frames, failed windows); the points published
    on arrival are kept in ``pipeline.points``."""
    config = dict(dict(window_size=10, window_stride=5, min_tracks=4,
                       refined_from='first_window'), **config)
    p = make_pipeline(config, factory or RigidALS)
    ids = np.arange(W.shape[1], dtype=np.uint32) if ids is None else ids
    results, refused, failed, p.points = [], [], [], []

    def take():
        refined, updates = p.refined()
        results.extend(refined)
        failed.extend(u.message for u in updates if u.kind == 'failed')

    frames = as_frames(W, 2)
    for f in range(frames.shape[0]):
        frame_ids = ids if ids.ndim == 1 else ids[f]
        try:
            p.points += p.add_frame(10 ** 9 + f * 33_000_000, frame_ids, frames[f].T)
        except FrameError as exc:
            refused.append(str(exc))
        take()
    p.flush()
    take()
    return results, p, refused, failed


def check_published(results, p, refused, sent):
    assert all(np.isfinite(r.xyz).all() for r in results + p.points)
    frames, published = p.windowing.stats['frames'], p.refinement.stats['published']
    assert frames + len(refused) == sent and len(p.points) == frames
    assert frames == published + p.frames_lost + p.pending_frames
    assert published == len(results)


@pytest.mark.parametrize('name', SCENES)
def test_pipeline_publishes_finite_clouds_or_nothing(name):
    W = scene(name)
    results, p, refused, failed = run_pipeline(W)
    print(name, {'published': len(results), 'refused': len(refused), 'failed': failed[:1]})
    check_published(results, p, refused, W.shape[0] // 2)
    if name == 'too_few_tracks':
        assert not results and len(refused) == W.shape[0] // 2
        assert 'min_tracks' in refused[0]
    if name == 'too_few_frames':
        assert not results and p.frames_lost == 2


def test_pipeline_publishes_nothing_from_a_solver_returning_nan():
    results, p, refused, failed = run_pipeline(scene('rigid'), factory=NaNSolver)
    check_published(results, p, refused, F)
    assert results == [] and p.refinement.stats['solved'] == 0
    assert p.refinement.stats['failed'] == p.windowing.stats['windows']
    assert failed and all('non-finite' in line for line in failed)


@pytest.mark.parametrize('name', SCENES)
def test_pipeline_with_the_grassmann_solver(name):
    W = scene(name)
    results, p, refused, failed = run_pipeline(W, factory=partial(GrassmannNRSfM, max_iter=60))
    print(name, {'published': len(results), 'refused': len(refused), 'failed': failed[:1]})
    check_published(results, p, refused, W.shape[0] // 2)


def test_all_tracks_replaced_mid_window_publishes_both_sequences():
    W = make_sequence('bending', F, P).W
    ids = np.tile(np.arange(P, dtype=np.uint32), (F, 1))
    ids[17:] += 10_000                       # frame 17: a new tracker session, mid-window
    results, p, refused, failed = run_pipeline(W, ids)
    check_published(results, p, refused, F)
    assert p.windowing.stats['resets'] == 1 and not failed and not refused
    assert [r.stamp_ns for r in results] == [10 ** 9 + f * 33_000_000 for f in range(F)]
    assert all((r.ids < 10_000).all() == (k < 17) for k, r in enumerate(results))


# -- the node process ----------------------------------------------------------------------------
@pytest.mark.ros
def test_node_publishes_no_garbage_on_degenerate_streams(ros_env, tmp_path):
    """Degenerate scenes back to back (each a new sequence): every published cloud is finite,
    every message is accounted for and the node stays up."""
    pytest.importorskip('rclpy')
    import rosutil                      # imported here: it needs rclpy, the rest of this file not
    from std_msgs.msg import Header

    names = ('rigid', 'planar', 'static_rigid', 'duplicated_frames', 'one_pixel')
    messages, f = [], 0
    for k, name in enumerate(names):
        W = scene(name)
        for uv in as_frames(W, 2):
            header = Header(frame_id='camera')
            header.stamp.sec, header.stamp.nanosec = 1000 + f // 30, (f % 30) * 33_000_000
            ids = np.arange(P, dtype=np.uint32) + 10_000 * k       # a new sequence per scene
            messages.append(cloud.encode_tracks(ids, uv.T, header))
            f += 1
    args = ['-p', 'window_size:=10', '-p', 'window_stride:=5', '-p', 'min_tracks:=4']
    log = tmp_path / 'node.log'
    with rosutil.node_with_feeder(ros_env, log, args) as (proc, feeder):
        rosutil.publish(feeder, messages)
        counts = feeder.accounted(len(messages))
        assert counts is not None, log.read_text()
        assert proc.poll() is None
        points = list(feeder.points)
    published = [cloud.decode_points(m)[1] for m in points]
    print({**counts, 'clouds received': len(points)})
    assert all(np.isfinite(xyz).all() for xyz in published), 'a non-finite cloud was published'
    assert counts['messages received'] == len(messages)
    assert counts['messages received'] == (counts['dropped messages'] + counts['frames published']
                                           + counts['frames lost'] + counts['frames pending'])
