"""Record 0817: the stage 'relief' under robust weights, on the drift rows.

    python -m bench.records.r0817 [--seeds 3,4,5,6,7] [--kinds bending,...]

``bench.missing``'s drift case (60 x 400, 1 px noise, 5 % of the tracks drifting up to 20 px):
e3D over the clean tracks' default solve, for the drifting tracks' default solve (the stage
measured on the tracks the robust weights kept) and with ``relief='never'`` (what the stage did
where weights applied before this record), with the factors of the clean and drifting solves.
"""
import sys

import numpy as np

from grass_nrsfm_ros.nrsfm import e3d, GrassmannNRSfM
from .r0816 import BAR, drift_rows
from ..missing import drift_case


def row(kind, seed):
    seq, W, _ = drift_case(kind, seed)
    clean = GrassmannNRSfM().fit(seq.W)
    reference = e3d(clean.S, seq.S)
    now, held_off = GrassmannNRSfM().fit(W), GrassmannNRSfM(relief='never').fit(W)
    ratios = {'now': e3d(now.S, seq.S) / reference,
              'held_off': e3d(held_off.S, seq.S) / reference}
    weighed = len(now.report.downweighted_tracks or [])
    print(f"{kind} s{seed}: {ratios['now']:.3f} (factor {now.report.relief:.3f}, "
          f"{weighed} tracks weighed down), held off {ratios['held_off']:.3f}; clean factor "
          f'{clean.report.relief:.3f}', flush=True)
    return ratios


def main(argv=None):
    rows = drift_rows(row, argv, '3,4,5,6,7', __doc__.split('\n')[0])
    for mode in ('now', 'held_off'):
        ratios = np.array([r[mode] for r in rows])
        print(f'{mode}: {int((ratios <= BAR).sum())} of {len(rows)} within {BAR}, '
              f'{int((ratios <= 1.05).sum())} within 1.05, mean {ratios.mean():.3f}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
