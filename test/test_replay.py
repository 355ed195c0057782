"""replay: a real rclpy subscriber in this process receives what a replay subprocess publishes,
with the recorded stamps and the recorded timing scaled by --rate. (Marked ros.)"""
from contextlib import contextmanager
from pathlib import Path
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.typesys import get_typestore, Stores

from grass_nrsfm_ros import bag
from grass_nrsfm_ros.cloud import decode_tracks

rclpy = pytest.importorskip('rclpy')
from rclpy.executors import SingleThreadedExecutor  # noqa: E402, I100
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import PointCloud2  # noqa: E402

pytestmark = pytest.mark.ros
REPO = Path(__file__).resolve().parents[1]
TOLERANCE_S = 0.030    # per-message timing error allowed; measured p50 ~1 ms on 2 loaded cores


class Listener:
    """An rclpy node in this process: ``got`` ``[(monotonic receive time, msg)]`` on
    ``/tracks``, ``clocks`` on ``/clock`` (with ``clock``)."""

    def __init__(self, clock=False):
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node('replay_test_sub', context=self.context)
        self.got, self.clocks = [], []
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.node.create_subscription(PointCloud2, '/tracks',
                                      lambda m: self.got.append((time.monotonic(), m)), qos)
        if clock:
            self.node.create_subscription(Clock, '/clock', self.clocks.append, 100)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def spin_until(self, condition, timeout):
        """Handle messages until ``condition()`` holds (checked after each one, and every
        10 ms without one) or ``timeout`` s pass; return ``condition()``."""
        deadline = time.monotonic() + timeout
        while not condition() and time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.01)
        return condition()

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)


