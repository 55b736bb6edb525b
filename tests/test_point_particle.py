"""Starts for comparisons with classic billiards: ``initial: {sample: point_particle}`` (docs/reference.md §4).

A point particle's billiard flow keeps the Liouville measure: the centre uniform in the area (volume) of the table
it moves in, the direction uniform, here with |v| = 1 and no spin. Each law is checked against a closed form:
the share of starts in a sub-region against its area share (binomial interval), the direction by a
Kolmogorov–Smirnov test, and through the dynamics the mean first flight in a disc (8r/3π), its mean chord (16r/3π)
and Santaló's mean free path πA/P of the specular Sinai table.
"""
import math

import numpy as np
import pytest
from scipy import stats

import rbx
from rbx import config, ensembles, rng
from rbx.config import ConfigError
from rbx.sampling import _draws, sample_point_particle

M = 20_000
P_MIN = 1e-3          # fixed seeds: deterministic; a correct sampler passes far above this
Z = 4.5               # binomial and mean intervals: a correct sampler is inside at this seed


def experiment(table, rule=None, radius=0.1, **run):
    return rbx.load({"table": table, "boundary": {"default": rule or {"rule": "constant", "rank": 0}},
                     "ball": {"radius": radius}, "initial": {"sample": "point_particle"},
                     "run": {"trajectories": 1, **run}})


def draw(table, seed=5, count=M, first=0):
    exp = experiment(table)
    return exp, sample_point_particle(exp.geometry(), seed, first, count)


def binomial_ok(k, n, p):
    return abs(k - n * p) <= Z * math.sqrt(n * p * (1 - p))


SINAI = {"kind": "sinai", "size": [2.0, 1.5], "radius": 0.4}
# the shrunk Sinai table (R = 0.1): [0.1, 1.9] × [0.1, 1.4] without the disc of radius 0.5 about (1, 0.75)
SINAI_AREA = 1.8 * 1.3 - math.pi * 0.5 ** 2
SINAI_PERIMETER = 2 * (1.8 + 1.3) + 2 * math.pi * 0.5


def test_draws_are_the_streams_of_rbx_rng():
    # the rejection rounds read further along each trajectory's own initial-state stream
    got = _draws(9, 3, 4, 16, 8)
    for j in range(4):
        key = np.uint64(rng.stream_key(9, 3 + j, rng.PURPOSE_INITIAL))
        assert np.array_equal(got[j], [rng.uniform(key, np.uint64(16 + i)) for i in range(8)])
    assert np.array_equal(_draws(9, 3, 4, 0, 8), rng.uniform_table(9, 3, 4, rng.PURPOSE_INITIAL, 8))


def test_centre_is_uniform_in_the_area():
    exp, s = draw(SINAI)
    p = s["position"]
    assert np.all(exp.geometry().clearance(p) >= 0)
    # a strip away from the disc: [0.1, 0.5] × [0.1, 1.4], area 0.52
    k = np.count_nonzero(p[:, 0] < 0.5)
    assert binomial_ok(k, M, 0.4 * 1.3 / SINAI_AREA), k / M
    # a ring about the disc: 0.5 < r < 0.6, area π(0.6² − 0.5²), inside the shrunk rectangle
    r = np.hypot(p[:, 0] - 1.0, p[:, 1] - 0.75)
    k = np.count_nonzero(r < 0.6)
    assert binomial_ok(k, M, math.pi * (0.36 - 0.25) / SINAI_AREA), k / M
    # the two coordinates on their own: the x-marginal of the rectangle less the disc, at x < 1 (CDF in closed form)
    x = p[:, 0]
    k = np.count_nonzero(x < 1.0)
    assert binomial_ok(k, M, 0.5), k / M


def test_a_wrong_area_law_fails_the_check():
    # the check can fail: centres uniform in the bounding box, the disc not removed, put 0.22, not 0.33, at x < 0.5
    u = rng.uniform_table(5, 0, M, rng.PURPOSE_INITIAL, 2)
    p = np.array([0.1, 0.1]) + u * np.array([1.8, 1.3])
    assert not binomial_ok(np.count_nonzero(p[:, 0] < 0.5), M, 0.4 * 1.3 / SINAI_AREA)


def test_direction_is_uniform_with_unit_speed_and_no_spin():
    _, s = draw(SINAI)
    v = s["velocity"]
    phi = np.mod(np.arctan2(v[:, 1], v[:, 0]), 2 * np.pi) / (2 * np.pi)
    assert stats.kstest(phi, "uniform").pvalue > P_MIN
    assert np.max(np.abs(np.hypot(v[:, 0], v[:, 1]) - 1.0)) <= 2 * np.finfo(float).eps
    assert np.all(s["angular_velocity"] == 0.0)
    assert stats.kstest(s["orientation"] / (2 * np.pi), "uniform").pvalue > P_MIN
    # a direction drawn with the billiard measure's cos law would fail: the test can fail
    cos_law = np.arcsin(2 * rng.uniform_table(5, 0, M, rng.PURPOSE_INITIAL, 1)[:, 0] - 1)
    assert stats.kstest(np.mod(cos_law, 2 * np.pi) / (2 * np.pi), "uniform").pvalue < P_MIN


