"""Live tracking: nrsfm.tracking against exact models, ShapeTracking, and LivePipeline
(tracking + mapping) against a real rigid solver and the Grassmannian one."""
import numpy as np
import pytest
from scipy.optimize import minimize
from scipy.spatial.transform import Rotation

from doubles import (bending_sheet as make_sequence, frames_of, RigidALS, sliding_windows,
                     stacked)
from grass_nrsfm_ros.mapper import make_mapper, Mapper
from grass_nrsfm_ros.nrsfm import tracking
from grass_nrsfm_ros.nrsfm.measurement import as_frames
from grass_nrsfm_ros.nrsfm.metrics import e3d
from grass_nrsfm_ros.nrsfm.synthetic import make_sequence as make_surface
from grass_nrsfm_ros.pipeline import make_pipeline, reconstruct_live
from grass_nrsfm_ros.refinement import Refinement
from grass_nrsfm_ros.shape_tracking import bootstrap_model, ShapeTracking
from grass_nrsfm_ros.windowing import Frame, Windowing


def random_rotation(rng):
    return Rotation.random(random_state=rng).as_matrix()


def low_rank_sequence(F=40, P=300, rank=2, seed=0):
    """World shapes ``mean + sum_k c_fk B_k`` seen by rotating cameras: ``(X: (F, 3, P),
    R: (F, 3, 3))``, all exact."""
    rng = np.random.default_rng(seed)
    mean = rng.standard_normal((3, P)) * np.array([[1.0], [0.8], [0.5]])
    modes = 0.2 * rng.standard_normal((rank, 3, P))
    c = np.sin(np.outer(np.linspace(0, 3, F), np.arange(1, rank + 1)))
    X = mean + np.einsum('fk,kdp->fdp', c, modes)
    X -= X.mean(axis=2, keepdims=True)
    t = np.linspace(0, 1, F)
    R = Rotation.from_rotvec(np.stack([0.5 * np.sin(3 * t), 0.6 * t, 0.2 * np.cos(2 * t)],
                                      1)).as_matrix()
    return X, R


def test_fit_rotation_recovers_the_orthographic_rotation_not_the_svd_shortcut():
    rng = np.random.default_rng(1)
    X = rng.standard_normal((3, 200)) * np.array([[1.0], [1.0], [0.3]])
    X -= X.mean(axis=1, keepdims=True)
    R_true = random_rotation(rng)
    w = (R_true @ X)[:2]
    start = Rotation.from_rotvec([0.1, -0.15, 0.05]).as_matrix() @ R_true
    R = tracking.fit_rotation(w, X, start, steps=8)
    assert np.abs(R - R_true).max() < 1e-8
    # the shortcut (Procrustes of w against X's x, y rows) is far from it
    U, _, Vt = np.linalg.svd(w @ X[:2].T)
    assert np.abs(U @ Vt - R_true[:2, :2]).max() > 1e-2


def test_tracking_an_exact_low_rank_sequence_reproduces_its_shapes():
    X, R = low_rank_sequence()
    F, _, P = X.shape
    S = R @ X
    ids = np.arange(P, dtype=np.uint32) + 7
    model = tracking.build_model(S[:20].reshape(60, P), R[:20], ids, np.arange(20))
    assert model.rank == 2
    tracker = tracking.Tracker(model, noise_share=0.0)     # exact: no prior
    for f in range(20, F):
        out = tracker.track(f, ids, S[f, :2].T + 50.0)
        assert out.residual < 1e-6
        np.testing.assert_allclose(out.xyz[:, 2], S[f, 2] - S[f, 2].mean(), atol=1e-6)


