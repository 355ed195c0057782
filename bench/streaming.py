"""Streaming: the sliding windows' output (no ROS), window 30 / stride 10 (the defaults).

The pipeline is :func:`~grass_nrsfm_ros.pipeline.reconstruct_live` over an inline
LivePipeline, and the output measured is ``points/refined`` with ``refined_from:
first_window``: each frame once, from the first window that solves it (the sliding windows).

* accuracy: e3D of those clouds against the whole-sequence solve and against rigid
  factorisation per window (published the same way), on dense faces (60 and 99 frames;
  skipped without the face model), the synthetic kinds and the mocap sets of the data folder
  (quick: the 60-frame face, bending and pickup's first 120 frames);
* warm start: the default ('resume': the previous window's solution resumed) against 'model'
  (the previous solution's spatial groups and rotation method carried); iterations and CPU
  seconds per window (windows after the first, the whole ``Mapper.solve``);
* throughput: frames per second sustained and window latency for 1k, 10k and 30k tracks.

Frames are fed as fast as the pipeline takes them, on one thread, with no window skipped (the
inline backend solves each window as it closes, inside ``add_frame``): ``fps = frames refined
/ time in add_frame, refined and flush`` (the per-frame tracking included); a window's latency
is from the moment it closed (``Update.closed_at``) to its Update being taken. The solver is
GrassmannNRSfM (recorded in the JSON as 'ours').
"""
import functools
import time
from types import SimpleNamespace

import numpy as np

from grass_nrsfm_ros.nrsfm import GrassmannNRSfM
from grass_nrsfm_ros.nrsfm.metrics import e3d
from grass_nrsfm_ros.nrsfm.synthetic import kinds
from grass_nrsfm_ros.params import defaults
from grass_nrsfm_ros.pipeline import make_pipeline, reconstruct_live
from . import common, plot

PIXELS_PER_UNIT = 200.0
WINDOW, STRIDE = 30, 10
#: the streaming variants compared (``warm_start``): the default and the other
VARIANTS = (('resume', {}), ('model', {'warm_start': 'model'}))


class RigidSolver:
    """``fit(W, init=None)`` by rigid factorisation (ignores ``init``): the per-window
    reference."""

    def fit(self, W, init=None):
        out = common.solve('rigid', W)
        return SimpleNamespace(S=out['S'], R=out['R'], groups=None, report=None)


class Counting:
    """A solver factory that records ``(iterations, CPU seconds)`` of each fit; the solver is
    otherwise the factory's own (its parameters and ``fit``'s keywords, which the mapper
    reads, unchanged)."""

    def __init__(self, factory):
        self.factory, self.fits = factory, []

    def __call__(self):
        solver, fits = self.factory(), self.fits
        fit = solver.fit

        @functools.wraps(fit)
        def counted(W, *args, **kwargs):
            start = time.process_time()
            result = fit(W, *args, **kwargs)
            fits.append((getattr(result.report, 'iterations', 0),
                         time.process_time() - start))
            return result
        solver.fit = counted
        return solver


def timed_solves(mapper):
    """``cpu``, a list that fills with the CPU seconds of each ``mapper.solve`` that solved
    (``mapper.solve`` wrapped in place)."""
    solve, cpu = mapper.solve, []

    def timed(window, progress=None):
        start = time.process_time()
        update = solve(window, progress)
        if update.kind == 'solved':
            cpu.append(time.process_time() - start)
        return update
    mapper.solve = timed
    return cpu


def sliding_pipeline(factory, **options):
    """An inline LivePipeline with the defaults, window WINDOW / STRIDE, ``refined_from:
    first_window`` and ``options`` (parameters), solving with ``factory``."""
    return make_pipeline({**defaults(), 'window_size': WINDOW, 'window_stride': STRIDE,
                          'refined_from': 'first_window', **options}, factory)


def streamed(W, factory, **options):
    """Run ``W: (2F, P)`` through :func:`sliding_pipeline`; ``(S: (3F, P) as refined,
    CPU seconds of each Mapper.solve that solved)``."""
    F, P = W.shape[0] // 2, W.shape[1]
    ids = np.arange(P, dtype=np.uint32)
    pipe = sliding_pipeline(factory, **options)
    solve_cpu = timed_solves(pipe.backend.mapper)
    _, results, _ = reconstruct_live(pipe, np.arange(F), [(ids, W[2 * f:2 * f + 2].T)
                                                          for f in range(F)])
    assert [r.stamp_ns for r in results] == list(range(F)), 'every frame refined once'
    return np.vstack([r.xyz.T for r in results]), solve_cpu


def per_window(fits, solve_cpu):
    """Mean solver iterations and CPU seconds of ``Mapper.solve`` (rotations included) of the
    windows after the first."""
    later = fits[1:] or fits
    return float(np.mean([f[0] for f in later])), float(np.mean(solve_cpu[1:] or solve_cpu))


