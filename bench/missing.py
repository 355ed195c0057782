"""Missing data and tracker errors in the offline solver (issue #38's targets, record 0800).

* ``back``: the real back (``../shared/data/russell_back``, 150 x 245 pixel tracks, 4 % unseen,
  stereo truth): all 245 tracks solved, e3D (per-frame scale) over the seen entries with a
  truth (the two stereo outlier depths, z < 800, left out), over rigid factorisation of the
  126 complete tracks (bar <= 0.8); also ours on the 126 alone, ours-all on those 126,
  ours-all with the rotations from every track completed instead of the complete core, rigid
  factorisation on all 245 tracks completed (the same entries as ours-all) and ours-all given
  the oracle rotations (:func:`oracle_rotations` of :func:`registered_truth`: the back's turns
  against the camera; record 0807).
* ``occlusion``: the package's synthetic kinds with 20 % of the entries unseen in
  occlusion-like blocks (:func:`synthetic.occlusion_mask`), e3D over every entry (and over the
  seen ones) against the same tracks complete (bar <= 1.15); both also with the true
  rotations (``WarmStart(R=seq.R)``), which split the ratio into what the rotations and what
  the shapes cost (record 0809).
* ``drift``: 5 % of the tracks drifting up to 20 px (:func:`synthetic.drifting_tracks`, 1 px =
  the sequence's max |centred W| / 200), against the clean tracks (bar <= 1.2), with
  ``robust`` 'auto' (the default since record 0816: 'cauchy' where it weighs down at least
  2 % of the tracks), 'never' and 'cauchy' (its weighed-down tracks' 3D from their kept
  neighbours since record 0811, found also by their neighbours' residual since record 0812);
  the drifting tracks found, clean ones touched; 'never' and the clean tracks also with the
  true rotations (record 0809).

Synthetic: 60 frames x 400 tracks, orbiting camera, noise r = 0.005 (1 px), seeds 3 (and 4, 5
in --full). ``python -m bench.missing [--smoke|--full]`` writes ``bench/results/missing.json``.
"""
import sys
import time

import numpy as np

from grass_nrsfm_ros.nrsfm import e3d, GrassmannNRSfM, rigid_factorisation, synthetic, WarmStart
from grass_nrsfm_ros.nrsfm.measurement import nearest_rotation
from grass_nrsfm_ros.nrsfm.missing import fill_unseen
from grass_nrsfm_ros.nrsfm.stages import rotations
from . import common

BARS = {'back': 0.8, 'occlusion': 1.15, 'drift': 1.2}
NOISE = 0.005
#: stereo outliers of the back's truth: depths below this are left out of its e3D
BACK_MIN_DEPTH = 800.0


def solve(W, init=None, **params):
    """``(result, seconds)`` of a default solve with ``params`` (``init``: a WarmStart)."""
    start = time.perf_counter()
    result = GrassmannNRSfM(**params).fit(W, init=init)
    return result, time.perf_counter() - start


def oracle_rotations(W, S, visible):
    """``R: (F, 3, 3)``, the oracle rotations of tracks ``W: (2F, P)`` given their truth
    ``S: (3F, P)`` (camera frame or any other; NaN allowed where ``visible: (F, P)`` is False):
    per frame the least-squares affine camera ``A: (2, 3)`` taking the truth onto the tracks
    (both centred over the frame's visible entries), its rows made orthonormal (``U V^T`` of
    its SVD: the scale and skew left out) and completed by their cross product. Exact on
    noise-free orthographic tracks of a truth that is not flat. The world frame is the
    truth's."""
    F, P = visible.shape
    m = np.asarray(visible, dtype=float)[:, None, :]
    count = np.maximum(m.sum(axis=2, keepdims=True), 1.0)
    X = np.where(m > 0, np.asarray(S, dtype=float).reshape(F, 3, P), 0.0)
    Y = np.where(m > 0, np.asarray(W, dtype=float).reshape(F, 2, P), 0.0)
    X = (X - X.sum(axis=2, keepdims=True) / count) * m
    Y = (Y - Y.sum(axis=2, keepdims=True) / count) * m
    XXt = X @ X.transpose(0, 2, 1)
    A = np.linalg.solve(XXt, X @ Y.transpose(0, 2, 1)).transpose(0, 2, 1)     # (F, 2, 3)
    U, _, Vt = np.linalg.svd(A, full_matrices=False)
    rows = U @ Vt
    return np.concatenate([rows, np.cross(rows[:, 0], rows[:, 1])[:, None]], axis=1)


