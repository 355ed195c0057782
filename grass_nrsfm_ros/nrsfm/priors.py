"""Extra shape priors for the ADMM S-update of :mod:`.admm`.

Temporal smoothness of the world-frame shapes, ``(lam/2) ||D S||^2`` with ``D`` the
second-difference operator over frames (applied to every coordinate of every point). With it
the S-update ``min 1/2 ||W - R S||^2 + lam/2 ||D S||^2 + beta/2 ||S - S# - Y1/beta||^2`` couples
frames: for every point the same symmetric positive definite banded ``(3F, 3F)`` system
``(blockdiag(R_f^T P R_f) + lam (D^T D kron I_3) + beta I) s = b`` (half-bandwidth 6), factored
once per beta and solved for all P right-hand sides at once (O(F P) memory and time). With
per-entry data weights ``M: (F, 2, P)`` (tracks not seen in every frame) the data part is
``blockdiag(R_f^T diag(M_f) R_f)``: one system per distinct pattern of weights over frames.
"""
import numpy as np
from scipy.linalg import cho_solve_banded, cholesky_banded
from scipy.linalg.lapack import dpbtrf, dpbtrs

HALF_BANDWIDTH = 6     # frame f couples to f +- 2 through D^T D: 3 * 2 rows in (3F) layout


def second_difference_bands(F):
    """Bands ``(3, F)`` of ``D^T D`` (``D: (F-2, F)`` rows ``[1, -2, 1]``): row d holds
    ``(D^T D)[f + d, f]`` at column f (zero past the end)."""
    bands = np.zeros((3, F))
    if F < 3:
        return bands
    w = np.array([1.0, -2.0, 1.0])
    for i in range(3):
        for j in range(i, 3):
            # row r of D touches frames r + i and r + j with weight w[i] w[j]
            bands[j - i, i:F - 2 + i] += w[i] * w[j]
    return bands


#: up to this many frames the S update multiplies by the dense inverse of its (3F, 3F) system
#: (one GEMM, cache-friendly) instead of the banded solve (LAPACK pbtrs, one column at a time):
#: 99 frames x 28,880 points 0.11 s vs 0.27 s CPU per solve, same result to 1e-15; the inverse
#: costs O(F^3) per beta, which stays small up to here, and is only formed for at least 3F
#: points (fewer are solved banded: the inverse would cost more than solving them)
DENSE_MAX_FRAMES = 200


