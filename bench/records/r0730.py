"""Record 0730: which criterion tells the first solve's depths from their mirror.

For each rendered pinhole face (40 x 400) and each draw of its tracks' rounding (0: as
rendered), the first orthographic solve of the normalised tracks, then round 1 solved from
both signs of its depths. Printed per case: the true sign (correlation with the true centred
depths), the sign each criterion picks (the rank-3 residual of ``x (1 + s delta)`` before any
round: ``low_rank_sign``; the solver's fit residual of each round-1 input; the perspective
residual of each round 1) and each round 1's e3D over the orthographic e3D of the same points;
then how often each criterion picked the true sign.

``python -m bench.records.r0730 [--seeds 0,1,...] [--draws N]`` (default seeds 0-7, draws 0-5;
about 7 minutes of one core).
"""
import sys

import numpy as np

from bench.perspective import e3d, face_shapes, orthographic, pinhole, rounding_draw
from grass_nrsfm_ros.nrsfm import camera
from grass_nrsfm_ros.nrsfm import perspective as pm
from grass_nrsfm_ros.nrsfm.solver import GrassmannNRSfM


def case(S, x, ortho):
    """One input: the picks of each criterion, the true sign and each sign's round-1 ratio."""
    solver = GrassmannNRSfM(inextensible='never')      # the rounds' chain (record 0725)
    delta = pm.centred_depths(solver.fit(x).S)
    rounds = {s: pm.PerspectiveNRSfM._round(solver, x, s * delta, 1) for s in (1.0, -1.0)}
    ratio = {s: e3d(pm.camera_frame_shapes(x, new), S) / ortho
             for s, (_, new, _) in rounds.items()}
    return {'true': float(np.sign(np.sum(delta * pm.centred_depths(S)))),
            'low rank': pm.low_rank_sign(x, delta),
            'fit': min(rounds, key=lambda s: rounds[s][0].fit),
            'perspective residual': min(rounds, key=lambda s: rounds[s][0].residual),
            'ratio': ratio}


def main(argv):
    seeds = range(8)
    draws = 6
    if '--seeds' in argv:
        seeds = [int(s) for s in argv[argv.index('--seeds') + 1].split(',')]
    if '--draws' in argv:
        draws = int(argv[argv.index('--draws') + 1])
    K = pinhole()
    right = {'low rank': 0, 'fit': 0, 'perspective residual': 0}
    total = 0
    for seed in seeds:
        S = face_shapes(40, 400, seed)
        if S is None:
            print('Surrey face model not found (set GRASS_NRSFM_DATA)')
            return 1
        W_px = camera.project(S, K)
        ortho = e3d(GrassmannNRSfM().fit(orthographic(S)).S, S)
        for draw in range(draws):
            x = camera.normalise(W_px if draw == 0 else rounding_draw(W_px, draw), K)
            row = case(S, x, ortho)
            total += 1
            for name in right:
                right[name] += row[name] == row['true']
            print(f"face {seed} draw {draw}: true {row['true']:+.0f}; picks: low rank "
                  f"{row['low rank']:+.0f}, fit {row['fit']:+.0f}, perspective residual "
                  f"{row['perspective residual']:+.0f}; round 1 / orthographic: + "
                  f"{row['ratio'][1.0]:.3f}, - {row['ratio'][-1.0]:.3f}", flush=True)
    print('true sign picked: ' + ', '.join(f'{k} {v} of {total}' for k, v in right.items()))
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
