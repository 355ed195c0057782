"""LivePipeline: every frame reconstructed on arrival, windows refining the model behind it.

The one pipeline object of the node, ``grass-nrsfm reconstruct BAG`` and the demo. Pure Python
and numpy: no ROS import.

* **Tracking** (the caller's thread, every frame): :meth:`LivePipeline.add_frame` fits the
  frame to the newest :class:`~grass_nrsfm_ros.nrsfm.tracking.ShapeModel` and returns its
  :class:`~grass_nrsfm_ros.pipeline.FrameResult` at once (``Step.points``), with the windows
  the frame closed (``Step.windows``). Before a sequence's first model, frames are tracked
  against a bootstrap model grown from the frames so far (:func:`bootstrap_model`).
* **Mapping** (a worker, or synchronously offline): :meth:`LivePipeline.solve` solves a window
  with the :class:`~grass_nrsfm_ros.pipeline.SlidingWindow` (the ADMM, context, key frames,
  warm start) and turns the solution into the next model; the tracker swaps to it at its next
  frame, carrying its rotation through the frames both models share. The window's frames come
  back refined (``Step.refined``: each frame once, as the SlidingWindow publishes them: by
  default from the solve that reconstructs it for the ``window_size / window_stride``-th
  time, ``refined_from``).
* ``output='windows'``: no tracking; ``Step.points`` are the windows' frames as they are
  solved (the sliding-window behaviour, for comparison).

When a frame's tracking residual exceeds ``residual_limit`` times the median of the last
frames', the frame is still published, and the next window is closed early (a fresh model).
Offline, solving each window as it closes makes the output reproducible: the same input gives
the same ``points`` and ``points/refined``.

Shapes: ``ids: (P,)`` track ids, ``uv: (P, 2)`` pixels, ``xyz: (P, 3)`` output units.
"""
from collections import deque
from dataclasses import dataclass
import threading
import time

import numpy as np

from grass_nrsfm_ros.nrsfm.measurement import centre, InvalidInputError
from grass_nrsfm_ros.nrsfm.rotation import rigid_factorisation, rigid_world_shape
from grass_nrsfm_ros.nrsfm.solver import one_blas_thread
from grass_nrsfm_ros.nrsfm.tracking import build_model, fit_subset, rigid_model, Tracker
from grass_nrsfm_ros.params import OUTPUTS
from grass_nrsfm_ros.pipeline import (common_ids, DEPTH_FLIP, FrameResult, make_windows,
                                      window_matrix)

#: a bootstrap model is rebuilt from the frames so far when their count reaches each of these
BOOTSTRAP_AT = (3, 6, 12, 24, 48)
#: a bootstrap model whose depth spread exceeds this many times its x, y spread is ill-posed
#: (too little rotation): the frames are tracked as flat instead
BOOTSTRAP_DEPTH_LIMIT = 1.0
#: tracking latencies kept for the percentiles
LATENCY_WINDOW = 300
#: tracked frames whose median residual a new frame's is compared with
RESIDUAL_BASELINE = 30


@dataclass(frozen=True)
class Step:
    """What one call gives out: ``points`` (FrameResults to publish on ``points``),
    ``refined`` (on ``points/refined``), ``windows`` (closed, for the mapping)."""

    points: tuple = ()
    refined: tuple = ()
    windows: tuple = ()


def bootstrap_model(frames):
    """A rank-0 ShapeModel from the rigid factorisation of ``frames`` (Frames of one
    sequence, oldest first, on their common tracks), or None when too few frames or the
    depth is ill-posed (spread beyond BOOTSTRAP_DEPTH_LIMIT times the image spread). The
    rotations and the depth check come from at most FIT_TRACKS of the tracks (the cost of a
    rebuild, on the tracking thread, does not grow with them), the shape of every track from
    those rotations."""
    ids = frames[0].ids
    for f in frames[1:]:
        ids = common_ids(ids, f.ids)
    if len(frames) < BOOTSTRAP_AT[0] or ids.size < 4:
        return None
    W, _ = centre(window_matrix(frames, ids))
    try:
        R, S = rigid_factorisation(W[:, fit_subset(ids.size)])
    except (InvalidInputError, np.linalg.LinAlgError):     # no spread, degenerate frames
        return None
    Sf = S.reshape(len(frames), 3, -1)
    spread = Sf - Sf.mean(axis=2, keepdims=True)
    depth, image = np.std(spread[:, 2]), np.std(spread[:, :2])
    if not np.isfinite(depth) or depth > BOOTSTRAP_DEPTH_LIMIT * image:
        return None
    stamps = np.array([f.stamp_ns for f in frames], dtype=np.int64)
    return rigid_model(rigid_world_shape(R, W), R, ids, stamps)


