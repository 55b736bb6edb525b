"""Measurements on single 2D orbits: arrays in, numbers out (pure numpy; nothing here simulates or draws).

What the paper (§2.6, the circular and the wedge billiard) states about orbits of a rough disc, as functions of
the recorded collision points and states:

- the **vertex angle** at each collision of a polygonal orbit (:func:`vertex_angles`) and its spread;
- the distances of the segments' lines from a centre (:func:`line_distances`), split by parity into the **two
  caustic radii** of a circular table (:func:`caustic_radii`), the offset between the foot of the perpendicular
  from the centre and the segment's midpoint (:func:`midpoint_offsets`), and the closed-form radii from the initial
  state (:func:`predicted_caustic_radii`); :func:`circle_orbit` measures all of it on one run;
- the **largest distance from a vertex** (:func:`max_distance`), the wedge's invariant s·n (distance from the
  shrunk vertex times normal speed, :func:`wedge_invariant`), the supremum of the distance it implies
  (:func:`wedge_distance_supremum`) and the period of every bounded orbit of a wedge (:func:`wedge_period`), both
  from the initial state in :func:`wedge_prediction`;
- the **period** of a sequence of states (:func:`detect_period`), with the mismatch at that period reported.

Conventions (docs/conventions.md, docs/reference.md §1): positions are the centre of the disc (it moves in the table
shrunk by the radius R); ``v₀ = R√κ·ω`` is the scaled spin of the angle–position coordinates, so that a completely rough
collision at a wall with inward normal ν is the half-turn ``V ↦ 2(a·V)a − V`` of ``V = (v₀, v)`` about
``a = (√κ, Jν)/√(1+κ)``, J the rotation by +90° (the matrix of docs/reference.md §1 on (v₀, v·Jν), with the normal
velocity reversed). Collision points are the records 1, 2, … of a run (record 0 is the initial state, not on a wall).
"""
import math
from dataclasses import dataclass

import numpy as np


def _dot(x, y):
    """x·y of two short vectors, summed in index order -> float. Not ``x @ y``: NumPy hands that to BLAS, whose
    kernel (and so the last bits of a sum of products) depends on the CPU."""
    total = 0.0
    for a, b in zip(np.asarray(x, float).tolist(), np.asarray(y, float).tolist()):
        total += a * b
    return total


def _norm(x):
    """|x| of a short vector (``math.hypot``: no BLAS, the same bits on every CPU) -> float."""
    return math.hypot(*np.asarray(x, float).tolist())


def _points(p):
    p = np.asarray(p, float)
    if p.ndim != 2 or p.shape[1] != 2:
        raise ValueError(f"expected an (K, 2) array of points, got shape {p.shape}")
    return p


def spread(x):
    """max − min of the finite values of x (0.0 for fewer than one value)."""
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    return float(np.ptp(x)) if x.size else 0.0


# ---- polygonal orbits ------------------------------------------------------------------------------------------


def segment_directions(points):
    """Unit vectors of the segments p[i] → p[i+1] -> (K−1, 2)."""
    d = np.diff(_points(points), axis=0)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def vertex_angles(points):
    """Angle at each interior point of the polyline p[0], p[1], … between the segment that arrives and the one that
    leaves -> (K−2,) in [0, π]: the angle between −u_in and u_out (π for a straight continuation, 0 for a
    reversal). For the collision points of a billiard orbit it is the angle of the orbit's corner at the wall."""
    u = segment_directions(points)
    c = np.sum(-u[:-1] * u[1:], axis=1)
    s = np.abs(u[:-1, 0] * u[1:, 1] - u[:-1, 1] * u[1:, 0])
    # better conditioned than arccos near 0 and π; math.atan2 (libm), not np.arctan2, whose AVX-512 version gives
    # other last bits than the one other CPUs run
    return np.array([math.atan2(a, b) for a, b in zip(s.tolist(), c.tolist())], float)


def line_distances(points, centre=(0.0, 0.0)):
    """Distance from ``centre`` to the line through each segment p[i] p[i+1] -> (K−1,)."""
    p = _points(points)
    u = segment_directions(p)
    q = p[:-1] - np.asarray(centre, float)
    return np.abs(q[:, 0] * u[:, 1] - q[:, 1] * u[:, 0])


