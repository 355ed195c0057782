"""Test doubles and the inputs several test files share (one module, imported as ``doubles``:
pytest puts test/ on the path, and the node tests' launch strings run from test/).

Inputs: :func:`bending_sheet` (``W: (2F, P)`` pixels, ``S: (3F, P)``, ``ids: (P,)``),
:func:`random_rotations` (``(F, 3, 3)``); :func:`frames_of` and :func:`stacked` (frames in,
FrameResults out as ``(3F, P)``), :func:`sliding_windows` (a pipeline's windows without its
tracking); :func:`wait_until`, the polling helper. A real rigid
solver, :class:`RigidALS` (it takes ``grass_nrsfm_ros.nrsfm.WarmStart`` and reports
``rotation_method='rigid'``, so the mapper's default 'resume' warm start resumes it), which
the node and pipeline tests inject in place of GrassmannNRSfM; solvers that misbehave (NaN,
slow, not cancellable, failing, crashing); stand-ins with the solver's or the pipeline's
protocol.
"""
import os
from pathlib import Path
import signal
import time
from types import SimpleNamespace

import numpy as np

from grass_nrsfm_ros.nrsfm import GrassmannNRSfM
from grass_nrsfm_ros.nrsfm.measurement import as_frames, centre
from grass_nrsfm_ros.nrsfm.missing import fill_unseen
from grass_nrsfm_ros.nrsfm.rotation import rigid_factorisation


# -- shared inputs ----------------------------------------------------------------------------
def sheet_rotation(yaw, pitch):
    """The camera of :func:`bending_sheet`: yaw about y, then pitch about x."""
    cy, sy, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rx = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
    return Rx @ Ry


def bending_sheet(F=60, P=200, *, bend=0.15, noise=0.0, seed=0):
    """A bending sheet seen by a turning orthographic camera, in pixels.

    Returns ``W: (2F, P)`` (with a drifting translation), ``S: (3F, P)`` camera-frame ground
    truth, ``ids: (P,)`` track ids. ``bend`` scales the non-rigid part.
    """
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-1, 1, (2, P))
    base = np.vstack([xy, 0.4 * np.cos(2 * xy[0]) * np.cos(1.5 * xy[1])])
    t = np.linspace(0, 1, F)
    S_world = np.stack([base + bend * np.sin(2 * np.pi * tt) * np.vstack(
        [0 * xy[0], 0 * xy[0], xy[0] ** 2 - 0.3]) for tt in t])            # (F, 3, P)
    R = np.stack([sheet_rotation(0.8 * np.sin(2 * np.pi * tt), 0.4 * np.cos(3 * tt)) for tt in t])
    S = (R @ S_world) * 100.0                                             # pixels
    W = S[:, :2, :] + np.stack([200 + 20 * t, 150 - 10 * t], axis=1)[:, :, None]
    W = W + noise * rng.standard_normal(W.shape)
    ids = rng.permutation(10 * P)[:P].astype(np.uint32) + 5
    return W.reshape(2 * F, P), S.reshape(3 * F, P), ids


def frames_of(W, ids):
    """``[(ids, uv: (P, 2))]``, one per frame of ``W: (2F, P)``: what the pipeline takes."""
    return [(ids, uv.T) for uv in as_frames(W, 2)]


def stacked(results, ids=None):
    """``(3F, P)`` from FrameResults (anything with ``ids: (P,)`` and ``xyz: (P, 3)``) in their
    order; columns in the order of ``ids`` (None: as each result has them)."""
    if ids is None:
        return np.vstack([r.xyz.T for r in results])
    return np.vstack([r.xyz[np.argsort(r.ids)][np.searchsorted(np.sort(r.ids), ids)].T
                      for r in results])


def sliding_windows(pipeline, W, ids):
    """FrameResults of ``W: (2F, P)`` through an inline LivePipeline's windowing, mapper and
    refinement driven directly, without its tracking: the windows close every stride only (no
    fresh window a surprising frame asks for), as ``points/refined`` gives them out."""
    windowing, refinement = pipeline.windowing, pipeline.refinement
    mapper = pipeline.backend.mapper
    windows, out = [], []
    for f, (fid, uv) in enumerate(frames_of(W, ids)):
        windows += windowing.push(windowing.accept(f, fid, uv))
    for window in windows + windowing.flush(refinement.waiting(windowing.sequence)):
        refinement.expect(window)
        out += refinement.take(mapper.solve(window))
    return out


def paced(items, period):
    """Yield ``items`` one per ``period`` s from the first (a sensor's rate, not a wait): the one
    paced-publishing helper."""
    start = time.monotonic()
    for i, item in enumerate(items):
        time.sleep(max(0.0, start + i * period - time.monotonic()))
        yield item


