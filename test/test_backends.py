"""Mapping backends (grass_nrsfm_ros.backends): the inline one and the child process give the
same Updates for the same windows; a child that dies is restarted. Then ``mapping:=process``
over DDS: windows solved in a child process of the node.

The node runs with the rigid solver of test/doubles.py (or one that fails or crashes), fed at
30 Hz from this process: every frame comes back on ``points`` at once and the windows on
``points/refined``; a failing window and a dying child are reported and lose nothing else;
``~/reset`` reaches the child; the child never outlives the node.
"""
import os
from pathlib import Path
import select
import signal
import threading
from types import SimpleNamespace

import numpy as np
import pytest

from doubles import bending_sheet, frames_of, RigidALS, stacked as stacked_results, wait_until
from grass_nrsfm_ros import cloud
from grass_nrsfm_ros.backends import _Child, InlineBackend, ProcessBackend, WindowSpec
from grass_nrsfm_ros.mapper import make_mapper
from grass_nrsfm_ros.nrsfm.measurement import as_frames
from grass_nrsfm_ros.nrsfm.metrics import e3d
from grass_nrsfm_ros.params import defaults
from grass_nrsfm_ros.windowing import Windowing


# -- ROS-free: the backends alone -----------------------------------------------------------------
def closed(W, ids, **kwargs):
    """``(frames, windows)``: every accepted Frame of ``W: (2F, P)`` and the Windows they close
    (then the flush), as the pipeline hands them to a backend."""
    windowing = Windowing(**kwargs)
    frames, windows = [], []
    for f, (fid, uv) in enumerate(frames_of(W, ids)):
        frames.append(windowing.accept(f, fid, uv))
        windows.append(windowing.push(frames[-1]))
    windows[-1] = windows[-1] + windowing.flush(waiting=True)
    return frames, windows


def assert_same_updates(a, b):
    assert [(u.kind, u.index, u.stamps, u.final, u.flipped, u.preview) for u in a] == \
        [(u.kind, u.index, u.stamps, u.final, u.flipped, u.preview) for u in b]
    for x, y in zip(a, b):
        assert [r.stamp_ns for r in x.results] == [r.stamp_ns for r in y.results]
        for r, q in zip(x.results, y.results):
            np.testing.assert_array_equal(r.ids, q.ids)
            np.testing.assert_array_equal(r.xyz, q.xyz)
        assert (x.model is None) == (y.model is None)
        if x.model is not None:
            np.testing.assert_array_equal(x.model.mean, y.model.mean)
            np.testing.assert_array_equal(x.model.R, y.model.R)


def test_a_preview_never_replaces_a_window_waiting_in_the_child():
    """The child solves the newest window waiting, but a preview (a new sequence's first
    frames) gives way to the window waiting (the old sequence's last, say)."""
    W, S, ids = bending_sheet(F=40, P=60)
    _, windows = closed(W, ids, first_model_frames=15)
    preview, first = (WindowSpec.of(w) for w in (windows[14][0], windows[29][0]))
    sent = []
    child = _Child(None, None, SimpleNamespace(send=sent.append), None)
    child._take_window(first)
    child._take_window(preview)
    assert child.pending is first
    assert [(u.kind, u.preview, u.message) for u in sent] == [('dropped', True, 'skipped')]
    child.pending = None
    child._take_window(preview)
    child._take_window(first)                               # a window replaces a preview
    assert child.pending is first and [u.preview for u in sent] == [True, True]


def test_process_and_inline_backends_give_the_same_updates():
    """A short sequence with the rigid solver, the default 'resume' warm start and a preview
    window: each window waited for (none skipped), the child's Updates equal the inline ones
    bit for bit."""
    W, S, ids = bending_sheet(F=50, P=120, noise=0.5)
    config = {**defaults(), 'refined_from': 'last_window', 'first_model_frames': 15}
    frames, windows = closed(W, ids, first_model_frames=15)
    inline = InlineBackend(make_mapper(config, RigidALS))
    for step in windows:
        for window in step:
            inline.submit(window)
    expected = inline.updates()
    assert [u.kind for u in expected] == ['solved'] * 4 + ['released']
    assert [u.preview for u in expected] == [True] + [False] * 4
    assert expected[2].results and expected[1].figures['reprojection_residual'] < 0.05
    ready = threading.Event()
    backend = ProcessBackend(config, RigidALS, notify=ready.set)
    got = []
    try:
        for frame, step in zip(frames, windows):
            backend.feed(frame)
            for window in step:
                backend.submit(window)
                while not got or (got[-1].index, got[-1].preview) != \
                        (window.index, window.preview):             # one at a time
                    assert ready.wait(60), 'no update from the mapping process'
                    ready.clear()
                    got += backend.updates()
        assert backend.outstanding == 0 and backend.restarts == 0
    finally:
        backend.close()
    assert not backend.alive
    assert_same_updates(got, expected)
    rows = np.concatenate([np.arange(3 * r.stamp_ns, 3 * r.stamp_ns + 3) for r in got[1].results])
    assert e3d(stacked_results(got[1].results, ids), S[rows]) < 0.05