def midpoint_offsets(points, centre=(0.0, 0.0)):
    """Distance between the foot of the perpendicular from ``centre`` to each segment's line and the segment's
    midpoint -> (K−1,). Zero when the segment touches the circle about ``centre`` of radius
    :func:`line_distances` at its midpoint (every chord of a circle about the same centre does)."""
    p = _points(points)
    c = np.asarray(centre, float)
    u = segment_directions(p)
    q = p[:-1] - c
    foot = q - np.sum(q * u, axis=1, keepdims=True) * u
    mid = 0.5 * (p[1:] + p[:-1]) - c
    return np.linalg.norm(mid - foot, axis=1)


@dataclass(frozen=True)
class CausticPair:
    """The lines of segments 0, 2, 4, … and of segments 1, 3, 5, … of an orbit, as two circles about a centre.

    ``radii``: mean distance of the even and of the odd segments' lines from the centre; ``spreads``: their
    max − min; ``alternation``: the largest distance of any segment's line from the radius of its parity (0 when
    the segments touch the two circles alternately, exactly); ``separation``: |r_even − r_odd| (two circles,
    not one, when it is well above ``alternation``)."""
    radii: tuple
    spreads: tuple
    alternation: float
    separation: float
    segments: int


def caustic_radii(points, centre=(0.0, 0.0)):
    """Split the segments' distances from ``centre`` by parity -> :class:`CausticPair` (needs ≥ 2 segments)."""
    d = line_distances(points, centre)
    if len(d) < 2:
        raise ValueError("caustic radii need at least two segments (three points)")
    even, odd = d[0::2], d[1::2]
    r = (float(np.mean(even)), float(np.mean(odd)))
    alternation = float(max(np.max(np.abs(even - r[0])), np.max(np.abs(odd - r[1]))))
    return CausticPair(r, (spread(even), spread(odd)), alternation, abs(r[0] - r[1]), len(d))


def rough_axis(normal, kappa):
    """Axis a = (√κ, Jν)/√(1+κ) of the half-turn that a completely rough collision at a wall with inward unit
    normal ν applies to V = (v₀, v_x, v_y) -> (3,)."""
    nu = np.asarray(normal, float)
    return np.array([math.sqrt(kappa), -nu[1], nu[0]]) / math.sqrt(1.0 + kappa)


def rough_collision(V, normal, kappa):
    """The completely rough collision map on V = (v₀, v) -> V' = 2(a·V)a − V (docs/reference.md §1, in
    angle–position form)."""
    a = rough_axis(normal, kappa)
    V = np.asarray(V, float)
    return 2.0 * _dot(V, a) * a - V


def predicted_caustic_radii(position, velocity, angular_velocity, rho, R, kappa, centre=(0.0, 0.0)):
    """The two caustic radii and the vertex angle of a completely rough orbit in a circle, in closed form from its
    initial state -> (r_in, r_out, vertex angle).

    The centre moves in the circle of radius ``rho`` (the table's radius minus R). r_in is the distance from the centre
    of the initial flight's line; at the first collision the rough map (docs/reference.md §1) turns (v₀, v) into the
    outgoing state, whose line is at r_out; the vertex angle is the angle there between the two segments. Along a chord
    the tangential velocity and v₀ are unchanged and the map is an involution, so every later collision repeats this
    one: the segments between collisions 1–2, 3–4, … lie at r_out, those between 2–3, 4–5, … at r_in.
    """
    c = np.asarray(centre, float)
    p = np.asarray(position, float) - c
    v = np.asarray(velocity, float)
    b, cc = p @ v, p @ p - rho * rho
    t = (-b + math.sqrt(b * b - (v @ v) * cc)) / (v @ v)     # the forward root: p + t v on the circle
    q = p + t * v
    nu = -q / np.linalg.norm(q)                               # inward normal at the collision point
    out = rough_collision(np.concatenate([[R * math.sqrt(kappa) * angular_velocity], v]), nu, kappa)[1:]
    cross = lambda x, w: abs(x[0] * w[1] - x[1] * w[0]) / np.linalg.norm(w)
    angle = math.atan2(abs(v[0] * out[1] - v[1] * out[0]), float(-v @ out))
    return cross(p, v), cross(q, out), angle


