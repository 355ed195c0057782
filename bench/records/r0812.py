"""Record 0812: drifting tracks found by their neighbours' residual as well as by the rank-6
residual (``robust='cauchy'``): e3D over the clean tracks' default solve, drifting tracks
found / clean tracks weighed down, with the rank-6 residual alone (record 0801) and with both
(both under this record's residual floor, 1e-3; record 0814 changed both).

    python -m bench.records.r0812 [--seeds 3,4,5,6,7] [--kinds bending,...] [--clean]

``bench.missing``'s drift rows (60 x 400, 1 px noise, 5 % of the tracks drifting up to
20 px, the drift's generator seeded seed + 200); ``--clean``: the clean tracks instead (what
'cauchy' does where nothing drifts).
"""
import sys

import numpy as np

from grass_nrsfm_ros.nrsfm import e3d, GrassmannNRSfM
from grass_nrsfm_ros.nrsfm.stages import robust
from . import r0814
from ..missing import drift_case


def cauchy_figures(W, S, drifting, clean, weights_of):
    """``(e3D / clean, found, clean tracks touched)`` of a 'cauchy' solve of ``W`` whose stage
    weighs the tracks with ``weights_of``."""
    shapes, down = r0814.cauchy(W, weights_of)
    return e3d(shapes, S) / clean, int((down & drifting).sum()), int((down & ~drifting).sum())


def main(argv=None):
    args = r0814.parse(argv, __doc__)
    print('| kind | seed | rank 6 alone: ratio (found / clean touched) | both |')
    print('| --- | --- | --- | --- |')
    for kind in args.kinds.split(','):
        for seed in (int(s) for s in args.seeds.split(',')):
            seq, W, drifting = drift_case(kind, seed)
            if args.clean:
                W, drifting = seq.W, np.zeros(seq.W.shape[1], dtype=bool)
            clean = e3d(GrassmannNRSfM().fit(seq.W).S, seq.S)
            cells = [cauchy_figures(W, seq.S, drifting, clean, fn)
                     for fn in (r0814.at_old_floor(robust.low_rank_weights), r0814.before)]
            print(f'| {kind} | {seed} | ' + ' | '.join(f'{r:.3f} ({f} / {c})' for r, f, c in cells)
                  + ' |', flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