def registered_truth(S, truth):
    """``(3F, P)``: each frame of the truth ``S`` turned onto its first frame (orthogonal
    Procrustes, det +1, over the points with a truth in both), NaN where no truth."""
    F, P = truth.shape
    X = np.where(truth[:, None], S.reshape(F, 3, P), 0.0)
    both = (truth & truth[0])[:, None].astype(float)                  # (F, 1, P)
    count = np.maximum(both.sum(axis=2, keepdims=True), 1.0)
    Xf = (X - (X * both).sum(axis=2, keepdims=True) / count) * both
    X0 = (X[0] - (X[0] * both).sum(axis=2, keepdims=True) / count) * both
    Q = nearest_rotation(X0 @ Xf.transpose(0, 2, 1))                    # Q_f X_f ~ X_0
    return np.where(truth[:, None], Q @ S.reshape(F, 3, P), np.nan).reshape(3 * F, P)


def back_data():
    """The real back, or None without ../shared: ``(W: (2F, P) NaN where not seen, S: (3F, P),
    visible: (F, P), truth: (F, P) the entries with a truth, core: (P,) the complete tracks,
    rigid: rigid factorisation's e3D on them)``."""
    root = common.data_root()
    if root is None or not (root / 'russell_back' / 'back.npz').is_file():
        return None
    with np.load(root / 'russell_back' / 'back.npz') as z:
        W, S, visible = z['W'].astype(float), z['S'].astype(float), z['visible']
    F, P = visible.shape
    depth = S.reshape(F, 3, P)[:, 2]
    truth = visible & np.isfinite(S).reshape(F, 3, P).all(axis=1) & (depth > BACK_MIN_DEPTH)
    core = visible.all(axis=0)
    rigid = e3d(rigid_factorisation(W[:, core])[1], S[:, core], scale=True)
    return np.where(np.repeat(visible, 2, axis=0), W, np.nan), S, visible, truth, core, rigid


def back_row():
    data = back_data()
    if data is None:
        return None
    W, S, visible, truth, core, rigid = data
    F, P = visible.shape
    common.log('missing: back, 126 complete tracks')
    alone, t_alone = solve(W[:, core])
    common.log('missing: back, all 245 tracks')
    ours, t_all = solve(W)
    all_e3d = e3d(ours.S, S, scale=True, visible=truth)
    common.log('missing: back, all 245 tracks, rotations from every track completed')
    shipped, rotations.CORE_SHARE = rotations.CORE_SHARE, np.inf
    try:
        completed = e3d(solve(W)[0].S, S, scale=True, visible=truth)
    finally:
        rotations.CORE_SHARE = shipped
    common.log('missing: back, all 245 tracks, oracle rotations')
    R = oracle_rotations(W, registered_truth(S, truth), truth)
    oracle = e3d(solve(W, init=WarmStart(R=R))[0].S, S, scale=True, visible=truth)
    rigid_all = e3d(rigid_factorisation(fill_unseen(W)[0])[1], S, scale=True, visible=truth)
    return {'case': 'back', 'sequence': 'russell_back', 'F': F, 'P': P,
            'unseen': float(1 - visible.mean()), 'rigid_complete': rigid,
            'ours_complete': e3d(alone.S, S[:, core], scale=True),
            'ours_all_on_complete': e3d(ours.S[:, core], S[:, core], scale=True),
            'ours_all': all_e3d, 'ratio': all_e3d / rigid, 'bar': BARS['back'],
            'ours_all_rotations_completed': completed,
            'ratio_rotations_completed': completed / rigid,
            'ours_all_oracle_rotations': oracle, 'ratio_oracle_rotations': oracle / rigid,
            'rigid_all': rigid_all, 'ours_all_over_rigid_all': all_e3d / rigid_all,
            'seconds': t_all, 'seconds_complete': t_alone, 'completion': ours.report.completion,
            'K_rot': ours.report.K_rot}


