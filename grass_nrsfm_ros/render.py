"""Pictures with numpy only: a PNG writer, an RGB canvas with lines and 5x7 text, point-cloud
views (z-buffered splats coloured by depth, sphere-shaded), frame figures, contact sheets
and simple line plots for benchmarks.

Shapes: a frame is ``xyz: (3, P)`` in camera coordinates (x right, y down, z forward), the
columns of ``S: (3F, P)`` rows ``3f..3f+2``. Images are ``(H, W, 3) uint8``.
"""
import struct
import zlib

import numpy as np

WHITE = (255, 255, 255)
BLACK = (0, 0, 0)
GREY = (150, 150, 150)
PALETTE = [(31, 119, 180), (214, 39, 40), (44, 160, 44), (255, 127, 14), (148, 103, 189),
           (140, 86, 75), (227, 119, 194), (23, 190, 207)]

# viridis at 8 control points; colormap() interpolates between them
_VIRIDIS = np.array([(68, 1, 84), (70, 50, 126), (54, 92, 141), (39, 127, 142),
                     (31, 161, 135), (74, 193, 109), (160, 218, 57), (253, 231, 37)], float)

# ---------------------------------------------------------------------------- PNG


def png_bytes(rgb):
    """PNG file contents for ``rgb: (H, W, 3) uint8`` (8-bit truecolour, filter 0, zlib)."""
    rgb = np.ascontiguousarray(rgb, dtype=np.uint8)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or 0 in rgb.shape:
        raise ValueError(f'expected a non-empty (H, W, 3) image; got shape {rgb.shape}')
    h, w, _ = rgb.shape
    rows = np.concatenate([np.zeros((h, 1), np.uint8), rgb.reshape(h, 3 * w)], axis=1)

    def chunk(tag, data):
        return (struct.pack('>I', len(data)) + tag + data
                + struct.pack('>I', zlib.crc32(tag + data) & 0xFFFFFFFF))

    header = struct.pack('>IIBBBBB', w, h, 8, 2, 0, 0, 0)
    return (b'\x89PNG\r\n\x1a\n' + chunk(b'IHDR', header)
            + chunk(b'IDAT', zlib.compress(rows.tobytes(), 6)) + chunk(b'IEND', b''))


def write_png(path, rgb):
    """Write ``rgb: (H, W, 3) uint8`` to ``path`` as a PNG."""
    data = png_bytes(rgb)
    with open(path, 'wb') as f:
        f.write(data)


# ---------------------------------------------------------------------------- colour


def colormap(t):
    """Viridis-like colours ``(N, 3) uint8`` for ``t: (N,)`` in [0, 1] (clipped)."""
    t = np.clip(np.nan_to_num(np.asarray(t, float)), 0.0, 1.0) * (len(_VIRIDIS) - 1)
    i = np.minimum(t.astype(int), len(_VIRIDIS) - 2)
    frac = (t - i)[:, None]
    return np.round(_VIRIDIS[i] * (1 - frac) + _VIRIDIS[i + 1] * frac).astype(np.uint8)


# ---------------------------------------------------------------------------- text

