"""The rule tree's fast tests (rbx.rules) against the plain ones they replace, and rbx.trig.sincos against libm.

- 2D hemisphere on a flat wall: ⌊θ/π + phase⌋ odd gives the same child as the sign of ν·R(θ)·axis with libm's cos
  and sin, on random axes, walls and angles up to 1e9; a wall without one normal (an arc) takes the cos/sin test,
  and only scenes with such a wall compile it (S_ROUND_HEMI).
- Random: integer thresholds on a draw's 53 bits pick the same child as the float draw against the cumulative
  probabilities, at and next to every threshold.
"""
import math

import numpy as np
import pytest
from numba import njit

import rbx
from rbx import engine, rules
from rbx.rng import draw_bits, uniform
from rbx.simulation import Simulation
from rbx.trig import sincos

ROUGH, SMOOTH = {"rule": "constant", "rank": 1}, {"rule": "constant", "rank": 0}


def _sim(table, rule, position=(0.5, 0.5)):
    n = len(position)
    return Simulation(rbx.load({
        "table": table, "boundary": {"default": rule}, "ball": {"radius": 0.1, "inertia": "uniform"},
        "initial": {"position": list(position), "velocity": [0.6, 0.8] if n == 2 else [0.6, 0.8, 0.3],
                    "angular_velocity": 1.0 if n == 2 else [1.0, 0.0, 0.5]},
        "run": {"collisions": 10, "trajectories": 1, "seed": 3}, "output": {"record": ["time"]}}))


def _hemisphere(axis):
    return {"rule": "hemisphere", "axis": list(axis), "rough": ROUGH, "smooth": SMOOTH}


def _choose(r, wall, nu, theta, rounded, key=0, draws=0):
    return rules.choose(wall, np.asarray(nu, float), np.eye(3), theta, np.uint64(key), draws, r.root, r.kind,
                        r.first, r.nchild, r.children, r.threshold, r.axis, r.phase, 2, rounded)


def _by_cos(r, wall, nu, theta):
    """The plain test: rough (child 0) iff ν·R(θ)·axis < 0, with libm's cos and sin."""
    node = r.root[wall]
    ax = r.axis[node]
    c, s = math.cos(theta), math.sin(theta)
    val = nu[0] * (c * ax[0] - s * ax[1]) + nu[1] * (s * ax[0] + c * ax[1])
    return r.children[r.first[node] + (0 if val < 0.0 else 1)], val


@pytest.mark.parametrize("table", [{"kind": "rectangle", "width": 2.0, "height": 1.0},
                                   {"kind": "polygon", "vertices": [[0, 0], [3, 0], [1, 2.5]]}])
def test_the_phase_test_on_flat_walls_is_the_sign_of_the_cosine(table):
    rng = np.random.default_rng(7)
    checked = 0
    for _ in range(20):
        axis = rng.normal(size=2)
        sim = _sim(table, _hemisphere(axis))
        r, geom = sim.rules, sim.geom
        assert not r.round_hemisphere
        normals = rules.flat_normals(geom)
        for w in range(len(geom.wall_list)):
            assert np.isfinite(r.phase[r.root[w], w])
            nu = normals[w]
            for theta in np.concatenate([rng.uniform(-10, 10, 200), rng.uniform(-1e9, 1e9, 200),
                                         [0.0, -0.0, math.pi, 1e6 * math.pi]]):
                want, val = _by_cos(r, w, nu, theta)
                if abs(val) < 1e-15 * (1 + abs(theta)):
                    continue        # within the rounding θ carries: either answer (module docstring)
                got, draws = _choose(r, w, nu, theta, False)
                assert got == want and draws == 0
                assert _choose(r, w, nu, theta, True)[0] == want
                checked += 1
    assert checked > 20 * 3 * 400


def test_a_hemisphere_on_an_arc_takes_the_cosine_and_compiles_it():
    stadium = _sim({"kind": "stadium", "length": 1.0, "radius": 0.5}, _hemisphere([0.3, 1.0]), (0.0, 0.0))
    r, geom = stadium.rules, stadium.geom
    assert r.round_hemisphere and stadium.spec() & engine.S_ROUND_HEMI
    normals = rules.flat_normals(geom)
    curved = [w for w in range(len(geom.wall_list)) if np.isnan(normals[w, 0])]
    assert curved and len(curved) < len(geom.wall_list)      # the caps; the flat sides keep their phase
    rng = np.random.default_rng(2)
    for w in curved:
        assert np.isnan(r.phase[r.root[w], w])
        for theta in rng.uniform(-50, 50, 300):
            phi = rng.uniform(0, 2 * np.pi)
            nu = np.array([math.cos(phi), math.sin(phi)])
            assert _choose(r, w, nu, theta, True)[0] == _by_cos(r, w, nu, theta)[0]
    # flat walls only, or a rule that is not a hemisphere on the arcs: not compiled
    assert not _sim({"kind": "strip", "width": 1.0}, _hemisphere([0, 1])).spec() & engine.S_ROUND_HEMI
    assert not _sim({"kind": "circle", "radius": 1.0}, ROUGH, (0.0, 0.0)).spec() & engine.S_ROUND_HEMI


