"""Organic Priors' rotations (Kumar & Van Gool, ECCV 2022): Dai's rotation averaged per frame
with the rotations of the other column triplets of the corrective matrix. A research variant
kept for ``python -m bench.rotations`` only: it measured no better than Dai's rotations
(docs/decisions/archive/0500), so the solver no longer offers it (docs/decisions/0430).

* :func:`triplet_candidates`: at Dai's rank K, a full-rank PSD point ``Q`` of the null space of
  the orthonormality constraints, its 3K x 3K factor ``G = [G^1 ... G^K]`` (eigenvectors of Q,
  descending), and one rotation candidate per column triplet ``G^k`` after Dai's refinement.
* :func:`register_candidates`: each candidate ``R^k: (F, 3, 3)`` registered to the reference
  by one world rotation, over its global-sign and depth-mirror variants, and per frame the
  sign of the camera rows nearer the reference.
* :func:`l1_average`: the per-frame L1 rotation average (Weiszfeld in the tangent space, from
  the projected entry-wise median) of ``samples: (F, n, 3, 3)`` with ``mask: (F, n)``.
* :func:`op_samples`, :func:`average_within`: the samples of a reference, their filter and
  average; :func:`op_rotations`: the whole method, a ``RotationEstimate``.

Rotations are ``(..., 3, 3)`` world to camera, as in :mod:`grass_nrsfm_ros.nrsfm.rotation`. The
constants are OP's: filter radius ``DELTA`` (chordal, to the reference), ``SRA_ITERATIONS``,
``SRA_TOL``.
"""
import numpy as np

from grass_nrsfm_ros.nrsfm.measurement import nearest_rotation
from grass_nrsfm_ros.nrsfm.rotation import (_constraint_matrix, _motion_factor, _null_space,
                                            _numerical_rank, _refine, _rotations_from_triple,
                                            _smat, _svec, estimate_rotations, normalised_svd,
                                            RotationEstimate)

#: OP's filter: a candidate is kept in a frame where its chordal distance to the reference is
#: below this
DELTA = 0.05
#: OP's Weiszfeld iterations (a cap) and its stop on the tangent step (radians)
SRA_ITERATIONS = 50
SRA_TOL = 1e-3
#: alternating projections (PSD cone <-> null space) for the full-rank PSD point Q
PSD_SWEEPS = 50
#: tangent vectors shorter than this are the current average itself (Hartley's safeguard)
TINY_ANGLE = 1e-12
#: sign of the camera rows and the orthographic depth-mirror, as matrices acting on R
ROW_SIGN = np.diag([-1.0, -1.0, 1.0])
MIRROR = np.diag([1.0, 1.0, -1.0])


# ----------------------------------------------------------------------------- SO(3)

def hat(v):
    """``v: (..., 3)`` -> skew matrices ``(..., 3, 3)``."""
    z = np.zeros(v.shape[:-1])
    return np.stack([np.stack([z, -v[..., 2], v[..., 1]], -1),
                     np.stack([v[..., 2], z, -v[..., 0]], -1),
                     np.stack([-v[..., 1], v[..., 0], z], -1)], -2)


def so3_exp(v):
    """Rodrigues: axis-angle ``v: (..., 3)`` -> rotations ``(..., 3, 3)``."""
    theta = np.linalg.norm(v, axis=-1)[..., None, None]
    K = hat(v)
    small = theta < 1e-8
    t = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta ** 2 / 6.0, np.sin(t) / t)
    b = np.where(small, 0.5 - theta ** 2 / 24.0, (1.0 - np.cos(t)) / t ** 2)
    return np.eye(3) + a * K + b * (K @ K)


def so3_log(R):
    """Rotations ``R: (..., 3, 3)`` -> axis-angle ``(..., 3)``, angles in [0, pi].

    Near pi the axis comes from ``a a^T = (sym(R) - cos I) / (1 - cos)`` (its largest
    column), the sign from the skew part."""
    cosang = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    theta = np.arccos(cosang)
    w = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0],
                  R[..., 1, 0] - R[..., 0, 1]], -1)
    small = theta < 1e-8
    factor = np.where(small, 0.5 + theta ** 2 / 12.0,
                      theta / (2.0 * np.sin(np.where(small, 1.0, theta))))
    v = w * factor[..., None]
    near_pi = theta > np.pi - 1e-3
    if near_pi.any():
        Rp, c = R[near_pi], cosang[near_pi]
        aa = ((Rp + np.swapaxes(Rp, -1, -2)) / 2.0 - c[:, None, None] * np.eye(3)) / (
            1.0 - c)[:, None, None]
        i = np.argmax(np.diagonal(aa, axis1=-2, axis2=-1), axis=-1)
        axis = np.take_along_axis(aa, i[:, None, None], axis=-1)[..., 0]
        axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
        sign = np.sign((axis * w[near_pi]).sum(-1))
        sign[sign == 0] = 1.0
        v[near_pi] = axis * (sign * theta[near_pi])[:, None]
    return v


