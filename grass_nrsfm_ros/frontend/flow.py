"""Dense 2D tracks anchored to keyframes (OpenCV optical flow, no ROS).

:class:`DenseTracker` follows the points of a grid of ``step`` pixels inside a region. Each
track is anchored to a *keyframe* (a past frame where its point is known) and is measured
against it in every frame, so its error does not grow frame by frame:

1. prediction: DIS optical flow from the last frame moves each track (in the box around the
   tracks);
2. refinement, per keyframe: the current frame is warped into the keyframe by the smooth
   displacement field of that keyframe's predicted tracks (so the turn and deformation since
   the keyframe are undone), then locally normalised (mean removed, contrast equalised:
   blind to shading gain and offset; in the keyframe's geometry, like the keyframe), and
   Lucas-Kanade from the normalised keyframe measures what the field missed at each track;
   then the other way round (the keyframe warped into the frame and normalised there, LK
   from it to the normalised frame), and the track is the mean of the two estimates; a
   track whose check (3) is weak leans on the smooth field of its neighbours' moves;
3. checks: a ZNCC of each track's patch against its keyframe patch, taken in the warped frame
   on slightly blurred images (optionally a forward-backward check); occlusion shows up as a
   failed check. A track that fails is hidden (not in the output, kept on its keyframe,
   moved by the prediction) and dies when it fails ``max_misses`` + 1 frames in a row, or
   when its keyframe is retired while it is hidden (so one keyframe serves every frame).

A track whose patch has changed (ZNCC below ``reanchor_zncc``) is *stale*: when enough
tracks are stale, the frame becomes a keyframe and they (with ``max_keyframes`` 1, the
default: every track) are re-anchored to it, keeping their ids. When too much
of the region has no track, the frame becomes a keyframe and new tracks are born on the
region's uncovered grid cells. A track dies when it leaves the image or fails its checks. Ids are
never reused within a sequence (until :meth:`reset`).

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
from functools import partial
import warnings

import cv2
import numpy as np

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
_PATCH_RADIUS = 5                  # photometric check and texture test on 11 x 11 patches
_MAX_REFINEMENT = 2.0              # px: prediction and its LK refinement disagreeing more: failed
_COVER_RADIUS = 0.75               # grid steps: a grid point with no track this near is uncovered
_BORDER = 2.0                      # a track closer than this to the image edge has left it
_STALE_SHARE = 0.02                # a new keyframe when more of the tracks than this are stale
_KEYFRAME_MARGIN = 24              # px around the tracks where a keyframe is normalised
_FLOW_MARGIN = 24                  # px around the tracks where DIS last -> current runs
_WARP_MARGIN = 8                   # px around a keyframe's tracks warped (plus the LK window)
_MIN_BOX = 48                      # px: the smallest box DIS and the warp run in
_FIELD_SIGMA = 4.0                 # px: smoothing of the displacement field of the tracks
_REMAP_ROWS = 32000                # OpenCV's remap takes maps of under 2^15 rows
_LK_ITERATIONS = 5                 # LK stops after this many steps, or a step under:
_LK_EPS = 0.03                     # px
_INVERSE_STEPS = 3                 # fixed-point steps inverting the field
_CHECK_SIGMA = 1.0                 # px: blur of both sides of the ZNCC check
_SMOOTH_ZNCC = 0.98              # a track checked below this leans on its neighbours' field
_NORM_SIGMA = 4.0                  # px: windows of the local normalisation before LK


@dataclass(frozen=True, eq=False)
class _Keyframe:
    """A frame tracks are anchored to: ``grey (H, W) float32``, its :func:`_normalise` and
    that :func:`_smoothed` (where the ZNCC check samples)."""

    grey: np.ndarray
    normalised: np.ndarray
    smoothed: np.ndarray


@dataclass(frozen=True, eq=False)
class _Crop:
    """A box of a frame: ``image (h, w)`` (normalised) and ``raw (h, w)`` float32 grey,
    whose pixel (0, 0) is the frame's ``origin (x0, y0)`` (float32)."""

    image: np.ndarray
    origin: np.ndarray
    raw: np.ndarray = None


