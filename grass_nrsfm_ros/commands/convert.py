"""``grass-nrsfm convert IN.npz OUT_BAG``: W (2F, P) as a tracks bag, for replay and the node.

Frame f becomes one PointCloud2 on ``--topic`` (track_id = column of W, u, v in pixels) with
header stamp and receive time ``start + f / rate``. Points marked False in an optional
``visible: (F, P)`` are left out of their frame. Ground truth ``S: (3F, P)``, when the .npz has
it (``S`` or ``S_gt``), goes to ``--gt-topic`` (default /ground_truth) in the ``points``
layout (x, y, z, track_id), stamped like the frame's tracks, so ``render`` and evaluation can
find it beside a reconstruction.
"""
import numpy as np

from grass_nrsfm_ros import bag
from grass_nrsfm_ros.cli import UserError
from grass_nrsfm_ros.commands.npz import load_tracks


def add_arguments(parser):
    parser.add_argument('input', help='.npz with W (2F, P) and optionally S (3F, P), visible')
    parser.add_argument('output', help='bag directory to create (rosbag2, MCAP storage)')
    parser.add_argument('--rate', type=float, default=30.0, help='frames per second (30)')
    parser.add_argument('--start', type=float, default=0.0,
                        help='stamp of frame 0 in seconds since the epoch (0)')
    parser.add_argument('--frame-id', default='camera_optical',
                        help='header.frame_id (camera_optical)')
    parser.add_argument('--topic', default='/tracks', help='tracks topic (/tracks)')
    parser.add_argument('--gt-topic', default='/ground_truth',
                        help='ground-truth topic when the .npz has S (/ground_truth)')
    parser.add_argument('--no-gt', action='store_true', help='leave ground truth out')


def run(args):
    if args.rate <= 0:
        raise UserError(f'--rate must be positive; got {args.rate}')
    W, S, visible = load_tracks(args.input)
    F = W.shape[0] // 2
    stamps = np.round((args.start + np.arange(F) / args.rate) * 1e9).astype(np.int64)
    counts = bag.tracks_bag_from_arrays(
        W, stamps, args.output, args.frame_id, topic=args.topic,
        S=None if args.no_gt else S, gt_topic=args.gt_topic, visible=visible)
    print(f'{args.output}: ' + ', '.join(f'{n} messages on {t}' for t, n in counts.items())
          + f' ({F} frames at {args.rate:g} Hz)')
    return 0
