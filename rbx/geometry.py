"""Tables as data: the boundary of the *shrunk* table (seen by the centre) as a list of primitives.

One general mechanism for every scene: tables are data, not classes. A primitive is an integer code,
the index of the wall it belongs to and a row of packed float parameters:

| code | primitive | parameters (row of ``params``) |
|---|---|---|
| ``HALFSPACE`` | line (2D) / plane (3D), no ends: the table is the intersection of such half-spaces | point p = [0:n], inward normal ν = [4:4+n] |
| ``SEGMENT`` | 2D line segment with ends (non-convex polygons) | start p = [0:2], ν = [4:6], tangent t = [8:10], length = [12] |
| ``CONCAVE_ARC`` | circle of radius ρ, centre kept inside (circle table) | centre c = [0:n], ρ = [12] |
| ``CONVEX_ARC`` | 2D arc of radius ρ, centre kept outside (a reflex vertex rounded by R, a dispersing ``cw`` arc grown by R) | c = [0:2], first normal = [4:6], last normal = [8:10] (CCW), ρ = [12], 1 if it spans more than 180° = [13] |
| ``SPHERE_OUT`` | whole circle (2D disc obstacle) or sphere (3D), centre kept outside | c = [0:n], ρ = [12] |
| ``FOCUS_ARC`` | 2D arc of radius ρ, centre kept inside (a focusing ``ccw`` arc shrunk by R) | c = [0:2], first and last radial directions [4:6], [8:10] (CCW), ρ = [12], span > 180° = [13] |
| ``CYLINDER`` | 3D cylinder with axis ∥ z, centre kept inside | axis point c = [0:2], ρ = [12] |

A table of the zoo (docs/reference.md §8) is built from its wall pieces (:mod:`rbx.tables`) by :func:`from_pieces`;
obstacles are added to any table by :func:`add_pieces`. A periodic cell (``Lattice``) is the ``lattice`` (lo, period) of
the geometry: the kernel walks the cells a flight crosses and tests each cell's images (:func:`periodic_flight`).

Adding a table kind = a builder here that lists its primitives (with ``Wall`` entries for names, tangent axes and
sampling patches), registered with its other facets in :mod:`rbx.tables`. Adding a primitive kind = a code, its
branch in :func:`collision_time`, :func:`contact_normal` and :func:`snap`, and its :func:`clearance`.
"""
import functools
from dataclasses import dataclass, field

import numpy as np

from ._jit import jit, jit_hot

