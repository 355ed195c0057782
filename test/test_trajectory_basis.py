"""PTA (trajectory-basis NRSfM): exact on trajectory-space data, sane on real mocap."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from grass_nrsfm_ros.nrsfm.measurement import as_frames, InvalidInputError, project, to_camera
from grass_nrsfm_ros.nrsfm.metrics import e3d, e3d_akhter
from grass_nrsfm_ros.nrsfm.trajectory_basis import (dct_basis, pta, reprojection_residual,
                                                    trajectory_design)


def turning_camera(F, seed):
    """``R: (F, 3, 3)``: a camera sweeping about a slowly tilting axis (well-posed for PTA)."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, F)
    angles = np.stack([0.3 * np.sin(2 * np.pi * t + rng.uniform(0, 6)),
                       2.5 * t + rng.uniform(0, 6),
                       0.2 * np.cos(3 * np.pi * t)], axis=1)
    return Rotation.from_euler('xyz', angles).as_matrix()


def trajectory_sequence(F=60, P=200, K=4, seed=0):
    """``(W, S_camera, R)`` whose world trajectories lie exactly in the first K DCT vectors."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(K, 3, P)) / (1.0 + np.arange(K))[:, None, None]
    world = np.einsum('fk,kcp->fcp', dct_basis(F, K), A).reshape(3 * F, P)
    R = turning_camera(F, seed)
    W = project(R, world) + rng.normal(size=(2 * F, 1)) * 5.0   # arbitrary translations
    return W, to_camera(R, world), R


def test_dct_basis_is_orthonormal_and_starts_constant():
    theta = dct_basis(50, 7)
    assert theta.shape == (50, 7)
    np.testing.assert_allclose(theta.T @ theta, np.eye(7), atol=1e-12)
    np.testing.assert_allclose(theta[:, 0], 1.0 / np.sqrt(50))


def test_design_matrix_maps_coefficients_to_projections():
    F, K, P = 9, 3, 5
    rng = np.random.default_rng(1)
    R, theta = turning_camera(F, 1), dct_basis(F, K)
    A = rng.normal(size=(K, 3, P))
    world = np.einsum('fk,kcp->fcp', theta, A).reshape(3 * F, P)
    np.testing.assert_allclose(trajectory_design(R, theta) @ A.reshape(3 * K, P),
                               project(R, world), atol=1e-12)


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_exact_on_trajectory_space_sequence_with_known_rotations(seed):
    W, S, R = trajectory_sequence(seed=seed)
    R_used, S_est = pta(W, R=R, K=4)
    assert R_used is not None and S_est.shape == S.shape
    S_centred = (as_frames(S, 3) - as_frames(S, 3).mean(axis=2, keepdims=True)).reshape(S.shape)
    np.testing.assert_allclose(S_est, S_centred, atol=1e-9 * np.abs(S).max())
    assert e3d(S_est, S) < 1e-10


def test_too_few_vectors_leaves_a_residual_and_more_removes_it():
    W, S, R = trajectory_sequence(K=6, seed=3)
    under = reprojection_residual(W, pta(W, R=R, K=3)[1])
    exact = reprojection_residual(W, pta(W, R=R, K=6)[1])
    assert under > 1e-3 and exact < 1e-10


def test_rejects_unidentifiable_K():
    W, _, R = trajectory_sequence(F=6, P=20, K=2)
    with pytest.raises(InvalidInputError):
        pta(W, R=R, K=5)                     # 3K = 15 > 2F = 12
    with pytest.raises(InvalidInputError):
        pta(W, R=R[:-1], K=2)                # one rotation short


def test_rigid_scene_with_estimated_rotations():
    pytest.importorskip('grass_nrsfm_ros.nrsfm.rotation')
    W, S, _ = trajectory_sequence(K=1, seed=4)   # K=1: constant trajectories, a rigid body
    R, S_est = pta(W, K=1)
    assert R.shape == (60, 3, 3)
    assert e3d(S_est, S) < 1e-6


@pytest.mark.data
def test_torresani_face_close_to_published(dataset):
    """PTA on Torresani's face: published 0.0436 (Akhter's metric, OP Tab. 2)."""
    pytest.importorskip('grass_nrsfm_ros.nrsfm.rotation')
    W, S = dataset('torresani_mocap/face.npz')
    _, S_est = pta(W, K=2)
    err = e3d_akhter(S_est, S)
    assert err < 1.5 * 0.0436
    # the reconstruction must beat a flat face (depth zero) by a wide margin
    flat = as_frames(S_est, 3).copy()
    flat[:, 2] = 0.0
    assert err < 0.5 * e3d_akhter(flat.reshape(S.shape), S)