@dataclass(frozen=True)
class CircleOrbit:
    """What the paper's proposition on the circular rough billiard says about one orbit, measured
    (:func:`circle_orbit`). Angles in radians, lengths in the table's unit."""
    collisions: int
    vertex_angle: float          # mean vertex angle
    vertex_angle_spread: float   # its max − min over the orbit
    caustics: CausticPair        # segments 1–2, 3–4, … (even) and 2–3, 4–5, … (odd)
    midpoint_offset: float       # largest distance between the foot of the perpendicular and the midpoint
    off_circle: float            # largest | |p − centre| − ρ | of the collision points
    predicted_radii: tuple       # closed form (even, odd) from the initial state
    predicted_vertex_angle: float

    @property
    def radius_error(self):
        """Largest |measured − closed-form| caustic radius."""
        return max(abs(a - b) for a, b in zip(self.caustics.radii, self.predicted_radii))


def circle_orbit(position, velocity, angular_velocity, rho, R, kappa, centre=(0.0, 0.0)):
    """Measure one completely rough orbit of a circular table -> :class:`CircleOrbit`.

    ``position`` (K, 2): record 0 (the initial state) then the collision points; ``velocity`` (K, 2) and
    ``angular_velocity`` (K,): only record 0 is used (the closed-form prediction). Needs ≥ 3 collisions."""
    p = np.asarray(position, float)
    pts = p[1:]
    if len(pts) < 3:
        raise ValueError("a circle orbit needs at least 3 collisions")
    r_in, r_out, angle = predicted_caustic_radii(p[0], np.asarray(velocity, float)[0],
                                                 float(np.asarray(angular_velocity, float).reshape(-1)[0]),
                                                 rho, R, kappa, centre)
    va = vertex_angles(pts)
    return CircleOrbit(
        collisions=len(pts), vertex_angle=float(np.mean(va)), vertex_angle_spread=spread(va),
        caustics=caustic_radii(pts, centre), midpoint_offset=float(np.max(midpoint_offsets(pts, centre))),
        off_circle=float(np.max(np.abs(np.linalg.norm(pts - np.asarray(centre, float), axis=1) - rho))),
        predicted_radii=(r_out, r_in), predicted_vertex_angle=angle)


# ---- wedges ----------------------------------------------------------------------------------------------------


def max_distance(positions, vertex=(0.0, 0.0)):
    """Largest distance of the finite points from ``vertex`` -> float."""
    p = np.asarray(positions, float).reshape(-1, 2)
    p = p[np.all(np.isfinite(p), axis=1)]
    return float(np.max(np.linalg.norm(p - np.asarray(vertex, float), axis=1))) if len(p) else float("nan")


def wedge_frame(angle_deg, R):
    """(shrunk vertex, inward normals of wall0 and wall1) of the wedge of that vertex angle for a disc of radius R
    (the centre moves in the wedge whose walls are moved inward by R; its vertex lies on the bisector)."""
    phi = math.radians(angle_deg)
    apex = R / math.sin(phi / 2) * np.array([math.cos(phi / 2), math.sin(phi / 2)])
    return apex, np.array([[0.0, 1.0], [math.sin(phi), -math.cos(phi)]])


def wedge_invariant(positions, velocities, walls, angle_deg, R):
    """s·n at each collision -> (K,): s the distance of the collision point from the shrunk vertex, n = v·ν the
    normal speed leaving the wall hit.

    For any collision law that reverses the normal velocity, a flight from one wall of a wedge to the other
    gives s_k·sin β = τ·n_{k+1} and s_{k+1}·sin β = τ·n_k, so s·n is the same at every collision: the dilation
    symmetry of the wedge. Orbits stay bounded exactly as long as n stays away from 0."""
    apex, normals = wedge_frame(angle_deg, R)
    p = np.asarray(positions, float).reshape(-1, 2)
    v = np.asarray(velocities, float).reshape(-1, 2)
    w = np.asarray(walls, np.int64).reshape(-1)
    s = np.linalg.norm(p - apex, axis=1)
    n = np.sum(v * normals[w], axis=1)
    return s * n


