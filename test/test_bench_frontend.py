"""bench.frontend: its timing holds the tracks it names (the region is enlarged by the share of
tracks a first run lost, so that the timed runs average at least ``target`` tracks); its
``--seeds`` render other scenes, named by their seed."""
import numpy as np

from bench import frontend
from grass_nrsfm_ros.frontend import scenes


def test_timing_averages_at_least_the_target_tracks():
    scene = scenes.sheet_scene('bending', 16, size=(240, 320), focal=310.0, extent_px=200,
                               grid=(32, 24))
    images = [scene.render(f) for f in range(scene.n_frames)]
    mask = scene.mask(0)
    target = 800
    figures = frontend.timing(images, mask, 'dis-fast+lk', target=target, repeats=1)
    step = figures['timing_step']
    assert mask[::step, ::step].sum() >= 2 * target
    first_cut = frontend._cut_rows(mask, step, target)
    assert first_cut[::step, ::step].sum() <= target
    lost, _ = frontend.run_tracker(images, 'dis-fast+lk', step, first_cut)
    assert np.mean([len(f.ids) for f in lost]) < target      # tracks die: the cut alone is short
    assert target <= figures['timing_tracks_mean'] <= 1.3 * target
    assert figures['ms_per_frame_1_thread'] > 0


def test_seeds_give_other_scenes_named_by_their_seed():
    (name0, sheet0), = [pair for pair in frontend.make_scenes(3) if 'sheet' in pair[0]]
    (name2, sheet2), = [pair for pair in frontend.make_scenes(3, seed=2) if 'sheet' in pair[0]]
    assert (name0, name2) == ('sheet', 'sheet seed 2')
    assert not np.array_equal(sheet0.render(0), sheet2.render(0))
