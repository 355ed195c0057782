"""Per-frame tracking against a shape model: each new frame reconstructed on arrival.

A :class:`ShapeModel` is built from one solved problem (window + context + key frames): its
world-frame shapes ``X_f = R_f^T S_f`` give a mean ``mean: (3, P)`` and ``r`` modes
``modes: (r, 3, P)`` (the leading right singular vectors of the deviations; ``r`` chosen from
their energy). :class:`Tracker` fits one frame's centred image points ``w: (2, P')`` (any
subset of the model's tracks) by alternating

* the rotation ``R`` in SO(3): Gauss-Newton on so(3) from the previous frame's rotation,
  minimising ``||w - Pi R X||`` (orthographic: ``Pi`` keeps rows 0, 1; the SVD of ``w X^T``
  is *not* this minimiser, since the projection drops depth);
* the mode coefficients ``c: (r,)``: the MAP estimate under a Gaussian (PPCA) prior
  ``c_k ~ N(0, var_k)``, ``var_k`` the model's own variance of mode k over its frames, and
  image noise ``sigma^2 = NOISE_SHARE * mean(w^2)`` per coordinate:
  ``(A^T A + sigma^2 diag(1 / var)) c = A^T b`` (``A: (2P, r)`` the projected modes, ``b``
  the data less the projected mean), optionally pulled towards the previous frame's
  coefficients by ``temporal_prior``. The prior lets many modes be kept (``MODE_ENERGY``
  0.9999): weak modes are shrunk instead of fitted freely or dropped. The whitened
  coefficients ``c_k / sqrt(var_k)`` stay within ``MODE_BOUND`` each (3 sigma: the MAP
  estimate constrained to that box where it leaves it), so a model that has grown stale
  is not extrapolated far past the shapes it was built from.

The frame's camera-frame shape is ``x, y`` = its centred data, ``z`` = the depth of
``R X`` (centred), as the windows publish. Tracks the model lacks take the depth of their
nearest model tracks in the image (inverse-distance weighted); tracks that are gone are absent.
When a new model arrives its world frame differs from the old one by a rotation ``Q``,
estimated from the rotations of the frames both have seen, so that tracking continues
without a jump (:meth:`Tracker.swap`).

Cost per frame: O(P r) numpy, no per-point Python.
"""
from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_triangular
from scipy.optimize import lsq_linear
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from .measurement import economy_svd, nearest_rotation

#: modes kept: the fewest whose energy reaches this share of the deviations' energy
MODE_ENERGY = 0.9999
#: and never more than this many, nor any whose RMS over the frames is below this share of
#: the mean shape's norm (a rigid solution has no modes)
MAX_MODES = 40
MODE_FLOOR = 1e-6
#: most tracks a frame's rotation and coefficients are fitted on
FIT_TRACKS = 4000
#: image noise variance per coordinate assumed by the coefficients' Gaussian prior, as a share
#: of the frame's mean squared centred image coordinate (3 % RMS noise)
NOISE_SHARE = 1e-3
#: each mode's whitened squared coefficient is kept within this (3 sigma): a stale model is
#: not extrapolated far past the shapes it was built from (docs/decisions/0449)
MODE_BOUND = 9.0
#: alternations of rotation and coefficients per frame, Gauss-Newton steps per rotation fit
ALTERNATIONS = 4
GN_STEPS = 2
#: tracks the model lacks take the depth of this many nearest model tracks in the image
NEW_TRACK_NEIGHBOURS = 6
#: rotations of tracked frames a Tracker keeps for the next swap (the newest; bounded so a
#: model that is never replaced does not grow them without end)
HISTORY_FRAMES = 1000


@dataclass(frozen=True)
class ShapeModel:
    """Mean world shape ``mean: (3, P)`` (centred) and modes ``modes: (r, 3, P)`` of the
    tracks ``ids: (P,)`` (sorted), from frames ``stamps: (F,)`` with rotations
    ``R: (F, 3, 3)`` (world -> camera) and coefficients ``coefficients: (F, r)``."""

    ids: np.ndarray
    mean: np.ndarray
    modes: np.ndarray
    stamps: np.ndarray
    R: np.ndarray
    coefficients: np.ndarray
    variances: np.ndarray = None

    @property
    def rank(self):
        return self.modes.shape[0]


