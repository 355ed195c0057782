"""Record 0014 (rotations registered to the refined shapes): e3D with the stage (default) and
without it (an empty WarmStart skips it; the parameter register_rotations until record 0430).

    python -m bench.records.r0014 [--full]

Quick: the record's examples at 60 x 500 (twisting orbit seed 5, bending orbit / shaky seed 1,
bending orbit seed 0) and the five kinds (orbit, seed 0). ``--full``: the record's 90 cases
(5 kinds x orbit / wobble / shaky x seeds 0-5).
"""
from grass_nrsfm_ros.nrsfm import GrassmannNRSfM, WarmStart
from grass_nrsfm_ros.nrsfm.synthetic import kinds
from . import compare


def unregistered(W):
    return GrassmannNRSfM().fit(W, init=WarmStart())


SETTINGS = [('auto', {}), ('never', unregistered)]


def main(argv=None):
    args = compare.parse(argv, __doc__)
    if args.full:
        cases = compare.synthetic_cases(kinds(), ('orbit', 'wobble', 'shaky'), range(6))
    else:
        cases = (compare.synthetic_cases(('twisting',), seeds=(5,))
                 + compare.synthetic_cases(('bending',), ('orbit', 'shaky'), (1,))
                 + compare.synthetic_cases(kinds()))
    compare.table(cases, SETTINGS,
                  extra=lambda report: 'reg' if report.rotations_registered else '   ')


if __name__ == '__main__':
    main()