def test_a_newer_window_replaces_the_one_waiting_in_the_child():
    W, S, ids = bending_sheet(F=60, P=80)
    frames, windows = closed(W, ids)
    ready = threading.Event()
    backend = ProcessBackend(defaults(), RigidALS, notify=ready.set)
    got = []
    try:
        for frame in frames:
            backend.feed(frame)
        for step in windows:                     # all at once: the child skips some
            for window in step:
                backend.submit(window)
        while backend.outstanding:
            assert ready.wait(60), 'no update from the mapping process'
            ready.clear()
            got += backend.updates()
        got += backend.updates()
    finally:
        backend.close()
    kinds = {u.index: (u.kind, u.message) for u in got}
    assert sorted(kinds) == [w.index for step in windows for w in step]
    assert kinds[max(kinds)][0] in ('solved', 'released')
    assert all(kind == 'solved' or (kind, message) == ('dropped', 'skipped')
               for kind, message in kinds.values() if kind != 'released')


def test_a_mapping_process_without_on_exit_restarts_its_dead_child():
    """The handle alone (no ``on_exit``, as a researcher might use it): a killed child is
    restarted, not a TypeError on the receiver thread."""
    backend = ProcessBackend(defaults())
    try:
        assert wait_until(lambda: backend.pid is not None)
        first = backend.pid
        os.kill(first, signal.SIGKILL)
        assert wait_until(lambda: backend.restarts == 1 and backend.pid not in (None, first))
        assert backend.alive
    finally:
        backend.close()
    assert not backend.alive


@pytest.mark.skipif(not hasattr(os, 'SCHED_IDLE'), reason='SCHED_IDLE is Linux only')
def test_the_mapping_child_runs_under_sched_idle():
    """The child takes only CPU time the live side does not want (record 0434); the parent's
    scheduling is left as it was."""
    before = os.sched_getscheduler(0)
    backend = ProcessBackend(defaults())
    try:
        assert wait_until(lambda: backend.pid is not None)
        assert os.sched_getscheduler(backend.pid) == os.SCHED_IDLE
        assert os.sched_getscheduler(0) == before != os.SCHED_IDLE
    finally:
        backend.close()


# -- mapping:=process over DDS ------------------------------------------------------------------
PERIOD = 1 / 30
T0 = 1_700_000_000_000_000_000
PROCESS = ['-p', 'mapping:=process', '-p', 'context_frames:=0']


def ros():
    """rosutil (it needs rclpy: the test is skipped without ROS 2)."""
    return pytest.importorskip('rosutil')


def stamp_ns(f):
    return T0 + int(f * PERIOD * 1e9)


def stamp_of(msg):
    return msg.header.stamp.sec * 10 ** 9 + msg.header.stamp.nanosec


