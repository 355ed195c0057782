"""Frame sources for the offline front end: a folder of images, a video file or a bag.

:func:`open_source` looks at a path and returns a :class:`FrameSource`, an iterable of
:class:`Frame` ``(index, stamp_ns, image)``:

* a **folder of images** (png, jpg, jpeg, bmp, tif, tiff, pgm, ppm, webp), read in name order
  with digit runs compared as numbers (``2.png`` before ``10.png``; zero-padded names sort the
  same either way); stamps ``index * 1e9 / fps`` ns (``fps`` 30 by default);
* a **video file** (anything OpenCV's VideoCapture opens); stamps from the container's frame
  times (``CAP_PROP_POS_MSEC``) where they increase, else ``index * 1e9 / fps`` of the
  stream's frame rate;
* a **bag** (a rosbag2 directory with metadata.yaml or .mcap files, a bare ``.mcap``, a ROS 1
  ``.bag``) with ``sensor_msgs/Image`` or ``sensor_msgs/CompressedImage`` on one topic;
  stamps from the image headers; intrinsics from the first ``sensor_msgs/CameraInfo`` on
  the matching ``camera_info`` topic whose ``k`` is not all zero.

``Frame.image``: ``(H, W)`` grey (uint8, or uint16 for 16-bit files and mono16) or
``(H, W, 3)`` / ``(H, W, 4)`` uint8 in **RGB(A)** order, as :class:`.DenseTracker` takes it
by default. ``FrameSource.camera``: a :class:`grass_nrsfm_ros.image.Camera` or None;
``stamps_from`` says where the stamps come from. An unreadable input raises
:class:`SourceError` (a ValueError, one line); one unreadable frame in a readable input is
skipped with a warning once (:attr:`FrameSource.skipped` counts them).
"""
from dataclasses import dataclass
from pathlib import Path
import re
import warnings

import cv2
import numpy as np

from grass_nrsfm_ros import image as image_io
from grass_nrsfm_ros.bag import BagError, BagReader

IMAGE_SUFFIXES = ('.png', '.jpg', '.jpeg', '.bmp', '.tif', '.tiff', '.pgm', '.ppm', '.webp')
BAG_SUFFIXES = ('.mcap', '.bag', '.db3')
IMAGE_TYPES = ('sensor_msgs/msg/Image', 'sensor_msgs/msg/CompressedImage')
CAMERA_INFO = 'sensor_msgs/msg/CameraInfo'
DEFAULT_FPS = 30.0


class SourceError(ValueError):
    """An input that cannot be read as frames; the message says which and why."""


@dataclass(frozen=True, eq=False)
class Frame:
    """One input frame: ``index`` (position in the input, 0-based, skipped frames counted),
    ``stamp_ns`` int, ``image`` ``(H, W)`` or ``(H, W, 3|4)`` RGB(A), ``frame_id`` (a bag's
    header frame_id, else '')."""

    index: int
    stamp_ns: int
    image: np.ndarray
    frame_id: str = ''


class FrameSource:
    """Base of the sources: iterate for :class:`Frame` objects; ``count`` the frames the input
    announces (None where unknown), ``camera`` intrinsics or None, ``kind`` 'folder', 'video'
    or 'bag', ``stamps_from`` a phrase, ``skipped`` unreadable frames left out."""

    kind = ''
    stamps_from = ''

    def __init__(self, path):
        self.path = Path(path)
        self.count = None
        self.camera = None
        self.skipped = 0
        self._warned = False

    def __iter__(self):
        raise NotImplementedError

    def _skip(self, what, why):
        self.skipped += 1
        if not self._warned:
            self._warned = True
            warnings.warn(f'{self.path}: {what} skipped ({why}); further unreadable frames '
                          'are skipped silently and counted', RuntimeWarning, stacklevel=3)


def open_source(path, *, fps=None, image_topic=None, info_topic=None):
    """The :class:`FrameSource` of ``path``: a bag, a folder of images or a video file.
    ``fps`` sets the frame rate of a folder's stamps (default 30) or replaces a video's;
    ``image_topic`` / ``info_topic`` choose a bag's topics. Raises FileNotFoundError or
    :class:`SourceError`."""
    path = Path(path)
    if fps is not None and not (np.isfinite(fps) and fps > 0):
        raise SourceError(f'the frame rate must be positive; got {fps}')
    if not path.exists():
        raise FileNotFoundError(f'{path} does not exist')
    if is_bag(path):
        return BagSource(path, image_topic=image_topic, info_topic=info_topic)
    if image_topic is not None or info_topic is not None:
        raise SourceError(f'{path} is not a bag: image and camera_info topics apply to bags')
    if path.is_dir():
        return FolderSource(path, fps=fps)
    return VideoSource(path, fps=fps)


