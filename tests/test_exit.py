"""The exit rule (docs/reference.md §3) and escape / return times (docs/reference.md §10;
rbx.dynamics.escape_times, docs/dynamics.md).

- A wall with ``{rule: exit}`` is a hole: the trajectory records the contact (rank −1, that wall, the state as it
  arrived) and ends; up to there it is the closed table's trajectory.
- Kac's lemma: started with the billiard measure on an exit wall, the mean return path (in the angle–position
  metric) is 4A/ℓ for a disc with spin in 2D (A: the area the centre moves in, ℓ: the hole's length).
- The escape rate from a small hole approaches ℓ/(4A) per unit path.
"""
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import rbx
from rbx.dynamics import escape_times, exponential_rate, survival

R = 0.1
SMOOTH = {"rule": "constant", "rank": 0}
ROUGH = {"rule": "constant", "rank": 1}
EXIT = {"rule": "exit"}
RECTANGLE = {"kind": "rectangle", "width": 2.0, "height": 1.0}
ALL = ["time", "position", "velocity", "angular_velocity", "orientation", "wall", "rank"]


def _config(table, default, walls=None, initial=None, collisions=200, trajectories=1, seed=1, record=ALL):
    boundary = {"default": default}
    if walls:
        boundary["walls"] = walls
    return {"table": table, "boundary": boundary, "ball": {"radius": R, "inertia": "uniform"},
            "initial": initial or {"position": [0.7, 0.4], "velocity": [-0.8, 0.6], "angular_velocity": 1.3},
            "run": {"collisions": collisions, "trajectories": trajectories, "seed": seed},
            "output": {"record": list(record)}}


def test_exit_rule_is_validated():
    exp = rbx.load(_config(RECTANGLE, ROUGH, {"left": EXIT}))
    assert type(exp.wall_rules[3]).__name__ == "Exit"
    with pytest.raises(rbx.ConfigError) as err:
        rbx.load(_config(RECTANGLE, ROUGH, {"left": {"rule": "exit", "rank": 0}}))
    assert err.value.key == "boundary.walls.left.rank"
    with pytest.raises(rbx.ConfigError) as err:
        rbx.load(_config(RECTANGLE, {"rule": "exti"}))
    assert "exit" in str(err.value)


@pytest.mark.parametrize("rule", [ROUGH, {"rule": "random", "choices": [SMOOTH, ROUGH], "probabilities": [0.5, 0.5]},
                                  {"rule": "hemisphere", "axis": [0, 1], "rough": ROUGH, "smooth": SMOOTH}])
def test_a_trajectory_ends_at_the_exit_contact(rule):
    closed = rbx.simulate(_config(RECTANGLE, rule))
    opened = rbx.simulate(_config(RECTANGLE, rule, {"left": EXIT}))
    left = 3
    k = int(np.argmax(closed.wall[0] == left))          # the first contact with the left wall
    assert k > 0
    assert opened.count[0] == k + 1                      # records 0 … k: the exit contact is the last
    assert opened.rank[0, k] == -1 and opened.wall[0, k] == left
    assert opened.position[0, k, 0] == pytest.approx(R, abs=1e-12)
    assert not opened.final["alive"][0]
    # up to the exit, the closed table's trajectory; the exit contact is the state as it arrived (no map)
    for f in ("time", "position", "velocity", "angular_velocity", "orientation"):
        np.testing.assert_array_equal(getattr(opened, f)[0, :k], getattr(closed, f)[0, :k])
    np.testing.assert_array_equal(opened.position[0, k], closed.position[0, k])
    np.testing.assert_array_equal(opened.velocity[0, k], closed.velocity[0, k - 1])
    np.testing.assert_array_equal(opened.angular_velocity[0, k], closed.angular_velocity[0, k - 1])
    times = escape_times(opened)
    assert times.exited[0] and times.wall[0] == left and times.time[0] == opened.time[0, k]


