"""Figures from arrays: each function takes data (and, for drawing the table, a :class:`rbx.geometry.Geometry`)
and returns a :class:`matplotlib.figure.Figure`. Nothing here reads files or simulates.

Figures are built without pyplot, so no global state or GUI backend is involved: ``fig.savefig`` renders with
matplotlib's Agg canvas. Units on the axes: L is the table's length unit, T the time unit of the config's
velocities; a step is one collision.
"""
import functools
import os
import re
import textwrap

import matplotlib
import numpy as np
from matplotlib import colormaps
from matplotlib.colors import LogNorm, Normalize
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from . import analysis, geometry, tables
from .paths import written_whole
from .tables import SHRUNK_STYLE, TABLE_STYLE

MAX_LEGEND = 10
#: the one style sheet of rbx's figures (font sizes, line widths, colours): every builder here runs inside it
STYLE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "rbx.mplstyle")
#: at most this many free flights drawn as lines in a 2D orbit of one trajectory (3D: ORBIT3D_SEGMENTS); m
#: trajectories share ORBIT_SEGMENTS/√m (ten in a rectangle: 253, not 800: ten colours over 800 flights were a
#: knot in which no path could be followed); beyond it the eye sees a solid block, so the rest of the run is shown
#: as a density of the time spent
ORBIT_SEGMENTS = 800
ORBIT3D_SEGMENTS = 400
#: and at most this many of one trajectory: more flights than that fill a small table with ink
PER_TRAJECTORY = 250
#: a periodic table's orbits wander off across the lattice, and their walks are the picture: up to this many flights
#: of each are drawn (250 drew a dot at the origin of a walk 60 cells long)
PER_TRAJECTORY_PERIODIC = 20_000
#: a to-scale 2D picture whose sides differ by more than this factor is drawn stretched (and says so)
MAX_ASPECT = 6.0


def style():
    """A context in which matplotlib uses rbx's style sheet (:data:`STYLE`)."""
    return matplotlib.rc_context(fname=STYLE)


def styled(build):
    """A figure builder run inside :func:`style`; the ticks are made there too (matplotlib makes them lazily, and
    the ones added when drawing copy the first), so the figure keeps the style when saved outside it."""
    @functools.wraps(build)
    def wrapper(*args, **kwargs):
        with style():
            fig = build(*args, **kwargs)
            fit_title(fig)
            grow_to_fit(fig)
            for ax in fig.axes:
                for axis in ax._axis_map.values():
                    axis.get_major_ticks()
                    axis.get_minor_ticks()
        return fig
    return wrapper


def save(fig, path, dpi=None):
    """``fig.savefig(path)`` with rbx's style (dpi: the style's unless given), its panels lettered; written whole
    beside ``path`` and then renamed to it (:func:`rbx.paths.written_whole`), so that a failure leaves no part."""
    letter_panels(fig)
    with style(), written_whole(path) as tmp:
        # a name without an extension: the default format named, or matplotlib appends its extension to the name
        fmt = None if os.path.splitext(tmp)[1] else matplotlib.rcParams["savefig.format"]
        fig.savefig(tmp, dpi=dpi if dpi is not None else "figure", format=fmt)


def letter_panels(fig):
    """Panel letters on a figure of several panels: "(a) ", "(b) ", … before each panel's title, in reading order
    (row by row of the figure's grid), so that a caption or a text can name a panel. A panel is an axes placed on
    the grid: colour bars and insets are not lettered. Lettering twice changes nothing."""
    panels = []
    for ax in fig.axes:
        spec = ax.get_subplotspec()
        if spec is not None:
            panels.append((spec.rowspan.start, spec.colspan.start, ax))
    if len(panels) < 2:
        return
    for k, (_, _, ax) in enumerate(sorted(panels, key=lambda p: p[:2])):
        letter = f"({chr(ord('a') + k)})"
        title = ax.title.get_text()
        if not title.startswith(letter):
            ax.title.set_text(f"{letter} {title}".rstrip())     # the title's own font and size kept


def _figure(width, height, title):
    fig = Figure(figsize=(width, height), layout="constrained")
    fig.suptitle(title)
    fig._rbx_title = title
    return fig


#: the width of an average character of the figure title's font, in ems (DejaVu Sans, mixed text: 0.55–0.6)
TITLE_EM = 0.6


def _break_lines(text, room, separators=(" · ", "; ")):
    """``text`` with each of its lines broken to at most ``room`` characters: at a separator first (kept at the
    end of the line it closes), else between words."""
    pattern = "(" + "|".join(re.escape(sep) for sep in separators) + ")"
    out = []
    for line in text.split("\n"):
        parts = re.split(pattern, line)           # text, separator, text, …
        row = ""
        for i in range(0, len(parts), 2):
            part, sep = parts[i], (parts[i + 1] if i + 1 < len(parts) else "")
            if len(row + part) <= room:
                row += part + sep
                continue
            if row:
                out.append(row.rstrip())
            wrapped = textwrap.wrap(part, room, break_long_words=False, break_on_hyphens=False) or [""]
            out += wrapped[:-1]
            row = wrapped[-1] + sep
        out.append(row.rstrip())
    return "\n".join(out)


def fit_title(fig):
    """Break the figure's title and its panels' titles so that each line fits the figure's width as built (a
    builder may resize its figure to the table's shape), a panel's title the panel's: a long scene phrase over a
    narrow, tall table, or a panel's note over a narrow panel, ran past the figure's edges and was cut off."""
    title = getattr(fig, "_rbx_title", None)
    width = fig.get_figwidth() * 72                      # points
    if title and fig._suptitle is not None:
        room = max(30, int(0.95 * width / (TITLE_EM * fig._suptitle.get_fontsize())))
        fig._suptitle.set_text(_break_lines(title, room))
    for ax in fig.axes:
        text = getattr(ax, "_rbx_title", None) or ax.title.get_text()
        if not text or ax.get_subplotspec() is None:
            continue
        ax._rbx_title = text
        # the panel's width before the layout makes room for labels and legends: take 85 % of it
        room = max(20, int(0.85 * ax.get_position().width * width / (TITLE_EM * ax.title.get_fontsize())))
        ax.title.set_text(_break_lines(text, room))


def grow_to_fit(fig, rounds=3):
    """Make the figure taller until its titles, labels and legends lie inside it. A builder sizes a figure for
    the table's shape before the titles are wrapped (:func:`fit_title`); a wide table under a title of five lines
    (a 2 × 1 rectangle of ten trajectories: the scene, the rule, the selection and the panel's note) left the
    layout no room, and the x label was cut off at the bottom edge."""
    for _ in range(rounds):
        fig.draw_without_rendering()
        renderer = fig._get_renderer()
        boxes = [ax.get_tightbbox(renderer) for ax in fig.axes] + [
            t.get_window_extent(renderer) for t in [fig._suptitle, *fig.legends] if t is not None]
        boxes = [b for b in boxes if b is not None and np.all(np.isfinite(b.extents))]
        if not boxes:
            return
        low = min(b.y0 for b in boxes) / fig.dpi           # inches above the bottom edge
        high = max(b.y1 for b in boxes) / fig.dpi
        height = fig.get_figheight()
        over = max(0.0, -low) + max(0.0, high - height)
        if over < 0.01:
            return
        fig.set_figheight(height + over + 0.05)


