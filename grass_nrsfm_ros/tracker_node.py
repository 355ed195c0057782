"""The tracker node: wiring only. ``image`` (sensor_msgs/Image: mono8, mono16, rgb8, bgr8,
rgba8, bgra8) and ``camera_info`` (sensor_msgs/CameraInfo) in, sensor-data QoS as
image_pipeline's subscribers (best effort, keep last 5); ``tracks`` out (PointCloud2: track_id
UINT32, u, v FLOAT32 pixels, and age UINT32 with ``publish_age``; stamp and frame_id of the
image; reliable, depth 10), the reconstruction node's input; ``/diagnostics`` once a second;
service ``~/reset`` (std_srvs/Trigger).

The tracking is :class:`grass_nrsfm_ros.frontend.DenseTracker`; images are read by
:mod:`grass_nrsfm_ros.image`; parameters are :mod:`grass_nrsfm_ros.tracker_params`; counts and
diagnostics :mod:`grass_nrsfm_ros.tracker_stats`. Each image is tracked in its callback (one
executor thread: frames stay in order). A bad image (unknown encoding, malformed, empty,
black or saturated) is skipped with a warning (once per kind every 10 s); a size change
restarts the tracks (new ids) at the new size; without camera_info the pixels are published as
they are (said once).

Start: ``ros2 run grass_nrsfm_ros tracker --ros-args ...``, ``grass-nrsfm tracker --ros-args
...`` or ``python -m grass_nrsfm_ros.tracker_node --ros-args ...``.
"""
import sys
import time
import warnings

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import numpy as np
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data, QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from std_msgs.msg import Header
from std_srvs.srv import Trigger

from grass_nrsfm_ros import cloud, image, tracker_params
from grass_nrsfm_ros.frontend import DenseTracker, FrameSizeError
from grass_nrsfm_ros.ros_common import spin, stamp_ns
from grass_nrsfm_ros.tracker_stats import TrackerStats

LOG_PERIOD_S = 10.0          # each kind of bad input is logged at most once per period
DIAGNOSTICS_PERIOD_S = 1.0
TRACKS_DTYPE = np.dtype([('track_id', '<u4'), ('u', '<f4'), ('v', '<f4')])
AGED_DTYPE = np.dtype([('track_id', '<u4'), ('u', '<f4'), ('v', '<f4'), ('age', '<u4')])


def tracks_array(frame, with_age):
    """Structured ``(P,)`` array (track_id, u, v[, age]) of a TrackFrame."""
    arr = np.empty(len(frame.ids), dtype=AGED_DTYPE if with_age else TRACKS_DTYPE)
    arr['track_id'] = frame.ids
    arr['u'], arr['v'] = frame.uv[:, 0], frame.uv[:, 1]
    if with_age:
        arr['age'] = np.clip(frame.age, 0, 2 ** 32 - 1)
    return arr


