"""Every parameter of the node, the windowed pipeline and the solver, from one schema.

Parameters are :class:`grass_nrsfm_ros.nrsfm.schema.Param` s: the node's and the pipeline's
are declared here (:data:`NODE_PARAMS`), the solver's in :mod:`grass_nrsfm_ros.nrsfm.schema`,
where they appear under the prefix ``solver.`` (a nested ``solver:`` mapping in YAML).
The readers: the ROS node (``declare_parameter`` with a ``ParameterDescriptor``), the sliding
window (:func:`check_window`), ``config/params.yaml`` (:func:`render_yaml`), the offline CLI
(``grass-nrsfm reconstruct --config FILE`` through :func:`load_config`) and the README's
parameter table (:func:`render_table`, between the markers README_BEGIN and README_END).

``python -m grass_nrsfm_ros.params`` prints the default ``config/params.yaml``;
``python -m grass_nrsfm_ros.params --readme README.md`` rewrites the README's table.
"""
import argparse
from dataclasses import replace
import difflib
import math
from pathlib import Path
import textwrap

import yaml

from grass_nrsfm_ros.nrsfm.camera import intrinsics
from grass_nrsfm_ros.nrsfm.schema import Param, SOLVER_PARAMS, validate_solver

NODE_NAME = 'grass_nrsfm'
SOLVER_PREFIX = 'solver.'
README_BEGIN = '<!-- params-table -->'
README_END = '<!-- /params-table -->'

#: values of ``warm_start``
WARM_STARTS = ('resume', 'model')
#: values of ``mapping``
MAPPINGS = ('process', 'inline')
#: values of ``refined_from``
REFINED_FROM = ('last_window', 'first_window')
#: values of ``input_reliability``
INPUT_RELIABILITIES = ('auto', 'best_effort', 'reliable')
#: the fewest frames a window can have
MIN_WINDOW_FRAMES = 3