def test_a_rank_zero_model_is_the_mean_shape_without_an_svd(monkeypatch):
    X, R = low_rank_sequence(F=12)
    S = (R @ X).reshape(36, -1)
    ids = np.arange(X.shape[2], dtype=np.uint32)
    full = tracking.build_model(S, R, ids, np.arange(12))
    monkeypatch.setattr(tracking, 'economy_svd', lambda M: pytest.fail('SVD for rank 0'))
    mean_only = tracking.build_model(S, R, ids, np.arange(12), max_modes=0)
    assert mean_only.rank == 0 and full.rank == 2
    np.testing.assert_allclose(mean_only.mean, full.mean, atol=1e-12)
    assert mean_only.coefficients.shape == (12, 0) and mean_only.variances.shape == (0,)
    out = tracking.Tracker(mean_only).track(12, ids, (R[0] @ X.mean(axis=0))[:2].T)
    assert out.residual < 1e-6


def test_the_bootstrap_fits_a_track_subset_and_shapes_every_track():
    X, R = low_rank_sequence(F=12, P=tracking.FIT_TRACKS + 1500, rank=1)
    X = np.broadcast_to(X[0], X.shape)                        # rigid: the first shape
    S = R @ X
    ids = np.arange(X.shape[2], dtype=np.uint32)
    frames = [Frame(f, '', ids, S[f, :2].T + 100.0) for f in range(12)]
    model = bootstrap_model(frames)
    assert model.rank == 0 and model.mean.shape == X.shape[1:]
    shapes = (model.R @ model.mean).reshape(-1, X.shape[2])
    assert e3d(shapes, S.reshape(-1, X.shape[2])) < 1e-6


@pytest.mark.parametrize('seed', [2, 3, 4, 5])
def test_bootstrap_rebuilds_keep_the_published_depth_orientation(seed):
    # seeds where the rebuilds at 6, 12 and 24 frames mirrored the published depths (before
    # oriented_like: +++---... or ---+++...), so the first model's orientation depended on how
    # many frames went out before it (test_node's refined e3d_akhter failed under load)
    W, S, ids = make_sequence(F=48, noise=0.5, seed=seed)
    windowing, tracking_ = Windowing(window_size=48, window_stride=10), ShapeTracking()
    agreement = []
    for f in range(48):
        result = tracking_.track(windowing.accept(f, ids, W[2 * f:2 * f + 2].T)).result
        z = result.xyz[:, 2]
        if z.std() > 0:                                    # flat before the first model
            order = np.argsort(ids)                        # ids are not sorted
            truth = S[3 * f + 2, order[np.searchsorted(ids[order], result.ids)]]
            agreement.append(np.corrcoef(z, truth)[0, 1])
    assert len(agreement) >= 40
    assert np.all(np.sign(agreement) == np.sign(agreement[0])), np.round(agreement, 2)


def test_coefficients_are_the_map_estimate_inside_the_box_and_the_bounded_one_beyond():
    rng = np.random.default_rng(3)
    A = rng.standard_normal((400, 5))
    var = np.array([4.0, 2.0, 1.0, 0.5, 0.1])
    G, sigma2 = A.T @ A, 2.0
    inside = A @ (0.5 * np.sqrt(var)) + 0.01 * rng.standard_normal(400)
    c = tracking.map_coefficients(G, A.T @ inside, var, sigma2)
    np.testing.assert_allclose(c, np.linalg.solve(G + np.diag(sigma2 / var), A.T @ inside),
                               rtol=1e-8)
    for u in ([40.0, 40.0, 40.0, 40.0, 40.0], [0.0, 0.5, -0.5, 0.0, 10.0]):
        b = A @ (np.array(u) * np.sqrt(var)) + 0.01 * rng.standard_normal(400)
        c = tracking.map_coefficients(G, A.T @ b, var, sigma2, bound=9.0)
        assert np.all(c ** 2 / var <= 9.0 * (1 + 1e-9)), c ** 2 / var

        def objective(c):         # the same objective's minimiser over the box, independently
            return np.sum((A @ c - b) ** 2) + sigma2 * np.sum(c ** 2 / var)
        box = [(-3 * s, 3 * s) for s in np.sqrt(var)]
        ref = minimize(objective, np.zeros(5), bounds=box, method='L-BFGS-B',
                       options=dict(ftol=1e-15, gtol=1e-12)).x
        np.testing.assert_allclose(c, ref, atol=1e-5)
    # one mode cannot spend the others' share: mode 4 at 10 sigma is held at 3 sigma (the
    # whitened norm of all five together, 9 x 5, would have let it reach 6.7)
    assert abs(c[4]) / np.sqrt(var[4]) == pytest.approx(3.0, rel=1e-6)
    # no prior: least squares, unbounded
    beyond = A @ (40.0 * np.sqrt(var))
    np.testing.assert_allclose(tracking.map_coefficients(G, A.T @ beyond, var, 0.0),
                               40.0 * np.sqrt(var), rtol=1e-8)


