"""Camera rotations from orthographic tracks.

* :func:`rigid_factorisation`: Tomasi-Kanade (rank 3 + metric upgrade), the baseline and the
  fallback for degenerate input.
* :func:`estimate_rotations`: the prior-free method of Dai, Li and He (CVPR 2012, IJCV 2014):
  rank-3K factorisation ``W = Pi B``, linear orthonormality constraints on one column triple
  ``Q_k = G_k G_k^T`` (3K x 3K), their null space (dimension ``2K^2 - K``), a rank-3 PSD point
  of that space found by alternating projections from seeded starts, then a scale-free
  nonlinear least-squares refinement of ``G_k`` (3K x 3), where W's spectrum shows a noise
  floor with the deformation columns' share of the motion held down (:func:`noise_penalty`).
  The rank K is picked from the data (:func:`choose_rank`) or given.

Conventions (see :mod:`.measurement`): ``W: (2F, P)``, ``S: (3F, P)`` camera frame,
``R: (F, 3, 3)`` world to camera. Inputs need not be centred.
"""
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from .measurement import (as_frames, centre, economy_svd, from_frames, nearest_rotation,
                          track_scale, validate_tracks)

#: ratio to the first singular value below which W is treated as having lower rank
RANK_TOL = 1e-6
#: number of seeded starts of the intersection search per K
N_STARTS = 2
#: alternating-projection sweeps from each start before the nonlinear refinement
N_PROJECTION_SWEEPS = 30
#: choose_rank: a next rank keeping more than this share of the noise-only ratio is noise
PLATEAU_RATIO = 0.93
#: choose_rank: a residual below this is an exact fit (noise-free data of that rank)
EXACT_RESIDUAL = 1e-7
#: default candidate ranks for K='auto'
DEFAULT_CANDIDATES = tuple(range(1, 7))
#: weight of the deformation columns' share of the motion in the refinement where the last
#: column used lies at W's noise floor (record 0736)
NOISE_PENALTY = 0.05
#: fewest singular values of W whose median is taken as its noise floor (fewer: no floor)
NOISE_FLOOR_VALUES = 72
#: penalty weights below this are not applied (noise-free input keeps the plain refinement)
MIN_PENALTY = 1e-4


@dataclass(frozen=True)
class RotationEstimate:
    """Result of :func:`estimate_rotations`.

    ``R: (F, 3, 3)`` world-to-camera rotations; ``K`` the rank used; ``scores`` per-K
    diagnostics ``{K: {...}}`` plus ``'rule'`` and, on fallback, ``'fallback'`` (the reason).
    """
    R: np.ndarray
    K: int
    scores: dict = field(default_factory=dict)


# ----------------------------------------------------------------------------- factorisation

def _fix_signs(U, Vt):
    """Make the largest-magnitude entry of each left singular vector positive (determinism)."""
    idx = np.argmax(np.abs(U), axis=0)
    sign = np.sign(U[idx, np.arange(U.shape[1])])
    sign[sign == 0] = 1.0
    return U * sign, Vt * sign[:, None]


def normalised_svd(W):
    """Centre and scale ``W: (2F, P)``.

    Returns ``(U (2F, r), d (r,), Vt (r, P), Wn (2F, P), scale)`` with signs fixed and
    ``Wn = centred W / scale``; dense tracks through the ``2F x 2F`` Gram matrix
    (:func:`~.measurement.economy_svd`).
    """
    Wc, _ = centre(validate_tracks(W))
    scale = track_scale(Wc)
    Wn = Wc / scale
    U, d, Vt = economy_svd(Wn)
    U, Vt = _fix_signs(U, Vt)
    return U, d, Vt, Wn, scale


def _motion_factor(U, d, rank):
    """``Pi_hat = U_r D_r^{1/2}: (2F, r)``."""
    return U[:, :rank] * np.sqrt(d[:rank])


# ----------------------------------------------------------------------------- constraints

def _svec_index(n):
    """Upper-triangle indices and weights so that ``<svec(X), svec(Y)> = <X, Y>_F``."""
    iu, ju = np.triu_indices(n)
    weight = np.where(iu == ju, 1.0, np.sqrt(2.0))
    return iu, ju, weight


