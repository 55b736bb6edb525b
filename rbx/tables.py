"""The registry of table kinds: one record per kind, read generically by everything else.

A :class:`TableKind` holds every facet of a kind: its dimension, its parameters and their checks, the walls it
is made of (:func:`walls`: pieces of lines, planes and circles in the table's own coordinates, before shrinking
by the ball's radius), the builder of the shrunk table the engine runs on (``build``: a function of
:mod:`rbx.construction`), the "ball fits" check, a length scale for tolerances, a phrase for titles, how to draw it
in the plane, and example parameters for the tests. The config loader, the engine's geometry, the plots, the
titles, the precise (mpmath) loop and the tests' reference loop all go through this registry; none names a kind.
``tests/test_tables.py`` fails when a registered kind lacks a facet.

How to add a table kind: write its builder in :mod:`rbx.construction` (most kinds are made of the existing
primitives), then one :func:`register` call here with its facets, and its tests (a catalog scene in
``tests/catalog.py``).

A kind's walls are wall pieces (:mod:`rbx.pieces`: plain data the precise loop can evaluate at its own precision),
re-exported here.
"""
import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from . import drawing, geometry
from .drawing import (SHRUNK_STYLE, TABLE_STYLE, _draw_box, _draw_nothing, _draw_outline,  # noqa: F401
                      _draw_strip, _draw_wedge)
from .pieces import (INF, OBSTACLES, Arc, Boundary, Circle, Cylinder, Lattice, Line, Plane,  # noqa: F401
                     Polygon, Segment, Sphere, piece_names, unit, wall_names)
from .model import SERVICES

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
    #: optional parameters: name -> check, as ``params`` (``obstacles`` is optional for every kind: OBSTACLES)
    optional: dict = None


KINDS = {}
#: ``build=FROM_WALLS`` in a registration: the kind is built from its wall pieces alone (:func:`from_walls`)
FROM_WALLS = "from its walls"


def register(kind):
    """Add a table kind to the registry -> the kind. ``build=FROM_WALLS``: built from its walls (the zoo)."""
    if kind.name in KINDS:
        raise ValueError(f"table kind {kind.name!r} registered twice")
    if kind.build is FROM_WALLS:
        kind = dataclasses.replace(kind, build=from_walls(kind.name))
    KINDS[kind.name] = kind
    return kind


def kind(name):
    return KINDS[name]


def dimension(name, params):
    """The dimension of a table: the kind's, or for a kind that exists in 2D and 3D (``sinai``, ``lorentz``) the
    one its parameters give -> 2 or 3."""
    d = KINDS[name].dimension
    return d(params) if callable(d) else d


def build(name, params, R):
    """The shrunk table of kind ``name`` with (validated) ``params`` for a ball of radius R -> Geometry, which
    keeps the kind's parameters (``geom.table``). A kind without a builder of its own (``build=None``: the presets
    and ``custom``) is built from its walls by :func:`rbx.geometry.from_pieces`; obstacles are added to any kind
    the same way."""
    k = KINDS[name]
    geom = (from_walls(name) if params.get("periodic") else k.build)(params, R)
    geom.table = dict(params)
    extra = obstacle_pieces(params)
    if extra:
        geom = geometry.add_pieces(geom, extra, R, own=walls(name, params))
        geom.table = dict(params)
    return geom


def from_walls(name):
    """The builder of a kind made of its wall pieces alone (the zoo's presets, ``custom``, a periodic cell):
    :func:`rbx.geometry.from_pieces` of the kind's own walls -> function (params, R) -> Geometry."""
    def build_it(params, R):
        return geometry.from_pieces(name, dimension(name, params), list(KINDS[name].walls(params)), R,
                                    scale=KINDS[name].scale(params))
    return build_it


def walls(name, params):
    """The wall pieces of a table (see the module docstring), the obstacles last -> list."""
    return list(KINDS[name].walls(params)) + obstacle_pieces(params)


def obstacle_pieces(params):
    """The ``obstacles`` parameter (validated) as :class:`Sphere` pieces -> list."""
    out = []
    for ob in params.get(OBSTACLES) or ():
        shape = ob["disc"] if "disc" in ob else ob["sphere"]
        out.append(Sphere(ob["name"], tuple(float(x) for x in shape["center"]), float(shape["radius"]), False))
    return out


# ---- parameter checks -------------------------------------------------------------------------------------------

