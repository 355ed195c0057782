"""Record 0026 (thinning of over-dense track clusters): e3D with thinning 'auto' (default)
and 'never' on surfaces with 40 % of their tracks in two small patches.

    python -m bench.records.r0026 [--full]

Quick: the five kinds (orbit, seed 0, 60 x 500, clustered 0.4). ``--full``: orbit / shaky x
seeds 0-2. (The record's 210 cases used 7 cluster layouts; the generator has one.) The
accuracy table's ``synthetic_inflating_clustered`` row (``python -m bench --full --only
accuracy``) is the 60 x 3,000 case with 'auto'.
"""
from grass_nrsfm_ros.nrsfm.synthetic import kinds
from . import compare

SETTINGS = [('auto', {}), ('never', {'thinning': 'never'})]


def main(argv=None):
    args = compare.parse(argv, __doc__)
    cameras, seeds = (('orbit', 'shaky'), (0, 1, 2)) if args.full else (('orbit',), (0,))
    cases = compare.synthetic_cases(kinds(), cameras, seeds, clustered=0.4)
    compare.table(cases, SETTINGS, extra=lambda report: f'{report.thinned_points:4d}th')


if __name__ == '__main__':
    main()
