"""The node over DDS: started in its own process (isolated domain, localhost discovery, logs in
a temporary folder), fed a synthetic sequence at 30 Hz from this process, its ``points``
checked against ground truth; malformed clouds are interleaved with good ones.

The node runs with the rigid solver of test/doubles.py (injected through ``main``), so these tests
exercise the node and the pipeline, not the Grassmannian solver.
"""
import signal

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.typesys import get_typestore, Stores

from doubles import bending_sheet, RigidALS
from grass_nrsfm_ros import cloud
from grass_nrsfm_ros.nrsfm.measurement import as_frames
from grass_nrsfm_ros.nrsfm.metrics import e3d, e3d_akhter
from grass_nrsfm_ros.pipeline import make_pipeline, reconstruct_live

rclpy = pytest.importorskip('rclpy')
from builtin_interfaces.msg import Time  # noqa: E402, I100
from sensor_msgs.msg import PointCloud2, PointField  # noqa: E402
from std_msgs.msg import Header  # noqa: E402
from rosutil import node_with_feeder, publish, status_values  # noqa: E402, I100

pytestmark = pytest.mark.ros
PERIOD = 1 / 30
T0 = 1_700_000_000_000_000_000


@pytest.fixture
def node_process(ros_env, tmp_path, request):
    """Start the node (extra ROS arguments: indirect parameter); yield (process, log path,
    feeder); stop it with SIGINT."""
    log = tmp_path / 'node.log'
    args = getattr(request, 'param', ())
    extra = [a.format(tmp=tmp_path) for a in args]
    # every cloud is checked: a subscriber history of window_size, as the README advises
    with node_with_feeder(ros_env, log, ['-p', 'frame_id:=cam_optical', *extra],
                          points_depth=30) as (proc, feeder):
        yield proc, log, feeder


