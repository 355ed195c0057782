"""Image operations the dense tracker measures with (OpenCV, no ROS).

Frames as uint8 grey (:func:`to_grey`), bilinear samples at float points (:func:`sample`),
Lucas-Kanade from given guesses (:func:`lucas_kanade`), warps by a displacement field
(:func:`warp`), the local normalisation Lucas-Kanade runs on (:func:`normalise`) and the
photometric check: zero-mean patches of ``len(OFFSETS)`` samples (11 x 11 pixels, every 2)
and their ZNCC (:func:`centred_patches`, :func:`patch_zncc`) on :func:`smoothed` images.

Points are ``(P, 2)`` float pixels (u, v), pixel centres at integer coordinates.
"""
from functools import partial

import cv2
import numpy as np

_PATCH_RADIUS = 5                  # photometric check and texture test on 11 x 11 patches
_REMAP_ROWS = 32000                # OpenCV's remap takes maps of under 2^15 rows
_LK_ITERATIONS = 5                 # LK stops after this many steps, or a step under:
_LK_EPS = 0.03                     # px
_CHECK_SIGMA = 1.0                 # px: blur of both sides of the ZNCC check
_NORM_SIGMA = 4.0                  # px: windows of the local normalisation before LK


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


OFFSETS = np.stack(np.meshgrid(np.arange(-_PATCH_RADIUS, _PATCH_RADIUS + 1, 2),
                               np.arange(-_PATCH_RADIUS, _PATCH_RADIUS + 1, 2)),
                   axis=-1).reshape(-1, 2).astype(np.float32)        # (n, 2), every 2 px

_OFFSETS_U, _OFFSETS_V = np.ascontiguousarray(OFFSETS[:, 0]), np.ascontiguousarray(OFFSETS[:, 1])

_PATCH_GROUP = 32                  # points per row of the patch sampling's remap maps


def centred_patches(grey, points):
    """``(P, n)`` float32 zero-mean bilinear patches of ``grey`` around ``points (P, 2)``
    (11 x 11 pixels sampled every 2; the remap maps hold ``_PATCH_GROUP`` points per row,
    in chunks of rows that OpenCV's remap takes)."""
    n, k = len(points), len(OFFSETS)
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


def patch_zncc(ref_patches, grey, points):
    """Zero-mean normalised cross-correlation ``(P,)`` of each track's patch in ``grey``
    against its zero-mean reference patch ``ref_patches (P, n)``; flat patches (std under 1
    grey level) score low."""
    if len(points) == 0:
        return np.zeros(0)
    b = centred_patches(grey, points)
    a = ref_patches
    n = a.shape[1]
    denom = np.sqrt((np.einsum('ij,ij->i', a, a) + n) * (np.einsum('ij,ij->i', b, b) + n))
    return np.einsum('ij,ij->i', a, b) / denom


def smoothed(image):
    """``image`` blurred by ``_CHECK_SIGMA``: the ZNCC check compares these, so that the
    detail a foreshortened view loses does not fail a track."""
    return cv2.GaussianBlur(image, (0, 0), _CHECK_SIGMA)


def warp(image, image_origin, field, origin):
    """The box at ``origin (x0, y0)`` of one image, filled from another ``image`` whose
    pixel (0, 0) is at ``image_origin``: ``out(x) = image(origin + x + field(x) -
    image_origin)`` for a displacement ``field (h, w, 2)`` (pixels)."""
    h, w = field.shape[:2]
    shift = origin - image_origin
    across = field[..., 0] + (np.arange(w, dtype=np.float32) + shift[0])[None, :]
    down = field[..., 1] + (np.arange(h, dtype=np.float32) + shift[1])[:, None]
    return cv2.remap(image, across, down, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def normalise(grey, sigma=_NORM_SIGMA):
    """``grey (h, w)`` with its local mean removed and its local contrast equalised
    (Gaussian windows of ``sigma`` px), as uint8 around 128 (40 grey levels per local
    standard deviation): Lucas-Kanade on it is blind to shading gain and offset."""
    image = grey.astype(np.float32, copy=False)
    size = (2 * int(round(sigma)) + 1,) * 2       # a box twice: a tent, about a Gaussian
    blur = partial(cv2.boxFilter, ddepth=-1, ksize=size, borderType=cv2.BORDER_REPLICATE)
    detail = cv2.subtract(image, blur(blur(image)))
    spread = blur(blur(cv2.multiply(detail, detail)))
    cv2.max(spread, 0.0, dst=spread)                                      # (rounding: >= 0)
    cv2.add(cv2.sqrt(spread, dst=spread), 1.0, dst=spread)
    gain = cv2.divide(40.0, spread)
    return cv2.add(cv2.multiply(detail, gain), 127.5, dtype=cv2.CV_8U)   # rounded, clipped
