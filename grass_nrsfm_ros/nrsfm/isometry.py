"""A sheet prior: depths of a surface that bends without stretching, from local isometry.

A sheet (paper, cloth, a mat) keeps the length ``L`` of every short edge between neighbouring
tracks. Seen orthographically (or on the weak-perspective image that :mod:`.perspective`
builds), an edge of image offset ``d: (2,)`` has ``|dz| = sqrt(L^2 - |d|^2)``; to first order
``dz = g . d`` with ``g`` the depth gradient at the point. From a point's ``k >= 3``
neighbours, ``d^T (g g^T) d = L^2 - |d|^2`` is linear in the symmetric ``G = g g^T``, so each
point's gradient is known up to its sign (:func:`local_gradients`, least squares, vectorised
over frames and points). The signs are synchronised over the neighbour graph frame by frame
(:func:`synchronised_signs`: on a smooth sheet neighbouring gradients agree; the leading
eigenvector of the signed affinity ``g_p . g_q``), each frame's remaining mirror sign is taken
from the solver's depths, and the depths are integrated over the edges in least squares
(:func:`integrate_depths`), weakly anchored to the solver's. ``x, y`` stay the solver's.

``L`` is the larger of a high quantile of the edge's image lengths over the frames and the
solver's median 3D length (as :mod:`.inextensible`, whose neighbour graph it shares).

:class:`SheetNRSfM` wraps a solver (``fit(W) -> result`` with ``S: (3F, P)``) and refines its
depths; :func:`refine_sheet` does it for given shapes.

Shapes: ``W: (2F, P)``, ``S: (3F, P)`` camera frame; neighbours ``(P, k)`` indices.
"""
from dataclasses import replace

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import eigsh, splu
from sklearn.base import BaseEstimator
from sklearn.neighbors import NearestNeighbors

from .inextensible import LENGTH_QUANTILE, trajectory_embedding
from .measurement import as_frames, from_frames

#: neighbours per point for the local gradients and the edge graph
NEIGHBOURS = 8
#: weight tying each frame's depths to the solver's (relative to unit edge weights)
ANCHOR = 1e-3


def neighbours(W, k=NEIGHBOURS):
    """``(P, k)`` indices of each track's ``k`` nearest tracks (trajectory embedding, as
    :func:`.inextensible.neighbour_edges`), itself excluded."""
    X = trajectory_embedding(W)
    k = min(k, X.shape[0] - 1)
    _, idx = NearestNeighbors(n_neighbors=k + 1).fit(X).kneighbors(X)
    return idx[:, 1:]


def edge_lengths(X, nbr, quantile=LENGTH_QUANTILE):
    """``(P, k)``: the sheet length of each edge ``(p, nbr[p, j])`` of the shapes ``X: (F, 3,
    P)``: the larger of its image lengths' ``quantile`` and its median 3D length."""
    d2 = X[:, :2, nbr] - X[:, :2, None, :].transpose(0, 1, 3, 2)       # (F, 2, P, k)
    image = np.quantile(np.linalg.norm(d2, axis=1), quantile, axis=0)
    d3 = X[:, :, nbr] - X[:, :, :, None]
    return np.maximum(image, np.median(np.linalg.norm(d3, axis=1), axis=0))


def _offsets(X, nbr):
    """``(F, P, k, 2)`` image offsets of each point's neighbours in ``X: (F, 3, P)``."""
    xy = X[:, :2, :].transpose(0, 2, 1)                                # (F, P, 2)
    return xy[:, nbr, :] - xy[:, :, None, :]


def local_gradients(X, nbr, lengths):
    """``(F, P, 2)`` depth gradients of ``X: (F, 3, P)``, each up to its sign, and ``(F, P)``
    confidences (the rank-one share of the fitted ``G``)."""
    d = _offsets(X, nbr)                                               # (F, P, k, 2)
    target = np.maximum(lengths[None] ** 2 - (d ** 2).sum(-1), 0.0)    # (F, P, k)
    A = np.stack([d[..., 0] ** 2, 2 * d[..., 0] * d[..., 1], d[..., 1] ** 2], axis=-1)
    normal = np.einsum('fpki,fpkj->fpij', A, A)
    normal += 1e-12 * np.trace(normal, axis1=2, axis2=3)[..., None, None] * np.eye(3)
    a, b, c = np.moveaxis(np.linalg.solve(normal, np.einsum('fpki,fpk->fpi', A, target)
                                          [..., None])[..., 0], -1, 0)
    G = np.stack([np.stack([a, b], -1), np.stack([b, c], -1)], -2)     # (F, P, 2, 2)
    values, vectors = np.linalg.eigh(G)
    top = np.maximum(values[..., 1], 0.0)
    g = vectors[..., :, 1] * np.sqrt(top)[..., None]
    confidence = (top - np.abs(values[..., 0])) / np.maximum(top, 1e-300)
    return g, np.clip(confidence, 0.0, 1.0)


