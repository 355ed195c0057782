"""Dense 2D tracks anchored to keyframes (OpenCV optical flow, no ROS).

:class:`DenseTracker` owns the tracks of one image stream: it follows the points of a grid of
``step`` pixels inside a region, each anchored to a *keyframe* (a past frame where its point
is known) and measured against it in every frame, so its error does not grow frame by frame.
Per frame: DIS optical flow from the last frame predicts; :class:`~.keyframes.KeyframeRefiner`
refines and checks against the keyframes; the tracker then hides, kills, re-anchors (a new
keyframe when enough tracks have changed appearance) and gives birth (where the region is
uncovered). A track dies when it leaves the image or fails its checks; ids are never reused
within a sequence (until :meth:`DenseTracker.reset`). The method and why: record 0600.

Shapes and units:

* a frame: ``(H, W)`` grey or ``(H, W, 3)`` / ``(H, W, 4)`` colour (``channel_order`` 'rgb'
  or 'bgr'), uint8, uint16 (scaled to 8 bits by the bit depth of the first uint16 frame) or
  float in [0, 1];
* ``region``: None (the whole image), a bool mask ``(H, W)`` of the first frame (it moves
  with the surface: at each keyframe with births it becomes the grid cells its tracks hold,
  holes closed) or a rectangle ``(x0, y0, x1, y1)`` of pixels, bounds included (fixed
  in the image);
* :class:`TrackFrame`: ``ids: (P,) uint32``, ``uv: (P, 2) float64`` pixels (pixel centres at
  integer coordinates, u to the right, v down), ``age: (P,) int64`` frames since birth,
  ``counts`` a dict of ints.

A frame of another size than the first raises :class:`FrameSizeError` (call
:meth:`DenseTracker.reset` to start a new sequence at the new size). A blank frame (black,
saturated or flat) gives no tracks, warns once and keeps the state, so tracking resumes on the
next good frame.
"""
from dataclasses import dataclass, field
import warnings

import cv2
import numpy as np

from . import grid, imaging
from .grid import FrameSizeError
from .keyframes import Anchors, KeyframeRefiner, make_keyframe

#: flow methods: a DIS preset from the last frame predicts; '+lk' refines against the
#: keyframe in the frame warped by the tracks' field (the default); '/prev+lk' refines by
#: Lucas-Kanade from the keyframe without the warp (translation only, 1 pyramid level); a
#: bare DIS preset has no refinement (chained DIS: it drifts); 'lk' predicts nothing (the
#: last positions) and refines with the warp by pyramidal LK (2 levels)
METHODS = ('dis-ultrafast', 'dis-fast', 'dis-medium',
           'dis-ultrafast+lk', 'dis-fast+lk', 'dis-medium+lk',
           'dis-ultrafast/prev+lk', 'dis-fast/prev+lk', 'dis-medium/prev+lk', 'lk')
_DIS_PRESETS = {'dis-ultrafast': cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST,
                'dis-fast': cv2.DISOPTICAL_FLOW_PRESET_FAST,
                'dis-medium': cv2.DISOPTICAL_FLOW_PRESET_MEDIUM}
DEFAULT_METHOD = 'dis-fast+lk'
_STALE_SHARE = 0.02                # a new keyframe when more of the tracks than this are stale
_KEYFRAME_MARGIN = 24              # px around the tracks where a keyframe is normalised
_FLOW_MARGIN = 24                  # px around the tracks where DIS last -> current runs


@dataclass(frozen=True, eq=False)
class TrackFrame:
    """The tracks alive in one frame.

    ``ids: (P,) uint32``, ``uv: (P, 2) float64`` pixels, ``age: (P,) int64`` frames since
    each track was born; ``counts``: 'alive', 'born', 'lost' (died this frame: left the
    image or failed its checks ``max_misses`` + 1 frames in a row), 'failed' (failed a check
    this frame), 'missed' (of those, hidden this frame but kept), 'left', 'reanchored' (1
    when this frame became a keyframe), 'blank' (1 for a blank frame, which has no tracks);
    ``K: (3, 3)`` or None.
    """

    ids: np.ndarray
    uv: np.ndarray
    age: np.ndarray
    counts: dict = field(default_factory=dict)
    K: np.ndarray = None

    def normalised(self):
        """``K^-1 [u v 1]`` as ``(P, 2)`` (needs ``K``)."""
        if self.K is None:
            raise ValueError('normalised coordinates need the intrinsics K')
        homog = np.column_stack([self.uv, np.ones(len(self.uv))])
        xy = np.linalg.solve(self.K, homog.T).T
        return xy[:, :2] / xy[:, 2:]


