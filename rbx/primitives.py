"""The primitives of the shrunk table (the boundary the centre meets) and their kernels.

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

Each primitive's contract — its collision time (the closed form, the numerically stable root), its contact
normal (pointing into the free region), the snap of a contact point onto it, its normal's Jacobian (the
curvature, for the tangent map), the clearance of points and the sampling patch of its wall — is one section
below: the flat primitives (``HALFSPACE``, ``SEGMENT``), what the round ones share, then ``CONCAVE_ARC`` and
``CYLINDER``, ``FOCUS_ARC``, ``CONVEX_ARC`` and ``SPHERE_OUT``. The kernels call them through
:func:`collision_time`, :func:`contact_normal`, :func:`snap` and :func:`normal_jacobian`, which pick the section by
the primitive's code. The parameters of a row are read through the named offsets :data:`P_POINT`,
:data:`P_NORMAL`, :data:`P_TANGENT`, :data:`P_RADIUS` (:data:`P_LENGTH`) and :data:`P_WIDE`.

How to add a primitive: a code; its section here (collision time, normal, snap, normal Jacobian) and its branch in
the four dispatchers; its case in :func:`rbx.construction.add_pieces` (its parameter row, a ``Wall`` with a
sampling patch), :func:`rbx.pieces.pieces_clearance`, :func:`rbx.construction.check_fit` and :mod:`rbx.drawing`;
a wall-piece dataclass in :mod:`rbx.pieces`; then tests/reference.py and :mod:`rbx.precise`.

A periodic cell is the ``lattice`` (lo, period) of the geometry: the kernel walks the cells a flight crosses and
tests each cell's images (:func:`periodic_flight`).
"""
from dataclasses import dataclass, field

import numpy as np

from ._jit import jit_hot
from .pieces import _polygon_clearance, pieces_clearance

HALFSPACE, SEGMENT, CONCAVE_ARC, CONVEX_ARC, SPHERE_OUT, FOCUS_ARC, CYLINDER = 0, 1, 2, 3, 4, 5, 6
#: every primitive code, by name
PRIMITIVES = {"HALFSPACE": HALFSPACE, "SEGMENT": SEGMENT, "CONCAVE_ARC": CONCAVE_ARC, "CONVEX_ARC": CONVEX_ARC,
              "SPHERE_OUT": SPHERE_OUT, "FOCUS_ARC": FOCUS_ARC, "CYLINDER": CYLINDER}
NPARAM = 16
#: the offsets of a primitive's parameters in its row of ``params`` (the table above): a point or centre [0:n],
#: a normal or an arc's first direction [4:4+n], a segment's tangent or an arc's last direction [8:8+n], a
#: radius or a segment's length [12], 1.0 if an arc spans more than 180° [13]
P_POINT, P_NORMAL, P_TANGENT, P_RADIUS, P_WIDE = 0, 4, 8, 12, 13
P_LENGTH = P_RADIUS
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
            nu = row[P_NORMAL:P_NORMAL + n]
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
                d = (pts - row[:n]) @ row[P_NORMAL:P_NORMAL + n]
            elif code == CONCAVE_ARC:
                d = row[P_RADIUS] - np.linalg.norm(pts - row[:n], axis=-1)
            else:  # pragma: no cover - only polygons have these, handled above
                raise ValueError(code)
            out = np.minimum(out, d)
        return out

    shrunk_radius: float = 0.0


def _row(n, p=(), nu=(), t=(), scalar=0.0):
    r = np.zeros(NPARAM)
    r[:len(p)] = p
    r[P_NORMAL:P_NORMAL + len(nu)] = nu
    r[P_TANGENT:P_TANGENT + len(t)] = t
    r[P_RADIUS] = scalar
    return r


# ---- flat primitives: HALFSPACE (a line or plane, no ends) and SEGMENT (2D, with ends) --------------------------
# collision time: max(d, 0)/−(v·ν) while moving into it, d = (a − p)·ν (a segment: the point within its length,
#   ± tol); normal: ν = the row's P_NORMAL; snap: a −= ((a − p)·ν)ν; normal Jacobian: 0; clearance: (a − p)·ν
#   (Geometry.clearance; the segments of a polygon: rbx.pieces._polygon_clearance); sampling patch: ('flat',
#   origin, ν, [(tangent, length)]) (rbx.construction, drawn by rbx.sampling)

