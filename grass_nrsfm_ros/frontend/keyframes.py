"""Keyframes and the measurement of tracks against them (OpenCV, no ROS).

:class:`Keyframe` holds the images of a frame tracks are anchored to (:func:`make_keyframe`).
:class:`KeyframeRefiner` measures, in a new frame, where each track's keyframe point is,
starting from a prediction, and how well its patch still matches:
``refine(grey, guess, anchors) -> (uv, zncc, ok)`` and the optional forward-backward distance.
It reads the tracks' anchors and writes nothing back: the tracker owns them.

Shapes: a frame ``grey (H, W)`` uint8; ``guess``, ``uv``: ``(P, 2)`` pixels; :class:`Anchors`
per track: its keyframe ``key (P,)``, its point there ``uv_ref (P, 2)``, its zero-mean
keyframe patch ``patches (P, n)`` (:func:`~.imaging.centred_patches`) and its failed checks
in a row ``misses (P,)``, beside ``keyframes`` (frame number -> :class:`Keyframe`).
"""
from dataclasses import dataclass
from functools import partial

import cv2
import numpy as np

from . import fields, grid, imaging

_MAX_REFINEMENT = 2.0              # px: prediction and its LK refinement disagreeing more: failed
_WARP_MARGIN = 8                   # px around a keyframe's tracks warped (plus the LK window)
_INVERSE_STEPS = 3                 # fixed-point steps inverting the field
_SMOOTH_ZNCC = 0.98                # a track checked below this leans on its neighbours' field


@dataclass(frozen=True, eq=False)
class Keyframe:
    """A frame tracks are anchored to: ``grey (H, W)``, its :func:`~.imaging.normalise` and
    that :func:`~.imaging.smoothed` (where the ZNCC check samples)."""

    grey: np.ndarray
    normalised: np.ndarray
    smoothed: np.ndarray


@dataclass(frozen=True, eq=False)
class Anchors:
    """What the tracks are measured against (see the module docstring for the shapes)."""

    keyframes: dict
    key: np.ndarray
    uv_ref: np.ndarray
    patches: np.ndarray
    misses: np.ndarray


def make_keyframe(grey, points, margin):
    """The :class:`Keyframe` of ``grey``, normalised only in the box ``margin`` pixels
    around ``points (N, 2)`` (where tracks will be measured; 128 elsewhere)."""
    normalised = np.full(grey.shape, 128, np.uint8)
    smoothed = normalised.copy()
    if len(points):
        x0, y0, x1, y1 = grid.box(points, grey.shape, margin)
        normalised[y0:y1, x0:x1] = imaging.normalise(grey[y0:y1, x0:x1])
        smoothed[y0:y1, x0:x1] = imaging.smoothed(normalised[y0:y1, x0:x1])
    return Keyframe(grey, normalised, smoothed)


