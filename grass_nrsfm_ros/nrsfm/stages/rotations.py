"""Stage 'rotations': the rotations ``R: (F, 3, 3)`` of a problem, given or estimated.

Given for every frame (``init.R`` with all frames known): used as they are. Otherwise estimated
from ``Wn: (2F, P)`` by Dai et al.'s method ('dai', and 'auto' before the rotation check) or
the rigid factorisation ('rigid'), then aligned to the given ones on the known frames. With
unseen entries (a masked problem) on :func:`core_tracks`: the tracks seen in every frame while
they are at least CORE_SHARE of all, else the completed tracks (docs/decisions/0432); tracks the
robust weights touched are left out (:func:`.robust.kept_tracks`, docs/decisions/0805).
Report: ``rotation_method`` ('given', 'dai' or 'rigid'), ``K_rot`` (Dai's rank or None).
"""
import numpy as np

from . import robust
from ..rotation import align_rotations, estimate_rotations, rigid_factorisation

NAME = 'rotations'
#: a masked problem's rotations come from its complete core while it holds this share of the
#: tracks (and at least CORE_MIN of them)
CORE_SHARE = 0.5
CORE_MIN = 20


def applies(problem):
    """Every solve has rotations."""
    return True


def method(problem, params):
    """'given', or the estimate asked for: the warm start's method, else the parameter."""
    if problem.init.R is not None and problem.known.all():
        return 'given'
    return problem.init.rotation_method or params['rotations']


def run(problem, params, report):
    """``R: (F, 3, 3)`` float64 for ``problem``; fills the report's section."""
    init, known = problem.init, problem.known
    asked = method(problem, params)
    if asked == 'given':
        report.rotation_method, report.K_rot = 'given', None
        return np.array(init.R, dtype=np.float64)
    Wn = problem.Wn[:, core_tracks(problem)]
    if asked == 'rigid':
        R, K = rigid_factorisation(Wn)[0], None
    else:
        est = estimate_rotations(Wn, K=params['K_rot'])
        R, K = np.array(est.R, dtype=np.float64), est.K
    report.rotation_method, report.K_rot = ('dai' if K is not None else 'rigid'), K
    if init.R is None:
        return R
    return align_rotations(R, np.asarray(init.R, dtype=np.float64), known)


def core_tracks(problem):
    """Columns of ``problem`` the rotations are estimated on: of the tracks the robust weights
    kept (:func:`.robust.kept_tracks`; all where none was weighed down), those seen in every
    frame while they are CORE_SHARE of all (and CORE_MIN), else all of them (completed)."""
    kept = robust.kept_tracks(problem)
    mask = problem.mask
    if mask is None:
        return slice(None) if kept is None else np.flatnonzero(kept)
    full = mask.all(axis=0) if kept is None else mask.all(axis=0) & kept
    core = np.flatnonzero(full)
    if core.size >= max(CORE_MIN, CORE_SHARE * mask.shape[1]):
        return core
    return slice(None) if kept is None else np.flatnonzero(kept)
