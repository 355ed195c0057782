"""Tracks with missing entries: the observation mask, its checks and a low-rank completion.

Shapes: ``W: (2F, P)`` tracks with NaN where a track is not seen, ``visible: (F, P)`` bool (True:
observed), ``weights: (2F, P)`` the data term's per-entry weights in [0, 1] (0: not seen).

* :func:`observation_mask`: ``(W, visible)`` -> ``(W, mask: (F, P) or None)``; None when every
  entry is seen (the complete path, unchanged);
* :func:`check_mask`: what a masked solve needs (every frame and every track seen often enough),
  or InvalidInputError naming the first frame or track that breaks it;
* :func:`fill_unseen`: ``W`` (NaN unseen) -> ``(filled, seen, model)``, :func:`complete` on
  its mask (computed once per window: the mapper hands it to the solver);
* :func:`complete`: the unseen entries of W filled by an iterative rank-r SVD imputation
  (hard impute) of ``W - t 1^T`` (t: the per-row translation, re-estimated every sweep), the
  rank chosen on held-out observed entries. Dai's rotations, the initial shapes and the stages
  read the completed tracks; the ADMM's data term sees only the observed ones
  (docs/decisions/0800).
"""
import numpy as np

from .measurement import economy_svd, InvalidInputError, validate_tracks

#: a masked solve needs each track seen in at least this many frames ...
MIN_TRACK_FRAMES = 2
#: ... and each frame to see at least this many tracks
MIN_FRAME_TRACKS = 4
#: hard impute: sweeps at most, and the relative change of the filled entries that stops it
COMPLETION_SWEEPS = 100
COMPLETION_TOL = 1e-6
#: candidate completions: hard impute at rank 3K (the rotation ranks K = 1, 2) and soft
#: impute at shrinkages relative to the largest singular value; the share of the tracks with a
#: run of frames held out to choose among them
COMPLETION_MODELS = (('rank', 3), ('rank', 6), ('soft', 0.03), ('soft', 0.01), ('soft', 0.003))
HOLD_OUT = 0.05
#: the rank is chosen on at most this many tracks (a fixed random subset)
CHOICE_TRACKS = 2000


def observation_mask(W, visible=None, name='W'):
    """``(W: (2F, P) float64, mask: (F, P) bool or None)``: an entry is observed where
    ``visible`` (when given) is True and both its u and v are finite; ``mask`` is None when
    every entry is observed (and W is then checked as complete tracks are). Raises
    InvalidInputError on a malformed W or visible."""
    W = np.asarray(W)
    if W.ndim != 2 or W.dtype.kind not in 'fiu' or W.shape[0] % 2 or W.shape[0] == 0:
        return validate_tracks(W, min_frames=1, min_points=1, name=name), None
    W = W.astype(np.float64, copy=False)
    F, P = W.shape[0] // 2, W.shape[1]
    seen = np.isfinite(W).reshape(F, 2, P).all(axis=1)
    if visible is not None:
        visible = np.asarray(visible)
        if visible.shape != (F, P) or visible.dtype != bool:
            raise InvalidInputError(f'visible must be a ({F}, {P}) bool array; got '
                                    f'{visible.shape} {visible.dtype}')
        seen &= visible
    return W, (None if seen.all() else seen)


def check_mask(mask, min_frames=3, min_points=4):
    """Raise InvalidInputError unless ``mask: (F, P)`` has ``min_frames`` frames and
    ``min_points`` tracks, every frame sees MIN_FRAME_TRACKS tracks and every track is seen in
    MIN_TRACK_FRAMES frames."""
    F, P = mask.shape
    if F < min_frames:
        raise InvalidInputError(f'W has {F} frames; at least {min_frames} needed')
    if P < min_points:
        raise InvalidInputError(f'W has {P} points; at least {min_points} needed')
    per_frame, per_track = mask.sum(axis=1), mask.sum(axis=0)
    if not mask.any():
        raise InvalidInputError('W has no observed entry (every entry non-finite or not '
                                'visible)')
    if (per_frame < MIN_FRAME_TRACKS).any():
        f = int(np.argmax(per_frame < MIN_FRAME_TRACKS))
        raise InvalidInputError(
            f'frame {f} sees {int(per_frame[f])} tracks (the others non-finite or not '
            f'visible); a masked solve needs at least {MIN_FRAME_TRACKS} in every frame '
            f'({int((per_frame < MIN_FRAME_TRACKS).sum())} frames fewer): leave those frames '
            'out')
    if (per_track < MIN_TRACK_FRAMES).any():
        j = int(np.argmax(per_track < MIN_TRACK_FRAMES))
        raise InvalidInputError(
            f'track {j} is seen in {int(per_track[j])} frames; a masked solve needs every '
            f'track seen in at least {MIN_TRACK_FRAMES} '
            f'({int((per_track < MIN_TRACK_FRAMES).sum())} tracks fewer): leave those tracks '
            'out')


def entry_weights(mask):
    """``(2F, P)`` float64 data-term weights of ``mask: (F, P)`` (1 observed, 0 not)."""
    return np.repeat(mask, 2, axis=0).astype(np.float64)


