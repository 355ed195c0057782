"""The ROS 2 node: wiring only. ``tracks`` (PointCloud2: track_id, u, v per camera frame) in;
``points`` (PointCloud2: x, y, z, track_id; every frame, tracked on arrival),
``points/refined`` (the same frames once their window is solved) and ``/diagnostics`` out;
optionally ``mesh`` (visualization_msgs/Marker TRIANGLE_LIST, ``publish_mesh``); service
``~/reset`` (std_srvs/Trigger). The input's reliability follows ``input_reliability``
(docs/decisions/0300-input-qos.md); rates and stamp delay are bookkept in
:mod:`grass_nrsfm_ros.rates`.

The algorithm lives in :mod:`grass_nrsfm_ros.live` (tracking against the newest model),
:mod:`grass_nrsfm_ros.pipeline` (windows, warm start, alignment) and
:mod:`grass_nrsfm_ros.nrsfm`; here: parameters (:mod:`grass_nrsfm_ros.params`), decoding,
one worker thread for solves (mapping), publishing, logging, recording.

Threading: a SingleThreadedExecutor runs the input subscription (which tracks and publishes
each frame at once) and the housekeeping (frames stay in order); a closed window is handed to
the mapping and the callback returns at once: a child process (``mapping: process``,
:mod:`grass_nrsfm_ros.mapping`, whose receiver thread publishes its results here) or one
worker thread (``worker``). One executor thread, not a MultiThreadedExecutor (docs/decisions:
the node's executor). While a solve runs, newer windows replace the one waiting (counted as
dropped windows): the mapping skips to the newest window.

Start: ``ros2 run grass_nrsfm_ros node --ros-args ...``, ``grass-nrsfm node --ros-args ...``
or ``python -m grass_nrsfm_ros.node --ros-args ...``.
"""
from collections import deque
import gc
import os
import re
import signal
import sys
import threading
import time

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import numpy as np
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                SetParametersResult)
import rclpy
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.duration import Duration
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import QoSOverridingOptions
from rclpy.serialization import deserialize_message
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header
from std_srvs.srv import Trigger
from threadpoolctl import threadpool_limits
from visualization_msgs.msg import Marker

from grass_nrsfm_ros import cloud, mesh, params, qos as offered_qos, rates
from grass_nrsfm_ros.bag import Recorder
from grass_nrsfm_ros.live import make_pipeline, solve_figures
from grass_nrsfm_ros.mapping import fix_mmap_threshold, MappingProcess
from grass_nrsfm_ros.marker import mesh_marker
from grass_nrsfm_ros.pipeline import FrameError, WindowError

POINTCLOUD2 = 'sensor_msgs/msg/PointCloud2'
SPIN_PERIOD_S = 0.1          # longest delay before the spin loop sees Ctrl-C / SIGTERM
LOG_PERIOD_S = 10.0          # the same kind of problem is logged at most once per period
ACK_TIMEOUT_S = 2.0           # longest wait for subscribers to take a burst of clouds
INPUT_DEPTH = 100            # tracks messages the node's reader keeps (3 s at 30 Hz)
CLOSE_GRACE_S = 1.0          # close() waits this long for a running solve, then leaves it
LATENCY_WINDOW = 300         # tracking latencies kept for the percentiles in /diagnostics
GIL_SWITCH_S = 0.0005        # the mapping thread yields the GIL this often (record 0400)
RELIABILITY = {'reliable': ReliabilityPolicy.RELIABLE,
               'best_effort': ReliabilityPolicy.BEST_EFFORT}


class SolveCancelled(Exception):
    """Raised in the solver's progress callback once the node is stopping."""


def descriptor(spec):
    """ParameterDescriptor for a :class:`grass_nrsfm_ros.nrsfm.schema.Param` (range, read-only,
    typing)."""
    d = ParameterDescriptor(description=spec.description, read_only=spec.read_only,
                            dynamic_typing=spec.type is None)
    if spec.range is not None and spec.type is int:
        d.integer_range = [IntegerRange(from_value=int(spec.range[0]),
                                        to_value=int(spec.range[1]), step=1)]
    elif spec.range is not None and spec.type is float:
        d.floating_point_range = [FloatingPointRange(from_value=float(spec.range[0]),
                                                     to_value=float(spec.range[1]), step=0.0)]
    return d


