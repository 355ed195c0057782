"""``grass-nrsfm demo``: the quick start's main job, from images, then on the embedded
synthetic tracks.

1. starts from images: a textured bending sheet rendered by :mod:`~grass_nrsfm_ros.frontend.
   scenes` (made here, no files), tracked by :class:`~grass_nrsfm_ros.frontend.DenseTracker`,
   reconstructed whole and by the live pipeline with the renderer's intrinsics ``K`` (points
   through the pinhole); prints the tracking error (px) and e3D against the renderer's ground
   truth, and the whole-sequence e3D of the perspective model (``projection``
   'perspective' on the normalised tracks), which does not beat the orthographic solve on
   this sheet yet (docs/decisions/0703);
2. generates :func:`~grass_nrsfm_ros.nrsfm.synthetic.default_sequence` (no external data) and
   reconstructs it whole with GrassmannNRSfM and with rigid factorisation, printing e3D;
3. converts it to a tracks bag and runs the node's live pipeline over it offline,
   recording tracks, ground truth and reconstructed points in an MCAP bag, printing e3D;
4. draws its last frame (estimate beside ground truth) as a PNG.
"""
from pathlib import Path
import shutil
import time

import numpy as np

from grass_nrsfm_ros import bag
from grass_nrsfm_ros.commands.reconstruct import reconstruct_bag
from grass_nrsfm_ros.commands.render import renderer
from grass_nrsfm_ros.commands.track import tracks_matrix
from grass_nrsfm_ros.frontend import DenseTracker, scenes
from grass_nrsfm_ros.nrsfm import e3d, GrassmannNRSfM, synthetic
from grass_nrsfm_ros.nrsfm.camera import normalise
from grass_nrsfm_ros.nrsfm.metrics import procrustes_align
from grass_nrsfm_ros.nrsfm.rotation import rigid_factorisation
from grass_nrsfm_ros.params import defaults
from grass_nrsfm_ros.pipeline import make_pipeline, reconstruct_live

#: the sequence from images: frames, image size (H, W), grid step in pixels
IMAGE_FRAMES, IMAGE_SIZE, IMAGE_STEP = 40, (240, 320), 5


def add_arguments(parser):
    parser.add_argument('-o', '--output', default='out/demo', help='output folder')
    parser.add_argument('--frames', type=int, default=None, help='override the frame count')
    parser.add_argument('--points', type=int, default=None, help='override the track count')


def make_sequence(frames, points):
    seq = synthetic.default_sequence()
    if frames is None and points is None:
        return seq
    kind = seq.meta.get('kind', 'bending')
    return synthetic.make_sequence(kind, n_frames=frames or seq.n_frames,
                                   n_points=points or seq.n_points)


def whole_sequence(seq):
    """e3D of the whole-sequence solve and of rigid factorisation; the solver result."""
    started = time.perf_counter()
    result = GrassmannNRSfM().fit(seq.W)
    seconds = time.perf_counter() - started
    _, S_rigid = rigid_factorisation(seq.W)
    how = ('the orthographic sheet model (surface auto)' if 'sheet_transport' in
           result.report.stages else f'{result.report.iterations} iterations')
    print(f'whole sequence: e3D {e3d(result.S, seq.S):.4f} (rigid factorisation '
          f'{e3d(S_rigid, seq.S):.4f}), {how}, {seconds:.1f} s')
    return result


def streaming(seq, tracks_bag, points_bag):
    """Run the node's pipeline over ``tracks_bag`` offline; print the e3D of the frames as
    tracked on arrival (``points``) and as their windows refined them (``points/refined``)."""
    pipeline = make_pipeline(defaults())
    try:
        report = reconstruct_bag(tracks_bag, points_bag, pipeline, progress=None)
    finally:
        pipeline.close()
    figures = []
    for topic in (bag.POINTS_TOPIC, bag.REFINED_TOPIC):
        S, ids, _ = bag.read_S(points_bag, topic)
        S_gt = seq.S[:, ids.astype(int)]
        done = np.isfinite(S).all(axis=1).reshape(-1, 3).all(axis=1)    # (F,) frames published
        keep = np.repeat(done, 3)
        figures.append(e3d(S[keep], S_gt[keep]))
    windows = pipeline.windowing
    print(f'live (window {windows.window_size}, stride {windows.window_stride}): '
          f'{report.frames_out}/{report.frames_in} frames, e3D {figures[0]:.4f} as tracked on '
          f'arrival ({pipeline.tracking.stats["bootstrap_frames"]} before the first model); '
          f'{report.frames_refined} refined, e3D {figures[1]:.4f}; {report.seconds:.1f} s')


def picture(result, seq, path):
    render = renderer()
    last = slice(3 * (seq.n_frames - 1), 3 * seq.n_frames)
    estimate, truth = procrustes_align(result.S[last], seq.S[last])
    render.write_png(path, render.frame_figure(estimate, truth,
                                               title=f'{seq.name}: last frame'))


