"""Windowing (the tracking thread's side of the live flow): frames in, closed Windows out.

It owns validation of a frame, sequences (a change of almost all track ids starts one), the
buffer ordered by stamp, windows, context and key frames. Pure Python and numpy: no ROS.

Shapes: a :class:`Frame` holds ``ids: (P,) uint32`` (sorted) and ``uv: (P, 2)`` pixels; a
:class:`Window` holds its own Frames, the ``ids: (P,)`` it is solved on, its ``context``
Frames and, as a property, ``W: (2F, P)``.

Policies:

* **Order.** Frames are buffered by stamp: a frame arriving out of order is inserted where it
  belongs while its window has not closed; a frame not newer than the newest frame of a closed
  window is refused as late (:class:`FrameError`), a second frame with a buffered stamp as a
  duplicate.
* **Windows.** Every ``window_stride`` frames (the first time after ``window_size``) a Window of
  the newest ``window_size`` buffered frames closes. It also carries up to ``context_frames``
  earlier frames and ``key_frames`` older ones spread evenly over the sequence
  (docs/decisions/0035, 0036). ``push(frame, close_early=True)`` closes the next window as soon
  as more than ``window_size - window_stride`` frames wait.
* **Preview.** Once a sequence has buffered ``first_model_frames`` frames (at least
  MIN_WINDOW_FRAMES, fewer than ``window_size``) and before its first window, a preview
  Window of them goes out: solved for a first model only (docs/decisions/0444). It moves no
  frame and counts as no window.
* **Tracks.** A window is solved on the tracks seen in WINDOW_TRACK_SHARE of its own frames;
  where a frame does not see one, its W holds NaN (docs/decisions/0432).
* **All ids change** (a new tracker session): a frame sharing fewer than ``min_tracks`` ids
  with the newest buffered frame starts a new *sequence*. The old buffer's frames that were in
  no window go out in one last window (``final``), and no state crosses the boundary.

What the mapping needs from the tracking side travels inside the frames: ``Frame.depth``, the
depth published for the frame (a solve that shares no frame with the mapping's previous one, as
a sequence's first, takes that orientation).
"""
from bisect import bisect_left
from collections import deque
from dataclasses import dataclass
from functools import reduce
import time

import numpy as np

from grass_nrsfm_ros import params
from grass_nrsfm_ros.cloud import strictly_increasing
from grass_nrsfm_ros.params import MIN_WINDOW_FRAMES


#: a window is solved on the tracks seen in at least this share of its own frames
#: (docs/decisions/0432); the others' entries are NaN in its W
WINDOW_TRACK_SHARE = 0.8


class FrameError(ValueError):
    """A frame that was refused (the message says why); the windowing state is unchanged."""


@dataclass(frozen=True)
class Frame:
    """One accepted frame: ``ids: (P,) uint32`` sorted, ``uv: (P, 2)`` pixels in the same order,
    the ``sequence`` it belongs to; ``depth``: ``(ids: (Q,), z: (Q,))`` published for it (None:
    not known); ``pinhole``: ``uv`` are normalised coordinates ``K^-1 [u v 1]`` of a pinhole
    camera, not pixels."""

    stamp_ns: int
    frame_id: str
    ids: np.ndarray
    uv: np.ndarray
    sequence: int = 0
    depth: tuple = None
    pinhole: bool = False


@dataclass(frozen=True)
class Window:
    """A closed window: its own ``frames`` (ascending stamps) on the ``ids: (P,)`` seen in
    WINDOW_TRACK_SHARE of them; ``context``: earlier Frames of its sequence solved with it
    (oldest first: key frames,
    then the newest ``context_frames``); ``closed_at``: ``time.monotonic()`` when it closed;
    ``fresh``: stamps of its frames in no earlier window; ``final``: the last window of its
    sequence; ``preview``: a sequence's first frames, solved for a model only (``index``: the
    next window's, ``fresh`` empty)."""

    sequence: int
    index: int
    frames: tuple
    ids: np.ndarray
    closed_at: float
    context: tuple = ()
    fresh: tuple = ()
    final: bool = False
    preview: bool = False

    @property
    def stamps(self):
        """``(F,)`` int64 stamps of the window's own frames."""
        return np.array([f.stamp_ns for f in self.frames], dtype=np.int64)

    @property
    def frame_ids(self):
        return tuple(f.frame_id for f in self.frames)

    @property
    def n_frames(self):
        return len(self.frames)

    @property
    def W(self):
        """``(2F, P)`` pixels of its tracks over the window's own frames, NaN where not seen."""
        return window_matrix(self.frames, self.ids)


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