def test_escape_times_of_trajectories_that_stay_are_censored():
    cfg = _config(RECTANGLE, ROUGH, {"left": EXIT}, initial={"sample": "billiard", "wall": "bottom"},
                  collisions=3, trajectories=200, record=[])
    out = escape_times(rbx.simulate(cfg))
    assert out.exited.any() and (~out.exited).any()
    assert np.all(out.wall[out.exited] == 3) and np.all(out.wall[~out.exited] == -1)
    run = rbx.simulate(cfg)
    np.testing.assert_array_equal(out.time, run.final["time"])


def test_survival_and_rate_of_exponential_times():
    """The estimators on exponential times with random censoring (a known rate)."""
    rng = np.random.default_rng(7)
    rate = 0.3
    t = rng.exponential(1 / rate, 20000)
    c = rng.exponential(8.0, t.size)                    # censoring times
    times, exited = np.minimum(t, c), t <= c
    fit, err, k = exponential_rate(times, exited)
    assert abs(fit - rate) < 4 * err and err < 0.01 * rate * 2
    fit2, err2, _ = exponential_rate(times, exited, start=2.0)   # memoryless: the tail has the same rate
    assert abs(fit2 - rate) < 4 * err2
    s, S = survival(times, exited)
    for x in (1.0, 3.0, 6.0):
        assert S[np.searchsorted(s, x, side="right") - 1] == pytest.approx(np.exp(-rate * x), abs=0.02)
    # without censoring Kaplan–Meier is the empirical survival function
    s, S = survival(t[:100], np.ones(100, bool))
    np.testing.assert_allclose(S[1:], 1 - np.arange(1, 101) / 100, atol=1e-12)


#: a Sinai table, 2 × 1.5 with a disc of radius 0.4 in its centre: the centre moves in the rectangle shrunk by R
#: minus the disc grown by R
SINAI = {"kind": "sinai", "size": [2.0, 1.5], "radius": 0.4}
SINAI_AREA = (2.0 - 2 * R) * (1.5 - 2 * R) - np.pi * (0.4 + R) ** 2


def test_kac_mean_return_path():
    """Kac's lemma. The billiard flow of a disc with spin preserves Liouville measure on the angle–position
    configuration space Q = D × R (x₀ = R√κθ, 3-dimensional); its mean free path is 4·vol/area = 4A/P (Santaló,
    d = 3), and the mean return path to a wall of length ℓ, started with the billiard measure there, is
    (P/ℓ)·(4A/P) = 4A/ℓ whenever almost every state returns. The specular Sinai table is ergodic in (a, v) on each
    level of the spin, which it conserves (Sinai), so almost every state returns. (The rough Sinai table is not
    ergodic: it traps a fifth of the billiard measure in orbits that never reach a gate; docs/dynamics.md.)"""
    cfg = _config(SINAI, SMOOTH, {"left": EXIT}, initial={"sample": "billiard", "wall": "left"}, collisions=5000,
                  trajectories=6000, seed=11, record=[])
    out = escape_times(rbx.simulate(cfg))
    assert out.exited.all()
    ell = 1.5 - 2 * R
    expected = 4 * SINAI_AREA / ell
    mean, err = out.path.mean(), out.path.std() / np.sqrt(out.path.size)
    assert abs(mean - expected) < 4 * err, (mean, err, expected)
    assert err < 0.05 * expected           # the test resolves the mean to a few per cent


