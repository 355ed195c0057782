"""Sheets: surfaces that bend without stretching, against rigid factorisation.

Options measured on the same tracks (e3D with a per-frame scale, and its ratio to rigid
factorisation's; the issue's bar is <= 0.6 for every sheet):

* ``default``: :class:`GrassmannNRSfM` as shipped (its inextensible stage on 'auto');
* ``no_inextensible``: the same with ``inextensible='never'`` (the paper's chain);
* ``isometry_solver`` / ``isometry_sync``: the default result's depths replaced by the local-
  isometry depths of :mod:`grass_nrsfm_ros.nrsfm.isometry` (gradient signs from the solver's
  own depths, or synchronised over the neighbour graph).

Sequences: the package's synthetic 'bending' and 'waving' sheets (orbiting camera, several
seeds) and the front end's rendered sheets (:func:`frontend.scenes.sheet_scene`: a head-turn
camera; perfect tracks of surface samples), orthographic. Writes ``bench/results/sheets.json``.
``python -m bench.sheets [--smoke|--full]``.
"""
import sys

import numpy as np

from grass_nrsfm_ros.nrsfm import faces, isometry, metrics, synthetic
from grass_nrsfm_ros.nrsfm.measurement import as_frames, from_frames
from grass_nrsfm_ros.nrsfm.rotation import rigid_factorisation
from grass_nrsfm_ros.nrsfm.solver import GrassmannNRSfM
from . import common

BAR = 0.6


def rendered_sheet(kind, F, P, seed):
    """``(W, S)``: orthographic tracks and camera-frame truth of ``P`` surface samples of the
    rendered sheet (centred on the optical axis)."""
    from grass_nrsfm_ros.frontend import scenes
    scene = scenes.sheet_scene(kind, F, seed=seed)
    tri, bary = faces.sample_surface(scene.vertices[0], scene.triangles, P,
                                     np.random.default_rng(seed))
    X = np.einsum('fncd,nc->fnd', scene.vertices[:, scene.triangles[tri], :], bary)
    S = from_frames(X.transpose(0, 2, 1))
    return from_frames(as_frames(S, 3)[:, :2, :]), S


def sequences(mode):
    F, P = mode.pick((20, 150), (40, 300), (60, 500))
    seeds = mode.pick((0,), (0, 1), (0, 1, 2))
    for kind in ('bending', 'waving'):
        for seed in seeds:
            seq = synthetic.make_sequence(kind, n_frames=F, n_points=P, seed=seed)
            yield f'synthetic_{kind}_seed{seed}', seq.W, seq.S
            yield (f'rendered_{kind}_seed{seed}',) + rendered_sheet(kind, F, P, seed)


def case(name, W, S):
    common.log(f'sheets: {name}')
    e3d = lambda est: metrics.e3d(est, S, scale=True)     # noqa: E731
    rigid = e3d(rigid_factorisation(W)[1])
    default = GrassmannNRSfM().fit(W)
    row = {'sequence': name, 'F': W.shape[0] // 2, 'P': W.shape[1], 'rigid': rigid,
           'default': e3d(default.S),
           'no_inextensible': e3d(GrassmannNRSfM(inextensible='never').fit(W).S)}
    for signs in ('solver', 'sync'):
        row[f'isometry_{signs}'] = e3d(isometry.refine_sheet(default.S, W, signs=signs)[0])
    row['ratios'] = {k: row[k] / rigid for k in
                     ('default', 'no_inextensible', 'isometry_solver', 'isometry_sync')}
    return row


def run(mode):
    rows = [case(*seq) for seq in sequences(mode)]
    options = list(rows[0]['ratios'])
    print(f"{'sequence':28s} {'rigid':>7s} " + ' '.join(f'{o:>16s}' for o in options))
    for row in rows:
        print(f"{row['sequence']:28s} {row['rigid']:7.4f} " +
              ' '.join(f"{row[o]:.4f} ({row['ratios'][o]:.2f})" for o in options))
    summary = {o: {'worst_ratio': max(r['ratios'][o] for r in rows),
                   'sheets_within_bar': sum(r['ratios'][o] <= BAR for r in rows)}
               for o in options}
    for o, s in summary.items():
        print(f"{o:16s} worst ratio {s['worst_ratio']:.2f}, {s['sheets_within_bar']} of "
              f'{len(rows)} within {BAR}')
    path = common.write_result(mode, 'sheets', {'rows': rows, 'summary': summary, 'bar': BAR})
    common.log(f'wrote {path}')
    return rows


if __name__ == '__main__':
    name = 'smoke' if '--smoke' in sys.argv else 'full' if '--full' in sys.argv else 'quick'
    run(common.Mode(name))