def is_bag(path):
    """Whether ``path`` looks like a bag: a directory with metadata.yaml or .mcap / .db3
    files, or a file ending in .mcap, .bag or .db3."""
    path = Path(path)
    if path.is_dir():
        return (path / 'metadata.yaml').exists() or any(
            p.suffix in ('.mcap', '.db3') for p in path.iterdir())
    return path.suffix.lower() in BAG_SUFFIXES


def natural_key(name):
    """Sort key of a file name with its digit runs compared as numbers."""
    return [(0, int(part), '') if part.isdigit() else (1, 0, part.lower())
            for part in re.split(r'(\d+)', name) if part]


def _to_rgb(pixels):
    """An OpenCV image (BGR(A) or grey) in the order Frame.image uses (RGB(A) or grey)."""
    if pixels.ndim == 3 and pixels.shape[2] == 3:
        return cv2.cvtColor(pixels, cv2.COLOR_BGR2RGB)
    if pixels.ndim == 3 and pixels.shape[2] == 4:
        return cv2.cvtColor(pixels, cv2.COLOR_BGRA2RGBA)
    if pixels.ndim == 3 and pixels.shape[2] == 1:
        return pixels[:, :, 0]
    return pixels


def _usable(pixels):
    """``pixels`` as uint8 / uint16, or None for what the tracker cannot take."""
    if pixels is None or pixels.size == 0 or pixels.ndim not in (2, 3):
        return None
    if pixels.dtype == np.uint8 or pixels.dtype == np.uint16:
        return pixels
    return None


class FolderSource(FrameSource):
    """The images of a folder in natural name order; stamps ``index / fps``."""

    kind = 'folder'

    def __init__(self, path, fps=None):
        super().__init__(path)
        self.fps = DEFAULT_FPS if fps is None else float(fps)
        self.stamps_from = f'frame index / {self.fps:g} Hz (a folder has no times)'
        self.files = sorted((p for p in self.path.iterdir()
                             if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES),
                            key=lambda p: natural_key(p.name))
        if not self.files:
            raise SourceError(f'{self.path}: a folder with no images '
                              f'({", ".join(s[1:] for s in IMAGE_SUFFIXES)}) and not a bag')
        self.count = len(self.files)

    def __iter__(self):
        for index, file in enumerate(self.files):
            pixels = _usable(cv2.imread(str(file), cv2.IMREAD_ANYDEPTH | cv2.IMREAD_ANYCOLOR))
            if pixels is None:
                self._skip(file.name, 'not a readable 8- or 16-bit image')
                continue
            yield Frame(index, int(round(index * 1e9 / self.fps)), _to_rgb(pixels))


