"""Sustained load on the node: a ``rate`` Hz stream of ``points``-point tracks clouds for
``seconds``, over DDS from this process to the node in its own process (isolated domain).

Reports the node's memory (RSS of the node and its children, a mapping process, sampled every
second), frames sent / published / skipped (the node's diagnostics), the accounting (every
message received is dropped, published, counted as lost (skipped windows) or pending:
``frames unaccounted`` must be 0) and the recording's completeness (messages in the recorded
bag vs sent and published).

    python -m bench.load                      # 10 min, 30 Hz, 30,000 points, the node as shipped
    python -m bench.load --seconds 20 --points 2000 --solver rigid
    python -m bench.load --seconds 120 --mapping process --key load_2min_process

``--solver grassmann`` (default) runs the node as shipped (GrassmannNRSfM, 60 context frames);
``rigid`` injects the rigid solver of test/doubles.py without context frames (the node and
pipeline under load, not the Grassmannian solver's speed). Results go
to ``bench/results/reliability.json`` under ``load`` (and are printed).
"""
import argparse
import json
import os
from pathlib import Path
import random
import signal
import sys
import tempfile
import time

import numpy as np
from std_msgs.msg import Header

from grass_nrsfm_ros import bag, cloud
from grass_nrsfm_ros.nrsfm.measurement import as_frames
from grass_nrsfm_ros.nrsfm.synthetic import make_sequence
from grass_nrsfm_ros.params import all_params, MAPPINGS
from . import common

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / 'test'))          # the node-over-DDS helpers of the tests
import rosutil  # noqa: E402, I100

RESULTS = REPO / 'bench' / 'results' / 'reliability.json'
DEFAULT_LAUNCH = 'import sys; from grass_nrsfm_ros.node import main; sys.exit(main())'


def isolated_env(tmp):
    """Environment for this process and the node: random domain, localhost, logs in ``tmp``."""
    env = {'ROS_DOMAIN_ID': str(random.randint(0, 101)),
           'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST', 'ROS_LOG_DIR': str(Path(tmp) / 'log'),
           'OPENBLAS_NUM_THREADS': '1', 'OMP_NUM_THREADS': '1'}
    os.environ.update(env)
    os.environ.pop('ROS_LOCALHOST_ONLY', None)
    return {**os.environ, 'PYTHONPATH': os.pathsep.join([str(REPO), str(REPO / 'test')])}


def rss_mb(pid):
    """Resident memory of process ``pid`` in MB (from /proc), or None once it has gone."""
    try:
        with open(f'/proc/{pid}/status') as f:
            for line in f:
                if line.startswith('VmRSS:'):
                    return int(line.split()[1]) / 1024
    except OSError:
        return None
    return None


def children(pid):
    """Pids of the child processes of ``pid`` (a mapping process), from /proc."""
    out = []
    try:
        for task in os.listdir(f'/proc/{pid}/task'):
            with open(f'/proc/{pid}/task/{task}/children') as f:
                out += [int(c) for c in f.read().split()]
    except OSError:
        pass
    return out


def tree_rss_mb(pid):
    """RSS in MB of process ``pid`` plus its children (the node and its mapping process), or
    None once it has gone."""
    own = rss_mb(pid)
    if own is None:
        return None
    return own + sum(rss_mb(c) or 0.0 for c in children(pid))


def sample(start, proc, feeder):
    """``(t_s, RSS MB of the node and its children, messages received, windows solved)``."""
    values = feeder.diagnostic_values()
    return (round(time.monotonic() - start, 1), tree_rss_mb(proc.pid),
            int(values.get('messages received', 0)), int(values.get('windows solved', 0)))


def clouds(points, n_frames=90, seed=0):
    """``n_frames`` distinct tracks clouds (rclpy) of a bending sheet, re-stamped when sent."""
    seq = make_sequence('bending', n_frames, points, camera='orbit', seed=seed)
    W = seq.W * 200 + 320
    ids = np.arange(points, dtype=np.uint32)
    return [cloud.encode_tracks(ids, uv.T, Header(frame_id='camera'))
            for uv in as_frames(W, 2)]


