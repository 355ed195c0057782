"""The dense tracker (grass_nrsfm_ros.frontend.flow): accuracy, life and death of tracks, bad
input. Images are a shifted blurred-noise texture here, rendered deforming surfaces with ground
truth in the tests marked 'scene'."""
import warnings

import cv2
import numpy as np
import pytest

from grass_nrsfm_ros.frontend import DenseTracker, FrameSizeError, METHODS, TrackFrame

H, W = 240, 320


def texture(seed=0, size=(400, 520)):
    rng = np.random.default_rng(seed)
    noise = cv2.GaussianBlur(rng.random(size).astype(np.float32) * 255, (0, 0), 2.0)
    return cv2.normalize(noise, None, 0, 255, cv2.NORM_MINMAX)


def shifted(base, du, dv, shape=(H, W)):
    """``base`` seen with its pixel (40 + du, 30 + dv) at the image origin: content moves by
    (-du, -dv)."""
    M = np.float32([[1, 0, -40 - du], [0, 1, -30 - dv]])
    return cv2.warpAffine(base, M, shape[::-1], flags=cv2.INTER_CUBIC).clip(0, 255).astype(
        np.uint8)


def by_id(frame):
    return dict(zip(frame.ids.tolist(), frame.uv))


@pytest.mark.parametrize('method, median, p95', [('dis-fast+lk', 0.1, 0.2),
                                                 ('dis-ultrafast+lk', 0.1, 0.2), ('lk', 0.1, 0.2),
                                                 ('dis-fast/prev+lk', 0.1, 0.2),
                                                 ('dis-ultrafast', 1.5, 2.5)])
def test_translation_tracked_to_a_tenth_of_a_pixel(method, median, p95):
    base = texture()
    tracker = DenseTracker(step=8, method=method)
    first = tracker.track(shifted(base, 0, 0))
    assert first.ids.dtype == np.uint32 and first.uv.shape == (len(first.ids), 2)
    assert len(first.ids) > 1000 and (first.age == 0).all()
    motion = np.array([0.0, 0.0])
    for _ in range(12):
        motion += (1.3, -0.7)
        out = tracker.track(shifted(base, *motion))
    start = by_id(first)
    old = np.isin(out.ids, first.ids)
    truth = np.array([start[i] for i in out.ids[old].tolist()]) - motion
    err = np.linalg.norm(out.uv[old] - truth, axis=1)
    moved = first.uv - motion
    inside = (moved.min(axis=1) >= 2) & (moved[:, 0] <= W - 3) & (moved[:, 1] <= H - 3)
    assert old.sum() > 0.95 * inside.sum()
    assert np.median(err) < median and np.percentile(err, 95) < p95
    assert (out.age[old] == 12).all() and (out.age[~old] < 12).all()


def test_shading_gain_and_offset_do_not_move_tracks():
    """A brightness gain that grows to 1.3x across the image and an offset, as shading
    changes when a surface turns: the tracks stay within a tenth of a pixel."""
    base = texture()
    ramp = np.linspace(0.0, 1.0, W, dtype=np.float32)[None, :]
    tracker = DenseTracker(step=8)
    first = tracker.track(shifted(base, 0, 0))
    for k in range(1, 9):
        lit = shifted(base, 0.7 * k, 0.4 * k) * (1 + 0.3 * k / 8 * ramp) + 2 * k
        out = tracker.track(np.clip(lit, 0, 255).astype(np.uint8))
    start = by_id(first)
    old = np.isin(out.ids, first.ids)
    truth = np.array([start[i] for i in out.ids[old].tolist()]) - (5.6, 3.2)
    err = np.linalg.norm(out.uv[old] - truth, axis=1)
    assert old.sum() > 0.9 * len(first.ids)
    assert np.median(err) < 0.1 and np.percentile(err, 95) < 0.25


