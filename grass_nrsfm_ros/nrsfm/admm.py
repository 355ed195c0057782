"""Algorithm 1 of Kumar et al. 2018: the Grassmannian ADMM, nothing else.

Problem solved on tracks ``Wn: (2F, P)`` centred per row and scaled to unit RMS, with known
rotations ``R: (F, 3, 3)`` and optional per-entry weights ``M: (2F, P)`` in [0, 1] (0: not
seen; None: all 1)::

    min  1/2 ||M^(1/2) o (Wn - R S)||^2 + gamma ||S#||_* + lam1 ||T_s - T_s C_s||^2
         + lam2 ||T_t - T_t C_t||^2
         + lam3 ||C_s||_* + lam4 ||C_t||_*
    s.t. S# = T1(S), Psi = xi(C, S), S = zeta(Psi, N)

``S: (F, 3, P)`` world-frame shapes (``S_f = R_f^T S_cam_f``), ``S#: (F, 3P)`` their frame-wise
vectorisation, ``T_s`` / ``T_t`` the projection embeddings of the spatial (trajectory-group)
and temporal (frame-block) Grassmann points, ``C_s: (K_s, K_s)``, ``C_t: (K_t, K_t)`` their
self-expression coefficients.

This module owns:

* :class:`AdmmSettings`: the numbers of one solve (absolute gamma, sizes, switches);
* the steps that need no state (shapes in their docstrings): :func:`closed_form_shapes`,
  :func:`svt_of_gram`, :func:`svt_factors`, :func:`svt_tall`, :func:`coefficient_step`,
  :func:`dual_step`, :func:`branch_objective`, the nuclear norms through Grams;
* :class:`AdmmState`: the variables and one iteration (:meth:`AdmmState.iterate`);
* :func:`stop_reason`: the stopping rule (every gap below GAP_TOLERANCE, or beta at beta_max);
* :func:`run`: iterate until the rule says stop.

Weights enter the S update exactly: per entry in the closed form (:func:`closed_form_shapes`),
per pattern of weights over frames in the smoothness prior's banded solve (priors.py); an
unseen entry's S then follows S# (docs/decisions/0800).

Layout: the ``(F, 3, P)`` arrays are stored column-permuted so that each spatial group is a
contiguous slice (the paper's T2); one iteration makes two sweeps over cache-sized column
blocks (no ``(F, 3, P)`` temporary); S# is thresholded through its ``F x F`` Gram (or the
``3P x 3P`` one when ``F > 3P``); problems with ``F * P >= FLOAT32_MIN_SIZE`` store the
iterates as float32, with float64 Grams, eigen/QR steps and sums.
"""
from dataclasses import dataclass, field
from itertools import groupby
import time

import numpy as np

from . import grassmann as gm
from .priors import smoothness_weight, TemporalSmoothness

#: the stopping rule's gap tolerance: every constraint gap (max abs) below it stops the run;
#: float32 gaps stop near 1e-7 |S|, so there beta reaching beta_max ends the run
GAP_TOLERANCE = 1e-12
#: bytes of one (F, 3, n) column block in the element-wise sweeps (keeps a block in cache)
BLOCK_BYTES = 1 << 20
#: storage of the (F, 3, P) iterates when F * P >= FLOAT32_MIN_SIZE
STORAGE_DTYPE = np.float32
FLOAT32_MIN_SIZE = 1 << 20


@dataclass(frozen=True)
class AdmmSettings:
    """The numbers of one ADMM solve. ``gamma`` is absolute (on unit-RMS tracks); ``K_s``,
    ``K_t``, ``N_s``, ``N_t`` are resolved integers; ``max_iter``: a cap on the iterations of
    :func:`run`."""

    gamma: float
    lambda1: float
    lambda2: float
    lambda3: float
    lambda4: float
    sigma_eps: float
    affinity_min: float
    regroup_every: int
    delta: float
    rho: float
    beta0: float
    beta_max: float
    warm_beta0: float
    smoothness: float
    spatial: bool
    temporal: bool
    random_state: object
    max_iter: int
    K_s: int
    K_t: int
    N_s: int
    N_t: int


@dataclass
class AdmmRun:
    """What :func:`run` did: iterations so far, per-iteration objective and gaps
    ``(max|S# - S|, max|C_s - J_s|, max|C_t - J_t|)``, why it stopped."""

    iterations: int = 0
    converged: bool = False
    reason: str = 'max_iter reached'
    diverged: bool = False
    objective: list = field(default_factory=list)
    gaps: list = field(default_factory=list)


