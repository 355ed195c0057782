"""Live output (tracking on arrival, windows refining behind it) against the sliding windows.

* offline accuracy (no ROS): the streaming bench's sequences plus, with ``--full``, a 300-frame
  slow face (its head turn spans the whole sequence), run through
  :func:`~grass_nrsfm_ros.pipeline.reconstruct_live` (each window solved inline as it
  closes): e3D of ``points`` (every frame as tracked on arrival, the bootstrap frames
  included) and of ``points/refined``, against the sliding windows (``points/refined`` with
  ``refined_from: first_window``, every track solved, the 'model' warm start); mapping CPU
  seconds per window (``Mapper.solve``, after the first, and from the third: resumed), frames
  before the first model; and a causal reference: frame t of one solve of every frame up to t
  (what re-solving the whole past at every frame would publish), at every frame t of the
  start-up (before the first model) and 10 later ones, against the points and windows on those
  frames;
* the node (``--node``): the slow face at 30 Hz over DDS into the node as shipped, optionally
  with the other core busy: frames back, latency from sending a frame's tracks to receiving
  its cloud (p50 / p95 / max), e3D of the received clouds on all frames; ``--frames`` for a
  longer face (3600: 2 minutes at 30 Hz);
* ``--offline``: the same pipeline offline on the node run's input (``--points``,
  ``--frames``), the e3D the node's is compared with, added to that run's entry.

    python -m bench --only live [--full]
    python -m bench.live --node [--points 10000] [--frames 300] [--busy] [--mapping process]
    python -m bench.live --offline --points 30000 --frames 3600

Results: ``bench/results/live.json`` (suite) and ``live_node.json`` (``--node``; keyed by
points, ``x<frames>f`` unless 300, ``_busy``, ``_<mapping>`` when ``--mapping`` is given, and
``_<kernel>`` where OPENBLAS_CORETYPE sets the BLAS kernel).
"""
import argparse
import json
import multiprocessing
import os
from pathlib import Path
import random
import sys
import tempfile
import time

import numpy as np

from grass_nrsfm_ros import cloud
from grass_nrsfm_ros.mapper import make_mapper
from grass_nrsfm_ros.nrsfm import GrassmannNRSfM
from grass_nrsfm_ros.nrsfm.faces import make_face_sequence
from grass_nrsfm_ros.nrsfm.measurement import as_frames, frame_rows
from grass_nrsfm_ros.nrsfm.metrics import e3d
from grass_nrsfm_ros.params import defaults, MAPPINGS, MIN_WINDOW_FRAMES, WINDOW_KEYS
from grass_nrsfm_ros.pipeline import live_events, make_pipeline, reconstruct_live
from grass_nrsfm_ros.windowing import Windowing
from . import common
from .streaming import accuracy_sequences, timed_solves

SLOW_FACE = 'slow_face300'
#: frames after the first model the causal reference (a solve of the whole past) is computed at
CAUSAL_SAMPLES = 10
#: the windows the live output is compared with: the sliding windows before #21 (every track
#: solved, the 'model' warm start)
BASELINE_WARM_START = 'model'
NODE_LAUNCH = 'import sys; from grass_nrsfm_ros.node import main; sys.exit(main())'


NODE_RESULTS = common.RESULTS / 'live_node.json'


def slow_face(P, F=300):
    """``(W, S)`` of an ``F``-frame dense face whose head turn spans the whole sequence
    (pixels: the face's mm), or None without the face model."""
    try:
        seq = make_face_sequence(n_frames=F, n_points=P, seed=0)
    except FileNotFoundError:
        return None
    return seq.W, seq.S


