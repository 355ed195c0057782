"""The numerical core of grass_nrsfm_ros: numpy, scipy and scikit-learn only, no ROS.

Conventions (see :mod:`.measurement`): ``W: (2F, P)`` tracks, ``S: (3F, P)`` camera-frame
shapes, ``R: (F, 3, 3)`` world-to-camera rotations. The estimator is :mod:`.solver`, Algorithm 1
:mod:`.admm`, its add-ons :mod:`.stages`, the parameters :mod:`.schema`.
"""
from .admm import AdmmSettings, AdmmState
from .measurement import centre, InvalidInputError, validate_tracks
from .metrics import e3d, e3d_akhter, procrustes_align, rotation_error
from .problem import NRSfMResult, SolverReport, WarmStart
from .rotation import align_rotations, estimate_rotations, rigid_factorisation
from .schema import Param, SOLVER_PARAMS
from .solver import GrassmannNRSfM

__all__ = ['AdmmSettings', 'AdmmState', 'InvalidInputError', 'centre',
           'validate_tracks', 'e3d', 'e3d_akhter', 'procrustes_align', 'rotation_error',
           'GrassmannNRSfM', 'NRSfMResult', 'SolverReport', 'WarmStart', 'align_rotations',
           'estimate_rotations', 'rigid_factorisation', 'Param', 'SOLVER_PARAMS']
