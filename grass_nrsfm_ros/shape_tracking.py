"""Shape tracking (the tracking thread): every frame fitted on arrival to the newest model.

:class:`ShapeTracking` fits each accepted Frame to the newest
:class:`~grass_nrsfm_ros.nrsfm.tracking.ShapeModel` the mapping offered (its rotation and mode
coefficients, :class:`~grass_nrsfm_ros.nrsfm.tracking.Tracker`). Before a sequence's first
model, frames are tracked against a rigid bootstrap model of the frames so far
(:func:`bootstrap_model`; each rebuild keeps the depth orientation of the one before,
:func:`oriented_like`, or takes the one a ``depth_sign`` tells, :func:`oriented_by`), flat
while that is ill-posed. A frame whose residual exceeds ``residual_limit`` times the median of
the last frames' is *surprising*: the caller closes the next window early (once per model).
Where the mapping also offered a pinhole sheet's SheetModel, each pinhole frame's depths come
from it alone (:func:`~grass_nrsfm_ros.nrsfm.sheet_model.frame_points`, docs/decisions/0732).
Pure Python and numpy: no ROS.

Shapes: ``ids: (P,)`` track ids, ``uv: (P, 2)`` pixels, ``xyz: (P, 3)`` camera frame in
pixels (x, y the frame's centred u, v; z the depth).
"""
from collections import deque
from dataclasses import dataclass, replace
import threading

import numpy as np

from grass_nrsfm_ros.mapper import DEPTH_FLIP, FrameResult
from grass_nrsfm_ros.nrsfm.measurement import centre, InvalidInputError
from grass_nrsfm_ros.nrsfm.rotation import rigid_factorisation, rigid_world_shape
from grass_nrsfm_ros.nrsfm.sheet_model import frame_points
from grass_nrsfm_ros.nrsfm.tracking import fit_subset, rigid_model, Tracker
from grass_nrsfm_ros.windowing import ids_in_every, window_matrix

#: a bootstrap model is rebuilt from the frames so far when their count reaches each of these
BOOTSTRAP_AT = (3, 6, 12, 24, 48)
#: a bootstrap model whose depth spread exceeds this many times its x, y spread is ill-posed
#: (too little rotation): the frames are tracked as flat instead
BOOTSTRAP_DEPTH_LIMIT = 1.0
#: tracked frames whose median residual a new frame's is compared with
RESIDUAL_BASELINE = 30


@dataclass(frozen=True)
class Tracked:
    """One tracked frame: its ``result``; ``surprising`` (see the module docstring);
    ``depth``: ``(ids, z: float32)`` published for it (the mapping orients a solve it cannot
    orient by its previous one by these), None where the frame went out flat."""

    result: FrameResult
    surprising: bool = False
    depth: tuple = None


def published_depth(tracked):
    """``(ids: (P,), z: (P,) float32)`` of a TrackedFrame: what the mapping needs to keep the
    published orientation (single precision: only the sign of a correlation is taken)."""
    return tracked.ids, tracked.xyz[:, 2].astype(np.float32)


def bootstrap_model(frames):
    """A rank-0 ShapeModel from the rigid factorisation of ``frames`` (Frames of one
    sequence, oldest first, on their common tracks), or None when too few frames or the
    depth is ill-posed (spread beyond BOOTSTRAP_DEPTH_LIMIT times the image spread). The
    rotations and the depth check come from at most FIT_TRACKS of the tracks, the shape of
    every track from those rotations."""
    ids = ids_in_every(frames)
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


def oriented_like(model, previous):
    """``model`` (a rank-0 bootstrap ShapeModel) mirrored in depth where its camera-frame
    depth correlates negatively with ``previous``'s on the frames and tracks both hold (a
    rigid factorisation's mirror is arbitrary: each rebuild would otherwise flip the published
    depths at random); ``model`` itself without a ``previous``."""
    if previous is None:
        return model
    _, a, b = np.intersect1d(model.ids, previous.ids, assume_unique=True, return_indices=True)
    _, fa, fb = np.intersect1d(model.stamps, previous.stamps, return_indices=True)
    depth = np.einsum('fk,kp->fp', model.R[fa, 2], model.mean[:, a])
    before = np.einsum('fk,kp->fp', previous.R[fb, 2], previous.mean[:, b])
    return model if np.sum(depth * before) >= 0.0 else mirrored(model)


def oriented_by(model, frames, depth_sign):
    """``model`` (a rank-0 bootstrap ShapeModel of ``frames``) mirrored in depth where
    ``depth_sign`` of the frames' tracks ``x: (2F, P)`` and the model's relative depths says
    so."""
    x = window_matrix(frames, model.ids)                    # the model's frames, in order
    delta = np.einsum('fk,kp->fp', model.R[:, 2], model.mean)
    return model if depth_sign(x, delta - delta.mean(axis=1, keepdims=True)) > 0 \
        else mirrored(model)


def mirrored(model):
    """``model`` with its depth mirrored (camera-frame z negated, x and y kept)."""
    return replace(model, mean=DEPTH_FLIP @ model.mean, R=DEPTH_FLIP @ model.R @ DEPTH_FLIP)