def _svec(X, n):
    """``X: (..., n, n)`` symmetric -> ``(..., n(n+1)/2)`` Frobenius-isometric vectorisation."""
    iu, ju, weight = _svec_index(n)
    return X[..., iu, ju] * weight


def _smat(v, n):
    """Inverse of :func:`_svec` for ``v: (..., n(n+1)/2)``."""
    iu, ju, weight = _svec_index(n)
    X = np.zeros(v.shape[:-1] + (n, n))
    X[..., iu, ju] = v / weight
    X[..., ju, iu] = v / weight
    return X


def _constraint_matrix(Pi):
    """Linear orthonormality constraints on ``Q = G G^T`` for ``Pi: (2F, n)``.

    Per frame with rows a, b of Pi: ``a Q a^T - b Q b^T = 0`` and ``a Q b^T = 0``.
    Returns ``A: (2F, n(n+1)/2)`` acting on ``svec(Q)``.
    """
    n = Pi.shape[1]
    a, b = Pi[0::2], Pi[1::2]
    aa = a[:, :, None] * a[:, None, :]
    bb = b[:, :, None] * b[:, None, :]
    ab = a[:, :, None] * b[:, None, :]
    equal_norms = _svec(aa - bb, n)
    orthogonal = _svec(0.5 * (ab + ab.transpose(0, 2, 1)), n)
    return np.concatenate([equal_norms, orthogonal], axis=0)


def _null_space(A, dim):
    """Orthonormal basis ``(m, dim)`` of the ``dim`` least-constrained directions of ``A``.

    Also returns the ratio of the largest null singular value to the smallest kept one (the
    gap; small means a clean null space).
    """
    _, s, Vt = np.linalg.svd(A, full_matrices=True)
    s_full = np.zeros(Vt.shape[0])
    s_full[:s.size] = s
    N = Vt[-dim:].T
    kept = s_full[-dim - 1] if Vt.shape[0] > dim else np.inf
    gap = s_full[-dim:].max() / kept if kept > 0 else 1.0
    return N, float(gap)


def _psd_rank3(Q):
    """Nearest PSD rank-3 factor ``G: (n, 3)`` (``G G^T`` ~ Q), choosing the sign of Q."""
    w, V = np.linalg.eigh(Q)
    if w[-3:].sum() < -w[:3].sum():          # the negative side carries the rank-3 part
        w, V = -w[::-1], V[:, ::-1]
    top = np.clip(w[-3:], 0.0, None)
    return V[:, -3:] * np.sqrt(top)


def _intersection_starts(N, n, rng, n_starts):
    """Rank-3 PSD points near the null space ``N: (m, d)``, from seeded random directions.

    Each start is a random symmetric matrix projected on the null space (independent of the
    basis chosen for it), then alternately truncated to rank-3 PSD and projected back.
    """
    starts = []
    for _ in range(n_starts):
        Z = rng.normal(size=(n, n))
        q = N @ (N.T @ _svec(Z + Z.T, n))
        for _ in range(N_PROJECTION_SWEEPS):
            G = _psd_rank3(_smat(q, n))
            q = N @ (N.T @ _svec(G @ G.T, n))
        G = _psd_rank3(_smat(q, n))
        if np.linalg.norm(G) > 0:
            starts.append(G / np.linalg.norm(G))
    return starts


# ----------------------------------------------------------------------------- refinement

def _orthonormality_terms(g, a, b):
    """``(r1, r2: (F, 3), n1, n2, d, s: (F,))`` of ``G = g.reshape(n, 3)``: the rows
    ``a G``, ``b G``, their squared norms, their dot product and ``n1 + n2``."""
    G = g.reshape(a.shape[1], 3)
    r1, r2 = a @ G, b @ G
    n1, n2 = (r1 ** 2).sum(1), (r2 ** 2).sum(1)
    return r1, r2, n1, n2, (r1 * r2).sum(1), np.maximum(n1 + n2, 1e-300)


def _orthonormality_residual(g, a, b):
    """Scale-free orthonormality residual ``e: (2F,)`` of ``G = g.reshape(n, 3)``.

    Per frame, with ``r1 = a G``, ``r2 = b G`` and ``s = |r1|^2 + |r2|^2``:
    ``e1 = (|r1|^2 - |r2|^2) / s`` and ``e2 = 2 r1.r2 / s`` (both in [-1, 1]).
    """
    _, _, n1, n2, d, s = _orthonormality_terms(g, a, b)
    return np.concatenate([(n1 - n2) / s, 2.0 * d / s])


