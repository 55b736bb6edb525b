"""Wall pieces: a table's walls as plain data, before the ball's radius shrinks them, and their plane geometry
(frames of a boundary's segments and arcs, its polyline and area, whether arcs cross, the clearance of points in
a table made of pieces). The registry of table kinds (:mod:`rbx.tables`) lists each kind's walls as these pieces;
:mod:`rbx.construction` turns them into the shrunk table's primitives; the precise loop (:mod:`rbx.precise`) and
the tests' reference loop read them at their own precision. Imports no other rbx module.

Numbers in a piece are plain data the precise loop can evaluate at its own precision: a direction is a tuple of
numbers or ``("deg", θ)``, the unit vector at angle θ (degrees) from the x axis.

| piece | meaning |
|---|---|
| :class:`Line` | 2D flat wall {point + s·direction, s_min ≤ s ≤ s_max}, inward ``normal`` |
| :class:`Plane` | 3D flat wall through ``point`` with inward ``normal`` and tangent axes; contact points bounded by the box ``[lo, hi]`` of the table (±inf: unbounded) |
| :class:`Circle` | 2D round table (the inside of the circle), one wall |
| :class:`Polygon` | 2D closed boundary through ``vertices`` (counter-clockwise), wall i the edge from vertex i to i+1; reflex vertices are rounded by R in the shrunk table |
| :class:`Boundary` | 2D closed boundary of :class:`Segment` and :class:`Arc` pieces |
| :class:`Sphere`, :class:`Cylinder` | a round wall (inside or an obstacle), a 3D cylinder's side |
| :class:`Lattice` | a periodic cell |
"""
import math
from dataclasses import dataclass

import numpy as np

INF = math.inf
#: the optional parameter every kind takes: scatterers inside the table (discs in 2D, spheres in 3D), walls named
#: by the user, after the kind's own walls
OBSTACLES = "obstacles"


# ---- the pieces ---------------------------------------------------------------------------------------------------

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


@dataclass(frozen=True)
class Segment:
    """2D straight piece of a :class:`Boundary` from ``start`` to ``end``; the table lies on its left."""
    name: str
    start: tuple
    end: tuple


@dataclass(frozen=True)
class Arc:
    """2D circular piece of a :class:`Boundary` from ``start`` to ``end`` on the circle about ``center``, going
    counter-clockwise (``turn = "ccw"``: focusing, the table on the circle's inside) or clockwise (``"cw"``:
    dispersing, the circle bulges into the table). Its radius is ``|start − center|`` (= ``|end − center|``, checked
    when the table is read); ``start == end`` is not allowed (a full circle is a :class:`Circle` or an obstacle)."""
    name: str
    start: tuple
    end: tuple
    center: tuple
    turn: str


@dataclass(frozen=True)
class Boundary:
    """A closed 2D outer boundary: ``pieces`` (:class:`Segment`, :class:`Arc`), each ending where the next starts,
    traversed counter-clockwise (the table on the left). Wall i is piece i. In the shrunk table a joint where the
    boundary turns clockwise (a reflex joint) is rounded by an arc of radius R about the joint, which belongs to
    the piece leaving the joint."""
    pieces: tuple


@dataclass(frozen=True)
class Sphere:
    """A round wall in n = len(center) dimensions (a circle in 2D, a sphere in 3D). ``inside``: the table is the
    inside of the sphere (the 3D ``sphere`` table); else the sphere is an obstacle (a scatterer: a disc in 2D), the
    table outside it. Shrunk table: radius − R inside, radius + R for an obstacle."""
    name: str
    center: tuple
    radius: float
    inside: bool = False


@dataclass(frozen=True)
class Cylinder:
    """3D side wall of a cylinder with axis parallel to z through ``center`` (x, y), the table inside it; its ends
    are closed by :class:`Plane` caps. Shrunk: radius − R."""
    name: str
    center: tuple
    radius: float


@dataclass(frozen=True)
class Lattice:
    """A periodic cell ``lo ≤ x ≤ hi``: opposite sides are identified (they are not walls: the ball passes
    through), and every other piece repeats with period ``hi − lo`` along each axis. Positions are recorded
    unfolded."""
    lo: tuple
    hi: tuple


