from dataclasses import replace
import tracemalloc

import numpy as np
import pytest

from conftest import data_root
from doubles import wobbling_rotations
from grass_nrsfm_ros.nrsfm import e3d, GrassmannNRSfM, InvalidInputError, WarmStart
from grass_nrsfm_ros.nrsfm.admm import (AdmmState, closed_form_shapes, coefficient_step,
                                        dual_step, nuclear_of_factors)
from grass_nrsfm_ros.nrsfm.config import admm_settings
from grass_nrsfm_ros.nrsfm.rotation import align_rotations, rigid_factorisation
from grass_nrsfm_ros.nrsfm.schema import solver_defaults


def deforming_sheet(F=30, P=600, seed=0, noise=0.0):
    """Dense smooth surface bending with three smooth modes: ``(W, S_camera, R)``."""
    rng = np.random.default_rng(seed)
    u, v = rng.uniform(-1, 1, (2, P))
    base = np.stack([u, v, 0.8 * (u ** 2 + v ** 2) + 0.3 * np.sin(2 * u) * np.cos(v)])
    modes = np.stack([np.stack([0 * u, 0 * v, u ** 2 - v ** 2]),
                      np.stack([0.2 * v, -0.2 * u, np.sin(3 * u)]),
                      np.stack([0 * u, 0.1 * u * v, np.cos(2 * v) * u])])
    t = np.linspace(0, 1, F)
    weights = 0.3 * np.sin(2 * np.pi * np.array([0.7, 1.1, 1.6])[:, None] * t + [[0], [1], [2]])
    world = base[None] + np.einsum('mf,mcp->fcp', weights, modes)
    R = wobbling_rotations(F, rng, amplitude=1.0)
    cam = R @ world + rng.normal(size=(F, 3, 1))             # plus a translation per frame
    W = cam[:, :2, :].reshape(2 * F, P)
    if noise:
        W = W + noise * np.abs(W).max() * rng.normal(size=W.shape)
    return W, cam.reshape(3 * F, P), R


def dense_face(F=30, P=1500, seed=0):
    """Dense deforming face from the Surrey face model (skips without the data):
    identity + 6 expression blendshapes with smooth weights in [0, 1.5], barycentric samples
    on the mesh, smooth head rotation (yaw 30, pitch 20, roll 10 degrees). ``(W, S, R)``."""
    root = data_root()
    if root is None or not (root / 'sfm_face' / 'sfm_face.npz').is_file():
        pytest.skip('sfm_face model not found (set GRASS_NRSFM_DATA)')
    rng = np.random.default_rng(seed)
    with np.load(root / 'sfm_face' / 'sfm_face.npz') as model:
        verts, tri, expr = model['mean'], model['triangles'], model['expressions']
    t = np.linspace(0, 1, F)
    w = 0.75 + 0.75 * np.sin(2 * np.pi * rng.uniform(0.5, 2, (6, 1)) * t
                             + rng.uniform(0, 2 * np.pi, (6, 1)))
    frames = verts[None] + np.einsum('ef,evc->fvc', w, expr)           # (F, V, 3)
    corners = tri[rng.integers(len(tri), size=P)]
    bary = rng.dirichlet(np.ones(3), size=P)
    points = np.einsum('pk,fpkc->fcp', bary, frames[:, corners])      # (F, 3, P)
    points -= points.mean(axis=(0, 2), keepdims=True)
    angles = np.radians([30, 20, 10])[:, None] * np.sin(
        2 * np.pi * rng.uniform(0.5, 1.5, (3, 1)) * t + rng.uniform(0, 2 * np.pi, (3, 1)))
    R = []
    for yaw, pitch, roll in angles.T:
        Ry = np.array([[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]])
        Rx = np.array([[1, 0, 0], [0, np.cos(pitch), -np.sin(pitch)],
                       [0, np.sin(pitch), np.cos(pitch)]])
        Rz = np.array([[np.cos(roll), -np.sin(roll), 0], [np.sin(roll), np.cos(roll), 0],
                       [0, 0, 1]])
        R.append(Ry @ Rx @ Rz)
    R = np.array(R)
    cam = R @ points
    return cam[:, :2].reshape(2 * F, P), cam.reshape(3 * F, P), R


def rigid_with_rotations(W, R):
    """Best single world shape for known rotations (least squares), in camera frames."""
    F, P = R.shape[0], W.shape[1]
    Wc = (W - W.mean(axis=1, keepdims=True)).reshape(F, 2, P)
    A = np.einsum('fki,fkj->ij', R[:, :2], R[:, :2])
    b = np.einsum('fki,fkp->ip', R[:, :2], Wc)
    shape = np.linalg.solve(A, b)
    return (R @ shape).reshape(3 * F, P)