@pytest.mark.parametrize("probs", [[0.5, 0.5], [1 / 3, 1 / 3, 1 / 3], [0.1, 0.0, 0.9], [1.0, 0.0], [0.25, 0.75]])
def test_integer_thresholds_pick_the_child_the_float_draw_picks(probs):
    cum = np.cumsum(probs)
    cum[-1] = np.inf
    thr = rules.thresholds(cum)
    assert thr.dtype == np.uint64 and thr[-1] == 2 ** 53

    def by_float(u):
        k = 0
        while u >= cum[k]:
            k += 1
        return k

    def by_int(m):
        k = 0
        while m >= int(thr[k]):
            k += 1
        return k
    # at, below and above every threshold, and the ends of the range
    ms = {0, 2 ** 53 - 1}
    for c in cum[:-1]:
        m0 = int(math.ceil(c * 2.0 ** 53))
        ms |= {max(m0 - 1, 0), min(m0, 2 ** 53 - 1), min(m0 + 1, 2 ** 53 - 1)}
    for m in ms:
        assert by_int(m) == by_float(m * 2.0 ** -53), m
    # and through the kernel, on real draws of a stream
    sim = _sim({"kind": "rectangle", "width": 2.0, "height": 1.0},
               {"rule": "random", "choices": [dict(SMOOTH, rank=0)] + [ROUGH] * (len(probs) - 1),
                "probabilities": probs})
    r = sim.rules
    key = np.uint64(12345)
    for d in range(2000):
        node, used = _choose(r, 0, [0.0, 1.0], 0.0, False, key, d)
        assert used == d + 1
        assert node == r.children[r.first[r.root[0]] + by_float(uniform(key, d))]
        assert node == r.children[r.first[r.root[0]] + by_int(int(draw_bits(key, d)) >> 11)]


def test_one_rule_on_every_wall_that_picks_among_constants_by_one_test_takes_the_kernels_short_pick():
    # engine.S_SHARED (rules.CompiledRules.shared_pick): every wall shares one node that picks among constant rules by
    # one test (a random choice of two or three, a 3D hemisphere rule): the kernel holds it in locals, no walk. Any
    # other shape, or one wall with a rule of its own, takes the walk
    two = {"rule": "random", "choices": [SMOOTH, ROUGH], "probabilities": [0.3, 0.7]}
    three = {"rule": "random", "choices": [SMOOTH, ROUGH, SMOOTH], "probabilities": [0.2, 0.3, 0.5]}
    four = {"rule": "random", "choices": [SMOOTH, ROUGH, SMOOTH, ROUGH], "probabilities": [0.25] * 4}
    nested = {"rule": "random", "choices": [SMOOTH, _hemisphere([0, 1])], "probabilities": [0.5, 0.5]}
    rect = {"kind": "rectangle", "width": 2.0, "height": 1.0}
    box = {"kind": "box", "size": [2.0, 1.0, 1.5]}
    for rule in (two, three, _hemisphere([0, 1])):
        assert _sim(rect, rule).spec() & engine.S_SHARED, rule
    for rule in (four, nested, ROUGH):
        assert not _sim(rect, rule).spec() & engine.S_SHARED, rule
    rough3 = {"rule": "constant", "rank": 2}
    hemi3 = {"rule": "hemisphere", "axis": [0, 0, 1], "rough": rough3, "smooth": SMOOTH}
    assert _sim(box, hemi3, position=(0.5, 0.5, 0.5)).spec() & engine.S_SHARED
    random3 = {"rule": "random", "choices": [SMOOTH, rough3], "probabilities": [0.5, 0.5]}
    assert not _sim(box, {**hemi3, "rough": random3}, position=(0.5, 0.5, 0.5)).spec() & engine.S_SHARED
    # one wall of another rule: no shared pick (a constant wall must draw nothing)
    mixed = rbx.load({"table": rect, "boundary": {"default": two, "walls": {"left": ROUGH}},
                      "ball": {"radius": 0.1}, "initial": {"position": [1.0, 0.5], "velocity": [0.6, 0.8],
                                                          "angular_velocity": 1.0},
                      "run": {"collisions": 10, "trajectories": 1, "seed": 3}})
    assert not Simulation(mixed).spec() & engine.S_SHARED