def unit(direction, cos=math.cos, sin=math.sin, radians=math.radians):
    """A piece's direction as numbers: ``("deg", θ)`` -> (cos θ, sin θ); a tuple stays as it is."""
    if direction and direction[0] == "deg":
        th = radians(direction[1])
        return (cos(th), sin(th))
    return tuple(direction)


def piece_names(piece):
    """The names of the walls a piece makes, in order -> tuple."""
    if isinstance(piece, Polygon):
        return tuple(piece.names)
    if isinstance(piece, Boundary):
        return tuple(q.name for q in piece.pieces)
    if isinstance(piece, Lattice):
        return ()
    return (piece.name,)


def wall_names(pieces):
    """The walls' names in wall order (the order of the pieces, a polygon's edges and a boundary's pieces in
    turn) -> list."""
    return [name for p in pieces for name in piece_names(p)]


# ---- plane geometry of pieces ----------------------------------------------------------------------------------

def _polygon_clearance(pts, verts, R):
    """(inside ? +1 : −1)·distance to the polygon's edges − R."""
    p = pts.reshape(-1, 2)
    best = np.full(len(p), np.inf)
    inside = np.zeros(len(p), dtype=bool)
    m = len(verts)
    for i in range(m):
        a, b = verts[i], verts[(i + 1) % m]
        e = b - a
        s = np.clip(((p - a) @ e) / (e @ e), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(p - (a + s[:, None] * e), axis=1))
        crosses = (a[1] > p[:, 1]) != (b[1] > p[:, 1])
        xint = a[0] + (p[:, 1] - a[1]) * e[0] / np.where(e[1] == 0, 1.0, e[1])
        inside ^= crosses & (p[:, 0] < xint)
    return (np.where(inside, best, -best) - R).reshape(pts.shape[:-1])


def _unit2(x):
    x = np.asarray(x, float)
    return x / np.linalg.norm(x)


def _left(t):
    return np.array([-t[1], t[0]])


def _angle(u):
    return float(np.arctan2(u[1], u[0]))


def _ccw_span(u0, u1):
    """The angle from direction u0 counter-clockwise to u1, in (0, 2π]."""
    d = (_angle(u1) - _angle(u0)) % (2 * np.pi)
    return d if d > 0 else 2 * np.pi


def _piece_frame(q):
    """Geometry of a boundary piece (rbx.tables Segment or Arc) -> dict: start, end, the unit tangents (direction
    of travel) and inward normals at both ends, and for an arc its centre, radius, turn and radial directions."""
    a, b = np.asarray(q.start, float), np.asarray(q.end, float)
    if not hasattr(q, "center"):
        t = _unit2(b - a)
        return dict(seg=True, a=a, b=b, t0=t, t1=t, n0=_left(t), n1=_left(t), length=float(np.linalg.norm(b - a)))
    c = np.asarray(q.center, float)
    rho = float(np.linalg.norm(a - c))
    u0, u1 = (a - c) / rho, (b - c) / np.linalg.norm(b - c)
    if q.turn == "ccw":      # focusing: the table inside the circle, inward normal −u, travel direction Ju
        return dict(seg=False, a=a, b=b, c=c, rho=rho, ccw=True, u0=u0, u1=u1, t0=_left(u0), t1=_left(u1),
                    n0=-u0, n1=-u1, span=_ccw_span(u0, u1))
    return dict(seg=False, a=a, b=b, c=c, rho=rho, ccw=False, u0=u0, u1=u1, t0=-_left(u0), t1=-_left(u1),
                n0=u0, n1=u1, span=_ccw_span(u1, u0))


def _arc_points(c, rho, a0, span, m):
    th = a0 + span * np.linspace(0.0, 1.0, m)
    return c + rho * np.stack([np.cos(th), np.sin(th)], axis=1)


def boundary_polyline(pieces, m=64):
    """The closed boundary as a polyline (arcs sampled with m points each, the last point of each piece left to
    the next) -> (k, 2) array."""
    out = []
    for q in pieces:
        f = _piece_frame(q)
        if f["seg"]:
            out.append(f["a"][None])
        elif f["ccw"]:
            out.append(_arc_points(f["c"], f["rho"], _angle(f["u0"]), f["span"], m)[:-1])
        else:
            out.append(_arc_points(f["c"], f["rho"], _angle(f["u0"]), -f["span"], m)[:-1])
    return np.concatenate(out)


