"""sensor_msgs/Image and CameraInfo <-> numpy, and camera_info YAML files, with no ROS import.

Images: :func:`image_to_numpy` reads anything shaped like a ``sensor_msgs/Image`` (rclpy
messages, rosbags dataclasses, ``types.SimpleNamespace``) into ``(H, W)`` (mono8 uint8, mono16
uint16 in native byte order) or ``(H, W, C)`` uint8 in the encoding's channel order (rgb8,
bgr8: C = 3; rgba8, bgra8: C = 4), honouring ``step`` (row padding) and ``is_bigendian``;
:func:`to_mono` makes ``(H, W)`` grey of it (OpenCV), :func:`exposure_problem` tells a black or
saturated frame. A malformed image raises :class:`ImageError` saying what is wrong.
:func:`image_layout` / :func:`to_image` go the other way (tests, benches).

Cameras: :func:`camera_from_info` (a ``sensor_msgs/CameraInfo``: ``k`` row-major 3 x 3, ``d``),
:func:`camera_from_yaml` (the file ROS camera_calibration writes: ``camera_matrix: {rows, cols,
data}``, ``distortion_coefficients``, ``image_width``, ``image_height``, ``distortion_model``)
and :func:`camera_from_intrinsics` (fx, fy, cx, cy) give a :class:`Camera`: ``K (3, 3)``,
``dist (n,)`` (empty: no distortion). A CameraInfo whose ``k`` is all zero is an uncalibrated
camera (REP 104): no Camera. Only :func:`to_image` imports ``sensor_msgs``.
"""
from dataclasses import dataclass

import numpy as np

#: encoding -> (channels, dtype of one channel)
ENCODINGS = {'mono8': (1, np.dtype('u1')), 'mono16': (1, np.dtype('u2')),
             'rgb8': (3, np.dtype('u1')), 'bgr8': (3, np.dtype('u1')),
             'rgba8': (4, np.dtype('u1')), 'bgra8': (4, np.dtype('u1'))}
#: OpenCV's colour conversion code (its name) to grey for each colour encoding
TO_GREY = {'rgb8': 'COLOR_RGB2GRAY', 'bgr8': 'COLOR_BGR2GRAY', 'rgba8': 'COLOR_RGBA2GRAY',
           'bgra8': 'COLOR_BGRA2GRAY'}
MAX_PIXELS = 100_000_000          # an image larger than this is refused, not allocated
#: an exposure problem: this share of a frame's sampled pixels at the range's ends
FLAT_SHARE = 0.98
FLAT_MARGIN = 0.02                 # "at the end": within this fraction of the full range


class ImageError(ValueError):
    """An image message that cannot be read; the message says why, ``kind`` what sort of
    problem it is ('malformed': layout and data disagree)."""

    kind = 'malformed'


class EncodingError(ImageError):
    """An encoding this module does not read."""

    kind = 'encoding'


class EmptyImageError(ImageError):
    """An image with no pixels."""

    kind = 'empty'


class CameraError(ValueError):
    """Camera intrinsics that cannot be used; the message says why."""


def _uint(msg, name):
    value = getattr(msg, name)
    try:
        value = int(value)
    except (TypeError, ValueError, OverflowError):
        raise ImageError(f'{name} {value!r} is not an integer') from None
    if not 0 <= value < 2 ** 32:
        raise ImageError(f'{name} {value} outside the uint32 range')
    return value


def _raw_bytes(data):
    """``data`` (bytes-like, array.array('B'), uint8 array, or ints 0..255) as a flat uint8
    array, without a copy where the buffer allows."""
    try:
        if isinstance(data, np.ndarray):
            return data.reshape(-1).view(np.uint8) if data.dtype == np.uint8 \
                else np.asarray(data, dtype=np.uint8).reshape(-1)
        return np.frombuffer(data, dtype=np.uint8)
    except (TypeError, ValueError, BufferError):
        try:
            return np.asarray(list(data), dtype=np.uint8)
        except (TypeError, ValueError, OverflowError) as exc:
            raise ImageError(f'data is not a byte buffer ({type(data).__name__}: '
                             f'{exc})') from None


