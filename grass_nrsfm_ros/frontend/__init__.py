"""The camera front end, with no ROS in it: images in, dense 2D tracks out.

* :class:`DenseTracker` (:mod:`.flow`): frames ``(H, W)`` / ``(H, W, 3|4)`` uint8 or uint16
  in, per frame a :class:`TrackFrame` out: ``ids: (P,) uint32``, ``uv: (P, 2) float64``
  pixels, ``age: (P,) int64`` frames, ``counts`` (alive, born, lost, failed checks); its
  image operations in :mod:`.imaging`, the tracks' displacement fields in :mod:`.fields`,
  its region, grid cells and boxes in :mod:`.grid`.
* :mod:`.sources`: image folders, videos and bags as frames.
* :mod:`.scenes`: a renderer of textured deforming surfaces through a pinhole camera with the
  ground truth of every surface point, for tests and benchmarks.
"""
from .flow import DenseTracker, FrameSizeError, METHODS, TrackFrame

__all__ = ['DenseTracker', 'FrameSizeError', 'METHODS', 'TrackFrame']