def common_ids(a, b):
    """The ids in both sorted unique id arrays ``a`` and ``b`` (``a`` itself when they are equal:
    the usual case, with no set operation)."""
    return a if np.array_equal(a, b) else np.intersect1d(a, b, assume_unique=True)


def ids_in_every(frames):
    """The sorted ids of the tracks every one of ``frames`` (Frames, or FrameResults: anything
    with sorted ``ids``) has."""
    return reduce(common_ids, (f.ids for f in frames[1:]), frames[0].ids)


def window_matrix(frames, ids):
    """``W: (2F, P)`` pixels of the tracks ``ids: (P,)`` (sorted) over ``frames``; NaN where a
    frame does not have a track."""
    return np.stack([frame_uv(f, ids) for f in frames]).transpose(0, 2, 1).reshape(
        2 * len(frames), ids.size)


def frame_uv(frame, ids):
    """``(P, 2)`` pixels of the tracks ``ids: (P,)`` (sorted) in ``frame``, NaN where it does not
    have them."""
    if frame.ids.size == ids.size and np.array_equal(frame.ids, ids):
        return frame.uv
    at = np.minimum(np.searchsorted(frame.ids, ids), frame.ids.size - 1)
    return np.where((frame.ids[at] == ids)[:, None], frame.uv[at], np.nan)


def tracks_seen(frames, share):
    """The sorted ids seen in at least ``share`` of ``frames`` (and in two of them): all their
    ids when the frames share one id set."""
    first = frames[0].ids
    if all(np.array_equal(f.ids, first) for f in frames[1:]):
        return first
    ids, counts = np.unique(np.concatenate([f.ids for f in frames]), return_counts=True)
    return ids[counts >= max(2, int(np.ceil(share * len(frames) - 1e-9)))]