def image_to_numpy(msg):
    """The pixels of ``msg`` (a sensor_msgs/Image): ``(H, W)`` for mono8 / mono16, ``(H, W, C)``
    uint8 in the encoding's channel order for rgb8, bgr8, rgba8, bgra8. A view of the message's
    buffer where no padding or byte swap forbids it (read-only then: copy before writing).

    Raises ImageError for an unknown encoding, an empty image, a ``step`` shorter than a row, or
    ``data`` whose size is not ``step * height``."""
    encoding = str(msg.encoding)
    if encoding not in ENCODINGS:
        hint = ' (a Bayer image: debayer it first, e.g. image_proc)' \
            if encoding.startswith('bayer') else ''
        raise EncodingError(f'unsupported encoding {encoding!r}{hint}; expected one of '
                            f'{sorted(ENCODINGS)}')
    height, width, step = _uint(msg, 'height'), _uint(msg, 'width'), _uint(msg, 'step')
    if height == 0 or width == 0:
        raise EmptyImageError(f'empty image ({width} x {height})')
    if height * width > MAX_PIXELS:
        raise ImageError(f'image {width} x {height} is larger than {MAX_PIXELS} pixels')
    channels, dtype = ENCODINGS[encoding]
    row_bytes = width * channels * dtype.itemsize
    if step < row_bytes:
        raise ImageError(f'step {step} is shorter than a row of {width} {encoding} pixels '
                         f'({row_bytes} bytes)')
    raw = _raw_bytes(msg.data)
    if raw.size != step * height:
        raise ImageError(f'data has {raw.size} bytes; {width} x {height} {encoding} with step '
                         f'{step} needs {step * height}')
    dtype = dtype.newbyteorder('>' if bool(msg.is_bigendian) else '<')
    rows = raw.reshape(height, step)[:, :row_bytes]
    if dtype.itemsize > 1 or step != row_bytes:
        rows = np.ascontiguousarray(rows)
    pixels = rows.view(dtype).reshape((height, width) if channels == 1
                                      else (height, width, channels))
    return pixels if dtype.isnative else pixels.astype(dtype.newbyteorder('='))


def to_mono(pixels, encoding):
    """``(H, W)`` grey of ``pixels`` (as :func:`image_to_numpy` returns them for ``encoding``):
    mono images as they are, colour ones by OpenCV's BT.601 luma (uint8; alpha ignored)."""
    if pixels.ndim == 2:
        return pixels
    import cv2            # the front end's dependency; 0.15 ms at 640 x 480 (numpy: 7 ms)

    return cv2.cvtColor(pixels, getattr(cv2, TO_GREY[encoding]))


def image_mono(msg):
    """``(H, W)`` grey pixels (uint8, or uint16 for mono16) of a sensor_msgs/Image."""
    return to_mono(image_to_numpy(msg), str(msg.encoding))


def exposure_problem(mono, sample_step=4):
    """'black', 'saturated' or None: whether ``FLAT_SHARE`` of a grey frame's pixels (every
    ``sample_step``-th in each direction) lie within ``FLAT_MARGIN`` of the bottom or top of its
    dtype's range (a frame with no texture left to track)."""
    sample = mono[::sample_step, ::sample_step]
    top = np.iinfo(mono.dtype).max if mono.dtype.kind in 'ui' else 1.0
    margin = FLAT_MARGIN * top
    if np.count_nonzero(sample <= margin) >= FLAT_SHARE * sample.size:
        return 'black'
    if np.count_nonzero(sample >= top - margin) >= FLAT_SHARE * sample.size:
        return 'saturated'
    return None


def image_layout(pixels, encoding, step=None, bigendian=False):
    """sensor_msgs/Image keyword arguments (all but ``header``) holding ``pixels`` in
    ``encoding``; ``step`` (default: no padding) pads each row; ``bigendian`` for mono16."""
    channels, dtype = ENCODINGS[encoding]
    height, width = pixels.shape[:2]
    if pixels.shape[2:] != (() if channels == 1 else (channels,)):
        raise ImageError(f'pixels of shape {pixels.shape} are not {encoding}')
    row_bytes = width * channels * dtype.itemsize
    step = row_bytes if step is None else int(step)
    order = '>' if bigendian else '<'
    rows = np.ascontiguousarray(pixels, dtype=dtype.newbyteorder(order)).reshape(height, -1)
    data = np.zeros((height, step), np.uint8)
    data[:, :row_bytes] = rows.view(np.uint8)
    return dict(height=height, width=width, encoding=encoding, is_bigendian=int(bigendian),
                step=step, data=data.reshape(-1))


def to_image(pixels, encoding, header, **layout):
    """A sensor_msgs/Image of ``pixels`` (see :func:`image_layout`)."""
    # imported here: sensor_msgs comes with ROS 2 (the optional extra); reading needs none
    from sensor_msgs.msg import Image

    fields = image_layout(pixels, encoding, **layout)
    fields['data'] = fields['data'].tobytes()
    return Image(header=header, **fields)


