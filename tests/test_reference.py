"""Checks of the slow pure-Python reference (tests/reference.py) against the reference trajectories of
tests/data/trajectories.json (from an independent implementation), the invariants of
docs/reference.md §1 over whole trajectories on every scene kind, and closed forms from the literature.

The containment checks here are written independently of the reference's own collision geometry."""

import json
import math
import os
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from reference import collide, reference_run  # noqa: E402

DATA = Path(__file__).parent / "data" / "trajectories.json"
VECTORS = json.loads(DATA.read_text())["cases"]
S3 = math.sqrt(3.0)

ROUGH_2D = {"rule": "constant", "rank": 1}
SMOOTH = {"rule": "constant", "rank": 0}
ROUGH_3D = {"rule": "constant", "rank": 2}


def config(table, position, velocity, omega, *, boundary, radius=0.1, inertia="uniform", orientation=None,
           collisions=200):
    dim = len(position)
    if orientation is None:
        orientation = 0.0 if dim == 2 else [0.0, 0.0, 0.0]
    return {
        "table": table,
        "boundary": boundary,
        "ball": {"radius": radius, "inertia": inertia},
        "initial": {"position": position, "velocity": velocity, "angular_velocity": omega,
                    "orientation": orientation},
        "run": {"collisions": collisions},
    }


# ---------------------------------------------------------------------------------------------------------------
# (a) the reference trajectories (tests/data/trajectories.json)


@pytest.mark.parametrize("case", VECTORS, ids=[c["name"] for c in VECTORS])
def test_reference_reproduces_vectors(case):
    records = reference_run(case["config"])
    expected = case["records"]
    assert len(records) == len(expected)
    for i, (got, want) in enumerate(zip(records, expected)):
        assert got["wall"] == want["wall"], i
        for key in ("time", "position", "velocity", "angular_velocity", "orientation"):
            np.testing.assert_allclose(np.asarray(got[key], dtype=float), np.asarray(want[key], dtype=float),
                                       rtol=0, atol=1e-10, err_msg="record %d, %s" % (i, key))


# ---------------------------------------------------------------------------------------------------------------
# (b) energy and containment on every scene kind


def point_segment_distance(p, a, b):
    ab = b - a
    length2 = float(ab @ ab)
    if length2 == 0.0:  # a zero-length flight (second hit of a corner)
        return float(np.linalg.norm(p - a))
    s = min(1.0, max(0.0, float((p - a) @ ab) / length2))
    return float(np.linalg.norm(p - (a + s * ab)))


def segments_intersect(p1, p2, q1, q2):
    def orient(a, b, c):
        return (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])

    d1, d2 = orient(q1, q2, p1), orient(q1, q2, p2)
    d3, d4 = orient(p1, p2, q1), orient(p1, p2, q2)
    return d1 * d2 < 0 and d3 * d4 < 0


def segment_segment_distance(p1, p2, q1, q2):
    if segments_intersect(p1, p2, q1, q2):
        return 0.0
    return min(point_segment_distance(p1, q1, q2), point_segment_distance(p2, q1, q2),
               point_segment_distance(q1, p1, p2), point_segment_distance(q2, p1, p2))


def inside_polygon(p, vertices):
    """Even-odd ray casting."""
    inside = False
    m = len(vertices)
    for i in range(m):
        (x1, y1), (x2, y2) = vertices[i], vertices[(i + 1) % m]
        if (y1 > p[1]) != (y2 > p[1]):
            x = x1 + (p[1] - y1) * (x2 - x1) / (y2 - y1)
            if x > p[0]:
                inside = not inside
    return inside


def polygon_of(table):
    if table["kind"] == "rectangle":
        w, h = table["width"], table["height"]
        return [[0, 0], [w, 0], [w, h], [0, h]]
    return table["vertices"]


