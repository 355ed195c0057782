"""Synthetic deforming dense sequences with ground truth (no external data needed).

A :class:`Sequence` bundles orthographic tracks and their ground truth in the conventions of
:mod:`.measurement` (F frames, P points):

* ``W: (2F, P)`` tracks; rows ``2f, 2f+1`` equal rows ``3f, 3f+1`` of ``S`` plus the frame's
  translation plus noise.
* ``S: (3F, P)`` camera-frame ground truth, ``S_f = R_f S_world_f``.
* ``R: (F, 3, 3)`` world-to-camera rotations; ``S_world: (3F, P)`` the deforming shape.

:func:`make_sequence` samples points on a parametric surface (uniformly in its parameters) and
moves them by a genuinely non-linear deformation (see :func:`all_kinds`); the camera follows
one of :func:`camera_motions`. Everything is deterministic under ``seed``; the point samples,
camera, translation and noise draw from independent streams, so changing ``n_points`` leaves the
camera unchanged. Shapes are unit-ish (about 2 across) for every kind.

:meth:`Sequence.save_npz` / :meth:`Sequence.load_npz` use the layout of the benchmark data
folder (``W``, ``S``, ``visible``, ``meta`` JSON) plus ``R`` and ``translation``.
"""
from dataclasses import dataclass, field
import json
from pathlib import Path

import numpy as np

from .measurement import (as_frames, centre, from_frames, to_camera, to_world,
                          validate_rotations, validate_shapes, validate_tracks)

DEG = np.pi / 180.0


@dataclass(frozen=True, eq=False)
class Sequence:
    """A sequence of tracks with (optional) ground truth.

    ``W: (2F, P)``, ``S: (3F, P)`` camera frame or None, ``R: (F, 3, 3)`` world->camera or
    None, ``S_world: (3F, P)`` or None, ``translation: (2F, 1)`` added to the projected
    ``S`` (None where unknown), ``noise_sigma`` the standard deviation of the Gaussian noise on
    ``W`` (same units as ``W``), ``meta`` a JSON-serialisable dict.
    """

    name: str
    W: np.ndarray
    S: np.ndarray = None
    R: np.ndarray = None
    S_world: np.ndarray = None
    noise_sigma: float = 0.0
    meta: dict = field(default_factory=dict)
    translation: np.ndarray = None

    @property
    def n_frames(self):
        """F."""
        return self.W.shape[0] // 2

    @property
    def n_points(self):
        """P."""
        return self.W.shape[1]

    def save_npz(self, path):
        """Write a compressed ``.npz`` in the benchmark-data layout (float64 arrays).

        Arrays: ``W``, ``S`` and ``R`` where known, ``translation`` where known,
        ``visible: (F, P)`` all True, ``meta`` a JSON string (name, F, P, camera, ...).
        """
        arrays = {'W': self.W, 'visible': np.ones((self.n_frames, self.n_points), bool)}
        for key in ('S', 'R', 'translation'):
            value = getattr(self, key)
            if value is not None:
                arrays[key] = value
        meta = {'name': self.name, 'F': self.n_frames, 'P': self.n_points,
                'camera': 'orthographic', 'noise_sigma': self.noise_sigma, **self.meta}
        np.savez_compressed(path, meta=np.array(json.dumps(meta)), **arrays)

    @classmethod
    def load_npz(cls, path):
        """Read a file of the benchmark-data layout (``W``; ``S``, ``R``, ``translation`` if
        present) written by :meth:`save_npz` or found in the data folder. Arrays as float64."""
        path = Path(path)
        with np.load(path) as npz:
            meta = json.loads(str(npz['meta'])) if 'meta' in npz.files else {}
            W = validate_tracks(npz['W']).astype(np.float64)
            S = _optional(npz, 'S')
            R = _optional(npz, 'R')
            translation = _optional(npz, 'translation')
        F, P = W.shape[0] // 2, W.shape[1]
        if S is not None:
            S = validate_shapes(S, n_frames=F, n_points=P)
        if R is not None:
            R = validate_rotations(R, F)
        S_world = to_world(R, S) if R is not None and S is not None else None
        return cls(name=meta.get('name', path.stem), W=W, S=S, R=R, S_world=S_world,
                   noise_sigma=float(meta.get('noise_sigma', 0.0)), meta=meta,
                   translation=translation)