FIELDS_3D = ["time", "position", "velocity", "angular_velocity", "orientation", "wall", "rank"]


SHARED_CASES = [
    ({"kind": "strip", "width": 1.0}, "hemisphere"),             # 2D: each flat wall's phase (rules.phases)
    ({"kind": "rectangle", "width": 2.0, "height": 1.0}, "hemisphere"),
    ({"kind": "circle", "radius": 1.0}, "hemisphere"),          # 2D on a curved wall: cos θ, sin θ (S_ROUND_HEMI)
    ({"kind": "rectangle", "width": 2.0, "height": 1.0}, "random3"),
    ({"kind": "plates", "gap": 1.0}, "hemisphere"),             # a slab: the test reads one row of A
    ({"kind": "box", "size": [2.0, 1.0, 1.5]}, "hemisphere"),  # rules.hemisphere_step on the box's sides
    ({"kind": "sphere", "radius": 1.0}, "hemisphere"),           # and on a curved wall
    ({"kind": "plates", "gap": 1.0}, "random3"),
    ({"kind": "box", "size": [2.0, 1.0, 1.5]}, "random2")]


# the general loop (the suite's) in make test; the specialised loops users run (a compile of 5–15 s each) in
# make stress
@pytest.mark.parametrize("mode", ["general", pytest.param("specialised", marks=pytest.mark.long)])
@pytest.mark.parametrize("table, rule", SHARED_CASES)
def test_the_shared_pick_follows_the_orbit_of_the_walk_bit_for_bit(table, rule, mode, monkeypatch):
    # the same records (every field, 3000 collisions, 2 trajectories from the billiard measure) with the short pick
    # and with the walk (S_SHARED taken away), and every leaf taken
    from rbx.simulation import MemorySink
    monkeypatch.setattr(engine, "KERNELS", mode)
    dim3 = table["kind"] in ("plates", "box", "sphere")
    top = {"rule": "constant", "rank": 2 if dim3 else 1}      # completely rough
    # 2D has ranks 0 and 1 only: the middle leaf repeats the rough one (the third threshold is still read)
    middle = {"rule": "constant", "rank": 1, "direction_deg": 60} if dim3 else ROUGH
    three = [SMOOTH, middle, top]
    boundary = {"hemisphere": {"rule": "hemisphere", "axis": [0.3, -0.5, 0.8] if dim3 else [0.6, -0.8],
                               "rough": top, "smooth": SMOOTH},
                "random3": {"rule": "random", "choices": three, "probabilities": [0.2, 0.5, 0.3]},
                "random2": {"rule": "random", "choices": [SMOOTH, top], "probabilities": [0.4, 0.6]}}[rule]
    d = {"table": table, "boundary": {"default": boundary}, "ball": {"radius": 0.1, "inertia": "uniform"},
         "initial": {"sample": "billiard"}, "run": {"collisions": 3000, "trajectories": 2, "seed": 5},
         "output": {"record": FIELDS_3D}}
    runs = []
    for drop in (0, engine.S_SHARED):
        sim = Simulation(rbx.load(d), drop_bits=drop)
        assert bool(sim.spec() & engine.S_SHARED) == (drop == 0)
        sink = MemorySink()
        sim.run(sink)
        runs.append(sink.records)
    # the first record is the start's (rank 0 whatever the rule): the leaves taken are the later ones
    ranks = {0, 1, top["rank"]} if rule == "random3" else {0, top["rank"]}
    assert set(np.unique(runs[0]["rank"][:, 1:])) == ranks
    for f in runs[0]:
        np.testing.assert_array_equal(runs[0][f], runs[1][f], err_msg=f)