class Timer:
    """Seconds per phase: ``add(phase, since)`` adds ``now - since`` and returns now."""

    def __init__(self):
        self.seconds = {}

    def add(self, phase, since):
        now = time.perf_counter()
        self.seconds[phase] = self.seconds.get(phase, 0.0) + now - since
        return now


def column_blocks(edges, width):
    """Column slices of at most ``width`` columns, each inside one group ``edges[k]:edges[k+1]``.

    Returns ``[(k, slice)]`` in column order.
    """
    out = []
    for k in range(len(edges) - 1):
        for a in range(edges[k], edges[k + 1], width):
            out.append((k, slice(a, min(a + width, edges[k + 1]))))
    return out


def blocked_view(flat, F, rows, cols):
    """The contiguous ``(F, rows, n)`` piece of a block-major ``flat`` buffer for ``cols``."""
    n = cols.stop - cols.start
    start = F * rows * cols.start
    return flat[start:start + F * rows * n].reshape(F, rows, n)


class Buffer:
    """One preallocated flat buffer handing out contiguous ``(F, rows, n)`` views."""

    def __init__(self, size, dtype=np.float64):
        self.flat = np.empty(size, dtype=dtype)

    def view(self, F, rows, n):
        return self.flat[:F * rows * n].reshape(F, rows, n)


def as_float64(block, buffer):
    """``block: (F, r, n)`` as float64: itself when it is, else copied into ``buffer``."""
    if block.dtype == np.float64:
        return block
    out = buffer.view(*block.shape)
    out[...] = block
    return out


def add_gram(G, block, buffer):
    """``G += X X^T`` (float64, ``G: (F, F)``) for a column block ``X: (F, 3, n)``."""
    X = as_float64(block, buffer).reshape(G.shape[0], -1)
    G += X @ X.T


def weight_patterns(M):
    """``(ids: (n,), patterns: (k, F, 2))``: the distinct columns of the weights ``M: (F, 2,
    n)`` and which one each column has."""
    F, _, n = M.shape
    patterns, ids = np.unique(M.reshape(2 * F, n).T, axis=0, return_inverse=True)
    return ids.reshape(n), patterns.reshape(-1, F, 2).astype(np.float64)


def regroup_due(every, K, it):
    """Whether iteration ``it`` (from 0) regroups a branch of ``K`` groups: every ``every``-th
    (never with ``every`` 0 or one group)."""
    return bool(every and K > 1 and (it + 1) % every == 0)


def closed_form_shapes(R, Rt, W, sharp, Y1, beta, work, out, M=None):
    """The S update without the smoothness prior, per frame in closed form: the solution of
    ``(R^T P R + beta I) S = R^T W + beta S# + Y1`` (P keeps the two image rows) is
    ``S = R^T diag(scale) (R (beta S# + Y1) + [W; 0])``, ``scale = (1/(1+beta), 1/(1+beta),
    1/beta)``. ``R, Rt: (F, 3, 3)`` (R and R^T), ``W: (F, 2, n)``, ``sharp, Y1: (F, 3, n)``;
    ``work``: two ``(F, 3, n)`` scratch arrays; the result is written to ``out``. With weights
    ``M: (F, 2, n)`` (P becomes diag(M)): ``[M o W; 0]`` and the image rows' scale
    ``1/(M + beta)``."""
    if M is not None:
        rhs = np.multiply(sharp, sharp.dtype.type(beta), out=work[0])
        rhs += Y1
        cam = np.matmul(R, rhs, out=work[1])
        cam[:, :2, :] += M * W
        cam[:, :2, :] /= M + sharp.dtype.type(beta)
        cam[:, 2, :] *= sharp.dtype.type(1.0 / beta)
        np.matmul(Rt, cam, out=out)
        return
    c = 1.0 / (1.0 + beta)
    scale = np.array([c, c, 1.0 / beta], dtype=sharp.dtype)[None, :, None]
    rhs = np.multiply(sharp, sharp.dtype.type(beta), out=work[0])
    rhs += Y1
    cam = np.matmul(R, rhs, out=work[1])
    cam[:, :2, :] += W
    cam *= scale
    np.matmul(Rt, cam, out=out)