def legend_outside(ax, where="right", **kwargs):
    """A legend beside the axes (right) or under them (below), never over the data."""
    if where == "below":     # the figure's own legend, laid out under the axes by constrained layout
        axes = ax if isinstance(ax, (list, tuple)) else [ax]
        handles, labels = [], []
        for a in axes:
            h, t = a.get_legend_handles_labels()
            handles, labels = handles + h, labels + t
        short = max((len(t) for t in labels), default=0) < 20
        kwargs.setdefault("ncols", min(5, len(labels)) if short else min(2, len(labels)))
        return axes[0].figure.legend(handles, labels, loc="outside lower center", **kwargs)
    return ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0, **kwargs)


def _few_ticks(ax, n=4):
    """At most about n labelled ticks per axis (3D axes and narrow panels: long labels ran together)."""
    for axis in ax._axis_map.values():
        axis.set_major_locator(MaxNLocator(n))


def _thin(paths, budget, geom=None, walk=False):
    """The first K records of each path, K such that the drawn flights total about ``budget``/√m for m paths (at
    most PER_TRAJECTORY each); in a periodic table (or for any ``walk``: the horizontal projection of an orbit
    between plates), up to PER_TRAJECTORY_PERIODIC each -> (paths, K or None if nothing was cut)."""
    per = PER_TRAJECTORY
    if walk or (geom is not None and getattr(geom, "lattice", None) is not None):
        per = PER_TRAJECTORY_PERIODIC
        budget = per * len(paths)
    else:
        budget = int(budget / np.sqrt(max(len(paths), 1)))
    total = sum(max(len(p) - 1, 0) for p in paths)
    if total <= budget:
        return paths, None
    k = max(2, min(budget // max(len(paths), 1), per) + 1)
    return [p[:k] for p in paths], k - 1


#: the drawn flights of a 2D orbit over its density cover at most about this share of the area the whole run visits
#: (the line length times the line width): 250 chords of the rough circle covered its annulus, and the grey density
#: of the whole run that the title promised could not be seen (now a few dozen of its chords are drawn over it)
INK_SHARE = 0.1


def _ink_cap(shown, k, visited, ax, lw_pt):
    """Fewer flights of each shown path (the first k' ≤ k) so that their ink covers at most :data:`INK_SHARE` of
    the area the whole run visits (``visited``: the occupied cells of its density, :func:`_density`) -> (paths,
    k')."""
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    fig = ax.figure
    width_pt = 0.75 * fig.get_figwidth() * 72.0                  # the axes before the layout: most of the width
    lw = lw_pt * max(x1 - x0, y1 - y0) / width_pt                # the line width in L
    room = INK_SHARE * visited / lw                               # the line length allowed [L]
    lengths = [np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p[:, :2], axis=0), axis=1))]) for p in shown]
    per = max(1, k)
    while per > 10 and sum(float(c[min(per, len(c) - 1)]) for c in lengths) > room:
        per = int(per * 0.9)
    return [p[:per + 1] for p in shown], per


#: the greys of a run's density under the drawn flights: from white to a middle grey, so that the darkest cell still
#: leaves the coloured lines over it their contrast (the full grey scale at 55 % opacity made a box's nearly uniform
#: projection a dark noise in which eight trajectories' lines were lost)
DENSITY_GREYS = matplotlib.colors.LinearSegmentedColormap.from_list("rbx_density", ["0.96", "0.6"])


def _density(ax, paths, points_only, lo, hi, bins=200):
    """The time spent at each place by the whole orbit, as a grey density under the drawn flights: points
    sampled uniformly along each straight flight (or the recorded points themselves, ``points_only``)."""
    pts = []
    for p in paths:
        p = p[:, :2]
        if points_only or len(p) < 2:
            pts.append(p)
            continue
        seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
        s = np.concatenate([[0.0], np.cumsum(seg)])
        if s[-1] <= 0:
            continue
        u = np.linspace(0.0, s[-1], min(400_000, 40 * len(p)))
        pts.append(np.stack([np.interp(u, s, p[:, 0]), np.interp(u, s, p[:, 1])], axis=1))
    if not pts:
        return 0.0
    q = np.concatenate(pts)
    span = np.maximum(np.asarray(hi[:2], float) - np.asarray(lo[:2], float), 1e-12)
    nx = int(np.clip(bins * span[0] / span.max(), 20, bins))
    ny = int(np.clip(bins * span[1] / span.max(), 20, bins))
    h, xe, ye = np.histogram2d(q[:, 0], q[:, 1], bins=(nx, ny), range=[[lo[0], hi[0]], [lo[1], hi[1]]])
    h = np.ma.masked_equal(h, 0)
    ax.pcolormesh(xe, ye, h.T, cmap=DENSITY_GREYS, norm=matplotlib.colors.LogNorm(vmin=1, vmax=max(h.max(), 2)),
                  zorder=0, rasterized=True)
    return int(h.count()) * float((xe[1] - xe[0]) * (ye[1] - ye[0]))


#: one colour per trajectory: matplotlib's tab10 with its brown (the 6th) replaced by a navy, since thin brown and
#: red lines could not be told apart, and its grey (the 8th) by a dark teal, since grey is the colour of the whole
#: run's density and of the tables' outlines
TRAJECTORY_COLOURS = [colormaps["tab10"](i) for i in range(5)] + [(0.1, 0.1, 0.45, 1.0)] + \
    [colormaps["tab10"](6), (0.0, 0.35, 0.35, 1.0)] + [colormaps["tab10"](i) for i in (8, 9)]


def _colour(i):
    return TRAJECTORY_COLOURS[i % len(TRAJECTORY_COLOURS)]


# ---- drawing the table -----------------------------------------------------------------------------------------


def _extent(paths, dims=2):
    pts = np.concatenate([p[:, :dims] for p in paths if len(p)] or [np.zeros((1, dims))])
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) == 0:
        pts = np.zeros((1, dims))
    return pts.min(axis=0), pts.max(axis=0)


def draw_table_2d(ax, geom, lo, hi):
    """The table (solid) and the shrunk table seen by the centre (dashed) on 2D axes, to scale; a 3D table as its
    horizontal projection. Unbounded tables are drawn over the data range [lo, hi] (and the axes limited to it).
    How each kind is drawn is a facet of its record in :mod:`rbx.tables`."""
    tables.draw(ax, geom, lo, hi)


