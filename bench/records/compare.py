"""Case sets and a settings-by-case e3D table for the record scripts (:mod:`bench.records`).

A case is ``(name, W: (2F, P), S: (3F, P))``; a setting is ``(label, solver keyword arguments)``
(or ``(label, fit)`` with ``fit(W) -> NRSfMResult`` where keywords do not suffice). The table
prints e3D (:func:`~grass_nrsfm_ros.nrsfm.metrics.e3d`, or Akhter's metric for mocap with
``metric='akhter'``), the iterations of the shape solve, and per setting the geometric mean of
its e3D ratio to the first setting's.
"""
import argparse
from contextlib import contextmanager
import time

import numpy as np

from grass_nrsfm_ros.nrsfm import GrassmannNRSfM
from grass_nrsfm_ros.nrsfm.metrics import e3d, e3d_akhter
from grass_nrsfm_ros.nrsfm.synthetic import make_sequence
from .. import common


@contextmanager
def patched(module, name, value):
    """``module.name`` set to ``value`` inside the block, restored after."""
    old = getattr(module, name)
    setattr(module, name, value)
    try:
        yield
    finally:
        setattr(module, name, old)


def parse(argv, doc):
    """``--full`` (the record's own case set) parsed from ``argv``."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument('--full', action='store_true', help="the record's full case set")
    return parser.parse_args(argv)


def synthetic_cases(kinds, cameras=('orbit',), seeds=(0,), F=60, P=500, **options):
    """Synthetic sequences (:func:`~grass_nrsfm_ros.nrsfm.synthetic.make_sequence`) named
    ``kind_camera_seed``; ``options`` go to the generator (noise, clustered)."""
    out = []
    for kind in kinds:
        for camera in cameras:
            for seed in seeds:
                seq = make_sequence(kind, n_frames=F, n_points=P, camera=camera, seed=seed,
                                    **options)
                out.append((f'{kind}_{camera}_{seed}', seq.W, seq.S))
    return out


def mocap_cases(names):
    """The data folder's sequences ``names`` that exist (a line for each one missing)."""
    out = []
    for name in names:
        loaded = common.load_dataset(name)
        if loaded is None:
            print(f'{name}: data not found, skipped')
            continue
        out.append((name, loaded[0], loaded[1]))
    return out


def face_cases(seeds, F=99, P=2000):
    """Dense Surrey-model faces ``face_FxP_seed`` (none without the face model)."""
    out = []
    for seed in seeds:
        loaded = common.dense_face(F, P, seed=seed)
        if loaded is None:
            print('dense faces: face model not found, skipped')
            return out
        out.append((f'face{F}x{P}_{seed}', *loaded))
    return out


def noisy(cases, r, seed=1000):
    """``cases`` with the paper's noise ratio ``r`` added to W (``name_r``)."""
    rng = np.random.default_rng(seed)
    return [(f'{name}_r{r:g}', common.add_noise(W, r, rng), S) for name, W, S in cases]


def solve(setting, W, init=None):
    """The result of one setting on ``W`` (from the WarmStart ``init`` where given)."""
    if callable(setting):
        return setting(W)
    solver = GrassmannNRSfM(**setting)
    return solver.fit(W) if init is None else solver.fit(W, init=init)


def table(cases, settings, metric='e3d', init=None, extra=None):
    """Print e3D per case (rows) and setting (columns); return ``{(case, label): e3D}``.
    ``init(name) -> WarmStart`` starts each solve of case ``name`` from it; ``extra(report)``
    adds a short figure of the solver's report to each cell."""
    score = e3d_akhter if metric == 'akhter' else e3d
    labels = [label for label, _ in settings]
    width = 26 if extra else 20
    print(f'{"case":28s} ' + ' '.join(f'{label:>{width}s}' for label in labels))
    out = {}
    for name, W, S in cases:
        cells = []
        for label, setting in settings:
            start = time.process_time()
            result = solve(setting, W, None if init is None else init(name))
            out[name, label] = float(score(result.S, S))
            cell = (f'{out[name, label]:.4f} {result.report.iterations:3d}it '
                    f'{time.process_time() - start:5.1f}s')
            cells.append((cell + (f' {extra(result.report)}' if extra else '')).rjust(width))
        print(f'{name:28s} ' + ' '.join(cells), flush=True)
    if cases and len(labels) > 1:
        first = labels[0]
        means = [np.exp(np.mean([np.log(out[name, label] / out[name, first])
                                 for name, _, _ in cases])) for label in labels]
        print(f'{"geometric mean / " + first:28s} '
              + ' '.join(f'{m:{width}.3f}' for m in means))
    return out
