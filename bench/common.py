"""Shared pieces of the benchmark suites: modes, methods, data sets, timing, JSON output and
curve fits.

A method is called as ``solve(name, W, **options)`` and returns a dict with ``S: (3F, P)``
camera frame, ``R: (F, 3, 3)`` and optional ``report``.
"""
from dataclasses import dataclass
import datetime
import json
import os
from pathlib import Path
import platform
import subprocess
import sys
import time

import numpy as np
from threadpoolctl import threadpool_info

from grass_nrsfm_ros.nrsfm import GrassmannNRSfM
from grass_nrsfm_ros.nrsfm.baselines import bmm
from grass_nrsfm_ros.nrsfm.faces import make_face_sequence
from grass_nrsfm_ros.nrsfm.rotation import estimate_rotations, rigid_factorisation
from grass_nrsfm_ros.nrsfm.synthetic import make_sequence
from grass_nrsfm_ros.nrsfm.trajectory_basis import DEFAULT_K, pta

BENCH = Path(__file__).resolve().parent
REPO = BENCH.parent
RESULTS = BENCH / 'results'
METHODS = ('ours', 'rigid', 'bmm', 'pta')


@dataclass(frozen=True)
class Mode:
    """``name``: 'smoke' (smallest case of each suite, seconds), 'quick' (default, a few
    minutes on 2 cores) or 'full' (everything); ``out``: results folder (None: the default)."""
    name: str
    out: Path = None

    def pick(self, smoke, quick, full):
        return {'smoke': smoke, 'quick': quick, 'full': full}[self.name]

    @property
    def out_dir(self):
        if self.out is not None:
            return Path(self.out)
        return RESULTS / 'smoke' if self.name == 'smoke' else RESULTS


# --------------------------------------------------------------------------- methods

def dai_rotations(W):
    """Rotations of ``W: (2F, P)`` by Dai et al.'s method (K chosen from the data)."""
    return estimate_rotations(W).R


def solve(method, W, *, R=None, params=None, K_traj=None):
    """Run ``method`` on ``W: (2F, P)``; returns ``{'S', 'R', 'report'}``.

    ``R``: rotations for BMM (default: Dai's, estimated here) and for PTA (default: rigid
    factorisation). ``params``: keyword arguments of GrassmannNRSfM for 'ours'.
    ``K_traj``: PTA's number of DCT vectors (default: its module default).
    """
    if method == 'ours':
        res = GrassmannNRSfM(**(params or {})).fit(W)
        return {'S': res.S, 'R': res.R, 'report': res.report, 'result': res}
    if method == 'rigid':
        R_est, S = rigid_factorisation(W)
        return {'S': S, 'R': R_est, 'report': None}
    if method == 'bmm':
        R_used = dai_rotations(W) if R is None else R
        S, report = bmm(W, R_used, return_report=True)
        return {'S': S, 'R': R_used, 'report': report}
    if method == 'pta':
        R_used, S = pta(W, R=R, K=K_traj or DEFAULT_K)
        return {'S': S, 'R': R_used, 'report': None}
    raise ValueError(f'unknown method {method!r}; choose from {METHODS}')


def timed(fn, *args, **kwargs):
    """``(value, wall seconds, CPU seconds of this process)``."""
    wall, cpu = time.perf_counter(), time.process_time()
    value = fn(*args, **kwargs)
    return value, time.perf_counter() - wall, time.process_time() - cpu


def report_summary(report):
    """A JSON-able digest of a solver report (or None)."""
    if report is None:
        return None
    if hasattr(report, 'to_dict'):
        d = report.to_dict()
    elif hasattr(report, '__dataclass_fields__'):
        d = {k: getattr(report, k) for k in report.__dataclass_fields__}
    else:
        return None
    keep = ('iterations', 'converged', 'reason', 'seconds', 'K_rot', 'K_s', 'K_t', 'N_s', 'N_t',
            'gamma', 'regrouped_points', 'reprojection_relative', 'gap', 'rank', 'fallback',
            'relief')
    return jsonable({k: d[k] for k in keep if k in d})


# --------------------------------------------------------------------------- data

def data_root():
    """The benchmark data folder (``$GRASS_NRSFM_DATA`` or ``../shared/data``), or None."""
    root = Path(os.environ.get('GRASS_NRSFM_DATA', REPO.parent / 'shared' / 'data'))
    return root if root.is_dir() else None


#: sequences with ground truth in the data folder: name -> (relative path, family)
DATASETS = {
    'drink': ('akhter_mocap/drink.npz', 'mocap'),
    'pickup': ('akhter_mocap/pickup.npz', 'mocap'),
    'yoga': ('akhter_mocap/yoga.npz', 'mocap'),
    'dance': ('akhter_mocap/dance.npz', 'mocap'),
    'face': ('torresani_mocap/face.npz', 'mocap'),
    'shark': ('torresani_mocap/shark.npz', 'mocap'),
    'kinect_paper10': ('perspective_subsets/kinect_paper.npz', 'perspective'),
    'tshirt10': ('perspective_subsets/white_cartoon_tshirt.npz', 'perspective'),
}


