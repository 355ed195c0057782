"""Windowing (grass_nrsfm_ros.windowing): validation, order, windows, context and key frames,
sequences; each policy of the module checked on its own (no solver)."""
import numpy as np
import pytest

from doubles import bending_sheet, frames_of
from grass_nrsfm_ros.windowing import FrameError, Windowing


def pushed(windowing, stamp, ids, uv, **kwargs):
    """The Windows one frame closes (accepted, then pushed)."""
    return windowing.push(windowing.accept(stamp, ids, uv), **kwargs)


def windows_of(windowing, W, ids):
    """Every Window a stream of ``W: (2F, P)`` closes (no flush)."""
    return [w for f, (fid, uv) in enumerate(frames_of(W, ids))
            for w in pushed(windowing, f, fid, uv)]


def test_a_preview_of_the_first_frames_goes_out_once_and_moves_nothing():
    W, S, ids = bending_sheet(F=65)
    plain = windows_of(Windowing(), W, ids)
    windowing = Windowing(first_model_frames=15)
    windows = windows_of(windowing, W, ids)
    preview, rest = windows[0], windows[1:]
    assert preview.preview and list(preview.stamps) == list(range(15))
    assert preview.fresh == () and preview.context == () and preview.index == 0
    assert [(w.index, list(w.stamps), w.fresh, w.preview) for w in rest] == \
        [(w.index, list(w.stamps), w.fresh, w.preview) for w in plain]
    assert windowing.stats['previews'] == 1 and windowing.stats['windows'] == 4
    # a new sequence (all ids changed) gets its own preview; none at or beyond window_size
    new = windows_of(windowing, W, ids + 10_000)
    assert new[0].final and not new[0].preview                  # the old sequence's last
    assert new[1].preview and new[1].sequence == 1 and windowing.stats['previews'] == 2
    assert not any(w.preview for w in windows_of(Windowing(first_model_frames=30), W, ids))


def test_windows_close_every_stride():
    W, S, ids = bending_sheet(F=65)
    windowing = Windowing()
    windows = windows_of(windowing, W, ids)
    # windows close at 30, 40, 50, 60 frames; the flush covers 61..65 with the 20 frames a
    # window leaves buffered
    assert [list(w.stamps) for w in windows] == [list(range(a, a + 30)) for a in (0, 10, 20, 30)]
    assert [w.fresh for w in windows] == [tuple(range(30))] + [
        tuple(range(a, a + 10)) for a in (30, 40, 50)]
    (last,) = windowing.flush()
    assert last.final and list(last.stamps) == list(range(40, 65))
    assert last.fresh == tuple(range(60, 65))
    assert windowing.stats == dict(frames=65, refused=0, resets=0, windows=5, previews=0,
                                   frames_dropped=0)
    order = np.argsort(ids)
    np.testing.assert_array_equal(windows[1].W, W[20:80][:, order])      # (2F, P), id order
    assert all(np.array_equal(w.ids, np.sort(ids)) for w in windows)
    assert windowing.flush() == [] and windowing.buffered_fresh == 0     # nothing new


def test_a_window_is_solved_on_the_tracks_seen_in_most_of_its_frames():
    """Tracks seen in WINDOW_TRACK_SHARE (80 %) of a window's frames are its tracks, with NaN
    where a frame does not see them; tracks seen less are left out."""
    W, S, ids = bending_sheet(F=30, P=50)
    windowing = Windowing()
    missing = {0: 6, 1: 7, 2: 30}               # track index -> frames it is not seen in
    windows = []
    for f, (fid, uv) in enumerate(frames_of(W, ids)):
        keep = np.array([f >= missing.get(i, 0) for i in range(ids.size)])
        windows += pushed(windowing, f, fid[keep], uv[keep])
    (window,) = windows
    # track 0 is seen in 24 of 30 frames (80 %): in; track 1 in 23: out; track 2 never: out
    expected = np.sort(ids[[0] + list(range(3, 50))])
    np.testing.assert_array_equal(window.ids, expected)
    column = np.searchsorted(window.ids, ids[0])
    assert np.isnan(window.W[:12, column]).all() and np.isfinite(window.W[12:, column]).all()
    others = np.delete(np.arange(window.ids.size), column)
    assert np.isfinite(window.W[:, others]).all()


def test_out_of_order_duplicate_and_late_frames():
    W, S, ids = bending_sheet(F=40)
    frames = frames_of(W, ids)
    windowing = Windowing()
    order = list(range(40))
    order[5], order[6] = order[6], order[5]                # swapped pair: reordered
    windows = []
    for f in order:
        windows += pushed(windowing, f, *frames[f])
        if f == 10:
            with pytest.raises(FrameError, match='duplicate stamp'):
                windowing.accept(10, *frames[10])
    with pytest.raises(FrameError, match='late frame'):
        windowing.accept(3, *frames[3])                    # window 0..29 already closed
    assert list(windows[0].stamps) == list(range(30))
    order = np.argsort(ids)
    for f in (5, 6):                                       # the swapped frames, in place
        np.testing.assert_array_equal(windows[0].frames[f].uv, frames[f][1][order])
    assert windowing.stats['refused'] == 2 and windowing.stats['frames'] == 40


