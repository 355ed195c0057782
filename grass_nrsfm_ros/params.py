"""Every parameter of the node and the windowed pipeline, once: name, default, type, range and
description.

Three readers share these specs: the ROS node (``declare_parameter`` with a
``ParameterDescriptor``), ``config/params.yaml`` (``--ros-args --params-file``) and the offline
CLI (``grass-nrsfm reconstruct --config FILE`` through :func:`load_config`).

The solver's parameters are not repeated here: their defaults come from
``inspect.signature(GrassmannNRSfM.__init__)`` and their descriptions from
``GrassmannNRSfM.parameter_specs``; they appear under the prefix ``solver.`` (a nested
``solver:`` mapping in YAML). The solver is imported lazily, so this module imports no ROS and
works before the solver is installed (then only the node parameters exist).

Run ``python -m grass_nrsfm_ros.params`` to print the default ``config/params.yaml``.
"""
from dataclasses import dataclass
import difflib
import inspect
import math
import re
import textwrap

NODE_NAME = 'grass_nrsfm'
SOLVER_PREFIX = 'solver.'


@dataclass(frozen=True)
class ParamSpec:
    """One parameter. ``type`` is bool, int, float or str, or None for a dynamically typed one
    (a solver parameter whose default is None or a string such as ``'auto'``); ``range`` is an
    inclusive ``(low, high)`` for numbers; ``read_only`` parameters fix the node's topology and
    can only be set at start-up."""

    name: str
    default: object
    type: type
    description: str
    range: tuple = None
    choices: tuple = None
    read_only: bool = True

    def check(self, value):
        """Return ``value`` converted to this parameter's type, or raise ValueError saying why."""
        if self.type is None:
            if self.choices and isinstance(value, str) and value not in self.choices:
                raise ValueError(f'{self.name}={value!r}: expected one of {list(self.choices)} '
                                 f'or a number')
            return value
        if self.type is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if not isinstance(value, self.type) or (self.type is int and isinstance(value, bool)):
            raise ValueError(f'{self.name}={value!r}: expected {self.type.__name__}, '
                             f'got {type(value).__name__}')
        if self.type is float and not math.isfinite(value):
            raise ValueError(f'{self.name}={value!r}: must be finite')
        if self.range is not None and not self.range[0] <= value <= self.range[1]:
            raise ValueError(f'{self.name}={value!r}: outside [{self.range[0]}, {self.range[1]}]')
        if self.choices and value not in self.choices:
            raise ValueError(f'{self.name}={value!r}: expected one of {list(self.choices)}')
        return value


#: values of ``warm_start`` and ``warm_rotations`` (SlidingWindow checks them too)
WARM_STARTS = ('model', 'full', 'off')
WARM_ROTATIONS = ('refine', 'fit', 'solver')
#: values of ``input_reliability``
INPUT_RELIABILITIES = ('auto', 'best_effort', 'reliable')