def frames(W, ids, first=0):
    """Tracks clouds of ``W: (2F, P)``, stamped from frame ``first`` at 30 Hz."""
    from builtin_interfaces.msg import Time
    from std_msgs.msg import Header
    out = []
    for f, uv in enumerate(as_frames(W, 2)):
        ns = stamp_ns(first + f)
        header = Header(stamp=Time(sec=ns // 10 ** 9, nanosec=ns % 10 ** 9), frame_id='camera')
        out.append(cloud.encode_tracks(ids, uv.T, header))
    return out


def stacked(messages, ids):
    """``(3F, P)`` of ``messages`` in stamp order, columns in the order of ``ids``."""
    decoded = [SimpleNamespace(ids=got, xyz=xyz) for got, xyz in
               (cloud.decode_points(m) for m in sorted(messages, key=stamp_of))]
    return stacked_results(decoded, ids)


def mapping_pid(feeder, node_pid):
    """The child's pid from the node's diagnostics, checked to be the node's child."""
    assert feeder.wait_for(lambda: feeder.diagnostic_values().get('mapping process', '')
                           .isdigit(), 20), feeder.diagnostic_values()
    pid = int(feeder.diagnostic_values()['mapping process'])
    stat = Path(f'/proc/{pid}/stat').read_text()
    assert int(stat.rsplit(')', 1)[1].split()[1]) == node_pid           # its parent
    return pid


def exits_within(pid, timeout):
    """True once process ``pid`` (not ours) has exited, waiting on its pidfd."""
    try:
        fd = os.pidfd_open(pid)
    except ProcessLookupError:
        return True
    try:
        return bool(select.select([fd], [], [], timeout)[0])
    finally:
        os.close(fd)


@pytest.mark.ros
def test_every_frame_on_points_windows_refined_reset_and_clean_exit(ros_env, tmp_path):
    rosutil = ros()
    from std_srvs.srv import Trigger
    log = tmp_path / 'node.log'
    W, S, ids = bending_sheet(F=60, noise=0.5)
    with rosutil.node_with_feeder(ros_env, log, PROCESS, points_depth=60) as (proc, feeder):
        child = mapping_pid(feeder, proc.pid)
        rosutil.publish(feeder, frames(W, ids))
        assert feeder.wait_for(lambda: len(feeder.points) >= 60
                               and len(feeder.refined) >= 60, 60), log.read_text()
        counts = feeder.accounted(60)
        assert counts is not None and counts['frames published'] == 60, log.read_text()
        assert sorted(stamp_of(m) for m in feeder.points) == [stamp_ns(f) for f in range(60)]
        assert sorted(stamp_of(m) for m in feeder.refined) == [stamp_ns(f) for f in range(60)]
        assert len(feeder.latencies) == 60 and np.median(feeder.latencies) < 0.1
        # the same thresholds as test_node's worker thread (same data, same rigid solver)
        assert e3d(stacked(feeder.refined, ids), S) < 0.042
        assert e3d(stacked(feeder.points, ids), S) < 0.058
        values = feeder.diagnostic_values()
        assert values['windows solved'] == '4' and values['windows not solved'] == '0'
        assert float(values['mapping hand-over p95 ms']) < 20, values
        # ~/reset reaches the child: the next sequence is refined from its own frames only
        client = feeder.node.create_client(Trigger, f'{feeder.node.get_namespace()}/'
                                           'grass_nrsfm/reset')
        assert client.wait_for_service(timeout_sec=10)
        future = client.call_async(Trigger.Request())
        assert feeder.wait_for(future.done, 10)
        assert 'windows in the mapping' in future.result().message
        rosutil.publish(feeder, frames(W[:60], ids, first=60))
        assert feeder.wait_for(lambda: len(feeder.refined) >= 90, 30), log.read_text()
        assert sorted(stamp_of(m) for m in feeder.refined)[60:] == \
            [stamp_ns(f) for f in range(60, 90)]
        proc.send_signal(signal.SIGINT)
        assert proc.wait(15) == 0
        assert exits_within(child, 5)
    assert 'Traceback' not in log.read_text()


@pytest.mark.ros
def test_a_failing_window_is_reported_and_nothing_else_is_lost(ros_env, tmp_path):
    rosutil = ros()
    launch = rosutil.RIGID_LAUNCH.replace('RigidALS', 'FailsSecondWindow')
    log = tmp_path / 'node.log'
    W, S, ids = bending_sheet(F=60, noise=0.5)
    with rosutil.node_with_feeder(ros_env, log, PROCESS, launch=launch,
                                  points_depth=60) as (proc, feeder):
        # 10 Hz: at 30 Hz a busy machine delays the child's solves until the node skips a
        # window (as designed), which this count of windows does not allow for
        rosutil.publish(feeder, frames(W, ids), period=0.1)
        assert feeder.wait_for(lambda: len(feeder.points) >= 60
                               and len(feeder.refined) >= 60, 60), log.read_text()
        counts = feeder.accounted(60)
        assert counts is not None and counts['frames published'] == 60
        values = feeder.diagnostic_values()
        assert values['windows not solved'] == '1' and values['windows solved'] == '3', values
    text = log.read_text()
    assert 'window 1 failed: RuntimeError: second window refused' \
        in text, text
    # window 2 (frames 20-49) refines the frames window 1 would have: none is missing
    assert sorted(stamp_of(m) for m in feeder.refined) == [stamp_ns(f) for f in range(60)]


@pytest.mark.ros
def test_a_dying_child_is_reported_restarted_and_never_outlives_the_node(ros_env, tmp_path):
    rosutil = ros()
    launch = rosutil.RIGID_LAUNCH.replace('RigidALS', 'KillsItsProcessOnce')
    log = tmp_path / 'node.log'
    env = {**ros_env, 'GRASS_TEST_CRASH_MARKER': str(tmp_path / 'crashed')}
    W, S, ids = bending_sheet(F=120, noise=0.5)
    with rosutil.node_with_feeder(env, log, PROCESS, launch=launch,
                                  points_depth=120) as (proc, feeder):
        first = mapping_pid(feeder, proc.pid)
        rosutil.publish(feeder, frames(W, ids))
        assert feeder.wait_for(lambda: len(feeder.points) >= 120, 30), log.read_text()
        counts = feeder.accounted(120, timeout=60)
        assert counts is not None and counts['frames published'] == 120, log.read_text()
        values = feeder.diagnostic_values()
        assert values['mapping restarts'] == '1', values
        second = int(values['mapping process'])
        assert second != first and exits_within(first, 0)
        # the restarted child solves again once it holds a window's frames
        assert feeder.wait_for(lambda: feeder.refined, 30), log.read_text()
        # the published depth keeps one orientation across the restart (the first model came
        # at frame 30, the crash at the second window): consecutive clouds' depths correlate
        # positively from the first model on
        z = stacked(feeder.points, ids).reshape(120, 3, -1)[31:, 2, :]
        assert (np.sum(z[1:] * z[:-1], axis=1) > 0).all()
        proc.send_signal(signal.SIGKILL)                   # the node dies: the child follows
        proc.wait(10)
        assert exits_within(second, 10)
    assert 'the mapping process exited with code -9: restarted it' in log.read_text()
