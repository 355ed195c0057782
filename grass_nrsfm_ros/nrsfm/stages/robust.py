"""Stage 'robust' (robust='cauchy'): tracks a tracker lost hold of (drift, jumps) weighed down
in the data term, before the rotations, so that they do not pull the shapes.

Each track's RMS residual (over its seen entries) against a rank-DETECT_RANK approximation of
the centred tracks ``Wn: (2F, P)``, fitted with the track weights of the round before (IRLS,
ROUNDS rounds): a drifting track leaves the low-rank span of the others, which the solver's
own fit (its shapes may deform per track) would absorb. Weights ``(P,)``: 1 up to
``median + THRESHOLD`` robust deviations (1.4826 MAD), ``(threshold / r)^2`` above (Cauchy's
tail). They multiply the data-term weights of the whole solve (:meth:`Problem.weighted`).
The rotations are then estimated on the tracks no weight touched (:func:`kept_tracks`, read by
:func:`.rotations.core_tracks`, record 0805): Dai's factorisation reads every track it is given,
and a drifting one moves its rank-3K span.
Report: ``downweighted_tracks`` (indices), a note; the result's ``track_weights``.
"""
import numpy as np

from ..measurement import economy_svd

NAME = 'robust'
#: rank of the approximation the residuals are taken against (record 0801)
DETECT_RANK = 6
#: IRLS rounds of the weighted approximation
ROUNDS = 3
#: robust deviations above the median residual from which a track is weighed down
THRESHOLD = 3.0
#: the rotations read the kept tracks only while they are at least this share of all
KEPT_SHARE = 0.5


def applies(problem, params):
    return params['robust'] != 'never' and problem.P > DETECT_RANK + 1


def residuals(Wn, weights, seen):
    """Per-track RMS residual ``(P,)`` of ``Wn: (2F, P)`` over its ``seen: (2F, P)`` entries
    against the rank-DETECT_RANK approximation of ``Wn`` with columns weighted by
    ``weights: (P,)``."""
    rank = min(DETECT_RANK, min(Wn.shape) - 1)
    U = economy_svd(Wn * np.sqrt(weights)[None, :])[0][:, :rank]
    resid = Wn - U @ (U.T @ Wn)
    return np.sqrt((seen * resid ** 2).sum(axis=0) / np.maximum(seen.sum(axis=0), 1))


def cauchy_weights(r):
    """Weights ``(P,)`` of the residuals ``r: (P,)``: 1 up to the threshold, then
    ``(threshold / r)^2``."""
    median = np.median(r)
    deviation = 1.4826 * np.median(np.abs(r - median))
    threshold = median + THRESHOLD * max(deviation, 1e-12 * max(median, 1e-300))
    return np.where(r > threshold, (threshold / np.maximum(r, 1e-300)) ** 2, 1.0)


def track_weights(problem):
    """``(P,)`` weights of the tracks of ``problem`` (IRLS on :func:`residuals`)."""
    seen = np.ones_like(problem.Wn) if problem.weights is None else problem.weights > 0
    weights = np.ones(problem.P)
    for _ in range(ROUNDS):
        weights = cauchy_weights(residuals(problem.Wn, weights, seen))
    return weights


def kept_tracks(problem):
    """``(P,)`` bool: the tracks of ``problem`` whose seen entries all weigh 1 (no robust
    weight touched them); None where none was touched, or where fewer than KEPT_SHARE of the
    tracks are kept (then every track)."""
    weights = problem.weights
    if weights is None:
        return None
    seen = np.repeat(problem.mask, 2, axis=0) if problem.mask is not None else weights > 0
    kept = ~(seen & (weights < 1)).any(axis=0)
    if kept.all() or kept.sum() < KEPT_SHARE * kept.size:
        return None
    return kept


def run(problem, params, report):
    """``(problem weighted, weights: (P,))``; fills the report's fields."""
    weights = track_weights(problem)
    down = np.flatnonzero(weights < 1.0)
    report.downweighted_tracks = down.tolist()
    report.notes.append(f'robust ({params["robust"]}): {down.size} of {problem.P} tracks '
                        f'weighed down (smallest weight {weights.min():.3g})')
    if down.size == 0:
        return problem, weights
    return problem.weighted(weights), weights