def run(args):
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    from_images()
    seq = make_sequence(args.frames, args.points)
    print(f'{seq.name}: {seq.n_frames} frames x {seq.n_points} tracks (synthetic, with ground '
          f'truth) -> {out}/')
    seq.save_npz(out / 'sequence.npz')
    result = whole_sequence(seq)
    np.savez_compressed(out / 'reconstruction.npz', S=result.S, R=result.R, S_gt=seq.S)
    tracks_bag, points_bag = out / 'tracks_bag', out / 'reconstruction_bag'
    for old in (tracks_bag, points_bag):
        shutil.rmtree(old, ignore_errors=True)
    stamps = np.arange(seq.n_frames, dtype=np.int64) * 33_333_333 + 1_700_000_000_000_000_000
    bag.tracks_bag_from_arrays(seq.W, stamps, tracks_bag, S=seq.S)
    streaming(seq, tracks_bag, points_bag)
    picture(result, seq, out / 'last_frame.png')
    print(f'wrote {out / "reconstruction.npz"}, {points_bag}/ (tracks, ground truth, points; '
          f'MCAP) and {out / "last_frame.png"}')
    return 0


def from_images(n_frames=IMAGE_FRAMES):
    """Rendered images -> DenseTracker -> the solver and the live pipeline; prints the
    tracking error against the renderer's truth and e3D (per-frame Procrustes with scale:
    pixels against scene units) of the tracks alive in every frame, beside the solver's e3D
    from the true projections of the same surface points (the tracker's share)."""
    started = time.perf_counter()
    H, W = IMAGE_SIZE
    scene = scenes.sheet_scene('bending', n_frames=n_frames, size=IMAGE_SIZE, focal=1.3 * H,
                               extent_px=int(0.8 * H), grid=(48, 36), seed=0)
    tracker = DenseTracker(IMAGE_STEP, scene.mask(0), K=scene.K)
    tracked = [tracker.track(image) for image in scene.frames()]
    W_all, ids = tracks_matrix([t.ids for t in tracked], [t.uv for t in tracked])
    complete = np.isfinite(W_all).all(axis=0)
    tracks, ids = W_all[:, complete], ids[complete]
    truth = scene.truth(tracks[0:2].T)                       # the surface points tracked
    uv = np.stack([tracks[0::2], tracks[1::2]], axis=-1)      # (F, P, 2)
    error = np.linalg.norm(uv - truth.uv, axis=-1)[truth.visible]
    S_gt = truth.X.transpose(0, 2, 1).reshape(-1, ids.size)  # (3F, P)
    print(f'from images: {n_frames} frames {W} x {H} rendered and tracked (step {IMAGE_STEP}), '
          f'{int(np.isfinite(W_all[0]).sum())} tracks in frame 0, {ids.size} in every frame; '
          f'tracking error median {np.median(error):.2f} px, p95 '
          f'{np.percentile(error, 95):.2f} px; {time.perf_counter() - started:.1f} s')
    started = time.perf_counter()
    result = GrassmannNRSfM().fit(tracks)
    perfect = GrassmannNRSfM().fit(truth.uv.transpose(0, 2, 1).reshape(-1, ids.size))
    _, S_rigid = rigid_factorisation(tracks)
    stamps = np.arange(n_frames, dtype=np.int64) * 33_333_333
    pipeline = make_pipeline(defaults(), camera=scene.K)
    try:
        points, refined, _ = reconstruct_live(pipeline, stamps, [(ids, uv[f]) for f in
                                                                 range(n_frames)])
    finally:
        pipeline.close()
    live, done = (results_e3d(r, stamps, ids, S_gt) for r in (points, refined))
    print(f'from images: whole sequence e3D {e3d(result.S, S_gt, scale=True):.4f} (perfect '
          f'tracks of the same points {e3d(perfect.S, S_gt, scale=True):.4f}, rigid '
          f'factorisation {e3d(S_rigid, S_gt, scale=True):.4f}); live e3D {live:.4f} as '
          f'tracked on arrival, {done:.4f} refined (with K); '
          f'{time.perf_counter() - started:.1f} s')
    started = time.perf_counter()
    pinhole = GrassmannNRSfM(projection='perspective').fit(normalise(tracks, scene.K))
    print(f'from images, the perspective model with K: whole sequence e3D '
          f'{e3d(pinhole.S, S_gt, scale=True):.4f}; {time.perf_counter() - started:.1f} s')


def results_e3d(results, stamps, ids, S_gt):
    """e3D (with scale) of FrameResults against ``S_gt: (3F, P)`` over the tracks ``ids``."""
    frame_of = {int(s): f for f, s in enumerate(stamps)}
    estimate, truth = [], []
    for r in results:
        f = frame_of[int(r.stamp_ns)]
        estimate.append(r.xyz.T)
        truth.append(S_gt[3 * f:3 * f + 3, np.searchsorted(ids, r.ids)])
    return e3d(np.vstack(estimate), np.vstack(truth), scale=True)
