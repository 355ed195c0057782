"""Stage 'rotation check' (rotations='auto', no rotations given): Dai's rotations or the rigid
factorisation's, whichever lets a plain solve reach lower-rank shapes.

Each candidate ``R: (F, 3, 3)`` is scored by the nuclear norm of the world-frame ``S#: (F, 3P')``
that a plain solve (no Grassmann branches, no refinement) reaches on at most CHECK_POINTS of
the tracks (a fixed random subset), Dai et al.'s own criterion; the rigid rotations are taken
when their score is ROTATION_MARGIN (relatively) lower. Two ADMM solves.
Report: ``rotation_checked``, ``rotation_method``, ``K_rot``, a note with both scores.
"""
import numpy as np

from . import rotations
from ..measurement import as_frames
from ..problem import Problem, SolverReport, WarmStart
from ..rotation import rigid_factorisation
from ..schema import ROTATION_MARGIN

NAME = 'rotation check'
#: tracks (a fixed random subset) the candidates are scored on
CHECK_POINTS = 500
#: the parameters of the scoring solves
CHECK_PARAMS = {'rotations': 'dai', 'spatial': False, 'temporal': False,
                'inextensible': 'never'}


def applies(problem, params):
    """'auto' asked (by the warm start or the parameter), no rotations given."""
    return rotations.method(problem, params) == 'auto' and problem.init.R is None


def score(problem, R, params, report, solve_shapes, name):
    """Nuclear norm of the world-frame S# a plain solve with ``R: (F, 3, 3)`` reaches on the
    check's subset of ``problem.Wn``; its ADMM solves are added to ``report.solves``."""
    F, P = R.shape[0], problem.P
    rng = np.random.default_rng(params['random_state'])
    idx = np.sort(rng.choice(P, CHECK_POINTS, replace=False)) \
        if P > CHECK_POINTS else np.arange(P)
    if problem.weights is None:
        subset = Problem.from_tracks(problem.Wn[:, idx], WarmStart(R=R))
    else:                                       # the subset's weights and completed tracks
        subset = problem.tracks(idx).with_rotations(R)
    sub_report = SolverReport()
    result = solve_shapes(subset, np.array(R, dtype=np.float64), {**params, **CHECK_PARAMS},
                          sub_report, reason=f'rotation check: {name}')
    report.solves += sub_report.solves
    world = np.matmul(R.transpose(0, 2, 1), as_frames(result.S, 3))
    return float(np.linalg.svd(world.reshape(F, -1), compute_uv=False).sum())


def run(problem, R, params, report, solve_shapes):
    """The checked rotations: ``R: (F, 3, 3)`` (Dai's) or the rigid factorisation's."""
    R_rigid = rigid_factorisation(problem.Wn[:, rotations.core_tracks(problem)])[0]
    dai, rigid = (score(problem, cand, params, report, solve_shapes, name)
                  for cand, name in ((R, 'dai'), (R_rigid, 'rigid')))
    use_rigid = rigid < (1.0 - ROTATION_MARGIN) * dai
    report.notes.append(f"rotations: {'rigid' if use_rigid else 'dai'} (S# nuclear norm with "
                        f"Dai's {dai:.4g}, with rigid {rigid:.4g})")
    report.rotation_checked = True
    if not use_rigid:
        return R
    report.rotation_method, report.K_rot = 'rigid', None
    return R_rigid
