"""Record 0811: the weighed-down tracks' 3D from their kept neighbours (``robust.refit``).

The drift rows of ``bench.missing`` (60 x 400, noise r 0.005 = 1 px, 5 % of the tracks drifting
up to 20 px), seeds 3, 4, 5: e3D / the clean tracks' default solve for the default, 'cauchy'
without the refit (``before``: the solve's own columns) and with it (``after``, shipped), from
one 'cauchy' solve (the refit comes last); also e3D over the clean tracks only and over the
drifting ones only, and the tracks found / clean ones touched / replaced. ``--clean``: 'cauchy'
on the clean tracks, before / after, over the default.

    python -m bench.records.r0811 [--kinds bending,...] [--seeds 3,4,5] [--clean]
"""
import argparse

import numpy as np

from grass_nrsfm_ros.nrsfm import e3d, GrassmannNRSfM, synthetic
from grass_nrsfm_ros.nrsfm.stages import robust
from . import compare
from ..missing import drift_case

SHIPPED = robust.refit


def cauchy(W):
    """``(result, S before the refit)`` of a 'cauchy' solve of ``W: (2F, P)``."""
    seen = {}

    def spy(S, *args, **kwargs):
        seen['S'] = S
        return SHIPPED(S, *args, **kwargs)

    with compare.patched(robust, 'refit', spy):
        result = GrassmannNRSfM(robust='cauchy').fit(W)
    return result, seen.get('S', result.S)


def row(kind, seed, clean_only):
    seq, W, drifting = drift_case(kind, seed)
    base = GrassmannNRSfM().fit(seq.W).S
    clean = e3d(base, seq.S)
    if clean_only:
        result, before = cauchy(seq.W)
        return (f'{kind} s{seed}: clean tracks, cauchy / default {e3d(before, seq.S) / clean:.4f} '
                f'-> {e3d(result.S, seq.S) / clean:.4f} ({len(result.report.downweighted_tracks)} '
                'weighed down)')
    never = e3d(GrassmannNRSfM().fit(W).S, seq.S) / clean
    result, before = cauchy(W)
    down = np.zeros(W.shape[1], dtype=bool)
    down[result.report.downweighted_tracks] = True
    ok, bad = ~drifting, drifting
    replaced = int((result.S != before).any(axis=0).sum())
    return (f'{kind} s{seed}: default {never:.3f}, cauchy {e3d(before, seq.S) / clean:.3f} -> '
            f'{e3d(result.S, seq.S) / clean:.3f}; clean tracks only '
            f'{e3d(before[:, ok], seq.S[:, ok]) / e3d(base[:, ok], seq.S[:, ok]):.3f} -> '
            f'{e3d(result.S[:, ok], seq.S[:, ok]) / e3d(base[:, ok], seq.S[:, ok]):.3f}; '
            f'drifting tracks {e3d(base[:, bad], seq.S[:, bad]):.4f} (clean solve) / '
            f'{e3d(before[:, bad], seq.S[:, bad]):.4f} -> '
            f'{e3d(result.S[:, bad], seq.S[:, bad]):.4f}; found {(down & bad).sum()}/{bad.sum()}, '
            f'clean touched {(down & ok).sum()}, replaced {replaced}')


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument('--kinds', default=','.join(synthetic.kinds()))
    parser.add_argument('--seeds', default='3,4,5')
    parser.add_argument('--clean', action='store_true')
    args = parser.parse_args()
    for kind in args.kinds.split(','):
        for seed in map(int, args.seeds.split(',')):
            print(row(kind, seed, args.clean), flush=True)


if __name__ == '__main__':
    main()
