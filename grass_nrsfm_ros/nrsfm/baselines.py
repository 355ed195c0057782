"""Reference shape steps that turn rotations into shapes (baselines for the solver).

* :func:`rigid`: Tomasi-Kanade rotations and rigid shape (re-exported from :mod:`.rotation`).
* :func:`bmm`: the shape step of Dai, Li and He's block-matrix method: the depths that make
  the world-frame shapes of lowest nuclear norm, ``min ||S#||_* s.t. W = R S``.

``W: (2F, P)`` (any translation), ``R: (F, 3, 3)``, shapes ``S: (3F, P)`` in camera frame.
"""
from dataclasses import dataclass

import numpy as np

from .measurement import (as_frames, centre, from_frames, track_scale, validate_rotations,
                          validate_tracks)
from .rotation import rigid_factorisation


def rigid(W):
    """Rigid baseline: ``(R: (F, 3, 3), S: (3F, P))`` by :func:`rotation.rigid_factorisation`."""
    return rigid_factorisation(W)


def singular_value_threshold(M, tau):
    """Soft-threshold the singular values of ``M: (m, q)`` at ``tau`` (SVT).

    Works through the Gram matrix of the smaller side (``min(m, q)`` squared), so a tall or
    wide matrix never needs its large Gram matrix. Returns ``(shrunk M, rank kept)``.
    """
    wide = M.shape[0] <= M.shape[1]
    gram = M @ M.T if wide else M.T @ M
    w, V = np.linalg.eigh(gram)
    sigma = np.sqrt(np.clip(w, 0.0, None))
    keep = sigma > tau
    factor = np.zeros_like(sigma)
    factor[keep] = (sigma[keep] - tau) / sigma[keep]
    Vk = V[:, keep] * factor[keep]
    shrunk = Vk @ (V[:, keep].T @ M) if wide else (M @ V[:, keep]) @ Vk.T
    return shrunk, int(keep.sum())


@dataclass(frozen=True)
class BMMReport:
    """Convergence record of :func:`bmm`: iterations, final relative gap, rank of S#."""
    iterations: int
    gap: float
    rank: int


def bmm(W, R, *, max_iter=500, rho=1.05, mu0=None, tol=1e-7, return_report=False):
    """Dai et al.'s BMM shape step: ``min ||S#||_*`` subject to ``W = R S`` exactly.

    ``S#: (F, 3P)`` stacks the world-frame shapes ``R_f^T S_f`` (row f = x, y, z rows of frame
    f). With R fixed only the depth row of each camera-frame shape is free, so ADMM alternates
    an SVT of ``S# + Y/mu`` (through the smaller Gram matrix) with a closed-form depth update;
    ``mu`` grows by ``rho`` per iteration from ``mu0`` (default ``1 / ||S#_0||_2``).

    ``W: (2F, P)`` any translation, ``R: (F, 3, 3)``. Returns ``S: (3F, P)`` camera frame
    (x, y = centred W), or ``(S, BMMReport)`` with ``return_report``.
    """
    Wc, _ = centre(validate_tracks(W))
    F, P = Wc.shape[0] // 2, Wc.shape[1]
    R = validate_rotations(R, F)
    scale = track_scale(Wc)
    Wf = as_frames(Wc / scale, 2)                                  # (F, 2, P)
    base = R[:, :2, :].transpose(0, 2, 1) @ Wf                     # (F, 3, P) in-plane part
    axis = R[:, 2, :]                                              # (F, 3) viewing direction
    depth = np.zeros((F, P))

    def sharp(z):
        return (base + axis[:, :, None] * z[:, None, :]).reshape(F, 3 * P)

    M = sharp(depth)
    Y = np.zeros_like(M)
    mu = mu0 if mu0 is not None else 1.0 / max(np.linalg.norm(M, 2), 1e-12)
    gap, rank, it = np.inf, 0, 0
    for it in range(1, max_iter + 1):
        Z, rank = singular_value_threshold(M + Y / mu, 1.0 / mu)
        target = (Z - Y / mu).reshape(F, 3, P)
        depth = np.einsum('fi,fip->fp', axis, target)
        M = sharp(depth)
        residual = M - Z
        Y += mu * residual
        mu *= rho
        gap = np.linalg.norm(residual) / max(np.linalg.norm(M), 1e-300)
        if gap < tol:
            break
    S = from_frames(np.concatenate([Wf, depth[:, None, :]], axis=1)) * scale
    if return_report:
        return S, BMMReport(iterations=it, gap=float(gap), rank=rank)
    return S