NODE_PARAMS = (
    Param('window_size', 30, int, 'Frames per sliding window solved together.',
          range=(MIN_WINDOW_FRAMES, 100000)),
    Param('window_stride', 10, int,
          'New frames between two windows; each window after the first publishes this many '
          'frames. Must not exceed window_size.', range=(1, 100000)),
    Param('min_tracks', 10, int,
          'Fewest tracks a frame must have; a frame sharing fewer ids than this with the '
          'previous frame starts a new sequence (all ids changed).', range=(4, 10000000)),
    Param('warm_start', 'resume', str,
          "What each window's solve takes from the previous window's solution on the "
          "overlapping frames and tracks. 'resume': its shapes and spatial groups, rotations by "
          "Dai's method refined from the previous ones at the carried rank (no rank search, no "
          "rotation check), the ADMM's penalty schedule from its start, stopped at beta 10. "
          "'model': the groups and the rotation method (Dai's or rigid; checked again once "
          'half the frames are new); rotations are re-estimated over window + context and '
          "shapes start from the solver's own start (the reference the live benchmark compares "
          "'resume' with). A window without context frames (the first) starts from the rigid "
          'factorisation.', choices=WARM_STARTS),
    Param('first_model_frames', 0, int,
          "Frames after which a sequence's first model is solved, before its first window "
          'closes: a preview window of the frames so far, whose model the tracking takes and '
          'whose shapes are not published on points/refined (an earlier model, often a worse '
          'one than the rigid start-up model: docs/decisions/0444). Below 3, or window_size and '
          'above: none (the first model comes from the first window).', range=(0, 100000)),
    Param('context_frames', 60, int,
          'Earlier frames solved again with each window (not republished): the shape prior '
          'sees window + context frames. 0: the window alone.', range=(0, 100000)),
    Param('key_frames', 30, int,
          'Older frames (beyond context_frames) also solved again with each window, spread '
          'evenly over the sequence so far, so long sequences keep their shape prior. 0: none; '
          'unused when context_frames is 0.', range=(0, 100000)),
    Param('refined_from', 'last_window', str,
          "Which solve's shapes of a frame go out on points/refined. "
          "'last_window': the solve that reconstructs the frame for the ceil(window_size / "
          'window_stride)-th time, as one of its own frames or as context (after the first '
          'window: the last window that has it among its own frames, with the most frames '
          'after it), window_size - window_stride frames later than the first; the last window '
          "of a sequence publishes the rest. 'first_window': the first window that solves it.",
          choices=REFINED_FROM),
    Param('flush_after', 1.0, float,
          'Seconds without an accepted tracks frame (checked once a second) after which the '
          'buffered frames are solved as the last window of the sequence: every frame not yet '
          'on points/refined goes out, as at the end of a bag. A later frame continues the '
          'sequence. 0: never.', range=(0.0, 1e6)),
    Param('mapping', 'process', str,
          "Where windows are solved: 'process' (a child process beside the tracking, at a "
          'lower CPU priority: every frame is published at once, refined when its window is '
          "solved; frames and models cross between the processes); 'inline' (in the input "
          'callback, before the next frame: the output equals the offline tools for the same '
          'input, but tracking waits for each solve).', choices=MAPPINGS),
    Param('mapping_tracks', 2000, int,
          'Most tracks a window is solved on (a fixed subset by track id); the others are '
          'filled in from their neighbours. 0: all tracks.', range=(0, 10000000)),
    Param('residual_limit', 3.0, float,
          'A tracked frame whose reprojection residual exceeds this many times the median of '
          "the last 30 tracked frames' is still published, and the next window is closed early "
          'for a fresh model (once per model).', range=(1.0001, 1e6)),
    Param('frame_id', '', str,
          'frame_id of the output clouds (the camera optical frame); empty: the input '
          "cloud's frame_id.", read_only=False),
    Param('metres_per_pixel', 1.0, float,
          'Without camera intrinsics: scale from pixels to output units (x, y, z are all '
          'multiplied by it).', range=(1e-12, 1e12), read_only=False),
    Param('camera', [], list,
          'Pinhole intrinsics [fx, fy, cx, cy] (pixels) of the tracks; they win over '
          'camera_info. Empty: those of the camera_info topic (sensor_msgs/CameraInfo), or '
          'none: the pixels are solved as orthographic projections (warned once). With them '
          "the output is the camera frame through the pinhole, each frame's mean depth "
          'scene_depth.'),
    Param('scene_depth', 1.0, float,
          "With camera intrinsics: each frame's mean depth in output units (the monocular "
          'scale is unknown: the distance from the camera to the surface in metres gives '
          'metres).', range=(1e-12, 1e12), read_only=False),
    Param('record_path', '', str,
          'rosbag2 (MCAP) directory recording the input tracks and output points; empty: '
          'off.'),
    Param('input_reliability', 'auto', str,
          "Reliability of the tracks subscription. 'auto': reliable while every publisher "
          'found offers reliable, best effort otherwise and while none is found (sensor '
          "data, REP 2003), adapted as publishers come and go; 'best_effort': hears every "
          "publisher, each connection best effort; 'reliable': hears reliable publishers "
          'only. A qos_overrides reliability for the tracks subscription wins over all three.',
          choices=INPUT_RELIABILITIES),
    Param('expected_rate', 30.0, float,
          'Expected tracks and points rate (Hz) for the frequency statuses in /diagnostics '
          '(WARN outside it, widened by rate_tolerance); 0: rates reported, not checked.',
          range=(0.0, 1e6)),
    Param('rate_tolerance', 0.1, float,
          'Fraction by which a measured rate may miss expected_rate before a WARN.',
          range=(0.0, 1.0)),
    Param('publish_mesh', False, bool,
          'Also publish a visualization_msgs/Marker TRIANGLE_LIST on mesh: the newest frame '
          "each solved window publishes, triangulated (Delaunay) on the track set's first "
          'frame in the image plane and coloured by depth.'),
    Param('mesh_max_edge', 3.0, float,
          'Triangles whose longest edge (in the image) exceeds this many times the median edge '
          'are left out of the mesh (gaps, convex hull).', range=(1.0, 1e6)),
)
#: the parameters the windowing takes
WINDOW_KEYS = ('window_size', 'window_stride', 'min_tracks', 'context_frames', 'key_frames',
               'first_model_frames')
#: the parameters the mapper takes (besides the solver's)
MAPPER_KEYS = ('min_tracks', 'warm_start', 'context_frames', 'mapping_tracks')


def solver_params():
    """The solver's Params, named ``solver.<name>``."""
    return tuple(replace(p, name=SOLVER_PREFIX + p.name) for p in SOLVER_PARAMS)


