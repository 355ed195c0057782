"""Record 0445: a sequence's first window on fewer tracks (FIRST_WINDOW_TRACKS) and with a
lower penalty cap: the live pipeline offline (every window solved inline as it closes) with
each variant, e3D of ``points`` and ``points/refined`` and the first window's CPU seconds.

    python -m bench.records.r0445 [--variants 1000:10,500:10,1000:1,500:1] [--only NAME,...]
"""
import argparse
import sys

from bench import common, live
from bench.records.r0435 import sequences
from grass_nrsfm_ros import mapper
from grass_nrsfm_ros.nrsfm.metrics import e3d
from grass_nrsfm_ros.params import defaults


def run_variant(W, tracks, beta_max):
    """``(points, refined, first window CPU s)`` with a first window (started from the rigid
    factorisation) on at most ``tracks`` tracks and capped at ``beta_max``."""
    shipped, fit_kwargs = mapper.FIRST_WINDOW_TRACKS, mapper.Mapper._fit_kwargs

    def capped(self, solver, problem, *args):
        kwargs = fit_kwargs(self, solver, problem, *args)
        if self.started_from == 'rigid':
            kwargs['beta_max'] = beta_max
        return kwargs
    mapper.FIRST_WINDOW_TRACKS, mapper.Mapper._fit_kwargs = tracks, capped
    try:
        points, refined, _, cpu = live.run_pipeline(W, defaults()['mapping_tracks'])
    finally:
        mapper.FIRST_WINDOW_TRACKS, mapper.Mapper._fit_kwargs = shipped, fit_kwargs
    return points, refined, cpu[0]


def chosen_sequences(only=''):
    """``[(name, W, S)]``: record 0435's sequences, the other synthetic kinds 60 x 1,000 and
    a second dense face; ``only``: comma-separated names to keep (empty: all)."""
    keep = set(filter(None, only.split(',')))
    more = [(f'{k}60', *common.synthetic(k, 60, 1000))
            for k in ('waving', 'inflating', 'twisting', 'articulated')]
    every = sequences() + more + [('face60s1', *common.dense_face(60, 3000, seed=1))]
    return [s for s in every if not keep or s[0] in keep]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--variants', default='1000:10,500:10,1000:1,500:1')
    parser.add_argument('--only', default='')
    args = parser.parse_args(argv)
    variants = [tuple(float(x) for x in v.split(':')) for v in args.variants.split(',')]
    for name, W, S in chosen_sequences(args.only):
        for tracks, beta in variants:
            points, refined, cpu = run_variant(W, int(tracks), beta)
            print(f'{name} first window {int(tracks)} tracks, beta {beta:g}: points '
                  f'{e3d(live.stacked(points), S):.4f} refined '
                  f'{e3d(live.stacked(refined), S):.4f} first window {cpu:.2f} CPU s',
                  flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