def flag(value, c, key):
    if not isinstance(value, bool):
        c.fail(key, f"expected true or false, got {c.kind(value)}")
    return value


def positive(value, c, key):
    return c.number(value, key, positive=True)


#: the lattices of the ``lorentz`` preset: one scatterer per cell at its centre, or two (centred: at a quarter
#: and three quarters of the cell's diagonal — a triangular lattice when the cell is [d, d√3])
LATTICES = ("simple", "centred")


def lattice(value, c, key):
    return c.choice(value, key, LATTICES, "lattice")


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
        D = V - V[0]               # from the first vertex: from the origin, a square at 1e8 cancelled to nothing
        area = 0.5 * np.sum(D[:, 0] * np.roll(D[:, 1], -1) - np.roll(D[:, 0], -1) * D[:, 1])
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


# ---- the kinds (docs/reference.md §2) --------------------------------------------------------------------------

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


def _rectangle_fits(p, R):
    """A ball fits in a rectangle when its diameter is less than the width and the height: the one it is not less
    than is named (the polygon's check named the wall left too short, 'right', for a height of 0.15)."""
    for side in ("width", "height"):
        if 2 * R >= p[side]:
            return (f"does not fit in a {_g(p['width'])} × {_g(p['height'])} rectangle: its {side} {_g(p[side])} is "
                    f"not more than the ball's diameter {_g(2 * R)}")
    return None


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
    walls=lambda p: ([Lattice((0.0, 0.0), (float(p["width"]), float(p["height"])))] if p.get("periodic") else
                     [Polygon(("bottom", "right", "top", "left"), tuple(map(tuple, _rectangle_vertices(p))))]),
    build=geometry.rectangle, fits=lambda p, R, geom: None if p.get("periodic") else _rectangle_fits(p, R),
    scale=lambda p: max(p["width"], p["height"]),
    phrase=lambda p: f"in a {'periodic ' if p.get('periodic') else ''}{_g(p['width'])} × {_g(p['height'])} "
                     "rectangle", draw=_draw_outline,
    example={"width": 2.0, "height": 1.0}, optional={"periodic": flag}))
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
    walls=lambda p: ([Lattice((0.0, 0.0, 0.0), tuple(float(x) for x in p["size"]))] if p.get("periodic") else
                     _box_walls(p)), build=geometry.box,
    fits=lambda p, R, geom: (f"does not fit in a box of size {p['size']}"
                             if 2 * R >= min(p["size"]) and not p.get("periodic") else None),
    scale=lambda p: max(p["size"]),
    phrase=lambda p: "in a " + ("periodic " if p.get("periodic") else "") + " × ".join(_g(x) for x in p["size"])
                     + " box", draw=_draw_box,
    example={"size": [2.0, 1.5, 1.0]}, optional={"periodic": flag}))


# ---- the zoo (docs/reference.md §8): walls as data, built by rbx.geometry.from_pieces ------------------------


def size23(value, c, key):
    """A rectangle [w, h] or a box [lx, ly, lz] of positive sides."""
    if not isinstance(value, list) or len(value) not in (2, 3):
        c.fail(key, f"expected a list of 2 (a rectangle) or 3 (a box) positive numbers, got {c.kind(value)}"
               + (f" of {len(value)}" if isinstance(value, list) else ""))
    size = c.vector(value, key, len(value))
    for i, s in enumerate(size):
        if s <= 0:
            c.fail(f"{key}[{i}]", f"must be positive, got {s:g}")
    return list(size)


#: joints and radii agree to this fraction of the boundary's size (the config's numbers are decimal)
JOIN_TOLERANCE = 1e-9