def test_fit_beats_rigid_reconstruction_with_true_rotations():
    W, S, R = dense_face()
    res = GrassmannNRSfM().fit(W, init=WarmStart(R=R))
    rigid = e3d(rigid_with_rotations(W, R), S)
    err = e3d(res.S, S)
    assert err < 0.6 * rigid, (err, rigid)
    assert res.report.converged and res.report.fallback is None
    # outputs in the caller's column order and units: x, y reproduce the centred tracks
    Wc = W - res.translation
    xy = res.S.reshape(-1, 3, W.shape[1])[:, :2].reshape(W.shape)
    assert np.linalg.norm(xy - Wc) < 0.05 * np.linalg.norm(Wc)
    assert res.report.reprojection_relative == pytest.approx(
        np.sqrt(np.mean((xy - Wc) ** 2)) / np.sqrt(np.mean(Wc ** 2)))
    assert np.allclose(res.R, R)
    assert res.groups.shape == (W.shape[1],) and res.groups.max() + 1 == res.report.K_s


def test_admm_gaps_shrink_and_report_is_complete():
    W, S, R = deforming_sheet(F=20, P=300, seed=1)
    seen = []
    res = GrassmannNRSfM().fit(W, init=WarmStart(R=R), progress=lambda i, rep: seen.append(i))
    rep = res.report
    gaps = np.array(rep.gaps)
    assert gaps.shape == (rep.iterations, 3)
    assert seen == list(range(1, rep.iterations + 1))
    assert len(rep.objective) == rep.iterations and np.all(np.isfinite(rep.objective))
    early, late = gaps[:10].max(axis=0), gaps[-10:].max(axis=0)
    assert late[0] < 1e-3 * early[0]                        # S# = T1(S)
    assert late[1] < 1e-3 * max(early[1], 1e-12) + 1e-9     # C_s = J_s
    assert late[2] < 1e-3 * max(early[2], 1e-12) + 1e-9     # C_t = J_t
    for phase in ('rotation', 's_update', 'spatial', 'svt', 'temporal', 'total'):
        assert phase in rep.seconds
    assert rep.reprojection_relative < 0.05
    assert min(rep.K_s, rep.K_t, rep.N_s, rep.N_t) >= 1


@pytest.mark.parametrize('spatial,temporal', [(False, False), (True, False), (False, True)])
def test_ablations_run_and_reconstruct(spatial, temporal):
    W, S, R = dense_face(F=20, P=800, seed=2)
    res = GrassmannNRSfM(spatial=spatial, temporal=temporal).fit(W, init=WarmStart(R=R))
    assert e3d(res.S, S) < 0.6 * e3d(rigid_with_rotations(W, R), S)


def test_sharp_step_thresholds_singular_values_wide_and_tall():
    """The S# step (temporal branch off) is the SVT by gamma / beta, through the F x F Gram
    (wide) and the 3P x 3P one (tall) alike; its norm is that of the result."""
    F, P, beta = 12, 20, 1.0
    rng = np.random.default_rng(0)
    params = dict(solver_defaults(), spatial=False, temporal=False, K_s=1, K_t=1, N_s=3, N_t=3)
    settings = replace(admm_settings(params, F, P, None, spatial=False), gamma=2.0)
    state = AdmmState(rng.normal(size=(2 * F, P)), wobbling_rotations(F, rng),
                      rng.normal(size=(F, 3, P)), settings)
    X = rng.normal(size=(F, 3 * P))
    (left, right), _, nuclear = state._sharp_operator(X @ X.T, beta, 0)
    wide = left @ (right.T @ X)
    tall, _, nuclear_tall = state._sharp_tall(X, beta, 0)
    np.testing.assert_allclose(wide, tall, atol=1e-10)
    sv_in, sv_out = (np.linalg.svd(A, compute_uv=False) for A in (X, wide))
    np.testing.assert_allclose(sv_out, np.maximum(sv_in - 2.0, 0.0), atol=1e-9)
    assert np.isclose(nuclear, sv_out.sum()) and np.isclose(nuclear_tall, sv_out.sum())


