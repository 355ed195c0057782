"""The parameter schema: one typed declaration per parameter, and the solver's parameters.

:class:`Param` is the one parameter class of the package: the solver's parameters are declared
here (:data:`SOLVER_PARAMS`), the node's and the pipeline's in ``grass_nrsfm_ros.params``, and
every reader (the estimator's validation, the ROS descriptors, ``config/params.yaml``, the CLI
config, the README's table) takes range, choices and description from them.

``group``: 'node' (the ROS node and the windowed pipeline), 'solver' (everyday solver
parameters) or 'research' (switches no default uses: ablations, an iteration cap for short
runs).
"""
from dataclasses import dataclass
import math

import numpy as np

from .measurement import InvalidInputError

INT_MAX = 2 ** 31 - 1
FLOAT_MAX = 1e12
GROUPS = ('node', 'solver', 'research')

#: auto sizes (see :func:`grass_nrsfm_ros.nrsfm.config.sizes`) and thresholds quoted below
REGISTRATION_MIN_SPREAD = 5.0
INEXTENSIBLE_MIN_POINTS = 100
INEXTENSIBLE_RATIO = 0.6
THINNING_MIN_POINTS = 100
ROTATION_MARGIN = 0.10
#: values of the solver parameter ``projection``
PROJECTIONS = ('auto', 'orthographic', 'perspective')


@dataclass(frozen=True)
class Param:
    """One parameter.

    ``type``: bool, int, float or str; None for a dynamically typed one, which takes one of
    ``choices`` (such as 'auto'), ``None`` where ``nullable``, or a number of type
    ``number``. ``range``: inclusive ``(low, high)`` for numbers (``open_low``: low excluded).
    ``read_only``: fixed at the node's start-up."""

    name: str
    default: object
    type: type
    description: str
    range: tuple = None
    choices: tuple = None
    group: str = 'node'
    read_only: bool = True
    open_low: bool = False
    number: type = None
    nullable: bool = False

    def check(self, value):
        """Return ``value`` converted to this parameter's type, or raise InvalidInputError (a
        ValueError) saying why."""
        kind = self.type
        if kind is None:
            if value is None and self.nullable:
                return None
            if isinstance(value, str):
                if value in (self.choices or ()):
                    return value
                raise InvalidInputError(f'{self.name}={value!r}: expected one of '
                                        f'{list(self.choices or ())} or a number')
            kind = self.number
        value = _converted(value, kind)
        if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
            raise InvalidInputError(f'{self.name}={value!r}: expected {kind.__name__}, '
                                    f'got {type(value).__name__}')
        if kind is float and not math.isfinite(value):
            raise InvalidInputError(f'{self.name}={value!r}: must be finite')
        if self.range is not None:
            low, high = self.range
            if not (low < value if self.open_low else low <= value) or value > high:
                bracket = '(' if self.open_low else '['
                raise InvalidInputError(f'{self.name}={value!r}: outside '
                                        f'{bracket}{low}, {high}]')
        if kind is str and self.choices and value not in self.choices:
            raise InvalidInputError(f'{self.name}={value!r}: expected one of '
                                    f'{list(self.choices)}')
        return value

    @property
    def constraint(self):
        """The accepted values in words, e.g. ``float in (0, 1e+12]``, ``'auto' or int >= 1``."""
        kind = self.type or self.number
        parts = [repr(c) for c in self.choices or ()] if self.type is not str else []
        if kind is str:
            parts.append(' | '.join(repr(c) for c in self.choices) if self.choices else 'str')
        elif kind is bool:
            parts.append('bool')
        elif self.range is not None:
            low, high = self.range
            low_op = '>' if self.open_low else '>='
            low_text, high_text = (f'{x:g}' if kind is float else str(x) for x in (low, high))
            if high in (INT_MAX, FLOAT_MAX):
                parts.append(f'{kind.__name__} {low_op} {low_text}')
            else:
                parts.append(f'{kind.__name__} in {"(" if self.open_low else "["}{low_text}, '
                             f'{high_text}]')
        else:
            parts.append(kind.__name__)
        if self.nullable:
            parts.append('None')
        return ' or '.join(parts)


def _converted(value, kind):
    """numpy scalars as Python ones; an int given for a float."""
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, np.integer):
        value = int(value)
    elif isinstance(value, np.floating):
        value = float(value)
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


def _number(name, default, description, low=0.0, *, open_low=False, high=FLOAT_MAX,
            group='solver'):
    return Param(name, default, float, description, range=(low, high), open_low=open_low,
                 group=group)


