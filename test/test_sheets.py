"""Sheets: the local-isometry prior (nrsfm/isometry.py) and sheets against rigid
factorisation. Figures: bench/sheets.py, docs/decisions/0701."""
import numpy as np
import pytest

from grass_nrsfm_ros.nrsfm import isometry, metrics, synthetic
from grass_nrsfm_ros.nrsfm.measurement import as_frames
from grass_nrsfm_ros.nrsfm.rotation import rigid_factorisation
from grass_nrsfm_ros.nrsfm.solver import GrassmannNRSfM

BAR = 0.6       # issue 37: a sheet's e3D at most 0.6 of rigid factorisation's


def test_local_gradients_of_an_isometric_sheet_are_right_up_to_sign():
    seq = synthetic.make_sequence('bending', n_frames=10, n_points=400, seed=0)
    X = as_frames(seq.S, 3)
    nbr = isometry.neighbours(seq.W)
    g, confidence = isometry.local_gradients(X, nbr, isometry.edge_lengths(X, nbr))
    d = isometry._offsets(X, nbr)
    dz = X[:, 2, nbr] - X[:, 2, :, None]
    true = np.linalg.solve(np.einsum('fpki,fpkj->fpij', d, d),
                           np.einsum('fpki,fpk->fpi', d, dz)[..., None])[..., 0]
    steep = np.linalg.norm(true, axis=-1) > 0.2
    cos = np.abs((g * true).sum(-1))[steep] / (np.linalg.norm(g, axis=-1) *
                                               np.linalg.norm(true, axis=-1))[steep]
    assert steep.mean() > 0.3 and np.median(cos) > 0.99 and confidence.mean() > 0.5


def test_refined_depths_keep_x_y_and_each_frames_mean_depth():
    seq = synthetic.make_sequence('bending', n_frames=6, n_points=120, seed=2)
    S = seq.S + 0.05 * np.random.default_rng(0).standard_normal(seq.S.shape)
    refined, info = isometry.refine_sheet(S, seq.W, signs='sync')
    before, after = as_frames(S, 3), as_frames(refined, 3)
    np.testing.assert_array_equal(after[:, :2], before[:, :2])
    np.testing.assert_allclose(after[:, 2].mean(axis=1), before[:, 2].mean(axis=1))
    assert 0 <= info['mirrored_frames'] <= 6


def sheet_ratio(kind, seed=0):
    seq = synthetic.make_sequence(kind, n_frames=20, n_points=150, seed=seed)
    solved = isometry.SheetNRSfM(GrassmannNRSfM(), signs='sync').fit(seq.W)
    rigid = metrics.e3d(rigid_factorisation(seq.W)[1], seq.S, scale=True)
    return metrics.e3d(solved.S, seq.S, scale=True) / rigid


def test_a_bending_sheet_beats_rigid_by_the_bars_margin():
    assert sheet_ratio('bending') <= BAR


@pytest.mark.xfail(strict=True, reason='issue 37 open: the waving cloth is still worse than '
                   'rigid (docs/decisions/0701)')
def test_the_waving_cloth_beats_rigid_by_the_bars_margin():
    assert sheet_ratio('waving') <= BAR


class Recording:
    """GrassmannNRSfM, recording the warm start of every fit."""

    def __init__(self):
        self.solver, self.inits = GrassmannNRSfM(), []

    def fit(self, W, init=None):
        self.inits.append(init)
        return self.solver.fit(W, init=init)


def test_the_prior_inside_the_estimation_restarts_the_solver_from_the_sheet():
    seq = synthetic.make_sequence('bending', n_frames=8, n_points=120, seed=1)
    solver = Recording()
    result = isometry.SheetNRSfM(solver, signs='sync', alternations=2).fit(seq.W)
    assert len(solver.inits) == 3 and solver.inits[0] is None
    for init in solver.inits[1:]:
        assert init.resumed and init.S.shape == seq.S.shape and init.R.shape == (8, 3, 3)
        np.testing.assert_allclose(np.einsum('fij,fkj->fik', init.R, init.R),
                                   np.broadcast_to(np.eye(3), (8, 3, 3)), atol=1e-9)
    # the second start holds the first restart's sheet depths, refined from its result
    again = isometry.refine_sheet(solver.solver.fit(seq.W, init=solver.inits[1]).S, seq.W,
                                  signs='sync')[0]
    np.testing.assert_allclose(solver.inits[2].S, again, atol=1e-9)
    assert 'sheet prior' in result.report.notes[-1]
