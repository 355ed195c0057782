"""Record 0802: what the data term does with unseen entries. Side by side, e3D:

* ``free``: the weighted data term, unseen entries left to the low rank (record 0800);
* ``filled``: the unseen entries completed once (:func:`.missing.complete`) and taken as seen
  (the complete path on the completed tracks);
* ``X+N``: ``X`` then N refill rounds (``solver.REFILL_ROUNDS``: unseen entries replaced by
  the solve's reprojection ``R S + t``, solved again as complete tracks from its rotations and
  shapes, ``resumed``); without ``+N`` no round;
* each with the rotations from the complete core (``core``, record 0432), from every track
  completed (``all``: ``stages.rotations.CORE_SHARE`` = inf), the core at another share
  (``coreX``: CORE_SHARE = X) or the true ones (``true``);
* ``wX``: unseen entries weighted X in the data term (0: ``free``, 1: ``filled``).

Cases: the synthetic kinds with 20 % unseen in occlusion blocks (60 x 400, noise r 0.005, as
``bench.missing``), e3D over every entry and the ratio to the complete tracks; the real back
(all 245 tracks, e3D with per-frame scale over the seen entries with a truth, / rigid on the 126
complete ones).

    python -m bench.records.r0802 [--kinds bending,twisting] [--seeds 3,4] [--back]
        [--variants free:core,filled:core,filled:all,filled+1:core]
"""
import argparse
import sys
import time

import numpy as np

from bench.missing import back_data, NOISE
from grass_nrsfm_ros.nrsfm import e3d, GrassmannNRSfM, synthetic, WarmStart
from grass_nrsfm_ros.nrsfm import missing, problem as problem_module, solver
from grass_nrsfm_ros.nrsfm.stages import rotations

VARIANTS = 'free:core,free:all,filled:core,filled:all,filled+1:core,filled+2:core'


def unseen_weights(data):
    """What ``problem.entry_weights`` is replaced by for the data term ``data``: 'free' the
    shipped one, 'filled' none (every entry weighs 1: the complete path), 'wX' X unseen."""
    if data == 'free':
        return missing.entry_weights
    if data == 'filled':
        return lambda mask: None
    return lambda mask: missing.entry_weights(mask) * (1 - float(data[1:])) + float(data[1:])


def solve(W, variant, R_true=None):
    """``(result, seconds)`` of ``W: (2F, P)`` (NaN unseen) under ``variant`` 'data:rot'
    (rot 'true': ``R_true`` given)."""
    data, rot = variant.split(':')
    base, _, rounds = data.partition('+')
    shipped = problem_module.entry_weights, rotations.CORE_SHARE, solver.REFILL_ROUNDS
    problem_module.entry_weights = unseen_weights(base)
    solver.REFILL_ROUNDS = int(rounds or 0)
    rotations.CORE_SHARE = (np.inf if rot == 'all' else float(rot[4:]) if rot[4:]
                            else shipped[1])
    start = time.perf_counter()
    try:
        result = GrassmannNRSfM().fit(W, init=WarmStart(R=R_true) if rot == 'true' else None)
    finally:
        problem_module.entry_weights, rotations.CORE_SHARE, solver.REFILL_ROUNDS = shipped
    return result, time.perf_counter() - start


def occlusion(kind, seed, variants):
    seq = synthetic.make_sequence(kind, n_frames=60, n_points=400, noise=NOISE, seed=seed)
    visible = synthetic.occlusion_mask(seq.W, 0.2, np.random.default_rng(seed + 100))
    W = np.where(np.repeat(visible, 2, axis=0), seq.W, np.nan)
    complete = e3d(GrassmannNRSfM().fit(seq.W).S, seq.S)
    cells = [f'complete {complete:.4f}']
    if any(v.endswith(':true') for v in variants):
        cells.append('complete:true '
                     f'{e3d(GrassmannNRSfM().fit(seq.W, init=WarmStart(R=seq.R)).S, seq.S):.4f}')
    for variant in variants:
        result, seconds = solve(W, variant, seq.R)
        value = e3d(result.S, seq.S)
        cells.append(f'{variant} {value:.4f} ({value / complete:.3f}, {seconds:.0f} s)')
    print(f'{kind} s{seed}: ' + ', '.join(cells), flush=True)


def back(variants):
    W, S, _, truth, core, rigid = back_data()
    cells = [f'rigid(126) {rigid:.4f}']
    for variant in variants:
        result, seconds = solve(W, variant)
        value = e3d(result.S, S, scale=True, visible=truth)
        on_core = e3d(result.S[:, core], S[:, core], scale=True)
        cells.append(f'{variant} {value:.4f} ({value / rigid:.3f}; on 126 {on_core:.4f}; '
                     f'{seconds:.0f} s)')
    print('back: ' + ', '.join(cells), flush=True)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--kinds', default=','.join(synthetic.kinds()))
    parser.add_argument('--seeds', default='3')
    parser.add_argument('--back', action='store_true')
    parser.add_argument('--variants', default=VARIANTS)
    args = parser.parse_args(argv)
    variants = args.variants.split(',')
    if args.back:
        back(variants)
    for kind in filter(None, args.kinds.split(',')):
        for seed in (int(s) for s in args.seeds.split(',')):
            occlusion(kind, seed, variants)
    return 0


if __name__ == '__main__':
    sys.exit(main())
