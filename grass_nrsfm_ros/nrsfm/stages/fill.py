"""Stage 'fill' (after 'thinning' dropped tracks): the dropped tracks' 3D points from their
solved neighbours (:func:`..density.fill_dropped`), ``S: (3F, P')`` -> ``(3F, P)``.

Report: ``reprojection_rms`` and ``reprojection_relative`` over every track.
"""
import numpy as np

from ..density import fill_dropped
from ..measurement import as_frames, centre, track_scale

NAME = 'fill'


def applies(keep):
    return keep is not None


def run(S, labels, W, keep, report):
    """``(S: (3F, P), labels: (P,))`` for all tracks of ``W: (2F, P)`` from the solved
    ``S: (3F, P')``, ``labels: (P',)`` of the tracks ``keep``."""
    S, labels = fill_dropped(S, labels, W, keep)
    Wc = centre(W)[0]
    residual = as_frames(S, 3)[:, :2, :].reshape(Wc.shape) - Wc
    report.reprojection_rms = float(np.sqrt(np.mean(residual ** 2)))
    report.reprojection_relative = report.reprojection_rms / track_scale(Wc)
    return S, labels
