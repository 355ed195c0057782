"""Orthographic sheets: local-isometry depths fitted frame by frame, carried between frames.

Under orthographic projection a sheet that bends without stretching fixes each point's depth
gradient up to its sign (:func:`.isometry.local_gradients`; the edge lengths from the image
alone, :func:`.isometry.edge_lengths` of zero depths). The whole difficulty is the signs
(record 0714: with the true signs these depths are 0.12-0.45 of rigid factorisation's error on
the bending and flag sheets, with the synchronised signs of :mod:`.isometry` 0.36-1.6). A
developable sheet is face-on along whole rulings, where the gradient changes sign, so the
first-order sign agreement of :func:`.isometry.synchronised_signs` cannot hold. Here:

1. Per frame, candidate signs minimise the residual of an affine fit of the signed, bounded
   gradients ``h = g / sqrt(1 + |g|^2)`` (the normal's image part) over each point's
   neighbourhood, plus a first-order agreement term: ``s^T M s`` with ``M: (P, P)`` sparse
   (:func:`sign_cost`), minimised from its lowest eigenvector and from all-ones by single
   flips (:func:`spatial_signs`).
2. From a start frame with those signs, the depths are integrated
   (:func:`.isometry.integrate_depths`' least squares), the frame's 3D shape is carried to the
   next frame by the orthographic camera that best maps it onto the next image (a 2 x 3 fit
   made orthonormal, its third row the depth direction), and the next frame's depths are fitted
   to its edge sizes near the carried ones: from three starts (the signs of the carried
   depths' gradients, the frame's candidate signs, the carried depths), the edges' signs are
   taken from the depths and the depths integrated again, a few sweeps (lowering the isometry
   residual ``sum_e (|dz_e| - size_e)^2`` plus the tie), and the lowest fit is kept
   (:func:`frame_depths`); forwards and backwards to the ends (:func:`carry`). No rotation or
   low-rank solve is needed.
3. Every ``start_step``-th frame (at most MAX_STARTS, spread) starts such a run. Per frame,
   one run's depths are chosen: the sequence with the lowest summed isometry residual plus the
   tie between consecutive frames (:func:`consistent_path`, Viterbi), so that a run that went
   astray where a frame is ambiguous (a fold mirrored about a face-on ruling fits as well) is
   left there.

``x, y`` are the centred tracks; depths are centred per frame. Orthographic tracks only (on
pinhole tracks use :mod:`.max_depth`). Complete tracks only.

Shapes: ``W: (2F, P)``; ``S: (3F, P)`` camera frame; ``X: (F, 3, P)``; gradients ``(F, P,
2)``; signs ``(F, P)`` of +-1; neighbours ``(P, k)`` indices.
"""
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import eigsh
from sklearn.base import BaseEstimator

from . import isometry
from .measurement import as_frames, from_frames, spread_frames

#: weight of the first-order agreement term relative to the affine-fit residual
FIRST_ORDER = 1.0
#: every this many frames is a start frame, at most MAX_STARTS of them (spread over the
#: sequence: the runs cost time and memory in the frames times the starts)
START_STEP = 2
MAX_STARTS = 20
#: weight tying a frame's depths to the carried ones (relative to unit edge weights), in each
#: frame's fit and between frames in the choice of the path
CARRY_WEIGHT = 1e-2
#: sweeps of the edge signs from the depths in each frame's fit
SIGN_SWEEPS = 5


def bounded(g):
    """``(..., 2)``: the gradients' bounded form ``g / sqrt(1 + |g|^2)``."""
    return g / np.sqrt(1.0 + (g ** 2).sum(-1, keepdims=True))


def sign_cost(xy, h, nbr, first=FIRST_ORDER):
    """Sparse symmetric ``M: (P, P)`` with ``s^T M s`` the summed residual of an affine fit of
    ``s h`` over each point's neighbourhood (itself and ``nbr: (P, k)``) plus ``first`` times
    the summed squared differences ``|s_p h_p - s_q h_q|^2`` over the edges (up to a constant);
    ``xy: (P, 2)``, ``h: (P, 2)``."""
    P = xy.shape[0]
    N = np.concatenate([np.arange(P)[:, None], nbr], 1)
    m = N.shape[1]
    a = np.repeat(N, m, axis=1).ravel()
    b = np.tile(N, (1, m)).ravel()
    D = np.concatenate([np.ones((P, m, 1)), xy[N] - xy[:, None, :]], -1)
    Q, _ = np.linalg.qr(D)
    residual = np.eye(m)[None] - Q @ Q.transpose(0, 2, 1)              # (P, m, m)
    hh = np.einsum('pad,pbd->pab', h[N], h[N])
    M = sp.csr_matrix(((residual * hh).ravel(), (a, b)), shape=(P, P))
    i = np.repeat(np.arange(P), nbr.shape[1])
    j = nbr.ravel()
    A = sp.csr_matrix(((h[i] * h[j]).sum(-1), (i, j)), shape=(P, P))
    A = A + A.T
    M = M + first * (sp.diags(np.asarray(abs(A).sum(1)).ravel()) - A)
    return ((M + M.T) * 0.5).tocsc()


