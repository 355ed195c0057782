"""Record 0818: completion by alternating least squares, its rank chosen on held-out blocks.

    python -m bench.records.r0818 [--kinds bending,...] [--seed 3]

``bench.missing``'s occlusion rows (60 x 400, 1 px noise, 20 % of the entries unseen in
occlusion blocks): the unseen entries' error (relative to their centred truth) of the shipped
completion (:func:`.missing.complete`, the model chosen on held-out runs of single tracks) and
of :func:`als_fill` at ranks 2-8, each model's error on held-out *blocks* of seen entries
(:func:`block_held_out`: ``synthetic.occlusion_mask``'s blocks, 5 % of the entries), the model
those blocks choose, and the e3D of the masked solve given that completion (``fit(W,
filled=)``) over the complete solve's.
"""
import argparse

import numpy as np

from grass_nrsfm_ros.nrsfm import e3d, GrassmannNRSfM, synthetic
from grass_nrsfm_ros.nrsfm.missing import _impute, complete, COMPLETION_MODELS

RANKS = (2, 3, 4, 5, 6, 8)
#: ridge on both factors, relative to the largest singular value of the start
RIDGE = 1e-3


def als_fill(W, observed, rank, ridge=RIDGE, sweeps=200, tol=1e-6):
    """``W: (2F, P)`` with the entries not ``observed: (2F, P)`` filled by ``t 1^T + U V^T``
    (``U: (2F, rank)``, ``V: (P, rank)``, ``t`` the row translation) fitted to the observed
    entries by alternating ridge least squares, from the SVD of the row-mean filled W."""
    R, P = W.shape
    o = observed.astype(float)
    X = np.where(observed, W, 0.0)
    start = np.where(observed, W, X.sum(1, keepdims=True) / np.maximum(o.sum(1, keepdims=True), 1))
    Us, d, _ = np.linalg.svd(start - start.mean(1, keepdims=True), full_matrices=False)
    reg = ridge * d[0]
    U, t = Us[:, :rank] * np.sqrt(d[:rank]), start.mean(1)
    penalty = np.diag(np.r_[np.ones(rank), 0.0])
    low, previous = start, None
    for _ in range(sweeps):
        G = np.einsum('rp,ri,rj->pij', o, U, U) + reg * np.eye(rank)
        V = np.linalg.solve(G, (U.T @ ((X - t[:, None]) * o)).T[..., None])[..., 0]
        Va = np.column_stack([V, np.ones(P)])
        G = np.einsum('rp,pi,pj->rij', o, Va, Va) + reg * penalty
        Ua = np.linalg.solve(G, ((X * o) @ Va)[..., None])[..., 0]
        U, t = Ua[:, :rank], Ua[:, rank]
        low = U @ V.T + t[:, None]
        filled = low[~observed]
        if previous is not None and np.linalg.norm(filled - previous) <= tol * max(
                np.linalg.norm(filled), 1e-300):
            break
        previous = filled
    return np.where(observed, W, low)


def block_held_out(filled, seen, rng, share=0.05):
    """``(F, P)`` bool: the ``seen: (F, P)`` entries of :func:`synthetic.occlusion_mask`'s
    blocks hiding ``share`` of the entries of ``filled: (2F, P)`` (the tracks completed, for
    their frame-0 neighbourhoods), less the tracks that would keep under 2 seen frames and
    the frames that would keep under 4 seen tracks."""
    held = seen & ~synthetic.occlusion_mask(filled, share, rng)
    held &= ((seen & ~held).sum(axis=0) >= 2)[None, :]
    held &= ((seen & ~held).sum(axis=1) >= 4)[:, None]
    return held


def fill(W, observed, model):
    return als_fill(W, observed, model[1]) if model[0] == 'als' else _impute(W, observed, model)


def row(kind, seed):
    seq = synthetic.make_sequence(kind, n_frames=60, n_points=400, noise=0.005, seed=seed)
    visible = synthetic.occlusion_mask(seq.W, 0.2, np.random.default_rng(seed + 100))
    observed = np.repeat(visible, 2, axis=0)
    W = np.where(observed, seq.W, 0.0)
    unseen = ~observed
    scale = np.linalg.norm((seq.W - seq.W.mean(1, keepdims=True))[unseen])
    error = lambda X: np.linalg.norm((X - seq.W)[unseen]) / scale       # noqa: E731
    shipped, shipped_model = complete(W, visible)
    held = block_held_out(shipped, visible, np.random.default_rng(0))
    train, test = np.repeat(visible & ~held, 2, axis=0), np.repeat(held, 2, axis=0)
    models = list(COMPLETION_MODELS) + [('als', r) for r in RANKS]
    held_error = [np.linalg.norm((fill(W, train, m) - W)[test]) for m in models]
    chosen = models[int(np.argmin(held_error))]
    filled = fill(W, observed, chosen)
    complete_e3d = e3d(GrassmannNRSfM().fit(seq.W).S, seq.S)
    masked = GrassmannNRSfM().fit(np.where(observed, seq.W, np.nan))
    given = GrassmannNRSfM().fit(np.where(observed, seq.W, np.nan), filled=filled)
    errors = ', '.join(f'{m[0]} {m[1]:g}: {error(fill(W, observed, m)):.3f} (held out '
                       f'{h / held_error[0]:.2f})' for m, h in zip(models, held_error))
    print(f'{kind} s{seed}: shipped completion {shipped_model} {error(shipped):.3f}; blocks '
          f'choose {chosen[0]} {chosen[1]:g} {error(filled):.3f}; e3D / complete: shipped '
          f'{e3d(masked.S, seq.S) / complete_e3d:.3f}, given the chosen completion '
          f'{e3d(given.S, seq.S) / complete_e3d:.3f}\n  unseen error per model (held-out '
          f'blocks relative to rank 3): {errors}', flush=True)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--kinds', default=','.join(synthetic.kinds()))
    parser.add_argument('--seed', type=int, default=3)
    args = parser.parse_args(argv)
    for kind in args.kinds.split(','):
        row(kind, args.seed)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