_GLYPHS = {
    '0': '01110 10001 10011 10101 11001 10001 01110',
    '1': '00100 01100 00100 00100 00100 00100 01110',
    '2': '01110 10001 00001 00010 00100 01000 11111',
    '3': '11111 00010 00100 00010 00001 10001 01110',
    '4': '00010 00110 01010 10010 11111 00010 00010',
    '5': '11111 10000 11110 00001 00001 10001 01110',
    '6': '00110 01000 10000 11110 10001 10001 01110',
    '7': '11111 00001 00010 00100 01000 01000 01000',
    '8': '01110 10001 10001 01110 10001 10001 01110',
    '9': '01110 10001 10001 01111 00001 00010 01100',
    'A': '01110 10001 10001 10001 11111 10001 10001',
    'B': '11110 10001 10001 11110 10001 10001 11110',
    'C': '01110 10001 10000 10000 10000 10001 01110',
    'D': '11100 10010 10001 10001 10001 10010 11100',
    'E': '11111 10000 10000 11110 10000 10000 11111',
    'F': '11111 10000 10000 11110 10000 10000 10000',
    'G': '01110 10001 10000 10111 10001 10001 01111',
    'H': '10001 10001 10001 11111 10001 10001 10001',
    'I': '01110 00100 00100 00100 00100 00100 01110',
    'J': '00111 00010 00010 00010 00010 10010 01100',
    'K': '10001 10010 10100 11000 10100 10010 10001',
    'L': '10000 10000 10000 10000 10000 10000 11111',
    'M': '10001 11011 10101 10101 10001 10001 10001',
    'N': '10001 10001 11001 10101 10011 10001 10001',
    'O': '01110 10001 10001 10001 10001 10001 01110',
    'P': '11110 10001 10001 11110 10000 10000 10000',
    'Q': '01110 10001 10001 10001 10101 10010 01101',
    'R': '11110 10001 10001 11110 10100 10010 10001',
    'S': '01111 10000 10000 01110 00001 00001 11110',
    'T': '11111 00100 00100 00100 00100 00100 00100',
    'U': '10001 10001 10001 10001 10001 10001 01110',
    'V': '10001 10001 10001 10001 10001 01010 00100',
    'W': '10001 10001 10001 10101 10101 10101 01010',
    'X': '10001 10001 01010 00100 01010 10001 10001',
    'Y': '10001 10001 10001 01010 00100 00100 00100',
    'Z': '11111 00001 00010 00100 01000 10000 11111',
    ' ': '00000 00000 00000 00000 00000 00000 00000',
    '.': '00000 00000 00000 00000 00000 01100 01100',
    ',': '00000 00000 00000 00000 01100 00100 01000',
    '-': '00000 00000 00000 11111 00000 00000 00000',
    '+': '00000 00100 00100 11111 00100 00100 00000',
    ':': '00000 01100 01100 00000 01100 01100 00000',
    '/': '00000 00001 00010 00100 01000 10000 00000',
    '(': '00010 00100 01000 01000 01000 00100 00010',
    ')': '01000 00100 00010 00010 00010 00100 01000',
    '=': '00000 00000 11111 00000 11111 00000 00000',
    '%': '11000 11001 00010 00100 01000 10011 00011',
    '_': '00000 00000 00000 00000 00000 00000 11111',
    '?': '01110 10001 00001 00010 00100 00000 00100',
}
_FONT = {c: np.array([[b == '1' for b in row] for row in g.split()], bool)
         for c, g in _GLYPHS.items()}
GLYPH_W, GLYPH_H = 6, 7        # advance (5 + 1 space) and height, at scale 1


def text_mask(s, scale=1):
    """Boolean ``(7*scale, 6*scale*len(s))`` mask of ``s`` (upper-cased; unknown -> '?')."""
    cols = [np.pad(_FONT.get(c, _FONT['?']), ((0, 0), (0, 1))) for c in s.upper()] or \
        [np.zeros((GLYPH_H, 0), bool)]
    mask = np.concatenate(cols, axis=1)
    return np.kron(mask, np.ones((scale, scale), bool)).astype(bool)


# ---------------------------------------------------------------------------- canvas


