"""Record 0716: the perspective face bar on held-back identities; rounds, selectors, updates.

Pinhole sequences 40 x 400 as ``bench.perspective`` builds them (rendered faces of seeds 0-7,
bending sheets 0-2 and waving 0 five units away), normalised tracks of the wired path
(``camera.normalise(camera.project(S, K), K)``). Every e3D (per-frame scale) is printed as a
ratio to the orthographic solve of the same points' orthographic projections.

``rounds``: the iteration as shipped (``nrsfm/perspective.py``) run for ``--rounds`` rounds:
each round's ratio, perspective residual, the solver's fit residual, its inextensible check
(``U``: used, ``n``: not; ratio), and its depths' regression slope / correlation on the true
relative depths; then the outputs of other selectors over the same rounds (lowest residual
over rounds 0-4 = today's output; best round = an oracle; mean / median of the rounds'
depths; the kept round's input depths and the mean of input and output; lowest fit residual;
lowest edge-length variation of the output shapes ``Z (x, y, 1)``).
``warm``: rounds 2-6 warm-started from the previous round's result (``WarmStart(R, S)``, or
``R`` only with ``--warm R``). ``relax``: each round solves on ``(1 - a) delta_in + a
delta_out`` (``--relax 0.5``; ``--start never``: round 0 without the inextensible stage).
``truth``: one solve on the true weak-perspective image
``x (1 + delta_true)`` under inextensible auto / never / always.

    python -m bench.records.r0716 [--what rounds,warm,relax,truth] [--names face_4,face_6]
    python -m bench.records.r0716 --what relax --start never
"""
import argparse
import re

import numpy as np

from bench.perspective import face_shapes, orthographic, sheet_shapes
from grass_nrsfm_ros.frontend.scenes import pinhole
from grass_nrsfm_ros.nrsfm import camera, metrics, perspective as pp
from grass_nrsfm_ros.nrsfm.inextensible import neighbour_edges
from grass_nrsfm_ros.nrsfm.measurement import as_frames
from grass_nrsfm_ros.nrsfm.problem import WarmStart
from grass_nrsfm_ros.nrsfm.solver import _Rounds, GrassmannNRSfM

NAMES = tuple(f'face_{s}' for s in range(8)) + (
    'bending_0', 'bending_1', 'bending_2', 'waving_0')


def sequence(name, F=40, P=400):
    """``(S, x, orthographic e3D)`` of ``name`` ('face_3', 'bending_1', ...)."""
    kind, seed = name.rsplit('_', 1)
    S = face_shapes(F, P, int(seed)) if kind == 'face' else \
        sheet_shapes(kind, F, P, int(seed), 5.0)
    K = pinhole()
    x = camera.normalise(camera.project(S, K), K)
    return S, x, metrics.e3d(GrassmannNRSfM().fit(orthographic(S)).S, S, scale=True)


def ratio(x, delta, S, ortho):
    return metrics.e3d(pp.camera_frame_shapes(x, delta), S, scale=True) / ortho


def true_delta(S):
    Z = as_frames(S, 3)[:, 2]
    return Z / Z.mean(axis=1, keepdims=True) - 1.0


class Chain(_Rounds):
    """The wired chain, logging each solve's inextensible check; ``warm``: None, 'R' or 'RS'
    (rounds from the fourth call on start from the previous call's result)."""

    def __init__(self, warm=None, **params):
        super().__init__(GrassmannNRSfM(projection='orthographic', **params), init=None,
                         progress=None, beta_max=None)
        self.warm, self.previous, self.log = warm, None, []

    def fit(self, W):
        if self.warm and self.previous is not None and len(self.log) >= 3:
            S = self.previous.S if self.warm == 'RS' else None
            self.kwargs = {**self.kwargs, 'init': WarmStart(R=self.previous.R, S=S)}
        result = super().fit(W)
        note = [n for n in result.report.notes if 'inextensible' in n]
        found = re.search(r'ratio ([0-9.]+)', note[0]) if note else None
        self.log.append(('U' if result.report.inextensible else 'n')
                        + (found.group(1) if found else '?'))
        return result


def edge_variation(x, delta, edges):
    """Mean over edges of the relative variation over frames of the output shapes' edge
    lengths, each frame's lengths over their mean (the unknown per-frame scale)."""
    X = as_frames(pp.camera_frame_shapes(x, delta), 3)
    L = np.linalg.norm(X[:, :, edges[0]] - X[:, :, edges[1]], axis=1)
    L = L / L.mean(axis=1, keepdims=True)
    ok = L.mean(axis=0) > 1e-3
    return float(np.mean(L.std(axis=0)[ok] / L.mean(axis=0)[ok]))


