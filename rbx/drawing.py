"""Drawing tables (matplotlib, imported by the functions that draw): the paper's kinds by their own functions
(the registry's ``draw`` facet, :mod:`rbx.tables`), tables built from pieces by :func:`draw` (2D axes, a 3D table's
horizontal projection) and :func:`draw3d` (the round walls on 3D axes). The figures are in :mod:`rbx.plotting`.
"""
import numpy as np

from .pieces import Cylinder, Plane, Sphere, _caps_z

TABLE_STYLE = dict(color="0.15", lw=1.4)
SHRUNK_STYLE = dict(color="0.45", lw=0.9, ls="--")


def _closed_outlines(ax, geom, style_table, style_shrunk):
    for line, style in ((geom.outline, style_table), (geom.shrunk_outline, style_shrunk)):
        if line is not None:
            closed = np.vstack([line, line[:1]])
            ax.plot(closed[:, 0], closed[:, 1], **style)


def _draw_outline(ax, geom, lo, hi):
    _closed_outlines(ax, geom, TABLE_STYLE, SHRUNK_STYLE)


def _draw_strip(ax, geom, lo, hi):
    w, R = geom.table["width"], geom.shrunk_radius
    for y, style in ((0.0, TABLE_STYLE), (w, TABLE_STYLE), (R, SHRUNK_STYLE), (w - R, SHRUNK_STYLE)):
        ax.axhline(y, **style)
    pad = 0.05 * max(hi[0] - lo[0], w)
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(-0.1 * w, 1.1 * w)


def _draw_wedge(ax, geom, lo, hi):
    far = 10.0 * (np.max(np.abs(np.concatenate([lo, hi]))) + geom.size)
    for line, style in ((geom.outline, TABLE_STYLE), (geom.shrunk_outline, SHRUNK_STYLE)):
        apex = line[1]
        rays = [apex + far * (p - apex) / np.linalg.norm(p - apex) for p in (line[0], line[2])]
        ax.plot(*np.array([rays[0], apex, rays[1]]).T, **style)
    span = max(np.max(hi - lo), geom.size)
    ax.set_xlim(min(lo[0], 0.0) - 0.05 * span, max(hi[0], 0.0) + 0.05 * span)
    ax.set_ylim(min(lo[1], 0.0) - 0.05 * span, max(hi[1], 0.0) + 0.05 * span)


def _draw_nothing(ax, geom, lo, hi):
    """Plates have no side walls: their horizontal projection is the whole plane."""


def _draw_box(ax, geom, lo, hi):
    lx, ly = geom.table["size"][:2]
    R = geom.shrunk_radius
    for (x0, y0, x1, y1), style in (((0, 0, lx, ly), TABLE_STYLE), ((R, R, lx - R, ly - R), SHRUNK_STYLE)):
        ax.plot([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0], **style)


def draw_pieces(ax, geom, lo, hi):
    """A table built from pieces in the house style (:func:`draw`)."""
    draw(ax, geom, lo, hi, TABLE_STYLE, SHRUNK_STYLE)