class LivePipeline:
    """Tracking at frame rate over a SlidingWindow's mapping; see the module docstring.

    ``add_frame`` runs on one thread (tracking), ``solve`` on another (mapping) or the same.
    """

    def __init__(self, windows, *, output='live', temporal_prior=0.0, residual_limit=3.0):
        if output not in OUTPUTS:
            raise ValueError(f'output={output!r}: one of {OUTPUTS}')
        if not residual_limit > 1.0:
            raise ValueError(f'residual_limit={residual_limit}: must be > 1')
        self.windows, self.output = windows, output
        self.temporal_prior, self.residual_limit = float(temporal_prior), float(residual_limit)
        self._tracker = None
        self._residuals = deque(maxlen=RESIDUAL_BASELINE)   # of the last tracked frames
        self._requested = False         # a fresh window asked for since the current model
        self._bootstrap = []            # Frames of the sequence while it has no model
        self._bootstrap_seen = 0        # frames tracked since then (_bootstrap stops growing)
        self._bootstrap_depth = {}      # stamp -> (ids, z) published before the first model
        self._realigning = False        # the mapping lost its state: record depths until a model
        #: depths kept for the next model's orientation: as many frames as one solve holds
        self._depth_frames = windows.window_size + windows.context_frames
        self._waiting = None            # (sequence, ShapeModel) for the next frame
        self._sequence = None
        self._lock = threading.Lock()
        self.latencies = deque(maxlen=LATENCY_WINDOW)
        self.last = dict(residual=None, model_age=None, model_rank=None, bootstrap=None)
        self.stats = dict(tracked=0, refined=0, bootstrap_frames=0, fresh_windows=0,
                          models=0, first_model_after=None, tracking_failed=0)

    # -- tracking -------------------------------------------------------------------------------
    def add_frame(self, stamp_ns, ids, uv, frame_id=''):
        """Buffer and track one frame; raises FrameError (from the SlidingWindow) for a
        refused one. Returns a Step: the tracked frame (live) and the windows it closed."""
        started = time.perf_counter()
        windows = tuple(self.windows.add_frame(stamp_ns, ids, uv, frame_id))
        if self.output == 'windows':
            return Step(windows=windows)
        frame = self.windows.newest
        if self.windows.sequence != self._sequence:               # a new sequence
            self._sequence = self.windows.sequence
            self._forget_model()
        self._take_model()
        result = self._track(frame)
        self.latencies.append(time.perf_counter() - started)
        return Step(points=(result,), windows=windows)

    @property
    def has_model(self):
        """True once the current sequence is tracked against a solved window's model."""
        return self._tracker is not None and not self._bootstrap

    def _take_model(self):
        """Swap the tracker to the model the mapping left, if one of this sequence waits."""
        with self._lock:
            waiting, self._waiting = self._waiting, None
        if waiting is None or waiting[0] != self._sequence:
            return
        _, model = waiting
        self._requested = False
        self._realigning, self._bootstrap_depth = False, {}
        if self.has_model:
            self._tracker.swap(model)
            return
        if self.stats['first_model_after'] is None:
            self.stats['first_model_after'] = self._bootstrap_seen
        self._tracker = Tracker(model, temporal_prior=self.temporal_prior)
        self._bootstrap, self._bootstrap_seen = [], 0

    def _track(self, frame):
        """FrameResult of ``frame`` from the tracker, or from the bootstrap."""
        self.stats['tracked'] += 1
        if not self.has_model:
            return self._track_bootstrap(frame)
        tracked = self._fit(frame)
        if tracked is None:
            return self._flat(frame)
        self.last.update(residual=tracked.residual, model_rank=self._tracker.model.rank,
                         model_age=self._tracker.age, bootstrap=False)
        if self._surprising(tracked.residual):
            self.windows.request_window()
            self.stats['fresh_windows'] += 1
            self._requested = True
        self._residuals.append(tracked.residual)
        if self._realigning:
            self._keep_depth(frame.stamp_ns, tracked.ids, tracked.xyz[:, 2])
        return self._result(frame, tracked.ids, tracked.xyz)

    def _surprising(self, residual):
        """True if ``residual`` exceeds ``residual_limit`` times the median of the last
        RESIDUAL_BASELINE tracked frames', and no fresh window has been asked for since the
        current model arrived."""
        if self._requested or len(self._residuals) < RESIDUAL_BASELINE:
            return False
        return residual > self.residual_limit * max(float(np.median(self._residuals)), 1e-9)

    def _track_bootstrap(self, frame):
        """Before the first model: track against a rigid model of the frames so far (rebuilt
        at BOOTSTRAP_AT frame counts), flat while that is ill-posed."""
        self.stats['bootstrap_frames'] += 1
        self._bootstrap_seen += 1
        if len(self._bootstrap) < BOOTSTRAP_AT[-1]:         # later rebuilds use no more
            self._bootstrap.append(frame)
        if self._bootstrap_seen in BOOTSTRAP_AT:
            model = bootstrap_model(self._bootstrap)
            if model is not None:
                self._tracker = Tracker(model, temporal_prior=self.temporal_prior)
        tracked = None if self._tracker is None else self._fit(frame)
        if tracked is None:
            return self._flat(frame)
        self.last.update(residual=tracked.residual, model_age=self._tracker.age,
                         model_rank=0, bootstrap=True)
        self._keep_depth(frame.stamp_ns, tracked.ids, tracked.xyz[:, 2])
        return self._result(frame, tracked.ids, tracked.xyz)

    def _keep_depth(self, stamp_ns, ids, z):
        """Remember the depth ``z: (P,)`` published for ``ids: (P,)`` at ``stamp_ns`` (the
        newest ``_depth_frames`` frames), for the orientation of the next model."""
        self._bootstrap_depth[stamp_ns] = (ids, z)
        while len(self._bootstrap_depth) > self._depth_frames:
            del self._bootstrap_depth[next(iter(self._bootstrap_depth))]

    def published_depth(self, stamp_ns):
        """``(ids: (P,), z: (P,))`` published at ``stamp_ns`` before the current model (the
        bootstrap, or since :meth:`realign`), which the next model is oriented to; else None."""
        return self._bootstrap_depth.get(stamp_ns)

    def realign(self):
        """The mapping lost its state (a restarted mapping process): until its next model, the
        depths of tracked frames are kept so that model keeps the published orientation."""
        self._realigning = True

    def _fit(self, frame):
        """The tracker's TrackedFrame of ``frame``, or None (counted) where the fit fails or
        is not finite (degenerate frames: coincident or collinear tracks)."""
        centred = frame.uv - frame.uv.mean(axis=0)
        if np.sqrt(np.mean(centred ** 2)) <= 1e-9 * (1.0 + np.abs(frame.uv).max()):
            self.stats['tracking_failed'] += 1                 # no spread: nothing to fit
            return None
        with np.errstate(all='ignore'):
            try:
                tracked = self._tracker.track(frame.stamp_ns, frame.ids, frame.uv)
            except np.linalg.LinAlgError:
                tracked = None
        if tracked is None or not (np.isfinite(tracked.xyz).all()
                                   and np.isfinite(tracked.residual)):
            self.stats['tracking_failed'] += 1
            return None
        return tracked

    def _flat(self, frame):
        """``frame`` with no depth (z = 0): before any model, or where tracking failed."""
        xyz = np.column_stack([frame.uv - frame.uv.mean(axis=0), np.zeros(frame.ids.size)])
        self.last.update(residual=None, model_age=None, model_rank=None,
                         bootstrap=not self.has_model)
        return self._result(frame, frame.ids, xyz)

    def _result(self, frame, ids, xyz):
        return FrameResult(frame.stamp_ns, frame.frame_id, ids,
                           xyz * self.windows.metres_per_pixel)

    # -- mapping --------------------------------------------------------------------------------
    def solve(self, window, progress=None):
        """Solve ``window`` (SlidingWindow.solve: raises WindowError); its solution becomes the
        tracker's next model. Returns a Step: the window's frames as ``refined`` (live) or as
        ``points`` (windows)."""
        results, model = solve_window(self.windows, window, self.output,
                                      dict(self._bootstrap_depth), progress)
        return self.accept(window.sequence, results, model)

    def accept(self, sequence, results, model):
        """Take a solved window of ``sequence``: its FrameResults ``results`` and ``model``
        (:func:`solve_window`'s; None for output 'windows'). Returns solve's Step."""
        if self.output == 'windows':
            return Step(points=tuple(results))
        if model is not None:
            with self._lock:
                self._waiting = (sequence, model)
            self.stats['models'] += 1
        self.stats['refined'] += len(results)
        return Step(refined=tuple(results))

    def accept_solved_elsewhere(self, sequence, results, model, solved=True):
        """:meth:`accept` for a window solved by another SlidingWindow (a mapping process):
        this one's bookkeeping (SlidingWindow.note_solved, of the frames in ``results``;
        ``solved`` false: a final window released without a solve) first."""
        self.windows.note_solved(sequence, [r.stamp_ns for r in results], solved)
        return self.accept(sequence, results, model)

    def reset(self):
        """Drop the buffered frames, the tracker and its model (SlidingWindow.reset); the
        next frame starts a new sequence. Returns ``{'frames': buffered frames dropped, 'model':
        whether there was one}``."""
        dropped = self.windows.reset()
        had_model = self._tracker is not None
        with self._lock:
            self._waiting = None
        self._forget_model()
        self._realigning = False
        return {**dropped, 'model': dropped['model'] or had_model}

    def _forget_model(self):
        """No tracker, bootstrap or residual history: a sequence starts over."""
        self._tracker, self._bootstrap, self._bootstrap_depth = None, [], {}
        self._bootstrap_seen = 0
        self._residuals.clear()

    def flush(self):
        """The last window of the buffered frames (SlidingWindow.flush)."""
        return self.windows.flush()

    def latency_percentiles(self):
        """``(p50, p95)`` seconds of add_frame over the last LATENCY_WINDOW frames, or None."""
        if not self.latencies:
            return None
        return tuple(float(x) for x in np.percentile(self.latencies, [50, 95]))

    # -- the SlidingWindow's state, for callers ---------------------------------------------
    @property
    def previous(self):
        return self.windows.previous

    @property
    def pending_frames(self):
        return self.windows.pending_frames

    @property
    def metres_per_pixel(self):
        return self.windows.metres_per_pixel

    @metres_per_pixel.setter
    def metres_per_pixel(self, value):
        self.windows.metres_per_pixel = float(value)