def assert_in_shrunk_table(table, R, records, tol=1e-12):
    """Every recorded centre, and for polygons every flight between records, keeps distance ≥ R − tol from
    the table's boundary (the shrunk tables of strip/circle/wedge/plates/box are convex, so the endpoints of
    a flight suffice there), and every collision happens at distance R from the wall it names."""
    kind = table["kind"]
    points = [np.asarray(r["position"], dtype=float) for r in records]
    for k, a in enumerate(points):
        if kind == "strip":
            assert R - tol <= a[1] <= table["width"] - R + tol, k
        elif kind == "circle":
            assert np.linalg.norm(a) <= table["radius"] - R + tol, k
        elif kind == "wedge":
            phi = math.radians(table["angle_deg"])
            assert a[1] >= R - tol, k
            assert math.sin(phi) * a[0] - math.cos(phi) * a[1] >= R - tol, k
        elif kind in ("rectangle", "polygon"):
            verts = np.asarray(polygon_of(table), dtype=float)
            assert inside_polygon(a, verts), k
        elif kind == "plates":
            assert R - tol <= a[2] <= table["gap"] - R + tol, k
        elif kind == "box":
            for axis in range(3):
                assert R - tol <= a[axis] <= table["size"][axis] - R + tol, (k, axis)
        else:
            raise AssertionError(kind)
    # every collision is a real contact: the centre is at distance R from the wall it reports
    for k, rec in enumerate(records[1:], start=1):
        a, wall = points[k], rec["wall"]
        if kind == "strip":
            gap = a[1] - R if wall == 0 else table["width"] - R - a[1]
        elif kind == "circle":
            gap = table["radius"] - R - np.linalg.norm(a)
        elif kind == "wedge":
            phi = math.radians(table["angle_deg"])
            gap = a[1] - R if wall == 0 else math.sin(phi) * a[0] - math.cos(phi) * a[1] - R
        elif kind in ("rectangle", "polygon"):
            verts = np.asarray(polygon_of(table), dtype=float)
            gap = point_segment_distance(a, verts[wall], verts[(wall + 1) % len(verts)]) - R
        elif kind == "plates":
            gap = a[2] - R if wall == 0 else table["gap"] - R - a[2]
        else:
            axis, side = divmod(wall, 2)
            gap = a[axis] - R if side == 0 else table["size"][axis] - R - a[axis]
        assert abs(gap) <= tol, (k, wall, gap)
    if kind in ("rectangle", "polygon"):
        verts = np.asarray(polygon_of(table), dtype=float)
        m = len(verts)
        for k in range(len(points) - 1):
            for i in range(m):
                d = segment_segment_distance(points[k], points[k + 1], verts[i], verts[(i + 1) % m])
                assert d >= R - tol, (k, i, d)


def kappa_value(inertia, dim):
    return {"uniform": 2.0 / (dim + 2), "ring": 1.0, "shell": 1.0 if dim == 2 else 2.0 / 3.0}.get(inertia, inertia)


def energy(record, kappa, R):
    v = np.asarray(record["velocity"], dtype=float)
    w = np.atleast_1d(np.asarray(record["angular_velocity"], dtype=float))
    return 0.5 * (float(v @ v) + kappa * R * R * float(w @ w))


HEMI_2D = {"rule": "hemisphere", "axis": [0.6, 0.8], "rough": ROUGH_2D, "smooth": SMOOTH}
RANDOM_2D = {"rule": "random", "choices": [SMOOTH, ROUGH_2D], "probabilities": [0.5, 0.5]}
RANK1_30 = {"rule": "constant", "rank": 1, "direction_deg": 30}
RANDOM_DIRECTION = {"rule": "random", "probabilities": [1 / 3, 1 / 3, 1 / 3],
                    "choices": [{"rule": "constant", "rank": 1, "direction_deg": d} for d in (0, 60, 120)]}
HEMI_3D = {"rule": "hemisphere", "axis": [0, 0, 1], "rough": ROUGH_3D,
           "smooth": {"rule": "random", "choices": [SMOOTH, {"rule": "constant", "rank": 1, "direction": [1, 1, 0]}],
                      "probabilities": [0.3, 0.7]}}

STRIP = {"kind": "strip", "width": 1.0}
CIRCLE = {"kind": "circle", "radius": 1.0}
WEDGE = {"kind": "wedge", "angle_deg": 60}
RECTANGLE = {"kind": "rectangle", "width": 2.0, "height": 1.0}
CONVEX = {"kind": "polygon", "vertices": [[0, 0], [2, 0], [2.6, 1], [1.5, 2], [0.2, 1.6]]}
# an L-shape with a dent: reflex vertices at (1, 1) and (0.9, 1.6)
NONCONVEX = {"kind": "polygon", "vertices": [[0, 0], [2, 0], [2, 1], [1, 1], [1.4, 2], [0.9, 1.6], [0.4, 2], [0, 2]]}
PLATES = {"kind": "plates", "gap": 1.0}
BOX = {"kind": "box", "size": [1.0, 1.5, 2.0]}

