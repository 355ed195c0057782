"""The estimator: :class:`GrassmannNRSfM`, Algorithm 1 (:mod:`.admm`) in its chain of stages.

``GrassmannNRSfM(**params).fit(W, init=None, progress=None, beta_max=None) -> NRSfMResult`` with
``W: (2F, P)`` tracks; ``NRSfMResult.S: (3F, P)`` camera-frame shapes, ``R: (F, 3, 3)``,
``translation: (2F, 1)``, ``groups: (P,)`` spatial labels, ``report: SolverReport``.

The chain (:meth:`GrassmannNRSfM.fit`): (robust track weights ->) rotations -> rotation check
-> the shape pass (:func:`shape_pass`: thinning -> ADMM -> refinement -> fill) -> registration
(the shape pass again with registered rotations) -> relief (a cold solve's depths scaled to the
most nearly rigid shapes). The parameters are declared in
:mod:`.schema`; each ADMM solve gets its own settings (:mod:`.config`), the validated
parameters are never changed.
With ``projection='perspective'`` ``W`` holds normalised pinhole coordinates and the whole
chain runs inside the projective-depth iteration (:mod:`.perspective`); ``S`` is then in the
camera frame, projecting onto ``W``, each frame's mean depth 1. Before it, under
``surface='auto'``, the stage 'surface' (:mod:`.stages.surface`) may find the tracks a sheet
that bends without stretching, reconstructed then by :mod:`.max_depth` instead.
"""
from dataclasses import replace
import time

import numpy as np
from threadpoolctl import ThreadpoolController

from . import config
from .admm import AdmmRun, AdmmState, run, Timer
from .max_depth import MaxDepthNRSfM, TOL as TOL_SHEET
from .measurement import as_frames, from_frames, InvalidInputError
from .perspective import PerspectiveNRSfM
from .problem import initial_shapes, NRSfMResult, Problem, SolverReport, WarmStart
from .schema import SOLVER_PARAMS, SOLVER_SPECS, validate_solver
from .sheet_transport import TransportSheetNRSfM
from .stages import (fill, refinement, registration, relief, robust, rotation_check,
                     rotations, surface, thinning)

#: a masked problem's solve is followed by this many refill rounds (docs/decisions/0802)
REFILL_ROUNDS = 1
REFILL = 'refill'
#: BLAS threads inside fit: the rotation step, the initialisation and the iterations make
#: thousands of small BLAS calls, faster on one thread, and the thread count changes rounding
BLAS_THREADS = 1
_blas = []      # the ThreadpoolController, built at the first one_blas_thread()


def one_blas_thread():
    """Context manager: BLAS on BLAS_THREADS threads inside it. The controller (the loaded
    BLAS libraries, found by reading the process's memory map: 3 ms a call, 4 % of a resumed
    window's CPU on shark) is built once, at the first call, once numpy and scipy are loaded."""
    if not _blas:
        _blas.append(ThreadpoolController())
    return _blas[0].limit(limits=BLAS_THREADS, user_api='blas')


