"""Style: the package, tests and benchmarks pass flake8 with ament_flake8's settings
(setup.cfg [flake8]: 99 columns, google import order, single quotes)."""
import subprocess
import sys

import pytest

from conftest import REPO


@pytest.mark.linter
def test_flake8():
    pytest.importorskip('flake8')
    pytest.importorskip('flake8_quotes')
    pytest.importorskip('flake8_import_order')
    result = subprocess.run([sys.executable, '-m', 'flake8', 'grass_nrsfm_ros', 'test', 'bench',
                             'launch', 'setup.py'], cwd=REPO, capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr
