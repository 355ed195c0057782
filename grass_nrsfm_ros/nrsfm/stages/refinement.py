"""Stage 'refinement' (cold and resumed solves of dense tracks): each frame's depths made
inextensible (:func:`..inextensible.refine_depth`: edge lengths from the longest image
lengths, signs re-estimated from the world shapes), kept when that cuts the variation of the
3D edge lengths below INEXTENSIBLE_RATIO of the solver's ('auto') or always ('always').

Speaks ``S: (3F, P)`` camera frame, ``W: (2F, P)``, ``R: (F, 3, 3)``.
Report: ``inextensible``, a note with the edge-length variations.
"""
from dataclasses import dataclass, field, replace

import numpy as np

from ..inextensible import DepthIntegration, neighbour_edges, refine_depth
from ..schema import INEXTENSIBLE_MIN_POINTS, INEXTENSIBLE_RATIO

NAME = 'refinement'
#: tracks (a fixed random subset) the 'auto' decisions are made on
CHECK_POINTS = 2000


@dataclass(frozen=True)
class Check:
    """The edge-length variation of the solver's shapes (``before``) and of their inextensible
    depths (``after``) on ``tracks`` tracks, their ``ratio``, and whether the depths are
    ``used``; ``integration``: the check's :class:`DepthIntegration` when it was made on every
    track (the refinement then reuses it), else None."""
    before: float
    after: float
    ratio: float
    tracks: int
    used: bool
    integration: DepthIntegration = field(default=None, repr=False, compare=False)


def applies(problem, params):
    """Cold and resumed solves (a window warm-started with shapes keeps its carried depths),
    dense tracks unless 'always'."""
    mode = params['inextensible']
    if mode == 'never' or (problem.warm and not problem.init.resumed):
        return False
    return mode == 'always' or problem.P >= INEXTENSIBLE_MIN_POINTS


def check_tracks(P, random_state):
    """Indices ``(P',)`` of the tracks (all, or a fixed random CHECK_POINTS of them) on which
    the inextensible decisions are made."""
    if P <= CHECK_POINTS:
        return np.arange(P)
    rng = np.random.default_rng(random_state)
    return np.sort(rng.choice(P, CHECK_POINTS, replace=False))


def check(S, W, params):
    """The :class:`Check` of ``S: (3F, P)`` on the tracks ``W: (2F, P)`` under 'auto'; None
    under 'always' (nothing to decide: :func:`run` reports its own variations)."""
    if params['inextensible'] == 'always':
        return None
    idx = check_tracks(W.shape[1], params['random_state'])
    if idx.size == W.shape[1]:
        integration = DepthIntegration(S, neighbour_edges(W))
        return _check_of(integration.refine()[1], idx.size, integration)
    _, info = refine_depth(S[:, idx], neighbour_edges(W[:, idx]))
    return _check_of(info, idx.size)


def _check_of(info, tracks, integration=None):
    """The :class:`Check` of a :func:`refine_depth` ``info``, used when its ratio is below
    INEXTENSIBLE_RATIO."""
    before, after = info['length_variation_before'], info['length_variation_after']
    ratio = after / before if before > 0 else 1.0
    return Check(before, after, ratio, tracks, ratio < INEXTENSIBLE_RATIO, integration)


def run(S, R, W, params, result, report):
    """``S: (3F, P)`` with inextensible depths when the :class:`Check` ``result`` says so
    (always when None, 'always')."""
    refined = None
    if result is None:
        refined, info = refine_depth(S, neighbour_edges(W), R=R)
        result = replace(_check_of(info, W.shape[1]), used=True)
    c = result
    report.inextensible = c.used
    report.notes.append(
        f"inextensible depths {'used' if c.used else 'not used'} ({params['inextensible']}): "
        f'edge-length variation {c.before:.4f} -> {c.after:.4f} on {c.tracks} tracks (ratio '
        f'{c.ratio:.2f}, threshold {INEXTENSIBLE_RATIO:g})')
    if not c.used:
        return S
    if refined is not None:
        return refined
    if c.integration is not None:
        return refine_depth(S, (c.integration.i, c.integration.j), R=R,
                            integration=c.integration)[0]
    return refine_depth(S, neighbour_edges(W), R=R)[0]