class GrassmannNRSfM:
    """Dense NRSfM on the Grassmannian (Kumar et al. CVPR 2018, Algorithm 1).

    Keyword parameters are those of :data:`.schema.SOLVER_PARAMS`; they are stored unchanged
    by ``__init__`` and validated by :meth:`fit`.
    """

    parameter_specs = SOLVER_SPECS

    def __init__(self, **params):
        unknown = sorted(set(params) - set(SOLVER_SPECS))
        if unknown:
            raise TypeError(f'GrassmannNRSfM got an unexpected keyword argument {unknown[0]!r}')
        for spec in SOLVER_PARAMS:
            setattr(self, spec.name, params.get(spec.name, spec.default))

    # scikit-learn style introspection -------------------------------------------------------
    def get_params(self, deep=True):
        return {spec.name: getattr(self, spec.name) for spec in SOLVER_PARAMS}

    def set_params(self, **params):
        for name, value in params.items():
            if name not in SOLVER_SPECS:
                raise InvalidInputError(f'unknown parameter {name!r}')
            setattr(self, name, value)
        return self

    def __repr__(self):
        args = ', '.join(f'{k}={v!r}' for k, v in self.get_params().items())
        return f'{type(self).__name__}({args})'

    # the chain ---------------------------------------------------------------------------------
    def fit(self, W, init=None, progress=None, beta_max=None, visible=None, filled=None,
            refill_rounds=None):
        """Reconstruct ``W: (2F, P)``, NaN where a track is not seen (and ``visible: (F, P)``
        bool, optional, False where not seen): every track in every frame, the unseen entries
        filled by the low-rank model (:mod:`.missing`), or taken from ``filled: (2F, P)``, a
        completion already made (:func:`.missing.fill_unseen`). ``init``: optional
        :class:`WarmStart`; ``progress``:
        optional ``callback(iteration, report)`` called after every ADMM iteration;
        ``beta_max``: this call's cap on the penalty (None: the ``beta_max`` parameter), for
        every ADMM solve of the fit. The caller owns the schedule of a window: a sliding
        window that resumes an overlapping solution (``init.resumed``), or cannot resume the
        one before it, passes its cap here (10, docs/decisions/0408, 0425); ``init.resumed``
        alone starts the penalty at beta0 but does not cap it. ``refill_rounds``: this call's
        refill rounds of a masked problem (None: REFILL_ROUNDS; the live windows pass 0,
        docs/decisions/0802).

        The chain: rotations -> rotation check -> shape pass (thinning -> ADMM -> refinement
        -> fill) -> registration (the shape pass again with registered rotations); with
        ``robust`` the weighed-down tracks' 3D then from their kept neighbours
        (:func:`.stages.robust.refit`); the refill rounds of a masked problem; last, on a cold
        solve, the relief (:mod:`.stages.relief`)."""
        values = self.get_params()
        if beta_max is not None:
            values['beta_max'] = beta_max
        params = validate_solver(values)
        if params['surface'] == 'sheet':
            return self._sheet(W, params, visible)
        pinhole = params['projection'] == 'perspective'
        if pinhole and visible is not None and not np.all(visible):
            raise InvalidInputError("projection 'perspective' takes complete tracks; "
                                    'visible marks some entries unseen')
        if surface.applies(params, init, visible, W):
            return self._surface_decided(np.asarray(W, dtype=np.float64), params, progress,
                                         beta_max)
        if pinhole:
            return self._perspective(W, init, progress, beta_max)
        with one_blas_thread():
            start, timer = time.perf_counter(), Timer()
            problem = Problem.from_tracks(W, init, visible, params['random_state'], filled)
            report = SolverReport()
            track_weights = None
            if robust.applies(problem, params):
                problem, track_weights = robust.run(problem, params, report)
            if problem.completion is not None:
                report.notes.append(
                    f'{100 * (1 - problem.mask.mean()):.1f} % of the entries not seen: '
                    f'completed ({problem.completion}) for the rotations and the '
                    'start, left out of the data term')
            t = time.perf_counter()
            report.stages.append(rotations.NAME)
            R = rotations.run(problem, params, report)
            if rotation_check.applies(problem, params):
                report.stages.append(rotation_check.NAME)
                R = rotation_check.run(problem, R, params, report, shape_pass)
            timer.add('rotation', t)
            result = shape_pass(problem, R, params, report, timer, progress)
            report.seconds = dict(timer.seconds, total=time.perf_counter() - start)
            if registration.applies(problem, params, result):
                result = self._registered(problem, params, result, progress)
            if track_weights is not None:
                result.report.downweighted_tracks = report.downweighted_tracks
                result = replace(result, track_weights=track_weights,
                                 S=robust.refit(result.S, problem.W, track_weights,
                                                result.report))
        fitted = result.report     # the fit to the tracks seen, before any refill
        rounds = REFILL_ROUNDS if refill_rounds is None else int(refill_rounds)
        if problem.mask is not None and rounds > 0:
            result = self._refilled(problem, result, progress, beta_max, rounds)
        if relief.applies(problem, params, fitted):
            with one_blas_thread():
                result = relief.run(result)
        return result

    def _refilled(self, problem, first, progress, beta_max, rounds):
        """The stage 'refill' of a masked problem: ``rounds`` times, the unseen entries
        replaced by the solve's reprojection ``R S + t`` and the tracks solved again as complete
        ones, resumed from its rotations and shapes (docs/decisions/0802). The report: the
        first solve's mask, completion and rotations (method, Dai's rank, check), its stages,
        notes and solves then the last round's; the robust weights (``robust`` asked) are the
        last round's, taken on its refilled tracks."""
        seen, result = np.repeat(problem.mask, 2, axis=0), first
        for _ in range(rounds):
            again = np.where(seen, problem.W, reprojection(result))
            start = WarmStart(R=result.R, S=result.S, resumed=True)
            result = self.fit(again, init=start, progress=progress, beta_max=beta_max)
        report, base = result.report, first.report
        report.seconds = {k: base.seconds.get(k, 0.0) + report.seconds.get(k, 0.0)
                          for k in {**base.seconds, **report.seconds}}
        report.stages = base.stages + [REFILL] * rounds + report.stages
        report.solves = base.solves + report.solves
        report.notes = base.notes + report.notes
        report.observed_fraction, report.completion = base.observed_fraction, base.completion
        report.rotation_method, report.K_rot = base.rotation_method, base.K_rot
        report.rotation_checked = base.rotation_checked
        return result

    @staticmethod
    def _sheet(W, params, visible, fitted=None):
        """``surface='sheet'``: a surface that bends without stretching, from its own
        structure instead of the low-rank chain. Pinhole (``projection='perspective'``, the
        normalised tracks): the maximum-depth heuristic (:mod:`.max_depth`), ``S`` in the camera
        frame projecting onto ``W``. Orthographic: local-isometry depths fitted frame by frame
        near the shape carried from the frame before (:mod:`.sheet_transport`), ``S`` the
        centred tracks with those depths, ``translation`` the tracks' centroids. ``R`` the
        identity (the camera frame is the world's), no groups. ``fitted``: the sheet model's
        result on these tracks already made (the stage 'surface' checked every frame and
        track)."""
        if visible is not None and not np.all(visible) or not np.isfinite(W).all():
            raise InvalidInputError("surface 'sheet' takes complete tracks; some entries are "
                                    'unseen')
        start = time.perf_counter()
        F, P = W.shape[0] // 2, W.shape[1]
        pinhole = params['projection'] == 'perspective'
        with one_blas_thread():
            if fitted is None:
                fitted = (MaxDepthNRSfM() if pinhole else TransportSheetNRSfM()).fit(W)
            if pinhole:
                report, translation = _max_depth_report(fitted, P), np.zeros((2 * F, 1))
            else:
                report, translation = _transport_report(fitted), W.mean(axis=1, keepdims=True)
        report.seconds = {'total': time.perf_counter() - start}
        return NRSfMResult(S=fitted.S, R=np.repeat(np.eye(3)[None], F, axis=0),
                           translation=translation, groups=np.zeros(P, dtype=int),
                           blocks=np.array([0, F]), report=report)

    def _surface_decided(self, W, params, progress, beta_max):
        """``surface='auto'``: the stage 'surface' decides between the sheet (:meth:`_sheet`)
        and, through a pinhole, the projective-depth iteration (:meth:`_perspective`), else
        the low-rank chain."""
        start = time.perf_counter()
        pinhole = params['projection'] == 'perspective'
        with one_blas_thread():
            decided = surface.check(W) if pinhole else surface.check_orthographic(W)
        seconds = time.perf_counter() - start
        if decided.sheet:
            result = self._sheet(W, params, None, decided.fitted)
        elif pinhole:
            result = self._perspective(W, None, progress, beta_max)
        else:
            result = GrassmannNRSfM(**{**self.get_params(), 'surface': 'any'}).fit(
                W, progress=progress, beta_max=beta_max)
        report = result.report
        report.stages.insert(0, surface.NAME)
        report.notes.insert(0, surface.note(decided))
        report.seconds = {**report.seconds, surface.NAME: seconds,
                          'total': report.seconds.get('total', 0.0) + seconds}
        return result

    def _perspective(self, W, init, progress, beta_max):
        """``projection='perspective'``: the projective-depth iteration around this chain run
        orthographically (``init`` starts its first solve only). The kept round's result with
        ``S`` the camera-frame shapes, ``translation`` zero (``S`` projects onto ``W``) and
        ``report.perspective`` the iteration's rounds. The inextensible stage runs in the
        rounds only when asked for ('always'): under 'auto' it is held off
        (docs/decisions/0725)."""
        params = {**self.get_params(), 'projection': 'orthographic', 'relief': 'never'}
        if params['inextensible'] == 'auto':
            params['inextensible'] = 'never'
        chain = _Rounds(GrassmannNRSfM(**params), init=init, progress=progress,
                        beta_max=beta_max)
        outcome = PerspectiveNRSfM(chain).fit(W)
        report = replace(outcome.result.report, perspective=outcome.report())
        return replace(outcome.result, S=outcome.S, report=report,
                       translation=np.zeros_like(outcome.result.translation))

    @staticmethod
    def _registered(problem, params, first, progress):
        """The stage 'registration': the shape pass again with the rotations registered to
        ``first``'s shapes, then the better of the two."""
        start, timer = time.perf_counter(), Timer()
        again = problem.with_rotations(registration.rotations(first))
        report = SolverReport(stages=first.report.stages + [registration.NAME],
                              solves=list(first.report.solves))
        report.stages.append(rotations.NAME)
        R = rotations.run(again, params, report)
        second = shape_pass(again, R, params, report, timer, progress, reason='registration')
        report.seconds = dict(timer.seconds, total=time.perf_counter() - start)
        return registration.run(problem, params, first, second, time.perf_counter() - start)


