"""Maximum-depth heuristic (MDH) for sheets seen through a pinhole (Chhatkuli et al., TPAMI 2018).

An inextensible surface keeps the geodesic distance ``d_e`` between neighbouring tracks
``e = (i, j)``; the straight 3D distance never exceeds it. Along the rays ``q = (x, y, 1)`` of
the normalised tracks, MDH maximises the sum of all depths subject to

    ``|| Z_i^f q_i^f - Z_j^f q_j^f || <= d_e``   for every frame ``f`` and edge ``e``,

``d_e >= 0`` shared by the frames and normalised (``sum_e d_e = 1``). Pushed as far as the
edges allow, a sheet is stretched taut between its rays, which fixes its depths up to the one
global scale. The second-order cones are solved as a linear programme (scipy's HiGHS) by
cutting planes: each cone ``||v|| <= d`` is replaced by tangent planes ``a . v <= d`` (``|a| =
1``), first along the edge's image direction, the optical axis and their diagonals, then, for
every cone the last solution violates by more than ``tol`` of its ``d``, along that solution's
``v``; repeated until none is (cuts that have gone slack are dropped between rounds; HiGHS's
interior-point method, 8 times faster than its simplex here).

The edges are the neighbour graph of :func:`.inextensible.neighbour_edges`.

Refinement (:func:`refined_depths`, record 0720): the maximum is not the truth where the
perspective is weak. The LP's lengths ``d`` are right (the synthetic flag seen from 5 sizes
away: the true lengths within 0.97-1.03 of them, p5-p95), but in the frames where the sheet
is bent and tilted, half of the edges are left slack (``||v|| < 0.98 d``): the surface is
flattened (depth relief 0.16 of the distance against the truth's 0.27). Each frame's depths
are then fitted to the lengths as equalities, ``min_Z sum_e (||Z_i q_i - Z_j q_j|| - d_e)^2``
(Levenberg-Marquardt, every frame at once), started from the LP's depths.

:class:`MaxDepthNRSfM` (``fit(W) -> MaxDepthResult`` with ``S``) solves the LP on at most
``max_tracks`` tracks spread over the sheet, none that its neighbours contradict
(:func:`anchor_tracks`), and gives the others the depth of the plane through their nearest
anchors in each frame (:func:`interpolated_depths`): the LP's cost grows faster than its size
(10 x 90: 6 s, 40 x 100: 50-75 s CPU). On sequences longer than ``key_frames``, the lengths
come from the LP on that many frames spread over it; every other frame, independent given
the lengths, takes the largest depths they allow (:func:`largest_depths`, no LP).

Orthographic tracks have parallel rays: the depths are then unbounded (any depth translation
is feasible), so MDH is for pinhole tracks only.

Shapes: ``W: (2F, P)`` normalised tracks (rows ``2f, 2f+1``: x, y), ``Z: (F, P)`` depths,
``S: (3F, P)`` camera frame, edges ``i, j: (E,)``.
"""
from dataclasses import dataclass, field
import time

import numpy as np
from scipy.optimize import linprog
import scipy.sparse as sp
from sklearn.base import BaseEstimator
from sklearn.neighbors import NearestNeighbors

from . import isometry
from .density import affine_weights
from .inextensible import neighbour_edges, trajectory_embedding
from .measurement import (as_frames, centre, frame_rows, from_frames, InvalidInputError,
                          spread_frames, track_scale, validate_tracks)

#: neighbours per track in the edge graph
NEIGHBOURS = 8
#: a cone counts as met when ||v|| <= (1 + TOL) d
TOL = 1e-2
#: a cut is dropped once its slack exceeds this fraction of its terms' size (inactive)
PRUNE = 0.05
#: cutting-plane rounds at most
MAX_CUTS = 30
#: tracks the LP solves (the rest interpolated)
MAX_TRACKS = 100
#: Levenberg-Marquardt iterations of the refinement at most, and its relative tolerance
REFINE_ITERATIONS = 100
REFINE_TOL = 1e-8
#: frames the lengths are solved on; a longer sequence's other frames take those lengths
KEY_FRAMES = 40
#: an anchor's trajectory is reproduced by its neighbours' within this many times the median
#: track's residual (record 0723)
CONSISTENT = 2.0
#: Tikhonov regularisation of those reconstruction weights, relative to the trace
CONSISTENCY_REGULARISATION = 1e-3