def test_closed_form_shapes_solve_the_per_frame_normal_equations():
    """The S update without the prior is the solution of ``(R^T P R + beta I) S = R^T [W; 0]
    + beta S# + Y1`` frame by frame (P keeps the two image rows)."""
    F, n, beta = 5, 7, 3.0
    rng = np.random.default_rng(1)
    R = wobbling_rotations(F, rng)
    W = rng.normal(size=(F, 2, n))
    sharp, Y1 = rng.normal(size=(F, 3, n)), rng.normal(size=(F, 3, n))
    out = np.empty((F, 3, n))
    closed_form_shapes(R, R.transpose(0, 2, 1).copy(), W, sharp, Y1, beta,
                       [np.empty((F, 3, n)) for _ in range(2)], out)
    Pm = np.diag([1.0, 1.0, 0.0])
    lhs = R.transpose(0, 2, 1) @ Pm @ R + beta * np.eye(3)
    rhs = R[:, :2, :].transpose(0, 2, 1) @ W + beta * sharp + Y1
    np.testing.assert_allclose(out, np.linalg.solve(lhs, rhs), atol=1e-12)


def test_coefficient_and_dual_steps_and_the_nuclear_norm_of_factors():
    """J is the SVT of C + Y/beta by lam_nuclear/beta with its nuclear norm, the dual step
    moves Y by beta (C - J) and reports max |C - J|; the factored nuclear norm is that of the
    matrix ``L chol(core)``."""
    rng = np.random.default_rng(2)
    A = rng.normal(size=(4, 4))
    Omega, J, Y, beta = A @ A.T + np.eye(4), rng.normal(size=(4, 4)), rng.normal(size=(4, 4)), 2.0
    C, J_new, nuclear = coefficient_step(Omega, J, Y, 0.5, 0.8, beta)
    sv = np.linalg.svd(C + Y / beta, compute_uv=False)
    np.testing.assert_allclose(np.linalg.svd(J_new, compute_uv=False),
                               np.maximum(sv - 0.8 / beta, 0.0), atol=1e-12)
    assert nuclear == pytest.approx(np.maximum(sv - 0.4, 0.0).sum())
    Y_before = Y.copy()
    gap = dual_step(Y, C, J_new, beta)
    np.testing.assert_allclose(Y, Y_before + beta * (C - J_new))
    assert gap == np.abs(C - J_new).max() > 0
    L, core = rng.normal(size=(9, 3)), A[:3, :3] @ A[:3, :3].T
    expected = np.linalg.svd(L @ np.linalg.cholesky(core), compute_uv=False).sum()
    assert nuclear_of_factors(L, core) == pytest.approx(expected)


def test_warm_start_with_true_shapes_converges_in_fewer_iterations():
    W, S, R = dense_face(F=20, P=500, seed=3)
    cold = GrassmannNRSfM().fit(W, init=WarmStart(R=R))
    warm = GrassmannNRSfM().fit(W, init=WarmStart(R=R, S=S, groups=cold.groups))
    assert warm.report.iterations < cold.report.iterations
    assert warm.report.warm_started_frames == 20
    # config.WARM_BETA0 = 0.01 (chosen for streaming, records 0011, 0035) lets a warm run move
    # as far from its start as it needs, so starting at the truth ends at the cold run's
    # quality (measured: 0.0390 warm vs 0.0386 cold), not closer to the truth; the saving is
    # in iterations.
    assert e3d(warm.S, S) <= 1.05 * e3d(cold.S, S)
    assert np.array_equal(np.unique(warm.groups), np.unique(cold.groups))


def test_align_rotations_recovers_world_rotation_and_flip():
    rng = np.random.default_rng(4)
    R = wobbling_rotations(10, rng)
    Q = wobbling_rotations(1, rng, amplitude=2.0)[0]
    D = np.diag([1.0, 1.0, -1.0])
    est = D @ (R @ Q.T) @ D                                  # other world frame, depth-flipped
    known = np.arange(10) < 6
    aligned = align_rotations(est, R, known)
    assert np.allclose(aligned, R, atol=1e-10)


def test_no_p_by_p_allocation():
    F, P = 4, 20000                                          # P x P float64 would be 3.2 GB
    W, S, R = deforming_sheet(F=F, P=P, seed=5)
    tracemalloc.start()
    try:
        res = GrassmannNRSfM(K_s=4, max_iter=30).fit(W, init=WarmStart(R=R))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert res.S.shape == (3 * F, P)
    assert peak < 100e6, peak                                # ~ a few copies of (3F, P)


@pytest.mark.parametrize('W,needle', [
    (np.full((6, 10), np.nan), 'non-finite'),
    (np.ones((4, 10)), 'frames'),
    (np.ones((7, 10)), 'even number of rows'),
    (np.ones((6, 3)), 'points'),
    (np.ones(12), '2-D'),
])
def test_invalid_tracks_raise_clear_errors(W, needle):
    with pytest.raises(InvalidInputError, match=needle):
        GrassmannNRSfM().fit(W, init=WarmStart(R=np.tile(np.eye(3), (3, 1, 1))))


