"""Pinhole intrinsics and the pixel <-> normalised track maps (nrsfm/camera.py)."""
import numpy as np
import pytest

from grass_nrsfm_ros.nrsfm import camera
from grass_nrsfm_ros.nrsfm.measurement import InvalidInputError

K = camera.intrinsics(620.0, 610.0, 319.5, 239.5, skew=0.5)


def points(F=4, P=30, seed=0):
    rng = np.random.default_rng(seed)
    X = rng.uniform(-1, 1, (F, 3, P))
    X[:, 2] += 5.0
    return X.reshape(3 * F, P)


def test_normalise_inverts_to_pixels_and_matches_k_inverse():
    S = points()
    W_px = camera.project(S, K)
    W = camera.normalise(W_px, K)
    np.testing.assert_allclose(W, camera.project(S), atol=1e-12)
    np.testing.assert_allclose(camera.to_pixels(W, K), W_px, atol=1e-9)
    homog = np.linalg.inv(K) @ np.stack([W_px[0], W_px[1], np.ones(W_px.shape[1])])
    np.testing.assert_allclose(W[:2], homog[:2], atol=1e-12)


def test_missing_entries_stay_missing():
    W_px = camera.project(points(), K)
    W_px[2, 5] = np.nan
    W = camera.normalise(W_px, K)
    assert np.isnan(W[2, 5]) and np.isfinite(np.delete(W.ravel(), 2 * W.shape[1] + 5)).all()


def test_k_up_to_scale_is_divided_through():
    np.testing.assert_allclose(camera.validate_intrinsics(2.0 * K), K)


@pytest.mark.parametrize('bad, words', [
    (np.eye(2), 'shape'),
    ([[600, 0, 320], [0, 600, 240], [0, 1, 1]], 'upper triangular'),
    ([[-600, 0, 320], [0, 600, 240], [0, 0, 1]], 'positive focal'),
    ([[600, 0, np.nan], [0, 600, 240], [0, 0, 1]], 'non-finite'),
    ('K', 'numeric'),
])
def test_bad_intrinsics_say_why(bad, words):
    with pytest.raises(InvalidInputError, match=words):
        camera.validate_intrinsics(bad)


def test_points_behind_the_camera_are_refused():
    S = points()
    S[2, 7] = -1.0
    with pytest.raises(InvalidInputError, match='frame 0 point 7'):
        camera.project(S)


def test_odd_rows_are_refused():
    with pytest.raises(InvalidInputError, match=r'\(2F, P\)'):
        camera.normalise(np.zeros((3, 5)), K)
