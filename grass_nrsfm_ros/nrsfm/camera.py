"""Pinhole intrinsics: ``K: (3, 3)``, and tracks between pixels and normalised coordinates.

A pinhole camera sees the camera-frame point ``(X, Y, Z)`` at the pixel ``K [X/Z, Y/Z, 1]``
with ``K = [[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` (s: skew, usually 0). Its normalised image
point is ``x = K^-1 [u, v, 1] = (X/Z, Y/Z)``: the ray's direction, unitless.

* :func:`intrinsics` builds ``K`` from ``fx, fy, cx, cy`` (``--camera FX FY CX CY``).
* :func:`validate_intrinsics` checks a ``K`` (finite, upper triangular, positive focal
  lengths; a ``K`` scaled so that ``K[2, 2] != 1`` is divided through) and returns it.
* :func:`normalise` maps pixel tracks ``W_px: (2F, P)`` to normalised ones ``W: (2F, P)``,
  :func:`to_pixels` maps back; both keep NaN (missing) entries NaN.
* :func:`project` gives the normalised (or, with ``K``, pixel) tracks of camera-frame shapes
  ``S: (3F, P)``.
* :func:`resolved_projection` turns the solver parameter ``projection`` ('auto') into
  'perspective' or 'orthographic' by whether a ``K`` came with the tracks;
  :func:`warn_orthographic` says once per process that pixels without ``K`` are solved as
  orthographic projections.

Rows ``2f, 2f+1`` of a track matrix are frame f's u, v (pixels) or x, y (normalised).
"""
import warnings

import numpy as np

from .measurement import as_frames, from_frames, InvalidInputError


def intrinsics(fx, fy, cx, cy, skew=0.0):
    """``K: (3, 3)`` of focal lengths ``fx, fy`` and principal point ``cx, cy`` (pixels)."""
    return validate_intrinsics([[fx, skew, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def validate_intrinsics(K, name='K'):
    """``K`` as a float64 ``(3, 3)`` pinhole matrix with ``K[2] == [0, 0, 1]``, or raise
    InvalidInputError saying what is wrong. A ``K`` given up to scale (``K[2, 2] > 0``, not 1)
    is divided through by ``K[2, 2]``."""
    try:
        K = np.array(K, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise InvalidInputError(f'{name} must be a numeric (3, 3) matrix: {error}') from None
    if K.shape != (3, 3):
        raise InvalidInputError(f'{name} must be (3, 3); got shape {K.shape}')
    if not np.isfinite(K).all():
        raise InvalidInputError(f'{name} has non-finite entries: {K.tolist()}')
    if K[2, 0] != 0.0 or K[2, 1] != 0.0 or K[1, 0] != 0.0 or not K[2, 2] > 0.0:
        raise InvalidInputError(f'{name} must be upper triangular with K[2, 2] > 0 (a pinhole '
                                f'[[fx, s, cx], [0, fy, cy], [0, 0, 1]]); got {K.tolist()}')
    K /= K[2, 2]
    if not (K[0, 0] > 0.0 and K[1, 1] > 0.0):
        raise InvalidInputError(f'{name} needs positive focal lengths fx = K[0, 0], fy = '
                                f'K[1, 1]; got {K[0, 0]!r}, {K[1, 1]!r}')
    return K


def _uv(W, name):
    """``(u, v)``, each ``(F, P)`` float64, of a track matrix ``W: (2F, P)``."""
    W = np.asarray(W, dtype=np.float64)
    if W.ndim != 2 or W.shape[0] % 2:
        raise InvalidInputError(f'{name} must be (2F, P); got shape {W.shape}')
    return W[0::2], W[1::2]


def _interleave(a, b):
    """``(2F, P)`` with rows ``2f = a[f]``, ``2f + 1 = b[f]``."""
    return np.stack([a, b], axis=1).reshape(-1, a.shape[1])


def normalise(W_px, K):
    """Normalised tracks ``K^-1 [u, v, 1]``: ``(2F, P)`` of pixel tracks ``W_px: (2F, P)``."""
    K = validate_intrinsics(K)
    u, v = _uv(W_px, 'W_px')
    y = (v - K[1, 2]) / K[1, 1]
    x = (u - K[0, 2] - K[0, 1] * y) / K[0, 0]
    return _interleave(x, y)


def to_pixels(W, K):
    """Pixel tracks ``K [x, y, 1]``: ``(2F, P)`` of normalised tracks ``W: (2F, P)``."""
    K = validate_intrinsics(K)
    x, y = _uv(W, 'W')
    return _interleave(K[0, 0] * x + K[0, 1] * y + K[0, 2], K[1, 1] * y + K[1, 2])


def project(S, K=None):
    """Tracks ``(2F, P)`` of camera-frame shapes ``S: (3F, P)`` through a pinhole: normalised
    ``(X/Z, Y/Z)``, or pixels with ``K``. Raises InvalidInputError where a point is not in
    front of the camera (``Z <= 0``)."""
    X = as_frames(np.asarray(S, dtype=np.float64), 3)
    Z = X[:, 2:, :]
    if not (Z > 0).all():
        f, p = np.argwhere(~(Z[:, 0] > 0))[0]
        raise InvalidInputError(f'S frame {f} point {p} has depth {Z[f, 0, p]!r}: a pinhole '
                                'sees only points with Z > 0')
    W = from_frames(X[:, :2, :] / Z)
    return W if K is None else to_pixels(W, K)


class OrthographicPixelsWarning(UserWarning):
    """Pixel tracks with no camera intrinsics, solved as orthographic projections."""


#: what :func:`warn_orthographic` says
ORTHOGRAPHIC_MESSAGE = (
    'no camera intrinsics (K): the pixel tracks are solved as orthographic projections; a '
    'pinhole camera close to the surface doubles the 3D error (docs/decisions/0702). Give K '
    '(an npz K, --camera FX FY CX CY, a camera_info topic or the camera parameter).')


def warn_orthographic():
    """Warn (an :class:`OrthographicPixelsWarning`; Python's default filter shows it once per
    process) that pixel tracks without ``K`` are solved as orthographic projections."""
    warnings.warn(ORTHOGRAPHIC_MESSAGE, OrthographicPixelsWarning)


def resolved_projection(projection, K):
    """'perspective' or 'orthographic': the solver parameter ``projection`` ('auto',
    'orthographic' or 'perspective') for tracks given with intrinsics ``K`` (or None):
    'auto' is perspective exactly when ``K`` is given."""
    if projection == 'auto':
        return 'orthographic' if K is None else 'perspective'
    return projection
