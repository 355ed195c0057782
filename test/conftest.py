"""Shared fixtures: the benchmark data folder and ROS isolation.

Data: ``$GRASS_NRSFM_DATA`` or ``../shared/data`` beside the checkout; tests that need it skip
cleanly where it is absent.
"""
import os
from pathlib import Path
import random

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


@pytest.fixture
def ros_env(tmp_path, monkeypatch):
    """Isolated DDS for this process and the subprocesses it starts: a random domain (0..101),
    localhost discovery, logs in tmp, one BLAS thread. Returns the environment for
    subprocesses (PYTHONPATH: the checkout and test/, so test helpers import)."""
    pytest.importorskip('rclpy')
    env = {'ROS_DOMAIN_ID': str(random.randint(0, 101)),
           'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST', 'ROS_LOG_DIR': str(tmp_path / 'log'),
           'OPENBLAS_NUM_THREADS': '1', 'OMP_NUM_THREADS': '1'}
    for key, value in env.items():
        monkeypatch.setenv(key, value)
    monkeypatch.delenv('ROS_LOCALHOST_ONLY', raising=False)
    return {**os.environ, 'PYTHONPATH': os.pathsep.join([str(REPO), str(REPO / 'test')])}
