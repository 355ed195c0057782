"""Records 0805, 0806: where drifting tracks cost, and what keeps them from pulling the shapes.

The drift rows of ``bench.missing`` (60 x 400, noise r 0.005 = 1 px, 5 % of the tracks drifting
up to 20 px), several seeds, each variant's e3D over every entry / the clean tracks' default
solve; also e3D over the clean tracks only and over the drifting ones only, Dai's K, and the
drifting tracks found / clean ones touched. A variant is a weighting of the data term and a
choice of the tracks Dai's rotations read (``rotations.core_tracks``):

weights: ``none`` (robust 'never'), ``cauchy`` (the stage of record 0801 as it is),
``trim`` (its detection, the found tracks weighed 1e-3), ``entry`` (its detection, then in the
found tracks the entries off the low-rank fit made unseen and completed: the drift is late),
``impute`` (as ``entry``, the entries then taken as seen with their completed values),
``oracle``/``oimpute`` (the drifting tracks' entries more than 1 px off made unseen / imputed:
what a perfect detector would give).
rotations: ``all`` (every track, shipped before 0805), ``kept`` (the tracks no weight touched,
shipped: ``robust.kept_tracks``),
``oracle`` (the clean tracks), ``q75``/``q50`` (the share of the tracks with the lowest residual
to the detector's fit).

    python -m bench.records.r0805 [--kinds twisting,...] [--seeds 3,4,5] [--variants a/b,...]
    python -m bench.records.r0805 --detect        # detectors: drifting vs clean scores
    python -m bench.records.r0805 --clean         # 'cauchy' on clean tracks and the back
"""
import argparse
from dataclasses import replace
import sys
import time

import numpy as np

from grass_nrsfm_ros.nrsfm import e3d, GrassmannNRSfM, synthetic
from grass_nrsfm_ros.nrsfm.measurement import economy_svd
from grass_nrsfm_ros.nrsfm.missing import complete
from grass_nrsfm_ros.nrsfm.stages import robust, rotations
from . import compare
from ..missing import drift_case

SHIPPED_CORE = rotations.core_tracks
SHIPPED_ROBUST = robust.run
DEFAULT_VARIANTS = ('none/all', 'none/oracle', 'oracle/oracle', 'cauchy/all', 'cauchy/kept',
                    'trim/kept', 'entry/kept', 'cauchy/q75', 'none/q75')


# ------------------------------------------------------------------------------- rotations

def core_all(problem):
    """The rule before record 0805: every track, or the tracks seen in every frame while they
    are CORE_SHARE of all (robust weights not read)."""
    mask = problem.mask
    if mask is None:
        return slice(None)
    core = np.flatnonzero(mask.all(axis=0))
    return core if core.size >= max(rotations.CORE_MIN, rotations.CORE_SHARE * mask.shape[1]) \
        else slice(None)


def core_quantile(share):
    """The ``share`` of the tracks with the lowest residual to the IRLS rank-DETECT_RANK fit
    (robust.track_weights' last round)."""
    def core(problem):
        seen = np.ones_like(problem.Wn) if problem.weights is None else problem.weights > 0
        weights = np.ones(problem.P)
        for _ in range(robust.ROUNDS):
            r = robust.residuals(problem.Wn, weights, seen)
            weights = robust.cauchy_weights(r)
        return np.flatnonzero(r <= np.quantile(r, share))
    return core


def core_oracle(drifting):
    return lambda problem: np.flatnonzero(~drifting)


# ------------------------------------------------------------------------------- weights

def unseen_problem(problem, unseen):
    """``problem`` with the entries ``unseen: (F, P)`` made unseen and completed again."""
    mask = (problem.mask if problem.mask is not None else
            np.ones((problem.F, problem.P), bool)) & ~unseen
    W, completion = complete(problem.W, mask)
    weights = np.repeat(mask, 2, axis=0).astype(float)
    translation = W.mean(axis=1, keepdims=True)
    Wn = (W - translation) / problem.scale
    return replace(problem, W=W, Wn=Wn, translation=translation, weights=weights,
                   completion=completion, mask=mask)


def entry_outliers(problem, tracks):
    """``(F, P)`` bool: in ``tracks: (P,)`` bool, the entries whose 2D residual to the
    rank-DETECT_RANK fit of the other tracks is above median + 3 robust deviations of the
    clean tracks' entries."""
    F, P = problem.F, problem.P
    seen = np.ones_like(problem.Wn) if problem.weights is None else problem.weights > 0
    rank = min(robust.DETECT_RANK, min(problem.Wn.shape) - 1)
    U = economy_svd(problem.Wn * (~tracks)[None, :])[0][:, :rank]
    resid = problem.Wn - U @ (U.T @ problem.Wn)
    r = np.sqrt((np.where(seen, resid, 0.0) ** 2).reshape(F, 2, P).sum(axis=1))
    ref = r[:, ~tracks]
    med = np.median(ref)
    threshold = med + robust.THRESHOLD * 1.4826 * np.median(np.abs(ref - med))
    return (r > threshold) & tracks[None, :]