def boundary(value, c, key):
    """A closed 2D boundary of pieces ``{name, from, to}`` (segment) or ``{name, from, to, center, turn}`` (arc),
    each starting where the previous one ends, counter-clockwise, not crossing itself -> list of plain mappings."""
    if not isinstance(value, list) or len(value) < 2:
        c.fail(key, f"expected a list of at least 2 pieces ({{name, from, to}} or {{name, from, to, center, turn}}), "
                    f"got {c.kind(value)}" + (f" of {len(value)}" if isinstance(value, list) else ""))
    out, names = [], set()
    for i, piece in enumerate(value):
        k = f"{key}[{i}]"
        arc = isinstance(piece, dict) and ("center" in piece or "turn" in piece)
        c.mapping(piece, k, ("name", "from", "to", "center", "turn"),
                  ("name", "from", "to") + (("center", "turn") if arc else ()))
        name = piece["name"]
        if not isinstance(name, str) or not name:
            c.fail(f"{k}.name", f"expected a wall name, got {c.kind(name)}")
        if name in names:
            c.fail(f"{k}.name", f"'{name}' names two walls")
        names.add(name)
        q = {"name": name, "from": list(c.vector(piece["from"], f"{k}.from", 2)),
             "to": list(c.vector(piece["to"], f"{k}.to", 2))}
        if q["from"] == q["to"]:
            c.fail(k, "starts where it ends (a piece of zero length)")
        if arc:
            q["center"] = list(c.vector(piece["center"], f"{k}.center", 2))
            q["turn"] = c.choice(piece["turn"], f"{k}.turn", ("ccw", "cw"), "turn")
        out.append(q)
    pieces = boundary_pieces(out)
    # a fraction of the boundary's extent, plus the rounding of its coordinates: a fraction of the largest
    # coordinate let a gap of 0.05 through in a table 10 wide at x = 1e8, and the ball fell out through it
    pts = np.array([p["from"] + p["to"] for p in out], float).reshape(-1, 2)
    extent = float(np.max(np.ptp(pts, axis=0))) or 1.0
    tol = JOIN_TOLERANCE * extent + 64 * np.finfo(float).eps * float(np.max(np.abs(pts)))
    for i, (p, q) in enumerate(zip(out, pieces)):
        if isinstance(q, Arc):
            r0 = math.dist(q.start, q.center)
            r1 = math.dist(q.end, q.center)
            if abs(r0 - r1) > tol:
                c.fail(f"{key}[{i}].center", f"is {r0:g} from 'from' but {r1:g} from 'to': not the centre of a "
                                             "circle through both")
        nxt = out[(i + 1) % len(out)]
        if math.dist(p["to"], nxt["from"]) > tol:
            c.fail(f"{key}[{(i + 1) % len(out)}].from", f"{nxt['from']} is not where the previous piece "
                                                        f"'{p['name']}' ends ({p['to']}): the boundary must be closed")
    poly = geometry.boundary_polyline(pieces, 64)
    if _self_intersecting(poly) or geometry.arcs_cross(pieces, tol):
        c.fail(key, "the boundary crosses or touches itself")
    area = geometry.boundary_area(pieces)
    if not area > 0:
        c.fail(key, "must go counter-clockwise, the table on the left (the enclosed area is not positive)")
    return out


def boundary_pieces(plain):
    """Validated boundary mappings -> :class:`Segment` / :class:`Arc` pieces (each piece starts exactly where the
    previous one ends: at the previous piece's ``to``)."""
    out = []
    for p in plain:
        start, end = tuple(p["from"]), tuple(p["to"])
        if "center" in p:
            out.append(Arc(p["name"], start, end, tuple(p["center"]), p["turn"]))
        else:
            out.append(Segment(p["name"], start, end))
    return out


def obstacles(value, c, key, n):
    """``[{name, disc: {center, radius}}]`` (2D) or ``[{name, sphere: {center, radius}}]`` (3D) -> plain list."""
    shape = "disc" if n == 2 else "sphere"
    if not isinstance(value, list):
        c.fail(key, f"expected a list of {{name, {shape}: {{center, radius}}}}, got {c.kind(value)}")
    out = []
    for i, ob in enumerate(value):
        k = f"{key}[{i}]"
        c.mapping(ob, k, ("name", shape), ("name", shape))
        if not isinstance(ob["name"], str) or not ob["name"]:
            c.fail(f"{k}.name", f"expected a wall name, got {c.kind(ob['name'])}")
        c.mapping(ob[shape], f"{k}.{shape}", ("center", "radius"), ("center", "radius"))
        out.append({"name": ob["name"], shape: {
            "center": list(c.vector(ob[shape]["center"], f"{k}.{shape}.center", n)),
            "radius": c.number(ob[shape]["radius"], f"{k}.{shape}.radius", positive=True)}})
    return out


def _zoo_fits(p, R, geom):
    """Tables built from pieces are checked by :func:`fits` (:func:`rbx.geometry.check_fit`) for every kind."""
    return None


def fits(name, p, R, geom):
    """None, or why a ball of radius R does not fit the table: the kind's own check, then for a table with pieces
    (the zoo, obstacles on any kind) :func:`rbx.geometry.check_fit` (pieces too small, obstacles overlapping each
    other or the boundary once grown by R, a free region with no room)."""
    problem = KINDS[name].fits(p, R, geom)
    if problem is None and geom.pieces:
        problem = geometry.check_fit(geom, R)
    return problem


