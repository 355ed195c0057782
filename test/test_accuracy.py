"""End-to-end accuracy of GrassmannNRSfM with its DEFAULT parameters (no per-sequence tuning).

Every threshold is the value measured with the current defaults (smoothness=1e-4; 2-core
machine, OpenBLAS, random_state 0) plus a modest margin, written next to it, so a regression
fails. Besides the
absolute threshold each case must beat rigid factorisation (Tomasi-Kanade) on the same tracks.
Known failures of the requirement "beat rigid on every deforming sequence" are kept as strict
xfails: they fail loudly (XPASS) once fixed, so the marker must then be removed.

Runtime: about a minute of CPU (mocap ~14 s, 10 synthetic cases ~10 s, faces ~10 s). The
1,102-frame drink sequence costs ~66 s of CPU and runs only with GRASS_NRSFM_SLOW_TESTS=1.
"""
from functools import lru_cache
import os
import re

import pytest

from conftest import data_root, load_dataset
from grass_nrsfm_ros.nrsfm import GrassmannNRSfM
from grass_nrsfm_ros.nrsfm.faces import make_face_sequence
from grass_nrsfm_ros.nrsfm.metrics import e3d, e3d_akhter
from grass_nrsfm_ros.nrsfm.rotation import rigid_factorisation
from grass_nrsfm_ros.nrsfm.synthetic import make_sequence

SLOW = os.environ.get('GRASS_NRSFM_SLOW_TESTS') == '1'


def solve(W, S, *, scale=False):
    """``(ours e3D, rigid e3D, ours e3D_akhter, ours S)`` with default parameters."""
    S_ours = GrassmannNRSfM().fit(W).S
    S_rigid = rigid_factorisation(W)[1]
    return (e3d(S_ours, S, scale=scale), e3d(S_rigid, S, scale=scale), e3d_akhter(S_ours, S),
            S_ours)


# ------------------------------------------------------------------------------ mocap
# (relpath, e3D threshold (measured), Akhter threshold (measured), Dai et al.'s published BMM
# value in Akhter's metric, whether ours beats rigid today)
MOCAP = {
    'drink': ('akhter_mocap/drink.npz', 0.0085, 0.016, 0.0266),    # 0.0068
    'pickup': ('akhter_mocap/pickup.npz', 0.019, 0.045, 0.1731),   # 0.0160
    'yoga': ('akhter_mocap/yoga.npz', 0.019, 0.035, 0.1150),       # 0.0158
    'dance': ('akhter_mocap/dance.npz', 0.132, 0.1864, 0.1864),    # 0.1223, ak 0.1816
    'face': ('torresani_mocap/face.npz', 0.019, 0.0303, 0.0303),   # 0.0165, ak 0.0281
    'shark': ('torresani_mocap/shark.npz', 0.10, 0.21, 0.2311),    # 0.0763, ak 0.1738
}
KNOWN_WORSE_THAN_RIGID = set()          # shark was, before the smoothness prior (see below)
KNOWN_WORSE_THAN_BMM_PUBLISHED = set()


@lru_cache(maxsize=None)
def mocap(name):
    W, S = load_dataset(MOCAP[name][0])
    return solve(W, S)[:3]


def mocap_params():
    out = []
    for name in MOCAP:
        marks = [pytest.mark.skipif(name == 'drink' and not SLOW,
                                    reason='drink: ~66 s CPU; set GRASS_NRSFM_SLOW_TESTS=1')]
        out.append(pytest.param(name, marks=marks, id=name))
    return out


@pytest.mark.parametrize('name', mocap_params())
def test_mocap_below_measured_thresholds(name):
    ours, _, akhter = mocap(name)
    _, e3d_max, akhter_max, _ = MOCAP[name]
    assert ours < e3d_max
    assert akhter < akhter_max


@pytest.mark.parametrize('name', mocap_params())
def test_mocap_beats_rigid(name):
    ours, rigid, _ = mocap(name)
    if name in KNOWN_WORSE_THAN_RIGID:
        assert ours > rigid, f'{name} now beats rigid: remove it from KNOWN_WORSE_THAN_RIGID'
        pytest.xfail(f'{name}: ours {ours:.4f} >= rigid {rigid:.4f} (known, open)')
    assert ours < rigid


