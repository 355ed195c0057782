"""A sheet's model for one frame at a time: the maximum-depth lengths, then each frame alone.

The maximum-depth heuristic (:mod:`.max_depth`) couples frames only through the edge lengths
``d`` of its anchor tracks. Given them, every frame is independent: its anchors take the
largest depths the lengths allow (:func:`.max_depth.largest_depths`), fitted to the lengths as
equalities (:func:`.max_depth.refined_depths`), and every other track the depth of the plane
through its nearest anchors in that frame's image (:func:`.max_depth.plane_depths`). That is
what a live pipeline needs: :func:`fit_sheet_model` on frames so far (the mapping), then
:func:`frame_depths` on each frame as it arrives (the tracking), whatever subset of the
tracks it sees (docs/decisions/0732).

Shapes: ``W: (2F, P)`` normalised pinhole tracks (rows ``2f, 2f+1``: x, y), ``ids: (P,)``
track ids, ``xy: (P, 2)`` one frame's normalised points, ``Z: (P,)`` its depths (the model's
scale: the lengths sum to 1).
"""
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .max_depth import largest_depths, MaxDepthNRSfM, NEIGHBOURS, plane_depths, refined_depths

#: refinement iterations per frame when each frame is reconstructed on arrival
FRAME_ITERATIONS = 10
#: fewest of a model's anchors a frame must see (with an edge between them) to take its depths
MIN_ANCHORS = 10


@dataclass(frozen=True)
class SheetModel:
    """The lengths of a sheet: anchor tracks ``ids: (n,)`` (sorted), their neighbour
    ``edges = (i, j)`` (indices into ``ids``) and ``lengths: (E,)``, from the frames
    ``stamps: (F,)``."""

    ids: np.ndarray
    edges: tuple
    lengths: np.ndarray
    stamps: np.ndarray


def fit_sheet_model(W, ids, stamps, result=None):
    """The :class:`SheetModel` of the complete normalised tracks ``W: (2F, P)`` with track
    ids ``ids: (P,)`` (sorted) over frames ``stamps: (F,)``: the maximum-depth LP on every
    frame (:class:`.max_depth.MaxDepthNRSfM`), or ``result``, its MaxDepthResult on them."""
    if result is None:
        result = MaxDepthNRSfM().fit(W)
    return SheetModel(np.asarray(ids)[result.anchors], tuple(result.edges),
                      np.asarray(result.lengths, dtype=np.float64),
                      np.asarray(stamps, dtype=np.int64))


def frame_depths(model, ids, xy, iterations=FRAME_ITERATIONS):
    """``Z: (P,)`` depths of one frame's tracks ``ids: (P,)`` (sorted) at normalised points
    ``xy: (P, 2)`` from the :class:`SheetModel` (see the module docstring; ``iterations``: of
    the refinement), or None where the frame sees fewer than MIN_ANCHORS of its anchors joined
    by an edge."""
    ids = np.asarray(ids)
    seen, mine, theirs = np.intersect1d(model.ids, ids, assume_unique=True,
                                        return_indices=True)
    if seen.size < MIN_ANCHORS:
        return None
    where = np.full(model.ids.size, -1)
    where[mine] = np.arange(mine.size)
    i, j = (where[np.asarray(e)] for e in model.edges)
    kept = (i >= 0) & (j >= 0)
    i, j, d = i[kept], j[kept], model.lengths[kept]
    joined = np.unique(np.r_[i, j])
    if joined.size < MIN_ANCHORS:
        return None
    renumber = np.full(mine.size, -1)
    renumber[joined] = np.arange(joined.size)
    edges = (renumber[i], renumber[j])
    anchors = theirs[joined]                                    # indices into ids
    x = np.asarray(xy, dtype=np.float64)[anchors].T            # (2, n)
    Z_a = largest_depths(x, edges, d)
    if iterations:
        Z_a = refined_depths(x, Z_a, d, edges, max_iterations=iterations)
    points = np.asarray(xy, dtype=np.float64)
    k = min(NEIGHBOURS, anchors.size)
    _, near = cKDTree(points[anchors]).query(points, k=k)
    Z = plane_depths(points[None], anchors, Z_a, near.reshape(len(points), k))[0]
    Z[anchors] = Z_a[0]
    return Z