def _rays(W):
    """``(F, P, 3)`` rays ``(x, y, 1)`` of normalised tracks ``W: (2F, P)``."""
    xy = as_frames(W, 2).transpose(0, 2, 1)
    return np.concatenate([xy, np.ones(xy.shape[:2] + (1,))], axis=-1)


def _initial_directions(q, i, j):
    """``(F, E, m, 3)`` unit tangent directions of each cone: +- the edge's image direction
    (lateral), +- the optical axis, and their four diagonals."""
    u = q[:, i, :2] - q[:, j, :2]                                       # (F, E, 2)
    u /= np.maximum(np.linalg.norm(u, axis=-1, keepdims=True), 1e-300)
    lateral = np.concatenate([u, np.zeros(u.shape[:2] + (1,))], axis=-1)
    axis = np.broadcast_to([0.0, 0.0, 1.0], lateral.shape)
    dirs = [s * lateral + t * axis for s, t in
            ((1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1))]
    dirs = np.stack(dirs, axis=2)
    return dirs / np.linalg.norm(dirs, axis=-1, keepdims=True)


def _cut_rows(a, q, i, j, frames, edges, P, E):
    """Sparse rows ``a . (Z_i q_i - Z_j q_j) - d_e <= 0`` for cones ``(frames, edges)``
    (``(n,)`` each) with directions ``a: (n, 3)``; the variables are ``Z: (F P)`` then
    ``d: (E)``."""
    n = a.shape[0]
    ii, jj = i[edges], j[edges]
    ci = np.einsum('nk,nk->n', a, q[frames, ii])
    cj = -np.einsum('nk,nk->n', a, q[frames, jj])
    rows = np.repeat(np.arange(n), 3)
    cols = np.stack([frames * P + ii, frames * P + jj, q.shape[0] * P + edges], 1).ravel()
    vals = np.stack([ci, cj, -np.ones(n)], 1).ravel()
    return sp.csr_matrix((vals, (rows, cols)), shape=(n, q.shape[0] * P + E))


def max_depth(W, edges=None, *, k=NEIGHBOURS, tol=TOL, max_cuts=MAX_CUTS):
    """MDH depths of the normalised tracks ``W: (2F, P)`` over ``edges = (i, j)`` (default:
    :func:`.inextensible.neighbour_edges` with ``k``). Returns ``(Z: (F, P), d: (E,), info)``
    with ``sum(d) = 1``; info: edges, cutting rounds, cuts, the largest relative violation
    left and the LP's seconds. Given the lengths, see :func:`largest_depths`."""
    x = validate_tracks(W, min_frames=2, min_points=4)
    i, j = edges if edges is not None else neighbour_edges(x, k)
    i, j = np.asarray(i, dtype=np.intp), np.asarray(j, dtype=np.intp)
    q = _rays(x)
    FP = q.shape[0] * q.shape[1]
    A_eq = sp.csr_matrix(np.r_[np.zeros(FP), np.ones(i.size)][None])
    return cutting_planes(q, i, j, (0, None), A_eq, [1.0], tol, max_cuts)


