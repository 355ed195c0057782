"""Record 0431 (the live flow in rooms): the live pipeline's outputs, saved from one tree and
compared with another's (``np.array_equal`` on every frame of ``points`` and
``points/refined``).

    git worktree add ../grass-764e969 764e969
    python -m bench.records.r0431 save /tmp/before.npz --package-root ../grass-764e969
    python -m bench.records.r0431 compare /tmp/before.npz

Sequences: bending 60 x 300 and articulated 50 x 200 (``make_sequence``, seed 0), default
parameters, each window solved as it closes. Works with the package before issue #40
(``grass_nrsfm_ros.live``) and after it (``grass_nrsfm_ros.pipeline``).
"""
import argparse
import sys

import numpy as np

CASES = (('bending', 60, 300), ('articulated', 50, 200))


def outputs():
    """``{name: array}`` of every frame's xyz on points and points/refined."""
    from grass_nrsfm_ros.nrsfm.measurement import as_frames
    from grass_nrsfm_ros.nrsfm.synthetic import make_sequence
    try:
        from grass_nrsfm_ros.pipeline import make_pipeline, reconstruct_live
    except ImportError:                                   # before issue #40
        from grass_nrsfm_ros.live import make_pipeline, reconstruct_live
    out = {}
    for kind, F, P in CASES:
        seq = make_sequence(kind, n_frames=F, n_points=P, seed=0)
        ids = np.arange(P) + 3
        points, refined = reconstruct_live(make_pipeline({}), list(range(F)),
                                           [(ids, uv.T) for uv in as_frames(seq.W, 2)])[:2]
        for name, results in (('points', points), ('refined', refined)):
            out[f'{kind}_{name}_stamps'] = np.array([r.stamp_ns for r in results])
            out[f'{kind}_{name}_xyz'] = np.stack([r.xyz for r in results])
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m bench.records.r0431', description=__doc__)
    parser.add_argument('action', choices=('save', 'compare'))
    parser.add_argument('file')
    parser.add_argument('--package-root', help='import grass_nrsfm_ros from this tree')
    args = parser.parse_args(argv)
    if args.package_root:
        sys.path.insert(0, args.package_root)
    now = outputs()
    if args.action == 'save':
        np.savez(args.file, **now)
        import grass_nrsfm_ros
        print(f'{args.file}: {len(now)} arrays saved from {grass_nrsfm_ros.__file__}')
        return 0
    with np.load(args.file) as before:
        different = [k for k in now if not np.array_equal(now[k], before[k])]
    print(f'compared {len(now)} arrays: {len(different)} different {different}')
    return 1 if different else 0


if __name__ == '__main__':
    sys.exit(main())