def header(f):
    ns = T0 + int(f * PERIOD * 1e9)
    return Header(stamp=Time(sec=ns // 10 ** 9, nanosec=ns % 10 ** 9), frame_id='camera')


def stamp_of(msg):
    stamp = getattr(msg, 'header', msg).stamp
    return stamp.sec * 10 ** 9 + stamp.nanosec


def all_published(feeder, sent, log):
    """Wait until the node has accounted for the ``sent`` messages and every cloud it counts
    as published has arrived here (a duplicate would then be among them)."""
    counts = feeder.accounted(sent)
    assert counts is not None, log.read_text()
    assert feeder.wait_for(lambda: len(feeder.points) >= counts['frames published'], 10), counts


def good_frames(W, ids, first=0):
    return [cloud.encode_tracks(ids, as_frames(W, 2)[f].T, header(first + f))
            for f in range(W.shape[0] // 2)]


def stacked(points, ids):
    """``(3F, P)`` from ``points`` messages, columns in the order of ``ids``."""
    blocks = []
    for msg in points:
        got_ids, xyz = cloud.decode_points(msg)
        assert np.array_equal(np.sort(got_ids), np.sort(ids))
        blocks.append(xyz[np.argsort(got_ids)][np.searchsorted(np.sort(ids), ids)].T)
    return np.vstack(blocks)


@pytest.mark.parametrize('node_process', [('-p', 'record_path:={tmp}/recording')],
                         indirect=True)
def test_node_reconstructs_a_30hz_stream(node_process, tmp_path):
    proc, log, feeder = node_process
    W, S, ids = bending_sheet(F=60, noise=0.5)
    publish(feeder, good_frames(W, ids))
    assert feeder.wait_for(lambda: len(feeder.points) >= 60, 60), log.read_text()
    all_published(feeder, 60, log)
    points = sorted(feeder.points, key=stamp_of)
    assert [stamp_of(m) for m in points] == [stamp_of(header(f)) for f in range(60)]
    assert all(m.header.frame_id == 'cam_optical' for m in points)
    # each cloud follows its tracks at once (a window's frames would wait for the window:
    # a stride, 0.33 s, plus the solve); generous bounds for a loaded machine
    assert len(feeder.latencies) == 60
    assert np.median(feeder.latencies) < 0.1 and max(feeder.latencies) < 3.0, feeder.latencies
    assert feeder.wait_for(lambda: len(feeder.refined) >= 60, 60), log.read_text()
    refined = sorted(feeder.refined, key=stamp_of)
    assert [stamp_of(m) for m in refined] == [stamp_of(header(f)) for f in range(60)]
    # same data and thresholds as test_pipeline: streaming 0.0349, one-rotation 0.058; the
    # frames tracked on arrival against the rigid stand-in's models 0.0505
    assert e3d(stacked(refined, ids), S) < 0.042
    assert e3d(stacked(points, ids), S) < 0.058
    assert e3d_akhter(stacked(refined, ids), S) < 0.07
    assert feeder.wait_for(lambda: feeder.diagnostics, 5)
    keys = {kv.key for kv in feeder.diagnostics[-1].status[0].values}
    assert {'windows solved', 'solve seconds', 'iterations', 'reprojection residual',
            'tracks in window', 'tracks thinned', 'dropped windows', 'dropped messages',
            'tracking latency p50 ms', 'tracking latency p95 ms', 'tracking residual',
            'model age frames', 'mapping backlog', 'frames tracked', 'frames refined'} <= keys
    proc.send_signal(signal.SIGINT)
    assert proc.wait(15) == 0
    # the recording, read back by rosbags: every input and output message, in order
    with AnyReader([tmp_path / 'recording'],
                   default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        recorded = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages()
                    if c.topic.endswith('/points')]
    namespace = feeder.node.get_namespace()
    assert counts == {f'{namespace}/tracks': 60, f'{namespace}/points': 60,
                      f'{namespace}/points/refined': 60}
    assert [stamp_of(m) for m in recorded] == [stamp_of(m) for m in points]


def malformed(good, kind):
    """A broken copy of the tracks cloud ``good``."""
    msg = PointCloud2(header=good.header, height=good.height, width=good.width,
                      fields=list(good.fields), is_bigendian=good.is_bigendian,
                      point_step=good.point_step, row_step=good.row_step,
                      data=bytes(good.data), is_dense=good.is_dense)
    if kind == 'missing':
        msg.fields = [f for f in good.fields if f.name != 'track_id']
    elif kind == 'datatype':
        msg.fields = [PointField(name=f.name, offset=f.offset, count=1,
                                 datatype=PointField.INT32 if f.name == 'u' else f.datatype)
                      for f in good.fields]
    elif kind == 'truncated':
        msg.data = bytes(good.data)[:len(good.data) // 2]
    elif kind == 'duplicate':
        tracks = cloud.decode_tracks(good)
        ids, uv = tracks.ids.copy(), tracks.uv
        ids[1] = ids[0]
        msg = cloud.encode_tracks(ids, uv, good.header)
    elif kind == 'empty':
        msg = cloud.encode_tracks(np.zeros(0, np.uint32), np.zeros((0, 2)), good.header)
    return msg


def with_non_finite(good):
    """``good`` plus 7 extra tracks whose u or v is NaN or Inf."""
    tracks = cloud.decode_tracks(good)
    ids, uv = tracks.ids, tracks.uv
    extra = np.arange(7, dtype=np.uint32) + ids.max() + 1
    bad_uv = np.array([[np.nan, 1], [2, np.nan], [np.inf, 3], [4, -np.inf]] + [[np.nan] * 2] * 3)
    return cloud.encode_tracks(np.r_[ids, extra], np.vstack([uv, bad_uv]), good.header)


LOG_LINES = {'missing': "missing field 'track_id'", 'datatype': "field 'u' has datatype",
             'truncated': 'layout needs', 'duplicate': 'duplicate track ids',
             'empty': 'empty tracks cloud', 'nan': 'points with non-finite u/v',
             'stamp': 'duplicate stamp', 'reset': 'all track ids changed',
             'record': 'recording to /proc/no_such_dir/recording failed'}


@pytest.mark.parametrize('node_process', [('-p', 'record_path:=/proc/no_such_dir/recording')],
                         indirect=True)
def test_bad_input_is_logged_once_and_good_frames_still_published(node_process):
    proc, log, feeder = node_process
    W, S, ids = bending_sheet(F=105, noise=0.5)
    frames = good_frames(W[:90], ids) + good_frames(W[90:], ids + 50_000, first=45)
    # frames 0..44: one tracker session, 45..104: every id changed
    messages = []
    for f, good in enumerate(frames):
        kind = {5: 'missing', 12: 'datatype', 20: 'truncated', 27: 'duplicate', 33: 'empty',
                50: 'stamp'}.get(f)
        if f == 40:
            good = with_non_finite(good)
        messages.append(good)
        if kind == 'stamp':
            messages.append(good)                   # the same frame again
        elif kind:
            messages.append(malformed(good, kind))  # same stamp, broken: dropped first
    publish(feeder, messages)
    # on failure: what arrived and the node's counts (lost frames = skipped windows under load)
    assert feeder.wait_for(lambda: len(feeder.points) >= 105, 60), (
        len(feeder.points), feeder.diagnostic_values(), log.read_text())
    all_published(feeder, len(messages), log)
    assert sorted(stamp_of(m) for m in feeder.points) == [stamp_of(header(f))
                                                          for f in range(105)]
    assert proc.poll() is None
    text = log.read_text()
    for kind, line in LOG_LINES.items():
        assert text.count(line) == 1, (kind, text)
    assert feeder.wait_for(lambda: len(feeder.refined) >= 105, 60), len(feeder.refined)
    refined = sorted(feeder.refined, key=stamp_of)
    # refined from each frame's third solve: for the rigid double, one rigid fit of the window
    # and up to 60 context frames of a bending sheet (0.049 / 0.054; from the first, < 0.05)
    assert e3d(stacked(refined[:45], ids), S[:135]) < 0.06
    assert e3d(stacked(refined[45:], ids + 50_000), S[135:]) < 0.06
    points = sorted(feeder.points, key=stamp_of)      # tracked on arrival: 0.037 / 0.051
    assert e3d(stacked(points[:45], ids), S[:135]) < 0.06
    assert e3d(stacked(points[45:], ids + 50_000), S[135:]) < 0.06


@pytest.mark.parametrize('node_process', [('-p', 'context_frames:=20', '-p', 'key_frames:=0')],
                         indirect=True)
def test_node_default_path_resumes_windows_in_the_child_process(node_process):
    """The default path (``mapping: process``, ``warm_start: resume``) with context frames: the
    windows after the second resume their predecessor in the child process, and every frame
    comes back refined. Published at 10 Hz so the rigid stand-in keeps up with the windows."""
    proc, log, feeder = node_process
    W, S, ids = bending_sheet(F=60, P=80, noise=0.5)
    publish(feeder, good_frames(W, ids), period=0.1)
    assert feeder.wait_for(lambda: len(feeder.refined) >= 60, 60), log.read_text()

    def resumed():
        return any(status_values(msg).get('started from') == 'resumed'
                   for msg in list(feeder.diagnostics))
    assert feeder.wait_for(resumed, 30), log.read_text()
    refined = sorted(feeder.refined, key=stamp_of)
    assert [stamp_of(m) for m in refined] == [stamp_of(header(f)) for f in range(60)]
    # offline, the same pipeline gives 0.0442 (windows resumed as here); live, a surprising
    # frame may close a window early, so the node's windows can differ: 0.0442-0.045 measured
    pipeline = make_pipeline({'context_frames': 20, 'key_frames': 0}, RigidALS)
    _, offline, updates = reconstruct_live(pipeline, range(60), [
        (ids, uv.T) for uv in as_frames(W, 2)])
    assert [u.figures.get('started_from') for u in updates][:4] == \
        ['rigid', 'resumed', 'resumed', 'resumed']
    offline_S = np.vstack([r.xyz.T[:, np.argsort(np.argsort(ids))] for r in offline])
    assert e3d(stacked(refined, ids), S) < 1.1 * e3d(offline_S, S)