V2 = [0.6, 0.8]
V3 = [0.3, -0.5, 0.8]
W3 = [1.0, -2.0, 0.5]
ROT = [0.3, -0.2, 0.9]

SCENES = [
    # id, config, draws uniforms, must run all 200 collisions
    ("strip-rough", config(STRIP, [0.0, 0.5], V2, 1.5, boundary={"default": ROUGH_2D}), True),
    ("strip-mixed", config(STRIP, [0.0, 0.5], V2, 1.5, orientation=0.3,
                           boundary={"default": HEMI_2D, "walls": {"top": RANDOM_2D}}), True),
    ("circle-rough", config(CIRCLE, [0.1, -0.2], [-0.3, 0.9], -2.0, boundary={"default": ROUGH_2D}), True),
    ("circle-mixed", config(CIRCLE, [0.1, -0.2], [-0.3, 0.9], -2.0, orientation=1.0, inertia="ring",
                            boundary={"default": {"rule": "random", "choices": [HEMI_2D, ROUGH_2D],
                                                  "probabilities": [0.5, 0.5]}}), True),
    ("wedge-rough", config(WEDGE, [1.0, 0.4], V2[:1] + [-0.8], 2.0, boundary={"default": ROUGH_2D}), True),
    ("wedge-rough-ring", config(WEDGE, [1.5, 0.5], [0.6, -0.8], 3.0, inertia="ring",
                                boundary={"default": ROUGH_2D}), True),
    # smooth collisions let a wedge orbit escape: this one ends after 22 collisions
    ("wedge-mixed", config(WEDGE, [1.73, 1.24], [math.cos(2.35), math.sin(2.35)], 3.76, inertia="ring",
                           boundary={"default": {"rule": "random", "choices": [SMOOTH, ROUGH_2D],
                                                 "probabilities": [0.2, 0.8]}}), False),
    ("rectangle-rough", config(RECTANGLE, [0.3, 0.4], V2, 0.7, boundary={"default": ROUGH_2D}), True),
    ("rectangle-mixed", config(RECTANGLE, [0.3, 0.4], V2, 0.7, inertia=0.3,
                               boundary={"default": SMOOTH, "walls": {"bottom": ROUGH_2D, "top": RANDOM_2D,
                                                                      "left": HEMI_2D}}), True),
    ("polygon-convex-rough", config(CONVEX, [1.0, 0.8], [0.8, 0.6], -1.0, boundary={"default": ROUGH_2D}), True),
    ("polygon-convex-mixed", config(CONVEX, [1.0, 0.8], [-0.28, 0.96], -1.0,
                                    boundary={"default": RANDOM_2D, "walls": {"edge2": HEMI_2D}}), True),
    ("polygon-nonconvex-rough", config(NONCONVEX, [0.5, 0.5], V2, 0.4, boundary={"default": ROUGH_2D}), True),
    ("polygon-nonconvex-mixed", config(NONCONVEX, [0.5, 0.5], V2, 0.4,
                                       boundary={"default": HEMI_2D, "walls": {"edge3": RANDOM_2D}}), True),
    ("plates-rough", config(PLATES, [0.0, 0.0, 0.5], V3, W3, orientation=ROT, boundary={"default": ROUGH_3D}), True),
    ("plates-mixed", config(PLATES, [0.0, 0.0, 0.5], V3, W3, orientation=ROT,
                            boundary={"default": RANK1_30,
                                      "walls": {"top": {"rule": "random", "choices": [ROUGH_3D, RANDOM_DIRECTION],
                                                        "probabilities": [0.5, 0.5]}}}), True),
    ("box-rough", config(BOX, [0.5, 0.7, 1.0], V3, W3, orientation=ROT, boundary={"default": ROUGH_3D}), True),
    ("box-mixed", config(BOX, [0.5, 0.7, 1.0], V3, W3, orientation=ROT,
                         boundary={"default": HEMI_3D, "walls": {"left": RANK1_30, "back": SMOOTH,
                                                                 "top": RANDOM_DIRECTION}}), True),
]


