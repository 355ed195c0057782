"""Record 0807's diagnosis helpers in ``bench.missing``: the oracle rotations (a truth's affine
camera onto its tracks, rows made orthonormal) and the truth registered to its first frame, with
unseen entries."""
from dataclasses import replace

import numpy as np

from bench.missing import oracle_rotations, registered_truth
from grass_nrsfm_ros.nrsfm import rotation_error, synthetic


def hidden(seq, fraction, seed):
    """``(W, S_world, visible)`` of ``seq`` with ``fraction`` of the entries hidden in occlusion
    blocks: NaN in the tracks and in the truth there."""
    visible = synthetic.occlusion_mask(seq.W, fraction, np.random.default_rng(seed))
    W = np.where(np.repeat(visible, 2, axis=0), seq.W, np.nan)
    S = np.where(np.repeat(visible, 3, axis=0), seq.S_world, np.nan)
    return W, S, visible


def test_oracle_rotations_are_the_true_ones_with_unseen_entries():
    seq = synthetic.make_sequence('bending', 20, 150, camera='shaky', seed=1)
    W, S, visible = hidden(seq, 0.2, 5)
    assert not visible.all()
    R = oracle_rotations(W, S, visible)
    assert R.shape == (20, 3, 3)
    np.testing.assert_allclose(R, seq.R, atol=1e-8)
    # pixel units and a translation per frame (the back's tracks) change nothing
    shift = np.random.default_rng(2).normal(0.0, 50.0, (40, 1))
    np.testing.assert_allclose(oracle_rotations(700.0 * W + shift, S, visible), seq.R, atol=1e-8)


def test_oracle_rotations_fit_noisy_tracks_better_than_estimated_ones():
    seq = synthetic.make_sequence('waving', 30, 200, noise=0.01, seed=4)
    W, S, visible = hidden(seq, 0.1, 6)
    R = oracle_rotations(W, S, visible)
    assert np.allclose(R @ R.transpose(0, 2, 1), np.eye(3), atol=1e-10)
    assert np.allclose(np.linalg.det(R), 1.0)
    assert rotation_error(R, seq.R) < 0.5                 # degrees; noise r 0.01


def test_registered_truth_takes_the_turns_out_of_a_rigid_truth():
    seq = synthetic.make_sequence('bending', 12, 100, camera='shaky', seed=2)
    F = 12
    shape = seq.S_world.reshape(F, 3, -1)[0]
    truth = np.einsum('fij,jp->fip', seq.R, shape).reshape(3 * F, -1)   # one shape, turning
    W, S, visible = hidden(replace(seq, S_world=truth), 0.2, 7)
    out = registered_truth(S, visible).reshape(F, 3, -1)
    assert np.isnan(out).any(axis=1).sum() == (~visible).sum()
    for f in range(1, F):
        both = visible[f] & visible[0]
        a = out[f][:, both] - out[f][:, both].mean(axis=1, keepdims=True)
        b = out[0][:, both] - out[0][:, both].mean(axis=1, keepdims=True)
        np.testing.assert_allclose(a, b, atol=1e-9)
