"""``grass-nrsfm replay BAG [--topic /tracks] [--rate R] [--loop] [--clock]``: publish a topic
of a bag (rosbag2 mcap or sqlite3, bare .mcap, ROS 1 .bag) with its recorded timing.

As ``ros2 bag play``: messages are scheduled by their recorded receive time, message k at
``wall0 + (t_k - t_0) / R`` on a monotonic clock; header stamps are published unchanged. ROS 2
messages go out as the recorded CDR bytes (no deserialisation); ROS 1 messages are converted
field by field into rclpy messages (the ROS 1 header's ``seq`` is dropped). ``--clock`` also
publishes rosgraph_msgs/Clock on /clock (the bag time, at each message and ``--clock-hz`` in
between) for nodes with ``use_sim_time``. Ctrl-C stops cleanly.
"""
import importlib
import signal
import time

import numpy as np
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rosgraph_msgs.msg import Clock

from grass_nrsfm_ros import bag
from grass_nrsfm_ros.cli import UserError

#: longest sleep between two checks for Ctrl-C while waiting for a message's time
MAX_SLEEP_S = 0.1


def add_arguments(parser):
    parser.add_argument('bag', help='bag directory, .mcap or ROS 1 .bag')
    parser.add_argument('--topic', default='/tracks', help='topic to publish (/tracks)')
    parser.add_argument('--remap', help='publish under this topic name instead')
    parser.add_argument('--rate', type=float, default=1.0, help='playback speed factor (1.0)')
    parser.add_argument('--loop', action='store_true', help='start again at the end')
    parser.add_argument('--clock', action='store_true', help='publish /clock (bag time)')
    parser.add_argument('--clock-hz', type=float, default=40.0,
                        help='/clock rate between messages (40)')
    parser.add_argument('--wait-for-subscribers', type=int, default=0, metavar='N',
                        help='wait until N subscribers are matched before starting (0)')
    parser.add_argument('--delay', type=float, default=0.0, metavar='S',
                        help='seconds to wait before playing, after --wait-for-subscribers, '
                             'so readers that match late get the first messages on time '
                             '(a reliable writer repairs those ~0.3 s late; 0)')
    parser.add_argument('--depth', type=int, default=10, help='publisher queue depth (10)')


def message_class(msgtype):
    """The rclpy class of ``pkg/msg/Name``."""
    pkg, _, name = msgtype.split('/')
    try:
        return getattr(importlib.import_module(f'{pkg}.msg'), name)
    except (ImportError, AttributeError):
        raise UserError(f'message type {msgtype} is not installed for rclpy') from None


def _element_class(field_type):
    """rclpy class of the elements of ``sequence<pkg/Name>`` / ``pkg/Name[3]``, or None."""
    inner = field_type
    if inner.startswith('sequence<'):
        inner = inner[len('sequence<'):].split(',')[0].rstrip('>')
    inner = inner.split('[')[0]
    if '/' not in inner:
        return None
    pkg, name = inner.split('/')[0], inner.split('/')[-1]
    return getattr(importlib.import_module(f'{pkg}.msg'), name)


def to_rclpy(obj, cls):
    """An rclpy ``cls`` message from a rosbags dataclass (ROS 1 or 2), matching by field name;
    fields the rclpy type lacks (ROS 1 ``seq``) are dropped."""
    msg = cls()
    for name, field_type in cls.get_fields_and_field_types().items():
        value = getattr(obj, name)
        current = getattr(msg, name)
        if hasattr(current, 'get_fields_and_field_types'):
            value = to_rclpy(value, type(current))
        elif isinstance(value, np.ndarray):
            value = value if value.dtype != np.uint8 else value.tobytes()
        elif isinstance(value, (list, tuple)):
            element = _element_class(field_type)
            if element is not None:
                value = [to_rclpy(v, element) for v in value]
        setattr(msg, name, value)
    return msg