@pytest.mark.parametrize("scene_id, cfg, must_finish", SCENES, ids=[s[0] for s in SCENES])
def test_energy_and_containment(scene_id, cfg, must_finish):
    uniforms = iter(np.random.default_rng(12345).random(10_000))
    records = reference_run(cfg, uniforms)
    if must_finish:
        assert len(records) == 201
    else:
        assert len(records) >= 20
    R = cfg["ball"]["radius"]
    dim = len(cfg["initial"]["position"])
    kappa = kappa_value(cfg["ball"]["inertia"], dim)
    e0 = energy(records[0], kappa, R)
    for k, rec in enumerate(records):
        assert abs(energy(rec, kappa, R) - e0) <= 1e-12 * e0, k
    assert_in_shrunk_table(cfg["table"], R, records)
    times = [r["time"] for r in records]
    assert all(t1 >= t0 for t0, t1 in zip(times, times[1:]))
    # every rule kind really happened: a mixed scene used more than one rank
    ranks = {r["rank"] for r in records[1:]}
    if "mixed" in scene_id:
        assert len(ranks) > 1, ranks
    if dim == 3:
        A = np.asarray(records[-1]["orientation"])
        np.testing.assert_allclose(A.T @ A, np.eye(3), rtol=0, atol=1e-13)
        assert abs(np.linalg.det(A) - 1.0) < 1e-12


def test_nonconvex_scene_hits_the_reflex_arcs():
    """The non-convex scenes must exercise the Minkowski-rounded reflex corners (normal (a − vertex)/R)."""
    cfg = SCENES[[s[0] for s in SCENES].index("polygon-nonconvex-rough")][1]
    records = reference_run(cfg)
    R = cfg["ball"]["radius"]
    verts = NONCONVEX["vertices"]
    reflex = {3: np.array(verts[3], float), 5: np.array(verts[5], float)}
    arc_hits = 0
    for rec in records[1:]:
        vertex = reflex.get(rec["wall"])
        if vertex is None:
            continue
        a = np.asarray(rec["position"])
        i = rec["wall"]
        e = np.subtract(verts[(i + 1) % len(verts)], verts[i])
        if abs(np.linalg.norm(a - vertex) - R) < 1e-12 and float((a - vertex) @ e) < 0:
            arc_hits += 1
    assert arc_hits > 0


# ---------------------------------------------------------------------------------------------------------------
# conventions the reference must follow (corners, grazing, escapes, random draws)


def test_corner_hit_resolves_both_walls_at_the_same_time():
    # centre heads straight for the shrunk corner (R, R) of the rectangle at 45°: bottom and left tie exactly
    cfg = config(RECTANGLE, [0.5, 0.5], [-1.0, -1.0], 0.0, boundary={"default": SMOOTH}, collisions=2)
    records = reference_run(cfg)
    assert [r["wall"] for r in records] == [-1, 0, 3]
    assert records[1]["time"] == records[2]["time"] == pytest.approx(0.4)
    np.testing.assert_allclose(records[2]["velocity"], [1.0, 1.0])


def test_grazing_flight_and_escape():
    # zero normal speed in a strip: no wall ahead, the run ends after record 0
    assert len(reference_run(config(STRIP, [0.0, 0.5], [1.0, 0.0], 0.0, boundary={"default": ROUGH_2D}))) == 1
    # a specular orbit in a 60° wedge escapes after at most 3 collisions
    records = reference_run(config(WEDGE, [2.0, 0.5], [-1.0, -0.2], 0.0, boundary={"default": SMOOTH}))
    assert 1 < len(records) <= 4


def test_random_rule_consumes_one_draw_per_random_node():
    nested = {"rule": "random", "probabilities": [0.5, 0.5],
              "choices": [SMOOTH, {"rule": "random", "probabilities": [0.25, 0.75], "choices": [SMOOTH, ROUGH_2D]}]}
    cfg = config(STRIP, [0.0, 0.5], V2, 0.0, boundary={"default": nested}, collisions=3)
    # collision 1: u=0.7 -> inner node, u=0.1 -> smooth; collision 2: u=0.2 -> smooth; collision 3: 0.9, 0.3 -> rough
    records = reference_run(cfg, iter([0.7, 0.1, 0.2, 0.9, 0.3]))
    assert [r["rank"] for r in records] == [0, 0, 0, 1]
    with pytest.raises(ValueError):
        reference_run(cfg)


