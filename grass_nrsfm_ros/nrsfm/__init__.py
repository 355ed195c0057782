"""The numerical core of grass_nrsfm_ros: numpy, scipy and scikit-learn only, no ROS.

Conventions (see :mod:`.measurement`): ``W: (2F, P)`` tracks, ``S: (3F, P)`` camera-frame
shapes, ``R: (F, 3, 3)`` world-to-camera rotations.
"""
from .admm import GrassmannNRSfM, NRSfMResult, SolverReport, WarmStart
from .measurement import centre, InvalidInputError, validate_tracks
from .metrics import e3d, e3d_akhter, procrustes_align, rotation_error

__all__ = ['InvalidInputError', 'centre', 'validate_tracks', 'e3d', 'e3d_akhter',
           'procrustes_align', 'rotation_error', 'GrassmannNRSfM', 'NRSfMResult',
           'SolverReport', 'WarmStart']