def all_params():
    """Every parameter: the node's, then the solver's (everyday, then research)."""
    return NODE_PARAMS + solver_params()


def defaults():
    """``{name: default}`` for every parameter."""
    return {p.name: p.default for p in all_params()}


def _flatten(mapping, prefix=''):
    flat = {}
    for key, value in mapping.items():
        if isinstance(value, dict):
            flat.update(_flatten(value, f'{prefix}{key}.'))
        else:
            flat[f'{prefix}{key}'] = value
    return flat


def _node_section(data, path):
    """The parameter mapping of a params file: ``<node>: ros__parameters:`` or flat."""
    sections = {k: v for k, v in data.items()
                if isinstance(v, dict) and 'ros__parameters' in v}
    if not sections:
        return data
    for key in ('/**/' + NODE_NAME, NODE_NAME, '/' + NODE_NAME, '/**'):
        if key in sections:
            return sections[key]['ros__parameters'] or {}
    if len(sections) == 1:
        return next(iter(sections.values()))['ros__parameters'] or {}
    raise ValueError(f'{path}: several node sections ({sorted(sections)}); expected '
                     f'{NODE_NAME!r}')


def _check_stride(values):
    if values.get('window_stride', 0) > values.get('window_size', math.inf):
        raise ValueError(f"window_stride={values['window_stride']} exceeds "
                         f"window_size={values['window_size']}")


def check_camera(value):
    """``camera`` as a list of 0 or 4 floats ``[fx, fy, cx, cy]`` (None, as rclpy gives an
    unset array, is empty); ValueError unless finite with fx, fy > 0."""
    values = [] if value is None else list(value)
    if values and (len(values) != 4 or any(isinstance(v, (bool, str)) for v in values)):
        raise ValueError(f'camera={values!r}: expected [fx, fy, cx, cy] (4 numbers) or []')
    values = [float(v) for v in values]
    if values and not (all(math.isfinite(v) for v in values) and min(values[:2]) > 0):
        raise ValueError(f'camera={values}: needs finite numbers and fx, fy > 0')
    return values


def camera_matrix(camera):
    """``K: (3, 3)`` of ``camera`` ``[fx, fy, cx, cy]``."""
    fx, fy, cx, cy = check_camera(camera)
    return intrinsics(fx, fy, cx, cy)


def validate(values):
    """Check ``{name: value}`` against the schema; returns converted values or raises
    ValueError naming the parameter (and the closest known name for a typo)."""
    specs = {p.name: p for p in all_params()}
    out = {}
    for name, value in values.items():
        if name not in specs:
            close = difflib.get_close_matches(name, specs, n=1)
            if SOLVER_PREFIX + name in specs:                   # a solver's, without its prefix
                close = [SOLVER_PREFIX + name]
            hint = f'; did you mean {close[0]!r}?' if close else ''
            raise ValueError(f'unknown parameter {name!r}{hint}')
        out[name] = check_camera(value) if name == 'camera' else specs[name].check(value)
    _check_stride(out)
    validate_solver(solver_kwargs(out))
    return out


def with_defaults(config):
    """Every parameter's value: ``config`` over the defaults, checked (:func:`validate`)."""
    return validate({**defaults(), **config})


def check_window(**values):
    """The SlidingWindow parameters ``values`` checked against NODE_PARAMS (ValueError)."""
    specs = {p.name: p for p in NODE_PARAMS}
    out = {name: specs[name].check(value) for name, value in values.items()}
    _check_stride(out)
    return out


def load_config(path):
    """Read a params file and return every parameter's value (defaults overridden by the file).

    Accepts the ROS layout (``grass_nrsfm: {ros__parameters: {...}}``, also ``/**``) or a flat
    mapping; nested mappings become dotted names (``solver: {gamma: 1e-3}`` ->
    ``solver.gamma``). Raises ValueError with the file, the parameter and why.
    """
    with open(path, encoding='utf-8') as f:
        try:
            data = yaml.safe_load(f) or {}
        except yaml.YAMLError as exc:
            raise ValueError(f'{path}: not valid YAML ({" ".join(str(exc).split())})') from None
    if not isinstance(data, dict):
        raise ValueError(f'{path}: expected a mapping of parameters, got {type(data).__name__}')
    try:
        values = validate(_flatten(_node_section(data, path)))
        return with_defaults(values)
    except ValueError as exc:
        raise ValueError(f'{path}: {exc}') from None