def test_collision_map_invariants():
    """docs/reference.md §1: involution, angular momentum about the contact point, no-slip states fixed, closed-form
    2D map."""
    rng = np.random.default_rng(7)
    R, kappa = 0.3, 0.5
    for n in (2, 3):
        for _ in range(20):
            nu = rng.normal(size=n)
            nu /= np.linalg.norm(nu)
            v = rng.normal(size=n)
            M = rng.normal(size=(n, n))
            W = M - M.T
            P = np.eye(n) - np.outer(nu, nu)
            v1, W1 = collide(v, W, nu, P, R, kappa)
            v2, W2 = collide(v1, W1, nu, P, R, kappa)
            np.testing.assert_allclose(v2, v, atol=1e-12)
            np.testing.assert_allclose(W2, W, atol=1e-12)
            r = -R * nu
            # angular momentum about the contact point −r×v + 2λω, as a matrix (hat(−r×v) = r vᵀ − v rᵀ)
            L0 = np.outer(r, v) - np.outer(v, r) + kappa * R * R * W
            L1 = np.outer(r, v1) - np.outer(v1, r) + kappa * R * R * W1
            np.testing.assert_allclose(L1, L0, atol=1e-12)
            # no-slip states: contact velocity purely normal -> specular reflection of the normal part only
            u = v + W @ r
            v_ns = v - (u - float(u @ nu) * nu)
            v3, W3_ = collide(v_ns, W, nu, P, R, kappa)
            np.testing.assert_allclose(v3, v_ns - 2 * float(v_ns @ nu) * nu, atol=1e-12)
            np.testing.assert_allclose(W3_, W, atol=1e-12)
    # paper eq. (update2), uniform disc: (v0, v·Jν) ↦ [[−1/3, 2√2/3], [2√2/3, 1/3]]·(v0, v·Jν), v0 = R√κω
    nu = np.array([0.6, 0.8])
    Jnu = np.array([-nu[1], nu[0]])
    w, v = 1.7, np.array([0.3, -1.1])
    v1, W1 = collide(v, np.array([[0, -w], [w, 0]]), nu, np.eye(2) - np.outer(nu, nu), R, kappa)
    s = R * math.sqrt(kappa)
    before = np.array([s * w, v @ Jnu])
    after = np.array([s * W1[1, 0], v1 @ Jnu])
    c = 2 * math.sqrt(2) / 3
    np.testing.assert_allclose(after, np.array([[-1 / 3, c], [c, 1 / 3]]) @ before, atol=1e-12)
    assert float(v1 @ nu) == pytest.approx(-float(v @ nu))


# ---------------------------------------------------------------------------------------------------------------
# (c) closed forms: periodic orbits of the rough uniform disc
#
# In angle–position coordinates (x0 = R√κ θ, x) each completely rough collision is a half-turn of the velocity
# (v0, v) about the axis (√κ e0 + Jν)/√(1+κ), which lies in the wall's plane. Two walls whose tangents Jν make
# an angle γ give axes with cosine (κ + cos γ)/(1 + κ): for the uniform disc (κ = 1/2) and γ = 120° (walls of a
# 60° corner seen from inside) the axes are perpendicular. Hence in a 60° wedge two collisions rotate the
# velocity by π and four give the identity; in the equilateral triangle the three axes are mutually
# perpendicular, so three collisions give the identity on (v, ω) and the position closes after six. The angle θ
# drifts (x0 is a helix coordinate) and does not return. For κ ≠ 1/2 none of this holds.


def flow_state_after_period(records, p):
    """(position, velocity, ω) of the flow at time T = t_{p+1} − t_1 (the period of the collision sequence),
    reconstructed from record p: T lies in the flight after collision p."""
    T = records[p + 1]["time"] - records[1]["time"]
    rec = records[p]
    position = np.asarray(rec["position"]) + (T - rec["time"]) * np.asarray(rec["velocity"])
    return position, np.asarray(rec["velocity"]), rec["angular_velocity"]


def assert_periodic(records, p, atol):
    for k in range(1, len(records) - p):
        a, b = records[k], records[k + p]
        scale = 1.0 + np.linalg.norm(a["position"])
        np.testing.assert_allclose(b["position"], a["position"], atol=atol * scale, rtol=0)
        np.testing.assert_allclose(b["velocity"], a["velocity"], atol=atol, rtol=0)
        assert abs(b["angular_velocity"] - a["angular_velocity"]) <= atol * (1 + abs(a["angular_velocity"]))
        assert b["wall"] == a["wall"]


TRIANGLE = {"kind": "polygon", "vertices": [[0.0, 0.0], [1.0, 0.0], [0.5, S3 / 2]]}


