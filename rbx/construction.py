"""Building shrunk tables, the room beside the registry of table kinds (:mod:`rbx.tables`, which calls these):
the builders of the paper's kinds (strip, circle, wedge, rectangle, polygon, plates, box: validated parameters,
radius R -> :class:`rbx.primitives.Geometry`), a table from its wall pieces (:mod:`rbx.pieces`: the zoo's kinds,
:func:`from_pieces`), obstacles on any kind (:func:`add_pieces`), the sampling patches trimmed to where the
centre can reach, and the check that a ball fits a table made of pieces (:func:`check_fit`). The primitives
they list are those of :mod:`rbx.primitives`.
"""
import functools

import numpy as np

from .pieces import (OBSTACLES, Boundary, Circle, Cylinder, Lattice, Line, Plane, Polygon, Sphere, _angle,
                     _arc_points, _caps_z, _ccw_span, _piece_frame, _polygon_clearance, arcs_cross, boundary_area, boundary_polyline,
                     pieces_clearance, unit)
from .primitives import (CONCAVE_ARC, CONVEX_ARC, CYLINDER, FOCUS_ARC, HALFSPACE, NPARAM, P_WIDE, SEGMENT,
                         SPHERE_OUT, Geometry, Wall, _row)


def _halfspaces(kind, n, R, planes, walls, size, outline=None):
    """A table that is an intersection of half-spaces {x: (x − p)·ν ≥ 0}, shrunk by R: p → p + Rν."""
    params = np.array([_row(n, np.asarray(p, float) + R * np.asarray(nu, float), nu) for p, nu in planes])
    m = len(planes)
    return Geometry(kind, n, np.full(m, HALFSPACE, np.int64), np.arange(m, dtype=np.int64), params, walls, size,
                    outline=outline, shrunk_radius=R)


def _flat_wall(name, origin, normal, axes, tangents=None):
    return Wall(name, None if tangents is None else np.asarray(tangents, float),
                [("flat", np.asarray(origin, float), np.asarray(normal, float), axes)])


# ---- builders of the table kinds (registered in rbx.tables): validated parameters, radius R -> Geometry -----------

def strip(p, R):
    w = p["width"]
    walls = [_flat_wall("bottom", (0, R), (0, 1), [((1, 0), np.inf)]),
             _flat_wall("top", (0, w - R), (0, -1), [((1, 0), np.inf)])]
    g = _halfspaces("strip", 2, R, [((0, 0), (0, 1)), ((0, w), (0, -1))], walls, w)
    g.slab = True
    return g


def circle(p, R):
    r = p["radius"]
    rho = r - R
    params = np.array([_row(2, (0, 0), (), (), rho)])
    walls = [Wall("rim", None, [("arc", np.zeros(2), rho, 0.0, 2 * np.pi, -1.0)])]
    t = np.linspace(0, 2 * np.pi, 361)
    circle = np.stack([np.cos(t), np.sin(t)], axis=1)
    return Geometry("circle", 2, np.array([CONCAVE_ARC]), np.array([0]), params, walls, 2 * r,
                    outline=r * circle, shrunk_outline=rho * circle, circle=(r, rho), shrunk_radius=R)


def wedge(p, R):
    phi = np.radians(p["angle_deg"])
    d1 = np.array([np.cos(phi), np.sin(phi)])
    nu0, nu1 = np.array([0.0, 1.0]), np.array([np.sin(phi), -np.cos(phi)])
    apex = R / np.sin(phi / 2) * np.array([np.cos(phi / 2), np.sin(phi / 2)])
    walls = [_flat_wall("wall0", apex, nu0, [((1, 0), np.inf)]), _flat_wall("wall1", apex, nu1, [(d1, np.inf)])]
    far = 10.0
    g = _halfspaces("wedge", 2, R, [((0, 0), nu0), ((0, 0), nu1)], walls, 1.0,
                    outline=np.array([far * np.array([1.0, 0.0]), [0.0, 0.0], far * d1]))
    g.shrunk_outline = np.array([apex + far * np.array([1.0, 0.0]), apex, apex + far * d1])
    g.can_sample = False
    return g


def rectangle(p, R):
    w, h = p["width"], p["height"]
    return polygon({"vertices": [[0, 0], [w, 0], [w, h], [0, h]]}, R, kind="rectangle",
                    names=["bottom", "right", "top", "left"])


