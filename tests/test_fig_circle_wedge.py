"""Figures `caustics`, `circle` and `periodic` (docs/reference.md §6): the measurements of rbx/orbits.py on
constructed data, the paper's properties on shortened runs of the actual configs in configs/experiments/, a case
where the property must fail, and one end-to-end run of `rbx simulate` plus a figure script."""
import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest
import yaml

from rbx import config, orbits
from rbx.simulation import run_in_memory

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
EXPERIMENTS = os.path.join(ROOT, "configs", "experiments")
BETA10 = math.degrees(math.acos((7 - 3 * math.sqrt(5)) / 8))     # the wedge where 2 collisions turn V by 4π/5
TIGHT = 1e-9


def run_config(name, collisions=None, edit=None):
    """Run configs/experiments/<name> in memory (optionally shortened, or edited as a dict) -> list of per-trajectory
    dicts of the recorded fields cut at their counts, and the Config."""
    path = os.path.join(EXPERIMENTS, name)
    overrides = {"collisions": collisions}
    if edit is None:
        cfg = config.load(path, overrides=overrides)
    else:
        with open(path) as f:
            data = yaml.safe_load(f)
        edit(data)
        cfg = config.from_dict(data, path, overrides)
    rec, count, _ = run_in_memory(cfg)
    return [{k: v[j, :count[j]] for k, v in rec.items()} for j in range(len(count))], cfg


# ---- rbx/orbits.py on constructed data -------------------------------------------------------------------------


def chords(rho, half_angles, n):
    """n + 1 points on the circle of radius rho whose chords alternately subtend 2a and 2b."""
    steps = [2 * half_angles[k % 2] for k in range(n)]
    phi = np.concatenate([[0.3], 0.3 + np.cumsum(steps)])
    return rho * np.stack([np.cos(phi), np.sin(phi)], axis=1)


def test_regular_polygon_orbit_has_its_interior_angle_and_one_radius():
    n, rho = 7, 0.9
    p = chords(rho, (math.pi / n, math.pi / n), 3 * n)
    assert np.allclose(orbits.vertex_angles(p), math.pi * (n - 2) / n, atol=1e-13)
    c = orbits.caustic_radii(p)
    assert c.radii == pytest.approx((rho * math.cos(math.pi / n),) * 2, abs=1e-13)
    assert c.alternation < 1e-13 and c.separation < 1e-13
    assert np.max(orbits.midpoint_offsets(p)) < 1e-13


def test_alternating_chords_give_two_radii_and_a_constant_vertex_angle():
    rho, a, b = 0.9, 0.4, 1.1
    p = chords(rho, (a, b), 40)
    assert np.allclose(orbits.vertex_angles(p), math.pi - a - b, atol=1e-12)   # inscribed angle
    c = orbits.caustic_radii(p)
    assert c.radii == pytest.approx((rho * math.cos(a), rho * math.cos(b)), abs=1e-13)
    assert c.spreads[0] < 1e-13 and c.spreads[1] < 1e-13 and c.alternation < 1e-13
    assert c.separation == pytest.approx(rho * (math.cos(a) - math.cos(b)))


def test_caustic_measurements_see_a_broken_pattern():
    p = chords(0.9, (0.4, 1.1), 20)
    p[7] = 0.9 * np.array([math.cos(2.0), math.sin(2.0)])          # one collision point moved along the circle
    assert orbits.spread(orbits.vertex_angles(p)) > 0.05
    assert orbits.caustic_radii(p).alternation > 0.01
    # off-centre segment: the foot of the perpendicular from the origin is (0, 1), the midpoint (1, 1)
    assert orbits.midpoint_offsets(np.array([[-1.0, 1.0], [3.0, 1.0]]))[0] == pytest.approx(1.0)


def test_vertex_angles_of_simple_corners():
    p = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [2.0, 1.0], [2.0, 0.0]])
    assert orbits.vertex_angles(p) == pytest.approx([math.pi, math.pi / 2, 0.0], abs=1e-15)
    assert orbits.line_distances(p[:2], centre=(0.5, 2.0))[0] == pytest.approx(2.0)


def test_no_slip_state_keeps_its_caustic():
    """The rough map is the identity on states whose contact point does not slip: (v₀, v·Jν) ∝ (√κ, 1), i.e.
    ω = v·Jν/R. Then the outgoing segment is the specular one: both radii equal, the vertex angle 2ψ."""
    rho, R, kappa = 0.9, 0.1, 0.5
    p, v = np.array([0.0, -0.5]), np.array([1.0, 0.0])
    q = np.array([math.sqrt(rho ** 2 - 0.25), -0.5])                 # the first collision point
    nu = -q / rho
    omega = float(v @ np.array([-nu[1], nu[0]])) / R
    r_in, r_out, angle = orbits.predicted_caustic_radii(p, v, omega, rho, R, kappa)
    assert r_in == pytest.approx(0.5) and r_out == pytest.approx(0.5, abs=1e-14)
    assert angle == pytest.approx(2 * math.asin(0.5 / rho))
    assert orbits.predicted_caustic_radii(p, v, omega + 1.0, rho, R, kappa)[1] < 0.49      # slipping: it changes


