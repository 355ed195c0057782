"""The node's integration surface over DDS (issue 22): the input QoS against best-effort and
reliable trackers, ``~/reset``, rates in ``/diagnostics``, the ``mesh`` marker and the offered
QoS in recordings. The node runs in its own process with the rigid solver of test/doubles.py
(test/rosutil); this process is the tracker."""
import time

from mcap.reader import make_reader
import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.interfaces import QosReliability
import yaml

from doubles import bending_sheet, paced
from grass_nrsfm_ros import cloud
from grass_nrsfm_ros.nrsfm.measurement import as_frames

rclpy = pytest.importorskip('rclpy')
from rclpy.qos import qos_profile_sensor_data, QoSProfile, ReliabilityPolicy  # noqa: E402, I100
from std_msgs.msg import Header  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402
from visualization_msgs.msg import Marker  # noqa: E402
from rosutil import node_with_feeder, publish, unique_namespace  # noqa: E402, I100
from test_node import good_frames, stamp_of  # noqa: E402

pytestmark = pytest.mark.ros
RELIABLE_10 = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)


def statuses(feeder):
    """``{status name suffix: (level int, message, {key: value})}`` of the newest diagnostics."""
    if not feeder.diagnostics:
        return {}
    return {s.name.split(': ', 1)[1]: (s.level[0] if isinstance(s.level, bytes) else s.level,
                                       s.message, {kv.key: kv.value for kv in s.values})
            for s in feeder.diagnostics[-1].status}


def frames_at_30hz(F, first=0, seed=0):
    W, _, ids = bending_sheet(F=F, noise=0.5, seed=seed)
    return good_frames(W, ids, first=first), ids


@pytest.mark.parametrize('mode, tracker, reliability', [
    ('auto', qos_profile_sensor_data, 'best_effort'),
    ('auto', RELIABLE_10, 'reliable'),
    ('best_effort', RELIABLE_10, 'best_effort'),
])
def test_trackers_of_either_reliability_are_heard(ros_env, tmp_path, mode, tracker,
                                                  reliability):
    """A best-effort tracker (rclpy's sensor-data profile) gets >= 95 % of 90 frames at 30 Hz
    back; a reliable one every frame, over a reliable connection under 'auto'."""
    with node_with_feeder(ros_env, tmp_path / 'node.log', ['-p', f'input_reliability:={mode}'],
                          points_depth=30, tracks_qos=tracker) as (proc, feeder):
        assert feeder.diagnostic_values()['input reliability'] == reliability
        messages, _ = frames_at_30hz(90)
        publish(feeder, messages)
        counts = feeder.accounted(int(0.95 * 90), timeout=30)
        assert counts is not None, (feeder.diagnostic_values(),
                                    (tmp_path / 'node.log').read_text())
        received = counts['messages received']
        if reliability == 'reliable' or tracker is RELIABLE_10:
            assert received == 90
        assert received >= 0.95 * 90
        assert feeder.wait_for(lambda: len(feeder.points) >= counts['frames published'], 10)
        assert counts['frames published'] >= 80


def test_qos_overrides_pin_the_input_reliability(ros_env, tmp_path):
    """An explicit qos_overrides reliability wins over input_reliability (and 'auto' then
    stops adapting): a best-effort override hears the reliable tracker best effort."""
    namespace = unique_namespace()
    override = f'qos_overrides.{namespace}/tracks.subscription.reliability:=best_effort'
    with node_with_feeder(ros_env, tmp_path / 'node.log', ['-p', override],
                          namespace=namespace, tracks_qos=RELIABLE_10) as (proc, feeder):
        time.sleep(2.5)                        # past two adaptation checks of 'auto'
        since = time.monotonic()
        assert feeder.wait_for(lambda: feeder.node_reports(since), 5)
        assert feeder.node_reports(since)['input reliability'] == 'best_effort'


def test_reset_drops_buffer_and_model_and_starts_a_new_sequence(ros_env, tmp_path):
    log = tmp_path / 'node.log'
    # each frame refined by its first window, no flush when the input pauses: what a reset
    # drops is the 5 frames buffered
    args = ['-p', 'refined_from:=first_window', '-p', 'flush_after:=0.0']
    with node_with_feeder(ros_env, log, args, points_depth=30) as (proc, feeder):
        client = feeder.node.create_client(Trigger, f'{feeder.node.get_namespace()}/'
                                           'grass_nrsfm/reset')
        assert client.wait_for_service(timeout_sec=10)
        messages, ids = frames_at_30hz(45)
        publish(feeder, messages)
        before = feeder.accounted(45)
        # every frame tracked and published; windows of 30, stride 10: frames 0-39 refined,
        # 40-44 buffered
        assert before['frames published'] == 45 and before['frames pending'] == 0, before
        values = feeder.diagnostic_values()
        assert values['frames refined'] == '40' and values['frames awaiting refinement'] == '5'
        future = client.call_async(Trigger.Request())
        assert feeder.wait_for(future.done, 10)
        answer = future.result()
        assert answer.success
        assert 'dropped 5 buffered frames' in answer.message
        assert 'the model of sequence 1' in answer.message
        assert 'sequence 2 starts' in answer.message
        since = time.monotonic()
        assert feeder.wait_for(lambda: feeder.node_reports(since).get('resets requested') == '1',
                               5)
        values = feeder.node_reports(since)
        assert values['sequences'] == '2' and values['frames not refined'] == '5'
        assert values['last reset'] == answer.message
        # the same tracker goes on (same ids, later stamps): a new sequence from the next frame
        more, _ = frames_at_30hz(40, first=45, seed=0)
        publish(feeder, more)
        after = feeder.accounted(85)
        assert after['frames published'] == 85 and after['frames lost'] == 0, after
        assert feeder.wait_for(lambda: len(feeder.points) >= 85, 10)
        stamps = sorted(stamp_of(m) for m in feeder.points)
        assert stamps[45:] == sorted(stamp_of(m) for m in more)
    text = log.read_text()
    assert text.count('reset: dropped 5 buffered frames') == 1, text


