"""Where the dense tracker works: its region, grid cells and boxes (numpy and OpenCV, no ROS).

A region is None (the whole image), a bool mask ``(H, W)`` or a rectangle ``(x0, y0, x1,
y1)`` (:func:`validate_region`, :func:`region_mask`); grid points ``(G, 2)`` int (u, v) sit
at ``k step + step // 2`` (:func:`region_cells`), and a grid point is covered by a track
within ``_COVER_RADIUS`` steps (:func:`covered`). Boxes are ``(x0, y0, x1, y1)`` ints, ``x1``
/ ``y1`` exclusive (:func:`box`); a :class:`Crop` is a box of a frame.
"""
from dataclasses import dataclass

import cv2
import numpy as np

_COVER_RADIUS = 0.75               # grid steps: a grid point with no track this near is uncovered
_BORDER = 2.0                      # a track closer than this to the image edge has left it
_MIN_BOX = 48                      # px: the smallest box DIS and the warp run in


class FrameSizeError(ValueError):
    """A frame's size differs from the sequence's reference frame."""


@dataclass(frozen=True, eq=False)
class Crop:
    """A box of a frame: ``image (h, w)`` (normalised) and ``raw (h, w)`` float32 grey,
    whose pixel (0, 0) is the frame's ``origin (x0, y0)`` (float32)."""

    image: np.ndarray
    origin: np.ndarray
    raw: np.ndarray = None


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
    carried = occupied_mask(uv, step, shape)
    return carried if carried.any() else region_mask(region, shape)


def region_cells(region, step):
    """Grid points ``(G, 2)`` int (u, v) of the bool mask ``region``: ``k step + step // 2``."""
    offset = step // 2
    v, u = np.nonzero(region[offset::step, offset::step])
    return np.column_stack([u, v]) * step + offset


def validate_region(region):
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


def inside(uv, shape):
    H, W = shape
    return ((uv[:, 0] >= _BORDER) & (uv[:, 0] <= W - 1 - _BORDER)
            & (uv[:, 1] >= _BORDER) & (uv[:, 1] <= H - 1 - _BORDER))


def cell_index(points, step, shape):
    """Flat index of each point's grid cell (cells of ``step`` pixels) and the cell count."""
    H, W = shape
    rows, cols = -(-H // step), -(-W // step)
    c = np.clip(np.floor(points[:, 0] / step).astype(np.int64), 0, cols - 1)
    r = np.clip(np.floor(points[:, 1] / step).astype(np.int64), 0, rows - 1)
    return r * cols + c, rows * cols


def covered(cells, uv, step, shape):
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


def uncovered_share(cells, uv, step, shape):
    if len(cells) == 0:
        return 0.0
    return 1.0 - float(covered(cells, uv, step, shape).mean())


def box(points, shape, margin):
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


def sub_crop(crop, points, margin):
    """The part of the :class:`Crop` ``crop`` around ``points (P, 2)`` (frame pixels):
    their bounding box grown by ``margin``, within the crop."""
    h, w = crop.image.shape
    x0, y0, x1, y1 = box(points - crop.origin, (h, w), margin)
    if (x0, y0, x1, y1) == (0, 0, w, h):
        return crop
    return Crop(crop.image[y0:y1, x0:x1], crop.origin + np.float32([x0, y0]),
                None if crop.raw is None else crop.raw[y0:y1, x0:x1])


def occupied_mask(uv, step, shape, close_cells=9):
    """The grid cells holding tracks, with holes up to ``close_cells`` cells across closed
    (where tracks died inside the surface, new ones can be born), as a pixel mask
    ``(H, W)``; it does not grow past the outer tracks."""
    H, W = shape
    index, n = cell_index(uv, step, shape)
    rows, cols = -(-H // step), -(-W // step)
    cells = np.zeros(n, np.uint8)
    cells[index] = 1
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (close_cells, close_cells))
    cells = cv2.morphologyEx(cells.reshape(rows, cols), cv2.MORPH_CLOSE, kernel,
                             borderType=cv2.BORDER_CONSTANT, borderValue=0)
    return np.kron(cells, np.ones((step, step), np.uint8))[:H, :W].astype(bool)