def _orthonormality_jacobian(g, a, b):
    """Jacobian ``J: (2F, 3n)`` of :func:`_orthonormality_residual` at ``g``."""
    r1, r2, n1, n2, d, s = _orthonormality_terms(g, a, b)
    c1a = (4.0 * n2 / s ** 2)[:, None] * r1
    c1b = (-4.0 * n1 / s ** 2)[:, None] * r2
    c2a = 2.0 * r2 / s[:, None] - (4.0 * d / s ** 2)[:, None] * r1
    c2b = 2.0 * r1 / s[:, None] - (4.0 * d / s ** 2)[:, None] * r2
    J = a[None, :, :, None] * np.stack([c1a, c2a])[:, :, None, :] + \
        b[None, :, :, None] * np.stack([c1b, c2b])[:, :, None, :]       # (2, F, n, 3)
    return J.reshape(2 * a.shape[0], 3 * a.shape[1])


def _refine(G0, Pi, penalty=0.0):
    """Minimise the scale-free orthonormality residual over ``G: (n, 3)`` from ``G0``, plus
    ``penalty`` times the share of the motion ``Pi G`` carried by Pi's columns beyond the
    first three (:func:`_share_terms`). Returns ``(G / |G|, rms orthonormality residual)``."""
    a, b = Pi[0::2], Pi[1::2]
    weights = np.sqrt(penalty) * (np.arange(Pi.shape[1]) >= 3)
    scale = np.repeat(np.linalg.norm(Pi, axis=0), 3)          # |Pi_j| per entry of g

    def fun(g):
        residual = _orthonormality_residual(g, a, b)
        if penalty == 0.0:
            return residual
        return np.concatenate([residual, _share_terms(g, scale, weights)[0]])

    def jac(g):
        J = _orthonormality_jacobian(g, a, b)
        if penalty == 0.0:
            return J
        return np.vstack([J, _share_terms(g, scale, weights)[1]])

    sol = least_squares(fun, G0.ravel(), jac=jac, method='trf', x_scale='jac',
                        xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=200)
    G = sol.x.reshape(G0.shape)
    residual = _orthonormality_residual(sol.x, a, b)
    return G / np.linalg.norm(G), float(np.sqrt(np.mean(residual ** 2)))


def _share_terms(g, scale, weights):
    """``(terms: (3n,), J: (3n, 3n))``: each entry of ``G = g.reshape(n, 3)`` as its part of
    the motion ``Pi G`` (``scale`` |Pi_j| per entry, Pi's columns orthogonal), over the whole,
    times ``weights`` (per column, repeated per entry); their squares sum to the weighted
    share of the motion in those columns. ``J`` is their Jacobian."""
    k = np.repeat(weights, 3)
    part = scale * g
    total = np.linalg.norm(part)
    J = np.diag(k * scale) / total - np.outer(k * part, part * scale) / total ** 3
    return k * part / total, J


def noise_penalty(d, n):
    """The refinement's penalty (:func:`_refine`) for a factorisation of rank ``n`` of a W
    with singular values ``d`` (descending): ``NOISE_PENALTY`` times the noise floor (the
    median of ``d``, where W has at least ``NOISE_FLOOR_VALUES`` of them and the median is
    not below ``RANK_TOL`` of the first: no exact low rank) over the last column's singular
    value ``d[n - 1]``, at most ``NOISE_PENALTY``; 0 for a rigid factorisation (n <= 3),
    without a floor, or below ``MIN_PENALTY``."""
    if n <= 3 or d.size < NOISE_FLOOR_VALUES or d[n - 1] <= 0:
        return 0.0
    floor = float(np.median(d))
    if floor < RANK_TOL * d[0]:
        return 0.0
    penalty = NOISE_PENALTY * min(1.0, floor / float(d[n - 1]))
    return penalty if penalty >= MIN_PENALTY else 0.0


# ----------------------------------------------------------------------------- rotations