def solver_kwargs(config):
    """The solver's keyword arguments from a config dict (``solver.`` prefix removed, unset
    (None) values left to the solver's defaults)."""
    n = len(SOLVER_PREFIX)
    return {k[n:]: v for k, v in config.items() if k.startswith(SOLVER_PREFIX) and v is not None}


def window_kwargs(config):
    """SlidingWindow's keyword arguments from a config dict."""
    return {k: config[k] for k in WINDOW_KEYS if k in config}


# ----------------------------------------------------------------------------- generated files
def _sections():
    """``(title, yaml key or None, params)`` in the order of the files."""
    research = [p for p in solver_params() if p.group == 'research']
    everyday = [p for p in solver_params() if p.group != 'research']
    return (('Node and sliding window', None, list(NODE_PARAMS)),
            ('Solver', 'solver', everyday),
            ('Solver: research switches (no default uses them)', 'solver', research))


def render_yaml():
    """The default params file (``config/params.yaml``) as text, descriptions as comments."""
    lines = ['# Parameters of grass_nrsfm_ros (generated by `python -m grass_nrsfm_ros.params`).',
             '# Used by `ros2 run grass_nrsfm_ros node --ros-args --params-file FILE` and by',
             '# `grass-nrsfm reconstruct --config FILE`.',
             f'/**/{NODE_NAME}:', '  ros__parameters:']
    opened = False
    for title, key, group in _sections():
        indent = '    '
        if key is not None:
            if not opened:
                lines.append(f'    {key}:')
                opened = True
            indent = '      '
            lines.append(f'{indent}# --- {title}')
        for p in group:
            name = p.name[len(SOLVER_PREFIX):] if key else p.name
            lines += textwrap.wrap(f'{p.description} [{p.constraint}]', 99,
                                   initial_indent=indent + '# ',
                                   subsequent_indent=indent + '# ')
            lines.append(f'{indent}{name}: {_yaml_value(p.default)}')
    return '\n'.join(lines) + '\n'


def _summary(description):
    """The first sentence of a description."""
    head, dot, _ = description.partition('. ')
    return head + '.' if dot else description


def render_table():
    """The README's parameter table (Markdown): a row per node parameter, a row per solver
    group naming its parameters (config/params.yaml describes each)."""
    def row(*cells):
        return '| ' + ' | '.join(c.replace('|', '\\|') for c in cells) + ' |'
    out = [row('parameter', 'default', 'values', 'meaning'), '| --- | --- | --- | --- |']
    sections = _sections()
    for p in sections[0][2]:
        out.append(row(f'`{p.name}`', f'`{_yaml_value(p.default)}`', p.constraint,
                       _summary(p.description)))
    for title, _, group in sections[1:]:
        names = ', '.join(f'`{p.name[len(SOLVER_PREFIX):]}`' for p in group)
        out.append(row('`solver.*`', '', '', f'{title}: {names}'))
    return '\n'.join(out) + '\n'


def readme_with_table(text):
    """``text`` (the README) with the generated table between README_BEGIN and README_END."""
    head, begin, rest = text.partition(README_BEGIN)
    _, end, tail = rest.partition(README_END)
    if not begin or not end:
        raise ValueError(f'README has no {README_BEGIN} ... {README_END} markers')
    return f'{head}{README_BEGIN}\n{render_table()}{README_END}{tail}'


def _yaml_value(value):
    if value is None:
        return 'null'
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, str):
        return f"'{value}'"
    if isinstance(value, float):
        text = repr(value)            # YAML 1.1 (PyYAML, rcl) reads 1e-08 as a string: 1.0e-08
        mantissa, e, exponent = text.partition('e')
        return f'{mantissa}.0{e}{exponent}' if e and '.' not in mantissa else text
    return str(value)


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m grass_nrsfm_ros.params',
                                     description='Print config/params.yaml, or rewrite the '
                                     "README's parameter table.")
    parser.add_argument('--readme', metavar='PATH', help='rewrite the table in this README')
    args = parser.parse_args(argv)
    if args.readme:
        path = Path(args.readme)
        path.write_text(readme_with_table(path.read_text(encoding='utf-8')), encoding='utf-8')
    else:
        print(render_yaml(), end='')


if __name__ == '__main__':
    main()