def test_the_shared_hemisphere_pick_on_a_slab_takes_a_non_finite_orientation_as_the_walk_does():
    # a first flight of ~4e299 at spin 1e20: τ|ω| overflows and A turns NaN. The walk's test (rough iff s < 0) takes
    # NaN as smooth; the slab's one-row test must too (the run then stops on the non-finite state, both ways)
    from rbx.simulation import MemorySink, NonFiniteState
    hemi = {"rule": "hemisphere", "axis": [0.3, -0.5, 0.8], "rough": {"rule": "constant", "rank": 2},
            "smooth": SMOOTH}
    d = {"table": {"kind": "plates", "gap": 1.0}, "boundary": {"default": hemi},
         "ball": {"radius": 0.1, "inertia": "uniform"},
         "initial": {"position": [0, 0, 0.5], "velocity": [1e-10, 0, 1e-300], "angular_velocity": [1e20, 0, 0]},
         "run": {"collisions": 1, "trajectories": 1}, "output": {"record": ["rank"]}}
    ranks = []
    for drop in (0, engine.S_SHARED):
        sim = Simulation(rbx.load(d), drop_bits=drop)
        assert bool(sim.spec() & engine.S_SHARED) == (drop == 0)
        with pytest.raises(NonFiniteState):
            sim.run(MemorySink())
        assert np.isnan(sim.A).all()
        ranks.append(sim.last_rank.tolist())
    assert ranks == [[0], [0]]


def test_a_random_rule_runs_the_map_without_a_branch_on_the_rank_and_the_same_orbit():
    # a random rule sets engine.S_BLEND (a run-time bit: no kernel of its own): the collision map computes the rough
    # change at rank 0 too, times 0, where a branch on the drawn rank would be mispredicted half the time. The same
    # orbit with the bit taken away (the map's branch), every field of 4000 collisions, bit for bit up to the sign
    # of a zero; a hemisphere rule keeps the branch (its rank follows the orbit, which the branch predicts ahead)
    from rbx.simulation import MemorySink
    d = {"table": {"kind": "rectangle", "width": 2.0, "height": 1.0},
         "boundary": {"default": {"rule": "random", "choices": [SMOOTH, ROUGH], "probabilities": [0.5, 0.5]}},
         "ball": {"radius": 0.1, "inertia": "uniform"}, "initial": {"sample": "billiard"},
         "run": {"collisions": 4000, "trajectories": 2, "seed": 3},
         "output": {"record": ["time", "position", "velocity", "angular_velocity", "orientation", "rank"]}}
    # every wall the same pair (the kernel holds it in locals), and one wall a pair of its own (the walk)
    own = {"rule": "random", "choices": [ROUGH, SMOOTH], "probabilities": [0.6, 0.4]}
    for walls in ({}, {"left": own}):
        d["boundary"]["walls"] = walls
        runs = []
        for drop in (0, engine.S_BLEND, engine.S_SHARED):     # and the same with the walk instead of the short pick
            sim = Simulation(rbx.load(d), drop_bits=drop)
            both = engine.S_BLEND | (0 if walls else engine.S_SHARED)
            assert sim.spec() & (engine.S_BLEND | engine.S_SHARED) == both & ~drop
            sink = MemorySink()
            sim.run(sink)
            runs.append(sink.records)
        assert set(np.unique(runs[0]["rank"])) == {0, 1}
        for f in runs[0]:
            for other in runs[1:]:
                np.testing.assert_array_equal(runs[0][f], other[f], err_msg=f)
    assert not _sim({"kind": "strip", "width": 1.0}, _hemisphere([0, 1])).spec() & engine.S_BLEND


@njit
def _sincos_all(x):
    c, s = np.empty(x.size), np.empty(x.size)
    for i in range(x.size):
        c[i], s[i] = sincos(x[i])
    return c, s


def test_sincos_agrees_with_libm():
    rng = np.random.default_rng(1)
    for hi in (1.0, 10.0, 1e3, 1e6, 1e9, 5.9e9):
        x = rng.uniform(-hi, hi, 100_000)
        c, s = _sincos_all(x)
        assert np.max(np.abs(c - np.cos(x))) <= 4.5e-16 and np.max(np.abs(s - np.sin(x))) <= 4.5e-16, hi
    # next to multiples of π/2, where the result is small: accurate relative to it (the reduction's ~85 bits)
    x = np.nextafter(np.arange(-10 ** 5, 10 ** 5, 3) * (np.pi / 2), np.inf)
    c, s = _sincos_all(x)
    assert np.max(np.abs(c - np.cos(x))) < 1e-24 and np.max(np.abs(s - np.sin(x))) < 1e-24
    # beyond the reduction's range, inf and NaN: libm itself
    x = np.array([7e9, -1e15, 1e300, np.inf, -np.inf, np.nan, 0.0, -0.0])
    c, s = _sincos_all(x)
    with np.errstate(invalid="ignore"):
        np.testing.assert_array_equal(c, np.cos(x))
        np.testing.assert_array_equal(s, np.sin(x))
