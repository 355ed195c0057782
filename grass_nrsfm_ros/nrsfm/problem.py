"""What a solve is given and what it returns: the warm start, the checked problem, the result
and the report.

Shapes: ``W: (2F, P)`` tracks, ``S: (3F, P)`` camera-frame shapes, ``R: (F, 3, 3)``
world-to-camera rotations, ``known: (F,)`` bool, ``groups: (P,)`` integer spatial labels,
``weights: (2F, P)`` the data term's per-entry weights in [0, 1] (None: every entry weighs 1).
"""
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from .measurement import (centre, InvalidInputError, track_scale, validate_rotations,
                          validate_shapes, validate_tracks)
from .missing import check_mask, complete, entry_weights, observation_mask


@dataclass
class WarmStart:
    """Initial values for :meth:`GrassmannNRSfM.fit`.

    ``R: (F, 3, 3)`` rotations, ``S: (3F, P)`` camera-frame shapes (any translation, same units
    as W), ``known: (F,)`` bool frames whose R and S are given (default: all), ``groups: (P,)``
    spatial labels, ``rotation_method``: 'dai' or 'rigid', how rotations that are not
    given are estimated (None: the solver's ``rotations`` parameter; a method given skips the
    'auto' check, e.g. one a previous solve of overlapping frames chose). ``resumed``: the
    shapes resume a previous window's solution, so the solve runs as a cold one from them (the
    penalty from beta0, not config.WARM_BETA0; the inextensible depths, or on sparse tracks the
    smoothness prior; not the stage 'relief', which keeps to solves given nothing); its cap
    is the caller's (``fit(..., beta_max=)``). Every field is optional.
    """
    R: np.ndarray = None
    S: np.ndarray = None
    known: np.ndarray = None
    groups: np.ndarray = None
    rotation_method: str = None
    resumed: bool = False


@dataclass
class SolverReport:
    """What the solver did; every number refers to the run that produced it.

    ``stages``: the stages that ran, in order; ``solves``: one ``(reason, F, P, iterations)``
    per ADMM solve made (the rotation check's, the shape solve and the registration's
    re-solve)."""
    iterations: int = 0
    converged: bool = False
    reason: str = ''
    objective: list = field(default_factory=list)
    gaps: list = field(default_factory=list)      # per iteration: (S#-T1(S), C_s-J_s, C_t-J_t)
    seconds: dict = field(default_factory=dict)
    K_rot: int = None
    K_s: int = 0
    K_t: int = 0
    N_s: int = 0
    N_t: int = 0
    gamma: float = 0.0                           # nuclear-norm weight used (unit-RMS W)
    regrouped_points: int = 0                    # total trajectory moves made by xi
    reprojection_rms: float = float('nan')       # RMS of W - RS in W's units
    reprojection_relative: float = float('nan')  # the same over the RMS of centred W
    warm_started_frames: int = 0
    rotation_method: str = None                  # 'dai', 'rigid' or 'given' (init.R)
    rotation_checked: bool = False               # the 'auto' check chose rotation_method
    inextensible: bool = False                   # inextensible depths replaced the solver's
    rotations_registered: bool = False           # R re-estimated from the refined shapes, kept
    relief: float = 1.0                          # depth factor of the stage 'relief'
    thinned_points: int = 0                      # tracks left out of the solve, filled in
    fallback: str = None
    observed_fraction: float = 1.0               # share of W's entries seen (masked solves)
    completion: str = None                       # the completion of unseen entries (missing.py)
    downweighted_tracks: list = field(default_factory=list)  # tracks the robust term weighed < 1
    notes: list = field(default_factory=list)    # automatic decisions worth knowing
    stages: list = field(default_factory=list)
    solves: list = field(default_factory=list)
    perspective: dict = None                     # projection 'perspective': the iteration

    def to_dict(self):
        """The report as plain JSON types (numpy scalars as numbers, tuples as lists)."""
        def plain(value):
            if isinstance(value, dict):
                return {str(k): plain(v) for k, v in value.items()}
            if isinstance(value, (list, tuple, np.ndarray)):
                return [plain(v) for v in value]
            return value.item() if isinstance(value, np.generic) else value
        return plain(asdict(self))


