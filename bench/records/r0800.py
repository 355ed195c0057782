"""Record 0800: how unseen entries enter Algorithm 1's S update, and what the rotations and the
start are taken from. Side by side on the synthetic kinds with 20 % of the entries hidden in
occlusion blocks (60 x 400, noise r 0.005), e3D over every entry:

* ``exact`` (shipped): the weighted S update, per entry / per pattern;
* ``em``: imputation, each S update fitting ``M o W + (1 - M) o (R S)`` with the current S
  (the weighted data term's majoriser; the unweighted closed form and banded solve unchanged);
* both with the true rotations too, to separate the S update from the rotations;
* ``complete``: the same tracks with nothing hidden.

    python -m bench.records.r0800 [--kinds bending,inflating]
"""
import argparse
import sys

import numpy as np

from grass_nrsfm_ros.nrsfm import admm, e3d, GrassmannNRSfM, synthetic, WarmStart
from grass_nrsfm_ros.nrsfm import solver as solver_module


class EMState(admm.AdmmState):
    """Algorithm 1 with the unseen entries imputed from the current S instead of weighted."""

    def _update_shapes(self, cols, beta):
        if self.M is None:
            return super()._update_shapes(cols, beta)
        M, W = self.M, self.W
        fit = np.matmul(self.R2, self.S[:, :, cols])
        imputed = fit + M[:, :, cols] * (W[:, :, cols] - fit)
        self.M, self.W = None, W.copy()
        self.W[:, :, cols] = imputed
        try:
            super()._update_shapes(cols, beta)
        finally:
            self.M, self.W = M, W


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--kinds', default=','.join(synthetic.kinds()))
    args = parser.parse_args(argv)
    shipped = admm.AdmmState
    for kind in args.kinds.split(','):
        seq = synthetic.make_sequence(kind, n_frames=60, n_points=400, noise=0.005, seed=3)
        visible = synthetic.occlusion_mask(seq.W, 0.2, np.random.default_rng(103))
        W = np.where(np.repeat(visible, 2, axis=0), seq.W, np.nan)
        cells = [f'complete {e3d(GrassmannNRSfM().fit(seq.W).S, seq.S):.4f}']
        for init_name, init in (('estimated R', None), ('true R', WarmStart(R=seq.R))):
            for name, state in (('exact', shipped), ('em', EMState)):
                solver_module.AdmmState = state
                try:
                    value = e3d(GrassmannNRSfM().fit(W, init=init).S, seq.S)
                finally:
                    solver_module.AdmmState = shipped
                cells.append(f'{name} ({init_name}) {value:.4f}')
        print(f'{kind}: ' + ', '.join(cells), flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