def solve_window(windows, window, output='live', published=None, progress=None):
    """The mapping's work for one window: ``(results, model)``. ``windows.solve(window)``
    (raises WindowError) gives the FrameResults; live output also turns the solution into a
    ShapeModel, first flipping it (and ``windows``' kept solution) when its depth disagrees with
    ``published`` (``{stamp: (ids, z)}`` published before this model, see
    :func:`disagrees_with`). Output 'windows': no model (None). BLAS on BLAS_THREADS threads."""
    with one_blas_thread():
        released = windows.releases(window)                 # not solved again: no new model
        results = windows.solve(window, progress=progress)
        if output == 'windows' or released:
            return results, None
        solution = windows.previous
        if published and disagrees_with(solution, published):
            windows.flip_previous()
            results = [FrameResult(r.stamp_ns, r.frame_id, r.ids, r.xyz @ DEPTH_FLIP)
                       for r in results]
        return results, build_model(solution.S, solution.R, solution.ids, solution.stamps)


def solve_figures(solution, seconds):
    """What the diagnostics show of a solved window: its ``seconds``, the ADMM iterations,
    the reprojection residual and the tracks thinned, from ``solution`` (a
    :class:`~grass_nrsfm_ros.pipeline.Solution`)."""
    report = solution.report
    return dict(solve_seconds=seconds, iterations=getattr(report, 'iterations', ''),
                reprojection_residual=solution.residual,
                tracks_thinned=getattr(report, 'thinned_points', ''))