def _meets(f, g, tol):
    """The points (within ``tol``) where two boundary pieces meet, at least one of them an arc (their frames,
    :func:`_piece_frame`) -> list of points: a line or circle against a circle, kept where the point lies on both
    pieces (a segment between its ends, an arc within its angular span)."""
    def on(h, p):
        if h["seg"]:
            t = h["b"] - h["a"]
            u = (p - h["a"]) @ t / (t @ t)
            return -tol / h["length"] <= u <= 1.0 + tol / h["length"]
        first = h["u0"] if h["ccw"] else h["u1"]
        ang = np.mod(_angle(p - h["c"]) - _angle(first), 2 * np.pi)
        slack = tol / h["rho"]
        return ang <= h["span"] + slack or ang >= 2 * np.pi - slack
    if f["seg"]:
        f, g = g, f
    c, rho = f["c"], f["rho"]
    if g["seg"]:
        t = (g["b"] - g["a"]) / g["length"]
        foot = g["a"] + ((c - g["a"]) @ t) * t
        d = float(np.linalg.norm(c - foot))
        if d > rho + tol:
            return []
        h = np.sqrt(max(rho * rho - d * d, 0.0))
        cands = [foot - h * t, foot + h * t]
    else:
        c2, rho2 = g["c"], g["rho"]
        D = float(np.linalg.norm(c2 - c))
        if D == 0.0 or D > rho + rho2 + tol or D < abs(rho - rho2) - tol:
            return []
        e = (c2 - c) / D
        x = (D * D + rho * rho - rho2 * rho2) / (2 * D)
        h = np.sqrt(max(rho * rho - x * x, 0.0))
        cands = [c + x * e + h * _left(e), c + x * e - h * _left(e)]
    return [p for p in cands if on(f, p) and on(g, p)]


def arcs_cross(pieces, tol):
    """Whether a closed boundary of segments and arcs crosses or touches itself at a point of an arc (segments
    among themselves: rbx.tables' polygon test): two pieces meeting anywhere but at a joint they share. Exact (a
    line or circle against a circle): a polyline of 64 points per arc let an arc dipping 1e-4 below the floor
    through."""
    frames = [_piece_frame(q) for q in pieces]
    m = len(frames)
    for i in range(m):
        for j in range(i + 1, m):
            f, g = frames[i], frames[j]
            if f["seg"] and g["seg"]:
                continue
            joints = []
            if j == i + 1:
                joints.append(f["b"])
            if i == 0 and j == m - 1:
                joints.append(f["a"])
            for p in _meets(f, g, tol):
                if all(np.linalg.norm(p - J) > 1e3 * tol for J in joints):
                    return True
    return False


def boundary_area(pieces):
    """Signed area enclosed by a closed boundary of segments and arcs (positive: counter-clockwise), exact for
    arcs: ½∮(x dy − y dx), with x measured from the first piece's start (from the origin, the products of a table
    at 1e8 cancelled to nothing and a unit square came out clockwise)."""
    area = 0.0
    o = np.asarray(_piece_frame(pieces[0])["a"], float)
    for q in pieces:
        f = _piece_frame(q)
        if f["seg"]:
            a, b = f["a"] - o, f["b"] - o
            area += 0.5 * (a[0] * b[1] - b[0] * a[1])
        else:
            c, rho = f["c"] - o, f["rho"]
            th0 = _angle(f["u0"])
            dth = f["span"] if f["ccw"] else -f["span"]
            th1 = th0 + dth
            # x = cx + ρ cos θ, y = cy + ρ sin θ: ½∫(x y' − y x') dθ
            area += 0.5 * (c[0] * rho * (np.sin(th1) - np.sin(th0)) + c[1] * rho * (np.cos(th0) - np.cos(th1))
                           + rho * rho * dth)
    return float(area)