def test_a_stale_model_is_not_extrapolated_past_its_bound():
    X, R = low_rank_sequence(F=60, rank=3)
    F, _, P = X.shape
    S = R @ X
    ids = np.arange(P, dtype=np.uint32)
    model = tracking.build_model(S[:20].reshape(60, P), R[:20], ids, np.arange(20))
    tracker = tracking.Tracker(model)
    far = X[30] + 30.0 * np.einsum('k,kdp->dp', np.sqrt(model.variances), model.modes)
    out = tracker.track(30, ids, (R[30] @ far)[:2].T)
    assert np.max(out.coefficients ** 2 / model.variances) <= tracking.MODE_BOUND * 1.01
    assert np.max(tracking.Tracker(model, noise_share=0.0).track(
        30, ids, (R[30] @ far)[:2].T).coefficients ** 2 / model.variances) > \
        10 * tracking.MODE_BOUND


def test_new_tracks_take_their_neighbours_depth_and_gone_tracks_are_absent():
    X, R = low_rank_sequence(P=400)
    S = R @ X
    ids = np.arange(400, dtype=np.uint32)
    model_ids = ids[:300]                               # tracks 300..399 unknown to the model
    model = tracking.build_model(S[:20, :, :300].reshape(60, 300), R[:20], model_ids,
                                 np.arange(20))
    tracker = tracking.Tracker(model, noise_share=0.0)     # exact: no prior
    present = np.r_[np.arange(10, 300), np.arange(300, 400)]        # 0..9 gone, 100 new
    f = 25
    out = tracker.track(f, ids[present], S[f, :2][:, present].T)
    assert out.new_tracks == 100 and list(out.ids) == list(ids[present])
    known = np.arange(290)                              # depth is centred over all tracks
    z_true = S[f, 2, present[known]]
    z_known = out.xyz[known, 2]
    assert np.abs((z_known - z_known.mean()) - (z_true - z_true.mean())).max() < 1e-6
    # the cloud is random, so a new track's depth is only checked to be a convex combination
    # of the known tracks' depths (inverse-distance weights)
    z = out.xyz[:, 2]
    assert z[290:].min() >= z[:290].min() - 1e-9 and z[290:].max() <= z[:290].max() + 1e-9


def test_the_fit_model_kept_across_frames_follows_the_tracks_present():
    """The tracker keeps the model's centred fit columns while frames repeat their tracks;
    a frame with other tracks, and a model swap, must not reuse them: each frame equals what
    a tracker without the kept columns gives (the same state, recomputed)."""
    X, R = low_rank_sequence(F=40, P=300, rank=2)
    S = R @ X
    ids = np.arange(300, dtype=np.uint32)
    models = [tracking.build_model(S[a:a + 20].reshape(60, 300), R[a:a + 20], ids,
                                   np.arange(a, a + 20)) for a in (0, 5)]
    kept, fresh = tracking.Tracker(models[0]), tracking.Tracker(models[0])
    subsets = [ids, ids, ids[50:], ids[50:], ids[::2], ids, ids]
    for f, present in zip(range(20, 27), subsets):
        if f == 26:                              # the same tracks as the frame before
            kept.swap(models[1])
            fresh.swap(models[1])
        fresh._fit_cache = None
        a = kept.track(f, present, S[f, :2][:, present].T)
        b = fresh.track(f, present, S[f, :2][:, present].T)
        assert np.array_equal(a.xyz, b.xyz) and np.array_equal(a.R, b.R)