_draw_pieces = drawing.draw_pieces


def draw(ax, geom, lo, hi):
    """Draw a table on 2D axes (a 3D table: its horizontal projection) over the data range [lo, hi]: the kind's
    own drawing, or for a table built from pieces (the zoo, a periodic cell) the pieces; obstacles on top."""
    k = KINDS[geom.kind]
    if geom.from_pieces:
        _draw_pieces(ax, geom, lo, hi)
        return
    k.draw(ax, geom, lo, hi)
    if geom.pieces is not None:
        _draw_pieces(ax, geom, lo, hi)


def _scale_of_pieces(pieces):
    pts = []
    for q in pieces:
        if isinstance(q, Boundary):
            for r in q.pieces:
                pts += [r.start, r.end]
                if isinstance(r, Arc):
                    rad = math.dist(r.start, r.center)
                    pts += [tuple(x + rad for x in r.center), tuple(x - rad for x in r.center)]
        elif isinstance(q, Polygon):
            pts += list(q.vertices)
        elif isinstance(q, Lattice):
            pts += [q.lo, q.hi]
        elif isinstance(q, Sphere):
            pts += [tuple(x + q.radius for x in q.center), tuple(x - q.radius for x in q.center)]
    return max(1e-300, float(np.max(np.ptp(np.array(pts, float), axis=0)))) if pts else 1.0


def _stadium_walls(p):
    r, L = p["radius"], p["length"]
    return [Boundary((Segment("bottom", (0.0, -r), (L, -r)), Arc("right", (L, -r), (L, r), (L, 0.0), "ccw"),
                      Segment("top", (L, r), (0.0, r)), Arc("left", (0.0, r), (0.0, -r), (0.0, 0.0), "ccw")))]


def _mushroom_walls(p):
    rc, w, h = p["cap_radius"], p["stem_width"], p["stem_height"]
    x = w / 2
    return [Boundary((Segment("stem_bottom", (-x, -h), (x, -h)), Segment("stem_right", (x, -h), (x, 0.0)),
                      Segment("cap_floor_right", (x, 0.0), (rc, 0.0)),
                      Arc("cap", (rc, 0.0), (-rc, 0.0), (0.0, 0.0), "ccw"),
                      Segment("cap_floor_left", (-rc, 0.0), (-x, 0.0)), Segment("stem_left", (-x, 0.0), (-x, -h))))]


def _cell_walls(size):
    if len(size) == 2:
        return [Polygon(("bottom", "right", "top", "left"),
                        ((0.0, 0.0), (size[0], 0.0), (size[0], size[1]), (0.0, size[1])))]
    return _box_walls({"size": size})


def _scatterer(size, radius):
    return Sphere("scatterer", tuple(0.5 * float(s) for s in size), float(radius), False)


register(TableKind(
    "custom", 2, "a closed boundary of segments and arcs, counter-clockwise", {"boundary": boundary},
    walls=lambda p: [Boundary(tuple(boundary_pieces(p["boundary"])))], build=FROM_WALLS, fits=_zoo_fits,
    scale=lambda p: _scale_of_pieces([Boundary(tuple(boundary_pieces(p["boundary"])))]),
    phrase=lambda p: f"in a custom table of {len(p['boundary'])} pieces", draw=_draw_pieces,
    example={"boundary": [{"name": "floor", "from": [0.0, 0.0], "to": [2.0, 0.0]},
                          {"name": "bulge", "from": [2.0, 0.0], "to": [2.0, 1.0], "center": [2.6, 0.5],
                           "turn": "cw"},
                          {"name": "roof", "from": [2.0, 1.0], "to": [0.0, 1.0]},
                          {"name": "cap", "from": [0.0, 1.0], "to": [0.0, 0.0], "center": [0.0, 0.5],
                           "turn": "ccw"}]}))
register(TableKind(
    "stadium", 2, "Bunimovich stadium: half discs of radius about (0, 0) and (length, 0) joined by straight walls",
    {"radius": positive, "length": positive}, walls=_stadium_walls, build=FROM_WALLS, fits=_zoo_fits,
    scale=lambda p: p["length"] + 2 * p["radius"],
    phrase=lambda p: f"in a stadium of radius {_g(p['radius'])} and length {_g(p['length'])}", draw=_draw_pieces,
    example={"radius": 0.5, "length": 1.0}))