def svt_of_gram(G, tau):
    """The SVT by ``tau`` of a matrix X given its Gram ``G: (n, n)`` (``X X^T`` or ``X^T X``):
    the Gram's eigenvectors ``vecs: (n, n)`` and ``shrink: (n,)``, ``max(s - tau, 0) / s`` of
    the singular values s (0 where s is 0): ``SVT(X) = vecs diag(shrink) vecs^T X`` (or X
    times it)."""
    vals, vecs = np.linalg.eigh(G)
    sv = np.sqrt(np.maximum(vals, 0.0))
    shrink = np.where(sv > 0, np.maximum(sv - tau, 0.0) / np.where(
        sv > 0, sv, 1.0), 0.0)
    return vecs, shrink


def svt_factors(G, tau):
    """The wide SVT by ``tau`` of ``X: (F, m)`` from its Gram ``G: (F, F)``: ``left, right: (F,
    r)`` (r: the singular values kept) with ``SVT(X) = left right^T X``, and ``core = right^T G
    right: (r, r)``, so that the result's Gram is ``left core left^T``."""
    vecs, shrink = svt_of_gram(G, tau)
    kept = shrink > 0
    right = vecs[:, kept]                           # SVT: V diag(shrink) V^T, kept part
    return right * shrink[kept], right, right.T @ G @ right


def svt_tall(X, tau):
    """The SVT by ``tau`` of a tall ``X: (F, m)`` (F > m) through its ``(m, m)`` Gram."""
    # a general product, not numpy's symmetric one for X.T @ X: the rounding it always had
    vecs, shrink = svt_of_gram(X.T @ X.copy(), tau)
    return X @ ((vecs * shrink) @ vecs.T)


def nuclear_of_gram(gram):
    """The nuclear norm of a matrix of Gram ``gram``."""
    return float(np.sqrt(np.maximum(np.linalg.eigvalsh(gram), 0.0)).sum())


def nuclear_of_factors(L, core):
    """:func:`nuclear_of_gram` of ``L core L^T`` (``L: (F, r)``, ``core: (r, r)`` PSD, r small)
    through an ``(r, r)`` matrix with the Gram's nonzero eigenvalues."""
    vals, vecs = np.linalg.eigh(core)
    K = L @ (vecs * np.sqrt(np.maximum(vals, 0.0)))         # the Gram is K K^T
    return float(np.sqrt(np.maximum(np.linalg.eigvalsh(K.T @ K), 0.0)).sum())


def coefficient_step(Omega, J, Y, lam, lam_nuclear, beta):
    """Algorithm 1's C and J steps of one branch (all ``(K, K)``): C in closed form
    (:func:`~.grassmann.c_update`), then ``J = SVT(C + Y/beta)`` by ``lam_nuclear / beta``.
    Returns ``(C, J, ||J||_*)``."""
    C = gm.c_update(Omega, J, Y, lam, beta)
    J, nuclear = gm.singular_value_threshold(C + Y / beta, lam_nuclear / beta)
    return C, J, nuclear


def dual_step(Y, C, J, beta):
    """``Y += beta (C - J)`` in place (all ``(K, K)``); returns the gap ``max |C - J|``."""
    Y += beta * (C - J)
    return float(np.abs(C - J).max())


def branch_objective(C, Omega, lam, lam_nuclear, nuclear_J):
    """One branch's objective terms: ``lam ||T - T C||^2 + lam_nuclear ||J||_*`` (the first
    from ``C, Omega: (K, K)``, :func:`~.grassmann.embedding_error`)."""
    return lam * gm.embedding_error(C, Omega) + lam_nuclear * nuclear_J


