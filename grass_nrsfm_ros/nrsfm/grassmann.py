"""Grassmann points, the projection kernel Omega, the LRR step on C, xi regrouping and zeta.

Kumar et al. 2018 represent local subspaces as points on the Grassmann manifold:

* spatial: the trajectories (columns of ``S: (3F, P)``) of one point group span a subspace of
  R^{3F}; its top-``N_s`` left singular vectors ``Psi_sk: (3F, N_s)`` are the group's point;
* temporal: the shapes (columns of ``S#: (3P, F)``) of one contiguous block of frames span a
  subspace of R^{3P}, represented here through the block's ``(F, F)`` Gram matrix only
  (``Psi_tk = X_k^T A_k`` with ``A_k: (f_k, N_t)``), so no ``3P x N`` basis is ever formed.

Everything here works on stacked bases through their cross-Gram ``Psi^T Psi`` and on small
Gram matrices (``3F x 3F``, ``F x F``, ``p x p`` with ``p <= 3F``); no ``P x P`` matrix.

Functions (shapes in their docstrings): :func:`projection_kernel`, :func:`c_update`,
:func:`singular_value_threshold`, :func:`lrr_affinity`, :func:`top_subspace`,
:func:`subspace_iteration`, :func:`zeta`, :func:`initial_groups`, :func:`reassign_by_residual`,
:func:`regroup_points`, :func:`contiguous_blocks`, :func:`move_block_boundaries`,
:func:`regroup_blocks`, :func:`spatial_kernel`, :func:`temporal_kernel`, :func:`block_projector`.
"""
import numpy as np
from sklearn.cluster import KMeans, MiniBatchKMeans


def projection_kernel(cross, sizes, delta=1e-8):
    """Projection kernel ``Omega_ij = ||Psi_i^T Psi_j||_F^2`` of K Grassmann points.

    ``cross: (n, n)`` is ``Psi^T Psi`` of the stacked bases ``Psi = [Psi_1 .. Psi_K]`` with
    ``sizes: (K,)`` columns each (``n = sum(sizes)``). Returns ``Omega: (K, K)``, symmetric PSD
    (``Omega = Z^T Z`` with ``Z_i = vec(Psi_i Psi_i^T)``), plus ``delta * trace(Omega) / K * I``
    so that it stays positive definite when two points coincide (the paper's delta I).
    """
    edges = np.concatenate([[0], np.cumsum(sizes)])
    sq = np.add.reduceat(np.add.reduceat(cross ** 2, edges[:-1], axis=0), edges[:-1], axis=1)
    sq = 0.5 * (sq + sq.T)
    K = len(sizes)
    return sq + delta * max(np.trace(sq), 1.0) / K * np.eye(K)


def spatial_kernel(bases, delta):
    """Omega_s: (K, K), the :func:`projection_kernel` of the spatial points
    ``bases[k]: (3F, r_k)`` (orthonormal columns)."""
    stacked = np.concatenate(bases, axis=1)
    return projection_kernel(stacked.T @ stacked, [b.shape[1] for b in bases], delta)


def temporal_kernel(G, edges, bases, delta):
    """Omega_t: (K, K), the :func:`projection_kernel` of the temporal points of
    :func:`block_bases` (``G: (F, F)``, ``edges: (K+1,)``), through G only."""
    return projection_kernel(block_cross(G, edges, bases), [v.shape[1] for v, _ in bases],
                             delta)


def embedding_error(C, Omega):
    """``sum_i ||Z_i - sum_j C_ij Z_j||^2 = tr(Omega) - 2 tr(C Omega) + tr(C Omega C^T)``.

    Row convention of the supplementary material (point i is expressed by row i of C).
    """
    return float(np.trace(Omega) - 2.0 * np.trace(C @ Omega) + np.trace(C @ Omega @ C.T))


