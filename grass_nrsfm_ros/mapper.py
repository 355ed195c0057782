"""The mapper: ``Mapper.solve(window) -> Update``, one closed Window solved into the next model.

It owns what carries from one solve to the next: the previous solution, the warm start
(``warm_start``: 'resume' or 'model', docs/decisions/0037, 0404), the depth alignment (each
solution's depth sign agrees with the previous one on the overlap, or, where they share no
frame (a sequence's first solve, a restarted mapping, windows skipped without context), with
the depths the tracking published, which travel in the frames), the
penalty schedule of a resumed window (passed to the solver per call, 0408, 0425) and the
tracks a window is solved on (``mapping_tracks``, 0403). Pure Python and numpy: no ROS.

Shapes: a window's problem is ``W: (2F, P)`` pixels over ``F = n_context + n_frames`` frames,
NaN where a frame does not see a track (the solver fills those; the starts read ``W``
completed, and each frame's results hold the tracks it sees); an :class:`Update` carries
:class:`FrameResult` s (``xyz: (P, 3)`` in the camera frame: the
frame's centred u, v and the depth, in pixels) and a
:class:`~grass_nrsfm_ros.nrsfm.tracking.ShapeModel` for the tracking; for a pinhole sheet also
its :class:`~grass_nrsfm_ros.nrsfm.sheet_model.SheetModel`, rebuilt at every window, from which
its frames' results come (docs/decisions/0732).
"""
from dataclasses import dataclass, field, replace
import inspect
import time

import numpy as np
from scipy.spatial import cKDTree

from grass_nrsfm_ros import params
from grass_nrsfm_ros.nrsfm import GrassmannNRSfM, WarmStart
from grass_nrsfm_ros.nrsfm.density import fill_dropped
from grass_nrsfm_ros.nrsfm.max_depth import REFINE_ITERATIONS
from grass_nrsfm_ros.nrsfm.measurement import as_frames, centre
from grass_nrsfm_ros.nrsfm.missing import fill_unseen
from grass_nrsfm_ros.nrsfm.rotation import (choose_rank, DEFAULT_CANDIDATES, max_rank,
                                            normalised_svd, rigid_factorisation,
                                            rotations_from_start)
from grass_nrsfm_ros.nrsfm.sheet_model import frame_points
from grass_nrsfm_ros.nrsfm.solver import one_blas_thread
from grass_nrsfm_ros.nrsfm.tracking import build_model
from grass_nrsfm_ros.sheet_mapping import SheetMapping
from grass_nrsfm_ros.windowing import common_ids, window_matrix

#: fewest tracks a window may be solved on when ``mapping_tracks`` caps them
MIN_MAPPING_TRACKS = 100
#: a sequence's first window (started from the rigid factorisation) is solved on at most this
#: many tracks, the rest filled in: the first model comes sooner (docs/decisions/0433)
FIRST_WINDOW_TRACKS = 1000
#: a context frame joins a solve only while it sees at least this share of the window's tracks
CONTEXT_TRACKS = 0.9
#: warm_start 'model': the rotation method chosen by the solver's check on a problem with full
#: context is carried until the frames new since that check reach this share of its frames
RECHECK_SHARE = 0.5
#: the largest ADMM penalty of a window with context under 'resume' (docs/decisions/0408, 0425)
WINDOW_BETA_MAX = 10.0
#: the largest ADMM penalty of a window started from the rigid factorisation, a sequence's
#: first: its model comes sooner (docs/decisions/0435, 0445)
FIRST_WINDOW_BETA_MAX = 1.0
#: a window with unseen entries is solved without the solver's refill rounds: they cost 37 %
#: more mapping CPU at 10,000 tracks for 0.7 % of refined e3D on live windows (docs/decisions/
#: 0802)
WINDOW_REFILL_ROUNDS = 0
DEPTH_FLIP = np.diag([1.0, 1.0, -1.0])


class WindowError(ValueError):
    """A window that cannot be solved (too few common tracks, a non-finite solution)."""