class Player:
    """Publish one topic of a bag with scaled timing; one instance per run."""

    def __init__(self, node, args):
        self.node, self.args = node, args
        known = bag.topics(args.bag)
        if args.topic not in known:
            raise bag.TopicNotFoundError(f'bag {args.bag} has no topic {args.topic!r} '
                                         f'(topics: {", ".join(sorted(known)) or "none"})')
        self.msgtype = known[args.topic][0]
        self.cls = message_class(self.msgtype)
        qos = QoSProfile(depth=args.depth, reliability=ReliabilityPolicy.RELIABLE)
        self.pub = node.create_publisher(self.cls, args.remap or args.topic, qos)
        self.clock_pub = None
        if args.clock:
            self.clock_pub = node.create_publisher(Clock, '/clock', 10)
        self.published = 0
        self.stopped = False                  # set by a signal handler (see run)

    def stop(self, signum=None, frame=None):
        """Signal handler: stop after the message being published."""
        self.stopped = True

    def publish_clock(self, t_ns):
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(int(t_ns), 1_000_000_000)
        self.clock_pub.publish(msg)

    def wait_until(self, target, bag_time_at, t_target):
        """Sleep (spinning) until monotonic ``target``, publishing /clock meanwhile (never past
        ``t_target``, the bag time of the message due then, so /clock does not step back)."""
        period = 1.0 / self.args.clock_hz if self.clock_pub else MAX_SLEEP_S
        while not self.stopped:
            now = time.monotonic()
            if now >= target:
                return
            step = min(period, target - now)
            if step > 0.002:
                rclpy.spin_once(self.node, timeout_sec=0)
            time.sleep(max(0.0, min(step, target - time.monotonic())))
            if self.clock_pub is not None:
                self.publish_clock(min(bag_time_at(time.monotonic()), t_target))

    def play_once(self):
        wall0, t0 = None, None
        rate = self.args.rate
        for t_ns, raw, _, is_ros1, decode in bag.iter_raw(self.args.bag, self.args.topic,
                                                          msgtype=None):
            if wall0 is None:
                wall0, t0 = time.monotonic(), t_ns
            target = wall0 + (t_ns - t0) / 1e9 / rate
            self.wait_until(target, lambda now: t0 + (now - wall0) * rate * 1e9, t_ns)
            if self.stopped:
                return
            self.pub.publish(to_rclpy(decode(), self.cls) if is_ros1 else bytes(raw))
            if self.clock_pub is not None:
                self.publish_clock(t_ns)
            self.published += 1

    def wait_for_subscribers(self, n, timeout=30.0):
        deadline = time.monotonic() + timeout
        while self.pub.get_subscription_count() < n and not self.stopped:
            if time.monotonic() > deadline:
                raise UserError(f'no {n} subscriber(s) on {self.pub.topic_name} after '
                                f'{timeout:g} s')
            rclpy.spin_once(self.node, timeout_sec=0.05)


def spin_for(node, seconds, player):
    """Spin ``node`` for ``seconds`` (or until the player is stopped)."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and not player.stopped:
        rclpy.spin_once(node, timeout_sec=min(0.05, max(0.0, deadline - time.monotonic())))


def run(args):
    if args.rate <= 0:
        raise UserError(f'--rate must be positive; got {args.rate}')
    if args.delay < 0:
        raise UserError(f'--delay must be >= 0; got {args.delay}')
    # Ctrl-C / SIGTERM only set a flag that the playing loop reads between messages. With
    # rclpy's own handlers, which shut the context down at once from C, a publish under way
    # failed ("publisher's context is invalid": a traceback, exit code 1); and a
    # KeyboardInterrupt raised from our own handler sometimes ended the process with SIGINT
    # (exit -2) although it was caught.
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node('grass_nrsfm_replay')
    player = None
    try:
        player = Player(node, args)
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, player.stop)
        if args.wait_for_subscribers > 0:
            player.wait_for_subscribers(args.wait_for_subscribers)
        spin_for(node, args.delay, player)
        while not player.stopped:
            player.play_once()
            if not args.loop:
                break
        # let reliable messages reach late acknowledgers before the publisher goes away
        spin_for(node, 0.5, player)
        if player.stopped:
            print('replay: interrupted')
    except KeyboardInterrupt:            # Ctrl-C before the handlers are set (no rclpy ones)
        print('replay: interrupted')
    finally:
        if player is not None:
            print(f'replay: published {player.published} messages on '
                  f'{player.pub.topic_name}')
        node.destroy_node()
        rclpy.try_shutdown()
    return 0
