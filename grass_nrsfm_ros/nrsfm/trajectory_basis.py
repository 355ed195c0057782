"""PTA: non-rigid SfM in trajectory space (Akhter, Sheikh, Khan, Kanade, NeurIPS 2008 /
TPAMI 2011), a baseline for the benchmarks.

Each point's x, y and z trajectory over the F frames is a combination of the first K vectors of
the DCT-II basis ``theta: (F, K)``. In world coordinates ``S_f = sum_k theta[f, k] A_k`` with
``A: (K, 3, P)``, so ``W = Lambda A`` where ``Lambda: (2F, 3K)`` holds the blocks
``theta[f, k] * R_f[:2]``. Given the rotations this is one linear least-squares problem with P
right-hand sides, solved for all points at once through the SVD of the small ``Lambda``
(O(F K^2 + F K P), nothing P x P).

Rotations. Akhter's code takes them from a rank-3K factorisation of W and a nonlinear metric
upgrade of one 3K x 3 corrective triple. Here, by default (``rotations='rigid'``), they come
from the rigid (Tomasi-Kanade) factorisation in :mod:`.rotation` (the TPAMI paper's reasoning:
trajectory-space reconstruction only needs the camera, and rigid factorisation is a good
camera estimate when the deformation is small against the camera motion). ``rotations='akhter'``
uses the closest thing in this package to Akhter's choice: the corrective-triple rotations of a
rank-3K factorisation (:func:`.rotation.rotations_for_rank` with the trajectory K, capped by
the rank W supports). Any ``R: (F, 3, 3)`` can also be passed (e.g. ground truth or
:func:`.rotation.estimate_rotations`).

Conventions (:mod:`.measurement`): ``W: (2F, P)``, ``S: (3F, P)`` camera frame,
``R: (F, 3, 3)`` world to camera.
"""
import numpy as np

from . import rotation
from .measurement import (as_frames, centre, from_frames, InvalidInputError, validate_rotations,
                          validate_tracks)

#: default number of DCT trajectory vectors
DEFAULT_K = 5
#: relative singular-value cut-off of the least-squares solve
RCOND = 1e-10


def dct_basis(n_frames, K):
    """The first K orthonormal DCT-II basis vectors as columns: ``theta: (F, K)``.

    ``theta[t, k] = sqrt(c_k / F) cos(pi (2t + 1) k / (2F))`` with ``c_0 = 1``, ``c_k = 2``
    (the columns of MATLAB's ``idct(eye(F))`` used by Akhter et al.).
    """
    if not 1 <= K <= n_frames:
        raise InvalidInputError(f'K must be in 1..F={n_frames}; got {K}')
    t = np.arange(n_frames)[:, None]
    k = np.arange(K)[None, :]
    theta = np.cos(np.pi * (2 * t + 1) * k / (2 * n_frames))
    weight = np.where(k == 0, 1.0, 2.0) / n_frames
    return theta * np.sqrt(weight)


def trajectory_design(R, theta):
    """``Lambda: (2F, 3K)`` with block (f, k) = ``theta[f, k] * R[f, :2, :]``.

    Column ``3k + c`` multiplies coefficient c (x, y, z) of basis vector k.
    """
    F, K = theta.shape
    blocks = theta[:, None, :, None] * R[:, :2, None, :]       # (F, 2, K, 3)
    return blocks.reshape(2 * F, 3 * K)


def trajectory_coefficients(Wc, R, theta, rcond=RCOND):
    """Least-squares coefficients ``A: (K, 3, P)`` of ``Wc: (2F, P)`` (centred) given R, theta.

    Minimum-norm solution through the SVD of ``Lambda: (2F, 3K)``; all P points at once.
    """
    Lam = trajectory_design(R, theta)
    U, s, Vt = np.linalg.svd(Lam, full_matrices=False)
    keep = s > rcond * s[0]
    coef = (Vt[keep].T / s[keep]) @ (U[:, keep].T @ Wc)        # (3K, P)
    return coef.reshape(theta.shape[1], 3, Wc.shape[1])


def shapes_from_coefficients(A, R, theta):
    """Camera-frame shapes ``S: (3F, P)`` from ``A: (K, 3, P)``:
    ``S_f = R_f sum_k theta_fk A_k``."""
    world = np.einsum('fk,kcp->fcp', theta, A)                  # (F, 3, P)
    return from_frames(R @ world)


def _rotations(W, K, rotations):
    """``R: (F, 3, 3)`` by the named rule (see the module docstring)."""
    if rotations == 'rigid':
        return rotation.rigid_factorisation(W)[0]
    if rotations == 'akhter':
        return rotation.estimate_rotations(W, K=K).R
    if rotations == 'dai':
        return rotation.estimate_rotations(W).R
    raise InvalidInputError(f"rotations must be 'rigid' or 'akhter'; got {rotations!r}")


def pta(W, R=None, K=DEFAULT_K, *, rotations='rigid'):
    """PTA reconstruction of ``W: (2F, P)`` (any translation). Returns ``(R, S)``.

    ``R: (F, 3, 3)`` the rotations used (given, or estimated by ``rotations``), ``S: (3F, P)``
    camera-frame shapes of the centred tracks. ``K`` DCT vectors per trajectory; needs
    ``3K <= 2F`` so that the coefficients are determined.
    """
    W = validate_tracks(W)
    F = W.shape[0] // 2
    K = int(K)
    if K < 1 or 3 * K > 2 * F:
        raise InvalidInputError(f'K={K} DCT vectors need 1 <= 3K <= 2F = {2 * F}')
    Wc, _ = centre(W)
    R = _rotations(W, K, rotations) if R is None else validate_rotations(R, F)
    theta = dct_basis(F, K)
    A = trajectory_coefficients(Wc, R, theta)
    return R, shapes_from_coefficients(A, R, theta)


def reprojection_residual(W, S):
    """RMS of ``centre(W) - x,y rows of S`` relative to the RMS of the centred W."""
    Wc, _ = centre(validate_tracks(W))
    xy = from_frames(as_frames(S, 3)[:, :2, :])
    return float(np.sqrt(np.mean((Wc - xy) ** 2) / np.mean(Wc ** 2)))