def draw_table_3d(ax, geom, lo, hi):
    """The flat walls of a 3D table on 3D axes -> the (lo, hi) corners of the drawn region. A bounded face is
    drawn as its outline (the table solid, the shrunk table dashed); an unbounded one (plates) as a translucent
    plane over the data range [lo, hi]."""
    R = geom.shrunk_radius
    # a margin per axis: one margin of the longest range for all drew the plates of an orbit 0.45 wide across and
    # 600 long as planes 60 wide, and the path was a sliver in the middle of them
    pad = 0.05 * np.maximum(np.asarray(hi, float) - np.asarray(lo, float), geom.size)
    span_lo, span_hi = np.array(lo, float) - pad, np.array(hi, float) + pad
    out_lo, out_hi = np.array(lo, float), np.array(hi, float)
    if geom.pieces is not None:      # round walls and obstacles of a table built from pieces (rbx.geometry)
        out_lo, out_hi = geometry.draw3d(ax, geom, out_lo, out_hi, TABLE_STYLE, SHRUNK_STYLE)
    for piece in tables.walls(geom.kind, geom.table):
        if not isinstance(piece, tables.Plane):
            continue
        p0, nu = np.array(piece.point, float), np.array(piece.normal, float)
        t1, t2 = (np.array(t, float) for t in piece.tangents)
        blo, bhi = np.array(piece.lo, float), np.array(piece.hi, float)
        with np.errstate(invalid="ignore"):   # 0·inf along the axes a tangent does not use
            a0, a1, b0, b1 = (float(np.sum(np.where(t != 0, x * t, 0.0))) for x, t in
                              ((blo, t1), (bhi, t1), (blo, t2), (bhi, t2)))
        if np.all(np.isfinite([a0, a1, b0, b1])):
            for shift, style in ((0.0, TABLE_STYLE), (R, SHRUNK_STYLE)):
                base = p0 + shift * nu
                a = [a0 + shift, a1 - shift]
                b = [b0 + shift, b1 - shift]
                corners = [base - (base @ t1) * t1 - (base @ t2) * t2 + x * t1 + y * t2
                           for x, y in ((a[0], b[0]), (a[1], b[0]), (a[1], b[1]), (a[0], b[1]), (a[0], b[0]))]
                ax.plot(*np.array(corners).T, **style)
                out_lo, out_hi = np.minimum(out_lo, np.min(corners, axis=0)), np.maximum(out_hi, np.max(corners,
                                                                                                  axis=0))
        else:
            X, Y = np.meshgrid([span_lo @ t1, span_hi @ t1], [span_lo @ t2, span_hi @ t2])
            pts = p0[None, None, :] - (p0 @ t1) * t1 - (p0 @ t2) * t2 + X[..., None] * t1 + Y[..., None] * t2
            ax.plot_surface(pts[..., 0], pts[..., 1], pts[..., 2], color="0.5", alpha=0.18, linewidth=0)
            k = int(np.argmax(np.abs(nu)))          # the plane bounds the drawn region only across itself
            out_lo[k], out_hi[k] = min(out_lo[k], p0[k]), max(out_hi[k], p0[k])
    return out_lo, out_hi


# ---- orbits ----------------------------------------------------------------------------------------------------


def _first(k, stride, trajectories=2):
    """What the drawn part of a long orbit is: its first k flights as lines, or, when the records skip collisions
    (``stride`` > 1: no straight flight joins them), its first k records as points; of each of the ``trajectories``
    drawn, or of the one."""
    of = "each trajectory" if trajectories > 1 else "the trajectory"
    if stride > 1:
        return f"points: the first {k} records of {of} (one every {stride} collisions)"
    return f"lines: the first {k} collisions of {of}"


@styled
def orbit_figure(paths, geom, title, labels=None, points_only=False, stride=1):
    """The 2D path of the centre (or the horizontal projection of a 3D one) in the table drawn to scale.

    ``paths``: list of (T_j, ≥2) arrays of positions, one per trajectory; consecutive collision points are joined
    by straight segments (the free flights) unless ``points_only`` (records that skip collisions, ``stride``
    collisions apart). A long orbit
    is drawn as its first flights (:data:`ORBIT_SEGMENTS` in all) over a grey density of the whole run; a table
    much longer than wide (a strip) is stretched across, and the axis label says so."""
    fig = _figure(6.4, 6.0, title)
    ax = fig.add_subplot()
    # a 3D orbit between plates drifts along them: its projection was a block of ink over a striped density of a
    # uniform drift; it is drawn as a stretch a few gaps long, as in orbit3d_figure
    drifts = geom.dimension == 3 and geom.lattice is None and bool(analysis.unbounded_axes(geom))
    shown, k = _thin(paths, ORBIT_SEGMENTS, geom)
    if drifts:
        shown, k = _short_stretch(shown if k is not None else paths, paths)
    lo, hi = _extent(shown if drifts else paths)
    draw_table_2d(ax, geom, lo, hi)
    _round_caps(ax)
    if k is not None and not drifts:
        visited = _density(ax, paths, points_only, *_extent(paths))
        if not points_only:
            shown, k = _ink_cap(shown, k, visited, ax, 0.6)
    alpha = 1.0 if len(paths) == 1 else 0.8
    for i, p in enumerate(shown):
        style = dict(ls="none", marker=".", ms=2) if points_only else dict(lw=0.6)
        ax.plot(p[:, 0], p[:, 1], color=_colour(i), alpha=alpha, label=labels[i] if labels else None, **style)
    for i, p in enumerate(shown):            # the starts on top of every path
        if len(p):
            ax.plot(p[0, 0], p[0, 1], "o", color=_colour(i), ms=4, mec="white", mew=0.5, zorder=5)
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    ratio = (y1 - y0) / max(x1 - x0, 1e-300)
    if 1 / MAX_ASPECT <= ratio <= MAX_ASPECT:
        ax.set_aspect("equal", adjustable="box")
        # to scale, so the figure takes the table's shape (a wide, low figure for a wide table)
        width = 9.0 if ratio < 0.5 else 6.4
        legend = 1.5 if labels and 1 < len(paths) <= MAX_LEGEND and ratio >= 0.5 else 0.0   # beside the axes
        fig.set_size_inches(width, float(np.clip((width - legend - 0.8) * ratio + 1.6, 3.2, 9.0)))
        ax.set_xlabel("x [L]")
        ax.set_ylabel("y [L]")
    elif ratio < 1:
        fig.set_size_inches(9.0, 3.6)
        ax.set_xlabel("x [L]")
        ax.set_ylabel("y [L] (not to scale)")
    else:
        fig.set_size_inches(4.4, 7.5)
        ax.set_xlabel("x [L] (not to scale)")
        ax.set_ylabel("y [L]")
    if drifts and k is not None:
        (a, b), (c, d) = ((f"{v:.3g}".replace("-", "−") for v in corner[:2]) for corner in _extent(paths))
        ax.set_title(f"{_first(k, stride if points_only else 1, len(shown))}\n(whole run: x {a} to {c}, y {b} to "
                     f"{d} [L])")
    elif k is not None:
        ax.set_title(f"{_first(k, stride if points_only else 1, len(shown))}; grey: the whole run")
    if labels and 1 < len(paths) <= MAX_LEGEND:     # one trajectory: the title names it, a legend only took room
        legend_outside(ax, "below" if ratio < 0.5 else "right")
    return fig


