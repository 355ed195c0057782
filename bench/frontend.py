"""Front end: dense tracks from rendered image sequences against their ground truth.

``python -m bench.frontend [--smoke] [--frames F] [--methods M1,M2] [--step N]
[--options JSON] [--seeds S1,S2]`` renders a Surrey-model face (where the model is present)
and a bending sheet (640 x 480, f = 620 px, 100 frames, sensor noise 1 grey level, 30 %
Lambert shading; ``--seeds``: the face and sheet of each of those seeds, other identities,
expressions, textures and head turns, measured without the timing),
tracks them with :class:`grass_nrsfm_ros.frontend.DenseTracker` (region: the frame-0 mask of
the surface; ``--options``: its keyword arguments) and measures, per sequence and method:

* tracking error against the true projection of the surface point each track was born on,
  over every (frame, track) pair where the point is visible: median / p95 / max px;
* the share of frame-0 tracks alive in the last frame among those visible there (and among
  those visible in every frame, and among those visible and seen within ``FACING_DEGREES``
  of face-on in every frame); tracks alive while their point is hidden;
* tracks born in the face's frame 0 at step 2 and step 1;
* milliseconds per frame with at least 5,000 tracks on average on one core
  (``cv2.setNumThreads(1)``; the region's lowest rows cut to hold that; the median of 3 runs;
  ``OPENBLAS_NUM_THREADS=1``; the machine's load average is recorded beside it);
* e3D (per-frame Procrustes with scale) of GrassmannNRSfM on the complete frame-0 tracks in
  normalised coordinates ``K^-1 [u v 1]`` over e3D from perfect tracks of the same points,
  with the orthographic solver and through the pinhole (``projection='perspective'``, the
  solver a camera's tracks get); and of the tracked points through the pinhole over rigid
  factorisation's (issues #37, #38: the rendered face from the front end's tracks, e3D / rigid);
  for the sheet also with ``surface='sheet'`` (the maximum-depth heuristic).

Figures go to stdout and ``bench/results/frontend.json`` (``--seeds``:
``frontend_seeds.json``; ``--smoke``: 12 frames, one method, ``bench/results/smoke/``).
"""
import argparse
import json
import os
import time

import cv2
import numpy as np

from grass_nrsfm_ros.frontend import DenseTracker, scenes
from grass_nrsfm_ros.frontend.flow import DEFAULT_METHOD, METHODS
from grass_nrsfm_ros.nrsfm import e3d, GrassmannNRSfM
from grass_nrsfm_ros.nrsfm.camera import normalise
from grass_nrsfm_ros.nrsfm.measurement import from_frames
from grass_nrsfm_ros.nrsfm.rotation import rigid_factorisation
from . import common

RECONSTRUCTION_POINTS = 1500         # complete tracks given to the solver (evenly subsampled)
CALIBRATION_RUNS = 5                 # untimed runs that size the timing region
FACING_DEGREES = 75.0                # beyond this from face-on a point counts as edge-on


def make_scenes(n_frames, seed=0):
    """``[(name, Scene)]``: the face where the Surrey model is found, and a bending sheet,
    of ``seed`` (named with it where it is not 0)."""
    out, suffix = [], f' seed {seed}' if seed else ''
    try:
        out.append(('face' + suffix, scenes.face_scene(n_frames, seed=seed)))
    except FileNotFoundError as exc:
        common.log(f'frontend: no face ({exc.__class__.__name__}); sheet only')
    out.append(('sheet' + suffix, scenes.sheet_scene('bending', n_frames, seed=seed)))
    return out


def render(scene):
    """All frames ``[(H, W, 3) uint8]`` and the seconds per frame it took."""
    start = time.perf_counter()
    images = [scene.render(f) for f in range(scene.n_frames)]
    for f in range(scene.n_frames):
        scene.raster(f)                  # depth buffers for the visibility of the truth
    return images, (time.perf_counter() - start) / scene.n_frames


def run_tracker(images, method, step, region, **kwargs):
    """``(frames: [TrackFrame], ms per frame after the first)``."""
    tracker = DenseTracker(step=step, region=region, method=method, **kwargs)
    frames, seconds = [], []
    for image in images:
        start = time.perf_counter()
        frames.append(tracker.track(image))
        seconds.append(time.perf_counter() - start)
    return frames, 1e3 * float(np.median(seconds[1:])) if len(seconds) > 1 else None