@dataclass(frozen=True)
class TrackedFrame:
    """One tracked frame: ``xyz: (P, 3)`` camera frame for ``ids: (P,)`` (x, y its centred
    data); ``R: (3, 3)`` in the model's world frame; ``residual``: ``||w - Pi R X|| / ||w||``
    over the model's tracks; ``new_tracks``: how many tracks took their neighbours' depth."""

    ids: np.ndarray
    xyz: np.ndarray
    R: np.ndarray
    coefficients: np.ndarray
    residual: float
    new_tracks: int


def build_model(S, R, ids, stamps, *, energy=MODE_ENERGY, max_modes=MAX_MODES):
    """ShapeModel from camera-frame shapes ``S: (3F, P)`` and rotations ``R: (F, 3, 3)`` of
    tracks ``ids: (P,)`` over frames ``stamps: (F,)``. ``max_modes`` 0: the mean alone
    (:func:`rigid_model`, no SVD of the deviations)."""
    F, P = R.shape[0], S.shape[1]
    S = S.reshape(F, 3, P)
    S = S - S.mean(axis=2, keepdims=True)
    X = R.transpose(0, 2, 1) @ S                              # (F, 3, P) world shapes
    mean = X.mean(axis=0)
    if max_modes == 0:
        return rigid_model(mean, R, ids, stamps)
    D = (X - mean).reshape(F, 3 * P)
    _, s, Vt = economy_svd(D)
    share = np.cumsum(s ** 2) / max(float(np.sum(s ** 2)), 1e-300)
    rank = int(min(np.searchsorted(share, energy) + 1, max_modes, max(F - 1, 0),
                   np.sum(s > MODE_FLOOR * np.linalg.norm(mean) * np.sqrt(F))))
    modes = Vt[:rank].reshape(rank, 3, P)
    coefficients = D @ Vt[:rank].T
    variances = mode_variances(s, rank, F, P)
    return ShapeModel(np.asarray(ids), mean, modes, np.asarray(stamps, dtype=np.int64),
                      np.asarray(R, dtype=np.float64), coefficients, variances)


def rigid_model(X, R, ids, stamps):
    """The rank-0 ShapeModel of the rigid world shape ``X: (3, P)`` of tracks ``ids: (P,)``
    seen with rotations ``R: (F, 3, 3)`` at ``stamps: (F,)``: its mean alone, no modes."""
    X = X - X.mean(axis=1, keepdims=True)
    return ShapeModel(np.asarray(ids), X, np.zeros((0,) + X.shape),
                      np.asarray(stamps, dtype=np.int64), np.asarray(R, dtype=np.float64),
                      np.zeros((R.shape[0], 0)), np.zeros(0))


def mode_variances(s, rank, F, P):
    """Prior variances ``(rank,)`` of the coefficients from the singular values ``s`` of the
    ``(F, 3P)`` deviations: PPCA's ``s_k^2 / F - sigma_u^2``, ``sigma_u^2`` the
    per-coordinate variance left in the discarded modes (floored, never zero)."""
    lam = s ** 2 / max(F, 1)
    rest = float(np.sum(lam[rank:])) / max(3 * P - rank, 1)
    floor = 1e-12 * (float(lam[0]) if lam.size else 1.0) + 1e-300
    return np.maximum(lam[:rank] - rest, floor)


def fit_rotation(w, X, R, steps=GN_STEPS):
    """Rotation ``(3, 3)`` minimising ``||w - (R X)[:2]||`` by Gauss-Newton on so(3) from
    ``R``; ``w: (2, P)``, ``X: (3, P)``, both centred."""
    for _ in range(steps):
        Y = R @ X
        e = w - Y[:2]
        # d(R' X)/d delta with R' = exp([delta]x) R is delta x Y: per point the Jacobian rows
        # Jx = (0, Y2, -Y1), Jy = (-Y2, 0, Y0); J^T J and J^T e from C = Y Y^T and E = e Y^T
        C, E = Y @ Y.T, e @ Y.T
        H = np.array([[C[2, 2], 0.0, -C[0, 2]],
                      [0.0, C[2, 2], -C[1, 2]],
                      [-C[0, 2], -C[1, 2], C[0, 0] + C[1, 1]]])
        g = np.array([-E[1, 2], E[0, 2], E[1, 0] - E[0, 1]])
        H[np.diag_indices(3)] += 1e-9 * np.trace(H) + 1e-300
        R = Rotation.from_rotvec(np.linalg.solve(H, g)).as_matrix() @ R
    return nearest_rotation(R)