def polygon(p, R, kind="polygon", names=None):
    V = np.asarray(p["vertices"], dtype=float)
    m = len(V)
    names = names or [f"edge{i}" for i in range(m)]
    E = np.roll(V, -1, axis=0) - V                       # edge i: V[i] -> V[i+1]
    L = np.linalg.norm(E, axis=1)
    T = E / L[:, None]
    N = np.stack([-T[:, 1], T[:, 0]], axis=1)            # inward normal of a CCW polygon
    Ep = np.roll(E, 1, axis=0)
    turn = Ep[:, 0] * E[:, 1] - Ep[:, 1] * E[:, 0]            # vertex i: from edge i-1 to edge i; > 0 convex
    size = float(np.max(np.ptp(V, axis=0)))
    reflex = turn < -1e-14 * size * size
    # edges on one line (a side cut into several walls): each is its own segment, never the half-space of the
    # line, which would cover its neighbours (a flight meets the line once, and the lowest wall index took the hit)
    shared_line = np.array([any(i != j and N[i] @ N[j] > 1 - 1e-12 and abs((V[j] - V[i]) @ N[i]) <= 1e-14 * size
                                for j in range(m)) for i in range(m)])

    def offset_meet(i, j):  # intersection of the offset lines of edges i and j
        A = np.array([N[i], N[j]])
        b = np.array([V[i] @ N[i] + R, V[j] @ N[j] + R])
        if abs(np.linalg.det(A)) < 1e-14:
            return V[j] + R * N[j]
        return np.linalg.solve(A, b)

    starts, ends = [], []
    for i in range(m):
        j = (i + 1) % m
        starts.append(V[i] + R * N[i] if reflex[i] else offset_meet(i - 1, i))
        ends.append(V[j] + R * N[i] if reflex[j] else offset_meet(i, j))
    lengths = np.array([(e - s) @ T[i] for i, (s, e) in enumerate(zip(starts, ends))])
    walls = [_flat_wall(names[i], starts[i], N[i], [(T[i], max(lengths[i], 0.0))]) for i in range(m)]
    if not reflex.any() and not shared_line.any():
        g = _halfspaces(kind, 2, R, [(V[i], N[i]) for i in range(m)], walls, size, outline=V)
        g.shrunk_outline = np.array(starts)
        g.lengths = lengths
        return g
    codes, wall_idx, rows, shrunk = [], [], [], []
    for i in range(m):
        if reflex[i]:  # arc around vertex i, from normal N[i] counter-clockwise to N[i-1]; belongs to edge i
            codes.append(CONVEX_ARC)
            wall_idx.append(i)
            rows.append(_row(2, V[i], N[i], N[i - 1], R))
            a0, a1 = np.arctan2(N[i][1], N[i][0]), np.arctan2(N[i - 1][1], N[i - 1][0])
            a1 = a1 if a1 >= a0 else a1 + 2 * np.pi
            walls[i].patches.append(("arc", V[i], R, a0, a1, 1.0))
            shrunk.extend(V[i] + R * np.stack([np.cos(t), np.sin(t)]) for t in np.linspace(a1, a0, 8))
        # an edge whose line has the whole polygon on its inner side (the L's four outer sides) is a half-space:
        # its line's crossing can never come before the flight leaves the table, so the smallest time is the same
        # without the segment's ends, and four axis-aligned ones make an axis box (Geometry.axis_box: closed form)
        supporting = bool(np.all((V - V[i]) @ N[i] >= -1e-14 * size)) and not shared_line[i]
        codes.append(HALFSPACE if supporting else SEGMENT)
        wall_idx.append(i)
        rows.append(_row(2, starts[i], N[i], T[i], lengths[i]))
        shrunk.extend([starts[i], ends[i]])
    # a polygon with a reflex vertex may narrow below 2R (a neck): the parts of its walls that the centre cannot
    # reach (behind another wall's offset) are no part of the wall's measure, and no start is drawn there
    clearance = functools.partial(_polygon_clearance, verts=V, R=R)
    for wall in walls:
        wall.patches = [q for patch in wall.patches for q in _trim_patch(patch, size, clearance)]
    g = Geometry(kind, 2, np.array(codes, np.int64), np.array(wall_idx, np.int64), np.array(rows), walls, size,
                 outline=V, shrunk_outline=np.array(shrunk), shrunk_radius=R)
    g.lengths = lengths
    return g


