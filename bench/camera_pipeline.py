"""Camera to 3D over DDS: images at 30 Hz -> tracker node -> reconstruction node -> ``points``,
each node in its own process (isolated domain, localhost), images published from this process.

Figures: the share of images that come back as ``points`` (and as ``tracks``), and the latency
from an image's stamp (the wall clock when it is published) to the receipt here of its tracks
and of its points (p50 / p95 / max, all frames and after the first 2 s); the nodes' own
figures from ``/diagnostics`` (tracker latency, tracks alive). Images: a rendered textured
bending sheet (grass_nrsfm_ros.frontend.scenes, 640 x 480 rgb8, played forwards and backwards),
its frame-0 mask as the tracker's ``mask``, camera_info beside each image. Every process (this
one stands for the camera driver) gets the Fast DDS profile that camera.launch.py sets,
``config/fastdds_large_images.xml``, unless ``--dds-profile ''`` (Fast DDS's defaults).

    python -m bench.camera_pipeline                      # 20 s, step 8, the shipped solver
    python -m bench.camera_pipeline --seconds 10 --step 4 --solver rigid

Results go to ``bench/results/camera_pipeline.json`` (and are printed). The machine's load
average is recorded: the figures are wall-clock latencies on a shared 2-core machine.
"""
import argparse
import json
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time

import cv2
import numpy as np

from grass_nrsfm_ros import image
from grass_nrsfm_ros.frontend import scenes
from . import common
from .load import DEFAULT_LAUNCH, isolated_env

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / 'test'))          # the node-over-DDS helpers of the tests
import rosutil  # noqa: E402, I100
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402, I100
from sensor_msgs.msg import CameraInfo, Image, PointCloud2  # noqa: E402
from std_msgs.msg import Header  # noqa: E402

RESULTS = REPO / 'bench' / 'results' / 'camera_pipeline.json'
TRACKER_LAUNCH = 'import sys; from grass_nrsfm_ros.tracker_node import main; sys.exit(main())'
NAMESPACE = '/bench_camera'
WARMUP_S = 2.0
DDS_PROFILE = REPO / 'config' / 'fastdds_large_images.xml'


class Endpoint(rosutil.SpunNode):
    """This process's side: publishes ``image`` and ``camera_info``; notes when each stamp's
    ``tracks`` and ``points`` arrive, and the nodes' newest diagnostics."""

    def __init__(self):
        super().__init__('camera', NAMESPACE)
        self.image_pub = self.node.create_publisher(Image, 'image', 10)
        self.info_pub = self.node.create_publisher(CameraInfo, 'camera_info', 10)
        self.tracks_at, self.points_at, self.tracks_sizes, self.diagnostics = {}, {}, [], {}
        self.tracks_sub = self.node.create_subscription(PointCloud2, 'tracks',
                                                        self._on_tracks, 100)
        self.points_sub = self.node.create_subscription(PointCloud2, 'points',
                                                        self._on_points, 100)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, 10)
        self.start()

    @staticmethod
    def _stamp(msg):
        return msg.header.stamp.sec * 10 ** 9 + msg.header.stamp.nanosec

    def _on_tracks(self, msg):
        self.tracks_at[self._stamp(msg)] = time.time_ns()
        self.tracks_sizes.append(msg.width * msg.height)

    def _on_points(self, msg):
        self.points_at.setdefault(self._stamp(msg), time.time_ns())

    def _on_diagnostics(self, msg):
        for status in msg.status:
            if status.hardware_id.startswith(NAMESPACE + '/'):
                node = status.hardware_id.rpartition('/')[2]
                self.diagnostics.setdefault(node, {}).update(
                    {kv.key: kv.value for kv in status.values})

    def connected(self):
        tracker = self.diagnostics.get('grass_nrsfm_tracker', {})
        node = self.diagnostics.get('grass_nrsfm', {})
        return (self.image_pub.get_subscription_count() >= 1
                and self.points_sub.get_publisher_count() >= 1
                and int(tracker.get('image publishers', 0)) >= 1
                and int(tracker.get('tracks subscribers', 0)) >= 2
                and int(node.get('tracks publishers', 0)) >= 1
                and int(node.get('points subscribers', 0)) >= 1)


