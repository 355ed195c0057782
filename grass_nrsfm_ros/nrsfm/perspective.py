"""The perspective model: the projective-depth iteration around the whole solver chain.

A pinhole sees the camera-frame point ``(X, Y, Z)`` at the normalised image point
``x = (X/Z, Y/Z)`` (:mod:`.camera`: ``K^-1 [u, v, 1]``). Write each point's depth as
``Z = Zbar_f (1 + delta)``, ``Zbar_f`` the frame's mean depth: then ``x (1 + delta) =
(X, Y) / Zbar_f`` is the weak-perspective (scaled orthographic) image of the shape, which the
orthographic solver (:class:`.solver.GrassmannNRSfM`: rotations, ADMM, stages) reconstructs
in the units of its input, i.e. with the centred depths ``delta`` (Christy and Horaud's
paraperspective-to-perspective iteration, 1996).

:class:`PerspectiveNRSfM` / :func:`fit_perspective` iterate: solve on ``x``; read ``delta``
from the reconstruction's centred depths; solve on ``x (1 + delta)``; repeat.

* Depth sign. An orthographic solve cannot tell a shape from its depth mirror. The first
  solve's depths take the sign whose weak-perspective image ``x (1 + delta)`` is closer to
  rank 3 (:func:`low_rank_sign`: the true sign's is a scaled orthographic image of the
  shape, the mirror's is not); every later round takes, frame by frame, the sign that agrees
  with the previous round's depths.
* Perspective reprojection residual of a round (RMS, normalised units): the solver's
  reconstruction of its input ``x (1 + delta_prev)`` (its x, y plus the input's per-frame
  centroid) at the depths ``1 + delta`` it found, projected, against ``x``.
* Stopping: when the relative change of ``delta`` (``||delta_k - delta_k-1|| / ||delta_k||``)
  falls below ``tol``, when a solve returns flat depths (the round is void,
  :func:`depth_change`), or after ``max_rounds`` rounds. A rise of the residual does not stop
  it: the rounds do not converge, each solve lands anywhere in a wide band, and the round of
  lowest residual over all of them is returned (docs/decisions/0707).
* Depth scale. The solves flatten depth (their relative depths regress on the truth's with a
  slope of 0.78-0.94). The kept round's ``delta`` is multiplied by the factor ``c`` in
  ``rigidity.SCALES`` (from 1 up) whose camera-frame shapes are most nearly one rigid shape
  under the pinhole (:func:`.rigidity.most_rigid`): the head turns of a face fix its relief
  as they fix a rigid body's. Where the residual only grows with ``c`` (a cloth, a surface
  with no rigid core) ``c`` stays 1 (:func:`depth_scale`, docs/decisions/0733).

Output, in the camera frame and consistent with the pinhole: ``Z = scale (1 + delta)``,
``X = Z x``, ``Y = Z y``, so ``S`` projects exactly onto the given ``x``. The monocular scale
is unknown: each frame's mean depth is ``scale`` (default 1: shapes in units of the distance
to the surface; give the distance in metres for metres). Frames' distances are not recovered.

Shapes: ``W: (2F, P)`` normalised tracks (rows ``2f, 2f+1``: x, y of frame f), ``S: (3F, P)``
camera frame, ``delta: (F, P)``.
"""
from dataclasses import dataclass, field

import numpy as np
from sklearn.base import BaseEstimator

from .measurement import as_frames, from_frames, InvalidInputError, validate_tracks
from .rigidity import most_rigid, SCALES

#: rounds of the iteration (the first orthographic solve is round 0); all are run (no stop at
#: a rise of the residual) and the lowest residual's kept (docs/decisions/0707, 0727)
MAX_ROUNDS = 8
#: stop when the relative change of the depths falls below this
TOL = 0.02
#: 1 + delta is kept at least this (a point cannot reach the camera's plane)
MIN_RELATIVE_DEPTH = 0.1
#: a solve whose centred depths' RMS is below this fraction of the tracks' RMS spread
#: returned a flat shape (tshirt10's second round: exactly zero depths): the round is void
FLAT_DEPTHS = 1e-6