def disagrees_with(solution, published):
    """True if ``solution``'s depth correlates negatively with the depths ``published``
    (``{stamp: (ids, z)}``) on the frames both have (the first model of a sequence keeps the
    orientation the bootstrap published; later windows align to their predecessor)."""
    total = 0.0
    Z = solution.S.reshape(len(solution.stamps), 3, -1)[:, 2, :]
    for f, stamp in enumerate(solution.stamps):
        if int(stamp) not in published:
            continue
        ids, z = published[int(stamp)]
        _, a, b = np.intersect1d(solution.ids, ids, assume_unique=True, return_indices=True)
        total += float(np.dot(Z[f, a] - Z[f, a].mean(), z[b] - z[b].mean()))
    return total < 0.0


def make_pipeline(config, solver_factory=None, **options):
    """The LivePipeline that ``config`` describes (a dict of parameters as from
    :func:`grass_nrsfm_ros.params.load_config` or the node's declarations; absent keys take
    their defaults), over :func:`grass_nrsfm_ros.pipeline.make_windows` (``solver_factory``,
    ``options``)."""
    return LivePipeline(make_windows(config, solver_factory, **options),
                        output=config.get('output', 'live'),
                        temporal_prior=config.get('tracking_prior', 0.0),
                        residual_limit=config.get('residual_limit', 3.0))


def reconstruct_live(pipeline, stamps, frames, frame_id=''):
    """Run ``pipeline`` (a LivePipeline) over a whole sequence offline, each window solved as
    it closes; returns ``(points, refined)``: FrameResults in stamp order.
    ``frames``: iterable of ``(ids: (P,), uv: (P, 2))``, one per stamp."""
    points, refined = [], []
    for stamp, (ids, uv) in zip(stamps, frames):
        step = pipeline.add_frame(stamp, ids, uv, frame_id)
        points += step.points
        for window in step.windows:
            solved = pipeline.solve(window)
            points += solved.points
            refined += solved.refined
    for window in pipeline.flush():
        solved = pipeline.solve(window)
        points += solved.points
        refined += solved.refined
    return points, refined
