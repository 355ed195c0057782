"""``grass-nrsfm reconstruct IN.npz -o OUT.npz`` and ``grass-nrsfm evaluate OUT.npz GT.npz``:
real solves of a small synthetic sequence, their figures checked against ground truth, and the
clear one-line errors (exit code 2) on bad input."""
import json
import re
import sys

import numpy as np
import pytest

from grass_nrsfm_ros.cli import main
from grass_nrsfm_ros.nrsfm.metrics import e3d
from grass_nrsfm_ros.nrsfm.rotation import rigid_factorisation
from grass_nrsfm_ros.nrsfm.synthetic import make_sequence

F, P = 24, 300


@pytest.fixture(scope='module')
def sequence():
    return make_sequence('inflating', n_frames=F, n_points=P, camera='orbit', seed=1)


def printed_e3d(text):
    return float(re.search(r'e3D \(per-frame Procrustes, no scale\): ([0-9.]+)', text).group(1))


def test_reconstruct_then_evaluate(sequence, tmp_path, capsys):
    sequence.save_npz(tmp_path / 'in.npz')
    assert main(['reconstruct', str(tmp_path / 'in.npz'), '-o', str(tmp_path / 'out.npz'),
                 '--quiet']) == 0
    solved = printed_e3d(capsys.readouterr().out)
    with np.load(tmp_path / 'out.npz') as out:
        assert out['S'].shape == (3 * F, P) and out['R'].shape == (F, 3, 3)
        assert out['translation'].shape == (2 * F, 1) and out['groups'].shape == (P,)
        assert 'points' not in out.files
        report = json.loads(str(out['report']))
        S = out['S']
    assert report['iterations'] > 0 and report['reprojection_relative'] < 0.05
    assert solved == pytest.approx(e3d(S, sequence.S), abs=1e-4)
    rigid = e3d(rigid_factorisation(sequence.W)[1], sequence.S)
    assert solved < 0.4 * rigid, (solved, rigid)              # measured 0.014 vs 0.074
    assert main(['evaluate', str(tmp_path / 'out.npz'), str(tmp_path / 'in.npz')]) == 0
    text = capsys.readouterr().out
    assert printed_e3d(text) == pytest.approx(solved, abs=1e-4)
    assert 'Akhter' in text


def incomplete(sequence, tmp_path):
    """The sequence with 40 tracks lost for 4 frames (NaN and visible), saved as in.npz;
    returns ``(visible: (F, P), the reconstruct arguments)``."""
    visible = np.ones((F, P), bool)
    visible[5:9, :40] = False                                 # 40 tracks lost for 4 frames
    W = sequence.W.copy()
    W.reshape(F, 2, P)[~visible[:, None, :].repeat(2, 1)] = np.nan
    np.savez(tmp_path / 'in.npz', W=W, S=sequence.S, visible=visible)
    return visible, ['reconstruct', str(tmp_path / 'in.npz'), '-o', str(tmp_path / 'out.npz'),
                     '--quiet']


def test_incomplete_tracks_are_all_reconstructed_and_the_filled_entries_said(
        sequence, tmp_path, capsys):
    visible, args = incomplete(sequence, tmp_path)
    assert main(args) == 0
    captured = capsys.readouterr()
    assert '160 of 7200 entries not seen (40 of 300 tracks incomplete): filled' in captured.out
    with np.load(tmp_path / 'out.npz') as out:
        S, seen, weights = out['S'], out['visible'], out['track_weights']
        assert out['R'].shape == (F, 3, 3) and 'points' not in out.files
        report = json.loads(str(out['report']))
    assert S.shape == (3 * F, P) and np.isfinite(S).all()
    np.testing.assert_array_equal(seen, visible)
    assert weights.shape == (P,) and report['observed_fraction'] == pytest.approx(visible.mean())
    solved = printed_e3d(captured.out)
    assert solved == pytest.approx(e3d(S, sequence.S), abs=1e-4)
    rigid = e3d(rigid_factorisation(sequence.W)[1], sequence.S)
    assert solved < 0.4 * rigid, (solved, rigid)              # measured 0.016 vs 0.074
    assert 'e3D over the observed entries' in captured.out


