"""Bags: recording (a writer thread), reading, recovery of killed recordings.

Everything here is I/O; no solver. Bags are written as rosbag2 **MCAP** bags, the layout
``ros2 bag record -s mcap`` makes: a directory ``NAME/`` with ``metadata.yaml`` (rosbag2
version 9, Jazzy) and ``NAME_0.mcap`` (profile ``ros2``, ``ros2msg`` schemas embedded, ``cdr``
messages). The MCAP file is written with the ``mcap`` library because it lets us choose the
chunk size and finish a chunk on demand: a recording killed with ``kill -9`` loses at most the
chunk in progress (``chunk_size`` bytes or ``flush_period`` seconds, whichever comes first)
plus the messages still queued, and :func:`recover` turns the rest into a normal bag.

Reading goes through ``rosbags.highlevel.AnyReader``: a rosbag2 directory (mcap or sqlite3),
a bare ``.mcap`` file, or a ROS 1 ``.bag``.

Topics (defaults; the node publishes ``points`` relative to its namespace):
``/tracks``: the input contract, one PointCloud2 per frame (track_id, u, v);
``/points``: reconstructions, one PointCloud2 per frame (x, y, z, track_id), camera frame;
``/ground_truth``: written by ``grass-nrsfm convert`` when the .npz has ``S``: the true shape
of each frame in the points layout, stamped like the frame's tracks.

Shapes: ``W: (2F, P)``, ``S: (3F, P)`` as in :mod:`grass_nrsfm_ros.nrsfm.measurement`.
"""
from collections import Counter, namedtuple
from dataclasses import dataclass, field
from functools import lru_cache
import os
from pathlib import Path
import queue
import threading
import time

import numpy as np

from grass_nrsfm_ros.cloud import (cloud_layout, CloudError, decode_points, decode_tracks,
                                   points_array, tracks_array)
from grass_nrsfm_ros.qos import offered_qos_list

TRACKS_TOPIC = '/tracks'
POINTS_TOPIC = '/points'
GROUND_TRUTH_TOPIC = '/ground_truth'
POINTCLOUD2 = 'sensor_msgs/msg/PointCloud2'
DEFAULT_CHUNK_SIZE = 256 * 1024          # bytes of messages per MCAP chunk
DEFAULT_FLUSH_PERIOD = 1.0               # seconds a chunk may stay open
DEFAULT_QUEUE_SIZE = 256                 # messages waiting for the writer thread
ROSBAG2_VERSION = 9                      # Jazzy

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


# ---------------------------------------------------------------------------- types

@lru_cache(maxsize=1)
def typestore():
    """The rosbags type store for ROS 2 Jazzy (message classes, CDR, definitions)."""
    from rosbags.typesys import get_typestore, Stores
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
    from rclpy.serialization import serialize_message      # rclpy message
    return serialize_message(data)


# ---------------------------------------------------------------------------- writing

