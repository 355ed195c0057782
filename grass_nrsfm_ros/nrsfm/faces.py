"""Dense deforming faces like Garg et al.'s synthetic faces, built from the Surrey face model.

The Surrey Face Model (P. Huber et al., VISAPP 2016; shape-only, 3,448 vertices, 6 expression
blendshapes) is free for non-commercial use only, so it is never part of this package: it is
read at run time from a path (see :func:`load_face_model`).

:func:`make_face_sequence` draws an identity ``mean + basis[:, :k] (a * sqrt(eigenvalues[:k]))``
with ``a ~ N(0, 1)``, blends the expressions in and out with smooth weights ``w_e(t)`` in about
[0, 1.5], samples ``n_points`` points on the mesh (area-weighted triangles, uniform barycentric
coordinates; fixed over time, so every point is a track), turns the head and projects
orthographically. Units are millimetres.
"""
from dataclasses import dataclass
import os
from pathlib import Path

import numpy as np

from .synthetic import camera_rotations, frame_times, observe, random_streams

ENV_MODEL = 'GRASS_NRSFM_FACE_MODEL'
ENV_DATA = 'GRASS_NRSFM_DATA'
MODEL_RELPATH = Path('sfm_face') / 'sfm_face.npz'


@dataclass(frozen=True, eq=False)
class FaceModel:
    """The linear face model. V vertices, T triangles, K identity components, E expressions.

    ``mean: (V, 3)`` mm, ``basis: (3V, K)`` vertex-major orthonormal identity basis,
    ``eigenvalues: (K,)`` variances, ``triangles: (T, 3)`` int, ``expressions: (E, V, 3)``
    additive offsets, ``expression_names: (E,)`` str.
    """

    mean: np.ndarray
    basis: np.ndarray
    eigenvalues: np.ndarray
    triangles: np.ndarray
    expressions: np.ndarray
    expression_names: tuple
    path: Path = None

    def identity(self, coefficients):
        """Vertices ``(V, 3)`` of the identity ``mean + basis[:, :k] (a * sqrt(eig[:k]))`` for
        ``coefficients a: (k,)`` in standard deviations."""
        a = np.asarray(coefficients, dtype=np.float64)
        k = a.shape[0]
        offset = self.basis[:, :k] @ (a * np.sqrt(self.eigenvalues[:k]))
        return self.mean + offset.reshape(-1, 3)


def model_candidates():
    """Where :func:`load_face_model` looks, in order, when no path is given."""
    candidates = []
    if os.environ.get(ENV_MODEL):
        candidates.append(Path(os.environ[ENV_MODEL]))
    if os.environ.get(ENV_DATA):
        candidates.append(Path(os.environ[ENV_DATA]) / MODEL_RELPATH)
    checkout = Path(__file__).resolve().parents[2]
    candidates.append(checkout.parent / 'shared' / 'data' / MODEL_RELPATH)
    return candidates


def load_face_model(path=None):
    """Load the Surrey face model ``sfm_face.npz`` as a :class:`FaceModel` (float64).

    ``path`` or, if None, the first existing of ``$GRASS_NRSFM_FACE_MODEL``,
    ``$GRASS_NRSFM_DATA/sfm_face/sfm_face.npz`` and ``../shared/data/sfm_face/sfm_face.npz``
    beside the checkout. Raises FileNotFoundError naming the places tried.
    """
    tried = [Path(path)] if path is not None else model_candidates()
    found = next((p for p in tried if p.is_file()), None)
    if found is None:
        places = ', '.join(str(p) for p in tried)
        raise FileNotFoundError(
            f'Surrey face model not found (tried: {places}). The model is free for '
            f'non-commercial use only and is not shipped with grass_nrsfm_ros: pass its path, '
            f'or set {ENV_MODEL} to sfm_face.npz or {ENV_DATA} to the data folder holding '
            f'{MODEL_RELPATH}.')
    with np.load(found) as npz:
        return FaceModel(
            mean=npz['mean'].astype(np.float64),
            basis=npz['pca_basis'].astype(np.float64),
            eigenvalues=npz['pca_eigenvalues'].astype(np.float64),
            triangles=npz['triangles'].astype(np.int64),
            expressions=npz['expressions'].astype(np.float64),
            expression_names=tuple(str(n) for n in npz['expression_names']),
            path=found)


