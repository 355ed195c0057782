"""Streaming: frames per second sustained and window latency through pipeline.SlidingWindow (no
ROS) for 1k, 10k and 30k tracks (quick: 1k and 10k). The solver is ours where it exists, else
the rigid factorisation (recorded in the JSON), so the pipeline's own overhead is measured too.

Frames are fed as fast as the pipeline takes them, on one thread, with no window skipped:
``fps = frames published / (time in add_frame + solve)``; a window's latency is from the moment
it closed (``Window.closed_at``) to the end of its solve.
"""
import time
from types import SimpleNamespace

import numpy as np

from . import common, plot

PIXELS_PER_UNIT = 200.0


class RigidSolver:
    """``fit(W, init=None)`` by rigid factorisation, for when the ADMM solver is absent."""

    def fit(self, W, init=None):
        out = common.solve('rigid', W)
        return SimpleNamespace(S=out['S'], R=out['R'], groups=None, report=None)


def solver_factory():
    """``(factory, name)`` or ``(None, why)``."""
    if not common.missing('ours'):
        from grass_nrsfm_ros.pipeline import default_solver_factory
        return default_solver_factory(), 'ours'
    if not common.missing('rigid'):
        return RigidSolver, 'rigid (GrassmannNRSfM not available)'
    return None, common.missing('rigid')


def stream(P, n_frames, window_size, stride, factory):
    from grass_nrsfm_ros.pipeline import SlidingWindow

    W, _ = common.synthetic('bending', n_frames, P)
    W = PIXELS_PER_UNIT * W + 320.0
    ids = np.arange(P, dtype=np.uint32)
    pipe = SlidingWindow(factory, window_size=window_size, window_stride=stride,
                         min_tracks=10)
    busy, latencies, solve_s, published = 0.0, [], [], 0
    for f in range(n_frames):
        t = time.monotonic()
        windows = pipe.add_frame(1_000_000 * (f + 1), ids, W[2 * f:2 * f + 2].T)
        busy += time.monotonic() - t
        for window in windows + (pipe.flush() if f == n_frames - 1 else []):
            t = time.monotonic()
            published += len(pipe.solve(window))
            done = time.monotonic()
            busy += done - t
            solve_s.append(done - t)
            latencies.append(done - window.closed_at)
    return {'P': P, 'frames': n_frames, 'window_size': window_size, 'window_stride': stride,
            'windows': len(latencies), 'frames_published': published,
            'fps': published / busy if busy > 0 else None,
            'latency_mean_s': float(np.mean(latencies)), 'latency_max_s': float(np.max(latencies)),
            'solve_mean_s': float(np.mean(solve_s)), 'stats': dict(pipe.stats)}


def run(mode):
    try:
        import grass_nrsfm_ros.pipeline  # noqa: F401
    except ImportError as exc:
        why = f'grass_nrsfm_ros.pipeline not available ({exc})'
        return {'rows': [], 'skipped': [{'why': why}]}
    factory, solver = solver_factory()
    if factory is None:
        return {'rows': [], 'skipped': [{'why': solver}]}
    tracks = mode.pick((1000,), (1000, 10000), (1000, 10000, 30000))
    n_frames, window, stride = mode.pick((15, 10, 5), (50, 30, 10), (90, 30, 10))
    rows, skipped = [], []
    for P in tracks:
        common.log(f'streaming: {P} tracks, {n_frames} frames, window {window}/{stride}')
        try:
            rows.append({'solver': solver, **stream(P, n_frames, window, stride, factory)})
        except Exception as exc:
            skipped.append({'P': P, 'why': f'{type(exc).__name__}: {exc}'})
    out = {'solver': solver, 'rows': rows, 'skipped': skipped}
    if mode.name != 'smoke' and rows:
        series = {solver: ([np.log10(r['P']) for r in rows], [r['fps'] for r in rows])}
        path = plot.line_plot(mode.out_dir / 'streaming_fps.png', series,
                              title='sustained fps vs tracks', xlabel='log10 tracks',
                              ylabel='frames/s', logy=True)
        out['plots'] = [path.name] if path else []
    return out