class Windowing:
    """Frames in (:meth:`accept`, then :meth:`push`), Windows out; see the module docstring.

    ``stats``: ``frames`` accepted, ``refused``, ``resets`` (sequences started after the
    first), ``windows`` closed, ``previews`` sent, ``frames_dropped`` (accepted, then
    dropped before any window: too few frames at the end of a sequence, or a reset).
    """

    def __init__(self, *, window_size=30, window_stride=10, min_tracks=10, context_frames=60,
                 key_frames=30, first_model_frames=0):
        params.check_window(window_size=window_size, window_stride=window_stride,
                            min_tracks=min_tracks, context_frames=context_frames,
                            key_frames=key_frames, first_model_frames=first_model_frames)
        self.window_size, self.window_stride = int(window_size), int(window_stride)
        self.min_tracks, self.context_frames = int(min_tracks), int(context_frames)
        self.key_frames = int(key_frames) if self.context_frames else 0
        self.first_model_frames = int(first_model_frames)
        self.sequence = 0
        self._frames = []               # buffered Frames, ascending stamps
        self._history = deque(maxlen=max(self.context_frames, 1))   # Frames that left _frames
        self._keys = KeyFrames(self.key_frames)     # older Frames, thinned evenly
        self._index = 0                 # of the next window
        self._emitted_until = None      # newest stamp of the last closed window
        self._close_early = False
        self.stats = dict(frames=0, refused=0, resets=0, windows=0, previews=0,
                          frames_dropped=0)

    # -- frames in ------------------------------------------------------------------------------
    def accept(self, stamp_ns, ids, uv, frame_id=''):
        """Validate one frame: the :class:`Frame` (copies, ids sorted; ``sequence`` one more than
        the current one when it starts a new sequence). Raises FrameError (counted refused)."""
        ids, uv = np.asarray(ids), np.asarray(uv, dtype=np.float64)
        try:
            if ids.ndim != 1 or uv.shape != (ids.size, 2):
                raise FrameError(f'ids {ids.shape} and uv {uv.shape} do not match (P,), (P, 2)')
            if ids.size < self.min_tracks:
                raise FrameError(f'{ids.size} tracks; at least min_tracks={self.min_tracks} '
                                 'needed')
            if not np.isfinite(uv).all():
                raise FrameError(f'{int((~np.isfinite(uv)).any(axis=1).sum())} tracks with '
                                 'non-finite u/v')
            order = slice(None) if strictly_increasing(ids) else np.argsort(ids, kind='stable')
            ids, uv = ids[order].astype(np.uint32), uv[order].copy()
            if (ids[1:] == ids[:-1]).any():
                raise FrameError(f'duplicate track id {int(ids[1:][ids[1:] == ids[:-1]][0])}')
            new_sequence = bool(self._frames) and \
                common_ids(ids, self._frames[-1].ids).size < self.min_tracks
            if not new_sequence:                # a new sequence's stamps start afresh
                self._check_stamp(int(stamp_ns))
        except FrameError:
            self.stats['refused'] += 1
            raise
        return Frame(int(stamp_ns), str(frame_id), ids, uv, self.sequence + new_sequence)

    def push(self, frame, close_early=False, waiting=False):
        """Buffer an accepted ``frame``; return the Windows it closes (usually none; the last
        window of the old sequence first when it starts a new one, see :meth:`flush` for
        ``waiting``). ``close_early``: close the next window as soon as it can (the model no
        longer explains the frames)."""
        windows = []
        if frame.sequence != self.sequence:
            windows += self.flush(waiting)
            self._start_sequence(frame.sequence)
        self._close_early = self._close_early or close_early
        stamps = [f.stamp_ns for f in self._frames]
        self._frames.insert(bisect_left(stamps, frame.stamp_ns), frame)
        self.stats['frames'] += 1
        if self._emitted_until is None and len(self._frames) == self.first_model_frames \
                and MIN_WINDOW_FRAMES <= self.first_model_frames < self.window_size:
            windows.append(self._preview())
        kept = self.window_size - self.window_stride     # frames a window leaves buffered
        early = self._close_early and len(self._frames) > max(kept, MIN_WINDOW_FRAMES - 1)
        if len(self._frames) >= self.window_size or early:
            self._close_early = False
            windows.append(self._emit(self._frames[:self.window_size]))
            leaving = self._frames[:len(self._frames) - kept]
            spill = len(self._history) + len(leaving) - self._history.maxlen
            if self.context_frames and spill > 0:
                self._keys.extend((list(self._history) + leaving)[:spill])
            self._history.extend(leaving)
            self._frames = self._frames[len(leaving):]
        return windows

    def flush(self, waiting=False):
        """The last window of the sequence (end of a sequence or of a bag), over the newest
        buffered frames, if any of them was in no window or (``waiting``) frames of closed
        windows still wait to go out (the mapping releases them); ``[]`` otherwise, and with
        fewer than MIN_WINDOW_FRAMES frames (the new ones counted dropped)."""
        frames = self._frames[-self.window_size:]
        fresh = self._fresh(frames)
        if not (fresh or waiting) or len(frames) < MIN_WINDOW_FRAMES:
            self.stats['frames_dropped'] += len(fresh)
            if fresh:                           # given up: not dropped twice
                self._emitted_until = fresh[-1].stamp_ns
            return []
        return [self._emit(frames, final=True)]

    def reset(self):
        """Drop the buffered frames (those in no window counted dropped); the next frame starts
        a new sequence. Returns the number of frames dropped."""
        dropped = len(self._fresh(self._frames))
        self.stats['frames_dropped'] += dropped
        self._start_sequence(self.sequence + 1)
        return dropped

    @property
    def buffered_fresh(self):
        """Frames buffered and in no window yet."""
        return len(self._fresh(self._frames))

    # -- internals ------------------------------------------------------------------------------
    def _start_sequence(self, sequence):
        self._frames = []
        self._history.clear()
        self._keys = KeyFrames(self.key_frames)
        self.sequence = sequence
        self._emitted_until = None              # a new sequence's stamps may start earlier
        self._close_early = False
        self.stats['resets'] += 1

    def _fresh(self, frames):
        return [f for f in frames if self._emitted_until is None
                or f.stamp_ns > self._emitted_until]

    def _check_stamp(self, stamp_ns):
        """Raise FrameError for a stamp that is late (not newer than the last closed window) or
        a duplicate of a buffered frame's."""
        if self._emitted_until is not None and stamp_ns <= self._emitted_until:
            raise FrameError(f'late frame: stamp {stamp_ns} is not newer than the last '
                             f'emitted window ({self._emitted_until})')
        if any(f.stamp_ns == stamp_ns for f in self._frames):
            raise FrameError(f'duplicate stamp {stamp_ns} (the first frame is kept)')

    def _preview(self):
        """The preview Window of the buffered frames (see the module docstring)."""
        frames = tuple(self._frames)
        self.stats['previews'] += 1
        return Window(self.sequence, self._index, frames, tracks_seen(frames, WINDOW_TRACK_SHARE),
                      time.monotonic(), preview=True)

    def _emit(self, frames, final=False):
        common = tracks_seen(frames, WINDOW_TRACK_SHARE)
        fresh = tuple(f.stamp_ns for f in self._fresh(frames))
        self._emitted_until = int(frames[-1].stamp_ns)
        first = frames[0].stamp_ns
        context = tuple(f for f in self._keys.frames + list(self._history)
                        if f.stamp_ns < first) if self.context_frames else ()
        window = Window(self.sequence, self._index, tuple(frames), common, time.monotonic(),
                        context, fresh, final)
        self._index += 1
        self.stats['windows'] += 1
        return window
