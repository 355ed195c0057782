"""Organic Priors' rotations (rotation_averaging) and the weighted partial nuclear norm."""
import numpy as np

from grass_nrsfm_ros.nrsfm import GrassmannNRSfM
from grass_nrsfm_ros.nrsfm.admm import partial_weights
from grass_nrsfm_ros.nrsfm.measurement import nearest_rotation
from grass_nrsfm_ros.nrsfm.metrics import e3d, rotation_error
from grass_nrsfm_ros.nrsfm.problem import WarmStart
from grass_nrsfm_ros.nrsfm.rotation import estimate_rotations
from grass_nrsfm_ros.nrsfm.rotation_averaging import (chordal, l1_average, MIRROR, op_rotations,
                                                      register_candidates, ROW_SIGN, so3_exp,
                                                      so3_log, triplet_candidates)
from grass_nrsfm_ros.nrsfm.synthetic import rotations_from_angles


def angles_deg(A, B):
    return np.degrees(np.linalg.norm(so3_log(A @ np.swapaxes(B, -1, -2)), axis=-1))


def random_rotations(rng, n):
    return so3_exp(rng.normal(size=(n, 3)))


def low_rank_problem(F=120, P=40, K=3, seed=1):
    """Exact rank-K tracks ``W = R (C x I3) B``: ``(W, S camera frame, R)``."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, F)
    R = rotations_from_angles(2 * np.pi * 0.6 * t, 0.4 * np.sin(3 * t), 0.2 * np.cos(5 * t))
    B = rng.normal(size=(K, 3, P))
    C = np.column_stack([np.ones(F)] + [0.4 * np.sin((k + 1) * 3 * t + k) for k in range(K - 1)])
    S = R @ np.einsum('fk,kip->fip', C, B)
    return S[:, :2].reshape(2 * F, P), S.reshape(3 * F, P), R


def test_log_inverts_exp_at_every_angle_up_to_pi():
    rng = np.random.default_rng(0)
    axes = rng.normal(size=(200, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    theta = np.concatenate([[0.0, 1e-10, 1e-6], np.linspace(0.1, np.pi - 1e-3, 194),
                            [np.pi - 1e-5, np.pi - 1e-8, np.pi]])
    R = so3_exp(axes * theta[:, None])
    np.testing.assert_allclose(so3_exp(so3_log(R)), R, atol=1e-7)
    np.testing.assert_allclose(np.linalg.norm(so3_log(R), axis=1), theta, atol=1e-7)


def test_l1_average_ignores_an_outlier_that_moves_the_chordal_mean():
    rng = np.random.default_rng(2)
    F, n = 30, 7
    truth = random_rotations(rng, F)
    noise = so3_exp(rng.normal(scale=0.01, size=(F, n, 3)))
    samples = noise @ truth[:, None]
    samples[:, -1] = so3_exp(np.tile([0.0, 0.0, np.pi / 2], (F, 1))) @ truth      # 90 deg off
    mask = np.ones((F, n), dtype=bool)
    R, iterations = l1_average(samples, mask)
    chordal_mean = nearest_rotation(samples.mean(axis=1))
    assert iterations <= 50
    assert angles_deg(R, truth).max() < 1.0
    assert angles_deg(chordal_mean, truth).min() > 5.0


def test_l1_average_uses_only_the_kept_samples():
    rng = np.random.default_rng(3)
    truth = random_rotations(rng, 10)
    samples = np.stack([truth, random_rotations(rng, 10), random_rotations(rng, 10)], axis=1)
    mask = np.zeros((10, 3), dtype=bool)
    mask[:, 0] = True
    R, _ = l1_average(samples, mask)
    assert angles_deg(R, truth).max() < 1e-6


def test_registration_undoes_world_rotation_row_sign_mirror_and_per_frame_signs():
    rng = np.random.default_rng(4)
    ref = random_rotations(rng, 50)
    Z = random_rotations(rng, 1)[0]
    cand = ROW_SIGN @ MIRROR @ ref @ MIRROR @ Z          # every discrete ambiguity at once
    cand[::7] = ROW_SIGN @ cand[::7]                      # and a few per-frame sign flips
    registered, residual = register_candidates(ref, cand[None])
    assert residual[0] < 1e-9
    np.testing.assert_allclose(registered[0], ref, atol=1e-9)


def test_candidates_on_an_exact_low_rank_problem_recover_the_true_rotations():
    W, _, R = low_rank_problem()
    cand, residuals = triplet_candidates(W, 3)
    assert cand.shape == (3, 120, 3, 3)
    exact = residuals < 1e-9
    assert exact.any()
    assert all(rotation_error(c, R) < 0.01 for c in cand[exact])
    est = op_rotations(W, K=3)
    assert est.K == 3 and est.scores['op']['candidates'] == 3
    assert rotation_error(est.R, R) < 0.01
    # what the filter keeps lies within its radius of the reference (Dai's rotations)
    dai = estimate_rotations(W, K=3).R
    assert chordal(est.R, dai).max() < 0.05


def test_op_rotations_at_rank_one_are_dai_rotations():
    W, _, _ = low_rank_problem(K=1)
    est = op_rotations(W, K=1)
    np.testing.assert_array_equal(est.R, estimate_rotations(W, K=1).R)
    assert est.scores['op']['candidates'] == 0


def test_solver_reports_op_rotations_and_accepts_them_in_a_warm_start():
    W, _, _ = low_rank_problem(F=40, P=30, K=2)
    res = GrassmannNRSfM(rotations='op', max_iter=5).fit(W)
    assert res.report.rotation_method == 'op' and res.report.K_rot >= 1
    warm = GrassmannNRSfM(max_iter=5).fit(W, init=WarmStart(rotation_method='op'))
    assert warm.report.rotation_method == 'op' and not warm.report.rotation_checked


def test_partial_weights_leave_the_first_singular_value_free_and_do_not_decrease():
    W, _, R = low_rank_problem()
    Wn = (W - W.mean(axis=1, keepdims=True)) / np.sqrt(np.mean(W ** 2))
    theta = partial_weights(Wn, R)
    assert theta.shape == (120,) and theta[0] == 0.0
    assert np.all(np.diff(theta) >= 0.0) and theta[1] > 0.0


def test_weighted_norm_with_op_schedule_recovers_exact_low_rank_shapes():
    """From the true rotations, OP's weighted partial norm (with OP's penalty schedule) recovers
    exact rank-2 shapes; the plain norm's shrinkage leaves a bias."""
    W, S, R = low_rank_problem(F=80, P=40, K=2, seed=5)
    params = dict(spatial=False, temporal=False, smoothness=0.0, beta0=1e-4, rho=1.1,
                  beta_max=1e10, max_iter=400)
    errors = {nuclear: e3d(GrassmannNRSfM(nuclear=nuclear, **params).fit(
        W, init=WarmStart(R=R)).S, S) for nuclear in ('plain', 'weighted')}
    assert errors['weighted'] < 1e-3 < 0.01 < errors['plain'], errors
