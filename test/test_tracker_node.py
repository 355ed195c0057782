"""The tracker node over DDS: started in its own process (isolated domain, localhost
discovery, logs in a temporary folder), fed images of a textured scene moved by known shifts at
30 Hz from this process; its ``tracks`` checked against the shifts, every encoding, every kind
of bad image, ``~/reset``, and two namespaced camera -> tracker -> reconstruction pipelines in
one domain kept apart.

Images are 160 x 120 with a grid step of 8 px (about 300 tracks): these tests are about the
node's plumbing; bench/camera_pipeline.py measures 640 x 480.
"""
from pathlib import Path
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from doubles import paced
from grass_nrsfm_ros import cloud, image

rclpy = pytest.importorskip('rclpy')
cv2 = pytest.importorskip('cv2')
from builtin_interfaces.msg import Time  # noqa: E402, I100
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image, PointCloud2  # noqa: E402
from std_msgs.msg import Header  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402
from rosutil import RIGID_LAUNCH, SpunNode, stop, unique_namespace  # noqa: E402, I100

pytestmark = pytest.mark.ros
TEST_DIR = Path(__file__).resolve().parent
PERIOD = 1 / 30
H, W, STEP = 120, 160, 8
TRACKER = 'import sys; from grass_nrsfm_ros.tracker_node import main; sys.exit(main())'
#: a reliable image subscription with a long history: these tests account for every image
RELIABLE = ('-p', 'qos_overrides.{ns}/image.subscription.reliability:=reliable',
            '-p', 'qos_overrides.{ns}/image.subscription.depth:=100')


def texture(seed, height=H + 80, width=W + 80):
    """A smooth random texture (grey uint8) larger than the images cut from it."""
    rng = np.random.default_rng(seed)
    noise = rng.integers(0, 256, (height, width)).astype(np.uint8)
    return cv2.normalize(cv2.GaussianBlur(noise, (0, 0), 2.0), None, 0, 255, cv2.NORM_MINMAX)