def _optional(npz, key):
    return npz[key].astype(np.float64) if key in npz.files else None


# ---------------------------------------------------------------------------------------------
# Surfaces: each maps parameters ``uv: (P, 2)`` in [0, 1]^2 and times ``t: (F,)`` in [0, 1] to
# world points ``(F, 3, P)``.

def _sheet(uv, width=2.0, height=1.5):
    """Flat sheet coordinates ``x: (P,)``, ``y: (P,)`` centred on the origin."""
    return width * (uv[:, 0] - 0.5), height * (uv[:, 1] - 0.5)


def _bent_arc(s, kappa):
    """Point at arc length ``s`` on a circle of curvature ``kappa`` tangent to the x axis at 0.

    Returns ``(along, depth)`` = ``(sin(k s) / k, (1 - cos(k s)) / k)``, smooth through k = 0.
    """
    along = s * np.sinc(kappa * s / np.pi)
    depth = 0.5 * kappa * s ** 2 * np.sinc(kappa * s / (2 * np.pi)) ** 2
    return along, depth


def _bending(uv, t):
    """A paper sheet bending (isometrically) about an axis that turns slowly; the curvature
    varies from 1.6 per unit length (ends curled up by about 90 degrees) through flat to
    slightly reversed (-0.2)."""
    x, y = _sheet(uv)
    t = t[:, None]
    kappa = 0.7 + 0.9 * np.sin(2 * np.pi * t + 0.4)           # (F, 1)
    phi = 0.5 * np.sin(np.pi * t)                             # bend-axis direction
    c, s = np.cos(phi), np.sin(phi)
    a = c * x + s * y                                         # across the bend axis
    b = -s * x + c * y                                        # along the bend axis
    along, depth = _bent_arc(a, kappa)
    pts = np.stack([c * along - s * b, s * along + c * b, depth - depth.mean(1, keepdims=True)])
    return pts.transpose(1, 0, 2)


def _waving(uv, t):
    """A cloth held at its left edge with travelling sinusoidal waves (growing towards the
    free edge) along x and, weaker, along y; the cloth is pulled in as it waves. It
    stretches: edge lengths of a 40 x 40 grid over 60 frames are 0.69-1.29 of frame 0's along
    x and 0.91-1.10 along y (p5-p95), so the inextensible priors do not hold on it; 'flag' is
    the isometric waving cloth (record 0713)."""
    x, y = _sheet(uv)
    t = t[:, None]
    reach = 0.08 + 0.3 * (x + 1.0) / 2.0                      # amplitude grows to the free edge
    phase_x = 2.5 * np.pi * x / 2.0 - 2 * np.pi * 1.5 * t
    phase_y = 2 * np.pi * y / 1.5 - 2 * np.pi * 0.7 * t + 1.0
    z = reach * np.sin(phase_x) + 0.35 * reach * np.sin(phase_y)
    xs = x - 0.12 * reach * (1.0 + np.cos(phase_x))
    ys = y + 0.05 * reach * np.sin(phase_y + phase_x)
    return np.stack([xs, ys, z]).transpose(1, 0, 2)


def _arc_length_curve(theta, length, s):
    """Points ``(along, depth)``, each ``(F, P)``, at arc lengths ``s: (P,)`` of the planar
    curves whose tangent angle is ``theta: (F, G)`` on ``G`` equally spaced arc lengths over
    ``[0, length]``: the integrals of cos and sin of theta (trapezoids), linear in between."""
    grid = np.linspace(0.0, length, theta.shape[1])
    step = 0.5 * (grid[1] - grid[0])
    curves = []
    for f in (np.cos(theta), np.sin(theta)):
        integral = np.concatenate([np.zeros((f.shape[0], 1)),
                                   np.cumsum(step * (f[:, 1:] + f[:, :-1]), axis=1)], axis=1)
        curves.append(np.stack([np.interp(s, grid, row) for row in integral]))
    return curves


