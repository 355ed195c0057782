"""Record 0448: an earlier first model from fewer tracks, and what a skipped window does to the
live model.

* ``--variants``: the live pipeline offline (record 0445's sequences) with the first window on
  N tracks, its spatial groups carried to the next window or not (``N:carry`` / ``N:own``):
  e3D of ``points`` and ``points/refined``, the first window's CPU seconds;
* ``--orders``: windows of the 10k slow face solved in the given orders, as the node's mapping
  does when it skips windows (``0,1,2`` offline; ``0,2``: the first model late, window 1
  replaced): each solve's start, e3D on its frames and the rank of the tracking model it gives;
  then frames 50-150 and 150-300 tracked with the last model, its modes cut to ``--modes``;
* ``--energies``: the offline live bench's sequences (``bench.streaming.accuracy_sequences``,
  full, without the 99-frame face) with the tracking model's modes kept up to each energy
  share: e3D of ``points``.

    python -m bench.records.r0448 [--variants 1000:carry,500:carry,500:own]
        [--orders 0,1/0,2/0,3] [--modes 40,10,5,3] [--energies 0.9999,0.99] [--only NAME,...]
"""
import argparse
from dataclasses import replace
import sys

import numpy as np

from bench import common, live
from bench.records import r0445
from bench.records.r0433 import windows_of
from bench.streaming import accuracy_sequences
from grass_nrsfm_ros import mapper, params
from grass_nrsfm_ros.nrsfm.metrics import e3d
from grass_nrsfm_ros.nrsfm.solver import one_blas_thread
from grass_nrsfm_ros.nrsfm.tracking import build_model, Tracker


def own_groups(start_for):
    """``Mapper._start_for`` that carries no spatial groups from a rigid-started solve."""
    def wrapped(self, problem):
        rigid_before = self.started_from == 'rigid'          # the previous solve's start
        init = start_for(self, problem)
        if self.started_from == 'model' and rigid_before:
            init = replace(init, groups=None)
        return init
    return wrapped


def variants(spec, only):
    shipped = mapper.Mapper._start_for
    for name, W, S in r0445.chosen_sequences(only):
        for tracks, groups in (v.split(':') for v in spec.split(',')):
            mapper.Mapper._start_for = own_groups(shipped) if groups == 'own' else shipped
            try:
                points, refined, cpu = r0445.run_variant(W, int(tracks), 1.0)
            finally:
                mapper.Mapper._start_for = shipped
            print(f'{name} first window {tracks} tracks, groups {groups}: points '
                  f'{e3d(live.stacked(points), S):.4f} refined '
                  f'{e3d(live.stacked(refined), S):.4f} first window {cpu:.2f} CPU s',
                  flush=True)


def tracked(model, W, S, frames):
    """e3D of ``frames`` (a range) of ``W`` tracked from ``model`` on (every track)."""
    tracker, ids = Tracker(model), np.arange(W.shape[1], dtype=np.uint32)
    xyz = [tracker.track(f, ids, W[2 * f:2 * f + 2].T).xyz.T for f in frames]
    return e3d(np.vstack(xyz), S[3 * frames.start:3 * frames.stop])


def orders(spec, modes):
    W, S = live.slow_face(10000, 300)
    windows = windows_of(W)
    for order in spec.split('/'):
        solver = mapper.make_mapper(params.defaults())
        with one_blas_thread():
            for i in (int(x) for x in order.split(',')):
                update = solver.solve(windows[i])
                p = solver.previous
                rows = (3 * p.stamps[:, None] + np.arange(3)).ravel()
                print(f'order {order}: window {i} ({len(p.stamps)} frames) from '
                      f'{solver.started_from}: e3D {e3d(p.S, S[rows][:, p.ids]):.4f}, '
                      f'model rank {update.model.rank}', flush=True)
        for cap in modes:
            model = build_model(p.S, p.R, p.ids, p.stamps, max_modes=cap)
            print(f'order {order}: at most {cap} modes (rank {model.rank}): frames 50-150 '
                  f'{tracked(model, W, S, range(50, 150)):.4f}, 150-300 '
                  f'{tracked(model, W, S, range(150, 300)):.4f}', flush=True)


def energies(spec, only):
    keep = set(filter(None, only.split(',')))
    shipped = build_model.__kwdefaults__['energy']
    for name, W, S in accuracy_sequences(common.Mode('full')):
        if name == 'face99x3000' or (keep and name not in keep):
            continue
        for energy in (float(e) for e in spec.split(',')):
            build_model.__kwdefaults__['energy'] = energy
            try:
                points = live.run_pipeline(W, params.defaults()['mapping_tracks'])[0]
            finally:
                build_model.__kwdefaults__['energy'] = shipped
            print(f'{name} modes to energy {energy}: points {e3d(live.stacked(points), S):.4f}',
                  flush=True)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--variants', default='1000:carry,500:carry,500:own')
    parser.add_argument('--orders', default='0,1/0,2/0,3')
    parser.add_argument('--modes', default='40,10,5,3')
    parser.add_argument('--energies', default='0.9999,0.99')
    parser.add_argument('--only', default='')
    args = parser.parse_args(argv)
    if args.variants:
        variants(args.variants, args.only)
    if args.orders:
        orders(args.orders, [int(m) for m in args.modes.split(',') if m])
    if args.energies:
        energies(args.energies, args.only)
    return 0


if __name__ == '__main__':
    sys.exit(main())
