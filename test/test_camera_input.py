"""Camera intrinsics as input: ``grass-nrsfm reconstruct`` with ``K`` in the npz or
``--camera``, the solver parameter ``projection``, and pixel tracks without ``K`` solved as
before (with a warning). Pinhole ground truth: a synthetic inflating surface 2.5 units in
front of the camera (its size is about 2), projected through ``K``."""
import json
import re
import warnings

import numpy as np
import pytest

from grass_nrsfm_ros.cli import main
from grass_nrsfm_ros.nrsfm import camera, GrassmannNRSfM, synthetic
from grass_nrsfm_ros.nrsfm.camera import OrthographicPixelsWarning
from grass_nrsfm_ros.nrsfm.measurement import as_frames, from_frames
from grass_nrsfm_ros.nrsfm.metrics import e3d

F, P, DISTANCE = 24, 300, 2.5
K = camera.intrinsics(500.0, 520.0, 320.0, 240.0)


@pytest.fixture(scope='module')
def pinhole():
    """``(S: (3F, P) camera frame, W: (2F, P) pixels)``."""
    seq = synthetic.make_sequence('inflating', n_frames=F, n_points=P, camera='orbit', seed=1)
    X = as_frames(seq.S, 3).copy()
    X[:, 2] += DISTANCE
    S = from_frames(X)
    return S, camera.project(S, K)


@pytest.fixture(scope='module')
def perspective(pinhole):
    """The estimator's perspective solve of the normalised tracks."""
    return GrassmannNRSfM(projection='perspective').fit(camera.normalise(pinhole[1], K))


def reconstruct(tmp_path, arrays, *extra, name='out.npz'):
    np.savez(tmp_path / 'in.npz', **arrays)
    out = tmp_path / name
    assert main(['reconstruct', str(tmp_path / 'in.npz'), '-o', str(out), '--quiet',
                 *extra]) == 0
    with np.load(out) as npz:
        return {k: npz[k] for k in npz.files}


def test_perspective_beats_the_orthographic_solve_of_the_same_pixels(pinhole, perspective):
    S, W = pinhole
    pixels = e3d(GrassmannNRSfM().fit(W).S, S, scale=True)
    seen = e3d(GrassmannNRSfM().fit(from_frames(as_frames(S, 3)[:, :2])).S, S, scale=True)
    ours = e3d(perspective.S, S, scale=True)
    # measured: 0.0115 against 0.173 (pixels as orthographic) and 0.0134 (the orthographic
    # projections of the same points)
    assert ours < 0.1 * pixels and ours < 1.2 * seen, (ours, pixels, seen)
    report = perspective.report.perspective
    assert report['kept'] >= 1 and len(report['rounds']) >= 3
    assert not np.any(perspective.translation)


def test_the_output_is_the_camera_frame_of_the_pinhole(pinhole, perspective):
    S, W = pinhole
    Z = as_frames(perspective.S, 3)[:, 2]
    assert (Z > 0).all()
    np.testing.assert_allclose(Z.mean(axis=1), 1.0, rtol=1e-12)       # the documented unit
    np.testing.assert_allclose(camera.project(perspective.S, K), W, atol=1e-9)


def test_k_from_the_npz(pinhole, perspective, tmp_path, capsys):
    S, W = pinhole
    with warnings.catch_warnings():
        warnings.simplefilter('error', OrthographicPixelsWarning)      # none with K
        out = reconstruct(tmp_path, dict(W=W, S=S, K=K), '--scale', '2.5')
    np.testing.assert_array_equal(out['S'], 2.5 * perspective.S)
    np.testing.assert_array_equal(out['K'], K)
    assert str(out['projection']) == 'perspective'
    assert json.loads(str(out['report']))['perspective']['kept'] >= 1
    text = capsys.readouterr().out
    printed = float(re.search(r'e3D \(per-frame Procrustes, with scale\): ([0-9.]+)',
                              text).group(1))
    assert printed == pytest.approx(e3d(perspective.S, S, scale=True), abs=1e-4)
    assert "each frame's mean depth 2.5" in text


def test_k_from_the_command_line_wins_over_the_npz(pinhole, perspective, tmp_path, capsys):
    S, W = pinhole
    out = reconstruct(tmp_path, dict(W=W), '--camera', '500', '520', '320', '240')
    np.testing.assert_array_equal(out['S'], perspective.S)
    wrong = reconstruct(tmp_path, dict(W=W, K=camera.intrinsics(900, 900, 0, 0)), '--camera',
                        '500', '520', '320', '240', name='wrong.npz')
    np.testing.assert_array_equal(wrong['S'], perspective.S)
    assert 'its K replaced by --camera' in capsys.readouterr().out


def test_pixels_without_k_are_solved_as_before_with_a_warning(pinhole, tmp_path):
    S, W = pinhole
    W = W[:, :120]
    with pytest.warns(OrthographicPixelsWarning, match='no camera intrinsics'):
        out = reconstruct(tmp_path, dict(W=W))
    np.testing.assert_array_equal(out['S'], GrassmannNRSfM().fit(W).S)
    assert str(out['projection']) == 'orthographic' and 'K' not in out
    assert json.loads(str(out['report']))['perspective'] is None
    # projection 'orthographic' with K: the pixels as before (no warning: K was given)
    config = tmp_path / 'ortho.yaml'
    config.write_text('solver:\n  projection: orthographic\n')
    with warnings.catch_warnings():
        warnings.simplefilter('error', OrthographicPixelsWarning)
        out = reconstruct(tmp_path, dict(W=W, K=K), '--config', str(config))
    np.testing.assert_array_equal(out['S'], GrassmannNRSfM().fit(W).S)


def test_projection_perspective_without_k_takes_normalised_tracks(pinhole, perspective,
                                                                  tmp_path):
    S, W = pinhole
    config = tmp_path / 'perspective.yaml'
    config.write_text('solver:\n  projection: perspective\n')
    out = reconstruct(tmp_path, dict(W=camera.normalise(W, K)), '--config', str(config))
    np.testing.assert_array_equal(out['S'], perspective.S)


@pytest.mark.parametrize('arrays, extra, message', [
    (dict(K=np.eye(2)), (), 'K must be (3, 3)'),
    (dict(K=np.diag([500.0, -500.0, 1.0])), (), 'positive focal lengths'),
    (dict(), ('--camera', '0', '500', '320', '240'), '--camera: '),
    (dict(K=K), ('--scale', '-1'), '--scale -1.0: expected a finite number > 0'),
    (dict(), ('--scale', '2'), '--scale applies to the perspective model'),
])
def test_bad_camera_input_is_one_clear_line(pinhole, tmp_path, capsys, arrays, extra, message):
    np.savez(tmp_path / 'in.npz', W=pinhole[1][:, :50], **arrays)
    assert main(['reconstruct', str(tmp_path / 'in.npz'), '-o', str(tmp_path / 'out.npz'),
                 '--quiet', *extra]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / 'out.npz').exists()