def c_update(Omega, J, Y, lam, beta):
    """Closed-form C step: ``argmin_C lam*err(C) + <Y, C - J> + beta/2 ||C - J||^2``.

    ``err`` is :func:`embedding_error`; its optimality condition
    ``2 lam (C Omega - Omega) + Y + beta (C - J) = 0`` gives
    ``C = (2 lam Omega + beta J - Y)(2 lam Omega + beta I)^{-1}`` (Algorithm 1, line 2).
    Only ``Omega = L L^T`` enters, so no Cholesky factor is needed. All ``(K, K)``.
    """
    K = Omega.shape[0]
    lhs = 2.0 * lam * Omega + beta * np.eye(K)
    rhs = 2.0 * lam * Omega + beta * J - Y
    # C lhs = rhs  <=>  lhs^T C^T = rhs^T (lhs symmetric)
    return np.linalg.solve(lhs, rhs.T).T


def singular_value_threshold(M, tau):
    """``U max(Sigma - tau, 0) V^T`` of a small matrix ``M``; returns ``(result, nuclear)``."""
    U, s, Vt = np.linalg.svd(M, full_matrices=False)
    s = np.maximum(s - tau, 0.0)
    return (U * s) @ Vt, float(s.sum())


def lrr_affinity(C, power):
    """LRR post-processing of ``C: (K, K)`` (Liu et al. 2013), as the paper's xi describes.

    ``C = U Sigma V^T``, ``X = U Sigma^{1/2}`` with unit rows, ``A_ij = |X X^T|_ij ** power``,
    symmetrised. Returns ``A: (K, K)`` in [0, 1] with unit diagonal (for non-zero rows).
    """
    U, s, _ = np.linalg.svd(C)
    X = U * np.sqrt(s)
    norms = np.linalg.norm(X, axis=1, keepdims=True)
    X = X / np.where(norms > 0, norms, 1.0)
    A = np.abs(X @ X.T) ** power
    return 0.5 * (A + A.T)


def top_subspace(M, rank):
    """Orthonormal basis ``(m, rank)`` of the top-``rank`` left singular subspace of ``M: (m, n)``.

    Uses the smaller Gram matrix (``m x m`` or ``n x n``), so tall/wide blocks stay cheap.
    Returns ``(basis, singular_values)``.
    """
    m, n = M.shape
    rank = min(rank, m, n)
    if m <= n:
        vals, vecs = np.linalg.eigh(M @ M.T)
        idx = np.argsort(vals)[::-1][:rank]
        return vecs[:, idx], np.sqrt(np.maximum(vals[idx], 0.0))
    vals, vecs = np.linalg.eigh(M.T @ M)
    idx = np.argsort(vals)[::-1][:rank]
    sv = np.sqrt(np.maximum(vals[idx], 0.0))
    basis = M @ (vecs[:, idx] / np.where(sv > 0, sv, 1.0))
    q, _ = np.linalg.qr(basis)              # re-orthonormalise (tiny singular values)
    return q, sv


def subspace_iteration(M, basis, steps=1):
    """Warm-started block power iteration: refine ``basis: (m, r)`` towards the top-r left
    singular subspace of ``M: (m, n)``. Cost ``O(m n r)`` per step. The products run in M's
    precision (float32 M stays float32), the QR in float64."""
    for _ in range(steps):
        basis, _ = np.linalg.qr((M @ (M.T @ basis.astype(M.dtype, copy=False))).astype(
            np.float64, copy=False))
    return basis


def zeta(S, edges, rank, weight=1.0, bases=None):
    """Local rank-``rank`` reconstruction of each column group of ``S: (D, P)`` (in place).

    Groups are the contiguous column slices ``edges[k]:edges[k+1]``. Each slice ``S_k`` becomes
    ``S_k - weight (I - Psi_k Psi_k^T) S_k``; with ``weight = 1`` that is the paper's
    ``Psi_k^r Sigma_k^r V_k^{rT}`` (rank-r truncated SVD). ``bases`` (one ``(D, r)`` per group,
    or None) defaults to the exact top-r subspace. Groups with at most ``rank`` columns are
    left unchanged. Returns ``S``.
    """
    for k in range(len(edges) - 1):
        block = S[:, edges[k]:edges[k + 1]]
        if block.shape[1] <= rank:
            continue
        basis = top_subspace(block, rank)[0] if bases is None else bases[k]
        basis = basis.astype(S.dtype, copy=False)          # products in S's precision
        if weight == 1.0:
            block[...] = basis @ (basis.T @ block)
        else:
            block -= weight * (block - basis @ (basis.T @ block))
    return S


