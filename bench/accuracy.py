"""Accuracy: e3D of ours (GrassmannNRSfM defaults) vs rigid, BMM and PTA on every sequence with
ground truth: the data folder's mocap and perspective sets, the synthetic kinds and the dense
Surrey faces; published numbers beside ours where the data is the same (:mod:`.published`).

PTA's number of DCT vectors K is swept and the best value against ground truth is reported (an
upper bound on PTA, labelled ``K_oracle``), with rigid-factorisation rotations ('pta') and with
the same Dai rotations BMM gets ('pta_dai').
"""
import numpy as np

from grass_nrsfm_ros.nrsfm.metrics import e3d, e3d_akhter
from grass_nrsfm_ros.nrsfm.synthetic import kinds
from . import common
from .published import published_for

PTA_K_MAX = 15


def cases(mode):
    """Yield ``(name, family, W, S)``; missing data is skipped with a log line."""
    if mode.name == 'smoke':
        yield ('synthetic_bending', 'synthetic', *common.synthetic('bending', 10, 100))
        return
    names = mode.pick(None, ('face', 'shark', 'kinect_paper10', 'tshirt10'),
                      tuple(common.DATASETS))
    for name in names:
        loaded = common.load_dataset(name)
        if loaded is None:
            common.log(f'accuracy: {name}: data not found, skipped')
            continue
        W, S, family = loaded
        yield name, family, W, S
    F, P = mode.pick(None, (30, 500), (60, 3000))
    for kind in kinds():
        yield (f'synthetic_{kind}', 'synthetic', *common.synthetic(kind, F, P))
    # 40 % of the tracks in two patches of 1 % of the surface each (the solver thins them)
    yield ('synthetic_inflating_clustered', 'synthetic',
           *common.synthetic('inflating', F, P, clustered=0.4))
    F, P = mode.pick(None, (30, 2000), (99, 28880))
    face = common.dense_face(F, P)
    if face is None:
        common.log('accuracy: Surrey face model not found, dense face skipped')
    else:
        yield f'dense_face_{F}x{P}', 'dense_face', *face


def errors(S_est, S, family):
    # perspective subsets: tracks in normalised image coordinates, ground truth in mm, so the
    # per-frame Procrustes also fits a scale there
    out = {'e3d': e3d(S_est, S, scale=family == 'perspective')}
    if family == 'mocap':
        out['e3d_akhter'] = e3d_akhter(S_est, S)
    return out


def pta_oracle(W, S, family, R=None):
    """PTA over K = 1..min(15, 2F/3); the best by e3D (Akhter's metric on mocap)."""
    F = W.shape[0] // 2
    key = 'e3d_akhter' if family == 'mocap' else 'e3d'
    best, sweep = None, {}
    for K in range(1, min(PTA_K_MAX, 2 * F // 3) + 1):
        out, wall, cpu = common.timed(common.solve, 'pta', W, R=R, K_traj=K)
        err = errors(out['S'], S, family)
        sweep[K] = err[key]
        if best is None or err[key] < best[0][key]:
            best = (err, wall, cpu, K)
    err, wall, cpu, K = best
    return {**err, 'seconds_wall': wall, 'seconds_cpu': cpu, 'K_oracle': K, 'K_sweep': sweep}


def run_case(name, family, W, S):
    rows, skipped = [], []
    F, P = W.shape[0] // 2, W.shape[1]
    base = {'sequence': name, 'family': family, 'F': F, 'P': P}
    published = published_for(name)
    R_dai, wall, cpu = common.timed(common.dai_rotations, W)
    base_rot = {'rotation_seconds_wall': wall, 'rotation_seconds_cpu': cpu}
    for method in ('ours', 'rigid', 'bmm', 'pta', 'pta_dai'):
        common.log(f'accuracy: {name} ({F} x {P}) {method}')
        try:
            if method == 'pta':
                row = pta_oracle(W, S, family)
            elif method == 'pta_dai':
                row = {**pta_oracle(W, S, family, R=R_dai), **base_rot}
            else:
                out, wall, cpu = common.timed(common.solve, method, W, R=R_dai)
                row = {**errors(out['S'], S, family), 'seconds_wall': wall, 'seconds_cpu': cpu,
                       'report': common.report_summary(out['report'])}
                if method == 'bmm':
                    row.update(base_rot)
        except Exception as exc:      # a failing method is a result, not a crash of the suite
            skipped.append({'sequence': name, 'method': method,
                            'why': f'{type(exc).__name__}: {exc}'})
            continue
        pub = published.get(method.replace('_dai', ''))
        if pub:
            row['published'] = {'value': pub[0], 'metric': pub[1], 'source': pub[2]}
        rows.append({**base, 'method': method, **row})
    return rows, skipped


def run(mode):
    rows, skipped = [], []
    for name, family, W, S in cases(mode):
        r, s = run_case(name, family, np.asarray(W, float), np.asarray(S, float))
        rows += r
        skipped += s
    return {'rows': rows, 'skipped': skipped,
            'notes': ['e3d: per-frame Procrustes (metrics.e3d); e3d_akhter: compareStructs of '
                      'Akhter et al. (mocap only, the metric of the published mocap table)',
                      'pta/pta_dai: K chosen against ground truth (K_oracle), an upper bound',
                      'perspective family: orthographic methods on perspective data (context); '
                      'e3d with a per-frame scale (tracks normalised, ground truth in mm)']}
