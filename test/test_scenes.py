"""The renderer's ground truth (grass_nrsfm_ros.frontend.scenes): projections, coverage and
depth, visibility, and rendered texture moving with the true projections."""
import numpy as np
import pytest

from grass_nrsfm_ros.frontend import scenes
from grass_nrsfm_ros.frontend.imaging import sample


def square(z, half, centre=(0.0, 0.0), n=2):
    """A flat square facing the camera: vertices ``(n*n, 3)``, triangles, texcoords."""
    s = np.linspace(-half, half, n)
    x, y = np.meshgrid(s + centre[0], s + centre[1])
    vertices = np.column_stack([x.ravel(), y.ravel(), np.full(n * n, z)])
    texcoords = (np.column_stack([x.ravel(), y.ravel()]) - x.min()) / (2 * half)
    return vertices, scenes._grid_triangles(n, n), texcoords


def two_squares(n_frames=3):
    """A small square at depth 2 in front of a larger one at depth 4 (size 120 x 160)."""
    front, tri_f, tex_f = square(2.0, 0.2, centre=(0.1, 0.0))
    back, tri_b, tex_b = square(4.0, 1.0, n=5)
    vertices = np.concatenate([front, back])
    triangles = np.concatenate([tri_f, tri_b + len(front)])
    texcoords = np.concatenate([tex_f, tex_b])
    size = (120, 160)
    moving = np.stack([vertices + [0.02 * f, 0, 0] for f in range(n_frames)])
    texture = scenes.random_texture((64, 64), 1)
    background = scenes.random_texture(size, 2)
    return scenes.Scene('squares', moving, triangles, texcoords, scenes.pinhole(size, 100.0),
                        size, texture, background, noise=0.0, shading=0.0)


def test_rasteriser_covers_exactly_the_pixel_centres_inside():
    scene = two_squares()
    raster = scene.raster(0)
    K = scene.K
    u = K[0, 0] * np.array([-0.1, 0.3]) / 2.0 + K[0, 2]        # front square's u range
    v = K[1, 1] * np.array([-0.2, 0.2]) / 2.0 + K[1, 2]
    cols = np.arange(160)
    rows = np.arange(120)
    inside = ((cols[None] >= u[0]) & (cols[None] <= u[1])
              & (rows[:, None] >= v[0]) & (rows[:, None] <= v[1]))
    front = raster.triangle >= 0
    front &= raster.triangle < 2
    np.testing.assert_array_equal(front, inside)
    np.testing.assert_allclose(raster.depth[front], 2.0, rtol=1e-6)
    behind = (raster.triangle >= 2)
    np.testing.assert_allclose(raster.depth[behind], 4.0, rtol=1e-6)
    assert behind.sum() > 2 * front.sum()
    np.testing.assert_allclose(raster.bary[front | behind].sum(axis=1), 1.0, atol=1e-5)
    assert np.isinf(raster.depth[raster.triangle < 0]).all()


def test_perspective_correct_barycentrics_recover_the_surface_point():
    """A slanted triangle: the point interpolated from the pixel's barycentric coordinates
    projects back onto the pixel centre."""
    vertices = np.array([[-1.0, -1.0, 3.0], [1.5, -1.0, 6.0], [-1.0, 1.2, 4.0]])
    K = scenes.pinhole((100, 100), 80.0)
    uv = vertices @ K.T
    raster = scenes.rasterise(uv[:, :2] / uv[:, 2:], vertices[:, 2], np.array([[0, 1, 2]]),
                              (100, 100))
    rows, cols = np.nonzero(raster.triangle == 0)
    assert len(rows) > 500
    X = raster.bary[rows, cols].astype(np.float64) @ vertices
    back = X @ K.T
    np.testing.assert_allclose(back[:, 0] / back[:, 2], cols, atol=2e-3)
    np.testing.assert_allclose(back[:, 1] / back[:, 2], rows, atol=2e-3)
    np.testing.assert_allclose(raster.depth[rows, cols], X[:, 2], rtol=1e-5)


def test_truth_is_the_pinhole_projection_and_follows_the_surface():
    scene = scenes.sheet_scene('waving', 8, size=(120, 160), focal=150.0, extent_px=100,
                               grid=(24, 18))
    v, u = np.nonzero(scene.mask(0))
    uv0 = np.column_stack([u, v])[::7] + 0.25
    truth = scene.truth(uv0)
    assert truth.on_surface.all() and truth.uv.shape == (8, len(uv0), 2)
    np.testing.assert_allclose(truth.uv[0], uv0, atol=1e-9)
    expected = truth.X @ scene.K.T
    np.testing.assert_allclose(truth.uv, expected[..., :2] / expected[..., 2:], rtol=1e-12)
    assert np.abs(truth.uv[-1] - truth.uv[0]).max() > 3.0
    later = scene.truth(truth.uv[5, truth.visible[5]], start=5)
    gap = np.linalg.norm(later.X - truth.X[:, truth.visible[5]], axis=2)
    assert np.median(gap) < 1e-9 and np.percentile(gap, 99) < 1e-4 and gap.max() < 1e-2


def test_background_pixels_have_no_truth():
    scene = two_squares()
    truth = scene.truth(np.array([[1.0, 1.0], [80.0, 60.0]]))
    assert truth.on_surface.tolist() == [False, True]
    assert np.isnan(truth.uv[:, 0]).all() and not truth.visible[:, 0].any()
    assert truth.visible[:, 1].all()