HALFSPACE, SEGMENT, CONCAVE_ARC, CONVEX_ARC, SPHERE_OUT, FOCUS_ARC, CYLINDER = 0, 1, 2, 3, 4, 5, 6
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
    wall_list: list            # [Wall], in wall order (docs/conventions.md)
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
    #: the wall pieces (rbx.tables) of a table built from pieces, or with obstacles: clearance and drawing read
    #: them; None for the paper's tables without obstacles
    pieces: list | None = None
    #: a periodic cell: (lo, period) arrays; None if the table is not periodic
    lattice: tuple | None = None
    #: built from its wall pieces alone (:func:`from_pieces`: the zoo), not by a kind's own builder
    from_pieces: bool = False
    #: joints of its boundary pieces where the direction of travel turns (a corner, convex or reflex), not tangent
    corners: int = 0

    @property
    def wall_names(self):
        return [w.name for w in self.wall_list]

    @property
    def axis_box(self):
        """The primitives that bound the table as an axis-aligned box -> (2n,) int64 array [lo wall of axis 0, hi
        wall of axis 0, lo of axis 1, …], or None: every axis has exactly one half-space of normal +e_i (its lo
        side) and one of normal −e_i (hi), normals exactly ±1 and 0 (rectangle, box, Sinai tables). The kernel
        then takes :func:`box_collision`'s closed form for them (one division per axis) and looks at the other
        primitives only; the same flight times and primitives as :func:`next_collision`, bit for bit. Not for a
        slab (its own closed form) or a periodic cell (the images)."""
        n = self.dimension
        if self.slab or self.lattice is not None:
            return None
        found = [[], []]
        box = np.full(2 * n, -1, dtype=np.int64)
        for k, (code, row) in enumerate(zip(self.codes, self.params)):
            nu = row[4:4 + n]
            if code != HALFSPACE or np.count_nonzero(nu) != 1 or np.abs(nu).max() != 1.0:
                continue
            i = int(np.flatnonzero(nu)[0])
            side = 0 if nu[i] > 0 else 1
            if box[2 * i + side] != -1:
                return None              # two parallel walls on one side: not a box (leave it to the loop)
            box[2 * i + side] = k
        return box if np.all(box >= 0) else None

    @property
    def convex_boundary(self):
        """Bounded by one closed curve of segments and focusing arcs alone, with no reflex joint and no obstacle (a
        stadium, a convex custom table): the free region is convex, so a flight from inside meets its boundary
        once, and each of these primitives reports only points of its own piece (a segment within its length, an
        arc within its angles). The first primitive that reports a hit is then the next collision, and the kernel
        stops looking there (:func:`box_collision`'s ``first``). Not for half-spaces or a cylinder (their answer
        is where an unbounded line or surface is crossed, which may lie beyond another wall: the smallest is taken)
        nor for a table with a reflex joint or a dispersing wall (they are ``CONVEX_ARC``, ``SPHERE_OUT``). Every
        joint tangent (:attr:`corners` 0): at a corner the shrunk pieces cross before their ends (a segment keeps
        its whole length), so a piece can report a hit beyond the other one; tangent pieces meet end to end."""
        return (self.dimension == 2 and self.lattice is None and not self.slab and len(self.codes) > 0
                and self.corners == 0 and all(c == SEGMENT or c == FOCUS_ARC for c in self.codes))

    def clearance(self, points):
        """Signed distance of centre positions (…, n) inside the shrunk table (≥ 0 inside) -> (…) array."""
        pts = np.asarray(points, dtype=float)
        if self.pieces is not None:
            return pieces_clearance(self, pts)
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
        # an edge whose line has the whole polygon on its inner side (the L's four outer sides) is a half-space:
        # its line's crossing can never come before the flight leaves the table, so the smallest time is the same
        # without the segment's ends, and four axis-aligned ones make an axis box (Geometry.axis_box: closed form)
        supporting = bool(np.all((V - V[i]) @ N[i] >= -1e-14 * size))
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
    # arcs: |a + t v − c|² = ρ²  <=>  |v|² t² + 2 b t + cc = 0 (a cylinder: in the plane across its axis)
    b = 0.0
    cc = 0.0
    vv = 0.0
    m = 2 if code == CYLINDER else n
    for i in range(n):          # i < m: a loop of constant length n, so that every index into a, v is a constant
        if i < m:               # (a run-time trip count would keep the kernel's state out of registers, in 3D)
            dx = a[i] - params[k, i]
            b += dx * v[i]
            cc += dx * dx
            vv += v[i] * v[i]
    rho = params[k, 12]
    if b >= 0.0 and (code == CONVEX_ARC or code == SPHERE_OUT):
        return np.inf                            # moving away from a disc kept outside: never reaches it
    # |a−c|² − ρ² without cancelling ρ² away: a centre on the circle (snapped, or just hit) gives 0 or a few ulp
    # of ρ·|a−c|, where |a−c|² − ρ² would keep the rounding of the squares (a grazing flight needs the former)
    cc = (np.sqrt(cc) - rho) * (np.sqrt(cc) + rho)
    if code == CONCAVE_ARC or code == CYLINDER:
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
    if code == FOCUS_ARC:
        # leaving the disc through the arc between its radial directions: the larger root. In a non-convex table
        # the centre may be outside this circle (a mushroom's stem): the larger root is then where the line
        # leaves the disc, if it meets it at all
        if vv == 0.0:
            return np.inf
        if 0.0 < cc <= 4.0 * tol * rho:
            cc = 0.0                             # a hair outside by rounding (just hit, creeping along it): on it
        disc = b * b - vv * cc
        if disc < 0.0:
            # from outside the circle: a line that misses it, or one tangent to it within rounding — a flight along
            # a flat wall into its tangent joint with this arc, which must touch the arc there, not leave the table
            if disc < -1e-12 * b * b:
                return np.inf
            disc = 0.0
        if b > 0.0:
            t = -cc / (b + np.sqrt(disc))
        else:
            t = (np.sqrt(disc) - b) / vv
        if t < 0.0:
            if cc > 2.0 * tol * rho:
                return np.inf
            t = 0.0
        return t if _in_arc(params, k, a, v, t, tol * rho) else np.inf
    # CONVEX_ARC, SPHERE_OUT: entering the disc (sphere) kept outside; an arc only between its two normals
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
    if code == SPHERE_OUT:
        return t
    return t if _in_arc(params, k, a, v, t, tol * rho) else np.inf