def run_pipeline(W, mapping_tracks, **options):
    """``(points, refined, pipeline, mapping CPU seconds per window)`` of ``W: (2F, P)``
    through the default pipeline (inline, GrassmannNRSfM) with ``options`` (parameters, e.g.
    ``refined_from``, ``warm_start``) over the defaults: the CPU time of each
    ``Mapper.solve`` that solved (rotations, the solve, the next model), one BLAS thread as
    in the solver."""
    F, P = W.shape[0] // 2, W.shape[1]
    ids = np.arange(P, dtype=np.uint32)
    pipe, cpu = timed_pipeline(mapping_tracks, **options)
    points, refined, _ = reconstruct_live(pipe, np.arange(F),
                                          [(ids, uv.T) for uv in as_frames(W, 2)])
    assert [r.stamp_ns for r in points] == list(range(F)), 'every frame published once'
    assert [r.stamp_ns for r in refined] == list(range(F)), 'every frame refined once'
    return points, refined, pipe, cpu


def timed_pipeline(mapping_tracks, **options):
    """``(pipeline, cpu)``: the default pipeline (inline, GrassmannNRSfM) with ``options``
    over the defaults; ``cpu`` (a list) fills with the CPU seconds of each ``Mapper.solve``
    that solved."""
    pipe = make_pipeline({**defaults(), 'mapping_tracks': mapping_tracks, **options},
                         GrassmannNRSfM)
    return pipe, timed_solves(pipe.backend.mapper)


def stacked(results):
    return np.vstack([r.xyz.T for r in results])


def mean_or_none(values):
    return float(np.mean(values)) if len(values) else None


def geometric_mean(values):
    return float(np.exp(np.mean(np.log(values)))) if values else None


def causal_frames(F, first):
    """The frames ``t`` the causal reference is sampled at: every frame from
    MIN_WINDOW_FRAMES - 1 until ``first`` (the start-up, before the first model), then
    CAUSAL_SAMPLES spread evenly over the rest, the last frame included."""
    start = np.arange(MIN_WINDOW_FRAMES - 1, min(first, F))
    rest = np.unique(np.linspace(F - 1, first, CAUSAL_SAMPLES).astype(int)) if F > first \
        else np.zeros(0, dtype=int)
    return np.concatenate([start, rest])


def causal_reference(W, frames):
    """e3D-ready shapes ``(len(frames) * 3, P)``: for each frame ``t`` of ``frames``, frame
    t of one solve of every frame up to t (the windows' solver, every track, as a first
    window: no context). What a causal method that re-solved the whole past at every frame
    would publish for frame t."""
    P = W.shape[1]
    ids = np.arange(P, dtype=np.uint32)
    uv = as_frames(W, 2)
    config = defaults()
    out = []
    for t in frames:
        n = int(t) + 1
        windowing = Windowing(**{**{k: config[k] for k in WINDOW_KEYS}, 'window_size': n,
                                 'window_stride': min(n, config['window_stride'])})
        for f in range(n):
            closed = windowing.push(windowing.accept(f, ids, uv[f].T))
        update = make_mapper(config, GrassmannNRSfM).solve(closed[0])
        out.append(update.results[-1].xyz.T)
    return np.vstack(out)


