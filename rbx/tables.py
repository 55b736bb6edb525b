"""The registry of table kinds: one record per kind, read generically by everything else.

A :class:`TableKind` holds every facet of a kind: its dimension, its parameters and their checks, the walls it
is made of (:func:`walls`: pieces of lines, planes and circles in the table's own coordinates, before shrinking
by the ball's radius), the builder of the shrunk table the engine runs on (``build``: a function of
:mod:`rbx.geometry`), the "ball fits" check, a length scale for tolerances, a phrase for titles, how to draw it
in the plane, and example parameters for the tests. The config loader, the engine's geometry, the plots, the
titles, the precise (mpmath) loop and the tests' reference loop all go through this registry; none names a kind.
``tests/test_tables.py`` fails when a registered kind lacks a facet.

How to add a table kind: write its geometry builder in :mod:`rbx.geometry` (most kinds are made of the existing
primitives), then one :func:`register` call here with its facets, and its tests (a catalog scene in
``tests/catalog.py``).

Wall pieces (:func:`walls`) are plain data whose numbers the precise loop can evaluate at its own precision: a
direction is a tuple of numbers or ``("deg", θ)``, the unit vector at angle θ (degrees) from the x axis.

| piece | meaning |
|---|---|
| :class:`Line` | 2D flat wall {point + s·direction, s_min ≤ s ≤ s_max}, inward ``normal`` |
| :class:`Plane` | 3D flat wall through ``point`` with inward ``normal`` and tangent axes; contact points bounded by the box ``[lo, hi]`` of the table (±inf: unbounded) |
| :class:`Circle` | 2D round table (the inside of the circle), one wall |
| :class:`Polygon` | 2D closed boundary through ``vertices`` (counter-clockwise), wall i the edge from vertex i to i+1; reflex vertices are rounded by R in the shrunk table |
"""
import math
from dataclasses import dataclass

import numpy as np

from . import geometry

INF = math.inf


# ---- wall pieces ------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Line:
    name: str
    point: tuple
    direction: tuple
    normal: tuple
    s_min: float = -INF
    s_max: float = INF


@dataclass(frozen=True)
class Plane:
    name: str
    point: tuple
    normal: tuple
    tangents: tuple
    lo: tuple = (-INF, -INF, -INF)
    hi: tuple = (INF, INF, INF)


@dataclass(frozen=True)
class Circle:
    name: str
    center: tuple
    radius: float


@dataclass(frozen=True)
class Polygon:
    names: tuple
    vertices: tuple


def unit(direction, cos=math.cos, sin=math.sin, radians=math.radians):
    """A piece's direction as numbers: ``("deg", θ)`` -> (cos θ, sin θ); a tuple stays as it is."""
    if direction and direction[0] == "deg":
        th = radians(direction[1])
        return (cos(th), sin(th))
    return tuple(direction)


def wall_names(pieces):
    """The walls' names in wall order (the order of the pieces, a polygon's edges in turn) -> list."""
    return [name for p in pieces for name in (p.names if isinstance(p, Polygon) else (p.name,))]


# ---- the record -------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class TableKind:
    """Every facet of one table kind (see the module docstring). ``params``: name -> check(value, checker, key)
    returning the plain validated value (``checker`` is :class:`rbx.config._Checker`, ``key`` the dotted key);
    ``walls(p)``: the pieces; ``build(p, R)``: the shrunk table (:class:`rbx.geometry.Geometry`);
    ``fits(p, R, geom)``: None or why a ball of radius R does not fit; ``scale(p)``: a length scale;
    ``phrase(p)``: 'in a 2 × 1 rectangle'; ``draw(ax, geom, lo, hi)``: the table and the shrunk table on 2D axes
    (a 3D table: its horizontal projection) over the data range [lo, hi]; ``example``: parameters for tests."""
    name: str
    dimension: int
    description: str
    params: dict
    walls: object
    build: object
    fits: object
    scale: object
    phrase: object
    draw: object
    example: dict


KINDS = {}


def register(kind):
    """Add a table kind to the registry -> the kind."""
    if kind.name in KINDS:
        raise ValueError(f"table kind {kind.name!r} registered twice")
    KINDS[kind.name] = kind
    return kind


def kind(name):
    return KINDS[name]


def build(name, params, R):
    """The shrunk table of kind ``name`` with (validated) ``params`` for a ball of radius R -> Geometry, which
    keeps the kind's parameters (``geom.table``)."""
    geom = KINDS[name].build(params, R)
    geom.table = dict(params)
    return geom


def walls(name, params):
    """The wall pieces of a table (see the module docstring) -> list."""
    return list(KINDS[name].walls(params))


