"""Record 0430 (research variants out of the package): the default path's outputs, saved at
one commit and compared at another (``np.array_equal`` on every array).

    python -m bench.records.r0430 save FILE.npz      # at the earlier commit
    python -m bench.records.r0430 compare FILE.npz   # at the later one

Solves: bending 30 x 300 cold, resumed from its own solution and a model-style start capped
at beta 10 (per call where ``fit`` takes ``beta_max``, else by the parameter), the Surrey face
20 x 1,500 and mocap pickup (skipped without the data), and the live pipeline (windows
inline) on bending 60 x 400: every frame on ``points`` and ``points/refined``.
"""
import inspect
import sys

import numpy as np

from grass_nrsfm_ros.nrsfm import GrassmannNRSfM, WarmStart
from grass_nrsfm_ros.nrsfm.measurement import as_frames
from grass_nrsfm_ros.nrsfm.synthetic import make_sequence
from grass_nrsfm_ros.pipeline import make_pipeline, reconstruct_live
from .. import common


def arrays_of(tag, result):
    return {f'{tag}_S': result.S, f'{tag}_R': result.R, f'{tag}_groups': result.groups,
            f'{tag}_iterations': np.array([s[3] for s in result.report.solves])}


def capped(W, init, cap):
    """A default fit of ``W`` from ``init`` with the penalty capped at ``cap``."""
    if 'beta_max' in inspect.signature(GrassmannNRSfM.fit).parameters:
        return GrassmannNRSfM().fit(W, init=init, beta_max=cap)
    if init.resumed:                       # before the per-call cap: resumed_beta_max 10
        return GrassmannNRSfM().fit(W, init=init)
    return GrassmannNRSfM(beta_max=cap).fit(W, init=init)


def outputs():
    out = {}
    seq = make_sequence('bending', 30, 300)
    cold = GrassmannNRSfM().fit(seq.W)
    out.update(arrays_of('bending', cold))
    resumed = WarmStart(R=cold.R, S=cold.S, resumed=True)
    out.update(arrays_of('resumed', capped(seq.W, resumed, 10.0)))
    model = WarmStart(groups=cold.groups, rotation_method='dai')
    out.update(arrays_of('second', capped(seq.W, model, 10.0)))
    face = common.dense_face(20, 1500)
    if face is not None:
        out.update(arrays_of('face', GrassmannNRSfM().fit(face[0])))
    pickup = common.load_dataset('pickup')
    if pickup is not None:
        out.update(arrays_of('pickup', GrassmannNRSfM().fit(pickup[0])))
    seq = make_sequence('bending', n_frames=60, n_points=400)
    ids = np.arange(seq.W.shape[1])
    points, refined, _ = reconstruct_live(make_pipeline({}), np.arange(60),
                                          [(ids, uv.T) for uv in as_frames(seq.W, 2)])
    out['live_points'] = np.vstack([r.xyz.T for r in points])
    out['live_refined'] = np.vstack([r.xyz.T for r in refined])
    return out


def main(argv=None):
    mode, path = (argv if argv is not None else sys.argv[1:])[:2]
    now = outputs()
    if mode == 'save':
        np.savez(path, **now)
        print(f'saved {len(now)} arrays to {path}')
        return
    with np.load(path) as before:
        names = sorted(set(before.files) & set(now))
        different = [n for n in names if not np.array_equal(before[n], now[n])]
    print(f'compared {len(names)} arrays: {len(different)} different {different}')


if __name__ == '__main__':
    main()
