"""SlidingWindow: the windowed reconstruction under :mod:`grass_nrsfm_ros.live` (the mapping
of the node and of the offline bag tools). Pure Python and numpy: no ROS import.

Frames go in one at a time (``add_frame(stamp_ns, ids, uv, frame_id)``: ``ids: (P,)`` track
ids, ``uv: (P, 2)`` pixels); every ``window_stride`` frames (the first time after
``window_size`` frames) a :class:`Window` comes out, holding ``W: (2F, P)`` for the tracks seen
in *all* of its frames. ``solve(window)`` reconstructs it and returns the
:class:`FrameResult` of each frame not published before: the first window's frames, then the
``stride`` new frames of each later window, so every frame is published exactly once
(``refined_from='first_window'``, the sliding-window behaviour). With ``'last_window'`` a
frame is published by the solve that reconstructs it for the ``ceil(window_size /
window_stride)``-th time (as one of a window's own frames or as context): for a frame after
the first window, the last window that has it among its own frames, with the most frames after
it; the last window of a sequence (:meth:`SlidingWindow.flush`) publishes the rest.

Policies (the node reports each as it happens):

* **Tracks come and go.** A window reconstructs the tracks present in every one of its frames
  (an intersection by id); a track that appears later joins the first window that contains it
  from start to end. A window whose frames share fewer than ``min_tracks`` ids is not solved
  (:class:`WindowError`); its new frames are published by the next window that solves.
* **Order.** Frames are buffered by stamp, so a frame that arrives out of order is inserted
  where it belongs, as long as its window has not been emitted yet; a frame older than the
  newest frame of an emitted window is refused as late (:class:`FrameError`). A second frame
  with the stamp of a buffered one is refused as a duplicate (the first one is kept).
* **All ids change** (a new tracker session): a frame sharing fewer than ``min_tracks`` ids
  with the newest buffered frame starts a new *sequence*. The old buffer's unpublished frames
  come out in one last window (the newest ``window_size`` frames), the buffer is emptied and
  no warm start crosses the boundary.
* **Skipping.** A caller that cannot keep up may drop windows and solve only the newest: the
  next solved window publishes every unpublished frame it covers; frames that fell out of all
  solved windows are counted in ``stats['frames_lost']`` (with ``'last_window'``, a frame
  solved once goes out from its latest solve instead).

Context: each window is solved together with up to ``context_frames`` (60) earlier frames and
``key_frames`` (30) older ones spread evenly over the sequence (KeyFrames); a window alone (the
first of a sequence) starts from the rigid factorisation (docs/decisions/0035, 0036).
``mapping_tracks`` caps the tracks a window is solved on, the rest filled in (0403).

Warm start (``warm_start``), what a solve takes from the previous window's solution
(docs/decisions/0037, 0038):

* ``'model'``: the spatial groups of the overlapping tracks (new tracks take their
  nearest old track's) and the rotation method the solver's check chose (Dai's or rigid),
  carried until the frames new since that check reach RECHECK_SHARE of the frames it was made
  on; rotations are re-estimated over the whole problem, shapes start from the solver's own.
* ``'full'``: also the rotations of the overlapping frames (fixed) and their camera-frame
  shapes (:meth:`SlidingWindow._full_warm_start`).
* ``'off'``: every window with context from the solver's own start.
* ``'resume'`` (default): the previous window's solution resumed
  (:meth:`SlidingWindow._resume_start`): shapes and groups of the shared frames and tracks,
  rotations by Dai's method refined from the previous ones at the carried rank (no rank
  search, no rotation check), the solver's penalty schedule from its beta0.

Alignment: a window's camera-frame shapes are defined up to the sign of depth (the orthographic
reflection) and a depth offset; each window's depth is centred per frame and its sign chosen to
agree with the previous window on the overlap, so published clouds keep one orientation.
"""
from bisect import bisect_left
from collections import deque
from dataclasses import dataclass, replace
import inspect
import math
import threading
import time

import numpy as np
from scipy.spatial import cKDTree

from grass_nrsfm_ros import params
from grass_nrsfm_ros.cloud import strictly_increasing
from grass_nrsfm_ros.nrsfm import GrassmannNRSfM, WarmStart
from grass_nrsfm_ros.nrsfm.density import fill_dropped
from grass_nrsfm_ros.nrsfm.measurement import as_frames, centre
from grass_nrsfm_ros.nrsfm.rotation import (align_rotations, choose_rank, DEFAULT_CANDIDATES,
                                            estimate_rotations, max_rank, normalised_svd,
                                            rigid_factorisation, rotations_from_rows,
                                            rotations_from_start)
from grass_nrsfm_ros.nrsfm.solver import one_blas_thread
from grass_nrsfm_ros.params import MIN_WINDOW_FRAMES