@pytest.mark.parametrize("gate", [0.3, 0.1])
def test_escape_rate_from_a_small_hole(gate):
    """Started with the billiard measure on the walls (which the boundary map preserves), a table with a hole of
    length ℓ loses ℓ/(4A) per unit path: the flux through the hole over the phase volume. The specular Sinai table
    (ergodic on each level of the spin) keeps that rate while most trajectories leave (fitted on paths up to
    0.5·4A/ℓ, where 40 % have left)."""
    boundary = [{"name": "floor", "from": [0, 0], "to": [2, 0]},
                {"name": "right", "from": [2, 0], "to": [2, 1.5]},
                {"name": "roof", "from": [2, 1.5], "to": [0, 1.5]},
                {"name": "upper", "from": [0, 1.5], "to": [0, 0.75 + gate / 2]},
                {"name": "gate", "from": [0, 0.75 + gate / 2], "to": [0, 0.75 - gate / 2]},
                {"name": "lower", "from": [0, 0.75 - gate / 2], "to": [0, 0]}]
    table = {"kind": "custom", "boundary": boundary,
             "obstacles": [{"name": "scatterer", "disc": {"center": [1.0, 0.75], "radius": 0.4}}]}
    cfg = _config(table, SMOOTH, {"gate": EXIT}, initial={"sample": "billiard"}, collisions=300,
                  trajectories=6000, seed=2, record=[])
    out = escape_times(rbx.simulate(cfg))
    expected = gate / (4 * SINAI_AREA)
    rate, err, k = out.rate(0.0, 0.5 / expected)
    assert k > 1000 and np.all(out.path[~out.exited] >= 0.5 / expected)   # none censored inside the window
    assert abs(rate - expected) < 4 * err, (rate, err, expected)
    assert err < 0.05 * expected


def test_an_edge_between_two_collinear_edges_of_a_polygon_is_hit():
    """A polygon's side cut into collinear edges (here the left side: edge3, edge4, edge5) is three walls. Started
    with the billiard measure, which the boundary map preserves, the share of collisions on a wall is its length
    over the perimeter (of the table the centre moves in); the middle piece must get its share and, as an exit,
    let trajectories leave. (Taking an edge as the half-space of its line, a fast path for an outer side, covered
    the middle piece with its neighbours': it was never hit.)"""
    vertices = [[0, 0], [2, 0], [2, 1.5], [0, 1.5], [0, 0.8], [0, 0.7]]
    table = {"kind": "polygon", "vertices": vertices}
    cfg = _config(table, SMOOTH, initial={"sample": "billiard"}, collisions=40, trajectories=3000, seed=5,
                  record=["wall"])
    run = rbx.simulate(cfg)
    walls = list(rbx.load(cfg).wall_names)
    hits = np.asarray(run.wall)[:, 1:].ravel()             # the collisions after the start
    perimeter = 2 * (2 - 2 * R) + 2 * (1.5 - 2 * R)
    share = 0.1 / perimeter
    middle = walls.index("edge4")
    observed = np.mean(hits == middle)
    err = np.sqrt(share * (1 - share) / hits.size)
    assert abs(observed - share) < 5 * err + 0.002, (observed, share)
    opened = rbx.simulate(_config(table, SMOOTH, {"edge4": EXIT}, initial={"sample": "billiard"}, collisions=2000,
                                  trajectories=200, seed=5, record=[]))
    assert np.sum(opened.count < 2001) > 150


@pytest.mark.long
def test_a_run_file_in_which_every_trajectory_has_left_reads_back(tmp_path):
    """A file whose trajectories all ended at the exit (none left running) opens, through the API and
    `rbx plot --kind escape`: its saved state was once refused as damaged, the check of the running trajectories'
    state failing on an empty set."""
    out = tmp_path / "gone.h5"
    cfg = _config(RECTANGLE, SMOOTH, {"left": EXIT}, initial={"sample": "billiard"}, collisions=2000, trajectories=3)
    run = rbx.simulate(cfg, output=str(out))
    again = rbx.open(str(out))
    assert not np.any(again.final["alive"]) and not np.any(run.final["alive"])
    np.testing.assert_array_equal(again.final["position"], run.final["position"])
    assert np.all(escape_times(again).exited)
    plot = subprocess.run([str(Path(sys.executable).with_name("rbx")), "plot", str(out), "--kind", "escape",
                           "-o", str(tmp_path / "gone.png")], capture_output=True, text=True, timeout=300)
    assert plot.returncode == 0 and (tmp_path / "gone.png").stat().st_size > 0, plot.stderr