def test_equilateral_triangle_returns_after_six_collisions():
    cfg = config(TRIANGLE, [0.43, 0.31], [math.cos(0.9), math.sin(0.9)], 2.7, radius=0.05,
                 boundary={"default": ROUGH_2D}, collisions=13)
    records = reference_run(cfg)
    assert len({r["wall"] for r in records[1:]}) == 3
    position, velocity, omega = flow_state_after_period(records, 6)
    np.testing.assert_allclose(position, records[0]["position"], atol=1e-12)
    np.testing.assert_allclose(velocity, records[0]["velocity"], atol=1e-12)
    assert omega == pytest.approx(records[0]["angular_velocity"], abs=1e-12)
    assert_periodic(records, 6, 1e-12)
    # the velocity part alone closes after three collisions
    for k in range(1, 10):
        np.testing.assert_allclose(records[k + 3]["velocity"], records[k]["velocity"], atol=1e-12)
        assert records[k + 3]["angular_velocity"] == pytest.approx(records[k]["angular_velocity"], abs=1e-12)
    # ... but not the orientation angle
    assert abs(records[7]["orientation"] - records[1]["orientation"]) > 1e-3


def test_equilateral_triangle_every_orbit_is_periodic():
    """Random initial conditions: period 6 through all three walls, or period 4 in one 60° corner."""
    rng = np.random.default_rng(3)
    R = 0.05
    periods = []
    while len(periods) < 40:
        p = np.array([rng.random(), rng.random() * S3 / 2])
        if not (p[1] > R and S3 * p[0] - p[1] > 2 * R and S3 * (1 - p[0]) - p[1] > 2 * R):
            continue
        ang = rng.random() * 2 * math.pi
        records = reference_run(config(TRIANGLE, list(p), [math.cos(ang), math.sin(ang)], float(rng.normal() * 5),
                                       radius=R, boundary={"default": ROUGH_2D}, collisions=13))
        walls = {r["wall"] for r in records[1:]}
        period = 6 if len(walls) == 3 else 4
        assert_periodic(records, period, 1e-9)
        periods.append(period)
    assert 6 in periods


def test_triangle_periodicity_needs_uniform_disc():
    cfg = config(TRIANGLE, [0.43, 0.31], [math.cos(0.9), math.sin(0.9)], 2.7, radius=0.05, inertia="ring",
                 boundary={"default": ROUGH_2D}, collisions=13)
    records = reference_run(cfg)
    assert np.linalg.norm(np.subtract(records[7]["velocity"], records[1]["velocity"])) > 1e-3


def test_wedge_60_bounded_orbit_returns_after_four_collisions():
    cfg = config(WEDGE, [1.0, 0.4], [0.6, -0.8], 2.0, boundary={"default": ROUGH_2D}, collisions=13)
    records = reference_run(cfg)
    assert len(records) == 14
    assert [r["wall"] for r in records[1:5]] == [0, 1, 0, 1]
    position, velocity, omega = flow_state_after_period(records, 4)
    np.testing.assert_allclose(position, records[0]["position"], atol=1e-12)
    np.testing.assert_allclose(velocity, records[0]["velocity"], atol=1e-12)
    assert omega == pytest.approx(records[0]["angular_velocity"], abs=1e-12)
    assert_periodic(records, 4, 1e-12)
    assert abs(records[5]["orientation"] - records[1]["orientation"]) > 1e-3


def test_wedge_60_orbits_escape_early_or_are_periodic():
    """Random initial conditions in the rough 60° wedge: an orbit leaves after at most 3 collisions or is
    4-periodic (observed; the half-turn argument above explains the period)."""
    rng = np.random.default_rng(4)
    R = 0.1
    outcomes = set()
    tried = 0
    while tried < 60:
        p = np.array([0.3 + 3 * rng.random(), 3 * rng.random()])
        if not (p[1] > R and S3 * p[0] - p[1] > 2 * R):
            continue
        tried += 1
        ang = rng.random() * 2 * math.pi
        records = reference_run(config(WEDGE, list(p), [math.cos(ang), math.sin(ang)], float(rng.normal() * 5),
                                       radius=R, boundary={"default": ROUGH_2D}, collisions=13))
        if len(records) < 14:
            assert len(records) - 1 <= 3
            outcomes.add("escape")
        else:
            assert_periodic(records, 4, 1e-9)
            outcomes.add("periodic")
    assert outcomes == {"escape", "periodic"}
