"""Slow, obviously-correct reference event loop for rough billiards.

Pure Python + numpy, independent of the ``rbx`` engine: it reads a config mapping shaped like the cases of
``tests/data/trajectories.json``, takes from rbx only the table's walls as data (the registry of table kinds,
``rbx.tables.walls``: lines, planes, circles, polygons, boundaries of segments and arcs, spheres, cylinders and a
periodic lattice, in the table's own coordinates; ``rbx.tables.dimension``) and follows docs/reference.md §1–3,
§8 and docs/conventions.md as literally as possible, for any dimension n with the angular velocity held as an n×n
antisymmetric matrix ``W``. Free flight: a ← a + τv, 2D θ ← θ + τω, 3D A ← exp(τW)·A with exp summed as a Taylor
series (the engine uses Rodrigues).

    reference_run(config, uniforms=None) -> list[dict]

Record 0 is the initial state (wall −1, rank 0), record i the state just after collision i. Each record has
``time, position, velocity, angular_velocity, orientation, wall, rank``; 2D angular velocity / orientation are
floats (ω, continuous angle θ), 3D ones a length-3 list (ω) and a 3×3 nested list (A, body → space).
The run stops early (fewer records) when no wall lies ahead (escape), and at a wall whose rule is ``exit``: that
contact is recorded with no map applied (wall = that wall, rank = −1) and the trajectory ends there.

Collision map (docs/reference.md §1, the paper's eq. (update) in the space frame), at a wall with unit normal ν
pointing into the free region:
    r = −Rν,  u = v + W r,  u_t = u − (u·ν)ν,  Δv_t = −2α P u_t,
    v' = v − 2(v·ν)ν + Δv_t,  W' = W + (Δv_t rᵀ − r Δv_tᵀ)/(2λ),  2λ = κR²,  α = κ/(1+κ),
with P the orthogonal projector onto the roughness subspace (rank 0: 0; rank n−1: I − ννᵀ; 3D rank 1: ddᵀ).

Collision times: the centre moves in the table shrunk by R, the points at distance ≥ R from every wall. A
collision is the first time the centre comes within R of a wall, i.e. reaches the set of points at distance
exactly R from it, moving closer. Every wall contributes primitives that cover that set where the centre can
reach it:

* a straight wall (a line, a polygon edge, a boundary segment): its offset by R towards the table, restricted to
  the points whose foot on the wall lies on the wall (offset lines/planes with an extent);
* a round wall: the concentric circle, sphere or cylinder of radius r − R (the table inside it: the circle
  table, a focusing ``ccw`` arc, the 3D sphere, a cylinder's side) or r + R (the table outside it: a dispersing
  ``cw`` arc, a disc or sphere obstacle); an arc only over its own angular extent (which may exceed 180°);
* a joint of a polygon or boundary where it turns clockwise (a reflex joint: judged by the tangents of the two
  pieces there; a tangent joint is not reflex): the circle of radius R about the joint, over the fan where the
  joint is the nearest point of both pieces, (x − joint)·t_in ≥ 0 and (x − joint)·t_out ≤ 0 (t_in, t_out the
  unit tangents of the pieces arriving at and leaving the joint); it belongs to the piece leaving the joint.
  (At a convex joint the centre reaches one of the pieces' offsets first, and at a first contact with a joint
  the joint must be the nearest point of both pieces: the fan holds every such contact.)

For each primitive we solve for the time the centre line a + t·v meets it while moving into it (v·ν < 0 at the
hit point), keep it if the hit point lies on the primitive's extent, and take the smallest time, exact ties
going to the lower wall index. A point that rounding left a hair outside a primitive it is moving into is hit at
time 0 (conventions: corners, grazing). A line that only touches the circle of a focusing wall (the table inside
it) from outside, ahead and on the wall's extent, is a contact at the touching point (v·ν = 0): past it the flight
would leave the table (a flight along a flat wall into a tangent joint with a focusing arc).

A periodic table (a ``Lattice`` cell lo ≤ x ≤ hi: opposite sides identified, not walls) repeats its obstacles
with period hi − lo; positions stay unfolded. The flight is cut into windows of one cell's smallest side; in a
window every image whose grown obstacle meets the window's bounding box is tested (the integer shifts k with
c + k·period within reach of the box, by floor/ceil: no image that could be hit is left out), and the first
window holding a hit gives the collision. A flight that meets nothing within ``LATTICE_MAX_WINDOWS`` windows (a
flight along a corridor of an infinite-horizon gas) is an escape.
"""