class BagWriter:
    """Synchronous rosbag2/MCAP writer (the offline tools and the Recorder thread use it).

    ``path`` is the bag directory; it must not exist or be empty. ``close()`` writes the MCAP
    summary (index, statistics) and ``metadata.yaml``; it is idempotent. ``chunk_size`` bytes
    per chunk; ``compression`` None or 'zstd'.
    """

    def __init__(self, path, *, chunk_size=DEFAULT_CHUNK_SIZE, compression=None):
        from mcap.writer import CompressionType, Writer

        self.path = Path(path)
        if self.path.exists() and (not self.path.is_dir() or any(self.path.iterdir())):
            raise FileExistsError(f'{self.path} exists and is not an empty directory')
        self.path.mkdir(parents=True, exist_ok=True)
        self.mcap_path = self.path / f'{self.path.name}_0.mcap'
        self._file = open(self.mcap_path, 'wb')
        kind = {None: CompressionType.NONE, 'zstd': CompressionType.ZSTD}[compression]
        self._mcap = Writer(self._file, chunk_size=chunk_size, compression=kind)
        self._mcap.start(profile='ros2', library='grass_nrsfm_ros')
        self._schemas = {}           # msgtype -> schema id
        self._topics = {}            # topic -> (channel id, msgtype, hash, qos)
        self.counts = Counter()      # topic -> messages written
        self.bytes_written = 0
        self._t_min, self._t_max = None, None
        self.closed = False

    def add_topic(self, topic, msgtype, *, definition=None, qos=''):
        """Declare ``topic`` of ``msgtype`` (idempotent); ``definition`` for non-Jazzy types."""
        if topic in self._topics:
            if self._topics[topic][1] != msgtype:
                raise BagError(f'topic {topic} already has type {self._topics[topic][1]}')
            return
        if definition is None:
            definition, rihs = message_definition(msgtype)
        else:
            rihs = message_definition(msgtype)[1] if msgtype in typestore().types else ''
        if msgtype not in self._schemas:
            self._schemas[msgtype] = self._mcap.register_schema(
                name=msgtype, encoding='ros2msg', data=definition.encode())
        channel = self._mcap.register_channel(
            topic=topic, message_encoding='cdr', schema_id=self._schemas[msgtype],
            metadata={'offered_qos_profiles': qos, 'topic_type_hash': rihs})
        self._topics[topic] = (channel, msgtype, rihs, qos)

    def write(self, topic, data, t_ns, publish_ns=None):
        """Append CDR ``data`` (or a message, see :func:`serialize`) on ``topic`` at ``t_ns``."""
        if topic not in self._topics:
            raise BagError(f'topic {topic} was not added (add_topic first)')
        raw = serialize(data)
        t_ns = int(t_ns)
        self._mcap.add_message(channel_id=self._topics[topic][0], log_time=t_ns, data=raw,
                               publish_time=t_ns if publish_ns is None else int(publish_ns))
        self.counts[topic] += 1
        self.bytes_written += len(raw)
        self._t_min = t_ns if self._t_min is None else min(self._t_min, t_ns)
        self._t_max = t_ns if self._t_max is None else max(self._t_max, t_ns)

    def write_tracks(self, ids, uv, stamp, frame_id, *, topic=TRACKS_TOPIC, t_ns=None):
        """One ``tracks`` cloud: ``ids: (P,)``, ``uv: (P, 2)`` pixels, header stamp ``stamp``."""
        self.add_topic(topic, POINTCLOUD2)
        self.write(topic, cloud_cdr(tracks_array(ids, uv), stamp, frame_id),
                   stamp if t_ns is None else t_ns)

    def write_points(self, xyz, ids, stamp, frame_id, *, topic=POINTS_TOPIC, t_ns=None):
        """One ``points`` cloud: ``xyz: (P, 3)`` camera frame, ``ids: (P,)``."""
        self.add_topic(topic, POINTCLOUD2)
        self.write(topic, cloud_cdr(points_array(xyz, ids), stamp, frame_id),
                   stamp if t_ns is None else t_ns)

    def flush(self):
        """Finish the chunk in progress and hand it to the OS (survives a killed process)."""
        self._mcap.flush()

    def close(self):
        """Write the MCAP summary and ``metadata.yaml``; idempotent."""
        if self.closed:
            return
        self.closed = True
        try:
            self._mcap.add_metadata('rosbag2', {'ros_distro': 'jazzy',
                                                'serialized_metadata': ''})
            self._mcap.finish()
        finally:
            self._file.close()
        write_metadata(self.path, [self.mcap_path.name], self._topic_rows(),
                       self._t_min or 0, (self._t_max or 0) - (self._t_min or 0))

    def abort(self):
        """Close the file without a summary or metadata (after an I/O error)."""
        self.closed = True
        try:
            self._file.close()
        except OSError:
            pass

    def _topic_rows(self):
        return [(topic, msgtype, rihs, qos, self.counts[topic])
                for topic, (_, msgtype, rihs, qos) in self._topics.items()]

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        if exc[0] is None:
            self.close()
        else:
            self.abort()


def write_metadata(bag_dir, files, topics, start_ns, duration_ns):
    """``metadata.yaml`` (rosbag2 version 8, mcap storage) for ``topics``: rows of
    ``(name, msgtype, type hash, offered_qos_profiles, message_count)``."""
    import yaml

    count = sum(row[4] for row in topics)
    info = {
        'version': ROSBAG2_VERSION,
        'storage_identifier': 'mcap',
        'relative_file_paths': list(files),
        'duration': {'nanoseconds': int(duration_ns)},
        'starting_time': {'nanoseconds_since_epoch': int(start_ns)},
        'message_count': count,
        'topics_with_message_count': [
            {'topic_metadata': {'name': name, 'type': msgtype, 'serialization_format': 'cdr',
                                'offered_qos_profiles': offered_qos_list(qos),
                                'type_description_hash': rihs},
             'message_count': n}
            for name, msgtype, rihs, qos, n in topics],
        'compression_format': '',
        'compression_mode': '',
        'relative_file_paths_compression': None,
        'files': [{'path': f, 'starting_time': {'nanoseconds_since_epoch': int(start_ns)},
                   'duration': {'nanoseconds': int(duration_ns)}, 'message_count': count}
                  for f in files],
        'custom_data': None,
        'ros_distro': 'jazzy',
    }
    del info['relative_file_paths_compression']
    tmp = Path(bag_dir) / 'metadata.yaml.tmp'
    tmp.write_text(yaml.safe_dump({'rosbag2_bagfile_information': info}, sort_keys=False))
    tmp.replace(Path(bag_dir) / 'metadata.yaml')