def cutting_planes(q, i, j, bounds, A_eq, b_eq, tol=TOL, max_cuts=MAX_CUTS):
    """The cones of rays ``q: (F, P, 3)`` over edges ``i, j: (E,)`` by cutting planes (the
    module docstring): the LP maximising the summed depths over the variables ``Z: (F P)``
    then ``d: (E,)`` within ``bounds`` (linprog's) and ``A_eq x = b_eq`` (None: none).
    Returns ``(Z: (F, P), d: (E,), info)`` as :func:`max_depth`."""
    F, P, _ = q.shape
    E = i.size
    cost = np.r_[-np.ones(F * P), np.zeros(E)] / (F * P)
    dirs = _initial_directions(q, i, j)
    ff, ee = np.meshgrid(np.arange(F), np.arange(E), indexing='ij')
    m = dirs.shape[2]
    blocks = [_cut_rows(dirs.reshape(-1, 3), q, i, j, np.repeat(ff.ravel(), m),
                        np.repeat(ee.ravel(), m), P, E)]
    t0 = time.process_time()
    worst, rounds, cuts = np.inf, 0, blocks[0].shape[0]
    for rounds in range(1, max_cuts + 1):
        A = sp.vstack(blocks).tocsr()
        res = linprog(cost, A_ub=A, b_ub=np.zeros(A.shape[0]), A_eq=A_eq, b_eq=b_eq,
                      bounds=bounds, method='highs-ipm')
        if res.status != 0:
            raise RuntimeError(f'max_depth: the LP failed ({res.message})')
        Z = res.x[:F * P].reshape(F, P)
        d = res.x[F * P:]
        v = Z[:, i, None] * q[:, i] - Z[:, j, None] * q[:, j]          # (F, E, 3)
        norm = np.linalg.norm(v, axis=-1)
        excess = norm - (1 + tol) * d[None]
        worst = float((norm / np.maximum(d[None], 1e-300) - 1).max())
        bad_f, bad_e = np.nonzero(excess > 0)
        if bad_f.size == 0:
            break
        a = v[bad_f, bad_e] / norm[bad_f, bad_e, None]
        slack = -(A @ res.x)
        blocks = [A[slack <= PRUNE * np.abs(A).multiply(np.abs(res.x)[None]).sum(1).A1],
                  _cut_rows(a, q, i, j, bad_f, bad_e, P, E)]
        cuts += bad_f.size
    info = {'edges': int(E), 'rounds': rounds, 'cuts': int(cuts),
            'violation': worst, 'seconds_cpu': time.process_time() - t0}
    return Z, d, info


def largest_depths(W, edges, lengths, *, max_rounds=None):
    """``Z: (F, P)``: per frame of the normalised tracks ``W: (2F, P)``, the largest depths
    whose edges ``(i, j)`` are no longer than ``lengths: (E,)`` (the maximum depth with the
    lengths known, record 0731). Along unit rays at angle ``t`` the ranges ``r`` of an edge
    meet its cone iff each is at most ``r_other cos t + sqrt(d^2 - r_other^2 sin^2 t)``. Every
    range starts at its edges' least ``d / sin t`` and is lowered to that bound of each
    neighbour until none moves (Bellman-Ford's relaxation: at most ``P`` rounds, about the
    graph's diameter in practice); every cone then holds."""
    x = validate_tracks(W, min_frames=1, min_points=2)
    i, j = (np.asarray(e, dtype=np.intp) for e in edges)
    d = np.asarray(lengths, dtype=np.float64)
    q = _rays(x)
    norm = np.linalg.norm(q, axis=-1)                                       # (F, P)
    F, P = norm.shape
    cos = np.clip(np.einsum('fek,fek->fe', q[:, i], q[:, j]) / (norm[:, i] * norm[:, j]), -1, 1)
    src, dst = np.r_[i, j], np.r_[j, i]
    order = np.argsort(dst, kind='stable')
    src, dst = src[order], dst[order]
    cos, d2 = np.concatenate([cos, cos], 1)[:, order], np.r_[d, d][order] ** 2
    sin2 = 1 - cos ** 2
    starts = np.flatnonzero(np.r_[True, dst[1:] != dst[:-1]])
    nodes = dst[starts]
    r = np.full((F, P), np.inf)
    r[:, nodes] = np.sqrt(np.minimum.reduceat(d2 / np.maximum(sin2, 1e-300), starts, axis=1))
    for _ in range(P if max_rounds is None else max_rounds):
        r_src = r[:, src]
        bound = r_src * cos + np.sqrt(np.maximum(d2 - r_src ** 2 * sin2, 0.0))
        lowered = np.minimum(r[:, nodes], np.minimum.reduceat(bound, starts, axis=1))
        moved = (lowered < r[:, nodes] * (1 - 1e-12)).any()
        r[:, nodes] = lowered
        if not moved:
            break
    return r / norm