import math

import numpy as np

# A point at most this far (relative to the scene's length scale or |position|) on the wrong side of a wall it
# moves into is hit at flight time 0; anything further is a wall behind us (non-convex tables) and is ignored.
DISTANCE_TOLERANCE = 1e-10
# Slack on the extent of a primitive (relative to the scene's length scale): only decides which of two
# primitives meeting tangentially (segment end / reflex arc) reports a hit at their junction.
EXTENT_TOLERANCE = 1e-12
# A joint whose unit tangents have a cross product above −this is not reflex (tangent joints are not).
TANGENT_TOLERANCE = 1e-12
# A periodic flight that meets no obstacle within this many windows (each one cell's smallest side long) escapes.
LATTICE_MAX_WINDOWS = 10_000


# ---------------------------------------------------------------------------------------------------------------
# small linear-algebra helpers


def hat(omega):
    """3-vector ω -> antisymmetric W with W x = ω × x."""
    wx, wy, wz = omega
    return np.array([[0.0, -wz, wy], [wz, 0.0, -wx], [-wy, wx, 0.0]])


def vee(W):
    """Antisymmetric 3×3 W -> ω (inverse of hat)."""
    return np.array([W[2, 1], W[0, 2], W[1, 0]])


def angular_velocity_matrix(omega, n):
    """Space-frame angular velocity as an n×n antisymmetric matrix (2D: ω·J, J the +90° rotation)."""
    if n == 2:
        w = float(omega)
        return np.array([[0.0, -w], [w, 0.0]])
    return hat(np.asarray(omega, dtype=float))


def rodrigues(rotation_vector):
    """Rotation vector -> rotation matrix, by Rodrigues' formula."""
    rv = np.asarray(rotation_vector, dtype=float)
    angle = float(np.linalg.norm(rv))
    if angle == 0.0:
        return np.eye(3)
    K = hat(rv / angle)
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)


def rotation_exponential(X):
    """exp(X) for antisymmetric 3×3 X, summing the Taylor series until it stops changing (deliberately not
    Rodrigues' formula, which the engine uses).

    The rotation angle |vee(X)| is first reduced to [−π, π] (the same rotation): the series' terms then stay
    below π³/6 and each step is orthogonal to a few ulp. (scipy.linalg.expm, Padé with scaling and squaring, is
    biased at large angles: ~1e-14 loss of orthogonality per flight, visible after a few hundred flights.)"""
    angle = float(np.linalg.norm(vee(X)))
    if angle > math.pi:
        X = X * (math.remainder(angle, 2.0 * math.pi) / angle)
    total = np.eye(3)
    term = np.eye(3)
    for k in range(1, 400):  # terms underflow to 0 well before k = 400
        term = term @ X / k
        new_total = total + term
        if np.array_equal(new_total, total):
            return total
        total = new_total
    raise ArithmeticError("Taylor series of exp did not converge")


def rotation_2d(angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s], [s, c]])


# ---------------------------------------------------------------------------------------------------------------
# the shrunk table: walls and their primitives


class Segment:
    """Offset of a straight wall: the line {x : ν·x = ν·base + R} with hit points restricted to
    s = (x − base)·direction in [s_min, s_max] (±inf for unbounded walls). Normal ν (into the free region)."""

    def __init__(self, wall, base, direction, normal, s_min, s_max):
        self.wall = wall
        self.base = np.asarray(base, dtype=float)
        self.direction = np.asarray(direction, dtype=float)
        self.normal = np.asarray(normal, dtype=float)
        self.s_min = s_min
        self.s_max = s_max


class Plane:
    """Offset of a flat wall in 3D: {x : ν·x = ν·base + R}; hit points must satisfy lo ≤ x ≤ hi coordinatewise
    (bounds given with ±inf where unbounded)."""

    def __init__(self, wall, base, normal, lo, hi):
        self.wall = wall
        self.base = np.asarray(base, dtype=float)
        self.normal = np.asarray(normal, dtype=float)
        self.lo = np.asarray(lo, dtype=float)
        self.hi = np.asarray(hi, dtype=float)