def reduced_features(S, dims, random_state=None):
    """PCA of the trajectories (columns of ``S: (D, P)``) through the ``D x D`` Gram matrix.

    Returns ``(P, dims)`` features for clustering.
    """
    centred = S - S.mean(axis=1, keepdims=True)
    basis, _ = top_subspace(centred, dims)
    return (basis.T @ centred).T


def initial_groups(S, K, random_state=0, dims=20):
    """k-means++ groups of the trajectories of ``S: (D, P)`` on a PCA-reduced copy.

    Returns labels ``(P,)`` in ``0..K-1`` (every label used). MiniBatchKMeans above 20k points.
    """
    P = S.shape[1]
    if K <= 1:
        return np.zeros(P, dtype=np.int64)
    X = reduced_features(S, min(dims, S.shape[0], P))
    if P > 20000:
        km = MiniBatchKMeans(n_clusters=K, init='k-means++', n_init=3, batch_size=4096,
                             random_state=random_state)
    else:
        km = KMeans(n_clusters=K, init='k-means++', n_init=1, random_state=random_state)
    labels = km.fit_predict(X)
    _, labels = np.unique(labels, return_inverse=True)
    return labels.astype(np.int64)


def group_residuals(S, bases):
    """Squared residuals ``||(I - Psi_k Psi_k^T) s_j||^2``: ``(K, P)`` for ``S: (D, P)``."""
    energy = np.einsum('dp,dp->p', S, S)
    stacked = np.concatenate(bases, axis=1)                 # (D, sum r)
    coeff = stacked.T @ S                                   # (sum r, P)
    sizes = np.array([b.shape[1] for b in bases])
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    proj = np.add.reduceat(coeff ** 2, starts, axis=0)      # (K, P)
    return energy[None, :] - proj


def reassign_by_residual(S, labels, bases, affinity, affinity_min, min_size):
    """One K-subspaces step of xi: move trajectories to the group whose subspace explains them.

    ``S: (D, P)`` columns in any order with ``labels: (P,)``, ``bases``: per group ``(D, r)``.
    A trajectory in group g may only move to a group l with ``affinity[g, l] >= affinity_min``
    (the LRR affinity of C drives which groups exchange points). A group never shrinks below
    ``min_size``: the points it would lose that explain it worst stay. Returns new labels.
    """
    K = len(bases)
    res = group_residuals(S, bases)                         # (K, P)
    allowed = affinity[labels] >= affinity_min             # (P, K)
    allowed[np.arange(len(labels)), labels] = True
    res = np.where(allowed.T, res, np.inf)
    best = np.argmin(res, axis=0)
    gain = res[labels, np.arange(len(labels))] - res[best, np.arange(len(labels))]
    new = labels.copy()
    move = best != labels
    for k in range(K):                                      # loop over groups, not points
        members = np.flatnonzero(labels == k)
        leaving = members[move[members]]
        keep_at_least = min_size - (len(members) - len(leaving))
        if keep_at_least > 0:
            # keep the leavers with the smallest gain
            order = leaving[np.argsort(gain[leaving])]
            leaving = order[keep_at_least:]
        new[leaving] = best[leaving]
    return new


def regroup_points(S, labels, bases, C, power, affinity_min, rank):
    """xi for spatial groups with the affinity of ``C: (K, K)`` (:func:`lrr_affinity`, then
    :func:`reassign_by_residual` keeping ``> rank`` points a group); ``S: (3F, P)``,
    ``labels: (P,)``, ``bases[k]: (3F, r_k)``. Returns the new labels ``(P,)``."""
    return reassign_by_residual(S, labels, bases, lrr_affinity(C, power), affinity_min,
                                rank + 1)


def contiguous_blocks(F, K):
    """Edges ``(K+1,)`` of K contiguous, nearly equal blocks of ``range(F)``."""
    return np.round(np.linspace(0, F, K + 1)).astype(np.int64)