def test_complete_tracks_option_keeps_the_tracks_seen_in_every_frame(sequence, tmp_path, capsys):
    _, args = incomplete(sequence, tmp_path)
    assert main(args + ['--complete-tracks']) == 0
    text = capsys.readouterr().out
    assert 'keeping the 260 of 300 tracks' in text
    with np.load(tmp_path / 'out.npz') as out:
        assert out['S'].shape == (3 * F, 260)
        np.testing.assert_array_equal(out['points'], np.arange(40, P))
        S = out['S']
    assert printed_e3d(text) == pytest.approx(e3d(S, sequence.S[:, 40:]), abs=1e-4)
    assert main(['evaluate', str(tmp_path / 'out.npz'), str(tmp_path / 'in.npz')]) == 0
    assert printed_e3d(capsys.readouterr().out) == pytest.approx(printed_e3d(text), abs=1e-4)


def test_bad_frames_and_tracks_are_left_out_with_a_warning(sequence, tmp_path, capsys):
    """An all-NaN frame, a track seen once, a track never seen and entries with only u or v:
    each gets a warning; the rest is reconstructed, the left-out frame and tracks are NaN."""
    W = sequence.W.copy()
    W[6:8] = np.nan                                           # frame 3: nothing seen
    W[:, 7] = np.nan
    W[10:12, 7] = 1.0                                         # track 7: seen in frame 5 only
    W[:, 9] = np.nan                                          # track 9: never seen
    W[20, 11] = np.nan                                        # track 11, frame 10: u only
    visible = np.isfinite(W).reshape(F, 2, P).all(axis=1)
    visible[0, 9] = True                                      # visible, but NaN
    np.savez(tmp_path / 'in.npz', W=W, S=sequence.S, visible=visible)
    assert main(['reconstruct', str(tmp_path / 'in.npz'), '-o', str(tmp_path / 'out.npz'),
                 '--quiet']) == 0
    err = capsys.readouterr().err
    assert '1 entries have a finite u or v but not both' in err
    assert '1 frames see fewer than 4 tracks (first: frame 3)' in err
    assert '2 tracks are seen in fewer than 2 frames (first: track 7)' in err
    assert '1 entries marked visible are not finite: taken as not seen' in err
    with np.load(tmp_path / 'out.npz') as out:
        S, R, seen = out['S'].reshape(F, 3, P), out['R'], out['visible']
    assert np.isnan(S[3]).all() and np.isnan(R[3]).all()
    assert np.isnan(S[:, :, [7, 9]]).all()
    others = np.ones(P, bool)
    others[[7, 9]] = False
    assert np.isfinite(np.delete(S, 3, axis=0)[:, :, others]).all()
    assert not seen[10, 11] and not seen[3].any() and seen.sum() == (F - 1) * (P - 2) - 1
    # evaluate leaves the NaN entries out (frame 3, tracks 7 and 9) and says how many
    assert main(['evaluate', str(tmp_path / 'out.npz'), str(tmp_path / 'in.npz')]) == 0
    text = capsys.readouterr().out
    left_out = P + 2 * (F - 1)
    assert f'{left_out} of {F * P} entries not finite (tracks left out)' in text
    assert 'e3D Akhter (one rotation' in text        # the other frames' whole tracks
    finite = np.isfinite(S).all(axis=1)
    assert printed_e3d(text) == pytest.approx(
        e3d(S.reshape(3 * F, P), sequence.S, visible=finite), abs=1e-4)


@pytest.mark.parametrize('arrays, message', [
    ({'S': np.zeros((6, 5))}, 'has no array W'),
    ({'W': np.full((6, 5), np.nan)}, 'non-finite'),
    ({'W': np.zeros((5, 8))}, 'even number of rows'),
    ({'W': np.zeros((2, 8))}, 'W has 1 frames; at least 3 needed'),
    ({'W': np.array([['a'] * 8] * 6)}, 'must be numeric'),
    ({'W': np.random.default_rng(0).random((8, 10)), 'S': np.zeros((12, 9))},
     'ground truth S has 9 points; expected 10'),
    ({'W': np.random.default_rng(0).random((8, 10)), 'visible': np.ones((3, 10), bool) & False},
     'visible must have shape'),
])
def test_reconstruct_bad_input_is_one_clear_line(tmp_path, capsys, arrays, message):
    np.savez(tmp_path / 'bad.npz', **arrays)
    assert main(['reconstruct', str(tmp_path / 'bad.npz'), '-o', str(tmp_path / 'o.npz'),
                 '--quiet', '--complete-tracks']) == 2
    err = capsys.readouterr().err
    assert err.startswith('grass-nrsfm reconstruct: error: ') and message in err, err
    assert err.count('\n') == 1 and not (tmp_path / 'o.npz').exists()


