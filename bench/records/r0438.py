"""Record 0438 (rejected): resumed windows holding the inextensible depths once a solve of the
sequence used them ('always', no check), against the shipped check in every window: the live
pipeline offline (every window solved inline as it closes), e3D of ``points`` and
``points/refined`` and the mapping CPU seconds per window after the first.

    python -m bench.records.r0438
"""
import sys

import numpy as np

from bench import common, live
from grass_nrsfm_ros import mapper
from grass_nrsfm_ros.nrsfm.metrics import e3d
from grass_nrsfm_ros.params import defaults


def sequences():
    """The dense faces (60 and 99 x 3000, the slow face's first 120 frames at 10,000 tracks)
    and four synthetic kinds (60 x 1000)."""
    out = [(f'face{F}x3000', *common.dense_face(F, 3000)) for F in (60, 99)]
    slow = live.slow_face(10_000)
    if slow is not None:
        out.append(('slow_face120x10000', slow[0][:240], slow[1][:360]))
    return out + [(f'{k}60', *common.synthetic(k, 60, 1000))
                  for k in ('bending', 'waving', 'articulated', 'twisting')]


def holding():
    """Patch the Mapper: once a solve used the inextensible depths, its later resumed windows
    run 'always'. Returns the undo."""
    init, solve = mapper.Mapper.__init__, mapper.Mapper._solve

    def patched_init(self, solver_factory=None, **kwargs):
        init(self, solver_factory, **kwargs)
        factory, self._used = self.solver_factory, False

        def make():
            solver = factory()
            if self._used and self.started_from == 'resumed':
                solver.set_params(inextensible='always')
            return solver
        self.solver_factory = make

    def patched_solve(self, window, progress):
        out = solve(self, window, progress)
        self._used = self._used or bool(getattr(self.previous.report, 'inextensible', False))
        return out
    mapper.Mapper.__init__, mapper.Mapper._solve = patched_init, patched_solve

    def undo():
        mapper.Mapper.__init__, mapper.Mapper._solve = init, solve
    return undo


def run(held):
    """Rows ``(name, points e3D, refined e3D, CPU s per window)`` of every sequence."""
    undo = holding() if held else (lambda: None)
    try:
        rows = []
        for name, W, S in sequences():
            points, refined, _, cpu = live.run_pipeline(W, defaults()['mapping_tracks'])
            rows.append((name, e3d(live.stacked(points), S), e3d(live.stacked(refined), S),
                         float(np.mean(cpu[1:]))))
        return rows
    finally:
        undo()


def main():
    for held in (False, True):
        for name, points, refined, cpu in run(held):
            common.log(f"{'held' if held else 'checked':>8} {name:>20} points {points:.4f} "
                       f'refined {refined:.4f} CPU s / window {cpu:.2f}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