def track_matrix(frames):
    """``(ids: (P,), uv: (F, P, 2) NaN where not tracked, birth: (P,) frame, start: (P, 2))``
    of every track of a run."""
    ids = np.unique(np.concatenate([fr.ids for fr in frames]))
    uv = np.full((len(frames), len(ids), 2), np.nan)
    birth = np.full(len(ids), -1)
    start = np.full((len(ids), 2), np.nan)
    for f, fr in enumerate(frames):
        col = np.searchsorted(ids, fr.ids)
        uv[f, col] = fr.uv
        new = fr.age == 0
        birth[col[new]], start[col[new]] = f, fr.uv[new]
    return ids, uv, birth, start


def ground_truth(scene, birth, start):
    """True ``uv (F, P, 2)``, ``X (F, P, 3)``, ``visible (F, P)`` and ``facing (F, P)`` (the
    cosine of the angle from face-on) of each track's point."""
    F, P = scene.n_frames, len(birth)
    uv, X = np.full((F, P, 2), np.nan), np.full((F, P, 3), np.nan)
    visible, facing = np.zeros((F, P), bool), np.full((F, P), np.nan)
    for f in np.unique(birth[birth >= 0]):
        cols = np.flatnonzero(birth == f)
        truth = scene.truth(start[cols], start=int(f))
        uv[:, cols], X[:, cols], visible[:, cols] = truth.uv, truth.X, truth.visible
        facing[:, cols] = truth.facing
    return uv, X, visible, facing


def evaluate(scene, frames):
    """Accuracy, survival and reconstruction figures of one run."""
    ids, uv, birth, start = track_matrix(frames)
    true_uv, X, visible, facing = ground_truth(scene, birth, start)
    tracked = np.isfinite(uv[..., 0])
    err = np.linalg.norm(uv - true_uv, axis=2)
    scored = tracked & visible
    first = birth == 0
    last_visible = first & visible[-1]
    always_visible = first & visible.all(axis=0)
    with np.errstate(invalid='ignore'):
        always_facing = always_visible & (
            facing >= np.cos(np.radians(FACING_DEGREES))).all(axis=0)
    alive_last = tracked[-1]
    errors = err[scored]
    figures = {
        'tracks_total': int(len(ids)), 'tracks_frame0': int(first.sum()),
        'pairs_scored': int(scored.sum()),
        'error_median_px': float(np.median(errors)),
        'error_p95_px': float(np.percentile(errors, 95)),
        'error_max_px': float(errors.max()),
        'error_last_frame_median_px': float(np.median(err[-1][scored[-1]])),
        'alive_last_among_visible_last': float(alive_last[last_visible].mean()),
        'alive_last_among_visible_always': float(alive_last[always_visible].mean()),
        'alive_last_among_facing_always': float(alive_last[always_facing].mean()),
        'facing_degrees': FACING_DEGREES,
        'alive_while_hidden_share': float((tracked & ~visible).sum() / max(tracked.sum(), 1)),
        'born_off_surface': int((~np.isfinite(true_uv[0, :, 0])).sum()),
        'alive_per_frame': tracked.sum(axis=1).tolist(),
        'reanchored_frames': [f for f, fr in enumerate(frames) if fr.counts['reanchored']],
        'failed_checks': int(sum(fr.counts['failed'] for fr in frames)),
    }
    complete = complete_tracks(birth, uv, visible)
    figures.update(reconstruction(scene, uv[:, complete], true_uv[:, complete], X[:, complete]))
    return figures


def complete_tracks(birth, uv, visible):
    """``(P,) bool``: the tracks born in frame 0, tracked in ``uv (F, P, 2)`` (NaN where not)
    and ``visible (F, P)`` in every frame."""
    return (birth == 0) & np.isfinite(uv[..., 0]).all(axis=0) & visible.all(axis=0)


def evenly_spread(P):
    """Indices ``(P',)`` of at most RECONSTRUCTION_POINTS of ``P`` tracks, evenly spread."""
    return np.linspace(0, P - 1, min(P, RECONSTRUCTION_POINTS)).astype(int)


def track_scene(scene, **options):
    """``(uv, true_uv: (F, P, 2), X: (F, P, 3), visible: (F, P), birth: (P,))``: the default
    tracker (step 4, ``options`` its keywords) over ``scene`` rendered from its frame-0 mask,
    and the truth of every track (:func:`track_matrix`, :func:`ground_truth`)."""
    images, _ = render(scene)
    frames, _ = run_tracker(images, DEFAULT_METHOD, 4, scene.mask(0), **options)
    _, uv, birth, start = track_matrix(frames)
    true_uv, X, visible, _ = ground_truth(scene, birth, start)
    return uv, true_uv, X, visible, birth