def _flag(uv, t):
    """A cloth held at its left edge (a pole along y) with travelling waves that bend it
    without stretching (isometric by construction: unlike 'waving', which stretches by up to
    +-30 %). Every line across the cloth parallel to the pole stays straight; the cross-section
    is the curve of arc length ``s`` whose tangent angle is a sway about the pole (0.35 rad)
    plus a wave of 1.8 units travelling 1.5 times along it (0.3 rad at the pole growing to 1.0
    at the free edge) plus a weaker second one (0.3 of it; 0.9 units, 0.7 times, the other
    way round in phase). Depth range per frame 0.3-0.75 (about 2 across)."""
    x, y = _sheet(uv)
    length = 2.0
    grid = np.linspace(0.0, length, 2001)[None]                # arc length from the pole
    t = t[:, None]
    amplitude = 0.3 + 0.7 * grid / length
    theta = (0.35 * np.sin(2 * np.pi * 0.5 * t + 0.5)
             + amplitude * np.sin(2 * np.pi * grid / 1.8 - 2 * np.pi * 1.5 * t)
             + 0.3 * amplitude * np.sin(2 * np.pi * grid / 0.9 - 2 * np.pi * 0.7 * t + 1.0))
    along, depth = _arc_length_curve(theta, length, x + length / 2)
    xs = along - length / 2
    return np.stack([xs, np.broadcast_to(y, xs.shape), depth]).transpose(1, 0, 2)


def _inflating(uv, t):
    """A beating heart-like closed surface: an ellipsoid whose radius pulses non-uniformly
    (a contraction wave running from apex to base, stronger on one side) while it wrings
    (twists about its long axis)."""
    z0 = 2.0 * uv[:, 1] - 1.0                                 # uniform on the unit sphere
    lon = 2.0 * np.pi * uv[:, 0]
    ring = np.sqrt(1.0 - z0 ** 2)
    n = np.stack([ring * np.cos(lon), z0, ring * np.sin(lon)])     # (3, P) unit normals
    apex_to_base = (n[1] + 1.0) / 2.0                         # 0 at the apex, 1 at the base
    t = t[:, None]
    beat = 0.5 - 0.5 * np.cos(2 * np.pi * (2.0 * t - 0.15 * apex_to_base))  # (F, P) in [0, 1]
    side = 0.6 + 0.4 * n[0]                                   # the free wall moves more
    radius = 1.0 - 0.28 * beat * side
    axes = np.array([0.75, 1.0, 0.7])[:, None]
    pts = axes[None] * n[None] * radius[:, None, :]           # (F, 3, P)
    twist = 0.35 * beat * n[1]                                # wringing about the long axis
    c, s = np.cos(twist), np.sin(twist)
    x, y, z = pts[:, 0], pts[:, 1], pts[:, 2]
    return np.stack([c * x + s * z, y, -s * x + c * z], axis=1)


def _twisting(uv, t):
    """A strip twisting about its long axis (twist rate swinging both ways, up to about 90
    degrees at the ends) while sagging slightly."""
    x, y = _sheet(uv, width=2.0, height=0.7)
    t = t[:, None]
    rate = 1.5 * np.sin(2 * np.pi * 0.75 * t + 0.3)
    angle = rate * x
    sag = 0.15 * np.cos(np.pi * t) * (x ** 2 - 1.0 / 3.0)
    xs = np.broadcast_to(x, angle.shape)
    return np.stack([xs, y * np.cos(angle), y * np.sin(angle) + sag]).transpose(1, 0, 2)


