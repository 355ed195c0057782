"""Dense 2D tracks anchored to a reference frame (OpenCV optical flow, no ROS).

:class:`DenseTracker` follows the points of a grid of ``step`` pixels inside a region from a
*reference* frame into each new frame: the flow is always computed from the reference to the
current frame (never chained frame to frame), so a track's error does not grow with time. The
reference is renewed ("re-anchored") when the appearance has changed too much or too much of
the region has lost its tracks; then new tracks are born on the grid cells of the region that
hold no track. A track dies when it leaves the image or fails a check (a photometric ZNCC check
of its patch against the reference, and optionally a forward-backward check): occlusion shows
up as a failed check. Ids are never reused within a sequence (until :meth:`reset`).

Shapes and units:

* a frame: ``(H, W)`` grey or ``(H, W, 3)`` / ``(H, W, 4)`` colour (``channel_order`` 'rgb'
  or 'bgr'), uint8, uint16 (scaled to 8 bits by the bit depth of the first uint16 frame) or
  float in [0, 1];
* ``region``: None (the whole image), a bool mask ``(H, W)`` of the first frame (it moves
  with the surface: at each re-anchoring it becomes the grid cells its tracks hold, holes
  closed) or a rectangle ``(x0, y0, x1, y1)`` of pixels, bounds included (fixed
  in the image);
* :class:`TrackFrame`: ``ids: (P,) uint32``, ``uv: (P, 2) float64`` pixels (pixel centres at
  integer coordinates, u to the right, v down), ``age: (P,) int64`` frames since birth,
  ``counts`` a dict of ints.

A frame of another size than the reference raises :class:`FrameSizeError` (call
:meth:`DenseTracker.reset` to start a new sequence at the new size). A blank frame (black,
saturated or flat) gives no tracks, warns once and keeps the state, so tracking resumes on the
next good frame.
"""
from dataclasses import dataclass, field
import warnings

import cv2
import numpy as np
from scipy.spatial import cKDTree

#: flow methods: a DIS preset from the reference to the frame (its last flow as the initial
#: flow), optionally refined per track by Lucas-Kanade from the reference ('+lk'); or DIS
#: from the previous frame predicting where LK from the reference starts ('/prev+lk'); or
#: pyramidal Lucas-Kanade from the reference alone, starting at the last positions ('lk')
METHODS = ('dis-ultrafast', 'dis-fast', 'dis-medium',
           'dis-ultrafast+lk', 'dis-fast+lk', 'dis-medium+lk',
           'dis-ultrafast/prev+lk', 'dis-fast/prev+lk', 'dis-medium/prev+lk', 'lk')
_DIS_PRESETS = {'dis-ultrafast': cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST,
                'dis-fast': cv2.DISOPTICAL_FLOW_PRESET_FAST,
                'dis-medium': cv2.DISOPTICAL_FLOW_PRESET_MEDIUM}
DEFAULT_METHOD = 'dis-fast+lk'
_PATCH_RADIUS = 5                  # photometric check and texture test on 11 x 11 patches
_MAX_REFINEMENT = 1.0              # px: DIS and its LK refinement disagreeing more: failed
_COVER_RADIUS = 0.75               # grid steps: a grid point with no track this near is uncovered
_BORDER = 2.0                      # a track closer than this to the image edge has left it


class FrameSizeError(ValueError):
    """A frame's size differs from the sequence's reference frame."""