def _round_caps(ax):
    """Closed outlines drawn as open polylines showed a square cap (a short tick) where they start and end."""
    for line in ax.get_lines():
        line.set_solid_capstyle("round")
        line.set_dash_capstyle("round")
        line.set_solid_joinstyle("round")


@styled
def orbit3d_figure(paths, geom, title, labels=None, points_only=False, stride=1):
    """The 3D path of the centre between plates or in a box, beside its horizontal projection (x, y). A long
    orbit is drawn as its first flights (:data:`ORBIT3D_SEGMENTS` in all in 3D)."""
    fig = _figure(11.0, 5.2, title)
    # a gap column between the panels: constrained layout does not see a 3D axes' z label, which then ran into
    # the projection's y label
    gs = fig.add_gridspec(1, 3, width_ratios=[1.0, 0.1, 1.0])
    ax = fig.add_subplot(gs[0, 0], projection="3d")
    style = dict(ls="none", marker=".", ms=2) if points_only else dict(lw=0.6)
    shown, k = _thin(paths, ORBIT3D_SEGMENTS, geom)
    # between plates (unbounded, not periodic) the orbit drifts: 250 flights ran 80 L along the plates 1 apart, a
    # blue block at one end of planes drawn 600 L long; the 3D panel shows a stretch a few gaps long, the
    # projection the whole walk
    drifts = geom.lattice is None and bool(analysis.unbounded_axes(geom))
    if drifts:
        shown, k = _short_stretch(shown if k is not None else paths, paths)
    # the projection first: the flights it can show over the run's density (_ink_cap) are all the 3D panel shows
    # too (250 of the rough sphere's were a hedgehog in 3D)
    ax2 = fig.add_subplot(gs[0, 2])
    lo2, hi2 = _extent(shown if drifts else paths)
    draw_table_2d(ax2, geom, lo2, hi2)
    _round_caps(ax2)
    if drifts:          # the stretch of the 3D panel seen from above (the whole walk was a solid block of ink)
        shown2, k2 = shown, None
    else:
        shown2, k2 = _thin(paths, ORBIT_SEGMENTS, geom)
    if k2 is not None:
        visited = _density(ax2, paths, points_only, lo2, hi2)
        if not points_only:
            shown2, k2 = _ink_cap(shown2, k2, visited, ax2, 0.6)
            if k is not None and k2 < k:
                shown, k = [p[:k2 + 1] for p in shown], k2
    lo, hi = _extent(shown, 3)
    alpha = 1.0 if len(paths) == 1 else 0.8
    for i, p in enumerate(shown):
        ax.plot(p[:, 0], p[:, 1], p[:, 2], color=_colour(i), alpha=alpha, label=labels[i] if labels else None,
                **style)
    lo, hi = draw_table_3d(ax, geom, lo, hi)
    ranges = hi - lo
    ax.set_box_aspect(np.maximum(ranges, 0.2 * ranges.max()))  # to scale, unless a range is very thin
    _few_ticks(ax, 4)
    thin = ranges < 0.3 * ranges.max()
    for axis, flat in zip((ax.xaxis, ax.yaxis, ax.zaxis), thin):
        if flat:
            axis.set_major_locator(MaxNLocator(2))
    ax.set_xlabel("x [L]")
    ax.set_ylabel("y [L]")
    ax.set_zlabel("z [L]")
    stride = stride if points_only else 1
    each = " each" if len(shown) > 1 else ""
    ax.set_title("3D path of the centre" + (f" (first {k} {'records' if stride > 1 else 'collisions'}{each})"
                                            if k else ""))
    for i, p in enumerate(shown2):
        ax2.plot(p[:, 0], p[:, 1], color=_colour(i), alpha=alpha, label=labels[i] if labels else None, **style)
    for i, p in enumerate(shown2):
        if len(p):
            ax2.plot(p[0, 0], p[0, 1], "o", color=_colour(i), ms=4, mec="white", mew=0.5, zorder=5)
    (x0, x1), (y0, y1) = ax2.get_xlim(), ax2.get_ylim()
    if 1 / MAX_ASPECT <= (y1 - y0) / max(x1 - x0, 1e-300) <= MAX_ASPECT:
        ax2.set_aspect("equal", adjustable="datalim")
        ax2.set_xlabel("x [L]")
    else:
        ax2.set_xlabel("x [L] (not to scale)")
    ax2.set_ylabel("y [L]")
    drawn = f"points, first {k2} records" if stride > 1 else f"lines, first {k2} collisions"
    if drifts:
        (a, b), (c, d) = ((f"{v:.3g}".replace("-", "−") for v in corner[:2]) for corner in _extent(paths))
        ax2.set_title(f"the stretch of (a) seen from above\n(whole run: x {a} to {c}, y {b} to {d} [L])")
    else:
        ax2.set_title("horizontal projection" + (f": {drawn}; grey, whole run" if k2 else ""))
    if labels and 1 < len(paths) <= MAX_LEGEND:
        legend_outside(ax2)
    return fig


#: between plates the 3D panel shows a stretch of the orbit at most this many times the height it spans (the gap)
STRETCH = 6.0


def _short_stretch(shown, paths):
    """The first k flights of each path such that every drawn path spans at most :data:`STRETCH` times the whole
    run's vertical range horizontally -> (paths, k or None when nothing was cut)."""
    height = max(float(np.ptp(p[:, 2])) for p in paths if len(p)) or 1.0
    k = max(len(p) for p in shown) - 1
    for p in shown:
        span = np.maximum(np.maximum.accumulate(p[:, :2], axis=0) - np.minimum.accumulate(p[:, :2], axis=0), 0.0)
        over = np.nonzero(np.max(span, axis=1) > STRETCH * height)[0]
        if len(over):
            k = min(k, max(int(over[0]) - 1, 2))
    cut = [p[:k + 1] for p in shown]
    return cut, (k if any(len(p) > k + 1 for p in paths) else None)


# ---- phase portraits -------------------------------------------------------------------------------------------


#: the ink of a scatter panel: its markers' areas add up to about this many pt² (a quarter of a 4 × 4 inch panel), so
#: that 80 000 points (the box example's phase portrait) leave its structure visible; 2 pt² each covered the panel
#: twice over, one blot
SCATTER_INK = 20000.0


def marker_area(n):
    """The marker area [pt²] of a scatter panel of ``n`` points: a few points stand out (36 pt² at most), many are
    small enough to add up to :data:`SCATTER_INK` (0.25 pt² at least: a pixel at 150 dpi)."""
    return float(np.clip(SCATTER_INK / max(n, 1), 0.25, 36.0))