@pytest.mark.parametrize('params,needle', [
    (dict(rho=1.0), 'rho'), (dict(gamma=-1.0), 'gamma'), (dict(K_s='many'), 'K_s'),
    (dict(N_t=0), 'N_t'),
    (dict(spatial='yes'), 'spatial'),
    (dict(max_iter=0), 'max_iter'), (dict(beta_max=1e-6), 'beta_max'),
    (dict(rotations='true'), 'rotations'), (dict(random_state=-1), 'random_state'),
])
def test_invalid_parameters_raise_in_fit(params, needle):
    est = GrassmannNRSfM(**params)                           # stored unchanged
    assert all(getattr(est, k) == v for k, v in params.items())
    W, _, R = deforming_sheet(F=5, P=50)
    with pytest.raises(InvalidInputError, match=needle):
        est.fit(W, init=WarmStart(R=R))


def test_invalid_warm_start_raises():
    W, S, R = deforming_sheet(F=5, P=50)
    with pytest.raises(InvalidInputError, match='init.S'):
        GrassmannNRSfM().fit(W, init=WarmStart(R=R, S=S[:, :10]))
    with pytest.raises(InvalidInputError, match='init.R'):
        GrassmannNRSfM().fit(W, init=WarmStart(R=R * 2))
    with pytest.raises(InvalidInputError, match='init.known'):
        GrassmannNRSfM().fit(W, init=WarmStart(R=R, known=np.ones(3, bool)))
    with pytest.raises(InvalidInputError, match='init.groups'):
        GrassmannNRSfM().fit(W, init=WarmStart(R=R, groups=np.zeros(7, int)))
    with pytest.raises(InvalidInputError, match='init.rotation_method'):
        GrassmannNRSfM().fit(W, init=WarmStart(rotation_method='auto'))


def test_given_rotation_method_skips_the_check_and_is_reported():
    W, S, R = deforming_sheet(F=20, P=300, seed=2)
    checked = GrassmannNRSfM().fit(W).report
    assert checked.rotation_checked and checked.rotation_method in ('dai', 'rigid')
    res = GrassmannNRSfM().fit(W, init=WarmStart(rotation_method='rigid'))
    assert res.report.rotation_method == 'rigid' and not res.report.rotation_checked
    np.testing.assert_allclose(res.R, rigid_factorisation(W)[0])
    dai = GrassmannNRSfM().fit(W, init=WarmStart(rotation_method='dai')).report
    assert dai.rotation_method == 'dai' and dai.K_rot is not None
    assert GrassmannNRSfM().fit(W, init=WarmStart(R=R)).report.rotation_method == 'given'


def test_one_given_group_switches_the_spatial_branch_off_like_auto():
    W, S, R = deforming_sheet(F=10, P=200, seed=3)     # 200 points: 'auto' gives one group
    auto = GrassmannNRSfM().fit(W, init=WarmStart(R=R))
    given = GrassmannNRSfM().fit(W, init=WarmStart(R=R, groups=np.zeros(200, int)))
    assert any('spatial branch off' in n for n in auto.report.notes)
    assert any('init.groups hold one group' in n for n in given.report.notes)
    np.testing.assert_allclose(given.S, auto.S)


def test_parameter_specs_document_every_parameter():
    names = set(GrassmannNRSfM().get_params())
    assert names == set(GrassmannNRSfM.parameter_specs)
    assert all(spec.description and spec.constraint
               for spec in GrassmannNRSfM.parameter_specs.values())


def test_sparse_auto_turns_spatial_branch_off_and_says_so():
    W, S, R = deforming_sheet(F=20, P=60, seed=6)
    rep = GrassmannNRSfM().fit(W, init=WarmStart(R=R)).report
    assert rep.K_s == 1 and rep.gaps[-1][1] == 0.0
    assert any('spatial branch off' in note for note in rep.notes)
    explicit = GrassmannNRSfM(K_s=2).fit(W, init=WarmStart(R=R)).report
    assert explicit.K_s == 2 and not explicit.notes


def test_fit_without_rotations_estimates_them():
    W, S, R = deforming_sheet(F=20, P=300, seed=7)
    res = GrassmannNRSfM().fit(W)
    assert res.R.shape == (20, 3, 3) and res.report.K_rot >= 1
    assert np.all(np.isfinite(res.S)) and res.report.seconds['rotation'] > 0
