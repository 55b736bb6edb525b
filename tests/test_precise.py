"""The high-precision loop (rbx/precise.py), the yardstick of docs/accuracy.md and docs/stress.md: it agrees with
the engine over short runs on every scene and rule of the catalog; at 15 digits (53 bits) its errors are those of
float64; more digits change nothing at the level of the engine's error."""
from fractions import Fraction

import numpy as np
import pytest

from rbx import config
from rbx.precise import PreciseBilliard, deviation, precise_run
from rbx.simulation import run_in_memory

from catalog import SCENES, scene

from rbx.model import RECORD_FIELDS as FIELDS
SHORT = 60          # collisions compared field by field (the chaotic scenes stay within 1e-10 that long)
DISCRETE = 150      # collisions whose walls and ranks must agree


def engine(name, collisions, record=FIELDS):
    c = scene(name, collisions=collisions, record=record)
    cfg = config.from_dict(c)
    rec, count, _ = run_in_memory(cfg)
    return cfg, {f: v[0, :count[0]] for f, v in rec.items()}


@pytest.mark.parametrize("name", sorted(SCENES))
def test_precise_loop_agrees_with_the_engine(name):
    cfg, rec = engine(name, DISCRETE)
    p, T = precise_run(cfg, digits=50)
    assert T == len(rec["wall"])
    np.testing.assert_array_equal(p["wall"], rec["wall"])
    np.testing.assert_array_equal(p["rank"], rec["rank"])       # random rules: the engine's own draws
    for f in FIELDS[:5]:
        for i in range(min(SHORT + 1, T)):
            got, want = np.asarray(rec[f][i], float), np.asarray(p[f][i], float).reshape(np.shape(rec[f][i]))
            scale = max(1.0, float(np.max(np.abs(want))))
            assert np.max(np.abs(got - want)) <= 1e-10 * scale, f"{name}: record {i}, {f}: {got} vs {want}"


def _max_dev(a, b, upto):
    return max(float(np.max(np.abs(np.asarray(a[f][:upto], float).reshape(upto, -1)
                                   - np.asarray(b[f][:upto], float).reshape(upto, -1))))
               for f in ("position", "velocity", "angular_velocity"))


@pytest.mark.parametrize("name", sorted(SCENES))
def test_fifteen_digits_behave_like_float64(name):
    K = 40
    cfg, rec = engine(name, K, record=("position", "velocity", "angular_velocity", "wall"))
    p50, T = precise_run(cfg, digits=50, orientation=False)
    p15, T15 = precise_run(cfg, digits=15, orientation=False)
    assert PreciseBilliard(cfg, digits=15).ctx.prec == 53
    assert T15 == T == len(rec["wall"])
    np.testing.assert_array_equal(p15["wall"], p50["wall"])
    d15, d_engine = _max_dev(p15, p50, T), _max_dev(rec, p50, T)
    # both carry the rounding of 53-bit arithmetic, of the same size (measured: ratios 0.5 … 10)
    assert 0 < d15 < 1e-11 and 0 < d_engine < 1e-11
    assert d15 <= 30 * d_engine + 1e-15 and d_engine <= 30 * d15 + 1e-15, (d15, d_engine)


@pytest.mark.parametrize("name", ["strip-random", "circle-hemisphere", "L-polygon-rough", "star-polygon-hemisphere",
                                  "plates-mixed", "box-hemisphere"])
def test_more_digits_change_nothing_at_the_engines_error(name):
    cfg, rec = engine(name, 40, record=("position", "velocity"))
    a, b = PreciseBilliard(cfg, digits=50), PreciseBilliard(cfg, digits=80)
    worst_digits, worst_engine = 0.0, 0.0
    for i in range(1, 41):
        assert a.step() and b.step()
        assert a.wall == b.wall and a.rank == b.rank
        worst_digits = max(worst_digits, float(max(abs(x - y) for x, y in zip(a.a + a.v, b.a + b.v))))
        d = deviation(b, rec["position"][i], rec["velocity"][i])
        worst_engine = max(worst_engine, d["position"], d["velocity"])
    assert worst_digits < 1e-35 and worst_digits < 1e-20 * worst_engine, (worst_digits, worst_engine)


