"""Record 0447: the node's mapping chain offline, the inextensible check's integration handed
to the refinement it decides or not: CPU seconds per window and whether the shapes and
rotations are bitwise the same.

The windows are those the live node solves on the 10,000-track slow face (`bench.live`'s
node run): the first (rigid start), the second ('model' start) and the newest waiting when
each solve ends (windows 12 and 24, resumed).

    python -m bench.records.r0447 [--windows 0,1,12,24] [--points 10000]
"""
import argparse
from dataclasses import replace
import sys

import numpy as np

from bench import common
from bench.live import slow_face
from bench.records.r0433 import windows_of
from grass_nrsfm_ros import mapper, params
from grass_nrsfm_ros.nrsfm.solver import one_blas_thread
from grass_nrsfm_ros.nrsfm.stages import refinement


def chain(windows, chosen):
    """Per chosen window ``(CPU s, S, R)`` of one mapper solving them in order."""
    solver = mapper.make_mapper(params.defaults())
    out = []
    for index in chosen:
        cpu = common.timed(solver.solve, windows[index])[2]
        out.append((cpu, solver.previous.S, solver.previous.R))
    return out


def unshared_check(check):
    """The stage's check without its integration (the refinement sets up and sweeps again)."""
    def wrapped(S, W, values):
        result = check(S, W, values)
        return None if result is None else replace(result, integration=None)
    return wrapped


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--windows', default='0,1,12,24')
    parser.add_argument('--points', type=int, default=10000)
    args = parser.parse_args(argv)
    chosen = [int(w) for w in args.windows.split(',')]
    windows = windows_of(slow_face(args.points, 300)[0])
    shipped = refinement.check
    with one_blas_thread():
        shared = chain(windows, chosen)
        refinement.check = unshared_check(shipped)
        try:
            unshared = chain(windows, chosen)
        finally:
            refinement.check = shipped
    print('| window | CPU s, shared | CPU s, not shared | S, R bitwise the same |')
    print('| --- | --- | --- | --- |')
    for index, (a, b) in zip(chosen, zip(shared, unshared)):
        same = np.array_equal(a[1], b[1]) and np.array_equal(a[2], b[2])
        print(f'| {index} | {a[0]:.2f} | {b[0]:.2f} | {same} |')
    return 0


if __name__ == '__main__':
    sys.exit(main())