@jit_hot
def _in_arc(params, k, a, v, t, slack):
    """Whether the point a + t v lies (within ``slack``) on the arc of primitive k: between its first and last
    radial directions [4:6], [8:10] going counter-clockwise (both half-plane tests for an arc of at most 180°,
    either of them for a longer one)."""
    mx = a[0] + t * v[0] - params[k, 0]
    my = a[1] + t * v[1] - params[k, 1]
    after_first = params[k, 4] * my - params[k, 5] * mx >= -slack
    before_last = mx * params[k, 9] - my * params[k, 8] >= -slack
    if params[k, 13] != 0.0:
        return after_first or before_last
    return after_first and before_last


@jit_hot
def contact_normal(code, params, k, a, nu, n):
    """Unit normal at the contact point of the centre ``a`` on the primitive, pointing into the free region -> nu."""
    if code == HALFSPACE or code == SEGMENT:
        for i in range(n):
            nu[i] = params[k, 4 + i]
        return
    s = 0.0
    m = 2 if code == CYLINDER else n
    for i in range(n):          # constant indices (see collision_time)
        nu[i] = a[i] - params[k, i] if i < m else 0.0
        s += nu[i] * nu[i]
    s = 1.0 / np.sqrt(s)
    if code == CONCAVE_ARC or code == FOCUS_ARC or code == CYLINDER:
        s = -s
    for i in range(n):
        nu[i] = nu[i] * s if i < m else 0.0


@jit_hot
def normal_jacobian(code, params, k, a, J, n):
    """J[i, j] = ∂ν_i/∂a_j: how the unit normal (into the free region) of primitive k turns as the contact point a
    moves on it, the wall's curvature (the tangent map of the dynamics needs it). Flat walls: 0. Round walls of
    radius ρ about c: ν = ±(a − c)/|a − c|, so J = ±(I − ûûᵀ)/|a − c| with û = (a − c)/|a − c| (+ for a wall kept
    outside: a reflex arc, a disc or sphere obstacle; − for one kept inside); a cylinder: the same across its
    axis, 0 along it."""
    for i in range(n):
        for j in range(n):
            J[i, j] = 0.0
    if code == HALFSPACE or code == SEGMENT:
        return
    m = 2 if code == CYLINDER else n
    s = 0.0
    for i in range(n):          # constant indices (see collision_time)
        if i < m:
            s += (a[i] - params[k, i]) * (a[i] - params[k, i])
    r = np.sqrt(s)
    sign = -1.0 if (code == CONCAVE_ARC or code == FOCUS_ARC or code == CYLINDER) else 1.0
    for i in range(n):
        if i < m:
            ui = (a[i] - params[k, i]) / r
            for j in range(n):
                if j < m:
                    uj = (a[j] - params[k, j]) / r
                    J[i, j] = sign * ((1.0 if i == j else 0.0) - ui * uj) / r


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
def box_collision(codes, params, a, v, tol, n, box, others, boxed, first):
    """:func:`next_collision` as the engine takes it -> (flight time, primitive). A table bounded by an
    axis-aligned box (:attr:`Geometry.axis_box`: primitive ``box[2i]`` is the side x_i = lo of normal +e_i,
    ``box[2i+1]`` the side x_i = hi of normal −e_i) has its sides in closed form: per axis, the sign of v_i says
    which side is ahead and one division gives its time — the half-space's ``max(d, 0)/−(v·ν)`` with d and v·ν
    reduced to their one non-zero term, so the same number (``boxed``: a compile-time constant in the engine,
    so that a table without a box has no trace of it). Then the primitives ``others`` (all of them without a
    box) by :func:`collision_time`. Ties go to the lower index, as in :func:`next_collision`: the
    same flight times and primitives, bit for bit (tests/test_fastpaths.py). One function for both cases, so
    that the kernel holds one copy of :func:`collision_time` (each inlined copy costs compile time).

    ``first`` (``Table.first_hit``: :attr:`Geometry.convex_boundary`, a run-time value): the first primitive of
    ``others`` that reports a hit is the next collision: the loop stops there (``others`` lists the segments before
    the arcs, the cheaper test first). The same primitive and flight time as the smallest over all of them, except where two adjacent
    pieces both report a hit within the tolerance at their joint (then either is the contact, a tolerance apart)."""
    best = np.inf
    which = -1
    if boxed:
        for i in range(n):
            vi = v[i]
            if vi > 0.0:
                q = box[2 * i + 1]
                t = max(params[q, i] - a[i], 0.0) / vi
            elif vi < 0.0:
                q = box[2 * i]
                t = max(a[i] - params[q, i], 0.0) / -vi
            else:
                continue
            # the smaller time, the lower index on a tie, written so that LLVM makes selects of it, not branches:
            # which of two times is smaller is a coin toss that a branch mispredicts (Sinai: 2.5 of 24 ns)
            upd = t < best
            if t == best:
                upd = q < which
            best = t if upd else best
            which = q if upd else which
    for m in range(others.shape[0]):
        k = others[m]
        t = collision_time(codes[k], params, k, a, v, tol, n)
        upd = t < best
        if t == best:
            upd = k < which
        best = t if upd else best
        which = k if upd else which
        if first and best < np.inf:
            break
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
    m = 2 if code == CYLINDER else n
    s = 0.0
    for i in range(n):          # constant indices (see collision_time)
        if i < m:
            s += (a[i] - params[k, i]) * (a[i] - params[k, i])
    f = params[k, 12] / np.sqrt(s)
    for i in range(n):
        if i < m:
            a[i] = params[k, i] + f * (a[i] - params[k, i])


