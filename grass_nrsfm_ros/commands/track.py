"""``grass-nrsfm track INPUT -o OUT``: dense 2D tracks of a folder of images, a video or a bag.

INPUT (:mod:`grass_nrsfm_ros.frontend.sources`): a folder of images (name order), a video file
(OpenCV) or a bag with ``sensor_msgs/Image`` (and ``CameraInfo``). The frames go through
:class:`~grass_nrsfm_ros.frontend.DenseTracker` (grid of ``--step`` pixels in ``--mask`` or
``--roi``, or the whole image).

OUT ``*.npz``: ``W: (2F, P)`` float64 pixels (rows 2f / 2f+1 = u / v of frame f, NaN where the
track is not tracked in frame f), ``ids: (P,)`` uint32 track ids, ``stamps: (F,)`` int64 ns,
``visible: (F, P)`` bool (W finite), ``K: (3, 3)`` where a camera is known (``--camera``,
``--camera-info`` or the bag's camera_info), ``meta`` a JSON string (input, settings, where
the stamps and K come from). Any other OUT is a bag directory (rosbag2, MCAP) holding
``/tracks`` (one PointCloud2 per frame: track_id, u, v, as the reconstruction node reads it)
and ``/camera_info`` (sensor_msgs/CameraInfo, ``k`` row-major) where a camera is known.

Progress goes to stderr: a bar on a terminal, a counter line every tenth of the input
elsewhere. An unreadable input is one line on stderr and exit code 2 (see :mod:`..cli`).
"""
import json
from pathlib import Path
import sys
import time
import warnings

import cv2
import numpy as np

from grass_nrsfm_ros import bag, image
from grass_nrsfm_ros.cli import UserError
from grass_nrsfm_ros.frontend import DenseTracker, FrameSizeError, METHODS
from grass_nrsfm_ros.frontend.flow import DEFAULT_METHOD
from grass_nrsfm_ros.frontend.sources import open_source, SourceError

CAMERA_INFO_TOPIC = '/camera_info'
CAMERA_INFO_TYPE = 'sensor_msgs/msg/CameraInfo'


def add_arguments(parser):
    parser.add_argument('input', help='a folder of images (name order), a video file, or a bag '
                        'with sensor_msgs/Image (and CameraInfo)')
    parser.add_argument('-o', '--output', required=True,
                        help='OUT.npz (W, ids, stamps, visible, K) or a bag directory to create '
                        '(tracks and camera_info topics)')
    region = parser.add_mutually_exclusive_group()
    region.add_argument('--mask', metavar='PNG',
                        help='the region in the first frame: nonzero pixels of a PNG')
    region.add_argument('--roi', type=float, nargs=4, metavar=('X0', 'Y0', 'X1', 'Y1'),
                        help='the region as a rectangle of pixels, bounds included')
    parser.add_argument('--step', type=int, default=4, help='grid step in pixels (4)')
    camera = parser.add_mutually_exclusive_group()
    camera.add_argument('--camera', type=float, nargs=4, metavar=('FX', 'FY', 'CX', 'CY'),
                        help='pinhole intrinsics in pixels')
    camera.add_argument('--camera-info', metavar='YAML',
                        help='a camera_info YAML file as ROS camera_calibration writes it')
    parser.add_argument('--method', choices=METHODS, default=DEFAULT_METHOD,
                        help=f'optical flow method ({DEFAULT_METHOD})')
    parser.add_argument('--min-zncc', type=float, default=None,
                        help='photometric check: a track whose patch correlates less with its '
                        "reference dies (the tracker's default)")
    parser.add_argument('--reanchor-zncc', type=float, default=None,
                        help='a new reference frame when the median correlation falls below '
                        "this (the tracker's default)")
    parser.add_argument('--fb-max-px', type=float, default=None,
                        help='forward-backward check: a track whose round trip misses by more '
                        'pixels dies (default: no such check, only the photometric one)')
    parser.add_argument('--max-frames', type=int, default=None, help='stop after N frames')
    parser.add_argument('--complete', action='store_true',
                        help='keep only the tracks tracked in every frame (what the solver '
                        'takes today)')
    parser.add_argument('--fps', type=float, default=None,
                        help="frame rate of a folder's stamps (30) or replacing a video's times")
    parser.add_argument('--image-topic', help="a bag's image topic (default: its only one)")
    parser.add_argument('--camera-info-topic',
                        help="a bag's CameraInfo topic (default: the image topic's sibling "
                        'camera_info, or the only one)')
    parser.add_argument('--frame-id', default=None,
                        help="header.frame_id of a bag written (the input bag's, else "
                        'camera_optical)')
    parser.add_argument('--quiet', action='store_true', help='no progress display')


