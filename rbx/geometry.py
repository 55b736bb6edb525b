"""Tables as data: the boundary of the *shrunk* table (seen by the centre) as a list of primitives.

One general mechanism for every scene (STYLE: tables are data, not classes). A primitive is an integer code,
the index of the wall it belongs to and a row of packed float parameters:

| code | primitive | parameters (row of ``params``) |
|---|---|---|
| ``HALFSPACE`` | line (2D) / plane (3D), no ends: the table is the intersection of such half-spaces | point p = [0:n], inward normal ν = [4:4+n] |
| ``SEGMENT`` | 2D line segment with ends (non-convex polygons) | start p = [0:2], ν = [4:6], tangent t = [8:10], length = [12] |
| ``CONCAVE_ARC`` | circle of radius ρ, centre kept inside (circle table) | centre c = [0:n], ρ = [12] |
| ``CONVEX_ARC`` | 2D arc of radius ρ around a reflex vertex, centre kept outside | c = [0:2], first normal = [4:6], last normal = [8:10] (CCW), ρ = [12] |

Adding a table kind = a builder here that lists its primitives (with ``Wall`` entries for names, tangent axes and
sampling patches), registered with its other facets in :mod:`rbx.tables`. Adding a primitive kind = a code, its
branch in :func:`collision_time`, :func:`contact_normal` and :func:`snap`, and its :func:`clearance`.
"""
from dataclasses import dataclass, field

import numpy as np

from ._jit import jit, jit_hot

HALFSPACE, SEGMENT, CONCAVE_ARC, CONVEX_ARC = 0, 1, 2, 3
NPARAM = 16
#: relative tolerance (of the table's size) on segment and arc ends, so that a flight through a joint between two
#: primitives hits at least one of them
END_TOLERANCE = 1e-12


@dataclass
class Wall:
    """A named wall: its tangent axes (3D planes: for ``direction_deg``) and its sampling patches."""
    name: str
    tangents: np.ndarray | None = None
    patches: list = field(default_factory=list)  # ('flat', origin, normal, [(axis, length or inf), ...]) | ('arc', ...)


@dataclass
class Geometry:
    """The shrunk table of one scene, ready for the kernels (arrays) and for Python (names, drawing, checks)."""
    kind: str
    dimension: int
    codes: np.ndarray          # (m,) int64 primitive codes
    walls: np.ndarray          # (m,) int64 wall index of each primitive
    params: np.ndarray         # (m, NPARAM) float64
    wall_list: list            # [Wall], in SPEC §2 order
    size: float                # a length scale of the table (for tolerances)
    outline: np.ndarray | None = None          # 2D: the table's boundary polygon (for drawing), or None
    shrunk_outline: np.ndarray | None = None   # 2D: the shrunk table's boundary (for drawing), or None
    circle: tuple | None = None                # (radius, shrunk radius) for the circle table
    table: dict | None = None                  # the kind's parameters (set by rbx.tables.build)
    #: two parallel walls, primitives 0 (x_{n−1} = lo) and 1 (x_{n−1} = hi): the engine takes
    #: :func:`slab_collision`'s closed form (strip, plates)
    slab: bool = False
    #: the billiard measure on the walls can be normalised (the patches are finite, or infinite only along a
    #: symmetry of the table, as in a strip); not for a wedge
    can_sample: bool = True

    @property
    def wall_names(self):
        return [w.name for w in self.wall_list]

    def clearance(self, points):
        """Signed distance of centre positions (…, n) inside the shrunk table (≥ 0 inside) -> (…) array."""
        pts = np.asarray(points, dtype=float)
        out = np.full(pts.shape[:-1], np.inf)
        if np.any((self.codes == SEGMENT) | (self.codes == CONVEX_ARC)):   # a non-convex polygon
            return _polygon_clearance(pts, self.outline, self.shrunk_radius)
        for code, row in zip(self.codes, self.params):
            n = self.dimension
            if code == HALFSPACE:
                d = (pts - row[:n]) @ row[4:4 + n]
            elif code == CONCAVE_ARC:
                d = row[12] - np.linalg.norm(pts - row[:n], axis=-1)
            else:  # pragma: no cover - only polygons have these, handled above
                raise ValueError(code)
            out = np.minimum(out, d)
        return out

    shrunk_radius: float = 0.0


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


def _row(n, p=(), nu=(), t=(), scalar=0.0):
    r = np.zeros(NPARAM)
    r[:len(p)] = p
    r[4:4 + len(nu)] = nu
    r[8:8 + len(t)] = t
    r[12] = scalar
    return r


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
    if not reflex.any():
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
        codes.append(SEGMENT)
        wall_idx.append(i)
        rows.append(_row(2, starts[i], N[i], T[i], lengths[i]))
        shrunk.extend([starts[i], ends[i]])
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


