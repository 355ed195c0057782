"""A real run of ``python -m bench --smoke`` (each suite's smallest case) and of the table
generator on what it wrote."""
import json
import math
import os
from pathlib import Path
import subprocess
import sys

import pytest

from bench import table
from bench.__main__ import chosen_suites, QUICK_SKIPS, SUITES as ALL_SUITES

REPO = Path(__file__).resolve().parents[1]
SUITES = ('accuracy', 'noise', 'parameters', 'scale', 'streaming', 'rotations')
#: numbers every row of a suite must carry, finite
ROW_KEYS = {'accuracy': ('e3d', 'seconds_wall', 'seconds_cpu', 'F', 'P'),
            'noise': ('r', 'e3d_mean', 'e3d_std', 'seconds_cpu_mean'),
            'parameters': ('e3d', 'seconds_cpu'),
            'scale': ('F', 'P', 'seconds_wall', 'seconds_cpu', 'rss_peak_mb', 'solve_extra_mb'),
            'streaming': ('P', 'fps', 'latency_mean_s', 'latency_max_s', 'frames_published'),
            'rotations': ('e3d', 'e3d_akhter', 'rotation_seconds_cpu', 'seconds_cpu', 'F', 'P')}


@pytest.fixture(scope='module')
def smoke_results(tmp_path_factory):
    out = tmp_path_factory.mktemp('bench_smoke')
    env = dict(os.environ, OPENBLAS_NUM_THREADS='1', OMP_NUM_THREADS='1',
               PYTHONPATH=os.pathsep.join(filter(None, [str(REPO),
                                                        os.environ.get('PYTHONPATH')])))
    proc = subprocess.run([sys.executable, '-m', 'bench', '--smoke', '--out', str(out)],
                          cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return out


def finite_numbers(x):
    if isinstance(x, dict):
        return all(finite_numbers(v) for v in x.values())
    if isinstance(x, list):
        return all(finite_numbers(v) for v in x)
    return not isinstance(x, float) or math.isfinite(x)


@pytest.mark.parametrize('suite', SUITES)
def test_smoke_json_has_finite_numbers_and_expected_keys(smoke_results, suite):
    doc = json.loads((smoke_results / f'{suite}.json').read_text())
    assert doc['suite'] == suite and doc['mode'] == 'smoke'
    assert {'environment', 'rows', 'skipped', 'seconds', 'cpu_seconds'} <= set(doc)
    assert doc['cpu_seconds'] > 0
    for skip in doc['skipped']:
        # the only acceptable skip is a module that is not there yet, never a crash
        assert 'not available' in skip['why'], skip
    if not doc['rows']:
        assert doc['skipped'], f'{suite}: no rows and no reason'
        pytest.skip(f'{suite}: dependencies missing: {doc["skipped"][0]["why"]}')
    for row in doc['rows']:
        for key in ROW_KEYS[suite]:
            assert isinstance(row.get(key), (int, float)), (suite, key, row.get(key))
        assert finite_numbers(row), row


def test_quick_run_leaves_out_the_research_suites_unless_named():
    assert chosen_suites('quick') == [s for s in ALL_SUITES if s not in QUICK_SKIPS]
    assert QUICK_SKIPS and set(QUICK_SKIPS) < set(ALL_SUITES)
    assert chosen_suites('full') == chosen_suites('smoke') == list(ALL_SUITES)
    assert chosen_suites('quick', ['rotations']) == ['rotations']


def test_accuracy_errors_are_errors(smoke_results):
    doc = json.loads((smoke_results / 'accuracy.json').read_text())
    for row in doc['rows']:
        assert 0.0 <= row['e3d'] < 2.0, row        # relative error of a sane reconstruction


def test_results_page_renders_every_suite(smoke_results, tmp_path):
    page = tmp_path / 'docs' / 'results.md'
    assert table.main(['--results', str(smoke_results), '--write', str(page)]) == 0
    text = page.read_text()
    assert text.startswith(table.HEADER[0] + '\n')
    assert 'python -m bench.table --write docs/results.md' in text
    for suite, name, _, _ in table.SECTIONS:
        if suite in SUITES:
            assert f'\n## {name}\n' in text and f'(#{table.anchor(name)})' in text, suite
    assert '| sequence | F x P | ours |' in text          # the accuracy table's header row


def test_results_page_links_the_plots_that_exist(tmp_path):
    results, page_dir = tmp_path / 'bench' / 'results', tmp_path / 'docs'
    results.mkdir(parents=True)
    (results / 'noise.png').write_bytes(b'png')
    doc = {'mode': 'quick', 'sequence': 'seq', 'F': 2, 'P': 3, 'plots': ['noise.png', 'gone.png'],
           'rows': [{'method': 'ours', 'r': 0.0, 'e3d_mean': 0.1, 'e3d_std': 0.0}]}
    (results / 'noise.json').write_text(json.dumps(doc))
    text = table.page(results, page_dir)
    assert 'Plots: [noise](../bench/results/noise.png)\n' in text
    assert 'gone' not in text and '## Accuracy' not in text     # only what exists is shown


def test_committed_results_page_is_the_generated_one():
    """docs/results.md is what ``python -m bench.table --write docs/results.md`` writes from
    the committed bench/results (regenerate it after a benchmark run)."""
    assert table.PAGE.read_text() == table.page(table.common.RESULTS, table.PAGE.parent)
