"""``python -m bench.kinect_paper``: the seed paper's kinect_paper experiment from its own images.

The 191 frames of Varol et al.'s sheet of paper (``<data>/kinect_paper_images``, K in its
meta.json) are read as ``grass-nrsfm track`` reads a folder (:mod:`grass_nrsfm_ros.frontend.
sources`) and tracked by :class:`~grass_nrsfm_ros.frontend.DenseTracker` on a grid inside the
paper's window x 253-508, y 132-363. Reconstructions (the names of the e3D figures):

* ``whole``: the tracks alive in every frame, in normalised coordinates ``K^-1 [u v 1]``,
  solved at once by ``GrassmannNRSfM`` as orthographic projections (the pictures show it);
* ``whole_perspective``: the same through the pinhole (``projection='perspective'``), the
  low-rank chain (``surface='any'``); ``surface_auto`` in the JSON: what the default
  ``surface='auto'`` decides on these tracks (record 0726: a sheet gets ``sheet_perspective``);
* ``rigid``: rigid factorisation of the same;
* ``sheet_perspective``: the same through the pinhole with ``surface='sheet'`` (the
  maximum-depth heuristic, its lengths from 40 key frames, records 0723, 0724);
* ``live_points`` / ``live_refined``: every track as the tracker gives it, in pixels with
  ``K``, through the live pipeline as the node runs it with ``camera_info``
  (``reconstruct_live``, default parameters).

Ground truth: the data holds none for the 191 frames; ``perspective_subsets/kinect_paper.npz``
has 90 points in 10 frames of the same pixel frame (Kinect depth, mm) whose frame numbers are
not known. They are located here: every image frame is tried as the subset's first frame, each
truth point whose nearest complete track there is within ``--tie-px`` becomes an affine
combination of its 4 nearest tracks and is carried by them into every frame; each subset
frame is the image frame where the carried points land nearest (median pixel distance). The
e3D (per-frame Procrustes with scale) of the same combination of the tracks' reconstructed
points against the truth is reported with that distance, so a poor match shows, beside
rigid factorisation's and the solver's on the subset's own 10 x 90 tracks.

Writes ``bench/results/kinect_paper.json`` and, unless ``--no-pictures``,
``docs/pictures/kinect_paper_tracking.png`` (alive tracks, births and failed checks per frame)
and ``docs/pictures/kinect_paper_fig1.png`` (input frames above their reconstructed surface,
coloured by depth, as the paper's Fig. 1). About 11 minutes on 2 cores.

    python -m bench.kinect_paper [--step 4] [--method dis-medium] [--frames N]
"""
import argparse
import io
import json
from pathlib import Path
import time

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.tri import Triangulation
import numpy as np
from PIL import Image

from bench.common import data_root, environment, jsonable, log, RESULTS
from grass_nrsfm_ros.commands.track import tracks_matrix
from grass_nrsfm_ros.frontend import DenseTracker
from grass_nrsfm_ros.frontend.sources import open_source
from grass_nrsfm_ros.nrsfm import e3d, GrassmannNRSfM
from grass_nrsfm_ros.nrsfm.camera import normalise
from grass_nrsfm_ros.nrsfm.measurement import frame_rows
from grass_nrsfm_ros.nrsfm.rotation import rigid_factorisation
from grass_nrsfm_ros.nrsfm.stages import surface as surface_stage
from grass_nrsfm_ros.params import defaults
from grass_nrsfm_ros.pipeline import make_pipeline, reconstruct_live

REPO = Path(__file__).resolve().parents[1]
PICTURES = REPO / 'docs' / 'pictures'
WINDOW = (253, 132, 508, 363)           # the seed paper's window: x0, y0, x1, y1 (pixels)
#: tracker settings: the most complete tracks of those measured (decision record 0621)
DPI = 80
TRACKER = dict(method='dis-medium', min_zncc=0.6, reanchor_zncc=0.75)


def parse_args(argv=None):
    parser = argparse.ArgumentParser(prog='python -m bench.kinect_paper',
                                     description=__doc__.splitlines()[0])
    parser.add_argument('--step', type=int, default=4, help='grid step in pixels (4)')
    parser.add_argument('--method', default=TRACKER['method'], help='DenseTracker method')
    parser.add_argument('--min-zncc', type=float, default=TRACKER['min_zncc'])
    parser.add_argument('--reanchor-zncc', type=float, default=TRACKER['reanchor_zncc'])
    parser.add_argument('--frames', type=int, default=None, help='only the first N frames')
    parser.add_argument('--tie-px', type=float, default=3.0,
                        help='a truth point ties to a track no farther than this in pixels')
    parser.add_argument('--out', default=str(RESULTS / 'kinect_paper.json'))
    parser.add_argument('--pictures', default=str(PICTURES))
    parser.add_argument('--no-pictures', action='store_true')
    parser.add_argument('--cache', help='an .npz of the tracks and reconstruction: read where '
                        'it exists (pictures and figures only), else written')
    return parser.parse_args(argv)


