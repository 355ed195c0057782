"""Streaming accuracy and the warm start with the real GrassmannNRSfM, window 30 / stride 10.

Every frame is taken as refined (``points/refined`` with ``refined_from: first_window``: once,
by the first window that solves it, through reconstruct_live) and compared with the ground
truth; the references are the whole-sequence solve and rigid factorisation solved per window
and published the same way. Thresholds are the measured values (in the comments) with a
margin.
"""
import numpy as np
import pytest

from doubles import frames_of, RecordingGrassmann, RigidPerWindow, sliding_windows, stacked
from grass_nrsfm_ros.mapper import FIRST_WINDOW_BETA_MAX, WINDOW_BETA_MAX
from grass_nrsfm_ros.nrsfm import GrassmannNRSfM, WarmStart
from grass_nrsfm_ros.nrsfm.faces import make_face_sequence
from grass_nrsfm_ros.nrsfm.measurement import as_frames
from grass_nrsfm_ros.nrsfm.metrics import e3d
from grass_nrsfm_ros.nrsfm.synthetic import make_sequence
from grass_nrsfm_ros.pipeline import make_pipeline, reconstruct_live

pytestmark = pytest.mark.slow          # each case solves whole sequences with GrassmannNRSfM


def streamed(W, factory, **options):
    """``W: (2F, P)`` through the pipeline (window 30, stride 10, ``options``):
    ``(3F, P)`` as refined from the first window."""
    F, P = W.shape[0] // 2, W.shape[1]
    pipe = make_pipeline({'window_size': 30, 'window_stride': 10,
                          'refined_from': 'first_window', **options}, factory)
    _, refined, _ = reconstruct_live(pipe, np.arange(F), frames_of(W, np.arange(P)))
    assert [r.stamp_ns for r in refined] == list(range(F))         # each frame once, in order
    return stacked(refined)


def errors(W, S):
    """``(streaming, whole-sequence, rigid per window)`` e3D. The whole-sequence solve is the
    one the windows run: without the rotation registration, which solves given a WarmStart
    (the windows; here an empty one) skip."""
    whole = GrassmannNRSfM().fit(W, init=WarmStart())
    return (e3d(streamed(W, GrassmannNRSfM), S), e3d(whole.S, S),
            e3d(streamed(W, RigidPerWindow, context_frames=0), S))


def test_streaming_dense_face_beats_rigid_windows():
    try:
        seq = make_face_sequence(n_frames=60, n_points=1000, seed=0)
    except FileNotFoundError as exc:
        pytest.skip(str(exc))
    stream, whole, rigid = errors(seq.W, seq.S)
    print(f'streaming {stream:.4f}, whole {whole:.4f}, rigid per window {rigid:.4f}')
    # measured (context 60, key frames 30, no warm start): streaming 0.0612, whole 0.0433
    # (x1.41), rigid per window 0.1177; each window alone 0.1088. The first 30 frames see only
    # the first window: most of the gap to whole is there.
    assert stream < 0.7 * rigid
    assert stream < 1.6 * whole


def test_streaming_synthetic_close_to_whole_sequence():
    seq = make_sequence('bending', n_frames=60, n_points=400)
    stream, whole, rigid = errors(seq.W, seq.S)
    print(f'streaming {stream:.4f}, whole {whole:.4f}, rigid per window {rigid:.4f}')
    # measured: streaming 0.1766, whole 0.1581 (x1.12; with the rotation registration, which
    # the windows skip, 0.1475), rigid per window 0.2657. The bound was 1.1x whole while whole
    # was 0.1682; the solver's rotation check then improved the whole-sequence solve (0.1682 ->
    # 0.1537) but not the windows (streaming 0.1715 -> 0.1710), so the ratio is now held at
    # 1.15x and streaming itself at 0.1710 + 5 % (the figure when that bound was set).
    assert stream < 1.15 * whole
    assert stream < 1.05 * 0.1710
    assert stream < 0.8 * rigid


def test_a_resumed_window_needs_fewer_iterations_than_cold_on_the_same_problem():
    seq = make_sequence('bending', n_frames=50, n_points=400)
    factory = RecordingGrassmann()
    streamed(seq.W, factory)                        # windows 0..29, 10..39, 20..49
    resumed, init = factory.reports[2], factory.inits[2]
    assert init.resumed and resumed.rotation_method == 'given'
    assert init.R.shape[0] == 50                    # context 0..19 and the window 20..49
    cold = GrassmannNRSfM(surface='any').fit(seq.W).report      # the same, from the start
    print(f'iterations: resumed {resumed.iterations}, cold {cold.iterations}')
    # measured: 52 resumed vs 108 cold
    assert resumed.iterations < 0.95 * cold.iterations