#: fewest tracks a window may be solved on when ``mapping_tracks`` caps them
MIN_MAPPING_TRACKS = 100
#: a context frame joins a solve only while the tracks common to it, the newer context frames
#: and the window stay at least this share of the window's tracks
CONTEXT_TRACKS = 0.9
#: warm_start 'model': the rotation method chosen by the solver's check on a problem with full
#: context is carried until the frames new since that check reach this share of its frames
RECHECK_SHARE = 0.5
DEPTH_FLIP = np.diag([1.0, 1.0, -1.0])


def common_ids(a, b):
    """The ids in both sorted unique id arrays ``a`` and ``b`` (``a`` itself when they are equal:
    the usual case, with no set operation)."""
    return a if np.array_equal(a, b) else np.intersect1d(a, b, assume_unique=True)


class KeyFrames:
    """At most ``size`` frames spread evenly over a stream of older frames: every ``step``-th
    one is kept, and ``step`` doubles (every other kept frame dropped) when they overflow."""

    def __init__(self, size):
        self.size, self.step, self.seen, self.frames = size, 1, 0, []

    def extend(self, frames):
        for frame in frames:
            if self.size and self.seen % self.step == 0:
                self.frames.append(frame)
                if len(self.frames) > self.size:
                    self.frames, self.step = self.frames[::2], 2 * self.step
            self.seen += 1


class FrameError(ValueError):
    """A frame that was refused (the message says why); the pipeline state is unchanged."""


class WindowError(ValueError):
    """A window that cannot be solved (too few common tracks)."""


@dataclass(frozen=True)
class Frame:
    """One buffered frame: ``ids: (P,) uint32`` sorted, ``uv: (P, 2)`` pixels in the same order."""

    stamp_ns: int
    frame_id: str
    ids: np.ndarray
    uv: np.ndarray


@dataclass(frozen=True)
class Window:
    """A window ready to solve: ``W: (2F, P)`` pixels of the ``ids: (P,)`` common tracks over
    frames ``stamps: (F,)`` (ascending); ``closed_at``: ``time.monotonic()`` when it closed;
    ``context``: the earlier Frames of its sequence solved with it but not published by it
    (oldest first: up to ``key_frames`` spread evenly over the older past, then the newest
    ``context_frames``); ``final``: the last window of its sequence
    (:meth:`SlidingWindow.flush`)."""

    sequence: int
    index: int
    stamps: np.ndarray
    frame_ids: tuple
    ids: np.ndarray
    W: np.ndarray
    closed_at: float
    context: tuple = ()
    final: bool = False

    @property
    def n_frames(self):
        return len(self.stamps)


@dataclass(frozen=True)
class FrameResult:
    """One reconstructed frame: ``xyz: (P, 3)`` in the camera frame (x, y = the frame's centred
    u, v; z = depth; all times ``metres_per_pixel``) for tracks ``ids: (P,)``."""

    stamp_ns: int
    frame_id: str
    ids: np.ndarray
    xyz: np.ndarray


@dataclass(frozen=True)
class Problem:
    """What one solve reconstructs: ``W: (2F, P)`` of tracks ``ids: (P,)`` over ``stamps: (F,)``
    = ``n_context`` context frames then the window's frames (``frame_ids: (F,)``)."""

    sequence: int
    stamps: np.ndarray
    ids: np.ndarray
    W: np.ndarray
    n_context: int
    frame_ids: tuple = ()


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


def _takes_progress(fit):
    """True if ``fit`` accepts a ``progress`` keyword."""
    try:
        params = inspect.signature(fit).parameters
    except (TypeError, ValueError):
        return False
    return 'progress' in params or any(p.kind == p.VAR_KEYWORD for p in params.values())


def default_solver_factory(**solver_kwargs):
    """A factory of ``GrassmannNRSfM(**solver_kwargs)``."""
    def make():
        return GrassmannNRSfM(**solver_kwargs)
    return make


def make_windows(config, solver_factory=None, **options):
    """The :class:`SlidingWindow` that ``config`` describes (a dict of parameters as from
    :func:`grass_nrsfm_ros.params.load_config` or the node's declarations; absent keys take
    their defaults). ``solver_factory`` replaces ``GrassmannNRSfM(**solver parameters)``;
    ``options`` (e.g. ``warm_start_class``) go to SlidingWindow as they are."""
    factory = solver_factory or default_solver_factory(**params.solver_kwargs(config))
    if config.get('output', 'live') == 'live':
        options = {'refined_from': config.get('refined_from', 'last_window'), **options}
    return SlidingWindow(factory, metres_per_pixel=config.get('metres_per_pixel', 1.0),
                         **params.window_kwargs(config), **options)