@styled
def phase_figure(panels, colour, title, colour_label, categorical=True, labels=None):
    """Scatter panels sharing one colouring. ``panels``: list of dicts with ``x``, ``y``, ``xlabel``, ``ylabel``
    and optionally ``title``, ``vlines`` (x positions to mark, e.g. wall joints), ``lines`` (list of
    (slope, label) lines through the origin), ``xlim``, ``ylim``, ``equal`` (bool). ``colour``: one value per
    point — a trajectory index (``categorical``, legend from ``labels``) or a step (colour bar). A panel that
    shows only some of the points gives their boolean mask as ``select``."""
    fig = _figure(5.2 * len(panels) + 0.8, 5.0, title)
    colour = np.asarray(colour)
    if categorical:
        keys = list(dict.fromkeys(colour.tolist()))
        rgba = np.array([_colour(keys.index(c)) for c in colour.tolist()]).reshape(-1, 4)
        norm = None
    else:
        norm = Normalize(float(np.min(colour)) if len(colour) else 0.0, float(np.max(colour)) if len(colour) else 1.0)
        rgba = colormaps["viridis"](norm(colour))
    axes = []
    for spec in panels:
        ax = fig.add_subplot(1, len(panels), len(axes) + 1)
        sel = spec.get("select")
        x, y, c = np.asarray(spec["x"]), np.asarray(spec["y"]), rgba if sel is None else rgba[sel]
        # drawn in a shuffled order, so that no trajectory (the last one) covers the others
        order = np.random.default_rng(0).permutation(len(x))
        ax.scatter(x[order], y[order], c=c[order], s=marker_area(len(x)), lw=0, rasterized=True)
        for v in spec.get("vlines", ()):
            ax.axvline(v, color="0.6", lw=0.6, ls=":")
        for slope, label in spec.get("lines", ()):
            ax.axline((0.0, 0.0), slope=slope, color="0.3", lw=0.8, ls="--", label=label)
        _dress(ax, spec)
        axes.append(ax)
    if categorical and labels and len(keys) <= MAX_LEGEND:
        for i, k in enumerate(keys):
            axes[-1].plot([], [], "o", color=_colour(i), ms=3.0, label=labels[i])
    elif categorical and len(keys) > 1:       # too many to list: say what the colours are
        axes[-1].plot([], [], "o", color=_colour(0), ms=3.0,
                      label=f"colour: trajectory\n({len(keys)}, not listed)")
    if any(spec.get("lines") for spec in panels) or (categorical and len(keys) > 1):
        legend_outside(axes[-1], markerscale=1.0)
    if not categorical:
        from matplotlib.cm import ScalarMappable
        fig.colorbar(ScalarMappable(norm=norm, cmap="viridis"), ax=axes, label=colour_label, shrink=0.5,
                     location="bottom", aspect=40)
    return fig


# ---- series ----------------------------------------------------------------------------------------------------


@styled
def series_figure(steps, values, title, ylabel, labels=None, scales=(0.01, 0.1, 1.0), points_only=False):
    """A coordinate against the collision step at several time scales (paper Figure `graph`): one panel per
    scale f, showing the first fraction f of the run. ``steps`` (T,), ``values``: list of (T,) arrays (one per
    trajectory; NaN past a trajectory's end)."""
    fig = _figure(8.0, 2.6 * len(scales) + 0.4, title)
    steps = np.asarray(steps)
    last = float(steps.max()) if len(steps) else 0.0
    first = float(steps.min()) if len(steps) else 0.0
    for k, f in enumerate(scales):
        ax = fig.add_subplot(len(scales), 1, k + 1)
        upto = first + f * (last - first)
        sel = steps <= upto
        for i, v in enumerate(values):
            style = dict(ls="none", marker=".", ms=1.5) if points_only or sel.sum() > 200_000 else dict(lw=0.7)
            ax.plot(steps[sel], np.asarray(v)[sel], color=_colour(i), label=labels[i] if labels else None,
                    **style)
        frac = "all" if f >= 1 else f"first 1/{round(1 / f)}" if abs(1 / f - round(1 / f)) < 1e-9 else f"first {f:g}"
        ax.set_title(f"{frac} of the run (steps {first:.0f} – {upto:.0f})")
        ax.set_xlabel("collision step [–]")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))     # steps are whole collisions
        if upto > first:
            ax.set_xlim(first, upto)        # the panel's stretch of the run, no ticks past its data
        ax.set_ylabel(ylabel)
        if k == 0 and labels and 1 < len(values) <= MAX_LEGEND:
            legend_outside(ax)
    return fig


# ---- diffusion -------------------------------------------------------------------------------------------------


def displacement_histogram(ax, dx, coordinate, T):
    """The final displacements ``dx`` (after ``T`` collisions) as a density histogram of equal bins on ``ax``, each
    bar outlined: two neighbours of one height read as one bar twice as wide."""
    ax.hist(dx, bins=max(10, min(60, int(np.sqrt(len(dx))) + 1)), density=True, color=_colour(0), alpha=0.6,
            edgecolor="white", linewidth=0.6, label=f"Δ{coordinate} after {T:.0f} collisions")


