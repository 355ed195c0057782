"""PNG plots for the benchmark results, no matplotlib: the package's renderer
(:func:`grass_nrsfm_ros.render.plot` and :func:`~grass_nrsfm_ros.render.write_png`).
``line_plot`` and ``matrix_image`` are the only entry points the suites use.
"""
import numpy as np

from grass_nrsfm_ros.render import plot, write_png


def line_plot(path, series, title='', xlabel='', ylabel='', logy=False, size=(360, 560)):
    """Write a line plot PNG; ``series`` maps a label to ``(x: (N,), y: (N,))``. Returns the
    path, or None when no series has a point."""
    series = {k: v for k, v in series.items() if len(v[0])}
    if not series:
        return None
    write_png(path, plot(series, title=title, xlabel=xlabel, ylabel=ylabel, size=size,
                         logy=logy))
    return path


def matrix_image(path, M, scale=4):
    """Write ``|M|`` (any 2-D array) as a grey-scale PNG, each entry ``scale`` pixels square,
    black = largest magnitude."""
    A = np.abs(np.asarray(M, float))
    A = A / A.max() if A.max() > 0 else A
    grey = np.rint(255 * (1.0 - A)).astype(np.uint8)
    grey = np.repeat(np.repeat(grey, scale, axis=0), scale, axis=1)
    write_png(path, np.repeat(grey[:, :, None], 3, axis=2))
    return path