class Rim:
    """Circular wall of a round table for the centre: the circle |x − centre| = radius (already shrunk),
    the centre stays inside, the normal points inward: ν = (centre − x)/|x − centre|."""

    def __init__(self, wall, centre, radius):
        self.wall = wall
        self.centre = np.asarray(centre, dtype=float)
        self.radius = float(radius)


class ReflexArc:
    """Arc of radius R around a reflex polygon vertex (the Minkowski-rounded corner), the centre stays outside,
    normal ν = (x − vertex)/R. Extent: the fan where the vertex is the nearest point of both edges, i.e.
    (x − vertex)·e_in ≥ 0 and (x − vertex)·e_out ≤ 0 (e_in, e_out the unit directions of the edges arriving at
    and leaving the vertex)."""

    def __init__(self, wall, vertex, radius, e_in, e_out):
        self.wall = wall
        self.vertex = np.asarray(vertex, dtype=float)
        self.radius = float(radius)
        self.e_in = np.asarray(e_in, dtype=float)
        self.e_out = np.asarray(e_out, dtype=float)


def left_normal(e):
    """Unit direction e rotated by +90°: the inward normal of a CCW polygon edge."""
    return np.array([-e[1], e[0]])


def polygon_primitives(vertices, R, first_wall=0):
    """Offset segments of every edge (full length, untrimmed: at convex corners the other offset line is always
    reached first) plus one arc per reflex vertex, attributed to the edge leaving it."""
    V = [np.asarray(p, dtype=float) for p in vertices]
    m = len(V)
    area2 = sum(V[i][0] * V[(i + 1) % m][1] - V[(i + 1) % m][0] * V[i][1] for i in range(m))
    if not area2 > 0:
        raise ValueError("polygon vertices must be counter-clockwise (positive area)")
    prims = []
    for i in range(m):
        edge = V[(i + 1) % m] - V[i]
        length = float(np.linalg.norm(edge))
        e = edge / length
        prims.append(Segment(first_wall + i, V[i], e, left_normal(e), 0.0, length))
    for i in range(m):
        e_in = V[i] - V[i - 1]
        e_out = V[(i + 1) % m] - V[i]
        cross = e_in[0] * e_out[1] - e_in[1] * e_out[0]
        if cross < 0:  # clockwise turn of a CCW boundary: interior angle > 180°, a reflex vertex
            prims.append(ReflexArc(first_wall + i, V[i], R, e_in / np.linalg.norm(e_in),
                                   e_out / np.linalg.norm(e_out)))
    return prims


class RoundWall:
    """A round wall of the shrunk table: the circle (2D), sphere (3D) or, with ``axes = 2`` in 3D, the cylinder
    with axis ∥ z, |x − centre| = radius over the first ``axes`` coordinates (radius already shrunk or grown).
    ``inside``: the free region is inside it (normal ν = (centre − x)/|x − centre|, hit where the line leaves
    it); else outside (ν = (x − centre)/|x − centre|, hit where the line enters it). ``arc``: None (the whole
    circle) or (first angle, span) of a 2D arc, counter-clockwise from the first angle, span in (0, 2π)."""

    def __init__(self, wall, centre, radius, inside, axes=None, arc=None):
        self.wall = wall
        self.centre = np.asarray(centre, dtype=float)
        self.radius = float(radius)
        self.inside = bool(inside)
        self.axes = len(self.centre) if axes is None else axes
        self.arc = arc

    def shifted(self, offset):
        """The same wall moved by ``offset`` (a periodic image)."""
        return RoundWall(self.wall, self.centre + offset, self.radius, self.inside, self.axes, self.arc)

    def on_extent(self, q, tol):
        """Whether the direction of q from the centre lies on the arc (within the length ``tol``)."""
        if self.arc is None:
            return True
        first, span = self.arc
        rel = q[:2] - self.centre
        delta = (math.atan2(rel[1], rel[0]) - first) % (2.0 * math.pi)
        slack = tol / self.radius
        return delta <= span + slack or delta >= 2.0 * math.pi - slack


