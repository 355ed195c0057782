"""Sheets: surfaces that bend without stretching, against rigid factorisation.

Options measured on the same tracks (e3D with a per-frame scale, and its ratio to rigid
factorisation's; the issue's bar is <= 0.6 for every sheet):

* ``default``: :class:`GrassmannNRSfM` as shipped (its inextensible stage on 'auto');
* ``no_inextensible``: the same with ``inextensible='never'`` (the paper's chain);
* ``isometry_solver`` / ``isometry_sync``: the default result's depths replaced by the local-
  isometry depths of :mod:`grass_nrsfm_ros.nrsfm.isometry` (gradient signs from the solver's
  own depths, or synchronised over the neighbour graph);
* ``sheet_registered``: the prior inside the estimation (:class:`isometry.SheetNRSfM` with
  ``alternations=1``): the rotations registered to the 'sync' sheet depths, the solver run
  again from them and from those shapes, its depths refined again (docs/decisions/0706);
* ``max_depth``: Chhatkuli et al.'s maximum-depth heuristic
  (:class:`max_depth.MaxDepthNRSfM`, pinhole only: it needs the rays' divergence; record
  0709).

Sequences: the package's synthetic 'bending' and 'waving' sheets (orbiting camera, several
seeds) and the front end's rendered sheets (:func:`frontend.scenes.sheet_scene`: a head-turn
camera; perfect tracks of surface samples), each orthographic and through a pinhole
(normalised tracks; the synthetic sheets 5 sizes from the camera as in
:mod:`bench.perspective`, the rendered ones where the renderer put them, f = 620 px at 640 x
480). Under the pinhole every option runs inside the projective-depth iteration
(:class:`perspective.PerspectiveNRSfM`) and rigid factorisation is of the normalised tracks;
``no_inextensible`` and ``isometry_solver`` are orthographic only. The real 10-frame subsets
kinect_paper10 and tshirt10 (a paper, a T-shirt; ground truth from depth) are pinhole rows
(bars 0.09 / 0.11, record 0705). Writes
``bench/results/sheets.json``. ``python -m bench.sheets [--smoke|--full]``.
"""
import sys
import time

import numpy as np

from grass_nrsfm_ros.nrsfm import camera, faces, isometry, max_depth, metrics, synthetic
from grass_nrsfm_ros.nrsfm.measurement import as_frames, from_frames
from grass_nrsfm_ros.nrsfm.perspective import PerspectiveNRSfM
from grass_nrsfm_ros.nrsfm.rotation import rigid_factorisation
from grass_nrsfm_ros.nrsfm.solver import GrassmannNRSfM
from . import common
from .perspective import sheet_shapes

BAR = 0.6
#: the synthetic sheets' distance from the pinhole (their size is about 2)
DISTANCE = 5.0


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
    """``(name, projection, W, S)``: tracks ``W: (2F, P)`` (orthographic, or normalised pinhole)
    and camera-frame truth ``S: (3F, P)``."""
    F, P = mode.pick((20, 150), (40, 300), (60, 500))
    seeds = mode.pick((0,), (0, 1), (0, 1, 2))
    for projection in ('orthographic', 'pinhole'):
        for kind in ('bending', 'waving'):
            for seed in seeds:
                if projection == 'orthographic':
                    seq = synthetic.make_sequence(kind, n_frames=F, n_points=P, seed=seed)
                    W, S = seq.W, seq.S
                else:
                    S = sheet_shapes(kind, F, P, seed, DISTANCE)
                    W = camera.project(S)
                yield f'synthetic_{kind}_seed{seed}', projection, W, S
                W, S = rendered_sheet(kind, F, P, seed)
                if projection == 'pinhole':
                    W = camera.project(S)
                yield f'rendered_{kind}_seed{seed}', projection, W, S
    for name in ('kinect_paper10', 'tshirt10'):
        loaded = common.load_dataset(name)
        if loaded is not None:
            yield name, 'pinhole', loaded[0], loaded[1]


def options(projection):
    """``{option: solver}`` measured under ``projection`` (each a ``fit(W) -> result``)."""
    chosen = {'default': GrassmannNRSfM(),
              'isometry_sync': isometry.SheetNRSfM(GrassmannNRSfM(), signs='sync'),
              'sheet_registered': isometry.SheetNRSfM(GrassmannNRSfM(), signs='sync',
                                                      alternations=1)}
    if projection == 'orthographic':
        chosen['no_inextensible'] = GrassmannNRSfM(inextensible='never')
        chosen['isometry_solver'] = isometry.SheetNRSfM(GrassmannNRSfM(), signs='solver')
        return chosen
    chosen = {name: PerspectiveNRSfM(solver) for name, solver in chosen.items()}
    chosen['max_depth'] = max_depth.MaxDepthNRSfM()
    return chosen


def case(name, projection, W, S):
    common.log(f'sheets: {name} {projection}')
    e3d = lambda est: metrics.e3d(est, S, scale=True)     # noqa: E731
    rigid = e3d(rigid_factorisation(W)[1])
    row = {'sequence': name, 'projection': projection, 'F': W.shape[0] // 2, 'P': W.shape[1],
           'rigid': rigid}
    row['seconds_cpu'] = {}
    for option, solver in options(projection).items():
        start = time.process_time()
        row[option] = e3d(solver.fit(W).S)
        row['seconds_cpu'][option] = time.process_time() - start
    row['ratios'] = {k: row[k] / rigid for k in OPTIONS if k in row}
    return row


OPTIONS = ('default', 'no_inextensible', 'isometry_solver', 'isometry_sync',
           'sheet_registered', 'max_depth')


def run(mode):
    rows = [case(*seq) for seq in sequences(mode)]
    print(f"{'sequence':28s} {'projection':12s} {'rigid':>7s} " +
          ' '.join(f'{o:>16s}' for o in OPTIONS))
    for row in rows:
        print(f"{row['sequence']:28s} {row['projection']:12s} {row['rigid']:7.4f} " +
              ' '.join(f"{row[o]:.4f} ({row['ratios'][o]:.2f})" if o in row else f"{'-':>16s}"
                       for o in OPTIONS))
    summary = {}
    for projection in ('orthographic', 'pinhole', 'all'):
        chosen = [r for r in rows if projection in ('all', r['projection'])]
        summary[projection] = {
            o: {'worst_ratio': max(r['ratios'][o] for r in chosen),
                'sheets_within_bar': sum(r['ratios'][o] <= BAR for r in chosen),
                'sheets': len(chosen)}
            for o in OPTIONS if all(o in r['ratios'] for r in chosen)}
    for projection, options_ in summary.items():
        for o, s in options_.items():
            print(f"{projection:12s} {o:16s} worst ratio {s['worst_ratio']:.2f}, "
                  f"{s['sheets_within_bar']} of {s['sheets']} within {BAR}")
    path = common.write_result(mode, 'sheets', {'rows': rows, 'summary': summary, 'bar': BAR})
    common.log(f'wrote {path}')
    return rows


if __name__ == '__main__':
    name = 'smoke' if '--smoke' in sys.argv else 'full' if '--full' in sys.argv else 'quick'
    run(common.Mode(name))
