"""Record 0440: ``surface='sheet'`` through the wired path (``grass-nrsfm reconstruct`` of the
pixel tracks with K and ``solver: {surface: sheet}``) on the real 10-frame subsets, e3D with a
per-frame scale against the default.

    python -m bench.records.r0440
"""
import sys

import numpy as np

from bench import common, perspective


def main():
    for name in ('kinect_paper10', 'tshirt10'):
        loaded = common.load_dataset(name)
        if loaded is None:
            common.log(f'{name}: no data')
            continue
        with np.load(common.data_root() / common.DATASETS[name][0]) as npz:
            W_px, K = npz['W_px'].astype(np.float64), npz['K']
        for config in ('', 'solver:\n  surface: sheet\n'):
            S, report, _ = perspective.reconstructed(W_px, K, config or None)
            common.log(f"{name} {'sheet' if config else 'default'}: e3D "
                       f'{perspective.e3d(S, loaded[1]):.4f} stages {report.get("stages")}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