def solver_tracks(K, uv, true_uv, X):
    """``(tracked, perfect: (2F, P') normalised K^-1 [u v 1], S: (3F, P') truth)``: the tracks
    ``uv (F, P, 2)``, their true positions and points ``X (F, P, 3)``, at most
    RECONSTRUCTION_POINTS of them evenly spread (:func:`evenly_spread`)."""
    keep = evenly_spread(uv.shape[1])
    return (normalise(pixel_tracks(uv[:, keep]), K), normalise(pixel_tracks(true_uv[:, keep]), K),
            from_frames(X[:, keep].transpose(0, 2, 1)))


def reconstruction(scene, uv, true_uv, X):
    """e3D of GrassmannNRSfM from the tracks and from perfect tracks of the same points."""
    P = uv.shape[1]
    if P < 50:
        return {'reconstruction_points': P}
    tracked, perfect, S = solver_tracks(scene.K, uv, true_uv, X)
    out = {'reconstruction_points': int(S.shape[1]), 'complete_tracks': int(P)}
    for name, W in (('tracked', tracked), ('perfect', perfect)):
        out[f'e3d_{name}'] = e3d(GrassmannNRSfM().fit(W).S, S, scale=True)
        out[f'e3d_{name}_perspective'] = e3d(
            GrassmannNRSfM(projection='perspective').fit(W).S, S, scale=True)
    out['e3d_ratio'] = out['e3d_tracked'] / out['e3d_perfect']
    out['e3d_ratio_perspective'] = (out['e3d_tracked_perspective'] /
                                    out['e3d_perfect_perspective'])
    out['e3d_tracked_rigid'] = e3d(rigid_factorisation(tracked)[1], S, scale=True)
    out['e3d_perspective_over_rigid'] = (out['e3d_tracked_perspective'] /
                                         out['e3d_tracked_rigid'])
    if 'sheet' in scene.name:                   # the sheet option (docs/decisions/0440)
        out['e3d_tracked_sheet'] = e3d(GrassmannNRSfM(projection='perspective',
                                                      surface='sheet').fit(tracked).S, S,
                                       scale=True)
        out['e3d_sheet_over_rigid'] = out['e3d_tracked_sheet'] / out['e3d_tracked_rigid']
    return out


def pixel_tracks(uv):
    """``W: (2F, P)`` of pixels ``uv: (F, P, 2)`` (rows 2f / 2f+1 = u / v of frame f)."""
    return from_frames(uv.transpose(0, 2, 1))


def density(image, mask):
    """Tracks born in a frame at step 2 and step 1 inside ``mask``."""
    return {f'tracks_step{step}': int(DenseTracker(step=step, region=mask).track(image)
                                      .counts['born']) for step in (2, 1)}


def timing(images, mask, method, target=5000, options=None, repeats=3):
    """Milliseconds per frame on one OpenCV thread with at least ``target`` tracks on average:
    the region is ``mask`` at the step that holds at least twice ``target`` grid points, its
    lowest rows cut until it holds ``target``, then enlarged by the share of tracks an untimed
    run lost on average, by whole rows, until a run averages ``target`` (at most
    ``CALIBRATION_RUNS`` runs); the median of ``repeats`` runs (each a median over frames)."""
    step = max(1, int(np.sqrt(mask.sum() / (2 * target))))
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        points, region, runs = target, None, 0
        while runs < CALIBRATION_RUNS:
            cut = _cut_rows(mask, step, points)
            if region is not None and (cut == region).all():
                points *= 1.01                  # not a grid point more yet: grow again
                continue
            region, runs = cut, runs + 1
            frames, _ = run_tracker(images, method, step, region, **(options or {}))
            mean = np.mean([len(fr.ids) for fr in frames])
            if mean >= target or (region == mask).all():
                break
            points = points * target / mean
        runs = [run_tracker(images, method, step, region, **(options or {}))
                for _ in range(repeats)]
    finally:
        cv2.setNumThreads(threads)
    frames = runs[0][0]
    return {'timing_step': step, 'timing_tracks_mean': float(np.mean(
        [len(fr.ids) for fr in frames])), 'ms_per_frame_1_thread': float(np.median(
            [ms for _, ms in runs])), 'ms_per_frame_runs': [ms for _, ms in runs],
        'load_average_1min': os.getloadavg()[0]}


def _cut_rows(mask, step, points):
    """``mask`` with its lowest rows cut until its grid at ``step`` holds at most ``points``."""
    region = mask.copy()
    for row in np.flatnonzero(region.any(axis=1))[::-1]:
        if region[::step, ::step].sum() <= points:
            break
        region[row] = False
    return region


