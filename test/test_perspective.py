"""The projective-depth iteration (nrsfm/perspective.py) against pinhole ground truth."""
from types import SimpleNamespace

import numpy as np
import pytest

from bench.perspective import along_axis
from grass_nrsfm_ros.nrsfm import camera, metrics, synthetic
from grass_nrsfm_ros.nrsfm.measurement import (as_frames, from_frames, InvalidInputError,
                                               to_camera)
from grass_nrsfm_ros.nrsfm.perspective import (camera_frame_shapes, centred_depths,
                                               depth_scale, fit_perspective,
                                               PerspectiveNRSfM)
from grass_nrsfm_ros.nrsfm.rigidity import rigid_residual
from grass_nrsfm_ros.nrsfm.rotation import rigid_factorisation


class FlippingRigid:
    """A rigid factorisation whose depth sign flips on every other call (each solve's
    global depth sign is arbitrary)."""

    def __init__(self):
        self.calls = 0

    def fit(self, W):
        self.calls += 1
        _, S = rigid_factorisation(W)
        if self.calls % 2 == 0:
            S = S * np.tile([[1.0], [1.0], [-1.0]], (S.shape[0] // 3, 1))
        return SimpleNamespace(S=S)


def rigid_object(seed=0, F=30, P=200, distance=3.0):
    seq = synthetic.make_sequence('bending', n_frames=F, n_points=P, seed=seed)
    frozen = np.repeat(as_frames(seq.S_world, 3)[F // 5][None], F, axis=0)  # curled
    return along_axis(to_camera(seq.R, from_frames(frozen)), distance)


@pytest.mark.parametrize('seed', [0, 1])
def test_rigid_object_recovered_exactly_with_a_consistent_sign(seed):
    S = rigid_object(seed)
    x = camera.project(S)
    result = fit_perspective(x, FlippingRigid(), max_rounds=8, tol=1e-4)
    first = metrics.e3d(camera_frame_shapes(x, result.rounds[0].delta), S, scale=True)
    error = metrics.e3d(result.S, S, scale=True, reflection=False)
    assert first > 0.03 and error < 0.004, (first, error, result.report())
    truth = centred_depths(S) / as_frames(S, 3)[:, 2].mean(axis=1, keepdims=True)
    kept = result.rounds[1:]
    assert len(kept) >= 3
    for r in kept:      # every round's depths agree with the truth's sign, frame by frame
        assert (np.einsum('fp,fp->f', r.delta, truth) > 0).all(), r.index
    assert all(r.sign.min() < 0 for r in kept[1:][::2]) or \
        all(r.sign.min() < 0 for r in kept[::2])     # the flips happened and were undone
    np.testing.assert_allclose(camera.project(result.S), x, atol=1e-12)


def test_output_is_in_the_camera_frame_at_the_given_scale():
    S = rigid_object(1, F=12, P=60)
    result = fit_perspective(camera.project(S), FlippingRigid(), max_rounds=3, scale=2.5)
    depth = as_frames(result.S, 3)[:, 2]
    np.testing.assert_allclose(depth.mean(axis=1), 2.5)
    assert (depth > 0).all()
    assert result.kept == int(np.argmin(result.residuals)) or result.kept in \
        [r.index for r in result.rounds if r.residual == min(result.residuals)]


@pytest.mark.parametrize('kwargs, words', [
    ({'max_rounds': -1}, 'max_rounds'), ({'tol': 0.0}, 'tol'), ({'scale': np.inf}, 'scale'),
    ({'solver': object()}, 'fit'),
])
def test_bad_parameters_say_why(kwargs, words):
    with pytest.raises(InvalidInputError, match=words):
        PerspectiveNRSfM(**kwargs).fit(camera.project(rigid_object(F=5, P=10)))


class FlatOnCall(FlippingRigid):
    """FlippingRigid whose ``flat``-th solve returns no depth (tshirt10's second round did)."""

    def __init__(self, flat):
        super().__init__()
        self.flat = flat

    def fit(self, W):
        result = super().fit(W)
        if self.calls == self.flat:
            S = as_frames(result.S, 3).copy()
            S[:, 2] = 0.0
            result = SimpleNamespace(S=from_frames(S))
        return result


def test_a_solve_with_flat_depths_stops_the_iteration_and_is_not_kept():
    S = rigid_object(0, F=12, P=60)
    x = camera.project(S)
    # calls: round 0, round 1, then round 2 (flat)
    result = fit_perspective(x, FlatOnCall(3), max_rounds=4, tol=1e-9)
    last = result.rounds[-1]
    assert last.index == 2 and last.change == np.inf, result.report()
    assert result.stopped.startswith('flat depths') and result.kept != 2
    assert np.linalg.norm(result.delta) > 0
    np.testing.assert_allclose(camera.project(result.S), x, atol=1e-12)


class MirroredFirst:
    """Rigid factorisation whose first solve returns the depth mirror of the truth's sign,
    later ones the truth's (each solve's global depth sign is arbitrary)."""

    def __init__(self, truth):
        self.truth, self.calls = truth, 0

    def fit(self, W):
        self.calls += 1
        S = as_frames(rigid_factorisation(W)[1], 3).copy()
        agrees = np.sum(S[:, 2] * self.truth) > 0
        if agrees == (self.calls == 1):
            S[:, 2] *= -1.0
        return SimpleNamespace(S=from_frames(S))


@pytest.mark.parametrize('seed', [0, 1])
def test_the_first_solves_mirror_is_turned_to_the_low_rank_sign(seed):
    """The depth sign is chosen once, on the first solve's depths, before any other solve:
    the sign whose weak-perspective image is closer to rank 3 (record 0730); every round
    after it agrees with it."""
    S = rigid_object(seed, F=12, P=60)
    x = camera.project(S)
    truth = centred_depths(S)
    solver = MirroredFirst(truth)
    result = fit_perspective(x, solver, max_rounds=3, tol=1e-9)
    assert solver.calls == 4            # round 0 and three rounds: no trial solve
    assert (result.rounds[0].sign == -1.0).all(), result.report()
    for r in result.rounds:
        assert (np.einsum('fp,fp->f', r.delta, truth) > 0).all(), r.index


class Scripted:
    """A solver returning prescribed multiples ``scripts[call]`` of the true relative depths
    ``truth: (F, P)``; its x, y fit its input exactly."""

    def __init__(self, truth, scripts):
        self.truth, self.scripts, self.calls = truth, scripts, 0

    def fit(self, W):
        z = self.scripts[min(self.calls, len(self.scripts) - 1)] * self.truth
        self.calls += 1
        centred = as_frames(W, 2) - as_frames(W, 2).mean(axis=2, keepdims=True)
        return SimpleNamespace(S=from_frames(np.concatenate([centred, z[:, None, :]], axis=1)))


def test_a_rise_of_the_residual_does_not_stop_the_iteration():
    """Record 0707: the rounds do not converge; a later round can be the most consistent. Here
    round 2 overshoots (its residual rises) and round 4 lands on the truth: the iteration goes
    on past the rise and keeps the round of lowest residual over all rounds."""
    S = rigid_object(0, F=12, P=60)
    x = camera.project(S)
    truth = centred_depths(S) / as_frames(S, 3)[:, 2].mean(axis=1, keepdims=True)
    # calls: round 0, rounds 1, 2, 3, 4, ...
    solver = Scripted(truth, [0.5, 0.8, 1.3, 1.0, 1.0])
    result = fit_perspective(x, solver, max_rounds=6)
    assert result.kept == int(np.argmin(result.residuals)) == 4, result.report()
    residuals = result.residuals
    assert residuals[0] > residuals[1] < residuals[2] > residuals[4], result.report()
    assert result.stopped.startswith('depth change'), result.stopped
    assert metrics.e3d(result.S, S, scale=True, reflection=False) < 1e-9
    np.testing.assert_allclose(camera.project(result.S), x, atol=1e-12)


@pytest.mark.slow
@pytest.mark.data
def test_rendered_pinhole_face_perspective_meets_the_bar_over_draws():
    """Issue #37's face bar through the solver's perspective model: a rendered face (the front
    end's renderer, perfect tracks of surface samples) reconstructed from its pinhole tracks,
    against the e3D of its orthographic projections' reconstruction. One draw is not a figure
    (the rounds land anywhere in a band and the ratio moves with the input's last bits, record
    0707), so the bar (1.2 x) is held by the median of 5 draws of the tracks' rounding; no draw
    is worse than 2 x, and the median beats the orthographic solve of the same pinhole tracks
    (1.58 x). With the inextensible stage decided in every round (before record 0725) the
    median was 1.21 with one BLAS kernel, 1.30 with another."""
    from bench.perspective import face_shapes, orthographic, rounding_draw
    from grass_nrsfm_ros.frontend.scenes import pinhole
    from grass_nrsfm_ros.nrsfm.solver import GrassmannNRSfM
    S = face_shapes(40, 400, seed=0)
    if S is None:
        pytest.skip('Surrey face model not found (set GRASS_NRSFM_DATA)')
    K = pinhole()
    x = camera.normalise(camera.project(S, K), K)
    reference = metrics.e3d(GrassmannNRSfM().fit(orthographic(S)).S, S, scale=True)
    ignoring = metrics.e3d(GrassmannNRSfM().fit(x).S, S, scale=True) / reference
    ratios = []
    for draw in range(1, 6):
        drawn = rounding_draw(x, draw)
        result = GrassmannNRSfM(projection='perspective').fit(drawn)
        ratios.append(metrics.e3d(result.S, S, scale=True) / reference)
        np.testing.assert_allclose(camera.project(result.S), drawn, atol=1e-9)
    assert np.median(ratios) <= 1.2 and np.median(ratios) < ignoring and max(ratios) <= 2.0, \
        (np.round(ratios, 3), ignoring)


def test_the_rounds_hold_the_inextensible_stage_off_unless_asked():
    """Under 'auto' the perspective rounds run without the inextensible stage (record 0725: its
    per-round check, biased through a pinhole, made the faces' rounds a lottery); 'always'
    still runs it in every round."""
    from grass_nrsfm_ros.nrsfm.solver import GrassmannNRSfM
    seq = synthetic.make_sequence('bending', n_frames=12, n_points=150, seed=0)
    x = camera.project(along_axis(seq.S, 5.0))
    auto = GrassmannNRSfM(projection='perspective', surface='any').fit(x)
    always = GrassmannNRSfM(projection='perspective', surface='any',
                            inextensible='always').fit(x)
    assert 'refinement' not in auto.report.stages
    assert 'refinement' in always.report.stages and always.report.inextensible


@pytest.mark.data
@pytest.mark.parametrize('seed', [3, 4])
def test_rendered_faces_keep_the_true_depth_sign(seed):
    """Record 0730: on these held-back faces (the tracks as rendered) the sign trial by the
    solver's fit residual kept the mirror from round 1 on (face 4: 4.54 x its orthographic
    e3D); the low-rank image's sign is the true one, and every round agrees with it."""
    from bench.perspective import face_shapes
    from grass_nrsfm_ros.frontend.scenes import pinhole
    from grass_nrsfm_ros.nrsfm.solver import GrassmannNRSfM
    S = face_shapes(40, 400, seed=seed)
    if S is None:
        pytest.skip('Surrey face model not found (set GRASS_NRSFM_DATA)')
    K = pinhole()
    x = camera.normalise(camera.project(S, K), K)
    result = fit_perspective(x, GrassmannNRSfM(inextensible='never'), max_rounds=2)
    truth = centred_depths(S)
    for r in result.rounds:
        assert (np.einsum('fp,fp->f', r.delta, truth) > 0).all(), (r.index, result.report())


def relative_depths(S):
    """``(F, P)``: each frame's depths of ``S: (3F, P)`` over their mean, less 1."""
    Z = as_frames(S, 3)[:, 2, :]
    return Z / Z.mean(axis=1, keepdims=True) - 1.0


def test_rigid_residual_is_zero_for_a_rigid_shape_at_any_distance():
    """One shape turned by an orbit's rotations and sized differently per frame (its distance
    changes) is rigid: residual 0; the bending sheet's frames are not (measured 0.018)."""
    seq = synthetic.make_sequence('bending', n_frames=20, n_points=100, seed=0)
    X = np.random.default_rng(0).standard_normal((3, 100))
    S = from_frames(np.stack([(1 + 0.1 * f) * seq.R[f] @ X for f in range(20)]))
    assert rigid_residual(S) < 1e-20
    assert rigid_residual(seq.S) > 0.01


@pytest.mark.data
def test_depth_scale_undoes_a_flattening_of_a_turning_face():
    """Record 0733: the true relative depths of a rendered face through the pinhole,
    flattened by 0.9 / 0.8 / 0.7, are scaled back by 1.1 / 1.225 / 1.4 (within 0.04 of the
    inverse); the true depths keep 1."""
    from bench.perspective import face_shapes
    from grass_nrsfm_ros.frontend.scenes import pinhole
    S = face_shapes(20, 200, seed=0)
    if S is None:
        pytest.skip('Surrey face model not found (set GRASS_NRSFM_DATA)')
    K = pinhole()
    x = camera.normalise(camera.project(S, K), K)
    delta = relative_depths(S)
    assert depth_scale(x, delta) == 1.0
    for flattening in (0.9, 0.8, 0.7):
        assert abs(flattening * depth_scale(x, flattening * delta) - 1.0) < 0.04, flattening


@pytest.mark.parametrize('kind', ['waving', 'bending'])
def test_depth_scale_leaves_a_bending_surface_as_it_is(kind):
    """A surface with no rigid core: the rigid residual only grows with the depth, so even
    its depths flattened by 0.8 keep the factor 1."""
    from bench.perspective import pinhole_sheet
    W, S = pinhole_sheet(kind, 20, 200, seed=0)
    assert depth_scale(W, relative_depths(S)) == depth_scale(W, 0.8 * relative_depths(S)) == 1