class DenseTracker:
    """Dense grid tracks anchored to keyframes; one instance per image stream.

    ``step`` grid spacing in pixels (int >= 1); ``region`` None, a bool mask ``(H, W)`` or a
    rectangle ``(x0, y0, x1, y1)``; ``method`` one of :data:`METHODS`; ``K`` optional
    intrinsics ``(3, 3)`` carried into each :class:`TrackFrame`.

    Checks: ``min_zncc`` (a track whose 11 x 11 normalised patch correlates less than this
    with its keyframe patch, in the warped frame, fails), ``fb_max_px`` (forward-backward
    distance above which a track fails; None: no forward-backward check), ``max_misses``
    (int >= 0: a failed track is hidden, and dies when it fails this many frames more in a
    row, or when its keyframe is retired while it is hidden: it is not re-anchored while
    hidden). Keyframes: a track
    is stale when its ZNCC is below ``reanchor_zncc``; the frame becomes a keyframe (stale
    tracks re-anchored to it) when more than 2 % of the tracks are stale, when more than
    ``reanchor_uncovered`` of the region's grid cells hold no track (a grid point is
    covered by a track within 0.75 steps; then tracks are born), or every
    ``reanchor_every`` frames (None: never by count; then every track is re-anchored and
    tracks are born). At most ``max_keyframes`` are kept: beyond, the tracks of the one
    holding fewest are re-anchored to the new one (1: every track follows the newest
    keyframe). Births only on cells whose patch's grey levels vary by ``min_texture`` or more.
    ``lk_window`` (odd) and ``lk_levels`` (pyramid levels; None: 0 for 'dis-*+lk', 1 for
    '/prev+lk', 2 for 'lk') set the Lucas-Kanade refinement, which fails a track when it
    moves it more than 2 px from the DIS prediction; ``channel_order`` of colour frames;
    ``blank_std``: a frame whose grey levels vary less than this is blank. Why: record 0600.
    """

    def __init__(self, step=4, region=None, method=DEFAULT_METHOD, *, K=None, min_zncc=0.8,
                 fb_max_px=None, reanchor_zncc=0.9, reanchor_uncovered=0.1,
                 reanchor_every=None, min_texture=2.0, lk_window=9, lk_levels=None,
                 channel_order='rgb', blank_std=2.0, max_keyframes=1, max_misses=1):
        _check_parameters(step, method, channel_order, min_zncc, reanchor_zncc,
                          reanchor_uncovered, min_texture, blank_std, fb_max_px, reanchor_every,
                          lk_window, max_keyframes, lk_levels, max_misses)
        self.max_misses = int(max_misses)
        self.step = int(step)
        self.method = method
        self.region = grid.validate_region(region)
        self.K = None if K is None else _validate_K(K)
        self.min_zncc, self.fb_max_px = float(min_zncc), fb_max_px
        self.reanchor_zncc, self.reanchor_uncovered = float(reanchor_zncc), reanchor_uncovered
        self.reanchor_every, self.min_texture = reanchor_every, float(min_texture)
        self.lk_window, self.channel_order = int(lk_window), channel_order
        self.blank_std = float(blank_std)
        preset = _DIS_PRESETS.get(method.split('+')[0].split('/')[0])
        self._dis_preset = preset
        self._dis = None if preset is None else cv2.DISOpticalFlow.create(preset)
        warp = '/prev' not in method
        self.lk_levels = lk_levels if lk_levels is not None else (
            2 if self._dis is None else 1 if not warp else 0)
        self.max_keyframes = int(max_keyframes)
        self._refiner = KeyframeRefiner(
            self.step, self.lk_window, self.lk_levels, warp=warp,
            refine_lk=method.endswith('+lk') or method == 'lk', predicted=self._dis is not None,
            min_zncc=self.min_zncc)
        self._next_id = 0
        self._warned = set()
        self.reset()

    # ---------------------------------------------------------------- public

    def reset(self):
        """Forget the keyframes and every track; the next frame starts a new sequence (new
        ids continue from the last one: ids are never reused by one tracker)."""
        self._keyframes = {}          # frame number -> Keyframe
        self._shape = None            # (H, W) of the sequence
        self._region_ref = None       # (H, W) bool region at the newest keyframe
        self._cells = np.zeros((0, 2), np.int64)    # (G, 2) its grid points
        self._last = None             # (H, W) uint8 last frame tracked
        self._step_flow = None        # (h, w, 2) float32 DIS flow last -> current frame, a box
        self._ids = np.zeros(0, np.uint32)
        self._key = np.zeros(0, np.int64)                              # (P,) keyframe
        self._uv_ref = np.zeros((0, 2), np.float32)                   # (P, 2) in it
        self._ref_patches = np.zeros((0, len(imaging.OFFSETS)), np.float32)   # (P, n) zero-mean
        self._uv = np.zeros((0, 2), np.float64)
        self._born = np.zeros(0, np.int64)
        self._misses = np.zeros(0, np.int64)                        # (P,) failed checks in a row
        self._frame = -1
        self._newest_key = -1
        self._uint16_shift = None

    def track(self, image):
        """Track one frame; returns its :class:`TrackFrame`."""
        grey, self._uint16_shift = imaging.to_grey(image, self.channel_order, self._uint16_shift)
        self._frame += 1
        if self._shape is not None and grey.shape != self._shape:
            raise FrameSizeError(
                f'frame {self._frame} is {grey.shape[1]} x {grey.shape[0]} pixels but the '
                f'sequence is {self._shape[1]} x {self._shape[0]}; call reset() to '
                f'start a new sequence at the new size')
        counts = dict(alive=0, born=0, lost=0, failed=0, missed=0, left=0, reanchored=0,
                      blank=0)
        spread = float(grey[::4, ::4].std())
        if spread < self.blank_std:
            self._warn_once('blank', f'blank frame (grey-level std {spread:.2f} < '
                            f'{self.blank_std}): no tracks in it, the state is kept')
            counts['blank'] = 1
            return self._frame_out(np.zeros(0, bool), counts)
        if self._shape is None:
            self._start(grey, counts)
        else:
            self._follow(grey, counts)
        self._last = grey
        return self._frame_out(self._misses == 0, counts)

    @property
    def n_alive(self):
        """Tracks alive after the last frame."""
        return len(self._ids)

    # ---------------------------------------------------------------- steps

    def _start(self, grey, counts):
        """First frame of a sequence: the first keyframe; tracks born on the region's grid."""
        self._shape = grey.shape
        self._new_keyframe(grey, np.zeros(0, bool), grid.region_mask(self.region, grey.shape),
                           counts)

    def _follow(self, grey, counts):
        """Track the alive tracks into ``grey``; kill, re-anchor, birth."""
        guess = self._predict(grey)
        anchors = Anchors(self._keyframes, self._key, self._uv_ref, self._ref_patches,
                          self._misses)
        uv, zncc, ok = self._refiner.refine(grey, guess, anchors)
        passed = ok & (zncc >= self.min_zncc)
        if self.fb_max_px is not None:
            passed &= self._refiner.forward_backward(grey, uv, anchors) <= self.fb_max_px
        uv = np.where(ok[:, None], uv, guess)        # a missed track moves with its prediction
        inside = grid.inside(uv, grey.shape)
        misses = np.where(passed, 0, self._misses + 1)
        keep = inside & (misses <= self.max_misses)
        counts['left'] = int((~inside).sum())
        counts['failed'] = int((inside & ~passed).sum())
        counts['missed'] = int((keep & ~passed).sum())
        counts['lost'] = int((~keep).sum())
        self._uv, self._misses = uv, misses
        self._keep(keep)
        healthy = self._misses == 0
        stale = (zncc[keep] < self.reanchor_zncc) & healthy
        by_count, uncovered = self._needs_keyframe(grey.shape)
        if by_count or uncovered or stale.sum() > _STALE_SHARE * max(healthy.sum(), 1):
            region = grid.carried_region(self.region, self._region_ref, self._uv[healthy],
                                         self.step, grey.shape) if by_count or uncovered else None
            self._new_keyframe(grey, (stale | by_count) & healthy, region, counts)

    def _predict(self, grey):
        """Where the alive tracks ``(P, 2) float32`` are expected in ``grey``: moved by DIS
        from the last frame (computed in the box around them), or where they were."""
        guess = self._uv.astype(np.float32)
        if self._dis is None or len(guess) == 0:
            return guess
        x0, y0, x1, y1 = grid.box(guess, grey.shape, _FLOW_MARGIN)
        last = np.ascontiguousarray(self._last[y0:y1, x0:x1])
        init = None
        if self._step_flow is not None and self._step_flow.shape[:2] == last.shape:
            init = self._step_flow
        else:                 # OpenCV's DIS can crash on a new size after an initial flow
            self._dis = cv2.DISOpticalFlow.create(self._dis_preset)
        self._step_flow = self._dis.calc(last, np.ascontiguousarray(grey[y0:y1, x0:x1]), init)
        origin = np.float32([x0, y0])
        return guess + imaging.sample(self._step_flow, guess - origin)

    def _needs_keyframe(self, shape):
        """``(by_count, uncovered)``: whether the current frame should become a keyframe for
        every track (``reanchor_every``), and whether too much of the region is uncovered
        (new tracks to be born)."""
        by_count = self.reanchor_every is not None and \
            self._frame - self._newest_key >= self.reanchor_every
        uncovered = grid.uncovered_share(self._cells, self._uv, self.step, shape) > \
            self.reanchor_uncovered
        return by_count, uncovered

    def _new_keyframe(self, grey, move, region, counts):
        """The current frame becomes a keyframe: the tracks ``move`` (and those of the
        oldest keyframe beyond ``max_keyframes``) are re-anchored to it, keeping their ids;
        with a ``region`` (None: no births), tracks are born on its uncovered cells."""
        key = self._frame
        points = self._uv if region is None else np.concatenate(
            [self._uv, grid.region_cells(region, self.step)])
        self._keyframes[key] = make_keyframe(grey, points, _KEYFRAME_MARGIN + self.lk_window)
        healthy = self._misses == 0           # missed tracks keep their keyframe
        older, held = np.unique(self._key[healthy & (self._key != key)], return_counts=True)
        retired = older[np.argsort(-held, kind='stable')[self.max_keyframes - 1:]]
        move = move | (np.isin(self._key, retired) & healthy)     # those holding fewest merge
        hidden = ~healthy & ~np.isin(self._key, np.setdiff1d(older, retired))
        if hidden.any():                      # hidden on a retired keyframe: they die
            counts['lost'] += int(hidden.sum())
            counts['missed'] -= int(hidden.sum())
            move = move[~hidden]
            self._keep(~hidden)
        self._key[move] = key
        self._uv_ref[move] = self._uv[move]
        self._ref_patches[move] = imaging.centred_patches(self._keyframes[key].smoothed,
                                                          self._uv_ref[move])
        self._newest_key = key
        counts['reanchored'] = 1
        if region is not None:
            self._region_ref = region
            self._cells = grid.region_cells(region, self.step)
            counts['born'] = self._birth(grey, key)
        for old in set(self._keyframes) - set(self._key.tolist()) - {key}:
            del self._keyframes[old]

    def _keep(self, keep):
        """Keep only the tracks ``keep (P,) bool`` (the others die)."""
        if keep.all():
            return
        self._ids, self._key, self._born = self._ids[keep], self._key[keep], self._born[keep]
        self._uv_ref, self._ref_patches = self._uv_ref[keep], self._ref_patches[keep]
        self._uv, self._misses = self._uv[keep], self._misses[keep]

    def _birth(self, grey, key):
        """New tracks on the uncovered, textured grid cells of the region, anchored to the
        keyframe ``key``; returns how many were born."""
        cells = self._cells
        if len(cells):
            cells = cells[~grid.covered(cells, self._uv, self.step, grey.shape)]
        patches = imaging.centred_patches(grey, cells)
        textured = np.sqrt((patches ** 2).mean(axis=1)) >= self.min_texture
        cells = cells[textured]
        patches = imaging.centred_patches(self._keyframes[key].smoothed, cells)
        n = len(cells)
        new_ids = self._next_id + np.arange(n, dtype=np.int64)
        if new_ids.size and new_ids[-1] >= 2 ** 32:
            raise OverflowError('track ids exhausted (2^32); create a new DenseTracker')
        self._next_id += n
        self._ids = np.concatenate([self._ids, new_ids.astype(np.uint32)])
        self._key = np.concatenate([self._key, np.full(n, key, np.int64)])
        self._uv = np.concatenate([self._uv, cells.astype(np.float64)])
        self._uv_ref = np.concatenate([self._uv_ref, cells.astype(np.float32)])
        self._born = np.concatenate([self._born, np.full(n, self._frame, np.int64)])
        self._misses = np.concatenate([self._misses, np.zeros(n, np.int64)])
        self._ref_patches = np.concatenate([self._ref_patches, patches])
        return n

    # ---------------------------------------------------------------- input

    def _frame_out(self, shown, counts):
        counts['alive'] = int(shown.sum())
        age = self._frame - self._born[shown]
        return TrackFrame(ids=self._ids[shown].copy(), uv=self._uv[shown].copy(), age=age,
                          counts=counts, K=self.K)

    def _warn_once(self, key, message):
        if key not in self._warned:
            self._warned.add(key)
            warnings.warn(message, RuntimeWarning, stacklevel=3)


