"""Rendered image sequences of textured deforming surfaces, with the ground truth of every
surface point (for the front end's tests and benchmarks).

A :class:`Scene` is a triangle mesh whose vertices move, ``vertices: (F, V, 3)`` in the
camera frame (x right, y down, z forward; units of the surface), ``triangles: (T, 3)``,
``texcoords: (V, 2)`` in [0, 1], seen through a pinhole camera ``K: (3, 3)`` as images
``(H, W, 3)`` uint8 RGB: a rich random colour texture on the surface (optionally Lambert
shaded from a light at the camera), a textured static background, optional Gaussian sensor
noise. Pixel centres are at integer coordinates: the point ``X`` projects to
``K [x/z, y/z, 1]``.

Rendering is a numpy z-buffer rasteriser (:func:`rasterise`) with perspective-correct
barycentric coordinates: every pixel knows its triangle and the surface point under it.
:meth:`Scene.truth` follows the surface point under any pixel of a frame through every frame:
``uv: (F, N, 2)`` true projections, ``X: (F, N, 3)`` camera-frame points and
``visible: (F, N)`` (in the image and not hidden behind the surface).

:func:`sheet_scene` renders the package's synthetic deformations (:mod:`..nrsfm.synthetic`:
'bending', 'waving', ...), :func:`face_scene` a Surrey-model face with expressions and a head
turn (:mod:`..nrsfm.faces`; FileNotFoundError without the model).
"""
from dataclasses import dataclass

import cv2
import numpy as np

from .imaging import sample
from ..nrsfm import faces, synthetic

DEG = np.pi / 180.0
_NEAR = 1e-6
_DEPTH_TOLERANCE = 0.01        # a point within 1 % of the z-buffer's depth is the surface seen
_BORDER = 2.0                  # px: a projection closer than this to the image edge is outside


@dataclass(frozen=True, eq=False)
class Raster:
    """One rasterised frame: ``triangle: (H, W) int32`` (-1: background),
    ``bary: (H, W, 3) float32`` perspective-correct barycentric coordinates,
    ``depth: (H, W) float32`` z (inf: background)."""

    triangle: np.ndarray
    bary: np.ndarray
    depth: np.ndarray


@dataclass(frozen=True, eq=False)
class Truth:
    """Ground truth of N surface points: ``uv: (F, N, 2)`` pixels, ``X: (F, N, 3)`` camera
    frame, ``visible: (F, N)`` bool, ``on_surface: (N,)`` bool (False: the start pixel showed
    the background; its rows are NaN and never visible), ``facing: (F, N)`` the cosine
    between the surface normal and the line of sight (1: seen face on, 0: edge-on; NaN off
    the surface)."""

    uv: np.ndarray
    X: np.ndarray
    visible: np.ndarray
    on_surface: np.ndarray
    facing: np.ndarray