class Canvas:
    """An RGB image ``rgb: (H, W, 3) uint8`` with simple drawing; coordinates are pixels,
    x right, y down; everything is clipped to the canvas."""

    def __init__(self, height, width, background=WHITE):
        self.rgb = np.empty((int(height), int(width), 3), np.uint8)
        self.rgb[:] = background

    @property
    def height(self):
        return self.rgb.shape[0]

    @property
    def width(self):
        return self.rgb.shape[1]

    def paste(self, img, y, x):
        """Copy ``img: (h, w, 3)`` with its top-left corner at (x, y), clipped."""
        h, w = img.shape[:2]
        y0, x0 = max(0, y), max(0, x)
        y1, x1 = min(self.height, y + h), min(self.width, x + w)
        if y1 > y0 and x1 > x0:
            self.rgb[y0:y1, x0:x1] = img[y0 - y:y1 - y, x0 - x:x1 - x]

    def pixels(self, xs, ys, color):
        """Set pixels at integer-rounded ``xs, ys: (N,)``; ``color`` one RGB or ``(N, 3)``."""
        xs, ys = np.round(xs).astype(int), np.round(ys).astype(int)
        inside = (xs >= 0) & (xs < self.width) & (ys >= 0) & (ys < self.height)
        color = np.asarray(color, np.uint8)
        self.rgb[ys[inside], xs[inside]] = color[inside] if color.ndim == 2 else color

    def line(self, x0, y0, x1, y1, color=BLACK, width=1):
        """A straight segment, ``width`` pixels thick."""
        n = int(max(abs(x1 - x0), abs(y1 - y0))) + 1
        t = np.linspace(0.0, 1.0, n)
        xs, ys = x0 + (x1 - x0) * t, y0 + (y1 - y0) * t
        for d in range(width):
            off = d - (width - 1) / 2
            if abs(x1 - x0) >= abs(y1 - y0):
                self.pixels(xs, ys + off, color)
            else:
                self.pixels(xs + off, ys, color)

    def polyline(self, xs, ys, color=BLACK, width=1):
        for i in range(len(xs) - 1):
            self.line(xs[i], ys[i], xs[i + 1], ys[i + 1], color, width)

    def rect(self, x0, y0, x1, y1, color=BLACK):
        """Outline of the box with corners (x0, y0), (x1, y1)."""
        self.polyline([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0], color)

    def markers(self, xs, ys, color=BLACK, radius=2):
        """Filled discs at ``xs, ys: (N,)``."""
        dy, dx = np.mgrid[-radius:radius + 1, -radius:radius + 1]
        keep = dx ** 2 + dy ** 2 <= radius ** 2 + 0.5
        for ox, oy in zip(dx[keep], dy[keep]):
            self.pixels(np.asarray(xs) + ox, np.asarray(ys) + oy, color)

    def text(self, x, y, s, color=BLACK, scale=1, anchor='left'):
        """Write ``s`` with its top at ``y``; ``anchor`` left, centre or right of ``x``."""
        mask = text_mask(s, scale)
        x = int(round(x - {'left': 0, 'centre': mask.shape[1] / 2,
                           'right': mask.shape[1]}[anchor]))
        ys, xs = np.nonzero(mask)
        self.pixels(xs + x, ys + int(round(y)), color)


# ---------------------------------------------------------------------------- point clouds

VIEWS = {
    # name: ((axis, sign) to screen right, to screen down, to depth away from the viewer);
    # each a proper rotation of the camera frame, so no view is mirrored
    'front': ((0, 1), (1, 1), (2, 1)),      # as the camera sees it: x right, y down
    'side': ((2, 1), (1, 1), (0, -1)),      # from the right: camera on the left, z to the right
    'top': ((0, 1), (2, -1), (1, 1)),       # from above: camera at the bottom, z upward
}


def fit_extent(clouds, views=tuple(VIEWS)):
    """``(centre: (3,), half: float)``: one box that holds every ``(3, P)`` cloud (NaN-safe)."""
    pts = np.concatenate([np.asarray(c, float) for c in clouds if c is not None], axis=1)
    pts = pts[:, np.isfinite(pts).all(axis=0)]
    if pts.size == 0:
        return np.zeros(3), 1.0
    lo, hi = pts.min(axis=1), pts.max(axis=1)
    half = float(max((hi - lo).max() / 2, 1e-12))
    return (lo + hi) / 2, half


