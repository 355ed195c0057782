"""Reading bags through ``rosbags.highlevel.AnyReader``: a rosbag2 directory (mcap or sqlite3),
a bare ``.mcap`` file, or a ROS 1 ``.bag``; reader errors become :class:`BagError` with a hint
(``grass-nrsfm recover``) where a killed recording is the likely cause.

Shapes: ``W: (2F, P)``, ``S: (3F, P)`` as in :mod:`grass_nrsfm_ros.nrsfm.measurement`.
"""
import os
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader

from grass_nrsfm_ros.bag.messages import (BagError, CorruptBagError, message_definition,
                                          POINTCLOUD2, POINTS_TOPIC, PointsFrame, stamp_ns,
                                          TopicNotFoundError, TrackFrame, TRACKS_TOPIC,
                                          typestore)
from grass_nrsfm_ros.cloud import (CloudError, decode_points, decode_tracks, structured_view,
                                   TRACK_FIELDS, tracks_array)


class BagReader:
    """An open AnyReader over ``path`` with errors turned into :class:`BagError`."""

    def __init__(self, path):
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
    with BagReader(path) as bag:
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
    with BagReader(path) as bag:
        for conn, t_ns, raw in bag.messages(bag.connections(topic, msgtype)):
            yield t_ns, raw, conn.msgtype, bag.is_ros1, (
                lambda raw=raw, conn=conn: bag.decode(raw, conn))


def read_clouds(path, topic):
    """Yield ``(t_ns, msg)`` PointCloud2 dataclasses on ``topic`` in receive-time order."""
    with BagReader(path) as bag:
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


def bag_size_bytes(path):
    """Total size of the files of a bag (directory or file)."""
    path = Path(path)
    if path.is_file():
        return path.stat().st_size
    return sum(os.path.getsize(p) for p in path.rglob('*') if p.is_file())


def definition_of(conn):
    """ros2msg text for a connection's type: Jazzy's own, else the one stored in the bag."""
    if conn.msgtype in typestore().types:
        return message_definition(conn.msgtype)[0]
    return conn.msgdef.data


def tracks_fields(msg):
    """Structured (track_id, u, v) array of a tracks cloud (all points, NaN kept)."""
    view = structured_view(msg, TRACK_FIELDS)
    uv = np.stack([view['u'], view['v']], axis=1).astype(np.float64)
    return tracks_array(view['track_id'], uv)