def test_rough_collision_is_the_matrix_of_the_spec():
    kappa, nu = 0.5, np.array([0.6, 0.8])
    Jnu = np.array([-nu[1], nu[0]])
    V = np.array([0.7, 0.3, -1.1])
    out = orbits.rough_collision(V, nu, kappa)
    c = 2 * math.sqrt(2) / 3
    before = np.array([V[0], V[1:] @ Jnu])
    assert np.allclose([out[0], out[1:] @ Jnu], np.array([[-1 / 3, c], [c, 1 / 3]]) @ before, atol=1e-15)
    assert out[1:] @ nu == pytest.approx(-(V[1:] @ nu))
    assert np.allclose(orbits.rough_collision(out, nu, kappa), V, atol=1e-15)     # an involution


def test_detect_period_finds_a_planted_period_and_reports_its_tolerance():
    rng = np.random.default_rng(5)
    base = rng.normal(size=(7, 3))
    x = np.tile(base, (40, 1)) + rng.normal(scale=1e-12, size=(280, 3))
    res = orbits.detect_period(x, tol=1e-9)
    assert res.period == 7 and 1e-13 < res.mismatch < 1e-10 and res.shorter > 0.1
    assert orbits.detect_period(x, tol=1e-13).period is None                # the noise is above that tolerance
    assert orbits.detect_period(rng.normal(size=(200, 3))).period is None
    one = orbits.detect_period(np.ones((10, 2)))
    assert one.period == 1 and one.mismatch == 0 and one.shorter == math.inf


def test_wedge_closed_forms():
    assert orbits.wedge_rotation_angle(60, 0.5) == pytest.approx(math.pi)
    assert orbits.wedge_period(60, 0.5) == 4
    assert orbits.wedge_period(BETA10, 0.5) == 10
    assert orbits.wedge_period(math.degrees(math.acos(-0.25)), 0.5) == 6
    assert orbits.wedge_period(90, 0.5) is None          # cos γ = 1/3: the tetrahedral angle, not a rational turn
    assert orbits.wedge_period(60, 1.0) is None          # a ring: the 60° wedge is no longer special


def test_wedge_invariant_on_a_constructed_flight():
    """From wall0 at distance s0 from the shrunk vertex, a flight reaches wall1; s·n is the same at both ends (n the
    normal speed leaving wall0, arriving at wall1: the same as leaving it when the normal velocity is reversed)."""
    beta, R = 70.0, 0.1
    apex, normals = orbits.wedge_frame(beta, R)
    d1 = np.array([math.cos(math.radians(beta)), math.sin(math.radians(beta))])
    p0 = apex + 2.0 * np.array([1.0, 0.0])
    v = np.array([-1.3, 0.9])
    t = -((p0 - apex) @ normals[1]) / (v @ normals[1])
    p1 = p0 + t * v
    assert (p1 - apex) @ normals[1] == pytest.approx(0, abs=1e-14) and (p1 - apex) @ d1 > 0
    v1 = v - 2 * (v @ normals[1]) * normals[1]
    inv = orbits.wedge_invariant([p0, p1], [v, v1], [0, 1], beta, R)
    assert inv[0] == pytest.approx(inv[1], rel=1e-14)
    assert orbits.max_distance([[3.0, 4.0], [np.nan, np.nan], [1.0, 0.0]]) == 5.0


# ---- the paper's properties on the actual configs, shortened ---------------------------------------------------


def test_caustics_config_vertex_angle_constant_and_two_caustics_at_midpoints():
    (t,), cfg = run_config("caustics.yaml", collisions=3000)
    res = orbits.circle_orbit(t["position"], t["velocity"], t["angular_velocity"], cfg.geometry().circle[1],
                              cfg.ball.radius, cfg.ball.kappa)
    assert res.collisions == 3000
    assert res.vertex_angle_spread < TIGHT
    assert res.caustics.alternation < TIGHT and res.caustics.separation > 0.1
    assert res.midpoint_offset < TIGHT and res.off_circle < 1e-12
    assert res.radius_error < TIGHT                                   # closed form from the initial state
    assert abs(res.vertex_angle - res.predicted_vertex_angle) < TIGHT


def test_circle_config_three_orbits_each_with_its_own_pair():
    tracks, cfg = run_config("circle.yaml", collisions=2000)
    assert len(tracks) == 3
    rho = cfg.geometry().circle[1]
    res = [orbits.circle_orbit(t["position"], t["velocity"], t["angular_velocity"], rho, cfg.ball.radius,
                               cfg.ball.kappa) for t in tracks]
    for r in res:
        assert r.vertex_angle_spread < TIGHT and r.caustics.alternation < TIGHT and r.midpoint_offset < TIGHT
        assert r.radius_error < TIGHT and r.caustics.separation > 0.1
    angles = sorted(r.vertex_angle for r in res)
    assert min(np.diff(angles)) > 0.1                                 # three different orbits


