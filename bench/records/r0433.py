"""Record 0433: CPU seconds and e3D of a sequence's first window at 10,000 tracks, solved on
N of them (the rest filled in).

    python -m bench.records.r0433 [--caps 5000,2000,1000,500]
"""
import argparse
import sys
import time

import numpy as np

from bench import common
from grass_nrsfm_ros import mapper, params
from grass_nrsfm_ros.nrsfm.metrics import e3d
from grass_nrsfm_ros.nrsfm.solver import one_blas_thread
from grass_nrsfm_ros.windowing import Windowing


def windows_of(W):
    """The windows the default windowing closes on ``W: (2F, P)``, every frame complete."""
    config = params.defaults()
    windowing = Windowing(**{k: config[k] for k in params.WINDOW_KEYS})
    ids = np.arange(W.shape[1], dtype=np.uint32)
    return [w for f in range(W.shape[0] // 2)
            for w in windowing.push(windowing.accept(f, ids, W[2 * f:2 * f + 2].T))]


def first_window(W, cap):
    """``(CPU s, e3D-ready S)`` of the first window of ``W: (2F, P)`` solved on ``cap``."""
    first = windows_of(W)[0]
    solver = mapper.make_mapper({**params.defaults(), 'mapping_tracks': cap})
    start = time.process_time()
    solver.solve(first)
    return time.process_time() - start, solver.previous.S


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--caps', default='5000,2000,1000,500')
    args = parser.parse_args(argv)
    W, S = common.dense_face(30, 10000)
    shipped = mapper.FIRST_WINDOW_TRACKS
    mapper.FIRST_WINDOW_TRACKS = 10 ** 9              # the cap under test is mapping_tracks
    with one_blas_thread():
        for cap in (int(c) for c in args.caps.split(',')):
            cpu, S_est = first_window(W, cap)
            print(f'{cap} tracks: {cpu:.2f} CPU s, e3D {e3d(S_est, S):.4f}')
    mapper.FIRST_WINDOW_TRACKS = shipped
    return 0


if __name__ == '__main__':
    sys.exit(main())
