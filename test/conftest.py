"""Shared fixtures: the benchmark data folder and ROS isolation.

Data: ``$GRASS_NRSFM_DATA`` or ``../shared/data`` beside the checkout; tests that need it skip
cleanly where it is absent.
"""
import os
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]


def data_root():
    """The benchmark data folder, or None."""
    root = Path(os.environ.get('GRASS_NRSFM_DATA', REPO.parent / 'shared' / 'data'))
    return root if root.is_dir() else None


def load_dataset(relpath):
    """``(W, S)`` float64 from ``<data>/<relpath>``, or skip the test."""
    root = data_root()
    if root is None or not (root / relpath).is_file():
        pytest.skip(f'benchmark data {relpath} not found (set GRASS_NRSFM_DATA)')
    with np.load(root / relpath) as npz:
        return npz['W'].astype(np.float64), npz['S'].astype(np.float64)


@pytest.fixture
def dataset():
    return load_dataset