# ---- parameter checks -------------------------------------------------------------------------------------------

def positive(value, c, key):
    return c.number(value, key, positive=True)


def angle_deg(value, c, key):
    return c.number(value, key, lo=0, hi=180, lo_open=True, hi_open=True)


def size3(value, c, key):
    size = c.vector(value, key, 3)
    for i, s in enumerate(size):
        if s <= 0:
            c.fail(f"{key}[{i}]", f"must be positive, got {s:g}")
    return list(size)


def vertices(value, c, key):
    """At least 3 points, counter-clockwise, no repeated consecutive vertex, not crossing or touching itself."""
    if not isinstance(value, list) or len(value) < 3:
        c.fail(key, f"expected a list of at least 3 points [x, y], got {c.kind(value)}"
               + (f" of {len(value)}" if isinstance(value, list) else ""))
    V = np.array([c.vector(p, f"{key}[{i}]", 2) for i, p in enumerate(value)])
    with np.errstate(over="ignore", invalid="ignore"):
        area = 0.5 * np.sum(V[:, 0] * np.roll(V[:, 1], -1) - np.roll(V[:, 0], -1) * V[:, 1])
    if not np.isfinite(area):
        c.fail(key, "coordinates too large (the area overflows)")
    if np.any(np.all(np.roll(V, -1, axis=0) == V, axis=1)):
        c.fail(key, "two consecutive vertices coincide")
    if _self_intersecting(V):
        c.fail(key, "the polygon crosses or touches itself")
    if area <= 0:
        c.fail(key, "must be listed counter-clockwise (the signed area is not positive)")
    return V.tolist()


def _self_intersecting(V):
    """Whether two non-adjacent edges cross or touch (a vertex on another edge counts: the shrunk table of such
    a polygon pinches to nothing there)."""
    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    def on_segment(p, a, b):
        return min(a[0], b[0]) <= p[0] <= max(a[0], b[0]) and min(a[1], b[1]) <= p[1] <= max(a[1], b[1])

    m = len(V)
    for i in range(m):
        a, b = V[i], V[(i + 1) % m]
        for j in range(i + 2, m):
            if i == 0 and j == m - 1:
                continue
            p, q = V[j], V[(j + 1) % m]
            d1, d2 = cross(a, b, p), cross(a, b, q)
            d3, d4 = cross(p, q, a), cross(p, q, b)
            if d1 * d2 < 0 and d3 * d4 < 0:
                return True
            if (d1 == 0 and on_segment(p, a, b)) or (d2 == 0 and on_segment(q, a, b)) or \
                    (d3 == 0 and on_segment(a, p, q)) or (d4 == 0 and on_segment(b, p, q)):
                return True
    return False


# ---- fits, phrases, drawing -------------------------------------------------------------------------------------

def _g(x):
    return f"{float(x):g}"


def _edges_fit(p, R, geom):
    """A polygon fits when every edge of its shrunk table keeps a positive length."""
    if np.any(geom.lengths <= 0):
        bad = int(np.argmin(geom.lengths))
        return f"does not fit in the {geom.kind} (near wall '{geom.wall_names[bad]}')"
    return None


def _closed_outlines(ax, geom, style_table, style_shrunk):
    for line, style in ((geom.outline, style_table), (geom.shrunk_outline, style_shrunk)):
        if line is not None:
            closed = np.vstack([line, line[:1]])
            ax.plot(closed[:, 0], closed[:, 1], **style)


TABLE_STYLE = dict(color="0.15", lw=1.4)
SHRUNK_STYLE = dict(color="0.45", lw=0.9, ls="--")


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


# ---- the kinds (SPEC §2) ----------------------------------------------------------------------------------------

def _strip_walls(p):
    w = p["width"]
    return [Line("bottom", (0.0, 0.0), (1.0, 0.0), (0.0, 1.0)), Line("top", (0.0, w), (1.0, 0.0), (0.0, -1.0))]


def _wedge_walls(p):
    phi = p["angle_deg"]
    # wall1 is walked towards the vertex by a boundary with the table on its left: its inward normal is the left
    # normal of −e1, at angle φ − 90°
    return [Line("wall0", (0.0, 0.0), (1.0, 0.0), (0.0, 1.0), 0.0, INF),
            Line("wall1", (0.0, 0.0), ("deg", phi), ("deg", phi - 90.0), 0.0, INF)]


def _rectangle_vertices(p):
    w, h = p["width"], p["height"]
    return [[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]]


def _plates_walls(p):
    g = p["gap"]
    t = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0))
    return [Plane("bottom", (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), t), Plane("top", (0.0, 0.0, g), (0.0, 0.0, -1.0), t)]


