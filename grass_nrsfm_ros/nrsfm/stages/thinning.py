"""Stage 'thinning' (thinning='auto', dense tracks): solve on a thinned set where a cluster of
tracks is far denser than the rest of the surface (:func:`..density.thinned_tracks`), so that
the cluster does not outweigh the rest; the stage 'fill' puts the dropped tracks back.

Speaks ``W: (2F, P)``; returns ``keep: (P',)`` sorted track indices, or None (no cluster).
Report: ``thinned_points``, a note.
"""
from ..density import thinned_tracks
from ..schema import THINNING_MIN_POINTS

NAME = 'thinning'


def applies(problem, params):
    return params['thinning'] != 'never' and problem.P >= THINNING_MIN_POINTS


def run(problem, params, report):
    """``keep: (P',)`` or None."""
    keep = thinned_tracks(problem.W, params['random_state'])
    if keep is None:
        return None
    P_all = problem.P
    report.thinned_points = P_all - keep.size
    report.notes.append(f'thinned: {keep.size} of {P_all} tracks solved, the '
                        f'{report.thinned_points} in over-dense clusters filled in '
                        'from their neighbours')
    return keep
