"""Scale: solve time (wall and CPU) and peak memory against P (at F=30 and F=100) and against F,
for ours and the baselines, each case in its own process; the growth exponents (log-log least
squares); and for ours the time per ADMM iteration over the time of one economy SVD of S# of the
same size.
"""
import argparse
import json
from pathlib import Path
import subprocess
import sys
import tempfile

import numpy as np

from . import common, plot

METHODS = ('ours', 'rigid', 'bmm', 'pta')


def grid(mode):
    """``[(sweep, F, P)]``: P sweeps at fixed F, then an F sweep at fixed P."""
    if mode.name == 'smoke':
        return [('P', 10, 500)]
    p_values = mode.pick(None, (1000, 3000, 10000), (1000, 3000, 10000, 30000, 70000))
    f_fixed = mode.pick(None, (30,), (30, 100))
    f_values = mode.pick(None, (10, 30, 60), (10, 30, 60, 100, 200))
    p_fixed = mode.pick(None, 1000, 3000)
    return ([('P', F, P) for F in f_fixed for P in p_values]
            + [('F', F, p_fixed) for F in f_values])


def run_worker(W_path, method, timeout):
    cmd = [sys.executable, '-m', 'bench.scale_worker', str(W_path), method]
    try:
        proc = subprocess.run(cmd, cwd=common.REPO, capture_output=True, text=True,
                              timeout=timeout)
    except subprocess.TimeoutExpired:
        return None, f'timed out after {timeout} s'
    if proc.returncode != 0:
        return None, (proc.stderr.strip().splitlines() or ['failed'])[-1]
    return json.loads(proc.stdout.strip().splitlines()[-1]), None


def cpu_per_iteration(row):
    """CPU seconds per ADMM iteration: the solve's CPU time times the shape step's share of the
    wall time, over the iterations (None for methods without iterations)."""
    it = row.get('iterations')
    if not it or row.get('seconds_shape') is None:
        return None
    return row['seconds_cpu'] * row['seconds_shape'] / max(row['seconds_wall'], 1e-9) / it


def exponents(rows):
    """Growth exponents of CPU time and of extra memory: per method, per sweep and fixed size."""
    out = []
    keys = sorted({(r['method'], r['sweep'], r['F'] if r['sweep'] == 'P' else r['P'])
                   for r in rows})
    for method, sweep, fixed in keys:
        sel = [r for r in rows if r['method'] == method and r['sweep'] == sweep
               and (r['F'] if sweep == 'P' else r['P']) == fixed]
        x = [r[sweep] for r in sel]
        out.append({'method': method, 'against': sweep,
                    'fixed': {'F' if sweep == 'P' else 'P': fixed}, 'points': len(sel),
                    'time_exponent': common.loglog_slope(x, [r['seconds_cpu'] for r in sel]),
                    'iteration_time_exponent': common.loglog_slope(
                        x, [cpu_per_iteration(r) or np.nan for r in sel]),
                    'memory_exponent': common.loglog_slope(
                        x, [r['solve_extra_mb'] for r in sel])})
    return out


def plots(rows, out_dir):
    names = []
    for sweep, fixed_key in (('P', 'F'), ('F', 'P')):
        for fixed in sorted({r[fixed_key] for r in rows if r['sweep'] == sweep}):
            sel = [r for r in rows if r['sweep'] == sweep and r[fixed_key] == fixed]
            for what, key, logy in (('time', 'seconds_cpu', True),
                                    ('memory', 'solve_extra_mb', False)):
                series = {m: ([r[sweep] for r in sel if r['method'] == m],
                              [r[key] for r in sel if r['method'] == m]) for m in METHODS}
                path = plot.line_plot(
                    out_dir / f'scale_{what}_vs_{sweep}_{fixed_key}{fixed}.png', series,
                    title=f'{what} vs {sweep} ({fixed_key}={fixed})',
                    xlabel={'F': 'frames F', 'P': 'tracks P'}.get(sweep, sweep),
                    ylabel='CPU time (s)' if what == 'time' else 'extra peak RSS (MiB)',
                    logy=logy, logx=True)
                if path:
                    names.append(path.name)
    return names