def rotations_from_rows(M):
    """``M: (F, 2, 3)`` camera rows (any scale) -> ``(R: (F, 3, 3), ok: (F,) bool)``.

    Each 2x3 block goes to the nearest matrix with orthonormal rows; the third row is their
    cross product. ``ok`` is False where the block has (numerically) rank < 2.
    """
    U, s, Vt = np.linalg.svd(M, full_matrices=False)
    rows = U @ Vt
    R = np.concatenate([rows, np.cross(rows[:, 0], rows[:, 1])[:, None, :]], axis=1)
    ok = s[:, 1] > RANK_TOL * np.maximum(s[:, 0], 1e-300)
    return R, ok


def sign_continuity(R):
    """Flip rows 0, 1 of frames so that consecutive rotations are as close as possible.

    ``R`` and ``diag(-1, -1, 1) R`` project identically up to the sign c_ik of the basis
    coefficient; of the two, each frame keeps the one nearer (in angle) to the previous frame's
    choice. ``R: (F, 3, 3)`` -> ``(F, 3, 3)``.
    """
    D = np.array([-1.0, -1.0, 1.0])
    rel = R[1:] @ R[:-1].transpose(0, 2, 1)                        # R_f R_{f-1}^T
    keep = np.trace(rel, axis1=1, axis2=2)
    flipped = np.einsum('fii,i->f', rel, D)                         # trace(D R_f R_{f-1}^T)
    parity = np.concatenate([[0], np.cumsum(flipped > keep) % 2])
    sign = np.where(parity == 1, -1.0, 1.0)
    out = R.copy()
    out[:, :2] *= sign[:, None, None]
    return out


