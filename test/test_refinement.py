"""The refinement policy (grass_nrsfm_ros.refinement): which solve's shapes of a frame go out on
``points/refined``, and the frame accounting, over windows solved by the mapper with the rigid
test solver (doubles.RigidALS)."""
from dataclasses import replace

import numpy as np

from doubles import bending_sheet, frames_of, RigidALS
from grass_nrsfm_ros.mapper import Mapper, Update
from grass_nrsfm_ros.refinement import Refinement
from grass_nrsfm_ros.windowing import Windowing


def closed_windows(F=80, P=100, waiting=False, **kwargs):
    """Every Window of a bending sheet's ``F`` frames (then the flush, ``waiting`` as the
    refinement says), and the windowing."""
    W, S, ids = bending_sheet(F=F, P=P)
    windowing = Windowing(**kwargs)
    windows = [w for f, (fid, uv) in enumerate(frames_of(W, ids))
               for w in windowing.push(windowing.accept(f, fid, uv))]
    return windows + windowing.flush(waiting), windowing


def accounted(refinement, windows):
    """True if published + lost + pending is every frame of the expected ``windows``."""
    frames = sum(len(w.fresh) for w in windows)
    stats = refinement.stats
    return stats['published'] + stats['frames_lost'] + refinement.pending == frames


def test_first_window_gives_out_each_frame_once_from_the_first_window_that_solves_it():
    windows, windowing = closed_windows(F=65)
    mapper, refinement = Mapper(RigidALS), Refinement(1)
    out = []
    for window in windows:
        refinement.expect(window)
        out += refinement.take(mapper.solve(window))
        assert accounted(refinement, windows[:window.index + 1])
    assert [r.stamp_ns for r in out] == list(range(65))
    assert refinement.stats == dict(solved=5, failed=0, published=65, frames_lost=0)
    assert refinement.pending == 0 and not refinement.waiting(0)


def test_skipping_windows_gives_out_covered_frames_and_counts_lost():
    windows, _ = closed_windows(F=80)
    windows = windows[:6]
    assert [w.n_frames for w in windows] == [30] * 6           # close at 30, 40, ..., 80
    mapper, refinement = Mapper(RigidALS), Refinement(1)
    for window in windows:                                     # all closed before any solve
        refinement.expect(window)
    first = refinement.take(mapper.solve(windows[0]))          # frames 0..29
    skipped = refinement.take(mapper.solve(windows[4]))        # frames 40..69
    assert [r.stamp_ns for r in first] == list(range(30))
    assert [r.stamp_ns for r in skipped] == list(range(40, 70))
    assert refinement.stats['frames_lost'] == 10               # frames 30..39
    assert accounted(refinement, windows) and refinement.pending == 10
    assert [r.stamp_ns for r in refinement.take(mapper.solve(windows[5]))] == \
        list(range(70, 80))
    assert accounted(refinement, windows) and refinement.pending == 0


def test_a_failed_window_is_counted_and_its_frames_go_out_with_the_next():
    windows, _ = closed_windows(F=50)
    mapper, refinement = Mapper(RigidALS), Refinement(1)
    out = []
    for window in windows:
        refinement.expect(window)
        if window.index == 1:
            out += refinement.take(Update.of(window, 'failed', message='window not solved'))
            continue
        out += refinement.take(mapper.solve(window))
    # window 2 (20..49) solves frames 30..39 first: its own, given out with 40..49
    assert [r.stamp_ns for r in out] == list(range(50))
    assert refinement.stats == dict(solved=2, failed=1, published=50, frames_lost=0)


def test_last_window_gives_out_each_frame_from_its_nth_solve():
    windows, _ = closed_windows(F=60, waiting=True)
    mapper, refinement = Mapper(RigidALS, refined_after=3), Refinement(3)
    got, results = [], {}
    for window in windows:
        refinement.expect(window)
        assert refinement.waiting(window.sequence)
        out = refinement.take(mapper.solve(window))
        got.append([r.stamp_ns for r in out])
        results.update({r.stamp_ns: (r, mapper.previous) for r in out})
        assert accounted(refinement, windows[:window.index + 1])
    # windows 0-29, 10-39 (context 0-9), 20-49 (context 0-19), 30-59, then the final one
    # (released: the last solve holds its frames)
    assert got == [[], [], list(range(30)), list(range(30, 40)), list(range(40, 60))]
    assert refinement.stats == dict(solved=4, failed=0, published=60, frames_lost=0)
    assert not refinement.waiting(0)
    for stamp in (0, 45):                      # frame 0 from the third solve, 45 the fourth
        r, solution = results[stamp]
        at = list(solution.stamps).index(stamp)
        z = solution.S.reshape(-1, 3, solution.ids.size)[at, 2]
        np.testing.assert_allclose(r.xyz[:, 2], z - z.mean(), atol=1e-12)


def test_waiting_frames_keep_their_orientation_across_a_flipped_solve():
    """A solve mirrored to agree with the published depths (a restarted mapping) agrees
    with the frames solved before it, which the tracking published: they go out as solved."""
    windows, _ = closed_windows(F=40)
    mapper, refinement = Mapper(RigidALS, refined_after=3), Refinement(3)
    refinement.expect(windows[0])
    first = mapper.solve(windows[0])
    assert refinement.take(first) == []                         # solved once: all wait
    refinement.expect(windows[1])
    second = mapper.solve(windows[1])
    flipped = replace(second, flipped=True, results=(), final=True)
    out = {r.stamp_ns: r for r in refinement.take(flipped)}
    assert sorted(out) == list(range(30))
    for r in first.results:
        np.testing.assert_array_equal(out[r.stamp_ns].xyz, r.xyz)


def test_dropped_updates_change_nothing():
    windows, _ = closed_windows(F=30)
    refinement = Refinement(1)
    refinement.expect(windows[0])
    assert refinement.take(Update.of(windows[0], 'dropped', message='skipped')) == []
    assert refinement.stats == dict(solved=0, failed=0, published=0, frames_lost=0)
    assert refinement.pending == 30