def draw(ax, geom, lo, hi, style_table, style_shrunk):
    """Draw a table built from pieces on 2D axes (a 3D table: its horizontal projection) over the data range
    [lo, hi]: the walls and, dashed, the shrunk walls the centre meets; a periodic table: its obstacles over the
    lattice cells the data covers, with the cells' sides dotted."""
    n, R = geom.dimension, geom.shrunk_radius
    styles = {"table": style_table, "shrunk": style_shrunk}
    shifts = [np.zeros(2)]
    if geom.lattice is not None:
        l0, period = geom.lattice[0][:2], geom.lattice[1][:2]
        k0 = np.floor((np.asarray(lo[:2]) - l0) / period).astype(int) - 1
        k1 = np.floor((np.asarray(hi[:2]) - l0) / period).astype(int) + 1
        if n == 3 and np.prod(k1 - k0 + 1) > 100:
            return      # a 3D lattice seen from above: the spheres of every layer would cover the plane
        if np.prod(k1 - k0 + 1) > 40000:
            return      # too many cells to draw: the orbit alone
        shifts = [np.array([i, j], float) * period for i in range(k0[0], k1[0] + 1) for j in range(k0[1], k1[1] + 1)]
        if len(shifts) <= 400:      # the cells' sides, where they do not clutter the picture
            for i in range(k0[0], k1[0] + 2):
                ax.axvline(l0[0] + i * period[0], color="0.8", lw=0.5, ls=":", zorder=0)
            for j in range(k0[1], k1[1] + 2):
                ax.axhline(l0[1] + j * period[1], color="0.8", lw=0.5, ls=":", zorder=0)
    curves = list(getattr(geom, "curves", []))
    if n == 3:
        t = np.linspace(0, 2 * np.pi, 181)
        circ = np.stack([np.cos(t), np.sin(t)], axis=1)
        for q in geom.pieces:
            if isinstance(q, (Sphere, Cylinder)):
                c = np.asarray(q.center, float)[:2]
                grow = -R if getattr(q, "inside", True) else R
                curves += [("table", c + q.radius * circ), ("shrunk", c + (q.radius + grow) * circ)]
            elif isinstance(q, Plane) and abs(q.normal[2]) != 1.0 and np.all(np.isfinite(q.lo + q.hi)):
                pass
        boxes = [q for q in geom.pieces if isinstance(q, Plane) and abs(q.normal[2]) != 1.0]
        if boxes:       # the faces x = lx and y = ly (a face's extent is infinite along its own normal)
            lx, ly = max(q.point[0] for q in boxes), max(q.point[1] for q in boxes)
            curves += [("table", np.array([[0, 0], [lx, 0], [lx, ly], [0, ly], [0, 0]], float)),
                       ("shrunk", np.array([[R, R], [lx - R, R], [lx - R, ly - R], [R, ly - R], [R, R]], float))]
    if len(shifts) > 25:        # many cells: each obstacle a light grey disc, the shrunk outlines left out
        from matplotlib.collections import PatchCollection
        from matplotlib.patches import Circle as Disc
        discs = [Disc(np.asarray(q.center[:2], float) + s, q.radius) for s in shifts for q in geom.pieces
                 if isinstance(q, Sphere) and not q.inside]
        ax.add_collection(PatchCollection(discs, facecolor="0.82", edgecolor="0.55", lw=0.4, zorder=0))
        ax.update_datalim(np.array([np.min(shifts, axis=0), np.max(shifts, axis=0) + geom.lattice[1][:2]]))
        ax.autoscale_view()
        return
    for s in shifts:
        for which, c in curves:
            ax.plot(c[:, 0] + s[0], c[:, 1] + s[1], **styles[which])


def draw3d(ax, geom, lo, hi, style_table, style_shrunk):
    """Draw the round walls of a 3D table built from pieces on 3D axes (the flat ones are drawn by
    :func:`rbx.plotting.draw_table_3d`): a sphere as a translucent surface with its equator, the shrunk one as a
    dashed equator; a cylinder's side as its rims and four lines along its axis; in a periodic table the obstacles
    of the cells the data covers (at most 64) -> the (lo, hi) corners of what was drawn."""
    R = geom.shrunk_radius
    out_lo, out_hi = np.array(lo, float), np.array(hi, float)
    shifts = [np.zeros(3)]
    if geom.lattice is not None:
        l0, period = geom.lattice
        k0 = np.floor((np.asarray(lo) - l0) / period).astype(int)
        k1 = np.floor((np.asarray(hi) - l0) / period).astype(int)
        if np.prod(k1 - k0 + 1) > 27:
            return out_lo, out_hi       # more cells than a 3D picture can show: the orbit alone
        shifts = [(np.array(k, float) + k0) * period for k in np.ndindex(*(k1 - k0 + 1))]
    t = np.linspace(0.0, 2 * np.pi, 73)
    u, w = np.meshgrid(np.linspace(0, 2 * np.pi, 25), np.linspace(0, np.pi, 13))
    for q in geom.pieces:
        if isinstance(q, Sphere):
            for s in shifts:
                c = np.asarray(q.center, float) + s
                r = q.radius
                ax.plot_surface(c[0] + r * np.cos(u) * np.sin(w), c[1] + r * np.sin(u) * np.sin(w),
                                c[2] + r * np.cos(w), color="0.6", alpha=0.15 if q.inside else 0.35, linewidth=0)
                for rad, style in ((r, style_table), (r - R if q.inside else r + R, style_shrunk)):
                    ax.plot(c[0] + rad * np.cos(t), c[1] + rad * np.sin(t), np.full_like(t, c[2]), **style)
                out_lo, out_hi = np.minimum(out_lo, c - r), np.maximum(out_hi, c + r)
        elif isinstance(q, Cylinder):
            z0, z1 = _caps_z(geom.pieces)
            c = np.asarray(q.center, float)
            for rad, style, dz in ((q.radius, style_table, 0.0), (q.radius - R, style_shrunk, R)):
                for z in (z0 + dz, z1 - dz):
                    ax.plot(c[0] + rad * np.cos(t), c[1] + rad * np.sin(t), np.full_like(t, z), **style)
                for a in np.arange(4) * np.pi / 2:
                    ax.plot([c[0] + rad * np.cos(a)] * 2, [c[1] + rad * np.sin(a)] * 2, [z0 + dz, z1 - dz], **style)
            out_lo = np.minimum(out_lo, [c[0] - q.radius, c[1] - q.radius, z0])
            out_hi = np.maximum(out_hi, [c[0] + q.radius, c[1] + q.radius, z1])
    return out_lo, out_hi
