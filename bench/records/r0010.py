"""Record 0010 (temporal smoothness prior): e3D at smoothness 1e-4 (default), 0 and
3e-4 .. 3e-3.

    python -m bench.records.r0010 [--full]

Quick: shark, the Torresani face, pickup and the inflating and waving sheets (orbit, seed 0,
60 x 500). ``--full``: the record's 29 sequences for 1e-4 against 0 (6 mocap, 5 kinds x
orbit / shaky x seeds 0-1, dense faces 99 x 2,000 seeds 0-2) with the whole sweep.
"""
from grass_nrsfm_ros.nrsfm.synthetic import kinds
from . import compare

WEIGHTS = (1e-4, 0.0, 3e-4, 1e-3, 3e-3)
MOCAP = ('drink', 'pickup', 'yoga', 'dance', 'face', 'shark')


def main(argv=None):
    args = compare.parse(argv, __doc__)
    if args.full:
        cases = (compare.mocap_cases(MOCAP)
                 + compare.synthetic_cases(kinds(), ('orbit', 'shaky'), (0, 1))
                 + compare.face_cases((0, 1, 2)))
    else:
        cases = (compare.mocap_cases(('shark', 'face', 'pickup'))
                 + compare.synthetic_cases(('inflating', 'waving')))
    compare.table(cases, [(f'smoothness {w:g}', {'smoothness': w}) for w in WEIGHTS])


if __name__ == '__main__':
    main()