_STOP = object()


class Recorder:
    """Record messages into a rosbag2/MCAP bag on a writer thread; the caller never waits on
    the disk.

    ``write`` only puts ``(topic, data, t_ns)`` on a bounded queue (``queue_size`` messages);
    rclpy messages are serialized on the writer thread, so do not change one after writing it.
    Chunks are finished every ``chunk_size`` bytes and at least every ``flush_period`` seconds,
    so a killed process loses at most that chunk and the queue (see :func:`recover`).

    Errors never raise from ``write``: the first one (unwritable path, full disk) is stored in
    ``error`` and passed once to ``on_error(message)``; later messages are dropped and counted
    in ``dropped`` (as are messages that find the queue full). ``close()`` drains the queue,
    writes the index and ``metadata.yaml``, and is idempotent.
    """

    def __init__(self, path, *, chunk_size=DEFAULT_CHUNK_SIZE, flush_period=DEFAULT_FLUSH_PERIOD,
                 queue_size=DEFAULT_QUEUE_SIZE, compression=None, on_error=None):
        self.path = Path(path)
        self.error = None
        self.dropped = 0
        self.written = 0
        self._on_error = on_error
        self._lock = threading.Lock()
        self._closed = False
        self._flush_period = float(flush_period)
        self._queue = queue.Queue(maxsize=queue_size)
        self._writer = None
        try:
            self._writer = BagWriter(path, chunk_size=chunk_size, compression=compression)
        except (OSError, BagError) as exc:
            self._fail(exc)
        self._thread = threading.Thread(target=self._run, name='grass_nrsfm_recorder',
                                        daemon=True)
        self._thread.start()

    @property
    def bytes_written(self):
        return self._writer.bytes_written if self._writer else 0

    def add_topic(self, topic, msgtype, *, qos=''):
        """Declare ``topic`` (e.g. '/points') of ``msgtype`` (e.g. sensor_msgs/msg/PointCloud2)."""
        message_definition(msgtype)           # unknown types fail here, in the caller
        self._put(('topic', topic, msgtype, qos), count=False)

    def write(self, topic, data, t_ns):
        """Queue one message (CDR bytes or a message); returns False if it was dropped."""
        return self._put(('msg', topic, data, int(t_ns)))

    def close(self, timeout=30.0):
        """Drain the queue, finish the bag; idempotent. Returns ``error`` (None when fine)."""
        with self._lock:
            if self._closed:
                return self.error
            self._closed = True
        self._queue.put(_STOP)
        self._thread.join(timeout)
        return self.error

    def _put(self, item, count=True):
        with self._lock:
            if self._closed or self.error is not None:
                self.dropped += count
                return False
            try:
                self._queue.put_nowait(item)
                return True
            except queue.Full:
                self.dropped += count
                return False

    def _fail(self, exc):
        if isinstance(exc, OSError):
            what = f'{exc.strerror or exc} ({exc.filename or self.path})'
        else:
            what = str(exc)
        with self._lock:
            if self.error is not None:
                return
            self.error = (f'recording to {self.path} failed: {what}; further messages are '
                          f'dropped. Rescue what was written with `grass-nrsfm recover '
                          f'{self.path}`')
        if self._writer is not None:
            self._writer.abort()
        if self._on_error is not None:
            self._on_error(self.error)

    def _run(self):
        opened_at = None                      # when the unflushed chunk got its first message
        while True:
            timeout = None
            if opened_at is not None:
                timeout = max(0.0, opened_at + self._flush_period - time.monotonic())
            try:
                item = self._queue.get(timeout=timeout)
            except queue.Empty:
                item = None
            if item is _STOP:
                break
            if self.error is not None:
                self._count_drop(item)
                opened_at = None              # nothing left to flush: block on the queue
                continue
            try:
                if item is not None:
                    opened_at = self._handle(item, opened_at)
                if opened_at is not None and time.monotonic() - opened_at >= self._flush_period:
                    self._writer.flush()
                    opened_at = None
            except OSError as exc:
                self._count_drop(item)
                self._fail(exc)
        if self.error is None and self._writer is not None:
            try:
                self._writer.close()
            except OSError as exc:
                self._fail(exc)

    def _count_drop(self, item):
        if item is not None and item[0] == 'msg':
            with self._lock:
                self.dropped += 1

    def _handle(self, item, opened_at):
        if item[0] == 'topic':
            self._writer.add_topic(item[1], item[2], qos=item[3])
            return opened_at
        _, topic, data, t_ns = item
        self._writer.write(topic, data, t_ns)
        self.written += 1
        return time.monotonic() if opened_at is None else opened_at