def _min_on_circle(V, e, N):
    """min of V'·N over the circle of V' obtained by rotating V about the unit axis e."""
    c = _dot(V, e) * e
    r = _norm(V - c)
    Np = N - _dot(N, e) * e
    return float(_dot(c, N) - r * _norm(Np))


def wedge_distance_supremum(velocity, angular_velocity, wall, invariant, angle_deg, R, kappa):
    """The largest distance from the shrunk vertex that a completely rough orbit of a wedge can reach -> (sup of s,
    smallest normal speed n_min) from one post-collision state (velocity, ω, index of the wall just hit) and the
    invariant s·n of :func:`wedge_invariant`.

    The walls alternate and each rough collision is a half-turn H_w of V = (v₀, v) about the wall's axis
    (:func:`rough_axis`), so two collisions rotate V about the fixed axis e of Q = H_other·H_wall: the states
    leaving this wall lie on the circle of V about e, those leaving the other wall on the circle of H_other·V
    about H_other·e. When the rotation angle is not a rational multiple of 2π these circles are filled densely,
    the normal speed comes arbitrarily close to its minimum n_min over them, and s = (s·n)/n to
    invariant / n_min. When n_min ≤ 0 the orbit is not bounded (sup = inf)."""
    _, normals = wedge_frame(angle_deg, R)
    V = np.concatenate([[R * math.sqrt(kappa) * angular_velocity], np.asarray(velocity, float)])
    a = [rough_axis(nu, kappa) for nu in normals]
    here, other = int(wall), 1 - int(wall)
    # V leaving `here` → leaving `other` (H_other·V) → leaving `here` again: the rotation Q = H_here·H_other
    # Q turns about the axis perpendicular to both half-turn axes (its direction's sign does not matter below)
    e = np.cross(a[here], a[other])
    e = e / _norm(e)
    N = [np.concatenate([[0.0], nu]) for nu in normals]
    n_here = _min_on_circle(V, e, N[here])
    n_other = _min_on_circle(2.0 * _dot(a[other], V) * a[other] - V, 2.0 * _dot(a[other], e) * a[other] - e,
                             N[other])
    n_min = min(n_here, n_other)
    return (invariant / n_min if n_min > 0 else math.inf), n_min


# ---- periods ---------------------------------------------------------------------------------------------------


def collision_states(position, velocity, angular_velocity, R, kappa):
    """States at collisions as comparable rows -> (K, 5): (x, y)/L with L the largest |position|, and
    (v_x, v_y, v₀)/S with v₀ = R√κ·ω and S the largest speed √(|v|² + v₀²) (the energy's). Differences of rows are
    then relative to the orbit's size and speed."""
    p = np.asarray(position, float).reshape(-1, 2)
    v = np.asarray(velocity, float).reshape(-1, 2)
    v0 = R * math.sqrt(kappa) * np.asarray(angular_velocity, float).reshape(-1, 1)
    V = np.hstack([v, v0])
    L = float(np.max(np.linalg.norm(p, axis=1)))
    S = float(np.max(np.linalg.norm(V, axis=1)))
    return np.hstack([p / (L if L > 0 else 1.0), V / (S if S > 0 else 1.0)])


@dataclass(frozen=True)
class Period:
    """Result of :func:`detect_period`. ``period``: the smallest p with mismatch ≤ tol (None if none up to
    ``max_period``); ``mismatch``: max_i max_j |state[i+p, j] − state[i, j]| over the whole sequence at that p
    (the tolerance to which the sequence is periodic; for None, the smallest mismatch found and ``best`` its p);
    ``shorter``: the smallest mismatch of any p below the period (how clearly no shorter period fits; inf when
    p = 1); ``tol``: the tolerance asked for; ``length``: number of states."""
    period: int | None
    mismatch: float
    shorter: float
    tol: float
    length: int
    best: int


