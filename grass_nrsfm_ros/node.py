"""The reconstruction node: rclpy wiring around :class:`~grass_nrsfm_ros.pipeline.LivePipeline`.

``tracks`` (PointCloud2: track_id, u, v per camera frame) and ``camera_info``
(sensor_msgs/CameraInfo: the tracks' pinhole intrinsics, unless the ``camera`` parameter gives
them) in; ``points`` (every frame, tracked on arrival), ``points/refined`` (each frame once,
from the windows behind), ``/diagnostics`` and, with ``publish_mesh``, ``mesh`` (Marker
TRIANGLE_LIST) out; service ``~/reset``. With intrinsics the points are the camera frame through
the pinhole (:mod:`grass_nrsfm_ros.pipeline`); while a camera_info publisher is there but none
has arrived, tracks are dropped (counted), for at most CAMERA_INFO_WAIT_S of stamps.

Threads: a SingleThreadedExecutor runs the input callback (each frame tracked and published at
once) and the housekeeping (docs/decisions/0039); with ``mapping: process`` the windows are
solved in a child process whose receiver thread publishes ``points/refined``
(:mod:`grass_nrsfm_ros.backends`); ``inline`` solves in the input callback.

Start: ``ros2 run grass_nrsfm_ros node --ros-args ...``, ``grass-nrsfm node --ros-args ...``
or ``python -m grass_nrsfm_ros.node --ros-args ...``.
"""
from collections import deque
import os
import re
import sys
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import SetParametersResult
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data, QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import QoSOverridingOptions
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import CameraInfo, PointCloud2
from std_msgs.msg import Header
from std_srvs.srv import Trigger
from threadpoolctl import threadpool_limits
from visualization_msgs.msg import Marker

from grass_nrsfm_ros import cloud, diagnostics, image, mesh, params, rates
from grass_nrsfm_ros.backends import fix_mmap_threshold
from grass_nrsfm_ros.bag import offered_qos, Recorder
from grass_nrsfm_ros.input_qos import InputSubscription
from grass_nrsfm_ros.marker import mesh_marker
from grass_nrsfm_ros.nrsfm.camera import ORTHOGRAPHIC_MESSAGE
from grass_nrsfm_ros.pipeline import LATENCY_WINDOW, make_pipeline
from grass_nrsfm_ros.ros_common import declare, spin, stamp_ns, to_stamp
from grass_nrsfm_ros.windowing import FrameError

POINTCLOUD2 = 'sensor_msgs/msg/PointCloud2'
LOG_PERIOD_S = 10.0          # the same problem is logged at most once per period
ACK_TIMEOUT_S = 2.0          # longest wait for subscribers to take a burst of clouds
ACK_POLL_S = 0.005           # the wait polls this often (rclpy's blocking wait holds the GIL)
GIL_SWITCH_S = 0.0005        # the mapping's threads yield the GIL this often (record 0400)
CAMERA_INFO_WAIT_S = 1.0     # tracks wait at most this long (stamps) for a silent camera_info
LEVELS = {'ok': DiagnosticStatus.OK, 'warn': DiagnosticStatus.WARN}


