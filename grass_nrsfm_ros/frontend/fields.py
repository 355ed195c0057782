"""Smooth displacement fields of scattered tracks (numpy and OpenCV, no ROS).

The tracks' moves ``(P, 2)`` at box pixels ``points (P, 2)`` are splatted bilinearly onto a
grid of ``step`` pixels (:func:`splatting`: ``(index (4P,), weight (4P,), (rows, cols), s)``),
smoothed by a normalised Gaussian (:func:`coarse_field`: ``(rows, cols, 2)``) and upsampled
to the box (:func:`displacement_field`: ``(h, w, 2)`` float32), or read back at the tracks
(:func:`neighbour_moves`).
"""
import cv2
import numpy as np

from .imaging import sample

_FIELD_SIGMA = 4.0                 # px: smoothing of the displacement field of the tracks


def displacement_field(points, moves, size, step, splat=None):
    """Dense displacement ``(h, w, 2) float32`` of a box ``size (h, w)`` from scattered
    ``points (P, 2)`` (box pixels) that moved by ``moves (P, 2)``: splatted bilinearly onto
    a grid of ``step`` pixels, normalised Gaussian smoothing (about 4 px), upsampled
    (``splat``: :func:`splatting` of the points, when already computed)."""
    h, w = size
    s = int(step)
    coarse = coarse_field(splat or splatting(points, size, s), moves)
    rows, cols = coarse.shape[:2]
    fine = cv2.resize(coarse, (cols * s, rows * s), interpolation=cv2.INTER_LINEAR)
    return np.ascontiguousarray(fine[s:s + h, s:s + w])


def on_coarse_grid(points, step):
    """Coordinates ``(P, 2)`` of box pixels ``points`` on :func:`coarse_field`'s grid."""
    return (points - (step - 1) / 2.0) / step + 1.0     # node j sits at (j - 1) s + (s-1)/2


def splatting(points, size, s):
    """Bilinear splatting of ``points (P, 2)`` (box pixels of a box ``size (h, w)``) onto
    the grid of ``s`` pixels of :func:`coarse_field`: ``(index (4P,), weight (4P,),
    (rows, cols), s)``."""
    h, w = size
    rows, cols = h // s + 3, w // s + 3
    where = on_coarse_grid(points, s)
    base = np.floor(where).astype(np.int64)
    frac = (where - base).astype(np.float32)
    u_weights = (1 - frac[:, 0], frac[:, 0])
    v_weights = (1 - frac[:, 1], frac[:, 1])
    columns = [np.minimum(np.maximum(base[:, 0] + d, 0), cols - 1) for d in (0, 1)]
    row_starts = [np.minimum(np.maximum(base[:, 1] + d, 0), rows - 1) * cols for d in (0, 1)]
    index = np.concatenate([row_starts[dr] + columns[dc] for dr in (0, 1) for dc in (0, 1)])
    weight = np.concatenate([v_weights[dr] * u_weights[dc] for dr in (0, 1) for dc in (0, 1)])
    return index, weight, (rows, cols), s


def coarse_field(splat, moves, use=None):
    """:func:`displacement_field` on its grid (see :func:`on_coarse_grid`): ``(rows,
    cols, 2) float32`` from the :func:`splatting` of the points and their ``moves (P, 2)``;
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


def neighbour_moves(splat, points, moves, trusted):
    """``(P, 2)``: the smooth displacement field of the ``trusted (P,)`` tracks' ``moves
    (P, 2)`` at ``points (P, 2)`` (box pixels; ``splat`` their :func:`splatting`); where fewer
    than 4 tracks are trusted, the moves themselves."""
    if trusted.sum() < 4:
        return moves
    coarse = coarse_field(splat, moves.astype(np.float32), trusted)
    return sample(coarse, on_coarse_grid(points, splat[3])).astype(np.float64)