@styled
def diffusion_figure(steps, msd, fit, displacement, title, coordinate="x", time_per_step=None, horizon=None):
    """Left: mean-square displacement against steps (log–log) with the fit 2·D·t + c and its confidence
    interval; right: the distribution of the final displacement against the Gaussian of the fitted MSD (not drawn
    with ``horizon``).
    ``time_per_step``: the mean time per collision τ [T], if known: D is then also given per unit time, D/τ.
    ``horizon``: why the slope is no diffusion coefficient (an infinite horizon: the short phrase of
    :func:`rbx.analysis.horizon_problem`),
    said in the MSD panel and the fit's label, which names the fitted number b (half the MSD's slope over the
    window), not D."""
    from scipy import stats
    unit = "rad" if coordinate == "theta" else "L"         # the orientation is an angle
    fig = _figure(11.0, 4.6, title)
    ax = fig.add_subplot(1, 2, 1)
    steps = np.asarray(steps, float)
    ok = (steps > 0) & (np.asarray(msd) > 0)
    ax.loglog(steps[ok], np.asarray(msd)[ok], ".", ms=3, color=_colour(0), label="ensemble MSD")
    t = np.geomspace(fit.start, fit.stop, 200)                # the fit is drawn where it was made
    model = fit.msd(t)
    pct = round(100 * fit.confidence)
    if horizon:
        # no coefficient: b, half the MSD's slope over the window, a number of the window alone
        label = (f"fit 2bt + c, over the fit window only: b = {analysis.plus_minus(fit.coefficient, fit.half_width)} "
                 f"{unit}²/collision ({pct}% CI)")
    else:
        label = (f"fit 2Dt + c: D = {analysis.plus_minus(fit.coefficient, fit.half_width)} {unit}²/collision "
                 f"({pct}% CI)")
    if time_per_step:
        label += (f"\n  = {analysis.plus_minus(fit.coefficient / time_per_step, fit.half_width / time_per_step)} "
                  f"{unit}²/T per unit time (mean time per collision {time_per_step:.4g} T)")
    if horizon:
        label += "\n  b: half the MSD's slope over the window, not D"
    ax.loglog(t[model > 0], model[model > 0], "-", color="k", lw=1, label=label)
    band_lo, band_hi = 2 * fit.low * t + fit.intercept, 2 * fit.high * t + fit.intercept
    # where the interval reaches 0 or below (few trajectories), a log axis cannot show its lower edge: the band
    # then runs to the bottom of the axis, rather than stop where the edge turns negative
    ylim = ax.get_ylim()
    good = band_hi > 0
    ax.fill_between(t[good], np.maximum(band_lo[good], ylim[0] / 10), band_hi[good], color="0.6", alpha=0.4, lw=0)
    ax.set_ylim(ylim[0], max(ylim[1], float(np.max(band_hi[good], initial=ylim[1]))))
    ax.axvspan(fit.start, fit.stop, color=_colour(2), alpha=0.07, label="fit window")
    ax.set_xlabel("collisions [–]")
    ax.set_ylabel(f"MSD ⟨Δ{coordinate}²⟩ [{unit}²]")
    ax.set_title(f"mean-square displacement, {fit.trajectories} trajectories")   # a fit needs 2 or more
    if horizon:
        ax.set_title(f"mean-square displacement, {fit.trajectories} trajectories\n"
                     f"no diffusion coefficient: {horizon}", color="C3")
    ax2 = fig.add_subplot(1, 2, 2)
    dx = np.asarray(displacement, float)
    dx = dx[np.isfinite(dx)]
    T = float(steps.max()) if len(steps) else 0.0
    var = float(fit.msd(T))
    displacement_histogram(ax2, dx, coordinate, T)
    if horizon:
        # the displacements spread as √(t·log t): no Gaussian of the fitted MSD's variance is expected
        ax2.plot([], [], " ", label="no Gaussian of variance 2bT + c drawn:\nwith an infinite horizon the MSD "
                                    "grows as t·log t")
    elif var > 0:
        sd = np.sqrt(var)
        u = np.linspace(min(dx.min(), -4 * sd) if len(dx) else -4 * sd, max(dx.max(), 4 * sd) if len(dx) else 4 * sd,
                        400)
        # a test of a handful of displacements tells nothing (p of 3 samples was printed as 0.71)
        test = (f"KS p = {stats.kstest(dx, stats.norm(0.0, sd).cdf).pvalue:.2g}" if len(dx) >= MIN_KS_SAMPLES
                else f"no KS test: {len(dx)} trajectories, fewer than {MIN_KS_SAMPLES}")
        ax2.plot(u, stats.norm.pdf(u, 0.0, sd), "k-", lw=1.2, label=f"Gaussian, variance 2DT + c = {var:.3g} {unit}² ({test})")
    ax2.set_xlabel(f"displacement Δ{coordinate} [{unit}]")
    ax2.set_ylabel(f"density [1/{unit}]")
    ax2.set_title("displacement distribution")
    legend_outside([ax, ax2], "below")
    return fig


# ---- the invariant-measure histogram ---------------------------------------------------------------------------


def density_name(d):
    if d == 3:
        return "sin 2φ"
    return f"{d - 1}·cos φ·sin{_superscript(d - 2)} φ"


def _superscript(k):
    return str(k).translate(str.maketrans("0123456789", "⁰¹²³⁴⁵⁶⁷⁸⁹"))


def censored_note(not_returned, samples, sep=" "):
    """Why a return-angle test with censored samples gives no p-value: the slow returns are the ones left out
    (``sep`` between its two halves: a line break in a legend)."""
    return (f"{not_returned} of {samples} samples did not return,{sep}and the test is biased by their absence; "
            "raise run.collisions")


#: the fewest samples a figure's Kolmogorov–Smirnov test is made of (the diffusion plot's Gaussian panel)
MIN_KS_SAMPLES = 20


@styled
def histogram_figure(angle, d, ks_statistic, ks_pvalue, title, bins=50, not_returned=0):
    """Histogram of return angles φ against the billiard-measure density (d−1)·cos φ·sin^(d−2) φ on [0, π/2].
    ``not_returned``: samples that did not return within the run; if any, the legend gives no KS test but
    :func:`censored_note`."""
    fig = _figure(6.4, 4.6, title)
    ax = fig.add_subplot()
    ax.hist(angle, bins=bins, range=(0.0, np.pi / 2), density=True, color=_colour(0), alpha=0.65,
            label=f"{len(angle)} return angles")
    u = np.linspace(0.0, np.pi / 2, 400)
    test = f"KS D = {ks_statistic:.3g}, p = {ks_pvalue:.3g}" if not not_returned else "no KS test"
    ax.plot(u, analysis.cos_law_pdf(u, d), "k-", lw=1.3, label=f"predicted {density_name(d)} ({test})")
    if not_returned:
        ax.plot([], [], " ", label=censored_note(not_returned, len(angle) + not_returned, sep="\n"))
    ax.set_xlim(0.0, np.pi / 2)
    ax.set_ylim(0.0, 1.25 * max(ax.get_ylim()[1], float(np.max(analysis.cos_law_pdf(u, d)))))
    ax.set_xlabel("return angle φ to the normal [rad]")
    ax.set_ylabel("density [1/rad]")
    legend_outside(ax, "below", **({"ncols": 1} if not_returned else {}))
    return fig


# ---- escape and return times (docs/reference.md §10) ----------------------------------------------------------