def splat(xyz, size=240, view='front', extent=None, radius=None, depth_range=None,
          background=WHITE):
    """``(size, size, 3) uint8`` view of ``xyz: (3, P)``: discs z-buffered along the view's
    depth axis, coloured by camera depth z (viridis, near = dark), shaded as spheres.

    ``extent`` ``(centre, half)`` from :func:`fit_extent` to share scale between panels;
    ``depth_range`` ``(zmin, zmax)`` to share colours.
    """
    xyz = np.asarray(xyz, float)
    xyz = xyz[:, np.isfinite(xyz).all(axis=0)]
    img = np.empty((size, size, 3), np.uint8)
    img[:] = background
    if xyz.shape[1] == 0:
        return img
    centre, half = extent if extent is not None else fit_extent([xyz])
    (right, s_r), (down, s_d), (depth, s_z) = VIEWS[view]
    scale = 0.45 * size / half
    sx = s_r * (xyz[right] - centre[right]) * scale + size / 2
    sy = s_d * (xyz[down] - centre[down]) * scale + size / 2
    d = s_z * xyz[depth]
    if radius is None:
        radius = int(np.clip(round(0.5 * size / np.sqrt(xyz.shape[1])), 1, 6))
    zmin, zmax = depth_range if depth_range is not None else (xyz[2].min(), xyz[2].max())
    colours = colormap((xyz[2] - zmin) / max(zmax - zmin, 1e-12)).astype(float)

    dy, dx = np.mgrid[-radius:radius + 1, -radius:radius + 1]
    r2 = (dx ** 2 + dy ** 2) / max(radius, 1) ** 2
    inside = r2 <= 1.0
    dx, dy, r2 = dx[inside], dy[inside], r2[inside]
    nz = np.sqrt(np.clip(1.0 - r2, 0.0, 1.0))                   # sphere normal (dx, dy, nz)/r
    light = np.array([-0.4, -0.5, 0.77])                        # from upper left, toward viewer
    shade = 0.45 + 0.55 * np.clip((dx * light[0] + dy * light[1]) / max(radius, 1)
                                  + nz * light[2], 0.0, 1.0)    # (K,)

    px = (np.round(sx)[:, None] + dx[None]).ravel().astype(int)   # (P*K,)
    py = (np.round(sy)[:, None] + dy[None]).ravel().astype(int)
    pd = (d[:, None] - nz[None] * (radius / scale)).ravel()   # sphere surface depth
    ok = (px >= 0) & (px < size) & (py >= 0) & (py < size)
    flat = py[ok] * size + px[ok]
    order = np.lexsort((pd[ok], flat))                   # per pixel, nearest first
    first = np.unique(flat[order], return_index=True)[1]
    win = np.flatnonzero(ok)[order[first]]               # winning (point, offset) per pixel
    point, offset = np.divmod(win, dx.size)
    rgb = colours[point] * shade[offset][:, None]
    img.reshape(-1, 3)[flat[order[first]]] = np.clip(rgb, 0, 255).astype(np.uint8)
    return img


def frame_figure(estimate=None, truth=None, title='', size=240, views=('front', 'side', 'top')):
    """A figure of one frame: a row per cloud (estimate, ground truth), a column per view;
    ``estimate``, ``truth``: ``(3, P)`` or None. The clouds share scale and depth colours."""
    rows = [(name, c) for name, c in (('estimate', estimate), ('ground truth', truth))
            if c is not None]
    if not rows:
        raise ValueError('nothing to draw: no estimate and no ground truth')
    extent = fit_extent([c for _, c in rows])
    zs = np.concatenate([np.asarray(c, float)[2] for _, c in rows])
    zs = zs[np.isfinite(zs)]
    depth_range = (zs.min(), zs.max()) if zs.size else (0.0, 1.0)
    label_w, top, gap = 14, 22 if title else 4, 4
    canvas = Canvas(top + len(rows) * (size + gap + 12), label_w + len(views) * (size + gap))
    if title:
        canvas.text(canvas.width / 2, 6, title, anchor='centre')
    for r, (name, cloud) in enumerate(rows):
        y = top + r * (size + gap + 12)
        for c, view in enumerate(views):
            x = label_w + c * (size + gap)
            canvas.text(x + size / 2, y, f'{name} {view}', GREY, anchor='centre')
            canvas.paste(splat(cloud, size, view, extent, depth_range=depth_range), y + 10, x)
            canvas.rect(x, y + 10, x + size - 1, y + 9 + size, GREY)
    return canvas.rgb


