"""PNG plots for the benchmark results, with matplotlib (the ``[plot]`` extra): figures are
made with ``matplotlib.figure.Figure`` and saved by the Agg canvas, so no GUI backend and no
pyplot state are involved.

``line_plot``, ``bar_plot`` and ``matrix_image`` are the entry points the suites use; each
writes one PNG with axes, ticks, axis labels (with units) and a legend, and returns its path.
"""
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
import numpy as np

DPI = 100


def _figure(height_in, width_in):
    fig = Figure(figsize=(width_in, height_in))
    FigureCanvasAgg(fig)
    return fig, fig.add_subplot()


def _save(fig, path):
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    return path


def line_plot(path, series, title='', xlabel='', ylabel='', logy=False, size=(360, 560),
              logx=False):
    """Write a line plot; ``series`` maps a label to ``(x: (N,), y: (N,))``; ``size`` is
    ``(height, width)`` in pixels. Returns ``path``, or None when every series is empty."""
    series = {k: v for k, v in series.items() if len(v[0])}
    if not series:
        return None
    fig, ax = _figure(size[0] / DPI, size[1] / DPI)
    for label, (x, y) in series.items():
        ax.plot(np.asarray(x, float), np.asarray(y, float), marker='o', ms=4, label=label)
    ax.set_xscale('log' if logx else 'linear')
    ax.set_yscale('log' if logy else 'linear')
    ax.set(title=title, xlabel=xlabel, ylabel=ylabel)
    ax.grid(True, which='both', alpha=0.3)
    ax.legend(fontsize='small')
    return _save(fig, path)


def bar_plot(path, values, title='', ylabel='', size=(360, 640)):
    """Write a bar chart of ``values`` (label -> number), each bar labelled with its value."""
    fig, ax = _figure(size[0] / DPI, size[1] / DPI)
    labels = list(values)
    bars = ax.bar(range(len(labels)), [values[k] for k in labels],
                  color=[f'C{i}' for i in range(len(labels))], label=labels)
    ax.bar_label(bars, fmt='%.2f')
    ax.set_xticks(range(len(labels)), [''] * len(labels))
    ax.set(title=title, ylabel=ylabel)
    ax.set_ylim(0, max(1.0, 1.2 * max(values.values())))
    ax.legend(fontsize='small', loc='upper left')
    ax.grid(True, axis='y', alpha=0.3)
    return _save(fig, path)


def matrix_image(path, M, scale=4, title='', label='|entry|'):
    """Write ``|M|`` (any 2-D array) as an image with a colour bar; ``scale`` pixels per entry
    (at least 3 inches wide)."""
    A = np.abs(np.asarray(M, float))
    h, w = A.shape
    width = max(3.0, w * scale / DPI + 1.2)
    fig, ax = _figure(max(2.5, width * h / max(w, 1)), width)
    im = ax.imshow(A, cmap='Greys', interpolation='nearest', aspect='auto')
    fig.colorbar(im, ax=ax, label=label)
    ax.set(title=title, xlabel='column', ylabel='row')
    return _save(fig, path)