def run(mode, methods=None, step=4, n_frames=None, options=None, seeds=None):
    """Rows of figures per sequence and method; ``options``: DenseTracker keyword
    arguments (None: its defaults); ``seeds``: the scenes of those seeds, without the
    timing (None: seed 0, timed)."""
    options = options or {}
    methods = methods or mode.pick([DEFAULT_METHOD], [DEFAULT_METHOD], list(METHODS))
    n_frames = n_frames or mode.pick(12, 100, 100)
    rows, sequences = [], {}
    made = [pair for seed in (seeds or [0]) for pair in make_scenes(n_frames, seed)]
    for name, scene in made:
        images, render_s = render(scene)
        mask = scene.mask(0)
        sequences[name] = {'frames': n_frames, 'size': list(scene.size),
                           'render_ms_per_frame': 1e3 * render_s,
                           'mask_pixels': int(mask.sum())}
        if name == 'face' or len(sequences) == 1:
            sequences[name].update(density(images[0], mask))
        for method in methods:
            common.log(f'frontend: {name} {method} step {step}')
            frames, ms = run_tracker(images, method, step, mask, **options)
            row = {'sequence': name, 'method': method, 'step': step, 'ms_per_frame': ms,
                   'options': options}
            row.update(evaluate(scene, frames))
            if seeds is None:
                row.update(timing(images, mask, method, options=options))
            rows.append(row)
            print(summary(row), flush=True)
    return {'rows': rows, 'sequences': sequences, 'targets': TARGETS}


TARGETS = {'face_error_median_px': 0.5, 'face_error_p95_px': 2.0, 'sheet_error_median_px': 0.3,
           'sheet_error_p95_px': 1.5, 'alive_last_among_visible_last': 0.9,
           'tracks_step2_face': 5000, 'ms_per_frame_5000_tracks': 25, 'e3d_ratio': 1.2,
           'face_perspective_over_rigid': 0.6}


def summary(row):
    ms = row.get('ms_per_frame_1_thread', row['ms_per_frame'])
    return (f"{row['sequence']:5s} {row['method']:17s} err median {row['error_median_px']:.3f}"
            f" p95 {row['error_p95_px']:.3f} max {row['error_max_px']:.1f} px | alive "
            f"{100 * row['alive_last_among_visible_last']:.1f} % (facing "
            f"{100 * row['alive_last_among_facing_always']:.1f} %) | hidden-alive "
            f"{100 * row['alive_while_hidden_share']:.2f} % | {row['tracks_frame0']} tracks | "
            f"{ms:.1f} ms/frame at {row.get('timing_tracks_mean', np.nan):.0f} tracks | e3D "
            f"ratio {row.get('e3d_ratio', np.nan):.3f}, perspective "
            f"{row.get('e3d_ratio_perspective', np.nan):.3f} | reanchored "
            f"{len(row['reanchored_frames'])}x")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--smoke', action='store_true', help='12 frames, one method')
    parser.add_argument('--frames', type=int, default=None, help='frames per sequence')
    parser.add_argument('--methods', default=None,
                        help=f'comma-separated, of {", ".join(METHODS)} (default: '
                        f'{DEFAULT_METHOD}; "all": every one)')
    parser.add_argument('--step', type=int, default=4, help='grid step in pixels')
    parser.add_argument('--options', type=json.loads, default=None,
                        help='DenseTracker keyword arguments as JSON, e.g. '
                        '\'{"min_zncc": 0.75}\'')
    parser.add_argument('--seeds', default=None,
                        help='comma-separated scene seeds (other faces and sheets, untimed; '
                        'written to frontend_seeds.json)')
    parser.add_argument('--out', default=None, help='results folder')
    args = parser.parse_args(argv)
    seeds = None if args.seeds is None else [int(s) for s in args.seeds.split(',')]
    methods = None
    if args.methods:
        methods = list(METHODS) if args.methods == 'all' else args.methods.split(',')
        unknown = set(methods) - set(METHODS)
        if unknown:
            parser.error(f'unknown methods {sorted(unknown)}; choose from {METHODS}')
    mode = common.Mode('smoke' if args.smoke else 'quick', out=args.out)
    payload = run(mode, methods, args.step, args.frames, args.options, seeds)
    path = common.write_result(mode, 'frontend' if seeds is None else 'frontend_seeds', payload)
    print(f'wrote {path}')


if __name__ == '__main__':
    main()
