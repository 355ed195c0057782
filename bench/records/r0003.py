"""Record 0003 (penalty growth rho): e3D and iterations at rho 1.2 (default), 1.1 and 1.3.

    python -m bench.records.r0003 [--full]

Quick: the five synthetic kinds (orbit, seed 0, 60 x 500) and the Torresani face and shark.
``--full``: the record's 53 cases (5 kinds x orbit / wobble / shaky x seeds 0-2 at 60 x 500,
dense faces 99 x 2,000 seeds 0-2, five mocap sets).
"""
from grass_nrsfm_ros.nrsfm.synthetic import kinds
from . import compare

SETTINGS = [('rho 1.2', {}), ('rho 1.1', {'rho': 1.1}), ('rho 1.3', {'rho': 1.3})]


def main(argv=None):
    args = compare.parse(argv, __doc__)
    if args.full:
        cases = (compare.synthetic_cases(kinds(), ('orbit', 'wobble', 'shaky'), (0, 1, 2))
                 + compare.face_cases((0, 1, 2))
                 + compare.mocap_cases(('drink', 'pickup', 'yoga', 'face', 'shark')))
    else:
        cases = compare.synthetic_cases(kinds()) + compare.mocap_cases(('face', 'shark'))
    compare.table(cases, SETTINGS)


if __name__ == '__main__':
    main()
