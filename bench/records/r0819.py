"""Record 0819: robust weights as the lever for the front end's drifting face tracks.

    python -m bench.records.r0819 [--face 2]

The shipped tracker on a rendered face (``bench.frontend``'s scene of that seed, 100 frames,
step 4); its complete frame-0 tracks, evenly subsampled to 1,500 as ``bench.frontend`` gives
them to the solver (normalised by K), solved through the pinhole (``projection=
'perspective'``). e3D (per-frame scale) of: the perfect tracks of the same points; the tracked
ones as shipped, with ``robust='cauchy'``, with its floor lowered (``RESIDUAL_FLOOR``,
``LOCAL_THRESHOLD``); with oracle weights (the tracks whose largest pixel error exceeds 5 or 3
px weighed down) under the shipped refit and a refit from the first 10 frames; and with those
tracks given their perfect positions. Also the rank correlation of the stage's two residuals
with each track's RMS pixel error.
"""
import argparse
from contextlib import nullcontext
from unittest import mock

import numpy as np
from scipy.stats import spearmanr

from grass_nrsfm_ros.frontend import scenes
from grass_nrsfm_ros.nrsfm import e3d, GrassmannNRSfM
from grass_nrsfm_ros.nrsfm.inextensible import trajectory_embedding
from grass_nrsfm_ros.nrsfm.measurement import centre
from grass_nrsfm_ros.nrsfm.problem import Problem
from grass_nrsfm_ros.nrsfm.stages import robust
from .. import frontend

EARLY_FRAMES = 10


def face_tracks(seed):
    """``(tracked, perfect: (2F, P) normalised, truth: (3F, P), error: (F, P) px)``."""
    scene = scenes.face_scene(100, seed=seed)
    uv, true_uv, X, visible, birth = frontend.track_scene(scene)
    tracks = np.flatnonzero(frontend.complete_tracks(birth, uv, visible))
    tracks = tracks[frontend.evenly_spread(len(tracks))]
    uv, true_uv, X = uv[:, tracks], true_uv[:, tracks], X[:, tracks]
    return (*frontend.solver_tracks(scene.K, uv, true_uv, X),
            np.linalg.norm(uv - true_uv, axis=2))


def early_refit(S, W, weights, report=None):
    """:func:`robust.refit` with each weighed-down track's 3D always the affine combination of
    its nearest kept tracks over the first EARLY_FRAMES frames (before drift builds up)."""
    down, keep = np.flatnonzero(weights < 1.0), np.flatnonzero(weights >= 1.0)
    Wc, rows = centre(W)[0], np.arange(W.shape[0]) < 2 * EARLY_FRAMES
    out = S.copy()
    for track in down:
        nbrs, w = robust.neighbours(Wc, keep, track, rows)
        out[:, track] = S[:, nbrs] @ w
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--face', type=int, default=2)
    args = parser.parse_args(argv)
    tracked, perfect, truth, error = face_tracks(args.face)
    largest, rms = error.max(axis=0), np.sqrt((error ** 2).mean(axis=0))

    def solve(W, robust_mode='auto', **constants):
        with mock.patch.multiple(robust, **constants) if constants else nullcontext():
            result = GrassmannNRSfM(projection='perspective', robust=robust_mode).fit(W)
        return e3d(result.S, truth, scale=True), len(result.report.downweighted_tracks or [])

    reference = solve(perfect)[0]
    print(f'face {args.face}: {tracked.shape[1]} tracks, pixel error median '
          f'{np.median(error):.2f} p95 {np.percentile(error, 95):.2f}; largest > 5 px on '
          f'{int((largest > 5).sum())}, > 3 px on {int((largest > 3).sum())} tracks; perfect '
          f'tracks e3D {reference:.4f}', flush=True)
    problem = Problem.from_tracks(tracked, None, None, 0, None)
    seen = np.ones_like(problem.Wn, dtype=bool)
    local = robust.local_residuals(problem.Wn, np.ones(problem.P, bool), seen,
                                   trajectory_embedding(problem.Wn))
    print(f"  rank correlation with the RMS pixel error: neighbours' residual "
          f'{spearmanr(local, rms)[0]:.2f}, low-rank residual '
          f'{spearmanr(robust.residuals(problem.Wn, np.ones(problem.P), seen), rms)[0]:.2f}')
    variants = {'shipped': ('auto', {}), 'cauchy': ('cauchy', {}),
                'cauchy, floor 5e-3': ('cauchy', {'RESIDUAL_FLOOR': 5e-3}),
                'cauchy, floor 3e-3': ('cauchy', {'RESIDUAL_FLOOR': 3e-3}),
                'cauchy, floor 3e-3, 5 deviations': (
                    'cauchy', {'RESIDUAL_FLOOR': 3e-3, 'LOCAL_THRESHOLD': 5.0})}
    for limit in (5.0, 3.0):
        weights = np.where(largest > limit, 1e-3, 1.0)
        oracle = {'track_weights': lambda problem, w=weights: w}
        variants[f'oracle > {limit:g} px'] = ('cauchy', oracle)
        early = {**oracle, 'refit': early_refit}
        variants[f'oracle > {limit:g} px, early refit'] = ('cauchy', early)
    for name, (mode, constants) in variants.items():
        value, weighed = solve(tracked, mode, **constants)
        print(f'  {name}: {value:.4f} ({value / reference:.3f} of perfect; {weighed} weighed '
              'down)', flush=True)
    for limit in (5.0, 3.0):
        W = np.where((largest > limit)[None, :], perfect, tracked)
        value = solve(W)[0]
        print(f'  tracks > {limit:g} px given their perfect positions: {value:.4f} '
              f'({value / reference:.3f})', flush=True)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
