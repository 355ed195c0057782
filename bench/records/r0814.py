"""Record 0814: the rank-6 residual's weight only where the neighbours' residual corroborates
it, and a residual floor of 1e-2 (``robust='cauchy'``): before (record 0812) -> now.

    python -m bench.records.r0814 [--seeds 3,4,5,6,7] [--kinds bending,...] [--clean]

Default: ``bench.missing``'s drift rows (60 x 400, 1 px noise, 5 % of the tracks drifting up
to 20 px, the drift's generator seeded seed + 200), e3D over the clean tracks' default solve
(drifting tracks found / clean tracks weighed down). ``--clean``: what 'cauchy' does where
nothing drifts, e3D over the default solve (tracks weighed down): the mocap sequences, the
dense face 99 x 2,000 seed 0, the five kinds (orbit, seed 2, 60 x 500, noise-free) and the
drift rows' sequences without their drift.
"""
import argparse
import sys

import numpy as np

from grass_nrsfm_ros.nrsfm import e3d, GrassmannNRSfM, synthetic
from grass_nrsfm_ros.nrsfm.stages import robust
from . import compare
from ..missing import drift_case

KINDS = 'bending,waving,inflating,twisting,articulated'
MOCAP = ('drink', 'pickup', 'yoga', 'dance', 'face', 'shark')


def at_old_floor(weights_of):
    """``weights_of(problem)`` under record 0812's RESIDUAL_FLOOR (1e-3)."""
    def weights(problem):
        with compare.patched(robust, 'RESIDUAL_FLOOR', 1e-3):
            return weights_of(problem)
    return weights


#: record 0812's weights: the smaller of both residuals' everywhere, floor 1e-3
before = at_old_floor(lambda problem: np.minimum(robust.low_rank_weights(problem),
                                                 robust.neighbour_weights(problem)[0]))


def cauchy(W, weights_of):
    """A 'cauchy' solve of ``W`` whose stage weighs the tracks with ``weights_of``: ``(S,
    down: (P,) bool)``."""
    with compare.patched(robust, 'track_weights', weights_of):
        result = GrassmannNRSfM(robust='cauchy').fit(W)
    down = np.zeros(W.shape[1], dtype=bool)
    down[result.report.downweighted_tracks] = True
    return result.S, down


def row(name, W, S, reference, drifting=None):
    """A table row: ``name``, then per weighting e3D / ``reference`` (found / clean touched, or
    touched)."""
    cells = []
    for fn in (before, robust.track_weights):
        shapes, down = cauchy(W, fn)
        counts = f'{int(down.sum())}' if drifting is None else \
            f'{int((down & drifting).sum())} / {int((down & ~drifting).sum())}'
        cells.append(f'{e3d(shapes, S) / reference:.3f} ({counts})')
    print(f'| {name} | ' + ' | '.join(cells) + ' |', flush=True)


def parse(argv, doc):
    """The drift records' arguments (0812, 0814): ``--seeds``, ``--kinds``, ``--clean``."""
    parser = argparse.ArgumentParser(description=doc.split('\n')[0])
    parser.add_argument('--seeds', default='3,4,5,6,7')
    parser.add_argument('--kinds', default=KINDS)
    parser.add_argument('--clean', action='store_true')
    return parser.parse_args(argv)


def main(argv=None):
    args = parse(argv, __doc__)
    seeds = [int(s) for s in args.seeds.split(',')]
    print('| case | before (record 0812) | now |')
    print('| --- | --- | --- |')
    if args.clean:
        cases = (compare.mocap_cases(MOCAP) + compare.face_cases((0,))
                 + compare.synthetic_cases(synthetic.kinds(), seeds=(2,)))
        for kind in args.kinds.split(','):
            for seed in seeds:
                seq = drift_case(kind, seed)[0]
                cases.append((f'{kind} {seed} clean', seq.W, seq.S))
        for name, W, S in cases:
            row(name, W, S, e3d(GrassmannNRSfM().fit(W).S, S))
        return 0
    for kind in args.kinds.split(','):
        for seed in seeds:
            seq, W, drifting = drift_case(kind, seed)
            row(f'{kind} {seed}', W, seq.S, e3d(GrassmannNRSfM().fit(seq.W).S, seq.S), drifting)
    return 0


if __name__ == '__main__':
    sys.exit(main())
