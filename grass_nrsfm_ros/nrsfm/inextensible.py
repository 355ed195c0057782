"""Inextensible depth refinement (not in the paper; ``GrassmannNRSfM(inextensible=...)``).

A surface that bends without stretching (paper, cloth, a hinged panel) keeps the length
``l_e`` of every short edge ``e = (i, j)`` between neighbouring points. An orthographic camera
shows the edge foreshortened, ``|dxy_e^f| = l_e cos(theta_e^f)``, so a high quantile of the
image lengths over the sequence bounds ``l_e`` (where the edge never faces the camera, the
solver's own 3D length, the larger, is taken). Each frame's depth differences then follow from
the data, ``|z_i - z_j| = sqrt(l_e^2 - |dxy_e^f|^2)``; their signs come from the solver's
depths, then from the refined ones (a few sweeps). Each frame's depths are the least-squares
integration of these differences over the neighbour graph (one sparse ``P x P`` Laplacian
factor for all frames), weakly anchored to the solver's depths; ``x, y`` stay the data's.

Given the rotations, the signs are re-estimated against the other frames (``sign_rounds``):
the refined world shapes are projected onto their mean plus their top SIGN_RANK components,
and each frame is integrated again with the signs of that projection's depths.

:func:`length_variation` (temporal std over mean of the 3D edge lengths) measures how far a
reconstruction is from inextensible; the solver's refinement stage compares it before and
after (:mod:`.stages.refinement`). :func:`register_rotations` re-estimates rotations from
refined shapes (:mod:`.stages.registration`).

Shapes: ``S: (3F, P)`` camera frame, ``W: (2F, P)``, ``R: (F, 3, 3)``; edges ``i, j: (E,)``.
Memory stays O(F P + F E) in frame / edge chunks; nothing is P x P but the sparse Laplacian.
"""
import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu
from sklearn.neighbors import NearestNeighbors

from .measurement import as_frames, from_frames, nearest_rotation, validate_rotations
from .rotation import normalised_svd

#: neighbours per point in the edge graph
NEIGHBOURS = 8
#: tracks closer than this fraction of the median neighbour distance count as one (no edge).
#: On ../shared/data the closest pair is >= 0.11 of the median; at 0.005 the edge graphs of
#: 43 synthetic and face sequences (500-3,000 random tracks) are unchanged, while 0.02 changed
#: 1-9 edges of random samples' closest pairs and moved twisting 60 x 3,000 from 0.0655 to 0.0681
COINCIDENT = 0.005
#: extra neighbours queried so that coincident ones can be skipped
COINCIDENT_SLACK = 4
#: dimensions of the trajectory embedding the neighbours are found in
EMBED_DIMS = 8
#: the edge length is this quantile of its image lengths over the frames
LENGTH_QUANTILE = 0.95
#: depth re-integrations with the signs of the previous one
SIGN_SWEEPS = 3
#: rounds of signs from the low-rank world shapes (when the rotations are given)
SIGN_ROUNDS = 3
#: components (beyond the mean) of the world S# projection the signs come from
SIGN_RANK = 2
#: register_rotations: alternations (a fixed number: the low-rank model absorbs part of any
#: rotation, so the alternation creeps on, 1e-3-1e-2 per step in the rotation entries after
#: 20 steps on 60 x 500 sheets, not a common rotation of the world frame)
REGISTRATION_ITERATIONS = 20
#: weight tying each frame's depths to the solver's (relative to the unit edge weights)
ANCHOR = 1e-3
#: entries per (frames x edges) chunk: 120 frames x 30,000 tracks (the node under load) peak
#: at 266 MB in refine_depth with 2^20 (2^22: 582 MB, and slower: 9.8 vs 7.1 s CPU)
CHUNK = 1 << 20


def trajectory_embedding(W, dims=EMBED_DIMS):
    """``(P, n)``: the tracks of ``W: (2F, P)`` as points in the space of their leading ``n =
    min(dims, rank)`` principal components (the rotation step's SVD of the centred, unit-RMS
    tracks); nearby points are nearby on the surface."""
    _, d, Vt, _, _ = normalised_svd(W)
    n = min(dims, d.size)
    return (d[:n, None] * Vt[:n]).T


def neighbour_edges(W, k=NEIGHBOURS):
    """Edges ``(i, j): (E,)`` (``i < j``, unique) joining each track of ``W: (2F, P)`` to its
    ``k`` nearest in a ``EMBED_DIMS``-dimensional embedding of the trajectories (their leading
    principal components, from the rotation step's SVD of the centred tracks).

    Coincident tracks (closer than ``COINCIDENT`` of the median neighbour distance: duplicated
    or near-duplicated tracks) are not joined: such an edge has no measurable length, and its
    relative length variation (pure noise over almost nothing) would swamp the 'auto'
    decision's mean. Each track is joined to its ``k`` nearest non-coincident tracks instead.
    """
    X = trajectory_embedding(W)
    P = X.shape[0]
    m = min(k + 1 + COINCIDENT_SLACK, P)
    dist, idx = NearestNeighbors(n_neighbors=m).fit(X).kneighbors(X)
    apart = dist > COINCIDENT * np.median(dist[:, 1:])      # False for self and duplicates
    first = np.argsort(~apart, axis=1, kind='stable')[:, :min(k, m - 1)]   # k nearest apart
    rows = np.arange(P)[:, None]
    chosen = apart[rows, first]
    pairs = np.stack([np.broadcast_to(rows, first.shape)[chosen], idx[rows, first][chosen]],
                     axis=1)
    pairs = np.unique(np.sort(pairs, axis=1), axis=0)
    return pairs[:, 0], pairs[:, 1]


