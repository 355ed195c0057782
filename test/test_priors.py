"""Temporal smoothness prior of the S-update (grass_nrsfm_ros/nrsfm/priors.py)."""
import numpy as np
import pytest

from doubles import random_rotations
from grass_nrsfm_ros.nrsfm import GrassmannNRSfM
from grass_nrsfm_ros.nrsfm.priors import smoothness_weight, TemporalSmoothness, track_roughness
from grass_nrsfm_ros.nrsfm.synthetic import make_sequence


def second_difference(F):
    D = np.zeros((F - 2, F))
    for r in range(F - 2):
        D[r, r:r + 3] = [1.0, -2.0, 1.0]
    return D


# the dense-inverse path, and the banded one by the frames or by too few points
@pytest.mark.parametrize('dense_max_frames, points', [(200, None), (0, None), (200, 6)])
@pytest.mark.parametrize('F', [3, 4, 9])
def test_banded_solve_matches_dense_normal_equations(F, dense_max_frames, points, monkeypatch):
    monkeypatch.setattr('grass_nrsfm_ros.nrsfm.priors.DENSE_MAX_FRAMES', dense_max_frames)
    rng = np.random.default_rng(F)
    P, lam, beta = 6, 2.5, 0.3
    R = random_rotations(F, rng)
    W, rhs = rng.normal(size=(F, 2, P)), rng.normal(size=(F, 3, P))
    A = np.zeros((3 * F, 3 * F))
    for f in range(F):
        A[3 * f:3 * f + 3, 3 * f:3 * f + 3] = R[f, :2].T @ R[f, :2]
    D = second_difference(F)
    A += lam * np.kron(D.T @ D, np.eye(3)) + beta * np.eye(3 * F)
    b = (rhs + R[:, :2].transpose(0, 2, 1) @ W).reshape(3 * F, P)
    expected = np.linalg.solve(A, b).reshape(F, 3, P)
    smoother = TemporalSmoothness(R, lam, points)
    assert smoother.dense == (dense_max_frames > 0 and points is None)
    np.testing.assert_allclose(smoother.solve(W, rhs, beta), expected, atol=1e-10)


def test_energy_is_half_lambda_squared_second_differences():
    rng = np.random.default_rng(1)
    F, P, lam = 8, 5, 3.0
    S = rng.normal(size=(F, 3, P))
    D = np.kron(second_difference(F), np.eye(3))
    expected = 0.5 * lam * np.sum((D @ S.reshape(3 * F, P)) ** 2)
    smoother = TemporalSmoothness(random_rotations(F, rng), lam)
    assert smoother.energy(S) == pytest.approx(expected)
    linear = np.linspace(0, 1, F)[:, None, None] * np.ones((F, 3, P))
    assert smoother.energy(linear) == pytest.approx(0.0, abs=1e-20)


def test_weight_is_relative_to_track_roughness():
    t = np.linspace(0, 1, 50)
    smooth = np.repeat(np.sin(2 * np.pi * t), 2)[:, None] * np.ones((1, 4))
    rough = smooth + 0.1 * np.random.default_rng(0).normal(size=smooth.shape)
    assert track_roughness(rough) > 10 * track_roughness(smooth)
    assert smoothness_weight(smooth, 1e-3) == pytest.approx(1e-3 / track_roughness(smooth))


def test_smoothness_reaches_lower_shape_roughness():
    seq = make_sequence('bending', 30, 200, camera='shaky', seed=0)
    # the prior's effect on the ADMM's shapes, before the inextensible depths (which, since
    # they apply from 100 tracks, replace much of the depth: 0.81 instead of < 0.8 with them)
    plain = GrassmannNRSfM(surface='any', inextensible='never').fit(seq.W)
    smooth = GrassmannNRSfM(surface='any', smoothness=1e-2, inextensible='never').fit(seq.W)

    def roughness(res):
        S = res.R.transpose(0, 2, 1) @ res.S.reshape(30, 3, -1)
        return np.sum((S[2:] - 2 * S[1:-1] + S[:-2]) ** 2)
    assert roughness(smooth) < 0.8 * roughness(plain)
    assert smooth.report.reprojection_relative < 0.05
