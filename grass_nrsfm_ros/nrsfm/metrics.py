"""Reconstruction error metrics.

* :func:`e3d`: the dense-NRSfM e3D of Garg et al. 2013 / Kumar et al. 2018: per-frame
  Procrustes alignment (each frame centred, orthogonal, reflection allowed, no scale by
  default), then ``mean_f ||S_est_f - S_gt_f||_F / ||S_gt_f||_F``.
* :func:`e3d_akhter`: the metric of Akhter et al.'s ``compareStructs`` used by the sparse mocap
  tables (PTA, BMM): one orthogonal alignment for the whole sequence, errors as mean point
  distance over ``s`` = mean row standard deviation of the ground truth.

Both take ``S: (3F, P)`` in camera coordinates.
"""
import numpy as np

from .measurement import (as_frames, frame_rows, from_frames, InvalidInputError,
                          nearest_rotation, validate_shapes)


def _nearest_orthogonal(M, reflection):
    """Nearest orthogonal matrices to ``M: (..., 3, 3)`` (``U V^T``); det +1 unless reflection."""
    if not reflection:
        return nearest_rotation(M)
    U, _, Vt = np.linalg.svd(M)
    return U @ Vt


def procrustes_align(S_est, S_gt, *, scale=False, reflection=True, centre=True, visible=None):
    """Align each frame of ``S_est: (3F, P)`` to ``S_gt: (3F, P)``.

    Returns ``(aligned_est, gt)``, both ``(3F, P)`` and, when ``centre``, with each frame's
    centroid removed. Per frame solves ``min_{Q, s} ||s Q X - Y||_F`` with Q orthogonal
    (``det Q = +1`` unless ``reflection``) and s = 1 unless ``scale``. ``visible: (F, P)``
    bool: only those points count (centroids over them; both outputs 0 elsewhere).
    """
    X = as_frames(np.asarray(S_est, dtype=np.float64), 3)
    Y = as_frames(np.asarray(S_gt, dtype=np.float64), 3)
    if visible is not None:
        m = np.asarray(visible, dtype=np.float64)[:, None, :]
        X, Y = np.where(m > 0, X, 0.0), np.where(m > 0, Y, 0.0)
        if centre:
            count = np.maximum(m.sum(axis=2, keepdims=True), 1.0)
            X = (X - X.sum(axis=2, keepdims=True) / count) * m
            Y = (Y - Y.sum(axis=2, keepdims=True) / count) * m
    elif centre:
        X = X - X.mean(axis=2, keepdims=True)
        Y = Y - Y.mean(axis=2, keepdims=True)
    M = Y @ X.transpose(0, 2, 1)                      # (F, 3, 3) cross-covariance
    Q = _nearest_orthogonal(M, reflection)
    aligned = Q @ X
    if scale:
        num = np.einsum('fij,fij->f', aligned, Y)
        den = np.einsum('fij,fij->f', aligned, aligned)
        aligned = aligned * (num / np.where(den > 0, den, 1.0))[:, None, None]
    return from_frames(aligned), from_frames(Y)


def e3d(S_est, S_gt, *, scale=False, reflection=True, centre=True, per_frame=False,
        visible=None):
    """Mean over frames of ``||S_est_f - S_gt_f||_F / ||S_gt_f||_F`` after per-frame Procrustes.

    ``S_est, S_gt: (3F, P)``. With ``per_frame=True`` returns the ``(F,)`` errors instead.
    ``visible: (F, P)`` bool: each frame over those points only (both S may be non-finite
    elsewhere), the frames with none left out (``per_frame``: NaN there).
    """
    if visible is not None:
        visible = np.asarray(visible, dtype=bool)
        expected = (np.shape(S_gt)[0] // 3, np.shape(S_gt)[1])
        if visible.shape != expected or np.shape(S_est) != np.shape(S_gt):
            raise InvalidInputError(f'visible must be (F, P) = {expected} and S_est as S_gt '
                                    f'{np.shape(S_gt)}; got {visible.shape}, '
                                    f'{np.shape(S_est)}')
        if per_frame:
            out = np.full(visible.shape[0], np.nan)
        frames = np.flatnonzero(visible.any(axis=1))
        rows = frame_rows(frames, 3)
        visible = visible[frames]
        S_gt, S_est = (np.where(np.repeat(visible, 3, axis=0),
                                np.asarray(S, dtype=np.float64)[rows], 0.0)
                       for S in (S_gt, S_est))
    S_gt = validate_shapes(S_gt, name='S_gt')
    S_est = validate_shapes(S_est, n_frames=S_gt.shape[0] // 3, n_points=S_gt.shape[1],
                            name='S_est')
    aligned, gt = procrustes_align(S_est, S_gt, scale=scale, reflection=reflection,
                                   centre=centre, visible=visible)
    diff = as_frames(aligned - gt, 3)
    norms = np.linalg.norm(as_frames(gt, 3), axis=(1, 2))
    if not (norms > 0).all():
        raise InvalidInputError(f'S_gt frame {int(np.argmin(norms))} has zero norm (a single '
                                'point once centred): e3D is undefined')
    err = np.linalg.norm(diff, axis=(1, 2)) / norms
    if visible is not None and per_frame:
        out[frames] = err
        return out
    return err if per_frame else float(err.mean())


def e3d_akhter(S_est, S_gt):
    """Akhter et al.'s mocap error (``compareStructs``): one rotation for the whole sequence.

    Each frame is centred, one orthogonal Q (reflection allowed) aligns all of ``S_est``
    to ``S_gt`` in least squares, and the error is the mean over frames and points of the
    3D point distance divided by ``s``, the mean over the 3F rows of the ground truth's
    standard deviation. ``S_est, S_gt: (3F, P)``.
    """
    S_gt = validate_shapes(S_gt, name='S_gt')
    S_est = validate_shapes(S_est, n_frames=S_gt.shape[0] // 3, n_points=S_gt.shape[1],
                            name='S_est')
    X = as_frames(S_est, 3)
    Y = as_frames(S_gt, 3)
    X = X - X.mean(axis=2, keepdims=True)
    Y = Y - Y.mean(axis=2, keepdims=True)
    Q = _nearest_orthogonal(np.einsum('fip,fjp->ij', Y, X), reflection=True)
    s = from_frames(Y).std(axis=1).mean()
    if not s > 0:
        raise InvalidInputError('S_gt does not move or extend (zero row deviation): Akhter '
                                "et al.'s error is undefined")
    dist = np.linalg.norm(Q @ X - Y, axis=1)          # (F, P)
    return float(dist.mean() / s)


def rotation_error(R_est, R_gt):
    """Mean over frames of the angle (degrees) between ``R_est`` and ``R_gt``, both (F, 3, 3).

    The orthographic camera cannot tell a rotation from its depth-flipped mirror, so each
    frame's error is the smaller of the two candidates' angles on the camera rows.
    """
    R_est = np.asarray(R_est, dtype=np.float64)
    R_gt = np.asarray(R_gt, dtype=np.float64)
    flip = np.diag([1.0, 1.0, -1.0])
    best = []
    for cand in (R_est, flip @ R_est @ flip):
        # align the global world frame once, then compare frame by frame
        Q = _nearest_orthogonal(np.einsum('fij,fik->jk', cand, R_gt), reflection=False)
        rel = R_gt @ (cand @ Q).transpose(0, 2, 1)
        cosang = np.clip((np.trace(rel, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
        best.append(np.degrees(np.arccos(cosang)))
    return float(np.minimum(*best).mean())
