"""Uneven track density: thin over-dense tracks before the solve, fill them in after.

Every step of the solver weights every track equally (the nuclear norms, the least squares,
the rotation factorisation). Where a tracker puts many tracks on a small, textured part of
the surface, that part outweighs the rest and the rest is reconstructed badly.

The density of track j is ``1 / r_j^2``, ``r_j`` the distance to its k-th nearest track in the
trajectory embedding (the surface is two-dimensional there). ``k = max(DENSITY_NEIGHBOURS,
DENSITY_SPAN * P)`` spans a fixed share of the tracks, so that the estimate's resolution on the
surface does not grow with P (beyond ``DENSITY_SAMPLE`` tracks it is estimated on a fixed
random sample, each track taking its nearest sampled track's density). With k = 8 at every P,
the foreshortened flanks of an inflating surface under a static camera (uniformly sampled)
put 2.5 % / 5 % / 7.5 % of 3,000 / 10,000 / 30,000 tracks over the limit; with the share and
the sample, <= 0.9 %, 0 and 0.07 %.

The reference is the *area-weighted* median density: the density that covers half the
surface, each track standing for an area ``r_j^2``; a dense cluster carries little area, so
it does not move the reference as the plain median would. Tracks denser than
``DENSITY_LIMIT`` times the reference are kept with probability ``DENSITY_LIMIT * reference /
density`` (a fixed random draw), which caps their density near the limit; and only when at
least ``DENSITY_MIN_SHARE`` of the tracks are over the limit (a cluster, not the spread of a
random sample), so that evenly sampled sequences are solved exactly as before. Measured share
over the limit: <= 1.7 % on 360 uniform synthetic sequences (5 kinds x 4 cameras x 6 seeds x
120 / 500 / 3,000 tracks) and their 30-frame windows; <= 0.05 % on the package's dense faces
(99 x 2,000 / 28,880, seeds 0-5; max density 4-9x the reference); 0 on every sequence of
../shared/data but dance, which has 12 % over the limit and is never thinned (75 markers,
below ``admm.THINNING_MIN_POINTS``); 21-41 % with a quarter or more of the tracks in patches
of 1 % of the surface (make_sequence(clustered=...)); 10-20 % on faces sampled uniformly per
mesh triangle (the small triangles around the eyes and mouth; test_admm's face).

The dropped tracks' 3D points are filled in from the solved ones: each is written as an affine
combination of its ``FILL_NEIGHBOURS`` nearest kept tracks whose weights reproduce its 2D
trajectory over all frames (locally linear reconstruction weights, regularised), and its depth
is the same combination of theirs; x, y are its own data. Exact for a locally planar patch.

Measured ('auto' against 'never'), 60 x 500 synthetic surfaces, 5 kinds x orbit / shaky
cameras x 7 layouts (a quarter / half / three quarters of the tracks in one patch of 1-9 % of
the surface, 40 % in two patches of 1 %, 10 % in one, density growing towards one edge as
u^(-2/3)):

* seeds 0 (70 cases, where the limits were chosen) / 1-2 (140, validation): geometric mean of
  the e3D ratios 0.96 / 0.95, better (by > 3 %) on 25 / 52, worse on 14 / 28; worse than rigid
  16 -> 15 / 37 -> 34; 14 % less CPU. The inflating surface, which stretches and so relies on
  the low-rank shape prior the cluster dominates, gains most (0.82 / 0.87), e.g. two patches
  orbit seed 0 0.098 -> 0.046 (rigid 0.071, test_density). The ratios spread from 0.25 to 1.93:
  bending and twisting move both ways (1.01 / 0.97 on average) with the rotation check and the
  refinement chain, whose choices any change of the track set can flip (in the 4 cases
  checked, the thinned solve scored on its kept tracks alone is as far from 'never' as the
  filled result). The mild layouts (one
  patch of 9 %, the smooth gradient) come out at 1.03; a limit of 4 or 16 instead of 8
  changes the seed-0 mean by -0.01 / +0.01.
* the filled tracks are as good as the solved ones: given the true kept depths, their RMS
  depth error is 0.01-0.08 % of the depths' std clean, 0.9-1.7 % at noise r = 0.03.
* faces sampled uniformly per mesh triangle (test_admm's; 30 x 1,500 and 60 x 3,000, seeds
  0-2, 4-7 % of the tracks dropped): better on all 6, by 1-3 %, with the estimated and the true
  rotations alike.
* sliding windows (bench.streaming's 30-frame windows, stride 10, over 60 frames; 40 % in
  two patches, orbit seed 0, 5 kinds):
  geometric mean e3D 0.125 -> 0.113, better on all 5, 10-20 % less CPU per window.

Shapes: ``W: (2F, P)``, ``S: (3F, P)``.
"""
import numpy as np
from sklearn.neighbors import NearestNeighbors

from .inextensible import trajectory_embedding
from .measurement import as_frames, centre, from_frames, track_scale

