"""The mapper (grass_nrsfm_ros.mapper) against a real solver: an iterative rigid factorisation
(doubles.RigidALS), so its policies are checked one by one without the Grassmannian solver:
the problem a window is solved as (context, tracks), the warm start, the depth alignment, the
frames it gives results for, the windows it refuses."""
from dataclasses import replace

import numpy as np
import pytest

from doubles import bending_sheet, frames_of, recording_rigid, RigidALS, stacked
from grass_nrsfm_ros.mapper import make_mapper, Mapper, WindowError
from grass_nrsfm_ros.nrsfm import missing, problem as solver_problem
from grass_nrsfm_ros.nrsfm.measurement import as_frames, centre
from grass_nrsfm_ros.nrsfm.metrics import e3d
from grass_nrsfm_ros.windowing import Windowing


def windows_of(W, ids, keep=None, **kwargs):
    """Every Window a stream of ``W: (2F, P)`` closes, then the flush; ``keep(f, ids)``: the
    tracks of frame ``f`` that are sent (None: all)."""
    windowing = Windowing(**kwargs)
    out = []
    for f, (fid, uv) in enumerate(frames_of(W, ids)):
        mask = np.ones(fid.size, bool) if keep is None else keep(f, fid)
        out += windowing.push(windowing.accept(f, fid[mask], uv[mask]))
    return out + windowing.flush()


def solved(mapper, windows):
    """Every window solved in turn: the FrameResults the mapper gives out, in order."""
    return [r for w in windows for r in mapper.solve(w).results]


def test_the_first_window_starts_rigid_and_the_next_resume_the_previous_solution():
    W, S, ids = bending_sheet(F=40, noise=0.5)
    seen = []
    mapper = Mapper(recording_rigid(seen))
    windows = windows_of(W, ids)                     # frames 0..29; 10..39 with context 0..9
    mapper.solve(windows[0])
    first = mapper.previous
    problem = mapper._problem(windows[1])
    carried = mapper._carried_start(problem, mapper._overlap(problem))
    mapper.solve(windows[1])
    # the first window starts from the rigid factorisation, every frame known; RigidALS
    # reports rigid rotations: Dai's rank 1, so the next window resumes
    assert seen[0][1].known.all() and seen[0][1].S.shape == (90, 200)
    assert first.K_rot == 1 and mapper.previous.K_rot == 1
    # carried: rotations of the 30 shared frames, the newest one's for the 10 new frames
    assert problem.n_context == 10 and carried.known.tolist() == [True] * 30 + [False] * 10
    np.testing.assert_allclose(carried.R[:30], first.R)
    np.testing.assert_allclose(carried.R[30:], np.repeat(first.R[29:30], 10, axis=0))
    depth = as_frames(carried.S, 3)[:30, 2, :]
    old = as_frames(first.S, 3)[:, 2, :]
    np.testing.assert_allclose(depth, old - old.mean(axis=1, keepdims=True), atol=1e-9)
    np.testing.assert_allclose(as_frames(carried.S, 3)[30:, 2, :],
                               np.repeat(depth[29:30], 10, axis=0))
    # x, y of the start are the centred tracks of the problem
    np.testing.assert_allclose(as_frames(carried.S, 3)[:, :2, :],
                               as_frames(centre(problem.W)[0], 2))
    # resumed: the carried shapes, every frame's rotation given (RigidALS takes them all)
    _, init = seen[1]
    assert init.resumed and init.known.all() and init.R.shape == (40, 3, 3)
    np.testing.assert_array_equal(init.S, carried.S)
    assert e3d(mapper.previous.S, S[:120][:, np.argsort(ids)]) < 0.05


def test_model_warm_start_carries_no_shapes():
    W, S, ids = bending_sheet(F=40, noise=0.5)
    seen = []
    mapper = Mapper(recording_rigid(seen), warm_start='model')
    solved(mapper, windows_of(W, ids))
    _, init = seen[1]
    assert init.R is None and init.S is None and not init.resumed


def test_context_frames_are_solved_again_but_given_out_once():
    W, S, ids = bending_sheet(F=60, noise=0.5)
    seen = []
    mapper = Mapper(recording_rigid(seen), context_frames=15)
    windows = windows_of(W, ids, context_frames=15, key_frames=0)
    results = solved(mapper, windows)
    # windows 0..29, 10..39, 20..49, 30..59 with at most 15 earlier frames each (bounded)
    assert [r.stamp_ns for r in results] == list(range(60))          # each frame once
    W_last, init = seen[-1]
    assert W_last.shape == (2 * 45, ids.size)
    np.testing.assert_allclose(W_last[:30], W[30:60][:, np.argsort(ids)])   # frames 15..29
    assert init.known.all() and init.resumed
    assert e3d(stacked(results, ids), S) < 0.042