def refined_depths(W, Z, d, edges, *, max_iterations=REFINE_ITERATIONS, tol=REFINE_TOL):
    """``(F, P)`` depths of the normalised tracks ``W: (2F, P)``: per frame, the least-squares
    fit of the edge lengths ``d: (E,)`` as equalities over ``edges = (i, j)``, ``min_Z sum_e
    (||Z_i q_i - Z_j q_j|| - d_e)^2``, started from ``Z: (F, P)`` (the LP's or the largest
    depths).
    Levenberg-Marquardt on every frame at once (each frame's normal matrix ``(P, P)``, its
    damping per frame); a frame stops when its cost or its step changes by at most ``tol``
    relative, or after ``max_iterations``."""
    i, j = (np.asarray(e, dtype=np.intp) for e in edges)
    q = _rays(W)
    Z = np.array(Z, dtype=np.float64)
    F, P = Z.shape
    pairs = np.r_[i * P + i, j * P + j, i * P + j, j * P + i]
    diagonal = np.arange(P)
    damping = np.full(F, 1e-3)
    v, n = _edge_vectors(Z, q[:, i], q[:, j], i, j)
    cost = ((n - d) ** 2).sum(axis=1)
    active = np.arange(F)
    for _ in range(max_iterations):
        f, m = active, active.size
        qi, qj = q[f][:, i], q[f][:, j]
        r = n[f] - d
        u = v[f] / np.maximum(n[f], 1e-300)[..., None]
        a, b = np.einsum('fek,fek->fe', u, qi), -np.einsum('fek,fek->fe', u, qj)   # dr/dZ
        H = np.bincount((pairs + P * P * np.arange(m)[:, None]).ravel(),
                        np.concatenate([a * a, b * b, a * b, a * b], axis=1).ravel(),
                        minlength=m * P * P).reshape(m, P, P)
        g = np.bincount((np.r_[i, j] + P * np.arange(m)[:, None]).ravel(),
                        np.concatenate([a * r, b * r], axis=1).ravel(),
                        minlength=m * P).reshape(m, P)
        h = H[:, diagonal, diagonal]
        H[:, diagonal, diagonal] += damping[f, None] * np.maximum(
            h, 1e-12 * h.max(axis=1, keepdims=True) + 1e-300)      # never exactly singular
        step = np.linalg.solve(H, g[..., None])[..., 0]
        Z_new = Z[f] - step
        v_new, n_new = _edge_vectors(Z_new, qi, qj, i, j)
        c_new = ((n_new - d) ** 2).sum(axis=1)
        better = c_new < cost[f]
        done = (np.abs(cost[f] - c_new) <= tol * cost[f]) | (
            np.linalg.norm(step, axis=1) <= tol * (tol + np.linalg.norm(Z[f], axis=1)))
        fb = f[better]
        Z[fb], v[fb], n[fb], cost[fb] = Z_new[better], v_new[better], n_new[better], \
            c_new[better]
        damping[f] = np.where(better, damping[f] / 3, damping[f] * 4)
        active = f[~done & (damping[f] < 1e10)]
        if active.size == 0:
            break
    return Z


def _edge_vectors(Z, qi, qj, i, j):
    """``(v: (F, E, 3), |v|: (F, E))`` of the edges ``Z_i q_i - Z_j q_j``."""
    v = Z[:, i, None] * qi - Z[:, j, None] * qj
    return v, np.linalg.norm(v, axis=-1)