def fit_frame(w, mean, modes, R, c, prior=0.0, alternations=ALTERNATIONS, variances=None,
              noise_share=NOISE_SHARE, bound=MODE_BOUND):
    """``(R: (3, 3), c: (r,), X: (3, P))`` fitting ``w: (2, P)`` (centred) to the model shape
    ``mean + sum_k c_k modes_k`` (``mean: (3, P)``, ``modes: (r, 3, P)``, both centred over
    these tracks), starting from ``R`` and ``c``; ``prior`` pulls ``c`` towards the given one;
    ``variances: (r,)`` the Gaussian prior's (None: no prior), image noise variance
    ``noise_share * mean(w^2)``; each coefficient stays within ``c_k^2 / var_k <= bound``
    (:func:`map_coefficients`)."""
    c_prior = c
    sigma2 = noise_share * float(np.mean(w ** 2)) if variances is not None else 0.0
    scale = np.ones(modes.shape[0]) if variances is None else variances
    X = mean + np.tensordot(c, modes, axes=1)
    for _ in range(alternations):
        R = fit_rotation(w, X, R)
        if modes.shape[0]:
            At = np.matmul(R[:2], modes).reshape(modes.shape[0], -1)   # A^T: (r, 2P)
            b = (w - R[:2] @ mean).ravel()
            G = At @ At.T
            lam = prior * np.trace(G) / max(G.shape[0], 1)
            c = map_coefficients(G, At @ b, scale, sigma2, lam, c_prior, bound)
            X = mean + np.tensordot(c, modes, axes=1)
    return R, c, X


def map_coefficients(G, g, variances, sigma2, lam=0.0, c_prior=None, bound=MODE_BOUND):
    """Mode coefficients ``(r,)`` minimising ``||A c - b||^2 + sigma2 sum_k c_k^2 / var_k
    + lam ||c - c_prior||^2`` (``G = A^T A: (r, r)``, ``g = A^T b: (r,)``): the MAP
    estimate, with each whitened coefficient ``u_k = c_k / sqrt(var_k)`` kept within
    ``u_k^2 <= bound`` (a box, solved as bounded least squares where the MAP estimate leaves
    it): a model does not extrapolate any of its modes far past the shapes it was built from.
    ``sigma2`` 0: least squares, unbounded."""
    sd = np.sqrt(variances)
    rhs = g + (lam * c_prior if lam else 0.0)
    H = (G + lam * np.eye(G.shape[0])) * np.outer(sd, sd)            # whitened data term
    H[np.diag_indices_from(H)] += sigma2 + 1e-12 * np.trace(H) + 1e-300
    q = sd * rhs
    u = np.linalg.solve(H, q)
    limit = np.sqrt(bound)
    if sigma2 > 0 and np.abs(u).max() > limit:
        L = np.linalg.cholesky(H)                     # ||L^T u - L^-1 q||^2 = the objective
        u = lsq_linear(L.T, solve_triangular(L, q, lower=True), bounds=(-limit, limit),
                       method='bvls').x
    return sd * u