def _descend(M, s):
    """Single sign flips that lower ``s^T M s`` until none does."""
    s = s.copy()
    diag = M.diagonal()
    field_ = M @ s
    for _ in range(50 * s.size):
        delta = -4.0 * s * (field_ - diag * s)
        p = int(np.argmin(delta))
        if delta[p] >= -1e-12:
            break
        field_ -= 2.0 * s[p] * M[:, p].toarray().ravel()
        s[p] = -s[p]
    return s


def _lowest_vector(M):
    """``(P,)``: the eigenvector of the lowest eigenvalue of ``M`` among the points it
    constrains (a face-on point has no gradient, so no cost: its row is zero and would make
    that eigenvector any mix of such points, one BLAS thread count to another); 0 elsewhere."""
    diag = M.diagonal()
    active = np.flatnonzero(diag > 1e-12 * max(diag.max(initial=0.0), 1e-300))
    v = np.zeros(M.shape[0])
    if active.size == 0:
        return v
    sub = M[active][:, active]
    if active.size <= 1000:
        v[active] = np.linalg.eigh(sub.toarray())[1][:, 0]
    else:
        shift = -1e-3 * abs(sub).sum() / active.size
        v[active] = eigsh(sub, k=1, sigma=shift, which='LM', v0=np.ones(active.size))[1][:, 0]
    return v


def spatial_signs(X, h, nbr, first=FIRST_ORDER):
    """``(signs (F, P), costs)``: per frame of ``X: (F, 3, P)`` the signs of ``h: (F, P, 2)``
    found for :func:`sign_cost` (from its lowest eigenvector and from all-ones), and the
    frames' cost matrices."""
    F, P, _ = h.shape
    signs = np.ones((F, P))
    costs = []
    for f in range(F):
        M = sign_cost(X[f, :2].T, h[f], nbr, first)
        costs.append(M)
        v = _lowest_vector(M)
        best = None
        for start in (np.where(v >= 0, 1.0, -1.0), np.ones(P)):
            s = _descend(M, start)
            c = s @ (M @ s)
            if best is None or c < best[0]:
                best = (c, s)
        signs[f] = best[1]
    return signs, costs


def carried_depths(X_prev, xy):
    """``(P,)`` centred depths of the shape ``X_prev: (3, P)`` seen by the orthographic camera
    that best maps it onto the centred image ``xy: (2, P)``."""
    M = xy @ np.linalg.pinv(X_prev)
    U, _, Vt = np.linalg.svd(M, full_matrices=False)
    R = U @ Vt
    z = np.cross(R[0], R[1]) @ X_prev
    return z - z.mean()


def refined(integrate, z, z_anchor, frame, sweeps=SIGN_SWEEPS):
    """``(P,)``: the depths ``z`` of ``frame`` integrated again from their own edge signs,
    ``sweeps`` times: each sweep lowers its isometry residual plus the tie to ``z_anchor:
    (P,)`` (a majorisation of ``sum_e (|dz_e| - size_e)^2``)."""
    for _ in range(sweeps):
        z = integrate.from_signs(integrate.edge_signs(z[None]), z_anchor[None], [frame])[0]
    return z


def frame_depths(integrate, g, X, nbr, frame, carried, candidate):
    """``(P,)`` depths of ``frame`` given the ``carried: (P,)`` ones: of three starts (the
    signs of the carried depths' gradients, the frame's spatial ``candidate`` signs turned to
    agree with those, the carried depths themselves), each :func:`refined`, the one with the
    lowest isometry residual plus the tie to the carried depths."""
    signs = isometry.solver_signs(g[[frame]], np.vstack([X[frame, :2], carried])[None], nbr)[0]
    turned = candidate * (1.0 if candidate @ signs >= 0 else -1.0)
    starts = [integrate(g[[frame]] * s[None, :, None], carried[None], [frame])[0]
              for s in (signs, turned)] + [carried]
    fits = [refined(integrate, z, carried, frame) for z in starts]
    costs = [integrate.residual(z[None], [frame])[0]
             + integrate.anchor * ((z - carried) ** 2).sum() for z in fits]
    return fits[int(np.argmin(costs))]