def plates(p, R):
    gap = p["gap"]
    axes = [((1, 0, 0), np.inf), ((0, 1, 0), np.inf)]
    tang = [(1, 0, 0), (0, 1, 0)]
    walls = [_flat_wall("bottom", (0, 0, R), (0, 0, 1), axes, tang),
             _flat_wall("top", (0, 0, gap - R), (0, 0, -1), axes, tang)]
    g = _halfspaces("plates", 3, R, [((0, 0, 0), (0, 0, 1)), ((0, 0, gap), (0, 0, -1))], walls, gap)
    g.slab = True
    return g


def box(p, R):
    lx, ly, lz = p["size"]
    ex, ey, ez = np.eye(3)
    spec = [("left", ex, 0, (ey, ez)), ("right", -ex, lx, (ey, ez)), ("front", ey, 0, (ex, ez)),
            ("back", -ey, ly, (ex, ez)), ("bottom", ez, 0, (ex, ey)), ("top", -ez, lz, (ex, ey))]
    L = np.array([lx, ly, lz])
    planes, walls = [], []
    for name, nu, offset, (t1, t2) in spec:
        axis = int(np.argmax(np.abs(nu)))
        point = np.zeros(3)
        point[axis] = offset
        planes.append((point, nu))
        origin = point + R * nu + R * (t1 + t2)
        walls.append(_flat_wall(name, origin, nu, [(t1, L @ t1 - 2 * R), (t2, L @ t2 - 2 * R)], (t1, t2)))
    return _halfspaces("box", 3, R, planes, walls, float(max(L)))


def _trim(point_at, lo, hi, size, clearance):
    """The sub-ranges of [lo, hi] where the offset piece point_at(s) lies in the shrunk table -> list of (s0, s1),
    in order, empty if none. Its ends may poke out past a convex joint, behind the neighbouring piece, and its
    middle where the table narrows below 2R (a neck, a dent): the ball's centre never gets there, so no start is
    drawn there and the wall's measure leaves it out. The tolerance is a fraction of the table's size plus the
    rounding of the points' coordinates (a table at 1e8 otherwise had no room along any wall). ``clearance``:
    the table's signed clearance of points (:func:`pieces_clearance`, a polygon's :func:`_polygon_clearance`)."""
    s = np.linspace(lo, hi, 2049)
    pts = np.array([point_at(x) for x in s])
    slack = 64 * np.finfo(float).eps * float(np.max(np.abs(pts)))
    ok = clearance(pts) >= -(1e-9 * size + slack)

    def edge(good, bad):
        for _ in range(60):
            mid = 0.5 * (good + bad)
            if clearance(point_at(mid)[None])[0] >= -(1e-13 * size + slack):
                good = mid
            else:
                bad = mid
        return good
    out = []
    i = 0
    while i < len(ok):
        if not ok[i]:
            i += 1
            continue
        j = i
        while j + 1 < len(ok) and ok[j + 1]:
            j += 1
        s0 = s[i] if i == 0 else edge(s[i], s[i - 1])
        s1 = s[j] if j == len(s) - 1 else edge(s[j], s[j + 1])
        if s1 > s0:
            out.append((s0, s1))
        i = j + 1
    return out


def _trim_patch(patch, size, clearance):
    """A wall's sampling patch (a flat one along one axis, or an arc) cut to the parts the centre can reach
    (:func:`_trim`) -> list of patches of the same kind, empty if none."""
    if patch[0] == "flat":
        _, origin, normal, [(axis, length)] = patch
        return [("flat", origin + s0 * axis, normal, [(axis, s1 - s0)])
                for s0, s1 in _trim(lambda s: origin + s * axis, 0.0, length, size, clearance)]
    _, c, rho, a0, a1, sign = patch
    return [("arc", c, rho, t0, t1, sign)
            for t0, t1 in _trim(lambda t: c + rho * np.array([np.cos(t), np.sin(t)]), a0, a1, size, clearance)]