class FrameSizeError(ValueError):
    """A frame's size differs from the sequence's reference frame."""


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
        self.region = _validate_region(region)
        self.K = None if K is None else _validate_K(K)
        self.min_zncc, self.fb_max_px = float(min_zncc), fb_max_px
        self.reanchor_zncc, self.reanchor_uncovered = float(reanchor_zncc), reanchor_uncovered
        self.reanchor_every, self.min_texture = reanchor_every, float(min_texture)
        self.lk_window, self.channel_order = int(lk_window), channel_order
        self.blank_std = float(blank_std)
        preset = _DIS_PRESETS.get(method.split('+')[0].split('/')[0])
        self._dis_preset = preset
        self._dis = None if preset is None else cv2.DISOpticalFlow.create(preset)
        self._refine_lk = method.endswith('+lk') or method == 'lk'
        self._warp = '/prev' not in method
        self.lk_levels = lk_levels if lk_levels is not None else (
            2 if self._dis is None else 1 if not self._warp else 0)
        self.max_keyframes = int(max_keyframes)
        self._lk = partial(lucas_kanade, self.lk_window, self.lk_levels)
        self._next_id = 0
        self._warned = set()
        self.reset()

    # ---------------------------------------------------------------- public

    def reset(self):
        """Forget the keyframes and every track; the next frame starts a new sequence (new
        ids continue from the last one: ids are never reused by one tracker)."""
        self._keyframes = {}          # frame number -> _Keyframe
        self._shape = None            # (H, W) of the sequence
        self._region_ref = None       # (H, W) bool region at the newest keyframe
        self._cells = np.zeros((0, 2), np.int64)    # (G, 2) its grid points
        self._last = None             # (H, W) uint8 last frame tracked
        self._step_flow = None        # (h, w, 2) float32 DIS flow last -> current frame, a box
        self._ids = np.zeros(0, np.uint32)
        self._key = np.zeros(0, np.int64)                              # (P,) keyframe
        self._uv_ref = np.zeros((0, 2), np.float32)                   # (P, 2) in it
        self._ref_patches = np.zeros((0, len(_OFFSETS)), np.float32)   # (P, n) zero-mean
        self._uv = np.zeros((0, 2), np.float64)
        self._born = np.zeros(0, np.int64)
        self._misses = np.zeros(0, np.int64)                        # (P,) failed checks in a row
        self._frame = -1
        self._newest_key = -1
        self._uint16_shift = None

    def track(self, image):
        """Track one frame; returns its :class:`TrackFrame`."""
        grey, self._uint16_shift = to_grey(image, self.channel_order, self._uint16_shift)
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
        self._new_keyframe(grey, np.zeros(0, bool), region_mask(self.region, grey.shape), counts)

    def _follow(self, grey, counts):
        """Track the alive tracks into ``grey``; kill, re-anchor, birth."""
        guess = self._predict(grey)
        uv, zncc, ok = self._refine(grey, guess)
        passed = ok & (zncc >= self.min_zncc)
        if self.fb_max_px is not None:
            passed &= self._forward_backward(grey, uv) <= self.fb_max_px
        uv = np.where(ok[:, None], uv, guess)        # a missed track moves with its prediction
        inside = _inside(uv, grey.shape)
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
            region = carried_region(self.region, self._region_ref, self._uv[healthy],
                                    self.step, grey.shape) if by_count or uncovered else None
            self._new_keyframe(grey, (stale | by_count) & healthy, region, counts)

    def _predict(self, grey):
        """Where the alive tracks ``(P, 2) float32`` are expected in ``grey``: moved by DIS
        from the last frame (computed in the box around them), or where they were."""
        guess = self._uv.astype(np.float32)
        if self._dis is None or len(guess) == 0:
            return guess
        x0, y0, x1, y1 = _box(guess, grey.shape, _FLOW_MARGIN)
        last = np.ascontiguousarray(self._last[y0:y1, x0:x1])
        init = None
        if self._step_flow is not None and self._step_flow.shape[:2] == last.shape:
            init = self._step_flow
        else:                 # OpenCV's DIS can crash on a new size after an initial flow
            self._dis = cv2.DISOpticalFlow.create(self._dis_preset)
        self._step_flow = self._dis.calc(last, np.ascontiguousarray(grey[y0:y1, x0:x1]), init)
        origin = np.float32([x0, y0])
        return guess + sample(self._step_flow, guess - origin)

    def _refine(self, grey, guess):
        """``(uv: (P, 2) float64, zncc: (P,), ok: (P,) bool)``: each keyframe's tracks
        refined against it, on the normalised frame (computed once, in the box around the
        guesses)."""
        uv = guess.astype(np.float64)
        zncc, ok = np.zeros(len(uv)), np.ones(len(uv), bool)
        if len(uv) == 0:
            return uv, zncc, ok
        x0, y0, x1, y1 = _box(guess, grey.shape, _WARP_MARGIN + self.lk_window)
        raw = grey[y0:y1, x0:x1]
        current = _Crop(_normalise(raw), np.float32([x0, y0]), raw)
        for key in np.unique(self._key):
            rows = np.flatnonzero(self._key == key)
            uv[rows], zncc[rows], ok[rows] = self._refine_keyframe(
                self._keyframes[key], current, self._uv_ref[rows], self._ref_patches[rows],
                guess[rows], both_ways=bool((self._misses[rows] == 0).any()))
        return uv, zncc, ok & np.isfinite(uv[:, 0]) & np.isfinite(uv[:, 1])

    def _refine_keyframe(self, keyframe, current, ref, patches, guess, both_ways=True):
        """Tracks of one keyframe at ``ref (P, 2)`` in it, with their reference
        ``patches (P, n)``: the frame ``current`` (a :class:`_Crop`) is warped into the
        keyframe by the displacement field of the ``guess`` es (where the method warps)
        and normalised, then Lucas-Kanade from the normalised keyframe corrects what the
        field missed; the ZNCC check is taken in the warped frame; a track whose ZNCC is
        under ``_SMOOTH_ZNCC`` is pulled toward its passing neighbours' field (fully at
        ``min_zncc``). Returns ``(uv (P, 2), zncc (P,), ok (P,))``."""
        shape = keyframe.normalised.shape
        if not self._warp:
            image = cv2.copyMakeBorder(current.image, int(current.origin[1]), max(
                shape[0] - int(current.origin[1]) - current.image.shape[0], 0), int(
                current.origin[0]), max(shape[1] - int(current.origin[0])
                                        - current.image.shape[1], 0), cv2.BORDER_REPLICATE)
            uv, ok = guess, np.ones(len(ref), bool)
            if self._refine_lk:
                uv, ok = self._lk(keyframe.normalised, image, ref, guess)
            if self._refine_lk and self._dis is not None:
                ok &= np.linalg.norm(uv - guess, axis=1) <= _MAX_REFINEMENT
            return uv, _patch_zncc(patches, _smoothed(image), uv), ok
        x0, y0, x1, y1 = _box(ref, shape, _WARP_MARGIN + self.lk_window)
        origin = np.float32([x0, y0])
        local = ref - origin
        splat = _splat(local, (y1 - y0, x1 - x0), self.step)
        field = _displacement_field(local, guess - ref, (y1 - y0, x1 - x0), self.step, splat)
        warped = _normalise(_warp(current.raw, current.origin, field, origin))
        where, ok = local, np.ones(len(ref), bool)
        if self._refine_lk:
            where, ok = self._lk(
                np.ascontiguousarray(keyframe.normalised[y0:y1, x0:x1]), warped, local,
                local.copy())
            if self._dis is not None:
                ok &= np.linalg.norm(where - local, axis=1) <= _MAX_REFINEMENT
        uv = where + origin + sample(field, where)
        zncc = _patch_zncc(patches, _smoothed(warped), where)
        if self._refine_lk and both_ways:
            back, both = self._refine_in_frame(keyframe, current, ref, uv.astype(np.float32))
            uv = np.where(both[:, None], 0.5 * (uv + back), uv)
        if self._refine_lk and self.min_zncc < _SMOOTH_ZNCC:
            weight = np.clip((_SMOOTH_ZNCC - zncc) / (_SMOOTH_ZNCC - self.min_zncc), 0.0, 1.0)
            uv = uv + weight[:, None] * (_neighbour_moves(
                splat, local, uv - ref, ok & (zncc >= self.min_zncc)) - (uv - ref))
        return uv, zncc, ok

    def _refine_in_frame(self, keyframe, current, ref, guess):
        """The same tracks measured the other way round: the normalised keyframe warped
        into the frame's box by the field from the ``guess`` es back to ``ref``, then LK
        from it to the normalised frame ``current``; returns ``(uv: (P, 2), ok: (P,))``.
        The two ways err in opposite directions where the view is foreshortened or
        stretched against the keyframe, so the tracker takes their mean."""
        current = _sub_crop(current, guess, _WARP_MARGIN + self.lk_window)
        local = guess - current.origin
        field = _displacement_field(local, ref - guess, current.image.shape, self.step)
        warped = _normalise(_warp(keyframe.grey, np.float32([0, 0]), field, current.origin))
        source = local
        for _ in range(_INVERSE_STEPS):       # where the warped keyframe shows each ``ref``
            source = ref - current.origin - sample(field, source)
        moved, ok = self._lk(warped, current.image, source, local.copy())
        ok &= np.linalg.norm(moved - local, axis=1) <= _MAX_REFINEMENT
        return moved + current.origin, ok

    def _forward_backward(self, grey, uv):
        """Distance ``(P,)`` between each track's keyframe point and its point tracked back
        from ``uv`` into its keyframe (LK on normalised images)."""
        points = uv.astype(np.float32)
        back = np.full(len(uv), np.inf)
        current = _normalise(grey)
        for key in np.unique(self._key):
            rows = np.flatnonzero(self._key == key)
            moved, ok = self._lk(current, self._keyframes[key].normalised, points[rows],
                                 self._uv_ref[rows].copy())
            distance = np.linalg.norm(moved - self._uv_ref[rows], axis=1)
            back[rows] = np.where(ok, distance, np.inf)
        return back

    def _needs_keyframe(self, shape):
        """``(by_count, uncovered)``: whether the current frame should become a keyframe for
        every track (``reanchor_every``), and whether too much of the region is uncovered
        (new tracks to be born)."""
        by_count = self.reanchor_every is not None and \
            self._frame - self._newest_key >= self.reanchor_every
        uncovered = _uncovered_share(self._cells, self._uv, self.step, shape) > \
            self.reanchor_uncovered
        return by_count, uncovered

    def _new_keyframe(self, grey, move, region, counts):
        """The current frame becomes a keyframe: the tracks ``move`` (and those of the
        oldest keyframe beyond ``max_keyframes``) are re-anchored to it, keeping their ids;
        with a ``region`` (None: no births), tracks are born on its uncovered cells."""
        key = self._frame
        self._keyframes[key] = self._keyframe_images(grey, region)
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
        self._ref_patches[move] = _centred_patches(self._keyframes[key].smoothed,
                                                   self._uv_ref[move])
        self._newest_key = key
        counts['reanchored'] = 1
        if region is not None:
            self._region_ref = region
            self._cells = region_cells(region, self.step)
            counts['born'] = self._birth(grey, key)
        for old in set(self._keyframes) - set(self._key.tolist()) - {key}:
            del self._keyframes[old]

    def _keep(self, keep):
        """Keep only the tracks ``keep (P,) bool`` (the others die)."""
        self._ids, self._key, self._born = self._ids[keep], self._key[keep], self._born[keep]
        self._uv_ref, self._ref_patches = self._uv_ref[keep], self._ref_patches[keep]
        self._uv, self._misses = self._uv[keep], self._misses[keep]

    def _keyframe_images(self, grey, region):
        """The :class:`_Keyframe` of ``grey``, normalised only in the box where its
        tracks (and births on ``region``) will be measured (128 elsewhere)."""
        points = self._uv
        if region is not None:
            points = np.concatenate([points, region_cells(region, self.step)])
        if len(points) == 0:
            return _Keyframe(grey, np.full(grey.shape, 128, np.uint8),
                             np.full(grey.shape, 128, np.uint8))
        x0, y0, x1, y1 = _box(points, grey.shape, _KEYFRAME_MARGIN + self.lk_window)
        normalised = np.full(grey.shape, 128, np.uint8)
        smoothed = normalised.copy()
        normalised[y0:y1, x0:x1] = _normalise(grey[y0:y1, x0:x1])
        smoothed[y0:y1, x0:x1] = _smoothed(normalised[y0:y1, x0:x1])
        return _Keyframe(grey, normalised, smoothed)

    def _birth(self, grey, key):
        """New tracks on the uncovered, textured grid cells of the region, anchored to the
        keyframe ``key``; returns how many were born."""
        cells = self._cells
        if len(cells):
            cells = cells[~_covered(cells, self._uv, self.step, grey.shape)]
        patches = _centred_patches(grey, cells)
        textured = np.sqrt((patches ** 2).mean(axis=1)) >= self.min_texture
        cells = cells[textured]
        patches = _centred_patches(self._keyframes[key].smoothed, cells)
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


