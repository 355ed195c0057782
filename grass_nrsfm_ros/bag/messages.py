"""What every bag module shares: topic names, frame records, errors, and the Jazzy message
types (rosbags' type store) that turn clouds into CDR bytes without a ROS install.

Shapes: ``TrackFrame.uv: (P, 2)``, ``PointsFrame.xyz: (P, 3)``, ``ids: (P,) uint32``.
"""
from collections import namedtuple
from functools import lru_cache

from rosbags.typesys import get_typestore, Stores

from grass_nrsfm_ros.cloud import cloud_layout

TRACKS_TOPIC = '/tracks'
POINTS_TOPIC = '/points'
REFINED_TOPIC = '/points/refined'
GROUND_TRUTH_TOPIC = '/ground_truth'
POINTCLOUD2 = 'sensor_msgs/msg/PointCloud2'

TrackFrame = namedtuple('TrackFrame', 'stamp_ns frame_id ids uv')
TrackFrame.__doc__ = 'One frame of tracks: ``ids: (P,) uint32``, ``uv: (P, 2) float64``.'
PointsFrame = namedtuple('PointsFrame', 'stamp_ns frame_id ids xyz')
PointsFrame.__doc__ = 'One reconstructed frame: ``ids: (P,) uint32``, ``xyz: (P, 3) float64``.'


class BagError(ValueError):
    """A bag that cannot be used; the message says which file and why."""


class CorruptBagError(BagError):
    """The bag is truncated, has no index or metadata, or its contents do not parse."""


class TopicNotFoundError(BagError):
    """The bag has no such topic (the message lists the topics it has)."""


@lru_cache(maxsize=1)
def typestore():
    """The rosbags type store for ROS 2 Jazzy (message classes, CDR, definitions)."""
    return get_typestore(Stores.ROS2_JAZZY)


@lru_cache(maxsize=None)
def message_definition(msgtype):
    """``(ros2msg text, RIHS01 hash)`` for a Jazzy ``msgtype`` such as sensor_msgs/msg/Image."""
    store = typestore()
    if msgtype not in store.types:
        raise BagError(f'unknown message type {msgtype!r}: give its definition explicitly')
    text, _ = store.generate_msgdef(msgtype, ros_version=2)
    return text, store.hash_rihs01(msgtype)


def stamp_ns(stamp):
    """Nanoseconds of a ``builtin_interfaces/Time``-like object (sec, nanosec)."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def cloud_cdr(arr, stamp, frame_id):
    """CDR bytes of a PointCloud2 (unordered, little-endian) holding structured ``arr: (N,)``.

    Built with rosbags' Jazzy types, so offline tools need no ROS install; the layout is
    :func:`grass_nrsfm_ros.cloud.cloud_layout`, as in the node's messages.
    """
    store = typestore()
    t = store.types
    sec, nanosec = divmod(int(stamp), 1_000_000_000)
    header = t['std_msgs/msg/Header'](
        stamp=t['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec), frame_id=frame_id)
    msg = t[POINTCLOUD2](header=header, **cloud_layout(arr, t['sensor_msgs/msg/PointField']))
    return bytes(store.serialize_cdr(msg, POINTCLOUD2))


def serialize(data, msgtype=None):
    """CDR bytes of ``data``: bytes-like as is, an rclpy message, or a rosbags dataclass."""
    if isinstance(data, (bytes, bytearray, memoryview)):
        return data
    if hasattr(data, '__msgtype__'):                       # rosbags dataclass
        return bytes(typestore().serialize_cdr(data, data.__msgtype__))
    # an rclpy message: rclpy is the optional 'ros' extra, which offline tools do without
    from rclpy.serialization import serialize_message
    return serialize_message(data)