class TemporalSmoothness:
    """Banded solver of the S-update with the smoothness prior.

    ``R: (F, 3, 3)`` world->camera, ``lam``: absolute weight on unit-RMS tracks, ``points``:
    the tracks P of every S update (all blocks together; None: many).
    """

    def __init__(self, R, lam, points=None):
        F = R.shape[0]
        self.F, self.lam = F, float(lam)
        self.dense = F <= DENSE_MAX_FRAMES and (points is None or points >= 3 * F)
        self.R = R
        self.ab = self._bands(np.ones((F, 2)))
        self._beta = None
        self._solve = None
        self._factors = {}              # pattern id -> banded factor at self._beta_weighted
        self._beta_weighted = None
        self._pattern_bands = {}        # pattern id -> its bands without beta

    def _bands(self, m):
        """Lower bands ``(HALF_BANDWIDTH + 1, 3F)`` of the system without beta for the data
        weights ``m: (F, 2)`` of one track: ``A[3f+i, 3f+j] = (R_f^T diag(m_f) R_f)[i, j]``
        (i >= j) plus the prior."""
        F, R = self.F, self.R
        data = np.einsum('fk,fki,fkj->fij', m, R[:, :2, :], R[:, :2, :])
        ab = np.zeros((HALF_BANDWIDTH + 1, 3 * F))
        for i in range(3):
            for j in range(i + 1):
                ab[i - j, 3 * np.arange(F) + j] += data[:, i, j]
        dd = second_difference_bands(F)
        for d in range(3):
            for i in range(3):
                ab[3 * d, 3 * np.arange(F) + i] += self.lam * dd[d]
        return ab

    def _solver_at(self, beta):
        """``solve(b: (3F, P)) -> x: (3F, P)`` for the system at ``beta`` (factored once per
        beta): the dense inverse up to DENSE_MAX_FRAMES frames and from 3F points, else the
        banded Cholesky."""
        if beta != self._beta:
            ab = self.ab.copy()
            ab[0] += beta
            factor = cholesky_banded(ab, lower=True, check_finite=False)
            if self.dense:
                self._solve = cho_solve_banded((factor, True), np.eye(3 * self.F),
                                               check_finite=False).__matmul__
            else:
                def banded(b):
                    return cho_solve_banded((factor, True), b, overwrite_b=True,
                                            check_finite=False)
                self._solve = banded
            self._beta = beta
        return self._solve

    def solve(self, W, rhs_world, beta):
        """S ``(F, 3, P)`` world frame minimising the S-update objective.

        ``W: (F, 2, P)`` unit-RMS centred tracks, ``rhs_world: (F, 3, P)`` = ``beta S# + Y1``.
        """
        F, P = self.F, W.shape[2]
        b = rhs_world + np.matmul(self.R[:, :2, :].transpose(0, 2, 1), W)
        return self._solver_at(beta)(b.reshape(3 * F, P)).reshape(F, 3, P)

    def solve_weighted(self, W, M, rhs_world, beta, ids, patterns):
        """As :meth:`solve` with data weights ``M: (F, 2, n)``: the columns are solved by
        their pattern (``ids: (n,)`` into ``patterns: (k, F, 2)``, the same for every call),
        each pattern's banded system factored once per beta (the all-ones pattern:
        :meth:`solve`'s)."""
        F, n = self.F, W.shape[2]
        b = (rhs_world + np.matmul(self.R[:, :2, :].transpose(0, 2, 1), M * W)).reshape(3 * F, n)
        if beta != self._beta_weighted:
            self._factors, self._beta_weighted = {}, beta
        out = np.empty_like(b)
        order = np.argsort(ids, kind='stable')
        edges = np.flatnonzero(np.diff(ids[order])) + 1
        for cols in np.split(order, edges):
            pid = int(ids[cols[0]])
            if (patterns[pid] == 1.0).all():
                out[:, cols] = self._solver_at(beta)(b[:, cols])
                continue
            if pid not in self._factors:
                if pid not in self._pattern_bands:
                    self._pattern_bands[pid] = self._bands(patterns[pid])
                ab = self._pattern_bands[pid].copy()
                ab[0] += beta
                factor, info = dpbtrf(ab, lower=1)       # LAPACK direct: ~100 us per call less
                if info != 0:
                    raise np.linalg.LinAlgError(f'smoothness system not positive definite '
                                                f'(dpbtrf info {info})')
                self._factors[pid] = factor
            out[:, cols] = dpbtrs(self._factors[pid], b[:, cols], lower=1)[0]
        return out.reshape(F, 3, n)

    def energy(self, S):
        """``(lam/2) ||D S||^2`` for ``S: (F, 3, P)``."""
        if self.F < 3:
            return 0.0
        d2 = S[2:] - 2.0 * S[1:-1] + S[:-2]
        return 0.5 * self.lam * float(np.vdot(d2, d2))


def track_roughness(Wn):
    """Mean squared second difference over frames of ``Wn: (2F, P)`` over its mean square."""
    F = Wn.shape[0] // 2
    X = Wn.reshape(F, 2, -1)
    if F < 3:
        return 1.0
    d2 = X[2:] - 2.0 * X[1:-1] + X[:-2]
    return float(np.mean(d2 ** 2) / max(np.mean(X ** 2), np.finfo(float).tiny))


def smoothness_weight(Wn, relative):
    """Absolute weight ``lam`` of ``(lam/2)||D S||^2`` for a relative one: ``relative`` over
    the roughness of the observed tracks, so that the prior costs ``relative`` times the data
    energy on shapes exactly as rough as the image tracks."""
    return relative / max(track_roughness(Wn), 1e-12)