def wait_until(condition, timeout=60.0):
    """Poll ``condition()`` until it holds (True) or ``timeout`` s pass (False): the one polling
    helper for what gives no event to wait on (another process's state)."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.02)
    return True


# -- a real rigid solver (the node tests inject it) --------------------------------------------
def camera_rows(A):
    """Nearest 2x3 matrices with orthonormal rows to ``A: (F, 2, 3)``."""
    U, _, Vt = np.linalg.svd(A, full_matrices=False)
    return U @ Vt


def full_rotation(M):
    """``M: (F, 2, 3)`` orthonormal rows -> ``(F, 3, 3)`` rotations (third row = cross)."""
    return np.concatenate([M, np.cross(M[:, 0], M[:, 1])[:, None, :]], axis=1)


def tomasi_kanade(Wc):
    """Rigid factorisation of centred ``Wc: (2F, P)``: cameras ``(F, 2, 3)``, shape ``(3, P)``."""
    U, s, Vt = np.linalg.svd(Wc, full_matrices=False)
    M = U[:, :3] * np.sqrt(s[:3])
    m = M.reshape(-1, 2, 3)

    def row(a, b):            # coefficients of a^T Q b for symmetric Q (6 unknowns)
        return np.stack([a[:, 0] * b[:, 0], a[:, 0] * b[:, 1] + a[:, 1] * b[:, 0],
                         a[:, 0] * b[:, 2] + a[:, 2] * b[:, 0], a[:, 1] * b[:, 1],
                         a[:, 1] * b[:, 2] + a[:, 2] * b[:, 1], a[:, 2] * b[:, 2]], axis=1)
    A = np.vstack([row(m[:, 0], m[:, 0]) - row(m[:, 1], m[:, 1]), row(m[:, 0], m[:, 1]),
                   row(m[:, 0], m[:, 0])])
    b = np.concatenate([np.zeros(2 * len(m)), np.ones(len(m))])
    q = np.linalg.lstsq(A, b, rcond=None)[0]
    Q = np.array([[q[0], q[1], q[2]], [q[1], q[3], q[4]], [q[2], q[4], q[5]]])
    w, V = np.linalg.eigh(Q)
    G = V * np.sqrt(np.clip(w, 1e-12, None))
    cams = camera_rows(m @ G)
    return cams, np.linalg.pinv(cams.reshape(-1, 3)) @ Wc


class RigidALS:
    """Iterative rigid factorisation: start from Tomasi-Kanade (or a warm start's rotations:
    ``init.R`` on the ``init.known`` frames, all when ``known`` is None, as a resumed
    WarmStart gives them), then alternate shape (least squares) and cameras (a
    majorise-minimise step on the orthonormal-rows constraint) until the relative change of
    the residual is below ``tol``. NaN entries of W (tracks a frame does not see) are filled
    by the package's completion first."""

    def __init__(self, tol=1e-7, max_iterations=500):
        self.tol, self.max_iterations = tol, max_iterations

    def fit(self, W, init=None):
        start = time.process_time()
        Wc, t = centre(fill_unseen(W)[0])
        cams, X = tomasi_kanade(Wc)
        known = None if init is None or init.R is None else (
            np.ones(len(init.R), dtype=bool) if init.known is None else np.asarray(init.known))
        if known is not None and known.any():
            # rotate the closed-form start into the warm start's world, keep its known cameras
            Q = camera_rows(np.einsum('fij,fik->jk', cams[known], init.R[known, :2])[None])[0]
            cams = cams @ Q
            cams[known] = init.R[known, :2]
            X = np.linalg.lstsq(cams.reshape(-1, 3), Wc, rcond=None)[0]
        previous = np.inf
        for it in range(1, self.max_iterations + 1):
            # one majorise-minimise step per frame: min ||W_f - M_f X|| over orthonormal rows
            G = X @ X.T
            step = 1.0 / np.linalg.eigvalsh(G)[-1]
            cams = camera_rows(cams + step * (as_frames(Wc, 2) @ X.T - cams @ G))
            X = np.linalg.lstsq(cams.reshape(-1, 3), Wc, rcond=None)[0]
            residual = np.linalg.norm(Wc - cams.reshape(-1, 3) @ X)
            if previous - residual <= self.tol * max(residual, 1e-12):
                break
            previous = residual
        R = full_rotation(cams)
        S = (R @ X).reshape(-1, X.shape[1])
        report = SimpleNamespace(iterations=it, residual=residual, rotation_method='rigid',
                                 seconds={'total': time.process_time() - start})
        return SimpleNamespace(S=S, R=R, translation=t, groups=None, report=report)


def recording_rigid(seen):
    """A RigidALS solver factory that appends each fit's ``(W, init)`` to ``seen``."""
    class Recording(RigidALS):
        def fit(self, W, init=None):
            seen.append((W, init))
            return super().fit(W, init)
    return Recording