@dataclass
class PerspectiveRound:
    """One round: ``sign`` applied to the solver's depths (per frame, ``(F,)``), the
    perspective ``residual`` (RMS, normalised units), the relative ``change`` of the depths
    from the previous round (NaN on round 0), ``delta: (F, P)`` its relative depths (signs
    applied), ``fit``: the solver's own relative residual of its input (:func:`fit_residual`;
    NaN on round 0)."""
    index: int
    residual: float
    change: float
    sign: np.ndarray
    delta: np.ndarray
    fit: float = float('nan')


@dataclass
class PerspectiveResult:
    """``S: (3F, P)`` camera frame (each frame's mean depth ``scale``), ``delta: (F, P)``
    relative depths, ``result``: the solver's result of the round kept (``kept``),
    ``rounds``: every round, ``stopped``: why the iteration ended."""
    S: np.ndarray
    delta: np.ndarray
    result: object
    kept: int
    rounds: list = field(default_factory=list)
    stopped: str = ''
    scale: float = 1.0
    clamped: int = 0
    depth_scale: float = 1.0

    @property
    def residuals(self):
        """The perspective residual of every round."""
        return [r.residual for r in self.rounds]

    def report(self):
        """The iteration as plain JSON types."""
        return {'kept': self.kept, 'stopped': self.stopped, 'scale': self.scale,
                'depth_scale': self.depth_scale, 'clamped_points': self.clamped,
                'rounds': [{'index': r.index, 'residual': r.residual, 'change': r.change,
                            'flipped_frames': int((r.sign < 0).sum())}
                           for r in self.rounds]}


def centred_depths(S):
    """``(F, P)``: each frame's depths of ``S: (3F, P)`` less their mean."""
    z = as_frames(np.asarray(S, dtype=np.float64), 3)[:, 2, :]
    return z - z.mean(axis=1, keepdims=True)


def weak_perspective_tracks(x, delta):
    """``x (1 + delta)``: ``(2F, P)`` from normalised tracks ``x: (2F, P)`` and ``delta: (F,
    P)``."""
    return x * np.repeat(1.0 + delta, 2, axis=0)


def agreeing_signs(delta, previous):
    """``(F,)`` of +-1: per frame, the sign of ``delta: (F, P)`` that agrees with
    ``previous: (F, P)`` (non-negative correlation)."""
    return np.where(np.einsum('fp,fp->f', delta, previous) >= 0.0, 1.0, -1.0)


def flat_depths(delta, x):
    """True where relative depths ``delta: (F, P)`` have no size: their RMS below FLAT_DEPTHS
    of the normalised tracks' ``x: (2F, P)`` RMS spread about each frame's centroid (a solve
    that found no depth)."""
    spread = np.sqrt(np.mean((x - x.mean(axis=1, keepdims=True)) ** 2))
    return bool(np.linalg.norm(delta) <= FLAT_DEPTHS * spread * np.sqrt(delta.size))


def depth_change(new, previous, x):
    """``||new - previous|| / ||new||`` of relative depths ``(F, P)``; inf where ``new`` is
    flat (:func:`flat_depths`): its ratio would be noise over nothing."""
    if flat_depths(new, x):
        return float('inf')
    return float(np.linalg.norm(new - previous) / np.linalg.norm(new))


def perspective_residual(S, W_in, x, delta):
    """RMS of the pinhole reprojection of the solver's reconstruction ``S: (3F, P)`` of its
    input ``W_in: (2F, P)`` (x, y plus the input's centroid per frame) at relative depths
    ``1 + delta: (F, P)``, against the normalised tracks ``x: (2F, P)``."""
    X = as_frames(np.asarray(S, dtype=np.float64), 3)[:, :2, :]
    X = X - X.mean(axis=2, keepdims=True) + as_frames(W_in, 2).mean(axis=2, keepdims=True)
    seen = X / np.maximum(1.0 + delta, MIN_RELATIVE_DEPTH)[:, None, :]
    return float(np.sqrt(np.mean((from_frames(seen) - x) ** 2)))