class Tracker:
    """Reconstructs frames one at a time against the current :class:`ShapeModel`."""

    def __init__(self, model, *, temporal_prior=0.0, noise_share=NOISE_SHARE):
        """``noise_share``: the coefficients' Gaussian prior's image noise (0: plain least
        squares, which reproduces an exact model exactly)."""
        self.temporal_prior = float(temporal_prior)
        self.noise_share = float(noise_share)
        self.model = model
        self.R = model.R[-1].copy()
        self.c = model.coefficients[-1].copy() if model.rank else np.zeros(0)
        self.history = {}               # stamp -> R of tracked frames (model's world frame)
        self._fit_cache = None          # (model columns, their centred mean and modes)
        self.age = 0                    # frames tracked since the model's newest frame

    def swap(self, model):
        """Continue with ``model``: the current rotation is carried into its world frame.
        When this tracker tracked ``model``'s newest frame n, from ``model``'s own rotation
        of it and the motion tracked since: ``R = R_old_t R_old_n^T R_new_n``; else through
        the frames both hold rotations of (``Q`` from ``R_new_f ~ R_old_f Q``); without
        shared frames, ``model``'s newest rotation."""
        newest = int(model.stamps[-1])
        shared = [i for i, s in enumerate(model.stamps) if int(s) in self.history]
        if newest in self.history:        # rounding kept from compounding over swaps
            self.R = nearest_rotation(self.R @ self.history[newest].T @ model.R[-1])
        elif shared:
            M = sum(self.history[int(model.stamps[i])].T @ model.R[i] for i in shared)
            self.R = self.R @ nearest_rotation(M)
        else:
            self.R = model.R[-1].copy()
        self.age = sum(1 for stamp in self.history if stamp > newest)
        self.model = model
        self.c = model.coefficients[-1].copy() if model.rank else np.zeros(0)
        self.history = {}
        self._fit_cache = None

    def _fit_model(self, cols):
        """``(mean: (3, n), modes: (r, 3, n))`` of the model on its columns ``cols: (n,)``
        that a frame is fitted on, centred over them; kept while the frames' columns repeat
        (the usual case: the copy and centring are not redone per frame)."""
        if self._fit_cache is None or not np.array_equal(self._fit_cache[0], cols):
            mean, modes = self.model.mean[:, cols], self.model.modes[:, :, cols]
            self._fit_cache = (cols, mean - mean.mean(axis=1, keepdims=True),
                               modes - modes.mean(axis=2, keepdims=True))
        return self._fit_cache[1:]

    def track(self, stamp_ns, ids, uv):
        """TrackedFrame of one frame: ``ids: (P,)`` sorted unique, ``uv: (P, 2)``."""
        model = self.model
        if np.array_equal(model.ids, ids):          # the usual case: no copy of the model
            cols = known = np.arange(ids.size)
            mean, modes = model.mean, model.modes
        else:
            _, cols, known = np.intersect1d(model.ids, ids, assume_unique=True,
                                            return_indices=True)
            mean, modes = model.mean[:, cols], model.modes[:, :, cols]
        w_all = uv.T - uv.mean(axis=0)[:, None]                  # (2, P)
        fit = fit_subset(known.size)
        w_fit = w_all[:, known[fit]]
        R, c, _ = fit_frame(w_fit - w_fit.mean(axis=1, keepdims=True),
                            *self._fit_model(cols[fit]), self.R, self.c, self.temporal_prior,
                            variances=model.variances, noise_share=self.noise_share)
        w = w_all[:, known]
        w = w - w.mean(axis=1, keepdims=True)
        X = mean + np.tensordot(c, modes, axes=1)                # centring X = centring both
        Y = R @ (X - X.mean(axis=1, keepdims=True))
        residual = float(np.linalg.norm(w - Y[:2]) / max(np.linalg.norm(w), 1e-300))
        z = np.empty(ids.size)
        z[known] = Y[2]
        new = np.setdiff1d(np.arange(ids.size), known, assume_unique=True)
        if new.size:
            z[new] = neighbour_depth(uv[known], Y[2], uv[new])
        xyz = np.column_stack([w_all.T, z - z.mean()])
        self.R, self.c = R, c
        self.history[int(stamp_ns)] = R
        if len(self.history) > HISTORY_FRAMES:
            del self.history[next(iter(self.history))]
        self.age += 1
        return TrackedFrame(ids, xyz, R, c, residual, int(new.size))


def fit_subset(n, most=FIT_TRACKS):
    """Indices of the tracks (of ``n``) a frame is fitted on: all, or ``most`` evenly spread
    (the fit's cost then does not grow with the tracks; every track's depth is still
    computed)."""
    return slice(None) if n <= most else np.linspace(0, n - 1, most).astype(int)


def neighbour_depth(uv_known, z_known, uv_new, k=NEW_TRACK_NEIGHBOURS):
    """Depths ``(N,)`` at ``uv_new: (N, 2)``: inverse-distance mean of the ``k`` nearest of
    ``uv_known: (P, 2)`` with depths ``z_known: (P,)``."""
    k = min(k, len(z_known))
    dist, idx = cKDTree(uv_known).query(uv_new, k=k)
    dist, idx = dist.reshape(len(uv_new), k), idx.reshape(len(uv_new), k)
    weight = 1.0 / np.maximum(dist, 1e-9 * (np.ptp(uv_known) + 1e-300))
    return np.sum(weight * z_known[idx], axis=1) / np.sum(weight, axis=1)
