"""The table zoo (docs/reference.md §8): every kind and preset built from wall pieces, 2D and 3D, custom
boundaries, obstacles on an existing kind, periodic cells.

* the engine equals the pure-Python reference (tests/reference.py) collision by collision;
* the invariant catalog over 10⁵ collisions: never outside the free region, every collision on the wall it names,
  energy kept — with the free region and the distances to the walls computed here, from the wall pieces
  (``rbx.tables.walls``), independently of rbx.geometry and of the reference; grazing flights past discs and
  spheres, tangent joints, arc/segment corners and reflex joints built on purpose;
* Santaló's mean free path 4A/P (2D with spin) and 15π/8·V/S (3D) of the billiard measure, A, P, V, S in closed
  form (a custom boundary's by Green's theorem along its offset pieces);
* the return angles to a curved wall follow sin 2φ (KS);
* periodic tables record unfolded positions, and a Lorentz gas diffuses;
* bad tables are refused by the real CLI: exit 2, one line naming the key.
"""
import copy
import math
import os
import subprocess
import sys

import numpy as np
import pytest
import yaml
from matplotlib.path import Path

import rbx
from rbx import tables
from rbx.rng import PURPOSE_RULES, uniforms
from rbx.simulation import Simulation

from catalog import CUSTOM_BOUNDARY, ZOO, zoo
from reference import reference_run

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RBX_EXE = os.path.join(os.path.dirname(sys.executable), "rbx")
FIELDS = ("time", "position", "velocity", "angular_velocity", "orientation", "wall", "rank")
NAMES = sorted(ZOO)
TWO_D = [k for k in NAMES if len(ZOO[k]["initial"]["position"]) == 2]
THREE_D = [k for k in NAMES if k not in TWO_D]


def table_of(c):
    t = dict(c["table"])
    return t.pop("kind"), t


def energy(v, w, R, kappa):
    """½(|v|² + κR²|ω|²) per record (ω a scalar in 2D, a vector in 3D)."""
    w = np.asarray(w, float)
    w2 = w * w if w.ndim == 1 else np.sum(w * w, axis=-1)
    return 0.5 * (np.sum(np.asarray(v, float) ** 2, axis=-1) + kappa * R * R * w2)


# ---- the free region, computed here from the wall pieces ---------------------------------------------------------