def detect_period(states, tol=1e-9, max_period=None):
    """Smallest p ≥ 1 with |state[i+p] − state[i]| ≤ tol for every i (max norm over the components) ->
    :class:`Period`. ``states``: (K, d) rows in comparable units (e.g. :func:`collision_states`); p is searched up
    to ``max_period`` (default K // 2, so that every p is tested on at least half the sequence)."""
    x = np.asarray(states, float)
    if x.ndim == 1:
        x = x[:, None]
    K = len(x)
    top = K // 2 if max_period is None else min(int(max_period), K - 1)
    shorter, best, best_p = math.inf, math.inf, 0
    for p in range(1, top + 1):
        m = float(np.max(np.abs(x[p:] - x[:-p])))
        if m <= tol:
            return Period(p, m, shorter, tol, K, p)
        shorter = min(shorter, m)
        if m < best:
            best, best_p = m, p
    return Period(None, best, shorter, tol, K, best_p)


def wedge_rotation_angle(angle_deg, kappa):
    """Angle 2γ by which two completely rough collisions (one on each wall) rotate V = (v₀, v) -> radians.

    The axes of the two half-turns (:func:`rough_axis`) make the angle γ with cos γ = (κ − cos β)/(1 + κ), β the
    vertex angle (the walls' tangents Jν make the angle π − β); two half-turns compose to the rotation by 2γ. For
    the uniform disc (κ = ½) in the 60° wedge γ = π/2: V returns after 4 collisions."""
    c = (kappa - math.cos(math.radians(angle_deg))) / (1.0 + kappa)
    return 2.0 * math.acos(max(-1.0, min(1.0, c)))


def wedge_period(angle_deg, kappa, max_turns=1000, tol=1e-9):
    """The period in collisions of every bounded completely rough orbit of the wedge -> 2q, or None when the
    rotation 2γ (:func:`wedge_rotation_angle`) is not m/q of a full turn for any q ≤ ``max_turns`` (to ``tol``).

    The velocities then repeat after 2q collisions, and so do the positions: along an orbit s·n is constant
    (:func:`wedge_invariant`), so the distance s from the shrunk vertex is a function of the velocity."""
    turns = wedge_rotation_angle(angle_deg, kappa) / (2.0 * math.pi)
    for q in range(1, max_turns + 1):
        if abs(q * turns - round(q * turns)) <= tol * q:
            return 2 * q
    return None


@dataclass(frozen=True)
class WedgePrediction:
    """Closed-form facts about a completely rough wedge orbit, from its initial state alone
    (:func:`wedge_prediction`): ``first_wall`` hit, ``invariant`` s·n, ``supremum`` of the distance from the shrunk
    vertex (inf: the orbit escapes), ``n_min`` the smallest normal speed on the velocity circles, ``period`` in
    collisions (None: the rotation 2γ is not a rational turn, or the orbit escapes), ``apex`` the shrunk vertex."""
    first_wall: int
    invariant: float
    supremum: float
    n_min: float
    period: int | None
    apex: np.ndarray


def wedge_prediction(position, velocity, angular_velocity, angle_deg, R, kappa):
    """From an initial state inside the shrunk wedge -> :class:`WedgePrediction` (None if no wall lies ahead).

    The first flight is a straight line to the nearer wall ahead; there s·n is fixed and the rough collision gives
    the first post-collision state, from which :func:`wedge_distance_supremum` follows the velocity circles."""
    apex, normals = wedge_frame(angle_deg, R)
    p, v = np.asarray(position, float), np.asarray(velocity, float)
    times = []
    for nu in normals:
        vn = _dot(v, nu)
        times.append(_dot(p - apex, nu) / -vn if vn < 0 else math.inf)
    wall = int(np.argmin(times))
    if not math.isfinite(times[wall]):
        return None
    hit = p + times[wall] * v
    invariant = _norm(hit - apex) * -_dot(v, normals[wall])
    V = rough_collision(np.concatenate([[R * math.sqrt(kappa) * angular_velocity], v]), normals[wall], kappa)
    sup, n_min = wedge_distance_supremum(V[1:], V[0] / (R * math.sqrt(kappa)), wall, invariant, angle_deg, R, kappa)
    period = wedge_period(angle_deg, kappa) if math.isfinite(sup) else None
    return WedgePrediction(wall, invariant, sup, n_min, period, apex)
