"""Sheets: surfaces that bend without stretching, against rigid factorisation.

Options measured on the same tracks (e3D with a per-frame scale, and its ratio to rigid
factorisation's; the issue's bar is <= 0.6 for every sheet):

* ``default``: :class:`GrassmannNRSfM` as shipped (its inextensible stage on 'auto'; through
  the pinhole ``projection='perspective'``, whose rounds hold the stage off, record 0725);
* ``no_inextensible``: the same with ``inextensible='never'`` (the paper's chain);
* ``isometry_solver`` / ``isometry_sync``: the default result's depths replaced by the local-
  isometry depths of :mod:`grass_nrsfm_ros.nrsfm.isometry` (gradient signs from the solver's
  own depths, or synchronised over the neighbour graph);
* ``sheet_registered``: the prior inside the estimation (:class:`isometry.SheetNRSfM` with
  ``alternations=1``): the rotations registered to the 'sync' sheet depths, the solver run
  again from them and from those shapes, its depths refined again (docs/decisions/0706);
* ``sheet_transport``: local-isometry depths from the tracks alone, each frame's fitted to its
  edge sizes near the shape carried from the frame before by the best orthographic camera,
  runs from several start frames joined by a Viterbi path
  (:class:`sheet_transport.TransportSheetNRSfM`, orthographic only; record 0714);
* ``max_depth``: Chhatkuli et al.'s maximum-depth heuristic
  (:class:`max_depth.MaxDepthNRSfM`, pinhole only: it needs the rays' divergence; record
  0709).

Sequences: the package's synthetic 'bending', 'waving' and 'flag' sheets (orbiting camera,
several seeds) and the front end's rendered sheets (:func:`frontend.scenes.sheet_scene`: a
head-turn camera; perfect tracks of surface samples), each orthographic and through a pinhole
(normalised tracks; the synthetic sheets 5 sizes from the camera as in
:mod:`bench.perspective`, the rendered ones where the renderer put them, f = 620 px at 640 x
480). Under the pinhole every option runs inside the projective-depth iteration
(:class:`perspective.PerspectiveNRSfM`) and rigid factorisation is of the normalised tracks;
``no_inextensible`` and ``isometry_solver`` are orthographic only. The real 10-frame subsets
kinect_paper10 and tshirt10 (a paper, a T-shirt; ground truth from depth) are pinhole rows
(bars 0.09 / 0.11, record 0705).

'waving' stretches: its edge lengths range over 0.69-1.29 of frame 0's along the waves (p5-p95,
a 40 x 40 grid, 60 frames), so it is outside the assumption of every inextensible prior here;
'flag' is the isometric waving cloth (a held edge, travelling waves, edge lengths constant to
5e-4; record 0713). 'bending' is isometric too.

Writes ``bench/results/sheets.json``. ``python -m bench.sheets [--smoke|--full] [--kinds
flag,...]``: with ``--kinds`` only those kinds' synthetic and rendered sheets run (``real``: the
real subsets), and their rows replace the same kinds' rows of the JSON already there (the
others are kept; ``runs`` in the JSON and the table's note say which rows came from which
run). ``--options sheet_transport,...`` with ``--kinds``: only those options run, on those
kinds' sheets under the projections they apply to, and their figures are added to the rows
already there (the rows' other figures are kept).
"""
import argparse
import json
import time

import numpy as np

from grass_nrsfm_ros.nrsfm import (camera, faces, isometry, max_depth, metrics,
                                   sheet_transport, synthetic)
from grass_nrsfm_ros.nrsfm.measurement import as_frames, from_frames
from grass_nrsfm_ros.nrsfm.perspective import PerspectiveNRSfM
from grass_nrsfm_ros.nrsfm.rotation import rigid_factorisation
from grass_nrsfm_ros.nrsfm.solver import GrassmannNRSfM
from . import common
from .perspective import pinhole_sheet

BAR = 0.6
#: the synthetic and rendered sheets' kinds (:mod:`grass_nrsfm_ros.nrsfm.synthetic`)
KINDS = ('bending', 'waving', 'flag')
REAL = ('kinect_paper10', 'tshirt10')
NOTE = ('waving stretches (edge lengths 0.69-1.29 of those of frame 0 along the waves, '
        'p5-p95): it is outside the assumption of the inextensible priors (the inextensible '
        'stage, the isometry options, max_depth); flag is the isometric waving cloth, bending '
        'the isometric bending sheet (record 0713).')
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


