"""``grass-nrsfm evaluate OUT.npz GT.npz``: e3D of a reconstruction against ground truth.

When OUT reconstructs only some of the input's tracks (``points``, written by ``reconstruct
--complete-tracks``), the ground truth's matching columns are compared.
"""
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
    print(f'e3D (per-frame Procrustes, no scale): {e3d(S_est, S_gt):.4f}')
    if args.scale:
        print(f'e3D (per-frame Procrustes, with scale): {e3d(S_est, S_gt, scale=True):.4f}')
    print(f'e3D Akhter (one rotation, /mean row std): {e3d_akhter(S_est, S_gt):.4f}')
    return 0