BOX_FACES = (("left", 0, 0), ("right", 0, 1), ("front", 1, 0), ("back", 1, 1), ("bottom", 2, 0), ("top", 2, 1))


def _box_walls(p):
    size = tuple(float(s) for s in p["size"])
    E = np.eye(3)
    out = []
    for name, axis, side in BOX_FACES:
        point = [0.0, 0.0, 0.0]
        point[axis] = 0.0 if side == 0 else size[axis]
        normal = tuple(float(x) for x in E[axis] * (1.0 if side == 0 else -1.0))
        t1, t2 = (tuple(float(x) for x in E[k]) for k in range(3) if k != axis)
        lo = tuple(-INF if k == axis else 0.0 for k in range(3))
        hi = tuple(INF if k == axis else size[k] for k in range(3))
        out.append(Plane(name, tuple(point), normal, (t1, t2), lo, hi))
    return out


def _fits_width(name, what):
    """A ball fits between two parallel walls ``p[name]`` apart when 2R is less: ``what`` names them, with {}."""
    def fits(p, R, geom):
        return "does not fit " + what.format(_g(p[name])) if 2 * R >= p[name] else None
    return fits


register(TableKind(
    "strip", 2, "infinite along x, walls y = 0 and y = width", {"width": positive},
    walls=_strip_walls, build=geometry.strip, fits=_fits_width("width", "in a strip of width {}"),
    scale=lambda p: p["width"], phrase=lambda p: f"in a strip of width {_g(p['width'])}", draw=_draw_strip,
    example={"width": 1.0}))
register(TableKind(
    "circle", 2, "a disc of the given radius about the origin", {"radius": positive},
    walls=lambda p: [Circle("rim", (0.0, 0.0), p["radius"])], build=geometry.circle,
    fits=lambda p, R, geom: (f"does not fit in a circle of radius {_g(p['radius'])}" if R >= p["radius"] else None),
    scale=lambda p: p["radius"], phrase=lambda p: f"in a circle of radius {_g(p['radius'])}", draw=_draw_outline,
    example={"radius": 1.0}))
register(TableKind(
    "wedge", 2, "vertex at the origin, walls along angle 0 and angle_deg", {"angle_deg": angle_deg},
    walls=_wedge_walls, build=geometry.wedge, fits=lambda p, R, geom: None, scale=lambda p: 1.0,
    phrase=lambda p: f"in a {_g(p['angle_deg'])}° wedge", draw=_draw_wedge, example={"angle_deg": 60.0}))
register(TableKind(
    "rectangle", 2, "width × height, corner at the origin", {"width": positive, "height": positive},
    walls=lambda p: [Polygon(("bottom", "right", "top", "left"), tuple(map(tuple, _rectangle_vertices(p))))],
    build=geometry.rectangle, fits=_edges_fit, scale=lambda p: max(p["width"], p["height"]),
    phrase=lambda p: f"in a {_g(p['width'])} × {_g(p['height'])} rectangle", draw=_draw_outline,
    example={"width": 2.0, "height": 1.0}))
register(TableKind(
    "polygon", 2, "vertices counter-clockwise, convex or not", {"vertices": vertices},
    walls=lambda p: [Polygon(tuple(f"edge{i}" for i in range(len(p["vertices"]))),
                             tuple(map(tuple, p["vertices"])))],
    build=geometry.polygon, fits=_edges_fit,
    scale=lambda p: max(float(np.linalg.norm(v)) for v in p["vertices"]),
    phrase=lambda p: f"in a polygon with {len(p['vertices'])} vertices", draw=_draw_outline,
    example={"vertices": [[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [1.0, 1.0], [1.0, 2.0], [0.0, 2.0]]}))
register(TableKind(
    "plates", 3, "infinite in x and y, walls z = 0 and z = gap", {"gap": positive},
    walls=_plates_walls, build=geometry.plates, fits=_fits_width("gap", "between plates {} apart"),
    scale=lambda p: p["gap"], phrase=lambda p: f"between plates {_g(p['gap'])} apart", draw=_draw_nothing,
    example={"gap": 1.0}))
register(TableKind(
    "box", 3, "size [lx, ly, lz], corner at the origin", {"size": size3},
    walls=_box_walls, build=geometry.box,
    fits=lambda p, R, geom: (f"does not fit in a box of size {p['size']}" if 2 * R >= min(p["size"]) else None),
    scale=lambda p: max(p["size"]), phrase=lambda p: "in a " + " × ".join(_g(x) for x in p["size"]) + " box",
    draw=_draw_box, example={"size": [2.0, 1.5, 1.0]}))