def sequences(mode, kinds=KINDS, real=True):
    """``(name, projection, W, S)``: tracks ``W: (2F, P)`` (orthographic, or normalised pinhole)
    and camera-frame truth ``S: (3F, P)`` of the ``kinds``' sheets, then (``real``) the real
    subsets."""
    F, P = mode.pick((20, 150), (40, 300), (60, 500))
    seeds = mode.pick((0,), (0, 1), (0, 1, 2))
    for projection in ('orthographic', 'pinhole'):
        for kind in kinds:
            for seed in seeds:
                if projection == 'orthographic':
                    seq = synthetic.make_sequence(kind, n_frames=F, n_points=P, seed=seed)
                    W, S = seq.W, seq.S
                else:
                    W, S = pinhole_sheet(kind, F, P, seed, DISTANCE)
                yield f'synthetic_{kind}_seed{seed}', projection, W, S
                W, S = rendered_sheet(kind, F, P, seed)
                if projection == 'pinhole':
                    W = camera.project(S)
                yield f'rendered_{kind}_seed{seed}', projection, W, S
    for name in REAL if real else ():
        loaded = common.load_dataset(name)
        if loaded is not None:
            yield name, 'pinhole', loaded[0], loaded[1]


def options(projection):
    """``{option: solver}`` measured under ``projection`` (each a ``fit(W) -> result``)."""
    if projection == 'orthographic':
        return {'default': GrassmannNRSfM(),
                'isometry_sync': isometry.SheetNRSfM(GrassmannNRSfM(), signs='sync'),
                'sheet_registered': isometry.SheetNRSfM(GrassmannNRSfM(), signs='sync',
                                                        alternations=1),
                'no_inextensible': GrassmannNRSfM(inextensible='never'),
                'isometry_solver': isometry.SheetNRSfM(GrassmannNRSfM(), signs='solver'),
                'sheet_transport': sheet_transport.TransportSheetNRSfM()}
    rounds = GrassmannNRSfM(relief='never')          # the rounds scale their own (0734)
    sheet = {'isometry_sync': isometry.SheetNRSfM(rounds, signs='sync'),
             'sheet_registered': isometry.SheetNRSfM(rounds, signs='sync', alternations=1)}
    return {'default': GrassmannNRSfM(projection='perspective'),     # as shipped (record 0725)
            **{name: PerspectiveNRSfM(solver) for name, solver in sheet.items()},
            'max_depth': max_depth.MaxDepthNRSfM()}


def case(name, projection, W, S, only=None):
    """The row of one sheet: every option under ``projection`` (``only``: those named)."""
    common.log(f'sheets: {name} {projection}')
    e3d = lambda est: metrics.e3d(est, S, scale=True)     # noqa: E731
    rigid = e3d(rigid_factorisation(W)[1])
    row = {'sequence': name, 'projection': projection, 'F': W.shape[0] // 2, 'P': W.shape[1],
           'rigid': rigid}
    row['seconds_cpu'] = {}
    for option, solver in options(projection).items():
        if only is not None and option not in only:
            continue
        start = time.process_time()
        row[option] = e3d(solver.fit(W).S)
        row['seconds_cpu'][option] = time.process_time() - start
    row['ratios'] = {k: row[k] / rigid for k in OPTIONS if k in row}
    return row


OPTIONS = ('default', 'no_inextensible', 'isometry_solver', 'isometry_sync',
           'sheet_registered', 'sheet_transport', 'max_depth')


def order(row):
    """Sort key of a row: projection, kind, seed, synthetic before rendered; real ones last."""
    name = row['sequence']
    if name in REAL:
        return (2, REAL.index(name), 0, 0)
    source, kind, seed = name.split('_')
    return (row['projection'] != 'orthographic', KINDS.index(kind), int(seed[4:]),
            source == 'rendered')


def row_kind(row):
    """The sheet kind of a row ('real' for the real subsets)."""
    return 'real' if row['sequence'] in REAL else row['sequence'].split('_')[1]