def _articulated(uv, t):
    """Two gently curved panels hinged along the y axis, opening and closing like a book
    (each panel rigid; the two hinge angles move independently)."""
    x, y = _sheet(uv)
    z = 0.15 * np.sin(np.pi * np.abs(x))                      # each panel curved like a page
    t = t[:, None]
    right = x >= 0.0
    angle = np.where(right, 1.0 * np.sin(np.pi * t) ** 2, -0.5 * np.sin(2 * np.pi * t))
    c, s = np.cos(angle), np.sin(angle)
    xs, zs = c * x + s * z, -s * x + c * z
    return np.stack([xs, np.broadcast_to(y, xs.shape), zs]).transpose(1, 0, 2)


_KINDS = {
    'bending': _bending,
    'waving': _waving,
    'inflating': _inflating,
    'twisting': _twisting,
    'articulated': _articulated,
    'flag': _flag,
}

#: the kinds the benchmarks, records and tests iterate (:func:`kinds`); 'flag' (record 0713) is
#: asked for by name, so that adding it changed none of their rows or run times
_ITERATED = ('bending', 'waving', 'inflating', 'twisting', 'articulated')


def kinds():
    """Names of the five deformations the benchmarks iterate: 'bending' (isometric),
    'waving' (stretches: edge lengths 0.69-1.29 of frame 0's along the waves, p5-p95),
    'inflating', 'twisting' and 'articulated'. :func:`all_kinds` adds 'flag', an isometric
    waving cloth."""
    return _ITERATED


def all_kinds():
    """Names of every deformation :func:`make_sequence` knows: :func:`kinds` and 'flag'."""
    return tuple(_KINDS)


# ---------------------------------------------------------------------------------------------
# Cameras

def rotations_from_angles(yaw, pitch, roll):
    """World->camera rotations ``(F, 3, 3)`` = ``Rz(roll) Rx(pitch) Ry(yaw)``; angles in
    radians, each ``(F,)``."""
    yaw, pitch, roll = (np.asarray(a, dtype=np.float64) for a in (yaw, pitch, roll))
    F = yaw.shape[0]

    def axis_rotation(angle, i, j):
        R = np.tile(np.eye(3), (F, 1, 1))
        c, s = np.cos(angle), np.sin(angle)
        R[:, i, i], R[:, i, j], R[:, j, i], R[:, j, j] = c, -s, s, c
        return R

    return axis_rotation(roll, 0, 1) @ axis_rotation(pitch, 1, 2) @ axis_rotation(yaw, 2, 0)


def _smooth_random(rng, t, amplitude, n_waves=3):
    """A smooth random signal ``(F,)`` on times ``t: (F,)`` in [0, 1]: a few sinusoids of
    0.3 to 1.5 cycles per sequence, scaled so its peak magnitude is about ``amplitude``."""
    freq = rng.uniform(0.3, 1.5, n_waves)
    phase = rng.uniform(0.0, 2 * np.pi, n_waves)
    weight = rng.uniform(0.5, 1.0, n_waves)
    signal = (weight[:, None] * np.sin(2 * np.pi * freq[:, None] * t + phase[:, None])).sum(0)
    return amplitude * signal / weight.sum()


def _orbit(rng, t):
    phase = rng.uniform(0.0, 2 * np.pi, 3)
    return (35 * DEG * np.sin(2 * np.pi * 0.8 * t + phase[0]),
            20 * DEG * np.sin(2 * np.pi * 0.6 * t + phase[1]),
            10 * DEG * np.sin(2 * np.pi * 0.5 * t + phase[2]))


def _wobble(rng, t):
    return tuple(_smooth_random(rng, t, 6 * DEG) for _ in range(3))


def _static(rng, t):
    zero = np.zeros_like(t)
    return zero, zero, zero


def _shaky(rng, t):
    return tuple(a + rng.normal(0.0, 2 * DEG, t.shape) for a in _orbit(rng, t))


_CAMERAS = {'orbit': _orbit, 'wobble': _wobble, 'static': _static, 'shaky': _shaky}