def sample_surface(vertices, triangles, n_points, rng):
    """Area-weighted uniform samples on a mesh: ``(tri: (P,), bary: (P, 3))``.

    ``vertices: (V, 3)``, ``triangles: (T, 3)``. Triangles are drawn with probability
    proportional to their area in ``vertices``, barycentric coordinates uniformly on each.
    """
    corners = vertices[triangles]                              # (T, 3, 3)
    area = 0.5 * np.linalg.norm(
        np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    tri = rng.choice(len(triangles), size=n_points, p=area / area.sum())
    r1, r2 = rng.random((2, n_points))
    root = np.sqrt(r1)
    bary = np.stack([1.0 - root, root * (1.0 - r2), root * r2], axis=1)
    return tri, bary


def interpolate(values, triangles, tri, bary):
    """Values at barycentric samples: ``values: (..., V, 3)`` -> ``(..., P, 3)``."""
    corner = values[..., triangles[tri], :]                    # (..., P, 3 corners, 3)
    return np.einsum('...pcd,pc->...pd', corner, bary)


def expression_weights(n_expressions, n_frames, rng, peak=1.5):
    """Smooth expression weights ``(F, E)`` in [0, peak): each expression rises and falls in
    two Gaussian bumps with random centres, widths and heights, so several blend at once; the
    sum saturates smoothly as ``peak * tanh(sum / peak)``."""
    t = frame_times(n_frames)[:, None, None]                   # (F, 1, 1)
    n_bumps = 2
    centres = rng.uniform(-0.1, 1.1, (1, n_expressions, n_bumps))
    widths = rng.uniform(0.08, 0.25, (1, n_expressions, n_bumps))
    heights = rng.uniform(0.4, 1.2, (1, n_expressions, n_bumps)) * peak
    bumps = heights * np.exp(-0.5 * ((t - centres) / widths) ** 2)
    return peak * np.tanh(bumps.sum(axis=2) / peak)


def make_face_sequence(n_frames=99, n_points=28880, *, model=None, noise=0.0, seed=0,
                       identity_components=10, head_motion='orbit', translation=0.0):
    """A dense deforming face (mm) seen by an orthographic camera, with ground truth.

    ``model`` a :class:`FaceModel`, a path, or None (see :func:`load_face_model`).
    ``head_motion`` one of :func:`.synthetic.camera_motions` ('orbit': yaw +-35, pitch +-20,
    roll +-10 degrees). ``noise`` is the paper's r (sigma = r max|W|). The world shape of each
    frame is centred on the identity's sample centroid. Returns a :class:`.synthetic.Sequence`
    with ``W: (2F, P)``, ``S: (3F, P)``, ``R: (F, 3, 3)``; ``meta`` holds the expression
    weights.
    """
    if not isinstance(model, FaceModel):
        model = load_face_model(model)
    rng_points, rng_camera, rng_translation, rng_noise = random_streams(seed)
    rng_identity, rng_expression = (np.random.default_rng(s) for s in
                                    np.random.SeedSequence([seed, 1]).spawn(2))
    k = int(identity_components)
    identity = model.identity(rng_identity.standard_normal(k))
    tri, bary = sample_surface(identity, model.triangles, n_points, rng_points)
    base = interpolate(identity, model.triangles, tri, bary)              # (P, 3)
    offsets = interpolate(model.expressions, model.triangles, tri, bary)   # (E, P, 3)
    weights = expression_weights(len(model.expressions), n_frames, rng_expression)  # (F, E)
    points = (base - base.mean(axis=0)).T                                  # (3, P)
    deltas = offsets.transpose(0, 2, 1).reshape(len(offsets), -1)          # (E, 3P)
    S_world = (weights @ deltas + points.reshape(1, -1)).reshape(-1, n_points)  # (3F, P)
    R = camera_rotations(head_motion, n_frames, rng_camera)
    meta = {'generator': __name__, 'kind': 'face', 'camera_motion': head_motion, 'seed': seed,
            'identity_components': k, 'units': 'mm',
            'expression_names': list(model.expression_names),
            'expression_weights': weights.round(6).tolist()}
    return observe(f'face_{head_motion}', S_world, R, noise=noise, translation=translation,
                   rng_translation=rng_translation, rng_noise=rng_noise, meta=meta)
