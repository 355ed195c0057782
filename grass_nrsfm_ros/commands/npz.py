"""Reading the commands' ``.npz`` files (the layout of ``../shared/data``: ``W: (2F, P)``,
optional ground truth ``S: (3F, P)`` (or ``S_gt``), optional ``visible: (F, P)`` bool,
optional pinhole intrinsics ``K: (3, 3)``)."""
import contextlib
import zipfile

import numpy as np

from grass_nrsfm_ros.cli import UserError
from grass_nrsfm_ros.nrsfm.camera import validate_intrinsics
from grass_nrsfm_ros.nrsfm.measurement import InvalidInputError


@contextlib.contextmanager
def opened(path):
    """``np.load(path)`` of an .npz archive, or UserError naming the file."""
    try:
        npz = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise
    except (ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
        raise UserError(f'{path}: not a readable .npz archive ({exc.__class__.__name__})') \
            from None
    if not isinstance(npz, np.lib.npyio.NpzFile):
        raise UserError(f'{path}: a single .npy array, not an .npz archive of named arrays')
    with npz:
        yield npz


def load_tracks(path):
    """``(W: (2F, P) float64, S: (3F, P) float64 or None, visible: (F, P) bool or None)``.

    Only the presence of ``W`` is checked here; shapes and values are the solver's to check.
    """
    with opened(path) as npz:
        if 'W' not in npz:
            raise UserError(f'{path} has no array W (has {sorted(npz.files)})')
        S = next((npz[k] for k in GROUND_TRUTH_KEYS if k in npz), None)
        visible = np.asarray(npz['visible'], bool) if 'visible' in npz else None
        W = np.asarray(npz['W'])
    if W.dtype.kind not in 'fiu':
        raise UserError(f'{path}: W must be numeric; got dtype {W.dtype}')
    return W.astype(np.float64), None if S is None else np.asarray(S, np.float64), visible


def load_camera(path):
    """``K: (3, 3)`` float64 of an .npz (validated), or None where it has none."""
    with opened(path) as npz:
        if 'K' not in npz:
            return None
        K = np.asarray(npz['K'])
    try:
        return validate_intrinsics(K, name=f'{path}: K')
    except InvalidInputError as exc:
        raise UserError(str(exc)) from None


#: the shapes an .npz holds, in order of preference: an estimate's (``reconstruct`` writes
#: ``S``) and ground truth (``S_gt`` where a file holds both, like the demo's reconstruction)
ESTIMATE_KEYS, GROUND_TRUTH_KEYS = ('S',), ('S_gt', 'S')


def load_shapes(path, keys=ESTIMATE_KEYS):
    """``(S: (3F, P) float64, points: (P,) or None)`` from an .npz (the first of ``keys`` it
    holds), or UserError; ``points``: the input tracks' columns that S reconstructs (None:
    all)."""
    with opened(path) as npz:
        key = next((k for k in keys if k in npz), None)
        if key is None:
            raise UserError(f'{path} has no array S (has {sorted(npz.files)})')
        points = np.asarray(npz['points']) if 'points' in npz else None
        return np.asarray(npz[key], dtype=np.float64), points


def complete_tracks(visible, n_frames, n_points, path):
    """Column indices ``(P',)`` of the tracks seen in every frame, checking ``visible``'s
    shape ``(F, P)``."""
    if visible.shape != (n_frames, n_points):
        raise UserError(f'{path}: visible must have shape (F, P) = ({n_frames}, {n_points}); '
                        f'got {visible.shape}')
    return np.flatnonzero(visible.all(axis=0))
