"""A sheet's model for one frame at a time: the maximum-depth lengths, then each frame alone.

The maximum-depth heuristic (:mod:`.max_depth`) couples frames only through the edge lengths
``d`` of its anchor tracks. Given them, every frame is independent: its anchors take the
largest depths the lengths allow (:func:`.max_depth.largest_depths`), fitted to the lengths as
equalities (:func:`.max_depth.refined_depths`), and every other track the depth of the plane
through its nearest anchors in that frame's image (:func:`.max_depth.plane_depths`). That is
what a live pipeline needs: :func:`fit_sheet_model` on frames so far (the mapping), then
:func:`frame_depths` on each frame as it arrives (the tracking), whatever subset of the
tracks it sees (docs/decisions/0732); :func:`frame_points` gives them as the pipeline's
results carry them.

Shapes: ``W: (2F, P)`` normalised pinhole tracks (rows ``2f, 2f+1``: x, y), ``ids: (P,)``
track ids, ``xy: (P, 2)`` one frame's normalised points, ``Z: (P,)`` its depths (the model's
scale: the lengths sum to 1), ``xyz: (P, 3)`` its centred points and relative depths.
"""
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
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
    the refinement), or None where the largest connected group of its anchors that the frame
    sees (joined by the model's edges) has fewer than MIN_ANCHORS."""
    ids = np.asarray(ids)
    _, in_model, in_frame = np.intersect1d(model.ids, ids, assume_unique=True,
                                           return_indices=True)
    if in_model.size < MIN_ANCHORS:
        return None
    seen_at = np.full(model.ids.size, -1)
    seen_at[in_model] = np.arange(in_model.size)
    i, j = (seen_at[np.asarray(e)] for e in model.edges)
    both = (i >= 0) & (j >= 0)
    i, j, d = i[both], j[both], model.lengths[both]
    n = in_model.size
    _, group = connected_components(sp.coo_matrix((np.ones(i.size), (i, j)), shape=(n, n)),
                                    directed=False)
    largest = group == np.bincount(group).argmax()
    if largest.sum() < MIN_ANCHORS:           # a connected group that large has edges
        return None
    inside = largest[i]
    renumber = np.cumsum(largest) - 1
    edges = (renumber[i[inside]], renumber[j[inside]])
    anchors = in_frame[largest]                                 # indices into ids
    points = np.asarray(xy, dtype=np.float64)
    x, lengths = points[anchors].T, d[inside]                  # (2, n), (E',)
    Z_a = largest_depths(x, edges, lengths)
    if iterations:
        Z_a = refined_depths(x, Z_a, lengths, edges, max_iterations=iterations)
    if not np.isfinite(Z_a).all():
        return None
    k = min(NEIGHBOURS, anchors.size)
    _, near = cKDTree(points[anchors]).query(points, k=k)
    Z = plane_depths(points[None], anchors, Z_a, near.reshape(len(points), k))[0]
    Z[anchors] = Z_a[0]
    return Z


def frame_points(model, ids, xy, iterations=FRAME_ITERATIONS):
    """``xyz: (P, 3)``: one frame's normalised points ``xy: (P, 2)`` less their mean, and the
    relative depths ``Z / mean(Z) - 1`` of :func:`frame_depths` (the form of the pipeline's
    results, which :func:`~grass_nrsfm_ros.pipeline.pinhole_points` takes through the
    pinhole); None where the model does not reach the frame, or the frame is degenerate (a
    singular refinement, non-finite or non-positive depths)."""
    points = np.asarray(xy, dtype=np.float64)
    try:
        Z = frame_depths(model, ids, points, iterations)
    except ValueError:                  # a singular frame (LinAlgError), bad points
        return None
    if Z is None or not np.isfinite(Z).all() or Z.mean() <= 0.0:
        return None
    return np.column_stack([points - points.mean(axis=0), Z / Z.mean() - 1.0])