class SlidingWindow:
    """The windowed pipeline; see the module docstring for the policies.

    ``solver_factory()`` returns an object with ``fit(W, init=None)`` returning a result with
    ``S: (3F, P)``, ``R: (F, 3, 3)``, optional ``groups: (P,)`` and ``report``. ``add_frame``
    and ``solve`` may run on two different threads (one each).
    """

    def __init__(self, solver_factory=None, *, window_size=30, window_stride=10, min_tracks=10,
                 warm_start='resume', align_windows=True, metres_per_pixel=1.0,
                 context_frames=60, warm_rotations='solver', warm_start_class=None,
                 key_frames=30, mapping_tracks=0, refined_from='first_window'):
        params.check_window(window_size=window_size, window_stride=window_stride,
                            context_frames=context_frames, key_frames=key_frames,
                            warm_start=warm_start, warm_rotations=warm_rotations,
                            mapping_tracks=mapping_tracks, refined_from=refined_from)
        self.refined_from = refined_from
        #: a frame is published by the solve that reconstructs it for this many'th time
        self.publish_after = 1 if refined_from == 'first_window' else \
            math.ceil(int(window_size) / int(window_stride))
        self.solver_factory = solver_factory or default_solver_factory()
        self.context_frames, self.warm_rotations = int(context_frames), warm_rotations
        self.key_frames = int(key_frames) if self.context_frames else 0
        self.window_size, self.window_stride = int(window_size), int(window_stride)
        self.min_tracks = int(min_tracks)
        if mapping_tracks and mapping_tracks < max(self.min_tracks, MIN_MAPPING_TRACKS):
            raise ValueError(f'mapping_tracks={mapping_tracks}: 0 (all) or at least '
                             f'{max(self.min_tracks, MIN_MAPPING_TRACKS)}')
        self.mapping_tracks = int(mapping_tracks)
        self.newest = None              # the Frame the last add_frame accepted
        self._window_wanted = False
        self.warm_start, self.align_windows = warm_start, bool(align_windows)
        self.metres_per_pixel = float(metres_per_pixel)
        self._warm_start_class = warm_start_class
        self._frames = []               # buffered Frames, ascending stamps
        self._history = deque(maxlen=max(self.context_frames, 1))   # Frames that left _frames
        self._keys = KeyFrames(self.key_frames)     # older Frames, thinned evenly
        self._sequence = 0
        self._window_index = 0
        self._emitted_until = None      # newest stamp of the last emitted window
        #: 'last_window': (sequence, {stamp: (FrameResult of its latest solve, solves)}) of
        #: the frames solved but not published yet
        self._latest = (None, {})
        self._unpublished = deque(maxlen=1_000_000)   # (sequence, stamp) emitted, not published
        self._published_until = {}      # sequence -> newest published stamp
        self._previous = None           # Solution of the last solved window
        self._rotation_check = None     # (sequence, method, stamps) of the last full check
        self._resumed_rank = None       # Dai's rank of the rotations a resumed start gave
        self._lock = threading.Lock()
        self.stats = dict(frames=0, refused=0, resets=0, windows=0, solved=0, failed=0,
                          published=0, frames_lost=0)

    # -- input side -------------------------------------------------------------------------
    def add_frame(self, stamp_ns, ids, uv, frame_id=''):
        """Buffer one frame; return the windows it closes (usually none, sometimes one; two
        when all ids changed). Raises FrameError for a refused frame."""
        frame, new_sequence = self._checked_frame(int(stamp_ns), ids, uv, str(frame_id))
        windows = []
        if new_sequence:
            windows += self.flush()
            self._frames = []
            self._history.clear()
            self._keys = KeyFrames(self.key_frames)
            self._sequence += 1
            self._emitted_until = None          # a new sequence's stamps may start earlier
            self._count('resets')
        stamps = [f.stamp_ns for f in self._frames]
        self._frames.insert(bisect_left(stamps, frame.stamp_ns), frame)
        self._count('frames')
        self.newest = frame
        kept = self.window_size - self.window_stride     # frames a window leaves buffered
        early = self._window_wanted and len(self._frames) > max(kept, MIN_WINDOW_FRAMES - 1)
        if len(self._frames) >= self.window_size or early:
            self._window_wanted = False
            windows.append(self._emit(self._frames[:self.window_size]))
            leaving = self._frames[:len(self._frames) - kept]
            spill = len(self._history) + len(leaving) - self._history.maxlen
            if self.context_frames and spill > 0:
                self._keys.extend((list(self._history) + leaving)[:spill])
            self._history.extend(leaving)
            self._frames = self._frames[len(leaving):]
        return windows

    def request_window(self):
        """Close the next window early: at the next frame, over the frames buffered since the
        last window (the model no longer explains the data)."""
        self._window_wanted = True

    def flush(self):
        """The last window of the sequence (end of a sequence or of a bag; it publishes every
        frame it can): over the newest buffered frames if any of them was never in a window,
        or (``refined_from='last_window'``) while frames of emitted windows wait unpublished;
        ``[]`` otherwise."""
        frames = self._frames[-self.window_size:]
        fresh = [f for f in frames if self._emitted_until is None
                 or f.stamp_ns > self._emitted_until]
        waiting = self.publish_after > 1 and bool(self._unpublished) \
            and self._unpublished[-1][0] == self._sequence
        if not (fresh or waiting) or len(frames) < MIN_WINDOW_FRAMES:
            self._count('frames_lost', len(fresh))
            if fresh:                           # given up: not pending, not lost twice
                self._emitted_until = fresh[-1].stamp_ns
            return []
        return [self._emit(frames, final=True)]

    @property
    def sequence(self):
        """The current sequence's number (0 first; one more after each reset or id change)."""
        return self._sequence

    def reset(self):
        """Drop the buffered frames (counted lost unless already in a window) and the model
        (the previous solution, the rotation check); the next frame starts a new sequence.
        Frames of windows already closed stay pending until their solve or a newer sequence's
        publication accounts for them. Returns ``{'frames': buffered frames dropped, 'model':
        whether there was one}``."""
        fresh = [f for f in self._frames
                 if self._emitted_until is None or f.stamp_ns > self._emitted_until]
        self._count('frames_lost', len(fresh))
        had_model = self._previous is not None
        self._frames = []
        self._history.clear()
        self._keys = KeyFrames(self.key_frames)
        self._previous, self._rotation_check = None, None
        self._sequence += 1
        self._emitted_until = None
        self._count('resets')
        return {'frames': len(fresh), 'model': had_model}

    def _checked_frame(self, stamp_ns, ids, uv, frame_id):
        ids = np.asarray(ids)
        uv = np.asarray(uv, dtype=np.float64)
        try:
            if ids.ndim != 1 or uv.shape != (ids.size, 2):
                raise FrameError(f'ids {ids.shape} and uv {uv.shape} do not match (P,), (P, 2)')
            if ids.size < self.min_tracks:
                raise FrameError(f'{ids.size} tracks; at least min_tracks={self.min_tracks} '
                                 'needed')
            if not np.isfinite(uv).all():
                raise FrameError(f'{int((~np.isfinite(uv)).any(axis=1).sum())} tracks with '
                                 'non-finite u/v')
            # the frame keeps copies (the caller may reuse its arrays); sorted input needs no sort
            order = slice(None) if strictly_increasing(ids) else np.argsort(ids, kind='stable')
            ids, uv = ids[order].astype(np.uint32), uv[order].copy()
            if (ids[1:] == ids[:-1]).any():
                raise FrameError(f'duplicate track id {int(ids[1:][ids[1:] == ids[:-1]][0])}')
            new_sequence = bool(self._frames) and self._shared(
                Frame(stamp_ns, frame_id, ids, uv), self._frames[-1]) < self.min_tracks
            if not new_sequence:                # a new sequence's stamps start afresh
                self._check_stamp(stamp_ns)
        except FrameError:
            self._count('refused')
            raise
        return Frame(stamp_ns, frame_id, ids, uv), new_sequence

    def _check_stamp(self, stamp_ns):
        """Raise FrameError for a stamp that is late (not newer than the last emitted window)
        or a duplicate of a buffered frame's."""
        if self._emitted_until is not None and stamp_ns <= self._emitted_until:
            raise FrameError(f'late frame: stamp {stamp_ns} is not newer than the last '
                             f'emitted window ({self._emitted_until})')
        if any(f.stamp_ns == stamp_ns for f in self._frames):
            raise FrameError(f'duplicate stamp {stamp_ns} (the first frame is kept)')

    @staticmethod
    def _shared(a, b):
        return int(common_ids(a.ids, b.ids).size)

    def _emit(self, frames, final=False):
        common = frames[0].ids
        for f in frames[1:]:
            common = common_ids(common, f.ids)
        W = window_matrix(frames, common)
        stamps = np.array([f.stamp_ns for f in frames], dtype=np.int64)
        for s in stamps:
            if self._emitted_until is None or s > self._emitted_until:
                self._unpublished.append((self._sequence, int(s)))
        self._emitted_until = int(stamps[-1])
        context = tuple(f for f in self._keys.frames + list(self._history)
                        if f.stamp_ns < stamps[0]) \
            if self.context_frames else ()
        window = Window(self._sequence, self._window_index, stamps,
                        tuple(f.frame_id for f in frames), common, W, time.monotonic(),
                        context, final)
        self._window_index += 1
        self._count('windows')
        return window

    # -- solve side -------------------------------------------------------------------------
    def solve(self, window, progress=None):
        """Reconstruct ``window`` (with its context frames); return FrameResults of its frames
        not yet published (in stamp order). Raises WindowError when its frames share fewer than
        ``min_tracks`` tracks. ``progress(iteration, report)`` is handed to solvers whose
        ``fit`` takes it (an exception raised there abandons the solve and propagates).
        BLAS runs on BLAS_THREADS threads throughout, as in the solver."""
        with one_blas_thread():
            return self._solve(window, progress)

    def _solve(self, window, progress):
        if self.releases(window):
            return self._release(window)
        if window.ids.size < self.min_tracks:
            self._count('failed')
            raise WindowError(f'window {window.index}: its {window.n_frames} frames share '
                              f'{window.ids.size} tracks (< min_tracks={self.min_tracks})')
        problem = self._problem(window)
        Wc, _ = centre(problem.W)
        init = self._start_for(problem, Wc)
        keep = self._mapped_tracks(problem.ids)
        solver = self._schedule_for(self.solver_factory(), problem, init)
        kwargs = {} if init is None else {'init': subset_init(init, keep)}
        if progress is not None and _takes_progress(solver.fit):
            kwargs['progress'] = progress
        result = solver.fit(problem.W if keep is None else problem.W[:, keep], **kwargs)
        S = np.array(result.S, dtype=np.float64)
        R = np.array(result.R, dtype=np.float64)
        if not (np.isfinite(S).all() and np.isfinite(R).all()):
            self._count('failed')
            raise WindowError(f'window {window.index}: the solver returned non-finite shapes or '
                              'rotations; nothing published')
        groups = getattr(result, 'groups', None)
        if keep is not None:
            labels = np.zeros(keep.size, dtype=int) if groups is None else groups
            S, groups = fill_dropped(S, labels, problem.W, keep)
        Z = as_frames(S, 3)[:, 2, :]
        Z -= Z.mean(axis=1, keepdims=True)
        if self.align_windows and self._depth_disagrees(problem, Z):
            S = flip_depth(S)
            R = DEPTH_FLIP @ R @ DEPTH_FLIP
            Z = as_frames(S, 3)[:, 2, :]
        F = len(problem.stamps)
        uv = problem.W.reshape(F, 2, -1).transpose(0, 2, 1)
        residual = float(np.linalg.norm(as_frames(Wc, 2) - as_frames(S, 3)[:, :2, :])
                         / max(np.linalg.norm(Wc), 1e-300))
        report = getattr(result, 'report', None)
        if getattr(report, 'rotation_checked', False):
            full = problem.n_context >= self.context_frames
            self._rotation_check = (problem.sequence, report.rotation_method, problem.stamps) \
                if full else None
        self._previous = Solution(window.sequence, problem.stamps, problem.ids, uv, S, R,
                                  groups, report, residual, self._rank_of(report, init))
        self._count('solved')
        return self._publish(window, problem, as_frames(Wc, 2), Z)

    def releases(self, window):
        """True if :meth:`solve` will not solve ``window`` again but release its frames: the
        last window of a sequence whose frames the last solution holds (:meth:`flush` with no
        new frame)."""
        p = self._previous
        return (window.final and p is not None and p.sequence == window.sequence
                and np.isin(window.stamps, p.stamps).all())

    def _release(self, window):
        """The final ``window``'s FrameResults without a solve: every frame solved but not
        published yet, from its latest solve."""
        return self._publish_latest(window, None, None, None)

    def _rank_of(self, report, init):
        """Dai's rank of a solve's rotations: the solver's, 1 for rigid ones, the resumed
        start's when they were given (None: unknown)."""
        method = getattr(report, 'rotation_method', None)
        if method == 'dai':
            return report.K_rot
        if method == 'rigid':
            return 1
        return self._resumed_rank if method == 'given' and init is not None else None

    def flip_previous(self):
        """Mirror the depth of the last solution (``S``'s z rows, ``R`` -> ``D R D``) and of the
        frames waiting to be published from earlier solves, so the next window aligns to the
        flipped orientation."""
        p = self._previous
        p.S, p.R = flip_depth(p.S), DEPTH_FLIP @ p.R @ DEPTH_FLIP
        latest = self._latest[1]
        for stamp, (r, solves) in latest.items():      # solved in the same orientation
            latest[stamp] = (replace(r, xyz=r.xyz @ DEPTH_FLIP), solves)

    def _mapped_tracks(self, ids):
        """Indices ``(mapping_tracks,)`` (sorted) of the tracks ``ids: (P,)`` the solver sees,
        or None for all; the same ids are picked in every window (a fixed hash of the id)."""
        if not self.mapping_tracks or ids.size <= self.mapping_tracks:
            return None
        key = (ids.astype(np.uint64) * np.uint64(2654435761)) % np.uint64(1 << 32)
        return np.sort(np.argsort(key, kind='stable')[:self.mapping_tracks])

    def _problem(self, window):
        """What ``window`` is solved as: its context frames (newest first dropped last) then its
        own frames, on the tracks common to all of them. Context frames are dropped, oldest
        first, while the common tracks are fewer than ``CONTEXT_TRACKS`` of the window's."""
        context = window.context            # bounded when the window closed (_emit)
        ids = window.ids
        kept = 0
        for frame in reversed(context):
            common = common_ids(ids, frame.ids)
            if common.size < max(self.min_tracks, CONTEXT_TRACKS * window.ids.size):
                break
            ids, kept = common, kept + 1
        context = context[len(context) - kept:] if kept else ()
        stamps = np.concatenate([np.array([f.stamp_ns for f in context], dtype=np.int64),
                                 window.stamps])
        if ids.size == window.ids.size:
            W_window = window.W
        else:
            cols = np.searchsorted(window.ids, ids)
            W_window = window.W[:, cols]
        W = np.vstack([window_matrix(context, ids), W_window]) if context else W_window
        frame_ids = tuple(f.frame_id for f in context) + tuple(window.frame_ids)
        return Problem(window.sequence, stamps, ids, W, len(context), frame_ids)

    def note_solved(self, sequence, stamps, solved=True):
        """Bookkeep a window of ``sequence`` solved elsewhere (a mapping process with its own
        SlidingWindow) that published the frames ``stamps: (F,)``: counted solved (unless
        ``solved`` is false: a final window released without a solve), those frames counted
        published (and those it passed over lost), as :meth:`solve` does."""
        if solved:
            self._count('solved')
        self._count('published', len(self._fresh(sequence, stamps)))

    def note_failed(self):
        """Count a window that was not solved elsewhere (see :meth:`note_solved`)."""
        self._count('failed')

    def _fresh(self, sequence, stamps):
        """Indices of ``stamps: (F,)`` (a solved window of ``sequence``) not published before;
        marks them published and counts the frames this window passed over as lost."""
        done = self._published_until.get(sequence)
        fresh = [i for i, s in enumerate(stamps) if done is None or s > done]
        if not fresh:
            return []
        newest, first = int(stamps[fresh[-1]]), int(stamps[fresh[0]])
        self._published_until[sequence] = newest
        while self._unpublished and self._unpublished[0] <= (sequence, newest):
            seq, stamp = self._unpublished.popleft()
            if seq < sequence or stamp < first:
                self._count('frames_lost')
        return fresh

    def _publish(self, window, problem, XY, Z):
        """FrameResults to publish of a solved ``problem`` (``XY: (F, 2, P)`` centred pixels,
        ``Z: (F, P)`` centred depth): its window's frames not published before
        ('first_window'), or those :meth:`_publish_latest` releases ('last_window')."""
        if self.publish_after > 1:
            return self._publish_latest(window, problem, XY, Z)
        c = problem.n_context
        fresh = [c + i for i in self._fresh(window.sequence, problem.stamps[c:])]
        out = [self._result(problem, i, XY, Z) for i in fresh]
        self._count('published', len(out))
        return out

    def _publish_latest(self, window, problem, XY, Z):
        """'last_window': note this solve's shapes of every unpublished frame of ``problem``
        (None: no solve) as the frame's latest, then publish, in stamp order and each from
        its latest solve, the unpublished frames up to the newest that is due: solved
        ``publish_after`` times, or not reconstructed by this solve (it left the solves:
        dropped context, a skipped window), or any (``window.final``)."""
        done = self._published_until.get(window.sequence)
        if self._latest[0] != window.sequence:
            self._latest = (window.sequence, {})
        latest = self._latest[1]
        solved = set()
        stamps = () if problem is None else problem.stamps
        for i, stamp in enumerate(int(s) for s in stamps):      # frames, not points
            if done is None or stamp > done:
                solves = latest[stamp][1] + 1 if stamp in latest else 1
                latest[stamp] = (self._result(problem, i, XY, Z), solves)
                solved.add(stamp)
        due = [s for s, (_, n) in latest.items()
               if window.final or n >= self.publish_after or s not in solved]
        if not due:
            return []
        order = sorted(s for s in latest if s <= max(due))
        out = [latest.pop(order[i])[0] for i in self._fresh(window.sequence, order)]
        self._count('published', len(out))
        return out

    def _result(self, problem, i, XY, Z):
        """The FrameResult of ``problem``'s frame ``i``."""
        xyz = np.empty((problem.ids.size, 3))
        xyz[:, :2] = XY[i].T
        xyz[:, 2] = Z[i]
        return FrameResult(int(problem.stamps[i]), problem.frame_ids[i], problem.ids,
                           xyz * self.metres_per_pixel)

    def _overlap(self, problem):
        """Indices ``(frames_new, frames_old, tracks_new, tracks_old)`` shared with the previous
        solution, or None when it belongs to another sequence or shares too little."""
        p = self._previous
        if p is None or p.sequence != problem.sequence:
            return None
        _, fn, fo = np.intersect1d(problem.stamps, p.stamps, return_indices=True)
        _, tn, to = np.intersect1d(problem.ids, p.ids, assume_unique=True, return_indices=True)
        if fn.size == 0 or tn.size < self.min_tracks:
            return None
        return fn, fo, tn, to

    def _depth_disagrees(self, problem, Z):
        """True if depth ``Z: (F, P)`` (centred per frame) correlates negatively with the
        previous window's depth on the overlapping frames and tracks."""
        ov = self._overlap(problem)
        if ov is None:
            return False
        fn, fo, tn, to = ov
        new = Z[np.ix_(fn, tn)]
        old = as_frames(self._previous.S, 3)[:, 2, :][np.ix_(fo, to)]
        new = new - new.mean(axis=1, keepdims=True)
        old = old - old.mean(axis=1, keepdims=True)
        return float(np.sum(new * old)) < 0.0

    def _start_for(self, problem, Wc):
        """The solver's ``init`` for ``problem`` (centred tracks ``Wc: (2F, P)``), or None.

        A problem without context frames (the first window of a sequence, or
        ``context_frames`` 0) starts from the rigid factorisation unless ``warm_start`` is
        'full' and it overlaps the previous solution; otherwise 'off' gives None (the solver's
        own start), 'model' the previous solution's spatial groups and rotation method, 'full'
        its rotations and shapes too (:meth:`_full_warm_start`), 'resume' those refined
        (:meth:`_resume_start`)."""
        cls = self._warm_start_class or WarmStart
        ov = self._overlap(problem)
        self._resumed_rank = None
        if self.warm_start == 'resume' and self._resumable(problem, ov):
            return self._resume_start(problem, Wc, ov, cls)
        if self.warm_start == 'full' and ov is not None:
            return self._full_warm_start(problem, Wc, ov, cls)
        if not problem.n_context or self.warm_start == 'full':
            return self._rigid_start(problem.W, cls)
        if self.warm_start == 'off':
            return None
        groups = None
        if ov is not None and self._previous.groups is not None:
            groups = np.asarray(self._previous.groups)[self._donors(problem, ov)]
        return cls(groups=groups, rotation_method=self._carried_rotation_method(problem))

    def _schedule_for(self, solver, problem, init):
        """``solver``, stopping at its ``resumed_beta_max`` where ``problem`` is a window with
        context under 'resume' that does not resume its predecessor (the second window of a
        sequence: the first is a rigid start, docs/decisions/archive/0415), its rotation check's
        solves included: they reach the same shapes by then (docs/decisions/0425). Solvers without
        that parameter keep their own schedule."""
        params = solver.get_params() if hasattr(solver, 'set_params') else {}
        if (self.warm_start == 'resume' and problem.n_context and 'resumed_beta_max' in params
                and not getattr(init, 'resumed', False)):
            solver.set_params(beta_max=min(params['beta_max'], params['resumed_beta_max']))
        return solver

    def _resumable(self, problem, ov):
        """True if ``problem`` (with context) can resume the previous solution's run."""
        p = self._previous
        return ov is not None and problem.n_context > 0 and p.K_rot is not None

    def _resume_start(self, problem, Wc, ov, cls):
        """WarmStart resuming from the previous solution (warm_start 'resume'): rotations by
        Dai's method refined from the previous ones (:meth:`_resume_rotations`), shapes and
        spatial groups as :meth:`_full_warm_start` carries them, solved as a cold solve from
        them (``resumed``; docs/decisions/0404)."""
        fn = ov[0]
        known = np.zeros(len(problem.stamps), dtype=bool)
        known[fn] = True
        start = self._full_warm_start(problem, Wc, ov, cls)
        R, self._resumed_rank = self._resume_rotations(problem.W, np.asarray(start.R), known,
                                                       self._previous.K_rot)
        return replace(start, R=R, known=np.ones(known.size, dtype=bool), resumed=True)

    @staticmethod
    def _resume_rotations(W, R0, known, K):
        """``(R: (F, 3, 3), K)``: Dai's rotations of ``W`` refined from ``R0`` on the ``known``
        frames (:func:`rotations_from_start`) at ranks K - 1, K, K + 1 within Dai's candidates
        (K = 1, rigid: that rank only), the rank chosen among them by :func:`choose_rank`;
        ``(R0, K)`` where every rank fails."""
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

    def _carried_rotation_method(self, problem):
        """The rotation method of the solver's last check in this sequence if that check saw
        full context (``context_frames`` earlier frames: while the solves still grow, each one
        checks) and fewer than RECHECK_SHARE of its frames are new in ``problem``; else None
        (the solver checks again). Checked during growth, bending 60 x 400 streamed 0.171;
        carried from the 40-frame check to the 50-frame solve, 0.189."""
        if self._rotation_check is None:
            return None
        sequence, method, stamps = self._rotation_check
        if sequence != problem.sequence:
            return None
        new = np.setdiff1d(problem.stamps, stamps, assume_unique=True).size
        return method if new < RECHECK_SHARE * stamps.size else None

    def _donors(self, problem, ov):
        """For each track of ``problem``, the index of a track of the previous solution: the
        same track where shared, else the nearest shared track in the image of the first
        shared frame. ``(P,)`` int."""
        fn, fo, tn, to = ov
        p = self._previous
        F, P = len(problem.stamps), problem.ids.size
        donor = np.full(P, -1)
        donor[tn] = to
        missing = donor < 0
        if missing.any():
            tree = cKDTree(p.uv[fo[0]][to])
            new_uv = problem.W.reshape(F, 2, P)[fn[0]].T[missing]     # pixels, same frame
            donor[missing] = to[tree.query(new_uv)[1]]
        return donor

    def _full_warm_start(self, problem, Wc, ov, cls):
        """WarmStart from the previous solution on the overlap ``ov``: rotations fixed on the
        shared frames, camera-frame shapes and spatial groups carried (new frames copy the
        nearest shared frame's rotation and depth, new tracks their donor's depth and group)."""
        fn, fo, tn, to = ov
        p = self._previous
        F, P = len(problem.stamps), problem.ids.size
        # every new frame copies the nearest shared frame (in time): rotation and depth
        nearest = fn[np.clip(np.searchsorted(fn, np.arange(F)), 0, fn.size - 1)]
        source = fo[np.searchsorted(fn, nearest)]
        R = p.R[source]
        donor = self._donors(problem, ov)
        Zold = as_frames(p.S, 3)[:, 2, :]
        Z = Zold[source][:, donor]
        Z -= Z.mean(axis=1, keepdims=True)
        S = np.empty((F, 3, P))
        S[:, :2, :] = as_frames(Wc, 2)
        S[:, 2, :] = Z
        known = np.zeros(F, dtype=bool)
        known[fn] = True
        R = self._warm_rotations(Wc, R, as_frames(p.S, 3)[source][:, :, donor], known)
        if self.warm_rotations != 'solver':
            known[:] = True
        groups = None if p.groups is None else np.asarray(p.groups)[donor]
        return cls(R=R, S=S.reshape(3 * F, P), known=known, groups=groups)

    def _warm_rotations(self, Wc, R, S, known):
        """Rotations ``(F, 3, 3)`` of the warm start. ``R``: the previous solution's on known
        frames, the nearest known frame's elsewhere; ``S: (F, 3, P)``: the camera-frame shape
        of the frame each rotation came from.
        'solver': as given (the solver estimates the unknown ones); 'fit': each unknown frame
        fitted to its tracks against the world shape of its source frame; 'refine': Dai's
        rotations over all frames, aligned to the known ones by one world rotation."""
        if self.warm_rotations == 'solver' or known.all():
            return R
        if self.warm_rotations == 'fit':
            S = S - S.mean(axis=2, keepdims=True)
            X = R.transpose(0, 2, 1) @ S                     # world shapes of the source frames
            M = as_frames(Wc, 2) @ np.linalg.pinv(X)         # (F, 2, 3) camera rows
            fitted, ok = rotations_from_rows(M)
            out = R.copy()
            use = ~known & ok
            out[use] = fitted[use]
            return out
        est = estimate_rotations(Wc).R
        probe = np.concatenate([est, np.eye(3)[None]])     # the last row yields the global Q
        aligned = align_rotations(probe, np.concatenate([R, np.eye(3)[None]]),
                                  np.append(known, False))
        Q = aligned[-1]                     # D I D = I: the probe is Q for either twin
        twins = (est @ Q, DEPTH_FLIP @ est @ DEPTH_FLIP @ Q)
        return min(twins, key=lambda t: np.linalg.norm(t[known] - R[known]))

    @staticmethod
    def _rigid_start(W, cls):
        """WarmStart of a problem with no previous solution: the rigid factorisation's rotations
        and camera-frame shape for every frame."""
        R, S = rigid_factorisation(W)
        return cls(R=R, S=S, known=np.ones(W.shape[0] // 2, dtype=bool), groups=None)

    def _count(self, key, n=1):
        with self._lock:
            self.stats[key] += n

    @property
    def pending_frames(self):
        """Accepted frames neither published nor counted lost yet: buffered for a window that
        has not closed, or in a window not yet solved. At any time ``stats['frames'] ==
        stats['published'] + stats['frames_lost'] + pending_frames``."""
        frames = list(self._frames)
        waiting = sum(1 for f in frames
                      if self._emitted_until is None or f.stamp_ns > self._emitted_until)
        return len(self._unpublished) + waiting

    @property
    def previous(self):
        """The last solved window's Solution (its ``report`` holds the solver's report)."""
        return self._previous


def window_matrix(frames, ids):
    """``W: (2F, P)`` pixels of the tracks ``ids: (P,)`` (in every one of ``frames``)."""
    uv = np.stack([f.uv if f.ids.size == ids.size else
                   f.uv[np.searchsorted(f.ids, ids)] for f in frames])    # (F, P, 2)
    return uv.transpose(0, 2, 1).reshape(2 * len(frames), ids.size)


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


def reconstruct_sequence(pipeline, stamps, frames, frame_id=''):
    """Run ``pipeline`` over a whole sequence offline (no skipping) and return its FrameResults
    in stamp order. ``frames``: iterable of ``(ids: (P,), uv: (P, 2))``, one per stamp."""
    results = []
    for stamp, (ids, uv) in zip(stamps, frames):
        for window in pipeline.add_frame(stamp, ids, uv, frame_id):
            results += pipeline.solve(window)
    for window in pipeline.flush():
        results += pipeline.solve(window)
    return results