@pytest.mark.parametrize("name,period", [("periodic/a-wedge60.yaml", 4), ("periodic/b-wedge88.yaml", 10)])
def test_periodic_configs_are_bounded_and_periodic(name, period):
    (t,), cfg = run_config(name)
    angle, R, kappa = cfg.table["angle_deg"], cfg.ball.radius, cfg.ball.kappa
    assert len(t["position"]) == 1001                                 # 1000 flights, no escape
    assert orbits.wedge_period(angle, kappa) == period
    res = orbits.detect_period(orbits.collision_states(t["position"][1:], t["velocity"][1:],
                                                       t["angular_velocity"][1:], R, kappa), tol=TIGHT)
    assert res.period == period and res.mismatch < TIGHT and res.shorter > 1e-3
    # every collision of the engine is the half-turn of orbits.rough_collision about the wall's axis
    _, normals = orbits.wedge_frame(angle, R)
    V = np.column_stack([R * math.sqrt(kappa) * t["angular_velocity"], t["velocity"]])
    for k in range(1, 30):
        expected = orbits.rough_collision(V[k - 1], normals[t["wall"][k]], kappa)
        assert np.allclose(V[k], expected, atol=1e-13)
    pred = orbits.wedge_prediction(t["position"][0], t["velocity"][0], t["angular_velocity"][0], angle, R, kappa)
    assert pred.first_wall == t["wall"][1] and pred.period == period
    assert orbits.max_distance(t["position"][1:], pred.apex) <= pred.supremum * (1 + TIGHT)


def test_typical_wedge_orbit_is_bounded_by_the_closed_form_and_not_periodic():
    (t,), cfg = run_config("periodic/typical-wedge90.yaml", collisions=20000)
    angle, R, kappa = cfg.table["angle_deg"], cfg.ball.radius, cfg.ball.kappa
    p, v, w = t["position"], t["velocity"], t["wall"]
    assert len(p) == 20001
    spin0 = cfg.initial[0]["angular_velocity"]
    pred = orbits.wedge_prediction(p[0], v[0], spin0, angle, R, kappa)
    assert pred.period is None and math.isfinite(pred.supremum)
    inv = orbits.wedge_invariant(p[1:], v[1:], w[1:], angle, R)
    assert inv[0] == pytest.approx(pred.invariant, rel=1e-12)
    assert orbits.spread(inv) / pred.invariant < TIGHT
    s = orbits.max_distance(p[1:], pred.apex)
    assert 1 - 1e-6 < s / pred.supremum <= 1 + TIGHT                 # approached, never crossed
    head = orbits.collision_states(p[1:1001], v[1:1001], np.zeros(1000), R, kappa)
    assert orbits.detect_period(head, tol=TIGHT).period is None


def test_wrong_inertia_breaks_the_period_four():
    """The checks can fail: with a ring (κ = 1) instead of a uniform disc the same start in the 60° wedge stays
    bounded for 200 collisions but does not repeat after 4 (nor after 1, 2 or 3)."""
    def ring(data):
        data["ball"]["inertia"] = "ring"
    (t,), cfg = run_config("periodic/a-wedge60.yaml", collisions=200, edit=ring)
    assert cfg.ball.kappa == 1.0 and len(t["position"]) == 201
    res = orbits.detect_period(orbits.collision_states(t["position"][1:], t["velocity"][1:],
                                                       t["angular_velocity"][1:], cfg.ball.radius, 1.0),
                               tol=TIGHT, max_period=4)
    assert res.period is None and res.mismatch > 1e-3


# ---- end to end ------------------------------------------------------------------------------------------------


@pytest.mark.long
def test_simulate_and_plot_caustics_end_to_end(tmp_path):
    data, png = tmp_path / "caustics.h5", tmp_path / "caustics.png"
    env = dict(os.environ, MPLBACKEND="Agg")
    sim = subprocess.run([sys.executable, "-c", "from rbx.cli.main import main; main()", "simulate",
                          os.path.join(EXPERIMENTS, "caustics.yaml"), "-o", str(data), "--collisions", "3000",
                          "--quiet"], capture_output=True, text=True, timeout=300, env=env)
    assert sim.returncode == 0, sim.stderr
    fig = subprocess.run([sys.executable, os.path.join(ROOT, "scripts", "fig_caustics.py"), str(data), "-o",
                          str(png)], capture_output=True, text=True, timeout=300, env=env, cwd=tmp_path)
    assert fig.returncode == 0, fig.stdout + fig.stderr
    assert png.stat().st_size > 20_000
    with open(tmp_path / "caustics.json") as f:
        record = json.load(f)
    assert record["label"] == "caustics" and record["checks"] and all(c["ok"] for c in record["checks"])
    assert {m["name"]: m["value"] for m in record["measured"]}["collisions"] == 3000
