"""Stage 'surface' (``surface='auto'``, cold solves of complete tracks): whether the tracks are a
sheet that bends without stretching. A sheet is then reconstructed by a sheet model, anything
else by the low-rank chain.

* Through a pinhole (normalised tracks): the maximum-depth heuristic
  (:class:`..max_depth.MaxDepthNRSfM`) runs on CHECK_FRAMES frames spread over the sequence; its
  depths keep the lengths of their neighbour edges (:func:`..inextensible.length_variation`
  below SHEET_VARIATION) where the surface does not stretch, and cannot where it does (a face's
  expressions, a waving cloth that stretches) (docs/decisions/0726).
* Orthographic: the orthographic sheet model (:class:`..sheet_transport.TransportSheetNRSfM`)
  runs on at most CHECK_TRACKS tracks (spread over their order) of ORTHOGRAPHIC_CHECK_FRAMES
  frames; a sheet where its depths fit their edge sizes (relative isometry residual below
  SHEET_RESIDUAL); no decision above ORTHOGRAPHIC_MAX_POINTS tracks (docs/decisions/0738).

Speaks ``W: (2F, P)`` tracks. Report: stage ``surface``, a note with the measure and the
decision.
"""
from dataclasses import dataclass, field

import numpy as np

from ..inextensible import length_variation
from ..max_depth import MaxDepthNRSfM
from ..measurement import frame_rows, spread_frames
from ..sheet_transport import TransportSheetNRSfM

NAME = 'surface'
#: frames (spread over the sequence) the heuristic runs on for the decision
CHECK_FRAMES = 10
#: a sheet: the check's edge lengths vary (temporal std / mean, mean over edges) less than this
SHEET_VARIATION = 0.025
#: fewer tracks than this: no decision (the low-rank chain)
MIN_POINTS = 50
#: orthographic: the sheet model's tracks and frames for the decision
CHECK_TRACKS = 200
ORTHOGRAPHIC_CHECK_FRAMES = 20
#: orthographic: a sheet when the sheet model's isometry residual over its squared edge sizes
#: is below this
SHEET_RESIDUAL = 0.015
#: orthographic: no decision above this many tracks (the sheet model's cost grows faster than
#: the chain's: 30 x 4,000 in 19 s, 30 x 8,000 in 73 s)
ORTHOGRAPHIC_MAX_POINTS = 5000


@dataclass(frozen=True)
class Check:
    """The sheet measure ``value`` on ``frames`` x ``tracks`` (through a pinhole the edge-length
    variation of the maximum-depth depths on its anchors; orthographic the sheet model's
    relative isometry residual), and whether the tracks are taken for a ``sheet``;
    ``fitted``: the sheet model's result when the check ran on every frame (and,
    orthographic, every track): the sheet's reconstruction then; else None."""
    value: float
    frames: int
    tracks: int
    sheet: bool
    fitted: object = field(default=None, repr=False, compare=False)
    projection: str = 'perspective'


def applies(params, init, visible, W):
    """``surface='auto'``, no warm start, complete numeric tracks ``W: (2F, P)`` with P >=
    MIN_POINTS (and, orthographic, P <= ORTHOGRAPHIC_MAX_POINTS). Malformed tracks are not
    checked: the solve that follows says what is wrong with them."""
    W = np.asarray(W)
    most = np.inf if params['projection'] == 'perspective' else ORTHOGRAPHIC_MAX_POINTS
    return (params['surface'] == 'auto' and init is None
            and W.ndim == 2 and W.dtype.kind in 'fiu' and W.shape[0] % 2 == 0
            and (visible is None or bool(np.all(visible)))
            and MIN_POINTS <= W.shape[1] <= most and bool(np.isfinite(W).all()))


def check(W):
    """The :class:`Check` of the normalised tracks ``W: (2F, P)``."""
    F = W.shape[0] // 2
    keys = spread_frames(F, CHECK_FRAMES)
    result = MaxDepthNRSfM().fit(W[frame_rows(keys, 2)])
    variation = length_variation(result.S[:, result.anchors], *result.edges)
    return Check(variation, int(keys.size), int(result.anchors.size),
                 variation < SHEET_VARIATION, result if keys.size == F else None)


def check_orthographic(W):
    """The :class:`Check` of the orthographic tracks ``W: (2F, P)``."""
    F, P = W.shape[0] // 2, W.shape[1]
    keys = spread_frames(F, ORTHOGRAPHIC_CHECK_FRAMES)
    tracks = spread_frames(P, CHECK_TRACKS)              # evenly over the tracks' order
    whole = keys.size == F and tracks.size == P
    result = TransportSheetNRSfM().fit(W if whole else W[frame_rows(keys, 2)][:, tracks])
    residual = result.info['relative_residual']
    return Check(residual, int(keys.size), int(tracks.size), residual < SHEET_RESIDUAL,
                 result if whole else None, projection='orthographic')


def note(c):
    """The report's line for the :class:`Check` ``c``."""
    if c.projection == 'orthographic':
        return (f"surface 'auto': {'a sheet (local isometry)' if c.sheet else 'not a sheet'}: "
                f'the sheet model on {c.frames} frames x {c.tracks} tracks fits its edge sizes '
                f'to a relative residual {c.value:.4f} (threshold {SHEET_RESIDUAL:g})')
    return (f"surface 'auto': {'a sheet (maximum depth)' if c.sheet else 'not a sheet'}: "
            f'edge lengths of the maximum-depth depths on {c.frames} frames x {c.tracks} tracks '
            f'vary {c.value:.4f} (threshold {SHEET_VARIATION:g})')
