"""Record 0807: where the real back's error comes from (issue 38's back bar, e3D <= 0.061).

The back (``../shared/data/russell_back``: 150 x 245 pixel tracks, 4 % unseen, stereo truth),
all tracks solved, e3D with per-frame scale over the seen entries with a truth (as
``bench.missing``), its ratio to rigid factorisation on the 126 complete tracks (0.0762), and
e3D on those 126 of the same solve. Variants ``name`` = ``rotations/input/params``:

* rotations: ``est`` (the default chain), ``oracle`` (:func:`bench.missing.oracle_rotations` of
  the camera-frame truth: near the identity, the camera does not move), ``reg`` (the same of
  the truth registered to its first frame, :func:`bench.missing.registered_truth`: the back's
  own turns become rotations), ``rigid`` (``rotations='rigid'``), ``kN`` (Dai's at rank N),
  ``all`` (Dai's on every track completed, ``CORE_SHARE`` inf);
* input: ``px`` (the pixel tracks) or ``wp`` (the weak-perspective image of the true depths:
  normalised coordinates times each point's depth over its frame's mean, the input a perfect
  projective-depth iteration would reach);
* params: one solver parameter ``key=value`` (``-`` for none).

Floors (no solve): rank-k PCA of the truth of the 126 complete tracks (in the camera frame and
registered), the image's x, y with the true depths (the orthographic model's floor), rigid
factorisation on all 245 tracks completed and on the weak-perspective image, the oracle
rotations' spread and the estimates' errors against them.

With ``--mocap`` (record 0808): the four Akhter mocap sequences, our solver with the default,
the rigid and Dai's rank-1 rotations, and the rank rule's reason per sequence.

    python -m bench.records.r0807 [--floors] [--mocap] [--variants est/px/-,oracle/px/-,...]
"""
import argparse
import time

import numpy as np

from bench.missing import back_data, oracle_rotations, registered_truth
from grass_nrsfm_ros.nrsfm import (camera, e3d, estimate_rotations, GrassmannNRSfM,
                                   rigid_factorisation, rotation_error, WarmStart)
from grass_nrsfm_ros.nrsfm.measurement import as_frames
from grass_nrsfm_ros.nrsfm.missing import fill_unseen
from grass_nrsfm_ros.nrsfm.rotation import rotation_spread
from grass_nrsfm_ros.nrsfm.stages import rotations

VARIANTS = ('est/px/-,reg/px/-,oracle/px/-,rigid/px/-,k1/px/-,k2/px/-,k3/px/-,k5/px/-,all/px/-,'
            "est/px/inextensible='never',reg/px/inextensible='never',"
            "reg/px/inextensible='always',reg/px/gamma=1e-2,reg/px/gamma=1e-4,"
            'reg/px/smoothness=0,reg/px/smoothness=1e-3,est/wp/-,rigid/wp/-,reg/wp/-')


def normalised(W):
    """``(F, 2, P)``: the pinhole-normalised coordinates ``K^-1 [u v 1]`` of the back's
    ``W: (2F, P)``."""
    from bench import common
    with np.load(common.data_root() / 'russell_back' / 'back.npz') as z:
        K = z['K'].astype(float)
    return as_frames(camera.normalise(W, K), 2)


def depth_ratio(S, truth):
    """``(F, P)``: each point's true depth over its frame's mean (1 where no truth)."""
    F, P = truth.shape
    Z = np.where(truth, S.reshape(F, 3, P)[:, 2], np.nan)
    return np.where(truth, Z / np.nanmean(Z, axis=1, keepdims=True), 1.0)


def weak_perspective(W, S, truth):
    """``(2F, P)``: the normalised image of ``W`` times :func:`depth_ratio`; NaN where ``W``
    is."""
    return (normalised(W) * depth_ratio(S, truth)[:, None]).reshape(W.shape)


