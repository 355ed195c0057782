"""Record 0609: the front end's pixel error against its neighbours' (is drift spatially
coherent?), and the tracks corrected by their frame-0 neighbours.

    python -m bench.records.r0609 [--faces 0,2]

The shipped tracker on ``bench.frontend``'s rendered faces (100 frames, step 4). Per frame
(10, 30, 60, 90): the error ``e: (2,)`` px of each tracked, visible track against the truth,
and the median of its k nearest tracks' errors (k = 4, 8, 24, in the true image): a track
whose error is its own (incoherent) has a small neighbours' median. Then the frame-0 tracks
corrected: in every frame, each one's position predicted by a robust affine map (3 IRLS
rounds) from its k nearest frame-0 tracks' positions in frame 0 to theirs now, itself left out;
where it lies more than tau px from the prediction, the prediction replaces it. Error median
and p95 over every tracked, visible entry, as ``bench.frontend`` scores them.
"""
import argparse

import numpy as np
from scipy.spatial import cKDTree

from grass_nrsfm_ros.frontend import scenes
from .. import frontend


def tracked_face(seed):
    """``(uv, true_uv: (F, P, 2), visible: (F, P), birth: (P,))`` of the shipped tracker."""
    uv, true_uv, _, visible, birth = frontend.track_scene(scenes.face_scene(100, seed=seed))
    return uv, true_uv, visible, birth


def coherence(uv, true_uv, visible, frame, k):
    """``(own, neighbours)``: p95 of the tracks' error norms in ``frame`` and of the median of
    their k nearest tracks' errors."""
    ok = np.isfinite(uv[frame, :, 0]) & visible[frame]
    error, where = (uv[frame] - true_uv[frame])[ok], true_uv[frame][ok]
    nearest = cKDTree(where).query(where, k + 1)[1][:, 1:]
    median = np.median(error[nearest], axis=1)
    return (np.percentile(np.linalg.norm(error, axis=1), 95),
            np.percentile(np.linalg.norm(median, axis=1), 95))


def predicted(start, now, k, rounds=3, scale_px=1.0):
    """``(P, 2)``: each point's position ``now`` by the robust affine map of its k nearest
    points (itself left out) from ``start (P, 2)`` to ``now (P, 2)``."""
    nearest = cKDTree(start).query(start, k + 1)[1][:, 1:]
    offsets = start[nearest] - start[:, None]                                 # (P, k, 2)
    A = np.concatenate([np.ones(offsets.shape[:2] + (1,)), offsets], axis=2)  # (P, k, 3)
    weights = np.ones(offsets.shape[:2])
    for _ in range(rounds):
        Aw = A * weights[..., None]
        coef = np.linalg.solve(Aw.transpose(0, 2, 1) @ A + 1e-6 * np.eye(3),
                               Aw.transpose(0, 2, 1) @ now[nearest])         # (P, 3, 2)
        residual = np.linalg.norm(A @ coef - now[nearest], axis=2)
        weights = 1.0 / (1.0 + (residual / scale_px) ** 2)
    return coef[:, 0]


def corrected(uv, birth, k, tau):
    """``uv`` with the frame-0 tracks more than ``tau`` px from :func:`predicted` moved onto
    it, frame by frame."""
    out = uv.copy()
    first = np.flatnonzero(birth == 0)
    for f in range(1, uv.shape[0]):
        alive = first[np.isfinite(uv[f, first, 0])]
        guess = predicted(uv[0, alive], uv[f, alive], k)
        far = np.linalg.norm(uv[f, alive] - guess, axis=1) > tau
        out[f, alive[far]] = guess[far]
    return out


def scored(uv, true_uv, visible):
    error = np.linalg.norm(uv - true_uv, axis=2)[np.isfinite(uv[..., 0]) & visible]
    return np.median(error), np.percentile(error, 95)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--faces', default='0,2')
    args = parser.parse_args(argv)
    for seed in (int(s) for s in args.faces.split(',')):
        uv, true_uv, visible, birth = tracked_face(seed)
        median, p95 = scored(uv, true_uv, visible)
        print(f'face {seed}: shipped error median {median:.3f} p95 {p95:.2f} px', flush=True)
        for frame in (10, 30, 60, 90):
            figures = [coherence(uv, true_uv, visible, frame, k) for k in (4, 8, 24)]
            print(f"  frame {frame}: p95 own {figures[0][0]:.2f}; neighbours' median, k 4 / 8 "
                  '/ 24: ' + ' / '.join(f'{n:.2f}' for _, n in figures))
        for k in (8, 12, 24):
            row = []
            for tau in (1.5, 2.5, 4.0):
                median, p95 = scored(corrected(uv, birth, k, tau), true_uv, visible)
                row.append(f'tau {tau:g}: {median:.3f} / {p95:.2f}')
            print(f'  corrected, k {k}: ' + ', '.join(row), flush=True)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