def exact_tracker(F):
    """``(S: (F, 3, P), R: (F, 3, 3), ids, tracker)``: a rank-1 sequence and an exact tracker
    (no prior) on the model of its frames 0-19."""
    X, R = low_rank_sequence(F=F, rank=1)
    S = R @ X
    P = S.shape[2]
    ids = np.arange(P, dtype=np.uint32)
    model = tracking.build_model(S[:20].reshape(60, P), R[:20], ids, np.arange(20))
    return S, R, ids, tracking.Tracker(model, noise_share=0.0)


def test_a_model_swap_carries_the_rotation_through_the_shared_frames():
    """The second model's world is the first one's rotated by Q: tracking goes on from the
    same camera-frame shapes, with no jump."""
    S, R, ids, tracker = exact_tracker(F=50)
    F, P = S.shape[0], S.shape[2]
    for f in range(20, 30):
        tracker.track(f, ids, S[f, :2].T)
    Q = random_rotation(np.random.default_rng(5))
    second = tracking.build_model(S[10:30].reshape(60, P), R[10:30] @ Q, ids, np.arange(10, 30))
    tracker.swap(second)
    for f in range(30, F):
        out = tracker.track(f, ids, S[f, :2].T)
        np.testing.assert_allclose(out.xyz[:, 2], S[f, 2] - S[f, 2].mean(), atol=1e-6)


def test_a_late_model_swap_starts_from_its_newest_rotation_and_the_motion_since():
    """The model arrives four frames after its newest one (solved while tracking went on):
    the tracker carries only the motion since that frame onto the model's own rotation of it,
    so the old model's tracking errors on older shared frames do not leak into the new one."""
    S, R, ids, tracker = exact_tracker(F=50)
    F, P = S.shape[0], S.shape[2]
    for f in range(20, 30):
        tracker.track(f, ids, S[f, :2].T)
    rng = np.random.default_rng(6)
    for f in range(20, 25):                 # the old model's (here: corrupted) older estimates
        tracker.history[f] = random_rotation(rng) @ tracker.history[f]
    Q = random_rotation(np.random.default_rng(5))
    second = tracking.build_model(S[10:26].reshape(48, P), R[10:26] @ Q, ids, np.arange(10, 26))
    tracker.swap(second)
    assert tracker.age == 4
    np.testing.assert_allclose(tracker.R, R[29] @ Q, atol=1e-6)     # frame 29, new world
    for f in range(30, F):
        out = tracker.track(f, ids, S[f, :2].T)
        np.testing.assert_allclose(out.xyz[:, 2], S[f, 2] - S[f, 2].mean(), atol=1e-6)


def test_the_rotation_stays_a_rotation_over_many_model_swaps():
    """A model every second frame (fresh windows in a row): rounding in the carried rotation
    (here: 0.1 % of scale) must not compound from swap to swap (it once squared its
    determinant's error at each swap, until the rotation was zero)."""
    S, R, ids, tracker = exact_tracker(F=120)
    F, P = S.shape[0], S.shape[2]
    tracker.R = 1.001 * tracker.R
    for f in range(20, F):
        if f % 2 == 0:
            tracker.swap(tracking.build_model(S[f - 20:f].reshape(60, P), R[f - 20:f], ids,
                                              np.arange(f - 20, f)))
        out = tracker.track(f, ids, S[f, :2].T)
        assert abs(np.linalg.det(tracker.R) - 1.0) < 1e-9
    np.testing.assert_allclose(out.xyz[:, 2], S[F - 1, 2] - S[F - 1, 2].mean(), atol=1e-6)