def _segment_distance(p, a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    ab = b - a
    s = np.clip((p - a) @ ab / (ab @ ab), 0.0, 1.0)
    return np.linalg.norm(p - a - s[:, None] * ab, axis=1)


def _arc_frame(piece):
    """A boundary arc -> (centre, radius, first angle, ccw span): a cw arc is the ccw arc from its end."""
    c = np.asarray(piece.center, float)
    s, e = np.asarray(piece.start, float) - c, np.asarray(piece.end, float) - c
    a_s, a_e = math.atan2(s[1], s[0]), math.atan2(e[1], e[0])
    if piece.turn == "ccw":
        return c, float(np.linalg.norm(s)), a_s, (a_e - a_s) % (2 * math.pi)
    return c, float(np.linalg.norm(s)), a_e, (a_s - a_e) % (2 * math.pi)


def _arc_distance(p, piece):
    c, rho, first, span = _arc_frame(piece)
    rel = p - c
    on = np.mod(np.arctan2(rel[:, 1], rel[:, 0]) - first, 2 * math.pi) <= span
    ends = np.minimum(np.linalg.norm(p - np.asarray(piece.start, float), axis=1),
                      np.linalg.norm(p - np.asarray(piece.end, float), axis=1))
    return np.where(on, np.abs(np.linalg.norm(rel, axis=1) - rho), ends)


def _arc_points(piece, k=400):
    c, rho, first, span = _arc_frame(piece)
    th = first + span * np.linspace(0, 1, k)
    pts = c + rho * np.c_[np.cos(th), np.sin(th)]
    return pts if piece.turn == "ccw" else pts[::-1]


class FreeRegion:
    """The table seen by the ball's centre, from the wall pieces: ``clearance(points)`` (distance to the nearest
    wall minus R, negative outside the table or inside an obstacle grown by R; periodic tables take unfolded
    positions) and ``wall_distance(w, points)`` (the distance of centres to wall w's piece: R at a contact)."""

    def __init__(self, c):
        kind, params = table_of(c)
        self.R = float(c["ball"]["radius"])
        self.n = tables.dimension(kind, params)
        self.size = float(tables.kind(kind).scale(params))
        self.kappa = {"uniform": 2.0 / (self.n + 2)}[c["ball"].get("inertia", "uniform")]
        self.dist = []          # wall -> unsigned distance of points to its piece
        self.signed = []        # signed distances (≥ 0 inside the table) whose minimum bounds the table
        self.outline = None     # a 2D outer boundary as a fine polyline: inside test
        self.outer = 0          # its walls are the first ``outer`` ones
        self.period = None
        for piece in tables.walls(kind, params):
            if isinstance(piece, tables.Lattice):
                self.lo = np.asarray(piece.lo, float)
                self.period = np.asarray(piece.hi, float) - self.lo
            elif isinstance(piece, tables.Polygon):
                V = np.asarray(piece.vertices, float)
                for i in range(len(V)):
                    self.dist.append(lambda p, a=V[i], b=V[(i + 1) % len(V)]: _segment_distance(p, a, b))
                self.outline = V
                self.outer = len(self.dist)
            elif isinstance(piece, tables.Boundary):
                pts = []
                for q in piece.pieces:
                    if isinstance(q, tables.Segment):
                        self.dist.append(lambda p, q=q: _segment_distance(p, q.start, q.end))
                        pts.append(np.array([q.start], float))
                    else:
                        self.dist.append(lambda p, q=q: _arc_distance(p, q))
                        pts.append(_arc_points(q)[:-1])
                self.outline = np.vstack(pts)
                self.outer = len(self.dist)
            elif isinstance(piece, tables.Circle):
                cc, rho = np.asarray(piece.center, float), float(piece.radius)
                self.dist.append(lambda p, cc=cc, rho=rho: np.abs(np.linalg.norm(p - cc, axis=1) - rho))
                th = np.linspace(0, 2 * math.pi, 800, endpoint=False)
                self.outline = cc + rho * np.c_[np.cos(th), np.sin(th)]
                self.outer = len(self.dist)
            elif isinstance(piece, tables.Plane):
                pt, nu = np.asarray(piece.point, float), np.asarray(piece.normal, float)
                self.signed.append(lambda p, pt=pt, nu=nu: (p - pt) @ nu)
                self.dist.append(lambda p, pt=pt, nu=nu: np.abs((p - pt) @ nu))
            elif isinstance(piece, tables.Cylinder):
                cc, rho = np.asarray(piece.center, float), float(piece.radius)
                self.signed.append(lambda p, cc=cc, rho=rho: rho - np.linalg.norm(p[:, :2] - cc, axis=1))
                self.dist.append(lambda p, cc=cc, rho=rho: np.abs(rho - np.linalg.norm(p[:, :2] - cc, axis=1)))
            elif isinstance(piece, tables.Sphere):
                cc, rho = np.asarray(piece.center, float), float(piece.radius)
                if piece.inside:
                    self.signed.append(lambda p, cc=cc, rho=rho: rho - np.linalg.norm(p - cc, axis=1))
                    self.dist.append(lambda p, cc=cc, rho=rho: np.abs(rho - np.linalg.norm(p - cc, axis=1)))
                else:       # an obstacle: its nearest periodic image (if any)
                    f = (lambda p, cc=cc, rho=rho: np.linalg.norm(self._near(p - cc), axis=1) - rho)
                    self.signed.append(f)
                    self.dist.append(lambda p, f=f: np.abs(f(p)))
            else:
                raise TypeError(piece)
        self.path = None if self.outline is None else Path(np.vstack([self.outline, self.outline[:1]]),
                                                           closed=True)

    def _near(self, rel):
        """Offsets to the nearest periodic image (unchanged without a lattice)."""
        if self.period is None:
            return rel
        return rel - self.period * np.round(rel / self.period)

    def clearance(self, points):
        p = np.asarray(points, float).reshape(-1, self.n)
        out = np.full(len(p), np.inf)
        if self.path is not None:   # 2D outer boundary: distance to its walls, negative outside it
            d = np.min([f(p) for f in self.dist[:self.outer]], axis=0)
            out = np.where(self.path.contains_points(p), d, -d)
        for f in self.signed:
            out = np.minimum(out, f(p))
        return out - self.R

    def wall_distance(self, wall, points):
        return self.dist[wall](np.asarray(points, float).reshape(-1, self.n))


def test_free_region_helper_can_fail():
    """The helper's distances are right on known points (so the invariant tests below can fail)."""
    fr = FreeRegion(zoo("stadium"))
    pts = np.array([[0.5, 0.0], [0.5, -0.4], [0.5, -0.45], [1.4, 0.0], [-0.4, 0.0], [1.5, 0.0]])
    np.testing.assert_allclose(fr.clearance(pts), [0.4, 0.0, -0.05, 0.0, 0.0, -0.1], atol=1e-12)
    np.testing.assert_allclose(fr.wall_distance(1, pts[3:4]), [0.1], atol=1e-15)     # on the shrunk right cap
    fr = FreeRegion(zoo("lorentz-2d"))
    np.testing.assert_allclose(fr.clearance(np.array([[0.5, 0.9], [10.5, -3.3], [3.0, 3.0]])),
                               [0.0, -0.2, math.sqrt(0.5) - 0.4], atol=1e-12)
    fr = FreeRegion(zoo("custom"))
    # the reflex joint at (3, 2): a point R from the joint, in its fan (between the normals of the cap, (0, −1),
    # and of the slope), is on the free region's edge
    e = np.array([-0.6, 0.4]) / math.hypot(0.6, 0.4)
    b = np.array([0.0, -1.0]) + np.array([-e[1], e[0]])
    q = np.array([3.0, 2.0]) + 0.1 * b / np.linalg.norm(b)
    q = q[None]
    assert abs(fr.clearance(q)[0]) < 1e-12 and abs(fr.wall_distance(2, q)[0] - 0.1) < 1e-12
    fr = FreeRegion(zoo("cylinder"))
    np.testing.assert_allclose(fr.clearance(np.array([[0.9, 0.0, 0.75], [0.0, 0.0, 0.1], [0.0, 0.0, 1.5]])),
                               [0.0, 0.0, -0.1], atol=1e-12)


# ---- the engine equals the reference, collision by collision -------------------------------------------------------

COMPARED = 150


def _engine(c):
    run = rbx.simulate(c)
    return run, int(run.count[0])


@pytest.mark.parametrize("rules", ["rough", "smooth", "random"])
@pytest.mark.parametrize("name", NAMES)
def test_engine_matches_reference(name, rules):
    """Each of the engine's first 150 collisions equals the reference's collision from the engine's state before it
    (the zoo is chaotic: whole orbits part at rounding level after ~10–30 collisions, which the first records
    also show). Random rules: both take the engine's own draws, in order."""
    c = zoo(name, rules, collisions=COMPARED, record=FIELDS)
    run, T = _engine(c)
    assert T == COMPARED + 1
    fr = FreeRegion(c)
    size = fr.size
    draws = iter(uniforms(c["run"]["seed"], 0, PURPOSE_RULES, 0, 10 * COMPARED))
    worst = 0.0
    for i in range(1, T):
        start = {f: getattr(run, f)[0, i - 1] for f in FIELDS}
        ref = reference_run(c, uniforms=draws, start=start, collisions=1)
        assert len(ref) == 2, f"{name}: the reference finds no wall after record {i - 1}"
        r = ref[1]
        assert r["wall"] == run.wall[0, i] and r["rank"] == run.rank[0, i], (name, i, r["wall"], run.wall[0, i])
        for f in FIELDS[:5]:
            got = np.asarray(getattr(run, f)[0, i], float)
            want = np.asarray(r[f], float).reshape(got.shape)
            scale = max(size, float(np.max(np.abs(want)))) if f in ("time", "position") else \
                max(1.0, float(np.max(np.abs(want))))
            dev = float(np.max(np.abs(got - want))) / scale
            worst = max(worst, dev)
            assert dev <= 1e-10, f"{name}/{rules}: record {i}, {f}: {got} vs {want}"
    # the whole orbits agree too until rounding differences grow (every zoo orbit: at least the first 6 records;
    # the 3D Lorentz gas parts at 1e-10 after 7)
    whole = reference_run(c, uniforms=iter(uniforms(c["run"]["seed"], 0, PURPOSE_RULES, 0, 10 * COMPARED)),
                          collisions=6)
    for i, r in enumerate(whole):
        scale = max(size, float(np.max(np.abs(r["position"]))))
        np.testing.assert_allclose(run.position[0, i], r["position"], rtol=0, atol=1e-10 * scale)
        assert run.wall[0, i] == r["wall"]
    print(f"{name}/{rules}: worst relative deviation over {COMPARED} collisions {worst:.2e}")


# ---- the invariant catalog over 10⁵ collisions ---------------------------------------------------------------------

N = 100_000
INVARIANT_FIELDS = ("time", "position", "velocity", "angular_velocity", "wall")
#: the same and the orientation: for the tests below, whose 3D loops (which follow the orientation when it is
#: recorded) are then those other tests compile too
INVARIANT_FIELDS_ORIENTED = INVARIANT_FIELDS + ("orientation",)


def check_invariants(c, run, label, must_run=True, flights=True):
    """Never outside the free region, every contact on the wall it names, energy kept, straight flights."""
    fr = FreeRegion(c)
    size, R = fr.size, fr.R
    M = run.count.shape[0]
    for j in range(M):
        T = int(run.count[j])
        if must_run:
            assert T == c["run"]["collisions"] + 1, f"{label}[{j}]: ended after {T - 1} collisions"
        pos, vel, wall = run.position[j, :T], run.velocity[j, :T], run.wall[j, :T]
        worst = fr.clearance(pos).min()
        assert worst >= -1e-12 * size, f"{label}[{j}]: {worst / size:.3g} of the size outside the free region"
        if flights and T > 1:       # the flights between contacts stay inside too (sampled)
            s = np.array([0.25, 0.5, 0.75])
            mids = pos[:-1, None, :] + s[None, :, None] * (pos[1:] - pos[:-1])[:, None, :]
            worst = fr.clearance(mids.reshape(-1, fr.n)).min()
            assert worst >= -1e-12 * size, f"{label}[{j}]: a flight crosses a wall ({worst / size:.3g})"
        assert wall[0] == -1 and np.all(wall[1:] >= 0)
        for w in np.unique(wall[1:]):
            sel = np.nonzero(wall == w)[0]
            gap = np.abs(fr.wall_distance(int(w), pos[sel]) - R).max()
            assert gap <= 1e-12 * size, f"{label}[{j}]: a contact {gap / size:.3g} off wall {w}"
        e = energy(vel, run.angular_velocity[j, :T], R, fr.kappa)
        assert np.max(np.abs(e - e[0])) <= 1e-12 * e[0], f"{label}[{j}]: energy drift"
        dt = np.diff(run.time[j, :T])
        assert np.all(dt >= 0)
        # straight flights, positions unfolded: the displacement is the velocity times the flight time. The
        # recorded times carry an absolute rounding error of ~eps·t per addition; in a periodic table a long flight
        # is flown in steps of at most half a cell (each one an addition to the time and the position)
        steps = 1.0
        if fr.period is not None:
            steps += np.linalg.norm(pos[1:] - pos[:-1], axis=1)[:, None] / (0.5 * fr.period.min())
        slack = 1e-12 * size + 4e-16 * steps * (float(run.time[j, T - 1]) * float(np.abs(vel).max())
                                                + float(np.abs(pos).max()))
        assert np.all(np.abs(pos[1:] - pos[:-1] - vel[:-1] * dt[:, None]) <= slack), f"{label}[{j}]: a jump"


@pytest.mark.slow
@pytest.mark.parametrize("name", NAMES)
def test_invariants_over_1e5_collisions(name):
    c = zoo(name, "rough", collisions=N, record=INVARIANT_FIELDS)
    run = rbx.simulate(c)
    check_invariants(c, run, name)
    # every wall of the table is met
    walls = set(np.unique(run.wall[0, 1:]).tolist())
    kind, params = table_of(c)
    assert walls == set(range(len(tables.wall_names(tables.walls(kind, params))))), (name, walls)


@pytest.mark.slow
def test_invariants_with_random_and_smooth_rules():
    for name in ("mushroom", "custom", "sinai-3d", "periodic-rectangle"):
        for rules in ("smooth", "random"):
            c = zoo(name, rules, collisions=20_000, record=INVARIANT_FIELDS_ORIENTED)
            check_invariants(c, rbx.simulate(c), f"{name}/{rules}")


# ---- grazing flights, tangent joints, corners, built on purpose ---------------------------------------------------


def _rot(u, angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([c * u[0] - s * u[1], s * u[0] + c * u[1]])


def tangent_directions(p, centre, radius, factors=(1.0, 1 + 1e-15, 1 - 1e-15, 1 + 1e-9, 1 - 1e-9)):
    """Unit directions from p whose lines pass the circle (centre, radius·f) tangentially, both sides."""
    rel = np.asarray(centre, float) - np.asarray(p, float)
    d = float(np.linalg.norm(rel))
    out = []
    for f in factors:
        beta = math.asin(min(1.0, radius * f / d))
        out += [_rot(rel / d, beta), _rot(rel / d, -beta)]
    return out


def aim(p, target, jitter=(0.0, 1e-15, -1e-15, 1e-10, -1e-10)):
    """Unit directions from p to target, and turned by a few tiny angles."""
    rel = np.asarray(target, float) - np.asarray(p, float)
    return [_rot(rel / np.linalg.norm(rel), j) for j in jitter]


def states(p, directions, spin):
    return [{"position": [float(x) for x in p], "velocity": [float(x) for x in d],
             "angular_velocity": spin} for d in directions]


def grazing_2d():
    R = 0.1
    out = {}
    # past the Sinai scatterer (grown radius 0.5 about (1, 0.75)) and along it
    s = states([0.2, 0.2], tangent_directions([0.2, 0.2], [1.0, 0.75], 0.5), 0.0)
    for phi in (0.3, 2.0, -1.2):
        u = np.array([math.cos(phi), math.sin(phi)])
        q = np.array([1.0, 0.75]) + 0.5 * u
        for tilt in (0.0, 1e-16, -1e-16, 1e-12):
            s += states(q, [_rot(np.array([-u[1], u[0]]), tilt)], 1.0)
    out["sinai-2d"] = s
    # past an image of the Lorentz scatterer several cells away (cell (3, 2)), and one next door
    # (not along a corridor: a line tangent to a whole row of discs never meets one, see test_corridor_flight_ends)
    s = states([0.05, 0.1], tangent_directions([0.05, 0.1], [3.5, 2.5], 0.4), 0.5)
    s += states([0.05, 0.1], tangent_directions([0.05, 0.1], [2.5, -1.5], 0.4), -0.5)
    out["lorentz-2d"] = s
    # the stadium's tangent joints: at the joint points of the shrunk wall, along the flat shrunk wall into them
    s = []
    for joint in ([1.0, -0.4], [1.0, 0.4], [0.0, 0.4], [0.0, -0.4]):
        s += states([0.3, 0.1], aim([0.3, 0.1], joint), 1.0)
    for tilt in (1e-15, -1e-15, 1e-9):          # exactly along the wall: test_flight_along_a_flat_wall_...
        s += states([0.5, -0.4], [[math.cos(tilt), math.sin(tilt)]], 0.7)
        s += states([0.5, 0.4], [[-math.cos(tilt), math.sin(tilt)]], -0.7)
    out["stadium"] = s
    # the mushroom: the convex corner between the cap's floor and the cap, the reflex joints (stem → floor) passed
    # tangentially, and straight up along the stem's shrunk wall past a reflex joint's arc
    corner = [math.sqrt(0.9 ** 2 - R ** 2), R]
    s = states([0.0, -0.5], aim([0.0, -0.5], corner), 1.0) + states([0.5, 0.5], aim([0.5, 0.5], corner), -1.0)
    s += states([0.1, -0.5], tangent_directions([0.1, -0.5], [0.3, 0.0], R, (1.0, 1 + 1e-12, 1 - 1e-12)), 0.0)
    for dx in (0.0, 1e-16, -1e-16):
        s += states([0.2 + dx, -0.8], [[0.0, 1.0]], 0.5)
    out["mushroom"] = s
    # the custom table: its convex corners between the roof and the dent (the offsets cross there), the reflex
    # joint at (3, 2) passed tangentially, the tangent joint floor → cap
    x = math.sqrt(0.6 ** 2 - 0.4 ** 2)
    s = []
    for corner in ([1.4 + x, 2.3], [1.4 - x, 2.3], [3.0, 0.1]):
        s += states([0.5, 0.5], aim([0.5, 0.5], corner), 1.0)
    s += states([1.5, 0.5], tangent_directions([1.5, 0.5], [3.0, 2.0], R, (1.0, 1 + 1e-12, 1 - 1e-12)), 0.3)
    out["custom"] = s
    return out


GRAZING_2D = grazing_2d()


def _tangent_3d(p, centre, radius, normal_hint):
    """Unit directions from p tangent to the sphere (centre, radius·f) in the plane through p, centre and
    normal_hint."""
    p, centre = np.asarray(p, float), np.asarray(centre, float)
    rel = centre - p
    d = float(np.linalg.norm(rel))
    e1 = rel / d
    e2 = np.cross(np.cross(e1, normal_hint), e1)
    e2 /= np.linalg.norm(e2)
    out = []
    for f in (1.0, 1 + 1e-15, 1 - 1e-15, 1 + 1e-9, 1 - 1e-9):
        beta = math.asin(radius * f / d)
        out += [math.cos(beta) * e1 + math.sin(beta) * e2, math.cos(beta) * e1 - math.sin(beta) * e2]
    return out


def grazing_3d():
    R = 0.1
    out = {}
    spin = [0.3, -0.2, 0.5]
    p = [0.2, 0.2, 0.2]
    out["sinai-3d"] = states(p, _tangent_3d(p, [1.0, 0.75, 0.6], 0.4, [0, 0, 1]) +
                             _tangent_3d(p, [1.0, 0.75, 0.6], 0.4, [1, -1, 0]), spin)
    p = [0.05, 0.1, 0.1]
    out["lorentz-3d"] = states(p, _tangent_3d(p, [2.5, 1.5, 1.5], 0.4, [0, 0, 1]), spin)
    # whispering-gallery flights just inside the sphere, and a start on it moving along it
    s = []
    for tilt in (0.0, 1e-12, 1e-8, 1e-4):
        s += states([0.9, 0.0, 0.0], [[-tilt, math.sqrt(1 - tilt * tilt) * 0.8, math.sqrt(1 - tilt * tilt) * 0.6]],
                    spin)
    out["sphere"] = s
    # the cylinder's edges (side meets cap) from inside, and flights along the shrunk cap
    s = []
    for phi in (0.0, 1.0, 2.5):
        edge = [0.9 * math.cos(phi), 0.9 * math.sin(phi), 0.1]
        rel = np.subtract(edge, [0.0, 0.0, 0.75])
        s += states([0.0, 0.0, 0.75], [rel / np.linalg.norm(rel)], spin)
    for dz in (0.0, 1e-16, -1e-16):
        s += states([0.0, 0.0, 0.1 + dz], [[0.6, 0.8, 0.0]], spin)
    out["cylinder"] = s
    return out


GRAZING_3D = grazing_3d()
GRAZING = {**GRAZING_2D, **GRAZING_3D}


GRAZING_CASES = [(name, rules) for rules in ("rough", "smooth") for name in sorted(GRAZING)]


@pytest.mark.parametrize("name,rules", GRAZING_CASES)
def test_grazing_flights_and_corners(name, rules):
    c = zoo(name, rules, collisions=2000, record=INVARIANT_FIELDS_ORIENTED)
    c["initial"] = GRAZING[name]
    c["run"]["trajectories"] = len(GRAZING[name])
    run = rbx.simulate(c)
    check_invariants(c, run, f"{name}/{rules}")


def test_flight_along_a_flat_wall_into_a_tangent_joint():
    """A flight exactly along the stadium's shrunk flat wall reaches the tangent joint with a cap, where the line
    touches the cap's shrunk circle: past that point it would leave the table, so it is a contact (v·ν = 0, then
    repeated at flight time 0 while the velocity stays tangent, as on a circle's rim; conventions, Grazing)."""
    c = zoo("stadium", "rough", collisions=200, record=FIELDS)
    c["initial"] = states([0.5, -0.4], [[1.0, 0.0]], 0.7) + states([0.5, 0.4], [[-1.0, 0.0]], -0.7)
    c["run"]["trajectories"] = 2
    ref = [reference_run(c, start={**s, "time": 0.0, "orientation": 0.3}, collisions=5) for s in c["initial"]]
    assert [r[1]["wall"] for r in ref] == [1, 3] and all(len(r) == 6 for r in ref)
    np.testing.assert_allclose([r[1]["position"] for r in ref], [[1.0, -0.4], [0.0, 0.4]], rtol=0, atol=1e-15)
    run = rbx.simulate(c)
    assert list(run.count) == [201, 201], "the flight along the wall left the table"
    assert list(run.wall[:, 1]) == [1, 3]
    check_invariants(c, run, "stadium along a wall")


def test_corridor_flight_ends(tmp_path):
    """A flight along a corridor of a Lorentz gas (a line between two rows of grown discs, or tangent to one) meets
    nothing, ever: it must end like any flight with no wall ahead (an escape), not fly on for ever. The reference
    does so after LATTICE_MAX_WINDOWS cells; the engine is run in a subprocess so that a hang fails the test."""
    import reference
    c = zoo("lorentz-2d", "rough", collisions=10)
    for y in (0.05, -0.0999):
        c["initial"] = {"position": [0.05, y], "velocity": [1.0, 0.0], "angular_velocity": 0.0}
        assert len(reference_run(c)) == 1
        assert reference.LATTICE_MAX_WINDOWS * 1.0 < 1e5
    c["initial"] = [{"position": [0.05, 0.05], "velocity": [1.0, 0.0]},
                    {"position": [0.05, -0.0999], "velocity": [1.0, 0.0]},
                    {"position": [0.05, 0.05], "velocity": [1.0, -1e-15]}]
    c["run"]["trajectories"] = 3
    path = tmp_path / "corridor.yaml"
    path.write_text(yaml.safe_dump(c))
    try:
        res = subprocess.run([RBX_EXE, "simulate", str(path), "-o", str(tmp_path / "out.h5"), "--quiet"],
                             capture_output=True, text=True, timeout=90)
    except subprocess.TimeoutExpired:
        pytest.fail("a corridor flight did not end within 90 s")
    assert res.returncode == 0, res.stderr
    run = rbx.open(tmp_path / "out.h5")
    assert list(run.count) == [1, 1, 1]
    # not silently: the one warning line says what happened (also with --quiet)
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("rbx: warning: ") and "3 trajectories" in lines[0] \
        and "corridor" in lines[0], res.stderr


def test_long_flights_in_a_sparse_gas_are_followed_to_their_scatterer():
    """Scatterers of radius 0.001 (R = 0.001) in the unit cell: free flights of more than 10⁴ cells are common.
    The walk used to give up after 10⁴ cells and end the trajectory as an escape (3 of 4 trajectories cut short,
    the run reported complete); now each flight is followed to the scatterer it meets: every trajectory makes all
    its collisions, and the end of the longest flight lies on a grown scatterer (|x − c| = ρ)."""
    c = zoo("lorentz-2d", "smooth", collisions=20_000, record=["time", "position", "velocity", "wall"])
    c["table"]["radius"] = 0.001
    c["ball"]["radius"] = 0.001
    c["initial"] = {"sample": "billiard"}
    c["run"].update(trajectories=4, seed=3)
    run = rbx.simulate(c)
    assert list(run.count) == [20_001] * 4
    flights = np.linalg.norm(np.diff(run.position, axis=1), axis=2)
    j, k = np.unravel_index(np.argmax(flights), flights.shape)
    assert flights[j, k] > 1e4
    end = run.position[j, k + 1]
    folded = end - np.floor(end)                              # unit cell, scatterer at its centre
    assert abs(np.linalg.norm(folded - 0.5) - 0.002) < 1e-9
    np.testing.assert_array_equal(run.velocity[j, k + 1] != run.velocity[j, k], [True, True])


def test_the_cell_walk_ends_on_numbers_that_overflowed():
    """A flight of NaN, or along a corridor of cells of 1e307 (its length overflows to inf), ends after
    MAX_PERIODIC_FLIGHT cells' lengths as an escape: the bound is finite (a length compared with an infinite
    bound never ended). (An infinite velocity never reaches the kernel: the config bounds speeds, and the map
    keeps the energy.)"""
    from rbx import engine
    from rbx.geometry import periodic_flight
    geom = Simulation(rbx.load(zoo("lorentz-2d"))).geom
    t = engine.make_table(geom, 1e-12)
    scratch = [np.zeros(2) for _ in range(4)]
    for a, v, period in (([0.1, 0.1], [np.nan, 1.0], t.period), ([0.1, 0.1], [1.0, np.nan], t.period),
                         ([0.1, 0.1], [1.0, 0.0], np.array([1e307, 1e307]))):   # a corridor whose length overflows
        tau, k = periodic_flight(t.codes, t.params, np.array(a), np.array(v), 1e-12, 2, t.lattice_lo,
                                 np.asarray(period, float), t.images, t.image_shift, *scratch)
        assert k == -1 and tau == np.inf, (a, v, period, tau, k)


# ---- Santaló: the mean free path of the billiard measure -----------------------------------------------------------


def shrunk_area_perimeter(pieces, R):
    """Area and perimeter of the points at distance ≥ R from a closed counter-clockwise boundary of segments and
    arcs (rbx.tables pieces), by Green's theorem along the boundary of that region: each piece's offset by R
    towards the table (a focusing arc's circle shrunk, a dispersing arc's grown), cut where the offsets of the two
    pieces of a convex joint cross (the crossing nearest the joint), and an arc of radius R about each reflex
    joint, from the arriving piece's normal to the leaving piece's, clockwise. (For tables whose offsets meet only
    their neighbours', as the ones here.)"""
    curves = []
    for q in pieces:
        S, E = np.asarray(q.start, float), np.asarray(q.end, float)
        if isinstance(q, tables.Segment):
            L = float(np.linalg.norm(E - S))
            e = (E - S) / L
            nrm = np.array([-e[1], e[0]])
            curves.append({"line": True, "p": S + R * nrm, "e": e, "lo": 0.0, "hi": L, "t0": e, "t1": e,
                           "n0": nrm, "n1": nrm, "joint": S})
        else:
            c = np.asarray(q.center, float)
            rho = float(np.linalg.norm(S - c))
            sense = 1.0 if q.turn == "ccw" else -1.0
            a0 = math.atan2(*(S - c)[::-1])
            span = ((math.atan2(*(E - c)[::-1]) - a0) * sense) % (2 * math.pi)
            u0 = np.array([math.cos(a0), math.sin(a0)])
            u1 = np.array([math.cos(a0 + sense * span), math.sin(a0 + sense * span)])
            curves.append({"line": False, "c": c, "rho": rho - sense * R, "sense": sense, "a0": a0, "lo": 0.0,
                           "hi": span, "t0": sense * np.array([-u0[1], u0[0]]),
                           "t1": sense * np.array([-u1[1], u1[0]]), "n0": -sense * u0, "n1": -sense * u1,
                           "joint": S})

    def point(cv, s):
        if cv["line"]:
            return cv["p"] + s * cv["e"]
        th = cv["a0"] + cv["sense"] * s
        return cv["c"] + cv["rho"] * np.array([math.cos(th), math.sin(th)])

    def param(cv, x):
        if cv["line"]:
            return float((x - cv["p"]) @ cv["e"])
        th = math.atan2(*(x - cv["c"])[::-1])
        s = ((th - cv["a0"]) * cv["sense"]) % (2 * math.pi)
        return s - 2 * math.pi if s > math.pi + cv["hi"] / 2 else s

    def crossings(a, b):
        if a["line"] and b["line"]:
            M = np.array([a["e"], -b["e"]]).T
            s = np.linalg.solve(M, b["p"] - a["p"])
            return [a["p"] + s[0] * a["e"]]
        line, circ = (a, b) if a["line"] else (b, a)
        if circ["line"]:
            raise NotImplementedError
        if not line["line"]:
            raise NotImplementedError("two arcs meeting at a convex joint")
        d = line["p"] - circ["c"]
        B, C = float(d @ line["e"]), float(d @ d) - circ["rho"] ** 2
        root = math.sqrt(B * B - C)
        return [line["p"] + s * line["e"] for s in (-B - root, -B + root)]

    extra = []
    for i, cur in enumerate(curves):
        prev = curves[i - 1]
        cross = prev["t1"][0] * cur["t0"][1] - prev["t1"][1] * cur["t0"][0]
        J = cur["joint"]
        if cross < -1e-12:          # reflex: an arc of radius R about the joint, clockwise
            b0 = math.atan2(prev["n1"][1], prev["n1"][0])
            sweep = (b0 - math.atan2(cur["n0"][1], cur["n0"][0])) % (2 * math.pi)
            extra.append((J, R, b0, -sweep))
        elif cross > 1e-12:         # convex: cut both offsets where they cross, nearest the joint
            x = min(crossings(prev, cur), key=lambda y: float(np.linalg.norm(y - J)))
            prev["hi"] = param(prev, x)
            cur["lo"] = param(cur, x)
    area, perimeter = 0.0, 0.0

    def arc_green(c, rho, th0, dth):
        th1 = th0 + dth
        return 0.5 * (rho * rho * dth + rho * c[0] * (math.sin(th1) - math.sin(th0))
                      - rho * c[1] * (math.cos(th1) - math.cos(th0)))
    for cv in curves:
        if cv["line"]:
            p0, p1 = point(cv, cv["lo"]), point(cv, cv["hi"])
            area += 0.5 * (p0[0] * p1[1] - p1[0] * p0[1])
            perimeter += cv["hi"] - cv["lo"]
        else:
            th0, dth = cv["a0"] + cv["sense"] * cv["lo"], cv["sense"] * (cv["hi"] - cv["lo"])
            area += arc_green(cv["c"], cv["rho"], th0, dth)
            perimeter += cv["rho"] * (cv["hi"] - cv["lo"])
    for c, rho, th0, dth in extra:
        area += arc_green(c, rho, th0, dth)
        perimeter += rho * abs(dth)
    return area, perimeter


def test_green_area_on_known_shapes():
    """The Green's-theorem area and perimeter against closed forms: a stadium (tangent joints), a rectangle with
    a notch (a reflex corner: a quarter arc of radius R), a half disc (convex segment/arc corners)."""
    R = 0.1
    st = tables.walls("stadium", {"radius": 0.5, "length": 1.0})[0].pieces
    A, P = shrunk_area_perimeter(st, R)
    assert A == pytest.approx(2 * 0.4 * 1.0 + math.pi * 0.16, rel=1e-13)
    assert P == pytest.approx(2.0 + 2 * math.pi * 0.4, rel=1e-13)
    corners = [[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]]
    L = tables.boundary_pieces([{"name": f"e{i}", "from": corners[i], "to": corners[(i + 1) % 6]} for i in range(6)])
    A, P = shrunk_area_perimeter(L, R)
    # the L's shrunk region: the rectangles [0.1, 1.9] × [0.1, 0.9] and [0.1, 0.9] × [0.9, 1.9], and at the reflex
    # corner (1, 1) the square [0.9, 1]² less a quarter disc of radius R; its edges 1.8, 0.8, 0.9, 0.9, 0.8, 1.8 and
    # the quarter circle
    assert A == pytest.approx(1.8 * 0.8 + 0.8 * 1.0 + R * R * (1 - math.pi / 4), rel=1e-13)
    assert P == pytest.approx(1.8 + 0.8 + 0.9 + 0.9 + 0.8 + 1.8 + math.pi * R / 2, rel=1e-13)
    half = tables.boundary_pieces([{"name": "a", "from": [-1, 0], "to": [1, 0]},
                                   {"name": "b", "from": [1, 0], "to": [-1, 0], "center": [0, 0], "turn": "ccw"}])
    A, P = shrunk_area_perimeter(half, R)
    # the half disc of radius 0.9 above y = 0.1: segment area formula
    r, h = 0.9, R
    seg = r * r * math.acos(h / r) - h * math.sqrt(r * r - h * h)
    assert A == pytest.approx(seg, rel=1e-13)
    assert P == pytest.approx(2 * math.sqrt(r * r - h * h) + 2 * r * math.acos(h / r), rel=1e-13)


@pytest.mark.parametrize("start", range(4))
def test_the_signed_area_of_a_boundary_with_arcs_is_its_area_from_any_first_piece(start):
    """boundary_area (the counter-clockwise check) against closed forms: a 2 × 2 square whose top is a dispersing
    arc about (1, 3) (radius √2: the square less a circular segment of angle π/2), and one whose top is a cap about
    (1, 1.5) bulging out. The arc's centre term had the wrong sign: the dented square came out −2.57 (refused as
    clockwise) when listed from its floor and +3.43 from its dent; the capped one 1.88 instead of 4.88."""
    from rbx.pieces import Arc, Segment, boundary_area
    rho = math.sqrt(2.0)
    dent = [Segment("a", (0., 0.), (2., 0.)), Segment("b", (2., 0.), (2., 2.)),
            Arc("c", (2., 2.), (0., 2.), (1., 3.), "cw"), Segment("d", (0., 2.), (0., 0.))]
    segment = 0.5 * rho * rho * (math.pi / 2 - 1.0)          # the circular segment the dent cuts off
    cap_rho = math.hypot(1.0, 0.5)
    angle = 2 * math.pi - 2 * math.atan2(1.0, -0.5)          # the cap's arc above the chord y = 2
    cap = [Segment("a", (0., 0.), (2., 0.)), Segment("b", (2., 0.), (2., 2.)),
           Arc("c", (2., 2.), (0., 2.), (1., 1.5), "ccw"), Segment("d", (0., 2.), (0., 0.))]
    cap_area = 4.0 + 0.5 * cap_rho ** 2 * (angle - math.sin(angle))
    for pieces, area in ((dent, 4.0 - segment), (cap, cap_area)):
        listed = pieces[start:] + pieces[:start]
        assert boundary_area(listed) == pytest.approx(area, rel=1e-12), (start, area)


def santalo_value(name, c):
    """Closed-form mean free time of the billiard measure (unit speed in (v, R√κω)): 4A/P in 2D, 15π/8·V/S in 3D,
    A, P, V, S those of the free region (shrunk walls, grown obstacles, rounded reflex joints)."""
    R = c["ball"]["radius"]
    t = c["table"]
    if name == "stadium":
        r = t["radius"] - R
        A, P = 2 * r * t["length"] + math.pi * r * r, 2 * t["length"] + 2 * math.pi * r
    elif name == "sinai-2d":
        (w, h), g = t["size"], t["radius"] + R
        A, P = (w - 2 * R) * (h - 2 * R) - math.pi * g * g, 2 * (w - 2 * R) + 2 * (h - 2 * R) + 2 * math.pi * g
    elif name in ("lorentz-2d", "lorentz-centred"):
        (w, h), g = t["cell"], t["radius"] + R
        k = 2 if t.get("lattice") == "centred" else 1          # scatterers per cell
        A, P = w * h - k * math.pi * g * g, k * 2 * math.pi * g
    elif name in ("custom", "mushroom"):
        kind, params = table_of(c)
        A, P = shrunk_area_perimeter(tables.walls(kind, params)[0].pieces, R)
    elif name == "sinai-3d":
        a, b, h = (s - 2 * R for s in t["size"])
        g = t["radius"] + R
        V, S = a * b * h - 4 / 3 * math.pi * g ** 3, 2 * (a * b + b * h + a * h) + 4 * math.pi * g * g
    elif name == "lorentz-3d":
        g = t["radius"] + R
        V, S = float(np.prod(t["cell"])) - 4 / 3 * math.pi * g ** 3, 4 * math.pi * g * g
    elif name == "sphere":
        r = t["radius"] - R
        V, S = 4 / 3 * math.pi * r ** 3, 4 * math.pi * r * r
    elif name == "cylinder":
        r, h = t["radius"] - R, t["height"] - 2 * R
        V, S = math.pi * r * r * h, 2 * math.pi * r * r + 2 * math.pi * r * h
    else:
        raise KeyError(name)
    return 4 * A / P if tables.dimension(*table_of(c)) == 2 else 15 * math.pi / 8 * V / S


SANTALO = ["stadium", "sinai-2d", "lorentz-2d", "lorentz-centred", "custom", "mushroom", "sinai-3d", "lorentz-3d", "sphere",
           "cylinder"]


@pytest.mark.slow
@pytest.mark.parametrize("name", SANTALO)
def test_santalo_mean_free_path(name):
    M = 200_000
    c = zoo(name, "rough", collisions=1, record=["time"], trajectories=M)
    c["initial"] = {"sample": "billiard"}
    c["run"]["seed"] = 7
    run = rbx.simulate(c)
    assert np.all(run.count == 2)
    tau = run.time[:, 1] - run.time[:, 0]
    mean, err = float(tau.mean()), float(tau.std(ddof=1) / math.sqrt(M))
    want = santalo_value(name, c)
    print(f"{name}: mean free time {mean:.5f} ± {err:.5f}, Santaló {want:.5f} ({(mean - want) / err:+.2f} σ)")
    assert abs(mean - want) <= 4 * err, (name, mean, err, want)


# ---- the return angles to a curved wall ----------------------------------------------------------------------------


@pytest.mark.parametrize("name,wall", [("stadium", "right"), ("sinai-2d", "scatterer"), ("custom", "dent"),
                                       ("lorentz-2d", "scatterer"), ("lorentz-centred", "scatterer2")])
def test_return_angles_on_a_curved_wall_follow_sin_2phi(name, wall):
    from rbx.config import from_dict
    from rbx.histogram import return_experiment
    c = zoo(name, "rough", collisions=5000, record=[], trajectories=20_000)
    c["initial"] = {"sample": "billiard", "wall": wall}
    res = return_experiment(from_dict(c))
    print(f"{name}/{wall}: KS D = {res.ks_statistic:.4g}, p = {res.ks_pvalue:.3g}, not returned {res.not_returned}")
    assert res.d == 3 and res.not_returned <= 20
    assert res.ks_pvalue > 1e-3
    # a sampler off the billiard measure (spin scaled by 2) is caught
    assert return_experiment(from_dict(c), _spin_scale=2.0).ks_pvalue < 1e-10


# ---- periodic tables -----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["lorentz-2d", "lorentz-3d", "periodic-rectangle", "periodic-box"])
def test_periodic_positions_are_unfolded(name):
    c = zoo(name, "rough", collisions=20_000, record=INVARIANT_FIELDS)
    run = rbx.simulate(c)
    pos, vel, t = run.position[0], run.velocity[0], run.time[0]
    step = np.linalg.norm(np.diff(pos, axis=0), axis=1)
    flight = np.linalg.norm(vel[:-1], axis=1) * np.diff(t)
    np.testing.assert_allclose(step, flight, rtol=0, atol=1e-12 * (1 + t[-1]))
    # no jump by a cell: every step is a flight, and the orbit wanders over many cells
    cell = np.asarray(c["table"].get("cell") or c["table"].get("size") or [c["table"]["width"],
                                                                           c["table"]["height"]], float)
    assert np.ptp(pos, axis=0).max() > 5 * cell.max()


@pytest.mark.parametrize("name", ["lorentz-2d", "lorentz-centred", "periodic-rectangle"])
def test_collision_points_are_located_on_the_image_hit(name):
    """In a periodic table, analysis.locate takes each unfolded collision point back to the image of its wall
    (an obstacle may cross the cell's sides): the normal it gives is the one of the specular map, parallel to
    the velocity's change, and the point lies on the shrunk wall. It used to measure every point against the
    scatterer of cell 0: 195 of 200 normals were wrong, and the return angles failed their law (KS p = 0)."""
    from rbx import analysis
    c = zoo(name, "smooth", collisions=400, record=["position", "velocity", "wall"])
    run = rbx.simulate(c)
    geom = run.geometry()
    w, p, v = run.wall[0, 1:], run.position[0, 1:], run.velocity[0]
    assert np.ptp(p, axis=0).max() > 3          # unfolded over several cells
    s, nu = analysis.locate(geom, w, p)
    dv = v[1:] - v[:-1]
    dv /= np.linalg.norm(dv, axis=1)[:, None]
    np.testing.assert_allclose(np.abs(np.sum(dv * nu, axis=1)), 1.0, atol=1e-9)
    assert np.all(np.sum(dv * nu, axis=1) > 0)   # the change of velocity points into the free region
    assert np.all(np.isfinite(s))


def test_a_cell_tests_every_image_that_reaches_into_it():
    """The cell walk (rbx.geometry.periodic_flight) tests in each cell the obstacles' images listed by
    periodic_images: every image whose grown obstacle meets the cell (by the exact distance from its centre to
    the cell), and only images whose box meets it. Scatterers inside their cells: only themselves."""
    from rbx.geometry import periodic_images
    for name, crossing in (("lorentz-2d", False), ("lorentz-centred", True), ("lorentz-3d", False)):
        c = zoo(name)
        geom = tables.build(*table_of(c), float(c["ball"]["radius"]))
        prims, shifts = periodic_images(geom)
        n = geom.dimension
        lo, period = geom.lattice
        listed = {(int(k), tuple(s)) for k, s in zip(prims, shifts)}
        if not crossing:
            assert listed == {(k, (0.0,) * n) for k in range(len(geom.codes))}, name
            continue
        for k in range(len(geom.codes)):
            for s in np.ndindex(*(3,) * n):
                s = tuple(float(x) - 1.0 for x in s)
                c, rho = geom.params[k, :n] + np.array(s) * period, geom.params[k, 12]
                meets = np.linalg.norm(np.clip(c, lo, lo + period) - c) < rho
                assert not meets or (k, s) in listed, (name, k, s)
        assert any(any(s) for _, s in listed), name          # the centred lattice's scatterers cross the sides
        for k, s in listed:
            c, rho = geom.params[k, :n] + np.array(s) * period, geom.params[k, 12]
            assert np.all(c + rho >= lo - 1e-9) and np.all(c - rho <= lo + period + 1e-9), (name, k, s)


def positions_at(times, t, pos, vel):
    """The centre at the given times, from the records (position and velocity after each collision)."""
    k = np.searchsorted(t, times, side="right") - 1
    return pos[k] + (times - t[k])[:, None] * vel[k]


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2])
def test_lorentz_gas_diffuses(seed):
    """An ensemble in a Lorentz gas of finite horizon (the triangular lattice of "lorentz-centred"), the rule
    random between smooth and completely rough: the mean-square displacement grows linearly in time (the fitted
    exponent ≈ 1), giving a finite diffusion coefficient with a confidence interval, the same along x and y.
    Not the simple square lattice: its cells' sides are corridors that no scatterer reaches, so free flights have
    a heavy tail and the displacement grows as t log t (the fit's interval failed on 4 of 6 seeds). Not the
    completely rough rule alone either: in this dense lattice it keeps the ball in the pockets between three
    scatterers."""
    from rbx.analysis import fit_diffusion, growth_exponent
    M, K = 1000, 6000
    c = zoo("lorentz-centred", "random", collisions=K, record=["time", "position", "velocity"], trajectories=M)
    c["initial"] = {"sample": "billiard"}
    c["run"]["seed"] = seed
    run = rbx.simulate(c)
    assert np.all(run.count == K + 1)
    T = 0.9 * float(run.time[:, -1].min())
    grid = np.linspace(0.0, T, 201)
    x = np.array([positions_at(grid, run.time[j], run.position[j], run.velocity[j]) for j in range(M)])
    fits = [fit_diffusion(grid, x[:, :, i], fit_from=0.2) for i in range(2)]
    msd = np.mean(np.sum((x - x[:, :1]) ** 2, axis=2), axis=0)
    a = growth_exponent(grid, msd, 0.2 * T, T)
    D = [f.coefficient for f in fits]
    print(f"Lorentz gas: D_x = {D[0]:.4f} ± {fits[0].half_width:.4f}, D_y = {D[1]:.4f} ± {fits[1].half_width:.4f} "
          f"(95 %), MSD exponent {a:.3f}")
    for f in fits:
        assert 0 < f.low and f.half_width < 0.3 * f.coefficient
    assert abs(D[0] - D[1]) <= fits[0].half_width + fits[1].half_width     # hexagonal symmetry: isotropic
    assert 0.9 < a < 1.1


