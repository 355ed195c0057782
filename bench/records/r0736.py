"""Record 0736: Dai's refinement held down at W's noise floor, on noisy pinhole faces.

    python -m bench.records.r0736 [--faces 0,...,7] [--noise 0,0.5,1] [--frontend 0,1,2,3]

Each face of record 0735 (40 x 400, f = 620 px, Gaussian noise of ``--noise`` pixels on the
pixel tracks): e3D (per-frame scale) of the default perspective solve with the penalty
(shipped) and without it (``rotation.NOISE_PENALTY`` 0), and of rigid factorisation.
``--frontend``: faces rendered at 640 x 480 (100 frames, ``scenes.face_scene`` with that
seed) and tracked by the default front end (``bench.frontend``), their complete frame-0
tracks (1,500 evenly subsampled): the same three figures.
"""
import sys
from unittest import mock

from grass_nrsfm_ros.frontend import scenes
from grass_nrsfm_ros.nrsfm import GrassmannNRSfM, rotation
from grass_nrsfm_ros.nrsfm.rotation import rigid_factorisation
from .r0735 import face_arguments, noisy_face
from .. import frontend
from ..perspective import e3d


def figures(x, truth):
    """``{'penalised', 'plain', 'rigid'}`` e3D of normalised tracks ``x: (2F, P)``."""
    out = {'penalised': e3d(GrassmannNRSfM(projection='perspective').fit(x).S, truth)}
    with mock.patch.object(rotation, 'NOISE_PENALTY', 0.0):
        out['plain'] = e3d(GrassmannNRSfM(projection='perspective').fit(x).S, truth)
    out['rigid'] = e3d(rigid_factorisation(x)[1], truth)
    return out


def face_row(seed, sigma):
    x, truth, _ = noisy_face(seed, sigma)
    return report(f'face {seed} {sigma:g} px', figures(x, truth))


def frontend_row(seed):
    scene = scenes.face_scene(100, seed=seed)
    uv, true_uv, X, visible, birth = frontend.track_scene(scene)
    keep = frontend.complete_tracks(birth, uv, visible)
    x, _, truth = frontend.solver_tracks(scene.K, uv[:, keep], true_uv[:, keep], X[:, keep])
    return report(f'front-end face {seed}', figures(x, truth))


def report(name, row):
    print(f"{name}: penalised {row['penalised']:.4f}, plain {row['plain']:.4f}, rigid "
          f"{row['rigid']:.4f} (/ rigid {row['penalised'] / row['rigid']:.3f} against "
          f"{row['plain'] / row['rigid']:.3f})", flush=True)
    return row


def main(argv=None):
    args = face_arguments(argv, __doc__.split('\n')[0], '0,1,2,3,4,5,6,7', frontend='')
    if args is None:
        return 0
    rows = [face_row(int(f), float(s)) for s in args.noise.split(',') if args.faces
            for f in args.faces.split(',')]
    rows += [frontend_row(int(f)) for f in args.frontend.split(',') if f]
    for name in ('penalised', 'plain'):
        worse = sum(r[name] > r['rigid'] for r in rows)
        print(f'{name}: worse than rigid in {worse} of {len(rows)}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