def _chunks(n, size):
    """Slices over ``range(n)`` of at most ``CHUNK // size`` items each, so that an array of
    ``size`` entries per item stays within CHUNK entries per slice."""
    step = max(1, CHUNK // max(size, 1))
    return [slice(a, min(a + step, n)) for a in range(0, n, step)]


def _image_lengths(S, i, j, frames):
    """``|dxy|: (F', E)`` of the frames ``frames`` of ``S: (F, 3, P)``."""
    return np.hypot(S[frames, 0, i] - S[frames, 0, j], S[frames, 1, i] - S[frames, 1, j])


def _image_length_quantile(X, i, j, quantile):
    """``(E,)``: the ``quantile`` of each edge's image lengths over the frames of ``X: (F, 3,
    P)``."""
    out = np.empty(i.size)
    for e in _chunks(i.size, X.shape[0]):
        out[e] = np.quantile(_image_lengths(X, i[e], j[e], slice(None)), quantile, axis=0)
    return out


def _length_stats(X, i, j):
    """Per edge, over the frames of ``X: (F, 3, P)``: the median of its 3D length and the
    temporal std over the mean of it, both ``(E,)``."""
    median, relative_std = np.empty(i.size), np.empty(i.size)
    for e in _chunks(i.size, X.shape[0]):
        L = np.linalg.norm(X[:, :, i[e]] - X[:, :, j[e]], axis=1)
        median[e] = np.median(L, axis=0)
        relative_std[e] = L.std(axis=0) / np.maximum(L.mean(axis=0), 1e-300)
    return median, relative_std


def length_variation(S, i, j):
    """Mean over edges of the temporal std / mean of the 3D edge lengths of ``S: (3F, P)``."""
    i, j = np.asarray(i, dtype=np.intp), np.asarray(j, dtype=np.intp)
    return float(_length_stats(as_frames(S, 3), i, j)[1].mean()) if i.size else 0.0


def _low_rank_world(X, R, rank):
    """Yield ``(points, Y: (F, 3, p))``: chunks of the world shapes of ``X: (F, 3, P)`` (through
    ``R: (F, 3, 3)``) after projecting their S# (``(F, 3P)``) onto its mean plus its top
    ``rank`` components. Two passes over point chunks (an ``F x F`` Gram, then the
    projection), so nothing ``(F, 3P)``-sized is held."""
    F, _, P = X.shape
    Rt = R.transpose(0, 2, 1)

    def centred_world(points):
        Y = Rt @ X[:, :, points]                              # (F, 3, p)
        mean = Y.mean(axis=0)
        return (Y - mean).reshape(F, -1), mean

    gram = np.zeros((F, F))
    for points in _chunks(P, 3 * F):
        Y, _ = centred_world(points)
        gram += Y @ Y.T
    basis = np.linalg.eigh(gram)[1][:, ::-1][:, :rank]       # (F, rank)
    for points in _chunks(P, 3 * F):
        Y, mean = centred_world(points)
        yield points, (basis @ (basis.T @ Y)).reshape(F, 3, -1) + mean


def low_rank_depths(X, R, rank=SIGN_RANK):
    """Camera-frame depths ``(F, P)`` of the shapes ``X: (F, 3, P)`` after projecting their
    world S# (through ``R: (F, 3, 3)``) onto its mean plus its top ``rank`` components."""
    z = np.empty((X.shape[0], X.shape[2]))
    for points, world in _low_rank_world(X, R, rank):
        z[:, points] = np.einsum('fk,fkp->fp', R[:, 2, :], world)
    return z


def register_rotations(S, R, *, rank=SIGN_RANK, iterations=REGISTRATION_ITERATIONS):
    """World-to-camera rotations ``(F, 3, 3)`` that register the camera-frame shapes
    ``S: (3F, P)`` (refined depths: full 3D per frame) to their own low-rank world model:
    alternately project the world S# (through the current rotations, starting from
    ``R: (F, 3, 3)``) onto its mean plus ``rank`` components, and take each frame's rotation
    as the proper orthogonal Procrustes fit of its centred shape to that model (generalised
    Procrustes analysis with a low-rank rather than a rigid mean), ``iterations`` times."""
    X = as_frames(np.asarray(S, dtype=np.float64), 3)
    X = X - X.mean(axis=2, keepdims=True)
    R = validate_rotations(R, X.shape[0]).copy()
    for _ in range(iterations):
        cross = np.zeros((X.shape[0], 3, 3))                  # sum_p x_fp y_fp^T
        for points, world in _low_rank_world(X, R, rank):
            cross += np.einsum('fip,fjp->fij', X[:, :, points], world)
        R = nearest_rotation(cross)
    return R


class DepthIntegration:
    """The inextensible depths of one ``S: (3F, P)`` camera frame over ``edges = (i, j)``
    (see the module docstring): set up once (each edge's length, the Laplacian's factor) and
    swept once per number of sweeps, so a check and the refinement it decides can share them.
    :meth:`refine` gives ``(S_refined: (3F, P), info)``."""

    def __init__(self, S, edges, *, quantile=LENGTH_QUANTILE, anchor=ANCHOR):
        self.i, self.j = (np.asarray(e, dtype=np.intp) for e in edges)
        self.X = as_frames(np.asarray(S, dtype=np.float64), 3)
        P = self.X.shape[2]
        self.mean_depth = self.X[:, 2, :].mean(axis=1, keepdims=True)
        self.z0 = self.X[:, 2, :] - self.mean_depth                  # (F, P)
        # inextensible length: the larger of the image-length quantile and the median of the
        # solver's 3D length (an edge that never faces the camera is longer than all its images)
        solid, self.relative_std = _length_stats(self.X, self.i, self.j)
        self.length = np.maximum(_image_length_quantile(self.X, self.i, self.j, quantile), solid)
        E = self.i.size
        self.anchor = anchor
        rows = np.arange(E)
        self.incidence = sp.csr_matrix((np.r_[np.ones(E), -np.ones(E)],
                                        (np.r_[rows, rows], np.r_[self.i, self.j])),
                                       shape=(E, P))
        self._solve = splu((self.incidence.T @ self.incidence
                            + anchor * sp.eye(P)).tocsc()).solve
        self._swept = {}

    def integrate(self, signs_from):
        """Depths ``(F, P)`` (zero mean per frame) with the edge signs of ``signs_from: (F,
        P)``."""
        X, i, j, length = self.X, self.i, self.j, self.length
        rhs = self.anchor * self.z0.T                             # (P, F)
        for frames in _chunks(X.shape[0], i.size):
            dl = _image_lengths(X, i, j, frames)
            target = np.sqrt(np.maximum(length ** 2 - dl ** 2, 0.0))
            target *= np.where(signs_from[frames][:, i] >= signs_from[frames][:, j], 1.0, -1.0)
            rhs[:, frames] += self.incidence.T @ target.T
        z = self._solve(rhs).T
        return z - z.mean(axis=1, keepdims=True)

    def swept(self, sweeps):
        """Depths ``(F, P)`` after ``sweeps`` + 1 integrations, each with the signs of the
        one before (the first with the solver's); computed once per ``sweeps``."""
        if sweeps not in self._swept:
            z = self.z0
            for _ in range(sweeps + 1):
                z = self.integrate(z)
            self._swept[sweeps] = z
        return self._swept[sweeps]

    def refine(self, R=None, *, sweeps=SIGN_SWEEPS, sign_rounds=SIGN_ROUNDS,
               sign_rank=SIGN_RANK):
        """``(S_refined: (3F, P), info)``: :func:`refine_depth` of this integration's shapes
        and edges."""
        X, i, j = self.X, self.i, self.j
        if R is not None:
            R = validate_rotations(R, X.shape[0])
        z = self.swept(sweeps)
        out = X.copy()
        for _ in range(sign_rounds if R is not None and i.size else 0):
            out[:, 2, :] = z
            z = self.integrate(self.integrate(low_rank_depths(out, R, sign_rank)))
        out[:, 2, :] = z + self.mean_depth
        refined = from_frames(out)
        info = {'edges': int(i.size),
                'length_variation_before': float(self.relative_std.mean()) if i.size else 0.0,
                'length_variation_after': length_variation(refined, i, j)}
        return refined, info


def refine_depth(S, edges, *, R=None, quantile=LENGTH_QUANTILE, sweeps=SIGN_SWEEPS,
                 sign_rounds=SIGN_ROUNDS, sign_rank=SIGN_RANK, anchor=ANCHOR, integration=None):
    """``S: (3F, P)`` camera frame with each frame's depths replaced by the inextensible ones
    over ``edges = (i, j)`` (see the module docstring); x, y and each frame's mean depth kept.
    With the rotations ``R: (F, 3, 3)`` the signs are then re-estimated ``sign_rounds`` times
    from the rank-``sign_rank`` world shapes. ``integration``: the :class:`DepthIntegration`
    of these ``S`` and ``edges`` when one exists (its set-up and sweeps are reused; ``quantile``
    and ``anchor`` are then its own). Returns ``(S_refined: (3F, P), info)``, info with the
    length variation before and after."""
    if integration is None:
        integration = DepthIntegration(S, edges, quantile=quantile, anchor=anchor)
    return integration.refine(R, sweeps=sweeps, sign_rounds=sign_rounds, sign_rank=sign_rank)