def test_occluded_points_are_not_visible():
    scene = two_squares()
    points = scene.sample_points(3000)
    front_depth = np.isclose(points.X[0, :, 2], 2.0)
    behind_front = (~front_depth) & (np.abs(points.X[0, :, 0] - 0.2) < 0.18) & \
        (np.abs(points.X[0, :, 1]) < 0.18)
    assert behind_front.sum() > 10
    assert not points.visible[0, behind_front].any()
    assert points.visible[0, front_depth].all()
    far = (~front_depth) & (np.abs(points.X[0, :, 0] - 0.1) > 0.6)
    inside = (np.abs(points.uv[0] - (80, 60)) < (76, 56)).all(axis=1)
    assert points.visible[0, far & inside].all()


def test_facing_is_the_cosine_from_face_on():
    """A square facing the camera is seen face on at its centre; turned by 60 degrees about
    the vertical, a point on its axis is seen at 60 degrees."""
    scene = two_squares()
    truth = scene.truth(np.array([[80.0, 60.0], [1.0, 1.0]]))
    np.testing.assert_allclose(truth.facing[:, 0], 1.0, atol=1e-3)
    assert np.isnan(truth.facing[:, 1]).all()
    vertices, triangles, texcoords = square(0.0, 0.5)
    turn = np.radians(60.0)
    R = np.array([[np.cos(turn), 0, np.sin(turn)], [0, 1, 0], [-np.sin(turn), 0, np.cos(turn)]])
    slanted = (vertices @ R.T + [0, 0, 3.0])[None]
    size = (120, 160)
    scene = scenes.Scene('slanted', slanted, triangles, texcoords, scenes.pinhole(size, 100.0),
                         size, scenes.random_texture((64, 64), 1), scenes.random_texture(size, 2))
    truth = scene.truth(np.array([[79.5, 59.5]]))
    sight = truth.X[0, 0] / np.linalg.norm(truth.X[0, 0])
    np.testing.assert_allclose(truth.facing[0, 0], abs(sight @ R[:, 2]), rtol=1e-9)
    assert 0.45 < truth.facing[0, 0] < 0.55


def test_points_leaving_the_image_are_not_visible():
    scene = scenes.sheet_scene('bending', 10, size=(120, 160), focal=150.0, extent_px=90,
                               grid=(16, 12), exit_share=0.5)
    points = scene.sample_points(500)
    u = points.uv[..., 0]
    assert points.visible[0].mean() > 0.9
    np.testing.assert_array_equal(points.visible[u > 157.0], False)
    assert not points.visible[-1].any()


def test_rendered_texture_moves_with_its_true_projection():
    scene = scenes.sheet_scene('bending', 6, size=(240, 320), focal=300.0, extent_px=200,
                               grid=(48, 36), noise=0.0, shading=0.0)
    images = scene.images()
    assert images.shape == (6, 240, 320, 3) and images.dtype == np.uint8
    v, u = np.nonzero(scene.mask(0))
    uv0 = np.column_stack([u, v])[::5].astype(float)
    truth = scene.truth(uv0)
    seen = truth.visible[-1] & truth.visible[0]
    before = sample(images[0], uv0[seen])
    after = sample(images[-1], truth.uv[-1, seen])
    moved = np.linalg.norm(truth.uv[-1, seen] - uv0[seen], axis=1)
    assert np.median(moved) > 5.0
    same = np.median(np.abs(after - before))
    shuffled = np.median(np.abs(after - np.roll(before, 17, axis=0)))
    assert same < 6.0 < 4 * 6.0 < shuffled


def test_supersampled_frames_keep_the_geometry():
    scene = scenes.sheet_scene('bending', 2, size=(120, 160), focal=150.0, extent_px=90,
                               grid=(16, 12), noise=0.0, shading=0.0, supersample=2)
    image = scene.render(0)
    plain = scenes.Scene('plain', scene.vertices, scene.triangles, scene.texcoords, scene.K,
                         scene.size, scene.texture, scene.background, noise=0.0,
                         shading=0.0).render(0)
    mask = scene.mask(0)
    interior = mask & np.roll(mask, 2, 0) & np.roll(mask, -2, 0) & np.roll(mask, 2, 1) & \
        np.roll(mask, -2, 1)
    diff = np.abs(image.astype(int) - plain.astype(int))[interior]
    assert np.median(diff) < 8


def test_unknown_kind_is_named():
    with pytest.raises(ValueError, match='kind'):
        scenes.sheet_scene('melting', 2)


@pytest.mark.data
def test_face_scene_renders_a_turning_face():
    try:
        scene = scenes.face_scene(12, size=(240, 320), focal=310.0, extent_px=170)
    except FileNotFoundError:
        pytest.skip('Surrey face model not found (set GRASS_NRSFM_DATA)')
    mask = scene.mask(0)
    assert 0.05 < mask.mean() < 0.5
    v, u = np.nonzero(mask)
    truth = scene.truth(np.column_stack([u, v])[::3].astype(float))
    assert truth.visible.mean() > 0.8
    expected = truth.X @ scene.K.T
    np.testing.assert_allclose(truth.uv, expected[..., :2] / expected[..., 2:], rtol=1e-12)
    image = scene.render(6)
    assert image.shape == (240, 320, 3) and image[mask].std() > 20