@pytest.mark.parametrize("name", ["circle-rough", "L-polygon-rough", "box-rough", "plates-mixed"])
def test_precise_loop_is_time_reversible_and_keeps_the_energy(name):
    cfg = config.from_dict(scene(name))
    loop = PreciseBilliard(cfg, digits=50)
    a0, v0, e0 = list(loop.a), list(loop.v), loop.energy()
    for _ in range(50):
        assert loop.step()
    assert abs(loop.energy() - e0) < 1e-45 * e0
    total = loop.time
    loop.reverse()
    loop.time = 0 * total
    for _ in range(50):
        assert loop.step()
    # the backward run stands at the first collision point: carry it on to the forward run's total time
    rest = total - loop.time
    a = [x + rest * v for x, v in zip(loop.a, loop.v)]
    assert max(abs(x - y) for x, y in zip(a, a0)) < 1e-35
    assert max(abs(x + y) for x, y in zip(loop.v, v0)) < 1e-35


def test_an_exact_corner_is_a_tie_won_by_the_lower_wall():
    c = {"table": {"kind": "rectangle", "width": 2.0, "height": 1.0}, "boundary": {"default": {"rule": "constant",
                                                                                              "rank": 1}},
         "ball": {"radius": 0.125}, "initial": {"position": [0.5, 0.5], "velocity": [1.375, 0.375]},
         "run": {"collisions": 3}}
    p, _ = precise_run(c, digits=40)
    assert list(p["wall"][1:3]) == [1, 2]            # right, then top at flight time 0
    assert p["time"][1] == p["time"][2] == 1.0
    np.testing.assert_array_equal(p["position"][1], [1.875, 0.875])


def test_exact_inputs_and_escapes():
    # a specular point billiard in a 60° wedge escapes after at most 3 collisions; numbers may be exact fractions
    c = {"table": {"kind": "wedge", "angle_deg": 60}, "boundary": {"default": {"rule": "constant", "rank": 0}},
         "ball": {"radius": 0.1}, "initial": {"position": [1.5, 0.2], "velocity": [-0.2, 0.05]}}
    loop = PreciseBilliard(c, digits=30, initial={"position": [Fraction(3, 2), "0.2"], "velocity": [-0.2, 0.05]})
    assert loop.a[1] == loop.ctx.mpf("0.2")
    n = 0
    while loop.step():
        n += 1
    assert not loop.alive and 1 <= n <= 3
    with pytest.raises(ValueError, match="sampled"):
        PreciseBilliard({"table": {"kind": "circle", "radius": 1}, "boundary": {"default": {"rule": "constant",
                                                                                           "rank": 1}},
                         "ball": {"radius": 0.1}, "initial": {"sample": "billiard"}})


ZOO_STEPS = 15      # collisions per table, each checked at 30 digits (the custom tables, in the long tier: ~0.6 s each)


@pytest.mark.parametrize("name", ["stadium", "mushroom", pytest.param("custom", marks=pytest.mark.long),
                                  pytest.param("custom-bulb", marks=pytest.mark.long), "circle-obstacles",
                                  "lorentz-2d", "sinai-3d", "lorentz-3d", "sphere", "cylinder"])
def test_precise_loop_follows_the_zoo_one_collision_at_a_time(name):
    """The zoo's tables (docs/reference.md §8) in the precise loop: from each of the engine's first states, one
    collision at 30 digits lands where the engine's next record is (the orbits themselves are chaotic: compared whole,
    they part at rounding level within ~10–30 collisions)."""
    from catalog import zoo
    c = zoo(name, "rough", collisions=ZOO_STEPS, record=FIELDS)
    rec, count, _ = run_in_memory(config.from_dict(c))
    for i in range(1, int(count[0])):
        state = {f: np.asarray(rec[f][0, i - 1]).tolist() for f in ("position", "velocity", "angular_velocity",
                                                                    "orientation")}
        # the circle's rim bounds the table: an engine state a float64 rounding outside it is, at 30 digits, further
        # out than the loop's tolerance (a wall behind); at 15 digits (53 bits) it counts as on the rim
        loop = PreciseBilliard(c, digits=15 if name == "circle-obstacles" else 30, initial=state)
        assert loop.step()
        assert loop.wall == rec["wall"][0, i] and loop.rank == rec["rank"][0, i], (name, i)
        d = deviation(loop, rec["position"][0, i], rec["velocity"][0, i], rec["angular_velocity"][0, i])
        assert max(d.values()) <= 1e-12 * max(1.0, float(np.abs(rec["position"][0, i]).max())), (name, i, d)
