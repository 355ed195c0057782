"""sensor_msgs/Image and CameraInfo to numpy (grass_nrsfm_ros.image): every encoding, row
padding, byte order, each malformed image, grey conversion, exposure problems, and camera
intrinsics from CameraInfo, a camera_calibration YAML file and four numbers."""
import array
from types import SimpleNamespace

import numpy as np
import pytest

from grass_nrsfm_ros import image
from grass_nrsfm_ros.image import CameraError, ImageError

RNG = np.random.default_rng(7)
H, W = 5, 7


def pixels_for(encoding, height=H, width=W):
    channels, dtype = image.ENCODINGS[encoding]
    shape = (height, width) if channels == 1 else (height, width, channels)
    return RNG.integers(0, np.iinfo(dtype).max + 1, size=shape).astype(dtype)


def message(pixels, encoding, **layout):
    return SimpleNamespace(**image.image_layout(pixels, encoding, **layout))


@pytest.mark.parametrize('encoding', sorted(image.ENCODINGS))
@pytest.mark.parametrize('pad', [0, 3])
def test_each_encoding_round_trips_with_row_padding(encoding, pad):
    pixels = pixels_for(encoding)
    row_bytes = pixels[0].nbytes
    msg = message(pixels, encoding, step=row_bytes + pad)
    assert msg.step == row_bytes + pad and msg.data.size == (row_bytes + pad) * H
    got = image.image_to_numpy(msg)
    assert got.dtype == pixels.dtype and got.dtype.isnative
    np.testing.assert_array_equal(got, pixels)


@pytest.mark.parametrize('bigendian', [False, True])
def test_mono16_byte_order_is_honoured(bigendian):
    pixels = np.array([[0x0102, 0xA0B0, 65535]], dtype=np.uint16)
    msg = message(pixels, 'mono16', bigendian=bigendian)
    first = (0x01, 0x02) if bigendian else (0x02, 0x01)
    assert tuple(msg.data[:2]) == first
    np.testing.assert_array_equal(image.image_to_numpy(msg), pixels)


@pytest.mark.parametrize('kind', ['bytes', 'array', 'list'])
def test_data_as_bytes_array_or_list(kind):
    """rclpy gives array.array('B'), rosbags a uint8 array, hand-made messages bytes or lists."""
    pixels = pixels_for('rgb8')
    msg = message(pixels, 'rgb8')
    msg.data = {'bytes': msg.data.tobytes(), 'array': array.array('B', msg.data.tobytes()),
                'list': msg.data.tolist()}[kind]
    np.testing.assert_array_equal(image.image_to_numpy(msg), pixels)


def test_colour_encodings_give_the_same_grey():
    rgb = pixels_for('rgb8', 16, 16)
    rgba = np.dstack([rgb, np.full((16, 16), 9, np.uint8)])
    greys = [image.image_mono(message(p, e)) for p, e in (
        (rgb, 'rgb8'), (rgb[..., ::-1], 'bgr8'), (rgba, 'rgba8'),
        (rgba[..., [2, 1, 0, 3]], 'bgra8'))]
    for grey in greys[1:]:
        np.testing.assert_array_equal(grey, greys[0])
    r, g, b = (rgb[..., c].astype(float) for c in range(3))
    luma = 0.299 * r + 0.587 * g + 0.114 * b
    assert greys[0].dtype == np.uint8 and np.abs(greys[0] - luma).max() <= 0.51
    mono16 = pixels_for('mono16')
    assert image.image_mono(message(mono16, 'mono16')).dtype == np.uint16


def test_grey_matches_opencv():
    cv2 = pytest.importorskip('cv2')
    rgb = pixels_for('rgb8', 32, 40)
    np.testing.assert_array_equal(image.to_mono(rgb, 'rgb8'),
                                  cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY))