def compare(name, W, S, mapping_tracks):
    """One row: live points / refined vs today's windows, mapping CPU per window."""
    points, refined, live, cpu = run_pipeline(W, mapping_tracks)
    _, windows, _, cpu_windows = run_pipeline(W, 0, refined_from='first_window',
                                              warm_start=BASELINE_WARM_START)
    per_frame = e3d(stacked(points), S, per_frame=True)
    windows_per_frame = e3d(stacked(windows), S, per_frame=True)
    first = live.tracking.stats['first_model_after']
    row = {'sequence': name, 'F': W.shape[0] // 2, 'P': W.shape[1],
           'e3d_points': float(per_frame.mean()),
           'e3d_points_after_first_model': float(per_frame[first:].mean()),
           'e3d_windows_after_first_model': float(windows_per_frame[first:].mean()),
           'e3d_refined': e3d(stacked(refined), S), 'e3d_windows': e3d(stacked(windows), S),
           'first_model_after_frames': first,
           'fresh_windows': live.tracking.stats['fresh_windows'],
           'tracking_ms_p50': 1e3 * live.latency_percentiles()[0],
           'tracking_ms_p95': 1e3 * live.latency_percentiles()[1],
           'mapping_cpu_per_window_s': float(np.mean(cpu[1:] or cpu)),
           'windows_cpu_per_window_s': float(np.mean(cpu_windows[1:] or cpu_windows)),
           'mapping_cpu_from_third_window_s': mean_or_none(cpu[2:]),
           'windows_cpu_from_third_window_s': mean_or_none(cpu_windows[2:])}
    startup = row['F'] if first is None else first
    at = causal_frames(row['F'], startup)
    causal = e3d(causal_reference(W, at), S[frame_rows(at, 3)], per_frame=True)
    early = at < startup
    row.update(causal_frames=at.tolist(), e3d_causal_per_frame=causal.tolist())
    for part, chosen in (('startup', early), ('later', ~early)):
        row.update({f'e3d_causal_{part}': mean_or_none(causal[chosen]),
                    f'e3d_points_{part}': mean_or_none(per_frame[at[chosen]]),
                    f'e3d_windows_{part}': mean_or_none(windows_per_frame[at[chosen]])})
    common.log(f"{name:>16} e3D points {row['e3d_points']:.4f} refined {row['e3d_refined']:.4f}"
               f" windows {row['e3d_windows']:.4f}  CPU/window "
               f"{row['mapping_cpu_per_window_s']:.2f} vs {row['windows_cpu_per_window_s']:.2f} s"
               f'  first model after {first};  start-up causal / points / windows '
               f"{row['e3d_causal_startup']:.4f} / {row['e3d_points_startup']:.4f} / "
               f"{row['e3d_windows_startup']:.4f}")
    return row


def cpu_ratio(row, suffix='_per_window_s'):
    """Mapping CPU per window over the windows' in ``row`` (None where either is missing)."""
    live, windows = row.get('mapping_cpu' + suffix), row.get('windows_cpu' + suffix)
    return live / windows if live is not None and windows else None


def run(mode):
    mapping_tracks = defaults()['mapping_tracks']
    sequences = accuracy_sequences(mode)
    points = mode.pick(None, None, 10000)       # the slow face: --full only (28 windows)
    face = slow_face(points) if points else None
    if face is not None:
        sequences.append((SLOW_FACE, *face))
    rows, skipped = [], []
    for name, W, S in sequences:
        try:
            rows.append(compare(name, W, S, mapping_tracks))
        except Exception as exc:
            skipped.append({'sequence': name, 'why': f'{type(exc).__name__}: {exc}'})
    kept = [r for r in rows if r['sequence'] != SLOW_FACE]
    ratios = [r['e3d_points'] / r['e3d_windows'] for r in kept]
    causal = [r['e3d_causal_startup'] / r['e3d_windows_startup'] for r in kept]
    summary = {'geometric_mean_points_over_windows': geometric_mean(ratios),
               'worst_points_over_windows': max(ratios) if ratios else None,
               'geometric_mean_startup_causal_over_windows': geometric_mean(causal),
               'best_startup_causal_over_windows': min(causal) if causal else None,
               'mapping_cpu_over_windows': {r['sequence']: cpu_ratio(r) for r in rows},
               'mapping_cpu_over_windows_from_third': {
                   r['sequence']: cpu_ratio(r, '_from_third_window_s') for r in rows}}
    return {'rows': rows, 'skipped': skipped, 'summary': summary,
            'mapping_tracks': mapping_tracks}


# -- the node over DDS ----------------------------------------------------------------------------
def busy_loop(stop):
    """Keep one core busy until ``stop`` is set (the 'other core busy' condition)."""
    x = 0.0
    while not stop.is_set():
        x = (x + 1.0) % 7.0


