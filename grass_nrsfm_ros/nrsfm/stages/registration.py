"""Stage 'registration' (after a solve given no warm start whose inextensible depths were
kept, rotations spread by more than REGISTRATION_MIN_SPREAD degrees):
the rotations registered to the refined shapes (:func:`..inextensible.register_rotations`),
the shape pass solved again with them, and the second result kept when its inextensible depths
are used too and its edge lengths vary less (on the refinement's check tracks).

Speaks ``S: (3F, P)``, ``R: (F, 3, 3)`` of :class:`~..problem.NRSfMResult` s.
Report: ``rotations_registered``, a note, ``seconds['rotation registration']``; the kept
result's report keeps the first's rotation fields and notes.

No switch (the parameter register_rotations until docs/decisions/0430): the second result is
kept only when it measures better. A solve given a WarmStart, even an empty one, skips it.
"""
from .refinement import check_tracks
from ..inextensible import length_variation, neighbour_edges, register_rotations
from ..rotation import rotation_spread
from ..schema import REGISTRATION_MIN_SPREAD

NAME = 'registration'


def applies(problem, params, result):
    return (not problem.given and result.report.inextensible
            and rotation_spread(result.R) > REGISTRATION_MIN_SPREAD)


def rotations(result):
    """``R: (F, 3, 3)`` registered to ``result``'s refined shapes."""
    return register_rotations(result.S, result.R)


def run(problem, params, first, second, seconds):
    """``first`` or ``second`` (the solve with the registered rotations), whichever the rule
    keeps, with the report merged; ``seconds``: the time the registration took."""
    check = check_tracks(problem.P, params['random_state'])
    edges = neighbour_edges(problem.W[:, check])
    before, after = (length_variation(r.S[:, check], *edges) for r in (first, second))
    kept = second.report.inextensible and after < before
    note = ('rotations registered to the refined shapes and solved again: edge-length '
            f'variation {before:.4f} -> {after:.4f} on {check.size} tracks, '
            f"{'kept' if kept else 'not kept'}")
    if not kept:
        report = first.report
        report.notes.append(note)
        report.stages, report.solves = second.report.stages, second.report.solves
        report.seconds['rotation registration'] = seconds
        report.seconds['total'] += seconds
        return first
    report, old = second.report, first.report
    report.notes = old.notes + [note] + report.notes
    report.rotation_method, report.K_rot = old.rotation_method, old.K_rot
    report.rotation_checked = old.rotation_checked
    report.rotations_registered = True
    report.seconds = dict(old.seconds, **{'rotation registration': seconds})
    report.seconds['total'] = old.seconds['total'] + seconds
    return second