def arc_geometry(piece):
    """A boundary arc -> (centre, radius, (first angle, span) counter-clockwise, unit tangent at its start, unit
    tangent at its end), the tangents in the direction the boundary is traversed."""
    c = np.asarray(piece.center, dtype=float)
    s, e = np.asarray(piece.start, dtype=float) - c, np.asarray(piece.end, dtype=float) - c
    radius = float(np.linalg.norm(s))
    a_s, a_e = math.atan2(s[1], s[0]), math.atan2(e[1], e[0])
    ccw = piece.turn == "ccw"
    first = a_s if ccw else a_e                                   # a cw arc is the ccw arc from its end
    span = ((a_e - a_s) if ccw else (a_s - a_e)) % (2.0 * math.pi)

    def tangent(r):
        u = r / np.linalg.norm(r)
        return np.array([-u[1], u[0]]) if ccw else np.array([u[1], -u[0]])
    return c, radius, (first, span), tangent(s), tangent(e)


def boundary_primitives(pieces, R, first_wall=0):
    """The shrunk table of a closed counter-clockwise boundary of segments and arcs (see the module docstring):
    each piece's offset towards the table with its extent, and an arc of radius R about every reflex joint,
    attributed to the piece leaving it."""
    from rbx import tables
    prims, starts, ends = [], [], []
    for i, piece in enumerate(pieces):
        wall = first_wall + i
        if isinstance(piece, tables.Segment):
            p0, p1 = np.asarray(piece.start, dtype=float), np.asarray(piece.end, dtype=float)
            length = float(np.linalg.norm(p1 - p0))
            e = (p1 - p0) / length
            prims.append(Segment(wall, p0, e, left_normal(e), 0.0, length))
            starts.append(e)
            ends.append(e)
        elif isinstance(piece, tables.Arc):
            c, radius, arc, t_start, t_end = arc_geometry(piece)
            if piece.turn == "ccw":          # focusing: the table inside its circle, which shrinks by R
                if radius > R:
                    prims.append(RoundWall(wall, c, radius - R, True, arc=arc))
            else:                            # dispersing: the table outside, the circle grows by R
                prims.append(RoundWall(wall, c, radius + R, False, arc=arc))
            starts.append(t_start)
            ends.append(t_end)
        else:
            raise TypeError(piece)
    m = len(pieces)
    for i in range(m):
        t_in, t_out = ends[i - 1], starts[i]
        if t_in[0] * t_out[1] - t_in[1] * t_out[0] < -TANGENT_TOLERANCE:   # turns clockwise: reflex
            prims.append(ReflexArc(first_wall + i, pieces[i].start, R, t_in, t_out))
    return prims


class Table:
    """The table seen by the ball's centre: dimension, wall names (in wall order, docs/conventions.md), primitives,
    tangent axes."""

    def __init__(self, spec, R):
        # the walls as data from the registry of table kinds (rbx.tables): lines, planes, circles, polygons,
        # boundaries, spheres, cylinders and a lattice in the table's own coordinates; everything from here on
        # (shrinking, collision times, normals) is this module's own
        from rbx import tables
        kind = spec["kind"]
        params = {k: v for k, v in spec.items() if k != "kind"}
        self.kind = kind
        self.R = R
        self.tangent_axes = {}
        self.primitives = []
        self.lattice = None     # (lo, period) of a periodic table; its primitives then repeat (self.periodic)
        self.periodic = []
        pieces = tables.walls(kind, params)
        self.names = tables.wall_names(pieces)
        self.dim = tables.dimension(kind, params)
        wall = 0
        for piece in pieces:
            if isinstance(piece, tables.Lattice):
                lo = np.asarray(piece.lo, dtype=float)
                self.lattice = (lo, np.asarray(piece.hi, dtype=float) - lo)
                continue
            if isinstance(piece, tables.Polygon):
                self.primitives += polygon_primitives(piece.vertices, R, first_wall=wall)
                self.vertices = [np.asarray(p, dtype=float) for p in piece.vertices]
                wall += len(piece.names)
                continue
            if isinstance(piece, tables.Boundary):
                self.primitives += boundary_primitives(piece.pieces, R, first_wall=wall)
                wall += len(piece.pieces)
                continue
            if isinstance(piece, tables.Circle):
                self.primitives.append(Rim(wall, piece.center, float(piece.radius) - R))
            elif isinstance(piece, tables.Sphere):
                radius = float(piece.radius) - R if piece.inside else float(piece.radius) + R
                self.primitives.append(RoundWall(wall, piece.center, radius, piece.inside))
            elif isinstance(piece, tables.Cylinder):
                self.primitives.append(RoundWall(wall, piece.center, float(piece.radius) - R, True, axes=2))
            elif isinstance(piece, tables.Line):
                self.primitives.append(Segment(wall, piece.point, tables.unit(piece.direction),
                                               tables.unit(piece.normal), piece.s_min, piece.s_max))
            elif isinstance(piece, tables.Plane):   # contact points within the table's box shrunk by R
                self.primitives.append(Plane(wall, piece.point, piece.normal, np.asarray(piece.lo, float) + R,
                                             np.asarray(piece.hi, float) - R))
                self.tangent_axes[wall] = tuple(np.asarray(t, dtype=float) for t in piece.tangents)
            else:
                raise TypeError(piece)
            wall += 1
        if self.lattice is not None:       # every wall of a periodic table repeats: only round obstacles do here
            if not all(isinstance(p, RoundWall) and not p.inside for p in self.primitives):
                raise TypeError("a lattice holds only obstacles here")
            self.periodic, self.primitives = self.primitives, []
        self.scale = max(1.0, float(tables.kind(kind).scale(params)))