class _Rounds:
    """The orthographic chain as :class:`.perspective.PerspectiveNRSfM` calls it: ``fit(W)``
    with this fit's ``progress`` and ``beta_max`` every round, ``init`` on the first only."""

    def __init__(self, solver, **kwargs):
        self.solver, self.kwargs = solver, kwargs

    def fit(self, W):
        result = self.solver.fit(W, **self.kwargs)
        self.kwargs = {**self.kwargs, 'init': None}
        return result


def reprojection(result):
    """``(2F, P)``: ``R S + t`` of ``result`` (its camera-frame x, y rows and translation)."""
    F = result.R.shape[0]
    return as_frames(result.S, 3)[:, :2, :].reshape(2 * F, -1) + result.translation


def shape_pass(problem, R, params, report, timer=None, progress=None, reason='shapes'):
    """Shapes for ``problem`` with rotations ``R: (F, 3, 3)``: thinning -> ADMM -> refinement
    -> fill. Fills the report's shape fields (a later pass replaces them); returns the
    :class:`NRSfMResult`."""
    timer = timer if timer is not None else Timer()
    t = time.perf_counter()
    solved, keep = problem, None
    if thinning.applies(problem, params):
        report.stages.append(thinning.NAME)
        keep = thinning.run(problem, params, report)
        if keep is not None:
            solved = problem.tracks(keep)
    t = timer.add('thinning', t)

    F, P = solved.F, solved.P
    K_s, K_t, N_s, N_t = config.sizes(params, F, P, solved.groups)
    off = config.spatial_off_reason(params, K_s, N_s, P, solved.groups)
    if off:
        report.notes.append('spatial branch off: ' + off)
    spatial = params['spatial'] and off is None
    report.K_s, report.K_t, report.N_s, report.N_t = K_s, K_t, N_s, N_t
    report.gamma = params['gamma'] * np.sqrt(F * P)
    report.warm_started_frames = int(solved.known.sum()) if solved.warm else 0
    if problem.mask is not None:
        report.observed_fraction = float(problem.mask.mean())
        report.completion = problem.completion
    S, state = admm_solve(solved, R, params, spatial, report, timer, progress, reason)

    t = time.perf_counter()
    if refinement.applies(solved, params):
        report.stages.append(refinement.NAME)
        check = refinement.check(S, solved.W, params)
        S = refinement.run(S, R, solved.W, params, check, report)
        t = timer.add('inextensible', t)

    labels = state.labels_original_order()
    if fill.applies(keep):
        report.stages.append(fill.NAME)
        S, labels = fill.run(S, labels, problem.W, keep, report)
        timer.add('thinning', t)
    return NRSfMResult(S=S, R=R, translation=problem.translation, groups=labels,
                       blocks=state.t_edges.copy(), report=report, C_s=state.C_s.copy(),
                       C_t=state.C_t.copy())


