"""Stage 'relief' (after a cold orthographic solve that fits its tracks, ``relief='auto'``):
each frame's depths scaled about their mean by the factor ``c`` among SCALES (from 1 up) whose
camera-frame shapes are most nearly one rigid shape (:func:`..rigidity.most_rigid`, each
frame divided by the norm of its x, y rows, which the factor leaves as they are). The low-rank
solve flattens a turning face's relief; its turns fix the relief as they would fix a rigid
body's. Where the residual only grows with ``c`` (the sheets and mocap bodies measured) ``c``
stays 1. Where the solve does not fit its tracks (relative reprojection residual above
MAX_FIT: noise, a pinhole's share of the tracks) the factor was measured to hurt, and the stage
does not run; nor where the solve fell back (docs/decisions/0734). Where robust weights took
tracks down, the factor is measured on the tracks they kept (docs/decisions/0817). The x, y
rows, hence the reprojection, are unchanged.

Speaks ``S: (3F, P)`` camera-frame shapes of :class:`~..problem.NRSfMResult`.
Report: ``relief`` (the factor), ``seconds['relief']``, a note where it is not 1.
A solve given a WarmStart, even an empty one (the live windows, the refill rounds), and the
rounds of projection 'perspective' (which scale their own depths) skip it.
"""
from dataclasses import replace
import time

import numpy as np

from ..measurement import as_frames, from_frames
from ..rigidity import most_rigid, SCALES

NAME = 'relief'
#: the factor is measured on at most this many tracks, evenly spaced
MAX_TRACKS = 2000
#: the largest relative reprojection residual of the solve (``report.reprojection_relative``)
#: it runs at: between the clean sequences' 0.0024-0.0115 and 1 % noise's 0.025
MAX_FIT = 0.0175


def applies(problem, params, fitted):
    """``fitted``: the report of the solve of the tracks as seen (before a masked problem's
    refill rounds, whose filled entries fit by construction)."""
    return (params['relief'] == 'auto' and not problem.given and fitted.fallback is None
            and fitted.reprojection_relative <= MAX_FIT)


def scaled_depths(S, factor):
    """``(3F, P)``: ``S: (3F, P)`` with each frame's depths (z rows) scaled by ``factor``
    about their mean."""
    X = as_frames(np.asarray(S, dtype=np.float64), 3).copy()
    mean = X[:, 2].mean(axis=1, keepdims=True)
    X[:, 2] = mean + factor * (X[:, 2] - mean)
    return from_frames(X)


def factor(S, scales=SCALES):
    """The factor among ``scales`` whose :func:`scaled_depths` of ``S: (3F, P)`` have the
    least rigid residual (x, y norm), measured on at most MAX_TRACKS of its tracks."""
    P = S.shape[1]
    S = S[:, np.linspace(0, P - 1, min(P, MAX_TRACKS)).astype(int)]
    return most_rigid(lambda c: scaled_depths(S, c), scales, norm='image')


def run(result):
    """``result`` with its depths scaled by :func:`factor` of the tracks its robust weights
    kept (``track_weights`` 1; every track where it has none) and the report's ``relief`` (and
    ``seconds['relief']``, added to the total)."""
    start = time.perf_counter()
    weights = result.track_weights
    c = factor(result.S if weights is None else result.S[:, weights >= 1.0])
    report = result.report
    report.stages.append(NAME)
    report.relief = c
    seconds = time.perf_counter() - start
    report.seconds = {**report.seconds, NAME: seconds,
                      'total': report.seconds.get('total', 0.0) + seconds}
    if c == 1.0:
        return result
    report.notes.append(f'relief: the depths scaled by {c:.3f}, the most nearly rigid '
                        'shapes (docs/decisions/0734)')
    return replace(result, S=scaled_depths(result.S, c))
