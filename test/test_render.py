"""render.py (matplotlib): PNGs read back by matplotlib, views, draw order, the render command
(with and without matplotlib), and the bench plots."""
import sys

import numpy as np
import pytest

mpl_image = pytest.importorskip('matplotlib.image')
from bench import plot  # noqa: E402, I100
import grass_nrsfm_ros  # noqa: E402
from grass_nrsfm_ros import bag, mesh, render  # noqa: E402
from grass_nrsfm_ros.cli import main  # noqa: E402
from grass_nrsfm_ros.commands.render import aligned_pair  # noqa: E402


def read_png(path):
    """``(H, W, 3) uint8`` of a PNG file."""
    img = mpl_image.imread(path)
    assert img.dtype == np.float32 and img.shape[2] in (3, 4)
    return np.round(img[..., :3] * 255).astype(np.uint8)


def inked(img):
    """Fraction of pixels that are not white."""
    return (img < 250).any(axis=2).mean()


def test_png_round_trip_is_exact(tmp_path):
    rgb = np.random.default_rng(0).integers(0, 256, (17, 31, 3), dtype=np.uint8)
    render.write_png(tmp_path / 'a.png', rgb)
    assert (tmp_path / 'a.png').read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    np.testing.assert_array_equal(read_png(tmp_path / 'a.png'), rgb)
    with pytest.raises(ValueError, match='H, W, 3'):
        render.write_png(tmp_path / 'b.png', rgb[..., 0])


def test_nearest_points_are_drawn_last():
    xyz = np.array([[0.0, 0.0, 5.0], [0.0, 0.0, 1.0], [1.0, 1.0, 3.0], [np.nan, 0, 0]]).T
    assert list(render.draw_order(xyz, 'front')) == [0, 2, 1]          # far z first, NaN out
    assert list(render.draw_order(xyz, 'side')) == [0, 1, 2]           # seen from +x: x=1 last
    assert list(render.draw_order(xyz, 'top')) == [2, 0, 1]            # from -y: y=0 last


def test_views_are_not_mirrored():
    # a right-handed triad: x right, y down, z forward; each view shows a proper rotation
    for name, ((a, sa), (b, sb), (c, sc)) in render.VIEWS.items():
        R = np.zeros((3, 3))
        R[0, a], R[1, b], R[2, c] = sa, sb, sc
        assert np.isclose(np.linalg.det(R), 1.0), name


def test_frame_figure_has_a_panel_per_view_and_cloud():
    rng = np.random.default_rng(1)
    S = rng.normal(size=(3, 200))
    both = render.frame_figure(S, S + 0.01, title='frame 0', size=100)
    one = render.frame_figure(S, None, size=100, views=('front',))
    assert both.dtype == np.uint8 and both.shape[2] == 3
    assert both.shape[1] > 3 * 100 and both.shape[0] > 2 * 100
    assert one.shape[0] < both.shape[0] and one.shape[1] < both.shape[1]
    assert inked(both) > 0.05
    with pytest.raises(ValueError, match='nothing to draw'):
        render.frame_figure(None, None)


def test_render_command_npz_and_bag(tmp_path, capsys):
    rng = np.random.default_rng(2)
    F, P = 6, 50
    S_gt = rng.normal(size=(3 * F, P))
    S_est = 2.0 * S_gt * np.tile([[-1.0], [1.0], [1.0]], (F, 1))      # mirrored, scaled
    np.savez(tmp_path / 'r.npz', S=S_est, S_gt=S_gt)
    assert main(['render', str(tmp_path / 'r.npz'), '--frame', '2', '-o',
                 str(tmp_path / 'one.png'), '--size', '120', '--units', 'm']) == 0
    one = read_png(tmp_path / 'one.png')
    assert one.shape[1] > 3 * 120 and one.shape[0] > 2 * 120     # 3 views x (estimate, truth)
    assert inked(one) > 0.05
    assert main(['render', str(tmp_path / 'r.npz'), '--every', '2', '-o',
                 str(tmp_path / 'sheet.png'), '--columns', '2']) == 0
    sheet = read_png(tmp_path / 'sheet.png')
    assert sheet.shape[0] > sheet.shape[1] / 2            # 3 frames, 2 columns -> 2 rows

    W = S_gt[np.sort(np.r_[0:3 * F:3, 1:3 * F:3])]
    bag.tracks_bag_from_arrays(W, np.arange(F) * 10, tmp_path / 'b', S=S_gt)
    assert main(['render', str(tmp_path / 'b'), '--frame', '5', '-o',
                 str(tmp_path / 'gt.png')]) == 0
    assert inked(read_png(tmp_path / 'gt.png')) > 0.02
    assert main(['render', str(tmp_path / 'r.npz'), '--frame', '6', '-o',
                 str(tmp_path / 'x.png')]) == 2
    assert 'outside 0..5' in capsys.readouterr().err


def test_render_without_matplotlib_says_how_to_install_it(tmp_path, capsys, monkeypatch):
    np.savez(tmp_path / 'r.npz', S=np.zeros((3, 4)))
    monkeypatch.delitem(sys.modules, 'grass_nrsfm_ros.render')
    monkeypatch.delattr(grass_nrsfm_ros, 'render')
    monkeypatch.setitem(sys.modules, 'matplotlib', None)       # import matplotlib fails
    assert main(['render', str(tmp_path / 'r.npz'), '-o', str(tmp_path / 'x.png')]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "pip install 'grass_nrsfm_ros[plot]'" in err
    assert not (tmp_path / 'x.png').exists()


def test_estimate_is_aligned_to_truth_before_drawing():
    rng = np.random.default_rng(4)
    truth = rng.normal(size=(3, 30)) + 5.0
    est = 2.0 * np.diag([-1.0, 1.0, 1.0]) @ truth                # mirrored and scaled
    ids = np.arange(30)
    e, t, err = aligned_pair((0, ids[::-1], est[:, ::-1]), (0, ids, truth))   # ids permuted
    assert err < 1e-9
    np.testing.assert_allclose(e, t, atol=1e-9)


def test_bench_plots_are_pngs_with_content(tmp_path):
    x = np.arange(1, 6)
    assert plot.line_plot(tmp_path / 'l.png', {'a': (x, x ** 2), 'b': (x, 3 * x)}, 'title',
                          'x (frames)', 'y (s)', logy=True, logx=True) == tmp_path / 'l.png'
    line = read_png(tmp_path / 'l.png')
    assert line.shape[:2] == (360, 560) and inked(line) > 0.02
    assert plot.line_plot(tmp_path / 'none.png', {'a': ([], [])}) is None
    plot.bar_plot(tmp_path / 'b.png', {'one': 0.0, 'two': 2.5}, 'bars', 'lost (%)')
    assert inked(read_png(tmp_path / 'b.png')) > 0.02
    plot.matrix_image(tmp_path / 'm.png', np.eye(20), scale=10)
    assert inked(read_png(tmp_path / 'm.png')) > 0.02


def test_mesh_figure_draws_a_marker_triangle_list():
    g = np.stack(np.meshgrid(np.linspace(-1, 1, 8), np.linspace(-1, 1, 8)), -1).reshape(-1, 2)
    xyz = np.c_[g, 0.3 * g[:, 0] ** 2]
    vertices, colours = mesh.triangle_list(xyz, mesh.triangulate(g))
    img = render.mesh_figure(vertices, colours, size=(300, 400))
    assert img.shape == (300, 400, 3) and inked(img) > 0.1