def step_angles(R):
    """Angle (degrees) between consecutive rotations of ``R: (F, 3, 3)`` -> ``(F-1,)``."""
    rel = R[1:] @ R[:-1].transpose(0, 2, 1)
    cosang = np.clip((np.trace(rel, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    return np.degrees(np.arccos(cosang))


def to_world_frame(R_est, R_known, known):
    """Estimated rotations ``(F, 3, 3)`` put in the world frame of given ones on the
    ``known: (F,)`` frames: the world rotation Q (and whether to use the orthographic
    depth-flip twin ``D R D``, D = diag(1, 1, -1)) minimising
    ``sum_known ||R_est_f Q - R_known_f||^2``; every frame stays estimated."""
    D = np.diag([1.0, 1.0, -1.0])
    best, best_err = None, np.inf
    for cand in (R_est, D @ R_est @ D):
        M = np.einsum('fji,fjk->ik', cand[known], R_known[known])
        Q = nearest_rotation(M)
        err = np.linalg.norm(cand[known] @ Q - R_known[known])
        if err < best_err:
            best, best_err = cand @ Q, err
    return best


def align_rotations(R_est, R_known, known):
    """Align estimated rotations ``(F, 3, 3)`` to given ones on the ``known: (F,)`` frames
    (:func:`to_world_frame`); returns the aligned estimates with the known frames replaced by
    the given rotations."""
    best = to_world_frame(R_est, R_known, known)
    best[known] = R_known[known]
    return best


def rotation_spread(R):
    """Mean angle (degrees) of the rotations ``R: (F, 3, 3)`` from their mean (the rotation
    nearest to their average): how far the camera turns over the sequence."""
    mean = nearest_rotation(R.mean(axis=0))
    cosang = np.clip((np.trace(R @ mean.T, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.degrees(np.arccos(cosang)).mean())


def _rotations_from_triple(Pi, G):
    """Rotations from ``Pi: (2F, n)`` and one column triple ``G: (n, 3)``."""
    R, ok = rotations_from_rows(as_frames(Pi @ G, 2))
    return sign_continuity(R), ok


# ----------------------------------------------------------------------------- rigid

def rigid_world_shape(R, Wc):
    """Least-squares rigid world shape ``X: (3, P)`` with ``Wc_f ~ R_f[:2] X`` (min-norm):
    ``R: (F, 3, 3)``, ``Wc: (2F, P)`` centred per row, X in Wc's units."""
    cams = R[:, :2, :].reshape(-1, 3)                          # (2F, 3), rows as Wc's
    return np.linalg.pinv(cams.T @ cams, rcond=1e-8) @ (cams.T @ Wc)


def _rigid(W):
    """Tomasi-Kanade. Returns ``(R, S camera frame in W's units, info dict)``."""
    U, d, Vt, Wn, scale = normalised_svd(W)
    F = Wn.shape[0] // 2
    info = {'energy': float((d[:3] ** 2).sum() / (d ** 2).sum())}
    rank = int((d > RANK_TOL * d[0]).sum())
    R = None
    if rank >= 3:
        Pi = _motion_factor(U, d, 3)
        N, gap = _null_space(_constraint_matrix(Pi), 1)
        G = _psd_rank3(_smat(N[:, 0], 3))
        R, ok = _rotations_from_triple(Pi, G)
        info['null_gap'] = gap
        if not ok.all() or np.linalg.matrix_rank(G) < 3:
            info['fallback'] = 'metric upgrade degenerate (no rank-3 PSD solution)'
            R = None
    else:
        info['fallback'] = f'W has rank {rank} < 3 (static camera or planar scene)'
    if R is None:
        R = np.broadcast_to(np.eye(3), (F, 3, 3)).copy()
        depth = np.zeros((F, 1, Wn.shape[1]))
        S = from_frames(np.concatenate([as_frames(Wn, 2), depth], axis=1)) * scale
        return R, S, info
    S = from_frames(R @ rigid_world_shape(R, Wn)[None]) * scale
    return R, S, info


def rigid_factorisation(W):
    """Tomasi-Kanade rigid factorisation of ``W: (2F, P)`` (any translation).

    Returns ``(R: (F, 3, 3), S: (3F, P))`` with S the rigid shape in each frame's camera
    coordinates (centred, in W's units). Rank-deficient input (static camera, planar scene)
    gives identity rotations and the flat shapes ``[W_f; 0]``, never NaN.
    """
    R, S, _ = _rigid(W)
    return R, S


# ----------------------------------------------------------------------------- Dai et al.

def max_rank(F, P):
    """Largest K with ``3K <= min(2F, P)`` and enough constraints (2F) to pin the null space.

    The constraints must cut ``3K(3K+1)/2`` unknowns down to ``2K^2 - K``, i.e. at least
    ``5K(K+1)/2`` independent rows.
    """
    K = 1
    while 3 * (K + 1) <= min(2 * F, P) and 2 * F >= 5 * (K + 1) * (K + 2) // 2:
        K += 1
    return K


def _numerical_rank(d):
    """Number of singular values ``d`` above ``RANK_TOL`` times the largest."""
    return int((d > RANK_TOL * d[0]).sum())


def rotations_for_rank(W, K, *, random_state=0, n_starts=N_STARTS, warm=None, _svd=None):
    """Dai et al.'s rotations at a fixed rank K for ``W: (2F, P)``.

    ``warm``: an optional column triple ``(r', 3)`` from a smaller rank, padded with zeros and
    refined as one more start (the factorisations are nested, so this makes the best residual
    non-increasing in K). Where W has numerical rank ``r < 3K`` (but ``r > 3K - 3``) the
    factorisation uses rank r and the null space is taken numerically.
    Returns ``(R: (F, 3, 3), G: (r, 3), diagnostics dict)``. Raises ValueError if infeasible.
    """
    U, d, Vt, Wn, _ = _svd if _svd is not None else normalised_svd(W)
    n = min(3 * K, _numerical_rank(d))
    if n <= 3 * K - 3 or n < 3:
        raise ValueError(f'W has numerical rank {_numerical_rank(d)} <= 3(K-1) = {3 * K - 3}')
    Pi = _motion_factor(U, d, n)
    A = _constraint_matrix(Pi)
    null_dim = 2 * K * K - K
    if n < 3 * K:
        s = np.linalg.svd(A, compute_uv=False)
        null_dim = max(1, int((s < RANK_TOL * s[0]).sum()) + A.shape[1] - s.size)
    N, gap = _null_space(A, null_dim)
    rng = np.random.default_rng(random_state)
    starts = _intersection_starts(N, n, rng, n_starts)
    if warm is not None:
        starts.append(np.vstack([warm, np.zeros((n - warm.shape[0], 3))]))
    best, penalty = None, noise_penalty(d, n)
    for G0 in starts:
        G, res = _refine(G0, Pi, penalty)
        if best is None or res < best[1] - 1e-12:
            best = (G, res)
    if best is None:
        raise ValueError('no rank-3 PSD point found in the null space')
    G, res = best
    R, ok = _rotations_from_triple(Pi, G)
    if not ok.all():
        raise ValueError('rotation rows degenerate for some frames')
    steps = step_angles(R)
    info = {
        'residual': res,
        'rank_used': n,
        'null_dim': null_dim,
        'null_gap': gap,
        'penalty': penalty,
        'energy': float((d[:n] ** 2).sum() / (d ** 2).sum()),
        'step_median_deg': float(np.median(steps)) if steps.size else 0.0,
        'step_mean_deg': float(steps.mean()) if steps.size else 0.0,
    }
    return R, G, info


def estimate_rotations(W, K='auto', *, candidates=DEFAULT_CANDIDATES, random_state=0):
    """Camera rotations of ``W: (2F, P)`` (any translation) by Dai et al.'s method.

    ``K``: the shape-basis rank, an int, or 'auto' to choose among ``candidates`` with
    :func:`choose_rank`, searched upward only until that rule stops (``scores`` holds the
    ranks searched). Degenerate input falls back to :func:`rigid_factorisation` with the
    reason in ``scores['fallback']``. Returns a :class:`RotationEstimate`.
    """
    svd = normalised_svd(W)
    F, P = svd[3].shape[0] // 2, svd[3].shape[1]
    if K == 'auto':
        wanted = sorted(k for k in set(int(c) for c in candidates) if k >= 1)
        top = min(max(wanted, default=1), max_rank(F, P))
        ranks = list(range(1, top + 1))
    else:
        if int(K) != K or K < 1:
            raise ValueError(f'K must be a positive int or "auto"; got {K!r}')
        ranks = list(range(1, int(K) + 1))
    scores, results, warm = {}, {}, None
    keep = wanted if K == 'auto' else [int(K)]
    for k in ranks:
        try:
            R, warm, info = rotations_for_rank(W, k, random_state=random_state, warm=warm,
                                               _svd=svd)
        except (ValueError, np.linalg.LinAlgError) as exc:
            scores[k] = {'error': str(exc)}
            continue
        scores[k], results[k] = info, R
        if K == 'auto' and _rank_decided({j: scores[j]['residual'] for j in results
                                          if j in keep}, F):
            break                 # the higher ranks cannot change the choice: not searched
    results = {k: r for k, r in results.items() if k in keep}
    if not results:
        R, _, info = _rigid(W)
        failed = '; '.join(f'K={k}: {scores[k]["error"]}' for k in keep if k in scores)
        scores['fallback'] = info.get('fallback', failed or 'no rank gave rotations')
        scores['fallback'] += '; rigid factorisation used'
        return RotationEstimate(R=R, K=1, scores=scores)
    if K == 'auto':
        chosen, rule = choose_rank({k: scores[k]['residual'] for k in results}, F)
    else:
        chosen, rule = int(K), f'K={int(K)} given'
    scores['rule'] = rule
    return RotationEstimate(R=results[chosen], K=chosen, scores=scores)


def rotations_from_start(W, K, R0, known, _svd=None):
    """Dai et al.'s rotations of ``W: (2F, P)`` at rank ``K``, refined from given rotations
    ``R0: (F, 3, 3)`` on the ``known: (F,)`` frames instead of seeded starts (the incremental
    estimate of a window that overlaps a solved one).

    The start is the column triple ``G0: (3K, 3)`` with ``Pi_f G0 ~ c_f R0_f[:2]`` on the known
    frames (``c_f`` the basis coefficients: the smallest right singular vector of that linear
    system), refined over every frame as in :func:`rotations_for_rank`, put in R0's world frame
    (:func:`to_world_frame`); known frames are re-estimated, not kept. Raises ValueError where
    W's rank is too low or a frame's rows degenerate. ``_svd``: W's :func:`normalised_svd`,
    when already computed (several ranks of one W). Returns a :class:`RotationEstimate`."""
    U, d, Vt, Wn, _ = _svd if _svd is not None else normalised_svd(W)
    n = min(3 * int(K), _numerical_rank(d))
    if n < 3:
        raise ValueError(f'W has numerical rank {_numerical_rank(d)} < 3')
    Pi = _motion_factor(U, d, n)
    idx = np.flatnonzero(known)
    rows = as_frames(Pi, 2)[idx]                                # (Fk, 2, n)
    F_k = idx.size
    A = np.zeros((F_k, 2, 3, 3 * n + F_k))
    # vec(G) column-major over (n, 3): entry (j, c) at j * 3 + c
    A[:, :, :, :3 * n] = np.einsum('fij,ck->ficjk', rows, np.eye(3)).reshape(F_k, 2, 3, 3 * n)
    A[np.arange(F_k), :, :, 3 * n + np.arange(F_k)] = -R0[idx, :2, :]
    x = np.linalg.svd(A.reshape(6 * F_k, -1), full_matrices=False)[2][-1]
    G, residual = _refine(x[:3 * n].reshape(n, 3) / np.linalg.norm(x[:3 * n]), Pi,
                          noise_penalty(d, n))
    R, ok = _rotations_from_triple(Pi, G)
    if not ok.all():
        raise ValueError('rotation rows degenerate for some frames')
    scores = {'residual': residual, 'rank_used': n, 'rule': f'K={int(K)} from the start'}
    return RotationEstimate(R=to_world_frame(R, R0, known), K=int(K), scores=scores)


def noise_ratio(K, n_frames):
    """Expected ``r_{K+1} / r_K`` when rank K already explains W and the rest is noise.

    The refined ``G_k`` has ``9K - 4`` effective parameters (9K entries less a global rotation
    and scale) against ``2F`` residuals, so under noise alone each extra basis shape lowers the
    RMS residual by the factor ``sqrt((2F - 9K - 5) / (2F - 9K + 4))``.
    """
    dof = 2 * n_frames - (9 * K - 4)
    return float(np.sqrt(max(dof - 9, 1) / max(dof, 1)))


def choose_rank(residuals, n_frames, *, plateau=PLATEAU_RATIO, exact=EXACT_RESIDUAL):
    """Pick the rotation rank K from the best orthonormality residual at each K.

    ``residuals``: ``{K: rms residual}`` from the nested search (non-increasing in K);
    ``n_frames``: F. Rule: the smallest K whose residual is already exact (``< exact``) or
    that the next rank K' improves by no more than noise would
    (``r_K' / r_K > plateau * noise_ratio``, per rank step): past the true rank the extra
    columns only fit noise, while below it every added basis shape removes a large share.
    Without a plateau, the largest K. Over-estimating K costs little with nested starts and
    under-estimating costs much, so the rule leans high. Returns ``(K, reason)``.
    """
    ks = sorted(residuals)
    if not ks:
        raise ValueError('no residuals')
    for k, nxt in zip(ks, ks[1:] + [None]):
        reason = _rank_rule(residuals, k, nxt, n_frames, plateau, exact)
        if reason:
            return k, reason
    return ks[-1], f'K={ks[-1]}: largest feasible rank, no plateau before it'


def _rank_rule(residuals, k, nxt, n_frames, plateau, exact):
    """:func:`choose_rank`'s reason to stop at rank ``k`` (exact, or a plateau to the next
    rank ``nxt``, None when it is not known yet), or None."""
    r = residuals[k]
    if r < exact:
        return f'K={k}: residual {r:.2e} below {exact:g} (exact fit)'
    if nxt is None:
        return None
    ratio = residuals[nxt] / r
    expected = np.prod([noise_ratio(j, n_frames) for j in range(k, nxt)])
    if ratio > plateau * expected:
        return (f'K={k}: residual plateau, r{nxt}/r{k} = {ratio:.3f} > {plateau} x '
                f'{expected:.3f} (noise-only ratio)')
    return None


def _rank_decided(residuals, n_frames):
    """Whether :func:`choose_rank` on ``residuals`` (the ranks searched so far) already
    stops by a rule no higher rank can change (the search is nested: a rank's residual
    depends on the lower ranks only): an exact fit, or a plateau to a rank searched."""
    ks = sorted(residuals)
    return any(_rank_rule(residuals, k, nxt, n_frames, PLATEAU_RATIO, EXACT_RESIDUAL)
               for k, nxt in zip(ks, ks[1:] + [None]))
