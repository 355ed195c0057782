"""Rotations (issue 23): Dai's rotations against Organic Priors' ('op', bench/op_rotations.py),
each with the solver's nuclear norm, on the mocap sets and the synthetic kinds.

Per sequence and rotation method: the rotations' seconds, OP's diagnostics (the share of
candidate samples its filter keeps), the rotation error against the truth where there is one
(synthetic: degrees after one global alignment) and the angle between the two methods' rotations;
Akhter e3D (mocap) or e3D (synthetic) of the whole-sequence fit, with the published R-BMM and
OP numbers beside the mocap rows. OP's weighted partial norm (the 'weighted' rows of record
archive/0501) left the solver with record 0430; its figures stay in that record.
"""
import numpy as np

from grass_nrsfm_ros.nrsfm import GrassmannNRSfM
from grass_nrsfm_ros.nrsfm.metrics import e3d, e3d_akhter, rotation_error
from grass_nrsfm_ros.nrsfm.problem import WarmStart
from grass_nrsfm_ros.nrsfm.rotation import estimate_rotations
from grass_nrsfm_ros.nrsfm.synthetic import make_sequence
from . import common
from .op_rotations import average_within, op_rotations, op_samples, so3_log

#: OP Tab. 2 (Akhter metric): R-BMM and OP
PUBLISHED_OP = {'drink': (0.0119, 0.0071), 'pickup': (0.0198, 0.0152),
                'yoga': (0.0129, 0.0122), 'dance': (0.1491, 0.1209),
                'face': (0.0179, 0.0145), 'shark': (0.0551, 0.0551)}
MOCAP = ('drink', 'pickup', 'yoga', 'dance', 'face', 'shark')
#: the shape settings (one: the solver's defaults; the JSON's 'shape' column)
SHAPES = {'plain': {}}
#: filter radii of the delta sweep (chordal; OP's is 0.05; 4 keeps every candidate), by mode
DELTAS = {'quick': (4.0,), 'full': (0.2, 4.0)}
ROTATIONS = {'dai': lambda W: estimate_rotations(W), 'op': lambda W: op_rotations(W)}


def cases(mode):
    """``(name, family, W, S, R_true or None)``."""
    for name in mode.pick(('shark',), MOCAP, MOCAP):
        loaded = common.load_dataset(name)
        if loaded is None:
            common.log(f'rotations: {name}: data not found, skipped')
            continue
        W, S, family = loaded
        yield name, family, W, S, None
    F, P = mode.pick((20, 60), (40, 200), (60, 1000))
    for kind in mode.pick(('bending',), ('bending', 'waving', 'inflating', 'twisting',
                                         'articulated'), ('bending', 'waving', 'inflating',
                                                          'twisting', 'articulated')):
        seq = make_sequence(kind, n_frames=F, n_points=P, seed=0, noise=0.0)
        yield f'synthetic_{kind}', 'synthetic', seq.W, seq.S, seq.R


def delta_sweep(name, W, S, dai, deltas):
    """OP's rotations with wider filters than OP's 0.05 (the samples of Dai's estimate
    ``dai``): how far they move from Dai's, and the plain solve's Akhter e3D with them."""
    rows = []
    samples, _ = op_samples(W, dai)
    for delta in deltas:
        R, kept, _ = average_within(samples, delta)
        res = GrassmannNRSfM().fit(W, init=WarmStart(R=R))
        rows.append({'sequence': name, 'delta': delta, 'kept_share': kept,
                     'angle_to_dai_deg': mean_angle(R, dai.R),
                     'e3d_akhter': e3d_akhter(res.S, S)})
        print(f"{name:22s} delta {delta:g}: kept {rows[-1]['kept_share']:.3f} angle to Dai "
              f"{rows[-1]['angle_to_dai_deg']:.2f} deg, akhter {rows[-1]['e3d_akhter']:.4f}",
              flush=True)
    return rows


def mean_angle(A, B):
    """Mean angle (degrees) between ``A, B: (F, 3, 3)`` frame by frame."""
    return float(np.degrees(np.linalg.norm(so3_log(A @ B.transpose(0, 2, 1)), axis=-1)).mean())


def rotation_rows(name, W, R_true):
    """``({method: (R, row)}, Dai's RotationEstimate)`` for Dai's and OP's rotations."""
    out, ests = {}, {}
    for method, estimate in ROTATIONS.items():
        est, wall, cpu = common.timed(estimate, W)
        ests[method] = est
        row = {'K_rot': est.K, 'rotation_seconds_cpu': cpu}
        if 'op' in est.scores:
            op = est.scores['op']
            row.update(candidates=op['candidates'], kept_share=op['kept_share'],
                       sra_iterations=op['iterations'])
        if R_true is not None:
            row['rotation_error_deg'] = rotation_error(est.R, R_true)
        out[method] = (est.R, row)
    out['op'][1]['angle_to_dai_deg'] = mean_angle(out['op'][0], out['dai'][0])
    return out, ests['dai']


def run(mode):
    rows, skipped, sweep = [], [], []
    for name, family, W, S, R_true in cases(mode):
        F, P = W.shape[0] // 2, W.shape[1]
        rotations, dai = rotation_rows(name, W, R_true)
        if family == 'mocap' and mode.name != 'smoke':
            sweep += delta_sweep(name, W, S, dai, DELTAS[mode.name])
        for method, (R, rot_row) in rotations.items():
            for shape, params in SHAPES.items():
                common.log(f'rotations: {name} ({F} x {P}) {method} {shape}')
                try:
                    res, wall, cpu = common.timed(GrassmannNRSfM(**params).fit, W,
                                                  init=WarmStart(R=R))
                except Exception as exc:
                    skipped.append({'sequence': name, 'rotations': method, 'shape': shape,
                                    'why': f'{type(exc).__name__}: {exc}'})
                    continue
                row = {'sequence': name, 'family': family, 'F': F, 'P': P,
                       'rotations': method, 'shape': shape, **rot_row,
                       'e3d': e3d(res.S, S), 'e3d_akhter': e3d_akhter(res.S, S),
                       'seconds_cpu': cpu, 'iterations': res.report.iterations}
                if name in PUBLISHED_OP:
                    row['published_rbmm'], row['published_op'] = PUBLISHED_OP[name]
                rows.append(row)
                print(f"{name:22s} {method:3s} {shape:21s} akhter {row['e3d_akhter']:.4f} "
                      f"e3d {row['e3d']:.4f} rot_err {row.get('rotation_error_deg', np.nan):.3f}"
                      f" kept {row.get('kept_share', np.nan):.3f}", flush=True)
    return {'rows': rows, 'skipped': skipped, 'delta_sweep': sweep,
            'notes': ['rotations given to the solver as WarmStart(R=...) (the same as '
                      "rotations='dai' on these inputs; no rotation check)",
                      'rotation_error_deg: synthetic only (the mocap files carry no rotations)',
                      'published_rbmm / published_op: OP Tab. 2, Akhter metric']}