NODE_PARAMS = (
    ParamSpec('window_size', 30, int, 'Frames per sliding window solved together.',
              range=(3, 100000)),
    ParamSpec('window_stride', 10, int,
              'New frames between two windows; each window after the first publishes this many '
              'frames. Must not exceed window_size.', range=(1, 100000)),
    ParamSpec('min_tracks', 10, int,
              'Fewest tracks a frame must have; a frame sharing fewer ids than this with the '
              'previous frame starts a new sequence (all ids changed).', range=(4, 10000000)),
    ParamSpec('warm_start', 'model', str,
              "What each window's solve takes from the previous window's solution on the "
              "overlapping frames and tracks. 'model' (default): the tracks' spatial groups and "
              "the rotation method (Dai's or rigid; checked again once half the frames are "
              'new), while rotations are re-estimated over window + context and shapes start '
              "from the solver's own start: e3D as 'off' (shark better) at 36-40 % less CPU "
              "per window on long sequences (README: streaming). 'full': also the overlapping "
              "frames' rotations (fixed) and shapes: 45-70 % less CPU again, but it keeps the "
              "earlier windows' errors (Torresani face 0.083 vs 0.060). 'off': each window "
              "from the solver's own start. A window without context frames (the first) starts "
              'from the rigid factorisation.', choices=WARM_STARTS),
    ParamSpec('context_frames', 60, int,
              'Earlier frames solved again with each window (not republished): the shape '
              'prior sees window + context frames. 0: the window alone.', range=(0, 100000)),
    ParamSpec('key_frames', 30, int,
              'Older frames (beyond context_frames) also solved again with each window, spread '
              'evenly over the sequence so far, so long sequences keep their shape prior '
              "(Torresani face streaming e3D 0.063 -> 0.060; with warm_start 'full' it did not "
              'help, 0.080 -> 0.083). 0: none; unused when context_frames is 0.',
              range=(0, 100000)),
    ParamSpec('warm_rotations', 'solver', str,
              "Rotations of a fully warm-started solve (warm_start 'full'): 'solver' (previous "
              "ones fixed, new ones from the solver's estimate), 'refine' (Dai's over all frames, "
              'aligned to the previous solution: slightly more accurate, one more rotation '
              "estimate per window), 'fit' (previous ones; new frames fitted to the previous "
              'shape: cheapest, good on dense surfaces, poor on sparse mocap).',
              choices=WARM_ROTATIONS),
    ParamSpec('align_windows', True, bool,
              "Flip each window's depth to agree with the previous window on the overlap, so "
              'published clouds keep one orientation over time.'),
    ParamSpec('frame_id', '', str,
              'frame_id of the output clouds (the camera optical frame); empty: the input '
              "cloud's frame_id.", read_only=False),
    ParamSpec('metres_per_pixel', 1.0, float,
              'Scale from pixels to output units (x, y, z are all multiplied by it).',
              range=(1e-12, 1e12), read_only=False),
    ParamSpec('record_path', '', str,
              'rosbag2 (MCAP) directory recording the input tracks and output points; empty: '
              'off.'),
    ParamSpec('blas_threads', 0, int,
              'BLAS/OpenMP threads for the solver; 0: all cores but one (at least 1).',
              range=(0, 1024)),
    ParamSpec('input_reliability', 'auto', str,
              "Reliability of the tracks subscription. 'auto' (default): reliable while every "
              'publisher found offers reliable, best effort otherwise and while none is found '
              '(sensor data, REP 2003), adapted as publishers come and go; '
              "'best_effort': hears every publisher, each connection best effort; "
              "'reliable': hears reliable publishers only. A qos_overrides reliability for "
              'the tracks subscription wins over all three.', choices=INPUT_RELIABILITIES),
    ParamSpec('expected_rate', 30.0, float,
              'Expected tracks and points rate (Hz) for the frequency statuses in /diagnostics '
              '(WARN outside it, widened by rate_tolerance); 0: rates reported, not checked.',
              range=(0.0, 1e6)),
    ParamSpec('rate_tolerance', 0.1, float,
              'Fraction by which a measured rate may miss expected_rate before a WARN.',
              range=(0.0, 1.0)),
    ParamSpec('publish_mesh', False, bool,
              'Also publish a visualization_msgs/Marker TRIANGLE_LIST on mesh: the newest '
              "frame of each solved window, triangulated (Delaunay) on the track set's first "
              'frame in the image plane and coloured by depth.'),
    ParamSpec('mesh_max_edge', 3.0, float,
              'Triangles whose longest edge (in the image) exceeds this many times the median '
              'edge are left out of the mesh (gaps, convex hull).', range=(1.0, 1e6)),
)


def _solver_class():
    """GrassmannNRSfM, or None while the solver is not installed."""
    try:
        from grass_nrsfm_ros.nrsfm import GrassmannNRSfM
    except ImportError:
        return None
    return GrassmannNRSfM


def _type_of(default):
    for kind in (bool, int, float):
        if type(default) is kind:
            return kind
    return None                               # None or str defaults: dynamically typed


def _range_of(constraint):
    """Inclusive numeric range from a constraint such as ``'float in [0, 1]'`` or
    ``'int >= 1'``; None for anything else (the solver validates those in ``fit``)."""
    match = re.search(r'in \[([-\d.e]+), ([-\d.e]+)\]', constraint)
    if match:
        return float(match.group(1)), float(match.group(2))
    match = re.search(r'>= ([-\d.e]+)$', constraint)
    return (float(match.group(1)), 1e12) if match else None


def solver_params(cls=None):
    """ParamSpecs of the solver's ``__init__`` keyword parameters, prefixed ``solver.``: the
    default from the signature, ``(description, constraint)`` from ``parameter_specs``."""
    cls = cls or _solver_class()
    if cls is None:
        return ()
    out = []
    for name, p in inspect.signature(cls.__init__).parameters.items():
        if name == 'self' or p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD):
            continue
        description, constraint = cls.parameter_specs[name]
        default = None if p.default is p.empty else p.default
        kind = _type_of(default)
        rng = _range_of(constraint) if kind in (int, float) else None
        if rng is not None and kind is int:
            rng = (int(rng[0]), int(min(rng[1], 2**31 - 1)))
        choices = tuple(re.findall(r"'(\w+)'", constraint)) or None    # quoted words
        out.append(ParamSpec(SOLVER_PREFIX + name, default, kind,
                             f'{description} [{constraint}]', range=rng, choices=choices))
    return tuple(out)