@jit_hot
def collision_time(code, params, k, a, v, tol, n):
    """Flight time until the centre at ``a`` moving with ``v`` hits the primitive while moving into it -> t ≥ 0,
    or inf if it never does. A centre a hair outside (rounding) and moving in is hit at t = 0.
    The primitive is row ``k`` of ``params`` (indices, not a row view: views cost reference counting); ``n`` is
    the dimension, passed in so that the kernels compile it as a constant."""
    if code == HALFSPACE or code == SEGMENT:
        vn = 0.0
        d = 0.0
        for i in range(n):
            vn += v[i] * params[k, 4 + i]
            d += (a[i] - params[k, i]) * params[k, 4 + i]
        if vn >= 0.0:
            return np.inf                      # parallel or leaving: a grazing flight never touches the wall
        if code == HALFSPACE:
            return max(d, 0.0) / -vn
        if d < -tol:
            return np.inf                      # the segment's line lies behind: another part of the table
        t = max(d, 0.0) / -vn
        s = 0.0
        for i in range(2):
            s += (a[i] + t * v[i] - params[k, i]) * params[k, 8 + i]
        if s < -tol or s > params[k, 12] + tol:
            return np.inf
        return t
    # arcs: |a + t v − c|² = ρ²  <=>  |v|² t² + 2 b t + cc = 0
    b = 0.0
    cc = 0.0
    vv = 0.0
    for i in range(n):
        dx = a[i] - params[k, i]
        b += dx * v[i]
        cc += dx * dx
        vv += v[i] * v[i]
    rho = params[k, 12]
    # |a−c|² − ρ² without cancelling ρ² away: a centre on the circle (snapped, or just hit) gives 0 or a few ulp
    # of ρ·|a−c|, where |a−c|² − ρ² would keep the rounding of the squares (a grazing flight needs the former)
    cc = (np.sqrt(cc) - rho) * (np.sqrt(cc) + rho)
    if code == CONCAVE_ARC:
        # The centre is inside the circle (a bounded table): one a hair outside by rounding is taken to be on it,
        # else a grazing flight moving inward from there could miss the circle altogether and "escape".
        if vv == 0.0:
            return np.inf
        if cc > 0.0:
            cc = 0.0
        disc = b * b - vv * cc
        if b > 0.0:
            t = -cc / (b + np.sqrt(disc))         # stable form of the larger root
        else:
            t = (np.sqrt(disc) - b) / vv
        return t                                 # ≥ 0; 0 for a centre on the circle moving out (or along it)
    # CONVEX_ARC: entering the disc around a reflex vertex, through the arc between its two normals
    if b >= 0.0:
        return np.inf
    disc = b * b - vv * cc
    if disc <= 0.0:
        return np.inf                            # the line misses the disc or is tangent: a grazing flight
    t = cc / (np.sqrt(disc) - b)                 # stable form of the smaller root
    if t < 0.0:
        if cc < -2.0 * tol * rho:
            return np.inf
        t = 0.0
    mx = a[0] + t * v[0] - params[k, 0]
    my = a[1] + t * v[1] - params[k, 1]
    if params[k, 4] * my - params[k, 5] * mx < -tol * rho or mx * params[k, 9] - my * params[k, 8] < -tol * rho:
        return np.inf
    return t


@jit_hot
def contact_normal(code, params, k, a, nu, n):
    """Unit normal at the contact point of the centre ``a`` on the primitive, pointing into the free region -> nu."""
    if code == HALFSPACE or code == SEGMENT:
        for i in range(n):
            nu[i] = params[k, 4 + i]
        return
    s = 0.0
    for i in range(n):
        nu[i] = a[i] - params[k, i]
        s += nu[i] * nu[i]
    s = 1.0 / np.sqrt(s)
    if code == CONCAVE_ARC:
        s = -s
    for i in range(n):
        nu[i] *= s


@jit_hot
def next_collision(codes, params, a, v, tol, n):
    """The first primitive the centre hits -> (flight time, primitive index), (inf, -1) if none lies ahead.
    Ties go to the lower index (primitives are listed in wall order)."""
    best = np.inf
    which = -1
    for k in range(codes.shape[0]):
        t = collision_time(codes[k], params, k, a, v, tol, n)
        if t < best:
            best = t
            which = k
    return best, which


@jit_hot
def slab_collision(params, a, v, n):
    """Closed form for a slab (strip, plates): primitives 0 and 1 are the planes x_{n−1} = lo (normal +e) and
    x_{n−1} = hi (normal −e); the sign of the normal speed says which is next -> (flight time, primitive).
    Same as :func:`next_collision` on these two half-spaces, without the loop over primitives."""
    vn = v[n - 1]
    if vn > 0.0:
        return max(params[1, n - 1] - a[n - 1], 0.0) / vn, 1
    if vn < 0.0:
        return max(a[n - 1] - params[0, n - 1], 0.0) / -vn, 0
    return np.inf, -1


@jit_hot
def snap(code, params, k, a, nu, n):
    """Put the centre exactly on primitive ``k`` at contact (ν: its normal there): removes the rounding of the
    flight along the normal. Half-space and segment: a −= ((a − p)·ν)ν; arcs: a = c + ρ(a − c)/|a − c|."""
    if code == HALFSPACE or code == SEGMENT:
        d = 0.0
        for i in range(n):
            d += (a[i] - params[k, i]) * params[k, 4 + i]
        for i in range(n):
            a[i] -= d * params[k, 4 + i]
        return
    s = 0.0
    for i in range(n):
        s += (a[i] - params[k, i]) * (a[i] - params[k, i])
    f = params[k, 12] / np.sqrt(s)
    for i in range(n):
        a[i] = params[k, i] + f * (a[i] - params[k, i])
