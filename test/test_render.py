"""render.py: PNGs decoded back by hand (zlib + struct), views, the render command."""
import struct
import zlib

import numpy as np
import pytest

from grass_nrsfm_ros import bag, render
from grass_nrsfm_ros.cli import main
from grass_nrsfm_ros.commands.render import aligned_pair


def decode_png(path):
    """``(H, W, 3) uint8`` from an 8-bit RGB, filter-0 PNG (what write_png makes); checks CRCs."""
    data = open(path, 'rb').read()
    assert data[:8] == b'\x89PNG\r\n\x1a\n'
    pos, chunks = 8, {}
    while pos < len(data):
        (n,) = struct.unpack('>I', data[pos:pos + 4])
        tag, body = data[pos + 4:pos + 8], data[pos + 8:pos + 8 + n]
        (crc,) = struct.unpack('>I', data[pos + 8 + n:pos + 12 + n])
        assert crc == zlib.crc32(tag + body) & 0xFFFFFFFF, tag
        chunks[tag] = chunks.get(tag, b'') + body
        pos += 12 + n
    w, h, depth, colour, _, _, _ = struct.unpack('>IIBBBBB', chunks[b'IHDR'])
    assert (depth, colour) == (8, 2) and b'IEND' in chunks
    rows = np.frombuffer(zlib.decompress(chunks[b'IDAT']), np.uint8).reshape(h, 1 + 3 * w)
    assert (rows[:, 0] == 0).all()
    return rows[:, 1:].reshape(h, w, 3)


def test_png_round_trip_is_exact(tmp_path):
    rgb = np.random.default_rng(0).integers(0, 256, (17, 31, 3), dtype=np.uint8)
    render.write_png(tmp_path / 'a.png', rgb)
    np.testing.assert_array_equal(decode_png(tmp_path / 'a.png'), rgb)
    with pytest.raises(ValueError, match='H, W, 3'):
        render.write_png(tmp_path / 'b.png', rgb[..., 0])


def test_splat_draws_nearest_point_on_top_and_colours_by_depth():
    # two points at the same (x, y): the near one (z=1) must win the pixel
    xyz = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 5.0], [1.0, 1.0, 5.0]]).T
    img = render.splat(xyz, size=64, radius=3, extent=(np.zeros(3), 2.0))
    c = img[32, 32].astype(int)
    near, far = render.colormap(np.array([0.0, 1.0])).astype(int)
    assert np.abs(c - near).sum() < np.abs(c - far).sum()
    far_px = img[32 + 14, 32 + 14].astype(int)          # (1, 1) at scale 0.45*64/2
    assert np.abs(far_px - far).sum() < np.abs(far_px - near).sum()
    assert (img[0, 0] == 255).all()


def test_views_are_not_mirrored():
    # a right-handed triad: x right, y down, z forward; each view shows a proper rotation
    for name, ((a, sa), (b, sb), (c, sc)) in render.VIEWS.items():
        R = np.zeros((3, 3))
        R[0, a], R[1, b], R[2, c] = sa, sb, sc
        assert np.isclose(np.linalg.det(R), 1.0), name


def test_frame_figure_and_plot_have_content(tmp_path):
    rng = np.random.default_rng(1)
    S = rng.normal(size=(3, 200))
    img = render.frame_figure(S, S + 0.01, title='frame 0', size=100)
    assert img.shape[1] == 14 + 3 * 104 and img.shape[0] > 2 * 100
    assert (img != 255).any(axis=2).mean() > 0.05
    x = np.arange(5)
    p = render.plot({'a': (x, x ** 2), 'b': (x, 3 * x)}, 'title', 'x', 'y', size=(200, 300))
    assert p.shape == (200, 300, 3)
    dark = (p.sum(axis=2) < 200).sum()
    assert dark > 300                                   # axes, ticks and text are drawn


def test_render_command_npz_and_bag(tmp_path, capsys):
    rng = np.random.default_rng(2)
    F, P = 6, 50
    S_gt = rng.normal(size=(3 * F, P))
    S_est = 2.0 * S_gt * np.tile([[-1.0], [1.0], [1.0]], (F, 1))      # mirrored, scaled
    np.savez(tmp_path / 'r.npz', S=S_est, S_gt=S_gt)
    assert main(['render', str(tmp_path / 'r.npz'), '--frame', '2', '-o',
                 str(tmp_path / 'one.png'), '--size', '120']) == 0
    one = decode_png(tmp_path / 'one.png')
    assert one.shape[1] == 14 + 3 * 124
    assert (one != 255).any(axis=2).sum() > 1000
    assert main(['render', str(tmp_path / 'r.npz'), '--every', '2', '-o',
                 str(tmp_path / 'sheet.png'), '--columns', '2']) == 0
    sheet = decode_png(tmp_path / 'sheet.png')
    assert sheet.shape[0] > sheet.shape[1] / 2            # 3 frames, 2 columns -> 2 rows

    W = S_gt[np.sort(np.r_[0:3 * F:3, 1:3 * F:3])]
    bag.tracks_bag_from_arrays(W, np.arange(F) * 10, tmp_path / 'b', S=S_gt)
    assert main(['render', str(tmp_path / 'b'), '--frame', '5', '-o',
                 str(tmp_path / 'gt.png')]) == 0
    assert (decode_png(tmp_path / 'gt.png') != 255).any(axis=2).sum() > 1000
    assert main(['render', str(tmp_path / 'r.npz'), '--frame', '6', '-o',
                 str(tmp_path / 'x.png')]) == 2
    assert 'outside 0..5' in capsys.readouterr().err


def test_estimate_is_aligned_to_truth_before_drawing():

    rng = np.random.default_rng(4)
    truth = rng.normal(size=(3, 30)) + 5.0
    est = 2.0 * np.diag([-1.0, 1.0, 1.0]) @ truth                # mirrored and scaled
    ids = np.arange(30)
    e, t, err = aligned_pair((0, ids[::-1], est[:, ::-1]), (0, ids, truth))   # ids permuted
    assert err < 1e-9
    np.testing.assert_allclose(e, t, atol=1e-9)
