"""Helpers for tests that run the node in its own process over DDS (shared by test_node,
test_faults, test_degenerate and bench/load.py).

The isolated environment itself is the ``ros_env`` fixture in conftest.py (a random domain,
localhost discovery, logs in a temporary folder); this module needs rclpy.
"""
from contextlib import contextmanager
import os
from pathlib import Path
import random
import signal
import subprocess
import sys
import threading
import time

import rclpy
from diagnostic_msgs.msg import DiagnosticArray  # noqa: I100
from rclpy.executors import SingleThreadedExecutor
from sensor_msgs.msg import PointCloud2

from doubles import paced  # noqa: I100

TEST_DIR = Path(__file__).resolve().parent
#: the feeder's ``points`` history by default (test_node, which needs every cloud, asks for
#: the node's window_size, 30, as the README advises: with 10, a window's burst overwrote 3 of
#: 105 clouds in this Python subscriber's history while both cores were busy)
POINTS_DEPTH = 10
RIGID_LAUNCH = ('import sys; from doubles import RigidALS; '
                'from grass_nrsfm_ros.node import main; '
                'sys.exit(main(solver_factory=RigidALS))')


class SpunNode:
    """A node of this process spun by its own thread (in its own context unless one is given).
    Subclasses make their endpoints, then call :meth:`start`; :meth:`wait_for` checks a
    condition after every wake-up of the executor."""

    def __init__(self, name, namespace, context=None):
        self._owns_context = context is None
        self.context = context or rclpy.Context()
        if self._owns_context:
            rclpy.init(context=self.context)
        self.node = rclpy.create_node(name, namespace=namespace, context=self.context)

    def start(self):
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._woken = threading.Condition()          # notified after every executor wake-up
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self):
        while not self._stop.is_set():
            self.executor.spin_once(timeout_sec=0.05)
            with self._woken:
                self._woken.notify_all()

    def wait_for(self, condition, timeout):
        """Wait until ``condition()`` holds or ``timeout`` s pass; return ``condition()``.

        It is checked after every wake-up of the executor: at once when a message has been
        handled. Graph changes (a peer matched or gone) raise no callback in rclpy's Python
        API, so the executor also wakes every 50 ms without one and the condition is checked
        then."""
        with self._woken:
            return self._woken.wait_for(condition, timeout)

    def close(self):
        self._stop.set()
        self._thread.join()
        self.node.destroy_node()
        if self._owns_context:
            rclpy.shutdown(context=self.context)