def fit_residual(result, W_in):
    """The solver's own relative RMS residual of its input ``W_in: (2F, P)``: its report's
    ``reprojection_relative`` where it has one, else that of ``result.S``'s x, y."""
    report = getattr(result, 'report', None)
    value = getattr(report, 'reprojection_relative', None)
    if value is not None and np.isfinite(value):
        return float(value)
    centred = W_in - W_in.mean(axis=1, keepdims=True)
    X = as_frames(np.asarray(result.S, dtype=np.float64), 3)[:, :2, :]
    fitted = from_frames(X - X.mean(axis=2, keepdims=True))
    return float(np.sqrt(np.mean((fitted - centred) ** 2) / np.mean(centred ** 2)))


def low_rank_sign(x, delta, rank=3):
    """+1 or -1: the sign ``s`` of the relative depths ``delta: (F, P)`` whose weak-perspective
    image ``x (1 + s delta)`` (``x: (2F, P)`` normalised tracks) is closer to rank ``rank``
    (relative residual of its row-centred truncated SVD). The true sign's is a scaled
    orthographic image of the shape; the mirror's is not (record 0703: with the true depths
    the mirror's rank-3 residual is 2-3 times larger on a face, an inflating surface and a
    bending sheet)."""
    residuals = []
    for sign in (1.0, -1.0):
        W = weak_perspective_tracks(x, np.maximum(sign * delta, MIN_RELATIVE_DEPTH - 1.0))
        values = np.linalg.svd(W - W.mean(axis=1, keepdims=True), compute_uv=False)
        residuals.append(np.sum(values[rank:] ** 2) / max(np.sum(values ** 2), 1e-300))
    return 1.0 if residuals[0] <= residuals[1] else -1.0


def depth_scale(x, delta, scales=SCALES):
    """The factor among ``scales`` (the first on a tie) whose relative depths ``c delta``
    (``delta: (F, P)``) of the normalised tracks ``x: (2F, P)`` give the camera-frame shapes
    of least rigid residual (:func:`.rigidity.most_rigid`)."""
    return most_rigid(lambda c: camera_frame_shapes(x, c * delta), scales)


def camera_frame_shapes(x, delta, scale=1.0):
    """``S: (3F, P)``: ``Z = scale (1 + delta)``, ``X = Z x``, ``Y = Z y`` of normalised tracks
    ``x: (2F, P)`` and relative depths ``delta: (F, P)``."""
    Z = scale * np.maximum(1.0 + delta, MIN_RELATIVE_DEPTH)
    xy = as_frames(x, 2)
    return from_frames(np.concatenate([xy * Z[:, None, :], Z[:, None, :]], axis=1))


