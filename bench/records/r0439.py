"""Record 0439: the fill of the tracks a window does not solve, its neighbours and weights
found in the FILL_DIMS leading directions of the kept trajectories, against the whole
trajectories (FILL_DIMS None): the live pipeline offline (every window solved inline as it
closes) on the dense faces, e3D of ``points`` and ``points/refined`` and the mapping CPU
seconds per window after the first.

    python -m bench.records.r0439
"""
import sys

import numpy as np

from bench import common, live
from grass_nrsfm_ros.nrsfm import density
from grass_nrsfm_ros.nrsfm.metrics import e3d
from grass_nrsfm_ros.params import defaults


def sequences():
    """Dense faces 60 and 99 x 3,000, the slow face's first 120 frames at 10,000 and 30,000
    tracks."""
    out = [(f'face{F}x3000', *common.dense_face(F, 3000)) for F in (60, 99)]
    for P in (10_000, 30_000):
        slow = live.slow_face(P)
        if slow is not None:
            out.append((f'slow_face120x{P}', slow[0][:240], slow[1][:360]))
    return out


def main():
    shipped = density.FILL_DIMS
    for dims in (None, shipped):
        density.FILL_DIMS = dims
        for name, W, S in sequences():
            points, refined, _, cpu = live.run_pipeline(W, defaults()['mapping_tracks'])
            common.log(f'FILL_DIMS {dims} {name:>20} points {e3d(live.stacked(points), S):.4f} '
                       f'refined {e3d(live.stacked(refined), S):.4f} '
                       f'CPU s / window {np.mean(cpu[1:]):.2f}')
    density.FILL_DIMS = shipped
    return 0


if __name__ == '__main__':
    sys.exit(main())
