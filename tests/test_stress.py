"""Fast versions of the stress cases of scripts/stress.py (docs/stress.md): grazing flights, exact corner hits,
wedge escapes and bounces near the vertex, tiny and huge tables, a ball that barely fits, κ → 0 and κ = 1, far
positions, extreme speeds and a long run. Each asserts the invariants: the centre stays within 1e-12·size of the
shrunk table, every collision lies on the wall it names, the energy drifts by less than 1e-12, the run ends
(bounded collisions; escapes only where docs/conventions.md says so), and it agrees with the 50-digit orbit and
with the transformed reference run where the case has one.

A case that breaks goes into KNOWN_BROKEN as a strict xfail with a reproducer in the reason, so it flips when fixed."""
import math
import os
import sys

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "scripts"))

import stress  # noqa: E402

from rbx import config  # noqa: E402
from rbx.config import ConfigError  # noqa: E402
from rbx.simulation import run_in_memory  # noqa: E402

L_SHAPE = [[0, 0], [2, 0], [2, 2], [1, 2], [1, 1], [0, 1]]

#: quick stress cases that break today (their names in scripts/stress.py) -> reason, with a reproducer
KNOWN_BROKEN = {}


def _params():
    out = []
    for case in stress.cases():
        marks = [pytest.mark.xfail(strict=True, reason=KNOWN_BROKEN[case.name])] if case.name in KNOWN_BROKEN else []
        out.append(pytest.param(case, marks=marks, id=f"{case.group}: {case.name}"))
    return out


@pytest.mark.parametrize("case", _params())
def test_stress_case_keeps_the_invariants(case):
    res = stress.check_case(case, quick=True)
    if res.get("skipped"):
        pytest.skip("; ".join(res["remarks"]))
    assert res["problems"] == [], res["problems"]
    assert res["table"] >= -stress.TOL and res["wall"] <= stress.TOL
    assert res["energy"] <= stress.ENERGY_TOL
    assert res["collisions"] <= case.n(True)                       # bounded: the run ended


def test_specular_wedges_escape_within_the_point_billiard_bound():
    for case in stress.cases():
        if case.group == "wedge" and case.max_collisions is not None:
            res = stress.check_case(case, quick=True)
            assert res["escaped"] and 1 <= res["collisions"] <= case.max_collisions, case.name


def test_corners_are_resolved_one_wall_at_a_time_lower_index_first():
    by_name = {c.name: c for c in stress.cases()}
    res = stress.check_case(by_name["box corner, specular"], quick=True)
    assert res["first_walls"] == (1, 3, 5) and res["corner_dt"] == 0.0
    res = stress.check_case(by_name["rectangle: start in the corner (0.125, 0.125) moving into both walls"],
                            quick=True)
    assert res["first_walls"] == (0, 3)


def test_a_long_run_against_the_exact_strip_orbit():
    rows = {r["variant"]: r for r in stress.long_run(200_000, 20_000, log=lambda *_: None)}
    plain, default = rows["plain"], rows["default"]
    assert all(r["collisions"] == 200_000 for r in rows.values())
    for r in rows.values():          # the exact orbit is a closed form (stress.exact_strip)
        assert r["time_error"] < 1e-10 and r["x_error"] < 1e-10 and r["v_error"] < 1e-10, r
    assert plain["energy"] < 1e-10 and default["energy"] < 1e-14
    assert plain["reversal"] < 1e-10 and default["reversal"] < 1e-5
    if "compensated, no projection" in rows:
        assert rows["compensated, no projection"]["time_error"] < 1e-15


def test_the_closed_form_strip_orbit_is_the_precise_loops():
    from rbx.precise import PreciseBilliard
    loop = PreciseBilliard(config.from_dict(stress.LONG), digits=60)
    for N in (1, 2, 7, 100):
        while loop.collisions < N:
            loop.step()
        t, x, vx, w = stress.exact_strip(stress.LONG, N)
        assert abs(t - loop.time) < 1e-50 and abs(x - loop.a[0]) < 1e-50
        assert abs(vx - loop.v[0]) < 1e-50 and abs(w - loop.omega()) < 1e-50


def _circle(position, velocity, collisions, inertia="uniform"):
    return {"table": {"kind": "circle", "radius": 1.0}, "boundary": {"default": {"rule": "constant", "rank": 0}},
            "ball": {"radius": 0.1, "inertia": inertia},
            "initial": {"position": position, "velocity": velocity}, "run": {"collisions": collisions},
            "output": {"record": ["position", "wall"]}}


def test_a_grazing_orbit_never_escapes_the_circle():
    e = 1e-8
    cfg = config.from_dict(_circle([0.0, -0.9 * math.sqrt(1 - e * e)], [1.0, 0.0], 10_000))
    _, count, final = run_in_memory(cfg)
    assert final["alive"][0] and count[0] == 10_001


def test_a_centre_an_ulp_outside_the_rim_moving_inward_still_hits_it():
    # the state the grazing orbit above reaches after 6060 collisions
    cfg = config.from_dict(_circle([1.731197046377943e-04, -8.999999833497598e-01],
                                   [9.999999814967112e-01, 1.923709345780602e-04], 10))
    _, count, final = run_in_memory(cfg)
    assert final["alive"][0] and count[0] == 11


def test_a_flight_tangent_to_a_reflex_arc_touches_nothing():
    cfg = config.from_dict({"table": {"kind": "polygon", "vertices": L_SHAPE},
                            "boundary": {"default": {"rule": "constant", "rank": 1}}, "ball": {"radius": 0.125},
                            "initial": {"position": [0.5, 0.875], "velocity": [1.0, 0.0]},
                            "run": {"collisions": 1}, "output": {"record": ["time", "position", "wall"]}})
    rec, _, _ = run_in_memory(cfg)
    assert rec["wall"][0, 1] == 1 and rec["time"][0, 1] == 1.375
    np.testing.assert_array_equal(rec["position"][0, 1], [1.875, 0.875])


def test_a_kappa_the_config_accepts_gives_a_finite_orbit():
    c = {"table": {"kind": "strip", "width": 1.0}, "boundary": {"default": {"rule": "constant", "rank": 1}},
         "ball": {"radius": 0.1, "inertia": 1e-320}, "initial": {"position": [0, 0.5], "velocity": [0.6, 0.8],
                                                                  "angular_velocity": 1.5},
         "run": {"collisions": 100}, "output": {"record": ["velocity", "angular_velocity"]}}
    try:
        cfg = config.from_dict(c)
    except ConfigError:
        return                                       # rejecting it is a fix too
    rec, count, _ = run_in_memory(cfg)
    assert count[0] == 101
    assert np.all(np.isfinite(rec["velocity"])) and np.all(np.isfinite(rec["angular_velocity"]))