def camera_motions():
    """Names of the camera motions: 'orbit' (smooth yaw +-35, pitch +-20, roll +-10 degrees),
    'wobble' (small smooth random motion, a few degrees), 'static' (identity: degenerate),
    'shaky' (orbit plus 2 degree per-frame jitter)."""
    return tuple(_CAMERAS)


def camera_rotations(motion, n_frames, rng):
    """World->camera rotations ``R: (F, 3, 3)`` following ``motion`` (see
    :func:`camera_motions`), drawn from the generator ``rng``."""
    if motion not in _CAMERAS:
        raise ValueError(f'unknown camera motion {motion!r}; choose from {camera_motions()}')
    return rotations_from_angles(*_CAMERAS[motion](rng, frame_times(n_frames)))


def frame_times(n_frames):
    return np.linspace(0.0, 1.0, n_frames) if n_frames > 1 else np.zeros(1)


# ---------------------------------------------------------------------------------------------
# Assembly

def random_streams(seed):
    """Independent generators for points, camera, translation and noise."""
    return [np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(4)]


def observe(name, S_world, R, *, noise=0.0, translation=0.0, rng_translation, rng_noise,
            meta=None):
    """Project a world-frame sequence into a :class:`Sequence`.

    ``S_world: (3F, P)``, ``R: (F, 3, 3)``. ``translation`` is the peak per-frame image
    translation as a fraction of the shape's extent (max |centred W|); ``noise`` is the
    paper's r: Gaussian noise of sigma = r * max|W| on ``W`` only, with max|W| taken over the
    clean centred tracks (so translation does not change the noise level).
    """
    S = to_camera(R, S_world)
    F = R.shape[0]
    clean = from_frames(as_frames(S, 3)[:, :2, :])
    extent = float(np.abs(centre(clean)[0]).max())
    t = frame_times(F)
    shift = np.stack([_smooth_random(rng_translation, t, translation * extent)
                      for _ in range(2)], axis=1).reshape(2 * F, 1)
    sigma = float(noise) * extent
    W = clean + shift
    if sigma > 0.0:
        W = W + rng_noise.normal(0.0, sigma, W.shape)
    meta = {'family': 'synthetic', 'noise': float(noise), 'noise_sigma': sigma,
            'translation': float(translation), **(meta or {})}
    return Sequence(name=name, W=W, S=S, R=R, S_world=S_world, noise_sigma=sigma, meta=meta,
                    translation=shift)


#: make_sequence(clustered=...): lower-left corners and side of the two dense patches (uv)
_CLUSTER_CORNERS = ((0.2, 0.2), (0.7, 0.7))
_CLUSTER_SIDE = 0.1


