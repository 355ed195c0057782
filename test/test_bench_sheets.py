"""bench.sheets --kinds: a run of some kinds replaces those kinds' rows of the JSON there and
keeps the others (record 0713)."""
import json

import pytest

from bench import common, sheets


def row(name, projection='orthographic'):
    return {'sequence': name, 'projection': projection, 'rigid': 1.0, 'ratios': {}}


def test_a_kinds_run_replaces_its_rows_and_keeps_the_others(tmp_path):
    old = [row(f'{source}_{kind}_seed{seed}', projection)
           for projection in ('orthographic', 'pinhole') for kind in ('bending', 'waving')
           for seed in (0, 1) for source in ('synthetic', 'rendered')]
    old += [row('kinect_paper10', 'pinhole'), row('tshirt10', 'pinhole')]
    for r in old:
        r['rigid'] = 2.0 if 'waving' in r['sequence'] else 1.0
    (tmp_path / 'sheets.json').write_text(json.dumps(
        {'mode': 'quick', 'rows': old, 'environment': {'date': 'then', 'git': 'abc'}}))
    mode = common.Mode('quick', out=tmp_path)
    new = [row(f'{source}_{kind}_seed{seed}', projection)
           for projection in ('orthographic', 'pinhole') for kind in ('waving', 'flag')
           for seed in (0, 1) for source in ('synthetic', 'rendered')]
    rows, runs = sheets.merged(mode, new, ('waving', 'flag'))
    names = [(r['sequence'], r['projection']) for r in rows]
    assert len(rows) == len(old) + 8 and len(set(names)) == len(names)
    assert all(r['rigid'] == 1.0 for r in rows)          # the old waving rows are gone
    assert names[:4] == [('synthetic_bending_seed0', 'orthographic'),
                         ('rendered_bending_seed0', 'orthographic'),
                         ('synthetic_bending_seed1', 'orthographic'),
                         ('rendered_bending_seed1', 'orthographic')]
    assert names[8:10] == [('synthetic_flag_seed0', 'orthographic'),
                           ('rendered_flag_seed0', 'orthographic')]
    assert names[-2:] == [('kinect_paper10', 'pinhole'), ('tshirt10', 'pinhole')]
    assert runs[0] == {'kinds': ['bending', 'real'], 'date': 'then', 'git': 'abc'}
    assert runs[1]['kinds'] == ['waving', 'flag']


def test_a_kinds_run_merges_into_its_own_mode_only(tmp_path):
    (tmp_path / 'sheets.json').write_text(json.dumps({'mode': 'full', 'rows': []}))
    with pytest.raises(SystemExit, match='full run'):
        sheets.merged(common.Mode('quick', out=tmp_path), [], ('flag',))


def test_an_options_run_adds_its_figures_and_keeps_the_rows_others(tmp_path):
    old = [dict(row(f'{source}_flag_seed0', projection), default=2.0, ratios={'default': 2.0})
           for projection in ('orthographic', 'pinhole') for source in ('synthetic', 'rendered')]
    (tmp_path / 'sheets.json').write_text(json.dumps(
        {'mode': 'quick', 'rows': old, 'runs': [{'kinds': ['flag'], 'date': 'then',
                                                 'git': 'abc'}]}))
    mode = common.Mode('quick', out=tmp_path)
    new = [dict(row(f'{source}_flag_seed0'), sheet_transport=0.5,
                seconds_cpu={'sheet_transport': 1.0}) for source in ('synthetic', 'rendered')]
    rows, runs = sheets.with_options(mode, new, ('flag',), ('sheet_transport',))
    assert [r['ratios'] for r in rows] == 2 * [{'default': 2.0, 'sheet_transport': 0.5}] + \
        2 * [{'default': 2.0}]
    assert runs[0]['kinds'] == ['flag'] and runs[1]['kinds'] == ['sheet_transport on flag']
    new[0]['rigid'] = 1.5                                 # not the same tracks
    with pytest.raises(SystemExit, match='not the same tracks'):
        sheets.with_options(mode, new, ('flag',), ('sheet_transport',))