class VideoSource(FrameSource):
    """The frames of a video file (OpenCV); stamps from the container's frame times."""

    kind = 'video'

    def __init__(self, path, fps=None):
        super().__init__(path)
        capture = cv2.VideoCapture(str(self.path))
        try:
            if not capture.isOpened():
                raise SourceError(f'{self.path}: not a folder of images, a bag or a video '
                                  'file that OpenCV can open')
            self.stream_fps = float(capture.get(cv2.CAP_PROP_FPS) or 0.0)
            count = int(capture.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
            self.count = count if count > 0 else None
        finally:
            capture.release()
        self.fps = fps if fps is not None else (
            self.stream_fps if np.isfinite(self.stream_fps) and self.stream_fps > 0
            else DEFAULT_FPS)
        self.stamps_from = ('the video frame times' if fps is None
                            else f'frame index / {self.fps:g} Hz (--fps)')

    def __iter__(self):
        capture = cv2.VideoCapture(str(self.path))
        last, index, read_any = -1, 0, False
        try:
            while True:
                ok, pixels = capture.read()
                if not ok:
                    break
                stamp = self._stamp(capture, index, last)
                last = stamp
                read_any = True
                pixels = _usable(pixels)
                if pixels is None:
                    self._skip(f'frame {index}', 'not an 8- or 16-bit image')
                else:
                    yield Frame(index, stamp, _to_rgb(pixels))
                index += 1
        finally:
            capture.release()
        if not read_any:
            raise SourceError(f'{self.path}: OpenCV opens it but reads no frame from it')

    def _stamp(self, capture, index, last):
        """The frame time in ns: the container's where it increases, else index / fps."""
        by_index = int(round(index * 1e9 / self.fps))
        if self.stamps_from != 'the video frame times':
            return by_index
        msec = capture.get(cv2.CAP_PROP_POS_MSEC)
        stamp = int(round(msec * 1e6)) if np.isfinite(msec) else -1
        if stamp <= last or (index == 0 and stamp != 0):
            self.stamps_from = (f'frame index / {self.fps:g} Hz (the video has no usable '
                                'frame times)')
            return by_index
        return stamp


class BagSource(FrameSource):
    """The images of one topic of a bag, with the camera of its camera_info topic."""

    kind = 'bag'
    stamps_from = 'the image header stamps'

    def __init__(self, path, image_topic=None, info_topic=None):
        super().__init__(path)
        try:
            with BagReader(self.path) as bag:
                connections = bag.reader.connections
                self.image_topic, self.msgtype = _image_topic(self.path, connections,
                                                              image_topic)
                self.count = sum(c.msgcount for c in connections
                                 if c.topic == self.image_topic) or None
                self.info_topic = _info_topic(self.path, connections, self.image_topic,
                                              info_topic)
                if self.info_topic is not None:
                    self.camera = self._first_camera(bag)
        except BagError as exc:
            raise SourceError(str(exc)) from None

    def _first_camera(self, bag):
        conns = bag.connections(self.info_topic, CAMERA_INFO)
        for conn, _, raw in bag.messages(conns):
            try:
                camera = image_io.camera_from_info(bag.decode(raw, conn))
            except (image_io.CameraError, BagError) as exc:
                self._skip('a camera_info message', str(exc))
                continue
            if camera is not None:
                return camera
        return None

    def __iter__(self):
        try:
            with BagReader(self.path) as bag:
                conns = bag.connections(self.image_topic, self.msgtype)
                for index, (conn, _, raw) in enumerate(bag.messages(conns)):
                    frame = self._frame(bag, conn, raw, index)
                    if frame is not None:
                        yield frame
        except BagError as exc:
            raise SourceError(str(exc)) from None

    def _frame(self, bag, conn, raw, index):
        try:
            msg = bag.decode(raw, conn)
            pixels = _message_pixels(msg, self.msgtype)
        except (BagError, image_io.ImageError) as exc:
            self._skip(f'image {index} on {self.image_topic}', str(exc))
            return None
        stamp = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
        return Frame(index, stamp, pixels, str(msg.header.frame_id))


def _message_pixels(msg, msgtype):
    """``(H, W)`` or ``(H, W, 3|4)`` RGB(A) pixels of an Image or CompressedImage message."""
    if msgtype.endswith('CompressedImage'):
        data = np.frombuffer(bytes(msg.data), np.uint8)
        pixels = _usable(cv2.imdecode(data, cv2.IMREAD_ANYDEPTH | cv2.IMREAD_ANYCOLOR)) \
            if data.size else None
        if pixels is None:
            raise image_io.ImageError(f'compressed image ({msg.format!r}) does not decode')
        return _to_rgb(pixels)
    pixels = image_io.image_to_numpy(msg)
    encoding = str(msg.encoding)
    if encoding.startswith('bgr'):
        pixels = _to_rgb(pixels)
    return pixels


def _image_topic(path, connections, wanted):
    """``(topic, msgtype)`` of the bag's images: ``wanted`` or the only image topic."""
    images = sorted({(c.topic, c.msgtype) for c in connections if c.msgtype in IMAGE_TYPES})
    if wanted is not None:
        chosen = [t for t in images if t[0] == wanted]
        if not chosen:
            raise SourceError(f'{path}: no image topic {wanted!r} (image topics: '
                              f'{", ".join(t for t, _ in images) or "none"})')
        return chosen[0]
    if not images:
        have = sorted({f'{c.topic} ({c.msgtype})' for c in connections})
        raise SourceError(f'{path}: a bag with no sensor_msgs/Image topic (topics: '
                          f'{", ".join(have) or "none"})')
    if len(images) > 1:
        raise SourceError(f'{path}: several image topics ({", ".join(t for t, _ in images)}); '
                          'choose one with --image-topic')
    return images[0]


def bag_camera(path, topic, wanted=None):
    """``(Camera or None, camera_info topic or None)`` of a bag: the first calibrated message
    of the CameraInfo topic that goes with ``topic`` (see :func:`_info_topic`); unreadable
    messages are passed over."""
    with BagReader(path) as bag:
        info = _info_topic(path, bag.reader.connections, topic, wanted)
        if info is None:
            return None, None
        for conn, _, raw in bag.messages(bag.connections(info, CAMERA_INFO)):
            try:
                camera = image_io.camera_from_info(bag.decode(raw, conn))
            except (image_io.CameraError, BagError):
                continue
            if camera is not None:
                return camera, info
    return None, info


def _info_topic(path, connections, image_topic, wanted):
    """The camera_info topic that goes with ``image_topic``: ``wanted``, the sibling
    ``camera_info`` of the image topic, or the bag's only CameraInfo topic; None if none."""
    infos = sorted({c.topic for c in connections if c.msgtype == CAMERA_INFO})
    if wanted is not None:
        if wanted not in infos:
            raise SourceError(f'{path}: no CameraInfo topic {wanted!r} (CameraInfo topics: '
                              f'{", ".join(infos) or "none"})')
        return wanted
    parent = image_topic.rsplit('/', 1)[0]
    sibling = f'{parent}/camera_info'
    if sibling in infos:
        return sibling
    return infos[0] if len(infos) == 1 else None
