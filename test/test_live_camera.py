"""Camera intrinsics in the live pipeline (node, bags): pixels normalised on arrival, every
published frame through the pinhole (``K [X/Z, Y/Z, 1]`` = its pixels, each frame's mean depth
``scene_depth``), a change of intrinsics a new sequence, ``reconstruct BAG`` reading the bag's
camera_info, and the ``camera`` parameter. Pinhole ground truth: a synthetic inflating surface
2.5 units in front of the camera."""
import time
import warnings

import numpy as np
import pytest

from grass_nrsfm_ros import bag, params
from grass_nrsfm_ros.cli import main
from grass_nrsfm_ros.commands.demo import results_e3d
from grass_nrsfm_ros.commands.track import camera_info_message, CAMERA_INFO_TOPIC, \
    CAMERA_INFO_TYPE
from grass_nrsfm_ros.image import camera_from_intrinsics
from grass_nrsfm_ros.nrsfm import camera, synthetic
from grass_nrsfm_ros.nrsfm.camera import OrthographicPixelsWarning
from grass_nrsfm_ros.nrsfm.measurement import as_frames, from_frames
from grass_nrsfm_ros.nrsfm.perspective import flat_depths, low_rank_sign
from grass_nrsfm_ros.pipeline import make_pipeline, pinhole_points, reconstruct_live
from grass_nrsfm_ros.windowing import FrameError

F, P, DISTANCE = 60, 200, 2.5
FX, FY, CX, CY = 500.0, 520.0, 320.0, 240.0
K = camera.intrinsics(FX, FY, CX, CY)
SMALL = dict(window_size=20, window_stride=10, context_frames=20, key_frames=10)


def pinhole_surface(kind='inflating', n_points=P):
    """Camera-frame shapes ``(3F, P)`` of a synthetic surface DISTANCE in front of the camera."""
    seq = synthetic.make_sequence(kind, n_frames=F, n_points=n_points, camera='orbit', seed=1)
    X = as_frames(seq.S, 3).copy()
    X[:, 2] += DISTANCE
    return from_frames(X)


@pytest.fixture(scope='module')
def pinhole():
    """``(S: (3F, P) camera frame, W: (2F, P) pixels, stamps: (F,), frames)``."""
    S = pinhole_surface()
    W = camera.project(S, K)
    ids = np.arange(P, dtype=np.uint32)
    stamps = np.arange(F, dtype=np.int64) * 33_333_333 + 10 ** 18
    return S, W, stamps, [(ids, W[2 * f:2 * f + 2].T) for f in range(F)]


def live(pinhole, **kwargs):
    S, W, stamps, frames = pinhole
    config = {**params.defaults(), **SMALL, **kwargs.pop('config', {})}
    pipeline = make_pipeline(config, **kwargs)
    try:
        return reconstruct_live(pipeline, stamps, frames)
    finally:
        pipeline.close()


@pytest.fixture(scope='module')
def with_k(pinhole):
    return live(pinhole, camera=K, config={'scene_depth': 2.0})


def test_every_frame_goes_out_through_the_pinhole(pinhole, with_k):
    S, W, stamps, _ = pinhole
    points, refined, _ = with_k
    assert len(points) == F and len(refined) == F
    frame_of = {int(s): f for f, s in enumerate(stamps)}
    for result in points + refined:
        f = frame_of[result.stamp_ns]
        X = result.xyz
        assert (X[:, 2] > 0).all()
        assert X[:, 2].mean() == pytest.approx(2.0, rel=1e-12)       # scene_depth
        uv = X[:, :2] / X[:, 2:] * [FX, FY] + [CX, CY]
        np.testing.assert_allclose(uv, W[2 * f:2 * f + 2, result.ids].T, atol=1e-9)


def test_k_makes_the_live_points_better_than_pixels_as_orthographic(pinhole, with_k):
    S, _, stamps, frames = pinhole
    ids = frames[0][0]
    with pytest.warns(OrthographicPixelsWarning):
        plain = live(pinhole)
    ours = [results_e3d(r, stamps, ids, S) for r in with_k[:2]]
    theirs = [results_e3d(r, stamps, ids, S) for r in plain[:2]]
    # measured (points, refined): 0.264, 0.242 with K; 0.278, 0.269 pixels as orthographic
    assert ours[0] < theirs[0] and ours[1] < 0.95 * theirs[1], (ours, theirs)


