"""From validated parameters to one ADMM solve's :class:`~.admm.AdmmSettings`.

``params``: the dict :func:`.schema.validate_solver` returns. The validated parameters are
never changed; each solve gets its own settings (sizes resolved from ``(F, P)``, the spatial
branch switched off where a single group would remain, gamma made absolute) and this module's
constants (the numbers of Algorithm 1 that are not parameters).
"""
import numpy as np

from .admm import AdmmSettings

#: points per spatial group that 'auto' K_s aims at, in units of N_s + 1
POINTS_PER_GROUP = 20
#: constants of Algorithm 1 that no user needs to set (parameters until docs/decisions/0430):
#: the nuclear-norm weights on C_s and C_t: the Grassmann terms change almost nothing (0502)
LAMBDA3 = 0.1
LAMBDA4 = 0.1
#: xi's LRR affinity |C|^SIGMA_EPS and its gate: groups or blocks exchange points only at an
#: affinity of at least AFFINITY_MIN (the paper's; record 0007)
SIGMA_EPS = 4.0
AFFINITY_MIN = 0.5
#: iterations between xi's regroupings (record 0007)
REGROUP_EVERY = 10
#: numerical safeguard of the kernels Omega: adds DELTA * trace(Omega) / K * I
DELTA = 1e-8
#: initial beta of a solve from given shapes that are not resumed (a sliding window's rigid
#: start; records 0011, 0035): it lets the run move as far from its start as it needs
WARM_BETA0 = 0.01


def sizes(params, F, P, groups):
    """``(K_s, K_t, N_s, N_t)``: the given values, or 'auto' resolved from ``(F, P)``:
    ``N_s = min(3F - 1, 5)``, ``K_s = clip(P / (20 (N_s + 1)), 1, 20)`` (the number of given
    ``groups: (P,)`` when there are some), ``K_t = clip(round(F / 20), 1, 10)``,
    ``N_t = min(3, F // K_t)``."""
    N_s = params['N_s'] if params['N_s'] != 'auto' else int(min(3 * F - 1, 5))
    if groups is not None:
        K_s = int(len(np.unique(groups)))
    elif params['K_s'] != 'auto':
        K_s = params['K_s']
    else:
        K_s = int(np.clip(P // (POINTS_PER_GROUP * (N_s + 1)), 1, 20))
    K_s = max(1, min(K_s, P // (N_s + 1)))
    K_t = params['K_t'] if params['K_t'] != 'auto' else int(np.clip(round(F / 20), 1, 10))
    K_t = max(1, min(K_t, F))
    N_t = params['N_t'] if params['N_t'] != 'auto' else int(min(3, F // K_t))
    return K_s, K_t, N_s, N_t


def spatial_off_reason(params, K_s, N_s, P, groups):
    """Why the spatial branch is off for this solve although asked for, or None: 'auto' K_s
    left one group, which would make zeta_s a global rank-N_s constraint."""
    if not (params['spatial'] and K_s == 1 and params['K_s'] == 'auto'):
        return None
    if groups is not None:
        return 'init.groups hold one group'
    return (f'P={P} is too few points for K_s >= 2 groups of > '
            f'{POINTS_PER_GROUP * (N_s + 1)} points')


def admm_settings(params, F, P, groups, spatial):
    """The :class:`AdmmSettings` of a solve of ``F`` frames and ``P`` tracks with the spatial
    branch on or off."""
    K_s, K_t, N_s, N_t = sizes(params, F, P, groups)
    return AdmmSettings(
        gamma=params['gamma'] * np.sqrt(F * P), lambda1=params['lambda1'],
        lambda2=params['lambda2'], lambda3=LAMBDA3, lambda4=LAMBDA4, sigma_eps=SIGMA_EPS,
        affinity_min=AFFINITY_MIN, regroup_every=REGROUP_EVERY, delta=DELTA, rho=params['rho'],
        beta0=params['beta0'], beta_max=params['beta_max'], warm_beta0=WARM_BETA0,
        smoothness=params['smoothness'], spatial=spatial, temporal=params['temporal'],
        random_state=params['random_state'], max_iter=params['max_iter'], K_s=K_s, K_t=K_t,
        N_s=N_s, N_t=N_t)