def test_sensor_msgs_image_round_trip():
    pytest.importorskip('sensor_msgs')
    from std_msgs.msg import Header
    pixels = pixels_for('bgra8')
    msg = image.to_image(pixels, 'bgra8', Header(frame_id='cam'), step=W * 4 + 4)
    assert msg.header.frame_id == 'cam' and msg.step == W * 4 + 4
    np.testing.assert_array_equal(image.image_to_numpy(msg), pixels)


def broken(kind):
    msg = message(pixels_for('mono8'), 'mono8')
    if kind == 'encoding':
        msg.encoding = 'yuv422'
    elif kind == 'bayer':
        msg.encoding = 'bayer_rggb8'
    elif kind == 'empty':
        msg.height, msg.data = 0, msg.data[:0]
    elif kind == 'empty_width':
        msg.width = 0
    elif kind == 'truncated':
        msg.data = msg.data[:-1]
    elif kind == 'too_long':
        msg.data = np.r_[msg.data, np.uint8(0)]
    elif kind == 'step':
        msg.step = W - 1
    elif kind == 'size':
        msg.height, msg.width = 10 ** 5, 10 ** 4
    elif kind == 'height':
        msg.height = 'five'
    elif kind == 'data':
        msg.data = [1, 2, 300]
    return msg


@pytest.mark.parametrize('kind, match', [
    ('encoding', r"unsupported encoding 'yuv422'; expected one of \['bgr8', 'bgra8', 'mono16'"),
    ('bayer', 'a Bayer image: debayer it first'),
    ('empty', r'empty image \(7 x 0\)'),
    ('empty_width', r'empty image \(0 x 5\)'),
    ('truncated', 'data has 34 bytes; 7 x 5 mono8 with step 7 needs 35'),
    ('too_long', 'data has 36 bytes; 7 x 5 mono8 with step 7 needs 35'),
    ('step', 'step 6 is shorter than a row of 7 mono8 pixels'),
    ('size', 'larger than 100000000 pixels'),
    ('height', "height 'five' is not an integer"),
    ('data', 'data is not a byte buffer'),
])
def test_malformed_images_raise_a_specific_error(kind, match):
    with pytest.raises(ImageError, match=match) as err:
        image.image_to_numpy(broken(kind))
    assert err.value.kind == {'encoding': 'encoding', 'bayer': 'encoding', 'empty': 'empty',
                              'empty_width': 'empty'}.get(kind, 'malformed')


def test_exposure_problems():
    textured = pixels_for('mono8', 64, 64)
    assert image.exposure_problem(textured) is None
    black = np.full((64, 64), 3, np.uint8)
    black[:4, :4] = 200                        # a lit corner: still black
    assert image.exposure_problem(black) == 'black'
    assert image.exposure_problem(np.full((64, 64), 254, np.uint8)) == 'saturated'
    assert image.exposure_problem(np.full((64, 64), 65535, np.uint16)) == 'saturated'
    assert image.exposure_problem(np.full((64, 64), 128, np.uint8)) is None
    half = np.zeros((64, 64), np.uint8)
    half[:, 32:] = 255                         # black and white halves: neither
    assert image.exposure_problem(half) is None


# ---------------------------------------------------------------------------------- cameras
def camera_info(k, d=(), width=640, height=480, model='plumb_bob'):
    return SimpleNamespace(k=list(k), d=list(d), width=width, height=height,
                           distortion_model=model)


K_VALUES = [500.0, 0, 320.5, 0, 510.0, 240.25, 0, 0, 1]


def test_camera_from_camera_info():
    cam = image.camera_from_info(camera_info(K_VALUES, d=[0.1, -0.2, 0, 0, 0.01]))
    np.testing.assert_array_equal(cam.K, np.reshape(K_VALUES, (3, 3)))
    np.testing.assert_array_equal(cam.dist, [0.1, -0.2, 0, 0, 0.01])
    assert (cam.width, cam.height, cam.distortion_model) == (640, 480, 'plumb_bob')
    assert image.camera_from_info(camera_info(K_VALUES, d=[0] * 5)).dist.size == 0
    assert image.camera_from_info(camera_info([0] * 9)) is None        # uncalibrated