def block_bases(G, edges, rank):
    """Temporal Grassmann points from the ``(F, F)`` Gram matrix of ``X: (F, 3P)``.

    For block k (rows ``edges[k]:edges[k+1]``) returns ``V_k: (f_k, r_k)`` (top eigenvectors
    of ``G_kk``) and ``sv_k: (r_k,)``; the basis of the block's shape subspace is
    ``Psi_k = X_k^T V_k / sv_k`` and its rank-r projection of ``X_k`` is ``V_k V_k^T X_k``.
    """
    sizes = np.diff(edges)
    out = [None] * sizes.size
    for size in np.unique(sizes):           # blocks of one size: one batched eigh
        ks = np.flatnonzero(sizes == size)
        rows = edges[ks][:, None] + np.arange(size)
        vals, vecs = np.linalg.eigh(G[rows[:, :, None], rows[:, None, :]])
        top = np.arange(size - 1, size - 1 - min(rank, size), -1)   # descending
        for i, k in enumerate(ks):
            out[k] = (vecs[i][:, top], np.sqrt(np.maximum(vals[i][top], 0.0)))
    return out


def block_cross(G, edges, bases):
    """``Psi^T Psi`` of the stacked temporal bases of :func:`block_bases` (via G only)."""
    coeff = np.zeros((G.shape[0], sum(v.shape[1] for v, _ in bases)))
    col = 0
    for k, (v, sv) in enumerate(bases):
        coeff[edges[k]:edges[k + 1], col:col + v.shape[1]] = v / np.where(sv > 0, sv, 1.0)
        col += v.shape[1]
    return coeff.T @ G @ coeff


def move_block_boundaries(G, edges, bases, affinity, affinity_min, min_size):
    """xi for temporal blocks: shift each boundary by one frame where the neighbouring block's
    subspace explains the boundary frame better, keeping blocks contiguous and
    ``>= min_size`` frames, and only between blocks with ``affinity >= affinity_min``.

    ``G: (F, F)`` Gram of the shapes, ``edges: (K+1,)``, ``bases`` from :func:`block_bases`.
    Returns new edges.
    """
    def residual(f, k):
        v, sv = bases[k]
        c = (v / np.where(sv > 0, sv, 1.0)).T @ G[edges[k]:edges[k + 1], f]
        return G[f, f] - c @ c

    new = edges.copy()
    for k in range(len(edges) - 2):                  # boundary between block k and k+1
        if affinity[k, k + 1] < affinity_min:
            continue
        b = edges[k + 1]
        last, first = b - 1, b
        if (b - new[k] > min_size and residual(last, k + 1) < residual(last, k)):
            new[k + 1] = b - 1
        elif (edges[k + 2] - b > min_size and residual(first, k) < residual(first, k + 1)):
            new[k + 1] = b + 1
    return new


def regroup_blocks(G, edges, bases, C, power, affinity_min, rank):
    """xi for temporal blocks with the affinity of ``C: (K, K)`` (:func:`lrr_affinity`, then
    :func:`move_block_boundaries` keeping ``> rank`` frames a block). Returns the edges and
    their :func:`block_bases` (``edges``, ``bases`` themselves when no boundary moved)."""
    new = move_block_boundaries(G, edges, bases, lrr_affinity(C, power), affinity_min, rank + 1)
    if np.array_equal(new, edges):
        return edges, bases
    return new, block_bases(G, new, rank)


def block_projector(F, edges, bases):
    """zeta_t as an operator: the block-diagonal ``B: (F, F)`` whose block k is
    ``V_k V_k^T`` for ``bases[k] = (V_k: (f_k, r_k), sv_k)`` of :func:`block_bases` (the
    identity where ``r_k = f_k``), so that ``B X`` projects each block of ``X: (F, m)``."""
    B = np.eye(F)
    for k, (v, _) in enumerate(bases):
        r = slice(edges[k], edges[k + 1])
        if v.shape[1] < r.stop - r.start:
            B[r, r] -= np.eye(r.stop - r.start) - v @ v.T
    return B
