"""Record 0446 (rejected): a faster penalty growth (rho) in a sequence's first window, the one
started from the rigid factorisation: the live pipeline offline (every window solved inline as
it closes), e3D of ``points`` and ``points/refined`` and the first window's CPU seconds.

    python -m bench.records.r0446 [--rhos 1.2,1.5,2.0] [--only NAME,...]
"""
import argparse
import sys

from bench import live
from bench.records.r0445 import chosen_sequences
from grass_nrsfm_ros import mapper
from grass_nrsfm_ros.nrsfm.metrics import e3d
from grass_nrsfm_ros.nrsfm.schema import solver_defaults
from grass_nrsfm_ros.params import defaults


def run_variant(W, rho):
    """``(points, refined, first window CPU s)`` with the first window's rho set to ``rho``
    (the later windows keep the solver's)."""
    fit_kwargs = mapper.Mapper._fit_kwargs
    shipped = solver_defaults()['rho']

    def grown(self, solver, problem, *args):
        solver.set_params(rho=rho if self.started_from == 'rigid' else shipped)
        return fit_kwargs(self, solver, problem, *args)
    mapper.Mapper._fit_kwargs = grown
    try:
        points, refined, _, cpu = live.run_pipeline(W, defaults()['mapping_tracks'])
    finally:
        mapper.Mapper._fit_kwargs = fit_kwargs
    return points, refined, cpu[0]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--rhos', default='1.2,1.5,2.0')
    parser.add_argument('--only', default='')
    args = parser.parse_args(argv)
    for name, W, S in chosen_sequences(args.only):
        for rho in (float(r) for r in args.rhos.split(',')):
            points, refined, cpu = run_variant(W, rho)
            print(f'{name} first window rho {rho:g}: points {e3d(live.stacked(points), S):.4f} '
                  f'refined {e3d(live.stacked(refined), S):.4f} first window {cpu:.2f} CPU s',
                  flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