def test_camera_from_sensor_msgs_camera_info():
    pytest.importorskip('sensor_msgs')
    from sensor_msgs.msg import CameraInfo
    msg = CameraInfo(k=K_VALUES, d=[0.0] * 5, width=64, height=48, distortion_model='plumb_bob')
    cam = image.camera_from_info(msg)
    assert cam.K[0, 2] == 320.5 and cam.dist.size == 0 and cam.width == 64
    assert image.camera_from_info(CameraInfo()) is None


@pytest.mark.parametrize('k, match', [
    ([500.0, 0, 320, 0, -1, 240, 0, 0, 1], 'fx and fy must be > 0'),
    ([500.0, 0, 320, 0, 500, 240, 1, 0, 1], 'not upper triangular'),
    ([np.nan, 0, 320, 0, 500, 240, 0, 0, 1], 'non-finite'),
    ([500.0, 0, 320], 'K is not 9 numbers'),
])
def test_bad_camera_info_raises(k, match):
    with pytest.raises(CameraError, match=match):
        image.camera_from_info(camera_info(k))


CALIBRATION_YAML = """\
image_width: 640
image_height: 480
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [528.4, 0., 320.9, 0., 529.1, 238.7, 0., 0., 1.]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [0.0321, -0.0712, 0.0011, -0.0004, 0.]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1., 0., 0., 0., 1., 0., 0., 0., 1.]
projection_matrix:
  rows: 3
  cols: 4
  data: [530.2, 0., 320.5, 0., 0., 531.1, 238.2, 0., 0., 0., 1., 0.]
"""


def test_camera_from_calibration_yaml(tmp_path):
    path = tmp_path / 'camera.yaml'
    path.write_text(CALIBRATION_YAML)
    cam = image.camera_from_yaml(path)
    np.testing.assert_allclose(cam.K, [[528.4, 0, 320.9], [0, 529.1, 238.7], [0, 0, 1]])
    np.testing.assert_allclose(cam.dist, [0.0321, -0.0712, 0.0011, -0.0004, 0])
    assert (cam.width, cam.height, cam.distortion_model) == (640, 480, 'plumb_bob')
    path.write_text(CALIBRATION_YAML.replace('[0.0321, -0.0712, 0.0011, -0.0004, 0.]',
                                             '[0., 0., 0., 0., 0.]'))
    assert image.camera_from_yaml(path).dist.size == 0


@pytest.mark.parametrize('text, match', [
    ('image_width: 640\n', 'camera_matrix is missing'),
    (CALIBRATION_YAML.replace('data: [528.4, 0., 320.9, 0., 529.1, 238.7, 0., 0., 1.]',
                              'data: [528.4, 0., 320.9]'),
     'camera_matrix is 3 x 3 with 3 values'),
    (CALIBRATION_YAML.replace('cols: 5\n', 'cols: 4\n'),
     'distortion_coefficients is 1 x 4 with 5 values'),
    ('camera_matrix: {rows: 3, cols: [1,\n', 'not valid YAML'),
    ('- 1\n', 'expected a camera_info mapping'),
])
def test_bad_calibration_yaml_raises_with_the_path(tmp_path, text, match):
    path = tmp_path / 'bad.yaml'
    path.write_text(text)
    with pytest.raises(CameraError, match=match) as err:
        image.camera_from_yaml(path)
    assert str(path) in str(err.value)


def test_missing_calibration_file(tmp_path):
    with pytest.raises(CameraError, match='cannot read'):
        image.camera_from_yaml(tmp_path / 'none.yaml')


def test_camera_from_intrinsics():
    cam = image.camera_from_intrinsics(500, 510, 320, 240)
    np.testing.assert_array_equal(cam.K, [[500, 0, 320], [0, 510, 240], [0, 0, 1]])
    assert cam.dist.size == 0
    with pytest.raises(CameraError, match='fx and fy must be > 0'):
        image.camera_from_intrinsics(0, 510, 320, 240)