def rounds(name, n_rounds):
    S, x, ortho = sequence(name)
    chain = Chain()
    out = pp.PerspectiveNRSfM(chain, max_rounds=n_rounds).fit(x)
    dt = true_delta(S)
    kept = out.rounds
    e = [ratio(x, r.delta, S, ortho) for r in kept]
    cells = [f'{r.index}:{v:.3f} res {r.residual:.2e} fit {r.fit:.4f} slope '
             f'{np.sum(r.delta * dt) / np.sum(dt * dt):.2f}/'
             f'{np.corrcoef(r.delta.ravel(), dt.ravel())[0, 1]:.2f}'
             for r, v in zip(kept, e)]
    print(f'{name}: orthographic {ortho:.4f}; ' + ' | '.join(cells))
    print(f'  checks by solve (round 0, trials +/-, rounds 2-): {" ".join(chain.log)}')
    D = np.stack([r.delta for r in kept])
    today = min(range(min(5, len(kept))), key=lambda k: kept[k].residual)
    inp = D[today - 1] if today else D[0]
    inp = inp * pp.agreeing_signs(inp, D[today])[:, None]
    fit = 1 + min(range(min(4, len(kept) - 1)), key=lambda k: kept[k + 1].fit)
    edges = np.asarray(neighbour_edges(x))
    var = [edge_variation(x, d, edges) for d in D[:5]]
    picks = {'today (lowest residual 0-4)': e[today], 'best round': min(e),
             'mean 1-4': ratio(x, D[1:5].mean(0), S, ortho),
             f'median 1-{len(D) - 1}': ratio(x, np.median(D[1:], 0), S, ortho),
             'kept input': ratio(x, inp, S, ortho),
             'kept (input+output)/2': ratio(x, (inp + D[today]) / 2, S, ortho),
             'lowest fit 1-4': e[fit], 'lowest edge variation 0-4': e[int(np.argmin(var))]}
    print('  ' + ', '.join(f'{k} {v:.3f}' for k, v in picks.items()), flush=True)


def iterate(name, warm=None, relax=1.0, n_rounds=6, start='auto'):
    """Round 0 (inextensible ``start``), round 1's sign trial as shipped, then rounds
    2..n_rounds with a warm start or a relaxed input; prints each round's ratio, the lowest
    residual's over 1-4 / all, and the rounds' inextensible checks."""
    S, x, ortho = sequence(name)
    chain = Chain(warm)
    if start == 'auto':
        delta = pp.centred_depths(chain.fit(x).S)
    else:
        delta = pp.centred_depths(GrassmannNRSfM(inextensible=start).fit(x).S)
        chain.log.append(f'{start} start')
    trials = [pp.PerspectiveNRSfM._round(chain, x, s * delta, 1) for s in (1.0, -1.0)]
    trials.sort(key=lambda t: (not np.isfinite(t[0].change), t[0].fit, t[0].residual))
    record, new, result = trials[0]
    chain.previous = result
    delta = np.sign(np.sum(new * delta)) * delta
    rows = [(record.residual, new)]
    delta = (1.0 - relax) * delta + relax * new
    for k in range(2, n_rounds + 1):
        record, new, result = pp.PerspectiveNRSfM._round(chain, x, delta, k)
        chain.previous = result
        rows.append((record.residual, new))
        delta = (1.0 - relax) * delta + relax * new
    e = [ratio(x, d, S, ortho) for _, d in rows]
    k4 = min(range(4), key=lambda k: rows[k][0])
    kn = min(range(len(rows)), key=lambda k: rows[k][0])
    cells = ' '.join(f'{i + 1}:{v:.3f}/{r:.2e}' for i, (v, (r, _)) in enumerate(zip(e, rows)))
    print(f'{name} warm {warm} relax {relax} start {start}: lowest residual 1-4 {e[k4]:.3f}, '
          f'1-{n_rounds} {e[kn]:.3f}; {cells}; checks {" ".join(chain.log)}', flush=True)


def truth(name):
    S, x, ortho = sequence(name)
    dt = true_delta(S)
    W = pp.weak_perspective_tracks(x, dt)
    cells = []
    for mode in ('auto', 'never', 'always'):
        d = pp.centred_depths(GrassmannNRSfM(inextensible=mode).fit(W).S)
        cells.append(f'{mode} {ratio(x, np.sign(np.sum(d * dt)) * d, S, ortho):.3f}')
    print(f'{name} true weak-perspective image: ' + ', '.join(cells), flush=True)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--what', default='rounds')
    parser.add_argument('--names', default=','.join(NAMES))
    parser.add_argument('--rounds', type=int, default=7)
    parser.add_argument('--warm', default='RS')
    parser.add_argument('--relax', type=float, default=0.5)
    parser.add_argument('--start', default='auto', help="round 0's inextensible setting")
    args = parser.parse_args(argv)
    for what in args.what.split(','):
        for name in args.names.split(','):
            if what == 'rounds':
                rounds(name, args.rounds)
            elif what == 'warm':
                iterate(name, warm=args.warm)
            elif what == 'relax':
                iterate(name, relax=args.relax, start=args.start)
            elif what == 'truth':
                truth(name)


if __name__ == '__main__':
    main()
