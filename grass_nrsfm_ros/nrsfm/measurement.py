"""Measurement-matrix conventions, validation and centring.

Shapes used across the core (F frames, P points):

* ``W: (2F, P)``: 2D tracks. Rows ``2f, 2f+1`` are the image u, v of frame f; column j is
  point j in every frame.
* ``S: (3F, P)``: 3D shapes. Rows ``3f..3f+2`` are x, y, z of frame f in that frame's camera
  coordinates (x, y reproduce the centred W up to the residual, z is depth).
* ``R: (F, 3, 3)``: rotation from the solver's world frame to frame f's camera; the first two
  rows are the orthographic camera of frame f.
"""
import numpy as np

#: a wide matrix's SVD goes through its Gram matrix when it has more than this many columns
#: per row (:func:`economy_svd`)
GRAM_COLUMNS_PER_ROW = 10


class InvalidInputError(ValueError):
    """Raised when an input array breaks the conventions above (with the offending value)."""


def validate_tracks(W, *, min_frames=2, min_points=4, name='W'):
    """Return ``W: (2F, P)`` as a float64 array, or raise InvalidInputError saying why."""
    W = np.asarray(W)
    if W.ndim != 2:
        raise InvalidInputError(f'{name} must be 2-D (2F, P); got shape {W.shape}')
    if W.dtype.kind not in 'fiu':
        raise InvalidInputError(f'{name} must be numeric; got dtype {W.dtype}')
    rows, points = W.shape
    if rows % 2:
        raise InvalidInputError(f'{name} needs an even number of rows (2F); got {rows}')
    if rows // 2 < min_frames:
        raise InvalidInputError(f'{name} has {rows // 2} frames; at least {min_frames} needed')
    if points < min_points:
        raise InvalidInputError(f'{name} has {points} points; at least {min_points} needed')
    W = W.astype(np.float64, copy=False)
    bad = ~np.isfinite(W)
    if bad.any():
        r, c = np.argwhere(bad)[0]
        raise InvalidInputError(
            f'{name} has {int(bad.sum())} non-finite entries (first: frame {r // 2}, '
            f'point {c}, value {W[r, c]})')
    return W


def validate_shapes(S, *, n_frames=None, n_points=None, name='S'):
    """Return ``S: (3F, P)`` as float64, checking shape against optional F and P."""
    S = np.asarray(S, dtype=np.float64)
    if S.ndim != 2 or S.shape[0] % 3:
        raise InvalidInputError(f'{name} must be (3F, P); got shape {S.shape}')
    if n_frames is not None and S.shape[0] // 3 != n_frames:
        raise InvalidInputError(f'{name} has {S.shape[0] // 3} frames; expected {n_frames}')
    if n_points is not None and S.shape[1] != n_points:
        raise InvalidInputError(f'{name} has {S.shape[1]} points; expected {n_points}')
    if not np.isfinite(S).all():
        raise InvalidInputError(f'{name} has non-finite entries')
    return S


def validate_rotations(R, n_frames=None, *, name='R', atol=1e-6):
    """Return ``R: (F, 3, 3)`` as float64 if every R_f is orthonormal, else raise."""
    R = np.asarray(R, dtype=np.float64)
    if R.ndim != 3 or R.shape[1:] != (3, 3):
        raise InvalidInputError(f'{name} must be (F, 3, 3); got shape {R.shape}')
    if n_frames is not None and R.shape[0] != n_frames:
        raise InvalidInputError(f'{name} has {R.shape[0]} frames; expected {n_frames}')
    gap = np.abs(R @ R.transpose(0, 2, 1) - np.eye(3)).max()
    if not np.isfinite(gap) or gap > atol:
        raise InvalidInputError(f'{name} is not orthonormal (max |R R^T - I| = {gap:.3g})')
    return R


def n_frames_of(W):
    """Number of frames F of ``W: (2F, P)``."""
    return W.shape[0] // 2


def centre(W):
    """Remove each row's mean. Returns ``(Wc: (2F, P), t: (2F, 1))`` with ``W = Wc + t``."""
    t = W.mean(axis=1, keepdims=True)
    return W - t, t


def as_frames(M, rows_per_frame):
    """View ``M: (rF, P)`` as ``(F, r, P)`` (no copy for contiguous input)."""
    return M.reshape(-1, rows_per_frame, M.shape[-1])


def frame_rows(frames, rows_per_frame):
    """``(len(frames) * rows_per_frame,)`` row indices of ``frames: (n,)`` in a matrix of
    ``rows_per_frame`` rows per frame (``W: (2F, P)``: 2, ``S: (3F, P)``: 3)."""
    return (rows_per_frame * np.asarray(frames)[:, None] + np.arange(rows_per_frame)).ravel()


def spread_frames(F, n):
    """``(m,)`` sorted distinct frame indices, ``m = min(F, n)``, spread evenly over ``F``
    frames, the first and the last included."""
    return np.unique(np.linspace(0, F - 1, min(F, int(n))).round().astype(int))


def from_frames(X):
    """Stack ``X: (F, r, P)`` back to ``(rF, P)``."""
    return X.reshape(-1, X.shape[-1])


def project(R, S):
    """Orthographic projection of world shapes: ``R: (F,3,3)``, ``S_world: (3F,P)`` -> ``(2F,P)``.

    Only the first two rows of each R_f are used.
    """
    return from_frames(R[:, :2, :] @ as_frames(S, 3))


def to_camera(R, S_world):
    """World-frame shapes ``(3F, P)`` -> camera-frame shapes ``(3F, P)`` via ``R_f S_f``."""
    return from_frames(R @ as_frames(S_world, 3))


def to_world(R, S_camera):
    """Camera-frame shapes ``(3F, P)`` -> world-frame shapes ``(3F, P)`` via ``R_f^T S_f``."""
    return from_frames(R.transpose(0, 2, 1) @ as_frames(S_camera, 3))


def track_scale(Wc):
    """Root-mean-square of centred tracks ``Wc: (2F, P)``; the solver's unit of length."""
    scale = float(np.sqrt(np.mean(Wc ** 2)))
    if not np.isfinite(scale) or scale <= 0.0:
        raise InvalidInputError('W has no spread: every track is constant within each frame')
    return scale


def nearest_rotation(M):
    """The proper rotations (det +1) nearest to ``M: (..., 3, 3)`` in Frobenius norm: ``U V^T``
    of the SVD, with the last column of U negated where that would be a reflection."""
    U, _, Vt = np.linalg.svd(M)
    U[..., :, -1] *= np.where(np.linalg.det(U @ Vt) < 0, -1.0, 1.0)[..., None]
    return U @ Vt


def economy_svd(M):
    """``(U: (m, k), d: (k,), Vt: (k, n))``, the economy SVD of ``M: (m, n)``, k = min(m, n).
    A wide M (``n > GRAM_COLUMNS_PER_ROW * m``) goes through its ``m x m`` Gram matrix
    (``O(m^2 n)``, no n-sized factorisation: 99 x 28,880 in 0.03 s instead of 1.0 s);
    singular values below ~1e-8 of the largest are then not resolved."""
    if M.shape[1] <= GRAM_COLUMNS_PER_ROW * M.shape[0]:
        return np.linalg.svd(M, full_matrices=False)
    vals, vecs = np.linalg.eigh(M @ M.T)
    d = np.sqrt(np.maximum(vals[::-1], 0.0))
    U = np.ascontiguousarray(vecs[:, ::-1])
    Vt = (U.T @ M) / np.where(d > 0, d, 1.0)[:, None]
    return U, d, Vt
