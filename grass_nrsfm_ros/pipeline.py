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

Camera intrinsics (:meth:`LivePipeline.set_camera`, ``K: (3, 3)``): each frame's pixels become
normalised coordinates ``K^-1 [u, v, 1]`` on arrival, the rooms behind work on those, and each
FrameResult goes out through the pinhole (:func:`pinhole_points`): depth ``Z = scene_depth (1 +
s z)`` from the reconstruction's centred depth ``z`` (normalised units), ``X, Y = Z x, Z y``, so
``K [X/Z, Y/Z, 1]`` is the frame's pixels and each frame's mean depth is ``scene_depth``. The
depth sign ``s`` (an orthographic solve's is arbitrary) is chosen once per sequence, from the
frames of its first solved window (:func:`~grass_nrsfm_ros.nrsfm.perspective.low_rank_sign`);
later windows keep the sign of the earlier ones, so it holds (frames before it: ``s = 1``).
Results from a pinhole sheet's model (``signed``) carry their own sign: ``s`` is not applied.
Without ``K`` the pixels are solved as orthographic projections (warned once).

Shapes: ``ids: (P,)`` track ids, ``uv: (P, 2)`` pixels; a FrameResult's ``xyz: (P, 3)`` in the
camera frame: pinhole as above with ``K``, else times ``metres_per_pixel``.
"""
from collections import deque, OrderedDict
from dataclasses import replace
import threading
import time

import numpy as np

from grass_nrsfm_ros import params
from grass_nrsfm_ros.backends import InlineBackend, ProcessBackend
from grass_nrsfm_ros.mapper import make_mapper, refined_after_of
from grass_nrsfm_ros.nrsfm.camera import validate_intrinsics, warn_orthographic
from grass_nrsfm_ros.nrsfm.perspective import flat_depths, low_rank_sign, MIN_RELATIVE_DEPTH
from grass_nrsfm_ros.refinement import Refinement
from grass_nrsfm_ros.shape_tracking import ShapeTracking
from grass_nrsfm_ros.windowing import FrameError, ids_in_every, Windowing

#: tracking latencies kept for the percentiles
LATENCY_WINDOW = 300
#: with K: frames whose normalised points are kept for the output (a frame's are dropped once
#: it is refined; this bounds frames never refined)
RAYS_KEPT = 1000
#: with K: fewest frames of a sequence's first solved window that decide its depth sign
SIGN_FRAMES = 10


def pinhole_points(xyz, rays, scene_depth=1.0):
    """``(P, 3)`` camera-frame points through the pinhole: ``Z = scene_depth * (1 + z)`` (at
    least MIN_RELATIVE_DEPTH of it), ``X, Y = Z * rays``, from a reconstruction ``xyz: (P, 3)``
    of normalised points (``z``: depth relative to the frame's centroid, normalised units)
    and the points' normalised coordinates ``rays: (P, 2)``."""
    Z = scene_depth * np.maximum(1.0 + xyz[:, 2], MIN_RELATIVE_DEPTH)
    return np.column_stack([rays * Z[:, None], Z])


class LivePipeline:
    """See the module docstring. :meth:`add_frame` and :meth:`flush` on the tracking thread;
    :meth:`refined` wherever the backend's updates are read (the same thread inline, the
    receiver thread of a ProcessBackend).

    ``add_frame`` raises :class:`~grass_nrsfm_ros.windowing.FrameError` for a refused frame.
    """

    def __init__(self, windowing, tracking, refinement, backend, *, metres_per_pixel=1.0,
                 camera=None, scene_depth=1.0, projection='auto'):
        self.windowing, self.tracking = windowing, tracking
        self.refinement, self.backend = refinement, backend
        self.metres_per_pixel = float(metres_per_pixel)
        self.scene_depth, self.projection = float(scene_depth), projection
        self.camera = None if camera is None else validate_intrinsics(camera)
        self.tracking.depth_sign = None if self.camera is None else low_rank_sign
        self._rays = OrderedDict()      # with K: stamp -> (ids, normalised uv, sequence)
        self._signs = {}                # with K: sequence -> its depth sign, once chosen
        self.orthographic_warning = warn_orthographic      # pixels without K: said once
        self._said_orthographic = False
        self.latencies = deque(maxlen=LATENCY_WINDOW)
        self._surprised = False         # the last frame asked for a fresh window
        self._lock = threading.Lock()   # the refinement: tracking and publishing threads

    def add_frame(self, stamp_ns, ids, uv, frame_id=''):
        """Track one frame and hand it on: ``(FrameResult,)`` to publish on ``points``."""
        started = time.perf_counter()
        frame = self._normalised(self.windowing.accept(stamp_ns, ids, uv, frame_id))
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

    def set_camera(self, K):
        """Use intrinsics ``K: (3, 3)`` (None: none) from the next frame on. A change of
        intrinsics starts a new sequence (:meth:`reset`); returns True where it did."""
        K = None if K is None else validate_intrinsics(K)
        same = (K is None and self.camera is None) or (
            K is not None and self.camera is not None and np.allclose(K, self.camera,
                                                                      rtol=1e-9, atol=0.0))
        if same:
            return False
        self.camera = K
        self.tracking.depth_sign = None if K is None else low_rank_sign
        self.reset()
        return True

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
                self.tracking.offer(update.sequence, update.model, update.sheet)
            if self.camera is not None and update.sequence not in self._signs:
                self._choose_sign(update)
            with self._lock:
                out += [self._scaled(r, refined=True) for r in self.refinement.take(update)]
        return out, updates

    def reset(self):
        """Drop the buffered frames, the windows waiting and the model; the next frame starts
        a new sequence. Returns ``{'frames': buffered frames dropped, 'model': whether there
        was one}``."""
        frames = self.windowing.reset()
        self._rays.clear()
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
            if not window.preview:
                with self._lock:
                    self.refinement.expect(window)
            self.backend.submit(window)

    def _normalised(self, frame):
        """The accepted ``frame`` in normalised coordinates (its rays kept for the output) with
        ``K``; as it is without (warned once), or refused where the solver's projection is
        'perspective' (it needs ``K``)."""
        if self.camera is None:
            if self.projection == 'perspective':
                raise FrameError("solver.projection 'perspective' needs camera intrinsics (the "
                                 'camera parameter or a camera_info topic); none yet')
            if not self._said_orthographic:
                self._said_orthographic = True
                self.orthographic_warning()
            return frame
        K = self.camera
        y = (frame.uv[:, 1] - K[1, 2]) / K[1, 1]
        x = (frame.uv[:, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
        frame = replace(frame, uv=np.column_stack([x, y]), pinhole=True)
        self._rays[frame.stamp_ns] = (frame.ids, frame.uv, frame.sequence)
        while len(self._rays) > RAYS_KEPT:
            self._rays.popitem(last=False)
        return frame

    def _scaled(self, result, refined=False):
        """``result`` in output units: through the pinhole (:func:`pinhole_points`) where its
        frame came with ``K``, else times ``metres_per_pixel``."""
        rays = self._rays.get(result.stamp_ns)
        if rays is None:
            return replace(result, xyz=result.xyz * self.metres_per_pixel)
        if refined:
            self._rays.pop(result.stamp_ns)
        ids, uv, sequence = rays
        at = np.searchsorted(ids, result.ids)
        sign = 1.0 if result.signed else self._signs.get(sequence, 1.0)
        xyz = result.xyz * [1.0, 1.0, sign]
        return replace(result, xyz=pinhole_points(xyz, uv[at], self.scene_depth))

    def _choose_sign(self, update):
        """The depth sign of ``update``'s sequence, once: from the frames of its first solved
        window with K whose depths are not flat (:func:`flat_depths`: the next window decides
        then), by :func:`low_rank_sign` on their common tracks; never from a sheet model's
        results (``signed``)."""
        frames = [(r, self._rays[r.stamp_ns]) for r in update.results
                  if r.stamp_ns in self._rays and self._rays[r.stamp_ns][2] == update.sequence
                  and not r.signed]
        if len(frames) < SIGN_FRAMES:
            return
        common = ids_in_every([r for r, _ in frames])
        if common.size < 4:
            return
        x, delta = [], []
        for r, (ids, uv, _) in frames:
            x.append(uv[np.searchsorted(ids, common)].T)
            delta.append(r.xyz[np.searchsorted(r.ids, common), 2])
        x, delta = np.vstack(x), np.stack(delta)
        if not flat_depths(delta, x):
            self._signs[update.sequence] = low_rank_sign(x, delta)


def make_pipeline(config, solver_factory=None, *, mapping='inline', notify=None, on_exit=None,
                  blas_threads=1, camera=None):
    """The LivePipeline ``config`` describes (parameters as from
    :func:`grass_nrsfm_ros.params.load_config` or the node; absent keys take their defaults),
    its windows solved ``mapping`` 'inline' or in a 'process' (``notify``, ``on_exit``,
    ``blas_threads``: see :class:`~grass_nrsfm_ros.backends.ProcessBackend`).
    ``solver_factory`` replaces ``GrassmannNRSfM(**solver parameters)``. Intrinsics:
    ``camera`` (``K: (3, 3)``), else the ``camera`` parameter ([fx, fy, cx, cy] or []), else
    none (:meth:`LivePipeline.set_camera` sets them later). The windows are solved with the
    solver's ``projection``: 'auto' solves orthographically (on the normalised points with
    ``K``; the depth correction through the pinhole applies to every frame); 'perspective'
    runs the projective-depth iteration in every window (docs/decisions/0703). An unknown
    parameter or a bad value raises ValueError (:func:`~grass_nrsfm_ros.params.with_defaults`)."""
    config = params.with_defaults(config)
    if camera is None and config['camera']:
        camera = params.camera_matrix(config['camera'])
    if mapping == 'process':
        backend = ProcessBackend(config, solver_factory, notify=notify, on_exit=on_exit,
                                 blas_threads=blas_threads)
    else:
        backend = InlineBackend(make_mapper(config, solver_factory), notify=notify)
    return LivePipeline(Windowing(**{k: config[k] for k in params.WINDOW_KEYS}),
                        ShapeTracking(config['residual_limit']),
                        Refinement(refined_after_of(config)), backend,
                        metres_per_pixel=config['metres_per_pixel'], camera=camera,
                        scene_depth=config['scene_depth'],
                        projection=config['solver.projection'])


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