def test_context_frames_dropped_when_they_share_too_few_tracks():
    W, S, ids = bending_sheet(F=40, P=100)
    gone = ids[:20]                                       # tracked only until frame 4
    windows = windows_of(W, ids, lambda f, fid: ~np.isin(fid, gone) if f >= 5 else
                         np.ones(fid.size, bool), context_frames=30)
    problem = Mapper(RigidALS, context_frames=30)._problem(windows[1])   # context: frames 0..9
    # frames 0..4 lack no window track, so all ten share the window's 80 tracks
    assert problem.n_context == 10 and problem.ids.size == 80
    windows = windows_of(W, ids, lambda f, fid: ~np.isin(fid, ids[:20]) if f < 5 else
                         np.ones(fid.size, bool), context_frames=30)
    mapper = Mapper(RigidALS, context_frames=30)
    problem = mapper._problem(windows[1])
    # frames 0..4 lack 20 of the window's 100 tracks (< 90% common): only frames 5..9 kept
    assert problem.n_context == 5 and problem.ids.size == 100
    assert [r.stamp_ns for r in solved(mapper, windows[:2])] == list(range(40))


def test_every_context_frame_is_used_while_fewer_than_context_frames():
    W, S, ids = bending_sheet(F=60, P=100)
    mapper = Mapper(RigidALS, context_frames=30)
    windows = windows_of(W, ids, context_frames=30)[:4]
    # windows 0..29, 10..39, 20..49, 30..59: 0, 10, 20 and 30 earlier frames, all solved again
    assert [mapper._problem(w).n_context for w in windows] == [0, 10, 20, 30]
    np.testing.assert_array_equal(mapper._problem(windows[2]).stamps, np.arange(50))


def test_key_frames_are_solved_with_the_window():
    W, S, ids = bending_sheet(F=160, P=60)
    windows = windows_of(W, ids, context_frames=20, key_frames=4)
    problem = Mapper(RigidALS, context_frames=20)._problem(windows[-1])   # window 130..159
    np.testing.assert_array_equal(problem.stamps,
                                  [0, 32, 64, 96] + list(range(110, 160)))


def test_warm_start_fills_new_tracks_from_nearest_old_track():
    W, S, ids = bending_sheet(F=40, P=300, noise=0.0)
    seen = []
    mapper = Mapper(recording_rigid(seen), context_frames=5)
    late = ids[:30]                                       # tracked from frame 5 on
    windows = windows_of(W, ids, lambda f, fid: ~np.isin(fid, late) if f < 5 else
                         np.ones(fid.size, bool), context_frames=5, key_frames=0)
    mapper.solve(windows[0])                              # frames 0..29, 270 tracks
    problem = mapper._problem(windows[1])                 # context 5..9, frames 10..39
    carried = mapper._carried_start(problem, mapper._overlap(problem))
    mapper.solve(windows[1])
    _, init = seen[1]
    assert init.S.shape[1] == 300 and carried.known.sum() == 25
    # the filled-in depth of new tracks is close to the truth (relative to the depth spread)
    order = np.argsort(ids)
    truth = as_frames(S, 3)[5, 2, order]
    start = as_frames(init.S, 3)[0, 2, :]
    sign = np.sign(np.dot(truth - truth.mean(), start))
    new = np.isin(np.sort(ids), late)
    err = np.abs(sign * start[new] - (truth[new] - truth.mean()))
    assert np.median(err) < 0.2 * truth.std()


def test_results_only_for_frames_solved_at_most_refined_after_times():
    W, S, ids = bending_sheet(F=80, P=100)
    windows = windows_of(W, ids)
    for refined_after in (1, 3):
        mapper = Mapper(RigidALS, refined_after=refined_after)
        solves, given = {}, {}
        for window in windows:
            for stamp in mapper._problem(window).stamps:
                solves[int(stamp)] = solves.get(int(stamp), 0) + 1
            for r in mapper.solve(window).results:
                given[r.stamp_ns] = given.get(r.stamp_ns, 0) + 1
        assert max(solves.values()) > 3                  # frame 0: context of later windows
        assert given == {s: min(n, refined_after) for s, n in solves.items()}