def node_run(points=10_000, rate=30.0, busy=False, extra_args=(), frames=300):
    """Feed the slow face (``frames`` frames) at ``rate`` Hz into the node; return the
    figures."""
    sys.path.insert(0, str(common.REPO / 'test'))
    tmp = Path(tempfile.mkdtemp(prefix='grass_live_'))
    os.environ.update({'ROS_DOMAIN_ID': str(random.randint(0, 101)),
                       'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
                       'ROS_LOG_DIR': str(tmp / 'log')})
    env = {**os.environ, 'PYTHONPATH': os.pathsep.join([str(common.REPO),
                                                        str(common.REPO / 'test')])}
    import rosutil
    from std_msgs.msg import Header

    W, S = slow_face(points, frames)
    F = W.shape[0] // 2
    ids = np.arange(points, dtype=np.uint32)
    t0 = 1_700_000_000_000_000_000
    period = 1.0 / rate
    messages = [cloud.encode_tracks(ids, uv.T, Header(frame_id='camera'))
                for uv in as_frames(W, 2)]
    for f, msg in enumerate(messages):
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(t0 + int(f * period * 1e9),
                                                                10 ** 9)
    stop = multiprocessing.Event()
    hog = multiprocessing.Process(target=busy_loop, args=(stop,), daemon=True) if busy else None
    if hog:
        hog.start()
    try:
        with rosutil.node_with_feeder(env, tmp / 'node.log', list(extra_args),
                                      launch=NODE_LAUNCH, points_depth=F) as (_, feeder):
            start = time.monotonic()
            for f, msg in enumerate(messages):
                time.sleep(max(0.0, start + f * period - time.monotonic()))
                feeder.publish(msg)
            feeder.wait_for(lambda: len(feeder.points) >= F, 30)
            received = {m.header.stamp.sec * 10 ** 9 + m.header.stamp.nanosec: m
                        for m in feeder.points}
            latencies = np.array(feeder.latencies)
            values = feeder.diagnostic_values()
    finally:
        stop.set()
        if hog:
            hog.join()
    stamps = [t0 + int(f * period * 1e9) for f in range(F)]
    got = [f for f, s in enumerate(stamps) if s in received]
    errors = [e3d(cloud.decode_points(received[stamps[f]])[1].T, S[3 * f:3 * f + 3])
              for f in got]                       # the mean of per-frame errors, as e3d's
    figures = {'points': points, 'rate': rate, 'frames': F, 'busy_core': busy,
               'frames_received': len(got), 'share_received': len(got) / F,
               'latency_ms_p50': 1e3 * float(np.percentile(latencies, 50)),
               'latency_ms_p95': 1e3 * float(np.percentile(latencies, 95)),
               'latency_ms_max': 1e3 * float(latencies.max()),
               'e3d_received': float(np.mean(errors)), 'diagnostics': values}
    common.log(json.dumps({k: v for k, v in figures.items() if k != 'diagnostics'}))
    return figures


def offline_reference(points, frames):
    """e3D of the live pipeline's ``points`` offline (every window solved inline as it
    closes) on the slow face the node run of ``points`` tracks and ``frames`` frames is fed,
    with the mapping CPU seconds per window."""
    W, S = slow_face(points, frames)
    pipe, cpu = timed_pipeline(defaults()['mapping_tracks'])
    ids = np.arange(points, dtype=np.uint32)
    errors = {}                     # frame by frame: nothing (F, P)-sized is kept
    events = live_events(pipe, ((f, ids, uv.T, '') for f, uv in enumerate(as_frames(W, 2))))
    for kind, item in events:
        if kind == 'points':
            f = item.stamp_ns
            errors[f] = e3d(item.xyz.T, S[3 * f:3 * f + 3])
    assert sorted(errors) == list(range(frames)), 'every frame published once'
    figures = {'offline_e3d_points': float(np.mean(list(errors.values()))),
               'offline_cpu_per_window_s': float(np.mean(cpu[1:] or cpu)),
               'offline_windows': len(cpu), 'offline_git': common.environment().get('git')}
    common.log(json.dumps(figures))
    return figures