# ------------------------------------------------------------------------------ tracking
def track(folder, K, step, frames=None, **options):
    """Track the window over the folder's frames: ``(W: (2F, P) px, ids, stamps,
    counts: {name: (F,) int}, seconds per frame)``."""
    source = open_source(folder)
    tracker = DenseTracker(step, WINDOW, K=K, **options)
    ids, uv, stamps, counts = [], [], [], []
    seconds = 0.0
    for frame in source:
        if frames is not None and len(stamps) >= frames:
            break
        started = time.perf_counter()
        out = tracker.track(frame.image)
        seconds += time.perf_counter() - started
        ids.append(out.ids)
        uv.append(out.uv)
        stamps.append(frame.stamp_ns)
        counts.append(out.counts)
    W, track_ids = tracks_matrix(ids, uv)
    per_frame = {k: np.array([c[k] for c in counts]) for k in counts[0]}
    return W, track_ids, np.array(stamps), per_frame, seconds / len(stamps)


# ------------------------------------------------------------------------------ ground truth
def locate_subset(W_px, W_gt_px, tie_px, neighbours=4):
    """Where the truth subset sits in the sequence. ``W_px: (2F, P)`` complete tracks,
    ``W_gt_px: (2G, N)`` truth pixels. Each truth point is an affine combination of its
    ``neighbours`` nearest tracks in the candidate first frame (weights summing to 1, least
    norm), carried by them through the frames. Returns, for the first-frame candidate with
    the smallest median residual, ``dict(frames: (G,), residual_px: (G,) median distance of
    the carried points, tied: (N,) bool (nearest track within tie_px), tracks: (N, k)
    columns of W_px, weights: (N, k))``."""
    F, G = W_px.shape[0] // 2, W_gt_px.shape[0] // 2
    tracks_uv = np.stack([W_px[0::2], W_px[1::2]], axis=-1)          # (F, P, 2)
    truth_uv = np.stack([W_gt_px[0::2], W_gt_px[1::2]], axis=-1)     # (G, N, 2)
    best = None
    for a in range(F):
        d = np.linalg.norm(tracks_uv[a][None] - truth_uv[0][:, None], axis=-1)   # (N, P)
        near = np.argsort(d, axis=1)[:, :neighbours]                            # (N, k)
        tied = d[np.arange(len(near)), near[:, 0]] <= tie_px
        if tied.sum() < 10:
            continue
        near = near[tied]
        weights = affine_weights(tracks_uv[a, near], truth_uv[0, tied])         # (n, k)
        carried = np.einsum('fnkc,nk->fnc', tracks_uv[:, near], weights)       # (F, n, 2)
        miss = np.median(np.linalg.norm(carried[None] - truth_uv[:, tied][:, None], axis=-1),
                         axis=-1)                                               # (G, F)
        frames = miss.argmin(axis=1)
        residual = miss[np.arange(G), frames]
        score = float(np.median(residual))
        if best is None or score < best['score']:
            best = dict(score=score, frames=frames, residual_px=residual, tied=tied,
                        tracks=near, weights=weights)
    return best


def affine_weights(corners, points):
    """Least-norm weights ``(n, k)`` summing to 1 with ``sum_k w corners[:, k] = points``
    (``corners: (n, k, 2)``, ``points: (n, 2)``)."""
    A = np.concatenate([corners.transpose(0, 2, 1), np.ones((len(points), 1,
                                                             corners.shape[1]))], axis=1)
    b = np.concatenate([points, np.ones((len(points), 1))], axis=1)            # (n, 3)
    return np.einsum('nkr,nr->nk', np.linalg.pinv(A), b)


def subset_e3d(S_est, match, S_gt):
    """e3D (per frame Procrustes with scale) of the truth points' reconstruction (the same
    affine combination of their tracks' shapes) in the located frames against the truth
    ``S_gt: (3G, N)``."""
    rows = frame_rows(match['frames'], 3)
    shapes = S_est[rows][:, match['tracks']]                                   # (3G, n, k)
    estimate = np.einsum('rnk,nk->rn', shapes, match['weights'])
    return e3d(estimate, S_gt[:, match['tied']], scale=True)