# -- LivePipeline -------------------------------------------------------------------------------
def live(solver=RigidALS, **config):
    """An inline LivePipeline with ``solver``, ``refined_from: first_window`` and ``config``."""
    return make_pipeline({'refined_from': 'first_window', **config}, solver)


def sliding(W, ids, solver=RigidALS, **config):
    """``(the windows' FrameResults of W without the tracking, the mapper)``."""
    p = live(solver, **config)
    return sliding_windows(p, W, ids), p.backend.mapper


def test_every_frame_is_published_on_arrival_and_refined_once():
    W, S, ids = make_sequence(F=60, P=150)
    pipe = live()
    refined = []
    for f, (fid, uv) in enumerate(frames_of(W, ids)):
        points = pipe.add_frame(f, fid, uv, 'cam')
        assert [r.stamp_ns for r in points] == [f]               # at once, this frame
        refined += pipe.refined()[0]
    assert [r.stamp_ns for r in refined] == list(range(60))
    assert pipe.tracking.stats['first_model_after'] == 30
    points, refined, _ = reconstruct_live(live(), np.arange(60), frames_of(W, ids))
    assert [r.stamp_ns for r in points] == list(range(60))
    assert [r.stamp_ns for r in refined] == list(range(60))


def test_refined_output_is_the_windows_output_and_tracking_follows_the_rigid_model():
    W, S, ids = make_sequence(F=60, P=150, bend=0.0)                 # rigid: exact for RigidALS
    points, refined, _ = reconstruct_live(live(), np.arange(60), frames_of(W, ids))
    windows, _ = sliding(W, ids)
    # the same frames, up to one depth sign for the whole sequence (the first model keeps
    # the orientation the bootstrap published)
    sign = np.sign(np.dot(refined[0].xyz[:, 2], windows[0].xyz[:, 2]))
    for a, b in zip(refined, windows):
        np.testing.assert_array_equal(a.xyz, b.xyz * [1, 1, sign])
    tracked = np.vstack([r.xyz.T for r in points[30:]])          # tracks in id order
    assert e3d(tracked, S[90:, np.argsort(ids)]) < 1e-4


def test_refined_from_the_last_window_waits_for_each_frames_third_solve():
    W, S, ids = make_sequence(F=60, P=150, bend=0.1)
    pipe = live(refined_from='last_window')
    got, results = [], {}
    for f, (fid, uv) in enumerate(frames_of(W, ids)):
        pipe.add_frame(f, fid, uv)
        refined, updates = pipe.refined()
        results.update({r.stamp_ns: r for r in refined})
        got += [([r.stamp_ns for r in refined], pipe.backend.mapper.previous)] * len(updates)
    pipe.flush()
    refined, updates = pipe.refined()
    results.update({r.stamp_ns: r for r in refined})
    got += [([r.stamp_ns for r in refined], pipe.backend.mapper.previous)] * len(updates)
    # windows 0-29, 10-39 (context 0-9), 20-49 (context 0-19), 30-59, then the flush
    assert [stamps for stamps, _ in got] == [[], [], list(range(30)), list(range(30, 40)),
                                             list(range(40, 60))]
    assert pipe.refinement.stats['solved'] == 4             # the flush solved nothing again
    assert sorted(results) == list(range(60))
    # each frame from its latest solve: frame 0 from the third, 45 from the fourth
    for stamp, solution in ((0, got[2][1]), (45, got[3][1])):
        at = list(solution.stamps).index(stamp)
        z = as_frames(solution.S, 3)[at, 2]
        np.testing.assert_allclose(results[stamp].xyz[:, 2], z - z.mean(), atol=1e-12)
    assert pipe.windowing.stats['frames'] == \
        pipe.refinement.stats['published'] + pipe.frames_lost == 60


