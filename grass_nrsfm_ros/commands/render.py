"""``grass-nrsfm render BAG_OR_NPZ --frame N -o out.png [--every K]``: pictures of frames.

Sources: an .npz whose ``S: (3F, P)`` is the reconstruction and ``S_gt`` (if present) the
ground truth; or a bag whose ``/points`` clouds are the reconstruction (one per stamp, the
latest wins) and ``/ground_truth`` (written by ``convert``) the truth, matched by stamp and
track id. ``--gt`` takes the truth from another .npz (its ``S``) or bag instead. A source with
only ground truth draws that alone. With ground truth, each estimate is aligned to it per frame
(Procrustes with scale, reflection allowed: NRSfM recovers shape up to these) and the title
gives the frame's e3D. Needs matplotlib (``pip install 'grass_nrsfm_ros[plot]'``).
"""
from pathlib import Path

import numpy as np

from grass_nrsfm_ros import bag
from grass_nrsfm_ros.cli import UserError
from grass_nrsfm_ros.commands.npz import opened
from grass_nrsfm_ros.nrsfm.metrics import e3d, procrustes_align

PLOT_HINT = "pictures need matplotlib: pip install 'grass_nrsfm_ros[plot]'"


def renderer():
    """:mod:`grass_nrsfm_ros.render`, or a UserError saying in one line how to get matplotlib."""
    try:
        from grass_nrsfm_ros import render
    except ModuleNotFoundError as exc:
        if (exc.name or '').split('.')[0] != 'matplotlib':
            raise
        raise UserError(PLOT_HINT) from None
    return render


def add_arguments(parser):
    parser.add_argument('source', help='.npz (S, optional S_gt) or bag (/points, /ground_truth)')
    parser.add_argument('-o', '--output', required=True, help='PNG to write')
    parser.add_argument('--frame', type=int, default=0, help='frame index (0)')
    parser.add_argument('--every', type=int, default=0,
                        help='contact sheet of every K-th frame instead of one frame')
    parser.add_argument('--gt', help='ground truth from this .npz (S) or bag (--gt-topic)')
    parser.add_argument('--points-topic', default='/points', help='reconstruction topic')
    parser.add_argument('--gt-topic', default='/ground_truth', help='ground-truth topic')
    parser.add_argument('--size', type=int, default=240, help='pixels per view (240)')
    parser.add_argument('--columns', type=int, default=4, help='contact sheet columns (4)')
    parser.add_argument('--units', default='', help="axis units, e.g. 'm' (none)")


def frames_from_npz(path, key):
    """``[(frame index, ids, xyz: (3, P))]`` from ``S: (3F, P)`` under ``key``, or None."""
    with opened(path) as npz:
        if key not in npz:
            return None
        S = np.asarray(npz[key], np.float64)
    if S.ndim != 2 or S.shape[0] % 3:
        raise UserError(f'{path}: {key} must be (3F, P); got {S.shape}')
    ids = np.arange(S.shape[1])
    return [(f, ids, S[3 * f:3 * f + 3]) for f in range(S.shape[0] // 3)]


def frames_from_bag(path, topic):
    """``[(stamp_ns, ids, xyz: (3, P))]`` in stamp order (latest cloud per stamp), or None."""
    try:
        by_stamp = {f.stamp_ns: (f.ids, f.xyz.T) for f in bag.read_points(path, topic)}
    except bag.TopicNotFoundError:
        return None
    return [(s, *by_stamp[s]) for s in sorted(by_stamp)]


def load(path, est_key='S', gt_key='S_gt', points_topic='/points', gt_topic='/ground_truth'):
    """``(estimate frames or None, truth frames or None)`` from an .npz or a bag."""
    if Path(path).suffix == '.npz':
        return frames_from_npz(path, est_key), frames_from_npz(path, gt_key)
    return frames_from_bag(path, points_topic), frames_from_bag(path, gt_topic)


def aligned_pair(est, truth):
    """Estimate aligned to truth on their common ids: ``(est (3, P), truth (3, P), e3D)``."""
    common, ie, it = np.intersect1d(est[1], truth[1], return_indices=True)
    X, Y = est[2][:, ie], truth[2][:, it]
    ok = np.isfinite(X).all(axis=0) & np.isfinite(Y).all(axis=0)
    if ok.sum() < 3:
        return est[2], truth[2], None
    X, Y = X[:, ok], Y[:, ok]
    aligned, _ = procrustes_align(X, Y, scale=True, centre=True)
    return aligned + Y.mean(axis=1, keepdims=True), Y, e3d(X, Y, scale=True)


def figure(k, est_frames, gt_frames, size, views=('front', 'side', 'top'), units=''):
    """The figure of the k-th frame (estimate order, or truth order when there is none)."""
    frame_figure = renderer().frame_figure
    main = est_frames if est_frames is not None else gt_frames
    key, _, _ = main[k]
    est = est_frames[k] if est_frames is not None else None
    truth = None
    if gt_frames is not None:
        if est_frames is None:
            truth = gt_frames[k]
        else:
            truth = next((g for g in gt_frames if g[0] == key), None)
    title = f'frame {k}'
    if est is not None and truth is not None:
        e, t, err = aligned_pair(est, truth)
        if err is not None:
            title += f'  e3D {err:.3f}'
        return frame_figure(e, t, title, size, views, units)
    return frame_figure(est[2] if est is not None else None,
                        truth[2] if truth is not None else None, title, size, views, units)


def run(args):
    render = renderer()
    est, truth = load(args.source, points_topic=args.points_topic, gt_topic=args.gt_topic)
    if args.gt:
        truth = (frames_from_npz(args.gt, 'S') if Path(args.gt).suffix == '.npz'
                 else frames_from_bag(args.gt, args.gt_topic))
        if truth is None:
            raise UserError(f'{args.gt} holds no ground truth')
    if est is None and truth is None:
        raise UserError(f'{args.source} holds no reconstruction (S / {args.points_topic}) and '
                        f'no ground truth (S_gt / {args.gt_topic})')
    n = len(est if est is not None else truth)
    if args.every > 0:
        frames = list(range(0, n, args.every))
        images = [figure(k, est, truth, args.size // 2, ('front', 'side'), args.units)
                  for k in frames]
        render.write_png(args.output, render.contact_sheet(images, args.columns))
        print(f'{args.output}: {len(frames)} frames (every {args.every} of {n})')
        return 0
    if not 0 <= args.frame < n:
        raise UserError(f'--frame {args.frame} outside 0..{n - 1}')
    render.write_png(args.output, figure(args.frame, est, truth, args.size, units=args.units))
    print(f'{args.output}: frame {args.frame} of {n}')
    return 0