def test_the_first_model_takes_the_orientation_the_frames_carry():
    """Depths published before a model travel in the window's frames: the sequence's first
    solution is mirrored (``flipped``) when it disagrees with them, and not otherwise."""
    W, S, ids = bending_sheet(F=30, noise=0.5)
    (window,) = windows_of(W, ids)
    plain = Mapper(RigidALS).solve(window)
    assert not plain.flipped
    for sign in (1.0, -1.0):
        frames = tuple(replace(f, depth=(r.ids, sign * r.xyz[:, 2]))
                       for f, r in zip(window.frames, plain.results))
        mapper = Mapper(RigidALS)
        update = mapper.solve(replace(window, frames=frames))
        assert update.flipped == (sign < 0)
        for a, b in zip(update.results, plain.results):
            np.testing.assert_allclose(a.xyz, b.xyz * [1, 1, sign], atol=1e-9)
        z = as_frames(mapper.previous.S, 3)[:, 2, :]
        assert np.sum(z * as_frames(plain.model.R @ plain.model.mean, 3)[:, 2, :]) * sign > 0


def test_a_later_window_aligns_to_the_previous_solution_not_the_frames():
    W, S, ids = bending_sheet(F=40, noise=0.5)
    windows = windows_of(W, ids)
    mapper = Mapper(RigidALS)
    mapper.solve(windows[0])
    frames = tuple(replace(f, depth=(f.ids, -np.arange(f.ids.size, dtype=float)))
                   for f in windows[1].frames)
    assert not mapper.solve(replace(windows[1], frames=frames)).flipped


def test_a_window_sharing_no_frame_with_the_previous_takes_the_published_orientation():
    """Windows skipped without context (window 0, then window 3 of 10-frame strides): no
    frame to align on, so the solve takes the orientation of the depths published for its
    frames, the tracking's on the previous model."""
    W, S, ids = bending_sheet(F=60, noise=0.5)
    windows = windows_of(W, ids, context_frames=0)
    reference = Mapper(RigidALS, context_frames=0)
    reference.solve(windows[0])
    skipped = reference.solve(windows[3])
    for sign in (1.0, -1.0):
        frames = tuple(replace(f, depth=(r.ids, (sign * r.xyz[:, 2]).astype(np.float32)))
                       for f, r in zip(windows[3].frames, skipped.results))
        mapper = Mapper(RigidALS, context_frames=0)
        mapper.solve(windows[0])
        update = mapper.solve(replace(windows[3], frames=frames))
        assert update.flipped == (sign < 0)
        for a, b in zip(update.results, skipped.results):
            np.testing.assert_allclose(a.xyz, b.xyz * [1, 1, sign], atol=1e-9)


def test_window_with_too_few_common_tracks_is_not_solved():
    W, S, ids = bending_sheet(F=30, P=60)
    windowing = Windowing(min_tracks=10)
    windows = []
    for f, (fid, uv) in enumerate(frames_of(W, ids)):
        windows += windowing.push(windowing.accept(f, fid[f:f + 20], uv[f:f + 20]))
    assert len(windows) == 1 and windows[0].ids.size == 0
    with pytest.raises(WindowError, match='share 0 tracks'):
        Mapper(RigidALS, min_tracks=10).solve(windows[0])


def test_bad_parameters_are_refused():
    with pytest.raises(ValueError, match='mapping_tracks'):
        Mapper(RigidALS, mapping_tracks=5)
    with pytest.raises(ValueError, match='warm_start'):
        Mapper(RigidALS, warm_start='full')


def test_a_window_with_unseen_entries_is_completed_once(monkeypatch):
    """The mapper completes a window's unseen entries (missing.fill_unseen) and hands the
    completion to the solver (``fit(W, filled=)``): one completion per window, the solver's
    report says it was given, no refill round follows (record 0802), and the solver sees W's
    own values where seen."""
    W, _, ids = bending_sheet(F=30, P=150)
    late = ids[:15]                                     # born at frame 3: seen in 27 of 30
    calls, real = [], missing.complete

    def counting(*args, **kwargs):
        calls.append(args[0].shape)
        return real(*args, **kwargs)
    monkeypatch.setattr(missing, 'complete', counting)
    monkeypatch.setattr(solver_problem, 'complete', counting)
    window = windows_of(W, ids, keep=lambda f, fid: (f >= 3) | ~np.isin(fid, late))[0]
    mapper = make_mapper({})
    mapper.solve(window)
    assert np.isin(late, window.ids).all()
    assert calls == [(60, 150)] and mapper.previous.report.completion == 'given'
    assert 'refill' not in mapper.previous.report.stages     # WINDOW_REFILL_ROUNDS: none
    problem = mapper._problem(window)
    seen = np.repeat(problem.seen, 2, axis=0)
    assert not seen.all() and np.array_equal(problem.filled[seen], problem.W[seen])