# ---- exits -------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["sinai-3d", "cylinder", "box-obstacles"])
def test_rank_1_on_the_flat_walls_of_a_3d_table_with_curved_walls(name):
    """Rank 1 with a roughness direction on every flat wall of a 3D table that also has curved walls (the Sinai
    scatterer, the cylinder's side, sphere obstacles), completely rough on the curved ones: it crashed while the
    rules were compiled (the curved walls have no tangent axes). Each collision equals the reference's from the
    engine's state before it."""
    c = zoo(name, "rough", collisions=60, record=FIELDS)
    geom = Simulation(rbx.load(c)).geom
    flat = [w.name for w in geom.wall_list if w.tangents is not None]
    assert flat and len(flat) < len(geom.wall_list)
    c["boundary"]["walls"] = {w: {"rule": "constant", "rank": 1, "direction_deg": 30} for w in flat}
    run, T = _engine(c)
    assert T == 61
    assert set(run.rank[0, 1:].tolist()) == {1, 2}
    size = FreeRegion(c).size
    for i in range(1, T):
        start = {f: getattr(run, f)[0, i - 1] for f in FIELDS}
        r = reference_run(c, start=start, collisions=1)[1]
        assert r["wall"] == run.wall[0, i] and r["rank"] == run.rank[0, i]
        for f in FIELDS[:5]:
            got = np.asarray(getattr(run, f)[0, i], float)
            want = np.asarray(r[f], float).reshape(got.shape)
            scale = max(size, float(np.max(np.abs(want)))) if f in ("time", "position") else \
                max(1.0, float(np.max(np.abs(want))))
            assert float(np.max(np.abs(got - want))) <= 1e-10 * scale, (name, i, f, got, want)


