"""Pictures with matplotlib (the ``[plot]`` extra): figures of one reconstructed frame (front,
side and top views, ground truth beside), contact sheets of many frames, a mesh marker's
triangles in 3D, PNG files.

Figures are made with ``matplotlib.figure.Figure`` on the Agg canvas (headless; no pyplot
state). Shapes: a frame is ``xyz: (3, P)`` in camera coordinates (x right, y down, z forward),
the columns of ``S: (3F, P)`` rows ``3f..3f+2``. Images are ``(H, W, 3) uint8``.
"""
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
import matplotlib.image
from mpl_toolkits.mplot3d.art3d import Poly3DCollection
import numpy as np

DPI = 100
AXES = 'xyz'
VIEWS = {
    # name: ((axis, sign) to screen right, to screen down, to depth away from the viewer);
    # each a proper rotation of the camera frame, so no view is mirrored
    'front': ((0, 1), (1, 1), (2, 1)),      # as the camera sees it: x right, y down
    'side': ((2, 1), (1, 1), (0, -1)),      # from the right: camera on the left, z to the right
    'top': ((0, 1), (2, -1), (1, 1)),       # from above: camera at the bottom, z upward
}


def fit_extent(clouds):
    """``(centre: (3,), half: float)``: one box that holds every ``(3, P)`` cloud (NaN-safe)."""
    pts = np.concatenate([np.asarray(c, float) for c in clouds if c is not None], axis=1)
    pts = pts[:, np.isfinite(pts).all(axis=0)]
    if pts.size == 0:
        return np.zeros(3), 1.0
    lo, hi = pts.min(axis=1), pts.max(axis=1)
    return (lo + hi) / 2, float(max((hi - lo).max() / 2, 1e-12))


def draw_order(xyz, view):
    """Indices of the finite points of ``xyz: (3, P)`` farthest first along ``view``'s depth,
    so that the nearest are drawn last (on top)."""
    xyz = np.asarray(xyz, float)
    (_, _), (_, _), (depth, sign) = VIEWS[view]
    finite = np.flatnonzero(np.isfinite(xyz).all(axis=0))
    return finite[np.argsort(-sign * xyz[depth, finite], kind='stable')]


def draw_view(ax, xyz, view, extent, depth_range, units=''):
    """Scatter ``xyz: (3, P)`` on ``ax`` as ``view`` shows it, coloured by camera depth z
    (viridis, near = dark) within ``depth_range``; axes in true coordinates (``units``)."""
    (right, s_r), (down, s_d), _ = VIEWS[view]
    centre, half = extent
    order = draw_order(xyz, view)
    xyz = np.asarray(xyz, float)[:, order]
    size = float(np.clip(4000.0 / max(order.size, 1), 0.5, 30.0))
    art = ax.scatter(xyz[right], xyz[down], c=xyz[2], s=size, cmap='viridis',
                     vmin=depth_range[0], vmax=depth_range[1], linewidths=0)
    margin = 1.05 * half
    ax.set_xlim(*(centre[right] + np.array([-margin, margin]) * s_r))
    ax.set_ylim(*(centre[down] + np.array([margin, -margin]) * s_d))    # screen down
    ax.set_aspect('equal')
    suffix = f' ({units})' if units else ''
    ax.set_xlabel(AXES[right] + suffix, fontsize='small')
    ax.set_ylabel(AXES[down] + suffix, fontsize='small')
    ax.tick_params(labelsize='x-small')
    return art