def merged(mode, rows, kinds):
    """``(rows, runs)``: ``rows`` of ``kinds`` in place of the same kinds' rows of the JSON in
    ``mode``'s folder, and the runs each row set came from."""
    env = common.environment()
    this = {'kinds': list(kinds), 'date': env['date'], 'git': env['git']}
    path = mode.out_dir / 'sheets.json'
    if not path.exists():
        return rows, [this]
    old = json.loads(path.read_text())
    if old.get('mode') != mode.name:
        raise SystemExit(f"{path} holds a {old.get('mode')} run; --kinds merges into the same "
                         f'mode only ({mode.name})')
    kept = [r for r in old['rows'] if row_kind(r) not in kinds]
    runs = old.get('runs') or [{'kinds': sorted({row_kind(r) for r in old['rows']}),
                                'date': old['environment']['date'],
                                'git': old['environment']['git']}]
    runs = [dict(r, kinds=[k for k in r['kinds'] if k not in kinds]) for r in runs]
    runs = [r for r in runs if r['kinds']] + [this]
    return sorted(kept + rows, key=order), runs


def with_options(mode, rows, kinds, only):
    """``(rows, runs)``: the JSON's rows in ``mode``'s folder with the options ``only``
    measured in ``rows`` (the same sheets) added to them."""
    path = mode.out_dir / 'sheets.json'
    if not path.exists():
        raise SystemExit(f'{path} is missing; --options adds figures to its rows')
    old = json.loads(path.read_text())
    if old.get('mode') != mode.name:
        raise SystemExit(f"{path} holds a {old.get('mode')} run; --options adds to the same "
                         f'mode only ({mode.name})')
    new = {(r['sequence'], r['projection']): r for r in rows}
    out = []
    for r in old['rows']:
        add = new.pop((r['sequence'], r['projection']), None)
        if add is not None:
            if abs(add['rigid'] - r['rigid']) > 1e-6 * r['rigid']:
                raise SystemExit(f"{r['sequence']}: rigid {add['rigid']} differs from the "
                                 f"JSON's {r['rigid']}: not the same tracks")
            r = dict(r, seconds_cpu=dict(r.get('seconds_cpu', {}), **add['seconds_cpu']))
            for o in only:
                if o in add:
                    r[o] = add[o]
            r['ratios'] = {k: r[k] / r['rigid'] for k in OPTIONS if k in r}
        out.append(r)
    if new:
        raise SystemExit(f'rows not in {path}: {sorted(new)}')
    env = common.environment()
    runs = old.get('runs') or []
    runs = runs + [{'kinds': [f"{', '.join(only)} on {', '.join(kinds)}"], 'date': env['date'],
                    'git': env['git']}]
    return out, runs


def run(mode, kinds=None, only=None):
    """Measure every option on the sheets (``kinds``: only those kinds' synthetic and
    rendered sheets, merged into the JSON already there)."""
    rows = [case(*seq, only=only) for seq in
            sequences(mode, [k for k in kinds or KINDS if k in KINDS],
                      real=kinds is None or 'real' in kinds)]
    if only is not None:
        rows, runs = with_options(mode, [r for r in rows if r['seconds_cpu']], kinds, only)
    elif kinds is None:
        env = common.environment()
        runs = [{'kinds': [*KINDS, 'real'], 'date': env['date'], 'git': env['git']}]
    else:
        rows, runs = merged(mode, rows, kinds)
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
    path = common.write_result(mode, 'sheets', {'rows': rows, 'summary': summary, 'bar': BAR,
                                                'note': NOTE, 'runs': runs})
    common.log(f'wrote {path}')
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m bench.sheets', description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    size = parser.add_mutually_exclusive_group()
    size.add_argument('--smoke', action='store_true')
    size.add_argument('--full', action='store_true')
    parser.add_argument('--kinds', help=f"comma-separated, of {', '.join(KINDS)}, real: only "
                        'their sheets (real: the real subsets), merged into the JSON already '
                        'there')
    parser.add_argument('--options', help=f"comma-separated, of {', '.join(OPTIONS)} (with "
                        '--kinds): only these options, added to the rows already there')
    args = parser.parse_args(argv)
    kinds = only = None
    if args.kinds:
        kinds = tuple(k for k in args.kinds.split(',') if k)
        if not set(kinds) <= {*KINDS, 'real'}:
            parser.error(f'--kinds: choose from {", ".join(KINDS)}, real')
    if args.options:
        only = tuple(o for o in args.options.split(',') if o)
        if not set(only) <= set(OPTIONS) or kinds is None:
            parser.error(f'--options: with --kinds, choose from {", ".join(OPTIONS)}')
    run(common.Mode('smoke' if args.smoke else 'full' if args.full else 'quick'), kinds, only)


if __name__ == '__main__':
    main()
