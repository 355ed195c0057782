"""Uneven track density (nrsfm/density.py; ``GrassmannNRSfM(thinning=...)``): clusters found
and thinned, uniform tracks left exactly alone, dropped tracks filled in correctly, and a real
solve of a clustered stretching surface checked against ground truth."""
import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from grass_nrsfm_ros.nrsfm import density, GrassmannNRSfM, InvalidInputError, WarmStart
from grass_nrsfm_ros.nrsfm.baselines import rigid
from grass_nrsfm_ros.nrsfm.density import fill_dropped, thinned_tracks
from grass_nrsfm_ros.nrsfm.measurement import as_frames, from_frames
from grass_nrsfm_ros.nrsfm.metrics import e3d
from grass_nrsfm_ros.nrsfm.synthetic import kinds, make_sequence


def test_fill_recovers_the_depths_of_a_plane():
    """A plane that shears and stretches over 20 frames under a turning camera: the depths of
    the 300 dropped points, combined from their kept neighbours, match the truth."""
    rng = np.random.default_rng(0)
    F, P = 20, 600
    uv = rng.random((P, 2))
    t = np.linspace(0.0, 1.0, F)
    world = np.zeros((F, 3, P))
    world[:, 0] = (1.0 + 0.3 * t)[:, None] * uv[:, 0] + 0.2 * t[:, None] * uv[:, 1]
    world[:, 1] = uv[:, 1]
    world[:, 2] = 0.5 * uv[:, 0] - 0.3 * uv[:, 1]
    R = Rotation.from_euler('yx', np.stack([40 * t, 15 * np.sin(3 * t)], axis=1),
                            degrees=True).as_matrix()
    S = R @ (world - world.mean(axis=2, keepdims=True))
    W = from_frames(S[:, :2])
    keep = np.sort(rng.choice(P, P // 2, replace=False))
    solved = S[:, :, keep] - S[:, :, keep].mean(axis=2, keepdims=True)   # as the solver's
    filled, labels = fill_dropped(from_frames(solved), np.arange(keep.size), W, keep)
    depth_error = np.abs(as_frames(filled, 3)[:, 2] - S[:, 2])
    assert depth_error.max() < 1e-3 * S[:, 2].std(), depth_error.max()   # measured 1.4e-4
    assert np.allclose(as_frames(filled, 3)[:, :2], S[:, :2])      # x, y are the data's
    assert np.array_equal(labels[keep], np.arange(keep.size))


@pytest.mark.parametrize('kind', ['bending', 'waving', 'articulated'])
def test_fill_in_the_leading_trajectory_directions_matches_the_whole_trajectories(
        kind, monkeypatch):
    """60 frames (120 trajectory rows): the dropped tracks' neighbours and weights are found in
    the FILL_DIMS leading directions of the kept trajectories; their depths match the truth
    and the fill from the whole trajectories (record 0439)."""
    seq = make_sequence(kind, n_frames=60, n_points=1500, seed=0)
    S = as_frames(seq.S, 3)
    keep = np.sort(np.random.default_rng(0).choice(1500, 500, replace=False))
    dropped = np.setdiff1d(np.arange(1500), keep)
    solved = from_frames(S[:, :, keep] - S[:, :, keep].mean(axis=2, keepdims=True))
    Z = S[:, 2] - S[:, 2].mean(axis=1, keepdims=True)
    errors = []
    for dims in (density.FILL_DIMS, None):           # 24 of 120 rows, then all 120
        monkeypatch.setattr(density, 'FILL_DIMS', dims)
        filled = as_frames(fill_dropped(solved, np.arange(keep.size), seq.W, keep)[0], 3)
        errors.append(np.sqrt(np.mean((filled[:, 2, dropped] - Z[:, dropped]) ** 2)) / Z.std())
    assert errors[0] < 0.005, errors                  # measured 0.0004-0.0039
    assert errors[0] < errors[1] + 1e-4, errors


def test_nearest_matches_a_brute_force_search():
    """The k-d tree's neighbours (nearest first) and distances are a brute-force search's, for
    k = 1 and k = 8, on 24-dimensional points."""
    rng = np.random.default_rng(1)
    points, queries = rng.normal(size=(300, 24)), rng.normal(size=(50, 24))
    brute = np.linalg.norm(queries[:, None, :] - points[None, :, :], axis=2)
    order = np.argsort(brute, axis=1)
    for k in (1, 8):
        dist, idx = density.nearest(cKDTree(points), queries, k)
        assert idx.shape == dist.shape == (50, k)
        np.testing.assert_array_equal(idx, order[:, :k])
        np.testing.assert_allclose(dist, np.take_along_axis(brute, order[:, :k], axis=1))


@pytest.mark.parametrize('kind', kinds())
def test_uniform_tracks_are_not_thinned(kind):
    for camera, P in (('orbit', 500), ('static', 3000)):
        seq = make_sequence(kind, n_frames=30, n_points=P, camera=camera, seed=1)
        assert thinned_tracks(seq.W) is None, (camera, P)


def test_uniform_solve_is_unchanged():
    seq = make_sequence('twisting', n_frames=30, n_points=400, seed=2)
    auto, never = (GrassmannNRSfM(thinning=mode).fit(seq.W) for mode in ('auto', 'never'))
    assert auto.report.thinned_points == 0
    assert np.array_equal(auto.S, never.S) and np.array_equal(auto.R, never.R)


def test_clustered_stretching_surface():
    """40 % of 500 tracks in two patches of 1 % of an inflating surface each: solved on all
    tracks, the clusters outweigh the rest and e3D is worse than rigid's (measured 0.098, rigid
    0.071); thinned then filled in, 0.046."""
    seq = make_sequence('inflating', n_frames=60, n_points=500, clustered=0.4, seed=0)
    auto = GrassmannNRSfM().fit(seq.W)
    never = GrassmannNRSfM(thinning='never').fit(seq.W)
    assert 50 < auto.report.thinned_points < 200
    assert any(note.startswith('thinned') for note in auto.report.notes)
    assert auto.S.shape == seq.S.shape and auto.groups.shape == (500,)
    err_auto, err_never = e3d(auto.S, seq.S), e3d(never.S, seq.S)
    assert err_auto < 0.6 * err_never, (err_auto, err_never)
    assert err_auto < 0.8 * e3d(rigid(seq.W)[1], seq.S)
    centred = seq.W - seq.W.mean(axis=1, keepdims=True)
    xy = as_frames(auto.S, 3)[:, :2].reshape(-1, 500)
    assert np.abs(xy - centred).max() < 0.05 * np.abs(centred).max()


def test_warm_started_clustered_window():
    """The sliding windows pass initial shapes and groups of every track; they are thinned
    with the tracks and the result covers every track again."""
    seq = make_sequence('inflating', n_frames=40, n_points=400, clustered=0.4, seed=1)
    cold = GrassmannNRSfM().fit(seq.W)
    warm = GrassmannNRSfM().fit(seq.W, init=WarmStart(R=cold.R, S=cold.S, groups=cold.groups))
    assert warm.report.thinned_points == cold.report.thinned_points > 0
    assert warm.S.shape == seq.S.shape and warm.groups.shape == (400,)
    assert e3d(warm.S, seq.S) < 1.2 * e3d(cold.S, seq.S)


def test_marker_sets_are_not_thinned():
    seq = make_sequence('inflating', n_frames=30, n_points=99, clustered=0.4, seed=0)
    auto, never = (GrassmannNRSfM(thinning=mode).fit(seq.W) for mode in ('auto', 'never'))
    assert auto.report.thinned_points == 0 and np.array_equal(auto.S, never.S)


def test_thinning_parameter_is_validated():
    with pytest.raises(InvalidInputError, match='thinning'):
        GrassmannNRSfM(thinning='sometimes').fit(make_sequence('bending', 10, 50).W)


def test_thinning_does_not_depend_on_units():
    """The same tracks in other units and with an offset: the same tracks thinned, the same
    e3D (measured 0.04551 / 0.04543; 0.04611 when the fill weights were computed in the
    caller's units, their absolute 1e-12 guard then acting)."""
    seq = make_sequence('inflating', n_frames=60, n_points=500, clustered=0.4, seed=0)
    base = GrassmannNRSfM().fit(seq.W)
    tiny = GrassmannNRSfM().fit(1e-6 * seq.W + 3e-6)
    assert tiny.report.thinned_points == base.report.thinned_points > 0
    assert e3d(tiny.S / 1e-6, seq.S) == pytest.approx(e3d(base.S, seq.S), rel=0.005)