# ---------------------------------------------------------------------------- recovery

@dataclass
class RecoveryReport:
    """What :func:`recover` rescued: messages per topic, and where reading stopped."""

    out_path: Path
    counts: Counter = field(default_factory=Counter)
    files: list = field(default_factory=list)
    stopped: list = field(default_factory=list)     # one line per file that ended early

    @property
    def messages(self):
        return sum(self.counts.values())


def mcap_files(bag_path):
    """The .mcap files of a bag directory (in split order) or ``[bag_path]`` for a file."""
    bag_path = Path(bag_path)
    if not bag_path.exists():
        raise FileNotFoundError(f'{bag_path} does not exist')
    if bag_path.is_file():
        return [bag_path]
    files = sorted(bag_path.glob('*.mcap'),
                   key=lambda p: (len(p.name), p.name))     # NAME_2 before NAME_10
    if not files:
        raise BagError(f'{bag_path} holds no .mcap file (only MCAP recordings can be recovered)')
    return files


def recover(bag_path, out_path=None, *, chunk_size=DEFAULT_CHUNK_SIZE):
    """Rebuild a killed recording (no metadata.yaml, no summary, truncated last chunk) into a
    normal bag at ``out_path`` (default ``<bag>_recovered``) holding every complete message.

    Reads each .mcap sequentially (``mcap.stream_reader.StreamReader``, CRCs checked) up to
    the first truncated or damaged record. Returns a :class:`RecoveryReport`.
    """
    from mcap.exceptions import McapError
    from mcap.records import Channel, Message, Schema
    from mcap.stream_reader import StreamReader

    files = mcap_files(bag_path)
    src = Path(bag_path)
    stem = src.stem if src.is_file() else src.name
    out = Path(out_path) if out_path else src.with_name(f'{stem}_recovered')
    report = RecoveryReport(out_path=out)
    with BagWriter(out, chunk_size=chunk_size) as writer:
        for path in files:
            report.files.append(path.name)
            schemas, channels = {}, {}
            with open(path, 'rb') as fh:
                try:
                    for rec in StreamReader(fh, validate_crcs=True).records:
                        if isinstance(rec, Schema):
                            schemas[rec.id] = rec
                        elif isinstance(rec, Channel):
                            channels[rec.id] = rec
                            schema = schemas[rec.schema_id]
                            writer.add_topic(rec.topic, schema.name,
                                             definition=schema.data.decode(),
                                             qos=rec.metadata.get('offered_qos_profiles', ''))
                        elif isinstance(rec, Message):
                            topic = channels[rec.channel_id].topic
                            writer.write(topic, rec.data, rec.log_time, rec.publish_time)
                            report.counts[topic] += 1
                except (McapError, KeyError, ValueError, UnicodeDecodeError) as exc:
                    name = type(exc).__name__
                    report.stopped.append(f'{path.name}: stopped at byte {fh.tell()} ({name}'
                                          f'{": " + str(exc) if str(exc) else ""})')
    return report


# ---------------------------------------------------------------------------- reading

