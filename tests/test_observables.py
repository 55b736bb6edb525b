"""Observables of rbx/observables.py against closed forms, those tests/test_sweep.py does not cover: the escape
rate through a small hole (the flux of the Liouville measure through the hole), the diffusion coefficient of the
specular Lorentz gas (Machta–Zwanzig's random walk between traps, and the Einstein relation on the same orbits),
and the regular share (integrable against ergodic). Starts are a point particle's (initial: {sample:
point_particle}): the invariant measure the closed forms are written for."""
import math

import numpy as np
import pytest

import rbx
from rbx import analysis
from rbx.sweeping import sweep

SPECULAR = {"rule": "constant", "rank": 0}


def point_study(base, measure, trajectories, collisions, seed, vary=None):
    return {"base": base, "set": {"initial": {"sample": "point_particle"}},
            "vary": vary or {"ball.inertia": [0.5]}, "measure": measure,
            "ensemble": {"trajectories": trajectories, "collisions": collisions, "seed": seed}}


def test_escape_rate_through_a_small_hole():
    # A point particle in a chaotic table of area A with a hole of length h escapes at the rate of the flux of the
    # Liouville measure through the hole, h·∫cos φ dφ / (2π·A) = h/(πA) per unit path, to first order in h
    # (Kac's lemma: the mean return time is πA/h). The table: a Sinai table (disc of radius 0.4 in a 2 × 1.5
    # rectangle) with its top-left corner cut by a short edge, the hole (0.09 long once shrunk by R = 0.01).
    base = {"table": {"kind": "polygon", "vertices": [[0, 0], [2, 0], [2, 1.5], [0.07, 1.5], [0, 1.43]],
                      "obstacles": [{"name": "disc", "disc": {"center": [1.0, 0.75], "radius": 0.4}}]},
            "boundary": {"default": SPECULAR, "walls": {"edge3": {"rule": "exit"}}}, "ball": {"radius": 0.01}}
    ds = sweep(point_study(base, ["escape_rate", "trapped_share"], 3000, 3000, 2))
    geom = rbx.load({**base, "initial": {"sample": "point_particle"}}).geometry()
    area, _ = analysis.table_measure(geom)
    hole = analysis.wall_measure(geom, 3)
    assert 0.08 < hole < 0.1 and 2.3 < area < 2.5
    expected = hole / (math.pi * area)
    rate, err = float(ds["escape_rate"][0]), float(ds["escape_rate_stderr"][0])
    assert 0 < err < 0.05 * rate
    assert abs(rate - expected) < 4 * err, (rate, err, expected)
    # the rough ball's rate would be h/(4A) (velocity dimension 3): 21 % lower, far outside the error
    assert abs(rate - hole / (4 * area)) > 8 * err
    assert float(ds["trapped_share"][0]) < 0.01           # e^(−γ·path): ~1e-9 survive 3000 collisions