def shift(f):
    """The view's offset (x, y) in frame ``f``: the scene moves by minus it in the image."""
    return np.array([10 + f, 10 + f // 2])


def view(canvas, f, height=H, width=W):
    x, y = shift(f)
    return np.ascontiguousarray(canvas[y:y + height, x:x + width])


def header(f, base_sec=1000):
    return Header(stamp=Time(sec=base_sec + f, nanosec=123), frame_id='cam_optical')


def stamp_of(msg):
    stamp = getattr(msg, 'header', msg).stamp
    return stamp.sec * 10 ** 9 + stamp.nanosec


def camera_info():
    return CameraInfo(header=Header(frame_id='cam_optical'), width=W, height=H,
                      k=[200.0, 0, 80, 0, 200, 60, 0, 0, 1], d=[0.0] * 5,
                      distortion_model='plumb_bob')


class Camera(SpunNode):
    """This process's side of one namespace: publishes ``image`` and ``camera_info``, keeps
    ``tracks``, ``points`` and the namespace's ``/diagnostics`` statuses by node name."""

    def __init__(self, namespace, context=None):
        super().__init__('camera', namespace, context)
        self.namespace = namespace
        self.image_pub = self.node.create_publisher(Image, 'image', 10)
        self.info_pub = self.node.create_publisher(CameraInfo, 'camera_info', 10)
        self.created = time.monotonic()
        self.tracks, self.points, self.statuses = [], [], {}
        self.tracks_sub = self.node.create_subscription(PointCloud2, 'tracks',
                                                        self.tracks.append, 100)
        self.points_sub = self.node.create_subscription(PointCloud2, 'points',
                                                        self.points.append, 100)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics,
                                      10)
        self.reset_client = self.node.create_client(
            Trigger, f'{namespace}/grass_nrsfm_tracker/reset')
        self.start()

    def _on_diagnostics(self, msg):
        """Keep the values of a node of our namespace (all its statuses in the message)."""
        values = {}
        for status in msg.status:
            node = status.hardware_id.rpartition('/')[2]
            if status.hardware_id == f'{self.namespace}/{node}':
                values.setdefault(node, {}).update({kv.key: kv.value for kv in status.values})
        for node, kept in values.items():
            self.statuses[node] = (time.monotonic(), kept)

    def values(self, node='grass_nrsfm_tracker'):
        """The newest diagnostics values of ``node`` sent after our publishers were made."""
        at, values = self.statuses.get(node, (0.0, {}))
        return values if at > self.created else {}

    def connected(self, reconstruction=False):
        """Both sides see each other: our image writer and tracks reader matched, and the
        tracker's diagnostics (sent after our writer was made) report our writer and reader
        (matching is not symmetric); with ``reconstruction``, also the reconstruction node
        and its points."""
        tracker = self.values()
        ok = (self.image_pub.get_subscription_count() >= 1
              and self.tracks_sub.get_publisher_count() >= 1
              and int(tracker.get('image publishers', 0)) >= 1
              and int(tracker.get('tracks subscribers', 0)) >= 1 + reconstruction)
        if reconstruction:
            node = self.values('grass_nrsfm')
            ok = ok and self.points_sub.get_publisher_count() >= 1 \
                and int(node.get('tracks publishers', 0)) >= 1 \
                and int(node.get('points subscribers', 0)) >= 1
        return ok

    def send(self, frames, period=PERIOD):
        """Publish ``frames`` (Image messages) at a camera's rate, camera_info beside each
        (unless ``self.info`` is None)."""
        for msg in paced(frames, period):
            if self.info is not None:
                self.info.header = msg.header
                self.info_pub.publish(self.info)
            self.image_pub.publish(msg)

    info = None


def start(ros_env, log, namespace, args=(), launch=TRACKER):
    """A node (``launch``: Python code run from test/) in ``namespace``, output in ``log``."""
    extra = [a.format(ns=namespace) for a in args]
    with open(log, 'w') as out:
        return subprocess.Popen(
            [sys.executable, '-c', launch, '--ros-args', '-r', f'__ns:={namespace}',
             '-p', f'step:={STEP}', *extra] if launch == TRACKER else
            [sys.executable, '-c', launch, '--ros-args', '-r', f'__ns:={namespace}', *extra],
            cwd=TEST_DIR, env=ros_env, stdout=out, stderr=subprocess.STDOUT)


@pytest.fixture
def tracker(ros_env, tmp_path, request):
    """The tracker node (extra ROS arguments: indirect parameter, ``{ns}`` its namespace) and
    a connected Camera; yields (process, log path, camera)."""
    namespace = unique_namespace()
    log = tmp_path / 'tracker.log'
    proc = start(ros_env, log, namespace, getattr(request, 'param', ()))
    camera = Camera(namespace)
    try:
        assert camera.wait_for(camera.connected, 60), log.read_text()
        yield proc, log, camera
    finally:
        camera.close()
        assert stop(proc) == 0, log.read_text()


def received(camera, n, log, timeout=30):
    """Wait for ``n`` tracks messages; return them decoded: [(stamp, ids, uv, msg)]."""
    assert camera.wait_for(lambda: len(camera.tracks) >= n, timeout), (
        len(camera.tracks), camera.values(), log.read_text())
    return [(stamp_of(m), *_decoded(m), m) for m in camera.tracks]


def _decoded(msg):
    tracks = cloud.decode_tracks(msg)
    return tracks.ids, tracks.uv


def motion_error(first, later, f0, f, height=H, width=W):
    """``(share, errors)``: the share of frame ``f0``'s tracks still in view at frame ``f``
    (the known shift, 4 px from the edges) that are alive there, and their pixel errors."""
    ids0, uv0 = first
    ids, uv = later
    moved = uv0 - (shift(f) - shift(f0))
    in_view = ((moved >= 4) & (moved <= [width - 5, height - 5])).all(axis=1).sum()
    common, i0, i1 = np.intersect1d(ids0, ids, return_indices=True)
    return common.size / in_view, np.linalg.norm(uv[i1] - moved[i0], axis=1)


def test_tracks_for_every_image_at_30hz(tracker):
    """Default (sensor data) QoS: every image the node receives gives a tracks message with
    its stamp and frame_id; the tracks follow the known shift."""
    proc, log, camera = tracker
    camera.info = camera_info()
    canvas = texture(1)
    camera.send([image.to_image(view(canvas, f), 'mono8', header(f)) for f in range(60)])
    assert camera.wait_for(lambda: camera.values().get('images received') == '60', 10), \
        (camera.values(), log.read_text())     # best effort on localhost: none lost
    got = received(camera, 60, log)
    assert [s for s, *_ in got] == [stamp_of(header(f)) for f in range(60)]
    assert all(m.header.frame_id == 'cam_optical' for *_, m in got)
    assert [f.name for f in got[0][3].fields] == ['track_id', 'u', 'v', 'age']
    n0 = got[0][1].size
    assert n0 >= 0.8 * (H // STEP) * (W // STEP), n0
    share, errors = motion_error(got[0][1:3], got[59][1:3], 0, 59)
    assert share >= 0.95 and np.median(errors) < 0.2 and errors.max() < 1.0, errors
    ages = cloud.structured_view(got[59][3], {'track_id': (cloud.UINT32,),
                                              'age': (cloud.UINT32,)})
    born_first = np.isin(ages['track_id'], got[0][1])
    assert (ages['age'][born_first] == 59).all()
    assert camera.wait_for(lambda: camera.values().get('frames published') == '60', 5)
    values = camera.values()
    assert values['camera'] == 'fx 200 fy 200 cx 80 cy 60'
    assert int(values['tracks alive']) == got[59][1].size
    assert float(values['latency p95 ms']) > 0 and float(values['stamp to tracks p50 ms']) > 0
    assert {'rate hz', 'tracks born', 'tracks lost', 'failed checks'} <= set(values)
    assert 'no camera_info' not in log.read_text()


def encoded(grey, f):
    """Frame ``f`` (grey uint8) in the f-th encoding of a cycle, some rows padded, mono16 in
    both byte orders: every encoding gives back the same grey image."""
    kind = f % 7
    rgb = np.dstack([grey] * 3)
    rgba = np.dstack([rgb, np.full_like(grey, 77)])
    pixels, encoding, layout = [
        (grey, 'mono8', {}), (grey.astype(np.uint16) * 257, 'mono16', {}),
        (grey.astype(np.uint16) * 257, 'mono16', {'bigendian': True, 'step': 2 * W + 6}),
        (rgb, 'rgb8', {'step': 3 * W + 8}), (rgb, 'bgr8', {}), (rgba, 'rgba8', {}),
        (rgba, 'bgra8', {'step': 4 * W + 4})][kind]
    return image.to_image(pixels, encoding, header(f), **layout)


@pytest.mark.parametrize('tracker', [RELIABLE], indirect=True)
def test_every_encoding_over_dds(tracker):
    proc, log, camera = tracker
    canvas = texture(2)
    camera.send([encoded(view(canvas, f), f) for f in range(14)])
    got = received(camera, 14, log)
    assert [s for s, *_ in got] == [stamp_of(header(f)) for f in range(14)]
    for f in range(1, 14):             # one sequence: the same tracks through every encoding
        share, errors = motion_error(got[0][1:3], got[f][1:3], 0, f)
        assert share >= 0.95 and np.median(errors) < 0.2, (f, errors)
    assert 'skipped' not in log.read_text()


def bad(kind, canvas, f):
    """A broken or untrackable image (stamp ``f``) of kind ``kind``."""
    msg = image.to_image(view(canvas, f), 'mono8', header(f))
    if kind == 'encoding':
        msg.encoding = 'yuv422'
    elif kind == 'truncated':
        msg.data = bytes(msg.data)[:-10]
    elif kind == 'empty':
        msg = Image(header=header(f), encoding='mono8')
    elif kind == 'black':
        msg = image.to_image(np.full((H, W), 2, np.uint8), 'mono8', header(f))
    elif kind == 'saturated':
        msg = image.to_image(np.full((H, W), 255, np.uint8), 'mono8', header(f))
    return msg


LOG_LINES = {'encoding': "unsupported encoding 'yuv422'", 'truncated': 'data has',
             'empty': 'empty image (0 x 0)', 'black': 'black image at',
             'saturated': 'saturated image at',
             'size': 'image size changed from 160 x 120 to 128 x 96',
             'camera': 'no camera_info on'}


@pytest.mark.parametrize('tracker', [RELIABLE], indirect=True)
def test_bad_images_are_said_once_and_the_tracks_go_on(tracker):
    proc, log, camera = tracker
    canvas = texture(3)
    kinds = ('encoding', 'truncated', 'empty', 'black', 'saturated')
    messages, good = [], []
    for f in range(12):
        if 2 <= f < 2 + len(kinds):
            messages.append(bad(kinds[f - 2], canvas, 100 + f))
        messages.append(image.to_image(view(canvas, f), 'mono8', header(f)))
        good.append(f)
    for f in range(12, 18):           # the camera switches to a smaller size
        messages.append(image.to_image(view(canvas, f, 96, 128), 'mono8', header(f)))
        good.append(f)
    camera.send(messages)
    got = received(camera, len(good), log)
    assert [s for s, *_ in got] == [stamp_of(header(f)) for f in good]
    assert proc.poll() is None
    # one sequence through the bad images: the first frame's tracks followed to frame 11
    share, errors = motion_error(got[0][1:3], got[11][1:3], 0, 11)
    assert share >= 0.95 and np.median(errors) < 0.2
    # a new size: new tracks, new ids
    assert got[12][1].min() > max(ids.max() for _, ids, *_ in got[:12])
    assert camera.wait_for(lambda: camera.values().get('images received') ==
                           str(len(messages)), 10), camera.values()
    values = camera.values()
    assert (values['frames skipped (bad image)'], values['frames skipped (black)'],
            values['frames skipped (saturated)'], values['size changes'],
            values['frames published']) == ('3', '1', '1', '1', str(len(good)))
    text = log.read_text()
    for kind, line in LOG_LINES.items():
        assert text.count(line) == 1, (kind, text)


def test_reset_service_starts_new_tracks(tracker):
    proc, log, camera = tracker
    canvas = texture(4)
    camera.send([image.to_image(view(canvas, f), 'mono8', header(f)) for f in range(5)])
    before = received(camera, 5, log)
    assert camera.reset_client.wait_for_service(timeout_sec=10)
    answer = camera.reset_client.call_async(Trigger.Request())
    assert camera.wait_for(answer.done, 10)
    assert answer.result().success
    assert f'dropped {before[4][1].size} tracks' in answer.result().message
    camera.send([image.to_image(view(canvas, f), 'mono8', header(f)) for f in range(5, 8)])
    after = received(camera, 8, log)
    assert after[5][1].min() > before[4][1].max()            # ids are never reused
    share, errors = motion_error(after[5][1:3], after[7][1:3], 5, 7)
    assert share >= 0.95 and np.median(errors) < 0.2


def test_two_namespaced_pipelines_keep_their_streams_apart(ros_env, tmp_path):
    """/cam_a and /cam_b, each camera -> tracker -> reconstruction node (rigid stand-in
    solver; with the mapping processes, six processes beside this one on two cores), in one
    domain: every image of each gives tracks and points in its own namespace only, and the
    points hold the tracks' ids. The image subscriptions are reliable here: this test is
    about the names."""
    base = unique_namespace()
    spaces = {'a': f'{base}/cam_a', 'b': f'{base}/cam_b'}
    bases = {'a': 1000, 'b': 5000}                  # stamps tell the streams apart
    procs, cameras = [], {}
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        for key, ns in spaces.items():
            procs.append((start(ros_env, tmp_path / f'tracker_{key}.log', ns, RELIABLE), key))
            procs.append((start(ros_env, tmp_path / f'node_{key}.log', ns,
                                ['-p', 'context_frames:=0'], launch=RIGID_LAUNCH), key))
            cameras[key] = Camera(ns, context=context)
            cameras[key].info = camera_info()      # the node waits for it (up to 1 s)
        for camera in cameras.values():
            assert camera.wait_for(lambda c=camera: c.connected(reconstruction=True), 90), (
                camera.values(), camera.values('grass_nrsfm'),
                ''.join(p.read_text() for p in tmp_path.glob('*.log')))
        frames = {key: [image.to_image(view(texture(10 + i), f), 'mono8',
                                       header(f, bases[key])) for f in range(40)]
                  for i, key in enumerate(cameras)}
        senders = [threading.Thread(target=cameras[k].send, args=(frames[k],))
                   for k in cameras]
        for sender in senders:
            sender.start()
        for sender in senders:
            sender.join()
        for key, camera in cameras.items():
            expected = [stamp_of(m) for m in frames[key]]
            assert camera.wait_for(lambda c=camera: len(c.tracks) >= 40 and
                                   len(c.points) >= 40, 60), (
                key, len(camera.tracks), len(camera.points), camera.values(),
                camera.values('grass_nrsfm'))
            assert [stamp_of(m) for m in camera.tracks] == expected
            points = {stamp_of(m): m for m in camera.points}
            assert sorted(points) == expected                  # nothing of the other camera
            for msg in camera.tracks[::13]:
                ids, _ = cloud.decode_points(points[stamp_of(msg)])
                assert set(ids) <= set(cloud.decode_tracks(msg).ids) and ids.size >= 100
    finally:
        for camera in cameras.values():
            camera.close()
        rclpy.shutdown(context=context)
        codes = [(key, stop(proc)) for proc, key in procs]
    assert all(code == 0 for _, code in codes), codes


def test_cli_starts_and_stops_the_tracker(ros_env, tmp_path):
    """``grass-nrsfm tracker --ros-args ...``: the start-up line, exit code 0 on Ctrl-C; an
    unreadable mask: one error line, exit code 2."""
    namespace = unique_namespace()
    cli = [sys.executable, '-m', 'grass_nrsfm_ros.cli', 'tracker', '--ros-args']
    proc = subprocess.Popen([*cli, '-r', f'__ns:={namespace}', '-p', 'roi:=[8, 8, 100, 90]'],
                            env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)
    watchdog = threading.Timer(60, proc.kill)
    watchdog.start()
    first = proc.stdout.readline()           # the start-up line, once the node is up
    watchdog.cancel()
    assert 'step 4 px, roi [8, 8, 100, 90]' in first, first
    assert stop(proc) == 0, first + proc.stdout.read()
    bad = subprocess.run([*cli, '-p', f'mask:={tmp_path}/none.png'], env=ros_env,
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2
    assert bad.stderr.strip().splitlines()[-1] == \
        f"grass_nrsfm tracker: error: mask '{tmp_path}/none.png': no such file"