register(TableKind(
    "sinai", lambda p: len(p["size"]), "a rectangle [w, h] or box [lx, ly, lz] with a disc or sphere at its centre",
    {"size": size23, "radius": positive},
    walls=lambda p: _cell_walls(p["size"]) + [_scatterer(p["size"], p["radius"])], build=FROM_WALLS, fits=_zoo_fits,
    scale=lambda p: max(p["size"]),
    phrase=lambda p: f"in a Sinai {'billiard' if len(p['size']) == 2 else 'box'} "
                     + " × ".join(_g(x) for x in p["size"]) + f" with a scatterer of radius {_g(p['radius'])}",
    draw=_draw_pieces, example={"size": [2.0, 1.5], "radius": 0.4}))
def _lorentz_walls(p):
    cell = tuple(float(x) for x in p["cell"])
    walls = [Lattice(tuple(0.0 for _ in cell), cell)]
    if p.get("lattice", "simple") == "simple":
        return walls + [_scatterer(cell, p["radius"])]
    return walls + [Sphere(name, tuple(f * s for s in cell), float(p["radius"]), False)
                    for name, f in (("scatterer", 0.25), ("scatterer2", 0.75))]


register(TableKind(
    "lorentz", lambda p: len(p["cell"]), "periodic Lorentz gas: a disc or sphere of radius at the centre of each "
    "cell (lattice: centred, two: at a quarter and three quarters of the cell's diagonal)",
    {"cell": size23, "radius": positive},
    walls=_lorentz_walls, build=FROM_WALLS, fits=_zoo_fits,
    scale=lambda p: max(p["cell"]),
    phrase=lambda p: ("in a periodic Lorentz gas, " + ("" if p.get("lattice", "simple") == "simple" else
                                                       "centred lattice, ")
                      + "cell " + " × ".join(_g(x) for x in p["cell"]) + f", scatterer radius {_g(p['radius'])}"),
    draw=_draw_pieces, example={"cell": [1.0, 1.0], "radius": 0.3}, optional={"lattice": lattice}))
register(TableKind(
    "mushroom", 2, "Bunimovich mushroom: a half disc y ≥ 0 on a stem centred on x = 0",
    {"cap_radius": positive, "stem_width": positive, "stem_height": positive},
    walls=_mushroom_walls, build=FROM_WALLS,
    fits=lambda p, R, geom: (("stem_width", f"must be less than the cap's diameter 2·cap_radius "
                                            f"({_g(2 * p['cap_radius'])}), got {_g(p['stem_width'])}")
                             if p["stem_width"] >= 2 * p["cap_radius"] else None),
    scale=lambda p: max(2 * p["cap_radius"], p["cap_radius"] + p["stem_height"]),
    phrase=lambda p: f"in a mushroom (cap radius {_g(p['cap_radius'])}, stem {_g(p['stem_width'])} × "
                     f"{_g(p['stem_height'])})", draw=_draw_pieces,
    example={"cap_radius": 1.0, "stem_width": 0.6, "stem_height": 1.0}))
register(TableKind(
    "sphere", 3, "the inside of a sphere about the origin", {"radius": positive},
    walls=lambda p: [Sphere("sphere", (0.0, 0.0, 0.0), float(p["radius"]), True)], build=FROM_WALLS, fits=_zoo_fits,
    scale=lambda p: 2 * p["radius"], phrase=lambda p: f"in a sphere of radius {_g(p['radius'])}",
    draw=_draw_pieces, example={"radius": 1.0}))


def _cylinder_walls(p):
    h, t = float(p["height"]), ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0))
    return [Plane("bottom", (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), t), Plane("top", (0.0, 0.0, h), (0.0, 0.0, -1.0), t),
            Cylinder("side", (0.0, 0.0), float(p["radius"]))]


register(TableKind(
    "cylinder", 3, "axis z, caps at z = 0 and z = height", {"radius": positive, "height": positive},
    walls=_cylinder_walls, build=FROM_WALLS, fits=_zoo_fits, scale=lambda p: max(2 * p["radius"], p["height"]),
    phrase=lambda p: f"in a cylinder of radius {_g(p['radius'])} and height {_g(p['height'])}",
    draw=_draw_pieces, example={"radius": 1.0, "height": 1.5}))


# an experiment's geometry is built here (rbx.model asks through SERVICES: the model imports no table code)
SERVICES["build"] = build
