"""A surface over the reconstructed points: triangles from a 2D Delaunay triangulation of a
reference frame's tracks, over-long triangles dropped, vertices coloured by depth.

No ROS import (:mod:`grass_nrsfm_ros.marker` turns a mesh into a visualization_msgs Marker).
Shapes: ``uv: (P, 2)`` image-plane coordinates of the reference frame, ``xyz: (P, 3)`` one
reconstructed frame on the same tracks, ``triangles: (T, 3)`` int indices into the P tracks,
``vertices: (3T, 3)`` and ``colours: (3T, 4)`` RGBA in [0, 1] (TRIANGLE_LIST order).
"""
import numpy as np
from scipy.spatial import Delaunay, QhullError

#: a triangle is dropped when its longest edge exceeds this many times the median edge
MAX_EDGE_FACTOR = 3.0

# viridis at 8 control points (near = dark)
_VIRIDIS = np.array([(68, 1, 84), (70, 50, 126), (54, 92, 141), (39, 127, 142),
                     (31, 161, 135), (74, 193, 109), (160, 218, 57), (253, 231, 37)]) / 255.0


def triangulate(uv, max_edge_factor=MAX_EDGE_FACTOR):
    """``(T, 3)`` triangles of the Delaunay triangulation of ``uv: (P, 2)`` without those whose
    longest edge exceeds ``max_edge_factor`` x the median edge (the long, thin triangles
    across gaps and along the convex hull); empty for fewer than 3 points or collinear ones."""
    uv = np.asarray(uv, dtype=np.float64)
    if uv.shape[0] < 3:
        return np.zeros((0, 3), dtype=np.int64)
    try:
        tri = Delaunay(uv)
    except QhullError:                         # collinear or duplicate points only
        return np.zeros((0, 3), dtype=np.int64)
    simplices = tri.simplices.astype(np.int64)
    corners = uv[simplices]                                          # (T, 3, 2)
    edges = np.linalg.norm(corners - np.roll(corners, -1, axis=1), axis=2)   # (T, 3)
    longest = edges.max(axis=1)
    keep = longest <= max_edge_factor * np.median(edges)
    return simplices[keep]


def depth_colours(z, z_range=None):
    """``(N, 4)`` RGBA (viridis, alpha 1) for depths ``z: (N,)``, near = dark; ``z_range``
    ``(lo, hi)`` fixes the scale (default: the range of ``z``)."""
    z = np.asarray(z, dtype=np.float64)
    lo, hi = (np.nanmin(z), np.nanmax(z)) if z_range is None else z_range
    t = np.clip(np.nan_to_num((z - lo) / max(hi - lo, 1e-12)), 0, 1) * (len(_VIRIDIS) - 1)
    i = np.minimum(t.astype(int), len(_VIRIDIS) - 2)
    frac = (t - i)[:, None]
    rgb = _VIRIDIS[i] * (1 - frac) + _VIRIDIS[i + 1] * frac
    return np.hstack([rgb, np.ones((z.size, 1))])


def triangle_list(xyz, triangles):
    """``(vertices: (3T, 3), colours: (3T, 4))``: each triangle's corners from ``xyz: (P, 3)``
    in TRIANGLE_LIST order, coloured by their depth (z)."""
    xyz = np.asarray(xyz, dtype=np.float64)
    vertices = xyz[np.asarray(triangles, dtype=np.int64).reshape(-1)]
    return vertices, depth_colours(vertices[:, 2], (xyz[:, 2].min(), xyz[:, 2].max()))


class MeshCache:
    """The triangulation of the current track set: rebuilt (from the ``uv`` given with the
    first frame of a new set) only when the set of track ids changes."""

    def __init__(self, max_edge_factor=MAX_EDGE_FACTOR):
        self.max_edge_factor = max_edge_factor
        self.ids = None
        self.triangles = np.zeros((0, 3), dtype=np.int64)
        self.builds = 0

    def triangles_for(self, ids, uv):
        """Triangles ``(T, 3)`` indexing ``ids: (P,)``; ``uv: (P, 2)`` is used when the set of
        ids differs from the cached one (ids in another order are mapped, not rebuilt)."""
        ids = np.asarray(ids)
        if self.ids is None or self.ids.size != ids.size or \
                not np.array_equal(np.sort(self.ids), np.sort(ids)):
            self.ids = ids.copy()
            self.triangles = triangulate(uv, self.max_edge_factor)
            self.builds += 1
            return self.triangles
        if np.array_equal(self.ids, ids):
            return self.triangles
        order = np.argsort(ids)
        position = order[np.searchsorted(ids[order], self.ids)]    # cached index -> new index
        return position[self.triangles]