def region_mask(region, shape):
    """The first frame's ``region`` (None, a bool mask or a rectangle) as a bool mask
    ``shape = (H, W)``."""
    H, W = shape
    if isinstance(region, np.ndarray):
        if region.shape != shape:
            raise FrameSizeError(f'region mask is {region.shape[1]} x {region.shape[0]} but '
                                 f'the frame is {W} x {H}')
        return region
    mask = np.zeros(shape, bool)
    if region is None:
        mask[:] = True
    else:
        x0, y0, x1, y1 = region
        mask[max(y0, 0):max(y1 + 1, 0), max(x0, 0):max(x1 + 1, 0)] = True
    return mask


def carried_region(region, region_ref, uv, step, shape):
    """The region in the current frame: a mask moves with its tracks ``uv: (P, 2)`` (the grid
    cells holding tracks, holes closed); a rectangle or the whole image stays where it is
    (``region_ref``). A mask whose tracks are all gone starts again from the first frame's."""
    if not isinstance(region, np.ndarray):
        return region_ref
    carried = _occupied_mask(uv, step, shape)
    return carried if carried.any() else region_mask(region, shape)


def region_cells(region, step):
    """Grid points ``(G, 2)`` int (u, v) of the bool mask ``region``: ``k step + step // 2``."""
    offset = step // 2
    v, u = np.nonzero(region[offset::step, offset::step])
    return np.column_stack([u, v]) * step + offset