# ------------------------------------------------------------------------------ pictures
def tracking_figure(counts, complete_alive, path):
    """Alive tracks (and frame-0 tracks still alive) and per-frame births and failed checks."""
    fig = Figure(figsize=(7.0, 4.2), dpi=DPI)
    FigureCanvasAgg(fig)
    top, bottom = fig.add_subplot(2, 1, 1), fig.add_subplot(2, 1, 2)
    frames = np.arange(1, len(counts['alive']) + 1)
    top.plot(frames, counts['alive'], label='alive tracks')
    top.plot(frames, complete_alive, label='frame-1 tracks still alive')
    top.set_ylabel('tracks')
    top.legend(loc='lower left', fontsize=8)
    top.set_title('kinect_paper: dense tracks in the window x 253-508, y 132-363', fontsize=10)
    bottom.plot(frames, counts['failed'], label='failed checks (tracks killed)', color='C3')
    bottom.plot(frames, counts['born'], label='born', color='C2', alpha=0.7)
    anchors = frames[counts['reanchored'] > 0]
    bottom.plot(anchors, np.zeros(len(anchors)), '|', color='k', markersize=8,
                label='new reference frame')
    bottom.set_yscale('symlog', linthresh=10)
    bottom.set_xlabel('frame')
    bottom.set_ylabel('tracks per frame')
    bottom.legend(loc='upper left', fontsize=8)
    fig.tight_layout()
    save_small(fig, path)


def fig1(images, W_px, S_est, shown, step, path):
    """The paper's Fig. 1: input frames (window and tracks) above the reconstructed surface,
    triangulated over the tracks and coloured by depth."""
    fig = Figure(figsize=(2.6 * len(shown), 4.6), dpi=DPI)
    FigureCanvasAgg(fig)
    x0, y0, x1, y1 = WINDOW
    for k, f in enumerate(shown):
        ax = fig.add_subplot(2, len(shown), k + 1)
        ax.imshow(images[f][90:420, 170:590])
        ax.plot(W_px[2 * f] - 170, W_px[2 * f + 1] - 90, ',', color='#00ff66', alpha=0.6)
        ax.add_patch(_rectangle(x0 - 170, y0 - 90, x1 - x0, y1 - y0))
        ax.set_title(f'input frame {f + 1}', fontsize=9)
        ax.axis('off')
        ax3 = fig.add_subplot(2, len(shown), len(shown) + k + 1, projection='3d')
        surface(ax3, W_px[2 * f:2 * f + 2], S_est[3 * f:3 * f + 3], step)
        ax3.set_title(f'reconstruction, frame {f + 1}', fontsize=9)
    fig.subplots_adjust(left=0.01, right=0.99, top=0.95, bottom=0.01, wspace=0.02,
                        hspace=0.08)
    save_small(fig, path)


def surface(ax, uv, xyz, step):
    """Draw the shape ``xyz: (3, P)`` as a surface triangulated over its tracks' pixels
    ``uv: (2, P)`` (triangles with an edge over 3 grid steps dropped), seen from the camera's
    upper left, each triangle coloured by its depth."""
    tri = Triangulation(uv[0], uv[1])
    corners = uv.T[tri.triangles]                                        # (T, 3, 2)
    edges = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=-1).max(axis=1)
    triangles = tri.triangles[edges <= 3 * step]
    xyz = xyz - xyz.mean(axis=1, keepdims=True)
    mesh = ax.plot_trisurf(xyz[0], xyz[2], -xyz[1], triangles=triangles, linewidth=0,
                           antialiased=False, shade=False)
    mesh.set_array(xyz[2][triangles].mean(axis=1))
    mesh.set_cmap('viridis')
    mesh.autoscale()
    half = np.abs(xyz[:2]).max()
    for setter in (ax.set_xlim, ax.set_ylim, ax.set_zlim):
        setter(-half, half)
    ax.set_box_aspect((1, 1, 1), zoom=1.25)
    ax.view_init(elev=20, azim=-60)
    ax.set_axis_off()


def save_small(fig, path):
    """The figure as a 256-colour PNG (a third of the size of the RGB one)."""
    buffer = io.BytesIO()
    fig.savefig(buffer, dpi=DPI, format='png')
    buffer.seek(0)
    Image.open(buffer).convert('RGB').quantize(colors=256).save(path, optimize=True)


def _rectangle(x, y, w, h):
    from matplotlib.patches import Rectangle
    return Rectangle((x, y), w, h, fill=False, edgecolor='red', linewidth=0.8)