def _count(name, default, description, low=0, group='solver'):
    return Param(name, default, int, description, range=(low, INT_MAX), group=group)


def _auto_or_count(name, description, low=1):
    return Param(name, 'auto', None, description, range=(low, INT_MAX), choices=('auto',),
                 group='solver', number=int)


def _mode(name, default, choices, description, group='solver'):
    return Param(name, default, str, description, choices=choices, group=group)


SOLVER_PARAMS = (
    _number('gamma', 1e-3, 'Nuclear-norm weight on S#, relative: gamma * sqrt(F P) on '
            'unit-RMS tracks. The trade between fit and shape rank: raise it where noise '
            'should not be read as deformation, lower it to keep finer deformations.'),
    _number('smoothness', 1e-4, 'Temporal smoothness prior (lam/2)||D S||^2 on the world '
            'shapes (D: second differences over frames), relative to the roughness of the '
            'tracks; 0: off (motion that is not smooth from frame to frame, e.g. frames '
            'subsampled from a long recording). Cold solves, and resumed ones of sparse tracks '
            '(where the inextensible refinement does not apply); not from other given shapes.'),
    _number('lambda1', 1.0, 'Weight of the spatial self-expression error ||T_s - T_s C_s||^2 '
            "(the paper's 1); for studies of the Grassmann terms, which change little here "
            '(docs/decisions/0502).'),
    _number('lambda2', 1.0, 'Weight of the temporal self-expression error ||T_t - T_t C_t||^2 '
            "(the paper's 1); for studies of the Grassmann terms, as lambda1."),
    _auto_or_count('K_rot', "Rank used by the rotation step ('auto': chosen from the data); set "
                   'it where the number of deformation modes is known.'),
    _mode('rotations', 'auto', ('auto', 'dai', 'rigid'),
          "Rotation estimate in cold solves: 'dai' (Dai et al. 2014), 'rigid' (Tomasi-Kanade), "
          "or 'auto': Dai's unless the rigid rotations give shapes whose S# nuclear norm is "
          f"{100 * ROTATION_MARGIN:.0f} % lower. Set one to skip the check's two extra solves "
          "('rigid' for a nearly rigid object)."),
    _auto_or_count('K_s', "Number of spatial groups (trajectory subspaces); 'auto': from P. Set "
                   'it for an object of a known number of parts that move apart.'),
    _auto_or_count('K_t', "Number of contiguous temporal blocks (shape subspaces); 'auto': "
                   'from F. Set it for a sequence whose shapes change by phases.'),
    _auto_or_count('N_s', "Rank kept per spatial group by zeta; 'auto': from F. Set it where "
                   'the parts deform with more (or fewer) modes.'),
    _auto_or_count('N_t', "Rank kept per temporal block by zeta; 'auto': from the block "
                   'length. As N_s, over time.'),
    _mode('inextensible', 'auto', ('auto', 'always', 'never'),
          "After a cold solve, each frame's depths made inextensible (edge lengths from the "
          "longest image lengths): 'auto' on dense tracks (P >= "
          f'{INEXTENSIBLE_MIN_POINTS}) when that cuts the variation of the 3D edge lengths '
          f"below {INEXTENSIBLE_RATIO:g} of the solver's (held off in the rounds of projection "
          "'perspective'), 'always', or 'never' (the paper; "
          'a surface known to stretch). A solve given no warm start whose depths are kept '
          'then tries rotations registered to them, kept when its edge lengths vary less.'),
    _mode('relief', 'auto', ('auto', 'never'),
          "After a cold orthographic solve, each frame's depths scaled about their mean by the "
          'factor in 1-1.5 that makes the shapes most nearly one rigid shape (the low-rank '
          "solve flattens a turning face; a sheet keeps 1): 'auto' where the solve fits the "
          "tracks (not noisy ones), or 'never' (the solver's depths as they are). Not in the "
          'live windows or the perspective rounds, which scale their own '
          '(docs/decisions/0734).'),
    _mode('thinning', 'auto', ('auto', 'never'),
          "'auto': where a cluster of tracks is far denser than the rest of the surface "
          f'(P >= {THINNING_MIN_POINTS}), the shapes are solved on a thinned set and the '
          "dropped tracks filled in from their neighbours; 'never': every track is solved "
          '(a dense cluster whose own detail matters).'),
    _mode('projection', 'auto', PROJECTIONS,
          "How the tracks were imaged. 'orthographic': (scaled) orthographic projections, in "
          "pixels or any unit; 'perspective': normalised pinhole coordinates K^-1 [u, v, 1], "
          'solved by the projective-depth iteration around the whole chain (its rounds, depth '
          'sign and stopping rule: docs/decisions/0700, 0702), shapes in the camera frame '
          "projecting onto the tracks, each frame's mean depth 1; 'auto': perspective where "
          'camera intrinsics come with the tracks (reconstruct with K or --camera), '
          'orthographic otherwise.'),
    _mode('surface', 'auto', ('auto', 'any', 'sheet'),
          "What is reconstructed. 'any': the low-rank chain (Algorithm 1 and its stages); "
          "'sheet': a surface that bends without stretching (paper, a mat, a sheet), from "
          'its own structure instead: through a pinhole (projection perspective) Chhatkuli '
          "et al.'s maximum-depth heuristic on the normalised tracks (tens of seconds per "
          'sequence offline; docs/decisions/0709, 0440; live, each frame from the lengths '
          'the mapping rebuilds at every window, 0732); orthographic, local-isometry '
          'depths fitted frame by frame near the shape carried from the frame before '
          "(seconds; 0714, 0737). 'auto': "
          "a solve without a warm start of complete tracks (50 or more) is 'sheet' when, "
          'through a pinhole, the maximum-depth depths on 10 of its frames keep their edge '
          'lengths (0726; live, checked on the second window and as the sequence doubles) '
          'or, orthographic, the orthographic sheet depths on 20 frames x 200 tracks fit '
          "their edge sizes (0738; offline, up to 5,000 tracks), else 'any'. Complete "
          "tracks only for 'sheet'."),
    _mode('robust', 'auto', ('auto', 'never', 'cauchy'),
          "'cauchy': tracks whose residual against a low-rank approximation of all tracks, "
          "where their neighbours' agrees, or against the combination of their nearest tracks, "
          "is far above the others' (a tracker's drift or jumps) weighed down in the data "
          "term (Cauchy's tail beyond 3 and 8 robust deviations), left out of the rotations "
          'and their 3D taken from their neighbours, reported as downweighted_tracks; '
          "'auto': the same on 200 tracks or more where at least 2 % of them are weighed down, "
          "else plain least squares; 'never': plain least squares (docs/decisions/0801, 0805, "
          '0811, 0812, 0814, 0816).'),
    _number('rho', 1.2, 'Growth factor of the penalty beta per iteration: closer to 1 for a '
            'slower, more gradual schedule (more iterations).', 1.0, open_low=True),
    _number('beta0', 1e-3, 'Initial penalty beta (also of a resumed solve): lower lets the '
            'first iterations move further from the start.', open_low=True),
    _number('beta_max', 1e6, 'Largest penalty (>= beta0); the run stops when beta reaches it. '
            'Lower it for a faster, less converged solve (a call may cap it: fit(beta_max=)).',
            open_low=True),
    Param('random_state', 0, None, 'Seed for the k-means++ grouping and the rotation step; '
          'another seed (or None) to see how much a result owes to its random starts.',
          range=(0, INT_MAX), group='solver', number=int, nullable=True),
    # research switches: no default uses them
    Param('spatial', True, bool, 'Use the spatial Grassmann branch (C_s, xi_s, zeta_s); '
          'False: ablation.', group='research'),
    Param('temporal', True, bool, 'Use the temporal Grassmann branch (C_t, xi_t, zeta_t); '
          'False: ablation.', group='research'),
    _count('max_iter', 500, 'Cap on ADMM iterations (the default schedule beta0 -> beta_max '
           'stops after at most 115); for short test runs.', low=1, group='research'),
)

SOLVER_SPECS = {p.name: p for p in SOLVER_PARAMS}


def solver_defaults():
    """``{name: default}`` of the solver's parameters."""
    return {p.name: p.default for p in SOLVER_PARAMS}


def validate_solver(values):
    """``{name: value}`` of the solver's parameters checked against the schema and converted;
    raises InvalidInputError naming the parameter."""
    unknown = sorted(set(values) - set(SOLVER_SPECS))
    if unknown:
        raise InvalidInputError(f'unknown parameter {unknown[0]!r}')
    out = {name: SOLVER_SPECS[name].check(value) for name, value in values.items()}
    if out.get('beta_max', math.inf) < out.get('beta0', 0.0):
        raise InvalidInputError(f"beta_max ({out['beta_max']!r}) must be >= beta0")
    return out
