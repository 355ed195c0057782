"""Record 0012, later: Dai's rank search stopped where the higher ranks cannot change the
choice, against the full search (every rank, then :func:`choose_rank`): the same K, rule and
R, and the CPU seconds of each, on the synthetic kinds and the dense face.

    python -m bench.records.r0012 [--frames 60] [--points 400]
"""
import argparse
import sys

import numpy as np

from bench import common
from grass_nrsfm_ros.nrsfm.rotation import (choose_rank, DEFAULT_CANDIDATES,
                                            estimate_rotations, max_rank)
from grass_nrsfm_ros.nrsfm.solver import one_blas_thread


def every_rank(W):
    """The search over every candidate rank W can carry (what 'auto' searched before)."""
    F, P = W.shape[0] // 2, W.shape[1]
    return estimate_rotations(W, K=min(max(DEFAULT_CANDIDATES), max_rank(F, P)))


def full_choice(W, every):
    """``(K, rule, R)`` that :func:`choose_rank` takes from the search over every rank."""
    residuals = {k: v['residual'] for k, v in every.scores.items()
                 if isinstance(k, int) and 'residual' in v}
    K, rule = choose_rank(residuals, W.shape[0] // 2)
    return K, rule, estimate_rotations(W, K=K).R


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--frames', type=int, default=60)
    parser.add_argument('--points', type=int, default=400)
    args = parser.parse_args(argv)
    sequences = [(kind, common.synthetic(kind, args.frames, args.points)[0])
                 for kind in ('bending', 'waving', 'inflating', 'twisting', 'articulated')]
    sequences.append(('dense face', common.dense_face(args.frames, 1000)[0]))
    with one_blas_thread():
        for name, W in sequences:
            stopped, _, stopped_s = common.timed(estimate_rotations, W)
            every, _, full_s = common.timed(every_rank, W)
            K, rule, R = full_choice(W, every)
            searched = sorted(k for k in stopped.scores if isinstance(k, int))
            same = (stopped.K, stopped.scores['rule']) == (K, rule) and \
                np.array_equal(stopped.R, R)
            print(f'{name}: K {stopped.K}, ranks searched {searched}, identical {same}; '
                  f'CPU s stopped {stopped_s:.2f}, every rank {full_s:.2f}', flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