def synchronised_signs(g, nbr, confidence):
    """``(F, P)`` of +-1 making the gradients ``g: (F, P, 2)`` agree over the neighbour graph
    ``nbr: (P, k)``: per frame the leading eigenvector of the symmetric affinity ``c_p c_q
    g_p . g_q``."""
    F, P, _ = g.shape
    rows = np.repeat(np.arange(P), nbr.shape[1])
    cols = nbr.ravel()
    signs = np.ones((F, P))
    for f in range(F):
        w = (g[f, rows] * g[f, cols]).sum(-1) * confidence[f, rows] * confidence[f, cols]
        A = sp.csr_matrix((w, (rows, cols)), shape=(P, P))
        A = A + A.T
        _, v = eigsh(A, k=1, which='LA', v0=np.ones(P))
        signs[f] = np.where(v[:, 0] >= 0, 1.0, -1.0)
    return signs


def solver_signs(g, X, nbr):
    """``(F, P)`` of +-1: per point, the sign that makes ``g: (F, P, 2)`` agree with the least-
    squares depth gradient of ``X: (F, 3, P)``'s own depths over the neighbours."""
    d = _offsets(X, nbr)
    dz = X[:, 2, nbr] - X[:, 2, :, None]
    normal = np.einsum('fpki,fpkj->fpij', d, d) + 1e-12 * np.eye(2)
    own = np.linalg.solve(normal, np.einsum('fpki,fpk->fpi', d, dz)[..., None])[..., 0]
    return np.where((own * g).sum(-1) >= 0, 1.0, -1.0)


class DepthIntegrator:
    """Depths from signed edge sizes, the edge system of ``X: (F, 3, P)``, ``nbr: (P, k)``
    and ``lengths`` factorised once: calling it with gradients ``g: (F', P, 2)`` and
    ``z_anchor: (F', P)`` of the ``frames`` (all by default) gives the ``(F', P)`` centred
    depths whose edge differences are ``sign(g . d) sqrt(L^2 - |d|^2)`` (the sign from the
    mean gradient of the edge's ends) in least squares, plus ``anchor`` times the distance to
    ``z_anchor``."""

    def __init__(self, X, nbr, lengths, anchor=ANCHOR):
        F, _, P = X.shape
        self.i = np.repeat(np.arange(P), nbr.shape[1])
        self.j = nbr.ravel()
        E = self.i.size
        rows = np.arange(E)
        self.incidence = sp.csr_matrix((np.r_[-np.ones(E), np.ones(E)],
                                        (np.r_[rows, rows], np.r_[self.i, self.j])),
                                       shape=(E, P))
        self.solve = splu((self.incidence.T @ self.incidence + anchor * sp.eye(P))
                          .tocsc()).solve
        self.anchor = anchor
        self.d = _offsets(X, nbr).reshape(F, E, 2)                       # (F, E, 2)
        self.size = np.sqrt(np.maximum(lengths.ravel()[None] ** 2 - (self.d ** 2).sum(-1),
                                       0.0))

    def __call__(self, g, z_anchor, frames=slice(None)):
        mean_g = 0.5 * (g[:, self.i] + g[:, self.j])
        return self.from_signs(np.where((mean_g * self.d[frames]).sum(-1) >= 0, 1.0, -1.0),
                               z_anchor, frames)

    def from_signs(self, edge_signs, z_anchor, frames=slice(None)):
        """``(F', P)`` centred depths whose edge differences are ``edge_signs: (F', E)``
        times the edge sizes in least squares, plus ``anchor`` times the distance to
        ``z_anchor: (F', P)``."""
        target = self.size[frames] * edge_signs
        z = self.solve(self.anchor * z_anchor.T + self.incidence.T @ target.T).T
        return z - z.mean(axis=1, keepdims=True)

    def edge_signs(self, z):
        """``(F', E)`` of +-1: the signs of the edge differences of the depths ``z: (F',
        P)``."""
        return np.where(z[:, self.j] - z[:, self.i] >= 0, 1.0, -1.0)

    def residual(self, z, frames=slice(None)):
        """``(F',)``: per frame, the summed squared misfit of the depths ``z: (F', P)``'s edge
        differences to the edge sizes (up to their signs): the isometry residual."""
        return ((np.abs(z[:, self.j] - z[:, self.i]) - self.size[frames]) ** 2).sum(axis=1)