def collision_time(prim, a, v, R, scale):
    """Flight time until the centre a + t v meets primitive `prim` while moving into it, or inf.

    Returns (t, q) with q the hit point (None when there is no hit)."""
    scale = max(scale, float(np.max(np.abs(a))))  # rounding of positions grows with their size (far in a wedge)
    dist_tol = DISTANCE_TOLERANCE * scale
    ext_tol = EXTENT_TOLERANCE * scale
    if isinstance(prim, (Segment, Plane)):
        nu = prim.normal
        vn = float(nu @ v)
        if not vn < 0.0:  # parallel or moving away: never touches (grazing rule)
            return math.inf, None
        d = float(nu @ a) - (float(nu @ prim.base) + R)  # signed distance to the offset line, > 0 inside
        if d < -dist_tol:  # well behind the wall: a wall of the other side of a non-convex table
            return math.inf, None
        t = max(0.0, d / -vn)
        q = a + t * v
        if isinstance(prim, Segment):
            s = float((q - prim.base) @ prim.direction)
            if not (prim.s_min - ext_tol <= s <= prim.s_max + ext_tol):
                return math.inf, None
        else:
            if np.any(q < prim.lo - ext_tol) or np.any(q > prim.hi + ext_tol):
                return math.inf, None
        return t, q
    if isinstance(prim, Rim):
        p = a - prim.centre
        vv = float(v @ v)
        b = float(p @ v)
        C = float(p @ p) - prim.radius**2
        if vv == 0.0:
            return math.inf, None
        dist = prim.radius - math.sqrt(float(p @ p))  # > 0 inside
        if dist < 0.0:
            if dist < -dist_tol:
                return math.inf, None
            if b > 0.0:  # a hair outside and moving out
                return 0.0, a.copy()
        disc = b * b - vv * C
        if disc <= 0.0:
            return math.inf, None
        s = math.sqrt(disc)
        # larger root of vv t² + 2 b t + C = 0, in a cancellation-free form
        t = (-b + s) / vv if b <= 0.0 else -C / (b + s)
        if t < 0.0:
            t = 0.0
        q = a + t * v
        if not float((q - prim.centre) @ v) > 0.0:
            return math.inf, None
        return t, q
    if isinstance(prim, ReflexArc):
        p = a - prim.vertex
        vv = float(v @ v)
        b = float(p @ v)
        if vv == 0.0 or not b < 0.0:  # moving away from the vertex: never reaches its arc
            return math.inf, None
        C = float(p @ p) - prim.radius**2
        dist = math.sqrt(float(p @ p)) - prim.radius  # > 0 outside the arc's circle (free side)
        if dist < 0.0:
            if dist < -dist_tol:
                return math.inf, None
            t = 0.0
        else:
            disc = b * b - vv * C
            if disc <= 0.0:
                return math.inf, None
            s = math.sqrt(disc)
            t = C / (-b + s)  # smaller root, cancellation-free (b < 0)
        q = a + t * v
        rel = q - prim.vertex
        if not float(rel @ v) < 0.0:
            return math.inf, None
        if float(rel @ prim.e_in) < -ext_tol or float(rel @ prim.e_out) > ext_tol:
            return math.inf, None
        return t, q
    if isinstance(prim, RoundWall):
        m = prim.axes
        p = a[:m] - prim.centre
        w = v[:m]
        vv = float(w @ w)
        if vv == 0.0:
            return math.inf, None
        b = float(p @ w)                                  # > 0: moving away from the centre
        r = math.sqrt(float(p @ p))
        C = (r - prim.radius) * (r + prim.radius)         # |p|² − radius², without cancelling the squares
        disc = b * b - vv * C
        if prim.inside:
            d = prim.radius - r                           # > 0 on the free side (inside)
            clamped = False
            if d < -dist_tol and disc <= 0.0:
                # outside the circle (a stadium's straight part), the line touching it (or missing it by no more
                # than the tolerance) ahead, at a point of its extent: a contact there, v·ν = 0 — past the touching
                # point the flight would leave the free region, which lies inside the circle there (a flight along
                # a flat wall into a tangent joint)
                t_near = -b / vv
                h = math.sqrt(max(0.0, float(p @ p) - b * b / vv))   # the line's distance from the centre
                q = a + t_near * v
                if t_near > 0.0 and h - prim.radius <= dist_tol and prim.on_extent(q, ext_tol):
                    return t_near, q
                return math.inf, None
            if disc < 0.0:                                # the line misses the circle
                if not -dist_tol <= d:
                    return math.inf, None
                disc, clamped = 0.0, True                 # a hair outside: it counts as on the circle
            root = math.sqrt(disc)
            t = (-b + root) / vv if b <= 0.0 else -C / (b + root)   # the larger root, cancellation-free
            if t < 0.0:                                   # behind: only a point a hair outside moving out
                if d < -dist_tol:
                    return math.inf, None
                t = 0.0
            q = a + t * v
            if not clamped and t > 0.0 and not float((q[:m] - prim.centre) @ w) > 0.0:
                return math.inf, None                     # tangent: a grazing flight does not touch it
        else:
            d = r - prim.radius                           # > 0 on the free side (outside)
            if not b < 0.0:                               # moving away from the centre: never enters
                return math.inf, None
            if d < 0.0:
                if d < -dist_tol:                         # inside the circle, off the arc: nothing to enter
                    return math.inf, None
                t = 0.0                                   # a hair inside, moving in: hit now
            else:
                if disc <= 0.0:                           # misses, or tangent (grazing): no contact
                    return math.inf, None
                t = C / (-b + math.sqrt(disc))            # the smaller root, cancellation-free (b < 0)
            q = a + t * v
        if not prim.on_extent(q, ext_tol):
            return math.inf, None
        return t, q
    raise TypeError(prim)