def run(args):
    check_arguments(args)
    try:
        source = open_source(args.input, fps=args.fps, image_topic=args.image_topic,
                             info_topic=args.camera_info_topic)
    except SourceError as exc:
        raise UserError(str(exc)) from None
    camera, camera_from = chosen_camera(args, source)
    mask = read_mask(args.mask) if args.mask else None
    region = mask if mask is not None else (tuple(args.roi) if args.roi else None)
    checks = {name: getattr(args, name) for name in ('min_zncc', 'reanchor_zncc')
              if getattr(args, name) is not None}
    tracker = DenseTracker(args.step, region, args.method, K=None if camera is None
                           else camera.K, fb_max_px=args.fb_max_px, **checks)
    out = Path(args.output)
    sink = NpzSink(out) if out.suffix == '.npz' else BagSink(out, camera, args.frame_id)
    total = source.count if args.max_frames is None else min(
        source.count or args.max_frames, args.max_frames)
    progress = Progress(total, enabled=not args.quiet)
    started = time.perf_counter()
    with warnings.catch_warnings():
        warnings.showwarning = _one_line_warning
        try:
            n = track_frames(source, tracker, sink, progress, args.max_frames, mask)
        except SourceError as exc:
            sink.abort()
            raise UserError(str(exc)) from None
        finally:
            progress.close()
    seconds = time.perf_counter() - started
    if n == 0:
        sink.abort()
        raise UserError(f'{args.input}: no readable frame')
    meta = dict(input=str(args.input), kind=source.kind, frames=n, step=args.step,
                method=args.method, checks=dict(min_zncc=tracker.min_zncc,
                                                reanchor_zncc=tracker.reanchor_zncc,
                                                fb_max_px=tracker.fb_max_px),
                region=region_text(args), stamps_from=source.stamps_from,
                camera_from=camera_from, skipped_frames=source.skipped)
    summary = sink.close(camera, meta, complete=args.complete)
    print(f'{out}: {n} frames, {summary}; {1000 * seconds / n:.0f} ms per frame; stamps from '
          f'{source.stamps_from}; K {camera_from}'
          + (f'; {source.skipped} unreadable frames skipped' if source.skipped else ''))
    return 0


def check_arguments(args):
    if args.step < 1:
        raise UserError(f'--step must be >= 1 pixel; got {args.step}')
    if args.max_frames is not None and args.max_frames < 1:
        raise UserError(f'--max-frames must be >= 1; got {args.max_frames}')
    if args.roi and (args.roi[2] < args.roi[0] or args.roi[3] < args.roi[1]):
        raise UserError(f'--roi X0 Y0 X1 Y1 needs X0 <= X1 and Y0 <= Y1; got {args.roi}')
    out = Path(args.output)
    if out.suffix != '.npz' and out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise UserError(f'{out} exists: a bag is written into a new or empty directory '
                        '(or give OUT.npz)')


def chosen_camera(args, source):
    """``(Camera or None, where it comes from)``: the command line's, else the bag's."""
    try:
        if args.camera:
            return image.camera_from_intrinsics(*args.camera), 'from --camera'
        if args.camera_info:
            return image.camera_from_yaml(args.camera_info), f'from {args.camera_info}'
    except image.CameraError as exc:
        raise UserError(str(exc)) from None
    if source.camera is not None:
        return source.camera, f'from the bag topic {source.info_topic}'
    return None, 'unknown (pixels as they are)'


