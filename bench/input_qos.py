"""What the input QoS costs: frames lost between a tracker and the node at ``rate`` Hz x
``points`` tracks, with one CPU-bound process on the other core, for each pairing of the
node's ``input_reliability`` and the tracker's QoS (docs/decisions/0300-input-qos.md), over
Fast DDS's default transports (shared memory between local processes) and over UDP alone
(``FASTDDS_BUILTIN_TRANSPORTS=UDPv4``, what a tracker on another machine goes through; without
``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``, under which rmw_fastrtps sets its own transports
and keeps shared memory, as /proc/PID/maps shows).

    python -m bench.input_qos                  # 20 s per case, 30 Hz, 10,000 tracks
    python -m bench.input_qos --seconds 10 --points 2000

Lost = sent - the node's 'messages received' (its diagnostics, once it has settled); the
node runs the rigid stand-in solver of test/doubles.py without context frames, so it
solves windows meanwhile. Results: ``bench/results/input_qos.json`` and
``bench/results/input_qos.png`` (``--name`` changes the stem).
"""
import argparse
import json
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time

from bench.load import clouds, isolated_env

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / 'bench' / 'results'
#: (case name, node's input_reliability, tracker profile name)
CASES = (('reliable tracker, auto (reliable)', 'auto', 'reliable'),
         ('reliable tracker, best_effort', 'best_effort', 'reliable'),
         ('sensor-data tracker, auto (best effort)', 'auto', 'sensor_data'))
BUSY = 'while True: pass'
TRANSPORTS = {'default (shm)': None, 'udp': 'UDPv4'}


def tracker_qos(name):
    from rclpy.qos import qos_profile_sensor_data, QoSProfile, ReliabilityPolicy

    if name == 'sensor_data':
        return qos_profile_sensor_data                       # best effort, depth 5
    return QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)


def transport_env(tmp, builtin):
    """The isolated environment (bench.load), for this process too; ``builtin``: the only
    Fast DDS builtin transport (None: the defaults)."""
    env = isolated_env(tmp)
    if builtin is not None:
        for where in (env, os.environ):
            where['FASTDDS_BUILTIN_TRANSPORTS'] = builtin
            where.pop('ROS_AUTOMATIC_DISCOVERY_RANGE', None)
    return env


def run_case(mode, tracker, seconds, points, rate, tmp, messages, builtin=None):
    """Figures of one case: sent, received, lost, the node's input reliability."""
    sys.path.insert(0, str(REPO / 'test'))
    import rosutil

    env = transport_env(tmp, builtin)
    args = ['-p', f'input_reliability:={mode}', '-p', f'expected_rate:={rate}']
    n_total = int(round(seconds * rate))
    with rosutil.node_with_feeder(env, Path(tmp) / f'node_{mode}_{tracker}.log', args,
                                  keep_points=False,
                                  tracks_qos=tracker_qos(tracker)) as (proc, feeder):
        reliability = feeder.diagnostic_values().get('input reliability')
        start = time.monotonic()
        for k in range(n_total):
            time.sleep(max(0.0, start + k / rate - time.monotonic()))
            msg = messages[k % len(messages)]
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(time.time_ns(), 10 ** 9)
            feeder.pub.publish(msg)
        send_seconds = time.monotonic() - start
        settled = feeder.accounted(0, timeout=60, quiet=3.0) or {}
        received = int(feeder.diagnostic_values().get('messages received', 0))
    return dict(node_input_reliability=mode, resolved_reliability=reliability,
                tracker=tracker, sent=n_total, received=received, lost=n_total - received,
                lost_percent=round(100 * (n_total - received) / n_total, 2),
                send_seconds=round(send_seconds, 1), settled=bool(settled))


def plot(rows, path):
    from bench.plot import bar_plot

    bar_plot(path, {f"{r['case']}, {r['transport']}": r['lost_percent'] for r in rows},
             title=f'Frames lost in transport, {rows[0]["rate"]:g} Hz x {rows[0]["points"]:,} '
                   'tracks, other core busy', ylabel='frames lost (% of sent)')


def run(seconds=20.0, points=10_000, rate=30.0, transports=tuple(TRANSPORTS)):
    rows = []
    messages = clouds(points)
    busy = subprocess.Popen([sys.executable, '-c', BUSY])
    try:
        for transport in transports:
            builtin = TRANSPORTS[transport]
            os.environ.pop('FASTDDS_BUILTIN_TRANSPORTS', None)
            for case, mode, tracker in CASES:
                with tempfile.TemporaryDirectory(prefix='grass_qos_') as tmp:
                    row = run_case(mode, tracker, seconds, points, rate, tmp, messages,
                                   builtin)
                rows.append(dict(case=case, transport=transport, seconds=seconds,
                                 points=points, rate=rate, **row))
                print(json.dumps(rows[-1]), flush=True)
    finally:
        busy.kill()
        busy.wait()
        os.environ.pop('FASTDDS_BUILTIN_TRANSPORTS', None)
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--seconds', type=float, default=20.0)
    parser.add_argument('--points', type=int, default=10_000)
    parser.add_argument('--rate', type=float, default=30.0)
    parser.add_argument('--name', default='input_qos', help='result file stem (input_qos)')
    parser.add_argument('--transport', action='append', choices=TRANSPORTS,
                        help='only this transport (repeatable; default: all)')
    args = parser.parse_args(argv)
    rows = run(args.seconds, args.points, args.rate, args.transport or tuple(TRANSPORTS))
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / f'{args.name}.json').write_text(json.dumps(
        {'command': 'python -m bench.input_qos ' + ' '.join(argv or sys.argv[1:]),
         'rows': rows}, indent=1) + '\n')
    plot(rows, RESULTS / f'{args.name}.png')
    return 0


if __name__ == '__main__':
    sys.exit(main())
