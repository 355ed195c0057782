"""Records 0011 and 0035 (a first window started from the rigid factorisation, warm_beta0):
frames 0-29 of a sequence solved cold (from scratch), by the rigid factorisation alone, and
by the solver started from the rigid R and S at warm_beta0 0.01 (default), 0.1 and 1.

    python -m bench.records.r0011 [--full]

Quick: the dense face (60 x 2,000, frames 0-29; the bending sheet without the face model) and
pickup's first 30 frames. ``--full`` adds the five synthetic kinds (orbit, 60 x 500).
"""
from unittest import mock

from grass_nrsfm_ros.nrsfm import config, GrassmannNRSfM, WarmStart
from grass_nrsfm_ros.nrsfm.rotation import rigid_factorisation
from grass_nrsfm_ros.nrsfm.synthetic import kinds
from . import compare

FRAMES = 30


class Rigid:
    """The rigid factorisation as a result (report with 0 iterations)."""

    def __init__(self, W):
        self.R, self.S = rigid_factorisation(W)
        self.report = type('Report', (), {'iterations': 0})()


def from_rigid(warm_beta0):
    """A fit started from the rigid factorisation's R and S at ``warm_beta0``
    (config.WARM_BETA0, a parameter until record 0430)."""
    def fit(W):
        R, S = rigid_factorisation(W)
        with mock.patch.object(config, 'WARM_BETA0', warm_beta0):
            return GrassmannNRSfM().fit(W, init=WarmStart(R=R, S=S))
    return fit


def main(argv=None):
    args = compare.parse(argv, __doc__)
    cases = compare.face_cases((0,), F=60, P=2000) or compare.synthetic_cases(('bending',))
    cases += compare.mocap_cases(('pickup',))
    if args.full:
        cases += compare.synthetic_cases(kinds())
    first_window = [(name, W[:2 * FRAMES], S[:3 * FRAMES]) for name, W, S in cases]
    settings = [('cold', {}), ('rigid', Rigid)] + [
        (f'rigid start, {b:g}', from_rigid(b)) for b in (0.01, 0.1, 1.0)]
    compare.table(first_window, settings)


if __name__ == '__main__':
    main()