class KeyframeRefiner:
    """Lucas-Kanade refinement of predicted tracks against their keyframes.

    ``step`` the tracks' grid step (the displacement fields' grid); ``lk_window`` and
    ``lk_levels`` the Lucas-Kanade settings; ``warp``: the frame is warped into each
    keyframe by the tracks' displacement field (else translation LK from the keyframe);
    ``refine_lk``: LK runs at all (else the guesses are only checked); ``predicted``: the
    guesses come from a flow, and a track LK moves more than 2 px from its guess fails;
    ``min_zncc`` the check the tracker applies (weak tracks lean on their neighbours up to
    it). Why: record 0600.
    """

    def __init__(self, step, lk_window, lk_levels, *, warp, refine_lk, predicted, min_zncc):
        self.step, self.lk_window = int(step), int(lk_window)
        self.warp, self.refine_lk, self.predicted = warp, refine_lk, predicted
        self.min_zncc = float(min_zncc)
        self._lk = partial(imaging.lucas_kanade, self.lk_window, lk_levels)

    def refine(self, grey, guess, anchors):
        """``(uv: (P, 2) float64, zncc: (P,), ok: (P,) bool)``: each keyframe's tracks
        refined against it, on the normalised frame (computed once, in the box around the
        guesses)."""
        uv = guess.astype(np.float64)
        zncc, ok = np.zeros(len(uv)), np.ones(len(uv), bool)
        if len(uv) == 0:
            return uv, zncc, ok
        x0, y0, x1, y1 = grid.box(guess, grey.shape, _WARP_MARGIN + self.lk_window)
        raw = grey[y0:y1, x0:x1]
        current = grid.Crop(imaging.normalise(raw), np.float32([x0, y0]), raw)
        keys = np.unique(anchors.key)
        for key in keys:            # (one keyframe, the usual case: views, no copies)
            rows = slice(None) if keys.size == 1 else np.flatnonzero(anchors.key == key)
            uv[rows], zncc[rows], ok[rows] = self._refine_keyframe(
                anchors.keyframes[key], current, anchors.uv_ref[rows], anchors.patches[rows],
                guess[rows], both_ways=bool((anchors.misses[rows] == 0).any()))
        return uv, zncc, ok & np.isfinite(uv[:, 0]) & np.isfinite(uv[:, 1])

    def forward_backward(self, grey, uv, anchors):
        """Distance ``(P,)`` between each track's keyframe point and its point tracked back
        from ``uv`` into its keyframe (LK on normalised images)."""
        points = uv.astype(np.float32)
        back = np.full(len(uv), np.inf)
        current = imaging.normalise(grey)
        for key in np.unique(anchors.key):
            rows = np.flatnonzero(anchors.key == key)
            moved, ok = self._lk(current, anchors.keyframes[key].normalised, points[rows],
                                 anchors.uv_ref[rows].copy())
            distance = np.linalg.norm(moved - anchors.uv_ref[rows], axis=1)
            back[rows] = np.where(ok, distance, np.inf)
        return back

    def _refine_keyframe(self, keyframe, current, ref, patches, guess, both_ways=True):
        """Tracks of one keyframe at ``ref (P, 2)`` in it, with their reference
        ``patches (P, n)``: the frame ``current`` (a :class:`grid.Crop`) is warped into the
        keyframe by the displacement field of the ``guess`` es (where the method warps)
        and normalised, then Lucas-Kanade from the normalised keyframe corrects what the
        field missed; the ZNCC check is taken in the warped frame; a track whose ZNCC is
        under ``_SMOOTH_ZNCC`` is pulled toward its passing neighbours' field (fully at
        ``min_zncc``). Returns ``(uv (P, 2), zncc (P,), ok (P,))``."""
        if not self.warp:
            return self._refine_unwarped(keyframe, current, ref, patches, guess)
        shape = keyframe.normalised.shape
        x0, y0, x1, y1 = grid.box(ref, shape, _WARP_MARGIN + self.lk_window)
        origin = np.float32([x0, y0])
        local = ref - origin
        splat = fields.splatting(local, (y1 - y0, x1 - x0), self.step)
        field = fields.displacement_field(local, guess - ref, (y1 - y0, x1 - x0), self.step, splat)
        warped = imaging.normalise(imaging.warp(current.raw, current.origin, field, origin))
        where, ok = local, np.ones(len(ref), bool)
        if self.refine_lk:
            where, ok = self._lk(
                np.ascontiguousarray(keyframe.normalised[y0:y1, x0:x1]), warped, local,
                local.copy())
            if self.predicted:
                ok &= np.linalg.norm(where - local, axis=1) <= _MAX_REFINEMENT
        uv = where + origin + imaging.sample(field, where)
        zncc = imaging.patch_zncc(patches, imaging.smoothed(warped), where)
        if self.refine_lk and both_ways:
            back, both = self._refine_in_frame(keyframe, current, ref, uv.astype(np.float32))
            uv = np.where(both[:, None], 0.5 * (uv + back), uv)
        if self.refine_lk and self.min_zncc < _SMOOTH_ZNCC:
            weight = np.clip((_SMOOTH_ZNCC - zncc) / (_SMOOTH_ZNCC - self.min_zncc), 0.0, 1.0)
            uv = uv + weight[:, None] * (fields.neighbour_moves(
                splat, local, uv - ref, ok & (zncc >= self.min_zncc)) - (uv - ref))
        return uv, zncc, ok

    def _refine_unwarped(self, keyframe, current, ref, patches, guess):
        """:meth:`_refine_keyframe` without the warp: translation LK from the normalised
        keyframe to the normalised frame (padded to the keyframe's size)."""
        shape = keyframe.normalised.shape
        image = cv2.copyMakeBorder(current.image, int(current.origin[1]), max(
            shape[0] - int(current.origin[1]) - current.image.shape[0], 0), int(
            current.origin[0]), max(shape[1] - int(current.origin[0])
                                    - current.image.shape[1], 0), cv2.BORDER_REPLICATE)
        uv, ok = guess, np.ones(len(ref), bool)
        if self.refine_lk:
            uv, ok = self._lk(keyframe.normalised, image, ref, guess)
        if self.refine_lk and self.predicted:
            ok &= np.linalg.norm(uv - guess, axis=1) <= _MAX_REFINEMENT
        return uv, imaging.patch_zncc(patches, imaging.smoothed(image), uv), ok

    def _refine_in_frame(self, keyframe, current, ref, guess):
        """The same tracks measured the other way round: the normalised keyframe warped
        into the frame's box by the field from the ``guess`` es back to ``ref``, then LK
        from it to the normalised frame ``current``; returns ``(uv: (P, 2), ok: (P,))``.
        The two ways err in opposite directions where the view is foreshortened or
        stretched against the keyframe, so the tracker takes their mean."""
        current = grid.sub_crop(current, guess, _WARP_MARGIN + self.lk_window)
        local = guess - current.origin
        field = fields.displacement_field(local, ref - guess, current.image.shape, self.step)
        warped = imaging.normalise(imaging.warp(keyframe.grey, np.float32([0, 0]), field,
                                                current.origin))
        source = local
        for _ in range(_INVERSE_STEPS):       # where the warped keyframe shows each ``ref``
            source = ref - current.origin - imaging.sample(field, source)
        moved, ok = self._lk(warped, current.image, source, local.copy())
        ok &= np.linalg.norm(moved - local, axis=1) <= _MAX_REFINEMENT
        return moved + current.origin, ok
