"""Record 0731: the maximum depth with known lengths, the LP against the relaxation.

    python -m bench.records.r0731

The bench's pinhole sheets (bending, flag, waving; seeds 0, 1; 40 x 300): the lengths from
the LP on 10 of the frames (spread), then the other 30 frames' anchor depths from the LP with
those lengths (record 0724) and from :func:`~grass_nrsfm_ros.nrsfm.max_depth.largest_depths`,
e3D (per-frame scale) of the 100 anchors on those frames, as they come and refined to their
lengths (record 0720); CPU seconds.
"""
import time

import numpy as np

from grass_nrsfm_ros.nrsfm import e3d, max_depth as md
from grass_nrsfm_ros.nrsfm.measurement import frame_rows, spread_frames
from ..perspective import pinhole_sheet


def lp_with_lengths(W, edges, d):
    """``(F, n)`` depths of ``W: (2F, n)`` by record 0724's LP with the lengths ``d`` fixed:
    the LP's lengths pinned by their bounds, its sum constraint dropped."""
    q = md._rays(W)
    FP = q.shape[0] * q.shape[1]
    bounds = np.c_[np.r_[np.zeros(FP), d], np.r_[np.full(FP, np.inf), d]]
    return md.cutting_planes(q, *edges, bounds, None, None)[0]


def main():
    print('sheet | LP: e3D, refined (CPU s) | relaxation: e3D, refined (CPU ms)')
    for kind in ('bending', 'flag', 'waving'):
        for seed in (0, 1):
            W, S = pinhole_sheet(kind, 40, 300, seed=seed)
            anchors = md.anchor_tracks(W, md.MAX_TRACKS)
            sub = W[:, anchors]
            edges = md.neighbour_edges(sub, md.NEIGHBOURS)
            keys = spread_frames(40, 10)
            d = md.max_depth(sub[frame_rows(keys, 2)], edges)[1]
            other_frames = np.setdiff1d(np.arange(40), keys)
            others = frame_rows(other_frames, 2)
            truth = S[frame_rows(other_frames, 3)][:, anchors]
            row = []
            for solve in (lambda: lp_with_lengths(sub[others], edges, d),
                          lambda: md.largest_depths(sub[others], edges, d)):
                t0 = time.process_time()
                Z = solve()
                seconds = time.process_time() - t0
                refined = md.refined_depths(sub[others], Z, d, edges)
                row.append((e3d(md.shapes(sub[others], Z), truth, scale=True),
                            e3d(md.shapes(sub[others], refined), truth, scale=True), seconds))
            (a, b, s), (c, e, t) = row
            print(f'{kind} s{seed} | {a:.4f}, {b:.4f} ({s:.1f} s) | {c:.4f}, {e:.4f} '
                  f'({1000 * t:.0f} ms)')


if __name__ == '__main__':
    main()