def read_mask(path):
    """``(H, W)`` bool: the nonzero pixels of an image file."""
    pixels = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_ANYDEPTH)
    if pixels is None:
        if not Path(path).exists():
            raise FileNotFoundError(f'mask {path} does not exist')
        raise UserError(f'mask {path}: not a readable image')
    mask = pixels > 0
    if not mask.any():
        raise UserError(f'mask {path} is empty (no nonzero pixel)')
    return mask


def region_text(args):
    if args.mask:
        return f'mask {args.mask}'
    if args.roi:
        return 'roi ' + ' '.join(f'{v:g}' for v in args.roi)
    return 'the whole image'


def track_frames(source, tracker, sink, progress, max_frames, mask):
    """Track every frame of ``source`` into ``sink``; returns the frames tracked. A size
    change restarts the tracks (new ids) with a warning."""
    n = 0
    for frame in source:
        if n == 0 and mask is not None and mask.shape != frame.image.shape[:2]:
            raise SourceError(f'the mask is {mask.shape[1]} x {mask.shape[0]} pixels but the '
                              f'first frame {frame.image.shape[1]} x {frame.image.shape[0]}')
        try:
            tracks = tracker.track(frame.image)
        except FrameSizeError as exc:
            if mask is not None:
                raise SourceError(f'frame {frame.index}: {exc} (a mask fits one size)') \
                    from None
            warnings.warn(f'frame {frame.index}: {exc}; the tracks restart (new ids)',
                          RuntimeWarning)
            tracker.reset()
            tracks = tracker.track(frame.image)
        sink.add(frame, tracks)
        n += 1
        progress.update(n, tracker.n_alive)
        if max_frames is not None and n >= max_frames:
            break
    return n


def _one_line_warning(message, category, filename, lineno, file=None, line=None):
    print(f'grass-nrsfm track: warning: {message}', file=sys.stderr)


# ------------------------------------------------------------------------------ outputs
def tracks_matrix(ids_per_frame, uv_per_frame):
    """``(W: (2F, P), ids: (P,))`` over the union of the frames' track ids; NaN where a
    track is not in a frame."""
    ids = np.unique(np.concatenate([np.zeros(0, np.uint32)] + ids_per_frame)).astype(np.uint32)
    W = np.full((2 * len(ids_per_frame), ids.size), np.nan)
    for f, (frame_ids, uv) in enumerate(zip(ids_per_frame, uv_per_frame)):
        cols = np.searchsorted(ids, frame_ids)
        W[2 * f:2 * f + 2, cols] = uv.T
    return W, ids


def track_summary(W):
    """A phrase: how many tracks, how long they live, how many are complete."""
    visible = np.isfinite(W[0::2])
    P = visible.shape[1]
    if P == 0:
        return 'no tracks (the region holds no texture?)'
    length = int(np.median(visible.sum(axis=0)))
    return (f'{P} tracks ({int(visible[0].sum())} in frame 0, {int(visible[-1].sum())} in the '
            f'last, {int(visible.all(axis=0).sum())} in every frame; median length '
            f'{length} frame{"s" if length != 1 else ""})')


class NpzSink:
    """Collects the frames; writes OUT.npz at close."""

    def __init__(self, path):
        self.path = path
        self.ids, self.uv, self.stamps = [], [], []

    def add(self, frame, tracks):
        self.ids.append(tracks.ids)
        self.uv.append(tracks.uv)
        self.stamps.append(frame.stamp_ns)

    def close(self, camera, meta, complete=False):
        W, ids = tracks_matrix(self.ids, self.uv)
        summary = track_summary(W)
        if complete:
            keep = np.isfinite(W).all(axis=0)
            W, ids = W[:, keep], ids[keep]
            summary += f'; {ids.size} complete tracks kept'
        arrays = dict(W=W, ids=ids, stamps=np.asarray(self.stamps, np.int64),
                      visible=np.isfinite(W[0::2]), meta=np.array(json.dumps(meta)))
        if camera is not None:
            arrays['K'] = camera.K
        self.path.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(self.path, **arrays)
        return summary

    def abort(self):
        pass