def wall_normal(prim, q):
    """Unit normal into the free region at hit point q."""
    if isinstance(prim, (Segment, Plane)):
        return prim.normal.copy()
    if isinstance(prim, Rim):
        x = prim.centre - q
        return x / np.linalg.norm(x)
    if isinstance(prim, RoundWall):
        x = np.zeros(len(q))
        x[:prim.axes] = q[:prim.axes] - prim.centre
        if prim.inside:
            x = -x
        return x / np.linalg.norm(x)
    x = q - prim.vertex
    return x / np.linalg.norm(x)


def _first_hit(prims, a, v, R, scale, best):
    for prim in prims:
        t, q = collision_time(prim, a, v, R, scale)
        if t == math.inf:
            continue
        if (t, prim.wall) < (best[0], best[1]):
            best = (t, prim.wall, prim, q)
    return best


def lattice_images(table, p0, p1):
    """Every periodic image of the lattice's primitives whose grown obstacle meets the box spanned by the points
    p0, p1 -> list of primitives (shifted copies)."""
    lo_box, hi_box = np.minimum(p0, p1), np.maximum(p0, p1)
    period = table.lattice[1]
    out = []
    for prim in table.periodic:
        ranges = [range(math.ceil((lo_box[j] - prim.radius - prim.centre[j]) / period[j]),
                        math.floor((hi_box[j] + prim.radius - prim.centre[j]) / period[j]) + 1)
                  for j in range(len(period))]
        for k in np.array(np.meshgrid(*ranges, indexing="ij")).reshape(len(period), -1).T:
            out.append(prim.shifted(k * period))
    return out