def test_an_exit_wall_ends_the_trajectory_in_the_engine_and_the_reference():
    c = zoo("custom", "rough", collisions=500, record=FIELDS)
    c["boundary"]["walls"] = {"dent": {"rule": "exit"}}
    run = rbx.simulate(c)
    ref = reference_run(c)
    T = int(run.count[0])
    assert T == len(ref) < 501
    assert run.wall[0, T - 1] == ref[-1]["wall"] == 4 and run.rank[0, T - 1] == ref[-1]["rank"] == -1
    # the contact is recorded with no map applied: the velocity before and after are the same
    np.testing.assert_array_equal(run.velocity[0, T - 1], run.velocity[0, T - 2])
    np.testing.assert_allclose(run.position[0, T - 1], ref[-1]["position"], rtol=0, atol=1e-10 * 3)


# ---- validation: the real CLI ---------------------------------------------------------------------------------------

BASE = {"boundary": {"default": {"rule": "constant", "rank": 1}}, "ball": {"radius": 0.1},
        "initial": {"position": [0.5, 0.5], "velocity": [0.6, 0.8]}, "run": {"collisions": 10}}


def _custom(pieces):
    return {"kind": "custom", "boundary": pieces}


def _seg(name, a, b):
    return {"name": name, "from": a, "to": b}