class BagSink:
    """Writes each frame's tracks (and the camera_info) into a bag as they come."""

    def __init__(self, path, camera, frame_id):
        self.path, self.camera, self.frame_id = path, camera, frame_id
        self.writer = None
        self.ids, self.uv = [], []

    def add(self, frame, tracks):
        if self.writer is None:
            self.writer = bag.BagWriter(self.path)
            if self.frame_id is None:
                self.frame_id = frame.frame_id or 'camera_optical'
            if self.camera is not None:
                self.writer.add_topic(CAMERA_INFO_TOPIC, CAMERA_INFO_TYPE)
            self.size = frame.image.shape[:2]
        stamp = frame.stamp_ns
        self.writer.write_tracks(tracks.ids, tracks.uv, stamp, self.frame_id)
        if self.camera is not None:
            self.writer.write(CAMERA_INFO_TOPIC, camera_info_message(
                self.camera, stamp, self.frame_id, self.size), stamp)
        self.ids.append(tracks.ids)
        self.uv.append(tracks.uv)

    def close(self, camera, meta, complete=False):
        if complete:
            warnings.warn('--complete applies to .npz output; the bag holds every track',
                          RuntimeWarning)
        self.writer.close()
        counts = ', '.join(f'{n} messages on {t}' for t, n in self.writer.counts.items())
        return f'{track_summary(tracks_matrix(self.ids, self.uv)[0])}; {counts}'

    def abort(self):
        if self.writer is not None:
            self.writer.abort()


def camera_info_message(camera, stamp_ns, frame_id, size):
    """A rosbags ``sensor_msgs/CameraInfo`` of ``camera`` (K row-major in ``k``, P = [K | 0],
    R = I; plumb_bob with zero distortion where the camera has none) for an image of
    ``size (H, W)``."""
    t = bag.typestore().types
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    header = t['std_msgs/msg/Header'](
        stamp=t['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec), frame_id=frame_id)
    roi = t['sensor_msgs/msg/RegionOfInterest'](
        x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    dist = camera.dist if camera.dist.size else np.zeros(5)
    model = camera.distortion_model or 'plumb_bob'
    P = np.hstack([camera.K, np.zeros((3, 1))])
    height, width = size
    return t[CAMERA_INFO_TYPE](
        header=header, height=int(height), width=int(width), distortion_model=model,
        d=np.asarray(dist, np.float64), k=camera.K.astype(np.float64).ravel(),
        r=np.eye(3).ravel(), p=P.ravel(), binning_x=0, binning_y=0, roi=roi)


# ------------------------------------------------------------------------------ progress
class Progress:
    """Progress on stderr: a bar redrawn in place on a terminal (at most 10 times a second),
    else one counter line every tenth of ``total`` frames (every 100 where unknown)."""

    def __init__(self, total, enabled=True, stream=None, width=30):
        self.total, self.enabled, self.width = total, enabled, width
        self.stream = stream or sys.stderr
        self.tty = bool(getattr(self.stream, 'isatty', lambda: False)())
        self.every = max(1, (total or 1000) // 10)
        self.started = time.monotonic()
        self.last_draw = -1.0
        self.drawn = False

    def update(self, done, alive):
        if not self.enabled:
            return
        rate = done / max(time.monotonic() - self.started, 1e-9)
        of = f'/{self.total}' if self.total else ''
        if self.tty:
            now = time.monotonic()
            if now - self.last_draw < 0.1 and done != self.total:
                return
            self.last_draw = now
            filled = int(self.width * done / self.total) if self.total else 0
            bar = f'[{"#" * filled}{" " * (self.width - filled)}] ' if self.total else ''
            self.stream.write(f'\r{bar}{done}{of} frames, {alive} tracks alive, '
                              f'{rate:.1f} frames/s ')
            self.drawn = True
        elif done % self.every == 0 or done == self.total:
            self.stream.write(f'track: {done}{of} frames, {alive} tracks alive, '
                              f'{rate:.1f} frames/s\n')
        self.stream.flush()

    def close(self):
        if self.enabled and self.tty and self.drawn:
            self.stream.write('\n')
            self.stream.flush()