def _boundary(geom, piece, R, first_wall, codes, walls, rows, wall_list):
    """The primitives of a closed boundary of segments and arcs (and of its rounded reflex joints)."""
    frames = [_piece_frame(q) for q in piece.pieces]
    m = len(frames)
    size = geom.size
    clearance = functools.partial(pieces_clearance, geom)
    shrunk = []
    for i, (q, f) in enumerate(zip(piece.pieces, frames)):
        w = first_wall + i
        wall = Wall(q.name)
        prev = frames[i - 1]
        turn = prev["t1"][0] * f["t0"][1] - prev["t1"][1] * f["t0"][0]
        if abs(turn) > 1e-9 or prev["t1"] @ f["t0"] <= 0.0:
            geom.corners += 1
        if turn < -1e-12:   # a reflex joint: an arc of radius R about it, from this piece's normal to the last's
            n_out, n_in = f["n0"], prev["n1"]
            span = _ccw_span(n_out, n_in)
            codes.append(CONVEX_ARC)
            walls.append(w)
            r = _row(2, f["a"], n_out, n_in, R)
            r[P_WIDE] = 1.0 if span > np.pi else 0.0
            rows.append(r)
            for q in _trim_patch(("arc", f["a"], R, _angle(n_out), _angle(n_out) + span, 1.0), size, clearance):
                wall.patches.append(q)
                shrunk.append(_arc_points(f["a"], R, q[4], q[3] - q[4], 12))
        if f["seg"]:
            codes.append(SEGMENT)
            walls.append(w)
            start = f["a"] + R * f["n0"]
            rows.append(_row(2, start, f["n0"], f["t0"], f["length"]))
            for q in _trim_patch(("flat", start, f["n0"], [(f["t0"], f["length"])]), size, clearance):
                wall.patches.append(q)
                shrunk.append(np.array([q[1], q[1] + q[3][0][1] * f["t0"]]))
        else:
            rho = f["rho"] - R if f["ccw"] else f["rho"] + R
            first, last = (f["u0"], f["u1"]) if f["ccw"] else (f["u1"], f["u0"])
            codes.append(FOCUS_ARC if f["ccw"] else CONVEX_ARC)
            walls.append(w)
            r = _row(2, f["c"], first, last, rho)
            r[P_WIDE] = 1.0 if f["span"] > np.pi else 0.0
            rows.append(r)
            a0 = _angle(first)
            for q in _trim_patch(("arc", f["c"], rho, a0, a0 + f["span"], -1.0 if f["ccw"] else 1.0), size,
                                 clearance):
                wall.patches.append(q)
                shrunk.append(_arc_points(f["c"], rho, q[3], q[4] - q[3], 64))
        wall_list.append(wall)
    return boundary_polyline(piece.pieces), shrunk


def from_pieces(kind, n, pieces, R, scale):
    """The shrunk table of a table made of wall pieces (:mod:`rbx.tables`: the zoo, docs/reference.md §8)
    -> Geometry."""
    g = Geometry(kind, n, np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, NPARAM)), [], float(scale),
                 shrunk_radius=R)
    g.pieces = []
    g.from_pieces = True
    return add_pieces(g, pieces, R)


