"""``grass-nrsfm evaluate OUT.npz GT.npz``: e3D of a reconstruction against ground truth.

When OUT reconstructs only some of the input's tracks (``points``, written by ``reconstruct
--complete-tracks``), the ground truth's matching columns are compared. Entries not finite in
either (tracks ``reconstruct`` left out as NaN) are left out, and the count is said.
"""
import numpy as np

from grass_nrsfm_ros.cli import UserError
from grass_nrsfm_ros.commands.npz import GROUND_TRUTH_KEYS, load_shapes
from grass_nrsfm_ros.nrsfm.metrics import e3d, e3d_akhter


def add_arguments(parser):
    parser.add_argument('estimate', help='.npz with S (3F, P), e.g. from `reconstruct`')
    parser.add_argument('ground_truth', help='.npz with S (3F, P) ground truth')
    parser.add_argument('--scale', action='store_true',
                        help='also fit a per-frame scale in the Procrustes alignment')


def matched_ground_truth(S_gt, points, n_points):
    """The ground-truth columns ``(3F, P')`` the estimate's ``points`` name (all if None)."""
    if points is None or S_gt.shape[1] == n_points:
        return S_gt
    if points.ndim != 1 or points.size != n_points or points.dtype.kind not in 'iu' \
            or points.min(initial=0) < 0 or points.max(initial=0) >= S_gt.shape[1]:
        raise UserError(f"the estimate's points do not index the ground truth's "
                        f'{S_gt.shape[1]} columns')
    return S_gt[:, points]


def run(args):
    S_est, points = load_shapes(args.estimate)
    S_gt, _ = load_shapes(args.ground_truth, GROUND_TRUTH_KEYS)
    S_gt = matched_ground_truth(S_gt, points, S_est.shape[1])
    if S_est.shape != S_gt.shape:
        raise UserError(f'shapes differ: estimate {S_est.shape}, ground truth {S_gt.shape}')
    F = S_est.shape[0] // 3
    finite = (np.isfinite(S_est) & np.isfinite(S_gt)).reshape(F, 3, -1).all(axis=1)  # (F, P)
    visible = None if finite.all() else finite
    if visible is not None:
        print(f'{int((~finite).sum())} of {finite.size} entries not finite (tracks left out): '
              'compared on the rest')
    print(f'e3D (per-frame Procrustes, no scale): {e3d(S_est, S_gt, visible=visible):.4f}')
    if args.scale:
        print('e3D (per-frame Procrustes, with scale): '
              f'{e3d(S_est, S_gt, scale=True, visible=visible):.4f}')
    frames = finite.any(axis=1)                 # Akhter's metric needs whole columns: the
    whole = finite[frames].all(axis=0)          # tracks finite in every frame with any
    if whole.sum() < 3:
        print('e3D Akhter: not computed (fewer than 3 tracks finite in every frame)')
        return 0
    rows = np.repeat(frames, 3)
    print(f'e3D Akhter (one rotation, /mean row std): '
          f'{e3d_akhter(S_est[rows][:, whole], S_gt[rows][:, whole]):.4f}')
    return 0