def to_grey(image, channel_order='rgb', uint16_shift=None):
    """``(grey, shift)``: a frame as a contiguous ``(H, W)`` uint8 grey image, and the bit
    shift that brings uint16 frames to 8 bits (chosen on a stream's first uint16 frame from its
    largest value, then kept: pass it back)."""
    image = np.asarray(image)
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] not in (3, 4)) \
            or min(image.shape[:2]) < 8:
        raise ValueError(f'a frame must be (H, W), (H, W, 3) or (H, W, 4) with H, W >= 8; '
                         f'got shape {image.shape}')
    if image.dtype == np.uint16:
        if uint16_shift is None:
            uint16_shift = max(int(image.max()).bit_length(), 8) - 8
        image = np.clip(image >> uint16_shift, 0, 255).astype(np.uint8)
    elif np.issubdtype(image.dtype, np.floating):
        image = (np.clip(np.nan_to_num(image), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    elif image.dtype != np.uint8:
        raise ValueError(f'frames must be uint8, uint16 or float in [0, 1]; got {image.dtype}')
    if image.ndim == 3:
        code = {('rgb', 3): cv2.COLOR_RGB2GRAY, ('rgb', 4): cv2.COLOR_RGBA2GRAY,
                ('bgr', 3): cv2.COLOR_BGR2GRAY, ('bgr', 4): cv2.COLOR_BGRA2GRAY}
        image = cv2.cvtColor(image, code[channel_order, image.shape[2]])
    return np.ascontiguousarray(image), uint16_shift


def lucas_kanade(window, levels, src, dst, points, guess):
    """Pyramidal LK (``window`` pixels, ``levels`` pyramid levels) of ``points (P, 2)`` from
    ``src`` to ``dst`` starting at ``guess``: ``(moved (P, 2), ok (P,) bool)``."""
    moved, status, _ = cv2.calcOpticalFlowPyrLK(
        src, dst, points.reshape(-1, 1, 2), guess.reshape(-1, 1, 2).copy(),
        winSize=(window, window), maxLevel=levels,
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, _LK_ITERATIONS, _LK_EPS),
        flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
    return moved.reshape(-1, 2), status.ravel().astype(bool)


def _check_range(name, value, low, high):
    if isinstance(value, bool) or not isinstance(value, (int, float, np.number)) \
            or not low <= float(value) <= high:
        raise ValueError(f'{name} must be a number in [{low}, {high}]; got {value!r}')


def _validate_region(region):
    if region is None:
        return None
    if isinstance(region, np.ndarray) and region.ndim == 2:
        if region.dtype != bool:
            raise ValueError(f'a region mask must be a bool array (H, W); got {region.dtype}')
        if not region.any():
            raise ValueError('the region mask is empty')
        return region
    values = np.asarray(region)
    if values.shape != (4,) or not np.all(np.isfinite(values.astype(float))):
        raise ValueError(f'region must be None, a bool mask (H, W) or a rectangle '
                         f'(x0, y0, x1, y1); got {region!r}')
    x0, y0, x1, y1 = (int(round(float(v))) for v in values)
    if x1 < x0 or y1 < y0:
        raise ValueError(f'region rectangle (x0, y0, x1, y1) needs x0 <= x1 and y0 <= y1; '
                         f'got {region}')
    return (x0, y0, x1, y1)


def _validate_K(K):
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3) or not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f'K must be a finite (3, 3) matrix with fx, fy > 0; got {K!r}')
    return K