def random_rotations(F, rng):
    """``(F, 3, 3)`` rotations, uniformly random (QR of Gaussians, determinant +1)."""
    Q, _ = np.linalg.qr(rng.normal(size=(F, 3, 3)))
    return Q * np.sign(np.linalg.det(Q))[:, None, None]


def wobbling_rotations(F, rng, amplitude=0.5):
    """``(F, 3, 3)`` rotations turning smoothly about all three axes (``amplitude`` radians)."""
    t = np.linspace(0, 1, F)
    angles = amplitude * np.sin(2 * np.pi * rng.uniform(0.5, 1.5, 3)[:, None] * t
                                + rng.uniform(0, 2 * np.pi, 3)[:, None])
    out = []
    for a, b, c in angles.T:
        Rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
        Ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
        Rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
        out.append(Rz @ Ry @ Rx)
    return np.array(out)


# -- solvers that misbehave -------------------------------------------------------------------
class NaNSolver:
    """A broken solver: the rigid result with NaN in one frame's shape."""

    def fit(self, W, init=None):
        result = RigidALS().fit(W, init)
        result.S[3, :5] = np.nan
        return result


class SlowSolver:
    """The rigid test solver after ``SECONDS`` of 'iterations' (0.05 s each), each reported to
    ``progress(iteration, report)`` as GrassmannNRSfM does (so a node can cancel it). The
    sleeps stand for work: the node's tests need a solve that takes long."""

    SECONDS = 30.0

    def fit(self, W, init=None, progress=None):
        report = SimpleNamespace(iterations=0)
        for it in range(int(self.SECONDS / 0.05)):
            time.sleep(0.05)
            report.iterations = it + 1
            if progress is not None:
                progress(it + 1, report)
        return RigidALS().fit(W, init)


class StubbornSolver(SlowSolver):
    """A slow solver without a progress callback: it cannot be cancelled."""

    def fit(self, W, init=None):
        return super().fit(W, init, None)


class FailsSecondWindow(RigidALS):
    """The rigid test solver, raising RuntimeError at the second fit of its process."""

    fits = 0

    def fit(self, W, init=None):
        type(self).fits += 1
        if type(self).fits == 2:
            raise RuntimeError('second window refused by FailsSecondWindow')
        return super().fit(W, init)


class KillsItsProcessOnce(RigidALS):
    """The rigid test solver, but the second fit of a run kills its own process (SIGKILL: a
    crash); ``$GRASS_TEST_CRASH_MARKER`` names the file that records that it happened."""

    fits = 0

    def fit(self, W, init=None):
        type(self).fits += 1
        marker = Path(os.environ['GRASS_TEST_CRASH_MARKER'])
        if type(self).fits == 2 and not marker.exists():
            marker.touch()
            os.kill(os.getpid(), signal.SIGKILL)
        return super().fit(W, init)


# -- stand-ins with the solver's or the pipeline's protocol -----------------------------------
class RigidPerWindow:
    """Rigid factorisation per window (ignores any warm start)."""

    def fit(self, W, init=None):
        R, S = rigid_factorisation(W)
        return SimpleNamespace(S=S, R=R, groups=None, report=None)


class RecordingGrassmann:
    """A GrassmannNRSfM factory that keeps each fit's init, result and report."""

    def __init__(self):
        self.reports, self.inits, self.results = [], [], []

    def __call__(self):
        reports, inits, results = self.reports, self.inits, self.results

        class Fit(GrassmannNRSfM):
            def fit(self, W, init=None, **kwargs):
                result = super().fit(W, init=init, **kwargs)
                reports.append(result.report)
                inits.append(init)
                results.append(result)
                return result
        return Fit()


class ChunkPipeline:
    """A stand-in with LivePipeline's protocol: each frame out on ``points`` at once with
    xyz = (u, v, u + v); a 'window' of every 3 frames (and of the rest at ``flush``) gives an
    Update, its frames on ``points/refined`` alike."""

    def __init__(self):
        self.buffer, self._refined, self._updates = [], [], []

    def add_frame(self, stamp_ns, ids, uv, frame_id=''):
        if len(ids) < 3:
            raise ValueError(f'{len(ids)} tracks')
        result = SimpleNamespace(stamp_ns=stamp_ns, frame_id=frame_id, ids=ids,
                                 xyz=np.c_[uv, uv.sum(axis=1)])
        self.buffer.append(result)
        if len(self.buffer) == 3:
            self.flush()
        return (result,)

    def flush(self):
        if self.buffer:
            self._refined += self.buffer
            self._updates.append(SimpleNamespace(kind='solved', index=len(self._updates),
                                                 message='', preview=False))
        self.buffer = []

    def refined(self):
        out = (self._refined, self._updates)
        self._refined, self._updates = [], []
        return out