@pytest.mark.parametrize('bad, message', [
    (lambda ids, uv: (ids[:5], uv[:5]), 'min_tracks'),
    (lambda ids, uv: (np.r_[ids[:-1], ids[0]], uv), 'duplicate track id'),
    (lambda ids, uv: (ids, np.where(np.arange(len(ids))[:, None] == 3, np.nan, uv)),
     'non-finite'),
    (lambda ids, uv: (ids, uv[:, :1]), 'do not match'),
])
def test_bad_frames_are_refused_and_state_kept(bad, message):
    W, S, ids = bending_sheet(F=30)
    frames = frames_of(W, ids)
    windowing = Windowing()
    for f in range(10):
        pushed(windowing, f, *frames[f])
    with pytest.raises(FrameError, match=message):
        windowing.accept(10, *bad(*frames[10]))
    windows = [w for f in range(10, 30) for w in pushed(windowing, f, *frames[f])]
    assert len(windows) == 1 and windows[0].n_frames == 30
    assert windowing.stats['refused'] == 1


def test_frames_keep_copies_sorted_by_id():
    W, S, ids = bending_sheet(F=1, P=50)
    ids_in, uv_in = ids.copy(), W.T.copy()
    frame = Windowing().accept(7, ids_in, uv_in, 'cam')
    order = np.argsort(ids)
    np.testing.assert_array_equal(frame.ids, ids[order])
    np.testing.assert_array_equal(frame.uv, W.T[order])
    assert frame.ids.dtype == np.uint32 and frame.frame_id == 'cam' and frame.depth is None
    uv_in[:] = 0.0                                         # the caller reuses its arrays
    assert np.abs(frame.uv).max() > 0


def test_every_context_frame_is_carried_while_fewer_than_context_frames():
    W, S, ids = bending_sheet(F=60, P=100)
    windows = windows_of(Windowing(context_frames=30), W, ids)
    # windows 0..29, 10..39, 20..49, 30..59: 0, 10, 20 and 30 earlier frames
    # (a negative slice start once kept only the newest 10 of 20)
    assert [[c.stamp_ns for c in w.context] for w in windows] == [
        [], list(range(10)), list(range(20)), list(range(30))]


def test_key_frames_spread_evenly_over_the_older_past():
    W, S, ids = bending_sheet(F=160, P=60)
    windows = windows_of(Windowing(context_frames=20, key_frames=4), W, ids)
    contexts = [[c.stamp_ns for c in w.context] for w in windows]
    # frames leaving the newest 20 become key frames: every one, then every 2nd, 4th, ...
    assert contexts[2] == list(range(20))                           # window 20..49: none left
    assert contexts[3] == [0, 4, 8] + list(range(10, 30))           # 0..9 left
    assert contexts[4] == [0, 8, 16] + list(range(20, 40))          # 0..19 left
    assert contexts[5] == [0, 8, 16, 24] + list(range(30, 50))
    assert contexts[-1] == [0, 32, 64, 96] + list(range(110, 130))  # window 130..159
    assert all(w.context == () for w in windows_of(Windowing(context_frames=0), W, ids))


def test_context_frames_are_bounded():
    W, S, ids = bending_sheet(F=60, noise=0.5)
    windows = windows_of(Windowing(context_frames=15, key_frames=0), W, ids)
    assert [[c.stamp_ns for c in w.context] for w in windows] == [
        [], list(range(10)), list(range(5, 20)), list(range(15, 30))]


def test_close_early_closes_the_next_window_over_the_frames_since_the_last():
    W, S, ids = bending_sheet(F=50)
    frames = frames_of(W, ids)
    windowing = Windowing()
    windows = [w for f in range(33) for w in pushed(windowing, f, *frames[f])]
    assert len(windows) == 1                               # frames 0..29
    windows += pushed(windowing, 33, *frames[33], close_early=True)
    # the window closes at once over the 24 buffered frames: more than window_size - stride
    # (20) wait
    assert len(windows) == 2 and list(windows[1].stamps) == list(range(10, 34))
    assert windows[1].fresh == tuple(range(30, 34))


def test_all_ids_change_starts_a_new_sequence_and_flushes_the_old_one():
    W, S, ids = bending_sheet(F=75)
    frames = frames_of(W, ids)
    windowing = Windowing()
    windows = []
    for f in range(75):
        fid = ids if f < 35 else ids + 100_000            # tracker restarted at frame 35
        windows += pushed(windowing, f, fid, frames[f][1])
    windows += windowing.flush()
    assert windowing.stats['resets'] == 1 and windowing.sequence == 1
    # the new sequence's 40 frames close two windows; its flush has nothing new
    assert [(w.sequence, w.final, w.fresh[0], w.fresh[-1]) for w in windows] == [
        (0, False, 0, 29), (0, True, 30, 34), (1, False, 35, 64), (1, False, 65, 74)]
    assert windows[2].context == ()                       # no state crosses the boundary


def test_too_few_frames_at_the_end_are_counted_dropped_and_a_reset_drops_the_buffer():
    W, S, ids = bending_sheet(F=40)
    frames = frames_of(W, ids)
    windowing = Windowing()
    pushed(windowing, 0, *frames[0])
    pushed(windowing, 1, *frames[1])
    assert windowing.flush() == [] and windowing.stats['frames_dropped'] == 2
    assert windowing.buffered_fresh == 0                   # given up: not dropped twice
    assert windowing.flush() == [] and windowing.stats['frames_dropped'] == 2
    windowing = Windowing()
    for f in range(35):
        pushed(windowing, f, *frames[f])
    assert windowing.buffered_fresh == 5
    assert windowing.reset() == 5 and windowing.stats['frames_dropped'] == 5
    frame = windowing.accept(3, *frames[3])               # a new sequence: earlier stamps too
    assert frame.sequence == windowing.sequence == 1


def test_a_waiting_flush_closes_a_last_window_with_no_new_frame():
    W, S, ids = bending_sheet(F=30)
    windowing = Windowing()
    windows_of(windowing, W, ids)
    assert windowing.flush() == []
    (last,) = windowing.flush(waiting=True)               # frames of closed windows wait
    assert last.final and last.fresh == () and list(last.stamps) == list(range(10, 30))