def load_dataset(name):
    """``(W: (2F, P), S: (3F, P), family)`` float64, or None where the file is missing."""
    root = data_root()
    relpath, family = DATASETS[name]
    if root is None or not (root / relpath).is_file():
        return None
    with np.load(root / relpath) as npz:
        return npz['W'].astype(np.float64), npz['S'].astype(np.float64), family


def synthetic(kind, F, P, seed=0, noise=0.0, clustered=0.0):
    """``(W, S)`` of :func:`grass_nrsfm_ros.nrsfm.synthetic.make_sequence` (orbiting camera)."""
    seq = make_sequence(kind, n_frames=F, n_points=P, seed=seed, noise=noise,
                        clustered=clustered)
    return seq.W, seq.S


def dense_face(F, P, seed=0):
    """``(W, S)`` of a Surrey-model dense face, or None without the model."""
    try:
        seq = make_face_sequence(n_frames=F, n_points=P, seed=seed)
    except FileNotFoundError:
        return None
    return seq.W, seq.S


def add_noise(W, r, rng):
    """``W + N(0, sigma^2)`` with the paper's ``sigma = r * max|centred W|``."""
    Wc = W - W.mean(axis=1, keepdims=True)
    return W + rng.normal(0.0, r * np.abs(Wc).max(), W.shape)


# --------------------------------------------------------------------------- output

def jsonable(x):
    """``x`` with numpy scalars/arrays turned into plain Python (NaN/inf become None)."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, (np.bool_, bool)):
        return bool(x)
    if isinstance(x, (np.integer, int)):
        return int(x)
    if isinstance(x, (np.floating, float)):
        return float(x) if np.isfinite(x) else None
    return x


def environment():
    """Where and how the numbers were taken."""
    try:
        commit = subprocess.run(['git', '-C', str(REPO), 'rev-parse', '--short', 'HEAD'],
                                capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        commit = ''
    return {'date': datetime.datetime.now().isoformat(timespec='seconds'),
            'git': commit, 'python': platform.python_version(), 'numpy': np.__version__,
            'machine': platform.machine(), 'cpus': os.cpu_count(), 'cpu_model': cpu_model(),
            'blas_threads': os.environ.get('OPENBLAS_NUM_THREADS'),
            'blas_kernel': blas_kernel(), 'argv': sys.argv}


def cpu_model():
    """The CPU's model name as the kernel reports it (timings differ between machines), or
    None where /proc/cpuinfo does not say."""
    try:
        lines = Path('/proc/cpuinfo').read_text().splitlines()
    except OSError:
        return None
    names = [line.split(':', 1)[1].strip() for line in lines if line.startswith('model name')]
    return names[0] if names else None


def blas_kernel():
    """The BLAS kernel numpy's OpenBLAS runs (its 'architecture', which OPENBLAS_CORETYPE
    sets), or None where threadpoolctl does not report one."""
    kernels = {info.get('architecture') for info in threadpool_info()
               if info.get('internal_api') == 'openblas'} - {None}
    return ', '.join(sorted(kernels)) or None


def merge_result(path, key, figures):
    """Write ``figures`` into the JSON file ``path`` (under ``key``, or merged at the top),
    keeping its other keys."""
    old = json.loads(path.read_text()) if path.exists() else {}
    new = {**old, key: figures} if key else {**old, **figures}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(new, indent=1, sort_keys=True) + '\n')


def write_result(mode, suite, payload):
    """Write ``<out>/<suite>.json``; returns its path."""
    out = mode.out_dir
    out.mkdir(parents=True, exist_ok=True)
    path = out / f'{suite}.json'
    doc = {'suite': suite, 'mode': mode.name, 'environment': environment(), **payload}
    path.write_text(json.dumps(jsonable(doc), indent=1) + '\n')
    return path


def loglog_slope(x, y):
    """Least-squares slope of ``log y`` against ``log x`` (the growth exponent), or None."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    ok = (x > 0) & (y > 0) & np.isfinite(x) & np.isfinite(y)
    if ok.sum() < 2 or np.ptp(np.log(x[ok])) == 0:
        return None
    return float(np.polyfit(np.log(x[ok]), np.log(y[ok]), 1)[0])


def log(msg):
    """Progress to stderr (results go to JSON)."""
    print(msg, file=sys.stderr, flush=True)


def study_sequence(mode):
    """``(name, (W, S))`` of the parameter and noise studies: a dense face (a synthetic bending
    sheet where the face model is absent), sized by the mode."""
    if mode.name == 'smoke':
        return 'synthetic_bending', synthetic('bending', 10, 100)
    F, P = mode.pick(None, (30, 1000), (99, 5000))
    face = dense_face(F, P)
    if face is not None:
        return f'dense_face_{F}x{P}', face
    return 'synthetic_bending', synthetic('bending', F, P)
