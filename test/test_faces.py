import numpy as np
import pytest

from conftest import data_root
from grass_nrsfm_ros.nrsfm.faces import (ENV_MODEL, expression_weights, interpolate,
                                         load_face_model, make_face_sequence, sample_surface)
from grass_nrsfm_ros.nrsfm.measurement import as_frames, centre, to_camera
from grass_nrsfm_ros.nrsfm.metrics import e3d
from test_synthetic import rigid_with_residual  # noqa: I100, I201

RELPATH = 'sfm_face/sfm_face.npz'


@pytest.fixture(scope='module')
def model():
    root = data_root()
    if root is None or not (root / RELPATH).is_file():
        pytest.skip(f'face model {RELPATH} not found (set GRASS_NRSFM_DATA)')
    return load_face_model(root / RELPATH)


def test_model_loads(model):
    V = model.mean.shape[0]
    assert model.mean.shape == (V, 3) and model.basis.shape[0] == 3 * V
    assert model.expressions.shape == (6, V, 3) and len(model.expression_names) == 6
    assert model.triangles.max() < V
    # identity at zero coefficients is the mean; a few sigma move vertices by millimetres
    np.testing.assert_array_equal(model.identity(np.zeros(4)), model.mean)
    offset = model.identity([1.0, -2.0]) - model.mean
    expected = model.basis[:, :2] @ (np.array([1.0, -2.0]) * np.sqrt(model.eigenvalues[:2]))
    np.testing.assert_allclose(offset, expected.reshape(-1, 3), atol=1e-12)
    assert 1.0 < np.linalg.norm(offset, axis=1).max() < 100.0


def test_full_size_face_sequence(model):
    seq = make_face_sequence(model=model)          # 99 frames x 28,880 points
    F, P = 99, 28880
    assert seq.W.shape == (2 * F, P) and seq.S.shape == (3 * F, P) and seq.R.shape == (F, 3, 3)
    np.testing.assert_allclose(seq.W, as_frames(seq.S, 3)[:, :2].reshape(2 * F, P), atol=1e-9)
    np.testing.assert_allclose(to_camera(seq.R, seq.S_world), seq.S, atol=1e-9)
    np.testing.assert_allclose(seq.R @ seq.R.transpose(0, 2, 1), np.tile(np.eye(3), (F, 1, 1)),
                               atol=1e-12)
    # millimetres: a face is roughly 150 mm wide and 200 mm tall
    first = as_frames(seq.S_world, 3)[0]
    width, height = np.ptp(first[0]), np.ptp(first[1])
    assert 100 < width < 200 and 130 < height < 260
    weights = np.asarray(seq.meta['expression_weights'])
    assert weights.shape == (F, 6)
    assert weights.min() >= 0.0 and weights.max() <= 1.5
    assert (weights.max(axis=0) > 0.4).sum() >= 4      # several expressions come and go
    assert np.abs(np.diff(weights, axis=0)).max() < 0.2   # smoothly
    # a genuinely deforming face: rigid factorisation leaves a clear error
    _, S, residual = rigid_with_residual(seq.W[:, ::8])
    assert residual > 0.01
    assert e3d(S, seq.S[:, ::8]) > 0.03


def test_face_deterministic_and_noise(model):
    a = make_face_sequence(10, 2000, model=model, seed=3, noise=0.01)
    b = make_face_sequence(10, 2000, model=model, seed=3, noise=0.01)
    c = make_face_sequence(10, 2000, model=model, seed=4, noise=0.01)
    np.testing.assert_array_equal(a.W, b.W)
    np.testing.assert_array_equal(a.S, b.S)
    assert not np.allclose(a.S_world, c.S_world)
    clean = make_face_sequence(10, 2000, model=model, seed=3)
    np.testing.assert_array_equal(a.S, clean.S)
    expected = 0.01 * np.abs(centre(clean.W)[0]).max()
    assert a.noise_sigma == pytest.approx(expected, rel=1e-12)
    assert (a.W - clean.W).std() == pytest.approx(expected, rel=0.03)


def test_static_head_and_identity_components(model):
    seq = make_face_sequence(5, 500, model=model, head_motion='static', identity_components=0)
    np.testing.assert_array_equal(seq.R, np.tile(np.eye(3), (5, 1, 1)))
    assert seq.meta['identity_components'] == 0


def test_samples_lie_on_the_mesh_area_weighted(model):
    rng = np.random.default_rng(0)
    tri, bary = sample_surface(model.mean, model.triangles, 200000, rng)
    assert (bary >= 0).all()
    np.testing.assert_allclose(bary.sum(1), 1.0, atol=1e-12)
    corners = model.mean[model.triangles]
    area = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0],
                                         corners[:, 2] - corners[:, 0]), axis=1)
    # sampled area share of the left half of the face matches its true area share
    left = corners[:, :, 0].mean(1) < 0
    assert np.mean(left[tri]) == pytest.approx(area[left].sum() / area.sum(), abs=0.005)
    # barycentric interpolation reproduces the vertices at the corners
    corner_bary = np.eye(3)
    pts = interpolate(model.mean, model.triangles, np.array([5, 5, 5]), corner_bary)
    np.testing.assert_array_equal(pts, model.mean[model.triangles[5]])
    # uniform within a triangle: the mean barycentric coordinate is 1/3
    np.testing.assert_allclose(bary.mean(0), 1 / 3, atol=0.003)


def test_expression_weights_range():
    w = expression_weights(6, 99, np.random.default_rng(1))
    assert w.shape == (99, 6) and w.min() >= 0.0 and w.max() < 1.5


def test_missing_model_is_a_clear_error(tmp_path):
    with pytest.raises(FileNotFoundError, match=ENV_MODEL):
        load_face_model(tmp_path / 'nope.npz')
    with pytest.raises(FileNotFoundError, match='non-commercial'):
        make_face_sequence(2, 10, model=tmp_path / 'nope.npz')


def test_env_variable_finds_the_model(model, monkeypatch):
    monkeypatch.setenv(ENV_MODEL, str(model.path))
    assert load_face_model().path == model.path
