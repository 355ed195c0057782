"""Stage 'robust' (robust='cauchy', or 'auto'): tracks a tracker lost hold of (drift, jumps)
weighed down in the data term, before the rotations, so that they do not pull the shapes.
'auto' (the default) looks only at AUTO_MIN_TRACKS tracks or more and weighs down only where
at least AUTO_SHARE of them would be: dense tracks from a drifting tracker, not the one or two
tracks of a clean surface's fine detail (record 0816).

Two residuals per track, each over its seen entries, each with IRLS over ROUNDS rounds
(record 0812): against the affine combination of its nearest tracks not weighed down in the
round before (a drifting track leaves its neighbours, whatever the other tracks span), and
against a rank-DETECT_RANK approximation of the centred tracks ``Wn: (2F, P)`` fitted with the
track weights of the round before (a drifting track leaves the low-rank span of the others,
which the solver's own fit, its shapes deforming per track, would absorb). Weights ``(P,)``: 1
up to ``median + LOCAL_THRESHOLD`` (THRESHOLD for the low rank) robust deviations (1.4826
MAD), ``(threshold / r)^2`` above (Cauchy's tail); the smaller of the two, the low rank's
only where the neighbours' residual corroborates it (above CORROBORATION deviations: a track
that leaves the span but not its neighbours moves with the surface, record 0814). They
multiply the data-term weights of the whole solve (:meth:`Problem.weighted`).
The rotations are then estimated on the tracks no weight touched (:func:`kept_tracks`, read by
:func:`.rotations.core_tracks`, record 0805): Dai's factorisation reads every track it is given,
and a drifting one moves its rank-3K span.
After the solve (:func:`refit`, record 0811) each weighed-down track's 3D trajectory is taken
from its kept neighbours instead of from its own data: a weighed-down track's shape still
follows its data (record 0805), drifted entries included.
Report: ``downweighted_tracks`` (indices), notes; the result's ``track_weights``.
"""
import numpy as np
from scipy.spatial import cKDTree

from ..density import affine_weights, CHUNK, FILL_NEIGHBOURS, nearest
from ..inextensible import trajectory_embedding
from ..measurement import centre, economy_svd

NAME = 'robust'
#: rank of the approximation the residuals are taken against (record 0801)
DETECT_RANK = 6
#: IRLS rounds of the weighted approximation
ROUNDS = 3
#: robust deviations above the median residual from which a track is weighed down
THRESHOLD = 3.0
#: robust deviations above the median residual to the neighbours from which a track is weighed
#: down (record 0812)
LOCAL_THRESHOLD = 8.0
#: robust deviations above the median residual to the neighbours from which the low-rank
#: residual's weight applies (record 0814)
CORROBORATION = 5.0
#: no track is weighed down below this residual (units of the centred, unit-RMS tracks ``Wn``:
#: about 1 px where the surface spans 200 px): noise-free input's rounding, the neighbours'
#: regularisation and a dense surface's fine detail, not drift (records 0812, 0814)
RESIDUAL_FLOOR = 1e-2
#: the rotations read the kept tracks only while they are at least this share of all
KEPT_SHARE = 0.5
#: a weighed-down track's frame is trusted while its residual to its neighbours' combination is
#: at most this many robust deviations of the kept tracks' own residuals (record 0811)
TRUST = 3.0
#: rounds of neighbours and trusted frames
TRUST_ROUNDS = 5
#: kept tracks the residuals' scale is measured on (evenly spaced)
SCALE_SAMPLE = 40
#: Tikhonov regularisation of the neighbours' weights, relative to the trace (record 0811)
NEIGHBOUR_REGULARISATION = 1e-3
#: the final weights are fitted on every frame beside a drift ``sum_l v_l (f / (F - 1))^l``,
#: l = 1..DRIFT_ORDER, one per image axis: zero at the first frame, slow (record 0811)
DRIFT_ORDER = 2
#: 'auto': fewest tracks the weights are looked for on (sparse sets: plain least squares,
#: record 0815)
AUTO_MIN_TRACKS = 200
#: 'auto': the weights apply where at least this share of the tracks is weighed down (record
#: 0816)
AUTO_SHARE = 0.02


def applies(problem, params):
    mode = params['robust']
    return mode != 'never' and problem.P > DETECT_RANK + 1 and (
        mode == 'cauchy' or problem.P >= AUTO_MIN_TRACKS)


def residuals(Wn, weights, seen):
    """Per-track RMS residual ``(P,)`` of ``Wn: (2F, P)`` over its ``seen: (2F, P)`` entries
    against the rank-DETECT_RANK approximation of ``Wn`` with columns weighted by
    ``weights: (P,)``."""
    rank = min(DETECT_RANK, min(Wn.shape) - 1)
    U = economy_svd(Wn * np.sqrt(weights)[None, :])[0][:, :rank]
    resid = Wn - U @ (U.T @ Wn)
    return np.sqrt((seen * resid ** 2).sum(axis=0) / np.maximum(seen.sum(axis=0), 1))