@styled
def escape_figure(s, S, fit, exits, total, title, unit="path length [L]", expected=None, trapped=None, at_last=0,
                  falling=0, no_rate=None):
    """The survival function S(s) (Kaplan–Meier: the fraction of trajectories still in the table after path s) on
    a log scale, with the fitted law of :mod:`rbx.escape` (``fit``: an :class:`rbx.escape.EscapeFit`, or None)
    drawn over its window only, and only if it follows the data there; else the legend says that no exponential
    does. ``expected``: (γ, label) of a predicted rate, drawn dashed. ``trapped``: (share, low, high) where survival
    levels off: the share drawn as a level with its interval. ``at_last``: how many of the ``exits`` were at the
    run's last collision (said beside them). ``falling``: how many are still inside where survival has not levelled
    off (said: no trapped share can be read). ``no_rate``: why no rate is fitted, where one is not tried."""
    fig = _figure(8.4, 5.0, title)
    ax = fig.add_subplot()
    # the axis runs to the last exit, and the last level S > 0 is drawn up to it (S = 0 has no place on a log axis:
    # cut there, the last step lay on the axis' edge)
    end = float(np.max(s)) if len(s) else 1.0
    s, S = np.asarray(s)[np.asarray(S) > 0], np.asarray(S)[np.asarray(S) > 0]
    if len(s) and end > s[-1]:
        s, S = np.append(s, end), np.append(S, S[-1])
    counted = f"{exits} of {total} exited"
    if at_last:
        counted += f": {exits - at_last} before the run's last collision, {at_last} at it"
    ax.step(s, S, where="post", color=_colour(0), lw=1.2, label=f"Kaplan–Meier survival ({counted})")
    if trapped is not None:
        share, low, high = trapped
        ax.axhspan(low, high, color=_colour(1), alpha=0.25, lw=0)
        ax.axhline(share, color=_colour(1), lw=1.0, ls=":",
                   label=f"trapped share: {100 * share:.3g} % never exited (Wilson interval {100 * low:.3g}–"
                         f"{100 * high:.3g} %, z = 1)")
    elif falling:
        ax.plot([], [], " ", label=f"still falling at the end of the run ({falling} of {total} still inside): no "
                                   "trapped share can be read; run longer")
    drawn = fit is not None and fit.follows and fit.rate > 0 and np.isfinite(fit.rate_err)
    if drawn:
        # drawn as far as the survival is drawn: the last exit, where S = 0, may end the window off the log axis
        x = np.linspace(fit.start, min(fit.stop, max(end, fit.start)), 400)
        what = f"{fit.start:.3g} ≤ s ≤ {fit.stop:.3g}"
        rate = f"γ = {analysis.plus_minus(fit.rate, fit.rate_err)} per unit path"
        if fit.trapped:
            label = (f"fit over {what} of S(s₀)·[q + (1 − q)·e^(−γ(s − s₀))], s₀ = {fit.start:.3g}: {rate}, "
                     f"level S(s₀)·q = {100 * fit.survival0 * fit.level:.3g} %")
        else:
            label = f"fit over {what} of S(s₀)·e^(−γ(s − s₀)), s₀ = {fit.start:.3g}: {rate}"
        ax.plot(x, fit.survival(x), "k-", lw=1.0, label=label)
    else:
        ax.plot([], [], " ", label=no_rate or "no exponential law follows the survival over any window tried: no rate")
    if expected is not None:
        s0, S0 = (fit.start, fit.survival0) if drawn else (0.0, 1.0)
        x = np.linspace(s0, fit.stop if drawn else end, 200)
        ax.plot(x, S0 * np.exp(-expected[0] * (x - s0)), "k--", lw=0.9, label=expected[1])
    ax.set_yscale("log")
    positive = S[S > 0]
    bottom = max(0.5 * float(positive.min()) if len(positive) else 1e-3, 0.5 / max(total, 1))
    if trapped is not None and trapped[1] > 0:
        bottom = min(bottom, 0.5 * trapped[1])
    ax.set_ylim(bottom, 1.5)
    ax.set_xlim(0.0, end)
    if total and exits == total and len(S):
        # every orbit left: S falls to 0 at the last exit, which a log axis cannot show; drawn as a drop to the
        # axis (the last level alone read as an orbit that stays, the shape of a trapped share)
        ax.plot([end, end], [S[-1], bottom], color=_colour(0), lw=1.2, clip_on=False)
        ax.plot([end], [bottom], "v", color=_colour(0), ms=6, clip_on=False,
                label=f"the last orbit leaves at s = {end:.4g}: S = 0 from there (off the log axis)")
        ax.set_xlim(0.0, 1.02 * end)
    ax.set_xlabel(unit)
    ax.set_ylabel("fraction still in the table S(s) [–]")
    legend_outside(ax, "below", ncols=1)
    return fig


# ---- sections (docs/reference.md §10) -------------------------------------------------------------------------


#: the width of a character of a wall's name over a Birkhoff map, in points (DejaVu Sans at the "small" size)
NAME_CHAR_PT = 5.0


def _name_walls(ax, walls):
    """Each wall named over the middle of its stretch of a Birkhoff map's axis, on a secondary axis on top: in two
    rows, alternately (the mushroom's short walls ran into one another on one), and a name left out where even
    two rows leave it no room (a wall shorter than half its name)."""
    (x0, x1) = ax.get_xlim()
    fig = ax.figure
    cols = max(1, ax.get_subplotspec().get_gridspec().ncols) if ax.get_subplotspec() else 1
    points = 0.75 * fig.get_figwidth() * 72.0 / cols / max(x1 - x0, 1e-300)     # points per unit of s
    ticks, names = [], []
    for i, (s, name, length) in enumerate(walls):
        if NAME_CHAR_PT * len(name) > 2.0 * length * points:
            continue
        ticks.append(s)
        names.append(name if len(ticks) % 2 else name + "\n")
    top = ax.secondary_xaxis("top")
    top.set_xticks(ticks, names, fontsize="small")
    top.tick_params(length=0, pad=1.0)


