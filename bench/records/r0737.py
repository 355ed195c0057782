"""Record 0737: orthographic sheets, per-frame isometric fits joined by a Viterbi path.

    python -m bench.records.r0737 [--seeds 2,3]

``TransportSheetNRSfM`` (``GrassmannNRSfM(surface='sheet')`` on orthographic tracks), e3D with
a per-frame scale over rigid factorisation's, on sheets ``bench.sheets`` does not run: the
synthetic and rendered 'bending', 'flag' and 'waving' sheets of the held-out ``--seeds`` (40 x
300), the synthetic isometric sheets of seeds 0-1 with noise (0.003, 0.01; the sheets are about
2 across) and smaller sequences (20 x 150, 40 x 150, seeds 0-2). The script uses only the
package's public API, so run at an earlier commit it measures that commit's method.
"""
import argparse
import time

from bench.sheets import rendered_sheet
from grass_nrsfm_ros.nrsfm import e3d, GrassmannNRSfM, synthetic
from grass_nrsfm_ros.nrsfm.rotation import rigid_factorisation


def ratio(W, S):
    """``(e3D / rigid's, CPU seconds)`` of the orthographic sheet model on ``W: (2F, P)``."""
    start = time.process_time()
    S_hat = GrassmannNRSfM(surface='sheet').fit(W).S
    seconds = time.process_time() - start
    return e3d(S_hat, S, scale=True) / e3d(rigid_factorisation(W)[1], S, scale=True), seconds


def synthetic_ratio(kind, F, P, seed, noise=0.0):
    seq = synthetic.make_sequence(kind, n_frames=F, n_points=P, seed=seed, noise=noise)
    return ratio(seq.W, seq.S)[0]


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m bench.records.r0737', description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--seeds', default='2,3')
    seeds = [int(s) for s in parser.parse_args(argv).seeds.split(',')]
    print('held-out sheets, 40 x 300: e3D / rigid (CPU s)')
    for kind in ('bending', 'flag', 'waving'):
        for seed in seeds:
            q = synthetic.make_sequence(kind, n_frames=40, n_points=300, seed=seed)
            cells = [ratio(q.W, q.S), ratio(*rendered_sheet(kind, 40, 300, seed))]
            print(f'{kind:8s} seed {seed}: synthetic {cells[0][0]:.3f} ({cells[0][1]:.1f}), '
                  f'rendered {cells[1][0]:.3f} ({cells[1][1]:.1f})', flush=True)
    print('noise (synthetic, 40 x 300, seeds 0 / 1)')
    for noise in (0.003, 0.01):
        for kind in ('bending', 'flag'):
            print(f'{noise:5} {kind:8s} ' + ' / '.join(
                f'{synthetic_ratio(kind, 40, 300, s, noise):.2f}' for s in (0, 1)), flush=True)
    print('smaller sequences (synthetic, seeds 0 / 1 / 2)')
    for F, P in ((20, 150), (40, 150)):
        for kind in ('bending', 'flag'):
            print(f'{F} x {P} {kind:8s} ' + ' / '.join(
                f'{synthetic_ratio(kind, F, P, s):.2f}' for s in (0, 1, 2)), flush=True)


if __name__ == '__main__':
    main()
