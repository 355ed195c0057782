"""Bags: recording (a writer thread), reading, recovery of killed recordings. All I/O, no
solver; the offline reconstruction of a bag is :mod:`grass_nrsfm_ros.commands.reconstruct`.

Modules, by concern: :mod:`.messages` (topics, errors, Jazzy types, CDR), :mod:`.write`
(:class:`BagWriter`, ``metadata.yaml``, arrays as a tracks bag), :mod:`.record` (the
:class:`Recorder` thread), :mod:`.read` (:class:`BagReader` and the ``read_*`` functions),
:mod:`.recovery` (:func:`recover`). The names below are the public API:
``from grass_nrsfm_ros.bag import X``.

Topics (defaults; the node publishes ``points`` relative to its namespace):
``/tracks``: the input contract, one PointCloud2 per frame (track_id, u, v);
``/points``: reconstructions, one PointCloud2 per frame (x, y, z, track_id), camera frame;
``/ground_truth``: written by ``grass-nrsfm convert`` when the .npz has ``S``: the true shape
of each frame in the points layout, stamped like the frame's tracks.

Shapes: ``W: (2F, P)``, ``S: (3F, P)`` as in :mod:`grass_nrsfm_ros.nrsfm.measurement`.
"""
from grass_nrsfm_ros.bag.messages import (BagError, cloud_cdr, CorruptBagError,
                                          GROUND_TRUTH_TOPIC, message_definition, POINTCLOUD2,
                                          POINTS_TOPIC, PointsFrame, REFINED_TOPIC, serialize,
                                          stamp_ns, TopicNotFoundError, TrackFrame,
                                          TRACKS_TOPIC, typestore)
from grass_nrsfm_ros.bag.read import (bag_size_bytes, BagReader, definition_of,
                                      frames_to_matrix, iter_raw, read_clouds, read_points,
                                      read_S, read_tracks, read_W, topics, tracks_fields)
from grass_nrsfm_ros.bag.record import DEFAULT_FLUSH_PERIOD, DEFAULT_QUEUE_SIZE, Recorder
from grass_nrsfm_ros.bag.recovery import mcap_files, recover, RecoveryReport
from grass_nrsfm_ros.bag.write import (BagWriter, DEFAULT_CHUNK_SIZE, ROSBAG2_VERSION,
                                       tracks_bag_from_arrays, write_metadata)

__all__ = [
    'bag_size_bytes', 'BagError', 'BagReader', 'BagWriter', 'cloud_cdr', 'CorruptBagError',
    'DEFAULT_CHUNK_SIZE', 'DEFAULT_FLUSH_PERIOD', 'DEFAULT_QUEUE_SIZE', 'definition_of',
    'frames_to_matrix', 'GROUND_TRUTH_TOPIC', 'iter_raw', 'mcap_files', 'message_definition',
    'POINTCLOUD2', 'POINTS_TOPIC', 'PointsFrame', 'read_clouds', 'read_points', 'read_S',
    'read_tracks', 'read_W', 'recover', 'RecoveryReport', 'Recorder', 'REFINED_TOPIC',
    'ROSBAG2_VERSION',
    'serialize', 'stamp_ns', 'topics', 'TopicNotFoundError', 'TrackFrame', 'TRACKS_TOPIC',
    'tracks_bag_from_arrays', 'tracks_fields', 'typestore', 'write_metadata',
]