def test_pixels_without_k_are_said_once_per_pipeline(pinhole):
    """Without K the pipeline says so once, whatever resets Python's warnings registry on the
    way (libraries' catch_warnings do: the quick start's demo printed it 4 times, now once)."""
    _, _, stamps, frames = pinhole
    pipeline = make_pipeline({**params.defaults(), **SMALL})
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter('always')
            for stamp, (ids, uv) in zip(stamps[:5], frames[:5]):
                pipeline.add_frame(int(stamp), ids, uv)
    finally:
        pipeline.close()
    assert [w.category for w in caught] == [OrthographicPixelsWarning]


@pytest.mark.parametrize('kind, n_points', [('inflating', 200), ('bending', 300)])
def test_low_rank_sign_tells_the_true_depths_from_their_mirror(kind, n_points):
    S = pinhole_surface(kind, n_points)
    Z = as_frames(S, 3)[:, 2]
    delta = Z / Z.mean(axis=1, keepdims=True) - 1.0
    x = camera.project(S)
    assert low_rank_sign(x, delta) == 1.0 and low_rank_sign(x, -delta) == -1.0


def true_depth_agreement(results, S, stamps):
    """Median over frames of the correlation of the published depths with the true ones."""
    frame_of = {int(s): f for f, s in enumerate(stamps)}
    depth = [S[3 * frame_of[r.stamp_ns] + 2, r.ids.astype(int)] for r in results]
    return np.median([np.corrcoef(r.xyz[:, 2], z)[0, 1] for r, z in zip(results, depth)])


def test_the_depth_sign_is_the_true_one(pinhole, with_k):
    S, _, stamps, _ = pinhole
    assert true_depth_agreement(with_k[1], S, stamps) > 0.8           # measured 0.87
    bending = pinhole_surface('bending', 300)
    W = camera.project(bending, K)
    ids = np.arange(300, dtype=np.uint32)
    _, refined, updates = live((bending, W, stamps,
                                [(ids, W[2 * f:2 * f + 2].T) for f in range(F)]), camera=K)
    # its first window comes back flat (depths ~1e-15): no sign from it, the next one decides
    first = updates[0].results
    rows = np.array([[2 * f, 2 * f + 1] for f in np.searchsorted(stamps, [r.stamp_ns
                                                                          for r in first])])
    assert flat_depths(np.stack([r.xyz[:, 2] for r in first]),
                       camera.normalise(W, K)[rows.ravel()])
    assert true_depth_agreement(refined, bending, stamps) > 0.8        # measured 0.89


def test_the_camera_parameter_and_a_change_of_intrinsics(pinhole):
    S, W, stamps, frames = pinhole
    config = {**params.defaults(), **SMALL, 'camera': [FX, FY, CX, CY]}
    pipeline = make_pipeline(config)
    try:
        np.testing.assert_array_equal(pipeline.camera, K)
        for f in range(5):
            pipeline.add_frame(int(stamps[f]), *frames[f])
        assert pipeline.set_camera(K.copy()) is False                # the same: nothing
        assert pipeline.windowing.buffered_fresh == 5
        assert pipeline.set_camera(camera.intrinsics(600, 600, 320, 240)) is True
        assert pipeline.windowing.buffered_fresh == 0                # a new sequence
        (result,) = pipeline.add_frame(int(stamps[5]), *frames[5])
        assert result.xyz[:, 2].mean() == pytest.approx(1.0)
    finally:
        pipeline.close()


def test_perspective_without_k_refuses_frames_clearly(pinhole):
    config = {**params.defaults(), **SMALL, 'solver.projection': 'perspective'}
    pipeline = make_pipeline(config)
    try:
        with pytest.raises(FrameError, match="'perspective' needs camera intrinsics"):
            pipeline.add_frame(int(pinhole[2][0]), *pinhole[3][0])
    finally:
        pipeline.close()


@pytest.mark.parametrize('value, message', [
    ([1.0, 2.0, 3.0], 'expected [fx, fy, cx, cy]'), ([0.0, 500.0, 320.0, 240.0], 'fx, fy > 0'),
    (['a', 1, 2, 3], 'expected [fx, fy, cx, cy]'), ([np.inf, 5, 3, 2], 'finite')])
def test_bad_camera_parameter(value, message):
    with pytest.raises(ValueError, match=message.replace('[', r'\[').replace(']', r'\]')):
        params.validate({'camera': value})