@jit_hot
def _flat_time(code, params, k, a, v, tol, n):
    vn = 0.0
    d = 0.0
    for i in range(n):
        vn += v[i] * params[k, P_NORMAL + i]
        d += (a[i] - params[k, i]) * params[k, P_NORMAL + i]
    if vn >= 0.0:
        return np.inf                      # parallel or leaving: a grazing flight never touches the wall
    if code == HALFSPACE:
        return max(d, 0.0) / -vn
    if d < -tol:
        return np.inf                      # the segment's line lies behind: another part of the table
    t = max(d, 0.0) / -vn
    s = 0.0
    for i in range(2):
        s += (a[i] + t * v[i] - params[k, i]) * params[k, P_TANGENT + i]
    if s < -tol or s > params[k, P_LENGTH] + tol:
        return np.inf
    return t


@jit_hot
def _flat_normal(params, k, nu, n):
    for i in range(n):
        nu[i] = params[k, P_NORMAL + i]


@jit_hot
def _flat_snap(params, k, a, n):
    d = 0.0
    for i in range(n):
        d += (a[i] - params[k, i]) * params[k, P_NORMAL + i]
    for i in range(n):
        a[i] -= d * params[k, P_NORMAL + i]


# ---- round primitives, what they share: a circle or sphere of radius ρ = P_RADIUS about c = P_POINT (a cylinder:
# across its axis, the first two coordinates). Normal ±(a − c)/|a − c| into the free region (− for a wall that
# keeps the centre inside: CONCAVE_ARC, FOCUS_ARC, CYLINDER); snap: a = c + ρ(a − c)/|a − c|; normal Jacobian
# ±(I − ûûᵀ)/|a − c|; clearance ρ − |a − c| inside, |a − c| − ρ outside; sampling patch ('arc', c, ρ, a0, a1, ±1)
# in 2D (rbx.construction), the sphere and the cylinder by rbx.sampling's patches of pieces

@jit_hot
def _kept_inside(code):
    return code == CONCAVE_ARC or code == FOCUS_ARC or code == CYLINDER


@jit_hot
def _round_terms(code, params, k, a, v, n):
    """|a + t v − c|² = ρ²  <=>  |v|² t² + 2 b t + cc = 0 -> (b, cc = |a − c|², vv = |v|²) (a cylinder: in the
    plane across its axis)."""
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
    return b, cc, vv


@jit_hot
def _round_normal(code, params, k, a, nu, n):
    s = 0.0
    m = 2 if code == CYLINDER else n
    for i in range(n):          # constant indices (see _round_terms)
        nu[i] = a[i] - params[k, i] if i < m else 0.0
        s += nu[i] * nu[i]
    s = 1.0 / np.sqrt(s)
    if _kept_inside(code):
        s = -s
    for i in range(n):
        nu[i] = nu[i] * s if i < m else 0.0


@jit_hot
def _round_jacobian(code, params, k, a, J, n):
    m = 2 if code == CYLINDER else n
    s = 0.0
    for i in range(n):          # constant indices (see _round_terms)
        if i < m:
            s += (a[i] - params[k, i]) * (a[i] - params[k, i])
    r = np.sqrt(s)
    sign = -1.0 if _kept_inside(code) else 1.0
    for i in range(n):
        if i < m:
            ui = (a[i] - params[k, i]) / r
            for j in range(n):
                if j < m:
                    uj = (a[j] - params[k, j]) / r
                    J[i, j] = sign * ((1.0 if i == j else 0.0) - ui * uj) / r


@jit_hot
def _round_snap(code, params, k, a, n):
    m = 2 if code == CYLINDER else n
    s = 0.0
    for i in range(n):          # constant indices (see _round_terms)
        if i < m:
            s += (a[i] - params[k, i]) * (a[i] - params[k, i])
    f = params[k, P_RADIUS] / np.sqrt(s)
    for i in range(n):
        if i < m:
            a[i] = params[k, i] + f * (a[i] - params[k, i])


# ---- CONCAVE_ARC (the circle table, a sphere from inside) and CYLINDER (its side): the centre kept inside ---------
# collision time: the larger root, from a centre inside (one a hair outside by rounding is on the circle)

@jit_hot
def _inside_time(b, cc, vv):
    # The centre is inside the circle (a bounded table): one a hair outside by rounding is taken to be on it, else
    # a grazing flight moving inward from there could miss the circle altogether and "escape".
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


# ---- FOCUS_ARC: a 2D arc kept inside (a focusing ``ccw`` arc shrunk by R), between its first and last radial
# directions P_NORMAL, P_TANGENT (counter-clockwise; P_WIDE: it spans more than 180°)
# collision time: the larger root, if the point lies on the arc (a centre outside its circle: a mushroom's stem)