class TrackerNode(Node):
    """Dense tracks of each ``image`` published on ``tracks``."""

    def __init__(self, **node_kwargs):
        super().__init__(tracker_params.TRACKER_NODE_NAME, **node_kwargs)
        config = self._declare_parameters()
        self.tracker = DenseTracker(
            step=config['step'], method=config['method'], min_zncc=config['min_zncc'],
            region=tracker_params.load_region(config['mask'], config['roi']))
        self._with_age = config['publish_age']
        self.stats = TrackerStats(time.monotonic())
        self.camera = None                    # grass_nrsfm_ros.image.Camera, once one came
        self._shape = None                    # (H, W) of the images being tracked
        self._loggers = {}                    # kind of bad input -> its throttled logger
        self._said_no_camera = False
        overrides = QoSOverridingOptions.with_default_policies()
        self.image_sub = self.create_subscription(Image, 'image', self._on_image,
                                                  qos_profile_sensor_data,
                                                  qos_overriding_options=overrides)
        self.info_sub = self.create_subscription(CameraInfo, 'camera_info',
                                                 self._on_camera_info, qos_profile_sensor_data)
        self.tracks_pub = self.create_publisher(
            PointCloud2, 'tracks', QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE),
            qos_overriding_options=overrides)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.reset_srv = self.create_service(Trigger, '~/reset', self._on_reset)
        self.create_timer(DIAGNOSTICS_PERIOD_S, self._on_housekeeping)
        region = {type(None): 'the whole image', tuple: f"roi {config['roi']}"}.get(
            type(self.tracker.region), f"mask {config['mask']}")
        self.get_logger().info(
            f'tracking {self.image_sub.topic_name} -> {self.tracks_pub.topic_name}: '
            f"{config['method']}, step {config['step']} px, {region}")

    def _declare_parameters(self):
        """Declare every tracker parameter with its description; return the checked values.
        ``roi`` is an integer array: declared by type (rclpy cannot type an empty default)."""
        values = {}
        for spec in tracker_params.TRACKER_PARAMS:
            descriptor = ParameterDescriptor(description=spec.description, read_only=True)
            default = Parameter.Type.INTEGER_ARRAY if spec.name == 'roi' else spec.default
            values[spec.name] = self.declare_parameter(spec.name, default, descriptor).value
        return tracker_params.validate(values)

    # -- input ------------------------------------------------------------------------------
    def _on_camera_info(self, msg):
        try:
            camera = image.camera_from_info(msg)
        except image.CameraError as exc:
            return self._warn('camera_info', f'camera_info ignored: {exc}')
        if camera is not None and self.camera is None:
            fx, fy, cx, cy = camera.K[0, 0], camera.K[1, 1], camera.K[0, 2], camera.K[1, 2]
            self.get_logger().info(f'camera_info: fx {fx:g}, fy {fy:g}, cx {cx:g}, cy {cy:g}')
        self.camera = camera or self.camera

    def _on_image(self, msg):
        started = time.monotonic()
        self.stats.received()
        try:
            mono = image.image_mono(msg)
        except image.ImageError as exc:
            self.stats.skipped('bad image')
            return self._warn(f'{exc.kind} image',
                              f'image at {stamp_ns(msg.header.stamp)} ns skipped: {exc}')
        problem = image.exposure_problem(mono) if mono.dtype == np.uint8 else None
        if problem is not None:
            self.stats.skipped(problem)
            return self._warn(problem, f'{problem} image at {stamp_ns(msg.header.stamp)} ns '
                              'skipped: nothing to track in it; the tracks go on at the next')
        frame = self._track(mono, msg.header.stamp)
        if frame is None:
            return
        if frame.counts.get('blank'):
            self.stats.skipped('blank')
            return self._warn('blank', f'flat image at {stamp_ns(msg.header.stamp)} ns '
                              'skipped: nothing to track in it; the tracks go on at the next')
        self.tracks_pub.publish(cloud.to_pointcloud2(tracks_array(frame, self._with_age),
                                                     msg.header))
        now = time.monotonic()
        delay = self.get_clock().now().nanoseconds - stamp_ns(msg.header.stamp)
        self.stats.tracked(frame.counts, now - started, delay * 1e-9)

    def _track(self, mono, stamp):
        """The TrackFrame of ``mono``; a new size restarts the tracks; None if not tracked."""
        if self._shape is not None and mono.shape != self._shape:
            self.stats.count('size changes')
            self._warn('size', f'image size changed from {self._shape[1]} x {self._shape[0]} '
                       f'to {mono.shape[1]} x {mono.shape[0]} at {stamp_ns(stamp)} ns: tracks '
                       'restarted (new ids)')
            self.tracker.reset()
        self._shape = mono.shape
        try:
            with warnings.catch_warnings():       # blank frames: said here, once per kind
                warnings.simplefilter('ignore', RuntimeWarning)
                return self.tracker.track(mono)
        except (FrameSizeError, ValueError) as exc:
            self.stats.skipped('not tracked')
            self._warn('tracking', f'image at {stamp_ns(stamp)} ns not tracked: {exc}')
            return None

    def _warn(self, kind, text):
        """Log ``text`` unless the same ``kind`` of problem was logged in the last
        LOG_PERIOD_S (rclpy throttles per logger and call site: one child logger per kind)."""
        if kind not in self._loggers:
            self._loggers[kind] = self.get_logger().get_child(kind.replace(' ', '_'))
        self._loggers[kind].warning(text, throttle_duration_sec=LOG_PERIOD_S)

    # -- service and housekeeping ----------------------------------------------------------
    def _on_reset(self, request, response):
        """``~/reset``: drop every track; the next image is a new reference (new ids)."""
        alive = self.tracker.n_alive
        self.tracker.reset()
        self.stats.count('resets')
        response.success = True
        response.message = f'reset: dropped {alive} tracks; the next image starts new tracks'
        self.get_logger().info(response.message)
        return response

    def _on_housekeeping(self):
        if self.camera is None and self.stats.totals['images'] and not self._said_no_camera:
            self._said_no_camera = True
            self.get_logger().info(f'no camera_info on {self.info_sub.topic_name}: pixels as '
                                   'they are')
        self._publish_diagnostics()

    def _camera_values(self):
        if self.camera is None:
            return [('camera', 'no camera_info')]
        K = self.camera.K
        return [('camera', f'fx {K[0, 0]:g} fy {K[1, 1]:g} cx {K[0, 2]:g} cy {K[1, 2]:g}')]

    def _publish_diagnostics(self):
        report = self.stats.report(time.monotonic(), extra=[
            *self._camera_values(), ('resets requested', str(self.stats.totals['resets'])),
            ('image publishers', str(self.image_sub.get_publisher_count())),
            ('tracks subscribers', str(self.tracks_pub.get_subscription_count()))])
        status = DiagnosticStatus(
            level=DiagnosticStatus.WARN if report.level else DiagnosticStatus.OK,
            name=f'{self.get_name()}: tracker', message=report.message,
            hardware_id=self.get_fully_qualified_name(),
            values=[KeyValue(key=k, value=v) for k, v in report.values])
        self.diagnostics_pub.publish(DiagnosticArray(
            header=Header(stamp=self.get_clock().now().to_msg()), status=[status]))


def main(args=None):
    """Run the tracker node until Ctrl-C / SIGTERM; returns the exit code (2: invalid
    parameters, e.g. an unreadable mask)."""
    return spin(TrackerNode, args, 'grass_nrsfm tracker')


if __name__ == '__main__':
    sys.exit(main())
