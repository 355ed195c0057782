"""Record 0004 (nuclear-norm weight gamma): e3D at gamma 1e-3 (default) and 3e-4 .. 3e-2.

    python -m bench.records.r0004 [--full]

Quick: shark, pickup, the Torresani face and the waving sheet (orbit, 60 x 500). ``--full``
adds the dense face 99 x 2,000 (seed 0) and the other synthetic kinds.
"""
from grass_nrsfm_ros.nrsfm.synthetic import kinds
from . import compare

GAMMAS = (1e-3, 3e-4, 3e-3, 1e-2, 3e-2)


def main(argv=None):
    args = compare.parse(argv, __doc__)
    cases = (compare.mocap_cases(('shark', 'pickup', 'face'))
             + compare.synthetic_cases(kinds() if args.full else ('waving',)))
    if args.full:
        cases += compare.face_cases((0,))
    compare.table(cases, [(f'gamma {g:g}', {'gamma': g}) for g in GAMMAS])


if __name__ == '__main__':
    main()