def frame_figure(estimate=None, truth=None, title='', size=240, views=('front', 'side', 'top'),
                 units=''):
    """``(H, W, 3) uint8`` picture of one frame: a row per cloud (estimate, ground truth), a
    column per view, about ``size`` pixels per view; shared scale and depth colours."""
    rows = [(name, c) for name, c in (('estimate', estimate), ('ground truth', truth))
            if c is not None]
    if not rows:
        raise ValueError('nothing to draw: no estimate and no ground truth')
    extent = fit_extent([c for _, c in rows])
    zs = np.concatenate([np.asarray(c, float)[2] for _, c in rows])
    zs = zs[np.isfinite(zs)]
    depth_range = (zs.min(), zs.max()) if zs.size else (0.0, 1.0)
    fig = Figure(figsize=((len(views) * size + 90) / DPI, (len(rows) * size + 40) / DPI),
                 dpi=DPI, layout='constrained')
    canvas = FigureCanvasAgg(fig)
    axes = fig.subplots(len(rows), len(views), squeeze=False)
    for r, (name, cloud) in enumerate(rows):
        for c, view in enumerate(views):
            art = draw_view(axes[r, c], cloud, view, extent, depth_range, units)
            axes[r, c].set_title(f'{name}: {view}', fontsize='small')
    fig.colorbar(art, ax=axes, label='depth z' + (f' ({units})' if units else ''),
                 shrink=0.8)
    if title:
        fig.suptitle(title, fontsize='medium')
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()


def contact_sheet(images, columns=4, gap=6):
    """Tile ``(h, w, 3)`` images (equal or not) on white into a grid ``columns`` wide."""
    if not images:
        raise ValueError('no images for the contact sheet')
    columns = max(1, min(columns, len(images)))
    h = max(i.shape[0] for i in images)
    w = max(i.shape[1] for i in images)
    n_rows = -(-len(images) // columns)
    sheet = np.full((n_rows * (h + gap) + gap, columns * (w + gap) + gap, 3), 255, np.uint8)
    for k, img in enumerate(images):
        r, c = divmod(k, columns)
        y, x = gap + r * (h + gap), gap + c * (w + gap)
        sheet[y:y + img.shape[0], x:x + img.shape[1]] = img
    return sheet


def write_png(path, rgb):
    """Write ``rgb: (H, W, 3) uint8`` to ``path`` as a PNG."""
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or 0 in rgb.shape:
        raise ValueError(f'expected a non-empty (H, W, 3) image; got shape {rgb.shape}')
    matplotlib.image.imsave(path, np.ascontiguousarray(rgb, dtype=np.uint8), format='png')


def mesh_figure(vertices, colours, title='', size=(480, 640), view=(25, -65), units=''):
    """``(H, W, 3) uint8`` picture of a triangle list (a mesh Marker's ``points`` and
    ``colors``): ``vertices: (3T, 3)``, ``colours: (3T, 4)`` RGBA in [0, 1]; each triangle
    filled with its corners' mean colour. Drawn with x to the right, depth z into the picture
    and y downward (camera convention), seen from ``view`` = (elevation, azimuth) degrees."""
    vertices = np.asarray(vertices, float)
    shown = vertices[:, [0, 2, 1]]                       # plot axes: x, z, y (y inverted)
    faces = np.asarray(colours, float).reshape(-1, 3, 4).mean(axis=1)
    fig = Figure(figsize=(size[1] / DPI, size[0] / DPI), dpi=DPI, layout='constrained')
    canvas = FigureCanvasAgg(fig)
    ax = fig.add_subplot(projection='3d')
    ax.add_collection3d(Poly3DCollection(shown.reshape(-1, 3, 3), facecolors=faces,
                                         edgecolors=(0, 0, 0, 0.1), linewidths=0.2))
    centre, half = fit_extent([shown.T])
    suffix = f' ({units})' if units else ''
    for axis, (name, label) in enumerate(zip('xyz', ('x', 'z (depth)', 'y'))):
        getattr(ax, f'set_{name}lim')(centre[axis] - half, centre[axis] + half)
        getattr(ax, f'set_{name}label')(label + suffix)
    ax.invert_zaxis()
    ax.set_box_aspect((1, 1, 1))
    ax.view_init(elev=view[0], azim=view[1])
    ax.tick_params(labelsize='x-small')
    fig.suptitle(title or f'{len(faces)} triangles', fontsize='medium')
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()