def test_pinhole_points_keep_the_ray():
    rays = np.array([[0.1, -0.2], [0.0, 0.0], [-0.3, 0.05]])
    xyz = np.array([[9.0, 9.0, 0.2], [9.0, 9.0, -0.1], [9.0, 9.0, -2.0]])
    out = pinhole_points(xyz, rays, 3.0)
    np.testing.assert_allclose(out[:, 2], [3.6, 2.7, 0.3])           # clamped at 0.1 * 3
    np.testing.assert_allclose(out[:, :2] / out[:, 2:], rays)


def tracks_bag(path, W, stamps, with_camera=True):
    with bag.BagWriter(path) as writer:
        if with_camera:
            writer.add_topic(CAMERA_INFO_TOPIC, CAMERA_INFO_TYPE)
        ids = np.arange(W.shape[1], dtype=np.uint32)
        for f, stamp in enumerate(stamps):
            writer.write_tracks(ids, W[2 * f:2 * f + 2].T, int(stamp), 'camera_optical')
            if with_camera:
                writer.write(CAMERA_INFO_TOPIC, camera_info_message(
                    camera_from_intrinsics(FX, FY, CX, CY), int(stamp), 'camera_optical',
                    (480, 640)), int(stamp))


def test_reconstruct_bag_takes_k_from_its_camera_info(pinhole, tmp_path, capsys):
    S, W, stamps, _ = pinhole
    tracks_bag(tmp_path / 'tracks', W, stamps)
    config = tmp_path / 'small.yaml'
    config.write_text(''.join(f'{k}: {v}\n' for k, v in SMALL.items()))
    with warnings.catch_warnings():
        warnings.simplefilter('error', OrthographicPixelsWarning)
        assert main(['reconstruct', str(tmp_path / 'tracks'), '-o', str(tmp_path / 'out'),
                     '--config', str(config), '--quiet', '--scale', '2']) == 0
    assert 'K from the bag topic /camera_info' in capsys.readouterr().out
    S_out, ids, _ = bag.read_S(tmp_path / 'out', bag.REFINED_TOPIC)
    W32 = W.astype(np.float32).astype(np.float64)                     # the clouds' u, v
    _, refined, _ = live((S, W32, stamps, [(ids, W32[2 * f:2 * f + 2].T) for f in range(F)]),
                         camera=K, config={'scene_depth': 2.0})
    expected = np.full_like(S_out, np.nan)
    for r in refined:
        f = int(np.flatnonzero(stamps == r.stamp_ns)[0])
        expected[3 * f:3 * f + 3, np.searchsorted(ids, r.ids)] = r.xyz.T
    np.testing.assert_allclose(S_out, expected, rtol=1e-6, atol=1e-6)   # float32 clouds
    # the same bag without camera_info: pixels as orthographic projections, said once
    tracks_bag(tmp_path / 'plain', W, stamps, with_camera=False)
    with pytest.warns(OrthographicPixelsWarning):
        assert main(['reconstruct', str(tmp_path / 'plain'), '-o', str(tmp_path / 'out2'),
                     '--config', str(config), '--quiet']) == 0
    assert main(['reconstruct', str(tmp_path / 'plain'), '-o', str(tmp_path / 'out3'),
                 '--config', str(config), '--quiet', '--scale', '2']) == 2
    assert '--scale applies to the perspective model' in capsys.readouterr().err