class PerspectiveNRSfM(BaseEstimator):
    """The projective-depth iteration (see the module docstring) around ``solver`` (an object
    with ``fit(W) -> result`` whose ``result.S: (3F, P)`` is camera frame; default a
    :class:`.solver.GrassmannNRSfM` with its default parameters).

    ``max_rounds``: rounds after the first orthographic solve (0: that solve only, its
    depths taken as relative depths); ``tol``: relative change of the depths that stops the
    iteration; ``scale``: each frame's mean depth in the output (the unknown monocular
    scale); ``rescale_depths``: the kept depths scaled by :func:`depth_scale` (the module
    docstring)."""

    def __init__(self, solver=None, max_rounds=MAX_ROUNDS, tol=TOL, scale=1.0,
                 rescale_depths=True):
        self.solver = solver
        self.max_rounds = max_rounds
        self.tol = tol
        self.scale = scale
        self.rescale_depths = rescale_depths

    def _checked(self):
        rounds, tol, scale = self.max_rounds, self.tol, self.scale
        if isinstance(rounds, bool) or not isinstance(rounds, (int, np.integer)) or rounds < 0:
            raise InvalidInputError(f'max_rounds={rounds!r}: expected an int >= 0')
        for name, value in (('tol', tol), ('scale', scale)):
            if isinstance(value, bool) or not isinstance(value, (int, float, np.number)) or \
                    not np.isfinite(value) or value <= 0:
                raise InvalidInputError(f'{name}={value!r}: expected a finite number > 0')
        if not isinstance(self.rescale_depths, (bool, np.bool_)):
            raise InvalidInputError(f'rescale_depths={self.rescale_depths!r}: expected a bool')
        if self.solver is None:
            from .solver import GrassmannNRSfM
            return GrassmannNRSfM(relief='never'), int(rounds), float(tol), float(scale)
        if not callable(getattr(self.solver, 'fit', None)):
            raise InvalidInputError(f'solver must have a fit(W) method; got '
                                    f'{type(self.solver).__name__}')
        return self.solver, int(rounds), float(tol), float(scale)

    def fit(self, W):
        """Reconstruct the normalised tracks ``W: (2F, P)`` (``K^-1 [u, v, 1]``, see
        :func:`.camera.normalise`); returns a :class:`PerspectiveResult`."""
        solver, max_rounds, tol, scale = self._checked()
        x = validate_tracks(W, min_frames=3, min_points=4)
        F = x.shape[0] // 2
        first = solver.fit(x)
        raw = centred_depths(first.S)
        sign = low_rank_sign(x, raw)
        delta = sign * raw
        rounds = [PerspectiveRound(0, perspective_residual(first.S, x, x, delta), np.nan,
                                   np.full(F, sign), delta)]
        best = (rounds[0].residual, 0, delta, first)
        stopped = 'max_rounds' if max_rounds else 'max_rounds (0: orthographic solve only)'
        for index in range(1, max_rounds + 1):
            record, new, result = self._round(solver, x, delta, index)
            rounds.append(record)
            if not np.isfinite(record.change):
                stopped = 'flat depths: the solve returned no depth (round not kept)'
                break
            if record.residual < best[0]:
                best = (record.residual, index, new, result)
            if record.change < tol:
                stopped = f'depth change {record.change:.3g} < tol {tol:g}'
                break
            delta = new
        _, kept, delta, result = best
        factor = depth_scale(x, delta) if self.rescale_depths else 1.0
        delta = factor * delta
        clamped = int((1.0 + delta < MIN_RELATIVE_DEPTH).sum())
        return PerspectiveResult(S=camera_frame_shapes(x, delta, scale), delta=delta,
                                 result=result, kept=kept, rounds=rounds, stopped=stopped,
                                 scale=scale, clamped=clamped, depth_scale=factor)

    @staticmethod
    def _round(solver, x, delta, index):
        """Solve on ``x (1 + delta)``; returns ``(PerspectiveRound, new delta, result)``, the
        new depths' signs agreeing with ``delta`` frame by frame."""
        W_in = weak_perspective_tracks(x, np.maximum(delta, MIN_RELATIVE_DEPTH - 1.0))
        result = solver.fit(W_in)
        raw = centred_depths(result.S)
        sign = agreeing_signs(raw, delta)
        new = raw * sign[:, None]
        change = depth_change(new, delta, x)
        record = PerspectiveRound(index, perspective_residual(result.S, W_in, x, new), change,
                                  sign, new, fit=fit_residual(result, W_in))
        return record, new, result


def fit_perspective(W, solver=None, *, max_rounds=MAX_ROUNDS, tol=TOL, scale=1.0,
                    rescale_depths=True):
    """:meth:`PerspectiveNRSfM.fit` of the normalised tracks ``W: (2F, P)`` in one call."""
    return PerspectiveNRSfM(solver, max_rounds=max_rounds, tol=tol, scale=scale,
                            rescale_depths=rescale_depths).fit(W)