def test_evaluate_refuses_mismatched_shapes(tmp_path, capsys):
    np.savez(tmp_path / 'a.npz', S=np.zeros((6, 5)))
    np.savez(tmp_path / 'b.npz', S=np.zeros((9, 5)))
    np.savez(tmp_path / 'c.npz', W=np.zeros((4, 5)))
    assert main(['evaluate', str(tmp_path / 'a.npz'), str(tmp_path / 'b.npz')]) == 2
    assert 'shapes differ' in capsys.readouterr().err
    assert main(['evaluate', str(tmp_path / 'a.npz'), str(tmp_path / 'c.npz')]) == 2
    assert 'has no array S' in capsys.readouterr().err
    assert main(['evaluate', str(tmp_path / 'a.npz'), str(tmp_path / 'missing.npz')]) == 2
    assert 'missing.npz' in capsys.readouterr().err


def test_unreadable_files_and_paths_are_one_clear_line(sequence, tmp_path, capsys):
    sequence.save_npz(tmp_path / 'in.npz')
    (tmp_path / 'text.npz').write_text('not an archive\n')
    np.save(tmp_path / 'single.npy', np.zeros((4, 5)))
    (tmp_path / 'bad.yaml').write_text(':::: [\n')
    base = ['reconstruct', str(tmp_path / 'in.npz'), '--quiet', '-o']
    cases = [
        (['reconstruct', str(tmp_path / 'text.npz'), '-o', str(tmp_path / 'o.npz')],
         'text.npz: not a readable .npz archive'),
        (['evaluate', str(tmp_path / 'single.npy'), str(tmp_path / 'in.npz')],
         'single.npy: a single .npy array, not an .npz archive'),
        (base + [str(tmp_path / 'o.npz'), '--config', str(tmp_path / 'bad.yaml')],
         'bad.yaml: not valid YAML'),
        (base + [str(tmp_path / 'no' / 'such' / 'o.npz')], 'does not exist or is not writable'),
    ]
    for argv, message in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert message in err and err.count('\n') == 1, err


def test_evaluate_refuses_degenerate_ground_truth(tmp_path, capsys):
    np.savez(tmp_path / 'est.npz', S=np.random.default_rng(0).random((6, 5)))
    np.savez(tmp_path / 'gt.npz', S=np.zeros((6, 5)))
    assert main(['evaluate', str(tmp_path / 'est.npz'), str(tmp_path / 'gt.npz')]) == 2
    assert 'S_gt frame 0 has zero norm' in capsys.readouterr().err


def test_evaluate_prefers_s_gt_in_a_file_holding_both(tmp_path, capsys):
    """A file with an estimate ``S`` and ground truth ``S_gt`` (the demo's reconstruction) is
    ground truth through ``S_gt``, an estimate through ``S``."""
    rng = np.random.default_rng(0)
    truth, other = rng.random((9, 20)), rng.random((9, 20))
    np.savez(tmp_path / 'both.npz', S=other, S_gt=truth)
    np.savez(tmp_path / 'truth.npz', S=truth)
    assert main(['evaluate', str(tmp_path / 'truth.npz'), str(tmp_path / 'both.npz')]) == 0
    assert printed_e3d(capsys.readouterr().out) == 0.0
    assert main(['evaluate', str(tmp_path / 'both.npz'), str(tmp_path / 'truth.npz')]) == 0
    assert printed_e3d(capsys.readouterr().out) == pytest.approx(e3d(other, truth), abs=1e-4)


def test_visible_of_the_wrong_shape_is_refused_even_when_all_true(tmp_path, capsys):
    np.savez(tmp_path / 'in.npz', W=np.random.default_rng(0).random((8, 10)),
             visible=np.ones((3, 10), bool))
    assert main(['reconstruct', str(tmp_path / 'in.npz'), '-o', str(tmp_path / 'o.npz'),
                 '--quiet']) == 2
    assert 'visible must have shape' in capsys.readouterr().err


def test_a_command_that_needs_ros_says_so_in_one_line_without_it(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, 'rclpy', None)            # import rclpy fails
    monkeypatch.delitem(sys.modules, 'grass_nrsfm_ros.commands.replay', raising=False)
    with pytest.raises(SystemExit) as exit_:
        main(['replay', 'some.bag'])
    assert exit_.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith('grass-nrsfm replay: error: needs ROS 2')
    assert main(['evaluate', 'missing.npz', 'missing.npz']) == 2        # needs no ROS