def make_sequence(kind, n_frames=60, n_points=2000, *, noise=0.0, camera='orbit', seed=0,
                  translation=0.0, clustered=0.0):
    """A synthetic deforming dense sequence with ground truth.

    ``kind`` one of :func:`all_kinds`, ``camera`` one of :func:`camera_motions`. Points are
    drawn uniformly in the surface's parameters, except a share ``clustered`` of them, which
    lie in two patches of 1 % of the parameter area each (a tracker's textured spots; the
    others stay as they would be without). ``noise`` is the paper's r (sigma = r max|W|),
    ``translation`` the peak per-frame translation as a fraction of max|centred W|.
    Returns a :class:`Sequence` with ``W: (2F, P)``, ``S: (3F, P)``, ``R: (F, 3, 3)``.
    """
    if kind not in _KINDS:
        raise ValueError(f'unknown kind {kind!r}; choose from {all_kinds()}')
    if n_frames < 1 or n_points < 1:
        raise ValueError(f'need n_frames >= 1 and n_points >= 1; got {n_frames}, {n_points}')
    if not 0.0 <= clustered <= 1.0:
        raise ValueError(f'clustered must be a share in [0, 1]; got {clustered!r}')
    rng_points, rng_camera, rng_translation, rng_noise = random_streams(seed)
    uv = rng_points.random((n_points, 2))
    n = int(round(clustered * n_points))
    for corner, patch in zip(_CLUSTER_CORNERS, (slice(0, n // 2), slice(n // 2, n))):
        uv[patch] = corner + _CLUSTER_SIDE * uv[patch]
    S_world = from_frames(_KINDS[kind](uv, frame_times(n_frames)))
    R = camera_rotations(camera, n_frames, rng_camera)
    meta = {'generator': __name__, 'kind': kind, 'camera_motion': camera, 'seed': seed,
            'clustered': float(clustered)}
    return observe(f'{kind}_{camera}', S_world, R, noise=noise, translation=translation,
                   rng_translation=rng_translation, rng_noise=rng_noise, meta=meta)


def default_sequence():
    """The quick start's embedded default: 'bending', 60 frames, 3,000 points, orbiting
    camera, no noise."""
    return make_sequence('bending', n_frames=60, n_points=3000, camera='orbit', seed=0)


# ---------------------------------------------------------------------------------------------
# What trackers deliver: occlusions and drift

#: occlusion_mask: a block hides a neighbourhood of between 2 % and 10 % of the tracks (in the
#: first frame's image) for between a tenth and half of the frames
_BLOCK_TRACKS = (0.02, 0.10)
_BLOCK_FRAMES = (0.1, 0.5)


def occlusion_mask(W, fraction, rng):
    """``visible: (F, P)`` bool with about ``fraction`` (at most 0.4) of the entries of ``W:
    (2F, P)`` hidden in occlusion-like blocks: a neighbourhood of tracks (the nearest, in the
    first frame's image, to a random track not yet hidden) hidden over a contiguous run of
    frames, as by an occluder passing once; each track is hidden by at most one block."""
    if not 0.0 <= fraction <= 0.4:
        raise ValueError(f'fraction must be in [0, 0.4]; got {fraction!r}')
    F, P = W.shape[0] // 2, W.shape[1]
    uv = W[:2].T
    visible = np.ones((F, P), dtype=bool)
    free = np.ones(P, dtype=bool)
    while 1.0 - visible.mean() < fraction and free.any():
        k = max(1, int(P * rng.uniform(*_BLOCK_TRACKS)))
        centre_track = rng.choice(np.flatnonzero(free))
        dist = np.where(free, ((uv - uv[centre_track]) ** 2).sum(axis=1), np.inf)
        near = np.argsort(dist)[:min(k, int(free.sum()))]
        length = max(1, int(F * rng.uniform(*_BLOCK_FRAMES)))
        start = rng.integers(0, F - length + 1)
        visible[start:start + length, near] = False
        free[near] = False
    return visible


def image_pixel(W):
    """The length of one pixel in the units of ``W: (2F, P)``: the sequence's largest centred
    coordinate max|W - row means| taken as 200 px (an object filling a 640 x 480 image)."""
    return float(np.abs(centre(W)[0]).max()) / 200.0


def drifting_tracks(W, share, max_px, rng):
    """``(W_drift: (2F, P), drifting: (P,) bool)``: a ``share`` of the tracks of ``W`` given
    a slowly growing offset, as a tracker's drift: from a random frame in the first half it
    grows linearly along a fixed random direction to between half of and ``max_px`` pixels
    (:func:`image_pixel`) at the last frame."""
    F, P = W.shape[0] // 2, W.shape[1]
    drifting = np.zeros(P, dtype=bool)
    drifting[rng.choice(P, max(1, int(round(share * P))), replace=False)] = True
    n = int(drifting.sum())
    start = rng.integers(0, max(1, F // 2), n)
    ramp = np.clip((np.arange(F)[:, None] - start) / np.maximum(F - 1 - start, 1), 0.0, 1.0)
    angle = rng.uniform(0.0, 2 * np.pi, n)
    size = rng.uniform(0.5, 1.0, n) * max_px * image_pixel(W)
    offset = ramp[:, None, :] * (size * np.stack([np.cos(angle), np.sin(angle)]))[None]
    out = W.copy()
    out.reshape(F, 2, P)[:, :, drifting] += offset
    return out, drifting