def test_rates_and_stamp_delay_in_diagnostics(ros_env, tmp_path):
    """Input and output frequency in diagnostic_updater's keys, OK at the expected 30 Hz and
    WARN against an expected 60 Hz; the newest output stamp's delay behind the clock."""
    with node_with_feeder(ros_env, tmp_path / 'node.log', points_depth=30) as (proc, feeder):
        namespace = feeder.node.get_namespace()
        level, message, _ = statuses(feeder)[f'{namespace}/tracks input frequency']
        assert (level, message) == (1, 'No events recorded.')
        W, _, ids = bending_sheet(F=180, noise=0.5)
        clock = rclpy.clock.Clock()
        messages = [cloud.encode_tracks(ids, uv.T, Header(frame_id='camera'))
                    for uv in as_frames(W, 2)]
        for msg in paced(messages, 1 / 30):            # 6 s at 30 Hz, stamped when sent
            msg.header.stamp = clock.now().to_msg()
            feeder.pub.publish(msg)
        during = statuses(feeder)              # the last report inside the stream
        counts = feeder.accounted(180)
    level, message, values = during[f'{namespace}/tracks input frequency']
    assert (level, message) == (0, 'Desired frequency met'), values
    assert abs(float(values['Actual frequency (Hz)']) - 30) < 3
    assert {'Events in window', 'Events since startup', 'Duration of window (s)',
            'Target frequency (Hz)', 'Minimum acceptable frequency (Hz)',
            'Maximum acceptable frequency (Hz)'} <= set(values)
    assert float(values['Minimum acceptable frequency (Hz)']) == pytest.approx(27.0)
    _, _, out = during[f'{namespace}/points output frequency']
    assert int(out['Events since startup']) > 0
    level, message, delay = during[f'{namespace}/points output timestamp delay']
    assert {'Earliest timestamp delay', 'Latest timestamp delay',
            'Newest timestamp delay'} <= set(delay)
    # stamps are the send time: a frame waits for its window (up to 30 frames, 1 s) and a solve
    assert 0 < float(delay['Newest timestamp delay']) < 5, delay
    assert counts['frames published'] >= 170


def test_mesh_marker_and_offered_qos_in_the_recording(ros_env, tmp_path):
    log = tmp_path / 'node.log'
    args = ['-p', 'publish_mesh:=true', '-p', f'record_path:={tmp_path}/rec']
    with node_with_feeder(ros_env, log, args, points_depth=30,
                          tracks_qos=qos_profile_sensor_data) as (proc, feeder):
        namespace = feeder.node.get_namespace()
        markers = []
        mesh_sub = feeder.node.create_subscription(Marker, 'mesh', markers.append, 10)
        assert feeder.wait_for(lambda: mesh_sub.get_publisher_count() == 1, 10)
        messages, ids = frames_at_30hz(60)
        publish(feeder, messages)
        assert feeder.wait_for(lambda: len(markers) >= 1 and len(feeder.refined) >= 50, 30), \
            log.read_text()
    marker = markers[-1]
    assert marker.type == Marker.TRIANGLE_LIST and marker.action == Marker.ADD
    n = len(marker.points)
    assert n > 0 and n % 3 == 0 and len(marker.colors) == n
    # the newest frame of a solved window, as points/refined published it
    same = next(m for m in feeder.refined if stamp_of(m) == stamp_of(marker))
    got_ids, xyz = cloud.decode_points(same)
    vertices = np.array([[p.x, p.y, p.z] for p in marker.points])
    # every vertex is a published point of that frame
    dist = np.linalg.norm(vertices[:, None, :] - xyz[None, :, :], axis=2).min(axis=1)
    assert dist.max() < 1e-4
    assert n // 3 > len(got_ids)              # a surface: about 2 triangles per point
    # the recording carries what each publisher offered, as rosbag2 (Jazzy) writes it
    info = yaml.safe_load((tmp_path / 'rec' / 'metadata.yaml').read_text())
    topics = {t['topic_metadata']['name']: t['topic_metadata']['offered_qos_profiles']
              for t in info['rosbag2_bagfile_information']['topics_with_message_count']}
    (tracks,) = topics[f'{namespace}/tracks']
    (points,) = topics[f'{namespace}/points']
    assert tracks['reliability'] == 'best_effort' and points['reliability'] == 'reliable'
    assert points['durability'] == tracks['durability'] == 'volatile'
    for profile in (tracks, points):
        assert set(profile) == {'history', 'depth', 'reliability', 'durability', 'deadline',
                                'lifespan', 'liveliness', 'liveliness_lease_duration',
                                'avoid_ros_namespace_conventions'}
        assert set(profile['deadline']) == {'sec', 'nsec'}
    with open(next((tmp_path / 'rec').glob('*.mcap')), 'rb') as f:
        channels = make_reader(f).get_summary().channels.values()
        in_mcap = {c.topic: yaml.safe_load(c.metadata['offered_qos_profiles']) for c in channels}
    assert in_mcap == topics
    with AnyReader([tmp_path / 'rec']) as reader:
        read = {c.topic: c.ext.offered_qos_profiles for c in reader.connections}
    assert read[f'{namespace}/tracks'][0].reliability == QosReliability.BEST_EFFORT
    assert read[f'{namespace}/points'][0].reliability == QosReliability.RELIABLE
    assert read[f'{namespace}/points'][0].depth == points['depth']
