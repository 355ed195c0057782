"""How far a sequence of shapes is from one rigid shape: :func:`rigid_residual` of
``S: (3F, P)``, and :func:`most_rigid`, the factor by which the perspective depth scale
(:mod:`.perspective`) and the stage 'relief' (:mod:`.stages.relief`) scale flattened depths.
"""
import numpy as np

from .measurement import as_frames, nearest_rotation

#: the factors a flattened sequence's depths may be scaled by (the first on a tie): the
#: perspective rounds' (docs/decisions/0733) and the stage 'relief''s (0734)
SCALES = np.round(np.arange(1.0, 1.5 + 1e-9, 0.025), 3)
#: generalised Procrustes rounds of :func:`rigid_residual`
RIGID_ITERATIONS = 10
#: what each frame is divided by before the alignment: its whole norm, or that of its x, y
#: rows alone (left unchanged by a scale of the depths)
NORMS = ('shape', 'image')


def rigid_residual(S, iterations=RIGID_ITERATIONS, norm='shape'):
    """How far the frames of ``S: (3F, P)`` are from one rigid shape: each frame centred and
    divided by its Frobenius norm (``norm='shape'``) or by that of its x, y rows
    (``norm='image'``), the mean over frames of its squared distance to their common shape
    after its best rotation and scale (generalised Procrustes analysis from the first frame's
    shape, ``iterations`` rounds)."""
    if norm not in NORMS:
        raise ValueError(f'norm={norm!r}: expected one of {NORMS}')
    X = as_frames(np.asarray(S, dtype=np.float64), 3)
    X = X - X.mean(axis=2, keepdims=True)
    rows = X if norm == 'shape' else X[:, :2]
    X = X / np.maximum(np.linalg.norm(rows, axis=(1, 2), keepdims=True), 1e-300)
    shape = X[0]
    for _ in range(iterations):
        aligned = nearest_rotation(np.einsum('ip,fjp->fij', shape, X)) @ X
        shape = aligned.mean(axis=0)
        shape = shape / max(np.linalg.norm(shape), 1e-300)
    size = np.einsum('fip,ip->f', aligned, shape)
    return float(np.mean(np.sum((aligned - size[:, None, None] * shape) ** 2, axis=(1, 2))))


def most_rigid(shapes_at, scales=SCALES, norm='shape'):
    """The factor ``c`` among ``scales`` (the first on a tie) whose shapes ``shapes_at(c):
    (3F, P)`` have the least :func:`rigid_residual` (``norm`` as there)."""
    residuals = [rigid_residual(shapes_at(c), norm=norm) for c in scales]
    return float(scales[int(np.argmin(residuals))])