def add_pieces(geom, pieces, R, own=()):
    """``geom`` with the primitives and walls of ``pieces`` added after its own (obstacles on any table; every
    piece of a table of the zoo) -> a new Geometry. ``own``: the wall pieces of a table of the paper's kinds
    (its registry record's walls, :func:`rbx.tables.walls`), for the clearance of points."""
    n = geom.dimension
    codes, walls, rows = list(geom.codes), list(geom.walls), [r for r in geom.params]
    wall_list = list(geom.wall_list)
    g = Geometry(geom.kind, n, geom.codes, geom.walls, geom.params, wall_list, geom.size, outline=geom.outline,
                 shrunk_outline=geom.shrunk_outline, circle=geom.circle, table=geom.table, slab=False,
                 can_sample=geom.can_sample, shrunk_radius=R, lattice=geom.lattice, from_pieces=geom.from_pieces,
                 corners=geom.corners)
    if geom.pieces is None:     # a table of the paper's kinds: its own walls are pieces too, for clearance
        g.pieces = [q for q in own if not isinstance(q, Sphere)] if geom.table is not None else []
        g._own_clearance = geom
    else:
        g.pieces = list(geom.pieces)
    if hasattr(geom, "lengths"):
        g.lengths = geom.lengths
    g.curves = list(getattr(geom, "curves", []))
    z0, z1 = _caps_z(pieces)
    for q in pieces:
        w = len(wall_list)
        if isinstance(q, Lattice):
            g.lattice = (np.asarray(q.lo, float), np.asarray(q.hi, float) - np.asarray(q.lo, float))
            g.pieces.append(q)
            continue
        g.pieces.append(q)
        if isinstance(q, Boundary):
            outline, shrunk = _boundary(g, q, R, w, codes, walls, rows, wall_list)
            g.outline = outline
            g.curves.append(("table", np.vstack([outline, outline[:1]])))
            g.curves += [("shrunk", c) for c in shrunk]
        elif isinstance(q, Polygon):
            sub = polygon({"vertices": [list(v) for v in q.vertices]}, R, names=list(q.names))
            codes += list(sub.codes)
            walls += [w + int(k) for k in sub.walls]
            rows += list(sub.params)
            wall_list += sub.wall_list
            g.outline = sub.outline
            g.curves.append(("table", np.vstack([sub.outline, sub.outline[:1]])))
            g.curves.append(("shrunk", np.vstack([sub.shrunk_outline, sub.shrunk_outline[:1]])))
        elif isinstance(q, Plane):
            nu = np.asarray(q.normal, float)
            codes.append(HALFSPACE)
            walls.append(w)
            rows.append(_row(n, np.asarray(q.point, float) + R * nu, nu))
            tang = [np.asarray(t, float) for t in q.tangents]
            lo, hi = np.asarray(q.lo, float), np.asarray(q.hi, float)

            def along(x, t):         # x·t over t's non-zero components (x may be ±inf across the wall)
                return float(sum(x[i] * t[i] for i in range(n) if t[i] != 0.0))
            if np.all(np.isfinite([along(lo, t) for t in tang] + [along(hi, t) for t in tang])):
                origin = np.asarray(q.point, float) + R * nu
                axes = []
                for t in tang:
                    origin = origin + ((along(lo, t) + R) - origin @ t) * t
                    axes.append((t, along(hi, t) - along(lo, t) - 2 * R))
                wall_list.append(Wall(q.name, np.asarray(q.tangents, float), [("flat", origin, nu, axes)]))
            else:       # a cylinder's cap: a disc
                cyl = [c for c in pieces if isinstance(c, Cylinder)]
                patches = []
                if cyl:
                    centre = np.array([cyl[0].center[0], cyl[0].center[1], float(q.point[2]) + R * nu[2]])
                    patches = [("disc", centre, nu, cyl[0].radius - R)]
                wall_list.append(Wall(q.name, np.asarray(q.tangents, float), patches))
        elif isinstance(q, Sphere):
            c = np.asarray(q.center, float)
            rho = q.radius - R if q.inside else q.radius + R
            codes.append(CONCAVE_ARC if q.inside else SPHERE_OUT)
            walls.append(w)
            rows.append(_row(n, c, (), (), rho))
            sign = -1.0 if q.inside else 1.0
            patch = ("arc", c, rho, 0.0, 2 * np.pi, sign) if n == 2 else ("sphere", c, rho, sign)
            wall_list.append(Wall(q.name, None, [patch]))
            if n == 2:
                g.curves.append(("table", _arc_points(c, q.radius, 0.0, 2 * np.pi, 181)))
                g.curves.append(("shrunk", _arc_points(c, rho, 0.0, 2 * np.pi, 181)))
        elif isinstance(q, Cylinder):
            c = np.asarray(q.center, float)
            codes.append(CYLINDER)
            walls.append(w)
            rows.append(_row(n, c, (), (), q.radius - R))
            wall_list.append(Wall(q.name, None, [("cylinder", c, q.radius - R, z0 + R, z1 - R)]))
        elif isinstance(q, (Line, Circle)):
            raise ValueError(f"a {type(q).__name__} piece is only made by its own table kind")
        else:  # pragma: no cover
            raise TypeError(q)
    g.codes = np.array(codes, np.int64)
    g.walls = np.array(walls, np.int64)
    g.params = np.array(rows, float).reshape(-1, NPARAM)
    return g


