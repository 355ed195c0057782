"""Noise: e3D against the noise ratio r (sigma = r * max|centred W|, the paper's definition),
mean and spread over repeats (10 in --full, as in the paper; 2 in the quick run), for ours and
the baselines on one sequence (the dense face where the model exists, else synthetic bending).
"""
import numpy as np

from grass_nrsfm_ros.nrsfm.metrics import e3d
from . import common, plot
from .published import PUBLISHED_NOISE_SDG

METHODS = ('ours', 'rigid', 'bmm', 'pta')


def run(mode):
    name, (W, S) = common.study_sequence(mode)
    ratios = mode.pick((0.03,), (0.0, 0.01, 0.03, 0.05), (0.0, 0.01, 0.02, 0.03, 0.04, 0.05))
    repeats = mode.pick(1, 2, 10)
    rows, skipped = [], []
    for method in METHODS:
        for r in ratios:
            errs, cpus = [], []
            for rep in range(repeats if r > 0 else 1):
                Wn = common.add_noise(W, r, np.random.default_rng(1000 + rep))
                common.log(f'noise: {name} {method} r={r} repeat {rep}')
                try:
                    out, _, cpu = common.timed(common.solve, method, Wn)
                except Exception as exc:
                    skipped.append({'method': method, 'r': r, 'repeat': rep,
                                    'why': f'{type(exc).__name__}: {exc}'})
                    continue
                errs.append(e3d(out['S'], S))
                cpus.append(cpu)
            if errs:
                rows.append({'sequence': name, 'method': method, 'r': r, 'repeats': len(errs),
                             'e3d_mean': float(np.mean(errs)), 'e3d_std': float(np.std(errs)),
                             'e3d_min': float(np.min(errs)), 'e3d_max': float(np.max(errs)),
                             'seconds_cpu_mean': float(np.mean(cpus)), 'e3d_all': errs})
    plots = []
    if mode.name != 'smoke':
        series = {m: ([r['r'] for r in rows if r['method'] == m],
                      [r['e3d_mean'] for r in rows if r['method'] == m]) for m in METHODS}
        path = plot.line_plot(mode.out_dir / 'noise.png', series, title=f'e3D vs noise, {name}',
                              xlabel='noise r (sigma = r max|W|, pixels)',
                              ylabel='e3D (relative 3D error)')
        plots = [path.name] if path else []
    return {'sequence': name, 'F': W.shape[0] // 2, 'P': W.shape[1], 'rows': rows,
            'skipped': skipped, 'plots': plots,
            'published_sdg_mean_of_4_garg_faces': PUBLISHED_NOISE_SDG}
