"""Record 0013 (rotation check): e3D with rotations 'auto' (the check, default), always Dai's
and always the rigid factorisation's.

    python -m bench.records.r0013 [--full]

Quick: the bending sheet (orbit seeds 0-2, shaky seed 1), where the check takes the rigid
rotations, and twisting shaky seed 3 (a margin of 5.2 %: the rigid ones win but 5 % would
have taken them wrongly elsewhere), at 60 x 500. ``--full``: the record's 45 synthetic cases
at seeds 3-5 (5 kinds x orbit / wobble / shaky) and dense faces 99 x 2,000 seeds 3-5.
"""
from grass_nrsfm_ros.nrsfm.synthetic import kinds
from . import compare

SETTINGS = [('auto', {}), ('dai', {'rotations': 'dai'}), ('rigid', {'rotations': 'rigid'})]


def main(argv=None):
    args = compare.parse(argv, __doc__)
    if args.full:
        cases = (compare.synthetic_cases(kinds(), ('orbit', 'wobble', 'shaky'), (3, 4, 5))
                 + compare.face_cases((3, 4, 5)))
    else:
        cases = (compare.synthetic_cases(('bending',), seeds=(0, 1, 2))
                 + compare.synthetic_cases(('bending',), ('shaky',), (1,))
                 + compare.synthetic_cases(('twisting',), ('shaky',), (3,)))
    compare.table(cases, SETTINGS, extra=lambda report: f'{report.rotation_method:>5s}')


if __name__ == '__main__':
    main()
