import numpy as np
import pytest

from doubles import random_rotations
from grass_nrsfm_ros.nrsfm.measurement import InvalidInputError, validate_tracks
from grass_nrsfm_ros.nrsfm.metrics import e3d, e3d_akhter, procrustes_align, rotation_error


def test_e3d_zero_for_rotated_translated_copy():
    rng = np.random.default_rng(0)
    S = rng.normal(size=(3 * 6, 50))
    R = random_rotations(6, rng)
    moved = (R @ S.reshape(6, 3, 50) + rng.normal(size=(6, 3, 1))).reshape(18, 50)
    assert e3d(moved, S) < 1e-12
    assert e3d_akhter(S + 1.0, S) < 1e-12


def test_e3d_reflection_and_scale_flags():
    rng = np.random.default_rng(1)
    S = rng.normal(size=(3, 40))
    mirrored = S * np.array([[1.0], [1.0], [-1.0]])
    assert e3d(mirrored, S) < 1e-12                       # depth flip absorbed by default
    assert e3d(mirrored, S, reflection=False) > 0.1
    assert e3d(2.0 * S, S) == pytest.approx(1.0, rel=1e-9)   # no scale by default
    assert e3d(2.0 * S, S, scale=True) < 1e-12


def test_e3d_value_of_known_perturbation():
    rng = np.random.default_rng(2)
    S = rng.normal(size=(3, 200))
    S -= S.mean(axis=1, keepdims=True)
    noise = 0.05 * rng.normal(size=S.shape)
    err = e3d(S + noise, S)
    assert 0.03 < err <= np.linalg.norm(noise) / np.linalg.norm(S) + 1e-12


def test_procrustes_returns_centred_frames():
    rng = np.random.default_rng(3)
    S = rng.normal(size=(9, 30)) + 5.0
    aligned, gt = procrustes_align(S, S)
    assert np.allclose(gt.reshape(3, 3, 30).mean(axis=2), 0.0)
    assert np.allclose(aligned, gt)


def test_rotation_error_ignores_global_frame_and_depth_flip():
    rng = np.random.default_rng(4)
    R = random_rotations(10, rng)
    G = random_rotations(1, rng)[0]
    assert rotation_error(R @ G, R) < 1e-6
    D = np.diag([1.0, 1.0, -1.0])
    assert rotation_error(D @ R @ D, R) < 1e-6
    assert rotation_error(random_rotations(10, rng), R) > 10.0


@pytest.mark.parametrize('bad, message', [
    (np.zeros((3, 10)), 'even number of rows'),
    (np.zeros((2, 10)), 'frames'),
    (np.zeros((8, 2)), 'points'),
    (np.full((8, 10), np.nan), 'non-finite'),
    (np.zeros(10), '2-D'),
])
def test_validate_tracks_errors(bad, message):
    with pytest.raises(InvalidInputError, match=message):
        validate_tracks(bad)
