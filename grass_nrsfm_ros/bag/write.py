"""Writing rosbag2 **MCAP** bags synchronously: the layout ``ros2 bag record -s mcap`` makes, a
directory ``NAME/`` with ``metadata.yaml`` (rosbag2 version 9, Jazzy) and ``NAME_0.mcap``
(profile ``ros2``, ``ros2msg`` schemas embedded, ``cdr`` messages).

The MCAP file is written with the ``mcap`` library because it lets us choose the chunk size and
finish a chunk on demand (:meth:`BagWriter.flush`), which the Recorder thread relies on. Also
here: ``W: (2F, P)`` (and ground truth ``S: (3F, P)``) written as a tracks bag.
"""
from collections import Counter
from pathlib import Path

from mcap.writer import CompressionType, Writer
import numpy as np
import yaml

from grass_nrsfm_ros.bag.messages import (BagError, cloud_cdr, GROUND_TRUTH_TOPIC,
                                          message_definition, POINTCLOUD2, POINTS_TOPIC,
                                          serialize, TRACKS_TOPIC, typestore)
from grass_nrsfm_ros.bag.offered_qos import offered_qos_list
from grass_nrsfm_ros.cloud import points_array, tracks_array
from grass_nrsfm_ros.nrsfm.measurement import as_frames, validate_shapes, validate_tracks

DEFAULT_CHUNK_SIZE = 256 * 1024          # bytes of messages per MCAP chunk
ROSBAG2_VERSION = 9                      # Jazzy


class BagWriter:
    """Synchronous rosbag2/MCAP writer (the offline tools and the Recorder thread use it).

    ``path`` is the bag directory; it must not exist or be empty. ``close()`` writes the MCAP
    summary (index, statistics) and ``metadata.yaml``; it is idempotent. ``chunk_size`` bytes
    per chunk; ``compression`` None or 'zstd'.
    """

    def __init__(self, path, *, chunk_size=DEFAULT_CHUNK_SIZE, compression=None):
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
    """``metadata.yaml`` (rosbag2 version 9, mcap storage) for ``topics``: rows of
    ``(name, msgtype, type hash, offered_qos_profiles, message_count)``."""
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


def tracks_bag_from_arrays(W, stamps, out, frame_id='camera_optical', *, topic=TRACKS_TOPIC,
                           S=None, gt_topic=GROUND_TRUTH_TOPIC, visible=None):
    """Write ``W: (2F, P)`` as a tracks bag at ``out``: frame f is one cloud with the points
    visible in it (``visible: (F, P)`` bool, default all), track id = column of W, header
    stamp and receive time ``stamps[f]`` (ns). ``S: (3F, P)`` ground truth, when given, goes
    to ``gt_topic`` in the points layout with the same stamps. Returns the message counts.
    """
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
