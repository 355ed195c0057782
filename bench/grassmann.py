"""Why the Grassmannian terms are inert (issue 23): one ADMM run with both branches, probed.

Per iteration: how much zeta_s moves S (``||zeta_s(S) - S||^2 / ||S||^2`` summed over the
groups) and how much zeta_t moves the thresholded S# (``||(B - I) S#||^2 / ||S#||^2``), the
rank S# keeps after the SVT against N_t. At the end: the objective's terms (data, nuclear, the
lambda-weighted self-expression errors and coefficient norms), the largest normalised
off-diagonal of Omega_s / Omega_t (0: the subspaces are orthogonal, 1: identical), points
regrouped, block boundaries moved, and e3D of the same solve without either branch.
"""
import numpy as np

from grass_nrsfm_ros.nrsfm import config, grassmann as gm
from grass_nrsfm_ros.nrsfm.admm import AdmmState, stop_reason, Timer
from grass_nrsfm_ros.nrsfm.measurement import from_frames
from grass_nrsfm_ros.nrsfm.metrics import e3d
from grass_nrsfm_ros.nrsfm.problem import initial_shapes, Problem
from grass_nrsfm_ros.nrsfm.rotation import estimate_rotations
from grass_nrsfm_ros.nrsfm.schema import solver_defaults
from . import common


class ProbedState(AdmmState):
    """An AdmmState that records what zeta_s and zeta_t change in each iteration."""

    def _zeta_group(self, k):
        before = self._group(k).copy()
        super()._zeta_group(k)
        self.zeta_s_moved += float(np.sum((self._group(k) - before) ** 2))
        self.zeta_s_norm += float(np.sum(before ** 2))

    def _temporal(self, G1, beta, it):
        B, bases = super()._temporal(G1, beta, it)
        D = B - np.eye(self.F)
        self.zeta_t_share = float(np.trace(D @ G1 @ D.T) / max(np.trace(G1), 1e-300))
        sv = np.sqrt(np.maximum(np.linalg.eigvalsh(G1), 0.0))
        self.sharp_rank = int((sv > 1e-6 * sv.max()).sum())
        return B, bases

    def iterate(self, timer):
        self.zeta_s_moved = self.zeta_s_norm = 0.0
        self.zeta_t_share, self.sharp_rank = None, None
        return super().iterate(timer)


def max_off_diagonal(Omega):
    """Largest ``|Omega_ij| / sqrt(Omega_ii Omega_jj)``, i != j (0 for one point)."""
    d = np.sqrt(np.diag(Omega))
    M = np.abs(Omega) / np.outer(d, d)
    np.fill_diagonal(M, 0.0)
    return float(M.max()) if M.size > 1 else 0.0


def probe(W, S_gt, overrides):
    """One probed solve of ``W: (2F, P)`` (Dai's rotations, plain norm); a row of figures."""
    problem = Problem.from_tracks(W)
    params = {**solver_defaults(), **overrides}
    F, P = problem.F, problem.P
    R = estimate_rotations(problem.Wn).R
    K_s, K_t, N_s, N_t = config.sizes(params, F, P, None)
    spatial = params['spatial'] and config.spatial_off_reason(params, K_s, N_s, P, None) is None
    settings = config.admm_settings(params, F, P, None, spatial)
    state = ProbedState(problem.Wn, R, initial_shapes(problem, R), settings)
    edges0 = state.t_edges.copy()
    timer, trace = Timer(), []
    for it in range(settings.max_iter):
        objective, gaps = state.iterate(timer)
        trace.append({'iteration': it + 1, 'beta': state.beta,
                      'zeta_s_share': state.zeta_s_moved / max(state.zeta_s_norm, 1e-300)
                      if spatial else None,
                      'zeta_t_share': state.zeta_t_share, 'sharp_rank': state.sharp_rank})
        if stop_reason(state, objective, gaps):
            break
    s = settings
    sv = np.linalg.svd(state.S.reshape(F, -1).astype(np.float64), compute_uv=False)
    S_cam = from_frames(np.matmul(R, state.S_world_original_order())) * problem.scale
    terms = {'data_half': 0.5 * state.data, 'gamma_nuclear': None,
             'lambda1_selfexpr': s.lambda1 * gm.embedding_error(state.C_s, state.Omega_s)
             if spatial else None,
             'lambda2_selfexpr': s.lambda2 * gm.embedding_error(state.C_t, state.Omega_t)
             if s.temporal else None,
             'lambda4_nuclear_Ct': s.lambda4 * state.nuc_jt if s.temporal else None}
    terms['gamma_nuclear'] = s.gamma * float(sv.sum())
    return {'K_s': K_s, 'K_t': K_t, 'N_s': N_s, 'N_t': N_t, 'spatial_on': spatial,
            'iterations': len(trace), 'e3d': e3d(S_cam, S_gt), 'terms': terms,
            'regroup_every': s.regroup_every,
            'omega_s_max_off_diagonal': max_off_diagonal(state.Omega_s) if spatial else None,
            'omega_t_max_off_diagonal': max_off_diagonal(state.Omega_t) if s.temporal else None,
            'regrouped_points': state.moves,
            'block_edges_moved': int(np.abs(state.t_edges - edges0).sum()),
            'sharp_rank_final': int((sv > 1e-6 * sv[0]).sum()),
            'zeta_s_share_max': max((t['zeta_s_share'] or 0.0) for t in trace),
            'zeta_t_share_max': max((t['zeta_t_share'] or 0.0) for t in trace),
            'trace': trace[::10] + trace[-1:]}


def cases(mode):
    if mode.name == 'smoke':
        yield 'synthetic_bending', common.synthetic('bending', 10, 100)
        return
    F, P = mode.pick(None, (99, 5000), (99, 5000))
    face = common.dense_face(F, P)
    if face is not None:
        yield f'dense_face_{F}x{P}', face
    loaded = common.load_dataset('pickup')
    if loaded is not None:
        yield 'pickup', loaded[:2]


def run(mode):
    rows = []
    for name, (W, S) in cases(mode):
        for label, overrides in (('both', {}), ('none', {'spatial': False, 'temporal': False})):
            common.log(f'grassmann: {name} {label}')
            row = {'sequence': name, 'setting': label, 'F': W.shape[0] // 2, 'P': W.shape[1],
                   **probe(np.asarray(W, float), np.asarray(S, float), overrides)}
            rows.append(row)
            print(f"{name} {label}: e3d {row['e3d']:.4f} K_s {row['K_s']} N_s {row['N_s']} "
                  f"K_t {row['K_t']} N_t {row['N_t']} rank(S#) {row['sharp_rank_final']} "
                  f"zeta_s max {row['zeta_s_share_max']:.2e} zeta_t max "
                  f"{row['zeta_t_share_max']:.2e} moved {row['regrouped_points']} edges "
                  f"{row['block_edges_moved']} terms "
                  f"{ {k: None if v is None else round(v, 6) for k, v in row['terms'].items()} }",
                  flush=True)
    return {'rows': rows, 'skipped': []}