def carry(X, g, nbr, integrate, start, candidates):
    """``z (F, P)``: the depths of frame ``start`` from its ``candidates: (F, P)`` signs, then
    each frame's :func:`frame_depths` from the previous frame's shape carried onto its image
    (module docstring, step 2); ``integrate`` the frames' :class:`.isometry.DepthIntegrator`."""
    F, _, P = X.shape
    z = np.zeros((F, P))
    first = integrate(g[[start]] * candidates[start][None, :, None], np.zeros((1, P)), [start])[0]
    z[start] = refined(integrate, first, first, start)
    for order in (range(start + 1, F), range(start - 1, -1, -1)):
        for f in order:
            prev = f - 1 if f > start else f + 1
            zc = carried_depths(np.vstack([X[prev, :2], z[prev]]), X[f, :2])
            z[f] = frame_depths(integrate, g, X, nbr, f, zc, candidates[f])
    return z


def consistent_path(X, runs, integrate):
    """``(z (F, P), path (F,))``: per frame one of the ``runs: (C, F, P)``' depths, the
    sequence minimising the summed isometry residuals plus, between consecutive frames, the
    tie of each frame's depths to the previous frame's carried onto its image (Viterbi)."""
    C, F, _ = runs.shape
    residual = np.stack([integrate.residual(run) for run in runs], axis=1)        # (F, C)
    cost = residual[0].copy()
    back = np.zeros((F, C), dtype=np.int64)
    for f in range(1, F):
        carried = np.stack([carried_depths(np.vstack([X[f - 1, :2], run[f - 1]]), X[f, :2])
                            for run in runs])                                      # (C, P)
        tie = ((runs[None, :, f] - carried[:, None]) ** 2).sum(-1)               # (from, to)
        total = cost[:, None] + integrate.anchor * tie
        back[f] = np.argmin(total, axis=0)
        cost = total[back[f], np.arange(C)] + residual[f]
    path = np.zeros(F, dtype=np.int64)
    path[-1] = int(np.argmin(cost))
    for f in range(F - 1, 0, -1):
        path[f - 1] = back[f, path[f]]
    return runs[path, np.arange(F)], path


def transport_depths(W, *, k=isometry.NEIGHBOURS, quantile=isometry.LENGTH_QUANTILE,
                     first=FIRST_ORDER, start_step=START_STEP):
    """``(S: (3F, P), info)``: the centred tracks ``W: (2F, P)`` with the carried local-
    isometry depths (module docstring)."""
    W = np.asarray(W, dtype=np.float64)
    xy = as_frames(W, 2)
    F, _, P = xy.shape
    X = np.zeros((F, 3, P))
    X[:, :2] = xy - xy.mean(axis=2, keepdims=True)
    nbr = isometry.neighbours(W, k)
    lengths = isometry.edge_lengths(X, nbr, quantile)
    g, _ = isometry.local_gradients(X, nbr, lengths)
    candidates, _ = spatial_signs(X, bounded(g), nbr, first)
    integrate = isometry.DepthIntegrator(X, nbr, lengths, CARRY_WEIGHT)
    starts = np.arange(0, F, max(1, int(start_step)))
    starts = starts[spread_frames(starts.size, MAX_STARTS)]
    runs = np.stack([carry(X, g, nbr, integrate, start, candidates) for start in starts])
    X[:, 2], path = consistent_path(X, runs, integrate)
    residual = float(integrate.residual(X[:, 2]).sum())
    info = {'start_frames': starts[np.unique(path)].tolist(), 'isometry_residual': residual,
            'relative_residual': residual / max(float((integrate.size ** 2).sum()), 1e-300)}
    return from_frames(X), info


@dataclass
class TransportSheetResult:
    """``S: (3F, P)`` camera frame (centred tracks, centred depths), ``info``: the start frames
    whose runs the chosen path takes (``start_frames``), its summed isometry residual and that
    over the summed squared edge sizes (``relative_residual``)."""
    S: np.ndarray
    info: dict = field(default_factory=dict)


class TransportSheetNRSfM(BaseEstimator):
    """:func:`transport_depths` as a solver: ``fit(W: (2F, P)) ->``
    :class:`TransportSheetResult` (orthographic, complete tracks)."""

    def __init__(self, neighbours=isometry.NEIGHBOURS, quantile=isometry.LENGTH_QUANTILE,
                 first=FIRST_ORDER, start_step=START_STEP):
        self.neighbours = neighbours
        self.quantile = quantile
        self.first = first
        self.start_step = start_step

    def fit(self, W):
        S, info = transport_depths(W, k=self.neighbours, quantile=self.quantile,
                                   first=self.first, start_step=self.start_step)
        return TransportSheetResult(S=S, info=info)