class Scene:
    """A textured deforming mesh through a pinhole camera (see the module docstring).

    ``vertices: (F, V, 3)`` camera frame, ``triangles: (T, 3)``, ``texcoords: (V, 2)``,
    ``K: (3, 3)``, ``size (H, W)``; ``texture: (h, w, 3)`` and ``background: (H, W, 3)``
    uint8 RGB; ``noise`` sensor noise sigma in grey levels; ``shading`` the Lambertian share
    in [0, 1]; ``supersample`` renders at that factor and averages down (anti-aliasing).
    """

    def __init__(self, name, vertices, triangles, texcoords, K, size, texture, background, *,
                 noise=1.0, shading=0.3, supersample=1, seed=0):
        self.name = name
        self.vertices = np.asarray(vertices, dtype=np.float64)
        self.triangles = np.asarray(triangles, dtype=np.int64)
        self.texcoords = np.asarray(texcoords, dtype=np.float64)
        self.K = np.asarray(K, dtype=np.float64)
        self.size = tuple(int(s) for s in size)
        if background.shape[:2] != self.size:
            raise ValueError(f'background is {background.shape[:2]}, the image {self.size}')
        self.texture, self.background = texture, background
        self.noise, self.shading, self.supersample = float(noise), float(shading), supersample
        self.seed = seed
        self._depth = {}

    @property
    def n_frames(self):
        return self.vertices.shape[0]

    def project(self, X):
        """Pixels ``(..., 2)`` of camera-frame points ``X: (..., 3)``: ``K [x/z, y/z, 1]``."""
        homog = X @ self.K.T
        return homog[..., :2] / homog[..., 2:]

    def raster(self, f):
        """The :class:`Raster` of frame ``f`` at the image's resolution."""
        raster = rasterise(self.project(self.vertices[f]), self.vertices[f, :, 2],
                           self.triangles, self.size)
        self._depth[f] = raster.depth
        return raster

    def render(self, f):
        """Frame ``f`` as ``(H, W, 3)`` uint8 RGB."""
        s = self.supersample
        H, W = self.size
        K = self.K.copy()
        K[:2] *= s
        K[:2, 2] += (s - 1) / 2.0
        homog = self.vertices[f] @ K.T
        raster = rasterise(homog[:, :2] / homog[:, 2:], self.vertices[f, :, 2], self.triangles,
                           (H * s, W * s))
        image = self._shade(f, raster, s)
        if s > 1:
            image = cv2.resize(image, (W, H), interpolation=cv2.INTER_AREA)
        if self.noise > 0:
            rng = np.random.default_rng([self.seed, f])
            image += rng.standard_normal(image.shape, np.float32) * np.float32(self.noise)
        return np.clip(image + 0.5, 0, 255).astype(np.uint8)

    def frames(self):
        """The frames one by one (a generator of ``(H, W, 3)`` uint8)."""
        for f in range(self.n_frames):
            yield self.render(f)

    def images(self):
        """All frames, ``(F, H, W, 3)`` uint8."""
        return np.stack(list(self.frames()))

    def mask(self, f=0):
        """``(H, W)`` bool: where frame ``f`` shows the surface."""
        return self.raster(f).triangle >= 0

    def truth(self, uv, start=0):
        """Follow the surface points under pixels ``uv: (N, 2)`` of frame ``start`` through
        every frame; returns a :class:`Truth`."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        tri, bary = self._surface_points(uv, start)
        on_surface = tri >= 0
        corners = self.vertices[:, self.triangles[np.maximum(tri, 0)], :]    # (F, N, 3, 3)
        X = np.einsum('fncd,nc->fnd', corners, bary)
        X[:, ~on_surface] = np.nan
        projected = self.project(X)
        visible = self._visible(X, projected) & on_surface[None]
        return Truth(uv=projected, X=X, visible=visible, on_surface=on_surface,
                     facing=_facing(corners, X))

    def sample_points(self, n_points, seed=0):
        """``n_points`` area-weighted surface samples as a :class:`Truth` (uniform in the
        frame-0 surface)."""
        rng = np.random.default_rng(seed)
        tri, bary = faces.sample_surface(self.vertices[0], self.triangles, n_points, rng)
        X = np.einsum('fncd,nc->fnd', self.vertices[:, self.triangles[tri], :], bary)
        projected = self.project(X)
        return Truth(uv=projected, X=X, visible=self._visible(X, projected),
                     on_surface=np.ones(n_points, bool),
                     facing=_facing(self.vertices[:, self.triangles[tri], :], X))

    # ------------------------------------------------------------ internals

    def _surface_points(self, uv, start):
        """Triangle ``(N,)`` (-1 off the surface) and perspective-correct barycentric
        coordinates ``(N, 3)`` of the surface points under pixels ``uv`` of frame ``start``:
        of the triangles seen at the 3 x 3 pixels around each point, the one containing it
        (the most inside)."""
        raster = self.raster(start)
        H, W = self.size
        pix = self.project(self.vertices[start])
        col = np.round(uv[:, 0]).astype(int)
        row = np.round(uv[:, 1]).astype(int)
        best_tri = np.full(len(uv), -1, np.int64)
        best_bary = np.full((len(uv), 3), np.nan)
        best_score = np.full(len(uv), -np.inf)
        for dr, dc in [(0, 0), (0, -1), (0, 1), (-1, 0), (1, 0), (-1, -1), (-1, 1), (1, -1),
                       (1, 1)]:
            tri = raster.triangle[np.clip(row + dr, 0, H - 1),
                                  np.clip(col + dc, 0, W - 1)].astype(np.int64)
            screen = _barycentric(pix[self.triangles[np.maximum(tri, 0)]], uv)
            score = np.where(tri >= 0, screen.min(axis=1), -np.inf)
            better = score > best_score + 1e-9
            best_tri[better], best_bary[better], best_score[better] = \
                tri[better], screen[better], score[better]
        corners = self.triangles[np.maximum(best_tri, 0)]
        q = best_bary / self.vertices[start, :, 2][corners]
        return best_tri, q / q.sum(axis=1, keepdims=True)

    def _visible(self, X, uv):
        """``(F, N)``: in the image and not behind the surface (z-buffer test)."""
        H, W = self.size
        u, v = uv[..., 0], uv[..., 1]
        with np.errstate(invalid='ignore'):
            inside = (u >= _BORDER) & (u <= W - 1 - _BORDER) & (v >= _BORDER) & \
                (v <= H - 1 - _BORDER) & (X[..., 2] > 0)
        visible = np.zeros(inside.shape, bool)
        for f in range(self.n_frames):
            depth = self._depth[f] if f in self._depth else self.raster(f).depth
            ok = inside[f]
            seen = depth[np.round(v[f, ok]).astype(int), np.round(u[f, ok]).astype(int)]
            visible[f, ok] = X[f, ok, 2] <= seen * (1.0 + _DEPTH_TOLERANCE)
        return visible

    def _shade(self, f, raster, s):
        """Float32 image ``(H s, W s, 3)``: texture times shading on the surface, the
        background elsewhere."""
        hit = np.flatnonzero(raster.triangle.ravel() >= 0)
        corners = self.triangles[raster.triangle.ravel()[hit]]                # (n, 3)
        bary = raster.bary.reshape(-1, 3)[hit]                               # (n, 3)
        th, tw = self.texture.shape[:2]
        st = _interpolate(bary, np.float32(self.texcoords * (tw - 1, th - 1)), corners)
        colour = sample(self.texture, st)
        if self.shading > 0:
            normals = _interpolate(bary, np.float32(_vertex_normals(
                self.vertices[f], self.triangles)), corners)
            light = np.float32([0.3, -0.4, -1.0]) / np.float32(np.sqrt(1.25))
            cosine = np.abs(normals @ light) / np.maximum(np.linalg.norm(normals, axis=1), 1e-12)
            colour *= (1.0 - self.shading + self.shading * cosine)[:, None]
        background = self.background
        if s > 1:
            background = cv2.resize(background, raster.triangle.shape[::-1],
                                    interpolation=cv2.INTER_NEAREST)
        image = background.astype(np.float32).reshape(-1, 3)
        image[hit] = colour
        return image.reshape(background.shape)


def _facing(corners, X):
    """``(F, N)`` |cos| of the angle between each point's triangle normal and its line of
    sight, from ``corners: (F, N, 3, 3)`` and the points ``X: (F, N, 3)`` (camera frame)."""
    normal = np.cross(corners[..., 1, :] - corners[..., 0, :],
                      corners[..., 2, :] - corners[..., 0, :])
    with np.errstate(invalid='ignore', divide='ignore'):
        cosine = np.einsum('fnd,fnd->fn', normal, X) / (
            np.linalg.norm(normal, axis=-1) * np.linalg.norm(X, axis=-1))
    return np.abs(cosine)


def _interpolate(bary, values, corners):
    """``(n, C)``: per-vertex ``values (V, C)`` at barycentric ``bary (n, 3)`` of triangles
    with vertex indices ``corners (n, 3)``."""
    out = bary[:, 0, None] * values[corners[:, 0]]
    out += bary[:, 1, None] * values[corners[:, 1]]
    out += bary[:, 2, None] * values[corners[:, 2]]
    return out


# ---------------------------------------------------------------- rasteriser

def rasterise(uv, z, triangles, size):
    """Z-buffer rasterisation of a mesh projected to pixels ``uv: (V, 2)`` with depths
    ``z: (V,)``; ``triangles: (T, 3)``; ``size (H, W)``. A pixel (x, y) is covered by a
    triangle when its centre (x, y) lies inside it; the nearest covering triangle wins.
    Returns a :class:`Raster`."""
    H, W = size
    corners = uv[triangles]                                             # (T, 3, 2)
    depth = z[triangles]                                                # (T, 3)
    low = np.maximum(np.ceil(corners.min(axis=1)).astype(np.int64), 0)
    high = np.minimum(np.floor(corners.max(axis=1)).astype(np.int64), [W - 1, H - 1])
    coeffs, area = _perspective_planes(corners, depth)                  # (T, 3, 3)
    keep = np.nonzero((depth > _NEAR).all(axis=1) & (np.abs(area) > 1e-12)
                      & (high >= low).all(axis=1))[0]
    width = high[keep, 0] - low[keep, 0] + 1
    count = width * (high[keep, 1] - low[keep, 1] + 1)
    owner = np.repeat(keep.astype(np.int32), count)                     # (n,) triangle
    local = np.arange(count.sum(), dtype=np.int32) - np.repeat(
        (np.cumsum(count) - count).astype(np.int32), count)
    w = np.repeat(width.astype(np.int32), count)
    px = low[owner, 0].astype(np.int32) + local % w
    py = low[owner, 1].astype(np.int32) + local // w
    planes = coeffs.astype(np.float32)[owner]                           # (n, 3, 3)
    q = planes[:, :, 2]                                                 # (n, 3) bary / z
    q += planes[:, :, 0] * px[:, None].astype(np.float32)
    q += planes[:, :, 1] * py[:, None].astype(np.float32)
    inside = np.flatnonzero(q.min(axis=1) >= -1e-6 / depth.max())    # no cracks on edges
    owner, q = owner[inside], q[inside]
    key = py[inside] * W + px[inside]
    inverse_depth = q.sum(axis=1)
    nearest = np.zeros(H * W, np.float32)
    np.maximum.at(nearest, key, inverse_depth)
    win = np.flatnonzero(inverse_depth >= nearest[key])
    key = key[win]
    triangle = np.full(H * W, -1, np.int32)
    bary = np.zeros((H * W, 3), np.float32)
    triangle[key] = owner[win]
    bary[key] = q[win] / inverse_depth[win, None]
    with np.errstate(divide='ignore'):
        zbuf = np.float32(1.0) / nearest
    return Raster(triangle=triangle.reshape(H, W), bary=bary.reshape(H, W, 3),
                  depth=zbuf.reshape(H, W))


def _perspective_planes(corners, depth):
    """Per triangle, the planes ``(T, 3, 3)`` giving ``bary_i / z_i = a x + b y + c`` at pixel
    (x, y) (screen barycentric coordinates over depth: perspective-correct after
    normalising), and the signed doubled screen area ``(T,)``."""
    x, y = corners[..., 0], corners[..., 1]                             # (T, 3)
    x1, x2, x3 = x.T
    y1, y2, y3 = y.T
    area = (x2 - x1) * (y3 - y1) - (y2 - y1) * (x3 - x1)
    safe = np.where(np.abs(area) > 1e-12, area, 1.0)
    a = np.stack([y2 - y3, y3 - y1, y1 - y2], axis=1)
    b = np.stack([x3 - x2, x1 - x3, x2 - x1], axis=1)
    c = np.stack([x2 * y3 - x3 * y2, x3 * y1 - x1 * y3, x1 * y2 - x2 * y1], axis=1)
    scale = safe[:, None, None] * np.maximum(depth, _NEAR)[..., None]
    return np.stack([a, b, c], axis=2) / scale, area


def _barycentric(corners, points):
    """Screen-space barycentric coordinates ``(N, 3)`` of ``points: (N, 2)`` in triangles
    ``corners: (N, 3, 2)``."""
    a = corners[:, 0]
    e1, e2, p = corners[:, 1] - a, corners[:, 2] - a, points - a
    area = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    l1 = (p[:, 0] * e2[:, 1] - p[:, 1] * e2[:, 0]) / area
    l2 = (e1[:, 0] * p[:, 1] - e1[:, 1] * p[:, 0]) / area
    return np.column_stack([1.0 - l1 - l2, l1, l2])


def _vertex_normals(vertices, triangles):
    """Area-weighted vertex normals ``(V, 3)`` (not normalised)."""
    corners = vertices[triangles]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    out = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(out, triangles[:, k], normals)
    return out


# ---------------------------------------------------------------- textures

def random_texture(size, seed, finest=2.0):
    """A rich random RGB texture ``(h, w, 3)`` uint8: multi-scale noise (octaves from
    ``finest`` pixels of blur up to a quarter of the size) plus random coloured blobs."""
    h, w = size
    rng = np.random.default_rng(seed)
    image = np.zeros((h, w, 3), np.float32)
    scale = finest
    while scale < min(h, w) / 4:
        layer = rng.standard_normal((h, w, 3)).astype(np.float32)
        image += cv2.GaussianBlur(layer, (0, 0), scale) * np.float32(scale ** 0.5)
        scale *= 2.0
    blobs = np.zeros((h, w, 3), np.float32)
    n = int(h * w / 400)
    centres = rng.random((n, 2)) * (w, h)
    radii = rng.uniform(2, 12, n) * (min(h, w) / 512)
    colours = rng.uniform(-1, 1, (n, 3))
    for (x, y), r, c in zip(centres, radii, colours):
        cv2.circle(blobs, (int(x), int(y)), max(int(r), 1), c.tolist(), -1, cv2.LINE_AA)
    image = image / image.std() + 0.8 * cv2.GaussianBlur(blobs, (0, 0), finest)
    image = (image - image.mean()) / (3 * image.std())
    return np.clip(128 + 100 * image, 0, 255).astype(np.uint8)


# ---------------------------------------------------------------- scenes

def pinhole(size=(480, 640), focal=620.0):
    """``K (3, 3)`` with the principal point at the image centre."""
    H, W = size
    return np.array([[focal, 0.0, (W - 1) / 2.0], [0.0, focal, (H - 1) / 2.0], [0, 0, 1.0]])


def turn(n_frames, seed, yaw=30.0, pitch=10.0, roll=5.0):
    """Head-turn rotations ``(F, 3, 3)``: the yaw swings once from -``yaw`` to +``yaw``
    degrees over the sequence, pitch and roll move smoothly within +- theirs (random
    phases)."""
    rng = np.random.default_rng([seed, 7])
    t = synthetic.frame_times(n_frames)
    phase = rng.uniform(0, 2 * np.pi, 3)
    return synthetic.rotations_from_angles(
        -yaw * DEG * np.cos(np.pi * t),
        pitch * DEG * np.sin(2 * np.pi * 0.5 * t + phase[1]),
        roll * DEG * np.sin(2 * np.pi * 0.4 * t + phase[2]))


def _place(world, R, extent_px, focal, exit_share, H, W):
    """Camera-frame vertices ``(F, V, 3)``: ``R_f world_f`` at the depth where the shape's
    frame-0 extent spans ``extent_px``; the last ``exit_share`` of the sequence slides it out
    of the image to the right."""
    camera = np.einsum('fij,fvj->fvi', R, world)
    span = float(np.ptp(world[0, :, :2], axis=0).max())
    distance = focal * span / extent_px
    F = world.shape[0]
    shift = np.zeros((F, 3))
    shift[:, 2] = distance
    if exit_share > 0:
        t = synthetic.frame_times(F)
        ramp = np.clip((t - (1 - exit_share)) / exit_share, 0, 1)
        shift[:, 0] = ramp * (W / 2 + extent_px) * distance / focal
    return camera + shift[:, None, :]


def sheet_scene(kind='bending', n_frames=100, *, size=(480, 640), focal=620.0,
                extent_px=400, grid=(96, 72), yaw=25.0, exit_share=0.0, noise=1.0,
                shading=0.3, supersample=1, seed=0):
    """A textured sheet deforming as :mod:`..nrsfm.synthetic`'s ``kind`` (a mesh of
    ``grid`` vertices over its parameters), turning by :func:`turn` (``yaw`` degrees)."""
    if kind not in synthetic.all_kinds():
        raise ValueError(f'unknown kind {kind!r}; choose from {synthetic.all_kinds()}')
    nu, nv = grid
    params = np.stack(np.meshgrid(np.linspace(0, 1, nu), np.linspace(0, 1, nv)),
                      axis=-1).reshape(-1, 2)
    world = synthetic._KINDS[kind](params, synthetic.frame_times(n_frames))   # (F, 3, V)
    world = world.transpose(0, 2, 1)
    R = turn(n_frames, seed, yaw=yaw, pitch=yaw / 2.5, roll=yaw / 5)
    H, W = size
    vertices = _place(world, R, extent_px, focal, exit_share, H, W)
    texture = random_texture((int(extent_px * 0.75), extent_px), seed)
    background = random_texture(size, seed + 1000)
    return Scene(f'sheet_{kind}', vertices, _grid_triangles(nu, nv), params, pinhole(size, focal),
                 size, texture, background // 2 + 64, noise=noise, shading=shading,
                 supersample=supersample, seed=seed)


def _grid_triangles(nu, nv):
    """Two triangles per cell of an ``nu x nv`` vertex grid (row-major), ``(T, 3)``."""
    index = np.arange(nu * nv).reshape(nv, nu)
    a, b = index[:-1, :-1].ravel(), index[:-1, 1:].ravel()
    c, d = index[1:, :-1].ravel(), index[1:, 1:].ravel()
    return np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])


def face_scene(n_frames=100, *, model=None, size=(480, 640), focal=620.0, extent_px=340,
               yaw=30.0, exit_share=0.0, noise=1.0, shading=0.3, supersample=1, seed=0):
    """A Surrey-model face (random identity) blending expressions in and out and turning its
    head by :func:`turn` (``yaw`` degrees); ``model`` as :func:`..nrsfm.faces.load_face_model`
    takes it (FileNotFoundError without it)."""
    if not isinstance(model, faces.FaceModel):
        model = faces.load_face_model(model)
    rng = np.random.default_rng([seed, 3])
    identity = model.identity(rng.standard_normal(10))
    weights = faces.expression_weights(len(model.expressions), n_frames, rng)   # (F, E)
    world = identity[None] + np.einsum('fe,evd->fvd', weights, model.expressions)
    world = (world - identity.mean(axis=0)) * (1.0, -1.0, -1.0)       # y down, z away
    R = turn(n_frames, seed, yaw=yaw)
    H, W = size
    vertices = _place(world, R, extent_px, focal, exit_share, H, W)
    texcoords = (identity[:, :2] - identity[:, :2].min(0)) / np.ptp(identity[:, :2], axis=0)
    texcoords[:, 1] = 1.0 - texcoords[:, 1]
    texture = random_texture((extent_px, int(extent_px * 0.8)), seed)
    background = random_texture(size, seed + 1000)
    return Scene('face', vertices, model.triangles, texcoords, pinhole(size, focal), size,
                 texture, background // 2 + 64, noise=noise, shading=shading,
                 supersample=supersample, seed=seed)