@dataclass(frozen=True)
class FrameResult:
    """One reconstructed frame: ``xyz: (P, 3)`` in the camera frame (x, y = the frame's centred
    u, v; z = depth) for tracks ``ids: (P,)``; ``signed``: the depth's sign is known (a sheet
    model's), not a solve's arbitrary one."""

    stamp_ns: int
    frame_id: str
    ids: np.ndarray
    xyz: np.ndarray
    signed: bool = False


@dataclass(frozen=True)
class WindowProblem:
    """What one solve reconstructs: ``W: (2F, P)`` of tracks ``ids: (P,)`` over ``stamps: (F,)``
    = ``n_context`` context frames then the window's frames (``frame_ids: (F,)``); NaN where a
    frame does not see a track (``seen: (F, P)`` False), ``filled: (2F, P)`` W completed."""

    sequence: int
    stamps: np.ndarray
    ids: np.ndarray
    W: np.ndarray
    n_context: int
    frame_ids: tuple = ()
    filled: np.ndarray = None
    seen: np.ndarray = None


@dataclass
class Solution:
    """What a solved window leaves for the next one (camera frame, depth sign aligned)."""

    sequence: int
    stamps: np.ndarray
    ids: np.ndarray
    uv: np.ndarray          # (F, P, 2) pixels
    S: np.ndarray           # (3F, P)
    R: np.ndarray           # (F, 3, 3)
    groups: np.ndarray      # (P,) or None
    report: object          # the solver's report
    residual: float         # ||Wc - x,y rows of S|| / ||Wc||: relative reprojection residual
    K_rot: int = None       # Dai's rank of the rotations (1: rigid), None: unknown
    preview: bool = False   # of a preview window (its frames wait for the first window)


@dataclass(frozen=True)
class Update:
    """What the mapping gives out for one window. ``kind``: 'solved'; 'released' (a final
    window whose frames the last solve holds: no solve, the waiting frames go out); 'failed'
    (``message`` says why); 'dropped' (not solved: ``message`` 'skipped' when a newer window
    replaced it, 'reset', 'stopping'); ``preview``: of a preview window (a model, no
    results). ``results``: the solve's FrameResults of the frames it may still refine (see
    :meth:`Mapper.solve`); ``flipped``: this solve was mirrored to
    agree with the depths published for its frames; ``model``: the tracking's next
    ShapeModel; ``sheet``: the sequence's newest
    :class:`~grass_nrsfm_ros.nrsfm.sheet_model.SheetModel` (pinhole sheets, else None);
    ``figures``: what the diagnostics show."""

    kind: str
    sequence: int
    index: int
    stamps: tuple
    final: bool = False
    preview: bool = False
    closed_at: float = 0.0
    n_tracks: int = 0
    results: tuple = ()
    flipped: bool = False
    model: object = None
    sheet: object = None
    figures: dict = field(default_factory=dict)
    message: str = ''

    @classmethod
    def of(cls, window, kind, **kwargs):
        """An Update of ``window`` (a Window or a WindowSpec)."""
        return cls(kind, window.sequence, window.index, tuple(int(s) for s in window.stamps),
                   window.final, window.preview, window.closed_at, int(window.ids.size),
                   **kwargs)


def _accepts(fit, name):
    """True if ``fit`` takes the keyword ``name``."""
    try:
        signature = inspect.signature(fit).parameters
    except (TypeError, ValueError):
        return False
    return name in signature or any(p.kind == p.VAR_KEYWORD for p in signature.values())


def make_mapper(config, solver_factory=None, refined_after=None):
    """The Mapper that ``config`` (parameters as from :func:`grass_nrsfm_ros.params.load_config`
    or the node; absent keys take their defaults) describes; ``solver_factory`` replaces
    ``GrassmannNRSfM(**solver parameters)``; ``refined_after``: see :class:`Mapper`. An unknown
    parameter or a bad value raises ValueError."""
    config = params.with_defaults(config)
    solver_kwargs = params.solver_kwargs(config)
    factory = solver_factory or (lambda: GrassmannNRSfM(**solver_kwargs))
    return Mapper(factory, refined_after=refined_after or refined_after_of(config),
                  surface=config['solver.surface'],
                  **{k: config[k] for k in params.MAPPER_KEYS})