def all_params():
    """Every parameter: the node's, then the solver's."""
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
    for key in (NODE_NAME, '/' + NODE_NAME, '/**'):
        if key in sections:
            return sections[key]['ros__parameters'] or {}
    if len(sections) == 1:
        return next(iter(sections.values()))['ros__parameters'] or {}
    raise ValueError(f'{path}: several node sections ({sorted(sections)}); expected '
                     f'{NODE_NAME!r}')


def validate(values):
    """Check ``{name: value}`` against the specs; returns converted values or raises ValueError
    naming the parameter (and the closest known name for a typo)."""
    specs = {p.name: p for p in all_params()}
    solver_known = bool(solver_params())
    out = {}
    for name, value in values.items():
        if name not in specs:
            if name.startswith(SOLVER_PREFIX) and not solver_known:
                out[name] = value           # solver not installed: cannot check its names
                continue
            close = difflib.get_close_matches(name, specs, n=1)
            hint = f'; did you mean {close[0]!r}?' if close else ''
            raise ValueError(f'unknown parameter {name!r}{hint}')
        out[name] = specs[name].check(value)
    if out.get('window_stride', 0) > out.get('window_size', math.inf):
        raise ValueError(f"window_stride={out['window_stride']} exceeds "
                         f"window_size={out['window_size']}")
    return out


def load_config(path):
    """Read a params file and return every parameter's value (defaults overridden by the file).

    Accepts the ROS layout (``grass_nrsfm: {ros__parameters: {...}}``, also ``/**``) or a flat
    mapping; nested mappings become dotted names (``solver: {gamma: 1e-3}`` ->
    ``solver.gamma``). Raises ValueError with the file, the parameter and why.
    """
    import yaml

    with open(path, encoding='utf-8') as f:
        try:
            data = yaml.safe_load(f) or {}
        except yaml.YAMLError as exc:
            raise ValueError(f'{path}: not valid YAML ({" ".join(str(exc).split())})') from None
    if not isinstance(data, dict):
        raise ValueError(f'{path}: expected a mapping of parameters, got {type(data).__name__}')
    try:
        values = validate(_flatten(_node_section(data, path)))
        merged = {**defaults(), **values}
        return validate(merged)
    except ValueError as exc:
        raise ValueError(f'{path}: {exc}') from None


def solver_kwargs(config):
    """The solver's keyword arguments from a config dict (``solver.`` prefix removed, unset
    (None) values left to the solver's defaults)."""
    n = len(SOLVER_PREFIX)
    return {k[n:]: v for k, v in config.items() if k.startswith(SOLVER_PREFIX) and v is not None}


def window_kwargs(config):
    """SlidingWindow's keyword arguments from a config dict."""
    keys = ('window_size', 'window_stride', 'min_tracks', 'warm_start', 'align_windows',
            'context_frames', 'warm_rotations', 'key_frames')
    return {k: config[k] for k in keys if k in config}


def make_pipeline(config, solver_factory=None, **options):
    """The :class:`~grass_nrsfm_ros.pipeline.SlidingWindow` that ``config`` describes (a dict
    of parameters as from :func:`load_config` or the node's declarations; absent keys take
    their defaults). ``solver_factory`` replaces ``GrassmannNRSfM(**solver parameters)``;
    ``options`` (e.g. ``warm_start_class``) go to SlidingWindow as they are."""
    from grass_nrsfm_ros.pipeline import default_solver_factory, SlidingWindow

    factory = solver_factory or default_solver_factory(**solver_kwargs(config))
    return SlidingWindow(factory, metres_per_pixel=config.get('metres_per_pixel', 1.0),
                         **window_kwargs(config), **options)


def render_yaml():
    """The default params file (``config/params.yaml``) as text, descriptions as comments."""
    lines = ['# Parameters of grass_nrsfm_ros (generated by `python -m grass_nrsfm_ros.params`).',
             '# Used by `ros2 run grass_nrsfm_ros node --ros-args --params-file FILE` and by',
             '# `grass-nrsfm reconstruct --config FILE`.',
             f'{NODE_NAME}:', '  ros__parameters:']
    solver_started = False
    for p in all_params():
        indent = '    '
        key = p.name
        if p.name.startswith(SOLVER_PREFIX):
            if not solver_started:
                lines.append('    solver:')
                solver_started = True
            indent, key = '      ', p.name[len(SOLVER_PREFIX):]
        extra = ''
        if p.range and not p.name.startswith(SOLVER_PREFIX):   # solver: constraint in text
            extra = f' Range [{p.range[0]}, {p.range[1]}].'
        lines += textwrap.wrap(p.description + extra, 99, initial_indent=indent + '# ',
                               subsequent_indent=indent + '# ')
        lines.append(f'{indent}{key}: {_yaml_value(p.default)}')
    return '\n'.join(lines) + '\n'


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


if __name__ == '__main__':
    print(render_yaml(), end='')
