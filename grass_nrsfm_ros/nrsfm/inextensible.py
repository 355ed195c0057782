"""Inextensible depth refinement (not in the paper; ``GrassmannNRSfM(inextensible=...)``).

A surface that bends without stretching (paper, cloth, a hinged panel) keeps the length
``l_e`` of every short edge ``e = (i, j)`` between neighbouring points. An orthographic camera
shows the edge foreshortened, ``|dxy_e^f| = l_e cos(theta_e^f)``, so the longest image length
over the sequence bounds ``l_e`` and equals it where the edge faces the camera in some frame
(the maximum-depth heuristic, here without a template; a high quantile rather than the
maximum, for noise). An edge that never faces the camera (a steep flank) is longer than all
its images; there the solver's own 3D length (its median over the frames) is the larger and
is taken. Each frame's depth differences then follow from the data:
``|z_i - z_j| = sqrt(l_e^2 - |dxy_e^f|^2)``. Only their signs are unknown; they come from the
solver's depths, then from the refined depths (a few sweeps). Each frame's depths are the
least-squares integration of these differences over the neighbour graph (one sparse
``P x P`` Laplacian factor for all frames), weakly anchored to the solver's depths. ``x, y``
stay the data's.

Whether a sequence's surface is inextensible is judged by what the refinement achieves:
``length_variation`` (temporal std over mean of the 3D edge lengths) drops to 0.05-0.5 of the
solver's on bending, twisting and hinged sheets, but only to 0.68-0.92 on the dense faces and
the inflating surface, whose stretching no depth can undo. The solver's ``'auto'`` mode uses
that ratio (admm.py, with the measurements).

Shapes: ``S: (3F, P)`` camera frame, ``W: (2F, P)``; edges ``i, j: (E,)``. Memory stays
O(F P + F E) in frame / edge chunks; nothing is P x P but the sparse Laplacian.
"""
import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu
from sklearn.neighbors import NearestNeighbors

from .measurement import as_frames, from_frames
from .rotation import _normalised_svd

#: neighbours per point in the edge graph
NEIGHBOURS = 8
#: dimensions of the trajectory embedding the neighbours are found in
EMBED_DIMS = 8
#: the edge length is this quantile of its image lengths over the frames
LENGTH_QUANTILE = 0.95
#: depth re-integrations with the signs of the previous one
SIGN_SWEEPS = 3
#: weight tying each frame's depths to the solver's (relative to the unit edge weights)
ANCHOR = 1e-3
#: entries per (frames x edges) chunk: 120 frames x 30,000 tracks (the node under load) peak
#: at 266 MB in refine_depth with 2^20 (2^22: 582 MB, and slower: 9.8 vs 7.1 s CPU)
CHUNK = 1 << 20


def neighbour_edges(W, k=NEIGHBOURS):
    """Edges ``(i, j): (E,)`` (``i < j``, unique) joining each track of ``W: (2F, P)`` to its
    ``k`` nearest in a ``EMBED_DIMS``-dimensional embedding of the trajectories (their leading
    principal components, from the rotation step's SVD of the centred tracks)."""
    _, d, Vt, _, _ = _normalised_svd(W)
    n = min(EMBED_DIMS, d.size)
    X = (d[:n, None] * Vt[:n]).T                             # (P, n)
    k = min(k, X.shape[0] - 1)
    _, idx = NearestNeighbors(n_neighbors=k + 1).fit(X).kneighbors(X)
    pairs = np.stack([np.repeat(np.arange(X.shape[0]), k), idx[:, 1:].ravel()], axis=1)
    pairs = np.unique(np.sort(pairs, axis=1), axis=0)
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    return pairs[:, 0], pairs[:, 1]