def test_tracks_leave_the_image_die_and_new_ones_are_born_with_new_ids():
    base = texture(size=(400, 900))
    tracker = DenseTracker(step=8, method='dis-fast+lk')
    seen, alive_ids = set(), None
    born = lost = 0
    for k in range(40):
        out = tracker.track(shifted(base, 6.0 * k, 0))
        ids = set(out.ids.tolist())
        new = ids - (alive_ids or set())
        assert not (new & seen - ids) and len(out.ids) == len(ids)
        assert not new & (seen - (alive_ids or set())), 'an id came back'
        seen |= ids
        alive_ids = ids
        born += out.counts['born']
        lost += out.counts['lost']
        assert out.counts['alive'] == len(out.ids)
    first_ids = set(range(out.ids.min()))
    assert born > 1000 and lost > 800
    assert not first_ids & set(out.ids.tolist())
    assert len(out.ids) > 0.6 * (H // 8) * (W // 8)


def test_reset_keeps_ids_fresh():
    base = texture()
    tracker = DenseTracker(step=16)
    before = tracker.track(shifted(base, 0, 0)).ids
    tracker.reset()
    after = tracker.track(shifted(base, 0, 0)).ids
    assert after.min() > before.max()


def test_occluded_tracks_fail_the_check():
    base = texture()
    tracker = DenseTracker(step=8)
    first = tracker.track(shifted(base, 0, 0))
    image = shifted(base, 1, 1)
    image[60:180, 100:220] = shifted(texture(seed=5), 0, 0)[60:180, 100:220]
    out = tracker.track(image)
    assert out.counts['failed'] > 0.8 * (120 // 8) * (120 // 8)
    inside = (out.uv[:, 0] > 106) & (out.uv[:, 0] < 214) & (out.uv[:, 1] > 66) & \
        (out.uv[:, 1] < 174)
    assert (inside & np.isin(out.ids, first.ids)).sum() < 0.05 * (120 // 8) ** 2


def occlude_a_patch(tracker, base):
    """Frame 0 of ``base``, then a frame with a 60 x 60 patch of other texture: ``(first,
    occluded image, hidden, inside)``, ``inside (P,)``: frame 0's tracks well inside it."""
    first = tracker.track(shifted(base, 0, 0))
    occluded = shifted(base, 1, 1)
    occluded[90:150, 130:190] = shifted(texture(seed=5), 0, 0)[90:150, 130:190]
    hidden = tracker.track(occluded)
    inside = (first.uv[:, 0] > 140) & (first.uv[:, 0] < 180) & (first.uv[:, 1] > 100) & \
        (first.uv[:, 1] < 140)
    return first, occluded, hidden, inside


@pytest.mark.parametrize('max_misses', [0, 1])
def test_a_track_failing_once_is_hidden_and_dies_on_the_next_failure(max_misses):
    """A small patch occluded in one frame: its tracks fail, are hidden (not output) and
    come back with their ids where it is seen again (``max_misses`` 1), or die at once
    (0)."""
    base = texture()
    tracker = DenseTracker(step=8, max_misses=max_misses)
    first, occluded, hidden, inside = occlude_a_patch(tracker, base)
    assert inside.sum() >= 16 and not np.isin(first.ids[inside], hidden.ids).any()
    assert hidden.counts['failed'] >= inside.sum()
    assert hidden.counts['missed'] == (hidden.counts['failed'] if max_misses else 0)
    seen = tracker.track(shifted(base, 2, 2))
    back = np.isin(first.ids[inside], seen.ids).mean()
    if max_misses:
        assert back > 0.95 and seen.counts['missed'] == 0
        err = np.linalg.norm(np.array([by_id(seen)[i] for i in first.ids[inside].tolist()])
                             - (first.uv[inside] - 2), axis=1)
        assert np.median(err) < 0.1 and err.max() < 0.5
        tracker.track(occluded)
        tracker.track(occluded)
        assert not np.isin(first.ids[inside], tracker.track(shifted(base, 2, 2)).ids).any()
    else:
        assert back == 0


def test_a_hidden_track_dies_when_its_keyframe_is_retired():
    """A frame that hides tracks and becomes a keyframe (here every frame does) retires the
    keyframe they are measured against: they die then, not one frame later, so no frame
    keeps a second keyframe for its hidden tracks."""
    base = texture()
    tracker = DenseTracker(step=8, max_misses=1, reanchor_every=1)
    first, _, hidden, inside = occlude_a_patch(tracker, base)
    assert hidden.counts['reanchored'] and hidden.counts['failed'] >= inside.sum() >= 16
    assert hidden.counts['missed'] == 0 and hidden.counts['lost'] >= inside.sum()
    assert len(np.unique(tracker._key)) == 1
    seen = tracker.track(shifted(base, 2, 2))
    assert not np.isin(first.ids[inside], seen.ids).any()


def test_region_rectangle_and_mask():
    base = texture()
    roi = DenseTracker(step=4, region=(100, 50, 199, 149)).track(shifted(base, 0, 0))
    assert len(roi.ids) == 25 * 25
    assert roi.uv.min(0).tolist() == [102, 50] and roi.uv.max(0).tolist() == [198, 146]
    mask = np.zeros((H, W), bool)
    mask[:, :W // 2] = True
    half = DenseTracker(step=4, region=mask).track(shifted(base, 0, 0))
    assert (half.uv[:, 0] < W // 2).all() and len(half.ids) == (W // 8) * (H // 4)


def test_appearance_change_reanchors():
    base = texture()
    tracker = DenseTracker(step=8, reanchor_zncc=0.97, min_zncc=0.5)
    first = tracker.track(shifted(base, 0, 0))
    reanchored = 0
    for k in range(1, 25):
        blurred = cv2.GaussianBlur(shifted(base, k, 0), (0, 0), 0.1 + 0.08 * k)
        out = tracker.track(blurred)
        reanchored += out.counts['reanchored']
    assert reanchored >= 1
    start = by_id(first)
    common = [i for i in out.ids.tolist() if i in start]
    assert len(common) > 0.8 * len(first.ids)
    err = np.linalg.norm(np.array([by_id(out)[i] for i in common])
                         - (np.array([start[i] for i in common]) - (24, 0)), axis=1)
    assert np.median(err) < 0.5


def test_reanchor_every_frame_is_chaining():
    base = texture()
    tracker = DenseTracker(step=16, reanchor_every=1)
    tracker.track(shifted(base, 0, 0))
    assert all(tracker.track(shifted(base, k, 0)).counts['reanchored'] for k in range(1, 4))


@pytest.mark.parametrize('value', [0, 255])
def test_blank_frame_warns_once_and_tracking_resumes(value):
    base = texture()
    tracker = DenseTracker(step=8)
    first = tracker.track(shifted(base, 0, 0))
    blank = np.full((H, W), value, np.uint8)
    with pytest.warns(RuntimeWarning, match='blank frame'):
        out = tracker.track(blank)
    assert len(out.ids) == 0 and out.counts['blank'] == 1
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        tracker.track(blank)
    after = tracker.track(shifted(base, 2, 1))
    assert len(after.ids) > 0.95 * len(first.ids)
    assert np.isin(after.ids, first.ids).all() and (after.age == 3).all()


def test_colour_and_grey_give_the_same_tracks():
    base = texture()
    grey = [shifted(base, k, 0.5 * k) for k in range(4)]
    colour = [np.repeat(g[:, :, None], 3, axis=2) for g in grey]
    tracker_g, tracker_c = DenseTracker(step=8), DenseTracker(step=8, channel_order='bgr')
    for g, c in zip(grey, colour):
        a, b = tracker_g.track(g), tracker_c.track(c)
    np.testing.assert_array_equal(a.ids, b.ids)
    np.testing.assert_allclose(a.uv, b.uv, atol=1e-9)


def test_uint16_and_float_frames_are_scaled():
    base = texture()
    frames = [shifted(base, k, 0) for k in range(3)]
    reference = DenseTracker(step=8)
    twelve_bit = DenseTracker(step=8)
    floats = DenseTracker(step=8)
    for f in frames:
        a = reference.track(f)
        b = twelve_bit.track(f.astype(np.uint16) << 4)
        c = floats.track(f / 255.0)
    np.testing.assert_allclose(a.uv, b.uv, atol=1e-9)
    np.testing.assert_allclose(a.uv, c.uv, atol=1e-3)


def test_size_change_is_a_clear_error_and_reset_recovers():
    base = texture()
    tracker = DenseTracker(step=8)
    tracker.track(shifted(base, 0, 0))
    with pytest.raises(FrameSizeError, match='reset'):
        tracker.track(shifted(base, 0, 0, shape=(200, 300)))
    tracker.reset()
    assert len(tracker.track(shifted(base, 0, 0, shape=(200, 300))).ids) > 0


@pytest.mark.parametrize('kwargs', [dict(step=0), dict(step=2.5), dict(method='farneback'),
                                    dict(region=(10, 10, 5, 20)), dict(region='all'),
                                    dict(region=np.zeros((4, 4), bool)),
                                    dict(region=np.ones((4, 4))), dict(min_zncc=2),
                                    dict(lk_window=4), dict(reanchor_every=0),
                                    dict(K=np.eye(2)), dict(channel_order='rgba'),
                                    dict(max_misses=-1), dict(max_misses=0.5)])
def test_bad_parameters_are_named(kwargs):
    name = next(iter(kwargs))
    with pytest.raises(ValueError, match=name.split('_')[0]):
        DenseTracker(**kwargs)


@pytest.mark.parametrize('frame', [np.zeros((4, 4), np.uint8), np.zeros((20, 20, 2), np.uint8),
                                   np.zeros((20, 20), np.int32), np.zeros(5, np.uint8)])
def test_bad_frames_are_named(frame):
    with pytest.raises(ValueError, match='frame|uint8'):
        DenseTracker().track(frame)


def test_normalised_coordinates():
    K = np.array([[500.0, 0, 160], [0, 400, 120], [0, 0, 1]])
    out = DenseTracker(step=40, K=K).track(shifted(texture(), 0, 0))
    xy = out.normalised()
    np.testing.assert_allclose(xy[:, 0], (out.uv[:, 0] - 160) / 500)
    np.testing.assert_allclose(xy[:, 1], (out.uv[:, 1] - 120) / 400)
    with pytest.raises(ValueError, match='K'):
        TrackFrame(ids=out.ids, uv=out.uv, age=out.age).normalised()


def test_every_method_runs():
    base = texture()
    for method in METHODS:
        tracker = DenseTracker(step=16, method=method, fb_max_px=1.0)
        tracker.track(shifted(base, 0, 0))
        out = tracker.track(shifted(base, 2, 1))
        assert len(out.ids) > 200, method


# ------------------------------------------------------------------ rendered scenes

@pytest.fixture(scope='module')
def sheet():
    """A small rendered bending sheet (16 frames, 240 x 320) and its frames."""
    from grass_nrsfm_ros.frontend import scenes
    scene = scenes.sheet_scene('bending', 100, size=(240, 320), focal=310.0, extent_px=200,
                               grid=(48, 36))
    keep = np.arange(16)
    scene = scenes.Scene('sheet16', scene.vertices[keep], scene.triangles, scene.texcoords,
                         scene.K, scene.size, scene.texture, scene.background)
    return scene, [scene.render(f) for f in range(scene.n_frames)]


def test_rendered_sheet_is_tracked_within_bounds(sheet):
    scene, images = sheet
    tracker = DenseTracker(step=6, region=scene.mask(0))
    frames = [tracker.track(image) for image in images]
    first = frames[0]
    truth = scene.truth(first.uv)
    last = frames[-1]
    col = np.searchsorted(first.ids, last.ids[np.isin(last.ids, first.ids)])
    tracked = last.uv[np.isin(last.ids, first.ids)]
    seen = truth.visible[-1, col]
    err = np.linalg.norm(tracked[seen] - truth.uv[-1, col[seen]], axis=1)
    assert len(first.ids) > 500
    assert np.isin(first.ids[truth.visible[-1]], last.ids).mean() > 0.8
    assert np.median(err) < 0.2 and np.percentile(err, 95) < 1.2


def test_surface_leaving_the_view_kills_its_tracks_and_new_ones_are_born():
    from grass_nrsfm_ros.frontend import scenes
    scene = scenes.sheet_scene('waving', 24, size=(240, 320), focal=310.0, extent_px=200,
                               grid=(32, 24), exit_share=0.5)
    tracker = DenseTracker(step=8, region=(0, 0, 319, 239))
    frames = [tracker.track(scene.render(f)) for f in range(scene.n_frames)]
    first, last = frames[0], frames[-1]
    on_sheet = scene.truth(first.uv).on_surface
    assert on_sheet.sum() > 200
    assert not np.isin(first.ids[on_sheet], last.ids).any(), 'tracks survived off-image'
    assert sum(fr.counts['left'] + fr.counts['failed'] for fr in frames) >= on_sheet.sum()
    assert sum(fr.counts['born'] for fr in frames[1:]) > 0.5 * on_sheet.sum()
    births_at = [f for f, fr in enumerate(frames) if f and fr.counts['born']]
    assert births_at and all(frames[f].counts['reanchored'] for f in births_at), \
        'tracks were born without a new reference frame'
    assert len(last.ids) > 0.6 * len(first.ids)
    every = np.concatenate([fr.ids for fr in frames])
    births = np.concatenate([fr.ids[fr.age == 0] for fr in frames])
    assert len(np.unique(births)) == len(births) and np.isin(every, births).all()