def stamp_ns(stamp):
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def to_stamp(ns):
    return Time(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))


class RateLimitedLog:
    """Log each kind of problem at most once per ``period`` seconds, with a count of repeats.

    ``logger`` is an rclpy logger; rclpy requires one severity per call site, so each severity
    has its own method."""

    def __init__(self, logger, period=LOG_PERIOD_S):
        self._logger, self._period = logger, period
        self._last, self._repeats = {}, {}
        self._lock = threading.Lock()

    def _due(self, text):
        """``text`` (with the count of suppressed repeats) if it is due, else None."""
        kind = re.sub(r"\d+|'[^']*'", '#', text)
        now = time.monotonic()
        with self._lock:
            if now - self._last.get(kind, -self._period) < self._period:
                self._repeats[kind] = self._repeats.get(kind, 0) + 1
                return None
            repeats = self._repeats.pop(kind, 0)
            self._last[kind] = now
        return text + (f' ({repeats} more like this since the last report)' if repeats else '')

    def warning(self, text):
        line = self._due(text)
        if line:
            self._logger.warning(line)

    def info(self, text):
        line = self._due(text)
        if line:
            self._logger.info(line)


class ReconstructionNode(Node):
    """Subscribe ``tracks``, reconstruct sliding windows on a worker thread, publish ``points``.

    ``solver_factory`` / ``warm_start_class`` replace GrassmannNRSfM / WarmStart (tests).
    """

    def __init__(self, solver_factory=None, warm_start_class=None, **node_kwargs):
        super().__init__(params.NODE_NAME, **node_kwargs)
        config = self._declare_parameters()
        self._log = RateLimitedLog(self.get_logger())
        self._configure_blas()
        self.pipeline = make_pipeline(config, solver_factory, warm_start_class=warm_start_class)
        self._frame_id = config['frame_id']
        self._inline = config['mapping'] == 'inline'
        self._flush_after, self._last_frame_at = config['flush_after'], None
        self._handovers = deque(maxlen=LATENCY_WINDOW)    # seconds to hand a frame over
        self.mapper = None
        if config['mapping'] == 'process':
            self.mapper = MappingProcess(
                config, solver_factory, warm_start_class, output=self.pipeline.output,
                on_message=self._on_mapped, on_exit=self._on_mapping_exit,
                blas_threads=self._blas_threads)
        self._counts = dict(messages=0, dropped_messages=0, dropped_windows=0, solve_errors=0,
                            mapping_restarts=0)
        self._last_solve = {}
        self._lock = threading.Lock()
        self._pending, self._busy = None, False
        self._stopping = threading.Event()
        self._solve_thread = None
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        overrides = QoSOverridingOptions.with_default_policies()
        self._input_group = MutuallyExclusiveCallbackGroup()
        self._declare_input(config['input_reliability'], overrides)
        self.points_pub = self.create_publisher(PointCloud2, 'points', qos,
                                                qos_overriding_options=overrides)
        self.refined_pub = self.create_publisher(PointCloud2, 'points/refined', qos,
                                                 qos_overriding_options=overrides)
        self._latencies = deque(maxlen=LATENCY_WINDOW)     # tracks received -> points sent
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._declare_rates(config)
        self._declare_mesh(config)
        self._declare_services()
        self.create_timer(1.0, self._on_housekeeping,
                          callback_group=MutuallyExclusiveCallbackGroup())
        self.add_post_set_parameters_callback(self._on_parameters_set)
        self.recorder = self._open_recorder(config['record_path'])
        self.get_logger().info(
            f'reconstructing {self.tracks_sub.topic_name} -> {self.points_pub.topic_name}: '
            f'{self.pipeline.output} output, window {self.pipeline.windows.window_size}, '
            f'stride {self.pipeline.windows.window_stride}')

    # -- configuration ------------------------------------------------------------------------
    def _declare_parameters(self):
        """Declare every parameter with its descriptor; return their validated values."""
        values = {}
        for spec in params.all_params():
            value = self.declare_parameter(spec.name, spec.default, descriptor(spec)).value
            values[spec.name] = value
        return params.validate(values)

    def _on_parameters_set(self, changed):
        for p in changed:
            if p.name == 'metres_per_pixel':
                self.pipeline.metres_per_pixel = float(p.value)
            elif p.name == 'frame_id':
                self._frame_id = str(p.value)
        return SetParametersResult(successful=True)

    def _configure_blas(self):
        """Cap BLAS/OpenMP threads at all cores but one, so one stays free for the executor
        (the solver itself runs BLAS on one thread)."""
        self._blas_threads = max(1, (os.cpu_count() or 2) - 1)
        self._blas_limits = threadpool_limits(limits=self._blas_threads)

    def _open_recorder(self, path):
        """A :class:`grass_nrsfm_ros.bag.Recorder` of the input tracks (raw CDR, receive time)
        and output points (publish time), or None when off. Its writer thread keeps the disk
        off the solve path; a failure (unwritable path, full disk) is logged once and
        reconstruction goes on."""
        if not path:
            return None
        recorder = Recorder(path, on_error=self.get_logger().error)
        self._tracks_recorded = False           # added with its publishers' QoS on 1st message
        for publisher in (self.points_pub, self.refined_pub):
            recorder.add_topic(publisher.topic_name, POINTCLOUD2,
                               qos=self._offered_qos(publisher.topic_name, own=True))
        if recorder.error is None:
            self.get_logger().info(f'recording tracks and points to {path}')
        return recorder

    # -- input QoS ------------------------------------------------------------------------------
    def _declare_input(self, reliability, overrides):
        """The tracks subscription: a history of INPUT_DEPTH frames (a stall of the executor,
        the solver holding the GIL or a busy core, delays frames instead of overwriting them
        unseen) and the reliability ``input_reliability`` asks for (see params.py). A
        ``qos_overrides`` reliability pins it (then 'auto' adapts no more)."""
        self._input_mode = reliability
        self._input_pinned = self._reliability_overridden()
        asked = self._wanted_reliability() if reliability == 'auto' else RELIABILITY[reliability]
        self._subscribe_tracks(asked, overrides)

    def _reliability_overridden(self):
        """Whether a ``qos_overrides.<tracks>.subscription.reliability`` parameter was given
        (declared for a moment with an empty default; the override, if any, replaces it)."""
        name = f"qos_overrides.{self.resolve_topic_name('tracks')}.subscription.reliability"
        given = self.declare_parameter(name, '', ParameterDescriptor(dynamic_typing=True)).value
        self.undeclare_parameter(name)
        return given != ''

    def _subscribe_tracks(self, reliability, overrides=None):
        """(Re)create the raw tracks subscription: the CDR bytes are recorded as received,
        then decoded once."""
        kwargs = {} if overrides is None else {'qos_overriding_options': overrides}
        self.tracks_sub = self.create_subscription(
            PointCloud2, 'tracks', self._on_tracks_raw,
            QoSProfile(depth=INPUT_DEPTH, reliability=reliability), raw=True,
            callback_group=self._input_group, **kwargs)

    def _wanted_reliability(self):
        """RELIABLE while every tracks publisher found offers reliable; BEST_EFFORT when one
        offers best effort or none is found (the sensor-data fallback, as image_proc does)."""
        infos = self.get_publishers_info_by_topic(self.resolve_topic_name('tracks'))
        if infos and all(i.qos_profile.reliability == ReliabilityPolicy.RELIABLE
                         for i in infos):
            return ReliabilityPolicy.RELIABLE
        return ReliabilityPolicy.BEST_EFFORT

    def _adapt_input_qos(self):
        """'auto': resubscribe when the publishers found call for the other reliability."""
        if self._input_mode != 'auto' or self._input_pinned:
            return
        wanted = self._wanted_reliability()
        if wanted == self.tracks_sub.qos_profile.reliability:
            return
        self.destroy_subscription(self.tracks_sub)
        self._subscribe_tracks(wanted)
        self.get_logger().info(f'tracks publishers changed: subscribing '
                               f'{wanted.name.lower()} to {self.tracks_sub.topic_name}')

    # -- services -------------------------------------------------------------------------------
    def _declare_services(self):
        self._resets_requested, self._last_reset = 0, ''
        self.reset_srv = self.create_service(Trigger, '~/reset', self._on_reset)

    def _on_reset(self, request, response):
        """``~/reset``: drop the buffered frames, the window waiting and the model; the next
        frame starts a new sequence. A solve already running finishes and publishes."""
        with self._lock:
            waiting, self._pending = self._pending, None
        sequence = self.pipeline.windows.stats['resets'] + 1
        dropped = self.pipeline.reset()
        waiting = 'no window' if waiting is None else f'a {waiting.n_frames}-frame window'
        if self.mapper is not None:
            waiting = f'{self.mapper.reset()} windows in the mapping process'
        self._resets_requested += 1
        self._input_rate.reset(time.monotonic())
        self._output_rate.reset(time.monotonic())
        self._mesh.ids = None
        response.success = True
        response.message = (
            f'reset: dropped {dropped["frames"]} buffered frames, '
            f'{waiting} waiting, '
            f'{"the model" if dropped["model"] else "no model"} of sequence {sequence}; '
            f'sequence {sequence + 1} starts with the next frame')
        self._last_reset = response.message
        self.get_logger().info(response.message)
        self._publish_diagnostics()
        return response

    # -- mesh -----------------------------------------------------------------------------------
    def _declare_mesh(self, config):
        """``mesh`` publisher (visualization_msgs/Marker) when ``publish_mesh``, else None."""
        self._mesh = mesh.MeshCache(config['mesh_max_edge'])
        self.mesh_pub = None
        if config['publish_mesh']:
            self.mesh_pub = self.create_publisher(
                Marker, 'mesh', QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE))

    def _publish_mesh(self, result):
        """The surface of one published frame: triangles on its track set's first frame in the
        image plane (its x, y are the frame's centred u, v times metres_per_pixel)."""
        triangles = self._mesh.triangles_for(result.ids, result.xyz[:, :2])
        vertices, colours = mesh.triangle_list(result.xyz, triangles)
        header = Header(stamp=to_stamp(result.stamp_ns),
                        frame_id=self._frame_id or result.frame_id)
        self.mesh_pub.publish(mesh_marker(vertices, colours, header))

    # -- rates ----------------------------------------------------------------------------------
    def _declare_rates(self, config):
        """Input and output frequency (diagnostic_updater's FrequencyStatus) and output stamp
        delay (TimeStampStatus), bookkept in :mod:`grass_nrsfm_ros.rates`."""
        now = time.monotonic()
        self._input_rate = rates.FrequencyStatus(config['expected_rate'],
                                                 config['rate_tolerance'], now=now)
        self._output_rate = rates.FrequencyStatus(config['expected_rate'],
                                                  config['rate_tolerance'], now=now)
        self._output_delay = rates.TimeStampStatus()
        self._rate_cache = []

    def _rate_statuses(self):
        """DiagnosticStatus of each rate, one snapshot per call (call once per second)."""
        now = time.monotonic()
        named = ((f'{self.tracks_sub.topic_name} input frequency', self._input_rate.status(now)),
                 (f'{self.points_pub.topic_name} output frequency',
                  self._output_rate.status(now)),
                 (f'{self.points_pub.topic_name} output timestamp delay',
                  self._output_delay.status()))
        return [DiagnosticStatus(level=bytes([level]), name=f'{self.get_name()}: {name}',
                                 message=message, hardware_id=self.get_fully_qualified_name(),
                                 values=[KeyValue(key=k, value=v) for k, v in values])
                for name, (level, message, values) in named]

    def _on_housekeeping(self):
        """Once a second: adapt the input QoS, take the rates' snapshot, publish diagnostics."""
        self._adapt_input_qos()
        self._flush_if_idle()
        self._rate_cache = self._rate_statuses()
        self._publish_diagnostics()

    # -- input ----------------------------------------------------------------------------------
    def _offered_qos(self, topic, own=False):
        """``offered_qos_profiles`` of ``topic``'s publishers as discovered (this node's own
        with ``own``, the others' without), in rosbag2's form."""
        me = (self.get_name(), self.get_namespace())
        infos = [i for i in self.get_publishers_info_by_topic(topic)
                 if ((i.node_name, i.node_namespace) == me) == own]
        if own and not infos:                     # not in the graph yet: as created
            return offered_qos.offered_qos_yaml([self.points_pub.qos_profile])
        return offered_qos.offered_qos_yaml([i.qos_profile for i in infos])

    def _on_tracks_raw(self, raw):
        """Record one serialized tracks message (receive time), then decode and handle it."""
        received = time.monotonic()
        self._input_rate.tick()
        if self.recorder is not None:
            if not self._tracks_recorded:
                self.recorder.add_topic(self.tracks_sub.topic_name, POINTCLOUD2,
                                        qos=self._offered_qos(self.tracks_sub.topic_name))
                self._tracks_recorded = True
            self.recorder.write(self.tracks_sub.topic_name, raw,
                                self.get_clock().now().nanoseconds)
        try:
            msg = deserialize_message(raw, PointCloud2)
        except Exception as exc:                      # malformed CDR: drop, keep running
            self._counts['messages'] += 1
            return self._drop(None, f'undecodable tracks message ({type(exc).__name__}: {exc})')
        self._on_tracks(msg, received)

    def _on_tracks(self, msg, received=None):
        """Decode one frame, buffer it, publish its tracked cloud, hand any closed window to
        the mapping. ``received``: ``time.monotonic()`` when the message arrived."""
        received = received or time.monotonic()
        self._counts['messages'] += 1
        stamp = stamp_ns(msg.header.stamp)
        try:
            tracks = cloud.decode_tracks(msg)
        except cloud.CloudError as exc:
            return self._drop(stamp, f'bad tracks cloud: {exc}')
        if tracks.ids.size == 0:
            return self._drop(stamp, 'empty tracks cloud (no finite points)')
        invalid = int(msg.width) * int(msg.height) - tracks.ids.size
        if invalid:
            self._log.warning(f'tracks cloud at {stamp} ns: ignored {invalid} points with '
                              'non-finite u/v')
        resets = self.pipeline.windows.stats['resets']
        try:
            step = self.pipeline.add_frame(stamp, tracks.ids, tracks.uv, msg.header.frame_id)
        except FrameError as exc:
            return self._drop(stamp, f'frame refused: {exc}')
        self._last_frame_at = time.monotonic()
        if self.pipeline.windows.stats['resets'] != resets:
            self._log.info(f'all track ids changed at {stamp} ns: started a new sequence')
        for result in step.points:
            self._publish(self.points_pub, result)
        if step.points:
            self._latencies.append(time.monotonic() - received)
        if self.mapper is not None:
            return self._hand_over(step, stamp)
        self._map(step.windows)

    def _map(self, windows):
        """Hand closed ``windows`` to the mapping (process, worker or inline)."""
        for window in windows:
            if self.mapper is not None:
                self.mapper.submit(window)
            elif self._inline:
                self._solve_and_publish(window)     # reproducible: as the offline tools
            else:
                self._submit(window)

    def _hand_over(self, step, stamp):
        """``mapping: process``: the accepted frame (with the depth published for it before a
        model) and the windows it closed go to the mapping process."""
        started = time.perf_counter()
        self.mapper.add_frame(self.pipeline.windows.sequence, self.pipeline.windows.newest,
                              self._published_depth(stamp))
        self._map(step.windows)
        self._handovers.append(time.perf_counter() - started)

    def _flush_if_idle(self):
        """Once the input has been quiet ``flush_after`` seconds (once per quiet spell): the
        last window of the buffered frames to the mapping (LivePipeline.flush)."""
        if not self._flush_after or self._last_frame_at is None \
                or time.monotonic() - self._last_frame_at < self._flush_after:
            return
        self._last_frame_at = None
        self._map(self.pipeline.flush())

    def _published_depth(self, stamp):
        kept = self.pipeline.published_depth(stamp) if self.pipeline.output == 'live' else None
        return None if kept is None else kept[1]

    def _drop(self, stamp, reason):
        self._counts['dropped_messages'] += 1
        where = '' if stamp is None else f' at {stamp} ns'
        self._log.warning(f'dropped tracks message{where}: {reason}')

    # -- solving (worker thread) ----------------------------------------------------------------
    def _submit(self, window):
        """Solve ``window`` now, or keep it as the one waiting (replacing an older one)."""
        with self._lock:
            if self._busy:
                if self._pending is not None:
                    self._counts['dropped_windows'] += 1
                    self._log.warning('solves are falling behind: skipped to the newest window')
                self._pending = window
                return
            self._busy = True
            # a daemon thread: a solve that ignores cancellation cannot hold up the exit
            self._solve_thread = threading.Thread(target=self._solve_loop, args=(window,),
                                                  name='grass_nrsfm_solve', daemon=True)
            self._solve_thread.start()

    def _solve_loop(self, window):
        while window is not None and not self._stopping.is_set():
            try:
                self._solve_and_publish(window)
            except Exception:
                if not self._stopping.is_set() and self.context.ok():
                    raise
                # torn down under a solve left behind, or Ctrl-C shut the context down (from
                # C, before the executor returns) while this thread was publishing
                break
            with self._lock:
                window, self._pending = self._pending, None
                self._busy = window is not None
        with self._lock:
            self._busy = False

    # -- solving (mapping process) --------------------------------------------------------------
    def _on_mapped(self, message):
        """A message of the mapping process (its receiver thread): a solved window is taken
        as the next model and published, a failure or a skipped window counted and logged."""
        kind, spec = message[0], message[1]
        if self._stopping.is_set():
            return
        if kind == 'dropped':
            if message[2] == 'skipped':
                self._counts['dropped_windows'] += 1
                self._log.warning('solves are falling behind: skipped to the newest window')
            return
        if kind == 'failed':
            self._counts['solve_errors'] += 1
            self.pipeline.windows.note_failed()
            if message[2] == 'window':
                return self._log.warning(f'window not solved: {message[3]}')
            return self.get_logger().error(
                f'window {spec.index} failed in the mapping process: {message[3]}')
        _, spec, results, model, figures = message
        step = self.pipeline.accept_solved_elsewhere(spec.sequence, results, model,
                                                     solved=figures is not None)
        self._publish_solved(step, spec, figures)

    def _on_mapping_exit(self, exitcode, restarted):
        """The mapping process died unasked: say so; the tracking goes on with its model."""
        self._counts['solve_errors'] += 1
        self._counts['mapping_restarts'] += 1
        then = ('restarted it; windows need new frames before they solve again'
                if restarted else 'not restarted (too many restarts): the model is frozen')
        self.get_logger().error(f'the mapping process exited with code {exitcode}: {then}')
        if restarted:
            self.pipeline.realign()

    def _cancel_if_stopping(self, iteration, report):
        """The solver's progress callback: abandon the solve once the node is stopping."""
        if self._stopping.is_set():
            raise SolveCancelled(f'stopping at iteration {iteration}')

    def _solve_and_publish(self, window):
        started, released = time.monotonic(), self.pipeline.windows.releases(window)
        try:
            results = self.pipeline.solve(window, progress=self._cancel_if_stopping)
        except SolveCancelled:
            return
        except WindowError as exc:
            self._counts['solve_errors'] += 1
            return self._log.warning(f'window not solved: {exc}')
        except Exception as exc:                      # a solver failure must not stop the node
            self._counts['solve_errors'] += 1
            return self.get_logger().error(f'window {window.index} failed: '
                                           f'{type(exc).__name__}: {exc}')
        figures = None if released else solve_figures(self.pipeline.previous,
                                                      time.monotonic() - started)
        self._publish_solved(results, window, figures)

    def _publish_solved(self, step, window, figures):
        """Publish a solved window's Step (``points`` / ``refined``) and note its figures
        (None: a final window released without a solve)."""
        self._publish_paced(self.points_pub, step.points)
        self._publish_paced(self.refined_pub, step.refined)
        if figures is not None:
            self._last_solve = dict(figures, latency_seconds=time.monotonic() - window.closed_at,
                                    tracks_in_window=window.ids.size,
                                    frames_in_window=window.n_frames)
        if not self._stopping.is_set():
            self._publish_diagnostics()

    def _publish_paced(self, publisher, results):
        """Publish a window's frames, at most one QoS history (``depth``) ahead of the slowest
        reliable subscriber: the first window publishes ``window_size`` clouds at once, and a
        KEEP_LAST publisher would otherwise overwrite the ones not yet delivered."""
        depth = max(1, publisher.qos_profile.depth)
        for i, result in enumerate(results):
            if i and i % depth == 0:
                publisher.wait_for_all_acked(Duration(seconds=ACK_TIMEOUT_S))
            self._publish(publisher, result)
        if results and self.mesh_pub is not None and not self._stopping.is_set():
            self._publish_mesh(results[-1])

    def _publish(self, publisher, result):
        if self._stopping.is_set():
            return
        header = Header(stamp=to_stamp(result.stamp_ns),
                        frame_id=self._frame_id or result.frame_id)
        msg = cloud.encode_points(result.xyz, result.ids, header)
        publisher.publish(msg)
        if publisher is self.points_pub:
            self._output_rate.tick()
            self._output_delay.tick(result.stamp_ns * 1e-9,
                                    self.get_clock().now().nanoseconds * 1e-9)
        if self.recorder is not None:
            self.recorder.write(publisher.topic_name, msg, self.get_clock().now().nanoseconds)

    # -- diagnostics ------------------------------------------------------------------------------
    def _tracking_values(self):
        """The tracking half of /diagnostics (live output): latency, residual, model age,
        mapping backlog, frames tracked and refined."""
        live = self.pipeline
        if live.output != 'live':
            return {}
        p50, p95 = np.percentile(self._latencies, [50, 95]) if self._latencies else ('', '')
        last = live.last
        return {'tracking latency p50 ms': '' if p50 == '' else f'{1e3 * p50:.2f}',
                'tracking latency p95 ms': '' if p95 == '' else f'{1e3 * p95:.2f}',
                'tracking residual': '' if last['residual'] is None else
                f"{last['residual']:.4g}",
                'model age frames': '' if last['model_age'] is None else last['model_age'],
                'model rank': '' if last['model_rank'] is None else last['model_rank'],
                'bootstrap': last['bootstrap'],
                'mapping backlog': self._backlog(),
                **self._handover_values(),
                'frames tracked': live.stats['tracked'],
                'frames refined': live.stats['refined'],
                'frames not refined': live.windows.stats['frames_lost'],
                'frames awaiting refinement': live.pending_frames,
                'fresh windows requested': live.stats['fresh_windows'],
                'frames not tracked (published flat)': live.stats['tracking_failed'],
                'first model after frames': '' if live.stats['first_model_after'] is None
                else live.stats['first_model_after']}

    def _backlog(self):
        """Windows closed and not yet solved (running or waiting)."""
        if self.mapper is not None:
            return self.mapper.outstanding
        return int(self._busy) + int(self._pending is not None)

    def _handover_values(self):
        """``mapping: process``: what handing frames over costs the tracking, the restarts."""
        if self.mapper is None:
            return {}
        p95 = np.percentile(self._handovers, 95) if self._handovers else None
        return {'mapping process': (self.mapper.pid or 'starting') if self.mapper.alive
                else 'not running',
                'mapping hand-over p95 ms': '' if p95 is None else f'{1e3 * p95:.3f}',
                'mapping restarts': self._counts['mapping_restarts']}

    def _publish_diagnostics(self):
        stats = self.pipeline.windows.stats
        live = self.pipeline.output == 'live'
        behind = not live and (self._counts['dropped_windows'] > 0 or stats['frames_lost'] > 0)
        published = self.pipeline.stats['tracked'] if live else stats['published']
        values = {'windows solved': stats['solved'], 'frames published': published,
                  **self._tracking_values(),
                  **self._last_solve, 'messages received': self._counts['messages'],
                  'dropped messages': self._counts['dropped_messages'],
                  'dropped windows': self._counts['dropped_windows'],
                  'frames lost': 0 if live else stats['frames_lost'],
                  'frames pending': 0 if live else self.pipeline.pending_frames,
                  'sequences': stats['resets'] + 1,
                  'windows not solved': self._counts['solve_errors'],
                  'solver busy': self._backlog() > 0 if self.mapper is not None else self._busy,
                  'tracks publishers': self.tracks_sub.get_publisher_count(),
                  'points subscribers': self.points_pub.get_subscription_count(),
                  'input reliability': self.tracks_sub.qos_profile.reliability.name.lower(),
                  'resets requested': self._resets_requested}
        if self._last_reset:
            values['last reset'] = self._last_reset
        message = 'falling behind: skipping to the newest window' if behind else 'ok'
        level = DiagnosticStatus.WARN if behind else DiagnosticStatus.OK
        if self.recorder is not None and self.recorder.error:
            message, level = f'recording failed: {self.recorder.error}', DiagnosticStatus.WARN
        status = DiagnosticStatus(
            level=level, name=f'{self.get_name()}: reconstruction', message=message,
            hardware_id=self.get_fully_qualified_name(),
            values=[KeyValue(key=k.replace('_', ' '), value=str(v)) for k, v in values.items()])
        self.diagnostics_pub.publish(DiagnosticArray(
            header=Header(stamp=self.get_clock().now().to_msg()),
            status=[status, *self._rate_cache]))

    def close(self, grace=CLOSE_GRACE_S):
        """Stop solving (a running solve is cancelled through its progress callback, or left
        behind on its daemon thread after ``grace`` seconds), then close the recording."""
        self._stopping.set()
        if self.mapper is not None:
            self.mapper.close(grace)
        with self._lock:
            self._pending = None
            thread = self._solve_thread
        if thread is not None:
            thread.join(grace)
            if thread.is_alive():
                self.get_logger().warning(f'a solve is still running after {grace:g} s; '
                                          'exiting without its result')
        if self.recorder is not None:
            self.recorder.close()
            self.recorder = None


def main(args=None, *, solver_factory=None, warm_start_class=None):
    """Run the node until Ctrl-C / SIGTERM; returns the exit code (2: invalid parameters)."""
    sys.setswitchinterval(GIL_SWITCH_S)
    fix_mmap_threshold()
    # Ctrl-C / SIGTERM set a flag that the spin loop reads (at most SPIN_PERIOD_S later).
    # rclpy's own handlers shut the context down from C at once, racing the start-up and the
    # executor: a signal just after the start-up line ended in a traceback and exit code 1
    # ('context is not valid' building the wait set, or 'rcl_shutdown already called').
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    node = None
    try:
        try:
            node = ReconstructionNode(solver_factory, warm_start_class)
        except (ValueError, ParameterException) as exc:
            print(f'grass_nrsfm node: error: {exc}', file=sys.stderr)
            return 2
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        # later full collections skip what start-up made (modules, the node): one took 83 ms
        # of the GIL on this machine, a tracked frame's budget several times over; after
        # gc.freeze(), under 0.1 ms (record 0411)
        gc.freeze()
        while not stop.is_set():
            executor.spin_once(timeout_sec=SPIN_PERIOD_S)
    except ExternalShutdownException:
        pass
    finally:
        if node is not None:
            node.close()
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
