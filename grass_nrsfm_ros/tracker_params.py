"""The tracker node's parameters, from the package's one schema, and the region they give.

:data:`TRACKER_PARAMS` (:class:`grass_nrsfm_ros.nrsfm.schema.Param` s) are declared by
:mod:`grass_nrsfm_ros.tracker_node`, rendered as ``config/tracker.yaml`` (:func:`render_yaml`)
and checked by :func:`validate`. :func:`load_region` turns ``mask`` (a PNG: non-zero pixels are
the region in the first frame) and ``roi`` (``[x0, y0, x1, y1]`` pixels, bounds included) into
the ``region`` of :class:`grass_nrsfm_ros.frontend.DenseTracker`: None (the whole image), the
rectangle, or a bool mask ``(H, W)`` (the mask, cut to the rectangle when both are given).
No ROS import.

``python -m grass_nrsfm_ros.tracker_params`` prints the default ``config/tracker.yaml``.
"""
from pathlib import Path
import textwrap

import numpy as np

from grass_nrsfm_ros.frontend import METHODS
from grass_nrsfm_ros.frontend.flow import DEFAULT_METHOD
from grass_nrsfm_ros.nrsfm.schema import Param

TRACKER_NODE_NAME = 'grass_nrsfm_tracker'
#: the params file's node key: the tracker in any namespace (a bare name is the root's only)
FILE_KEY = f'/**/{TRACKER_NODE_NAME}'

TRACKER_PARAMS = (
    Param('step', 4, int,
          'Grid step in pixels: tracks start on the points of a grid of this spacing inside '
          'the region (step 2 on 640 x 480: up to 76,800 tracks).', range=(1, 1024)),
    Param('method', DEFAULT_METHOD, str,
          'Optical flow: a DIS preset from the last frame predicts each track; +lk refines '
          'it by Lucas-Kanade against its keyframe in the frame warped by the field of the '
          'tracks (/prev+lk: without the warp); a bare DIS preset chains (it drifts); lk '
          'predicts nothing and refines by pyramidal Lucas-Kanade.',
          choices=METHODS),
    Param('mask', '', str,
          'PNG file whose non-zero pixels are the region to track in the first frame (same '
          'size as the images); it moves with the surface. Empty: no mask.'),
    Param('roi', [], list,
          'Rectangle [x0, y0, x1, y1] in pixels (bounds included) to track in, fixed in the '
          'image; with a mask, the mask cut to it. Empty: the whole image.'),
    Param('min_zncc', 0.8, float,
          'A track fails when its 11 x 11 patch correlates (ZNCC) less than this with its '
          'keyframe patch (occlusion, a lost track): it is hidden, and dies when it fails '
          'again in the next frame.', range=(-1.0, 1.0)),
    Param('publish_age', True, bool,
          'Add an age field (UINT32, frames since the track was born) to each tracks cloud '
          'besides track_id, u and v.'),
)


def defaults():
    """``{name: default}`` of every tracker parameter."""
    return {p.name: p.default for p in TRACKER_PARAMS}


def _roi(value):
    """``roi`` as a list of 0 or 4 ints (None, as rclpy gives an unset array, is empty)."""
    values = [] if value is None else list(value)
    if values and (len(values) != 4 or any(isinstance(v, (bool, float, str)) for v in values)):
        raise ValueError(f'roi={values!r}: expected [x0, y0, x1, y1] (4 integers) or []')
    values = [int(v) for v in values]
    if values and (values[2] < values[0] or values[3] < values[1] or min(values) < 0):
        raise ValueError(f'roi={values}: needs 0 <= x0 <= x1 and 0 <= y0 <= y1')
    return values


def validate(values):
    """``{name: value}`` checked against :data:`TRACKER_PARAMS` (and converted); raises
    ValueError naming the parameter."""
    specs = {p.name: p for p in TRACKER_PARAMS}
    out = {}
    for name, value in values.items():
        if name not in specs:
            raise ValueError(f'unknown tracker parameter {name!r}; expected one of '
                             f'{sorted(specs)}')
        out[name] = _roi(value) if name == 'roi' else specs[name].check(value)
    return out


def load_region(mask_path, roi):
    """The DenseTracker ``region`` of ``mask`` (a PNG path, '' for none) and ``roi`` (0 or 4
    ints). Raises ValueError for a mask that cannot be read, is empty, or misses the roi."""
    if not mask_path:
        return tuple(roi) if roi else None
    import cv2

    if not Path(mask_path).is_file():
        raise ValueError(f'mask {mask_path!r}: no such file')
    mask = cv2.imread(str(mask_path), cv2.IMREAD_GRAYSCALE)
    if mask is None:
        raise ValueError(f'mask {mask_path!r}: cannot read it as an image')
    mask = mask > 0
    if roi:
        x0, y0, x1, y1 = roi
        inside = np.zeros_like(mask)
        inside[y0:y1 + 1, x0:x1 + 1] = True
        mask &= inside
    if not mask.any():
        raise ValueError(f'mask {mask_path!r} has no non-zero pixel'
                         + (f' inside roi {roi}' if roi else ''))
    return mask


def _yaml_value(value):
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, str):
        return f"'{value}'"
    return repr(value)


def render_yaml():
    """The default params file of the tracker node (``config/tracker.yaml``)."""
    lines = ['# Parameters of the grass_nrsfm_ros tracker node (generated by',
             '# `python -m grass_nrsfm_ros.tracker_params`). Used by',
             '# `ros2 run grass_nrsfm_ros tracker --ros-args --params-file FILE`; /**/ applies',
             '# it to the tracker in any namespace.',
             f'{FILE_KEY}:', '  ros__parameters:']
    for p in TRACKER_PARAMS:
        lines += textwrap.wrap(f'{p.description} [{p.constraint}]', 99, break_on_hyphens=False,
                               initial_indent='    # ', subsequent_indent='    # ')
        lines.append(f'    {p.name}: {_yaml_value(p.default)}')
    return '\n'.join(lines) + '\n'


if __name__ == '__main__':
    print(render_yaml(), end='')