def test_model_warm_start_carries_groups_and_rotation_method_at_equal_accuracy():
    seq = make_sequence('bending', n_frames=90, n_points=400)
    factory = RecordingGrassmann()
    options = dict(context_frames=20, key_frames=0)
    # the windows at every stride (the live pipeline's tracking may ask for a fresh window,
    # which moves the later ones: here one at frame 86)
    pipe = make_pipeline({'refined_from': 'first_window', 'warm_start': 'model', **options},
                         factory)
    sliding_windows(pipe, seq.W, np.arange(400))
    reports, inits = factory.reports, factory.inits
    # window 0 (frames 0-29) from the rigid factorisation; window 1 (10 context frames) checks;
    # window 2 (frames 0-49, full context) checks and its choice is carried until 25 of its 50
    # frames are new: window 5 (frames 30-79) checks again, window 6 carries that
    assert reports[0].rotation_method == 'given'
    assert [r.rotation_checked for r in reports[1:]] == [True, True, False, False, True, False]
    for i, source in ((3, 2), (4, 2), (6, 5)):
        assert inits[i].rotation_method == reports[source].rotation_method
        assert reports[i].rotation_method == inits[i].rotation_method
    assert all(init.rotation_method is None for init in inits[1:3] + inits[5:6])
    # the spatial groups of every track come from the previous solve (the same tracks)
    for i in range(2, len(inits)):
        np.testing.assert_array_equal(inits[i].groups, factory.results[i - 1].groups)


def schedule_length(cap):
    """ADMM iterations of the default penalty schedule from beta0 up to ``cap``."""
    solver = GrassmannNRSfM()
    beta, iterations = solver.beta0, 1
    while beta < cap:
        beta, iterations = min(beta * solver.rho, cap), iterations + 1
    return iterations


def test_resume_warm_start_resumes_the_previous_run_at_equal_accuracy():
    seq = make_sequence('bending', n_frames=90, n_points=400)
    factory = RecordingGrassmann()
    # no window closed early for a fresh model (a tracked frame's residual, which varies with
    # the BLAS kernel, asks for one): every window after the first holds 10 new frames
    options = dict(context_frames=20, key_frames=0, residual_limit=1e6)
    resumed = e3d(streamed(seq.W, factory, **options), seq.S)     # the default 'resume'
    model = e3d(streamed(seq.W, GrassmannNRSfM, warm_start='model', **options), seq.S)
    reports, inits, results = factory.reports, factory.inits, factory.results
    # window 0 from the rigid factorisation, window 1 (10 context frames) a full solve with
    # Dai's rank search and the rotation check; every later window resumes its predecessor
    assert reports[1].rotation_checked and reports[1].rotation_method == 'dai'
    # window 1 cannot resume (window 0 has no Dai rank) yet stops where the resumed windows
    # do, at WINDOW_BETA_MAX, its rotation check's two solves included (record 0425); window
    # 0, started from the rigid factorisation, stops at FIRST_WINDOW_BETA_MAX (record 0445)
    assert len(reports[1].solves) >= 3
    windows = schedule_length(WINDOW_BETA_MAX)
    assert all(n <= windows for *_, n in reports[1].solves), reports[1].solves
    first = schedule_length(FIRST_WINDOW_BETA_MAX)
    assert first < windows
    assert all(n <= first for *_, n in reports[0].solves), reports[0].solves
    for i in range(2, len(inits)):
        init = inits[i]
        assert reports[i].rotation_method == 'given' and not reports[i].rotation_checked
        assert init.known.all() and init.resumed and reports[i].stages.count('refinement')
        np.testing.assert_array_equal(init.groups, results[i - 1].groups)
        # the shapes of the shared frames are the previous solution's (up to the depth sign
        # the windows align); the 10 new frames start from the newest shared frame's depth
        shared = init.R.shape[0] - 10
        start, previous = as_frames(init.S, 3), as_frames(results[i - 1].S, 3)[-shared:, 2]
        previous = previous - previous.mean(axis=1, keepdims=True)
        np.testing.assert_allclose(np.abs(start[:shared, 2]), np.abs(previous), atol=1e-9)
        np.testing.assert_allclose(start[shared:, 2], start[shared - 1:shared, 2].repeat(10, 0))
    print(f'streamed e3D: resume {resumed:.4f}, model {model:.4f}')
    # measured: resume 0.1095, model 0.1063 (x1.03; bench/results/live.json has the windows
    # of the bench's sequences)
    assert resumed < 1.08 * model