def rendered(n_frames, encoding, size):
    """Image messages of a bending sheet (forwards then backwards: a loop without a jump), its
    frame-0 mask (H, W) bool and its CameraInfo."""
    scene = scenes.sheet_scene('bending', n_frames=n_frames, size=size)
    frames = list(scene.frames())
    frames += frames[-2:0:-1]
    if encoding == 'mono8':
        frames = [cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in frames]
    messages = [image.to_image(f, encoding, Header(frame_id='camera_optical')) for f in frames]
    info = CameraInfo(header=Header(frame_id='camera_optical'), height=size[0], width=size[1],
                      k=scene.K.reshape(-1).tolist(), d=[0.0] * 5, distortion_model='plumb_bob')
    return messages, scene.mask(0), info


def percentiles(ns_values):
    """p50 / p95 / max in ms of latencies in ns (None when there are none)."""
    if not ns_values:
        return None
    ms = np.asarray(ns_values, float) * 1e-6
    p50, p95 = np.percentile(ms, [50, 95])
    return dict(p50=round(p50, 1), p95=round(p95, 1), max=round(ms.max(), 1), n=ms.size)


def latencies(sent, received, after_ns=None):
    """Latencies (ns) of the stamps in ``sent`` (stamps, ns) received (stamp -> receipt ns),
    only stamps after ``after_ns`` if given."""
    return [received[s] - s for s in sent
            if s in received and (after_ns is None or s >= after_ns)]


def start_node(launch, args, env, log):
    with open(log, 'w') as out:
        return subprocess.Popen([sys.executable, '-c', launch, '--ros-args',
                                 '-r', f'__ns:={NAMESPACE}', *args],
                                cwd=REPO / 'test', env=env, stdout=out,
                                stderr=subprocess.STDOUT)