def run_variant(name, data):
    W, S, visible, truth, core, rigid = data
    rot, inp, params = name.split('/')
    kwargs = {} if params == '-' else eval(f'dict({params})')      # noqa: S307 (bench only)
    Wx = weak_perspective(W, S, truth) if inp == 'wp' else W
    init, share = None, rotations.CORE_SHARE
    if rot == 'oracle':
        init = WarmStart(R=oracle_rotations(Wx, S, truth))
    elif rot == 'reg':
        init = WarmStart(R=oracle_rotations(Wx, registered_truth(S, truth), truth))
    elif rot == 'rigid':
        kwargs['rotations'] = 'rigid'
    elif rot.startswith('k'):
        kwargs.update(rotations='dai', K_rot=int(rot[1:]))
    elif rot == 'all':
        rotations.CORE_SHARE = np.inf
    start = time.perf_counter()
    try:
        result = GrassmannNRSfM(**kwargs).fit(Wx, init=init)
    finally:
        rotations.CORE_SHARE = share
    ours = e3d(result.S, S, scale=True, visible=truth)
    on_core = e3d(result.S[:, core], S[:, core], scale=True)
    print(f'{name}: {ours:.4f} (/ rigid {ours / rigid:.3f}), on the 126 {on_core:.4f}, '
          f'K_rot {result.report.K_rot}, {time.perf_counter() - start:.0f} s', flush=True)


def floors(data):
    W, S, visible, truth, core, rigid = data
    F, P = visible.shape
    for name, T in (('camera-frame', S), ('registered', registered_truth(S, truth))):
        Tc = T.reshape(F, 3, P)[:, :, core]
        Tc = (Tc - Tc.mean(axis=2, keepdims=True)).reshape(F, -1)
        U, d, Vt = np.linalg.svd(Tc, full_matrices=False)
        for k in (1, 2, 3, 6):
            fit = ((U[:, :k] * d[:k]) @ Vt[:k]).reshape(3 * F, -1)
            print(f'rank-{k} PCA of the {name} truth (126): '
                  f'{e3d(fit, S[:, core], scale=True):.4f}')
    Z = S.reshape(F, 3, P)[:, 2]
    zbar = np.nanmean(np.where(truth, Z, np.nan), axis=1)[:, None, None]
    ortho = np.concatenate([normalised(W) * zbar, Z[:, None]], axis=1).reshape(3 * F, P)
    print(f'image x, y with the true depths: {e3d(ortho, S, scale=True, visible=truth):.4f}')
    wp = weak_perspective(W, S, truth)
    print(f'rigid on the 126: {rigid:.4f}; on all 245 completed: '
          f'{e3d(rigid_factorisation(fill_unseen(W)[0])[1], S, scale=True, visible=truth):.4f}'
          f'; on the weak-perspective 126: '
          f'{e3d(rigid_factorisation(wp[:, core])[1], S[:, core], scale=True):.4f}')
    R = oracle_rotations(W, S, truth)
    print('oracle rotations of the camera-frame truth: spread '
          f'{rotation_spread(R):.1f} deg')
    R = oracle_rotations(W, registered_truth(S, truth), truth)
    print(f'of the registered truth: spread {rotation_spread(R):.1f} deg; errors (deg) rigid '
          f'{rotation_error(rigid_factorisation(W[:, core])[0], R):.1f}, Dai K 1-6 '
          + ' '.join(f'{rotation_error(estimate_rotations(W[:, core], K=k).R, R):.1f}'
                     for k in range(1, 7)))


def mocap():
    from bench import common
    for name in ('drink', 'pickup', 'yoga', 'dance'):
        with np.load(common.data_root() / 'akhter_mocap' / f'{name}.npz') as z:
            W, S = z['W'].astype(float), z['S'].astype(float)
        rule = estimate_rotations(W).scores['rule']
        errors = [e3d(GrassmannNRSfM(**kw).fit(W).S, S) for kw in
                  ({}, {'rotations': 'rigid'}, {'rotations': 'dai', 'K_rot': 1})]
        print(f'{name}: default / rigid rotations / Dai K 1: '
              + ' / '.join(f'{e:.4f}' for e in errors) + f' ({rule})', flush=True)


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument('--variants', default=VARIANTS)
    parser.add_argument('--floors', action='store_true')
    parser.add_argument('--mocap', action='store_true')
    args = parser.parse_args(argv)
    data = back_data()
    if data is None:
        print('no ../shared/data/russell_back: nothing measured')
        return
    if args.floors:
        floors(data)
    if args.mocap:
        mocap()
    for name in args.variants.split(',') if args.variants else []:
        run_variant(name, data)


if __name__ == '__main__':
    main()