def sample(image, points, interpolation=cv2.INTER_LINEAR):
    """Samples ``(N, C)`` float32 of ``image (H, W[, C])`` at float ``points (N, 2)`` (u, v),
    bilinear by default, edges replicated (any N: OpenCV's remap takes under 2^15 rows)."""
    n = len(points)
    width = 1024
    rows = max(-(-n // width), 1)
    where = np.zeros((rows * width, 2), np.float32)
    where[:n] = points
    where = where.reshape(rows, width, 2)
    out = cv2.remap(image, where[..., 0], where[..., 1], interpolation,
                    borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(rows * width, -1)[:n].astype(np.float32)


_OFFSETS = np.stack(np.meshgrid(np.arange(-_PATCH_RADIUS, _PATCH_RADIUS + 1, 2),
                                np.arange(-_PATCH_RADIUS, _PATCH_RADIUS + 1, 2)),
                    axis=-1).reshape(-1, 2).astype(np.float32)        # (n, 2), every 2 px
_OFFSETS_U, _OFFSETS_V = np.ascontiguousarray(_OFFSETS[:, 0]), np.ascontiguousarray(_OFFSETS[:, 1])
_PATCH_GROUP = 32                  # points per row of the patch sampling's remap maps


def _centred_patches(grey, points):
    """``(P, n)`` float32 zero-mean bilinear patches of ``grey`` around ``points (P, 2)``
    (11 x 11 pixels sampled every 2; the remap maps hold ``_PATCH_GROUP`` points per row,
    in chunks of rows that OpenCV's remap takes)."""
    n, k = len(points), len(_OFFSETS)
    rows = max(-(-n // _PATCH_GROUP), 1)
    across = np.zeros((rows * _PATCH_GROUP, 1), np.float32)
    down = np.zeros((rows * _PATCH_GROUP, 1), np.float32)
    across[:n, 0], down[:n, 0] = points[:, 0], points[:, 1]
    across = (across + _OFFSETS_U).reshape(rows, _PATCH_GROUP * k)
    down = (down + _OFFSETS_V).reshape(rows, _PATCH_GROUP * k)
    patches = np.concatenate([cv2.remap(grey, across[r:r + _REMAP_ROWS], down[r:r + _REMAP_ROWS],
                                        cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
                              for r in range(0, rows, _REMAP_ROWS)])
    patches = patches.reshape(-1, k)[:n].astype(np.float32)
    return patches - patches.mean(axis=1, keepdims=True)


def _patch_zncc(ref_patches, grey, points):
    """Zero-mean normalised cross-correlation ``(P,)`` of each track's patch in ``grey``
    against its zero-mean reference patch ``ref_patches (P, n)``; flat patches (std under 1
    grey level) score low."""
    if len(points) == 0:
        return np.zeros(0)
    b = _centred_patches(grey, points)
    a = ref_patches
    n = a.shape[1]
    denom = np.sqrt((np.einsum('ij,ij->i', a, a) + n) * (np.einsum('ij,ij->i', b, b) + n))
    return np.einsum('ij,ij->i', a, b) / denom


def _inside(uv, shape):
    H, W = shape
    return ((uv[:, 0] >= _BORDER) & (uv[:, 0] <= W - 1 - _BORDER)
            & (uv[:, 1] >= _BORDER) & (uv[:, 1] <= H - 1 - _BORDER))


def _cell_index(points, step, shape):
    """Flat index of each point's grid cell (cells of ``step`` pixels) and the cell count."""
    H, W = shape
    rows, cols = -(-H // step), -(-W // step)
    c = np.clip(np.floor(points[:, 0] / step).astype(np.int64), 0, cols - 1)
    r = np.clip(np.floor(points[:, 1] / step).astype(np.int64), 0, rows - 1)
    return r * cols + c, rows * cols


def _covered(cells, uv, step, shape):
    """``(G,)`` bool: which grid points ``cells (G, 2)`` (``k step + step // 2``) have one
    of the tracks ``uv`` within ``_COVER_RADIUS`` grid steps. That radius is under a step,
    so a track can only cover the 4 grid points around it: those are marked on the grid."""
    if len(uv) == 0 or len(cells) == 0:
        return np.zeros(len(cells), bool)
    H, W = shape
    offset = step // 2
    rows, cols = (H - offset - 1) // step + 1, (W - offset - 1) // step + 1
    u, v = (uv[:, 0] - offset) / step, (uv[:, 1] - offset) / step    # in grid steps
    base_u, base_v = np.floor(u), np.floor(v)
    frac_u, frac_v = u - base_u, v - base_v
    base_u, base_v = base_u.astype(np.int64), base_v.astype(np.int64)
    marked = np.zeros(rows * cols, bool)
    for dr in (0, 1):
        for dc in (0, 1):
            near = (frac_u - dc) ** 2 + (frac_v - dr) ** 2 <= _COVER_RADIUS ** 2
            c, r = base_u[near] + dc, base_v[near] + dr
            on = (c >= 0) & (r >= 0) & (c < cols) & (r < rows)
            marked[r[on] * cols + c[on]] = True
    where = (cells - offset) // step
    return marked[where[:, 1] * cols + where[:, 0]]


def _uncovered_share(cells, uv, step, shape):
    if len(cells) == 0:
        return 0.0
    return 1.0 - float(_covered(cells, uv, step, shape).mean())


def _box(points, shape, margin):
    """``(x0, y0, x1, y1)`` ints, ``x1``/``y1`` exclusive: the bounding box of ``points
    (P, 2)`` grown by ``margin`` pixels, at least ``_MIN_BOX`` pixels a side where the image
    allows, clipped to the image."""
    H, W = shape
    u, v = points[:, 0], points[:, 1]           # (columns: reducing along axis 0 is slow)
    low = np.floor([u.min(), v.min()]) - margin
    high = np.ceil([u.max(), v.max()]) + margin + 1
    grow = np.maximum(_MIN_BOX - (high - low), 0) / 2
    low, high = low - grow, high + grow
    x0, y0 = (int(max(v, 0)) for v in low)
    x1, y1 = int(min(high[0], W)), int(min(high[1], H))
    return x0, y0, max(x1, x0 + 1), max(y1, y0 + 1)


def _sub_crop(crop, points, margin):
    """The part of the :class:`_Crop` ``crop`` around ``points (P, 2)`` (frame pixels):
    their bounding box grown by ``margin``, within the crop."""
    h, w = crop.image.shape
    x0, y0, x1, y1 = _box(points - crop.origin, (h, w), margin)
    if (x0, y0, x1, y1) == (0, 0, w, h):
        return crop
    return _Crop(crop.image[y0:y1, x0:x1], crop.origin + np.float32([x0, y0]),
                 None if crop.raw is None else crop.raw[y0:y1, x0:x1])


def _displacement_field(points, moves, size, step, splat=None):
    """Dense displacement ``(h, w, 2) float32`` of a box ``size (h, w)`` from scattered
    ``points (P, 2)`` (box pixels) that moved by ``moves (P, 2)``: splatted bilinearly onto
    a grid of ``step`` pixels, normalised Gaussian smoothing (about 4 px), upsampled
    (``splat``: :func:`_splat` of the points, when already computed)."""
    h, w = size
    s = int(step)
    coarse = _coarse_field(splat or _splat(points, size, s), moves)
    rows, cols = coarse.shape[:2]
    fine = cv2.resize(coarse, (cols * s, rows * s), interpolation=cv2.INTER_LINEAR)
    return np.ascontiguousarray(fine[s:s + h, s:s + w])


def _on_coarse_grid(points, step):
    """Coordinates ``(P, 2)`` of box pixels ``points`` on :func:`_coarse_field`'s grid."""
    return (points - (step - 1) / 2.0) / step + 1.0     # node j sits at (j - 1) s + (s-1)/2


def _splat(points, size, s):
    """Bilinear splatting of ``points (P, 2)`` (box pixels of a box ``size (h, w)``) onto
    the grid of ``s`` pixels of :func:`_coarse_field`: ``(index (4P,), weight (4P,),
    (rows, cols), s)``."""
    h, w = size
    rows, cols = h // s + 3, w // s + 3
    where = _on_coarse_grid(points, s)
    base = np.floor(where).astype(np.int64)
    frac = (where - base).astype(np.float32)
    u_weights = (1 - frac[:, 0], frac[:, 0])
    v_weights = (1 - frac[:, 1], frac[:, 1])
    columns = [np.minimum(np.maximum(base[:, 0] + d, 0), cols - 1) for d in (0, 1)]
    row_starts = [np.minimum(np.maximum(base[:, 1] + d, 0), rows - 1) * cols for d in (0, 1)]
    index = np.concatenate([row_starts[dr] + columns[dc] for dr in (0, 1) for dc in (0, 1)])
    weight = np.concatenate([v_weights[dr] * u_weights[dc] for dr in (0, 1) for dc in (0, 1)])
    return index, weight, (rows, cols), s


def _coarse_field(splat, moves, use=None):
    """:func:`_displacement_field` on its grid (see :func:`_on_coarse_grid`): ``(rows,
    cols, 2) float32`` from the :func:`_splat` of the points and their ``moves (P, 2)``;
    ``use (P,)`` bool: only those points (None: all)."""
    index, weight, (rows, cols), s = splat
    if use is not None:
        weight = weight * np.tile(use, 4)
    acc = np.empty((rows * cols, 3), np.float32)       # (grid nodes, [u, v, weight] sums)
    for c, values in enumerate((np.tile(moves[:, 0], 4) * weight,
                                np.tile(moves[:, 1], 4) * weight, weight)):
        acc[:, c] = np.bincount(index, values, minlength=rows * cols)
    acc = cv2.GaussianBlur(acc.reshape(rows, cols, 3), (0, 0), max(1.0, _FIELD_SIGMA / s))
    acc = acc.reshape(-1, 3)
    total = np.maximum(acc[:, 2], np.float32(1e-6))       # the splat weight at each node
    field = np.empty((rows * cols, 2), np.float32)
    for c in (0, 1):                    # (one strided division per channel: the fast way)
        np.divide(acc[:, c], total, out=field[:, c])
    return field.reshape(rows, cols, 2)


def _neighbour_moves(splat, points, moves, trusted):
    """``(P, 2)``: the smooth displacement field of the ``trusted (P,)`` tracks' ``moves
    (P, 2)`` at ``points (P, 2)`` (box pixels; ``splat`` their :func:`_splat`); where fewer
    than 4 tracks are trusted, the moves themselves."""
    if trusted.sum() < 4:
        return moves
    coarse = _coarse_field(splat, moves.astype(np.float32), trusted)
    return sample(coarse, _on_coarse_grid(points, splat[3])).astype(np.float64)


def _smoothed(image):
    """``image`` blurred by ``_CHECK_SIGMA``: the ZNCC check compares these, so that the
    detail a foreshortened view loses does not fail a track."""
    return cv2.GaussianBlur(image, (0, 0), _CHECK_SIGMA)


def _warp(image, image_origin, field, origin):
    """The box at ``origin (x0, y0)`` of one image, filled from another ``image`` whose
    pixel (0, 0) is at ``image_origin``: ``out(x) = image(origin + x + field(x) -
    image_origin)`` for a displacement ``field (h, w, 2)`` (pixels)."""
    h, w = field.shape[:2]
    shift = origin - image_origin
    across = field[..., 0] + (np.arange(w, dtype=np.float32) + shift[0])[None, :]
    down = field[..., 1] + (np.arange(h, dtype=np.float32) + shift[1])[:, None]
    return cv2.remap(image, across, down, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def _normalise(grey, sigma=_NORM_SIGMA):
    """``grey (h, w)`` with its local mean removed and its local contrast equalised
    (Gaussian windows of ``sigma`` px), as uint8 around 128 (40 grey levels per local
    standard deviation): Lucas-Kanade on it is blind to shading gain and offset."""
    image = grey.astype(np.float32, copy=False)
    size = (2 * int(round(sigma)) + 1,) * 2       # a box twice: a tent, about a Gaussian
    blur = partial(cv2.boxFilter, ddepth=-1, ksize=size, borderType=cv2.BORDER_REPLICATE)
    detail = cv2.subtract(image, blur(blur(image)))
    spread = np.maximum(blur(blur(cv2.multiply(detail, detail))), 0.0)   # (rounding: >= 0)
    gain = cv2.divide(40.0, cv2.sqrt(spread) + 1.0)
    return cv2.add(cv2.multiply(detail, gain), 127.5, dtype=cv2.CV_8U)   # rounded, clipped


def _occupied_mask(uv, step, shape, close_cells=9):
    """The grid cells holding tracks, with holes up to ``close_cells`` cells across closed
    (where tracks died inside the surface, new ones can be born), as a pixel mask
    ``(H, W)``; it does not grow past the outer tracks."""
    H, W = shape
    index, n = _cell_index(uv, step, shape)
    rows, cols = -(-H // step), -(-W // step)
    cells = np.zeros(n, np.uint8)
    cells[index] = 1
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (close_cells, close_cells))
    cells = cv2.morphologyEx(cells.reshape(rows, cols), cv2.MORPH_CLOSE, kernel,
                             borderType=cv2.BORDER_CONSTANT, borderValue=0)
    return np.kron(cells, np.ones((step, step), np.uint8))[:H, :W].astype(bool)
