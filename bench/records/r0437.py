"""Record 0437 (archived): live windows lifted by the previous window's depths, one round of
the projective-depth iteration per window. The live pipeline offline with K on the rendered
face, as shipped and with each window's normalised tracks multiplied by ``1 + s z``, ``z`` the
previous solution's relative depth of the frame (the newest shared frame's for new frames),
``s`` its low-rank sign.

    python -m bench.records.r0437 [--frames 100] [--points 600]
"""
import argparse
from dataclasses import replace
import sys

import numpy as np

from bench import perspective
from grass_nrsfm_ros import mapper, pipeline
from grass_nrsfm_ros.frontend.scenes import pinhole
from grass_nrsfm_ros.nrsfm import camera
from grass_nrsfm_ros.nrsfm.measurement import as_frames
from grass_nrsfm_ros.nrsfm.perspective import low_rank_sign
from grass_nrsfm_ros.params import defaults

SHIPPED = mapper.Mapper._problem


def lifted(signs):
    """A ``Mapper._problem`` that lifts each window by the previous solution's depths."""
    def problem(self, window):
        p, prev = SHIPPED(self, window), self.previous
        if prev is None or prev.sequence != p.sequence:
            return p
        Z = as_frames(prev.S, 3)[:, 2, :]
        Z = Z - Z.mean(axis=1, keepdims=True)
        if p.sequence not in signs:
            x = prev.uv.transpose(0, 2, 1).reshape(-1, prev.uv.shape[1])
            signs[p.sequence] = low_rank_sign(x, Z)
        column = np.minimum(np.searchsorted(prev.ids, p.ids), prev.ids.size - 1)
        shared = prev.ids[column] == p.ids
        row = {int(t): i for i, t in enumerate(prev.stamps)}
        delta = np.zeros((len(p.stamps), p.ids.size))
        for i, t in enumerate(p.stamps):
            delta[i, shared] = Z[row.get(int(t), -1), column[shared]]
        scale = np.repeat(np.maximum(1 + signs[p.sequence] * delta, 0.1), 2, axis=0)
        return replace(p, W=p.W * scale, filled=p.filled * scale)
    return problem


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--frames', type=int, default=100)
    parser.add_argument('--points', type=int, default=600)
    args = parser.parse_args(argv)
    S = perspective.face_shapes(args.frames, args.points)
    if S is None:
        print('no face model (../shared): nothing measured')
        return 0
    K = pinhole()
    W = camera.project(S, K)
    ids = np.arange(args.points, dtype=np.uint32)
    frames = [(ids, uv.T) for uv in as_frames(W, 2)]
    for name, problem in (('shipped', SHIPPED), ('lifted', lifted({}))):
        mapper.Mapper._problem = problem
        try:
            pipe = pipeline.make_pipeline(defaults(), camera=K)
            points, refined, _ = pipeline.reconstruct_live(pipe, np.arange(args.frames), frames)
        finally:
            mapper.Mapper._problem = SHIPPED
        stacked = [np.vstack([r.xyz.T for r in rs]) for rs in (points, refined)]
        print(f'{name}: points {perspective.e3d(stacked[0], S):.4f}, refined '
              f'{perspective.e3d(stacked[1], S):.4f}', flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