class _Bag:
    """An open AnyReader over ``path`` with errors turned into :class:`BagError`."""

    def __init__(self, path):
        from rosbags.highlevel import AnyReader

        self.path = Path(path)
        if not self.path.exists():
            raise FileNotFoundError(f'{self.path} does not exist')
        try:
            self.reader = AnyReader([self.path], default_typestore=typestore())
            self.reader.open()
        except FileNotFoundError as exc:
            raise CorruptBagError(self._hint(exc)) from None
        except Exception as exc:                      # rosbags raises many reader errors
            raise CorruptBagError(self._hint(exc)) from None
        self.is_ros1 = not self.reader.is2

    def _hint(self, exc):
        hint = ''
        if self.path.is_dir() and not (self.path / 'metadata.yaml').exists():
            hint = (f'; it has no metadata.yaml, as a killed recording: run '
                    f'`grass-nrsfm recover {self.path}`')
        elif self.path.suffix == '.mcap' or self.path.is_dir():
            hint = f'; if the recording was killed, run `grass-nrsfm recover {self.path}`'
        return f'cannot read bag {self.path}: {exc}{hint}'

    def connections(self, topic, msgtype=POINTCLOUD2):
        conns = [c for c in self.reader.connections if c.topic == topic]
        if not conns:
            have = sorted({c.topic for c in self.reader.connections})
            raise TopicNotFoundError(f'bag {self.path} has no topic {topic!r} (topics: '
                                     f'{", ".join(have) or "none"})')
        if msgtype is not None:
            wrong = {c.msgtype for c in conns} - {msgtype}
            if wrong:
                raise BagError(f'topic {topic} in {self.path} has type {wrong.pop()}, '
                               f'not {msgtype}')
        return conns

    def messages(self, conns):
        """``(connection, t_ns, raw)`` in time order; read errors become CorruptBagError."""
        try:
            yield from self.reader.messages(connections=conns)
        except (OSError, EOFError) as exc:
            raise CorruptBagError(self._hint(exc)) from None
        except Exception as exc:
            if type(exc).__module__.startswith(('rosbags', 'zstandard', 'lz4', 'sqlite3')):
                raise CorruptBagError(self._hint(exc)) from None
            raise

    def decode(self, raw, conn):
        try:
            return self.reader.deserialize(raw, conn.msgtype)
        except Exception as exc:
            raise CorruptBagError(f'message on {conn.topic} in {self.path} does not parse: '
                                  f'{exc}') from None

    def close(self):
        self.reader.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def topics(path):
    """``{topic: (msgtype, message count)}`` of a bag."""
    with _Bag(path) as bag:
        out = {}
        for c in bag.reader.connections:
            n = out.get(c.topic, (c.msgtype, 0))[1]
            out[c.topic] = (c.msgtype, n + c.msgcount)
        return out


def iter_raw(path, topic=TRACKS_TOPIC, msgtype=POINTCLOUD2):
    """Yield ``(t_ns, raw, msgtype, is_ros1, decode)`` for each message on ``topic``.

    ``raw`` is CDR for ROS 2 bags and ROS 1 serialization for .bag files; ``decode()``
    returns the rosbags dataclass. Used by replay, which publishes CDR as is.
    """
    with _Bag(path) as bag:
        for conn, t_ns, raw in bag.messages(bag.connections(topic, msgtype)):
            yield t_ns, raw, conn.msgtype, bag.is_ros1, (
                lambda raw=raw, conn=conn: bag.decode(raw, conn))


def read_clouds(path, topic):
    """Yield ``(t_ns, msg)`` PointCloud2 dataclasses on ``topic`` in receive-time order."""
    with _Bag(path) as bag:
        for conn, t_ns, raw in bag.messages(bag.connections(topic)):
            yield t_ns, bag.decode(raw, conn)


def read_tracks(path, topic=TRACKS_TOPIC):
    """Yield :class:`TrackFrame` ``(stamp_ns, frame_id, ids, uv)`` for each ``tracks`` cloud.

    Raises FileNotFoundError, CorruptBagError, TopicNotFoundError, or BagError for a cloud
    that breaks the input contract (which message, why).
    """
    for i, (_, msg) in enumerate(read_clouds(path, topic)):
        try:
            tracks = decode_tracks(msg)
        except CloudError as exc:
            raise BagError(f'{path}: message {i} on {topic}: {exc}') from None
        yield TrackFrame(stamp_ns(msg.header.stamp), msg.header.frame_id, tracks.ids, tracks.uv)


def read_points(path, topic=POINTS_TOPIC):
    """Yield :class:`PointsFrame` ``(stamp_ns, frame_id, ids, xyz)`` for each ``points`` cloud."""
    for i, (_, msg) in enumerate(read_clouds(path, topic)):
        try:
            ids, xyz = decode_points(msg)
        except CloudError as exc:
            raise BagError(f'{path}: message {i} on {topic}: {exc}') from None
        yield PointsFrame(stamp_ns(msg.header.stamp), msg.header.frame_id, ids, xyz)


