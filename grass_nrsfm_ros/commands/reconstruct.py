"""``grass-nrsfm reconstruct IN -o OUT [--config FILE]``.

``IN.npz`` holds ``W: (2F, P)`` (and optionally ground truth ``S: (3F, P)``, then e3D is
printed); ``OUT.npz`` gets ``S``, ``R``, ``translation``, ``groups`` and the solver report (JSON
string ``report``). The solver needs complete tracks: an input whose ``visible: (F, P)`` marks
entries as unobserved is refused, unless ``--complete-tracks`` keeps the tracks seen in every
frame (their columns are saved as ``points``, which ``evaluate`` uses). A bag directory or
``.mcap``/``.bag`` file runs the node's sliding-window pipeline offline and writes an output
bag (there, each window uses the tracks it sees throughout).
"""
import json
from pathlib import Path
import sys
import time

import numpy as np

from grass_nrsfm_ros.cli import UserError
from grass_nrsfm_ros.commands.npz import complete_tracks, load_tracks


def add_arguments(parser):
    parser.add_argument('input', help='.npz with W (2F, P), or a tracks bag')
    parser.add_argument('-o', '--output', required=True, help='output .npz (or bag directory)')
    parser.add_argument('--config', help="params.yaml (the node's file works too)")
    parser.add_argument('--topic', default='/tracks', help='tracks topic when IN is a bag')
    parser.add_argument('--quiet', action='store_true', help='no progress display')
    parser.add_argument('--complete-tracks', action='store_true',
                        help='when visible marks missing entries, reconstruct only the tracks '
                             'seen in every frame (saved as `points` in OUT)')


def solver_from_config(path):
    """A GrassmannNRSfM built from the solver entries of a params file (or defaults)."""
    from grass_nrsfm_ros.nrsfm import GrassmannNRSfM
    from grass_nrsfm_ros.params import load_config, solver_kwargs

    config = load_config(path) if path else {}
    return GrassmannNRSfM(**solver_kwargs(config)), config


class Progress:
    """One overwritten status line on stderr while the solver iterates."""

    def __init__(self, enabled):
        self.enabled = enabled and sys.stderr.isatty()
        self.start = time.monotonic()

    def __call__(self, iteration, report):
        if not self.enabled:
            return
        gap = max(report.gaps[-1]) if report.gaps else float('nan')
        sys.stderr.write(f'\r  iteration {iteration:4d}  gap {gap:9.3e}  '
                         f'{time.monotonic() - self.start:6.1f} s')
        sys.stderr.flush()

    def close(self):
        if self.enabled:
            sys.stderr.write('\n')


def observed_tracks(path, complete_only):
    """``(W: (2F, P'), S_gt: (3F, P') or None, points: (P',) or None)`` from an .npz: all
    tracks, or with ``complete_only`` those seen in every frame (``points``: their columns)
    where ``visible`` marks missing entries (refused otherwise)."""
    from grass_nrsfm_ros.nrsfm.measurement import validate_shapes

    W, S_gt, visible = load_tracks(path)
    F, P = W.shape[0] // 2, W.shape[1]
    if S_gt is not None:                 # checked before a long solve, not after it
        S_gt = validate_shapes(S_gt, n_frames=F, n_points=P, name=f'{path}: ground truth S')
    if visible is None:
        return W, S_gt, None
    points = complete_tracks(visible, F, P, path)
    if points.size == P:
        return W, S_gt, None
    if not complete_only:
        raise UserError(
            f'{path}: visible marks {int((~visible).sum())} of {visible.size} entries as '
            f'unobserved ({P - points.size} of {P} tracks incomplete); the solver needs '
            f'complete tracks: --complete-tracks reconstructs the {points.size} tracks seen '
            'in every frame')
    print(f'{path}: keeping the {points.size} of {P} tracks seen in every frame')
    return W[:, points], None if S_gt is None else S_gt[:, points], points


def check_writable(path):
    """UserError unless ``path``'s folder exists and may be written to."""
    import os

    folder = Path(path).resolve().parent
    if not folder.is_dir() or not os.access(folder, os.W_OK):
        raise UserError(f'cannot write {path}: folder {folder} does not exist or is not '
                        'writable')


def reconstruct_npz(args):
    from grass_nrsfm_ros.nrsfm import e3d

    W, S_gt, points = observed_tracks(args.input, args.complete_tracks)
    solver, _ = solver_from_config(args.config)
    check_writable(args.output)                          # before a long solve, not after it
    progress = Progress(not args.quiet)
    try:
        result = solver.fit(W, progress=progress)
    finally:
        progress.close()
    report = result.report
    extra = {} if points is None else {'points': points}
    np.savez_compressed(args.output, S=result.S, R=result.R, translation=result.translation,
                        groups=result.groups, report=json.dumps(report.to_dict()), **extra)
    F, P = W.shape[0] // 2, W.shape[1]
    print(f'{args.input}: F={F} P={P} K_rot={report.K_rot} iterations={report.iterations} '
          f'seconds={report.seconds["total"]:.1f} -> {args.output}')
    if S_gt is not None:
        print(f'e3D (per-frame Procrustes, no scale): {e3d(result.S, S_gt):.4f}')
    return 0


def reconstruct_bag_file(args):
    """The node's sliding-window pipeline over a tracks bag, offline, into an output bag; a
    refused input (corrupt or truncated bag, missing topic) leaves no output behind."""
    import shutil

    from grass_nrsfm_ros import bag
    from grass_nrsfm_ros.params import load_config
    from grass_nrsfm_ros.live import make_pipeline

    config = load_config(args.config) if args.config else {}
    known = bag.topics(args.input)                      # corrupt bags fail here, before output
    if args.topic not in known:
        raise bag.TopicNotFoundError(f'bag {args.input} has no topic {args.topic!r} (topics: '
                                     f'{", ".join(sorted(known)) or "none"})')
    pipeline = make_pipeline(config)
    out = Path(args.output)
    existed = out.exists()
    try:
        report = bag.reconstruct_bag(args.input, out, pipeline, topic=args.topic,
                                     progress=None if args.quiet else bag.text_progress())
    except BaseException:
        if not existed and out.exists():
            shutil.rmtree(out)                          # no half-written output bag
        raise
    print(f'{args.input}: {report.frames_in} frames in, {report.frames_out} reconstructed in '
          f'{report.windows} windows, {report.seconds:.1f} s -> {args.output}')
    for line in report.refused:
        print(f'refused: {line}', file=sys.stderr)
    return 0


def run(args):
    if Path(args.input).suffix == '.npz':
        return reconstruct_npz(args)
    return reconstruct_bag_file(args)
