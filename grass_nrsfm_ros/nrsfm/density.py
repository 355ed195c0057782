"""Uneven track density: thin over-dense tracks before the solve, fill them in after.

Every step of the solver weights every track equally, so where a tracker puts many tracks on a
small, textured part of the surface, that part outweighs the rest.

* :func:`track_density`: the density of track j is ``1 / r_j^2``, ``r_j`` the distance to its
  k-th nearest track in the trajectory embedding, ``k = max(DENSITY_NEIGHBOURS, DENSITY_SPAN P)``
  (estimated on a fixed random sample of DENSITY_SAMPLE tracks beyond that many).
* :func:`thinned_tracks`: the reference is the area-weighted median density (each track stands
  for an area ``r_j^2``, so a cluster does not move it). Tracks denser than DENSITY_LIMIT times
  the reference are kept with probability ``DENSITY_LIMIT * reference / density`` (a fixed
  random draw), and only when at least DENSITY_MIN_SHARE of the tracks are over the limit (a
  cluster, not the spread of a random sample).
* :func:`fill_dropped`: each dropped track's 3D point is the affine combination of its
  FILL_NEIGHBOURS nearest kept tracks whose weights reproduce its 2D trajectory over all frames
  (locally linear reconstruction weights, regularised), both found in the FILL_DIMS leading
  principal directions of the kept trajectories; x, y are its own data. Exact for a locally
  planar patch.

Shapes: ``W: (2F, P)``, ``S: (3F, P)``, ``keep: (P',)`` sorted indices of the kept tracks.
"""
import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from .inextensible import trajectory_embedding
from .measurement import as_frames, centre, economy_svd, from_frames, track_scale

#: fewest neighbours of the density estimate
DENSITY_NEIGHBOURS = 8
#: share of the tracks the density estimate spans (k = P / 200 from 1,600 tracks on)
DENSITY_SPAN = 1 / 200
#: most tracks the density is estimated on (a fixed random sample beyond)
DENSITY_SAMPLE = 4000
#: tracks denser than this many times the area-weighted median density are thinned
DENSITY_LIMIT = 8.0
#: share of over-dense tracks below which nothing is thinned
DENSITY_MIN_SHARE = 0.05
#: kept neighbours a dropped track's depth is combined from
FILL_NEIGHBOURS = 8
#: Tikhonov regularisation of the reconstruction weights, relative to the trace
FILL_REGULARISATION = 1e-5
#: leading principal directions of the kept trajectories the fill's neighbours and weights are
#: found in (None: the whole 2F-dimensional trajectories)
FILL_DIMS = 24
#: entries per chunk of (dropped tracks x rows x neighbours)
CHUNK = 1 << 22


def track_density(W, random_state=0):
    """``(density: (P,), reference: float)``: each track's ``1 / r_k^2`` and the area-weighted
    median density of ``W: (2F, P)``. Beyond DENSITY_SAMPLE tracks the densities are those of
    a fixed random sample of that many, each track taking its nearest sampled track's."""
    X = trajectory_embedding(W)
    P = X.shape[0]
    sample = np.arange(P) if P <= DENSITY_SAMPLE else np.sort(
        np.random.default_rng(random_state).choice(P, DENSITY_SAMPLE, replace=False))
    k = min(max(DENSITY_NEIGHBOURS, int(DENSITY_SPAN * sample.size)), sample.size - 1)
    tree = cKDTree(X[sample])
    dist = nearest(tree, X[sample], k + 1)[0][:, k]
    dist = np.maximum(dist, 1e-12 * max(dist.max(), 1e-300))
    density = 1.0 / dist ** 2
    order = np.argsort(density)
    area = np.cumsum(1.0 / density[order])
    reference = float(density[order][np.searchsorted(area, 0.5 * area[-1])])
    if sample.size < P:
        density = density[nearest(tree, X, 1)[1][:, 0]]
    return density, reference


def thinned_tracks(W, random_state=0):
    """Indices ``(P',)`` (sorted) of the tracks of ``W: (2F, P)`` to solve, or None when the
    density is even enough to keep all."""
    density, reference = track_density(W, random_state)
    excess = density / (DENSITY_LIMIT * reference)
    if np.mean(excess > 1.0) < DENSITY_MIN_SHARE:
        return None
    rng = np.random.default_rng(random_state)
    keep = rng.random(excess.size) * np.maximum(excess, 1.0) < 1.0
    return np.flatnonzero(keep)