def imputed_problem(problem, unseen):
    """``problem`` with the entries ``unseen: (F, P)`` replaced by their completion from the
    others and then taken as seen (weights as before)."""
    filled = unseen_problem(problem, unseen)
    return replace(filled, weights=problem.weights, completion=problem.completion,
                   mask=problem.mask)


def robust_variant(mode, drifting):
    def run(problem, params, report):
        if mode in ('oracle', 'oimpute'):
            unseen = np.zeros((problem.F, problem.P), bool)
            off = np.abs(problem.W - ORACLE_TRUTH[0]).reshape(problem.F, 2, problem.P).max(1)
            unseen[:, drifting] = off[:, drifting] > ORACLE_TRUTH[1]
            report.downweighted_tracks = np.flatnonzero(drifting).tolist()
            make = unseen_problem if mode == 'oracle' else imputed_problem
            return make(problem, unseen), np.where(drifting, 0.0, 1.0)
        weights = robust.track_weights(problem)
        down = weights < 1
        report.downweighted_tracks = np.flatnonzero(down).tolist()
        if mode == 'cauchy' or not down.any():
            return (problem.weighted(weights) if down.any() else problem), weights
        if mode == 'trim':
            weights = np.where(down, 1e-3, 1.0)
            return problem.weighted(weights), weights
        unseen = entry_outliers(problem, down)
        make = unseen_problem if mode == 'entry' else imputed_problem
        return make(problem, unseen), weights
    return run


ORACLE_TRUTH = [None, None]     # (clean W, 1 px) for the oracle weights


def solve(W, variant, drifting):
    mode, core = variant.split('/')
    cores = {'all': core_all, 'kept': SHIPPED_CORE,
             'oracle': core_oracle(drifting), 'q75': core_quantile(0.75),
             'q50': core_quantile(0.5)}
    params = {} if mode == 'none' else {'robust': 'cauchy'}
    with compare.patched(rotations, 'core_tracks', cores[core]), \
            compare.patched(robust, 'run', robust_variant(mode, drifting)):
        return GrassmannNRSfM(**params).fit(W)


def row(kind, seed, variants):
    seq, W, drifting = drift_case(kind, seed)
    ORACLE_TRUTH[:] = [seq.W, synthetic.image_pixel(seq.W)]
    clean = GrassmannNRSfM().fit(seq.W)
    base = e3d(clean.S, seq.S)
    cells = [f'{kind} s{seed}: clean {base:.4f} K{clean.report.K_rot}'
             f'{"+reg" if clean.report.rotations_registered else ""} (drift tr '
             f'{e3d(clean.S[:, drifting], seq.S[:, drifting]):.3f})']
    for variant in variants:
        t = time.perf_counter()
        res = solve(W, variant, drifting)
        down = np.zeros(W.shape[1], bool)
        down[res.report.downweighted_tracks] = True
        ratio = e3d(res.S, seq.S) / base
        on_clean = e3d(res.S[:, ~drifting], seq.S[:, ~drifting]) / \
            e3d(clean.S[:, ~drifting], seq.S[:, ~drifting])
        on_drift = e3d(res.S[:, drifting], seq.S[:, drifting])
        cells.append(f'{variant} {ratio:.3f} (clean tr {on_clean:.3f}, drift tr {on_drift:.3f},'
                     f' K{res.report.K_rot} {res.report.rotation_method}'
                     f'{"+reg" if res.report.rotations_registered else ""}, '
                     f'found {(down & drifting).sum()}/{drifting.sum()} '
                     f'+{(down & ~drifting).sum()}, {time.perf_counter() - t:.0f}s)')
    print('\n    '.join(cells), flush=True)