@pytest.mark.parametrize('name', mocap_params())
def test_mocap_beats_published_bmm(name):
    _, _, akhter = mocap(name)
    published = MOCAP[name][3]
    if name in KNOWN_WORSE_THAN_BMM_PUBLISHED:
        assert akhter > published, f'{name} now beats BMM: update KNOWN_WORSE_THAN_BMM_PUBLISHED'
        pytest.xfail(f'{name}: Akhter {akhter:.4f} >= BMM published {published} (known, open)')
    assert akhter < published


# ------------------------------------------------------------------------------ perspective
# normalised image coordinates through an orthographic model: e3D with a per-frame scale
# (the reconstruction is in normalised units, the ground truth in mm)
PERSPECTIVE = {
    # measured 0.1127 (rigid 0.2663); 0.0982 until the rotation check (69e72be), which takes the
    # rigid rotations here (S# norm 11.3 % lower, admm.py); the threshold was not raised with it
    'kinect_paper': ('perspective_subsets/kinect_paper.npz', 0.115),
    # measured 0.1344 (rigid 0.3862)
    'white_cartoon_tshirt': ('perspective_subsets/white_cartoon_tshirt.npz', 0.155),
}


@pytest.mark.parametrize('name', list(PERSPECTIVE))
def test_perspective_subsets_beat_rigid(name):
    relpath, e3d_max = PERSPECTIVE[name]
    W, S = load_dataset(relpath)
    ours, rigid, _, _ = solve(W, S, scale=True)
    assert ours < e3d_max
    assert ours < rigid


# ------------------------------------------------------------------------------ synthetic
# kind -> measured e3D (orbit, shaky) at 60 frames x 500 points, seed 0; threshold +15%.
# In brackets: without the inextensible depths (inextensible='never'); 'auto' uses them on all
# but inflating (a stretching surface) here. The registered rotations (stage 'registration') are
# kept on all of those but articulated shaky; before them: bending (0.1561, 0.0671), waving
# (0.2320, 0.2441), twisting (0.0608, 0.0329), articulated (0.0089, 0.0087).
SYNTHETIC = {
    'bending': (0.1387, 0.0471),       # (0.1547, 0.1473); rigid 0.2921, 0.2451 (orbit: rigid
                                       # rotations chosen)
    'waving': (0.2432, 0.2508),        # (0.2507, 0.2445); rigid 0.1711, 0.1724: KNOWN worse
    'inflating': (0.0234, 0.0140),     # rigid 0.0734, 0.0734 (0.0132 without smoothness)
    'twisting': (0.0555, 0.0331),      # (0.1498, 0.0974); rigid 0.4348, 0.2250
    'articulated': (0.0099, 0.0087),   # (0.0755, 0.0758); rigid 0.1013, 0.1016
}
SYNTHETIC_WORSE_THAN_RIGID = {'waving'}


def test_rotation_check_takes_rigid_rotations_where_dai_fails():
    # bending, seed 1: Dai's rotations are 10-44 degrees off at every K (ours 0.1807 with them,
    # 0.098 with the true ones); the rigid rotations' shapes have a 17 % lower S# nuclear norm
    # (the low-rank chain: surface='auto' takes this clean sheet for a sheet, record 0738)
    seq = make_sequence('bending', 60, 500, camera='orbit', seed=1)
    result = GrassmannNRSfM(surface='any').fit(seq.W)
    assert any(n.startswith('rotations: rigid') for n in result.report.notes)
    ours, rigid = e3d(result.S, seq.S), e3d(rigid_factorisation(seq.W)[1], seq.S)
    assert ours < 0.0269 * 1.15 and ours < rigid          # measured 0.0269, rigid 0.1460
    dai = GrassmannNRSfM(surface='any', rotations='dai', inextensible='never').fit(seq.W)
    assert e3d(dai.S, seq.S) > rigid                                  # measured 0.1807
    rigid_rotations = GrassmannNRSfM(surface='any', inextensible='never').fit(seq.W)
    assert e3d(rigid_rotations.S, seq.S) < rigid                      # measured 0.1350


