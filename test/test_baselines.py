"""Baseline shape steps: rigid and BMM (nuclear norm of S# under W = R S)."""
import numpy as np
import pytest
from test_rotation import synthetic

from grass_nrsfm_ros.nrsfm.baselines import bmm, rigid, singular_value_threshold
from grass_nrsfm_ros.nrsfm.metrics import e3d, e3d_akhter
from grass_nrsfm_ros.nrsfm.rotation import estimate_rotations, rigid_factorisation


@pytest.mark.parametrize('shape', [(8, 30), (30, 8)])
def test_singular_value_threshold_matches_full_svd(shape):
    rng = np.random.default_rng(0)
    M = rng.normal(size=shape)
    U, s, Vt = np.linalg.svd(M, full_matrices=False)
    tau = np.median(s)
    expected = (U * np.clip(s - tau, 0.0, None)) @ Vt
    shrunk, rank = singular_value_threshold(M, tau)
    assert np.allclose(shrunk, expected, atol=1e-10)
    assert rank == int((s > tau).sum())


def test_rigid_is_rigid_factorisation():
    W, _, _ = synthetic(K=1, seed=1)
    R1, S1 = rigid(W)
    R2, S2 = rigid_factorisation(W)
    assert np.array_equal(R1, R2) and np.array_equal(S1, S2)


def test_bmm_keeps_the_image_and_beats_planar_shapes():
    W, S, R_true = synthetic(K=2, seed=2)
    S_bmm, report = bmm(W, R_true, return_report=True)
    F, P = R_true.shape[0], W.shape[1]
    Wc = W - W.mean(axis=1, keepdims=True)
    assert np.allclose(S_bmm.reshape(F, 3, P)[:, :2].reshape(2 * F, P), Wc)
    flat = S_bmm.reshape(F, 3, P).copy()
    flat[:, 2] = 0.0
    assert e3d(S_bmm, S) < 0.05                    # measured with true rotations, K=2
    assert e3d(S_bmm, S) < 0.3 * e3d(flat.reshape(3 * F, P), S)
    assert report.iterations > 1 and report.gap < 1e-3


# Thresholds: measured e3D (per-frame) and Akhter's metric with estimate_rotations (K auto) +
# bmm, plus about 15-40 % margin. Where the Akhter threshold lies below Dai et al.'s published
# BMM number the test also proves we beat it: drink, pickup, yoga and face. Dance matches it
# (measured 0.1862 vs 0.1864). Shark: measured 0.235 vs Dai's 0.2311, and BMM is worse than the
# rigid shape there (0.111 vs 0.093 e3D): W has rank 5, so only the rank-2 null space exists.
MOCAP = [
    # (file, max e3d, max e3d_akhter, Dai BMM published, BMM beats rigid)
    ('akhter_mocap/drink.npz', 0.016, 0.025, 0.0266, True),      # 0.0125 / 0.0213
    ('akhter_mocap/pickup.npz', 0.035, 0.065, 0.1731, True),     # 0.0255 / 0.0490
    ('akhter_mocap/yoga.npz', 0.030, 0.050, 0.1150, True),       # 0.0210 / 0.0344
    ('akhter_mocap/dance.npz', 0.16, 0.24, 0.1864, True),        # 0.1242 / 0.1862
    ('torresani_mocap/face.npz', 0.021, 0.030, 0.0303, True),    # 0.0161 / 0.0263
    ('torresani_mocap/shark.npz', 0.13, 0.26, 0.2311, False),    # 0.1112 / 0.2350
]


@pytest.mark.data
@pytest.mark.parametrize('relpath, max_e3d, max_akhter, dai_bmm, beats_rigid', MOCAP)
def test_bmm_with_estimated_rotations_on_mocap(dataset, relpath, max_e3d, max_akhter, dai_bmm,
                                               beats_rigid):
    W, S = dataset(relpath)
    _, S_rigid = rigid_factorisation(W)
    S_est = bmm(W, estimate_rotations(W).R)
    err, err_akhter = e3d(S_est, S), e3d_akhter(S_est, S)
    assert (err < e3d(S_rigid, S)) == beats_rigid
    assert err < max_e3d
    assert err_akhter < max_akhter
    if max_akhter < dai_bmm:                       # the published number is beaten outright
        assert err_akhter < dai_bmm
