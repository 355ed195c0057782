"""Record 0816: ``robust`` 'auto' (the default) against 'never' and 'cauchy' on the drift rows.

    python -m bench.records.r0816 [--seeds 4,5,6,7] [--kinds bending,...]

``bench.missing``'s drift case (60 x 400, 1 px noise, 5 % of the tracks drifting up to 20 px,
the drift's generator seeded seed + 200): e3D over the clean tracks' default solve for each
mode; whether 'auto' applied its weights (and on how many tracks), and whether it did on the
clean tracks.
"""
import argparse
import sys

from grass_nrsfm_ros.nrsfm import e3d, GrassmannNRSfM
from ..missing import drift_case

KINDS = 'bending,waving,inflating,twisting,articulated'
BAR = 1.2


def row(kind, seed):
    seq, W, _ = drift_case(kind, seed)
    clean = GrassmannNRSfM().fit(seq.W)
    reference = e3d(clean.S, seq.S)
    results = {mode: GrassmannNRSfM(robust=mode).fit(W) for mode in ('auto', 'never', 'cauchy')}
    ratios = {mode: e3d(r.S, seq.S) / reference for mode, r in results.items()}
    auto = results['auto']
    weights = (f'applied, {len(auto.report.downweighted_tracks)} tracks'
               if auto.track_weights is not None else 'not applied')
    on_clean = 'applied' if clean.track_weights is not None else 'not applied'
    print(f"{kind} s{seed}: auto {ratios['auto']:.3f} (weights {weights}; on the clean tracks "
          f"{on_clean}), never {ratios['never']:.3f}, cauchy {ratios['cauchy']:.3f}", flush=True)
    return ratios


def drift_rows(row, argv, seeds, description):
    """``[row(kind, seed), ...]`` over the ``--seeds`` (default ``seeds``) and ``--kinds`` of
    ``argv``, seed by seed."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument('--seeds', default=seeds)
    parser.add_argument('--kinds', default=KINDS)
    args = parser.parse_args(argv)
    return [row(kind, int(seed)) for seed in args.seeds.split(',')
            for kind in args.kinds.split(',')]


def main(argv=None):
    rows = drift_rows(row, argv, '4,5,6,7', __doc__.split('\n')[0])
    for mode in ('auto', 'never', 'cauchy'):
        print(f'{mode}: {sum(r[mode] <= BAR for r in rows)} of {len(rows)} within {BAR}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
