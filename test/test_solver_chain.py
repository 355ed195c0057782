"""The solver as a chain: the stages and solves reported, no solver inside a solver, validated
parameters left unchanged, the schedule of resumed solves."""
from dataclasses import replace

import numpy as np
import pytest
import scipy.linalg  # noqa: F401  (its BLAS loaded, as in every solve)
from threadpoolctl import threadpool_info, threadpool_limits

from grass_nrsfm_ros.nrsfm import admm, GrassmannNRSfM, WarmStart
from grass_nrsfm_ros.nrsfm.config import admm_settings
from grass_nrsfm_ros.nrsfm.grassmann import block_bases
from grass_nrsfm_ros.nrsfm.measurement import InvalidInputError
from grass_nrsfm_ros.nrsfm.problem import initial_shapes, Problem
from grass_nrsfm_ros.nrsfm.schema import solver_defaults
from grass_nrsfm_ros.nrsfm.solver import BLAS_THREADS, one_blas_thread
from grass_nrsfm_ros.nrsfm.synthetic import make_sequence


def admm_problem(F=20, P=400, kind='articulated'):
    seq = make_sequence(kind, n_frames=F, n_points=P, camera='orbit', seed=1)
    problem = Problem.from_tracks(seq.W, WarmStart(R=seq.R))
    R = np.array(seq.R, dtype=np.float64)
    # K_s = 4 groups, regrouped every 10 iterations (which reorders the stored columns)
    params = dict(solver_defaults(), K_s=4)
    settings = admm_settings(params, F, P, None, spatial=True)
    return problem, R, settings


def fresh_state(problem, R, settings):
    return admm.AdmmState(problem.Wn, R, initial_shapes(problem, R), settings)


def test_report_lists_stages_and_solves_and_no_solver_is_built_inside(monkeypatch):
    seq = make_sequence('bending', n_frames=20, n_points=300, camera='orbit', seed=2)
    built, fits = [], []
    init, fit = GrassmannNRSfM.__init__, GrassmannNRSfM.fit

    def counting_init(self, **kwargs):
        built.append(kwargs)
        init(self, **kwargs)

    def counting_fit(self, *args, **kwargs):
        fits.append(args)
        return fit(self, *args, **kwargs)
    monkeypatch.setattr(GrassmannNRSfM, '__init__', counting_init)
    monkeypatch.setattr(GrassmannNRSfM, 'fit', counting_fit)
    states = []
    state_init = admm.AdmmState.__init__

    def counting_state(self, *args, **kwargs):
        states.append(1)
        state_init(self, *args, **kwargs)
    monkeypatch.setattr(admm.AdmmState, '__init__', counting_state)
    report = GrassmannNRSfM(surface='any').fit(seq.W).report
    assert len(built) == 1 and len(fits) == 1
    reasons = [s[0] for s in report.solves]
    assert len(report.solves) == len(states) >= 3
    assert reasons[:3] == ['rotation check: dai', 'rotation check: rigid', 'shapes']
    assert all(F == 20 and it >= 1 for _, F, _, it in report.solves)
    assert report.stages[:3] == ['rotations', 'rotation check', 'thinning']
    assert 'refinement' in report.stages                     # cold, 300 tracks: dense
    assert report.iterations in [it for *_, it in report.solves[2:]]
    if report.rotations_registered:
        assert reasons[-1] == 'registration' and 'registration' in report.stages


def test_warm_start_makes_one_solve():
    seq = make_sequence('waving', n_frames=15, n_points=120, seed=3)
    report = GrassmannNRSfM().fit(seq.W, init=WarmStart(R=seq.R)).report
    assert [s[0] for s in report.solves] == ['shapes']
    assert report.stages == ['rotations', 'thinning', 'refinement']


def test_fit_leaves_the_parameters_unchanged():
    """The spatial branch goes off for a sparse problem in that solve only."""
    seq = make_sequence('waving', n_frames=15, n_points=60, seed=4)
    est = GrassmannNRSfM()
    before = est.get_params()
    report = est.fit(seq.W, init=WarmStart(R=seq.R)).report
    assert any('spatial branch off' in note for note in report.notes)
    assert est.get_params() == before and est.spatial is True


@pytest.mark.parametrize('name', ['zeta_weight', 'local_rigidity', 'power_steps', 'eps',
                                  'nuclear', 'resumed_beta_max', 'lambda3', 'lambda4',
                                  'sigma_eps', 'affinity_min', 'regroup_every', 'delta',
                                  'warm_beta0', 'register_rotations'])
def test_deleted_options_are_refused(name):
    with pytest.raises(TypeError, match=name):
        GrassmannNRSfM(**{name: 1})