def test_refined_from_the_last_window_loses_no_frame_without_context():
    W, S, ids = make_sequence(F=60, P=150, bend=0.1)
    pipe = live(refined_from='last_window', context_frames=0)
    _, refined, _ = reconstruct_live(pipe, np.arange(60), frames_of(W, ids))
    # frames 0-9 are in no later window: out with the second, from the first window's solve
    assert [r.stamp_ns for r in refined] == list(range(60))
    assert pipe.frames_lost == 0


@pytest.mark.slow
def test_refined_from_the_last_window_is_more_accurate():
    """Measured (50 x 300, the Grassmannian solver): e3D of points/refined from the first
    window / the last: articulated 0.0555 / 0.0100, twisting 0.3903 / 0.0685."""
    ids = np.arange(300, dtype=np.uint32)
    for kind in ('articulated', 'twisting'):
        seq = make_surface(kind, n_frames=50, n_points=300, seed=0)
        errors = {}
        for refined_from in ('first_window', 'last_window'):
            pipe = make_pipeline({'refined_from': refined_from})
            _, refined, _ = reconstruct_live(pipe, np.arange(50), frames_of(seq.W, ids))
            assert [r.stamp_ns for r in refined] == list(range(50))
            errors[refined_from] = e3d(stacked(refined), seq.S)
        assert errors['last_window'] < 0.5 * errors['first_window'], (kind, errors)


def test_offline_output_is_reproducible():
    W, S, ids = make_sequence(F=50, P=120, bend=0.1)
    runs = [reconstruct_live(live(), np.arange(50), frames_of(W, ids)) for _ in range(2)]
    for a, b in zip(runs[0][0] + runs[0][1], runs[1][0] + runs[1][1]):
        assert a.stamp_ns == b.stamp_ns
        np.testing.assert_array_equal(a.xyz, b.xyz)


def test_tracks_joining_and_leaving_mid_sequence():
    W, S, ids = make_sequence(F=60, P=200, bend=0.0)
    pipe = live()
    out = []
    for f, (fid, uv) in enumerate(frames_of(W, ids)):
        keep = np.arange(200) < 150 if f < 40 else np.arange(200) >= 20     # 20 leave, 50 join
        out += pipe.add_frame(f, fid[keep], uv[keep])
        pipe.refined()
    late = out[45]
    present = np.flatnonzero(np.arange(200) >= 20)
    assert sorted(late.ids) == sorted(ids[present])               # the gone ones are absent
    gt = as_frames(S, 3)[45][:, present[np.argsort(ids[present])]]  # in id order, as published
    xyz = late.xyz.T
    joined = np.isin(late.ids, ids[150:])                          # 50 the model lacks
    assert e3d(xyz[:, ~joined], gt[:, ~joined]) < 1e-3             # rigid: exact where modelled
    flat = xyz.copy()
    flat[2, joined] = xyz[2, ~joined].mean()
    assert e3d(xyz, gt) < 0.5 * e3d(flat, gt)                      # neighbours' depth, not none


def test_an_abrupt_change_is_reported_and_asks_for_a_fresh_window():
    W, S, ids = make_sequence(F=80, P=150, bend=0.0)
    W2, _, _ = make_sequence(F=80, P=150, bend=0.6, seed=3)      # another surface, same ids
    W = np.vstack([W[:100], W2[100:]])                             # frames 50.. change
    pipe = live()
    residuals = []
    for f, (fid, uv) in enumerate(frames_of(W, ids)):
        points = pipe.add_frame(f, ids, uv)
        residuals.append(pipe.tracking.last['residual'])
        pipe.refined()
        if f == 49:
            assert pipe.tracking.stats['fresh_windows'] == 0
    assert residuals[50] > 10 * np.median(residuals[35:50])
    assert pipe.tracking.stats['fresh_windows'] >= 1
    assert len(points) == 1                                         # still published