class Feeder(SpunNode):
    """This process's side: publishes ``tracks``, collects ``points`` and ``/diagnostics``."""

    def __init__(self, namespace, keep_points=True, points_depth=POINTS_DEPTH, tracks_qos=10):
        super().__init__('feeder', namespace)
        self.points_received = 0                    # counted even when not kept (load runs)
        self.pub = self.node.create_publisher(PointCloud2, 'tracks', tracks_qos)
        self.pub_created = time.monotonic()
        self.points, self.diagnostics = [], []
        self.sent_at, self.latencies = {}, []       # stamp -> monotonic sent; seconds
        self.last_diagnostics_at = float('-inf')
        self.points_sub = self.node.create_subscription(
            PointCloud2, 'points', self._keep_point if keep_points else self._count_point,
            points_depth)
        self.refined = []
        self.node.create_subscription(
            PointCloud2, 'points/refined',
            self.refined.append if keep_points else (lambda msg: None), points_depth)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, 10)
        self.start()

    def _count_point(self, msg):
        self.points_received += 1
        self._latency(msg)

    def _keep_point(self, msg):
        self.points.append(msg)
        self._latency(msg)

    def _latency(self, msg):
        sent = self.sent_at.pop(msg.header.stamp.sec * 10 ** 9 + msg.header.stamp.nanosec, None)
        if sent is not None:
            self.latencies.append(time.monotonic() - sent)

    def publish(self, msg):
        """Publish a tracks message, noting when, so its ``points`` latency is measured."""
        self.sent_at[msg.header.stamp.sec * 10 ** 9 + msg.header.stamp.nanosec] = \
            time.monotonic()
        self.pub.publish(msg)

    def _on_diagnostics(self, msg):
        if any(s.hardware_id == self.node.get_namespace() + '/grass_nrsfm' for s in msg.status):
            self.diagnostics.append(msg)
            self.last_diagnostics_at = time.monotonic()

    def node_reports(self, since):
        """``{key: value}`` of the newest diagnostics received after ``since`` (monotonic), or
        {}."""
        if self.last_diagnostics_at <= since:
            return {}
        return self.diagnostic_values()

    def connected(self):
        """Both directions matched, on both sides: our ``tracks`` writer and ``points`` reader
        see the node's endpoints, and the node's diagnostics, sent after our writer was
        created, report our writer and our reader matched. (Matching is not symmetric: clouds
        sent before the node's reader matched our writer are ignored by it, and clouds the node
        sends before its writer matched our reader are gone, volatile durability. Before this
        check, 3 of 6 local runs of test_faults had a test that lost all or part of its stream:
        0 of 40 and 35 of 40 clouds, and a node that received nothing; none in 6 runs since.)
        A mapping process has also started (one still importing when the first windows close
        solves only the newest: beside a CPU hog, 2 of 10 runs of the 30 Hz stream lost the
        first window's frames)."""
        values = self.node_reports(self.pub_created)
        return (values.get('mapping process') != 'starting'
                and self.pub.get_subscription_count() >= 1
                and self.points_sub.get_publisher_count() >= 1
                and int(values.get('tracks publishers', 0)) >= 1
                and int(values.get('points subscribers', 0)) >= 1)

    def new_publisher(self, depth=10):
        """Replace our ``tracks`` writer (KEEP_LAST ``depth``, reliable) once the node has seen
        the old one go, and wait until the new one is connected to the node's reliable reader.
        (With no publisher the node ('auto') reads best effort; it resubscribes reliable within
        a second of seeing ours. Clouds sent before are lost in the switch: a fresh-clone CI run
        lost some of the 40 sent at once.)"""
        self.node.destroy_publisher(self.pub)
        gone = time.monotonic()
        assert self.wait_for(
            lambda: self.node_reports(gone).get('tracks publishers') == '0', 20)
        self.pub = self.node.create_publisher(PointCloud2, 'tracks', depth)
        self.pub_created = time.monotonic()
        assert self.wait_for(lambda: self.connected() and self.node_reports(
            self.pub_created).get('input reliability') == 'reliable', 20)

    def use_depth(self, depth):
        """Publish ``tracks`` with a KEEP_LAST history of ``depth`` (reliable) from now on."""
        if depth != self.pub.qos_profile.depth:
            self.new_publisher(depth)

    def diagnostic_values(self):
        """``{key: value}`` of the newest diagnostics status (strings), or {}."""
        return status_values(self.diagnostics[-1]) if self.diagnostics else {}

    def accounted(self, sent, timeout=30, reports=2):
        """Wait until the node's diagnostics count ``sent`` messages received, report the solver
        idle (no solve running, none waiting), and the last ``reports`` diagnostics (one a
        second) give the same counts; return them as ints (None on timeout). Then every
        message is accounted for: ``messages received == dropped messages + frames published
        + frames lost + frames pending``. (Without the 'solver busy' check, a solve longer than
        the quiet period once used here looked like the end and left its frames pending.)"""
        keys = ('messages received', 'dropped messages', 'frames published', 'frames lost',
                'frames pending', 'windows solved', 'dropped windows')

        def settled():
            latest = [status_values(msg) for msg in self.diagnostics[-reports:]]
            if len(latest) < reports or any(v.get('solver busy') != 'False' for v in latest):
                return False
            counts = {tuple(v.get(k) for k in keys) for v in latest}
            return len(counts) == 1 and int(latest[-1]['messages received']) >= sent

        if not self.wait_for(settled, timeout):
            return None
        values = self.diagnostic_values()
        return {k: int(values[k]) for k in keys}


def publish(feeder, messages, period=1 / 30):
    """Publish ``messages`` on the feeder's ``tracks`` at a sensor's rate, one per ``period`` s
    (a rate, not a wait)."""
    for msg in paced(messages, period):
        feeder.publish(msg)


def status_values(msg):
    """``{key: value}`` (strings) of the first status of a DiagnosticArray."""
    return {kv.key: kv.value for kv in msg.status[0].values}


def unique_namespace():
    return f'/test_{os.getpid()}_{random.randrange(10 ** 6)}'    # in case domains collide


def stop(proc, sig=signal.SIGINT, timeout=15):
    """Stop ``proc`` with ``sig`` (kill it after ``timeout`` s); return its exit code."""
    if proc.poll() is None:
        proc.send_signal(sig)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return proc.returncode


@contextmanager
def node_with_feeder(env, log, args=(), *, launch=RIGID_LAUNCH,
                     preexec_fn=None, connect_timeout=30, keep_points=True,
                     points_depth=POINTS_DEPTH, tracks_qos=10, namespace=None):
    """Start the node (``launch``: Python code run with ``-c`` from test/, extra ROS ``args``)
    in a fresh namespace, its output in ``log``; yield ``(process, feeder)`` once they are
    connected; stop it with SIGINT at the end. ``tracks_qos``: our tracks writer's QoS (a
    depth or a profile); ``namespace``: instead of a fresh one."""
    namespace = namespace or unique_namespace()
    if launch == RIGID_LAUNCH and not any(str(a).startswith('context_frames:=') for a in args):
        # the rigid stand-in is an iterative ALS in Python: on window + 60 context frames it
        # can take seconds per window and the node then skips windows; these tests are about
        # the node's plumbing, so they solve the window alone
        args = ['-p', 'context_frames:=0', *args]
    with open(log, 'w') as out:
        proc = subprocess.Popen(
            [sys.executable, '-c', launch, '--ros-args', '-r', f'__ns:={namespace}', *args],
            cwd=TEST_DIR, env=env, stdout=out, stderr=subprocess.STDOUT, preexec_fn=preexec_fn)
    feeder = Feeder(namespace, keep_points=keep_points, points_depth=points_depth,
                    tracks_qos=tracks_qos)
    try:
        assert feeder.wait_for(feeder.connected, connect_timeout), Path(log).read_text()
        yield proc, feeder
    finally:
        feeder.close()
        stop(proc)