def _frame_chunks(F, E):
    step = max(1, CHUNK // max(E, 1))
    return [slice(a, min(a + step, F)) for a in range(0, F, step)]


def _image_lengths(S, i, j, frames):
    """``|dxy|: (F', E)`` of the frames ``frames`` of ``S: (F, 3, P)``."""
    return np.hypot(S[frames, 0, i] - S[frames, 0, j], S[frames, 1, i] - S[frames, 1, j])


def _edge_chunks(F, E):
    step = max(1, CHUNK // max(F, 1))
    return [slice(a, a + step) for a in range(0, E, step)]


def _image_length_quantile(X, i, j, quantile):
    """``(E,)``: the ``quantile`` of each edge's image lengths over the frames of ``X: (F, 3,
    P)``."""
    out = np.empty(i.size)
    for e in _edge_chunks(X.shape[0], i.size):
        out[e] = np.quantile(_image_lengths(X, i[e], j[e], slice(None)), quantile, axis=0)
    return out


def _length_stats(X, i, j):
    """Per edge, over the frames of ``X: (F, 3, P)``: the median of its 3D length and the
    temporal std over the mean of it, both ``(E,)``."""
    median, relative_std = np.empty(i.size), np.empty(i.size)
    for e in _edge_chunks(X.shape[0], i.size):
        L = np.linalg.norm(X[:, :, i[e]] - X[:, :, j[e]], axis=1)
        median[e] = np.median(L, axis=0)
        relative_std[e] = L.std(axis=0) / np.maximum(L.mean(axis=0), 1e-300)
    return median, relative_std


def length_variation(S, i, j):
    """Mean over edges of the temporal std / mean of the 3D edge lengths of ``S: (3F, P)``."""
    i, j = np.asarray(i, dtype=np.intp), np.asarray(j, dtype=np.intp)
    return float(_length_stats(as_frames(S, 3), i, j)[1].mean()) if i.size else 0.0


def refine_depth(S, edges, *, quantile=LENGTH_QUANTILE, sweeps=SIGN_SWEEPS, anchor=ANCHOR):
    """``S: (3F, P)`` camera frame with each frame's depths replaced by the inextensible ones
    over ``edges = (i, j)`` (see the module docstring); x, y and each frame's mean depth kept.
    Returns ``(S_refined: (3F, P), info)``, info with the length variation before and after."""
    i, j = (np.asarray(e, dtype=np.intp) for e in edges)
    X = as_frames(np.asarray(S, dtype=np.float64), 3)
    F, _, P = X.shape
    mean_depth = X[:, 2, :].mean(axis=1, keepdims=True)
    z0 = X[:, 2, :] - mean_depth                              # (F, P)
    # inextensible length: the larger of the image-length quantile and the median of the
    # solver's 3D length (an edge that never faces the camera is longer than all its images)
    solid, relative_std = _length_stats(X, i, j)
    length = np.maximum(_image_length_quantile(X, i, j, quantile), solid)
    E = i.size
    rows = np.arange(E)
    incidence = sp.csr_matrix((np.r_[np.ones(E), -np.ones(E)], (np.r_[rows, rows], np.r_[i, j])),
                              shape=(E, P))
    solve = splu((incidence.T @ incidence + anchor * sp.eye(P)).tocsc()).solve
    z = z0
    for _ in range(sweeps + 1):
        rhs = anchor * z0.T                                   # (P, F)
        for frames in _frame_chunks(F, E):
            dl = _image_lengths(X, i, j, frames)
            target = np.sqrt(np.maximum(length ** 2 - dl ** 2, 0.0))
            target *= np.where(z[frames][:, i] >= z[frames][:, j], 1.0, -1.0)
            rhs[:, frames] += incidence.T @ target.T
        z = solve(rhs).T
        z -= z.mean(axis=1, keepdims=True)
    out = X.copy()
    out[:, 2, :] = z + mean_depth
    refined = from_frames(out)
    info = {'edges': int(E),
            'length_variation_before': float(relative_std.mean()) if E else 0.0,
            'length_variation_after': length_variation(refined, i, j)}
    return refined, info
