"""Stage 'surface' (``surface='auto'``, cold perspective solves of complete tracks): whether the
normalised tracks are a sheet that bends without stretching. The maximum-depth heuristic
(:class:`..max_depth.MaxDepthNRSfM`) runs on CHECK_FRAMES frames spread over the sequence; its
depths keep the lengths of their neighbour edges (:func:`..inextensible.length_variation`
below SHEET_VARIATION) where the surface does not stretch, and cannot where it does (a face's
expressions, a waving cloth that stretches). A sheet is then reconstructed by the heuristic,
anything else by the low-rank chain (docs/decisions/0726).

Speaks ``W: (2F, P)`` normalised tracks. Report: stage ``surface``, a note with the variation
and the decision.
"""
from dataclasses import dataclass, field

import numpy as np

from ..inextensible import length_variation
from ..max_depth import MaxDepthNRSfM
from ..measurement import frame_rows, spread_frames

NAME = 'surface'
#: frames (spread over the sequence) the heuristic runs on for the decision
CHECK_FRAMES = 10
#: a sheet: the check's edge lengths vary (temporal std / mean, mean over edges) less than this
SHEET_VARIATION = 0.025
#: fewer tracks than this: no decision (the low-rank chain)
MIN_POINTS = 50


@dataclass(frozen=True)
class Check:
    """The edge-length ``variation`` of the heuristic's depths on ``frames`` x ``tracks``
    (its anchors), and whether the tracks are taken for a ``sheet``; ``fitted``: the
    heuristic's result when the check ran on every frame (the sheet's reconstruction then),
    else None."""
    variation: float
    frames: int
    tracks: int
    sheet: bool
    fitted: object = field(default=None, repr=False, compare=False)


def applies(params, init, visible, W):
    """``surface='auto'`` under ``projection='perspective'``, no warm start, complete tracks
    ``W: (2F, P)`` with P >= MIN_POINTS."""
    return (params['surface'] == 'auto' and params['projection'] == 'perspective'
            and init is None and (visible is None or bool(np.all(visible)))
            and W.shape[1] >= MIN_POINTS and bool(np.isfinite(W).all()))


def check(W):
    """The :class:`Check` of the normalised tracks ``W: (2F, P)``."""
    F = W.shape[0] // 2
    keys = spread_frames(F, CHECK_FRAMES)
    result = MaxDepthNRSfM().fit(W[frame_rows(keys, 2)])
    variation = length_variation(result.S[:, result.anchors], *result.edges)
    return Check(variation, int(keys.size), int(result.anchors.size),
                 variation < SHEET_VARIATION, result if keys.size == F else None)


def note(c):
    """The report's line for the :class:`Check` ``c``."""
    return (f"surface 'auto': {'a sheet (maximum depth)' if c.sheet else 'not a sheet'}: "
            f'edge lengths of the maximum-depth depths on {c.frames} frames x {c.tracks} tracks '
            f'vary {c.variation:.4f} (threshold {SHEET_VARIATION:g})')
