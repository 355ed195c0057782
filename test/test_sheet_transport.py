"""Orthographic sheets: local-isometry depths with signs carried from frame to frame
(nrsfm/sheet_transport.py). Figures: bench/sheets.py, docs/decisions/0714."""
import numpy as np

from grass_nrsfm_ros.nrsfm import isometry, metrics, sheet_transport, synthetic
from grass_nrsfm_ros.nrsfm.rotation import rigid_factorisation
from grass_nrsfm_ros.nrsfm.solver import GrassmannNRSfM

BAR = 0.6       # issue 37: a sheet's e3D at most 0.6 of rigid factorisation's


def test_a_shape_is_carried_onto_a_rotated_view_with_its_depths():
    rng = np.random.default_rng(0)
    X = rng.standard_normal((3, 50))
    X -= X.mean(axis=1, keepdims=True)
    angle = 0.3
    R = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0],
                  [-np.sin(angle), 0, np.cos(angle)]])
    seen = R @ X
    np.testing.assert_allclose(sheet_transport.carried_depths(X, seen[:2]), seen[2],
                               atol=1e-10)


def crest():
    """A cylinder ``z = -x^2`` seen from above (its gradient -2x changes sign at the face-on
    crest x = 0), its true gradients, and them with arbitrary signs."""
    x, y = np.meshgrid(np.linspace(-1, 1, 21), np.linspace(-0.5, 0.5, 11))
    X = np.stack([x.ravel(), y.ravel(), -x.ravel() ** 2])[None]
    true = np.stack([-2 * X[0, 0], 0 * X[0, 0]], -1)[None]
    unsigned = true * np.where(X[0, 0] + 0.3 * X[0, 1] > 0, 1.0, -1.0)[None, :, None]
    W = X[:, :2].reshape(2, -1)
    return X, true, unsigned, isometry.neighbours(np.vstack([W, 1.01 * W]))


def right_up_to_one_sign(X, true, unsigned, signs):
    away = np.abs(X[0, 0]) > 0.06
    agree = np.sign((signs[0, :, None] * unsigned[0] * true[0]).sum(-1))[away]
    return bool(np.all(agree == agree[0]))


def test_signs_flip_across_a_face_on_crest():
    X, true, unsigned, nbr = crest()
    signs, _ = sheet_transport.spatial_signs(X, sheet_transport.bounded(unsigned), nbr)
    assert right_up_to_one_sign(X, true, unsigned, signs)


def test_an_orthographic_flag_beats_rigid_by_the_bars_margin_where_the_chain_does_not():
    seq = synthetic.make_sequence('flag', n_frames=40, n_points=300, seed=0)
    rigid = metrics.e3d(rigid_factorisation(seq.W)[1], seq.S, scale=True)
    carried = sheet_transport.TransportSheetNRSfM().fit(seq.W)
    chain = GrassmannNRSfM(surface='any').fit(seq.W)
    assert metrics.e3d(carried.S, seq.S, scale=True) <= BAR * rigid
    assert metrics.e3d(chain.S, seq.S, scale=True) > BAR * rigid
    assert carried.S.shape == seq.S.shape
    assert all(0 <= start < 40 for start in carried.info['start_frames'])


def test_the_solver_runs_it_for_an_orthographic_sheet():
    """``GrassmannNRSfM(surface='sheet')`` on orthographic tracks: these depths, the shapes
    (with the identity rotations and the centroids) reproducing the tracks, within the bar of
    rigid; tracks with unseen entries are refused."""
    import pytest
    from grass_nrsfm_ros.nrsfm.measurement import InvalidInputError
    seq = synthetic.make_sequence('flag', n_frames=40, n_points=300, seed=0)
    result = GrassmannNRSfM(surface='sheet').fit(seq.W)
    assert result.report.stages == ['sheet_transport'] and result.report.converged
    assert np.allclose(result.R, np.eye(3))
    image = np.einsum('fij,fjp->fip', result.R[:, :2], result.S.reshape(40, 3, -1))
    np.testing.assert_allclose(image.reshape(80, -1) + result.translation, seq.W, atol=1e-12)
    rigid = metrics.e3d(rigid_factorisation(seq.W)[1], seq.S, scale=True)
    assert metrics.e3d(result.S, seq.S, scale=True) <= BAR * rigid
    W = seq.W.copy()
    W[:2, 0] = np.nan
    with pytest.raises(InvalidInputError, match='complete tracks'):
        GrassmannNRSfM(surface='sheet').fit(W)


def test_the_path_leaves_each_run_where_it_went_astray():
    """Two runs of the true depths of a flag, each mirrored over a different stretch of frames
    (a mirrored frame fits its edge sizes as well): the chosen path takes, in every frame, the
    run that agrees with its neighbours in time."""
    seq = synthetic.make_sequence('flag', n_frames=30, n_points=200, seed=2)
    X = seq.S.reshape(30, 3, -1) - seq.S.reshape(30, 3, -1).mean(axis=2, keepdims=True)
    nbr = isometry.neighbours(seq.W)
    integrate = isometry.DepthIntegrator(X, nbr, isometry.edge_lengths(X, nbr),
                                         sheet_transport.CARRY_WEIGHT)
    runs = np.stack([X[:, 2].copy(), X[:, 2].copy()])
    runs[0, 5:11] *= -1
    runs[1, 18:24] *= -1
    z, path = sheet_transport.consistent_path(X, runs, integrate)
    np.testing.assert_array_equal(z, X[:, 2])
    assert set(path[5:11]) == {1} and set(path[18:24]) == {0}