def local_residuals(Wn, candidates, seen, embedding):
    """Per-track RMS residual ``(P,)`` of ``Wn: (2F, P)`` over its ``seen: (2F, P)`` entries
    against the affine combination (:func:`.density.affine_weights`) of its FILL_NEIGHBOURS
    nearest ``candidates: (P,) bool`` in ``embedding: (P, n)``, itself excluded, that
    reproduces it best there (record 0814); zeros where fewer than 3 candidates are left."""
    P = Wn.shape[1]
    pool = np.flatnonzero(candidates)
    k = min(FILL_NEIGHBOURS, pool.size - 1)
    if k < 2:
        return np.zeros(P)
    nbrs = pool[nearest(cKDTree(embedding[pool]), embedding, k + 1)[1]]          # (P, k + 1)
    own = nbrs == np.arange(P)[:, None]
    nbrs = np.take_along_axis(nbrs, np.argsort(own, axis=1, kind='stable'), axis=1)[:, :k]
    X, seen_rows = Wn.T, seen.T
    out = np.empty(P)
    step = max(1, CHUNK // (Wn.shape[0] * k))
    for a in range(0, P, step):
        part = slice(a, a + step)
        # (p, k, 2F) on the track's seen entries only: its unseen ones are the completion's
        diff = (X[nbrs[part]] - X[part, None, :]) * seen_rows[part, None, :]
        resid = np.einsum('pk,pkn->pn', affine_weights(diff), diff)          # combination - x
        out[part] = np.sqrt((seen_rows[part] * resid ** 2).sum(axis=1)
                            / np.maximum(seen_rows[part].sum(axis=1), 1))
    return out


def limit(r, threshold, reference=None):
    """The residual above which ``r: (P,)`` is an outlier: ``threshold`` robust deviations
    above the median (both of ``r[reference]``, ``reference: (P,) bool``; None: all), and
    RESIDUAL_FLOOR at least."""
    base = r if reference is None else r[reference]
    median = np.median(base)
    deviation = 1.4826 * np.median(np.abs(base - median))
    return max(median + threshold * deviation, RESIDUAL_FLOOR)


def cauchy_weights(r, threshold=THRESHOLD, reference=None):
    """Weights ``(P,)`` of the residuals ``r: (P,)``: 1 up to :func:`limit`, then ``(limit /
    r)^2``."""
    top = limit(r, threshold, reference)
    return np.where(r > top, (top / np.maximum(r, top)) ** 2, 1.0)


def track_weights(problem):
    """``(P,)`` weights of the tracks of ``problem``: the smaller of :func:`neighbour_weights`
    and, where the neighbours' residual is above CORROBORATION deviations, of
    :func:`low_rank_weights`."""
    weights, corroborated = neighbour_weights(problem)
    if not corroborated.any():
        return weights
    return np.minimum(weights, np.where(corroborated, low_rank_weights(problem), 1.0))


def low_rank_weights(problem):
    """``(P,)`` weights of the tracks of ``problem`` by IRLS on :func:`residuals`."""
    seen = _seen(problem)
    weights = np.ones(problem.P)
    for _ in range(ROUNDS):
        weights = cauchy_weights(residuals(problem.Wn, weights, seen))
    return weights


def neighbour_weights(problem):
    """``(weights: (P,), corroborated: (P,) bool)`` of the tracks of ``problem`` by IRLS on
    :func:`local_residuals` (the candidate neighbours and the median's reference: the tracks
    the round before left at 1); ``corroborated``: the last round's residual above
    CORROBORATION deviations."""
    seen, embedding = _seen(problem), trajectory_embedding(problem.Wn)
    weights = np.ones(problem.P)
    for _ in range(ROUNDS):
        kept = weights >= 1.0
        r = local_residuals(problem.Wn, kept, seen, embedding)
        weights = cauchy_weights(r, LOCAL_THRESHOLD, kept)
        if np.array_equal(weights >= 1.0, kept):        # the next round would repeat this one
            break
    return weights, r > limit(r, CORROBORATION, kept)


def _seen(problem):
    """``(2F, P)`` bool: the entries of ``problem`` its data term sees."""
    return np.ones_like(problem.Wn, dtype=bool) if problem.weights is None \
        else problem.weights > 0


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
    """``(problem weighted, weights: (P,))``, or ``(problem, None)`` where 'auto' finds fewer
    than AUTO_SHARE of the tracks to weigh down (a note says so); fills the report's fields."""
    weights = track_weights(problem)
    down = np.flatnonzero(weights < 1.0)
    if params['robust'] == 'auto' and down.size < AUTO_SHARE * problem.P:
        report.notes.append(f"robust ('auto'): {down.size} of {problem.P} tracks would be "
                            f'weighed down, fewer than {AUTO_SHARE:.0%}: plain least squares')
        return problem, None
    report.stages.append(NAME)
    report.downweighted_tracks = down.tolist()
    report.notes.append(f'robust ({params["robust"]}): {down.size} of {problem.P} tracks '
                        f'weighed down (smallest weight {weights.min():.3g})')
    if down.size == 0:
        return problem, weights
    return problem.weighted(weights), weights


def neighbours(Wc, keep, track, rows):
    """``(nbrs: (k,) indices into P, weights: (k,) summing to 1)``: the FILL_NEIGHBOURS columns
    of ``keep: (P',)`` nearest to column ``track`` of ``Wc: (2F, P)`` over ``rows: (2F,)`` bool,
    and the weights whose combination of them reproduces it there best
    (:func:`.density.affine_weights`, NEIGHBOUR_REGULARISATION)."""
    X, x = Wc[rows][:, keep], Wc[rows, track]
    k = min(FILL_NEIGHBOURS, keep.size)
    near = np.argpartition(((X - x[:, None]) ** 2).sum(axis=0), k - 1)[:k]
    diff = (X[:, near] - x[:, None]).T[None]                          # (1, k, rows)
    return keep[near], affine_weights(diff, NEIGHBOUR_REGULARISATION)[0]


def drift_weights(Wc, nbrs, track):
    """``(k,)`` weights summing to 1: the combination of the columns ``nbrs: (k,)`` of ``Wc: (2F,
    P)`` that, beside a drift of DRIFT_ORDER (powers of time, zero at the first frame, each image
    axis its own coefficients), reproduces column ``track`` over every frame best
    (NEIGHBOUR_REGULARISATION on the weights; the equality by its Lagrange multiplier)."""
    F, k = Wc.shape[0] // 2, nbrs.size
    time = (np.arange(F) / max(F - 1, 1))[:, None] ** np.arange(1, DRIFT_ORDER + 1)   # (F, L)
    drift = np.zeros((2 * F, 2 * DRIFT_ORDER))
    drift[0::2, :DRIFT_ORDER], drift[1::2, DRIFT_ORDER:] = time, time
    M = np.hstack([Wc[:, nbrs], drift])
    diff = Wc[:, nbrs] - Wc[:, [track]]
    A = M.T @ M
    A[:k, :k] += (NEIGHBOUR_REGULARISATION * np.trace(diff.T @ diff) + 1e-12) * np.eye(k)
    ones = np.r_[np.ones(k), np.zeros(2 * DRIFT_ORDER)]
    kkt = np.block([[A, ones[:, None]], [ones[None], np.zeros((1, 1))]])
    return np.linalg.solve(kkt, np.r_[M.T @ Wc[:, track], 1.0])[:k]


def refit(S, W, weights, report=None):
    """``S: (3F, P)`` with the columns of the weighed-down tracks (``weights: (P,)`` below 1)
    replaced by a combination of their kept neighbours' columns (record 0811). The neighbours
    (:func:`neighbours`): those that reproduce the track's image trajectory in ``W: (2F, P)``
    (complete: unseen entries completed) over its trusted frames, those whose distance from
    the combination is within TRUST robust deviations of the kept tracks' own (measured on
    SCALE_SAMPLE kept tracks against their other kept neighbours); trusted frames and
    neighbours alternated up to TRUST_ROUNDS times, from every frame. Their weights
    (:func:`drift_weights`): fitted on every frame beside a slow drift that starts at zero.
    A track with every frame trusted keeps its column. A drift late in a track leaves its
    early frames trusted, and its 3D follows its neighbours rather than the drifted data.
    ``S`` itself with no more than 2 SCALE_SAMPLE kept tracks. ``report``: a note with the
    tracks replaced and their trusted frames."""
    down = np.flatnonzero(weights < 1.0)
    keep = np.flatnonzero(weights >= 1.0)
    F = W.shape[0] // 2
    if down.size == 0 or keep.size <= 2 * SCALE_SAMPLE:
        return S
    Wc = centre(W)[0]
    every = np.ones(2 * F, dtype=bool)

    def distances(track, nbrs, w):
        return np.linalg.norm((Wc[:, track] - Wc[:, nbrs] @ w).reshape(F, 2), axis=1)

    sample = keep[np.linspace(0, keep.size - 1, SCALE_SAMPLE).round().astype(int)]
    others = np.setdiff1d(keep, sample)
    own = np.concatenate([distances(j, *neighbours(Wc, others, j, every)) for j in sample])
    threshold = TRUST * 1.4826 * np.median(own)
    out, trusted_frames = S.copy(), []
    for track in down:
        trusted = np.ones(F, dtype=bool)
        for _ in range(TRUST_ROUNDS):
            nbrs, w = neighbours(Wc, keep, track, np.repeat(trusted, 2))
            r = distances(track, nbrs, w)
            again = r <= max(threshold, np.sort(r)[min(2, F - 1)])
            if np.array_equal(again, trusted):
                break
            trusted = again
        trusted_frames.append(int(trusted.sum()))
        if not trusted.all():
            out[:, track] = S[:, nbrs] @ drift_weights(Wc, nbrs, track)
    if report is not None:
        trusted_frames = np.array(trusted_frames)
        moved = trusted_frames[trusted_frames < F]
        report.notes.append(f"robust: {moved.size} of the {down.size} weighed-down tracks' 3D "
                            'from their kept neighbours' + (
                                f' (trusted frames: median {np.median(moved):.0f} of {F}, '
                                f'fewest {moved.min()})' if moved.size else ''))
    return out
