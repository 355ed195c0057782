"""Record 0024 (inextensible sign rounds): e3D with the default 3 sign rounds at rank 2
against the sign sweeps alone (0 rounds) and rank 3, where 'auto' refines.

    python -m bench.records.r0024 [--full]

The rounds are arguments of ``inextensible.refine_depth``, not solver parameters: the other
settings wrap the refinement stage's call. Quick: articulated shaky seed 2, twisting orbit
seed 0, bending shaky seed 0 (the record's examples, 60 x 500). ``--full``: 5 kinds x orbit /
wobble / shaky x seeds 0-2 (the record's 36 refined cases are those where 'auto' refines).
"""
import functools

from grass_nrsfm_ros.nrsfm import GrassmannNRSfM
from grass_nrsfm_ros.nrsfm.inextensible import refine_depth
from grass_nrsfm_ros.nrsfm.stages import refinement
from grass_nrsfm_ros.nrsfm.synthetic import kinds
from . import compare


def with_refinement(**options):
    """A default fit whose refinement stage calls ``refine_depth`` with ``options``."""
    def fit(W):
        refinement.refine_depth = functools.partial(refine_depth, **options)
        try:
            return GrassmannNRSfM().fit(W)
        finally:
            refinement.refine_depth = refine_depth
    return fit


SETTINGS = [('3 rounds, rank 2', {}), ('sweeps alone', with_refinement(sign_rounds=0)),
            ('3 rounds, rank 3', with_refinement(sign_rank=3))]


def main(argv=None):
    args = compare.parse(argv, __doc__)
    if args.full:
        cases = compare.synthetic_cases(kinds(), ('orbit', 'wobble', 'shaky'), (0, 1, 2))
    else:
        cases = (compare.synthetic_cases(('articulated',), ('shaky',), (2,))
                 + compare.synthetic_cases(('twisting',))
                 + compare.synthetic_cases(('bending',), ('shaky',)))
    compare.table(cases, SETTINGS,
                  extra=lambda report: 'inex' if report.inextensible else '    ')


if __name__ == '__main__':
    main()