NECK = [_seg("floor", [0, 0], [3, 0]), _seg("right", [3, 0], [3, 1]), _seg("roofr", [3, 1], [1.6, 1]),
        _seg("vr", [1.6, 1], [1.5, 0.15]), _seg("vl", [1.5, 0.15], [1.4, 1]), _seg("roofl", [1.4, 1], [0, 1]),
        _seg("left", [0, 1], [0, 0])]
DENT = [_seg("floor", [0, 0], [4, 0]), _seg("right", [4, 0], [4, 3]), _seg("roof1", [4, 3], [3, 3]),
        {"name": "dent", "from": [3, 3], "to": [1, 3], "center": [2, 1.750438596491228], "turn": "cw"},
        _seg("roof2", [1, 3], [0, 3]), _seg("left", [0, 3], [0, 0])]


SQUARE = [_seg("a", [0, 0], [2, 0]), _seg("b", [2, 0], [2, 2]), _seg("c", [2, 2], [0, 2]), _seg("d", [0, 2], [0, 0])]
BAD = {
    "open": ({"table": _custom(SQUARE[:3] + [_seg("d", [0, 2], [0, 0.5])])}, "table.boundary[0].from"),
    "gap": ({"table": _custom([SQUARE[0], _seg("b", [2, 0.1], [2, 2])] + SQUARE[2:])}, "table.boundary[1].from"),
    "self-crossing": ({"table": _custom([_seg("a", [0, 0], [2, 2]), _seg("b", [2, 2], [2, 0]),
                                         _seg("c", [2, 0], [0, 2]), _seg("d", [0, 2], [0, 0])])}, "table.boundary"),
    "clockwise": ({"table": _custom([_seg("a", [0, 0], [0, 2]), _seg("b", [0, 2], [2, 2]),
                                     _seg("c", [2, 2], [2, 0]), _seg("d", [2, 0], [0, 0])])}, "table.boundary"),
    "arc-centre": ({"table": _custom(SQUARE[:1] + [{"name": "b", "from": [2, 0], "to": [2, 2], "center": [2.2, 0.9],
                                                   "turn": "cw"}] + SQUARE[2:])}, "table.boundary[1].center"),
    "obstacles-overlap": ({"table": {"kind": "rectangle", "width": 2, "height": 2, "obstacles": [
        {"name": "p", "disc": {"center": [1.0, 1.0], "radius": 0.3}},
        {"name": "q", "disc": {"center": [1.5, 1.0], "radius": 0.3}}]}}, "table.obstacles[1]"),
    "obstacle-grown-touches-another": ({"table": {"kind": "rectangle", "width": 2, "height": 2, "obstacles": [
        {"name": "p", "disc": {"center": [1.0, 1.0], "radius": 0.3}},
        {"name": "q", "disc": {"center": [1.7, 1.0], "radius": 0.3}}]}}, "ball.radius"),
    "obstacle-crosses-boundary": ({"table": {"kind": "rectangle", "width": 2, "height": 2, "obstacles": [
        {"name": "p", "disc": {"center": [1.0, 1.9], "radius": 0.2}}]}}, "table.obstacles[0]"),
    "obstacle-grown-touches-boundary": ({"table": {"kind": "rectangle", "width": 2, "height": 2, "obstacles": [
        {"name": "p", "disc": {"center": [1.0, 1.75], "radius": 0.2}}]}}, "ball.radius"),
    "obstacle-crosses-arc": ({"table": {"kind": "stadium", "radius": 0.5, "length": 1.0, "obstacles": [
        {"name": "p", "disc": {"center": [1.3, 0.0], "radius": 0.3}}]}}, "table.obstacles[0]"),
    "periodic-obstacle-outside-cell": ({"table": {"kind": "rectangle", "width": 1, "height": 1, "periodic": True,
                                                  "obstacles": [{"name": "p", "disc": {"center": [1.2, 0.5],
                                                                                       "radius": 0.2}}]}},
                                       "table.obstacles[0]"),
    "periodic-obstacle-meets-its-image": ({"table": {"kind": "rectangle", "width": 1, "height": 1, "periodic": True,
                                                     "obstacles": [{"name": "p", "disc": {"center": [0.5, 0.5],
                                                                                          "radius": 0.5}}]}},
                                          "table.obstacles[0]"),
    "lorentz-unknown-lattice": ({"table": {"kind": "lorentz", "cell": [1, 1], "radius": 0.3,
                                           "lattice": "hexagonal"}}, "table.lattice"),
    "lorentz-lattice-not-a-name": ({"table": {"kind": "lorentz", "cell": [1, 1], "radius": 0.3, "lattice": 2}},
                                   "table.lattice"),
    "lorentz-centred-scatterers-overlap": ({"table": {"kind": "lorentz", "cell": [1, 1.7320508], "radius": 0.55,
                                                      "lattice": "centred"}}, "table.radius"),
    "sinai-user-obstacle-overlaps-the-scatterer": ({"table": {"kind": "sinai", "size": [2, 1.5], "radius": 0.4,
                                                              "obstacles": [{"name": "extra", "disc": {
                                                                  "center": [1.3, 0.75], "radius": 0.1}}]}},
                                                   "table.obstacles[0]"),
    "lorentz-scatterer-meets-its-image": ({"table": {"kind": "lorentz", "cell": [1, 1], "radius": 0.5}},
                                          "table.radius"),
    "lorentz-centred-no-room-between": ({"table": {"kind": "lorentz", "cell": [1, 1.7320508], "radius": 0.45,
                                                   "lattice": "centred"}}, "ball.radius"),
    "periodic-obstacles-meet-across-a-side": (
        {"table": {"kind": "rectangle", "width": 1, "height": 1, "periodic": True,
                   "obstacles": [{"name": "p", "disc": {"center": [0.1, 0.5], "radius": 0.2}},
                                 {"name": "q", "disc": {"center": [0.8, 0.5], "radius": 0.2}}]}},
        "table.obstacles[1]"),
    "sphere-obstacles-overlap": ({"table": {"kind": "box", "size": [2, 2, 2], "obstacles": [
        {"name": "p", "sphere": {"center": [1.0, 1.0, 1.0], "radius": 0.3}},
        {"name": "q", "sphere": {"center": [1.0, 1.5, 1.0], "radius": 0.3}}]},
                                  "initial": {"position": [0.5, 0.5, 0.5], "velocity": [0.6, 0.8, 0]}},
                                 "table.obstacles[1]"),
    "mushroom-stem-too-wide": ({"table": {"kind": "mushroom", "cap_radius": 0.5, "stem_width": 1.2,
                                          "stem_height": 1.0}}, "table.stem_width"),
    "ball-too-big": ({"table": {"kind": "stadium", "radius": 0.5, "length": 1.0}, "ball": {"radius": 0.6}},
                     "ball.radius"),
    "start-in-obstacle": ({"table": {"kind": "sinai", "size": [2, 1.5], "radius": 0.4},
                           "initial": {"position": [1.1, 0.8], "velocity": [0.6, 0.8]}}, "initial.position"),
    "sphere-too-small": ({"table": {"kind": "sphere", "radius": 0.1},
                          "initial": {"position": [0, 0, 0], "velocity": [0.6, 0.8, 0]}}, "ball.radius"),
    # a gap of 0.05 in a table 10 wide at x = 1e8 (the join tolerance was a fraction of the largest coordinate)
    "gap-far-from-the-origin": ({"table": _custom([_seg("a", [1e8, 0], [1e8 + 9.95, 0]),
                                                   _seg("b", [1e8 + 10, 0], [1e8 + 10, 10]),
                                                   _seg("c", [1e8 + 10, 10], [1e8, 10]), _seg("d", [1e8, 10], [1e8, 0])]),
                                 "initial": {"position": [1e8 + 5, 5], "velocity": [1, -1]}},
                                "table.boundary[1].from"),
    "obstacle-named-as-a-wall": ({"table": {"kind": "rectangle", "width": 2, "height": 1, "obstacles": [
        {"name": "left", "disc": {"center": [1.0, 0.5], "radius": 0.2}}]}, "initial": {"position": [0.3, 0.5],
                                                                                     "velocity": [0.6, 0.8]}},
                                 "table.obstacles[0].name"),
    "two-obstacles-one-name": ({"table": {"kind": "rectangle", "width": 2, "height": 1, "obstacles": [
        {"name": "o", "disc": {"center": [0.6, 0.5], "radius": 0.1}},
        {"name": "o", "disc": {"center": [1.4, 0.5], "radius": 0.1}}]}, "initial": {"position": [1.0, 0.5],
                                                                                  "velocity": [0.6, 0.8]}},
                               "table.obstacles[0].name"),
    "sample-on-a-wall-the-ball-never-touches": ({"table": {"kind": "mushroom", "cap_radius": 1, "stem_width": 1.9,
                                                           "stem_height": 1},
                                                 "initial": {"sample": "billiard", "wall": "cap_floor_left"}},
                                                "initial.wall"),
    # a dispersing arc whose lowest point is 1e-4 below the floor: 64 points per arc missed the crossing
    "arc-dips-below-the-floor": ({"table": _custom(DENT[:3] + [{**DENT[3], "center": [2, 1.6666111112962898]}]
                                                   + DENT[4:])}, "table.boundary"),
    "arc-touches-the-floor": ({"table": _custom(DENT[:3] + [{**DENT[3], "center": [2, 5 / 3]}] + DENT[4:])},
                              "table.boundary"),
    # numbers whose squares overflow: the 1e307 cell used to run for ever, deaf to Ctrl-C
    "lorentz-cell-overflows": ({"table": {"kind": "lorentz", "cell": [1.0e307, 1.0e307], "radius": 0.3}},
                               "table.cell[0]"),
    "obstacle-centre-overflows": ({"table": {"kind": "rectangle", "width": 2, "height": 2, "obstacles": [
        {"name": "p", "disc": {"center": [1.0, 3e200], "radius": 0.3}}]}}, "table.obstacles[0].disc.center[1]"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_tables_exit_2_with_one_line_naming_the_key(case, tmp_path):
    """The command's own code in this process (click's runner: each refusal comes before anything is computed), and
    in a real process, with a time limit, where a table once ran for ever (numbers that overflow)."""
    from click.testing import CliRunner

    from rbx.cli.main import cli
    over, key = BAD[case]
    cfg = copy.deepcopy(BASE)
    cfg.update(copy.deepcopy(over))
    path = tmp_path / "cfg.yaml"
    path.write_text(yaml.safe_dump(cfg))
    args = ["simulate", str(path), "-o", str(tmp_path / "out.h5")]
    if "overflows" in case:
        res = subprocess.run([RBX_EXE, *args], capture_output=True, text=True, timeout=300)
        code, err = res.returncode, res.stderr
    else:
        res = CliRunner().invoke(cli, args, catch_exceptions=False)
        code, err = res.exit_code, res.stderr
    lines = err.strip().splitlines()
    assert code == 2, err
    assert len(lines) == 1, err
    assert lines[0].startswith(f"rbx: {path}: {key}: "), lines[0]
    assert not (tmp_path / "out.h5").exists()


# ---- the examples --------------------------------------------------------------------------------------------------


ZOO_EXAMPLES = {"custom.yaml": "custom", "stadium.yaml": "stadium", "sinai.yaml": "sinai-2d",
                "sinai3d.yaml": "sinai-3d", "lorentz.yaml": "lorentz-2d", "lorentz3d.yaml": "lorentz-3d",
                "mushroom.yaml": "mushroom", "sphere.yaml": "sphere", "cylinder.yaml": "cylinder"}


def test_every_zoo_kind_has_an_example_that_runs():
    """configs/examples/ holds an example of every preset (Sinai and Lorentz in 2D and 3D) and of a custom table;
    each runs (tests/test_cli_simulate.py also runs every example through the CLI, shortened)."""
    folder = os.path.join(ROOT, "configs", "examples")
    for f, kind in ZOO_EXAMPLES.items():
        with open(os.path.join(folder, f)) as fh:
            t = yaml.safe_load(fh)["table"]
        n = 3 if kind.endswith("3d") or kind in ("sphere", "cylinder") else 2
        assert t["kind"] == kind.split("-")[0] and tables.dimension(t["kind"], t) == n, (f, t)
        run = rbx.simulate(os.path.join(folder, f), collisions=200, trajectories=2)
        assert np.all(run.count == 201), f
    assert set(ZOO_EXAMPLES.values()) == {"custom", "stadium", "sinai-2d", "sinai-3d", "lorentz-2d", "lorentz-3d",
                                          "mushroom", "sphere", "cylinder"}


# ---- tables that narrow below the ball, far from the origin, in files of their own -----------------------------

@pytest.mark.parametrize("table,wall", [
    (_custom(NECK), "vl"), (_custom(NECK), None), (_custom(DENT), "floor"), (_custom(DENT), None),
    ({"kind": "polygon", "vertices": [s["from"] for s in NECK]}, "edge4"),
    ({"kind": "mushroom", "cap_radius": 1, "stem_width": 1.9, "stem_height": 1}, None)])
def test_starts_lie_in_the_free_region_where_the_table_narrows_below_the_ball(table, wall):
    """A neck 0.15 high (a V hanging from the roof) and a dent 0.15 above the floor, for a ball of radius 0.1: the
    offsets of the walls cross there, and the parts of them behind another wall are out of the ball's reach. Starts
    were drawn on them (12 of 50 below the shrunk floor; one went through the dent) and those trajectories ended
    after one record. Now every start lies in the free region, every trajectory makes all its collisions and never
    leaves the region. The mushroom's cap floors (0.05 each beside a stem 1.9 wide) were refused as 'does not fit'."""
    from rbx.geometry import _polygon_clearance, pieces_clearance
    c = {**copy.deepcopy(BASE), "table": table, "run": {"collisions": 2000, "trajectories": 60, "seed": 1},
         "initial": {"sample": "billiard", **({"wall": wall} if wall else {})},
         "output": {"record": ["time", "position", "velocity", "wall"]}}
    run = rbx.simulate(c)
    geom = run.geometry()
    assert list(run.count) == [2001] * 60
    pos = run.position.reshape(-1, 2)
    clear = (_polygon_clearance(pos, np.array(table["vertices"], float), 0.1) if table["kind"] == "polygon"
             else pieces_clearance(geom, pos))
    assert clear.min() > -1e-12, clear.min()
    assert np.isfinite(run.velocity).all()


def test_a_table_far_from_the_origin_is_the_same_table():
    """A unit square at (1e8, 1e8): its area cancelled to nothing (refused as clockwise) and no wall had room for
    the ball (the trim's tolerance ignored the rounding of coordinates of 1e8). Now the custom table and the polygon
    both run, and the orbit is the square at the origin's, shifted, to the rounding of numbers of 1e8."""
    far = 1e8
    square = [[0, 0], [1, 0], [1, 1], [0, 1]]
    runs = []
    for shift in (0.0, far):
        V = [[x + shift, y + shift] for x, y in square]
        for table in (_custom([_seg(n, V[i], V[(i + 1) % 4]) for i, n in enumerate("abcd")]),
                      {"kind": "polygon", "vertices": V}):
            c = {**copy.deepcopy(BASE), "table": table, "run": {"collisions": 50},
                 "initial": {"position": [shift + 0.5, shift + 0.5], "velocity": [0.6, 0.8]},
                 "output": {"record": ["position", "wall"]}}
            runs.append(rbx.simulate(c))
    for near, away in ((runs[0], runs[2]), (runs[1], runs[3])):
        assert away.count[0] == 51
        np.testing.assert_allclose(away.position[0] - far, near.position[0], atol=1e-6)
        np.testing.assert_array_equal(away.wall, near.wall)


@pytest.mark.long
def test_a_table_file_s_own_problems_are_reported_in_that_file(tmp_path):
    """A table in a file of its own: a problem of its keys found once the table is built (an obstacle that does
    not fit, a preset's size) names that file and the key in it, not the experiment's file and table.<key>."""
    cases = [({"kind": "mushroom", "cap_radius": 0.5, "stem_width": 1.2, "stem_height": 1.0}, "stem_width"),
             ({"kind": "rectangle", "width": 2, "height": 2, "obstacles": [
                 {"name": "p", "disc": {"center": [1.0, 1.9], "radius": 0.2}}]}, "obstacles[0]"),
             ({"kind": "lorentz", "cell": [1, 1], "radius": 0.6}, "radius"),
             ({"kind": "rectangle", "width": 2, "height": 1, "obstacles": [
                 {"name": "top", "disc": {"center": [1.0, 0.5], "radius": 0.2}}]}, "obstacles[0].name")]
    for table, key in cases:
        (tmp_path / "t.yaml").write_text(yaml.safe_dump(table))
        cfg = {**copy.deepcopy(BASE), "table": "t.yaml", "initial": {"sample": "billiard"}}
        path = tmp_path / "e.yaml"
        path.write_text(yaml.safe_dump(cfg))
        res = subprocess.run([RBX_EXE, "simulate", str(path), "-o", str(tmp_path / "o.h5")], capture_output=True,
                             text=True, timeout=300)
        lines = res.stderr.strip().splitlines()
        assert res.returncode == 2 and len(lines) == 1, res.stderr
        assert lines[0].startswith(f"rbx: {tmp_path / 't.yaml'}: {key}: "), lines[0]