def test_rotation_check_keeps_dai_rotations_within_its_margin():
    # twisting shaky, seed 3: the rigid rotations' S# nuclear norm is 5.2 % lower, inside the
    # 10 % margin (with the former 5 % margin the check took them: 0.1275 instead of 0.0374)
    seq = make_sequence('twisting', 60, 500, camera='shaky', seed=3)
    result = GrassmannNRSfM(surface='any').fit(seq.W)     # the chain (a sheet to 'auto')
    note = next(n for n in result.report.notes if n.startswith('rotations'))
    dai, rigid_norm = (float(v) for v in re.findall(r"(?:Dai's|rigid) ([0-9.]+)", note))
    assert note.startswith('rotations: dai') and 0.9 * dai < rigid_norm < dai, note
    assert e3d(result.S, seq.S) < 0.0374 * 1.15                       # measured 0.0374
    with_rigid = GrassmannNRSfM(surface='any', rotations='rigid').fit(seq.W)
    assert e3d(with_rigid.S, seq.S) > 0.1                             # measured 0.1275


@pytest.mark.parametrize('camera', ['orbit', 'shaky'])
@pytest.mark.parametrize('kind', list(SYNTHETIC))
def test_synthetic_kinds(kind, camera):
    seq = make_sequence(kind, 60, 500, camera=camera, seed=0)
    ours, rigid, _, _ = solve(seq.W, seq.S)
    measured = SYNTHETIC[kind][0 if camera == 'orbit' else 1]
    assert ours < 1.15 * measured
    if kind in SYNTHETIC_WORSE_THAN_RIGID:
        assert ours > rigid, f'{kind} now beats rigid: remove it from SYNTHETIC_WORSE_THAN_RIGID'
        pytest.xfail(f'{kind}/{camera}: ours {ours:.4f} >= rigid {rigid:.4f} (known, open)')
    assert ours < rigid


# ------------------------------------------------------------------------------ dense faces

def face_sequence(**kwargs):
    root = data_root()
    if root is None or not (root / 'sfm_face' / 'sfm_face.npz').is_file():
        pytest.skip('Surrey face model not found (set GRASS_NRSFM_DATA)')
    return make_face_sequence(model=root / 'sfm_face' / 'sfm_face.npz', **kwargs)


def test_dense_face_half_of_rigid():
    """99 x 2000 face, seed 0, orbiting head: measured 0.0455 vs rigid 0.1211 (0.38x)."""
    seq = face_sequence(n_frames=99, n_points=2000, seed=0, head_motion='orbit')
    ours, rigid, _, _ = solve(seq.W, seq.S)
    assert ours < 0.053
    assert ours < 0.5 * rigid


def test_dense_face_noise_grows_gently():
    """60 x 1500 face, r = 0.05 (sigma = r max|W|): measured 0.0729 (clean 0.0383 with the
    stage 'relief', 0.0478 without, record 0734; rigid 0.1237); the error stays below 0.65x
    rigid and below twice the clean error."""
    noisy = face_sequence(n_frames=60, n_points=1500, seed=0, noise=0.05)
    ours, rigid, _, _ = solve(noisy.W, noisy.S)
    assert ours < 0.084
    assert ours < 0.65 * rigid
    clean = face_sequence(n_frames=60, n_points=1500, seed=0)
    ours_clean = solve(clean.W, clean.S)[0]
    assert ours < 2.0 * ours_clean


# ------------------------------------------------------------------------------ smoothness prior
def test_the_smoothness_prior_is_what_beats_rigid_on_shark():
    """Ablation: without the temporal smoothness prior (smoothness=0, the paper's objective)
    shark is worse than rigid (measured 0.1177 vs 0.0933, Akhter 0.2462 vs BMM's published
    0.2311); the default (1e-4) gives 0.0763 (Akhter 0.1738; 0.0885 / 0.1938 without the stage
    'relief'). The ADMM's objective alone: the relief held off (with it the plain objective
    reaches 0.0915, record 0734)."""
    W, S = load_dataset(MOCAP['shark'][0])
    rigid = e3d(rigid_factorisation(W)[1], S)
    S_plain = GrassmannNRSfM(smoothness=0.0, relief='never').fit(W).S
    assert e3d(S_plain, S) > rigid
    assert e3d_akhter(S_plain, S) > MOCAP['shark'][3]
