"""``grass-nrsfm track``: a folder of images, a video and a bag of Images + CameraInfo become
the .npz layout (W NaN where a track is not tracked, ids, stamps, visible, K) or a tracks bag
with camera_info; an unreadable input is one line and exit code 2.

Inputs are rendered here by :mod:`grass_nrsfm_ros.frontend.scenes` (a textured bending sheet
with the true projection of every surface point) and written into tmp_path.
"""
import json

import cv2
import numpy as np
import pytest

from grass_nrsfm_ros import bag, cli, image
from grass_nrsfm_ros.commands.track import tracks_matrix
from grass_nrsfm_ros.frontend import DenseTracker, scenes
from grass_nrsfm_ros.frontend.sources import natural_key, open_source

FX, FY, CX, CY = 155.0, 150.0, 79.5, 59.5
N_FRAMES = 10


@pytest.fixture(scope='module')
def scene():
    return scenes.sheet_scene('bending', n_frames=N_FRAMES, size=(120, 160), focal=155.0,
                              extent_px=110, grid=(24, 18), yaw=10.0, seed=3)


@pytest.fixture(scope='module')
def frames(scene):
    return scene.images()                                  # (F, H, W, 3) RGB


def write_folder(folder, frames, names=None):
    folder.mkdir()
    for f, rgb in enumerate(frames):
        name = names[f] if names else f'{f:03d}.png'
        cv2.imwrite(str(folder / name), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    return folder


def track(capsys, *argv):
    """``(exit code, stdout, stderr lines)`` of ``grass-nrsfm track ARGV``."""
    code = cli.main(['track', *map(str, argv)])
    out, err = capsys.readouterr()
    return code, out, [line for line in err.splitlines() if line.strip()]


def load(path):
    with np.load(path) as npz:
        return {k: npz[k] for k in npz.files}


def reference_tracks(frames, **options):
    """W and ids from DenseTracker run directly on ``frames`` (the CLI must equal them)."""
    tracker = DenseTracker(**options)
    out = [tracker.track(f) for f in frames]
    return tracks_matrix([o.ids for o in out], [o.uv for o in out])


def test_folder_to_npz_layout_equals_the_tracker_and_follows_the_surface(
        tmp_path, capsys, scene, frames):
    folder = write_folder(tmp_path / 'frames', frames)
    out = tmp_path / 'tracks.npz'
    code, stdout, _ = track(capsys, folder, '-o', out, '--step', 4, '--roi', 30, 20, 130, 100,
                            '--camera', FX, FY, CX, CY)
    assert code == 0, stdout
    npz = load(out)
    W, ids = npz['W'], npz['ids']
    F, P = N_FRAMES, ids.size
    assert W.shape == (2 * F, P) and W.dtype == np.float64 and P > 300
    assert npz['stamps'].dtype == np.int64
    np.testing.assert_array_equal(npz['stamps'], np.round(np.arange(F) * 1e9 / 30))
    np.testing.assert_array_equal(npz['K'], [[FX, 0, CX], [0, FY, CY], [0, 0, 1]])
    assert npz['visible'].shape == (F, P) and npz['visible'].dtype == bool
    np.testing.assert_array_equal(npz['visible'], np.isfinite(W[0::2]))
    np.testing.assert_array_equal(np.isfinite(W[0::2]), np.isfinite(W[1::2]))
    assert json.loads(str(npz['meta']))['stamps_from'].startswith('frame index / 30 Hz')
    # the exact tracks of the front end, NaN where a track is not alive
    W_ref, ids_ref = reference_tracks(frames, step=4, region=(30, 20, 130, 100))
    np.testing.assert_array_equal(ids, ids_ref)
    np.testing.assert_array_equal(W, W_ref)
    # in the region in frame 0, on the grid; and where the surface point really went
    first = np.isfinite(W[0])
    u0, v0 = W[0, first], W[1, first]
    assert (u0 >= 30).all() and (u0 <= 130).all() and (v0 >= 20).all() and (v0 <= 100).all()
    truth = scene.truth(np.column_stack([u0, v0]))
    uv = np.stack([W[0::2, first], W[1::2, first]], axis=-1)          # (F, N, 2)
    seen = np.isfinite(uv[..., 0]) & truth.visible
    errors = np.linalg.norm(uv - truth.uv, axis=-1)[seen]
    assert seen[-1].sum() > 0.3 * first.sum()          # 43 % measured (160 x 120 pixels)
    assert np.median(errors) < 0.6 and np.percentile(errors, 95) < 1.5, \
        (np.median(errors), np.percentile(errors, 95))


def test_folder_without_camera_has_no_K_and_mask_bounds_the_start(tmp_path, capsys, frames):
    folder = write_folder(tmp_path / 'frames', frames[:4])
    mask = np.zeros(frames.shape[1:3], np.uint8)
    mask[40:80, 50:110] = 255
    cv2.imwrite(str(tmp_path / 'mask.png'), mask)
    out = tmp_path / 'sub' / 'tracks.npz'
    code, stdout, err = track(capsys, folder, '-o', out, '--mask', tmp_path / 'mask.png',
                              '--step', 3, '--complete')
    assert code == 0
    npz = load(out)
    assert 'K' not in npz
    assert np.isfinite(npz['W']).all() and npz['W'].shape[1] > 50      # --complete
    u0, v0 = npz['W'][0], npz['W'][1]
    assert (u0 >= 50).all() and (u0 < 110).all() and (v0 >= 40).all() and (v0 < 80).all()
    assert 'K unknown' in stdout
    assert any(line.startswith('track: 4/4 frames') for line in err)     # the counter line


def test_folder_order_is_by_name_with_numbers_as_numbers(tmp_path):
    names = ['f10.png', 'f9.png', 'f1.png', 'f100.png']
    assert sorted(names, key=natural_key) == ['f1.png', 'f9.png', 'f10.png', 'f100.png']
    folder = tmp_path / 'frames'
    folder.mkdir()
    for k, name in enumerate(names):                 # grey level = position in the order
        level = {'f1.png': 10, 'f9.png': 20, 'f10.png': 30, 'f100.png': 40}[name]
        cv2.imwrite(str(folder / name), np.full((16, 16), level, np.uint8))
    (folder / 'notes.txt').write_text('not an image')
    levels = [int(frame.image[0, 0]) for frame in open_source(folder)]
    assert levels == [10, 20, 30, 40]


def test_video_to_npz_with_the_video_frame_times(tmp_path, capsys, frames):
    path = tmp_path / 'clip.avi'
    H, W = frames.shape[1:3]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*'MJPG'), 25.0, (W, H))
    if not writer.isOpened():
        pytest.skip('OpenCV has no MJPG / AVI writer here')
    for rgb in frames:
        writer.write(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    writer.release()
    out = tmp_path / 'tracks.npz'
    code, stdout, _ = track(capsys, path, '-o', out, '--roi', 30, 20, 130, 100,
                            '--max-frames', 8)
    assert code == 0
    npz = load(out)
    assert npz['W'].shape[0] == 16 and npz['stamps'].shape == (8,)
    np.testing.assert_allclose(npz['stamps'], np.arange(8) * 40_000_000, atol=1_000_000)
    assert 'stamps from the video frame times' in stdout
    assert np.isfinite(npz['W'][-2:]).sum() > 300


def write_image_bag(path, frames, camera_k=None, encoding='bgr8', topic='/cam/image_raw'):
    """A bag of sensor_msgs/Image (and CameraInfo on the sibling topic) at 20 Hz."""
    types = bag.typestore().types
    info_topic = topic.rsplit('/', 1)[0] + '/camera_info'
    stamps = 1_700_000_000_000_000_000 + np.arange(len(frames)) * 50_000_000
    with bag.BagWriter(path) as writer:
        writer.add_topic(topic, 'sensor_msgs/msg/Image')
        if camera_k is not None:
            writer.add_topic(info_topic, 'sensor_msgs/msg/CameraInfo')
        for rgb, stamp in zip(frames, stamps):
            sec, nanosec = divmod(int(stamp), 1_000_000_000)
            header = types['std_msgs/msg/Header'](
                stamp=types['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec),
                frame_id='cam_optical')
            pixels = rgb[..., ::-1] if encoding == 'bgr8' else rgb
            writer.write(topic, types['sensor_msgs/msg/Image'](
                header=header, **image.image_layout(np.ascontiguousarray(pixels), encoding)),
                stamp)
            if camera_k is not None:
                roi = types['sensor_msgs/msg/RegionOfInterest'](
                    x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
                writer.write(info_topic, types['sensor_msgs/msg/CameraInfo'](
                    header=header, height=rgb.shape[0], width=rgb.shape[1],
                    distortion_model='plumb_bob', d=np.zeros(5), k=np.ravel(camera_k),
                    r=np.eye(3).ravel(), p=np.hstack([camera_k, np.zeros((3, 1))]).ravel(),
                    binning_x=0, binning_y=0, roi=roi), stamp)
    return stamps


def test_bag_of_images_and_camera_info_to_npz_and_to_a_tracks_bag(tmp_path, capsys, frames):
    K = np.array([[FX, 0, CX], [0, FY, CY], [0, 0, 1]])
    stamps = write_image_bag(tmp_path / 'images', frames[:6], K)
    out = tmp_path / 'tracks.npz'
    code, stdout, _ = track(capsys, tmp_path / 'images', '-o', out, '--roi', 30, 20, 130, 100)
    assert code == 0, stdout
    npz = load(out)
    np.testing.assert_array_equal(npz['stamps'], stamps)
    np.testing.assert_array_equal(npz['K'], K)
    assert 'K from the bag topic /cam/camera_info' in stdout
    # bgr8 images are the same frames: the same tracks as the folder's RGB
    W_ref, ids_ref = reference_tracks(frames[:6], step=4, region=(30, 20, 130, 100))
    np.testing.assert_array_equal(npz['W'], W_ref)

    code, stdout, _ = track(capsys, tmp_path / 'images', '-o', tmp_path / 'tracks_bag',
                            '--roi', 30, 20, 130, 100)
    assert code == 0
    W_bag, ids_bag, stamps_bag = bag.read_W(tmp_path / 'tracks_bag')    # the node's reader
    np.testing.assert_array_equal(stamps_bag, stamps)
    np.testing.assert_array_equal(ids_bag, ids_ref[np.isfinite(W_ref).any(axis=0)])
    np.testing.assert_allclose(W_bag, W_ref[:, np.isfinite(W_ref).any(axis=0)], atol=1e-4)
    with bag.BagReader(tmp_path / 'tracks_bag') as reader:
        conns = reader.connections('/camera_info', 'sensor_msgs/msg/CameraInfo')
        infos = [reader.decode(raw, c) for c, _, raw in reader.messages(conns)]
    assert len(infos) == 6
    assert infos[0].header.frame_id == 'cam_optical'
    np.testing.assert_array_equal(np.reshape(infos[0].k, (3, 3)), K)
    assert (infos[0].width, infos[0].height) == (160, 120)


def test_camera_from_the_command_line_wins_over_the_bag(tmp_path, capsys, frames):
    write_image_bag(tmp_path / 'images', frames[:3], np.diag([100.0, 100.0, 1.0]),
                    encoding='rgb8', topic='/image')
    out = tmp_path / 'tracks.npz'
    code, _, _ = track(capsys, tmp_path / 'images', '-o', out, '--camera', FX, FY, CX, CY)
    assert code == 0
    np.testing.assert_array_equal(load(out)['K'], [[FX, 0, CX], [0, FY, CY], [0, 0, 1]])


def test_camera_info_yaml(tmp_path, capsys, frames):
    folder = write_folder(tmp_path / 'frames', frames[:3])
    (tmp_path / 'cam.yaml').write_text(
        'image_width: 160\nimage_height: 120\ncamera_name: test\n'
        f'camera_matrix:\n  rows: 3\n  cols: 3\n  data: [{FX}, 0, {CX}, 0, {FY}, {CY}, 0, 0, 1]\n'
        'distortion_model: plumb_bob\n'
        'distortion_coefficients:\n  rows: 1\n  cols: 5\n  data: [0, 0, 0, 0, 0]\n')
    out = tmp_path / 'tracks.npz'
    code, _, _ = track(capsys, folder, '-o', out, '--camera-info', tmp_path / 'cam.yaml')
    assert code == 0
    np.testing.assert_array_equal(load(out)['K'], [[FX, 0, CX], [0, FY, CY], [0, 0, 1]])


@pytest.mark.parametrize('make', ['missing', 'empty folder', 'not a video', 'bag without images',
                                  'bad camera yaml'])
def test_unreadable_input_is_one_line_and_exit_code_2(tmp_path, capfd, frames, make):
    extra = []
    if make == 'missing':
        path = tmp_path / 'nowhere'
    elif make == 'empty folder':
        path = tmp_path / 'empty'
        path.mkdir()
    elif make == 'not a video':
        path = tmp_path / 'clip.avi'
        path.write_bytes(b'this is not a video' * 100)
    elif make == 'bag without images':
        path = tmp_path / 'tracks_bag'
        bag.tracks_bag_from_arrays(np.zeros((4, 3)), np.arange(2), path)
    else:
        path = write_folder(tmp_path / 'frames', frames[:2])
        (tmp_path / 'cam.yaml').write_text('camera_matrix: {rows: 3, cols: 3, data: [1, 2]}\n')
        extra = ['--camera-info', tmp_path / 'cam.yaml']
    code, stdout, err = track(capfd, path, '-o', tmp_path / 'out.npz', *extra)   # OpenCV too
    assert code == 2
    assert len(err) == 1 and err[0].startswith('grass-nrsfm track: error: '), err
    assert not (tmp_path / 'out.npz').exists()


def test_tracker_checks_reach_the_tracker_and_the_meta(tmp_path, capsys, frames):
    folder = write_folder(tmp_path / 'frames', frames[:4])
    out = tmp_path / 'tracks.npz'
    code, _, _ = track(capsys, folder, '-o', out, '--roi', 30, 20, 130, 100, '--method',
                       'dis-medium', '--min-zncc', 0.6, '--reanchor-zncc', 0.75)
    assert code == 0
    npz = load(out)
    meta = json.loads(str(npz['meta']))
    assert meta['method'] == 'dis-medium'
    assert meta['checks'] == {'min_zncc': 0.6, 'reanchor_zncc': 0.75, 'fb_max_px': None}
    W_ref, _ = reference_tracks(frames[:4], step=4, region=(30, 20, 130, 100),
                                method='dis-medium', min_zncc=0.6, reanchor_zncc=0.75)
    np.testing.assert_array_equal(npz['W'], W_ref)
    code, _, err = track(capsys, folder, '-o', out, '--min-zncc', 2)
    assert code == 2 and len(err) == 1 and 'min_zncc' in err[0]


class FakeTerminal:
    def __init__(self):
        self.text = ''

    def isatty(self):
        return True

    def write(self, text):
        self.text += text

    def flush(self):
        pass


def test_progress_is_a_bar_on_a_terminal_and_lines_elsewhere():
    from io import StringIO

    from grass_nrsfm_ros.commands.track import Progress

    terminal = FakeTerminal()
    bar = Progress(4, stream=terminal, width=8)
    for done in range(1, 5):
        bar.update(done, 100)
    bar.close()
    assert terminal.text.startswith('\r[##      ] 1/4 frames, 100 tracks alive')
    assert '[########] 4/4 frames' in terminal.text and terminal.text.endswith('\n')
    assert terminal.text.count('\n') == 1                   # redrawn in place
    lines = StringIO()
    counter = Progress(20, stream=lines)
    for done in range(1, 21):
        counter.update(done, 7)
    assert lines.getvalue().splitlines()[0].startswith('track: 2/20 frames, 7 tracks alive')
    assert len(lines.getvalue().splitlines()) == 10


def test_the_kinect_paper_bench_locates_a_subset_of_known_frames():
    """bench.kinect_paper's search for the truth subset: points between the tracks, 4 of 30
    frames of a turning sheet, 0.5 px noise; it finds the frames and ties the points to their
    nearest tracks."""
    from bench.kinect_paper import locate_subset

    scene = scenes.sheet_scene('waving', n_frames=30, size=(120, 160), focal=155.0,
                               extent_px=110, grid=(24, 18), yaw=30.0, seed=5)
    grid = np.stack(np.meshgrid(np.arange(40, 121, 4.0), np.arange(30, 91, 4.0)), -1)
    truth = scene.truth(grid.reshape(-1, 2))
    keep = truth.visible.all(axis=0)
    uv = truth.uv[:, keep]                                         # (F, P, 2) perfect tracks
    W_px = uv.transpose(0, 2, 1).reshape(-1, uv.shape[1])
    rng = np.random.default_rng(0)
    between = grid.reshape(-1, 2)[keep][::7] + 1.3                 # off the tracks by 1.8 px
    subset = scene.truth(between)
    frames = np.array([3, 11, 17, 26])
    gt = subset.uv[frames] + rng.normal(0, 0.5, (4, len(between), 2))
    match = locate_subset(W_px, gt.transpose(0, 2, 1).reshape(8, -1), tie_px=3.0)
    np.testing.assert_array_equal(match['frames'], frames)
    assert match['tied'].mean() > 0.8 and np.max(match['residual_px']) < 1.5


def test_an_unreadable_frame_is_skipped_with_one_warning(tmp_path, capfd, frames):
    folder = write_folder(tmp_path / 'frames', frames[:5])
    (folder / '002.png').write_bytes(b'\x89PNG broken')
    (folder / '003.png').write_bytes(b'')
    out = tmp_path / 'tracks.npz'
    code, stdout, err = track(capfd, folder, '-o', out, '--quiet')
    assert code == 0
    warnings_ = [line for line in err if 'warning' in line]
    assert len(err) == len(warnings_) == 1 and '002.png skipped' in err[0], err
    npz = load(out)
    np.testing.assert_array_equal(npz['stamps'], np.round(np.array([0, 1, 4]) * 1e9 / 30))
    assert npz['W'].shape[0] == 6 and '2 unreadable frames skipped' in stdout


def test_a_size_change_restarts_the_tracks_with_new_ids(tmp_path, capfd, frames):
    smaller = [cv2.resize(rgb, (128, 96), interpolation=cv2.INTER_AREA) for rgb in frames[3:6]]
    folder = write_folder(tmp_path / 'frames', list(frames[:3]) + smaller)
    out = tmp_path / 'tracks.npz'
    code, _, err = track(capfd, folder, '-o', out, '--quiet')
    assert code == 0
    assert len(err) == 1 and 'frame 3' in err[0] and 'restart' in err[0], err
    W = load(out)['W']
    before, after = np.isfinite(W[:6]).any(axis=0), np.isfinite(W[6:]).any(axis=0)
    assert before.any() and after.any() and not (before & after).any()


def test_the_tracks_bag_and_the_complete_npz_are_what_reconstruct_reads(tmp_path, capsys,
                                                                        frames):
    folder = write_folder(tmp_path / 'frames', frames)
    roi = ['--roi', 30, 20, 130, 100, '--quiet']
    assert track(capsys, folder, '-o', tmp_path / 'tracks_bag', *roi)[0] == 0
    assert cli.main(['reconstruct', str(tmp_path / 'tracks_bag'), '-o',
                     str(tmp_path / 'points_bag'), '--quiet']) == 0
    points = list(bag.read_points(tmp_path / 'points_bag'))
    assert len(points) == N_FRAMES and all(len(p.ids) > 100 for p in points)
    assert track(capsys, folder, '-o', tmp_path / 'complete.npz', '--complete', *roi)[0] == 0
    assert cli.main(['reconstruct', str(tmp_path / 'complete.npz'), '-o',
                     str(tmp_path / 'shapes.npz'), '--quiet']) == 0
    W = load(tmp_path / 'complete.npz')['W']
    assert load(tmp_path / 'shapes.npz')['S'].shape == (3 * N_FRAMES, W.shape[1])