@contextmanager
def replaying(env, bag_path, extra=(), clock=False):
    """A :class:`Listener` and a replay subprocess that starts once the listener is matched;
    yields ``(listener, process)``, then kills the replay if it still runs."""
    listener = Listener(clock)
    proc = subprocess.Popen([sys.executable, '-m', 'grass_nrsfm_ros.cli', 'replay',
                             str(bag_path), '--wait-for-subscribers', '1', *extra],
                            env=env, cwd=REPO, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        yield listener, proc
    finally:
        if proc.poll() is None:
            proc.kill()
        listener.close()


def receive(env, bag_path, n_expected, extra=(), timeout=60.0, clock=False):
    """Run replay in a subprocess; return ``[(monotonic receive time, msg)]`` and clocks."""
    with replaying(env, bag_path, extra, clock) as (listener, proc):
        # until replay has exited: its last /clock follows its last message (stopping at the
        # n-th message lost that /clock now and then)
        listener.spin_until(lambda: len(listener.got) >= n_expected and proc.poll() is not None,
                            timeout)
        out, _ = proc.communicate(timeout=30)
    assert proc.returncode == 0, out
    return listener.got, listener.clocks, out


def make_bag(path, F=15, period_ns=100_000_000, t0=1_700_000_000_000_000_000, P=25):
    W = np.random.default_rng(0).uniform(0, 500, (2 * F, P))
    # irregular timing: a gap in the middle so the schedule is not just a constant period
    stamps = t0 + np.arange(F) * period_ns + (np.arange(F) >= F // 2) * 2 * period_ns
    bag.tracks_bag_from_arrays(W, stamps, path)
    return W, stamps


@pytest.mark.parametrize('rate', [2.0, 0.5])
def test_replay_delivers_every_frame_with_scaled_timing(tmp_path, ros_env, rate):
    F = 15 if rate > 1 else 6
    W, stamps = make_bag(tmp_path / 'b', F=F)
    # --delay: a reader that matched the writer late got the first messages from the reliable
    # writer's repair, together, 0.26-0.30 s late (2 runs of 14 in one session)
    got, _, out = receive(ros_env, tmp_path / 'b', F, ['--rate', str(rate), '--delay', '0.5'])
    assert len(got) == F, out
    recv = np.array([t for t, _ in got])
    for f, (_, msg) in enumerate(got):
        assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == stamps[f]
        np.testing.assert_array_equal(decode_tracks(msg).uv, W[2 * f:2 * f + 2].T
                                      .astype(np.float32))
    expected = (stamps - stamps[0]) / 1e9 / rate
    error = (recv - recv[0]) - expected
    print(f'rate {rate}: timing error p50 {np.median(np.abs(error)) * 1e3:.2f} ms, '
          f'max {np.abs(error).max() * 1e3:.2f} ms')
    assert np.abs(error).max() < TOLERANCE_S


def test_replay_of_a_ros1_bag_with_clock(tmp_path, ros_env):
    ts2, ts1 = bag.typestore(), get_typestore(Stores.ROS1_NOETIC)
    W, stamps = make_bag(tmp_path / 'b', F=8)
    ros2 = list(bag.read_clouds(tmp_path / 'b', '/tracks'))
    with Writer1(tmp_path / 'one.bag') as w:
        conn = w.add_connection('/tracks', bag.POINTCLOUD2, typestore=ts1)
        for k, (t_ns, m) in enumerate(ros2):
            T = ts1.types['builtin_interfaces/msg/Time']
            m1 = ts1.types[bag.POINTCLOUD2](
                header=ts1.types['std_msgs/msg/Header'](
                    seq=k, stamp=T(sec=m.header.stamp.sec, nanosec=m.header.stamp.nanosec),
                    frame_id=m.header.frame_id),
                height=m.height, width=m.width,
                fields=[ts1.types['sensor_msgs/msg/PointField'](
                    name=p.name, offset=p.offset, datatype=p.datatype, count=p.count)
                    for p in m.fields],
                is_bigendian=False, point_step=m.point_step, row_step=m.row_step, data=m.data,
                is_dense=m.is_dense)
            w.write(conn, t_ns, ts1.serialize_ros1(m1, bag.POINTCLOUD2))
    del ts2
    got, clocks, out = receive(ros_env, tmp_path / 'one.bag', 8, ['--rate', '4', '--clock'],
                               clock=True)
    assert len(got) == 8, out
    for f, (_, msg) in enumerate(got):
        assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == stamps[f]
        assert msg.header.frame_id == 'camera_optical'
        np.testing.assert_array_equal(decode_tracks(msg).uv,
                                      W[2 * f:2 * f + 2].T.astype(np.float32))
    clock_ns = np.array([c.clock.sec * 10**9 + c.clock.nanosec for c in clocks])
    assert clock_ns.size >= 8
    assert (np.diff(clock_ns) >= 0).all()
    assert clock_ns.min() >= stamps[0] and clock_ns.max() == stamps[-1]


def test_replay_of_a_missing_topic_fails_clearly(tmp_path, ros_env):
    make_bag(tmp_path / 'b', F=3)
    out = subprocess.run([sys.executable, '-m', 'grass_nrsfm_ros.cli', 'replay',
                          str(tmp_path / 'b'), '--topic', '/nope'], env=ros_env, cwd=REPO,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2
    assert "no topic '/nope' (topics: /tracks)" in out.stderr


@pytest.mark.parametrize('sig', ['SIGINT', 'SIGTERM'])
def test_ctrl_c_stops_a_looping_replay_cleanly(tmp_path, ros_env, sig):
    """At --rate 1000 the signal lands while a message is being published (rclpy's own
    handlers used to invalidate the context under it: a traceback and exit code 1)."""
    make_bag(tmp_path / 'b', F=3)
    with replaying(ros_env, tmp_path / 'b', ['--loop', '--rate', '1000']) as (listener, proc):
        # the 3-frame bag played over 10 times: it loops
        assert listener.spin_until(lambda: len(listener.got) > 30, 30), len(listener.got)
        assert proc.poll() is None                   # still looping
        proc.send_signal(getattr(signal, sig))
        out, _ = proc.communicate(timeout=20)
    assert proc.returncode == 0, out
    assert 'replay: interrupted' in out and 'Traceback' not in out
    published = int(out.split('published ')[1].split()[0])
    assert published > 3                             # it did loop