# -------------------------------------------------------------------- helpers

def _check_parameters(step, method, channel_order, min_zncc, reanchor_zncc, reanchor_uncovered,
                      min_texture, blank_std, fb_max_px, reanchor_every, lk_window,
                      max_keyframes, lk_levels, max_misses):
    """Raise ValueError naming the first of DenseTracker's parameters out of its range."""
    if isinstance(step, bool) or not isinstance(step, (int, np.integer)) or step < 1:
        raise ValueError(f'step must be an int >= 1 pixel; got {step!r}')
    if method not in METHODS:
        raise ValueError(f'unknown method {method!r}; choose from {METHODS}')
    if channel_order not in ('rgb', 'bgr'):
        raise ValueError(f"channel_order must be 'rgb' or 'bgr'; got {channel_order!r}")
    _check_range('min_zncc', min_zncc, -1.0, 1.0)
    _check_range('reanchor_zncc', reanchor_zncc, -1.0, 1.0)
    _check_range('reanchor_uncovered', reanchor_uncovered, 0.0, 1.0)
    _check_range('min_texture', min_texture, 0.0, 255.0)
    _check_range('blank_std', blank_std, 0.0, 255.0)
    if fb_max_px is not None:
        _check_range('fb_max_px', fb_max_px, 0.0, np.inf)
    if reanchor_every is not None and (not isinstance(reanchor_every, (int, np.integer))
                                       or reanchor_every < 1):
        raise ValueError(f'reanchor_every must be None or an int >= 1; got '
                         f'{reanchor_every!r}')
    if not isinstance(lk_window, (int, np.integer)) or lk_window < 3 or lk_window % 2 == 0:
        raise ValueError(f'lk_window must be an odd int >= 3; got {lk_window!r}')
    if isinstance(max_keyframes, bool) or not isinstance(max_keyframes, (int, np.integer)) \
            or max_keyframes < 1:
        raise ValueError(f'max_keyframes must be an int >= 1; got {max_keyframes!r}')
    if lk_levels is not None and (not isinstance(lk_levels, (int, np.integer))
                                  or not 0 <= lk_levels <= 6):
        raise ValueError(f'lk_levels must be None or an int in [0, 6]; got {lk_levels!r}')
    if isinstance(max_misses, bool) or not isinstance(max_misses, (int, np.integer)) \
            or max_misses < 0:
        raise ValueError(f'max_misses must be an int >= 0; got {max_misses!r}')


def _check_range(name, value, low, high):
    if isinstance(value, bool) or not isinstance(value, (int, float, np.number)) \
            or not low <= float(value) <= high:
        raise ValueError(f'{name} must be a number in [{low}, {high}]; got {value!r}')


def _validate_K(K):
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3) or not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f'K must be a finite (3, 3) matrix with fx, fy > 0; got {K!r}')
    return K