def test_diffusion_of_the_specular_lorentz_gas():
    # The triangular Lorentz gas of finite horizon (lattice spacing 1; the centre meets discs of radius
    # r = 0.36 + R = 0.46). Machta & Zwanzig (Phys. Rev. Lett. 50, 1959 (1983)): a random walk between the
    # triangular traps, of free area A_t = (√3/2 − πr²)/2 each, left through 3 gaps of width w = 1 − 2r at the
    # small-hole rate 3w/(πA_t), by jumps of l = 1/√3: D = l²/(4τ). Exact as w → 0; at w = 0.08 within 20 %.
    # And the Einstein relation on the same orbits, D = ⟨|x(T) − x(0)|²⟩/(4T), computed here independently of
    # the observable's segments.
    base = str(rbx.__path__[0] + "/../configs/examples/lorentz-triangular.yaml")
    study = point_study(base, [{"diffusion": {"segments": 20}}], 200, 20000, 3)
    study["set"]["boundary"] = {"default": SPECULAR}
    ds = sweep(study)
    D, err = float(ds["diffusion"][0]), float(ds["diffusion_stderr"][0])
    assert 0 < err < 0.1 * D
    r = 0.46
    area_trap = (math.sqrt(3) / 2 - math.pi * r * r) / 2
    w = 1 - 2 * r
    machta_zwanzig = (1 / 3) * (3 * w / (math.pi * area_trap)) / 4
    assert abs(D - machta_zwanzig) < 0.2 * machta_zwanzig, (D, machta_zwanzig)
    exp = rbx.load(base, {"boundary": {"default": SPECULAR}, "initial": {"sample": "point_particle"},
                          "run.trajectories": 200, "run.collisions": 20000, "run.seed": 7,
                          "output.record": ["time", "position"], "output.every": 20000})
    run = rbx.simulate(exp)
    dx = run.position[:, -1] - run.position[:, 0]
    T = run.time[:, -1] - run.time[:, 0]
    per = np.sum(dx * dx, axis=1) / (4 * T)
    einstein, einstein_err = per.mean(), per.std(ddof=1) / math.sqrt(len(per))
    assert abs(D - einstein) < 4 * math.hypot(err, einstein_err), (D, err, einstein, einstein_err)


def test_regular_share_integrable_against_ergodic():
    # a specular rectangle is integrable: every orbit has λ₁ = 0 (share 1); the specular Sinai table (the same box
    # with a disc in it: one loop compiled for both) is ergodic and hyperbolic: no orbit is regular (share 0). The
    # Wilson interval (z = 1) must hold each.
    box = {"table": {"kind": "rectangle", "width": 2.0, "height": 1.5}, "boundary": {"default": SPECULAR},
           "ball": {"radius": 0.1}}
    sinai = {"table": {"kind": "sinai", "size": [2.0, 1.5], "radius": 0.4}, "boundary": {"default": SPECULAR},
             "ball": {"radius": 0.1}}
    for base, expected in ((box, 1.0), (sinai, 0.0)):
        ds = sweep(point_study(base, ["regular_share"], 24, 4000, 5))
        share = float(ds["regular_share"][0])
        low, high = float(ds["regular_share_low"][0]), float(ds["regular_share_high"][0])
        assert share == pytest.approx(expected) and low - 1e-12 <= expected <= high + 1e-12


def test_diffusion_says_where_the_horizon_is_infinite():
    """The diffusion observable carries the widest free corridor of the gas (rbx.analysis.free_corridors): the
    square Lorentz gas of the example (scatterer 0.3, R = 0.1) has corridors 1 − 2·0.4 = 0.2 wide along its cell's
    sides, so its value is no diffusion coefficient; the triangular one of finite horizon has none."""
    widths = []
    for name in ("lorentz", "lorentz-triangular"):
        base = str(rbx.__path__[0] + f"/../configs/examples/{name}.yaml")
        ds = sweep(point_study(base, [{"diffusion": {"segments": 4}}], 4, 200, 1))
        widths.append(float(ds["diffusion_horizon"][0]))
        assert ds["diffusion_horizon"].attrs["units"] == "L"
    assert widths[0] == pytest.approx(0.2, abs=1e-12) and widths[1] == 0.0


def test_the_study_plot_of_diffusion_says_where_it_is_no_coefficient():
    """``rbx plot RESULTS.nc --kind sweep`` of a diffusion study on the square gas drew 'diffusion coefficient D'
    with error bars and no word of its corridors; its legend says now that the value is a slope there, and says
    nothing of the kind on the triangular gas of finite horizon."""
    from rbx.cli.sweep import sweep_panel
    titles = []
    for name in ("lorentz", "lorentz-triangular"):
        base = str(rbx.__path__[0] + f"/../configs/examples/{name}.yaml")
        ds = sweep(point_study(base, [{"diffusion": {"segments": 4}}], 4, 200, 1))
        panel, title = sweep_panel(ds, "diffusion")
        titles.append((" ".join(panel.get("note", "").split()), panel["ylabel"], title))
    assert "not a diffusion coefficient at 1 of 1 points" in titles[0][0] and "0.2 wide" in titles[0][0], titles[0]
    assert titles[0][1].startswith("slope of the MSD (no coefficient)"), titles[0]
    assert "not a diffusion coefficient" not in titles[1][0] and "coefficient D" in titles[1][1], titles[1]