#: in a periodic table, a flight longer than this many times the cell's shortest side is taken to run along a
#: corridor that meets no obstacle, ever: it ends like an escape (reported: rbx.cli.simulate). 10⁴ cut real
#: flights short: with scatterers of radius 0.001 (R = 0.001) in the unit cell, 3 of 4 trajectories met one after
#: more than 10⁴ cells within 2·10⁴ collisions. Walking 10⁷ cells takes ~50 ms; a flight exactly along a corridor
#: (v along an axis between rows of scatterers) is the case this bound is for. (tests/reference.py stops after
#: LATTICE_MAX_WINDOWS windows, which its test scenes never reach)
MAX_PERIODIC_FLIGHT = 10_000_000


def periodic_images(geom):
    """The images a periodic table's cell walk tests in each cell (:func:`periodic_flight`) -> (primitive (Q,)
    int64, shift (Q, n) float64 in cells, each −1, 0 or 1): every primitive shifted by each neighbouring cell
    whose obstacle, grown by R, reaches into the cell [lo, lo + period] or within 1e-9 of a period of it (an
    obstacle may cross the cell's sides: a dense lattice, a gas of finite horizon). The unshifted ones come first.
    Obstacles are smaller than half a period once grown (:func:`check_fit`), so no image further away can
    reach the cell."""
    n = geom.dimension
    if geom.lattice is None:
        return np.zeros(0, dtype=np.int64), np.zeros((0, n))
    lo, period = (np.asarray(x, float) for x in geom.lattice)
    slack = 1e-9 * period
    prims, shifts = [], []
    cells = sorted(np.ndindex(*(3,) * n), key=lambda s: any(x != 1 for x in s))
    for s in cells:
        s = np.array(s, float) - 1.0
        for k in range(len(geom.codes)):
            c, rho = geom.params[k, :n] + s * period, geom.params[k, 12]
            if np.all(c + rho >= lo - slack) and np.all(c - rho <= lo + period + slack):
                prims.append(k)
                shifts.append(s)
    return np.array(prims, dtype=np.int64), np.array(shifts, dtype=np.float64).reshape(-1, n)