def shapes(W, Z):
    """``S: (3F, P)`` camera frame: ``Z (x, y, 1)`` of normalised tracks ``W: (2F, P)`` and
    depths ``Z: (F, P)``."""
    return from_frames((_rays(W) * Z[..., None]).transpose(0, 2, 1))


def anchor_tracks(W, n):
    """``(n,)`` indices of tracks of ``W: (2F, P)`` spread over the surface: farthest-point
    sampling in the trajectory embedding (:func:`.inextensible.trajectory_embedding`), from
    the track nearest the centroid, among the :func:`consistent_tracks` (record 0723)."""
    X = trajectory_embedding(W)
    P = X.shape[0]
    if n >= P:
        return np.arange(P)
    candidates = consistent_tracks(W)
    if candidates.size <= n:
        candidates = np.arange(P)
    X = X[candidates]
    chosen = np.empty(n, dtype=np.intp)
    chosen[0] = np.argmin(np.linalg.norm(X - X.mean(0), axis=1))
    dist = np.linalg.norm(X - X[chosen[0]], axis=1)
    for m in range(1, n):
        chosen[m] = np.argmax(dist)
        dist = np.minimum(dist, np.linalg.norm(X - X[chosen[m]], axis=1))
    return np.sort(candidates[chosen])


def consistent_tracks(W):
    """``(P',)`` sorted indices of the tracks of ``W: (2F, P)`` whose trajectory the affine
    combination of their NEIGHBOURS nearest (:func:`.isometry.neighbours`) reproduces within
    CONSISTENT times the median track's residual (locally linear weights,
    :func:`.density.affine_weights`): not the drifting or noisy ones, which tracks at a
    sheet's border often are."""
    Wc = centre(W)[0]
    T = (Wc / track_scale(Wc)).T                                            # (P, 2F)
    near = isometry.neighbours(W, NEIGHBOURS)                              # (P, k), not itself
    weights = affine_weights(T[near] - T[:, None, :], CONSISTENCY_REGULARISATION)
    residual = np.linalg.norm(np.einsum('pk,pkn->pn', weights, T[near]) - T, axis=1)
    return np.flatnonzero(residual <= CONSISTENT * np.median(residual))


def interpolated_depths(W, anchors, Z_anchor, k=NEIGHBOURS):
    """``Z: (F, P)`` for every track of ``W: (2F, P)`` from the depths ``Z_anchor: (F, n)``
    of the tracks ``anchors: (n,)``: per frame, the least-squares plane ``Z = a + b . x``
    through its ``k`` nearest anchors (trajectory embedding) evaluated at its image point."""
    X = trajectory_embedding(W)
    k = min(k, anchors.size)
    _, near = NearestNeighbors(n_neighbors=k).fit(X[anchors]).kneighbors(X)   # (P, k)
    Z = plane_depths(as_frames(W, 2).transpose(0, 2, 1), anchors, Z_anchor, near)
    Z[:, anchors] = Z_anchor
    return Z


def plane_depths(xy, anchors, Z_anchor, near):
    """``(F, P)``: at each image point ``xy: (F, P, 2)``, the least-squares plane ``Z = a + b .
    x`` through the depths ``Z_anchor: (F, n)`` of its anchors ``anchors[near]`` (``near: (P,
    k)`` indices into ``anchors``)."""
    local = xy[:, anchors[near], :] - xy[:, :, None, :]                       # (F, P, k, 2)
    A = np.concatenate([np.ones(local.shape[:3] + (1,)), local], axis=-1)
    normal = np.einsum('fpki,fpkj->fpij', A, A)
    normal += 1e-9 * np.trace(normal, axis1=2, axis2=3)[..., None, None] * np.eye(3)
    rhs = np.einsum('fpki,fpk->fpi', A, Z_anchor[:, near])
    return np.linalg.solve(normal, rhs[..., None])[..., 0, 0]


