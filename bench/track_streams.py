"""Live windows on track streams whose tracks die and are born: the live pipeline (shipped
solver) over synthetic surfaces seen by a tracker that loses each track with a fixed hazard
and starts it again, after a gap, under a new id (the way an image tracker's tracks come and
go), against the ground truth of every published entry.

    python -m bench.track_streams [--smoke] [--shares 1.0,0.8,0.6] [--context 0.5]
        [--unseen free,filled] [--refill 0,1] [--core 0.5,inf] [--seeds 0,1]

Per setting of the window's track share (windowing.WINDOW_TRACK_SHARE: a window is solved on
the tracks seen in that share of its frames; 1.0 is the old rule, tracks common to all), the
context share (mapper.CONTEXT_TRACKS), the data term of unseen entries ('free', shipped: left
out; 'filled': the completion taken as seen, bench.records.r0802), the refill rounds after
each masked window solve (mapper.WINDOW_REFILL_ROUNDS) and the share of complete
tracks the rotations are estimated on (stages.rotations.CORE_SHARE, inf: every track
completed), per stream seed: ``points/refined`` e3D over the entries it
publishes, and its coverage (the share of each frame's tracks that it publishes: a track not
in a window's solve is not refined). Results: bench/results/track_streams.json.
"""
import argparse
import sys
import time

import numpy as np

from grass_nrsfm_ros import mapper, windowing
from grass_nrsfm_ros.nrsfm import problem as solver_problem
from grass_nrsfm_ros.nrsfm.metrics import e3d
from grass_nrsfm_ros.nrsfm.stages import rotations
from grass_nrsfm_ros.pipeline import make_pipeline, reconstruct_live
from . import common
from .records.r0802 import unseen_weights

#: per frame, the chance that a track dies; it comes back after GAP frames under a new id
HAZARD = 0.01
GAP = (5, 30)


def track_stream(W, rng, hazard=HAZARD, gap=GAP):
    """``(frames, points)``: per frame of ``W: (2F, P)`` the ``(ids, uv: (P_f, 2))`` a tracker
    with these deaths and births gives, and ``points: {id: surface point}``."""
    F, P = W.shape[0] // 2, W.shape[1]
    ids = np.arange(P)
    back_at = np.full(P, -1)                # frame where a dead track's point is tracked again
    next_id, points, frames = P, dict(enumerate(range(P))), []
    for f in range(F):
        alive = back_at < 0
        reborn = back_at == f
        ids[reborn] = np.arange(next_id, next_id + reborn.sum())
        points.update(zip(ids[reborn].tolist(), np.flatnonzero(reborn).tolist()))
        next_id += int(reborn.sum())
        back_at[reborn] = -1
        alive |= reborn
        dying = alive & (rng.random(P) < hazard) & (f > 0)
        back_at[dying] = f + rng.integers(*gap, size=int(dying.sum()))
        alive &= ~dying
        frames.append((ids[alive].astype(np.uint32), W[2 * f:2 * f + 2, alive].T))
    return frames, points


def evaluate(refined, S, points):
    """``(e3D, coverage)`` of the refined FrameResults against ``S: (3F, P)``."""
    F, P = S.shape[0] // 3, S.shape[1]
    est, seen = np.zeros((3 * F, P)), np.zeros((F, P), dtype=bool)
    for f, r in enumerate(refined):
        cols = np.array([points[int(i)] for i in r.ids], dtype=int)
        est[3 * f:3 * f + 3, cols] = r.xyz.T
        seen[f, cols] = True
    return float(e3d(est, S, visible=seen)), seen


def run_one(name, S, frames, points, share, context, seed, unseen='free', core=None,
            refill=None):
    """Figures of one setting on the sequence ``name`` (truth ``S: (3F, P)``)."""
    windowing.WINDOW_TRACK_SHARE, mapper.CONTEXT_TRACKS = share, context
    mapper.WINDOW_REFILL_ROUNDS = mapper.WINDOW_REFILL_ROUNDS if refill is None else refill
    solver_problem.entry_weights = unseen_weights(unseen)
    rotations.CORE_SHARE = rotations.CORE_SHARE if core is None else core
    pipeline = make_pipeline({'refined_from': 'last_window'})
    stamps = np.arange(len(frames), dtype=np.int64) * 33_000_000
    start = time.process_time()
    _, refined, _ = reconstruct_live(pipeline, stamps, frames, 'cam')
    cpu = time.process_time() - start
    error, seen = evaluate(refined, S, points)
    tracked = sum(ids.size for ids, _ in frames)
    return dict(sequence=name, share=share, context=context, seed=seed, e3d=error,
                unseen=unseen, refill=mapper.WINDOW_REFILL_ROUNDS,
                core_share=rotations.CORE_SHARE if np.isfinite(rotations.CORE_SHARE) else 'inf',
                coverage=float(seen.sum() / tracked), frames_published=len(refined),
                cpu_seconds=cpu)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--smoke', action='store_true', help='one short sequence')
    parser.add_argument('--shares', default='1.0,0.8,0.6')
    parser.add_argument('--context', default='0.9,0.5')
    parser.add_argument('--unseen', default='free',
                        help="the data terms of unseen entries: 'free' (shipped), 'filled'")
    parser.add_argument('--refill', default=str(mapper.WINDOW_REFILL_ROUNDS),
                        help='refill rounds after each masked solve')
    parser.add_argument('--core', default=str(rotations.CORE_SHARE),
                        help='shares of complete tracks for the rotations (inf: never the core)')
    parser.add_argument('--seeds', default='0', help='track stream seeds')
    args = parser.parse_args(argv)
    mode = common.Mode('smoke' if args.smoke else 'quick')
    kinds = mode.pick(['bending'], ['bending', 'waving', 'articulated'], None)
    F, P = mode.pick((40, 150), (90, 400), None)
    shipped = (windowing.WINDOW_TRACK_SHARE, mapper.CONTEXT_TRACKS, solver_problem.entry_weights,
               rotations.CORE_SHARE, mapper.WINDOW_REFILL_ROUNDS)
    settings = [(float(share), float(context), unseen, float(core), int(refill))
                for share in args.shares.split(',') for context in args.context.split(',')
                for unseen in args.unseen.split(',') for core in args.core.split(',')
                for refill in args.refill.split(',')]
    rows = []
    try:
        for kind in kinds:
            W, S = common.synthetic(kind, F, P, noise=0.002)
            for seed in (int(s) for s in args.seeds.split(',')):
                frames, points = track_stream(W, np.random.default_rng(seed))
                for share, context, unseen, core, refill in settings:
                    row = run_one(kind, S, frames, points, share, context, seed, unseen, core,
                                  refill)
                    rows.append(row)
                    common.log(f'{kind} seed {seed}: share {share} context {context} unseen '
                               f'{unseen} refill {refill} core {core}: refined e3D '
                               f'{row["e3d"]:.4f}, coverage '
                               f"{row['coverage']:.3f}, {row['cpu_seconds']:.0f} CPU s")
    finally:
        (windowing.WINDOW_TRACK_SHARE, mapper.CONTEXT_TRACKS, solver_problem.entry_weights,
         rotations.CORE_SHARE, mapper.WINDOW_REFILL_ROUNDS) = shipped
    path = common.write_result(mode, 'track_streams', {
        'rows': rows, 'hazard': HAZARD, 'gap': list(GAP), 'F': F, 'P': P,
        'shipped': {'share': shipped[0], 'context': shipped[1], 'unseen': 'free',
                    'core_share': shipped[3], 'refill': shipped[4]}})
    common.log(f'written {path}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