@dataclass
class NRSfMResult:
    """``S: (3F, P)`` camera frame, ``R: (F, 3, 3)``, ``translation: (2F, 1)``,
    ``groups: (P,)`` spatial labels, ``blocks: (K_t + 1,)`` temporal block edges,
    ``C_s: (K_s, K_s)`` and ``C_t: (K_t, K_t)`` the self-expression coefficients at the end
    (rows: the supplementary's convention, group i ~ sum_j C_ij group j)."""
    S: np.ndarray
    R: np.ndarray
    translation: np.ndarray
    groups: np.ndarray
    blocks: np.ndarray
    report: SolverReport
    C_s: np.ndarray = None
    C_t: np.ndarray = None
    track_weights: np.ndarray = None      # (P,) the robust term's weights (None: all 1)


@dataclass
class Problem:
    """A checked problem: ``W: (2F, P)`` tracks as given, ``Wn: (2F, P)`` centred and divided by
    ``scale``, ``translation: (2F, 1)`` the row means; ``init`` the warm start (``given``: the
    caller passed one), ``known: (F,)``, ``groups: (P,)`` dense labels or None; ``weights:
    (2F, P)`` the data term's weights or None (every entry 1); ``mask: (F, P)`` bool, the
    entries seen (None: all). Where entries are not seen (weight 0), ``W`` holds them completed
    (:func:`.missing.complete`, or handed over: 'given', the model named by ``completion``)
    and ``translation`` is the completed rows' mean."""
    W: np.ndarray
    Wn: np.ndarray
    translation: np.ndarray
    scale: float
    init: WarmStart
    known: np.ndarray
    groups: np.ndarray
    given: bool
    weights: np.ndarray = None
    completion: str = None
    mask: np.ndarray = None

    @classmethod
    def from_tracks(cls, W, init=None, visible=None, random_state=0, filled=None):
        """Check ``W`` and ``init`` (raises InvalidInputError naming what is wrong). ``W`` may
        hold NaN where a track is not seen, ``visible: (F, P)`` bool marks more unseen
        entries; unseen entries are completed (``random_state``: the completion's hold-out),
        or taken from ``filled: (2F, P)`` when given (a completion already made,
        :func:`.missing.fill_unseen`; its seen entries are W's)."""
        W, mask = observation_mask(W, visible)
        weights = completion = None
        if mask is None:
            W = validate_tracks(W, min_frames=3, min_points=4)
        else:
            check_mask(mask, min_frames=3, min_points=4)
            if filled is None:
                W, completion = complete(W, mask, random_state)
            else:
                W, completion = np.where(np.repeat(mask, 2, axis=0), W,
                                         checked_filled(filled, W.shape)), 'given'
            weights = entry_weights(mask)
        given = init is not None
        init = init if given else WarmStart()
        if not isinstance(init, WarmStart):
            raise InvalidInputError(f'init must be a WarmStart or None; got {type(init).__name__}')
        known, groups = check_init(init, W.shape[0] // 2, W.shape[1])
        Wn, translation = centre(W)
        scale = track_scale(Wn)
        Wn /= scale                                     # centred, unit RMS
        return cls(W, Wn, translation, scale, init, known, groups, given, weights, completion,
                   mask)

    def weighted(self, track_weights):
        """The problem with each track's weights multiplied by ``track_weights: (P,)``."""
        base = self.weights if self.weights is not None else np.ones_like(self.W)
        return replace(self, weights=base * track_weights[None, :])

    @property
    def F(self):
        return self.W.shape[0] // 2

    @property
    def P(self):
        return self.W.shape[1]

    @property
    def warm(self):
        """Initial shapes are given (the warm-started solve of a sliding window)."""
        return self.init.S is not None

    def tracks(self, keep):
        """The problem restricted to the tracks ``keep: (P',)`` (sorted indices); the scale
        stays that of all tracks."""
        W = self.W[:, keep]
        S = None if self.init.S is None else np.asarray(self.init.S)[:, keep]
        groups = None if self.groups is None else dense_labels(self.groups[keep])
        weights = None if self.weights is None else self.weights[:, keep]
        mask = None if self.mask is None else self.mask[:, keep]
        return replace(self, W=W, Wn=centre(W)[0] / self.scale, init=replace(self.init, S=S),
                       groups=groups, weights=weights, mask=mask)

    def with_rotations(self, R):
        """The problem solved afresh with the rotations ``R: (F, 3, 3)`` given for every
        frame (and nothing else given)."""
        return replace(self, init=WarmStart(R=R), known=np.ones(self.F, dtype=bool),
                       groups=None, given=True)


def checked_filled(filled, shape):
    """``filled`` as float64 if it is a finite array of ``shape``, else InvalidInputError."""
    filled = np.asarray(filled)
    if filled.shape != shape or filled.dtype.kind not in 'fiu':
        raise InvalidInputError(f'filled must be a {shape} array of numbers; got '
                                f'{filled.shape} {filled.dtype}')
    filled = filled.astype(np.float64, copy=False)
    if not np.isfinite(filled).all():
        raise InvalidInputError('filled must be finite everywhere (a completion of W)')
    return filled


def check_init(init, F, P):
    """``(known: (F,) bool, groups: (P,) dense labels or None)`` of a checked WarmStart."""
    known = np.ones(F, dtype=bool) if init.known is None else np.asarray(init.known)
    if known.shape != (F,) or known.dtype != bool:
        raise InvalidInputError(f'init.known must be a ({F},) bool array; got '
                                f'{known.shape} {known.dtype}')
    groups = None
    if init.groups is not None:
        groups = np.asarray(init.groups)
        if groups.shape != (P,) or groups.dtype.kind not in 'iu':
            raise InvalidInputError(f'init.groups must be ({P},) integers; got '
                                    f'{groups.shape} {groups.dtype}')
        groups = dense_labels(groups)
    if init.R is not None:
        validate_rotations(init.R, F, name='init.R')
    if init.S is not None:
        validate_shapes(init.S, n_frames=F, n_points=P, name='init.S')
    if init.resumed and (init.S is None or init.R is None or not known.all()):
        raise InvalidInputError('init.resumed needs init.S and init.R given for every frame')
    if (init.R is not None or init.S is not None) and not known.any():
        raise InvalidInputError('init.known marks no frame as known')
    if init.rotation_method not in (None, 'dai', 'rigid'):
        raise InvalidInputError("init.rotation_method must be None, 'dai' or 'rigid'; got "
                                f'{init.rotation_method!r}')
    return known, groups


def dense_labels(groups):
    """``groups: (P,)`` integer labels renumbered 0 .. n_groups - 1 (int64)."""
    return np.unique(groups, return_inverse=True)[1].astype(np.int64)


def initial_shapes(problem, R):
    """World-frame initial shapes ``(F, 3, P)``: pinv(R) Wn, or the given camera-frame S on
    known frames (others: x, y from Wn, depth of the nearest known frame)."""
    F, P, init = R.shape[0], problem.Wn.shape[1], problem.init
    cam = np.zeros((F, 3, P))
    cam[:, :2, :] = problem.Wn.reshape(F, 2, P)
    if init.S is not None:
        given = np.asarray(init.S, dtype=np.float64).reshape(F, 3, P)
        given = (given - given.mean(axis=2, keepdims=True)) / problem.scale
        idx = np.flatnonzero(problem.known)
        nearest = idx[np.abs(np.arange(F)[:, None] - idx[None, :]).argmin(axis=1)]
        cam[:, 2, :] = given[nearest, 2, :]
        cam[problem.known] = given[problem.known]
    return R.transpose(0, 2, 1) @ cam