def next_collision(table, a, v):
    """(t, wall, primitive, hit point) of the next collision, or (inf, -1, None, None) if none lies ahead."""
    best = _first_hit(table.primitives, a, v, table.R, table.scale, (math.inf, -1, None, None))
    if table.lattice is None or not table.periodic:
        return best
    speed = float(np.linalg.norm(v))
    if speed == 0.0:
        return best
    window = float(np.min(table.lattice[1])) / speed
    for k in range(LATTICE_MAX_WINDOWS):
        t0, t1 = k * window, (k + 1) * window
        if best[0] <= t0:
            break
        # every hit in [t0, t1] is on an image meeting this stretch of the flight; times are from a, unwindowed
        best = _first_hit(lattice_images(table, a + t0 * v, a + t1 * v), a, v, table.R, table.scale, best)
        if best[0] <= t1:
            break
    return best


# ---------------------------------------------------------------------------------------------------------------
# boundary rules


def kappa_of(inertia, n):
    if isinstance(inertia, (int, float)) and not isinstance(inertia, bool):
        return float(inertia)
    if inertia == "uniform":
        return 2.0 / (n + 2)
    if inertia == "shell":
        return 1.0 if n == 2 else 2.0 / 3.0
    if inertia == "ring":
        if n != 2:
            raise ValueError("inertia 'ring' is a 2D mass distribution")
        return 1.0
    raise ValueError("unknown inertia %r" % (inertia,))


def resolve_rule(rule, nu, A, n, uniforms):
    """Walk a rule tree to a `constant` or `exit` leaf. Each `random` node consumes one uniform draw; `hemisphere` tests
    b = Aᵀ(−ν) (contact point in the body frame) against its axis: rough if b·axis > 0."""
    while True:
        kind = rule["rule"]
        if kind in ("constant", "exit"):
            return rule
        if kind == "hemisphere":
            b = A.T @ (-nu)
            axis = np.asarray(rule["axis"], dtype=float)
            rule = rule["rough"] if float(b @ axis) > 0.0 else rule["smooth"]
        elif kind == "random":
            if uniforms is None:
                raise ValueError("a random rule needs a stream of uniforms")
            u = float(next(uniforms))
            probs = rule["probabilities"]
            choices = rule["choices"]
            chosen = choices[-1]  # if rounding leaves the cumulative sum just below 1
            total = 0.0
            for p, c in zip(probs, choices):
                total += float(p)
                if u < total:
                    chosen = c
                    break
            rule = chosen
        else:
            raise ValueError("unknown rule %r" % kind)


def rough_projector(leaf, nu, n, tangent_axes):
    """Orthogonal projector P onto the roughness subspace of the tangent plane ν⊥, and the rank."""
    k = int(leaf["rank"])
    if k == 0:
        return np.zeros((n, n)), 0
    if k == n - 1:
        return np.eye(n) - np.outer(nu, nu), k
    if n == 3 and k == 1:
        if "direction_deg" in leaf:
            if tangent_axes is None:
                raise ValueError("direction_deg needs a wall with tangent axes")
            t1, t2 = tangent_axes
            th = math.radians(float(leaf["direction_deg"]))
            d = math.cos(th) * t1 + math.sin(th) * t2
        elif "direction" in leaf:
            d = np.asarray(leaf["direction"], dtype=float)
        else:
            raise ValueError("3D rank 1 needs direction_deg or direction")
        d = d - float(d @ nu) * nu
        norm = float(np.linalg.norm(d))
        if norm == 0.0:
            raise ValueError("roughness direction is normal to the wall")
        d = d / norm
        return np.outer(d, d), 1
    raise ValueError("rank %d not supported in dimension %d" % (k, n))


def collide(v, W, nu, P, R, kappa):
    """docs/reference.md §1 collision map (paper eq. (update), space frame). Returns (v', W')."""
    two_lambda = kappa * R * R
    alpha = kappa / (1.0 + kappa)
    r = -R * nu
    u = v + W @ r
    u_t = u - float(u @ nu) * nu
    dv = -2.0 * alpha * (P @ u_t)
    v_new = v - 2.0 * float(v @ nu) * nu + dv
    W_new = W + (np.outer(dv, r) - np.outer(r, dv)) / two_lambda
    return v_new, W_new


# ---------------------------------------------------------------------------------------------------------------
# the event loop