@dataclass(frozen=True, eq=False)
class TrackFrame:
    """The tracks alive in one frame.

    ``ids: (P,) uint32``, ``uv: (P, 2) float64`` pixels, ``age: (P,) int64`` frames since
    each track was born; ``counts``: 'alive', 'born', 'lost' (died this frame: 'left' the
    image or 'failed' a check), 'failed', 'left', 'reanchored' (1 when this frame became the
    reference), 'blank' (1 for a blank frame, which has no tracks); ``K: (3, 3)`` or None.
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
    """Dense grid tracks anchored to a reference frame; one instance per image stream.

    ``step`` grid spacing in pixels (int >= 1); ``region`` None, a bool mask ``(H, W)`` or a
    rectangle ``(x0, y0, x1, y1)``; ``method`` one of :data:`METHODS`; ``K`` optional
    intrinsics ``(3, 3)`` carried into each :class:`TrackFrame`.

    Checks: ``min_zncc`` (a track whose 11 x 11 patch correlates less than this with its
    reference patch dies), ``fb_max_px`` (forward-backward distance above which a track dies;
    None: no forward-backward check). Re-anchoring: when the median ZNCC of the tracks falls
    below ``reanchor_zncc``, when more than ``reanchor_uncovered`` of the region's grid cells
    hold no track (a grid point is covered by a track within 0.75 steps), or every
    ``reanchor_every`` frames (None: never by count). Births only on cells whose reference
    patch has a grey-level standard deviation of at least ``min_texture``. ``lk_window``
    (odd) and ``lk_levels`` (pyramid levels; None: 0 after DIS from the reference, 1 after
    DIS from the previous frame, 3 for 'lk') set the Lucas-Kanade refinement, which fails a
    track when it moves it more than 1 px from DIS; ``channel_order`` of colour frames;
    ``blank_std``: a frame whose grey levels vary less than this is blank. Why these
    defaults: docs/decisions/0600.
    """

    def __init__(self, step=4, region=None, method=DEFAULT_METHOD, *, K=None, min_zncc=0.8,
                 fb_max_px=None, reanchor_zncc=0.9, reanchor_uncovered=0.1,
                 reanchor_every=None, min_texture=2.0, lk_window=11, lk_levels=None,
                 channel_order='rgb', blank_std=2.0):
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
        if lk_levels is not None and (not isinstance(lk_levels, (int, np.integer))
                                      or not 0 <= lk_levels <= 6):
            raise ValueError(f'lk_levels must be None or an int in [0, 6]; got {lk_levels!r}')
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
        self._dis = None if preset is None else cv2.DISOpticalFlow.create(preset)
        self._refine = method.endswith('+lk') or method == 'lk'
        self._chain = '/prev' in method
        self.lk_levels = lk_levels if lk_levels is not None else (
            3 if self._dis is None else 1 if self._chain else 0)
        self._next_id = 0
        self._warned = set()
        self.reset()

    # ---------------------------------------------------------------- public

    def reset(self):
        """Forget the reference and every track; the next frame starts a new sequence (new
        ids continue from the last one: ids are never reused by one tracker)."""
        self._ref = None              # (H, W) uint8 reference frame
        self._region_ref = None       # (H, W) bool region in the reference frame
        self._flow = None             # (H, W, 2) float32 flow reference -> last frame
        self._last = None             # (H, W) uint8 last frame tracked
        self._ids = np.zeros(0, np.uint32)
        self._uv_ref = np.zeros((0, 2), np.float32)
        self._ref_patches = np.zeros((0, len(_OFFSETS)), np.float32)   # (P, n) zero-mean
        self._uv = np.zeros((0, 2), np.float64)
        self._born = np.zeros(0, np.int64)
        self._frame = -1
        self._ref_frame = -1
        self._uint16_shift = None

    def track(self, image):
        """Track one frame; returns its :class:`TrackFrame`."""
        grey = self._to_grey(image)
        self._frame += 1
        if self._ref is not None and grey.shape != self._ref.shape:
            raise FrameSizeError(
                f'frame {self._frame} is {grey.shape[1]} x {grey.shape[0]} pixels but the '
                f'reference is {self._ref.shape[1]} x {self._ref.shape[0]}; call reset() to '
                f'start a new sequence at the new size')
        counts = dict(alive=0, born=0, lost=0, failed=0, left=0, reanchored=0, blank=0)
        if float(grey.std()) < self.blank_std:
            self._warn_once('blank', f'blank frame (grey-level std {grey.std():.2f} < '
                            f'{self.blank_std}): no tracks in it, the state is kept')
            counts['blank'] = 1
            return self._frame_out(np.zeros(0, bool), counts)
        if self._ref is None:
            self._start(grey, counts)
        else:
            self._follow(grey, counts)
        self._last = grey
        return self._frame_out(np.ones(len(self._ids), bool), counts)

    @property
    def n_alive(self):
        """Tracks alive after the last frame."""
        return len(self._ids)

    # ---------------------------------------------------------------- steps

    def _start(self, grey, counts):
        """First frame of a sequence: it is the reference; tracks born on the region's grid."""
        region = self._region_mask(grey.shape)
        self._set_reference(grey, region)
        counts['reanchored'] = 1
        counts['born'] = self._birth(grey)

    def _follow(self, grey, counts):
        """Track the alive tracks from the reference into ``grey``; kill, re-anchor, birth."""
        uv, ok_flow = self._flow_tracks(grey)
        inside = _inside(uv, grey.shape)
        zncc = _patch_zncc(self._ref_patches, grey, uv)
        passed = ok_flow & (zncc >= self.min_zncc)
        if self.fb_max_px is not None:
            passed &= self._forward_backward(grey, uv) <= self.fb_max_px
        keep = inside & passed
        counts['left'] = int((~inside).sum())
        counts['failed'] = int((inside & ~passed).sum())
        counts['lost'] = int((~keep).sum())
        median_zncc = float(np.median(zncc[keep])) if keep.any() else -1.0
        self._ids, self._uv_ref, self._born = self._ids[keep], self._uv_ref[keep], self._born[keep]
        self._ref_patches = self._ref_patches[keep]
        self._uv = uv[keep]
        if self._needs_reanchor(median_zncc, grey.shape):
            region = self._carried_region(grey.shape)
            self._set_reference(grey, region)
            counts['reanchored'] = 1
            counts['born'] = self._birth(grey)

    def _flow_tracks(self, grey):
        """``(uv: (P, 2) float64, ok: (P,) bool)`` of the alive tracks in ``grey``."""
        if len(self._ids) == 0:
            return np.zeros((0, 2)), np.zeros(0, bool)
        guess = self._uv.astype(np.float32)
        if self._chain:
            step = self._dis.calc(self._last, grey, None)
            guess = guess + sample(step, guess)
            self._flow = _compose(self._flow, step)
        elif self._dis is not None:
            init = self._flow if self._flow is not None else None
            self._flow = self._dis.calc(self._ref, grey, None if init is None else init.copy())
            guess = self._uv_ref + sample(self._flow, self._uv_ref)
        ok = np.ones(len(guess), bool)
        if self._refine:
            dense = guess
            guess, ok = self._lucas_kanade(self._ref, grey, self._uv_ref, guess)
            if self._dis is not None:
                ok &= np.linalg.norm(guess - dense, axis=1) <= _MAX_REFINEMENT
        return guess.astype(np.float64), ok & np.isfinite(guess).all(axis=1)

    def _lucas_kanade(self, src, dst, points, guess):
        """Pyramidal LK of ``points (P, 2)`` from ``src`` to ``dst`` starting at ``guess``."""
        moved, status, _ = cv2.calcOpticalFlowPyrLK(
            src, dst, points.reshape(-1, 1, 2), guess.reshape(-1, 1, 2).copy(),
            winSize=(self.lk_window, self.lk_window), maxLevel=self.lk_levels,
            criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 10, 0.01),
            flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
        return moved.reshape(-1, 2), status.ravel().astype(bool)

    def _forward_backward(self, grey, uv):
        """Distance ``(P,)`` between each track's reference point and its point tracked back
        from ``uv`` into the reference."""
        points = uv.astype(np.float32)
        if self._dis is not None:
            back = self._dis.calc(grey, self._ref, None)
            guess = points + sample(back, points)
        else:
            guess = self._uv_ref.copy()
        if self._refine:
            guess, ok = self._lucas_kanade(grey, self._ref, points, guess)
            guess[~ok] = np.inf
        return np.linalg.norm(guess - self._uv_ref, axis=1)

    def _needs_reanchor(self, median_zncc, shape):
        """Whether the current frame should become the reference."""
        if self.reanchor_every is not None and \
                self._frame - self._ref_frame >= self.reanchor_every:
            return True
        if median_zncc < self.reanchor_zncc:
            return True
        cells = self._region_cells(self._region_ref)
        return _uncovered_share(cells, self._uv, self.step, shape) > self.reanchor_uncovered

    def _set_reference(self, grey, region):
        self._ref = grey
        self._region_ref = region
        self._ref_frame = self._frame
        self._flow = None
        self._uv_ref = self._uv.astype(np.float32)
        self._ref_patches = _centred_patches(grey, self._uv_ref)

    def _birth(self, grey):
        """New tracks on the uncovered, textured grid cells of the reference region; returns
        how many were born."""
        cells = self._region_cells(self._region_ref)
        if len(cells):
            cells = cells[~_covered(cells, self._uv, self.step, grey.shape)]
        patches = _centred_patches(grey, cells)
        textured = np.sqrt((patches ** 2).mean(axis=1)) >= self.min_texture
        cells, patches = cells[textured], patches[textured]
        n = len(cells)
        new_ids = self._next_id + np.arange(n, dtype=np.int64)
        if new_ids.size and new_ids[-1] >= 2 ** 32:
            raise OverflowError('track ids exhausted (2^32); create a new DenseTracker')
        self._next_id += n
        self._ids = np.concatenate([self._ids, new_ids.astype(np.uint32)])
        self._uv = np.concatenate([self._uv, cells.astype(np.float64)])
        self._uv_ref = np.concatenate([self._uv_ref, cells.astype(np.float32)])
        self._born = np.concatenate([self._born, np.full(n, self._frame, np.int64)])
        self._ref_patches = np.concatenate([self._ref_patches, patches])
        return n

    # ---------------------------------------------------------------- region

    def _region_mask(self, shape):
        """The region of the first frame as a bool mask ``(H, W)``."""
        H, W = shape
        if isinstance(self.region, np.ndarray):
            if self.region.shape != shape:
                raise FrameSizeError(f'region mask is {self.region.shape[1]} x '
                                     f'{self.region.shape[0]} but the frame is {W} x {H}')
            return self.region
        mask = np.zeros(shape, bool)
        if self.region is None:
            mask[:] = True
        else:
            x0, y0, x1, y1 = self.region
            mask[max(y0, 0):max(y1 + 1, 0), max(x0, 0):max(x1 + 1, 0)] = True
        return mask

    def _carried_region(self, shape):
        """The region in the current frame: a mask moves with its tracks (the grid cells
        holding tracks, holes closed); a rectangle or the whole image stays where it is. A
        mask whose tracks are all gone starts again from the first frame's."""
        if not isinstance(self.region, np.ndarray):
            return self._region_ref
        carried = _occupied_mask(self._uv, self.step, shape)
        return carried if carried.any() else self._region_mask(shape)

    def _region_cells(self, region):
        """Grid points ``(G, 2)`` int (u, v) of the region: ``k step + step // 2``."""
        offset = self.step // 2
        rows = region[offset::self.step, offset::self.step]
        v, u = np.nonzero(rows)
        return np.column_stack([u, v]) * self.step + offset

    # ---------------------------------------------------------------- input

    def _to_grey(self, image):
        """A frame as a contiguous ``(H, W)`` uint8 grey image."""
        image = np.asarray(image)
        if image.ndim == 3 and image.shape[2] == 1:
            image = image[:, :, 0]
        if image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] not in (3, 4)) \
                or min(image.shape[:2]) < 8:
            raise ValueError(f'a frame must be (H, W), (H, W, 3) or (H, W, 4) with H, W >= 8; '
                             f'got shape {image.shape}')
        image = self._to_uint8(image)
        if image.ndim == 3:
            code = {('rgb', 3): cv2.COLOR_RGB2GRAY, ('rgb', 4): cv2.COLOR_RGBA2GRAY,
                    ('bgr', 3): cv2.COLOR_BGR2GRAY, ('bgr', 4): cv2.COLOR_BGRA2GRAY}
            image = cv2.cvtColor(image, code[self.channel_order, image.shape[2]])
        return np.ascontiguousarray(image)

    def _to_uint8(self, image):
        if image.dtype == np.uint8:
            return image
        if image.dtype == np.uint16:
            if self._uint16_shift is None:
                bits = max(int(image.max()).bit_length(), 8)
                self._uint16_shift = bits - 8
            return np.clip(image >> self._uint16_shift, 0, 255).astype(np.uint8)
        if np.issubdtype(image.dtype, np.floating):
            return (np.clip(np.nan_to_num(image), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
        raise ValueError(f'frames must be uint8, uint16 or float in [0, 1]; got {image.dtype}')

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


def _centred_patches(grey, points):
    """``(P, n)`` float32 zero-mean bilinear patches of ``grey`` around ``points (P, 2)``
    (11 x 11 pixels sampled every 2)."""
    where = points.astype(np.float32)[:, None, :] + _OFFSETS[None]   # (P, n, 2)
    patches = sample(grey, where.reshape(-1, 2)).reshape(len(points), len(_OFFSETS))
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
    denom = np.sqrt(((a * a).sum(1) + n) * ((b * b).sum(1) + n))
    return (a * b).sum(1) / denom


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
    """``(G,)`` bool: which grid points have one of the tracks ``uv`` within
    ``_COVER_RADIUS`` grid steps (``shape`` unused: kept for the callers' symmetry)."""
    if len(uv) == 0 or len(cells) == 0:
        return np.zeros(len(cells), bool)
    distance, _ = cKDTree(uv).query(cells, distance_upper_bound=_COVER_RADIUS * step)
    return np.isfinite(distance)


def _uncovered_share(cells, uv, step, shape):
    if len(cells) == 0:
        return 0.0
    return 1.0 - float(_covered(cells, uv, step, shape).mean())


def _compose(first, second):
    """Flow ``(H, W, 2)`` of ``first`` (a -> b, None: zero) followed by ``second`` (b -> c)."""
    if first is None:
        return second
    H, W = first.shape[:2]
    grid = np.stack(np.meshgrid(np.arange(W, dtype=np.float32),
                                np.arange(H, dtype=np.float32)), axis=-1)
    where = grid + first
    return first + cv2.remap(second, where[..., 0], where[..., 1], cv2.INTER_LINEAR,
                             borderMode=cv2.BORDER_REPLICATE)


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