def latency_figures(latencies):
    """p50 / p95 / max (ms) of the tracks -> points latencies measured by the feeder."""
    if not latencies:
        return None
    p50, p95 = np.percentile(latencies, [50, 95])
    return dict(p50=round(1e3 * p50, 1), p95=round(1e3 * p95, 1),
                max=round(1e3 * max(latencies), 1), n=len(latencies))


def memory_figures(samples, warm_frames, warm_solves=2):
    """RSS figures from ``samples``: ``(t_s, rss_mb, messages received, windows solved)`` once a
    second. Warm-up ends at the first sample with ``warm_frames`` messages received (the
    pipeline's buffers full: window + context frames) and ``warm_solves`` windows solved (the
    solver's working set and the kept previous solution allocated); 'growth_after_warmup' is
    the largest RSS after it minus the RSS at it (with the real solver this is its working
    set coming and going), 'slope_mb_per_min' a least-squares line through the samples after
    it and 'mean_per_minute' (a leak of a frame per message shows as a steady slope)."""
    rss = np.array([m for _, m, _, _ in samples], dtype=float)
    t = np.array([s[0] for s in samples], dtype=float)
    warm = next((i for i, (_, _, n, k) in enumerate(samples)
                 if n >= warm_frames and k >= warm_solves), None)
    out = dict(start=round(float(rss[0]), 1), max=round(float(rss.max()), 1),
               end=round(float(rss[-1]), 1), warmup_frames=warm_frames,
               warmup_solves=warm_solves, warmup_end_s=None, after_warmup=None,
               growth_after_warmup=None, slope_mb_per_min=None,
               samples=[(s[0], round(s[1], 1)) for s in samples[::max(1, len(samples) // 120)]])
    if warm is not None:
        after = rss[warm:]
        out.update(warmup_end_s=float(t[warm]), after_warmup=round(float(after[0]), 1),
                   growth_after_warmup=round(float(after.max() - after[0]), 1))
        if after.size >= 3:
            out['slope_mb_per_min'] = round(float(np.polyfit(t[warm:], after, 1)[0] * 60), 2)
    minutes = (t // 60).astype(int)
    out['mean_per_minute'] = [round(float(rss[minutes == m].mean()), 1)
                              for m in np.unique(minutes)]
    return out


def run(seconds=600.0, points=30_000, rate=30.0, solver='rigid', window=30, stride=10,
        record=True, tmp=None, log=print, depth=10, context=None, mapping=None, settle=None):
    """Run the load; return the figures (a dict). ``context``: the node's context_frames
    (default: 0 for the rigid stand-in, as in the tests; the node's default for grassmann);
    ``mapping``: the node's mapping parameter (None: its default); ``settle``: seconds to wait
    for the node to account for every message after the stream (None: 120 rigid, 600)."""
    tmp = Path(tmp or tempfile.mkdtemp(prefix='grass_load_'))
    env = isolated_env(tmp)
    launch = rosutil.RIGID_LAUNCH if solver == 'rigid' else DEFAULT_LAUNCH
    if context is None:
        context = 0 if solver == 'rigid' else next(
            p.default for p in all_params() if p.name == 'context_frames')
    args = ['-p', f'window_size:={window}', '-p', f'window_stride:={stride}',
            '-p', f'context_frames:={context}']
    if mapping is not None:
        args += ['-p', f'mapping:={mapping}']
    if record:
        args += ['-p', f'record_path:={tmp}/recording']
    messages = clouds(points)
    period = 1.0 / rate
    n_total = int(round(seconds * rate))
    rss, late = [], 0
    with rosutil.node_with_feeder(env, tmp / 'node.log', args, launch=launch,
                                  keep_points=False) as (proc, feeder):
        feeder.use_depth(depth)
        start = time.monotonic()
        next_sample = start
        t0_ns = time.time_ns()
        for k in range(n_total):
            due = start + k * period
            now = time.monotonic()
            if now < due:
                time.sleep(due - now)
            elif now - due > period:
                late += 1
            msg = messages[k % len(messages)]
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(
                t0_ns + int(k * period * 1e9), 10 ** 9)
            feeder.publish(msg)
            if time.monotonic() >= next_sample:
                rss.append(sample(start, proc, feeder))
                next_sample += 1.0
                if len(rss) % 60 == 0:
                    log(f'{rss[-1][0]:.0f} s: sent {k + 1}, node RSS {rss[-1][1]:.0f} MB, '
                        f'received {rss[-1][2]}, solved {rss[-1][3]}')
        send_seconds = time.monotonic() - start
        settle = settle or (120 if solver == 'rigid' else 600)
        counts = feeder.accounted(n_total, timeout=settle)
        rss.append(sample(start, proc, feeder))
        received_points = feeder.points_received
        code = rosutil.stop(proc, signal.SIGINT, timeout=60)
    figures = dict(seconds=seconds, points=points, rate=rate, solver=solver, window=window,
                   stride=stride, context_frames=context, sent=n_total, mapping=mapping,
                   send_seconds=round(send_seconds, 1),
                   sends_late_by_more_than_a_period=late, exit_code=code,
                   points_clouds_received_by_subscriber=received_points,
                   latency_ms=latency_figures(feeder.latencies))
    rss = [r for r in rss if r[1] is not None]
    if counts is None:
        figures['error'] = 'diagnostics never settled'
        figures['last_diagnostics'] = feeder.diagnostic_values()
        figures['rss_mb'] = memory_figures(rss, window + context)
        return figures
    figures.update(counts)
    figures['last_diagnostics'] = feeder.diagnostic_values()
    figures['frames unaccounted'] = n_total - (counts['dropped messages'] +
                                               counts['frames published'] +
                                               counts['frames lost'] + counts['frames pending'])
    figures['rss_mb'] = memory_figures(rss, window + context)
    if record:
        topics = bag.topics(tmp / 'recording')
        figures['recorded'] = {t.rsplit('/', 1)[-1]: n for t, (_, n) in topics.items()}
        figures['recording_complete'] = (
            figures['recorded'].get('tracks') == n_total
            and figures['recorded'].get('points') == counts['frames published'])
        figures['recording_bytes'] = bag.bag_size_bytes(tmp / 'recording')
    return figures


def save(figures, key='load'):
    common.merge_result(RESULTS, key, {'environment': common.environment(), **figures})


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--seconds', type=float, default=600.0)
    parser.add_argument('--points', type=int, default=30_000)
    parser.add_argument('--rate', type=float, default=30.0)
    parser.add_argument('--solver', choices=('rigid', 'grassmann'), default='grassmann')
    parser.add_argument('--context', type=int, default=None,
                        help='context_frames (default: 0 rigid, the node default grassmann)')
    parser.add_argument('--window', type=int, default=30)
    parser.add_argument('--stride', type=int, default=10)
    parser.add_argument('--no-record', dest='record', action='store_false')
    parser.add_argument('--mapping', choices=MAPPINGS, default=None,
                        help="the node's mapping parameter (default: the node's)")
    parser.add_argument('--settle', type=float, default=None,
                        help='seconds to wait for the node to account for every message '
                        '(default 120 rigid, 600 grassmann)')
    parser.add_argument('--key', default='load', help='key in reliability.json (load)')
    args = parser.parse_args(argv)
    figures = run(args.seconds, args.points, args.rate, args.solver, args.window, args.stride,
                  args.record, context=args.context, mapping=args.mapping, settle=args.settle)
    save(figures, args.key)
    print(json.dumps({k: v for k, v in figures.items() if k != 'rss_mb'}, indent=1))
    print('rss_mb', {k: v for k, v in figures.get('rss_mb', {}).items() if k != 'samples'})
    return 0 if figures.get('frames unaccounted') == 0 else 1


if __name__ == '__main__':
    sys.exit(main())
