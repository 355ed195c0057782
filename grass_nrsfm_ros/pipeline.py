"""The live pipeline: every frame reconstructed on arrival, windows refining it behind.

One pipeline for the node, ``grass-nrsfm reconstruct BAG``, the demo, the bench and the tests.
It wires the rooms, each passing a frame on once:

    add_frame -> Windowing.accept -> ShapeTracking.track -> points
                                  -> Windowing.push -> Window -> backend (Mapper.solve)
    refined()  <- backend.updates() -> Update: model -> ShapeTracking.offer
                                                -> Refinement.take -> points/refined

:mod:`~grass_nrsfm_ros.windowing` (frames, sequences, windows), :mod:`~grass_nrsfm_ros.
shape_tracking` (each frame fitted to the newest model), :mod:`~grass_nrsfm_ros.backends` (where
the :mod:`~grass_nrsfm_ros.mapper` solves), :mod:`~grass_nrsfm_ros.refinement` (what goes out on
``points/refined``). Pure Python and numpy: no ROS.

Shapes: ``ids: (P,)`` track ids, ``uv: (P, 2)`` pixels; a FrameResult's ``xyz: (P, 3)`` in the
camera frame times ``metres_per_pixel``.
"""
from collections import deque
from dataclasses import replace
import threading
import time

import numpy as np

from grass_nrsfm_ros import params
from grass_nrsfm_ros.backends import InlineBackend, ProcessBackend
from grass_nrsfm_ros.mapper import make_mapper, refined_after_of
from grass_nrsfm_ros.refinement import Refinement
from grass_nrsfm_ros.shape_tracking import ShapeTracking
from grass_nrsfm_ros.windowing import Windowing

#: tracking latencies kept for the percentiles
LATENCY_WINDOW = 300


class LivePipeline:
    """See the module docstring. :meth:`add_frame` and :meth:`flush` on the tracking thread;
    :meth:`refined` wherever the backend's updates are read (the same thread inline, the
    receiver thread of a ProcessBackend).

    ``add_frame`` raises :class:`~grass_nrsfm_ros.windowing.FrameError` for a refused frame.
    """

    def __init__(self, windowing, tracking, refinement, backend, *, metres_per_pixel=1.0):
        self.windowing, self.tracking = windowing, tracking
        self.refinement, self.backend = refinement, backend
        self.metres_per_pixel = float(metres_per_pixel)
        self.latencies = deque(maxlen=LATENCY_WINDOW)
        self._surprised = False         # the last frame asked for a fresh window
        self._lock = threading.Lock()   # the refinement: tracking and publishing threads

    def add_frame(self, stamp_ns, ids, uv, frame_id=''):
        """Track one frame and hand it on: ``(FrameResult,)`` to publish on ``points``."""
        started = time.perf_counter()
        frame = self.windowing.accept(stamp_ns, ids, uv, frame_id)
        tracked = self.tracking.track(frame)
        if tracked.depth is not None:
            frame = replace(frame, depth=tracked.depth)
        self.backend.feed(frame)
        with self._lock:
            waiting = self.refinement.waiting(self.windowing.sequence)
        windows = self.windowing.push(frame, close_early=self._surprised, waiting=waiting)
        self._surprised = tracked.surprising
        self.latencies.append(time.perf_counter() - started)   # the tracking, not a solve
        self._submit(windows)
        return (self._scaled(tracked.result),)

    def flush(self):
        """Close the last window of the buffered frames (end of a bag, or a pause)."""
        with self._lock:
            waiting = self.refinement.waiting(self.windowing.sequence)
        self._submit(self.windowing.flush(waiting))

    def refined(self):
        """The backend's Updates taken: each model offered to the tracking; returns
        ``(FrameResults to publish on points/refined, Updates)``."""
        out, updates = [], self.backend.updates()
        for update in updates:
            if update.model is not None:
                self.tracking.offer(update.sequence, update.model)
            with self._lock:
                out += [self._scaled(r) for r in self.refinement.take(update)]
        return out, updates

    def reset(self):
        """Drop the buffered frames, the windows waiting and the model; the next frame starts
        a new sequence. Returns ``{'frames': buffered frames dropped, 'model': whether there
        was one}``."""
        frames = self.windowing.reset()
        had_model = self.tracking.reset()
        self.backend.reset()
        self._surprised = False
        return {'frames': frames, 'model': had_model}

    def close(self):
        self.backend.close()

    @property
    def pending_frames(self):
        """Accepted frames neither refined nor counted lost yet."""
        return self.refinement.pending + self.windowing.buffered_fresh

    @property
    def frames_lost(self):
        """Accepted frames that will never go out on points/refined."""
        return self.refinement.stats['frames_lost'] + self.windowing.stats['frames_dropped']

    def latency_percentiles(self):
        """``(p50, p95)`` seconds of add_frame over the last LATENCY_WINDOW frames, or None."""
        if not self.latencies:
            return None
        return tuple(float(x) for x in np.percentile(self.latencies, [50, 95]))

    def _submit(self, windows):
        for window in windows:
            with self._lock:
                self.refinement.expect(window)
            self.backend.submit(window)

    def _scaled(self, result):
        return replace(result, xyz=result.xyz * self.metres_per_pixel)


