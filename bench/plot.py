"""PNG plots for the benchmark results, no matplotlib.

Uses the package's renderer (``grass_nrsfm_ros.render``: ``plot`` and ``write_png``) where it
exists; until then a minimal fallback draws axes, lines and markers without any text (the
titles and axis names are in the JSON beside each plot). ``line_plot`` and ``matrix_image`` are
the only entry points the suites use, so the switch is in one place.
"""
import struct
import zlib

import numpy as np

PALETTE = ((31, 119, 180), (214, 39, 40), (44, 160, 44), (255, 127, 14), (148, 103, 189),
           (140, 86, 75), (227, 119, 194), (127, 127, 127))


def _renderer():
    try:
        from grass_nrsfm_ros import render
    except ImportError:
        return None
    return render if hasattr(render, 'plot') and hasattr(render, 'write_png') else None


def png_bytes(rgb):
    """PNG file bytes of ``rgb: (H, W, 3) uint8``."""
    rgb = np.ascontiguousarray(rgb, dtype=np.uint8)
    h, w, _ = rgb.shape
    raw = np.concatenate([np.zeros((h, 1), np.uint8), rgb.reshape(h, 3 * w)], axis=1)

    def chunk(tag, data):
        return (struct.pack('>I', len(data)) + tag + data
                + struct.pack('>I', zlib.crc32(tag + data) & 0xffffffff))
    return (b'\x89PNG\r\n\x1a\n' + chunk(b'IHDR', struct.pack('>IIBBBBB', w, h, 8, 2, 0, 0, 0))
            + chunk(b'IDAT', zlib.compress(raw.tobytes(), 6)) + chunk(b'IEND', b''))


def write_png(path, rgb):
    render = _renderer()
    if render is not None:
        return render.write_png(path, rgb)
    with open(path, 'wb') as fh:
        fh.write(png_bytes(rgb))
    return path


def _draw_segment(img, x0, y0, x1, y1, color):
    n = int(max(abs(x1 - x0), abs(y1 - y0))) + 1
    xs = np.rint(np.linspace(x0, x1, n)).astype(int)
    ys = np.rint(np.linspace(y0, y1, n)).astype(int)
    for dx in (0, 1):
        ok = (ys >= 0) & (ys < img.shape[0]) & (xs + dx >= 0) & (xs + dx < img.shape[1])
        img[ys[ok], xs[ok] + dx] = color


def _fallback_plot(series, size, logy):
    H, W = size
    img = np.full((H, W, 3), 255, np.uint8)
    data = []
    for x, y in series.values():
        x, y = np.asarray(x, float), np.asarray(y, float)
        if logy:
            y = np.log10(np.where(y > 0, y, np.nan))
        ok = np.isfinite(x) & np.isfinite(y)
        data.append((x[ok], y[ok]))
    xs = np.concatenate([d[0] for d in data] + [np.zeros(0)])
    ys = np.concatenate([d[1] for d in data] + [np.zeros(0)])
    if xs.size == 0:
        return img
    lo_x, hi_x = xs.min(), xs.max() + (xs.max() == xs.min())
    lo_y, hi_y = ys.min(), ys.max() + (ys.max() == ys.min())
    m = 20

    def px(x, y):
        return (m + (x - lo_x) / (hi_x - lo_x) * (W - 2 * m),
                H - m - (y - lo_y) / (hi_y - lo_y) * (H - 2 * m))
    _draw_segment(img, m, H - m, W - m, H - m, (0, 0, 0))
    _draw_segment(img, m, m, m, H - m, (0, 0, 0))
    for k, (x, y) in enumerate(data):
        color = PALETTE[k % len(PALETTE)]
        pts = [px(a, b) for a, b in zip(x, y)]
        for (a0, b0), (a1, b1) in zip(pts, pts[1:]):
            _draw_segment(img, a0, b0, a1, b1, color)
        for a, b in pts:
            r, c = int(round(b)), int(round(a))
            img[max(r - 2, 0):r + 3, max(c - 2, 0):c + 3] = color
    return img


def line_plot(path, series, title='', xlabel='', ylabel='', logy=False, size=(360, 560)):
    """Write a line plot PNG; ``series`` maps a label to ``(x: (N,), y: (N,))``."""
    series = {k: v for k, v in series.items() if len(v[0])}
    if not series:
        return None
    render = _renderer()
    if render is not None:
        rgb = render.plot(series, title=title, xlabel=xlabel, ylabel=ylabel, size=size,
                          logy=logy)
    else:
        rgb = _fallback_plot(series, size, logy)
    write_png(path, rgb)
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