def _boundary_distance(pts, frames):
    """(unsigned distance to the boundary, winding number about each point) for points (k, 2)."""
    dist = np.full(len(pts), np.inf)
    wind = np.zeros(len(pts))
    for f in frames:
        if f["seg"]:
            a, e = f["a"], f["b"] - f["a"]
            s = np.clip(((pts - a) @ e) / (e @ e), 0.0, 1.0)
            dist = np.minimum(dist, np.linalg.norm(pts - (a + s[:, None] * e), axis=1))
            wind += _subtended(pts, f["a"], f["b"])
        else:
            c, rho = f["c"], f["rho"]
            rel = pts - c
            r = np.linalg.norm(rel, axis=1)
            lo_dir = f["u0"] if f["ccw"] else f["u1"]
            ang = (np.arctan2(rel[:, 1], rel[:, 0]) - _angle(lo_dir)) % (2 * np.pi)
            on = ang <= f["span"]
            d_ends = np.minimum(np.linalg.norm(pts - f["a"], axis=1), np.linalg.norm(pts - f["b"], axis=1))
            dist = np.minimum(dist, np.where(on, np.abs(r - rho), d_ends))
            # the change of arg(q − p) along the arc: inside the circle it turns with the arc (monotone), outside
            # it stays within a cone narrower than π, so the principal difference is exact
            inside = r < rho
            principal = _subtended(pts, f["a"], f["b"])
            g0 = np.arctan2(f["a"][1] - pts[:, 1], f["a"][0] - pts[:, 0])
            g1 = np.arctan2(f["b"][1] - pts[:, 1], f["b"][0] - pts[:, 0])
            turning = (g1 - g0) % (2 * np.pi) if f["ccw"] else -((g0 - g1) % (2 * np.pi))
            wind += np.where(inside, turning, principal)
    return dist, wind / (2 * np.pi)


def _subtended(pts, a, b):
    """The signed angle from a − p to b − p, in (−π, π]."""
    g0 = np.arctan2(a[1] - pts[:, 1], a[0] - pts[:, 0])
    g1 = np.arctan2(b[1] - pts[:, 1], b[0] - pts[:, 0])
    return (g1 - g0 + np.pi) % (2 * np.pi) - np.pi


def pieces_clearance(geom, pts):
    """Signed distance of centre positions (…, n) inside the shrunk table built from pieces (≥ 0 inside): the
    distance to the nearest wall minus R, negative outside the table or inside an obstacle grown by R; periodic
    tables take positions unfolded -> (…) array."""
    n, R = geom.dimension, geom.shrunk_radius
    shape = pts.shape[:-1]
    p = pts.reshape(-1, n)
    out = np.full(len(p), np.inf)
    images = [np.zeros(n)]
    if geom.lattice is not None:
        lo, period = geom.lattice
        p = lo + np.mod(p - lo, period)
        images = [np.array(o, float) * period for o in np.ndindex(*(3,) * n)]
        images = [im - period for im in images]
    for piece in geom.pieces:
        if isinstance(piece, Boundary):
            dist, wind = _boundary_distance(p, [_piece_frame(q) for q in piece.pieces])
            d = np.where(np.abs(wind) > 0.5, dist, -dist) - R
        elif isinstance(piece, Polygon):
            d = _polygon_clearance(p, np.asarray(piece.vertices, float), R)
        elif isinstance(piece, (Plane, Line)):
            d = (p - np.asarray(piece.point, float)) @ np.asarray(unit(piece.normal), float) - R
        elif isinstance(piece, Circle):
            d = piece.radius - R - np.linalg.norm(p - np.asarray(piece.center, float), axis=1)
        elif isinstance(piece, Sphere):
            c = np.asarray(piece.center, float)
            if piece.inside:
                d = piece.radius - R - np.linalg.norm(p - c, axis=1)
            else:
                d = np.min([np.linalg.norm(p - c - im, axis=1) for im in images], axis=0) - piece.radius - R
        elif isinstance(piece, Cylinder):
            d = piece.radius - R - np.linalg.norm(p[:, :2] - np.asarray(piece.center, float), axis=1)
        else:
            continue
        out = np.minimum(out, d)
    return out.reshape(shape)


def _caps_z(pieces):
    """The z range between the horizontal Plane caps of a cylinder -> (z0, z1)."""
    zs = sorted(float(q.point[2]) for q in pieces if type(q).__name__ == "Plane" and abs(q.normal[2]) == 1.0)
    return (zs[0], zs[-1]) if len(zs) >= 2 else (-np.inf, np.inf)