def run_cases(cases, methods, timeout):
    """Solve each ``(sweep, F, P)`` case with each method in a fresh process; returns
    ``(rows, skipped)``."""
    rows, skipped = [], []
    with tempfile.TemporaryDirectory(prefix='bench_scale_') as tmp:
        for sweep, F, P in cases:
            W, _ = common.synthetic('bending', F, P)
            W_path = Path(tmp) / f'W_{F}_{P}.npy'
            np.save(W_path, W)
            del W
            for method in methods:
                common.log(f'scale: F={F} P={P} {method}')
                row, why = run_worker(W_path, method, timeout)
                if row is None:
                    skipped.append({'method': method, 'F': F, 'P': P, 'why': why})
                else:
                    rows.append({'sweep': sweep, **row})
    return rows, skipped


NOTES = ['each case runs in a fresh process; solve_extra_mb = peak RSS after the solve minus '
         'peak RSS after loading W (0 when the solve stays below it)',
         'iteration_over_svd: wall seconds per ADMM iteration / wall seconds of one economy SVD '
         'of the F x 3P matrix S# (best of 3); iteration_over_svd_cpu: the same in CPU seconds '
         '(the solve CPU time scaled by its shape-step share of the wall time)']


def run(mode):
    timeout = mode.pick(120, 300, 1800)
    rows, skipped = run_cases(grid(mode), METHODS, timeout)
    out = {'rows': rows, 'skipped': skipped, 'exponents': exponents(rows),
           'notes': NOTES}
    if mode.name != 'smoke':
        out['plots'] = plots(rows, mode.out_dir)
    return out


def table(rows, exps):
    """Markdown table of the rows and the P exponents."""
    lines = ['| method | F | P | iters | CPU s | wall s | peak MB | extra MB | CPU s/iter | '
             'SVD(S#) s | iter/SVD (wall) | iter/SVD (CPU) |', '|' + '---|' * 12]
    for r in rows:
        it = r.get('iterations')
        per_it = cpu_per_iteration(r)

        def fmt(x, f='{:.2f}'):
            return '' if x is None else f.format(x)
        lines.append(f"| {r['method']} | {r['F']} | {r['P']} | {fmt(it, '{}')} | "
                     f"{r['seconds_cpu']:.1f} | {r['seconds_wall']:.1f} | "
                     f"{r['rss_peak_mb']:.0f} | {r['solve_extra_mb']:.0f} | "
                     f"{fmt(per_it, '{:.3f}')} | "
                     f"{fmt(r.get('svd_S_sharp_seconds'), '{:.3f}')} | "
                     f"{fmt(r.get('iteration_over_svd'), '{:.2f}')} | "
                     f"{fmt(r.get('iteration_over_svd_cpu'), '{:.2f}')} |")
    for e in exps:
        it_exp = e.get('iteration_time_exponent')
        lines.append(f"\n{e['method']}: against {e['against']} at {e['fixed']}: time exponent "
                     f"{e['time_exponent']:.2f} (per iteration "
                     f"{float('nan') if it_exp is None else it_exp:.2f}), memory exponent "
                     f"{(e['memory_exponent'] or float('nan')):.2f} ({e['points']} points)")
    return '\n'.join(lines)


def main(argv=None):
    """``python -m bench.scale [--methods ours] [--P 1000 10000 ...] [--F 30 100]
    [--rows JSON]``: the P sweeps only, written to ``<out>/scale_sweep.json`` and printed as a
    table (``--rows``: re-print the table of an earlier result without solving)."""
    parser = argparse.ArgumentParser(prog='python -m bench.scale', description=main.__doc__)
    parser.add_argument('--methods', nargs='+', default=['ours'], choices=METHODS)
    parser.add_argument('--P', nargs='+', type=int, default=[1000, 10000, 30000, 70000])
    parser.add_argument('--F', nargs='+', type=int, default=[30, 100])
    parser.add_argument('--timeout', type=int, default=1800)
    parser.add_argument('--out', help='results folder (default bench/results)')
    parser.add_argument('--rows', help='an earlier scale_sweep.json to re-print')
    args = parser.parse_args(argv)
    if args.rows:
        rows = json.loads(Path(args.rows).read_text())['rows']
        print(table(rows, exponents(rows)))
        return 0
    cases = [('P', F, P) for F in args.F for P in args.P]
    rows, skipped = run_cases(cases, args.methods, args.timeout)
    exps = exponents(rows)
    mode = common.Mode('full', args.out)
    path = common.write_result(mode, 'scale_sweep', {'rows': rows, 'skipped': skipped,
                                                     'exponents': exps, 'notes': NOTES})
    print(table(rows, exps))
    print(f'-> {path}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