class ReconstructionNode(Node):
    """Subscribe ``tracks``, publish ``points`` and ``points/refined``; ``solver_factory``
    replaces GrassmannNRSfM (tests)."""

    def __init__(self, solver_factory=None, **node_kwargs):
        super().__init__(params.NODE_NAME, **node_kwargs)
        config = params.validate(declare(self, params.all_params()))
        self.frame_id, self.flush_after = config['frame_id'], config['flush_after']
        blas_threads = max(1, (os.cpu_count() or 2) - 1)     # one core stays for the executor
        self._blas_limits = threadpool_limits(limits=blas_threads)
        self.pipeline = make_pipeline(config, solver_factory, mapping=config['mapping'],
                                      notify=self._publish_refined, blas_threads=blas_threads,
                                      on_exit=self._on_mapping_exit)
        self.inline = config['mapping'] == 'inline'
        self.pipeline.orthographic_warning = lambda: self.get_logger().warning(
            ORTHOGRAPHIC_MESSAGE, once=True)
        self.camera_fixed = bool(config['camera'])      # the parameter wins over camera_info
        self.camera_wait_from = None                    # stamp of the first tracks that waited
        self.counts = dict(messages=0, dropped_messages=0, dropped_windows=0, resets=0)
        self.last_solve, self.last_reset, self.last_frame_at = {}, '', None
        self.latencies = deque(maxlen=LATENCY_WINDOW)      # tracks received -> points sent
        self.drop_loggers = {}                              # kind of bad input -> its logger
        self.stopping = threading.Event()
        overrides = QoSOverridingOptions.with_default_policies()
        self.input = InputSubscription(self, 'tracks', self._on_tracks_raw,
                                       config['input_reliability'], overrides=overrides,
                                       callback_group=MutuallyExclusiveCallbackGroup())
        self.info_sub = self.create_subscription(CameraInfo, 'camera_info', self._on_camera_info,
                                                 qos_profile_sensor_data)
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.points_pub = self.create_publisher(PointCloud2, 'points', qos,
                                                qos_overriding_options=overrides)
        self.refined_pub = self.create_publisher(PointCloud2, 'points/refined', qos,
                                                 qos_overriding_options=overrides)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.mesh_pub = self.create_publisher(
            Marker, 'mesh', QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)) \
            if config['publish_mesh'] else None
        self.mesh = mesh.MeshCache(config['mesh_max_edge'])
        self.rates = rates.NodeRates(config['expected_rate'], config['rate_tolerance'])
        self.reset_srv = self.create_service(Trigger, '~/reset', self._on_reset)
        self.create_timer(1.0, self._on_housekeeping,
                          callback_group=MutuallyExclusiveCallbackGroup())
        self.add_post_set_parameters_callback(self._on_parameters_set)
        self.recorder = self._open_recorder(config['record_path'])
        self.get_logger().info(
            f'reconstructing {self.input.subscription.topic_name} -> '
            f'{self.points_pub.topic_name}: window {config["window_size"]}, stride '
            f'{config["window_stride"]}, mapping {config["mapping"]}')

    # -- input (executor thread) ----------------------------------------------------------------
    def _on_tracks_raw(self, raw):
        """Record one serialized tracks message (receive time), decode it, track it, publish."""
        received = time.monotonic()
        self.rates.input.tick()
        self.counts['messages'] += 1
        self._record_input(raw)
        try:
            msg = deserialize_message(raw, PointCloud2)
            tracks = cloud.decode_tracks(msg)
        except Exception as exc:                      # malformed CDR or cloud: drop, go on
            return self._drop(f'bad tracks message ({type(exc).__name__}: {exc})')
        stamp = stamp_ns(msg.header.stamp)
        if self._waits_for_camera_info(stamp):
            return self._drop(f'tracks at {stamp} ns before the first camera_info from '
                              f'{self.info_sub.topic_name}')
        if tracks.ids.size == 0:
            return self._drop(f'empty tracks cloud at {stamp} ns (no finite points)')
        invalid = int(msg.width) * int(msg.height) - tracks.ids.size
        if invalid:
            self.get_logger().warning(f'tracks cloud at {stamp} ns: ignored {invalid} points '
                                      'with non-finite u/v', throttle_duration_sec=LOG_PERIOD_S)
        try:
            points = self.pipeline.add_frame(stamp, tracks.ids, tracks.uv, msg.header.frame_id)
        except FrameError as exc:
            return self._drop(f'frame at {stamp} ns refused: {exc}')
        self.last_frame_at = time.monotonic()
        if self.pipeline.windowing.stats['resets'] > self.counts['resets']:
            self.counts['resets'] = self.pipeline.windowing.stats['resets']
            self.get_logger().info(f'all track ids changed at {stamp} ns: started a new sequence')
        for result in points:
            self._publish(self.points_pub, result)
        self.latencies.append(time.monotonic() - received)
        if self.inline:
            self._publish_refined()

    def _waits_for_camera_info(self, stamp):
        """True while tracks are dropped for want of intrinsics: a camera_info publisher is
        there, none has arrived, and the first tracks that waited are less than
        CAMERA_INFO_WAIT_S older than ``stamp`` (then pixels as they are, said once)."""
        if self.pipeline.camera is not None or not self.info_sub.get_publisher_count():
            return False
        if self.camera_wait_from is None:
            self.camera_wait_from = stamp
        return stamp - self.camera_wait_from < CAMERA_INFO_WAIT_S * 1e9

    def _on_camera_info(self, msg):
        """Intrinsics of the tracks: a change starts a new sequence (the normalised points
        change); ignored while the ``camera`` parameter gives them."""
        if self.camera_fixed:
            return
        try:
            camera = image.camera_from_info(msg)
        except image.CameraError as exc:
            self.get_logger().warning(f'camera_info ignored: {exc}',
                                      throttle_duration_sec=LOG_PERIOD_S)
            return
        if camera is not None and self.pipeline.set_camera(camera.K):
            K = camera.K
            self.get_logger().info(f'camera_info: fx {K[0, 0]:g}, fy {K[1, 1]:g}, cx '
                                   f'{K[0, 2]:g}, cy {K[1, 2]:g}: points through the pinhole, '
                                   'a new sequence')

    def _drop(self, reason):
        """Count a dropped message; each kind of reason (its text, numbers and quoted names
        aside) is logged at most once per LOG_PERIOD_S by a logger of its own (rclpy throttles
        per call site and logger)."""
        self.counts['dropped_messages'] += 1
        kind = re.sub(r"\d+|'[^']*'", '#', reason)
        logger = self.drop_loggers.setdefault(
            kind, self.get_logger().get_child(f'input{len(self.drop_loggers)}'))
        logger.warning(f'dropped tracks message: {reason}', throttle_duration_sec=LOG_PERIOD_S)

    # -- mapping results (receiver thread, or the executor's with mapping: inline) --------------
    def _publish_refined(self):
        """Take the mapping's Updates: publish their refined frames, note what they say."""
        if self.stopping.is_set():
            return
        results, updates = self.pipeline.refined()
        self._publish_paced(self.refined_pub, results)
        for update in updates:
            self._note(update)
        if updates:
            self._publish_diagnostics()

    def _note(self, update):
        if update.kind == 'dropped' and update.message == 'skipped' and not update.preview:
            self.counts['dropped_windows'] += 1
            self.get_logger().warning('solves are falling behind: skipped to the newest '
                                      'window', throttle_duration_sec=LOG_PERIOD_S)
        elif update.kind == 'failed':
            self.get_logger().error(update.message, throttle_duration_sec=LOG_PERIOD_S)
        elif update.kind == 'solved':
            self.last_solve = dict(update.figures, tracks_in_window=update.n_tracks,
                                   latency_seconds=time.monotonic() - update.closed_at,
                                   frames_in_window=len(update.stamps))

    def _on_mapping_exit(self, exitcode, restarted):
        """The mapping process died unasked: say so; the tracking goes on with its model."""
        then = ('restarted it; windows need new frames before they solve again'
                if restarted else 'not restarted (too many restarts): the model is frozen')
        self.get_logger().error(f'the mapping process exited with code {exitcode}: {then}')

    # -- publishing -----------------------------------------------------------------------------
    def _publish_paced(self, publisher, results):
        """Publish a burst of frames at most one QoS history ahead of the slowest reliable
        subscriber (a KEEP_LAST publisher would overwrite the ones not yet delivered)."""
        depth = max(1, publisher.qos_profile.depth)
        for i, result in enumerate(results):
            if i and i % depth == 0:
                self._wait_acked(publisher)
            self._publish(publisher, result)
        if results and self.mesh_pub is not None and not self.stopping.is_set():
            self._publish_mesh(results[-1])

    def _wait_acked(self, publisher):
        """Wait up to ACK_TIMEOUT_S for ``publisher``'s subscribers to acknowledge what it
        sent, polling: rclpy's ``wait_for_all_acked`` with a timeout holds the GIL, and so
        would stop the tracking for as long (docs/decisions/0441)."""
        deadline = time.monotonic() + ACK_TIMEOUT_S
        while not publisher.wait_for_all_acked(Duration()):
            if time.monotonic() > deadline or self.stopping.is_set():
                return
            time.sleep(ACK_POLL_S)

    def _publish(self, publisher, result):
        if self.stopping.is_set():
            return
        msg = cloud.encode_points(result.xyz, result.ids, self._header(result))
        publisher.publish(msg)
        if publisher is self.points_pub:
            self.rates.output_published(result.stamp_ns * 1e-9,
                                        self.get_clock().now().nanoseconds * 1e-9)
        if self.recorder is not None:
            self.recorder.write(publisher.topic_name, msg, self.get_clock().now().nanoseconds)

    def _publish_mesh(self, result):
        """The surface of one refined frame, triangulated in the image plane."""
        triangles = self.mesh.triangles_for(result.ids, result.xyz[:, :2])
        vertices, colours = mesh.triangle_list(result.xyz, triangles)
        self.mesh_pub.publish(mesh_marker(vertices, colours, self._header(result)))

    def _header(self, result):
        return Header(stamp=to_stamp(result.stamp_ns), frame_id=self.frame_id or result.frame_id)

    # -- housekeeping, diagnostics, services ----------------------------------------------------
    def _on_housekeeping(self):
        """Once a second: adapt the input QoS, flush after a pause, publish diagnostics."""
        adapted = self.input.adapt()
        if adapted is not None:
            self.get_logger().info(f'tracks publishers changed: subscribing '
                                   f'{adapted.name.lower()} to '
                                   f'{self.input.subscription.topic_name}')
        if self.flush_after and self.last_frame_at is not None \
                and time.monotonic() - self.last_frame_at >= self.flush_after:
            self.last_frame_at = None
            self.pipeline.flush()
            if self.inline:
                self._publish_refined()
        self.rates.snapshot(self.input.subscription.topic_name, self.points_pub.topic_name)
        self._publish_diagnostics()

    def _publish_diagnostics(self):
        snap = diagnostics.snapshot(
            self.pipeline, latencies=self.latencies, counts=self.counts,
            handovers=getattr(self.pipeline.backend, 'handovers', ()),
            last_solve=self.last_solve)
        values = diagnostics.values(snap)
        values.update({'tracks publishers': self.input.subscription.get_publisher_count(),
                       'camera_info publishers': self.info_sub.get_publisher_count(),
                       'points subscribers': self.points_pub.get_subscription_count(),
                       'input reliability': self.input.reliability.name.lower(),
                       'resets requested': self.counts.get('resets_requested', 0)})
        if self.last_reset:
            values['last reset'] = self.last_reset
        level, message = diagnostics.summary(
            snap, None if self.recorder is None else self.recorder.error)
        status = DiagnosticStatus(level=LEVELS[level], name=f'{self.get_name()}: '
                                  'reconstruction', message=message,
                                  hardware_id=self.get_fully_qualified_name(),
                                  values=[KeyValue(key=k, value=str(v))
                                          for k, v in values.items()])
        self.diagnostics_pub.publish(DiagnosticArray(
            header=Header(stamp=self.get_clock().now().to_msg()),
            status=[status, *self._rate_statuses()]))

    def _rate_statuses(self):
        return [DiagnosticStatus(level=bytes([level]), name=f'{self.get_name()}: {name}',
                                 message=message, hardware_id=self.get_fully_qualified_name(),
                                 values=[KeyValue(key=k, value=v) for k, v in values])
                for name, level, message, values in self.rates.statuses()]

    def _on_reset(self, request, response):
        """``~/reset``: drop the buffered frames, the window waiting and the model; the next
        frame starts a new sequence. A solve already running finishes and publishes."""
        sequence = self.pipeline.windowing.stats['resets'] + 1      # as 'sequences' counts
        backlog = self.pipeline.backend.outstanding
        dropped = self.pipeline.reset()
        self.counts['resets'] = self.pipeline.windowing.stats['resets']
        self.counts['resets_requested'] = self.counts.get('resets_requested', 0) + 1
        self.rates.reset()
        self.mesh.ids = None
        response.success = True
        response.message = (
            f'reset: dropped {dropped["frames"]} buffered frames, {backlog} windows in the '
            f'mapping, {"the model" if dropped["model"] else "no model"} of sequence '
            f'{sequence}; sequence {sequence + 1} starts with the next frame')
        self.last_reset = response.message
        self.get_logger().info(response.message)
        self._publish_diagnostics()
        return response

    def _on_parameters_set(self, changed):
        for p in changed:
            if p.name == 'metres_per_pixel':
                self.pipeline.metres_per_pixel = float(p.value)
            elif p.name == 'scene_depth':
                self.pipeline.scene_depth = float(p.value)
            elif p.name == 'frame_id':
                self.frame_id = str(p.value)
        return SetParametersResult(successful=True)

    # -- recording ------------------------------------------------------------------------------
    def _open_recorder(self, path):
        """A Recorder of the input tracks (raw CDR, receive time) and output points (publish
        time), or None; a failure is logged once and reconstruction goes on."""
        if not path:
            return None
        recorder = Recorder(path, on_error=self.get_logger().error)
        for publisher in (self.points_pub, self.refined_pub):
            recorder.add_topic(publisher.topic_name, POINTCLOUD2,
                               qos=self._offered_qos(publisher.topic_name, own=True))
        if recorder.error is None:
            self.get_logger().info(f'recording tracks and points to {path}')
        return recorder

    def _record_input(self, raw):
        if self.recorder is None:
            return
        topic = self.input.subscription.topic_name
        if topic not in self.recorder.topics:         # added with its publishers' QoS
            self.recorder.add_topic(topic, POINTCLOUD2, qos=self._offered_qos(topic))
        self.recorder.write(topic, raw, self.get_clock().now().nanoseconds)

    def _offered_qos(self, topic, own=False):
        """``offered_qos_profiles`` of ``topic``'s publishers as discovered (this node's own
        with ``own``, the others' without), in rosbag2's form."""
        me = (self.get_name(), self.get_namespace())
        infos = [i for i in self.get_publishers_info_by_topic(topic)
                 if ((i.node_name, i.node_namespace) == me) == own]
        if own and not infos:                     # not in the graph yet: as created
            return offered_qos.offered_qos_yaml([self.points_pub.qos_profile])
        return offered_qos.offered_qos_yaml([i.qos_profile for i in infos])

    def close(self):
        """Stop the mapping (a running solve is cancelled), then close the recording."""
        self.stopping.set()
        self.pipeline.close()
        if self.recorder is not None:
            self.recorder.close()
            self.recorder = None


def main(args=None, *, solver_factory=None):
    """Run the node until Ctrl-C / SIGTERM; returns the exit code (2: invalid parameters)."""
    sys.setswitchinterval(GIL_SWITCH_S)
    fix_mmap_threshold()
    return spin(lambda: ReconstructionNode(solver_factory), args, 'grass_nrsfm node')


if __name__ == '__main__':
    sys.exit(main())