def frames_to_matrix(frames, field_name, rows):
    """Stack frames (TrackFrame/PointsFrame) into ``(rows*F, P)`` over the union of track ids.

    Returns ``(M, ids, stamps)``; entries of a track missing from a frame are NaN.
    """
    frames = list(frames)
    if not frames:
        raise BagError('no frames')
    ids = np.unique(np.concatenate([f.ids for f in frames]))
    M = np.full((rows * len(frames), ids.size), np.nan)
    for k, f in enumerate(frames):
        cols = np.searchsorted(ids, f.ids)
        M[rows * k:rows * k + rows, cols] = getattr(f, field_name).T
    return M, ids, np.array([f.stamp_ns for f in frames], dtype=np.int64)


def read_W(path, topic=TRACKS_TOPIC):
    """``(W: (2F, P), ids: (P,), stamps: (F,) ns)`` from a tracks bag; NaN where unseen."""
    return frames_to_matrix(read_tracks(path, topic), 'uv', 2)


def read_S(path, topic=POINTS_TOPIC):
    """``(S: (3F, P), ids: (P,), stamps: (F,) ns)`` from a points bag; NaN where absent."""
    return frames_to_matrix(read_points(path, topic), 'xyz', 3)


# ---------------------------------------------------------------------------- conversion

def tracks_bag_from_arrays(W, stamps, out, frame_id='camera_optical', *, topic=TRACKS_TOPIC,
                           S=None, gt_topic=GROUND_TRUTH_TOPIC, visible=None):
    """Write ``W: (2F, P)`` as a tracks bag at ``out``: frame f is one cloud with the points
    visible in it (``visible: (F, P)`` bool, default all), track id = column of W, header
    stamp and receive time ``stamps[f]`` (ns). ``S: (3F, P)`` ground truth, when given, goes
    to ``gt_topic`` in the points layout with the same stamps. Returns the message counts.
    """
    from grass_nrsfm_ros.nrsfm.measurement import as_frames, validate_shapes, validate_tracks

    W = validate_tracks(W, min_frames=1, min_points=1)
    F, P = W.shape[0] // 2, W.shape[1]
    stamps = np.asarray(stamps, dtype=np.int64)
    if stamps.shape != (F,):
        raise BagError(f'stamps must have shape ({F},); got {stamps.shape}')
    visible = np.ones((F, P), bool) if visible is None else np.asarray(visible, bool)
    if visible.shape != (F, P):
        raise BagError(f'visible must have shape ({F}, {P}); got {visible.shape}')
    uv = as_frames(W, 2).transpose(0, 2, 1)                       # (F, P, 2)
    xyz = None
    if S is not None:
        xyz = as_frames(validate_shapes(S, n_frames=F, n_points=P), 3).transpose(0, 2, 1)
    ids = np.arange(P, dtype=np.uint32)
    with BagWriter(out) as writer:
        for f in range(F):
            seen = visible[f]
            writer.write_tracks(ids[seen], uv[f, seen], stamps[f], frame_id, topic=topic)
            if xyz is not None:
                writer.write_points(xyz[f], ids, stamps[f], frame_id, topic=gt_topic)
    return dict(writer.counts)


def bag_size_bytes(path):
    """Total size of the files of a bag (directory or file)."""
    path = Path(path)
    if path.is_file():
        return path.stat().st_size
    return sum(os.path.getsize(p) for p in path.rglob('*') if p.is_file())


# ---------------------------------------------------------------------------- offline pipeline

@dataclass
class ReconstructionReport:
    """What :func:`reconstruct_bag` did: frames in and out, windows, refusals, timings."""

    out_path: Path
    frames_in: int = 0
    frames_out: int = 0
    windows: int = 0
    refused: list = field(default_factory=list)      # one line per refused frame or window
    copied: Counter = field(default_factory=Counter)  # input topic -> messages copied
    seconds: float = 0.0
    cpu_seconds: float = 0.0


