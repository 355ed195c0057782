"""What the package's ROS 2 nodes share: parameters declared from the one schema, stamps, and
a ``main`` that spins a node until Ctrl-C / SIGTERM."""
import gc
import signal
import sys
import threading

from builtin_interfaces.msg import Time
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions

SPIN_PERIOD_S = 0.1          # longest delay before the spin loop sees Ctrl-C / SIGTERM


def descriptor(spec):
    """ParameterDescriptor for a :class:`grass_nrsfm_ros.nrsfm.schema.Param` (range, read-only,
    typing)."""
    d = ParameterDescriptor(description=spec.description, read_only=spec.read_only,
                            dynamic_typing=spec.type in (None, list))
    if spec.range is not None and spec.type is int:
        d.integer_range = [IntegerRange(from_value=int(spec.range[0]),
                                        to_value=int(spec.range[1]), step=1)]
    elif spec.range is not None and spec.type is float:
        d.floating_point_range = [FloatingPointRange(from_value=float(spec.range[0]),
                                                     to_value=float(spec.range[1]), step=0.0)]
    return d


def declare(node, specs):
    """Declare every Param of ``specs`` on ``node``; ``{name: value}`` as given. A list
    parameter with an empty default is declared unset (rclpy cannot type an empty list):
    its value is then None."""
    return {spec.name: node.declare_parameter(
        spec.name, None if spec.type is list and not spec.default else spec.default,
        descriptor(spec)).value for spec in specs}


def stamp_ns(stamp):
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def to_stamp(ns):
    return Time(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))


def spin(make_node, args=None, name='grass_nrsfm node'):
    """Run ``make_node()`` until Ctrl-C / SIGTERM, then close (if it can) and destroy it; the
    exit code (2: invalid parameters, ValueError or ParameterException from ``make_node``).

    Ctrl-C / SIGTERM set a flag the spin loop reads (at most SPIN_PERIOD_S later): rclpy's own
    handlers shut the context down from C at once, racing the start-up and the executor."""
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    node = None
    try:
        try:
            node = make_node()
        except (ValueError, ParameterException) as exc:
            print(f'{name}: error: {exc}', file=sys.stderr)
            return 2
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        # later full collections skip what start-up made (record 0411)
        gc.freeze()
        while not stop.is_set():
            executor.spin_once(timeout_sec=SPIN_PERIOD_S)
    except ExternalShutdownException:
        pass
    finally:
        if node is not None:
            if hasattr(node, 'close'):
                node.close()
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