def integrate_depths(X, nbr, lengths, g, z_anchor, anchor=ANCHOR):
    """``(F, P)`` centred depths of every frame (:class:`DepthIntegrator`)."""
    return DepthIntegrator(X, nbr, lengths, anchor)(g, z_anchor)


def refine_sheet(S, W, *, k=NEIGHBOURS, quantile=LENGTH_QUANTILE, anchor=ANCHOR,
                 signs='solver'):
    """``S: (3F, P)`` camera frame with each frame's depths replaced by the local-isometry
    ones (module docstring); ``W: (2F, P)`` the tracks (for the neighbour graph). Each frame's
    mirror sign agrees with ``S``'s depths, its mean depth is kept. Returns ``(S_refined,
    info)``."""
    X = as_frames(np.asarray(S, dtype=np.float64), 3)
    nbr = neighbours(W, k)
    lengths = edge_lengths(X, nbr, quantile)
    g, confidence = local_gradients(X, nbr, lengths)
    if signs == 'solver':
        g = g * solver_signs(g, X, nbr)[..., None]
    else:
        g = g * synchronised_signs(g, nbr, confidence)[..., None]
    mean_depth = X[:, 2, :].mean(axis=1, keepdims=True)
    z0 = X[:, 2, :] - mean_depth
    z = integrate_depths(X, nbr, lengths, g, np.zeros_like(z0), anchor)
    mirror = np.where(np.einsum('fp,fp->f', z, z0) >= 0, 1.0, -1.0)
    g = g * mirror[:, None, None]
    z = integrate_depths(X, nbr, lengths, g, z0, anchor)
    out = X.copy()
    out[:, 2, :] = z + mean_depth
    info = {'mirrored_frames': int((mirror < 0).sum()),
            'confidence': float(confidence.mean())}
    return from_frames(out), info


class SheetNRSfM(BaseEstimator):
    """``solver`` (default :class:`.solver.GrassmannNRSfM()`) followed by :func:`refine_sheet`:
    ``fit(W: (2F, P)) -> result`` with the refined ``S`` (the solver's result otherwise).

    ``alternations`` > 0 puts the prior inside the estimation: that many times, the rotations
    are registered to the sheet depths (:func:`.inextensible.register_rotations`) and the
    solver runs again from them and from the sheet shapes (a resumed warm start: a cold
    solve's schedule and stages), whose result is refined again. ``solver.fit`` must then
    take ``init`` (a :class:`.problem.WarmStart`)."""

    def __init__(self, solver=None, neighbours=NEIGHBOURS, quantile=LENGTH_QUANTILE,
                 anchor=ANCHOR, signs='solver', alternations=0):
        self.solver = solver
        self.signs = signs
        self.neighbours = neighbours
        self.quantile = quantile
        self.anchor = anchor
        self.alternations = alternations

    def _refined(self, S, W):
        return refine_sheet(S, W, k=self.neighbours, quantile=self.quantile,
                            anchor=self.anchor, signs=self.signs)

    def fit(self, W):
        from .inextensible import register_rotations
        from .problem import WarmStart
        if self.solver is None:
            from .solver import GrassmannNRSfM
            solver = GrassmannNRSfM()
        else:
            solver = self.solver
        result = solver.fit(W)
        S, info = self._refined(result.S, W)
        for _ in range(self.alternations):
            R = register_rotations(S, result.R)
            result = solver.fit(W, init=WarmStart(R=R, S=S, resumed=True))
            S, info = self._refined(result.S, W)
        result = replace(result, S=S)
        result.report.notes.append(f'sheet prior: {info}')
        return result