@jit_hot
def periodic_flight(codes, params, a, v, tol, n, lo, period, images, shift, base, loc, off, ahead):
    """The next collision in a periodic table (a Lattice of period ``period`` from ``lo``) -> (flight time,
    primitive), the image hit being shifted by ``off`` (the contact point relative to the cell's primitives is
    a − off); (inf, −1) for a flight along a corridor that meets nothing within MAX_PERIODIC_FLIGHT cells.

    The flight walks the cells it crosses, in order (the traversal of Amanatides and Woo). In each cell it tests
    the images that reach into the cell (:func:`periodic_images`: primitive ``images[q]`` shifted by
    ``shift[q]`` cells from this one), from the point where the flight entered the cell (a quadratic solved from
    far away would lose digits as the square of the distance); the first hit that lies in the cell is the
    collision, else the flight crosses the side it reaches first (both at once at a corner). A hit at a side that
    rounding puts beyond it is found again in the next cell, which that image reaches too; rounding can only
    change the order of two cells the flight crosses within rounding of their common corner. ``a`` stays
    unfolded, and the caller flies the whole flight at once (one rounding per flight, as elsewhere). Scratch
    arrays of n values: ``base`` (the cell's index along each axis, an integer held as a float), ``loc``, ``off``
    (the start of the cell's walk, then the shift of the image hit), ``ahead`` (when the flight crosses the
    cell's next side along each axis)."""
    vv = 0.0
    short = np.inf
    for i in range(n):
        vv += v[i] * v[i]
        short = min(short, period[i])
    # at most MAX_PERIODIC_FLIGHT shortest sides: a bound that stays finite, so that a flight whose length has
    # overflowed (inf) or is NaN ends too (a cell of 1e307 walked for ever). A length, not a count of cells: an
    # integer counter carried through the walk cost the rough Lorentz gas 8 % (0.73 -> 0.67 of its hand loop)
    far = min(MAX_PERIODIC_FLIGHT * short / np.sqrt(vv), 1e308)
    for i in range(n):
        base[i] = np.floor((a[i] - lo[i]) / period[i])
        if v[i] > 0.0:
            ahead[i] = (lo[i] + (base[i] + 1.0) * period[i] - a[i]) / v[i]
        elif v[i] < 0.0:
            ahead[i] = (lo[i] + base[i] * period[i] - a[i]) / v[i]
        else:
            ahead[i] = np.inf
    acc = 0.0                                    # when the flight entered the current cell
    while True:
        leave = ahead[0]                         # when it leaves the cell
        for i in range(1, n):
            leave = min(leave, ahead[i])
        for i in range(n):
            off[i] = a[i] + acc * v[i]
        best = np.inf
        which = -1
        image = 0
        for q in range(images.shape[0]):
            k = images[q]
            for i in range(n):
                loc[i] = off[i] - (base[i] + shift[q, i]) * period[i]
            t = collision_time(codes[k], params, k, loc, v, tol, n)
            if t < best:
                best = t
                which = k
                image = q
        if which >= 0 and acc + best <= leave:
            for i in range(n):
                off[i] = (base[i] + shift[image, i]) * period[i]
            return acc + best, which
        acc = leave
        if not acc <= far:                       # NaN or inf included
            return np.inf, -1
        # into the next cell across the side reached first (across both at a corner). Only constant indices into
        # the scratch arrays and v: an index known at run time would keep them in memory, not registers (in the
        # engine that is its own velocity)
        for i in range(n):
            if ahead[i] == leave:
                base[i] += 1.0 if v[i] > 0.0 else -1.0
                ahead[i] += period[i] / abs(v[i])


