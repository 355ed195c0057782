"""Record 0022 (inextensible 'auto' from 100 tracks): e3D with inextensible 'auto' and
'never' on synthetic surfaces of 120 and 200 tracks (60 frames).

    python -m bench.records.r0022 [--full]

Quick: the five kinds (orbit, seed 0) at 120 tracks. ``--full``: the record's 5 kinds x
orbit / wobble / shaky x seeds 0-2 at 120 and at 200 tracks.
"""
from grass_nrsfm_ros.nrsfm.synthetic import kinds
from . import compare

SETTINGS = [('auto', {}), ('never', {'inextensible': 'never'})]


def main(argv=None):
    args = compare.parse(argv, __doc__)
    if args.full:
        cases = [case for P in (120, 200) for case in compare.synthetic_cases(
            kinds(), ('orbit', 'wobble', 'shaky'), (0, 1, 2), P=P)]
    else:
        cases = compare.synthetic_cases(kinds(), P=120)
    compare.table(cases, SETTINGS,
                  extra=lambda report: 'inex' if report.inextensible else '    ')


if __name__ == '__main__':
    main()
