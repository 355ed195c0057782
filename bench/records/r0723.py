"""Record 0723: the maximum-depth heuristic's anchors chosen among the tracks their neighbours
reproduce.

``kinect``: the seed paper's kinect_paper sequence tracked from its 191 images (as
``bench.kinect_paper``), the maximum depth on its complete tracks in the 10 frames where its
truth is located, scored there (e3D with a per-frame scale on the 60 tied truth points), for
each anchor rule; also the truth points' own pixels and their pixels carried by the tracks
(every point an anchor). ``synthetic``: the pinhole bending sheet of ``test_max_depth`` (10 x
300, 60 anchors), seeds 0-2, clean and with noise 0.003 (about 2 px at f = 620), e3D / rigid.

    python -m bench.records.r0723 [--what kinect,synthetic]
"""
import argparse
import json

import numpy as np

from bench import kinect_paper as kp
from bench.common import data_root
from grass_nrsfm_ros.nrsfm import camera, max_depth, metrics, synthetic
from grass_nrsfm_ros.nrsfm.measurement import as_frames, frame_rows, from_frames
from grass_nrsfm_ros.nrsfm.rotation import rigid_factorisation

SHIPPED = max_depth.anchor_tracks


def every_track(W, n):
    """Record 0709's anchors: farthest-point sampling over all tracks."""
    original = max_depth.consistent_tracks
    max_depth.consistent_tracks = lambda W: np.arange(W.shape[1])
    try:
        return SHIPPED(W, n)
    finally:
        max_depth.consistent_tracks = original


def first_image_kmeans(W, n):
    """Tried: the track nearest each of n k-means centres of the first frame's image points."""
    from sklearn.cluster import KMeans
    first = W[:2].T
    centres = KMeans(n, n_init=1, random_state=0).fit(first).cluster_centers_
    return np.unique(np.linalg.norm(first[:, None] - centres[None], axis=2).argmin(0))


RULES = {'every track (0709)': every_track, 'consistent (shipped)': SHIPPED,
         'k-means, first image': first_image_kmeans}


def fitted(W, rule, n):
    max_depth.anchor_tracks = rule
    try:
        return max_depth.MaxDepthNRSfM(max_tracks=n).fit(W).S
    finally:
        max_depth.anchor_tracks = SHIPPED


def kinect():
    root = data_root()
    folder = root / 'kinect_paper_images'
    K = np.array(json.loads((folder / 'meta.json').read_text())['K'], dtype=np.float64)
    W, *_ = kp.track(folder / 'frames', K, 4, None, method=kp.TRACKER['method'],
                     min_zncc=kp.TRACKER['min_zncc'], reanchor_zncc=kp.TRACKER['reanchor_zncc'])
    W_px = W[:, np.isfinite(W).all(axis=0)]
    with np.load(root / 'perspective_subsets' / 'kinect_paper.npz') as npz:
        W_gt_px, S_gt = npz['W_px'].astype(np.float64), npz['S'].astype(np.float64)
    match = kp.locate_subset(W_px, W_gt_px, 3.0)
    frames = match['frames']
    x = camera.normalise(W_px[frame_rows(frames, 2)], K)
    F3 = 3 * (W_px.shape[0] // 2)

    def score(S_frames):
        S = np.full((F3, W_px.shape[1]), np.nan)
        S[frame_rows(frames, 3)] = S_frames
        return kp.subset_e3d(S, match, S_gt)
    print(f'kinect_paper: {W_px.shape[1]} complete tracks, located frames {frames + 1}')
    print(f'  rigid on the tracks: {score(rigid_factorisation(x)[1]):.4f}')
    for name, rule in RULES.items():
        print(f'  anchors {name}: {score(fitted(x, rule, max_depth.MAX_TRACKS)):.4f}')
    tied = match['tied']
    uv = np.stack([W_px[0::2], W_px[1::2]], axis=-1)[frames]
    carried = np.einsum('fnkc,nk->fnc', uv[:, match['tracks']], match['weights'])
    for name, pixels in (('truth pixels', W_gt_px[:, tied]),
                         ('carried by the tracks', from_frames(carried.transpose(0, 2, 1)))):
        S = max_depth.MaxDepthNRSfM().fit(camera.normalise(pixels, K)).S
        print(f'  the {tied.sum()} truth points, {name}, every one an anchor: '
              f'{metrics.e3d(S, S_gt[:, tied], scale=True):.4f}')


def sheet(seed, noise):
    X = as_frames(synthetic.make_sequence('bending', n_frames=10, n_points=300, seed=seed).S,
                  3).copy()
    X[:, 2] += 5.0
    S = from_frames(X)
    W = camera.project(S)
    return W + noise * np.random.default_rng(seed).standard_normal(W.shape), S


def synthetic_rows():
    for seed in (0, 1, 2):
        for noise in (0.0, 0.003):
            W, S = sheet(seed, noise)
            rigid = metrics.e3d(rigid_factorisation(W)[1], S, scale=True)
            ratios = ', '.join(
                f'{name} {metrics.e3d(fitted(W, rule, 60), S, scale=True) / rigid:.3f}'
                for name, rule in RULES.items())
            print(f'bending seed {seed}, noise {noise}: {ratios}', flush=True)


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m bench.records.r0723')
    parser.add_argument('--what', default='kinect,synthetic')
    what = parser.parse_args(argv).what.split(',')
    if 'kinect' in what:
        kinect()
    if 'synthetic' in what:
        synthetic_rows()
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