def chordal(A, B):
    """``||A - B||_F`` over the last two axes."""
    return np.linalg.norm(A - B, axis=(-2, -1))


# ----------------------------------------------------------------------------- candidates

def _full_rank_psd_point(N, n):
    """A PSD ``Q: (n, n)`` in the span of the null-space basis ``N: (m, d)`` (alternating
    projections from the projection of the identity), trace 1; its rank is full (3K) where the
    constraints allow it (the sum of the triplets' ``G^k G^k^T``)."""
    q = N @ (N.T @ _svec(np.eye(n), n))
    for _ in range(PSD_SWEEPS):
        w, V = np.linalg.eigh(_smat(q, n))
        if w.sum() < 0:
            w = -w
        q = N @ (N.T @ _svec((V * np.clip(w, 0.0, None)) @ V.T, n))
    Q = _smat(q, n)
    if np.trace(Q) < 0:
        Q = -Q
    return Q / max(abs(np.trace(Q)), 1e-300)


def triplet_candidates(W, K, *, _svd=None):
    """One rotation candidate per column triplet of a corrective matrix at rank K.

    ``G = V diag(w)^{1/2}: (n, n)`` from the eigenvectors of the full-rank PSD null-space
    point (descending), n = 3K (less where W has lower rank); triplet k is columns 3k-3..3k,
    refined by Dai's scale-free orthonormality cost. Returns ``(R: (K', F, 3, 3),
    residuals: (K',))``, K' <= n // 3 (triplets with degenerate rows left out).
    """
    U, d, _, _, _ = _svd if _svd is not None else normalised_svd(W)
    n = min(3 * K, _numerical_rank(d))
    n -= n % 3
    Pi = _motion_factor(U, d, n)
    kk = n // 3
    N, _ = _null_space(_constraint_matrix(Pi), max(1, 2 * kk * kk - kk))
    w, V = np.linalg.eigh(_full_rank_psd_point(N, n))
    G = V[:, ::-1] * np.sqrt(np.clip(w[::-1], 0.0, None))
    rotations, residuals = [], []
    for k in range(kk):
        G0 = G[:, 3 * k:3 * k + 3]
        if np.linalg.norm(G0) == 0:
            continue
        Gk, res = _refine(G0 / np.linalg.norm(G0), Pi)
        R, ok = _rotations_from_triple(Pi, Gk)
        if ok.all():
            rotations.append(R)
            residuals.append(res)
    return np.array(rotations).reshape(-1, U.shape[0] // 2, 3, 3), np.array(residuals)


# ----------------------------------------------------------------------------- registration

def register_candidates(R_ref, candidates):
    """Register ``candidates: (n, F, 3, 3)`` to ``R_ref: (F, 3, 3)``.

    Per candidate, each of the four variants (camera-row sign ``ROW_SIGN R``, depth mirror
    ``MIRROR R MIRROR``) is registered by the world rotation ``Z`` minimising
    ``sum_f ||R_ref_f - R_f Z^T||^2`` (Procrustes), the variant of least residual is kept, and
    per frame the camera-row sign nearer the reference. Returns ``(registered (n, F, 3, 3),
    residuals (n,))``, residual the RMS chordal distance per frame.
    """
    out, residuals = [], []
    for R in candidates:
        best = None
        for variant in (R, ROW_SIGN @ R, MIRROR @ R @ MIRROR, ROW_SIGN @ MIRROR @ R @ MIRROR):
            Zt = nearest_rotation(np.einsum('fji,fjk->ik', variant, R_ref))
            reg = variant @ Zt
            flipped = ROW_SIGN @ reg
            closer = chordal(flipped, R_ref) < chordal(reg, R_ref)
            reg = np.where(closer[:, None, None], flipped, reg)
            res = float(np.sqrt(np.mean(chordal(reg, R_ref) ** 2)))
            if best is None or res < best[1]:
                best = (reg, res)
        out.append(best[0])
        residuals.append(best[1])
    return np.array(out).reshape(candidates.shape), np.array(residuals)


# ----------------------------------------------------------------------------- averaging

def entrywise_median(samples, mask):
    """Projected (:func:`nearest_rotation`) entry-wise median over the kept samples:
    ``samples: (F, n, 3, 3)``, ``mask: (F, n)`` with at least one True per frame -> (F, 3, 3)."""
    masked = np.where(mask[:, :, None, None], samples, np.nan)
    return nearest_rotation(np.nanmedian(masked, axis=1))


def l1_average(samples, mask, *, iterations=SRA_ITERATIONS, tol=SRA_TOL):
    """Per-frame L1 rotation average (Hartley et al.'s Weiszfeld on SO(3)).

    ``samples: (F, n, 3, 3)``, ``mask: (F, n)`` bool, at least one kept sample per frame.
    From the entry-wise median, ``v_i = log(R_i R^T)``, step ``sum v_i/|v_i| / sum 1/|v_i|``
    (samples at the average itself left out), ``R <- exp(step) R``; a frame stops when its
    step is below ``tol`` radians. Returns ``(R: (F, 3, 3), iterations done)``.
    """
    R = entrywise_median(samples, mask)
    active = np.ones(R.shape[0], dtype=bool)
    done = 0
    for done in range(1, iterations + 1):
        v = so3_log(samples[active] @ R[active, None].transpose(0, 1, 3, 2))
        norm = np.linalg.norm(v, axis=-1)
        weight = np.where(mask[active] & (norm > TINY_ANGLE),
                          1.0 / np.maximum(norm, TINY_ANGLE), 0.0)
        total = weight.sum(axis=1)
        step = (weight[..., None] * v).sum(axis=1) / np.where(total > 0, total, 1.0)[:, None]
        R[active] = so3_exp(step) @ R[active]
        still = np.linalg.norm(step, axis=-1) >= tol
        active[np.flatnonzero(active)[~still]] = False
        if not active.any():
            break
    return R, done


# ----------------------------------------------------------------------------- the method

def op_samples(W, reference, *, _svd=None):
    """The per-frame samples of OP's average for ``W: (2F, P)`` and Dai's ``reference``
    (a ``RotationEstimate``): ``(samples: (F, 1 + n, 3, 3)`` with the reference
    first, ``info`` dict of the candidates' refinement and registration residuals``)``."""
    cand, refine_res = triplet_candidates(W, reference.K, _svd=_svd)
    registered, reg_res = register_candidates(reference.R, cand)
    samples = np.concatenate([reference.R[:, None], registered.transpose(1, 0, 2, 3)], axis=1)
    return samples, {'candidates': int(cand.shape[0]), 'refine_residuals': refine_res.tolist(),
                     'registration_residuals': reg_res.tolist()}


def average_within(samples, delta=DELTA):
    """OP's filter and average of ``samples: (F, n, 3, 3)`` (reference first): ``(R: (F, 3, 3),
    kept share of the other samples, Weiszfeld iterations)``."""
    mask = chordal(samples, samples[:, :1]) < delta
    mask[:, 0] = True
    R, iterations = l1_average(samples, mask)
    return R, float(mask[:, 1:].mean()) if samples.shape[1] > 1 else 0.0, iterations


def op_rotations(W, K='auto', *, candidates=None, random_state=0, delta=DELTA):
    """Organic Priors' rotations of ``W: (2F, P)`` (any translation).

    The reference is Dai's rotation (``estimate_rotations``, its K chosen from
    the data or given); the K triplet candidates at that K (:func:`triplet_candidates`) are
    registered to it (:func:`register_candidates`), kept per frame within chordal ``delta`` of
    it, and averaged with it per frame (:func:`l1_average`). Falls back to the reference where
    Dai's step fell back or K = 1. Returns a ``RotationEstimate`` whose
    ``scores['op']`` holds the candidates' residuals, the share of samples kept and the
    Weiszfeld iterations.
    """
    svd = normalised_svd(W)
    kwargs = {} if candidates is None else {'candidates': candidates}
    ref = estimate_rotations(W, K=K, random_state=random_state, **kwargs)
    if 'fallback' in ref.scores or ref.K < 2:
        return RotationEstimate(R=ref.R, K=ref.K, scores={
            **ref.scores, 'op': {'candidates': 0, 'kept_share': 0.0, 'iterations': 0}})
    samples, info = op_samples(W, ref, _svd=svd)
    R, kept, iterations = average_within(samples, delta)
    info.update(kept_share=kept, iterations=iterations)
    return RotationEstimate(R=R, K=ref.K, scores={**ref.scores, 'op': info})