def occlusion_row(kind, seed, F, P):
    seq = synthetic.make_sequence(kind, n_frames=F, n_points=P, noise=NOISE, seed=seed)
    visible = synthetic.occlusion_mask(seq.W, 0.2, np.random.default_rng(seed + 100))
    W = np.where(np.repeat(visible, 2, axis=0), seq.W, np.nan)
    common.log(f'missing: occlusion {kind} seed {seed}')
    full, t_full = solve(seq.W)
    masked, t_masked = solve(W)
    complete_e3d, masked_e3d = e3d(full.S, seq.S), e3d(masked.S, seq.S)
    true = WarmStart(R=seq.R)
    complete_true, masked_true = (e3d(solve(X, init=true)[0].S, seq.S) for X in (seq.W, W))
    return {'case': 'occlusion', 'sequence': kind, 'seed': seed, 'F': F, 'P': P,
            'unseen': float(1 - visible.mean()), 'complete': complete_e3d, 'masked': masked_e3d,
            'masked_seen': e3d(masked.S, seq.S, visible=visible),
            'ratio': masked_e3d / complete_e3d, 'bar': BARS['occlusion'],
            'complete_true_rotations': complete_true, 'masked_true_rotations': masked_true,
            'ratio_true_rotations': masked_true / complete_true,
            'seconds': t_masked, 'seconds_complete': t_full,
            'completion': masked.report.completion}


def drift_case(kind, seed, F=60, P=400):
    """``(seq, W: (2F, P), drifting: (P,) bool)``: a drift row's clean sequence (1 px noise)
    and its tracks with 5 % drifting up to 20 px (the drift's generator seeded seed + 200)."""
    seq = synthetic.make_sequence(kind, n_frames=F, n_points=P, noise=NOISE, seed=seed)
    W, drifting = synthetic.drifting_tracks(seq.W, 0.05, 20.0, np.random.default_rng(seed + 200))
    return seq, W, drifting


def drift_row(kind, seed, F, P):
    seq, W, drifting = drift_case(kind, seed, F, P)
    common.log(f'missing: drift {kind} seed {seed}')
    clean = e3d(solve(seq.W)[0].S, seq.S)
    true = WarmStart(R=seq.R)
    clean_true, never_true = (e3d(solve(X, init=true, robust='never')[0].S, seq.S)
                              for X in (seq.W, W))
    row = {'case': 'drift', 'sequence': kind, 'seed': seed, 'F': F, 'P': P, 'clean': clean,
           'bar': BARS['drift'], 'drifting': int(drifting.sum()),
           'clean_true_rotations': clean_true, 'never_true_rotations': never_true,
           'ratio_true_rotations': never_true / clean_true}
    for robust in ('auto', 'never', 'cauchy'):
        result, seconds = solve(W, robust=robust)
        if robust == 'auto':
            row['auto_weighed'] = result.track_weights is not None
        row[robust] = e3d(result.S, seq.S)
        row[f'ratio_{robust}'] = row[robust] / clean
        row[f'seconds_{robust}'] = seconds
        if robust == 'cauchy':
            down = np.zeros(P, dtype=bool)
            down[result.report.downweighted_tracks] = True
            row['found'] = int((down & drifting).sum())
            row['clean_touched'] = int((down & ~drifting).sum())
            row['clean_tracks_robust'] = e3d(solve(seq.W, robust=robust)[0].S, seq.S) / clean
    return row