@dataclass
class MaxDepthResult:
    """``S: (3F, P)`` camera frame (projects onto the tracks; mean depth 1 over the sequence),
    ``Z: (F, P)`` its depths, ``anchors``: the tracks the LP solved, ``edges = (i, j)``: their
    neighbour graph (indices into ``anchors``), ``lengths: (E,)`` the LP's, ``info``: see
    :func:`max_depth`."""
    S: np.ndarray
    Z: np.ndarray
    anchors: np.ndarray
    info: dict = field(default_factory=dict)
    edges: tuple = None
    lengths: np.ndarray = None


class MaxDepthNRSfM(BaseEstimator):
    """MDH reconstruction of normalised pinhole tracks: ``fit(W: (2F, P)) ->``
    :class:`MaxDepthResult`. ``neighbours``: edges per track; ``max_tracks``: the LP runs on
    at most this many tracks (:func:`anchor_tracks`), the others' depths are interpolated
    (:func:`interpolated_depths`); ``tol``: the cones' relative tolerance; ``refine``: the
    LP's depths fitted to its lengths as equalities (:func:`refined_depths`, record 0720);
    ``key_frames``: on longer sequences the lengths come from the LP on this many frames
    spread over the sequence, and each other frame's depths are the largest those lengths
    allow (records 0724, 0731)."""

    def __init__(self, neighbours=NEIGHBOURS, max_tracks=MAX_TRACKS, tol=TOL, refine=True,
                 key_frames=KEY_FRAMES):
        self.neighbours = neighbours
        self.max_tracks = max_tracks
        self.tol = tol
        self.refine = refine
        self.key_frames = key_frames

    def _checked(self):
        for name, low in (('neighbours', 2), ('max_tracks', 4), ('key_frames', 2)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or \
                    value < low:
                raise InvalidInputError(f'{name}={value!r}: expected an int >= {low}')
        if not (isinstance(self.tol, (int, float)) and 0 < self.tol < 1):
            raise InvalidInputError(f'tol={self.tol!r}: expected a number in (0, 1)')
        if not isinstance(self.refine, (bool, np.bool_)):
            raise InvalidInputError(f'refine={self.refine!r}: expected True or False')

    def fit(self, W):
        """Reconstruct the normalised (complete) tracks ``W: (2F, P)``."""
        self._checked()
        x = validate_tracks(W, min_frames=2, min_points=4)
        anchors = anchor_tracks(x, int(self.max_tracks))
        sub = x[:, anchors]
        edges = neighbour_edges(sub, int(self.neighbours))
        Z_a, d, info = self._anchor_depths(sub, edges)
        if self.refine:
            t0 = time.process_time()
            Z_a = refined_depths(sub, Z_a, d, edges)
            info['refine_seconds_cpu'] = time.process_time() - t0
        Z = interpolated_depths(x, anchors, Z_a, self.neighbours)
        Z = Z / Z.mean()
        return MaxDepthResult(S=shapes(x, Z), Z=Z, anchors=anchors, info=info, edges=edges,
                              lengths=d)

    def _anchor_depths(self, sub, edges):
        """``(Z: (F, n), d, info)`` of the anchors' tracks ``sub: (2F, n)``: the LP on every
        frame, or on ``key_frames`` of them and then, with their lengths, the others'
        :func:`largest_depths`."""
        F = sub.shape[0] // 2
        keys = spread_frames(F, self.key_frames)
        Z_keys, d, info = max_depth(sub[frame_rows(keys, 2)], edges, tol=self.tol)
        if keys.size == F:
            return Z_keys, d, info
        Z = np.empty((F, sub.shape[1]))
        Z[keys] = Z_keys
        others = np.setdiff1d(np.arange(F), keys)
        t0 = time.process_time()
        Z[others] = largest_depths(sub[frame_rows(others, 2)], edges, d)
        info.update(key_frames=int(keys.size),
                    other_frames_seconds_cpu=time.process_time() - t0)
        return Z, d, info