# ------------------------------------------------------------------------------ main
def measure(args, frames_folder, K):
    """Track and reconstruct (or load both from ``args.cache`` where it exists; write it
    otherwise): a dict of W (2F, P) px, ids, stamps, counts, ms_per_frame, S, S_rigid,
    solve_seconds, iterations."""
    cache = Path(args.cache) if args.cache else None
    if cache is not None and cache.is_file():
        log(f'tracks and reconstruction from {cache}')
        with np.load(cache) as npz:
            run = {k: npz[k] for k in npz.files}
        run['counts'] = {k[6:]: run.pop(k) for k in list(run) if k.startswith('count_')}
        return run
    log(f'tracking {frames_folder} (step {args.step}, {args.method}) ...')
    W, ids, stamps, counts, frame_seconds = track(
        frames_folder, K, args.step, args.frames, method=args.method,
        min_zncc=args.min_zncc, reanchor_zncc=args.reanchor_zncc)
    complete = np.isfinite(W).all(axis=0)
    log(f'{W.shape[0] // 2} frames, {ids.size} tracks, {int(np.isfinite(W[0]).sum())} in '
        f'frame 1, {int(complete.sum())} in every frame; {1000 * frame_seconds:.0f} ms per '
        'frame')
    Wn = normalise(W[:, complete], K)
    started = time.perf_counter()
    result = GrassmannNRSfM().fit(Wn)
    solve_seconds = time.perf_counter() - started
    _, S_rigid = rigid_factorisation(Wn)
    log(f'GrassmannNRSfM: {int(complete.sum())} complete tracks in {solve_seconds:.0f} s')
    S_perspective = GrassmannNRSfM(projection='perspective', surface='any').fit(Wn).S
    log('GrassmannNRSfM through the pinhole: done')
    decided = surface_stage.check(Wn)           # what surface 'auto' chooses (record 0726)
    log(surface_stage.note(decided))
    started = time.perf_counter()
    S_sheet = GrassmannNRSfM(projection='perspective', surface='sheet').fit(Wn).S
    sheet_seconds = time.perf_counter() - started
    log(f"GrassmannNRSfM through the pinhole, surface 'sheet': {sheet_seconds:.0f} s")
    started = time.perf_counter()
    S_points, S_refined, live_stats = live(W, ids, stamps, K, complete)
    live_seconds = time.perf_counter() - started
    log(f'live pipeline: {live_seconds:.0f} s')
    run = dict(W=W, ids=ids, stamps=stamps, ms_per_frame=1000 * frame_seconds, S=result.S,
               S_rigid=S_rigid, S_perspective=S_perspective, S_sheet=S_sheet,
               sheet_seconds=sheet_seconds, solve_seconds=solve_seconds,
               iterations=result.report.iterations, S_points=S_points, S_refined=S_refined,
               live_seconds=live_seconds, live_stats=live_stats,
               surface_variation=decided.value,
               surface_sheet=decided.sheet)
    if cache is not None:
        arrays = {k: v for k, v in run.items() if k != 'live_stats'}
        np.savez_compressed(cache, **arrays, **{f'count_{k}': v for k, v in counts.items()})
    return {**run, 'counts': counts}


def live(W, ids, stamps, K, columns):
    """The live pipeline (defaults, inline, intrinsics ``K``) over every track of ``W: (2F,
    P)`` pixels (NaN where not tracked), as the node would run them: ``(S_points,
    S_refined, stats)``, each S ``(3F, C)`` for the tracks ``columns (P,) bool``, NaN where
    not published; stats: the tracking's ms per frame (p50, p95), the frames that went out
    from a sheet model (``signed``) on points and on points/refined, the first of them."""
    F = W.shape[0] // 2
    pipeline = make_pipeline(defaults(), camera=K)
    frames = []
    for f in range(F):
        seen = np.isfinite(W[2 * f])
        frames.append((ids[seen], W[2 * f:2 * f + 2, seen].T))
    try:
        points, refined, _ = reconstruct_live(pipeline, stamps, frames)
        latency = [1000 * t for t in pipeline.latency_percentiles()]
    finally:
        pipeline.close()
    frame_of = {int(s): f for f, s in enumerate(stamps)}
    signed = [frame_of[int(r.stamp_ns)] for r in points if r.signed]
    stats = dict(tracking_ms_p50_p95=latency, sheet_points=len(signed),
                 sheet_refined=sum(r.signed for r in refined),
                 first_sheet_frame=min(signed) + 1 if signed else None)
    wanted = ids[columns]
    shapes = []
    for results in (points, refined):
        S = np.full((3 * F, wanted.size), np.nan)
        for r in results:
            f = frame_of[int(r.stamp_ns)]
            _, mine, theirs = np.intersect1d(wanted, r.ids, return_indices=True)
            S[3 * f:3 * f + 3, mine] = r.xyz[theirs].T
        shapes.append(S)
    return (*shapes, stats)