def test_box_volume_and_sphere_of_directions():
    exp, s = draw({"kind": "box", "size": [1.0, 2.0, 1.0]})
    p, v = s["position"], s["velocity"]
    assert np.all((p >= 0.1) & (p <= np.array([0.9, 1.9, 0.9])))
    k = np.count_nonzero((p[:, 1] < 0.5) & (p[:, 2] > 0.6))      # 0.8 × 0.4 × 0.3 of 0.8 × 1.8 × 0.8
    assert binomial_ok(k, M, 0.4 * 0.3 / (1.8 * 0.8)), k / M
    assert stats.kstest((v[:, 2] + 1) / 2, "uniform").pvalue > P_MIN          # Archimedes: v_z uniform
    az = np.mod(np.arctan2(v[:, 1], v[:, 0]), 2 * np.pi) / (2 * np.pi)
    assert stats.kstest(az, "uniform").pvalue > P_MIN
    assert np.max(np.abs(np.linalg.norm(v, axis=1) - 1.0)) <= 4 * np.finfo(float).eps
    assert np.all(s["angular_velocity"] == 0.0)
    A = s["orientation"]
    assert np.allclose(np.einsum("mij,mkj->mik", A, A), np.eye(3), atol=1e-12)


def test_strip_and_periodic_cell():
    _, s = draw({"kind": "strip", "width": 1.0}, count=4000)
    assert np.all(s["position"][:, 0] == 0.0)          # along the infinite direction: 0, as the billiard sampler
    assert stats.kstest((s["position"][:, 1] - 0.1) / 0.8, "uniform").pvalue > P_MIN
    cell = {"kind": "lorentz", "cell": [1.0, 1.7320508075688772], "radius": 0.36, "lattice": "centred"}
    exp, s = draw(cell, count=4000)
    geom = exp.geometry()
    lo, period = geom.lattice
    assert np.all(geom.clearance(s["position"]) >= 0)
    assert np.all((s["position"] >= lo) & (s["position"] <= lo + period))


def test_a_start_depends_on_the_seed_and_its_index_only():
    exp = experiment(SINAI)
    geom = exp.geometry()
    whole = sample_point_particle(geom, 7, 0, 50)
    part = sample_point_particle(geom, 7, 20, 10)
    for k in ("position", "velocity", "orientation"):
        assert np.array_equal(whole[k][20:30], part[k])
    other = sample_point_particle(geom, 8, 0, 50)
    assert not np.array_equal(whole["position"], other["position"])


def test_first_flight_and_chord_in_a_disc():
    # In a disc of radius r (the shrunk one), from a point uniform in the area along a uniform direction, the
    # distance to the wall averages 8r/3π, and the chord then followed forever 16r/3π: the chords of the billiard
    # measure have ⟨ℓ⟩ = πr/2 and ⟨ℓ²⟩ = 8r²/3 (ℓ = 2r cos φ, φ ∝ cos φ), and a uniform start lies on a chord with
    # probability ∝ ℓ, at a uniform point of it (⟨ℓ²⟩/⟨ℓ⟩ and ⟨ℓ²⟩/2⟨ℓ⟩).
    exp = experiment({"kind": "circle", "radius": 1.0}, collisions=2, trajectories=4000, seed=2)
    run = rbx.simulate(exp)
    r = 0.9
    first = run.time[:, 1]
    chord = run.time[:, 2] - run.time[:, 1]
    for x, expected in ((first, 8 * r / (3 * math.pi)), (chord, 16 * r / (3 * math.pi))):
        assert abs(x.mean() - expected) <= Z * x.std() / math.sqrt(len(x)), (x.mean(), expected)


def test_santalo_mean_free_path_of_the_specular_sinai_table():
    # Santaló: the mean free path of a point particle in a table of area A and perimeter P is πA/P (the shrunk
    # table's, in closed form above). From starts of the invariant measure every collision counts alike.
    exp = experiment(SINAI, collisions=400, trajectories=400, seed=4)
    run = rbx.simulate(exp)
    t = run.time
    per_trajectory = (t[:, -1] - t[:, 1]) / (t.shape[1] - 2)
    expected = math.pi * SINAI_AREA / SINAI_PERIMETER
    err = per_trajectory.std() / math.sqrt(len(per_trajectory))
    assert abs(per_trajectory.mean() - expected) <= Z * err, (per_trajectory.mean(), expected, err)
    assert np.all(run.angular_velocity == 0.0)


def test_config_checks():
    with pytest.raises(ConfigError) as e:
        rbx.load({**_base(), "initial": {"sample": "point_particle", "wall": "bottom"}})
    assert e.value.key == "initial.wall" and "not on a wall" in e.value.problem
    with pytest.raises(ConfigError) as e:
        rbx.load({**_base(), "initial": {"sample": "pointparticle"}})
    assert e.value.key == "initial.sample" and "point_particle" in e.value.problem
    with pytest.raises(ConfigError) as e:
        rbx.load({**_base(), "table": {"kind": "wedge", "angle_deg": 60}})
    assert e.value.key == "initial.sample"
    exp = rbx.load(_base())
    assert exp.initial == ("point_particle", None) and exp.run.trajectories == 1
    assert ensembles.draws_random_numbers(exp)
    again = rbx.load(exp.to_dict())
    assert again.initial == exp.initial
    assert rbx.load(exp, {"ball.inertia": 0.2}).initial == exp.initial
    assert rbx.load(exp, {"initial": {"sample": "billiard"}}).initial == ("sample", None)


def _base():
    return {"table": {"kind": "rectangle", "width": 2.0, "height": 1.0},
            "boundary": {"default": {"rule": "constant", "rank": 0}}, "ball": {"radius": 0.1},
            "initial": {"sample": "point_particle"}}