def refined_after_of(config):
    """The solves a frame waits for before it goes out on ``points/refined``."""
    config = {**params.defaults(), **config}
    if config['refined_from'] == 'first_window':
        return 1
    return -(-int(config['window_size']) // int(config['window_stride']))


class Mapper:
    """Solves windows one after the other; see the module docstring.

    ``solver_factory()`` returns an object with ``fit(W, init=None)`` (optionally
    ``progress=`` and ``beta_max=``) returning ``S: (3F, P)``, ``R: (F, 3, 3)``, optional
    ``groups: (P,)`` and ``report``. ``refined_after``: each frame's results are given out
    from its first ``refined_after`` solves only (later ones cannot be published).
    ``surface`` (the solver's): which pinhole sequences get a sheet model
    (:class:`~grass_nrsfm_ros.sheet_mapping.SheetMapping`, docs/decisions/0732).
    """

    def __init__(self, solver_factory=None, *, min_tracks=10, warm_start='resume',
                 context_frames=60, mapping_tracks=0, refined_after=1, surface='auto'):
        params.check_window(min_tracks=min_tracks, warm_start=warm_start,
                            context_frames=context_frames, mapping_tracks=mapping_tracks)
        if mapping_tracks and mapping_tracks < max(min_tracks, MIN_MAPPING_TRACKS):
            raise ValueError(f'mapping_tracks={mapping_tracks}: 0 (all) or at least '
                             f'{max(min_tracks, MIN_MAPPING_TRACKS)}')
        self.solver_factory = solver_factory or GrassmannNRSfM
        self.min_tracks, self.warm_start = int(min_tracks), warm_start
        self.context_frames, self.mapping_tracks = int(context_frames), int(mapping_tracks)
        self.refined_after = int(refined_after)
        self.sheets = SheetMapping(surface)
        self.previous = None            # Solution of the last solved window
        self._rotation_check = None     # (sequence, method, stamps) of the last full check
        self._resumed_rank = None       # Dai's rank of the rotations a resumed start gave
        self.started_from = None        # the last solve's start: 'rigid', 'model', 'resumed'
        self._solves = (None, {})       # (sequence, {stamp: solves of that frame})

    def reset(self):
        """Forget the previous solution, the rotation check and the sheet model (a new
        sequence)."""
        self.previous, self._rotation_check, self._solves = None, None, (None, {})
        self.sheets.reset()

    def solve(self, window, progress=None):
        """Solve ``window`` with its context: an Update 'solved' (or 'released', see
        :class:`Update`). Raises WindowError. ``progress(iteration, report)`` is handed to
        solvers that take it (an exception raised there abandons the solve). BLAS on one
        thread throughout."""
        started = time.monotonic()
        if self._releases(window):
            return Update.of(window, 'released')
        with one_blas_thread():
            problem, S, Z, flipped, seen = self._solve(window, progress)
            model = build_model(self.previous.S, self.previous.R, self.previous.ids,
                                self.previous.stamps)
            sheet = self.sheets.update(window, first=self.started_from == 'rigid')
            results = () if window.preview else self._results(problem, S, Z, seen, sheet)
        return Update.of(window, 'solved', results=results, flipped=flipped, model=model,
                         sheet=sheet, figures=self._figures(time.monotonic() - started))

    # -- one solve ------------------------------------------------------------------------------
    def _solve(self, window, progress):
        if window.ids.size < self.min_tracks:
            raise WindowError(f'window {window.index}: its {window.n_frames} frames share '
                              f'{window.ids.size} tracks (< min_tracks={self.min_tracks})')
        problem = self._problem(window)
        filled, seen = problem.filled, problem.seen
        Wc, _ = centre(filled)
        init = self._start_for(problem)
        keep = self._mapped_tracks(problem.ids, first=self.started_from == 'rigid')
        solver = self.solver_factory()
        result = solver.fit(problem.W if keep is None else problem.W[:, keep],
                            **self._fit_kwargs(solver, problem, init, keep, progress))
        S = np.array(result.S, dtype=np.float64)
        R = np.array(result.R, dtype=np.float64)
        if not (np.isfinite(S).all() and np.isfinite(R).all()):
            raise WindowError(f'window {window.index}: the solver returned non-finite shapes '
                              'or rotations; nothing published')
        groups = getattr(result, 'groups', None)
        if keep is not None:
            labels = np.zeros(keep.size, dtype=int) if groups is None else groups
            S, groups = fill_dropped(S, labels, filled, keep)
        Z = as_frames(S, 3)[:, 2, :]
        Z -= Z.mean(axis=1, keepdims=True)
        flipped = self._mirrored(window, problem, Z)
        if flipped is not None:
            S, R, Z = flip_depth(S), DEPTH_FLIP @ R @ DEPTH_FLIP, -Z
        report = getattr(result, 'report', None)
        if getattr(report, 'rotation_checked', False):
            full = problem.n_context >= self.context_frames
            self._rotation_check = (problem.sequence, report.rotation_method, problem.stamps) \
                if full else None
        F = len(problem.stamps)
        uv = filled.reshape(F, 2, -1).transpose(0, 2, 1)
        error = (as_frames(Wc, 2) - as_frames(S, 3)[:, :2, :]) * seen[:, None, :]
        residual = float(np.linalg.norm(error) / max(np.linalg.norm(Wc * np.repeat(seen, 2, 0)),
                                                     1e-300))
        self.previous = Solution(window.sequence, problem.stamps, problem.ids, uv, S, R,
                                 groups, report, residual, self._rank_of(report, init),
                                 window.preview)
        return problem, as_frames(Wc, 2), Z, flipped == 'published', seen

    def _fit_kwargs(self, solver, problem, init, keep, progress):
        """The keywords of this solve's ``fit``: the start, the window's completion (the
        solver completes no window again) and no refill round (WINDOW_REFILL_ROUNDS), the
        progress callback and a penalty cap (never below the solver's beta0): for a window
        started from the rigid factorisation (a sequence's first) FIRST_WINDOW_BETA_MAX
        (docs/decisions/0445), for a window with context under 'resume' (resumed, or the
        second window of a sequence) WINDOW_BETA_MAX (docs/decisions/0425)."""
        kwargs = {} if init is None else {'init': subset_init(init, keep)}
        if not problem.seen.all():
            if _accepts(solver.fit, 'filled'):
                kwargs['filled'] = problem.filled if keep is None else problem.filled[:, keep]
            if _accepts(solver.fit, 'refill_rounds'):
                kwargs['refill_rounds'] = WINDOW_REFILL_ROUNDS
        if progress is not None and _accepts(solver.fit, 'progress'):
            kwargs['progress'] = progress
        cap = FIRST_WINDOW_BETA_MAX if self.started_from == 'rigid' else \
            WINDOW_BETA_MAX if self.warm_start == 'resume' and problem.n_context else None
        if cap and hasattr(solver, 'get_params') and _accepts(solver.fit, 'beta_max'):
            values = solver.get_params()
            kwargs['beta_max'] = min(values['beta_max'], max(cap, values['beta0']))
        return kwargs

    def _results(self, problem, XY, Z, seen, sheet=None):
        """FrameResults of the frames of ``problem`` solved at most ``refined_after`` times
        (this solve counted), each on the tracks it sees (``seen: (F, P)``); from the
        ``sheet`` model (:func:`~grass_nrsfm_ros.nrsfm.sheet_model.frame_points`, refined to
        convergence) where there is one and it reaches the frame."""
        if self._solves[0] != problem.sequence:
            self._solves = (problem.sequence, {})
        solves = self._solves[1]
        out = []
        for i, stamp in enumerate(int(s) for s in problem.stamps):
            solves[stamp] = solves.get(stamp, 0) + 1
            if solves[stamp] <= self.refined_after:
                xyz = np.column_stack([XY[i].T, Z[i]])
                ids = problem.ids
                if not seen[i].all():
                    ids, xyz = ids[seen[i]], xyz[seen[i]]
                result = FrameResult(stamp, problem.frame_ids[i], ids, xyz)
                if sheet is not None:
                    uv = problem.W[2 * i:2 * i + 2, seen[i]].T
                    xyz = frame_points(sheet, ids, uv, REFINE_ITERATIONS)
                    if xyz is not None:
                        result = replace(result, xyz=xyz, signed=True)
                out.append(result)
        return tuple(out)

    def _figures(self, seconds):
        """What the diagnostics show of the last solve."""
        report = self.previous.report
        return dict(solve_seconds=seconds, started_from=self.started_from,
                    iterations=getattr(report, 'iterations', ''),
                    reprojection_residual=self.previous.residual,
                    tracks_thinned=getattr(report, 'thinned_points', ''))

    def _releases(self, window):
        """True for a final window whose frames the last solution (not a preview's) holds:
        not solved again."""
        p = self.previous
        return (window.final and p is not None and p.sequence == window.sequence
                and not p.preview and np.isin(window.stamps, p.stamps).all())

    def _mirrored(self, window, problem, Z):
        """Why the solve's depth ``Z: (F, P)`` (centred per frame) must be mirrored, or None:
        'previous' where it correlates negatively with the previous solution's on the frames
        and tracks both hold; where they share none, 'published' where it correlates
        negatively with the depths published for ``window``'s frames (and context)."""
        ov = self._overlap(problem)
        if ov is not None:
            fn, fo, tn, to = ov
            old = as_frames(self.previous.S, 3)[:, 2, :][np.ix_(fo, to)]
            return 'previous' if correlation(Z[np.ix_(fn, tn)], old) < 0.0 else None
        published = {f.stamp_ns: f.depth for f in window.context + window.frames
                     if f.depth is not None}
        return 'published' if disagrees_with(problem, Z, published) else None

    def _problem(self, window):
        """What ``window`` is solved as: its context frames then its own frames, on the
        window's tracks. The context is its newest frames that each see at least
        ``CONTEXT_TRACKS`` of the window's tracks that its first frame sees (tracks born
        later are no reason to drop one; the first that sees fewer ends it)."""
        context, ids, kept = window.context, window.ids, 0
        old = common_ids(ids, window.frames[0].ids)
        for frame in reversed(context):
            if common_ids(old, frame.ids).size < max(self.min_tracks,
                                                     CONTEXT_TRACKS * old.size):
                break
            kept += 1
        context = context[len(context) - kept:] if kept else ()
        frames = context + window.frames
        stamps = np.array([f.stamp_ns for f in frames], dtype=np.int64)
        W = window_matrix(frames, ids)
        return WindowProblem(window.sequence, stamps, ids, W, len(context),
                             tuple(f.frame_id for f in frames), *fill_unseen(W)[:2])

    def _mapped_tracks(self, ids, first=False):
        """Indices (sorted) of the tracks ``ids: (P,)`` the solver sees, at most
        ``mapping_tracks`` (FIRST_WINDOW_TRACKS for the ``first`` window of a sequence), or None
        for all; the same ids are picked in every window (a fixed hash of the id)."""
        cap = self.mapping_tracks or ids.size
        if first:
            cap = min(cap, FIRST_WINDOW_TRACKS)
        if ids.size <= cap:
            return None
        key = (ids.astype(np.uint64) * np.uint64(2654435761)) % np.uint64(1 << 32)
        return np.sort(np.argsort(key, kind='stable')[:cap])

    # -- warm start -----------------------------------------------------------------------------
    def _overlap(self, problem):
        """Indices ``(frames_new, frames_old, tracks_new, tracks_old)`` shared with the previous
        solution, or None when it belongs to another sequence or shares too little."""
        p = self.previous
        if p is None or p.sequence != problem.sequence:
            return None
        _, fn, fo = np.intersect1d(problem.stamps, p.stamps, return_indices=True)
        _, tn, to = np.intersect1d(problem.ids, p.ids, assume_unique=True, return_indices=True)
        if fn.size == 0 or tn.size < self.min_tracks:
            return None
        return fn, fo, tn, to

    def _start_for(self, problem):
        """The solver's ``init`` for ``problem``: the previous solution resumed ('resume', when
        it overlaps and has context), the rigid factorisation for a problem without context
        (the first window of a sequence), else the previous solution's spatial groups and
        rotation method ('model'; and the second window under 'resume')."""
        ov = self._overlap(problem)
        self._resumed_rank = None
        if self.warm_start == 'resume' and self._resumable(problem, ov):
            self.started_from = 'resumed'
            return self._resume_start(problem, ov)
        if not problem.n_context:
            self.started_from = 'rigid'
            return rigid_start(problem.filled)
        self.started_from = 'model'
        groups = None
        if ov is not None and self.previous.groups is not None:
            groups = np.asarray(self.previous.groups)[self._donors(problem, ov)]
        return WarmStart(groups=groups, rotation_method=self._carried_rotation_method(problem))

    def _resumable(self, problem, ov):
        """True if ``problem`` (with context) can resume the previous solution."""
        return ov is not None and problem.n_context > 0 and self.previous.K_rot is not None

    def _resume_start(self, problem, ov):
        """WarmStart resuming the previous solution: its shapes and spatial groups carried
        (:meth:`_carried_start`), rotations by Dai's method refined from the previous ones
        (:func:`resume_rotations`), solved as a cold solve from them (``resumed``)."""
        start = self._carried_start(problem, ov)
        R, self._resumed_rank = resume_rotations(problem.filled, np.asarray(start.R),
                                                 start.known, self.previous.K_rot)
        return replace(start, R=R, known=np.ones(start.known.size, dtype=bool), resumed=True)

    def _carried_start(self, problem, ov):
        """WarmStart from the previous solution on the overlap ``ov``: rotations of the shared
        frames, camera-frame shapes and spatial groups carried (new frames copy the nearest
        shared frame's rotation and depth, new tracks their donor's depth and group)."""
        fn, fo, tn, to = ov
        p = self.previous
        F, P = len(problem.stamps), problem.ids.size
        nearest = fn[np.clip(np.searchsorted(fn, np.arange(F)), 0, fn.size - 1)]
        source = fo[np.searchsorted(fn, nearest)]
        donor = self._donors(problem, ov)
        Z = as_frames(p.S, 3)[:, 2, :][source][:, donor]
        Z -= Z.mean(axis=1, keepdims=True)
        S = np.empty((F, 3, P))
        S[:, :2, :] = as_frames(centre(problem.filled)[0], 2)
        S[:, 2, :] = Z
        known = np.zeros(F, dtype=bool)
        known[fn] = True
        groups = None if p.groups is None else np.asarray(p.groups)[donor]
        return WarmStart(R=p.R[source], S=S.reshape(3 * F, P), known=known, groups=groups)

    def _donors(self, problem, ov):
        """For each track of ``problem``, the index of a track of the previous solution: the
        same track where shared, else the nearest shared track in the image of the first
        shared frame. ``(P,)`` int."""
        fn, fo, tn, to = ov
        p = self.previous
        F, P = len(problem.stamps), problem.ids.size
        donor = np.full(P, -1)
        donor[tn] = to
        missing = donor < 0
        if missing.any():
            tree = cKDTree(p.uv[fo[0]][to])
            new_uv = problem.filled.reshape(F, 2, P)[fn[0]].T[missing]     # pixels, same frame
            donor[missing] = to[tree.query(new_uv)[1]]
        return donor

    def _carried_rotation_method(self, problem):
        """The rotation method of the solver's last check in this sequence if that check saw
        full context and fewer than RECHECK_SHARE of its frames are new in ``problem``; else
        None (the solver checks again)."""
        if self._rotation_check is None:
            return None
        sequence, method, stamps = self._rotation_check
        if sequence != problem.sequence:
            return None
        new = np.setdiff1d(problem.stamps, stamps, assume_unique=True).size
        return method if new < RECHECK_SHARE * stamps.size else None

    def _rank_of(self, report, init):
        """Dai's rank of a solve's rotations: the solver's, 1 for rigid ones, the resumed
        start's when they were given (None: unknown)."""
        method = getattr(report, 'rotation_method', None)
        if method == 'dai':
            return report.K_rot
        if method == 'rigid':
            return 1
        return self._resumed_rank if method == 'given' and init is not None else None


def rigid_start(W):
    """WarmStart of a problem with no previous solution: the rigid factorisation's rotations
    and camera-frame shape for every frame of ``W: (2F, P)``."""
    R, S = rigid_factorisation(W)
    return WarmStart(R=R, S=S, known=np.ones(W.shape[0] // 2, dtype=bool), groups=None)


def resume_rotations(W, R0, known, K):
    """``(R: (F, 3, 3), K)``: Dai's rotations of ``W: (2F, P)`` refined from ``R0`` on the
    ``known: (F,)`` frames at ranks K - 1, K, K + 1 within Dai's candidates (K = 1, rigid: that
    rank only), the rank chosen among them by :func:`choose_rank`; ``(R0, K)`` where every
    rank fails."""
    F = W.shape[0] // 2
    top = min(max(DEFAULT_CANDIDATES), max_rank(F, W.shape[1]))
    ranks = [K] if K == 1 else [k for k in (K - 1, K, K + 1) if 1 <= k <= top]
    estimates = {}
    try:
        svd = normalised_svd(W)                     # one SVD for every rank
    except (ValueError, np.linalg.LinAlgError):
        return R0, K
    for k in ranks:
        try:
            estimates[k] = rotations_from_start(W, k, R0, known, _svd=svd)
        except (ValueError, np.linalg.LinAlgError):
            continue
    if not estimates:
        return R0, K
    chosen = choose_rank({k: e.scores['residual'] for k, e in estimates.items()}, F)[0]
    return estimates[chosen].R, chosen


def subset_init(init, keep):
    """``init`` (a WarmStart or None) restricted to the tracks ``keep`` (None: all)."""
    if init is None or keep is None:
        return init
    S = None if init.S is None else np.asarray(init.S)[:, keep]
    groups = None if init.groups is None else np.asarray(init.groups)[keep]
    return replace(init, S=S, groups=groups)


def flip_depth(S):
    """``S: (3F, P)`` camera-frame shapes with their depth rows negated (DEPTH_FLIP)."""
    return (DEPTH_FLIP @ as_frames(S, 3)).reshape(S.shape)


def correlation(new, old):
    """Sum over frames of the products of two depths ``(F, P)``, each centred per frame."""
    new = new - new.mean(axis=1, keepdims=True)
    old = old - old.mean(axis=1, keepdims=True)
    return float(np.sum(new * old))


def disagrees_with(problem, Z, published):
    """True if the depth ``Z: (F, P)`` of ``problem``'s frames and tracks correlates
    negatively with the depths ``published`` (``{stamp: (ids, z)}``) on the frames both
    have."""
    total = 0.0
    for f, stamp in enumerate(problem.stamps):
        if int(stamp) not in published:
            continue
        ids, z = published[int(stamp)]
        _, a, b = np.intersect1d(problem.ids, ids, assume_unique=True, return_indices=True)
        total += correlation(Z[f, a][None], z[b][None].astype(np.float64))
    return total < 0.0
