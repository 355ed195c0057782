"""Record 0438: resumed windows hold the inextensible depths once a solve of the sequence used
them ('always', no check), against checking again in every window: the live pipeline offline
(every window solved inline as it closes), e3D of ``points`` and ``points/refined`` and the
mapping CPU seconds per window after the first.

    python -m bench.records.r0438
"""
import sys

import numpy as np

from bench import common, live
from grass_nrsfm_ros import mapper
from grass_nrsfm_ros.nrsfm.metrics import e3d
from grass_nrsfm_ros.params import defaults


def sequences():
    """The dense faces (60 x 3000, the slow face's first 120 frames at 10,000 tracks) and
    four synthetic kinds (60 x 1000)."""
    out = [('face60x3000', *common.dense_face(60, 3000))]
    slow = live.slow_face(10_000)
    if slow is not None:
        out.append(('slow_face120x10000', slow[0][:240], slow[1][:360]))
    return out + [(f'{k}60', *common.synthetic(k, 60, 1000))
                  for k in ('bending', 'waving', 'articulated', 'twisting')]


def run(held):
    """Rows of every sequence with the decision held (the shipped mapper) or checked again."""
    shipped = mapper.Mapper._holding_inextensible
    if not held:
        mapper.Mapper._holding_inextensible = lambda self, solver, *_: solver
    try:
        rows = []
        for name, W, S in sequences():
            points, refined, _, cpu = live.run_pipeline(W, defaults()['mapping_tracks'])
            rows.append((name, e3d(live.stacked(points), S), e3d(live.stacked(refined), S),
                         float(np.mean(cpu[1:]))))
        return rows
    finally:
        mapper.Mapper._holding_inextensible = shipped


def main():
    for held in (True, False):
        for name, points, refined, cpu in run(held):
            common.log(f"{'held' if held else 'checked':>8} {name:>20} points {points:.4f} "
                       f'refined {refined:.4f} CPU s / window {cpu:.2f}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