# ---- tables built from wall pieces (docs/reference.md §8): the zoo, obstacles on any table, periodic cells ------

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
            area += 0.5 * (c[0] * rho * (np.sin(th1) - np.sin(th0)) - c[1] * rho * (np.cos(th0) - np.cos(th1))
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
    from . import tables as T
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
        if isinstance(piece, T.Boundary):
            dist, wind = _boundary_distance(p, [_piece_frame(q) for q in piece.pieces])
            d = np.where(np.abs(wind) > 0.5, dist, -dist) - R
        elif isinstance(piece, T.Polygon):
            d = _polygon_clearance(p, np.asarray(piece.vertices, float), R)
        elif isinstance(piece, (T.Plane, T.Line)):
            d = (p - np.asarray(piece.point, float)) @ np.asarray(T.unit(piece.normal), float) - R
        elif isinstance(piece, T.Circle):
            d = piece.radius - R - np.linalg.norm(p - np.asarray(piece.center, float), axis=1)
        elif isinstance(piece, T.Sphere):
            c = np.asarray(piece.center, float)
            if piece.inside:
                d = piece.radius - R - np.linalg.norm(p - c, axis=1)
            else:
                d = np.min([np.linalg.norm(p - c - im, axis=1) for im in images], axis=0) - piece.radius - R
        elif isinstance(piece, T.Cylinder):
            d = piece.radius - R - np.linalg.norm(p[:, :2] - np.asarray(piece.center, float), axis=1)
        else:
            continue
        out = np.minimum(out, d)
    return out.reshape(shape)


def _caps_z(pieces):
    """The z range between the horizontal Plane caps of a cylinder -> (z0, z1)."""
    zs = sorted(float(q.point[2]) for q in pieces if type(q).__name__ == "Plane" and abs(q.normal[2]) == 1.0)
    return (zs[0], zs[-1]) if len(zs) >= 2 else (-np.inf, np.inf)


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
            r[13] = 1.0 if span > np.pi else 0.0
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
            r[13] = 1.0 if f["span"] > np.pi else 0.0
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


def add_pieces(geom, pieces, R):
    """``geom`` with the primitives and walls of ``pieces`` added after its own (obstacles on any table; every
    piece of a table of the zoo) -> a new Geometry."""
    from . import tables as T
    n = geom.dimension
    codes, walls, rows = list(geom.codes), list(geom.walls), [r for r in geom.params]
    wall_list = list(geom.wall_list)
    g = Geometry(geom.kind, n, geom.codes, geom.walls, geom.params, wall_list, geom.size, outline=geom.outline,
                 shrunk_outline=geom.shrunk_outline, circle=geom.circle, table=geom.table, slab=False,
                 can_sample=geom.can_sample, shrunk_radius=R, lattice=geom.lattice, from_pieces=geom.from_pieces,
                 corners=geom.corners)
    if geom.pieces is None:     # a table of the paper's kinds: its own walls are pieces too, for clearance
        g.pieces = [q for q in T.walls(geom.kind, geom.table or {}) if not isinstance(q, T.Sphere)] \
            if geom.table is not None else []
        g._own_clearance = geom
    else:
        g.pieces = list(geom.pieces)
    if hasattr(geom, "lengths"):
        g.lengths = geom.lengths
    g.curves = list(getattr(geom, "curves", []))
    z0, z1 = _caps_z(pieces)
    for q in pieces:
        w = len(wall_list)
        if isinstance(q, T.Lattice):
            g.lattice = (np.asarray(q.lo, float), np.asarray(q.hi, float) - np.asarray(q.lo, float))
            g.pieces.append(q)
            continue
        g.pieces.append(q)
        if isinstance(q, T.Boundary):
            outline, shrunk = _boundary(g, q, R, w, codes, walls, rows, wall_list)
            g.outline = outline
            g.curves.append(("table", np.vstack([outline, outline[:1]])))
            g.curves += [("shrunk", c) for c in shrunk]
        elif isinstance(q, T.Polygon):
            sub = polygon({"vertices": [list(v) for v in q.vertices]}, R, names=list(q.names))
            codes += list(sub.codes)
            walls += [w + int(k) for k in sub.walls]
            rows += list(sub.params)
            wall_list += sub.wall_list
            g.outline = sub.outline
            g.curves.append(("table", np.vstack([sub.outline, sub.outline[:1]])))
            g.curves.append(("shrunk", np.vstack([sub.shrunk_outline, sub.shrunk_outline[:1]])))
        elif isinstance(q, T.Plane):
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
                cyl = [c for c in pieces if isinstance(c, T.Cylinder)]
                patches = []
                if cyl:
                    centre = np.array([cyl[0].center[0], cyl[0].center[1], float(q.point[2]) + R * nu[2]])
                    patches = [("disc", centre, nu, cyl[0].radius - R)]
                wall_list.append(Wall(q.name, np.asarray(q.tangents, float), patches))
        elif isinstance(q, T.Sphere):
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
        elif isinstance(q, T.Cylinder):
            c = np.asarray(q.center, float)
            codes.append(CYLINDER)
            walls.append(w)
            rows.append(_row(n, c, (), (), q.radius - R))
            wall_list.append(Wall(q.name, None, [("cylinder", c, q.radius - R, z0 + R, z1 - R)]))
        elif isinstance(q, (T.Line, T.Circle)):
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
    from . import tables as T
    size = geom.size
    obstacles = [q for q in geom.pieces if isinstance(q, T.Sphere) and not q.inside]
    users = len(geom.table.get(T.OBSTACLES) or ()) if geom.table else 0     # the user's obstacles come last

    def key_of(q):
        """The config key that made obstacle q: ``obstacles[j]``, or a preset's scatterer (Sinai, Lorentz):
        its ``radius``."""
        j = obstacles.index(q) - (len(obstacles) - users)
        return f"obstacles[{j}]" if j >= 0 else "radius"
    for q in geom.pieces:
        if isinstance(q, T.Boundary):
            for p in q.pieces:
                f = _piece_frame(p)
                if not f["seg"] and f["ccw"] and f["rho"] <= R:
                    return f"does not fit in the arc '{p.name}' (radius {f['rho']:g} ≤ the ball's radius {R:g})"
        if isinstance(q, (T.Sphere, T.Cylinder)) and getattr(q, "inside", True) and q.radius <= R:
            return f"does not fit in '{q.name}' (radius {q.radius:g} ≤ the ball's radius {R:g})"
    z0, z1 = _caps_z(geom.pieces)
    if np.isfinite(z1 - z0) and z1 - z0 <= 2 * R:
        return f"does not fit between the caps {z1 - z0:g} apart"
    # a wall with no room for the centre along it (shorter than the ball, or behind a part narrower than 2R) is
    # one the ball never touches: that is no reason to refuse the table (a mushroom's cap floor of 0.05 beside a
    # wide stem was), only to refuse drawing starts on it (rbx.config). A table with no room along any wall has
    # none for the ball
    bounded = geom.wall_list[:len(geom.wall_list) - len(obstacles)]
    if bounded and not any(isinstance(q, T.Cylinder) for q in geom.pieces) and not any(
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
    others = [q for q in geom.pieces if q not in obstacles and not isinstance(q, T.Lattice)]
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


def draw(ax, geom, lo, hi, style_table, style_shrunk):
    """Draw a table built from pieces on 2D axes (a 3D table: its horizontal projection) over the data range
    [lo, hi]: the walls and, dashed, the shrunk walls the centre meets; a periodic table: its obstacles over the
    lattice cells the data covers, with the cells' sides dotted."""
    from . import tables as T
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
            if isinstance(q, (T.Sphere, T.Cylinder)):
                c = np.asarray(q.center, float)[:2]
                grow = -R if getattr(q, "inside", True) else R
                curves += [("table", c + q.radius * circ), ("shrunk", c + (q.radius + grow) * circ)]
            elif isinstance(q, T.Plane) and abs(q.normal[2]) != 1.0 and np.all(np.isfinite(q.lo + q.hi)):
                pass
        boxes = [q for q in geom.pieces if isinstance(q, T.Plane) and abs(q.normal[2]) != 1.0]
        if boxes:       # the faces x = lx and y = ly (a face's extent is infinite along its own normal)
            lx, ly = max(q.point[0] for q in boxes), max(q.point[1] for q in boxes)
            curves += [("table", np.array([[0, 0], [lx, 0], [lx, ly], [0, ly], [0, 0]], float)),
                       ("shrunk", np.array([[R, R], [lx - R, R], [lx - R, ly - R], [R, ly - R], [R, R]], float))]
    if len(shifts) > 25:        # many cells: each obstacle a light grey disc, the shrunk outlines left out
        from matplotlib.collections import PatchCollection
        from matplotlib.patches import Circle as Disc
        discs = [Disc(np.asarray(q.center[:2], float) + s, q.radius) for s in shifts for q in geom.pieces
                 if isinstance(q, T.Sphere) and not q.inside]
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
    from . import tables as T
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
        if isinstance(q, T.Sphere):
            for s in shifts:
                c = np.asarray(q.center, float) + s
                r = q.radius
                ax.plot_surface(c[0] + r * np.cos(u) * np.sin(w), c[1] + r * np.sin(u) * np.sin(w),
                                c[2] + r * np.cos(w), color="0.6", alpha=0.15 if q.inside else 0.35, linewidth=0)
                for rad, style in ((r, style_table), (r - R if q.inside else r + R, style_shrunk)):
                    ax.plot(c[0] + rad * np.cos(t), c[1] + rad * np.sin(t), np.full_like(t, c[2]), **style)
                out_lo, out_hi = np.minimum(out_lo, c - r), np.maximum(out_hi, c + r)
        elif isinstance(q, T.Cylinder):
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
