"""Record 0021 (inextensible depth refinement): e3D with inextensible 'auto' (default),
'never' (the paper) and 'always'.

    python -m bench.records.r0021 [--full]

Quick: the five kinds (orbit, seed 2, 60 x 500) and bending / articulated shaky seed 2.
``--full``: the record's 54 cases (6 mocap, 5 kinds x orbit / wobble / shaky x seeds 0-2 at
60 x 500, dense faces 99 x 2,000 seeds 0-2).
"""
from grass_nrsfm_ros.nrsfm.synthetic import kinds
from . import compare

SETTINGS = [('auto', {}), ('never', {'inextensible': 'never'}),
            ('always', {'inextensible': 'always'})]
MOCAP = ('drink', 'pickup', 'yoga', 'dance', 'face', 'shark')


def main(argv=None):
    args = compare.parse(argv, __doc__)
    if args.full:
        cases = (compare.mocap_cases(MOCAP)
                 + compare.synthetic_cases(kinds(), ('orbit', 'wobble', 'shaky'), (0, 1, 2))
                 + compare.face_cases((0, 1, 2)))
    else:
        cases = (compare.synthetic_cases(kinds(), seeds=(2,))
                 + compare.synthetic_cases(('bending', 'articulated'), ('shaky',), (2,)))
    compare.table(cases, SETTINGS,
                  extra=lambda report: 'inex' if report.inextensible else '    ')


if __name__ == '__main__':
    main()