def _impute(W, observed, model, sweeps=COMPLETION_SWEEPS, tol=COMPLETION_TOL):
    """``W: (2F, P)`` (any values where not ``observed: (2F, P)``) with its unseen entries
    replaced by those of a low-rank model of ``W - t 1^T`` (t the row means), alternated from
    the rows' observed means until the filled entries change by less than ``tol`` (relative).
    ``model``: ``('rank', r)`` hard impute, the rank-r truncation (its column space followed
    by one warm-started subspace iteration per sweep, ``O(F P r)``), or ``('soft', s)`` soft
    impute (Mazumder et al. 2010), the singular values shrunk by s times the first sweep's
    largest."""
    X = np.array(W, dtype=np.float64)
    unseen = ~observed
    counts = observed.sum(axis=1, keepdims=True)
    start = np.where(observed, X, 0.0).sum(axis=1, keepdims=True) / np.maximum(counts, 1)
    X[unseen] = np.broadcast_to(start, X.shape)[unseen]
    kind, value = model
    U, d, _ = economy_svd(X - X.mean(axis=1, keepdims=True))
    Q, tau = (U[:, :value], None) if kind == 'rank' else (None, value * d[0])
    for _ in range(sweeps):
        t = X.mean(axis=1, keepdims=True)
        Xc = X - t
        if kind == 'rank':
            Q = np.linalg.qr(Xc @ (Xc.T @ Q))[0]
            low = Q @ (Q.T @ Xc) + t
        else:
            U, d, Vt = economy_svd(Xc)
            low = (U * np.maximum(d - tau, 0.0)) @ Vt + t
        change = np.linalg.norm(low[unseen] - X[unseen])
        X[unseen] = low[unseen]
        if change <= tol * max(np.linalg.norm(X[unseen]), 1e-300):
            break
    return X


def held_out_runs(frame_obs, rng):
    """``held: (F, P')`` bool: for a HOLD_OUT share of the tracks of ``frame_obs: (F, P')``, a
    contiguous run of a fifth of the frames (where seen) held out, like an occlusion; a track
    keeps at least MIN_TRACK_FRAMES frames and a frame MIN_FRAME_TRACKS tracks."""
    F, P = frame_obs.shape
    length = max(1, F // 5)
    tracks = rng.random(P) < max(HOLD_OUT * 2, 2.0 / P)
    start = rng.integers(0, F - length + 1, P)
    frames = np.arange(F)[:, None]
    held = frame_obs & tracks & (frames >= start) & (frames < start + length)
    held &= (frame_obs & ~held).sum(axis=0, keepdims=True) >= MIN_TRACK_FRAMES
    held &= (frame_obs & ~held).sum(axis=1, keepdims=True) >= MIN_FRAME_TRACKS
    return held


def completion_model(W, observed, random_state=0):
    """The model of :data:`COMPLETION_MODELS` whose completion best predicts held-out runs of
    observed entries of ``W: (2F, P)`` (``observed: (2F, P)``; :func:`held_out_runs`), on at
    most CHOICE_TRACKS tracks."""
    rng = np.random.default_rng(random_state)
    P = W.shape[1]
    cols = np.sort(rng.choice(P, CHOICE_TRACKS, replace=False)) if P > CHOICE_TRACKS \
        else np.arange(P)
    Ws, obs = W[:, cols], observed[:, cols]
    F = Ws.shape[0] // 2
    frame_obs = obs[0::2]
    held = held_out_runs(frame_obs, rng)
    train = np.repeat(frame_obs & ~held, 2, axis=0)
    test = np.repeat(held, 2, axis=0)
    models = [m for m in COMPLETION_MODELS if m[0] == 'soft' or m[1] < min(2 * F, Ws.shape[1])]
    if not test.any():
        return models[0]
    errors = [np.linalg.norm((_impute(Ws, train, m) - Ws)[test]) for m in models]
    return models[int(np.argmin(errors))]


def fill_unseen(W, visible=None, random_state=0):
    """``(filled: (2F, P) float64, seen: (F, P) bool, model: str or None)``: ``W`` (NaN where
    not seen; ``visible: (F, P)`` marks more unseen entries) with its unseen entries completed
    by :func:`complete`; ``W`` itself, every entry seen and model None when complete. The one
    completion of a window: the mapper hands it to the solver (``fit(W, filled=)``)."""
    W, mask = observation_mask(W, visible)
    if mask is None:
        return W, np.ones((W.shape[0] // 2, W.shape[1]), dtype=bool), None
    filled, model = complete(W, mask, random_state)
    return filled, mask, model


def complete(W, mask, random_state=0):
    """``(W_filled: (2F, P), model)``: ``W`` with the entries not seen in ``mask: (F, P)``
    filled by :func:`_impute` with the model :func:`completion_model` chooses (as text, e.g.
    'rank 3', 'soft 0.01'); what ``W`` holds at those entries (NaN, anything) is not read."""
    observed = np.repeat(mask, 2, axis=0)
    W = np.where(observed, W, 0.0)
    model = completion_model(W, observed, random_state)
    return _impute(W, observed, model), f'{model[0]} {model[1]:g}'
