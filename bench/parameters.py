"""Parameters: e3D of ours against N_s and K_s, the ablation none / spatial / temporal / both,
and the structure the solver ends with (spatial group sizes, temporal blocks, and the
self-expression coefficients C_s / C_t as images where the result exposes them).
"""
import numpy as np

from grass_nrsfm_ros.nrsfm.metrics import e3d
from . import common, plot

ABLATION = {'none': dict(spatial=False, temporal=False), 'spatial': dict(spatial=True,
            temporal=False), 'temporal': dict(spatial=False, temporal=True),
            'both': dict(spatial=True, temporal=True)}


def coefficient_images(result, out_dir, tag):
    """Save ``C_s`` / ``C_t`` (if the result or its report carries them) as PNGs."""
    saved = {}
    for key in ('C_s', 'C_t'):
        M = getattr(result, key, None)
        if M is None:
            M = getattr(getattr(result, 'report', None), key, None)
        if M is None:
            continue
        M = np.asarray(M)
        if M.ndim == 2 and min(M.shape) > 0:
            path = plot.matrix_image(out_dir / f'parameters_{tag}_{key}.png', M,
                                     scale=max(1, 400 // max(M.shape)))
            saved[key] = {'shape': list(M.shape), 'png': path.name}
    return saved


def structure(result):
    groups = np.asarray(getattr(result, 'groups', np.zeros(0)))
    blocks = getattr(result, 'blocks', None)
    sizes = np.bincount(groups) if groups.size and groups.min() >= 0 else np.zeros(0)
    return {'n_groups': int((sizes > 0).sum()), 'group_sizes': sorted(sizes[sizes > 0].tolist()),
            'temporal_blocks': None if blocks is None else np.asarray(blocks).tolist()}


def run(mode):
    name, (W, S) = common.study_sequence(mode)
    sweeps = {'N_s': mode.pick((2,), (2, 3, 5), (1, 2, 3, 4, 5, 6, 8)),
              'K_s': mode.pick((2,), (1, 2, 4, 8), (1, 2, 4, 8, 16, 32))}
    settings = [(k, v, {k: v}) for k, values in sweeps.items() for v in values]
    ablation = mode.pick(('none', 'both'), tuple(ABLATION), tuple(ABLATION))
    settings += [('ablation', a, ABLATION[a]) for a in ablation]
    rows, skipped = [], []
    mode.out_dir.mkdir(parents=True, exist_ok=True)
    for param, value, kwargs in settings:
        common.log(f'parameters: {name} {param}={value}')
        try:
            out, wall, cpu = common.timed(common.solve, 'ours', W, params=kwargs)
        except Exception as exc:
            skipped.append({'param': param, 'value': value, 'why': f'{type(exc).__name__}: {exc}'})
            continue
        row = {'sequence': name, 'param': param, 'value': value, 'e3d': e3d(out['S'], S),
               'seconds_wall': wall, 'seconds_cpu': cpu,
               'report': common.report_summary(out['report']), **structure(out['result'])}
        if param == 'ablation':
            row['coefficients'] = coefficient_images(out['result'], mode.out_dir, value)
        rows.append(row)
    plots = []
    if mode.name != 'smoke':
        for param in sweeps:
            sel = [r for r in rows if r['param'] == param]
            path = plot.line_plot(mode.out_dir / f'parameters_{param}.png',
                                  {'ours': ([r['value'] for r in sel], [r['e3d'] for r in sel])},
                                  title=f'e3D vs {param}, {name}', xlabel=param, ylabel='e3D')
            if path:
                plots.append(path.name)
    return {'sequence': name, 'F': W.shape[0] // 2, 'P': W.shape[1], 'rows': rows,
            'skipped': skipped, 'plots': plots}