def smoothed(problem, params):
    """Whether the ADMM of ``problem`` takes the temporal smoothness prior: cold solves, and
    resumed ones where the inextensible refinement does not apply (sparse tracks); not from
    other given shapes (docs/decisions/0409)."""
    if not problem.warm:
        return True
    return problem.init.resumed and not refinement.applies(problem, params)


def admm_solve(problem, R, params, spatial, report, timer, progress, reason):
    """One run of Algorithm 1 from the problem's initial shapes.
    Fills the report's iteration fields and adds ``(reason, F, P, iterations)`` to
    ``report.solves``; returns ``(S_cam: (3F, P) in W's units, the spent AdmmState)``."""
    t = time.perf_counter()
    F, P = R.shape[0], problem.Wn.shape[1]
    settings = config.admm_settings(params, F, P, problem.groups, spatial)
    state = AdmmState(problem.Wn, R, initial_shapes(problem, R), settings, problem.groups,
                      warm=problem.warm, beta=settings.beta0 if problem.init.resumed else None,
                      smooth=smoothed(problem, params), weights=problem.weights)
    t = timer.add('initialisation', t)
    record = AdmmRun()
    report.iterations, report.objective, report.gaps = 0, record.objective, record.gaps
    report.reason, report.converged = record.reason, False

    def on_iteration(rec):
        report.iterations = rec.iterations
        if progress is not None:
            progress(rec.iterations, report)

    run(state, record, on_iteration, timer)
    report.iterations, report.reason = record.iterations, record.reason
    report.converged = record.converged
    if record.diverged:
        state.fall_back(initial_shapes(problem, R))
        report.fallback = (f'non-finite objective/gap at iteration {record.iterations}; '
                           'returned the initial shapes')
    report.solves.append((reason, F, P, record.iterations))
    report.regrouped_points = state.moves
    seen = 2 * F * P if problem.weights is None else max(float(problem.weights.sum()), 1e-300)
    report.reprojection_relative = float(np.sqrt(state.data_error() / seen))
    report.reprojection_rms = report.reprojection_relative * problem.scale
    S_cam = np.matmul(R, state.S_world_original_order())
    S_cam *= problem.scale
    timer.add('shape', t)
    return from_frames(S_cam), state