class ShapeTracking:
    """See the module docstring. :meth:`track` on the tracking thread; :meth:`offer` (a new
    model) from any thread.

    ``stats``: frames ``tracked``, ``bootstrap_frames``, ``fresh_windows`` (surprising frames),
    ``models`` taken, ``first_model_after`` (frames of the sequence before its first model),
    ``tracking_failed`` (published flat), ``sheet_frames`` (from a SheetModel); ``last``: the
    newest frame's residual, model age and rank, and whether it was a bootstrap frame.
    """

    def __init__(self, residual_limit=3.0, depth_sign=None):
        """``depth_sign(x: (2F, P), delta: (F, P)) -> +1 or -1``: where the frames' depth
        sign can be told (normalised tracks of a pinhole camera:
        :func:`~grass_nrsfm_ros.nrsfm.perspective.low_rank_sign`), each bootstrap model is
        oriented by it; None: each keeps the orientation of the one before."""
        if not residual_limit > 1.0:
            raise ValueError(f'residual_limit={residual_limit}: must be > 1')
        self.residual_limit = float(residual_limit)
        self.depth_sign = depth_sign
        self._tracker = None
        self._residuals = deque(maxlen=RESIDUAL_BASELINE)   # of the last tracked frames
        self._requested = False         # a fresh window asked for since the current model
        self._bootstrap = []            # Frames of the sequence while it has no model
        self._bootstrap_seen = 0        # frames tracked since then (_bootstrap stops growing)
        self._waiting = None            # (sequence, ShapeModel, SheetModel) for the next frame
        self._sheet = None              # the SheetModel of the sequence, None: none
        self._sequence = None
        self._lock = threading.Lock()
        self.last = dict(residual=None, model_age=None, model_rank=None, bootstrap=None)
        self.stats = dict(tracked=0, bootstrap_frames=0, fresh_windows=0, models=0,
                          first_model_after=None, tracking_failed=0, sheet_frames=0)

    @property
    def has_model(self):
        """True once the current sequence is tracked against a solved window's model."""
        return self._tracker is not None and not self._bootstrap

    def offer(self, sequence, model, sheet=None):
        """The mapping's newest ``model`` of ``sequence`` (and its ``sheet``, a SheetModel, or
        None): the next frame of that sequence is tracked against it; where a sheet model is
        held, each pinhole frame's depths are the sheet's (:func:`~grass_nrsfm_ros.nrsfm.
        sheet_model.frame_points`)."""
        with self._lock:
            self._waiting = (sequence, model, sheet)
        self.stats['models'] += 1

    def reset(self):
        """Forget the model, the one waiting and the bootstrap (a new sequence); True if
        there was a model (or a bootstrap one)."""
        with self._lock:
            had_model = self._tracker is not None or self._waiting is not None
            self._waiting = None
        self._forget_model()
        return had_model

    def track(self, frame):
        """The :class:`Tracked` ``frame`` (a windowing Frame)."""
        if frame.sequence != self._sequence:
            self._sequence = frame.sequence
            self._forget_model()
        self._take_model()
        self.stats['tracked'] += 1
        if not self.has_model:
            return self._track_bootstrap(frame)
        tracked = self._fit(frame)
        if tracked is None:
            return Tracked(self._flat(frame))
        self.last.update(residual=tracked.residual, model_rank=self._tracker.model.rank,
                         model_age=self._tracker.age, bootstrap=False)
        surprising = self._surprising(tracked.residual)
        if surprising:
            self.stats['fresh_windows'] += 1
            self._requested = True
        self._residuals.append(tracked.residual)
        result = self._result(frame, tracked.ids, tracked.xyz)
        if self._sheet is not None and frame.pinhole:
            at = np.searchsorted(frame.ids, result.ids)
            xyz = frame_points(self._sheet, result.ids, frame.uv[at])
            if xyz is not None:
                result = replace(result, xyz=xyz, signed=True)
                self.stats['sheet_frames'] += 1
        return Tracked(result, surprising, published_depth(tracked))

    # -- internals ------------------------------------------------------------------------------
    def _take_model(self):
        """Swap the tracker to the model the mapping left, if one of this sequence waits."""
        with self._lock:
            waiting, self._waiting = self._waiting, None
        if waiting is None or waiting[0] != self._sequence:
            return
        _, model, self._sheet = waiting
        self._requested = False
        if self.has_model:
            self._tracker.swap(model)
            return
        if self.stats['first_model_after'] is None:
            self.stats['first_model_after'] = self._bootstrap_seen
        self._tracker = Tracker(model)
        self._bootstrap, self._bootstrap_seen = [], 0

    def _forget_model(self):
        self._tracker, self._bootstrap, self._bootstrap_seen = None, [], 0
        self._sheet = None
        self._residuals.clear()

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
                if self.depth_sign is not None:
                    model = oriented_by(model, self._bootstrap, self.depth_sign)
                else:
                    model = oriented_like(model, None if self._tracker is None
                                          else self._tracker.model)
                self._tracker = Tracker(model)
        tracked = None if self._tracker is None else self._fit(frame)
        if tracked is None:
            return Tracked(self._flat(frame))
        self.last.update(residual=tracked.residual, model_age=self._tracker.age,
                         model_rank=0, bootstrap=True)
        return Tracked(self._result(frame, tracked.ids, tracked.xyz),
                       depth=published_depth(tracked))

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

    @staticmethod
    def _result(frame, ids, xyz):
        return FrameResult(frame.stamp_ns, frame.frame_id, ids, xyz)