class AdmmState:
    """ADMM variables of Algorithm 1 and one iteration, on ``Wn: (2F, P)``, ``R: (F, 3, 3)``
    from world-frame initial shapes ``S0: (F, 3, P)``; ``groups: (P,)`` initial spatial labels
    (None: k-means++ on S0, one group with the spatial branch off); ``warm``: S0 carries an
    earlier solution (the warm beta0, no smoothness prior); ``beta``: the penalty to start at
    instead (None: the settings' warm_beta0 or beta0); ``smooth``: the smoothness prior on or
    off instead (None: off when warm); ``weights: (2F, P)`` the data term's per-entry weights
    (None: all 1).

    One iteration makes two sweeps over column blocks:

    1. per block: S update, (per group) spatial bases + zeta_s, ``X = S - Y1/beta`` and its
       ``F x F`` Gram contribution, the data term ``||W - R S||^2``;
    2. per block: ``S# = op X`` with the ``F x F`` operator ``op`` (SVT and zeta_t) found from
       the Gram in between, the gap ``max |S# - S|`` and ``Y1 += beta (S# - S)``.
    """

    def __init__(self, Wn, R, S0, settings, groups=None, warm=False, beta=None, smooth=None,
                 weights=None):
        F, P = R.shape[0], Wn.shape[1]
        s = settings
        labels = groups if groups is not None else (
            gm.initial_groups(S0.reshape(3 * F, P), s.K_s, s.random_state)
            if s.spatial else np.zeros(P, dtype=np.int64))
        self._layout(Wn, R, settings, labels, np.argsort(labels, kind='stable'),
                     not warm if smooth is None else smooth)
        self.M = self.patterns = None
        if weights is not None:
            self.M = weights.reshape(F, 2, P)[:, :, self.order].astype(self.dtype)
            if self.smoother is not None:
                self.patterns = weight_patterns(self.M)
        self.iteration = 0
        self.beta = beta if beta is not None else s.warm_beta0 if warm else s.beta0
        self.beta_reached_max = False
        self.moves = 0
        self.S = S0[:, :, self.order].astype(self.dtype)
        self.Ssh = self.S.copy()
        self.Y1 = np.zeros_like(self.S)
        self.s_bases = self._spatial_bases_exact()
        self.t_edges = gm.contiguous_blocks(F, self.K_t)
        G = np.zeros((F, F))
        for _, cols in self.blocks:
            add_gram(G, self.Ssh[:, :, cols], self.wide)
        self.t_bases = gm.block_bases(G, self.t_edges, self.N_t)
        self.C_s, self.J_s, self.Y2 = (np.zeros((self.K_s, self.K_s)) for _ in range(3))
        self.C_t, self.J_t, self.Y3 = (np.zeros((self.K_t, self.K_t)) for _ in range(3))
        self.nuc_jt = 0.0
        self.Omega_s = gm.spatial_kernel(self.s_bases, s.delta)
        self.Omega_t = gm.temporal_kernel(G, self.t_edges, self.t_bases, s.delta)

    def _layout(self, Wn, R, settings, labels, order, smooth):
        """Sizes, column order, stored tracks and rotations, block tiling and buffers."""
        F, P = R.shape[0], Wn.shape[1]
        s = settings
        self.F, self.P, self.s, self.R, self.smooth = F, P, s, R, smooth
        self.gamma, self.K_t, self.N_s, self.N_t = s.gamma, s.K_t, s.N_s, s.N_t
        self.K_s = K_s = int(labels.max()) + 1
        self.order, self.labels = order, labels[order]
        self.s_edges = np.searchsorted(self.labels, np.arange(K_s + 1))
        self.data = None                    # ||Wn - R2 S||^2 of the last sweep
        self.dtype = dt = STORAGE_DTYPE if F * P >= FLOAT32_MIN_SIZE else np.float64
        self.W = Wn.reshape(F, 2, P)[:, :, order].astype(dt)
        self.R2 = R[:, :2, :].astype(dt)                           # (F, 2, 3) cameras
        self.Rs = R.astype(dt)                                     # (F, 3, 3)
        self.Rt = np.ascontiguousarray(self.Rs.transpose(0, 2, 1))
        self.tall = F > 3 * P
        self.width = P if self.tall else max(1, min(P, BLOCK_BYTES // (24 * F)))
        self.blocks = column_blocks(self.s_edges, self.width)
        self.buffers = [Buffer(3 * F * self.width, dt) for _ in range(3)]
        self.wide = Buffer(3 * F * self.width)                     # float64 copy of a block
        self.X = np.empty(3 * F * P, dtype=dt)   # X = S - Y1/beta, block-major (blocked_view)
        self.smoother = (TemporalSmoothness(R, smoothness_weight(Wn, s.smoothness), P)
                         if s.smoothness > 0 and smooth else None)

    # spatial Grassmann points ------------------------------------------------------------------
    def _group(self, k):
        return self.S.reshape(3 * self.F, self.P)[:, self.s_edges[k]:self.s_edges[k + 1]]

    def _spatial_bases_exact(self):
        return [gm.top_subspace(self._group(k).astype(np.float64), self.N_s)[0]
                for k in range(self.K_s)]

    def _regroup_spatial(self):
        S2 = self.S.reshape(3 * self.F, self.P).astype(np.float64, copy=False)
        new = gm.regroup_points(S2, self.labels, self.s_bases, self.C_s, self.s.sigma_eps,
                                self.s.affinity_min, self.N_s)
        moved = int((new != self.labels).sum())
        if moved == 0:
            return
        self.moves += moved
        perm = np.argsort(new, kind='stable')
        self.labels = new[perm]
        self.order = self.order[perm]
        self.s_edges = np.searchsorted(self.labels, np.arange(self.K_s + 1))
        self.blocks = column_blocks(self.s_edges, self.width)
        for arr in (self.W, self.S, self.Ssh, self.Y1) + ((self.M,) if self.M is not None
                                                          else ()):
            arr[...] = arr[:, :, perm]
        if self.patterns is not None:
            self.patterns = (self.patterns[0][perm], self.patterns[1])
        self.s_bases = self._spatial_bases_exact()

    def _update_group_basis(self, k):
        """Spatial basis of group k follows S by one warm-started power iteration."""
        group = self._group(k)
        if group.shape[1] > self.N_s:
            self.s_bases[k] = gm.subspace_iteration(group, self.s_bases[k], 1)

    def _zeta_group(self, k):
        """zeta_s of group k: the paper's rank-N_s reconstruction."""
        gm.zeta(self._group(k), self.s_edges[k:k + 2] - self.s_edges[k], self.N_s,
                bases=self.s_bases[k:k + 1])

    # sweep 1: S update, spatial branch, Gram of X = S - Y1/beta, data term ----------------------
    def _update_shapes(self, cols, beta):
        """S[:, :, cols]: :func:`closed_form_shapes`, or with the smoothness prior (frames
        coupled) one banded solve (priors.py); weighted where the state has weights."""
        M = None if self.M is None else self.M[:, :, cols]
        if self.smoother is not None:
            rhs = self.Ssh[:, :, cols].astype(np.float64) * beta + self.Y1[:, :, cols]
            W = self.W[:, :, cols].astype(np.float64)
            self.S[:, :, cols] = (
                self.smoother.solve(W, rhs, beta) if M is None else
                self.smoother.solve_weighted(W, M.astype(np.float64), rhs, beta,
                                             self.patterns[0][cols], self.patterns[1]))
            return
        work = [b.view(self.F, 3, cols.stop - cols.start) for b in self.buffers[:2]]
        closed_form_shapes(self.Rs, self.Rt, self.W[:, :, cols], self.Ssh[:, :, cols],
                           self.Y1[:, :, cols], beta, work, self.S[:, :, cols], M)

    def _gram_and_data(self, cols, beta, G):
        """Stores the block's ``X = S - Y1/beta``, adds its ``X X^T`` to G; returns the block's
        ``||R2 S - W||^2``."""
        F, n = self.F, cols.stop - cols.start
        X = np.multiply(self.Y1[:, :, cols], self.dtype(-1.0 / beta),
                        out=blocked_view(self.X, F, 3, cols))
        X += self.S[:, :, cols]
        add_gram(G, X, self.wide)
        resid = np.matmul(self.R2, self.S[:, :, cols], out=self.buffers[1].view(F, 2, n))
        resid -= self.W[:, :, cols]
        resid = as_float64(resid, self.wide)
        if self.M is not None:
            return float(np.vdot(resid, self.M[:, :, cols] * resid))
        return float(np.vdot(resid, resid))

    def _sweep_shapes(self, beta, regroup, timer, t):
        """Sweep 1. Returns ``(G: (F, F), ||W - R S||^2, t)``."""
        G, data = np.zeros((self.F, self.F)), 0.0
        if regroup:
            for _, cols in self.blocks:
                self._update_shapes(cols, beta)
            t = timer.add('s_update', t)
            self._regroup_spatial()
            t = timer.add('spatial', t)
        for k, pairs in groupby(self.blocks, key=lambda block: block[0]):
            group = [cols for _, cols in pairs]
            if not regroup:
                for cols in group:
                    self._update_shapes(cols, beta)
                t = timer.add('s_update', t)
            if self.s.spatial:
                if not regroup:
                    self._update_group_basis(k)
                self._zeta_group(k)
                t = timer.add('spatial', t)
            for cols in group:
                data += self._gram_and_data(cols, beta, G)
            t = timer.add('svt', t)
        return G, data, t

    # the S# step: SVT through the smaller Gram, zeta_t ------------------------------------------
    def _temporal(self, G1, beta, it):
        """Temporal branch on the Gram ``G1: (F, F)`` of the thresholded S#: returns the
        block-diagonal zeta_t operator ``B: (F, F)`` and the blocks' bases (C_t, xi_t, J_t
        updated). Block k of ``B G1 B^T`` is ``V_k V_k^T G1_kk V_k V_k^T``, whose top
        eigenpairs are ``V_k``'s own: the bases of the projected S# too (no second eigh)."""
        s = self.s
        self.C_t, self.J_t, self.nuc_jt = coefficient_step(self.Omega_t, self.J_t, self.Y3,
                                                           s.lambda2, s.lambda4, beta)
        bases = gm.block_bases(G1, self.t_edges, self.N_t)
        if regroup_due(s.regroup_every, self.K_t, it):
            self.t_edges, bases = gm.regroup_blocks(G1, self.t_edges, bases, self.C_t,
                                                    s.sigma_eps, s.affinity_min, self.N_t)
        return gm.block_projector(self.F, self.t_edges, bases), bases

    def _sharp_operator(self, G, beta, it):
        """Wide case (F <= 3P), from the Gram ``G: (F, F)`` of X: ``S# = left right^T X``
        (:func:`svt_factors`, then zeta_t), the Gram of S# and its nuclear norm. Applied as two
        thin products, S# costs ``2 r / F`` of one ``F x F`` operator."""
        left, right, core = svt_factors(G, self.gamma / beta)
        G1 = left @ core @ left.T
        if self.s.temporal:
            B, self.t_bases = self._temporal(G1, beta, it)
            left = B @ left
            G1 = left @ core @ left.T
        return (left, right), G1, nuclear_of_factors(left, core)

    def _sharp_tall(self, X, beta, it):
        """Tall case (F > 3P): S# of ``X: (F, 3P)`` (:func:`svt_tall`, then zeta_t)."""
        Z = svt_tall(X, self.gamma / beta)
        G1 = Z @ Z.T
        if self.s.temporal:
            B, self.t_bases = self._temporal(G1, beta, it)
            Z = B @ Z
            G1 = Z @ Z.T
        return Z, G1, nuclear_of_gram(Z.T @ Z)

    # sweep 2: S#, gap and Y1 ---------------------------------------------------------------------
    def _sweep_multipliers(self, beta, op=None, sharp=None):
        """``S# = left right^T X`` (``op = (left, right)``, :meth:`_sharp_operator`) or the
        given ``sharp: (F, 3P)``, ``Y1 += beta (S# - S)``; returns ``max |S# - S|``."""
        F, gap = self.F, 0.0
        if op is not None:
            left = np.ascontiguousarray(op[0], dtype=self.dtype)
            right_t = np.ascontiguousarray(op[1].T, dtype=self.dtype)
        for _, cols in self.blocks:
            n = cols.stop - cols.start
            if sharp is None:
                X = blocked_view(self.X, F, 3, cols).reshape(F, 3 * n)
                new = np.matmul(left, right_t @ X,
                                out=self.buffers[2].view(F, 3, n).reshape(F, 3 * n))
                new = new.reshape(F, 3, n)
            else:
                new = sharp.reshape(F, 3, self.P)[:, :, cols]
            diff = np.subtract(new, self.S[:, :, cols], out=self.buffers[1].view(F, 3, n))
            gap = max(gap, float(diff.max()), -float(diff.min()))
            diff *= self.dtype(beta)
            self.Y1[:, :, cols] += diff
            self.Ssh[:, :, cols] = new
        return gap

    # one iteration -------------------------------------------------------------------------
    def iterate(self, timer):
        """One iteration of Algorithm 1; returns ``(objective, gaps)``."""
        s, beta, it = self.s, self.beta, self.iteration
        t = time.perf_counter()
        regroup = s.spatial and regroup_due(s.regroup_every, self.K_s, it)
        if s.spatial:
            self.C_s, self.J_s, nuc_js = coefficient_step(self.Omega_s, self.J_s, self.Y2,
                                                          s.lambda1, s.lambda3, beta)
        G, data, t = self._sweep_shapes(beta, regroup, timer, t)
        t = timer.add('spatial', t)

        # S# update: SVT of T1(S) - Y1/beta via the smaller Gram matrix, then zeta_t
        op = sharp = None
        if self.tall:
            X = self.X.reshape(self.F, 3 * self.P).astype(np.float64)
            sharp, G1, nuclear = self._sharp_tall(X, beta, it)
        else:
            op, G1, nuclear = self._sharp_operator(G, beta, it)
        t = timer.add('temporal', t)

        obj = 0.0
        if s.spatial:
            self.Omega_s = gm.spatial_kernel(self.s_bases, s.delta)
            obj += branch_objective(self.C_s, self.Omega_s, s.lambda1, s.lambda3, nuc_js)
        if s.temporal:
            self.Omega_t = gm.temporal_kernel(G1, self.t_edges, self.t_bases, s.delta)
            obj += branch_objective(self.C_t, self.Omega_t, s.lambda2, s.lambda4, self.nuc_jt)

        gap_sh = self._sweep_multipliers(beta, op, sharp)
        gap_s = dual_step(self.Y2, self.C_s, self.J_s, beta) if s.spatial else 0.0
        gap_t = dual_step(self.Y3, self.C_t, self.J_t, beta) if s.temporal else 0.0
        self.data = data
        obj += 0.5 * data + self.gamma * nuclear
        if self.smoother is not None:
            obj += self.smoother.energy(self.S)
        self.beta_reached_max = beta >= s.beta_max
        self.beta = min(s.rho * beta, s.beta_max)
        self.iteration = it + 1
        timer.add('multipliers', t)
        return obj, (gap_sh, gap_s, gap_t)

    def fall_back(self, S0):
        """Replace the shapes by ``S0: (F, 3, P)`` (input order), after a divergence."""
        self.S = S0[:, :, self.order].astype(self.dtype)
        self.data = None

    def data_error(self):
        """``||Wn - R2 S||^2`` of the current S (from the last sweep unless S was reset)."""
        if self.data is None:
            resid = np.matmul(self.R2, self.S, dtype=np.float64)
            resid -= self.W
            self.data = float(np.vdot(resid, resid if self.M is None else self.M * resid))
        return self.data

    def S_world_original_order(self):
        """World-frame S ``(F, 3, P)`` in the input's column order; frees the iteration
        buffers (the state is spent afterwards)."""
        out = self.Ssh
        out[:, :, self.order] = self.S
        self.X = self.Y1 = self.S = self.Ssh = None
        return out

    def labels_original_order(self):
        out = np.empty_like(self.labels)
        out[self.order] = self.labels
        return out


def stop_reason(state, objective, gaps):
    """Why the run stops after an iteration with ``objective`` and ``gaps``, or None: a
    non-finite value ('diverged'), every gap below GAP_TOLERANCE, or beta at beta_max."""
    if not (np.isfinite(objective) and np.all(np.isfinite(gaps))):
        return 'diverged'
    if max(gaps) < GAP_TOLERANCE:
        return 'all constraint gaps below eps'
    if state.beta_reached_max:
        return 'beta reached beta_max'
    return None


def run(state, record=None, on_iteration=None, timer=None, iterations=None):
    """Iterate ``state`` until :func:`stop_reason` says stop, ``settings.max_iter`` iterations
    are done in all, or ``iterations`` more were made. ``record``: the :class:`AdmmRun` to
    append to (a new one by default); ``on_iteration(record)`` is called after each iteration
    that did not diverge. Returns the record."""
    record = record if record is not None else AdmmRun()
    timer = timer if timer is not None else Timer()
    last = state.s.max_iter if iterations is None else min(state.s.max_iter,
                                                           state.iteration + iterations)
    while state.iteration < last:
        obj, gaps = state.iterate(timer)
        record.iterations = state.iteration
        record.objective.append(obj)
        record.gaps.append(gaps)
        reason = stop_reason(state, obj, gaps)
        if reason == 'diverged':
            record.reason, record.diverged = reason, True
            break
        if on_iteration is not None:
            on_iteration(record)
        if reason is not None:
            record.reason, record.converged = reason, True
            break
    return record
