"""Record 0735: rendered pinhole faces with tracking noise, and the levers tried on them.

    python -m bench.records.r0735 [--faces 0,1,2,3] [--noise 0,0.5,1] [--levers]

Each face (``bench.perspective.face_shapes``, 40 x 400, f = 620 px at 640 x 480) through the
pinhole with Gaussian noise of ``--noise`` pixels on the pixel tracks (seeded face + 300),
normalised with K: e3D (per-frame scale) of the default perspective solve
(``GrassmannNRSfM(projection='perspective')``), of rigid factorisation, and of the default
orthographic solve on the orthographic projections with the same noise relative to the
tracks' spread. ``--levers``: also the perspective solve with the rotation check's margin 0,
with one depth sign per round for all frames, and with every round's rotations rigid.
"""
import argparse
import sys
from unittest import mock

import numpy as np

from grass_nrsfm_ros.nrsfm import camera, GrassmannNRSfM
from grass_nrsfm_ros.nrsfm import perspective
from grass_nrsfm_ros.nrsfm.measurement import centre
from grass_nrsfm_ros.nrsfm.rotation import rigid_factorisation
from grass_nrsfm_ros.nrsfm.stages import rotation_check
from ..perspective import e3d, face_shapes, orthographic, pinhole


def one_sign_per_round(delta, previous):
    """The rounds' sign as one sign for all frames (the lever; shipped: per frame)."""
    agree = np.einsum('fp,fp->', delta, previous) >= 0.0
    return np.full(delta.shape[0], 1.0 if agree else -1.0)


def perspective_e3d(x, truth, **params):
    return e3d(GrassmannNRSfM(projection='perspective', **params).fit(x).S, truth)


def levers(x, truth):
    """``{lever: e3D}`` of the perspective solve with each lever."""
    out = {}
    with mock.patch.object(rotation_check, 'ROTATION_MARGIN', 0.0):
        out['margin_0'] = perspective_e3d(x, truth)
    with mock.patch.object(perspective, 'agreeing_signs', one_sign_per_round):
        out['one_sign'] = perspective_e3d(x, truth)
    out['rigid_rotations'] = perspective_e3d(x, truth, rotations='rigid')
    return out


def noisy_face(seed, sigma):
    """``(x: (2F, P), truth: (3F, P), W_px: (2F, P))``: face ``seed``'s normalised pinhole
    tracks with Gaussian noise of ``sigma`` pixels (seeded), its truth and its pixel tracks."""
    truth = face_shapes(40, 400, seed)
    rng = np.random.default_rng(seed + 300)
    K = pinhole()
    W_px = camera.project(truth, K)
    return camera.normalise(W_px + rng.normal(0.0, sigma, W_px.shape), K), truth, W_px


def face_arguments(argv, description, faces, **flags):
    """The parsed ``--faces`` (default ``faces``) and ``--noise`` of ``argv`` and ``flags``
    (name: default), or None without the face model."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument('--faces', default=faces)
    parser.add_argument('--noise', default='0,0.5,1')
    for name, default in flags.items():
        parser.add_argument(f'--{name}', default=default,
                            action='store_true' if default is False else 'store')
    args = parser.parse_args(argv)
    if face_shapes(4, 10, 0) is None:
        print('the face model is missing (../shared): nothing to measure')
        return None
    return args


def row(seed, sigma, with_levers):
    x, truth, W_px = noisy_face(seed, sigma)
    ortho = orthographic(truth)
    relative = sigma * np.std(centre(ortho)[0]) / np.std(centre(W_px)[0])
    ortho = ortho + np.random.default_rng(seed + 400).normal(0.0, relative, ortho.shape)
    figures = {'perspective': perspective_e3d(x, truth),
               'rigid': e3d(rigid_factorisation(x)[1], truth),
               'orthographic': e3d(GrassmannNRSfM().fit(ortho).S, truth)}
    if with_levers:
        figures.update(levers(x, truth))
    print(f'face {seed} {sigma:g} px: ' + ', '.join(f'{k} {v:.4f}' for k, v in figures.items()),
          flush=True)
    return figures


def main(argv=None):
    args = face_arguments(argv, __doc__.split('\n')[0], '0,1,2,3', levers=False)
    if args is None:
        return 0
    rows = [row(int(f), float(s), args.levers) for s in args.noise.split(',')
            for f in args.faces.split(',')]
    worse = sum(r['perspective'] > r['rigid'] for r in rows)
    print(f'perspective worse than rigid in {worse} of {len(rows)}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