def compare(name, W, S, factory):
    """One accuracy row: whole vs streamed (each warm-start variant) vs rigid per window, with
    iterations and CPU seconds per window."""
    whole, wall, cpu = common.timed(factory().fit, W)
    row = {'sequence': name, 'F': W.shape[0] // 2, 'P': W.shape[1],
           'e3d_whole': e3d(whole.S, S), 'whole_cpu_s': cpu}
    for label, options in VARIANTS:
        counting = Counting(factory)
        S_stream, solve_cpu = streamed(W, counting, **options)
        iterations, seconds = per_window(counting.fits, solve_cpu)
        row.update({f'e3d_stream_{label}': e3d(S_stream, S), f'iterations_{label}': iterations,
                    f'cpu_per_window_{label}_s': seconds})
    row['e3d_rigid_per_window'] = e3d(streamed(W, RigidSolver, context_frames=0)[0], S)
    row['windows'] = len(counting.fits)
    common.log(f"{name:>16} F={row['F']:4d} P={row['P']:5d}  e3D whole {row['e3d_whole']:.4f}"
               f"  rigid/window {row['e3d_rigid_per_window']:.4f}  streamed (e3D, iterations, "
               'CPU s per window) ' + ', '.join(
                   f"{label} {row[f'e3d_stream_{label}']:.4f} "
                   f"{row[f'iterations_{label}']:.0f} {row[f'cpu_per_window_{label}_s']:.2f}"
                   for label, _ in VARIANTS))
    return row


def accuracy_sequences(mode):
    """``[(name, W, S)]`` for the accuracy comparison: dense faces, synthetic kinds and mocap
    sets; the quick run's one mocap set is cut to its first 120 frames (named 'pickup120')."""
    out = []
    faces = mode.pick((), ((60, 3000),), ((60, 3000), (99, 3000)))
    for F, P in faces:
        face = common.dense_face(F, P)
        if face is not None:
            out.append((f'face{F}x{P}', *face))
    for kind in mode.pick(('bending',), ('bending',), kinds()):
        F = mode.pick(35, 60, 60)
        out.append((f'{kind}{F}', *common.synthetic(kind, F, mode.pick(300, 1000, 1000))))
    frames = mode.pick(None, 120, None)
    for name in mode.pick((), ('pickup',),
                          [k for k, (_, fam) in common.DATASETS.items() if fam == 'mocap']):
        data = common.load_dataset(name)
        if data is not None and frames:
            out.append((f'{name}{frames}', data[0][:2 * frames], data[1][:3 * frames]))
        elif data is not None:
            out.append((name, data[0], data[1]))
    return out


def stream(P, n_frames, window_size, stride, factory):
    W, _ = common.synthetic('bending', n_frames, P)
    W = PIXELS_PER_UNIT * W + 320.0
    ids = np.arange(P, dtype=np.uint32)
    pipe = make_pipeline({**defaults(), 'window_size': window_size, 'window_stride': stride,
                          'min_tracks': 10, 'refined_from': 'first_window'}, factory)
    busy, latencies, solve_s, published = 0.0, [], [], 0
    for f in range(n_frames):
        t = time.monotonic()
        pipe.add_frame(1_000_000 * (f + 1), ids, W[2 * f:2 * f + 2].T)
        if f == n_frames - 1:
            pipe.flush()
        refined, updates = pipe.refined()
        done = time.monotonic()
        busy += done - t
        published += len(refined)
        for update in updates:
            solve_s.append(update.figures.get('solve_seconds', 0.0))
            latencies.append(done - update.closed_at)
    row = {'P': P, 'frames': n_frames, 'window_size': window_size, 'window_stride': stride,
           'windows': len(latencies), 'frames_published': published,
           'fps': published / busy if busy > 0 else None,
           'latency_mean_s': float(np.mean(latencies)),
           'latency_max_s': float(np.max(latencies)),
           'latency_steady_s': float(np.mean(latencies[1:] or latencies)),
           'solve_mean_s': float(np.mean(solve_s)),
           'stats': {**pipe.windowing.stats, **pipe.refinement.stats}}
    common.log(f"{P:>6} tracks: {row['fps']:.2f} frames/s sustained, window latency mean "
               f"{row['latency_mean_s']:.2f} s (first {latencies[0]:.2f}, later "
               f"{row['latency_steady_s']:.2f}, max {row['latency_max_s']:.2f})")
    return row


def run(mode):
    factory, solver = GrassmannNRSfM, 'ours'
    rows, skipped, accuracy = [], [], []
    for name, W, S in accuracy_sequences(mode):
        try:
            accuracy.append(compare(name, W, S, factory))
        except Exception as exc:
            skipped.append({'sequence': name, 'why': f'{type(exc).__name__}: {exc}'})
    tracks = mode.pick((1000,), (1000, 10000), (1000, 10000, 30000))
    n_frames, window, stride = mode.pick((15, 10, 5), (50, WINDOW, STRIDE),
                                         (90, WINDOW, STRIDE))
    for P in tracks:
        common.log(f'streaming: {P} tracks, {n_frames} frames, window {window}/{stride}')
        try:
            rows.append({'solver': solver, **stream(P, n_frames, window, stride, factory)})
        except Exception as exc:
            skipped.append({'P': P, 'why': f'{type(exc).__name__}: {exc}'})
    out = {'solver': solver, 'rows': rows, 'accuracy': accuracy, 'skipped': skipped}
    if mode.name != 'smoke' and rows:
        series = {solver: ([r['P'] for r in rows], [r['fps'] for r in rows])}
        path = plot.line_plot(mode.out_dir / 'streaming_fps.png', series,
                              title='sustained rate vs tracks', xlabel='tracks P',
                              ylabel='sustained rate (frames/s)', logy=True, logx=True)
        out['plots'] = [path.name] if path else []
    return out
