"""Record 0007 (regrouping): e3D and points regrouped at affinity_min 0.5 (the paper's gate,
default) and 0 (every group may exchange points).

    python -m bench.records.r0007 [--full]

Quick: dense face 99 x 1,000 (or the bending sheet 60 x 1,000 without the face model);
``--full``: face 99 x 2,000 (the record's case) and the five synthetic kinds.
"""
from unittest import mock

from grass_nrsfm_ros.nrsfm import config, GrassmannNRSfM
from grass_nrsfm_ros.nrsfm.synthetic import kinds
from . import compare


def ungated(W):
    """A fit with the gate at 0 (config.AFFINITY_MIN, a parameter until record 0430)."""
    with mock.patch.object(config, 'AFFINITY_MIN', 0.0):
        return GrassmannNRSfM().fit(W)


SETTINGS = [('affinity_min 0.5', {}), ('affinity_min 0', ungated)]


def main(argv=None):
    args = compare.parse(argv, __doc__)
    cases = compare.face_cases((0,), P=2000 if args.full else 1000)
    if args.full or not cases:
        cases += compare.synthetic_cases(kinds() if args.full else ('bending',), P=1000)
    compare.table(cases, SETTINGS, extra=lambda report: f'{report.regrouped_points:4d}mv')


if __name__ == '__main__':
    main()