def make_pipeline(config, solver_factory=None, *, mapping='inline', notify=None, on_exit=None,
                  blas_threads=1):
    """The LivePipeline ``config`` describes (parameters as from
    :func:`grass_nrsfm_ros.params.load_config` or the node; absent keys take their defaults),
    its windows solved ``mapping`` 'inline' or in a 'process' (``notify``, ``on_exit``,
    ``blas_threads``: see :class:`~grass_nrsfm_ros.backends.ProcessBackend`).
    ``solver_factory`` replaces ``GrassmannNRSfM(**solver parameters)``."""
    config = {**params.defaults(), **config}
    if mapping == 'process':
        backend = ProcessBackend(config, solver_factory, notify=notify, on_exit=on_exit,
                                 blas_threads=blas_threads)
    else:
        backend = InlineBackend(make_mapper(config, solver_factory), notify=notify)
    return LivePipeline(Windowing(**{k: config[k] for k in params.WINDOW_KEYS}),
                        ShapeTracking(config['residual_limit']),
                        Refinement(refined_after_of(config)), backend,
                        metres_per_pixel=config['metres_per_pixel'])


def live_events(pipeline, frames, refuse=()):
    """The offline driver: run ``pipeline`` (inline) over ``frames``, an iterable of
    ``(stamp_ns, ids: (P,), uv: (P, 2), frame_id)``, each window solved as it closes, then the
    last one. Yields ``(kind, item)`` as they happen: ('points', FrameResult), ('refined',
    FrameResult), ('update', Update) and, for a frame raising one of ``refuse`` (others
    propagate), ('refused', (stamp_ns, exception))."""
    for stamp, ids, uv, frame_id in frames:
        try:
            points = pipeline.add_frame(stamp, ids, uv, frame_id)
        except refuse as exc:
            yield 'refused', (stamp, exc)
        else:
            yield from (('points', r) for r in points)
        yield from _taken(pipeline)
    pipeline.flush()
    yield from _taken(pipeline)


def _taken(pipeline):
    refined, updates = pipeline.refined()
    yield from (('update', u) for u in updates)
    yield from (('refined', r) for r in refined)


def reconstruct_live(pipeline, stamps, frames, frame_id=''):
    """:func:`live_events` collected: ``(points, refined, updates)`` in stamp order, for
    ``frames``, an iterable of ``(ids: (P,), uv: (P, 2))``, one per stamp."""
    out = {'points': [], 'refined': [], 'update': []}
    for kind, item in live_events(pipeline, ((stamp, ids, uv, frame_id)
                                             for stamp, (ids, uv) in zip(stamps, frames))):
        out[kind].append(item)
    return out['points'], out['refined'], out['update']