def check_fit(geom, R):
    """None, or why the table built from pieces cannot hold a ball of radius R: a focusing arc, sphere or cylinder
    no larger than R, a wall with no room left once shrunk, obstacles overlapping each other or the boundary once
    grown by R; in a periodic table, an obstacle centred outside the cell or reaching its own image, obstacles
    overlapping each other's images, a table without obstacles -> str or None. Obstacles may cross the cell's
    sides (the images then reach into the neighbouring cells: :func:`periodic_images`)."""
    size = geom.size
    obstacles = [q for q in geom.pieces if isinstance(q, Sphere) and not q.inside]
    users = len(geom.table.get(OBSTACLES) or ()) if geom.table else 0     # the user's obstacles come last

    def key_of(q):
        """The config key that made obstacle q: ``obstacles[j]``, or a preset's scatterer (Sinai, Lorentz):
        its ``radius``."""
        j = obstacles.index(q) - (len(obstacles) - users)
        return f"obstacles[{j}]" if j >= 0 else "radius"
    for q in geom.pieces:
        if isinstance(q, Boundary):
            for p in q.pieces:
                f = _piece_frame(p)
                if not f["seg"] and f["ccw"] and f["rho"] <= R:
                    return f"does not fit in the arc '{p.name}' (radius {f['rho']:g} ≤ the ball's radius {R:g})"
        if isinstance(q, (Sphere, Cylinder)) and getattr(q, "inside", True) and q.radius <= R:
            return f"does not fit in '{q.name}' (radius {q.radius:g} ≤ the ball's radius {R:g})"
    z0, z1 = _caps_z(geom.pieces)
    if np.isfinite(z1 - z0) and z1 - z0 <= 2 * R:
        return f"does not fit between the caps {z1 - z0:g} apart"
    # a wall with no room for the centre along it (shorter than the ball, or behind a part narrower than 2R) is
    # one the ball never touches: that is no reason to refuse the table (a mushroom's cap floor of 0.05 beside a
    # wide stem was), only to refuse drawing starts on it (rbx.config). A table with no room along any wall has
    # none for the ball
    bounded = geom.wall_list[:len(geom.wall_list) - len(obstacles)]
    if bounded and not any(isinstance(q, Cylinder) for q in geom.pieces) and not any(
            any(p[0] != "flat" or all(length > 0 for _, length in p[3]) for p in w.patches) for w in bounded):
        return "does not fit in the table (no room along any wall)"
    shifts = [np.zeros(geom.dimension)]
    if geom.lattice is not None:
        lo, period = geom.lattice
        if not obstacles:
            return ("periodic", "a periodic table needs obstacles (nothing else is ever hit)")
        for q in obstacles:
            c = np.asarray(q.center, float)
            if np.any(c < lo) or np.any(c >= lo + period):
                return (key_of(q), f"'{q.name}' has its centre outside the periodic cell "
                        f"[{', '.join(f'{x:g}' for x in lo)}] – [{', '.join(f'{x:g}' for x in lo + period)}] (put "
                        "it in the cell: the lattice repeats it)")
        shifts = [(np.array(s, float) - 1.0) * period for s in np.ndindex(*(3,) * geom.dimension)]
    # every pair of obstacles, and in a periodic table every obstacle and the images of all of them (its own too:
    # then each is less than half a cell across once grown, so only the neighbouring cells' images reach a cell)
    for i, a in enumerate(obstacles):
        for b in obstacles[i:]:
            for s in shifts:
                if b is a and not np.any(s):
                    continue
                gap = float(np.linalg.norm(np.asarray(a.center, float) - np.asarray(b.center, float) - s)
                            - a.radius - b.radius)
                other = (f"'{b.name}'" if not np.any(s) else "its own periodic image" if b is a else
                         f"'{b.name}''s periodic image")
                if gap <= 0:
                    return (key_of(b) if key_of(b) != "radius" else key_of(a), f"'{a.name}' overlaps {other}")
                if gap < 2 * R * (1 - 1e-12):
                    return f"does not fit between obstacle '{a.name}' and {other} ({gap:g} apart)"
    others = [q for q in geom.pieces if q not in obstacles and not isinstance(q, Lattice)]
    if obstacles and others:
        probe = Geometry(geom.kind, geom.dimension, geom.codes, geom.walls, geom.params, geom.wall_list, size,
                         shrunk_radius=R, pieces=others)
        own = getattr(geom, "_own_clearance", None)
        for q in obstacles:
            c = np.asarray(q.center, float)
            dist = float((own or probe).clearance(c[None])[0]) + R      # to the walls themselves
            if not dist > q.radius:
                return (key_of(q), f"'{q.name}' overlaps the table's walls"
                        if dist > 0 else f"'{q.name}' is not inside the table")
            if dist - q.radius < 2 * R * (1 - 1e-12):
                return f"does not fit between obstacle '{q.name}' and the walls ({dist - q.radius:g} apart)"
    return None
