"""Statements of the paper (§2.6) and closed forms of the literature that need only the engine."""
import numpy as np
import pytest

from rbx import config
from rbx.simulation import run_in_memory

from catalog import scene


def run(c):
    cfg = config.from_dict(c)
    rec, count, _ = run_in_memory(cfg)
    return {k: v[:, :] for k, v in rec.items()}, count


def one(c):
    rec, count = run(c)
    return {k: v[0, :count[0]] for k, v in rec.items()}


@pytest.mark.parametrize("start", [([0.1, -0.2], [-0.3, 0.9], -2.0), ([0.5, 0.1], [0.2, 1.0], 4.0),
                                   ([-0.3, 0.3], [1.0, 0.1], 0.0)])
def test_circle_rough_vertex_angle_constant_and_two_caustics(start):
    c = scene("circle-rough", collisions=3000, record=["position"])
    c["initial"].update(position=start[0], velocity=start[1], angular_velocity=start[2])
    p = one(c)["position"][1:]               # collision points (record 0 is the start, inside)
    d = np.diff(p, axis=0)
    u = d / np.linalg.norm(d, axis=1, keepdims=True)
    angle = np.arccos(np.clip(np.sum(-u[:-1] * u[1:], axis=1), -1, 1))
    assert np.ptp(angle) < 1e-9
    # distance from the centre to each segment's line: two values, alternating
    dist = np.abs(p[:-1, 0] * u[:, 1] - p[:-1, 1] * u[:, 0])
    assert np.ptp(dist[0::2]) < 1e-9 and np.ptp(dist[1::2]) < 1e-9
    assert abs(dist[0] - dist[1]) > 1e-3                      # two different circles, not one
    # ... touched at the midpoints of the segments: the foot of the perpendicular is the midpoint
    mid = (p[1:] + p[:-1]) / 2
    foot = p[:-1] - np.sum(p[:-1] * u, axis=1, keepdims=True) * u
    assert np.max(np.linalg.norm(mid - foot, axis=1)) < 1e-9


def horizontal_excursion(name, collisions):
    r = one(scene(name, collisions=collisions, record=["position"]))
    xy = r["position"][:, :2]
    return np.max(np.linalg.norm(xy - xy[0], axis=1))


def test_plates_rank_two_on_both_is_bounded():
    e3, e5 = horizontal_excursion("plates-rank2", 1000), horizontal_excursion("plates-rank2", 100_000)
    assert e5 < 1.0 and e5 < 1.01 * e3          # no growth from 10³ to 10⁵ collisions


@pytest.mark.parametrize("name", ["plates-mixed", "plates-random-direction"])
def test_plates_rank_one_on_either_plate_is_unbounded(name):
    e3, e5 = horizontal_excursion(name, 1000), horizontal_excursion(name, 100_000)
    assert e5 > 5 * e3 and e5 > 100


def test_equilateral_triangle_rough_uniform_disc_has_period_six():
    """Every orbit that visits all three walls returns to its state after 6 collisions. Orbits that stay near a
    corner, bouncing between two walls, are orbits of the 60° wedge and have period 4 (next test). Both hold for
    the uniform disc only (κ = ½): each rough collision is a half-turn of (R√κ·ω, v) about (√κ·e₀ + Jν)/√(1+κ),
    and for walls at 60° two such axes are perpendicular exactly when κ = ½."""
    rng = np.random.default_rng(0)
    periods = {4: 0, 6: 0}
    for _ in range(150):
        c = scene("triangle-rough", collisions=48)
        c["initial"].update(velocity=list(rng.normal(size=2)), angular_velocity=float(rng.normal() * 5))
        r = one(c)
        period = 6 if len(np.unique(r["wall"][1:])) == 3 else 4
        periods[period] += 1
        for f in ("position", "velocity", "angular_velocity"):
            x = r[f][1:]                                        # collision states
            np.testing.assert_allclose(x[period:], x[:-period], atol=1e-10)
        p = r["position"][1:]
        assert min(np.max(np.abs(p[k:] - p[:-k])) for k in range(1, period)) > 1e-6   # and no shorter period
    assert periods[6] > 100


def test_sixty_degree_wedge_bounded_orbits_have_period_four():
    rng = np.random.default_rng(2)
    bounded = 0
    for _ in range(200):
        c = scene("wedge-rough", collisions=40)
        c["table"]["angle_deg"] = 60
        x = rng.uniform(0.4, 2.0)
        c["initial"].update(position=[x, rng.uniform(0.1, 0.5 * x)], velocity=list(rng.normal(size=2)),
                            angular_velocity=float(rng.normal() * 3))
        r = one(c)
        if len(r["position"]) < 41:
            continue                                           # escaped to infinity
        bounded += 1
        for f in ("position", "velocity", "angular_velocity"):
            x = r[f][1:]
            np.testing.assert_allclose(x[4:], x[:-4], atol=1e-9)
    assert bounded >= 20
