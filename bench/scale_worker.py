"""One scale case in a fresh process (clean peak memory): ``python -m bench.scale_worker
W.npy METHOD`` prints one JSON line with wall/CPU seconds, peak resident memory before and after
the solve, and for 'ours' the time per ADMM iteration against one economy SVD of S# (F x 3P).
"""
import json
import resource
import sys
import time

import numpy as np

from grass_nrsfm_ros.nrsfm.measurement import as_frames, to_world
from . import common


def maxrss_mb():
    """Peak resident set size of this process so far, MiB (Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def svd_seconds(X, repeats=3):
    """Best of ``repeats`` (wall, CPU) times of ``np.linalg.svd(X, full_matrices=False)``."""
    best, best_cpu = np.inf, np.inf
    for _ in range(repeats):
        t, c = time.perf_counter(), time.process_time()
        np.linalg.svd(X, full_matrices=False)
        best = min(best, time.perf_counter() - t)
        best_cpu = min(best_cpu, time.process_time() - c)
    return best, best_cpu


def main(argv):
    path, method = argv
    W = np.load(path)
    F, P = W.shape[0] // 2, W.shape[1]
    before = maxrss_mb()
    # the low-rank chain's scaling: surface='auto' would take this clean sheet for a sheet
    # (record 0738) and solve it by the sheet model instead
    params = {'surface': 'any'} if method == 'ours' else None
    out, wall, cpu = common.timed(common.solve, method, W, params=params)
    row = {'method': method, 'F': F, 'P': P, 'seconds_wall': wall, 'seconds_cpu': cpu,
           'rss_before_mb': before, 'rss_peak_mb': maxrss_mb(), 'W_mb': W.nbytes / 2 ** 20}
    row['solve_extra_mb'] = max(0.0, row['rss_peak_mb'] - before)
    if method == 'ours':
        report = out['report']
        shape_s = (report.seconds or {}).get('shape', wall)
        iters = max(int(report.iterations), 1)
        S_sharp = as_frames(to_world(out['R'], out['S']), 3).reshape(F, 3 * P)
        svd, svd_cpu = svd_seconds(S_sharp)
        shape_cpu = cpu * shape_s / max(wall, 1e-9)
        row.update({'iterations': report.iterations, 'seconds_shape': shape_s,
                    'seconds_per_iteration': shape_s / iters, 'svd_S_sharp_seconds': svd,
                    'svd_S_sharp_cpu_seconds': svd_cpu,
                    'iteration_over_svd': shape_s / iters / svd,
                    'iteration_over_svd_cpu': shape_cpu / iters / svd_cpu,
                    'report': common.report_summary(report)})
    print(json.dumps(common.jsonable(row)))
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