@pytest.mark.parametrize("table, pi_a_over_p, chord", [
    ({"kind": "circle", "radius": 1.0}, math.pi * 0.9 / 2, 16 * 0.9 / (3 * math.pi)),   # the shrunk table: r = 0.9
    ({"kind": "rectangle", "width": 2.0, "height": 1.0}, math.pi * 1.8 * 0.8 / 5.2, None)])   # 1.8 × 0.8
def test_mean_free_path_of_point_particle_starts_is_santalos_in_an_integrable_table(table, pi_a_over_p, chord):
    """Point-particle starts are drawn with the flow's measure, which meets an orbit of long chords more often; in a
    table that is not ergodic each orbit keeps its chord, so pooling orbits of equal collisions gave the flow's mean
    chord (16r/3π in a circle of radius r: 1.526 ± 0.015 against πA/P = 1.414). Each orbit weighted by its
    collisions per unit path gives Santaló's πA/P."""
    from rbx.observables import PointRuns, get
    exp = rbx.load({"table": table, "boundary": {"default": {"rule": "constant", "rank": 0}},
                    "ball": {"radius": 0.1, "inertia": 0.5}, "initial": {"sample": "point_particle"},
                    "run": {"collisions": 2000, "trajectories": 400, "seed": 3},
                    "output": {"record": ["position"], "every": 1}})
    runs = PointRuns(exp)
    runs.run = rbx.simulate(exp)
    v = get("mean_free_path").compute(runs, {"segments": 10})
    santalo = v.companions["santalo"]
    assert santalo == pytest.approx(pi_a_over_p, rel=1e-12)
    assert abs(v.value - santalo) < 3 * v.stderr and v.stderr < 0.03 * santalo, (v.value, v.stderr, santalo)
    if chord is not None:       # the flow's mean chord is told apart at this size
        assert abs(v.value - chord) > 3 * v.stderr, (v.value, v.stderr, chord)


def test_point_particle_orbits_under_rough_walls_are_not_weighted():
    """The weighting by collisions per unit path holds where point-particle starts are the flow's invariant measure:
    under specular walls. Under rough walls the orbits gain spin; the mean free path is then the pooled one."""
    from rbx.observables import PointRuns, get
    exp = rbx.load({"table": {"kind": "circle", "radius": 1.0}, "boundary": {"default": {"rule": "constant",
                                                                                          "rank": 1}},
                    "ball": {"radius": 0.1, "inertia": 0.5}, "initial": {"sample": "point_particle"},
                    "run": {"collisions": 200, "trajectories": 40, "seed": 3},
                    "output": {"record": ["position"], "every": 1}})
    runs = PointRuns(exp)
    runs.run = rbx.simulate(exp)
    step = np.linalg.norm(np.diff(np.asarray(runs.run.position)[:, 1:], axis=1), axis=-1)
    v = get("mean_free_path").compute(runs, {"segments": 10})
    assert v.value == pytest.approx(float(np.sum(step) / step.size), rel=1e-12)


def test_a_value_is_printed_to_the_precision_of_its_error():
    """'D = 0.008357 ± 0.01': the value carried digits its error does not support."""
    from rbx.analysis import plus_minus
    assert plus_minus(0.008357, 0.0098) == "0.0084 ± 0.0098"
    assert plus_minus(0.1147, 0.052) == "0.115 ± 0.052"
    assert plus_minus(-0.0065, 0.003) == "-0.0065 ± 0.0030"
    assert plus_minus(1234.5, 156) == "1230 ± 160"
    assert plus_minus(3.2e-12, 5.6e-14) == "3.200e-12 ± 0.056e-12"
    assert plus_minus(0.5, float("nan")) == "0.5 ± nan"