def summary(rows):
    """Per case: the mean of the ratios and how many rows meet the bar."""
    out = {}
    for case, key in (('occlusion', 'ratio'), ('occlusion', 'ratio_true_rotations'),
                      ('drift', 'ratio_auto'), ('drift', 'ratio_never'), ('drift', 'ratio_cauchy'),
                      ('drift', 'ratio_true_rotations'), ('back', 'ratio')):
        values = [r[key] for r in rows if r['case'] == case]
        if values:
            out[f'{case} {key}'] = {'mean': float(np.mean(values)), 'max': float(np.max(values)),
                                    'meet_bar': int(sum(v <= BARS[case] for v in values)),
                                    'rows': len(values)}
    return out


def run(mode):
    kinds = mode.pick(('bending',), synthetic.kinds(), synthetic.kinds())
    seeds = mode.pick((3,), (3,), (3, 4, 5))
    F, P = mode.pick((30, 150), (60, 400), (60, 400))
    rows = []
    if mode.name != 'smoke':
        back = back_row()
        if back is not None:
            rows.append(back)
    rows += [occlusion_row(k, s, F, P) for k in kinds for s in seeds]
    rows += [drift_row(k, s, F, P) for k in kinds for s in seeds]
    payload = {'rows': rows, 'summary': summary(rows), 'bars': BARS, 'noise': NOISE}
    path = common.write_result(mode, 'missing', payload)
    common.log(f'wrote {path}')
    for line in text(payload):
        print(line)
    return payload


def text(payload):
    """The figures as lines of text."""
    out = []
    for r in payload['rows']:
        if r['case'] == 'back':
            out.append(f"back {r['F']} x {r['P']}: all {r['ours_all']:.4f} / rigid(126) "
                       f"{r['rigid_complete']:.4f} = {r['ratio']:.3f} (bar {r['bar']}); ours(126) "
                       f"{r['ours_complete']:.4f}, all-on-126 {r['ours_all_on_complete']:.4f}; "
                       f"rotations from all completed {r['ours_all_rotations_completed']:.4f} "
                       f"({r['ratio_rotations_completed']:.3f}); oracle rotations "
                       f"{r['ours_all_oracle_rotations']:.4f} "
                       f"({r['ratio_oracle_rotations']:.3f}); "
                       f"rigid on all 245 completed {r['rigid_all']:.4f}")
        elif r['case'] == 'occlusion':
            out.append(f"occlusion {r['sequence']} s{r['seed']}: {r['masked']:.4f} / "
                       f"{r['complete']:.4f} = {r['ratio']:.3f} (seen {r['masked_seen']:.4f}); "
                       f"true rotations {r['masked_true_rotations']:.4f} / "
                       f"{r['complete_true_rotations']:.4f} = {r['ratio_true_rotations']:.3f}")
        else:
            out.append(f"drift {r['sequence']} s{r['seed']}: auto {r['ratio_auto']:.3f}, "
                       f"never {r['ratio_never']:.3f}, "
                       f"cauchy {r['ratio_cauchy']:.3f} (found {r['found']}/{r['drifting']}, "
                       f"clean touched {r['clean_touched']}; clean+cauchy "
                       f"{r['clean_tracks_robust']:.3f}); true rotations "
                       f"{r['never_true_rotations']:.4f} / {r['clean_true_rotations']:.4f} = "
                       f"{r['ratio_true_rotations']:.3f}")
    for key, value in payload['summary'].items():
        out.append(f"{key}: mean {value['mean']:.3f}, max {value['max']:.3f}, "
                   f"{value['meet_bar']}/{value['rows']} within the bar")
    return out


if __name__ == '__main__':
    name = 'smoke' if '--smoke' in sys.argv else 'full' if '--full' in sys.argv else 'quick'
    run(common.Mode(name))
