"""The mapping's sheet models: ``SheetMapping.update(window, first) -> SheetModel or None``.

It owns whether a sequence's pinhole frames are taken for a sheet that bends without
stretching, and the newest :class:`~grass_nrsfm_ros.nrsfm.sheet_model.SheetModel` of that
sequence (docs/decisions/0732). The :class:`~grass_nrsfm_ros.mapper.Mapper` hands it each
solved window and gives the model out with the window's Update. Pure Python and numpy: no ROS.

Shapes: a closed :class:`~grass_nrsfm_ros.windowing.Window`'s frames carry ``uv: (P, 2)``
normalised pinhole points (``frame.pinhole``); the model is fitted on ``W: (2F, P)`` of the
SHEET_FRAMES frames chosen, on the tracks all of them see.
"""
from dataclasses import dataclass

import numpy as np

from grass_nrsfm_ros.nrsfm.measurement import spread_frames
from grass_nrsfm_ros.nrsfm.sheet_model import fit_sheet_model
from grass_nrsfm_ros.nrsfm.stages import surface as surface_stage
from grass_nrsfm_ros.windowing import ids_in_every, window_matrix

#: frames (spread over a window's context and frames) a sheet model's lengths come from
SHEET_FRAMES = 10


@dataclass
class SequenceSheet:
    """What is known of one sequence: its frames so far, those at the last surface check,
    whether it is taken for a sheet, and its newest model (None: none yet)."""

    sequence: int
    frames: int = 0
    checked_at: int = 0
    is_sheet: bool = False
    model: object = None


class SheetMapping:
    """Sheet models of the pinhole sequences the mapping solves. ``surface`` (the solver's):
    'sheet' takes every pinhole sequence for a sheet; 'auto' where the stage ``surface`` does
    (checked at a sequence's second window, then whenever its frames have doubled since the
    last check, until it says sheet); 'any' never."""

    def __init__(self, surface='auto'):
        self.surface = surface
        self.state = None               # the SequenceSheet of the newest sequence

    def reset(self):
        """Forget the sequence (a new one starts)."""
        self.state = None

    def update(self, window, first):
        """The SheetModel of ``window``'s sequence after this window: None unless its frames
        are pinhole and the sequence is taken for a sheet. Not built at a sequence's first
        window (``first``: also any started without context), whose model must not wait for
        the LP: the previous one then. Built anew at each later window by
        :func:`~grass_nrsfm_ros.nrsfm.sheet_model.fit_sheet_model` on SHEET_FRAMES frames
        spread over the window's context and frames, on the tracks all of them see; the
        previous model where those are too few or the fit fails."""
        if self.surface == 'any' or not window.frames[-1].pinhole:
            return None
        if self.state is None or self.state.sequence != window.sequence:
            self.state = SequenceSheet(window.sequence, is_sheet=self.surface == 'sheet')
        state = self.state
        state.frames += len(window.fresh)
        if first or (not state.is_sheet and state.frames < 2 * state.checked_at):
            return state.model
        frames = window.context + window.frames
        chosen = [frames[k] for k in spread_frames(len(frames), SHEET_FRAMES)]
        ids = ids_in_every(chosen)
        if ids.size < surface_stage.MIN_POINTS:
            return state.model
        W = window_matrix(chosen, ids)
        stamps = np.array([f.stamp_ns for f in chosen], dtype=np.int64)
        try:
            fitted = None
            if not state.is_sheet:
                check = surface_stage.check(W)
                state.checked_at, state.is_sheet = state.frames, check.sheet
                fitted = check.fitted
            if state.is_sheet:
                state.model = fit_sheet_model(W, ids, stamps, fitted)
        except (ValueError, RuntimeError):       # degenerate frames (LinAlgError), the LP failing
            pass
        return state.model