def _max_depth_report(result, P):
    """The :class:`SolverReport` of a :class:`.max_depth.MaxDepthNRSfM` result on ``P``
    tracks."""
    info = result.info
    converged = info['violation'] <= TOL_SHEET
    report = SolverReport(stages=['max_depth'], converged=converged,
                          reason='cones met' if converged else 'cutting-plane rounds out',
                          iterations=int(info['rounds']))
    report.notes.append(f'maximum-depth heuristic on {result.anchors.size} of {P} tracks '
                        f"(the others interpolated): {info['rounds']} cutting-plane rounds, "
                        f"worst cone violation {info['violation']:.3g} (docs/decisions/0709)" +
                        ('; its depths then fitted to its lengths as equalities '
                         '(docs/decisions/0720)' if 'refine_seconds_cpu' in info else ''))
    return report


def _transport_report(result):
    """The :class:`SolverReport` of a :class:`.sheet_transport.TransportSheetNRSfM` result."""
    report = SolverReport(stages=['sheet_transport'], converged=True, reason='signs carried',
                          iterations=1)
    report.notes.append('orthographic sheet: local-isometry depths carried from frames '
                        f"{result.info['start_frames']} (isometry residual "
                        f"{result.info['isometry_residual']:.3g}; docs/decisions/0714)")
    return report