def _record(n, time, a, v, W, A, theta, wall, rank):
    if n == 2:
        omega = float(W[1, 0])
        orientation = float(theta)
    else:
        omega = [float(x) for x in vee(W)]
        orientation = [[float(x) for x in row] for row in A]
    return {
        "time": float(time),
        "position": [float(x) for x in a],
        "velocity": [float(x) for x in v],
        "angular_velocity": omega,
        "orientation": orientation,
        "wall": int(wall),
        "rank": int(rank),
    }


def reference_run(config, uniforms=None, start=None, collisions=None):
    """Follow one trajectory for config['run']['collisions'] (or ``collisions``) collisions; see the module
    docstring. ``start``: a record to start from instead of the config's initial state (its time, position,
    velocity, angular velocity, orientation — 3D: the matrix — and wall), e.g. one of the engine's records, to
    follow a chaotic orbit one collision at a time from the engine's own states."""
    ball = config["ball"]
    R = float(ball["radius"])
    table = Table(config["table"], R)
    n = table.dim
    kappa = kappa_of(ball.get("inertia", "uniform"), n)
    boundary = config["boundary"]
    per_wall = boundary.get("walls", {}) or {}
    for name in per_wall:
        if name not in table.names:
            raise ValueError("unknown wall %r" % name)
    rules = [per_wall.get(name, boundary.get("default")) for name in table.names]
    if any(rule is None for rule in rules):
        raise ValueError("a wall has no rule and there is no default")
    if uniforms is not None:
        uniforms = iter(uniforms)

    init = config["initial"] if start is None else start
    a = np.asarray(init["position"], dtype=float)
    v = np.asarray(init["velocity"], dtype=float)
    W = angular_velocity_matrix(init.get("angular_velocity", 0.0 if n == 2 else [0.0, 0.0, 0.0]), n)
    if n == 2:
        theta = float(init.get("orientation", 0.0))
        A = None
    else:
        theta = None
        o = init.get("orientation", [0.0, 0.0, 0.0])
        A = np.array(o, dtype=float) if np.ndim(o) == 2 else rodrigues(o)
    time = float(init.get("time", 0.0)) if start is not None else 0.0
    records = [_record(n, time, a, v, W, A, theta, -1 if start is None else start.get("wall", -1),
                       0 if start is None else start.get("rank", 0))]
    for _ in range(int(config["run"]["collisions"] if collisions is None else collisions)):
        tau, wall, prim, q = next_collision(table, a, v)
        if tau == math.inf:
            break  # escape: nothing ahead
        # free flight
        time += tau
        a = q
        if n == 2:
            theta = theta + tau * float(W[1, 0])
            A_now = rotation_2d(theta)
        else:
            A = rotation_exponential(tau * W) @ A
            A_now = A
        # collision
        nu = wall_normal(prim, q)
        leaf = resolve_rule(rules[wall], nu, A_now, n, uniforms)
        if leaf["rule"] == "exit":      # a hole: the contact is recorded as it is, and the trajectory ends
            records.append(_record(n, time, a, v, W, A, theta, wall, -1))
            break
        P, rank = rough_projector(leaf, nu, n, table.tangent_axes.get(wall))
        v, W = collide(v, W, nu, P, R, kappa)
        records.append(_record(n, time, a, v, W, A, theta, wall, rank))
    return records


def wavefront_sums(position, velocity, time, centre, rho, first):
    """The classic 2D billiard's largest exponent from one orbit's records (a specular run), by the curvature B of a
    divergent front: B ← B/(1 + ℓB) along a flight of length ℓ and B ← B + 2K/cos φ at a wall of curvature K
    (K = 1/ρ on the dispersing circle of radius ρ about ``centre``, 0 on flat walls) -> (Σ log(1 + ℓB) over the
    flights after collision ``first``, the time they take); λ₁ is their ratio."""
    S, B = 0.0, 0.0
    for k in range(1, len(time)):
        ell = (time[k] - time[k - 1]) * np.linalg.norm(velocity[k - 1])
        if k > first:
            S += np.log1p(ell * B)
        B = B / (1.0 + ell * B)
        r = position[k] - centre
        if abs(np.linalg.norm(r) - rho) < 1e-9 * rho:
            cos_phi = abs(velocity[k] @ r) / (rho * np.linalg.norm(velocity[k]))
            B += 2.0 / (rho * cos_phi)
    return S, time[-1] - time[first]