def contact_sheet(images, columns=4, background=WHITE, gap=6):
    """Tile ``(h, w, 3)`` images (equal or not) into a grid, ``columns`` wide."""
    if not images:
        raise ValueError('no images for the contact sheet')
    columns = max(1, min(columns, len(images)))
    h = max(i.shape[0] for i in images)
    w = max(i.shape[1] for i in images)
    n_rows = -(-len(images) // columns)
    canvas = Canvas(n_rows * (h + gap) + gap, columns * (w + gap) + gap, background)
    for k, img in enumerate(images):
        r, c = divmod(k, columns)
        canvas.paste(img, gap + r * (h + gap), gap + c * (w + gap))
    return canvas.rgb


# ---------------------------------------------------------------------------- plots


def nice_ticks(lo, hi, n=5):
    """About ``n`` round tick values covering [lo, hi]."""
    if not np.isfinite([lo, hi]).all() or hi <= lo:
        return np.array([lo]) if np.isfinite(lo) else np.array([0.0])
    raw = (hi - lo) / max(n, 1)
    mag = 10 ** np.floor(np.log10(raw))
    step = mag * min((s for s in (1, 2, 2.5, 5, 10) if s * mag >= raw), default=10)
    return np.arange(np.ceil(lo / step) * step, hi + step * 1e-9, step)


def _fmt(v):
    return f'{v:.3g}' if abs(v) < 1e4 else f'{v:.0e}'


def plot(series, title='', xlabel='', ylabel='', size=(360, 560), logy=False, markers=True):
    """A line plot ``(H, W, 3) uint8``: ``series`` maps a label to ``(x: (N,), y: (N,))``.

    Axes with round ticks, labels, a legend; ``logy`` plots log10(y) with 10^k labels.
    """
    H, W = size
    left, right, top, bottom = 58, 12, 26, 40
    canvas = Canvas(H, W)
    data = []
    for label, (x, y) in series.items():
        x, y = np.asarray(x, float), np.asarray(y, float)
        if logy:
            y = np.where(y > 0, np.log10(np.where(y > 0, y, 1)), np.nan)
        data.append((label, x, y))
    xs = np.concatenate([x for _, x, _ in data])
    ys = np.concatenate([y for _, _, y in data])
    xs, ys = xs[np.isfinite(xs)], ys[np.isfinite(ys)]
    x_lo, x_hi = (xs.min(), xs.max()) if xs.size else (0.0, 1.0)
    y_lo, y_hi = (ys.min(), ys.max()) if ys.size else (0.0, 1.0)
    if x_hi == x_lo:
        x_lo, x_hi = x_lo - 0.5, x_hi + 0.5
    pad = 0.05 * (y_hi - y_lo) if y_hi > y_lo else 0.5
    y_lo, y_hi = y_lo - pad, y_hi + pad

    def to_px(x, y):
        return (left + (x - x_lo) / (x_hi - x_lo) * (W - left - right),
                H - bottom - (y - y_lo) / (y_hi - y_lo) * (H - top - bottom))

    x0, y0 = to_px(x_lo, y_lo)
    x1, y1 = to_px(x_hi, y_hi)
    canvas.rect(x0, y1, x1, y0, BLACK)
    for t in nice_ticks(x_lo, x_hi):
        px, _ = to_px(t, y_lo)
        canvas.line(px, y0, px, y0 + 4)
        canvas.text(px, y0 + 7, _fmt(t), anchor='centre')
    y_ticks = np.arange(np.ceil(y_lo), np.floor(y_hi) + 1) if logy else nice_ticks(y_lo, y_hi)
    for t in y_ticks:
        _, py = to_px(x_lo, t)
        canvas.line(x0 - 4, py, x0, py)
        canvas.line(x0 + 1, py, x1 - 1, py, (232, 232, 232))
        canvas.text(x0 - 6, py - 3, f'1E{int(t)}' if logy else _fmt(t), anchor='right')
    canvas.text(W / 2, 8, title, anchor='centre')
    canvas.text((x0 + x1) / 2, H - 14, xlabel, anchor='centre')
    canvas.text(4, top - 14, ylabel)
    for k, (label, x, y) in enumerate(data):
        color = PALETTE[k % len(PALETTE)]
        ok = np.isfinite(x) & np.isfinite(y)
        px, py = to_px(x[ok], y[ok])
        canvas.polyline(px, py, color, width=2)
        if markers:
            canvas.markers(px, py, color, radius=2)
        canvas.line(x1 - 110, y1 + 10 + 12 * k, x1 - 95, y1 + 10 + 12 * k, color, width=2)
        canvas.text(x1 - 90, y1 + 7 + 12 * k, label, color)
    return canvas.rgb
