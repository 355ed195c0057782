"""``grass-nrsfm evaluate OUT.npz GT.npz``: e3D of a reconstruction against ground truth."""
import numpy as np

from grass_nrsfm_ros.cli import UserError
from grass_nrsfm_ros.nrsfm.metrics import e3d, e3d_akhter


def add_arguments(parser):
    parser.add_argument('estimate', help='.npz with S (3F, P), e.g. from `reconstruct`')
    parser.add_argument('ground_truth', help='.npz with S (3F, P) ground truth')
    parser.add_argument('--scale', action='store_true',
                        help='also fit a per-frame scale in the Procrustes alignment')


def load_shapes(path):
    """``S: (3F, P)`` from an .npz, or UserError."""
    with np.load(path) as npz:
        if 'S' not in npz:
            raise UserError(f'{path} has no array S (has {sorted(npz.files)})')
        return np.asarray(npz['S'], dtype=np.float64)


def run(args):
    S_est, S_gt = load_shapes(args.estimate), load_shapes(args.ground_truth)
    if S_est.shape != S_gt.shape:
        raise UserError(f'shapes differ: estimate {S_est.shape}, ground truth {S_gt.shape}')
    print(f'e3D (per-frame Procrustes, no scale): {e3d(S_est, S_gt):.4f}')
    if args.scale:
        print(f'e3D (per-frame Procrustes, with scale): {e3d(S_est, S_gt, scale=True):.4f}')
    print(f'e3D Akhter (one rotation, /mean row std): {e3d_akhter(S_est, S_gt):.4f}')
    return 0