def test_a_resumed_warm_start_runs_the_cold_schedule_and_stages():
    seq = make_sequence('bending', n_frames=30, n_points=300, seed=2)
    solver = GrassmannNRSfM()
    first = solver.fit(seq.W, init=WarmStart(R=seq.R))
    warm = WarmStart(R=first.R, S=first.S, groups=first.groups)
    cap = 10.0                          # the sliding windows' cap for a resumed solve
    plain = solver.fit(seq.W, init=warm)
    resumed = solver.fit(seq.W, init=replace(warm, resumed=True), beta_max=cap)
    # from given shapes: WARM_BETA0 and the carried depths; resumed: beta0 and the refinement
    assert 'refinement' not in plain.report.stages and 'refinement' in resumed.report.stages
    # resumed and capped: from beta0 until beta reaches the cap, every ADMM solve of the fit
    beta, schedule = solver.beta0, 1
    while beta < cap:
        beta, schedule = min(beta * solver.rho, cap), schedule + 1
    assert [n for *_, n in resumed.report.solves] == [schedule] * len(resumed.report.solves)
    # uncapped, to the same stopping rule the lower start takes more iterations (84 vs 96)
    longer = solver.fit(seq.W, init=replace(warm, resumed=True))
    assert plain.report.iterations < longer.report.iterations
    assert solver.beta_max == 1e6                       # the call's cap left no trace
    with pytest.raises(InvalidInputError, match='beta_max'):
        solver.fit(seq.W, init=replace(warm, resumed=True), beta_max=solver.beta0 / 2)
    with pytest.raises(InvalidInputError, match='resumed'):
        solver.fit(seq.W, init=WarmStart(S=first.S, resumed=True))


@pytest.mark.parametrize('points, smoothed', [(60, True), (300, False)])
def test_resumed_solves_take_the_smoothness_prior_on_sparse_tracks(points, smoothed,
                                                                   monkeypatch):
    """Cold solves and resumed solves of sparse tracks take the prior; resumed solves of
    dense tracks (inextensible depths instead) and solves from other given shapes do not."""
    seq = make_sequence('waving', n_frames=20, n_points=points, seed=1)
    solver = GrassmannNRSfM()
    first = solver.fit(seq.W, init=WarmStart(R=seq.R))
    warm = WarmStart(R=first.R, S=first.S, groups=first.groups)
    states = []

    def recording(*args, **kwargs):
        states.append(admm.AdmmState(*args, **kwargs))
        return states[-1]
    monkeypatch.setattr('grass_nrsfm_ros.nrsfm.solver.AdmmState', recording)
    solver.fit(seq.W, init=WarmStart(R=seq.R))
    solver.fit(seq.W, init=warm)
    solver.fit(seq.W, init=replace(warm, resumed=True))
    cold, given, resumed = (states[i].smoother is not None for i in (0, 1, -1))
    assert cold and not given and resumed == smoothed


def test_temporal_bases_are_those_of_the_projected_sharp_shapes():
    """The temporal bases kept after an iteration (reused, not re-decomposed) are the block
    bases of S#'s Gram after zeta_t: the same subspaces and singular values."""
    problem, R, _ = admm_problem(F=24, P=300)
    settings = admm_settings(dict(solver_defaults(), K_t=3), 24, 300, None, spatial=False)
    state = fresh_state(problem, R, settings)
    admm.run(state, iterations=8)
    assert state.K_t > 1 and any(v.shape[1] < e - b for (v, _), b, e in
                                 zip(state.t_bases, state.t_edges[:-1], state.t_edges[1:]))
    sharp = state.Ssh.reshape(state.F, -1).astype(np.float64)
    expected = block_bases(sharp @ sharp.T, state.t_edges, state.N_t)
    for (v, sv), (v_ref, sv_ref) in zip(state.t_bases, expected):
        np.testing.assert_allclose(sv, sv_ref, rtol=1e-4)
        np.testing.assert_allclose(v @ v.T, v_ref @ v_ref.T, atol=1e-4)


def test_one_blas_thread_limits_every_blas_and_restores_it():
    """The solver's BLAS limit (one controller built once) caps numpy's and scipy's BLAS to
    BLAS_THREADS inside it, also on a second use, and gives the thread counts back after."""
    def blas_threads():
        return sorted(i['num_threads'] for i in threadpool_info() if i['user_api'] == 'blas')

    with threadpool_limits(limits=2, user_api='blas'):
        before = blas_threads()
        assert before and max(before) == 2
        for _ in range(2):
            with one_blas_thread():
                assert set(blas_threads()) == {BLAS_THREADS}
            assert blas_threads() == before