@jit_hot
def _focus_time(params, k, a, v, tol, rho, b, cc, vv):
    # leaving the disc through the arc between its radial directions: the larger root. In a non-convex table the
    # centre may be outside this circle (a mushroom's stem): the larger root is then where the line leaves the
    # disc, if it meets it at all
    if vv == 0.0:
        return np.inf
    if 0.0 < cc <= 4.0 * tol * rho:
        cc = 0.0                             # a hair outside by rounding (just hit, creeping along it): on it
    disc = b * b - vv * cc
    if disc < 0.0:
        # from outside the circle: a line that misses it, or one tangent to it within rounding — a flight along a
        # flat wall into its tangent joint with this arc, which must touch the arc there, not leave the table
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


@jit_hot
def _in_arc(params, k, a, v, t, slack):
    """Whether the point a + t v lies (within ``slack``) on the arc of primitive k: between its first and last
    radial directions [P_NORMAL], [P_TANGENT] going counter-clockwise (both half-plane tests for an arc of at most
    180°, either of them for a longer one)."""
    mx = a[0] + t * v[0] - params[k, 0]
    my = a[1] + t * v[1] - params[k, 1]
    after_first = params[k, P_NORMAL] * my - params[k, P_NORMAL + 1] * mx >= -slack
    before_last = mx * params[k, P_TANGENT + 1] - my * params[k, P_TANGENT] >= -slack
    if params[k, P_WIDE] != 0.0:
        return after_first or before_last
    return after_first and before_last


# ---- CONVEX_ARC (a 2D arc kept outside: a reflex joint rounded by R, a dispersing ``cw`` arc grown by R; between
# its normals P_NORMAL, P_TANGENT) and SPHERE_OUT (a whole disc or sphere obstacle, kept outside)
# collision time: the smaller root while moving towards the centre (an arc: the point on it)

@jit_hot
def _outside_time(code, params, k, a, v, tol, rho, b, cc, vv):
    # entering the disc (sphere) kept outside; an arc only between its two normals
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


# ---- every primitive: what the kernels call, by the primitive's code ----------------------------------------------

@jit_hot
def collision_time(code, params, k, a, v, tol, n):
    """Flight time until the centre at ``a`` moving with ``v`` hits the primitive while moving into it -> t ≥ 0,
    or inf if it never does. A centre a hair outside (rounding) and moving in is hit at t = 0.
    The primitive is row ``k`` of ``params`` (indices, not a row view: views cost reference counting); ``n`` is
    the dimension, passed in so that the kernels compile it as a constant."""
    if code == HALFSPACE or code == SEGMENT:
        return _flat_time(code, params, k, a, v, tol, n)
    b, cc, vv = _round_terms(code, params, k, a, v, n)
    rho = params[k, P_RADIUS]
    if b >= 0.0 and (code == CONVEX_ARC or code == SPHERE_OUT):
        return np.inf                            # moving away from a disc kept outside: never reaches it
    # |a−c|² − ρ² without cancelling ρ² away: a centre on the circle (snapped, or just hit) gives 0 or a few ulp
    # of ρ·|a−c|, where |a−c|² − ρ² would keep the rounding of the squares (a grazing flight needs the former)
    cc = (np.sqrt(cc) - rho) * (np.sqrt(cc) + rho)
    if code == CONCAVE_ARC or code == CYLINDER:
        return _inside_time(b, cc, vv)
    if code == FOCUS_ARC:
        return _focus_time(params, k, a, v, tol, rho, b, cc, vv)
    return _outside_time(code, params, k, a, v, tol, rho, b, cc, vv)


@jit_hot
def contact_normal(code, params, k, a, nu, n):
    """Unit normal at the contact point of the centre ``a`` on the primitive, pointing into the free region -> nu."""
    if code == HALFSPACE or code == SEGMENT:
        _flat_normal(params, k, nu, n)
    else:
        _round_normal(code, params, k, a, nu, n)


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
    _round_jacobian(code, params, k, a, J, n)


@jit_hot
def snap(code, params, k, a, nu, n):
    """Put the centre exactly on primitive ``k`` at contact (ν: its normal there): removes the rounding of the
    flight along the normal. Half-space and segment: a −= ((a − p)·ν)ν; arcs: a = c + ρ(a − c)/|a − c|."""
    if code == HALFSPACE or code == SEGMENT:
        _flat_snap(params, k, a, n)
    else:
        _round_snap(code, params, k, a, n)


# ---- the searches: the next primitive hit ------------------------------------------------------------------------

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
            c, rho = geom.params[k, :n] + s * period, geom.params[k, P_RADIUS]
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