def test_live_points_follow_the_windows_on_a_deforming_surface():
    seq = make_surface('bending', n_frames=50, n_points=300, seed=0)
    ids = np.arange(300, dtype=np.uint32)
    points, refined, _ = reconstruct_live(make_pipeline({'refined_from': 'first_window'}),
                                          np.arange(50), frames_of(seq.W, ids))
    tracked = e3d(stacked(points[30:]), seq.S[90:])
    windows = e3d(stacked(refined[30:]), seq.S[90:])
    assert tracked < 1.5 * windows
    # one depth orientation across model swaps: consecutive tracked frames agree in sign
    z = np.stack([r.xyz[:, 2] for r in points[30:]])
    assert (np.einsum('fp,fp->f', z[1:], z[:-1]) > 0).all()
    # and no jump in depth scale beyond the truth's own change: a swap moves to the newer
    # model's depth (frame 40, the second model correcting the first: 0.79 of the truth's step)
    z_gt = as_frames(seq.S, 3)[30:, 2]
    step = np.linalg.norm(z, axis=1) / np.linalg.norm(z_gt - z_gt.mean(axis=1, keepdims=True),
                                                      axis=1)
    step = step[1:] / step[:-1]
    assert step.max() < 1.3 and step.min() > 0.7, step


def test_bad_parameters_are_refused():
    with pytest.raises(ValueError, match='residual_limit'):
        ShapeTracking(residual_limit=0.5)
    with pytest.raises(ValueError, match='mapping_tracks'):
        Mapper(RigidALS, mapping_tracks=5)
    with pytest.raises(ValueError, match='window_stride'):
        Windowing(window_size=10, window_stride=11)


def test_mapping_on_a_subset_of_tracks_fills_in_the_rest():
    seq = make_surface('bending', n_frames=40, n_points=600, seed=1)
    ids = np.arange(600, dtype=np.uint32)
    full, _ = sliding(seq.W, ids, None)
    part, cut = sliding(seq.W, ids, None, mapping_tracks=300)
    assert all(r.ids.size == 600 for r in part)
    e_full = e3d(stacked(full), seq.S)
    e_part = e3d(stacked(part), seq.S)
    assert e_part < 1.25 * e_full
    assert cut.previous.report is not None


def test_a_degenerate_frame_goes_out_flat_and_is_counted():
    W, S, ids = make_sequence(F=40, P=100, bend=0.0)
    pipe = live()
    for f, (fid, uv) in enumerate(frames_of(W, ids)):
        pipe.add_frame(f, fid, uv)
        pipe.refined()
    assert pipe.tracking.has_model and pipe.tracking.stats['tracking_failed'] == 0
    (result,) = pipe.add_frame(40, ids, np.full((100, 2), 7.0))    # every track coincides
    assert pipe.tracking.stats['tracking_failed'] == 1
    assert np.array_equal(result.xyz, np.zeros((100, 3)))


def test_a_reset_forgets_the_model_and_starts_a_new_sequence():
    W, S, ids = make_sequence(F=45, P=100, bend=0.0)
    pipe = live()
    for f, (fid, uv) in enumerate(frames_of(W, ids)):
        pipe.add_frame(f, fid, uv)
        pipe.refined()
    assert pipe.tracking.has_model
    assert pipe.reset() == {'frames': 5, 'model': True}           # frames 40..44 in no window
    assert not pipe.tracking.has_model and pipe.backend.mapper.previous is None
    assert pipe.frames_lost == 5
    pipe.add_frame(0, ids, frames_of(W, ids)[0][1])               # earlier stamps: a new one
    assert pipe.windowing.sequence == 1


def test_make_mapper_takes_the_windows_parameters_from_the_config():
    mapper = make_mapper({'warm_start': 'model', 'context_frames': 20, 'refined_from':
                          'last_window', 'window_size': 30, 'window_stride': 10}, RigidALS)
    assert (mapper.warm_start, mapper.context_frames, mapper.refined_after) == ('model', 20, 3)
    assert Refinement().refined_after == 1