# ------------------------------------------------------------------------------------ cameras
@dataclass(frozen=True)
class Camera:
    """Pinhole intrinsics: ``K (3, 3)`` float64, ``dist (n,)`` distortion coefficients of
    ``distortion_model`` (empty: none), image size in pixels (0: unknown)."""

    K: np.ndarray
    dist: np.ndarray
    width: int = 0
    height: int = 0
    distortion_model: str = ''


def _checked_K(values, where):
    try:
        K = np.asarray(values, dtype=np.float64).reshape(3, 3)
    except (TypeError, ValueError) as exc:
        raise CameraError(f'{where}: K is not 9 numbers ({exc})') from None
    if not np.isfinite(K).all():
        raise CameraError(f'{where}: K has non-finite entries')
    if K[0, 0] <= 0 or K[1, 1] <= 0 or K[2, 2] == 0:
        raise CameraError(f'{where}: K has fx {K[0, 0]:g}, fy {K[1, 1]:g}, K[2, 2] '
                          f'{K[2, 2]:g}; fx and fy must be > 0')
    if np.any(K[2, :2] != 0) or K[1, 0] != 0:
        raise CameraError(f'{where}: K {K.tolist()} is not upper triangular with last row '
                          '(0, 0, 1)')
    return K / K[2, 2]


def _checked_dist(values, where):
    try:
        dist = np.asarray(values if values is not None else [], dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise CameraError(f'{where}: distortion coefficients are not numbers ({exc})') from None
    if not np.isfinite(dist).all():
        raise CameraError(f'{where}: distortion coefficients are not finite')
    return dist if np.any(dist) else np.zeros(0)


def camera_from_info(msg):
    """The :class:`Camera` of a sensor_msgs/CameraInfo, or None where ``k`` is all zero (an
    uncalibrated camera). Raises CameraError for a ``k`` that is not a pinhole matrix."""
    k = np.asarray(msg.k, dtype=np.float64)
    if k.size == 9 and not np.any(k):
        return None
    return Camera(K=_checked_K(k, 'camera_info'), dist=_checked_dist(msg.d, 'camera_info'),
                  width=int(msg.width), height=int(msg.height),
                  distortion_model=str(msg.distortion_model))


def _matrix(data, key, shape, where):
    block = data.get(key)
    if not isinstance(block, dict) or 'data' not in block:
        raise CameraError(f'{where}: {key} is missing or has no data')
    values = block['data']
    if not isinstance(values, list):
        raise CameraError(f'{where}: {key} data is not a list of numbers')
    rows, cols = block.get('rows', shape[0]), block.get('cols', shape[1] or len(values))
    if shape[0] not in (None, rows) or shape[1] not in (None, cols) \
            or len(values) != rows * cols:
        raise CameraError(f'{where}: {key} is {rows} x {cols} with {len(values)} values; '
                          f"expected {shape[0]} x {shape[1] or 'n'}")
    return values


def camera_from_yaml(path):
    """The :class:`Camera` of a camera_info YAML file as ROS camera_calibration writes it.
    Raises CameraError (with the path) for an unreadable file or a missing or malformed
    ``camera_matrix``; ``distortion_coefficients`` may be absent (none)."""
    import yaml

    where = str(path)
    try:
        with open(path, encoding='utf-8') as f:
            data = yaml.safe_load(f)
    except OSError as exc:
        raise CameraError(f'{where}: cannot read ({exc.strerror or exc})') from None
    except yaml.YAMLError as exc:
        raise CameraError(f'{where}: not valid YAML ({" ".join(str(exc).split())})') from None
    if not isinstance(data, dict):
        raise CameraError(f'{where}: expected a camera_info mapping, got '
                          f'{type(data).__name__}')
    K = _checked_K(_matrix(data, 'camera_matrix', (3, 3), where), where)
    dist = np.zeros(0)
    if data.get('distortion_coefficients') is not None:
        dist = _checked_dist(_matrix(data, 'distortion_coefficients', (1, None), where), where)
    return Camera(K=K, dist=dist, width=int(data.get('image_width') or 0),
                  height=int(data.get('image_height') or 0),
                  distortion_model=str(data.get('distortion_model') or ''))


def camera_from_intrinsics(fx, fy, cx, cy):
    """The :class:`Camera` of focal lengths and principal point in pixels (no distortion)."""
    return Camera(K=_checked_K([[fx, 0, cx], [0, fy, cy], [0, 0, 1]], 'intrinsics'),
                  dist=np.zeros(0))