def entry_residuals(Wn, weights, rank):
    """``(F, P)`` 2D residuals of ``Wn: (2F, P)`` to its rank-``rank`` fit, columns weighted."""
    U = economy_svd(Wn * np.sqrt(weights)[None, :])[0][:, :rank]
    resid = Wn - U @ (U.T @ Wn)
    return np.sqrt((resid ** 2).reshape(Wn.shape[0] // 2, 2, -1).sum(axis=1))


def robust_z(r):
    med = np.median(r)
    return (r - med) / max(1.4826 * np.median(np.abs(r - med)), 1e-12)


def scores(Wn, rank, statistic, weights=None, rounds=robust.ROUNDS, tail='cauchy'):
    """``(z: (P,), weights: (P,))``: IRLS at ``rank`` on a track ``statistic`` ('rms' over
    frames, or 'max' over frames of the per-frame robust z of the entry residuals)."""
    weights = np.ones(Wn.shape[1]) if weights is None else weights
    for _ in range(rounds):
        e = entry_residuals(Wn, weights, rank)
        if statistic == 'rms':
            z = robust_z(np.sqrt((e ** 2).mean(axis=0)))
        else:
            med = np.median(e, axis=1, keepdims=True)
            mad = 1.4826 * np.median(np.abs(e - med), axis=1, keepdims=True)
            z = robust_z(((e - med) / np.maximum(mad, 1e-12)).max(axis=0))
        over = z > robust.THRESHOLD
        weights = np.where(over, (robust.THRESHOLD / np.maximum(z, 1e-12)) ** 2, 1.0) \
            if tail == 'cauchy' else np.where(over, 0.0, 1.0)
    return z, weights


def detect(kinds, seeds):
    """The drifting tracks' scores against a rank-r fit: weakest drifting track and the
    strongest clean one, in robust deviations above the median, and the count found."""
    setups = [('rms', (6,), 'cauchy'), ('max', (6,), 'cauchy'), ('rms', (6, 9), 'trim'),
              ('max', (6, 9), 'trim'), ('max', (3, 6, 9), 'trim'), ('max', (9,), 'trim'),
              ('rms', (3, 6, 9), 'trim')]
    for kind in kinds:
        for seed in seeds:
            seq, W, drifting = drift_case(kind, seed)
            Wn = W - W.mean(axis=1, keepdims=True)
            Wn /= np.sqrt(np.mean(Wn ** 2))
            cells = []
            for statistic, ranks, tail in setups:
                weights = None
                for rank in ranks:
                    z, weights = scores(Wn, rank, statistic, weights, tail=tail)
                found = weights < 1
                cells.append(f'{statistic}{"-".join(map(str, ranks))}{tail[0]} '
                             f'{z[drifting].min():.1f}/{z[~drifting].max():.1f} '
                             f'{found[drifting].sum()}+{found[~drifting].sum()}')
            print(f'{kind} s{seed}: ' + '; '.join(cells), flush=True)


def clean_rows(kinds, seeds):
    """Robust 'cauchy' (shipped, rotations from the kept tracks) on clean tracks and on the
    real back: e3D / the default's, tracks touched."""
    from bench import common
    from bench.missing import BACK_MIN_DEPTH
    for kind in kinds:
        for seed in seeds:
            seq = drift_case(kind, seed)[0]
            plain = e3d(GrassmannNRSfM().fit(seq.W).S, seq.S)
            res = GrassmannNRSfM(robust='cauchy').fit(seq.W)
            print(f'clean {kind} s{seed}: {plain:.4f}, cauchy {e3d(res.S, seq.S) / plain:.3f} '
                  f'({len(res.report.downweighted_tracks)} touched)', flush=True)
    for camera in ('orbit', 'shaky'):                   # test_accuracy's synthetic cases
        for kind in kinds:
            seq = synthetic.make_sequence(kind, 60, 500, camera=camera, seed=0)
            plain = e3d(GrassmannNRSfM().fit(seq.W).S, seq.S)
            res = GrassmannNRSfM(robust='cauchy').fit(seq.W)
            with compare.patched(rotations, 'core_tracks', core_all):
                old = e3d(GrassmannNRSfM(robust='cauchy').fit(seq.W).S, seq.S)
            print(f'accuracy {kind} {camera}: {plain:.4f}, cauchy {e3d(res.S, seq.S):.4f} '
                  f'(rotations on all {old:.4f}; {len(res.report.downweighted_tracks)} touched)',
                  flush=True)
    root = common.data_root()
    if root is None or not (root / 'russell_back' / 'back.npz').is_file():
        return
    with np.load(root / 'russell_back' / 'back.npz') as z:
        W, S, visible = z['W'].astype(float), z['S'].astype(float), z['visible']
    F, P = visible.shape
    truth = visible & np.isfinite(S).reshape(F, 3, P).all(axis=1) & \
        (S.reshape(F, 3, P)[:, 2] > BACK_MIN_DEPTH)
    cells = []
    for robust_mode in ('never', 'cauchy'):
        res = GrassmannNRSfM(robust=robust_mode).fit(W)
        cells.append(f'{robust_mode} {e3d(res.S, S, scale=True, visible=truth):.4f} '
                     f'({len(res.report.downweighted_tracks)} touched)')
    print('back: ' + ', '.join(cells), flush=True)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--kinds', default=','.join(synthetic.kinds()))
    parser.add_argument('--seeds', default='3,4,5')
    parser.add_argument('--variants', default=','.join(DEFAULT_VARIANTS))
    parser.add_argument('--detect', action='store_true')
    parser.add_argument('--clean', action='store_true')
    args = parser.parse_args(argv)
    kinds, seeds = args.kinds.split(','), [int(s) for s in args.seeds.split(',')]
    if args.detect:
        detect(kinds, seeds)
        return 0
    if args.clean:
        clean_rows(kinds, seeds)
        return 0
    for kind in kinds:
        for seed in seeds:
            row(kind, seed, args.variants.split(','))
    return 0


if __name__ == '__main__':
    sys.exit(main())