def _dress(ax, spec):
    """A panel's limits, aspect, labels and title from its spec (:func:`phase_figure`)."""
    if "xlim" in spec:
        ax.set_xlim(*spec["xlim"])
    if "ylim" in spec:
        ax.set_ylim(*spec["ylim"])
    if spec.get("equal"):
        (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
        if 1 / MAX_ASPECT <= abs(y1 - y0) / max(abs(x1 - x0), 1e-300) <= MAX_ASPECT:
            ax.set_aspect("equal", adjustable="box")
        else:                                   # to scale it would be a sliver with its tick labels run together
            ax.set_xlabel(spec["xlabel"] + " (not to scale)")
            spec = dict(spec, xlabel=spec["xlabel"] + " (not to scale)")
    ax.set_xlabel(spec["xlabel"])
    ax.set_ylabel(spec["ylabel"])
    if spec.get("walls"):
        _name_walls(ax, spec["walls"])
    if spec.get("title"):
        ax.set_title(spec["title"])


def repeated_points(x, y, few=20):
    """Where a section's points fall on at most ``few`` places (to 1e-9 of the data's span), each hit several
    times (a periodic orbit) -> a note saying so, else None."""
    xy = np.column_stack([np.asarray(x, float), np.asarray(y, float)])
    xy = xy[np.all(np.isfinite(xy), axis=1)]
    if len(xy) < 2:
        return None
    span = float(np.max(np.ptp(xy, axis=0))) or 1.0
    places = len(np.unique(np.round(xy / (1e-9 * span)), axis=0))
    if places > few or len(xy) < 3 * places:
        return None
    return (f"{len(xy)} points on {places} place{'s' if places != 1 else ''}: a periodic orbit, each hit about "
            f"{len(xy) / places:.0f} times")


@styled
def section_figure(panels, spin, title, spin_label):
    """Sections of phase space coloured by the (scaled) spin: ``panels`` as for :func:`phase_figure` (``x``,
    ``y``, labels, limits, ``vlines``); ``spin`` one value per point, on a diverging scale symmetric about 0."""
    fig = _figure(5.4 * len(panels) + 1.2, 5.0, title)
    spin = np.asarray(spin, float)
    top = float(np.nanmax(np.abs(spin))) if len(spin) else 1.0
    norm = Normalize(-top or -1.0, top or 1.0)
    ms = float(np.clip(30000.0 / max(len(spin), 1), 1.5, 12.0))
    axes = []
    for spec in panels:
        ax = fig.add_subplot(1, len(panels), len(axes) + 1)
        note = repeated_points(spec["x"], spec["y"])
        ax.scatter(spec["x"], spec["y"], c=spin, cmap="coolwarm", norm=norm, s=60.0 if note else ms, lw=0,
                   rasterized=True)
        for v in spec.get("vlines", ()):
            ax.axvline(v, color="0.6", lw=0.6, ls=":")
        _dress(ax, spec)
        if note:        # a periodic orbit: a few dots, each hit hundreds of times, looked like a plot that failed
            ax.text(0.02, 0.98, note, transform=ax.transAxes, va="top", ha="left", fontsize="small",
                    bbox=dict(facecolor="white", edgecolor="0.7", alpha=0.9))
        axes.append(ax)
    from matplotlib.cm import ScalarMappable
    fig.colorbar(ScalarMappable(norm=norm, cmap="coolwarm"), ax=axes, label=spin_label, shrink=0.85)
    return fig


# ---- studies (rbx sweep; docs/studies.md) ----------------------------------------------------------------------


#: a study figure's lines, one each (then again): markers and dashes that stay apart where lines coincide
SERIES_MARKERS = ("o", "s", "^", "D", "v", "P")
SERIES_DASHES = ("-", "--", "-.", ":")


@styled
def sweep_figure(panels, title, width=None):
    """An observable against a varied parameter with error bars, one panel per spec in ``panels``, side by side.

    A panel: ``series`` [{x, y, err ((n,) symmetric or (2, n) below/above), label}], optional ``references``
    [{x, y, label}] (dashed: a closed form at each point, or a constant when ``x`` is None), ``xlabel``,
    ``ylabel``, ``title``, ``logx``, ``logy``, ``note`` (a legend line of its own: what the error bars are)."""
    width = width or (4.6 * len(panels) + 2.8)
    fig = _figure(width, 4.8, title)
    axes = fig.subplots(1, len(panels), squeeze=False)[0]
    legends = []
    for ax, panel in zip(axes, panels):
        shades = [s["shade"] for s in panel["series"] if "shade" in s]
        norm = None
        if shades:      # values spread over decades (a log-scaled key): a log colour bar, not 9 of 12 lines alike
            logged = min(shades) > 0 and max(shades) / min(shades) >= 10
            norm = (LogNorm if logged else Normalize)(min(shades), max(shades))
        for k, s in enumerate(panel["series"]):
            x, y = np.asarray(s["x"], float), np.asarray(s["y"], float)
            err = None if s.get("err") is None else np.asarray(s["err"], float)
            if err is not None:
                err = np.where(np.isfinite(err), err, 0.0)
            colour = colormaps["viridis"](norm(s["shade"])) if "shade" in s else s.get("color", _colour(k))
            if norm is None:
                # a few lines, each its own marker and dashes, each drawn over the last with smaller markers: where
                # two lines take the same values (shares of few orbits are k/n), both stay visible
                style = dict(marker=s.get("marker", SERIES_MARKERS[k % len(SERIES_MARKERS)]),
                             ms=max(3.0, 6.5 - 1.2 * k), ls=SERIES_DASHES[k % len(SERIES_DASHES)], capsize=3)
            else:
                style = dict(marker=s.get("marker", "o"), ms=2.5, capsize=0)
            ax.errorbar(x, y, yerr=err, lw=1.2, color=colour, label=s.get("label"), **style)
            # the x axis spans every point, those without a value (NaN) too: their gap is seen, not cropped away
            shown = x[np.isfinite(x) & ((x > 0) if panel.get("logx") else True)]
            ax.update_datalim(np.column_stack([shown, np.zeros_like(shown)]), updatey=False)
        if norm is not None:        # many lines: a colour bar of their key, not a legend entry each
            from matplotlib.cm import ScalarMappable
            fig.colorbar(ScalarMappable(norm=norm, cmap="viridis"), ax=ax, label=panel.get("shade_label", ""),
                         shrink=0.85)
        for k, ref in enumerate(panel.get("references", ())):
            colour = colormaps["viridis"](norm(ref["shade"])) if "shade" in ref and norm is not None else \
                ref.get("color", "k")
            # above the points' line: a closed form the data follow was hidden under it
            style = dict(color=colour, ls=ref.get("ls", "--"), lw=1.0, label=ref.get("label"), zorder=3)
            if ref.get("x") is None:
                ax.axhline(float(ref["y"]), **style)
            else:
                ax.plot(np.asarray(ref["x"], float), np.asarray(ref["y"], float), **style)
        if panel.get("note"):
            ax.plot([], [], " ", label=panel["note"])
        if panel.get("logx"):
            ax.set_xscale("log")
        elif all(np.all(np.asarray(s["x"], float) == np.round(np.asarray(s["x"], float)))
                 for s in panel["series"]):
            ax.xaxis.set_major_locator(MaxNLocator(integer=True))     # a rank, a count: no tick at 0.2
        if panel.get("logy"):
            ax.set_yscale("log")
        ax.set_xlabel(panel.get("xlabel", ""))
        ax.set_ylabel(panel.get("ylabel", ""))
        if panel.get("ylim") is not None:
            ax.set_ylim(*panel["ylim"])
        if panel.get("title"):
            ax.set_title(panel["title"])
        ax.grid(True, alpha=0.3)
        if any(h.get_label() and not h.get_label().startswith("_") for h in ax.get_lines() + ax.containers):
            handles, labels = ax.get_legend_handles_labels()
            order = sorted(range(len(labels)), key=lambda i: labels[i] == panel.get("note"))    # the note last
            legends.append((ax, ax.legend([handles[i] for i in order], [labels[i] for i in order],
                                          fontsize="small", loc="upper center", bbox_to_anchor=(0.5, 0.0),
                                          borderaxespad=0.0)))
    if legends:         # one draw measures every panel's axis labels; each legend then goes under its own
        fig.draw_without_rendering()
        for ax, legend in legends:
            legend.set_bbox_to_anchor((0.5, 0.0), transform=_below_the_xlabel(ax))
    return fig


def _below_the_xlabel(ax, gap=4.0):
    """A transform whose (0.5, 0) is under the middle of ``ax``'s x-axis label with ``gap`` points between them
    (``ax``'s figure drawn once before): a legend anchored there never covers the label. The depth of the tick
    labels and the label below the axes is measured in points, which the layout keeps when it changes the axes'
    height (a fixed axes fraction, -0.16, put the legend over the label of short axes under a tall title)."""
    from matplotlib.transforms import offset_copy
    fig = ax.figure
    renderer = fig._get_renderer()
    boxes = [ax.xaxis.label.get_window_extent(renderer)] + [
        t.get_window_extent(renderer) for t in ax.get_xticklabels() if t.get_visible() and t.get_text()]
    lowest = min(b.y0 for b in boxes if np.all(np.isfinite(b.extents)))
    depth = max(0.0, ax.bbox.y0 - lowest) * 72.0 / fig.dpi
    return offset_copy(ax.transAxes, fig=fig, y=-(depth + gap), units="points")