def fill_dropped(S_kept, labels_kept, W, keep):
    """``(S: (3F, P), labels: (P,))``: the solved ``S_kept: (3F, P')`` and spatial labels
    ``labels_kept: (P',)`` of the tracks ``keep``, with the dropped tracks' points filled in
    (x, y their data, depth the combination of their kept neighbours') and labels (their
    nearest kept neighbour's); S centred on the mean of all the tracks of ``W: (2F, P)``."""
    F, P = W.shape[0] // 2, W.shape[1]
    dropped = np.setdiff1d(np.arange(P), keep)
    Wc = centre(W)[0]
    kept = as_frames(S_kept, 3).copy()
    kept[:, :2, :] += Wc[:, keep].mean(axis=1).reshape(F, 2, 1)   # to the mean of all tracks
    nbrs, weights = _reconstruction_weights(Wc / track_scale(Wc), keep, dropped)
    S = np.empty((F, 3, P))
    S[:, :, keep] = kept
    S[:, :2, dropped] = Wc[:, dropped].reshape(F, 2, -1)
    combine = sp.csr_matrix((weights.ravel(), (np.repeat(np.arange(dropped.size), nbrs.shape[1]),
                                               nbrs.ravel())), shape=(dropped.size, keep.size))
    S[:, 2, dropped] = (combine @ kept[:, 2, :].T).T
    S[:, 2, :] -= S[:, 2, :].mean(axis=1, keepdims=True)
    labels_kept = np.asarray(labels_kept)
    labels = np.empty(P, dtype=labels_kept.dtype)
    labels[keep] = labels_kept
    labels[dropped] = labels_kept[nbrs[:, 0]]
    return from_frames(S), labels


def _reconstruction_weights(Wc, keep, dropped, k=FILL_NEIGHBOURS):
    """``(neighbours: (D, k)`` indices into ``keep``, ``weights: (D, k)`` summing to 1) that
    best reproduce each dropped column of ``Wc: (2F, P)`` (centred, unit RMS) from its nearest
    kept columns."""
    k = min(k, keep.size)
    if FILL_DIMS is not None and FILL_DIMS < Wc.shape[0]:
        Wc = economy_svd(Wc[:, keep])[0][:, :FILL_DIMS].T @ Wc          # (FILL_DIMS, P)
    W_kept = Wc[:, keep]
    nbrs = nearest(cKDTree(W_kept.T), Wc[:, dropped].T, k)[1]     # nearest first
    weights = np.empty(nbrs.shape)
    kept_rows = np.ascontiguousarray(W_kept.T)                       # (P', 2F)
    dropped_rows = np.ascontiguousarray(Wc[:, dropped].T)             # (D, 2F)
    step = max(1, CHUNK // (Wc.shape[0] * k))
    for a in range(0, dropped.size, step):
        part = slice(a, a + step)
        diff = kept_rows[nbrs[part]] - dropped_rows[part][:, None, :]      # (d, k, 2F)
        weights[part] = affine_weights(diff)
    return nbrs, weights


def nearest(tree, queries, k):
    """``(distances, indices)``, each ``(Q, k)`` nearest first: the ``k`` points of ``tree`` (a
    :class:`scipy.spatial.cKDTree`) nearest each row of ``queries: (Q, n)``."""
    return tree.query(queries, k=list(range(1, k + 1)))


def affine_weights(diff, regularisation=FILL_REGULARISATION):
    """``(d, k)`` weights summing to 1, each row the affine combination of ``k`` neighbours
    nearest its point: ``diff: (d, k, n)`` the neighbours minus the point; the local Gram matrix
    regularised by ``regularisation`` times its trace (locally linear reconstruction)."""
    k = diff.shape[1]
    G = diff @ diff.transpose(0, 2, 1)
    G += regularisation * np.trace(G, axis1=1, axis2=2)[:, None, None] * np.eye(k)
    G += 1e-12 * np.eye(k)
    w = np.linalg.solve(G, np.ones((G.shape[0], k, 1)))[..., 0]
    return w / w.sum(axis=1, keepdims=True)