def main(argv=None):
    args = parse_args(argv)
    root = data_root()
    folder = None if root is None else root / 'kinect_paper_images'
    if folder is None or not (folder / 'meta.json').is_file():
        log('kinect_paper_images not found (set GRASS_NRSFM_DATA): nothing measured')
        return 1
    K = np.array(json.loads((folder / 'meta.json').read_text())['K'], dtype=np.float64)
    run = measure(args, folder / 'frames', K)
    W, ids, counts = run['W'], run['ids'], run['counts']
    F = W.shape[0] // 2
    complete = np.isfinite(W).all(axis=0)
    first = np.isfinite(W[0])
    W_px = W[:, complete]
    figures = dict(
        frames=F, step=args.step, window=WINDOW, tracker=dict(
            method=args.method, min_zncc=args.min_zncc, reanchor_zncc=args.reanchor_zncc),
        K=K, tracks_total=ids.size, tracks_frame1=int(first.sum()),
        tracks_complete=int(complete.sum()), ms_per_frame=float(run['ms_per_frame']),
        alive_mean=float(counts['alive'].mean()), failed_total=int(counts['failed'].sum()),
        born_total=int(counts['born'].sum()), reanchored=int(counts['reanchored'].sum()),
        solve_seconds=float(run['solve_seconds']), iterations=int(run['iterations']),
        sheet_seconds=float(run['sheet_seconds']),
        live_seconds=float(run['live_seconds']), live=run.get('live_stats'),
        surface_auto=dict(variation=float(run.get('surface_variation', np.nan)),
                          sheet=bool(run.get('surface_sheet', False))),
        coordinates='whole sequence: normalised K^-1 [u v 1] of the complete tracks; live '
        'pipeline: pixels of every track with K')
    figures['ground_truth'] = ground_truth_figures(
        W_px, {'whole': run['S'], 'whole_perspective': run['S_perspective'],
               'rigid': run['S_rigid'], 'sheet_perspective': run['S_sheet'],
               'live_points': run['S_points'],
               'live_refined': run['S_refined']}, K, args.tie_px)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(jsonable({'suite': 'kinect_paper', 'environment': environment(),
                                        **figures}), indent=1) + '\n')
    log(f'wrote {out}')
    if not args.no_pictures:
        pictures = Path(args.pictures)
        pictures.mkdir(parents=True, exist_ok=True)
        complete_alive = np.isfinite(W[0::2][:, first]).sum(axis=1)
        tracking_figure(counts, complete_alive, pictures / 'kinect_paper_tracking.png')
        shown = sorted({0, F - 1} | {int(np.argmax(_bend(run['S'])))})
        images = {frame.index: frame.image for frame in open_source(folder / 'frames')
                  if frame.index in shown}
        fig1(images, W_px, run['S'], shown, args.step, pictures / 'kinect_paper_fig1.png')
        log(f'wrote {pictures}/kinect_paper_tracking.png, kinect_paper_fig1.png')
    print(json.dumps(jsonable({k: v for k, v in figures.items() if k != 'K'}), indent=1))
    return 0


def _bend(S):
    """Per frame, the depth spread of the shape left after its best plane (how bent)."""
    F = S.shape[0] // 3
    spread = np.zeros(F)
    for f in range(F):
        xyz = S[3 * f:3 * f + 3]
        xyz = xyz - xyz.mean(axis=1, keepdims=True)
        spread[f] = np.linalg.svd(xyz, compute_uv=False)[2]
    return spread


def ground_truth_figures(W_px, estimates, K, tie_px):
    """e3D of each of ``estimates`` (name: S (3F, P)) against the 10-frame truth subset,
    located as the module docstring says."""
    root = data_root()
    path = root / 'perspective_subsets' / 'kinect_paper.npz'
    if not path.is_file():
        return {'available': False}
    with np.load(path) as npz:
        W_gt_px, S_gt = npz['W_px'].astype(np.float64), npz['S'].astype(np.float64)
    match = locate_subset(W_px, W_gt_px, tie_px)
    if match is None:
        return {'available': True, 'located': False}
    own = GrassmannNRSfM().fit(normalise(W_gt_px, K)).S
    e3ds = {name: subset_e3d(S, match, S_gt) for name, S in estimates.items()}
    return dict(available=True, located=True, frames=match['frames'] + 1,
                residual_px=match['residual_px'], points_tied=int(match['tied'].sum()),
                points=int(W_gt_px.shape[1]), e3d=e3ds,
                e3d_subset_alone=e3d(own, S_gt, scale=True))


if __name__ == '__main__':
    raise SystemExit(main())