def text_progress(stream=None, width=30):
    """A ``progress(done, total)`` callback drawing ``[####    ] done/total`` on stderr."""
    import sys

    stream = stream or sys.stderr
    state = {'last': -1.0}

    def draw(done, total):
        now = time.monotonic()
        if done < total and now - state['last'] < 0.1:
            return
        state['last'] = now
        filled = int(width * done / max(total, 1))
        stream.write(f'\r[{"#" * filled}{" " * (width - filled)}] {done}/{total} frames')
        if done >= total:
            stream.write('\n')
        stream.flush()
    return draw


def reconstruct_bag(in_path, out_path, pipeline, *, topic=TRACKS_TOPIC,
                    points_topic=POINTS_TOPIC, copy_inputs=True, progress=None,
                    skip_errors=(ValueError,)):
    """Run the windowed pipeline over a tracks bag offline, as fast as the solver goes, and
    write a bag at ``out_path`` with ``points_topic`` (one cloud per reconstructed frame,
    stamped with the frame's stamp, logged at its tracks' receive time) and, with
    ``copy_inputs``, every input message (CDR as recorded; for a ROS 1 source only the tracks,
    re-encoded).

    ``pipeline`` is a :class:`grass_nrsfm_ros.pipeline.SlidingWindow` (or anything with
    ``add_frame(stamp_ns, ids, uv, frame_id) -> [window]``, ``solve(window) -> [result]`` and
    ``flush() -> [window]``; results have ``stamp_ns, frame_id, ids: (P,), xyz: (P, 3)``).
    Frames and windows that raise one of ``skip_errors`` are refused and listed in the report.
    ``progress(done, total)`` is called after every input frame. Returns a
    :class:`ReconstructionReport`.
    """
    report = ReconstructionReport(out_path=Path(out_path))
    t_wall, t_cpu = time.perf_counter(), time.process_time()
    with _Bag(in_path) as src, BagWriter(out_path) as out:
        tracks_conns = src.connections(topic)
        total = sum(c.msgcount for c in tracks_conns)
        received = {}                                  # stamp -> receive time of its tracks
        conns = src.reader.connections if copy_inputs else tracks_conns
        if not src.is_ros1:
            for c in conns:
                out.add_topic(c.topic, c.msgtype, definition=_definition_of(c))

        def emit(results):
            for r in results:
                out.write_points(np.asarray(r.xyz), np.asarray(r.ids), r.stamp_ns, r.frame_id,
                                 topic=points_topic, t_ns=received.get(r.stamp_ns, r.stamp_ns))
                report.frames_out += 1

        def solve(windows):
            for window in windows:
                report.windows += 1
                try:
                    emit(pipeline.solve(window))
                except skip_errors as exc:
                    report.refused.append(f'window {report.windows}: {exc}')

        for conn, t_ns, raw in src.messages(conns):
            is_tracks = conn.topic == topic
            if copy_inputs and not src.is_ros1:
                out.write(conn.topic, raw, t_ns)
                report.copied[conn.topic] += 1
            if not is_tracks:
                continue
            msg = src.decode(raw, conn)
            stamp = stamp_ns(msg.header.stamp)
            if copy_inputs and src.is_ros1:
                out.add_topic(topic, POINTCLOUD2)
                out.write(topic, cloud_cdr(_tracks_fields(msg), stamp, msg.header.frame_id),
                          t_ns)
                report.copied[topic] += 1
            report.frames_in += 1
            try:
                tracks = decode_tracks(msg)
                received.setdefault(stamp, t_ns)
                solve(pipeline.add_frame(stamp, tracks.ids, tracks.uv, msg.header.frame_id))
            except (CloudError, *skip_errors) as exc:
                report.refused.append(f'frame {report.frames_in - 1} (stamp {stamp}): {exc}')
            if progress is not None:
                progress(report.frames_in, total)
        solve(pipeline.flush())
    report.seconds = time.perf_counter() - t_wall
    report.cpu_seconds = time.process_time() - t_cpu
    return report


def _definition_of(conn):
    """ros2msg text for a connection's type: Jazzy's own, else the one stored in the bag."""
    if conn.msgtype in typestore().types:
        return message_definition(conn.msgtype)[0]
    return conn.msgdef.data


def _tracks_fields(msg):
    """Structured (track_id, u, v) array of a tracks cloud (all points, NaN kept)."""
    from grass_nrsfm_ros.cloud import TRACK_FIELDS, structured_view

    view = structured_view(msg, TRACK_FIELDS)
    uv = np.stack([view['u'], view['v']], axis=1).astype(np.float64)
    return tracks_array(view['track_id'], uv)