# -- the node over DDS: camera_info and the camera parameter ------------------------------------
def node_frames(pinhole, count):
    from builtin_interfaces.msg import Time
    from std_msgs.msg import Header
    from grass_nrsfm_ros import cloud
    S, W, stamps, frames = pinhole
    out = []
    for f in range(count):
        ns = int(stamps[f])
        header = Header(stamp=Time(sec=ns // 10 ** 9, nanosec=ns % 10 ** 9), frame_id='cam')
        out.append((header, cloud.encode_tracks(frames[f][0], frames[f][1], header)))
    return out


def through_the_pinhole(feeder, pinhole, least):
    """Every ``points`` cloud received: its pixels through K are the frame's tracks."""
    from grass_nrsfm_ros import cloud
    S, W, stamps, _ = pinhole
    assert feeder.wait_for(lambda: len(feeder.points) >= least, 60)
    for msg in list(feeder.points):
        f = int(np.flatnonzero(stamps == msg.header.stamp.sec * 10 ** 9
                               + msg.header.stamp.nanosec)[0])
        ids, xyz = cloud.decode_points(msg)
        assert xyz[:, 2].mean() == pytest.approx(1.0, rel=1e-5)
        uv = xyz[:, :2] / xyz[:, 2:] * [FX, FY] + [CX, CY]
        np.testing.assert_allclose(uv, W[2 * f:2 * f + 2, ids.astype(int)].T, atol=2e-3)


def matched_camera_info_publisher(feeder):
    """A sensor-data QoS ``camera_info`` publisher on ``feeder``'s node, once the node under
    test reports it (matching is not symmetric: the node itself must have seen it)."""
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import CameraInfo
    created = time.monotonic()
    publisher = feeder.node.create_publisher(CameraInfo, 'camera_info', qos_profile_sensor_data)
    assert feeder.wait_for(lambda: publisher.get_subscription_count() > 0 and int(
        feeder.node_reports(created).get('camera_info publishers', 0)) >= 1, 20)
    return publisher


@pytest.mark.ros
def test_node_takes_k_from_camera_info(ros_env, tmp_path, pinhole):
    pytest.importorskip('rclpy')
    from sensor_msgs.msg import CameraInfo
    from doubles import paced
    from rosutil import node_with_feeder
    log = tmp_path / 'node.log'
    with node_with_feeder(ros_env, log, ['-p', 'window_size:=20', '-p', 'window_stride:=10'],
                          points_depth=30) as (proc, feeder):
        info_pub = matched_camera_info_publisher(feeder)
        for header, tracks in paced(node_frames(pinhole, 30), 1 / 30):    # a camera's rate
            info_pub.publish(CameraInfo(header=header, width=640, height=480,
                                        k=[FX, 0.0, CX, 0.0, FY, CY, 0.0, 0.0, 1.0]))
            feeder.publish(tracks)
        through_the_pinhole(feeder, pinhole, 20)
    assert 'camera_info: fx 500, fy 520, cx 320, cy 240' in log.read_text()


@pytest.mark.ros
def test_node_takes_k_from_its_camera_parameter(ros_env, tmp_path, pinhole):
    pytest.importorskip('rclpy')
    from rosutil import node_with_feeder, publish
    log = tmp_path / 'node.log'
    with node_with_feeder(ros_env, log, ['-p', f'camera:=[{FX}, {FY}, {CX}, {CY}]'],
                          points_depth=30) as (proc, feeder):
        publish(feeder, [tracks for _, tracks in node_frames(pinhole, 25)])
        through_the_pinhole(feeder, pinhole, 25)
    assert 'no camera intrinsics' not in log.read_text()


@pytest.mark.ros
def test_a_silent_camera_info_publisher_holds_tracks_back_one_second(
        ros_env, tmp_path, pinhole):
    """A camera_info publisher that never publishes: the tracks of the first second (stamps)
    are dropped, said once; then they go out as pixels (orthographic, said once)."""
    pytest.importorskip('rclpy')
    from rosutil import node_with_feeder, publish
    from grass_nrsfm_ros import node
    log = tmp_path / 'node.log'
    frames = node_frames(pinhole, 15)
    for f, (header, tracks) in enumerate(frames):       # 0.1 s apart: frames 10..14 after 1 s
        stamp = 10 ** 18 + f * 100_000_000
        header.stamp.sec, header.stamp.nanosec = divmod(stamp, 10 ** 9)
        tracks.header.stamp = header.stamp
    with node_with_feeder(ros_env, log, ['-p', 'window_size:=20', '-p', 'window_stride:=10'],
                          points_depth=30) as (proc, feeder):
        matched_camera_info_publisher(feeder)        # it never publishes; its node holds it
        publish(feeder, [tracks for _, tracks in frames])
        assert feeder.wait_for(lambda: len(feeder.points) >= 5, 60), log.read_text()
        assert feeder.wait_for(
            lambda: int(feeder.diagnostic_values().get('dropped messages', -1)) == 10, 30)
    assert node.CAMERA_INFO_WAIT_S == 1.0
    stamps = sorted(m.header.stamp.sec * 10 ** 9 + m.header.stamp.nanosec
                    for m in feeder.points)
    assert stamps == [10 ** 18 + f * 100_000_000 for f in range(10, 15)]
    text = log.read_text()
    assert text.count('before the first camera_info') == 1
    assert text.count('no camera intrinsics (K)') == 1