#: fewest neighbours of the density estimate
DENSITY_NEIGHBOURS = 8
#: share of the tracks the density estimate spans (k = P / 200 from 1,600 tracks on)
DENSITY_SPAN = 1 / 200
#: most tracks the density is estimated on (a fixed random sample beyond: 100 x 70,000 took
#: 7.1 s of CPU with k = 350 on all tracks, 1.1 s with the sample; the 99 x 28,880 face 0.46 s,
#: 1 % of its solve)
DENSITY_SAMPLE = 4000
#: tracks denser than this many times the area-weighted median density are thinned
DENSITY_LIMIT = 8.0
#: share of over-dense tracks below which nothing is thinned
DENSITY_MIN_SHARE = 0.05
#: kept neighbours a dropped track's depth is combined from
FILL_NEIGHBOURS = 8
#: Tikhonov regularisation of the reconstruction weights, relative to the trace. RMS depth
#: error of the filled tracks over the depths' std, given the true kept depths (inflating /
#: bending / articulated, 40 % clustered, 60 x 500): clean 0.0039 / 0.0015 / 0.0016 at 1e-3,
#: 0.0008 / 0.0006 / 0.0001 at 1e-5; with noise r = 0.03 0.009-0.017 at 1e-2 .. 1e-5 alike
FILL_REGULARISATION = 1e-5
#: entries per chunk of (dropped tracks x rows x neighbours)
CHUNK = 1 << 22


def track_density(W, random_state=0):
    """``(density: (P,), reference: float)``: each track's ``1 / r_k^2`` and the area-weighted
    median density of ``W: (2F, P)``. Beyond DENSITY_SAMPLE tracks the densities are those of
    a fixed random sample of that many, each track taking its nearest sampled track's."""
    X = trajectory_embedding(W)
    P = X.shape[0]
    sample = np.arange(P) if P <= DENSITY_SAMPLE else np.sort(
        np.random.default_rng(random_state).choice(P, DENSITY_SAMPLE, replace=False))
    k = min(max(DENSITY_NEIGHBOURS, int(DENSITY_SPAN * sample.size)), sample.size - 1)
    tree = NearestNeighbors(n_neighbors=k + 1).fit(X[sample])
    dist = tree.kneighbors(X[sample])[0][:, k]
    dist = np.maximum(dist, 1e-12 * max(dist.max(), 1e-300))
    density = 1.0 / dist ** 2
    order = np.argsort(density)
    area = np.cumsum(1.0 / density[order])
    reference = float(density[order][np.searchsorted(area, 0.5 * area[-1])])
    if sample.size < P:
        density = density[tree.kneighbors(X, n_neighbors=1, return_distance=False)[:, 0]]
    return density, reference


def thinned_tracks(W, random_state=0):
    """Indices ``(P',)`` (sorted) of the tracks of ``W: (2F, P)`` to solve, or None when the
    density is even enough to keep all."""
    density, reference = track_density(W, random_state)
    excess = density / (DENSITY_LIMIT * reference)
    if np.mean(excess > 1.0) < DENSITY_MIN_SHARE:
        return None
    rng = np.random.default_rng(random_state)
    keep = rng.random(excess.size) * np.maximum(excess, 1.0) < 1.0
    return np.flatnonzero(keep)


def fill_dropped(S_kept, labels_kept, W, keep):
    """``(S: (3F, P), labels: (P,))``: the solved ``S_kept: (3F, P')`` and spatial labels
    ``labels_kept: (P',)`` of the tracks ``keep``, with the dropped tracks' points filled in
    (x, y their data, depth the combination of their kept neighbours') and labels (their
    nearest kept neighbour's); S centred on the mean of all the tracks of ``W: (2F, P)``."""
    F, P = W.shape[0] // 2, W.shape[1]
    dropped = np.setdiff1d(np.arange(P), keep)
    Wc = centre(W)[0]
    kept = as_frames(S_kept, 3).copy()
    kept[:, :2, :] += Wc[:, keep].mean(axis=1).reshape(F, 2, 1)   # to the mean of all tracks
    nbrs, weights = _reconstruction_weights(Wc / track_scale(Wc), keep, dropped)
    S = np.empty((F, 3, P))
    S[:, :, keep] = kept
    S[:, :2, dropped] = Wc[:, dropped].reshape(F, 2, -1)
    S[:, 2, dropped] = np.einsum('fdk,dk->fd', kept[:, 2, :][:, nbrs], weights)
    S[:, 2, :] -= S[:, 2, :].mean(axis=1, keepdims=True)
    labels_kept = np.asarray(labels_kept)
    labels = np.empty(P, dtype=labels_kept.dtype)
    labels[keep] = labels_kept
    labels[dropped] = labels_kept[nbrs[:, 0]]
    return from_frames(S), labels


def _reconstruction_weights(Wc, keep, dropped, k=FILL_NEIGHBOURS):
    """``(neighbours: (D, k)`` indices into ``keep``, ``weights: (D, k)`` summing to 1) that
    best reproduce each dropped column of ``Wc: (2F, P)`` (centred, unit RMS) from its nearest
    kept columns."""
    k = min(k, keep.size)
    W_kept = Wc[:, keep]
    nbrs = NearestNeighbors(n_neighbors=k).fit(W_kept.T).kneighbors(
        Wc[:, dropped].T, return_distance=False)                   # nearest first
    weights = np.empty(nbrs.shape)
    step = max(1, CHUNK // (Wc.shape[0] * k))
    for a in range(0, dropped.size, step):
        part = slice(a, a + step)
        diff = W_kept[:, nbrs[part]] - Wc[:, dropped[part]][:, :, None]   # (2F, d, k)
        G = np.einsum('rdi,rdj->dij', diff, diff)
        G += FILL_REGULARISATION * np.trace(G, axis1=1, axis2=2)[:, None, None] * np.eye(k)
        G += 1e-12 * np.eye(k)
        w = np.linalg.solve(G, np.ones((G.shape[0], k, 1)))[..., 0]
        weights[part] = w / w.sum(axis=1, keepdims=True)
    return nbrs, weights