def stored(key):
    """The entry ``key`` of live_node.json ({} when none)."""
    return json.loads(NODE_RESULTS.read_text()).get(key, {}) if NODE_RESULTS.exists() else {}


def run_key(points, frames, busy=False, suffix=''):
    """The live_node.json key of a node run: ``10000``, ``30000x3600f``, ``10000_busy``..."""
    return f"{points}{'' if frames == 300 else f'x{frames}f'}{'_busy' if busy else ''}{suffix}"


def median_run(runs):
    """The run of median p95 latency among ``runs`` (figures dicts), with every run's
    p50 / p95 / max latency, e3D and first model under ``runs``, and the median e3D of the runs
    (``e3d_received_median``: one run's e3D varies by 10 % here)."""
    chosen = sorted(runs, key=lambda r: r['latency_ms_p95'])[len(runs) // 2]
    keys = ('latency_ms_p50', 'latency_ms_p95', 'latency_ms_max', 'frames_received',
            'e3d_received')
    every = [{**{k: r[k] for k in keys}, 'first_model_after_frames':
              r['diagnostics'].get('first model after frames')} for r in runs]
    return {**chosen, 'runs': every,
            'e3d_received_median': float(np.median([r['e3d_received'] for r in runs]))}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--node', action='store_true', help='the node over DDS (else offline)')
    parser.add_argument('--points', type=int, default=10_000)
    parser.add_argument('--rate', type=float, default=30.0)
    parser.add_argument('--busy', action='store_true', help='keep the other core busy')
    parser.add_argument('--mapping', default=None,
                        help="the node's mapping parameter, or several (inline,process) run in "
                        "turn (default: the node's; given, it names the result: "
                        '10000_busy_process)')
    parser.add_argument('--repeat', type=int, default=1,
                        help='runs of each mapping (in turn); the median p95 run is kept')
    parser.add_argument('--frames', type=int, default=300,
                        help='frames of the slow face (3600: 2 minutes at 30 Hz)')
    parser.add_argument('--offline', action='store_true',
                        help="add the same pipeline offline on the same input to the run's "
                        'entry (its e3D the ratio is taken against)')
    args = parser.parse_args(argv)
    if args.offline:
        key = run_key(args.points, args.frames)
        common.merge_result(NODE_RESULTS, key, {**stored(key),
                                                **offline_reference(args.points, args.frames)})
        return 0
    if not args.node:
        from . import __main__
        return __main__.main(['--only', 'live'])
    mappings = args.mapping.split(',') if args.mapping else [defaults()['mapping']]
    if not set(mappings) <= set(MAPPINGS):
        parser.error(f'--mapping: one or more of {MAPPINGS}')
    runs = {m: [] for m in mappings}
    for _ in range(args.repeat):
        for mapping in mappings:
            figures = node_run(args.points, args.rate, args.busy,
                               extra_args=('-p', f'mapping:={mapping}'), frames=args.frames)
            runs[mapping].append(dict(figures, mapping=mapping))
    coretype = os.environ.get('OPENBLAS_CORETYPE', '').lower()
    kernel = f'_{coretype}' if coretype else ''
    for mapping, done in runs.items():
        suffix = ('' if args.mapping is None else f'_{mapping}') + kernel
        figures = median_run(done) if len(done) > 1 else done[0]
        key = run_key(args.points, args.frames, args.busy, suffix)
        offline = {k: v for k, v in stored(key).items() if k.startswith('offline_')}
        common.merge_result(NODE_RESULTS, key,
                            {'environment': common.environment(), **common.jsonable(figures),
                             **offline})
    return 0


if __name__ == '__main__':
    sys.exit(main())