def run(seconds=20.0, step=8, method=None, solver='grassmann', encoding='rgb8',
        size=(480, 640), rate=30.0, frames=45, image_depth=None, dds_profile=DDS_PROFILE,
        log=common.log):
    """Run the pipeline once; return the figures. ``image_depth``: the tracker's image
    history (None: its default, 5); ``dds_profile``: a Fast DDS XML profile for every
    process (None or '': Fast DDS's defaults)."""
    tmp = Path(tempfile.mkdtemp(prefix='grass_camera_'))
    if dds_profile:
        os.environ['FASTRTPS_DEFAULT_PROFILES_FILE'] = str(dds_profile)
    else:
        os.environ.pop('FASTRTPS_DEFAULT_PROFILES_FILE', None)
    env = isolated_env(tmp)
    log(f'rendering {frames} frames of {size[1]} x {size[0]}')
    messages, mask, info = rendered(frames, encoding, size)
    cv2.imwrite(str(tmp / 'mask.png'), mask.astype(np.uint8) * 255)
    tracker_args = ['-p', f'step:={step}', '-p', f'mask:={tmp / "mask.png"}']
    if method:
        tracker_args += ['-p', f'method:={method}']
    if image_depth:
        tracker_args += ['-p', f'qos_overrides.{NAMESPACE}/image.subscription.depth:='
                         f'{image_depth}']
    procs = [start_node(TRACKER_LAUNCH, tracker_args, env, tmp / 'tracker.log'),
             start_node(rosutil.RIGID_LAUNCH if solver == 'rigid' else DEFAULT_LAUNCH,
                        ['-p', 'context_frames:=0'] if solver == 'rigid' else [], env,
                        tmp / 'node.log')]
    endpoint = Endpoint()
    try:
        if not endpoint.wait_for(endpoint.connected, 120):
            raise RuntimeError('the nodes did not connect: ' + ''.join(
                (tmp / f).read_text() for f in ('tracker.log', 'node.log')))
        n_total = int(round(seconds * rate))
        sent, late = [], 0
        load_before = os.getloadavg()
        start = time.monotonic()
        for k in range(n_total):
            due = start + k / rate
            now = time.monotonic()
            if now < due:
                time.sleep(due - now)
            elif now - due > 1 / rate:
                late += 1
            msg = messages[k % len(messages)]
            stamp = time.time_ns()
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 10 ** 9)
            info.header.stamp = msg.header.stamp
            endpoint.info_pub.publish(info)
            endpoint.image_pub.publish(msg)
            sent.append(stamp)
        endpoint.wait_for(lambda: len(endpoint.points_at) >= n_total, 10)
        tracker = dict(endpoint.diagnostics.get('grass_nrsfm_tracker', {}))
        node = dict(endpoint.diagnostics.get('grass_nrsfm', {}))
        load_after = os.getloadavg()
    finally:
        endpoint.close()
        codes = [rosutil.stop(p) for p in procs]
    steady = sent[0] + int(WARMUP_S * 1e9)
    points_back = sum(s in endpoint.points_at for s in sent)
    tracks_back = sum(s in endpoint.tracks_at for s in sent)
    return dict(
        seconds=seconds, rate=rate, size=list(size), encoding=encoding, step=step,
        method=method or 'default', solver=solver, image_depth=image_depth or 5,
        dds_profile=Path(dds_profile).name if dds_profile else 'Fast DDS defaults',
        sent=n_total,
        sends_late_by_more_than_a_period=late,
        tracks_back=tracks_back, points_back=points_back,
        share_points_back=round(points_back / n_total, 4),
        share_tracks_back=round(tracks_back / n_total, 4),
        tracks_per_frame_median=int(np.median(endpoint.tracks_sizes))
        if endpoint.tracks_sizes else 0,
        image_to_tracks_ms=percentiles(latencies(sent, endpoint.tracks_at)),
        image_to_points_ms=percentiles(latencies(sent, endpoint.points_at)),
        image_to_points_after_warmup_ms=percentiles(latencies(sent, endpoint.points_at,
                                                              steady)),
        tracker_diagnostics={k: tracker.get(k) for k in (
            'images received', 'frames published', 'latency p50 ms', 'latency p95 ms',
            'tracks alive', 'failed checks', 're-anchored')},
        node_diagnostics={k: node.get(k) for k in (
            'messages received', 'frames published', 'tracking latency p50 ms',
            'tracking latency p95 ms', 'windows solved', 'frames from a sheet model')},
        load_average_before=[round(x, 2) for x in load_before],
        load_average_after=[round(x, 2) for x in load_after], exit_codes=codes)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--seconds', type=float, default=20.0)
    parser.add_argument('--step', type=int, default=8, help="the tracker's grid step (8)")
    parser.add_argument('--method', default=None, help="the tracker's method (its default)")
    parser.add_argument('--solver', choices=('grassmann', 'rigid'), default='grassmann')
    parser.add_argument('--encoding', choices=('rgb8', 'mono8'), default='rgb8')
    parser.add_argument('--size', type=int, nargs=2, default=(480, 640), metavar=('H', 'W'))
    parser.add_argument('--image-depth', type=int, default=None,
                        help="the tracker's image history (its default: 5)")
    parser.add_argument('--dds-profile', default=str(DDS_PROFILE),
                        help="Fast DDS XML profile for every process ('': Fast DDS's defaults)")
    parser.add_argument('--key', default='camera_pipeline',
                        help='key in bench/results/camera_pipeline.json')
    args = parser.parse_args(argv)
    figures = run(args.seconds, args.step, args.method, args.solver, args.encoding,
                  tuple(args.size), image_depth=args.image_depth, dds_profile=args.dds_profile)
    common.merge_result(RESULTS, args.key,
                        common.jsonable({'environment': common.environment(), **figures}))
    print(json.dumps(figures, indent=1))
    return 0


if __name__ == '__main__':
    sys.exit(main())
