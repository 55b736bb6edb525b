"""The paper's figures graph, graphRandom, plate, roughrank and histogram (docs/reference.md §6): the properties
their figure scripts check, asserted on shortened in-memory runs of the actual configs in configs/experiments/, the
closed forms the scripts compare with, and one end-to-end run of `rbx simulate` and a figure script.

Bounds are set from the measured values at these lengths and fixed seeds, with margins of several times the noise;
a wrong engine (a bounded or ballistic strip, a lost memory, a drift at the wrong velocity, a measure that is not
kept) fails them by far.
"""
import glob
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from rbx import analysis, config
from rbx.histogram import return_experiment
from rbx.model import Constant
from rbx.physics import collision_map, spin_vector
from rbx.simulation import run_in_memory

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
EXPERIMENTS = os.path.join(ROOT, "configs", "experiments")
sys.path.insert(0, os.path.join(ROOT, "scripts"))

from fig_graph import orbit_measures  # noqa: E402
from fig_histogram import side_wall_comparison  # noqa: E402
from fig_plate import plates_measures  # noqa: E402
from fig_roughrank import kind_of, uses_random  # noqa: E402


def run(name, **overrides):
    cfg = config.load(os.path.join(EXPERIMENTS, name), overrides)
    rec, count, _ = run_in_memory(cfg)
    return cfg, rec


def strip_orbit(name, collisions):
    cfg, rec = run(name, collisions=collisions)
    x, t, rank = rec["position"][0, :, 0], rec["time"][0], rec["rank"][0]
    return orbit_measures(np.arange(len(x)), t, x, rank)


def plates_orbit(name, collisions):
    cfg, rec = run(name, collisions=collisions)
    o = dict(steps=np.arange(rec["position"].shape[1]) * cfg.output.every, time=rec["time"][0],
             position=rec["position"][0], geom=cfg.geometry(), init=cfg.resolved["initial"], R=cfg.ball.radius,
             kappa=cfg.ball.kappa, rules=cfg.wall_rules, every=cfg.output.every)
    return o, plates_measures(o)


# ---- graph and graphRandom: the strip -------------------------------------------------------------------------


def test_graph_hemisphere_orbit_has_long_memory_and_outruns_a_random_walk():
    m = strip_orbit("graph.yaml", 100_000)
    r = strip_orbit("graphRandom/orbit.yaml", 100_000)
    for o in (m, r):
        assert o["flight spread"] <= 1e-9                       # the paper: time between collisions is constant
        assert abs(o["flight time"] - 1.0) < 1e-12              # gap 0.8 / |v_y| 0.8
    assert 0.4 < m["rough fraction"] < 0.6                      # both hemispheres are met
    assert abs(r["rough fraction"] - 0.5) < 0.01                # p = ½
    # memory at lags 100 … 10⁴, in units of the noise of an estimated autocorrelation: 46 against 4.5 here
    assert m["memory"] > 20 * m["noise"]
    assert r["memory"] < 7 * r["noise"]
    # the velocity correlation of the random rule: 1/(1 + κ) after one collision, × (1 − κ)/(1 + κ) after two
    assert abs(r["rho1"] - 2 / 3) < 0.02 and abs(r["rho2"] - 2 / 9) < 0.02
    # range of x from 10² to 10⁵ collisions: 171 for the hemisphere rule, 65 for the random walk (√1000 ≈ 32)
    assert m["ranges"][-1] / m["ranges"][0] > 120
    assert m["range exponent"] > 0.65 and 0.35 < r["range exponent"] < 0.65


def test_strip_random_rank_msd_recursion_has_the_closed_form_diffusion_coefficient():
    for kappa, vx, w, vy in ((0.5, 0.6, 1.5, 0.8), (0.3, -0.2, 4.0, 0.5), (1.0, 0.9, -2.0, -0.3)):
        _, D, c = analysis.strip_random_rank_msd([0, 10], [0, 0.5], [vx, vy], w, 1.0, 0.1, kappa, 0.5)
        tau = 0.8 / abs(vy)
        u2 = vx * vx + kappa * 0.01 * w * w
        assert D == pytest.approx(tau * tau * u2 * (1 + 1 / kappa) / 4, rel=1e-9)
    # p = 0: specular only, x = 0.3 + 0.6·(k − 1) at collision k (the first flight is half as long)
    k = np.arange(6)
    msd, _, _ = analysis.strip_random_rank_msd(k, [0, 0.5], [0.6, 0.8], 1.5, 1.0, 0.1, 0.5, 0.0)
    np.testing.assert_allclose(msd, np.where(k > 0, 0.6 * k - 0.3, 0.0) ** 2, rtol=1e-12, atol=1e-15)


def test_graph_random_ensemble_diffuses_with_the_exact_coefficient():
    cfg, rec = run("graphRandom/ensemble.yaml", collisions=2000, trajectories=2000)
    x = rec["position"][:, :, 0]
    steps = np.arange(x.shape[1]) * cfg.output.every
    fit = analysis.fit_diffusion(steps, x, fit_from=0.1)
    init = cfg.resolved["initial"]
    exact, D, c = analysis.strip_random_rank_msd(steps, init["position"], init["velocity"], init["angular_velocity"],
                                                 1.0, cfg.ball.radius, cfg.ball.kappa, 0.5)
    assert D == pytest.approx(0.2784375, rel=1e-9) and abs(c) < 1.0
    assert abs(fit.coefficient - D) <= 1.5 * fit.half_width          # ±7% interval; a wrong D is off by far more
    assert abs(fit.coefficient - D) / D < 0.15
    msd = analysis.mean_square_displacement(x)
    slope = analysis.growth_exponent(steps, msd, 200, 2000)
    assert 0.9 < slope < 1.1
    # the fitted intercept is noise of ± several tens of L², not curvature
    assert abs(fit.intercept - c) <= 1.5 * fit.intercept_half_width


def test_billiard_sampled_starts_make_the_strip_msd_heavy_tailed():
    """Why graphRandom starts every trajectory in one state: |v_y| is conserved, so each trajectory diffuses with
    its own D ∝ 1/v_y², which has no finite mean under the cos law; a few grazing starts carry the MSD."""
    cfg = config.from_dict({"table": "../tables/strip.yaml", "boundary": "../boundary/random01.yaml",
                            "ball": {"radius": 0.1, "inertia": "uniform"},
                            "initial": {"sample": "billiard", "wall": "bottom"},
                            "run": {"collisions": 2000, "trajectories": 2000, "seed": 0},
                            "output": {"record": ["position", "velocity", "angular_velocity"], "every": 10}},
                           os.path.join(EXPERIMENTS, "sampled.yaml"))
    rec, _, _ = run_in_memory(cfg)
    x = rec["position"][:, :, 0]
    steps = np.arange(x.shape[1]) * 10
    v, w = rec["velocity"][:, 0], rec["angular_velocity"][:, 0]
    predicted = 0.75 * (0.8 / np.abs(v[:, 1])) ** 2 * (v[:, 0] ** 2 + 0.5 * 0.01 * w ** 2)
    window = steps >= 200
    tc = steps[window] - steps[window].mean()
    y = (x - x[:, :1])[:, window] ** 2
    D = 0.5 * (y - y.mean(axis=1, keepdims=True)) @ tc / (tc @ tc)
    ratio = D / predicted
    assert abs(ratio.mean() - 1) < 3 * ratio.std() / math.sqrt(len(ratio)) + 0.02   # each trajectory: its own D
    top = np.argsort(-predicted)[:len(D) // 100]
    assert D[top].sum() / D.sum() > 0.3                                               # 1% carry a third or more
    fit = analysis.fit_diffusion(steps, x)
    assert fit.half_width / fit.coefficient > 0.25                                    # hence a useless interval


# ---- plate and roughrank: the plates ---------------------------------------------------------------------------


def test_plate_rank_two_orbit_is_bounded():
    o, m = plates_orbit("plate.yaml", 100_000)
    assert m["eN"] <= 1.001 * m["e1"] and m["eN"] < 1.0
    assert m["exponent"] < 0.01 and m["tamsd_exponent"] < 0.1
    assert np.linalg.norm(m["drift"]) == pytest.approx(0, abs=1e-12)
    assert np.linalg.norm(m["measured_drift"]) < 1e-4 * m["speed"]


ROUGHRANK = sorted(os.path.basename(p) for p in glob.glob(os.path.join(EXPERIMENTS, "roughrank", "*.yaml")))


def test_roughrank_has_the_paper_three_conditions_and_the_reference():
    kinds = set()
    for name in ROUGHRANK:
        cfg = config.load(os.path.join(EXPERIMENTS, "roughrank", name))
        kinds.add(kind_of(cfg.wall_rules))
        assert cfg.resolved["initial"] == config.load(os.path.join(EXPERIMENTS, "plate.yaml")).resolved["initial"]
    assert kinds == {"both-random", "constant-random", "rank2-rank1", "rank2-rank2"}


@pytest.mark.parametrize("name", ROUGHRANK)
def test_roughrank_growth_and_drift(name):
    o, m = plates_orbit(f"roughrank/{name}", 100_000)
    kind = kind_of(o["rules"])
    if kind == "rank2-rank2":
        assert m["exponent"] < 0.01 and m["eN"] <= 1.001 * m["e1"]
        return
    assert m["exponent"] > 0.45                                  # unbounded: 0.68, 1.00, 1.00 at 10⁵ collisions
    drifts = kind in ("constant-random", "rank2-rank1")          # a state that slips in no rough direction exists
    assert m["drifts"] == drifts
    if drifts:
        assert m["exponent"] > 0.99 and m["tamsd_exponent"] > 1.95
        assert m["drift_error"] < 0.01
    if uses_random(o["rules"]):
        assert 0.85 < m["rest_tamsd_exponent"] < 1.15            # what is left is a random walk
    else:
        assert m["rest_exponent"] < 0.01                         # what is left is bounded


def test_conserved_drift_is_left_alone_by_every_collision_map():
    """The slip-free part of a state (rbx.analysis.slip_constraints) is fixed by the engine's collision map
    (rbx.physics) for every (wall, direction) pair the rules can use, and changed by a map outside them."""
    R, kappa = 0.1, 0.4
    geom = config.load(os.path.join(EXPERIMENTS, "plate.yaml")).geometry()
    rules = config.load(os.path.join(EXPERIMENTS, "roughrank", "constant-random.yaml")).wall_rules
    rough = analysis.rough_directions(rules, geom)
    assert len(rough) == 4                                       # bottom: 0°, 60°, 120°; top: 0°
    K = analysis.slip_constraints(rough, R, kappa)
    z = np.array([0.3, -0.5, 0.7, 0.04, 0.09, -0.02])           # (v, R√κ·ω), v_z = 0.7
    zF = z - np.linalg.pinv(K) @ (K @ z)
    assert np.linalg.norm(zF[:2]) > 0.1                          # a slip-free horizontal velocity exists
    v, w = zF[:3].copy(), zF[3:] / (R * math.sqrt(kappa))
    v[2] = 0.7
    for nu, d in rough:
        v2, W2 = collision_map(v, w, nu, R, kappa, 1, np.array([d, np.zeros(3)]))
        np.testing.assert_allclose(v2[:2], v[:2], atol=1e-12)
        np.testing.assert_allclose(spin_vector(W2), w, atol=1e-12)
        assert v2[2] == pytest.approx(-v[2])
    np.testing.assert_allclose(analysis.conserved_drift(z[:3], z[3:] / (R * math.sqrt(kappa)), rough, R, kappa)[:2],
                               zF[:2], atol=1e-12)
    # rank 1 along y on the top plate is not among the rules: it changes that state
    v3, _ = collision_map(v, w, np.array([0, 0, -1.0]), R, kappa, 1, np.array([[0, 1.0, 0], [0, 0, 0]]))
    assert np.linalg.norm(v3[:2] - v[:2]) > 1e-3
    # rank 2 on both plates: nothing horizontal is conserved
    both = analysis.rough_directions((Constant(2), Constant(2)), geom)
    assert np.linalg.norm(analysis.conserved_drift(z[:3], z[3:], both, R, kappa)[:2]) < 1e-12


def test_growth_exponents_and_time_averaged_msd():
    n = np.arange(1, 10_001, dtype=float)
    assert analysis.growth_exponent(n, 3 * n ** 0.5, 10, 1e4) == pytest.approx(0.5)
    line = np.stack([0.3 * n, -0.4 * n], axis=1)
    np.testing.assert_allclose(analysis.time_averaged_msd(line, [1, 10, 100]), 0.25 * np.array([1, 100, 1e4]))
    np.testing.assert_allclose(analysis.running_excursion(np.array([[0, 0], [3, 4], [1, 0], [0, 6.0]])),
                               [0, 5, 5, 6])


# ---- histogram ------------------------------------------------------------------------------------------------


def test_histogram_config_writes_into_data_and_returns_follow_the_law():
    cfg = config.load(os.path.join(EXPERIMENTS, "histogram.yaml"), {"trajectories": 20_000})
    assert cfg.output.path == os.path.join(ROOT, "data", "histogram.h5")
    r = return_experiment(cfg)
    assert r.not_returned == 0 and r.ks_pvalue > 0.01
    start, side, a, b, two = side_wall_comparison(r.angle, np.nonzero(r.returned)[0], r.initial_angle)
    assert 0.45 < side.mean() < 0.65                             # the rest come straight back from the top wall
    np.testing.assert_allclose(r.angle[~side], start[~side], atol=1e-12)
    assert two.pvalue > 0.01
    # a sampler with the wrong spin scale draws a measure the return map does not keep: both tests see it
    wrong = return_experiment(cfg, _spin_scale=1.3)
    *_, two_wrong = side_wall_comparison(wrong.angle, np.nonzero(wrong.returned)[0], wrong.initial_angle)
    assert wrong.ks_pvalue < 1e-10 and two_wrong.pvalue < 1e-6


# ---- end to end ------------------------------------------------------------------------------------------------


@pytest.mark.long
def test_simulate_then_figure_script(tmp_path):
    rbx = os.path.join(os.path.dirname(sys.executable), "rbx")
    h5 = tmp_path / "plate.h5"
    png = tmp_path / "plate.png"
    sim = subprocess.run([rbx, "simulate", os.path.join(EXPERIMENTS, "plate.yaml"), "-o", str(h5),
                          "--collisions", "20000", "--quiet"], capture_output=True, text=True, timeout=300)
    assert sim.returncode == 0, sim.stderr
    fig = subprocess.run([sys.executable, os.path.join(ROOT, "scripts", "fig_plate.py"), str(h5), "-o", str(png)],
                         capture_output=True, text=True, timeout=300, cwd=ROOT,
                         env={**os.environ, "MPLBACKEND": "Agg"})
    assert fig.returncode == 0, fig.stdout + fig.stderr
    assert png.stat().st_size > 10_000
    import json
    record = json.loads((tmp_path / "plate.json").read_text())
    assert record["label"] == "plate" and record["checks"] and all(c["ok"] for c in record["checks"])


@pytest.mark.long
def test_roughrank_script_end_to_end(tmp_path):
    # the four runs, shortened: the script must read them and draw (its checks may or may not hold on 4000
    # collisions; a traceback — a run file read the wrong way — is what this catches)
    rbx = os.path.join(os.path.dirname(sys.executable), "rbx")
    runs = []
    for name in ROUGHRANK:
        h5 = tmp_path / name.replace(".yaml", ".h5")
        sim = subprocess.run([rbx, "simulate", os.path.join(EXPERIMENTS, "roughrank", name), "-o", str(h5),
                              "--collisions", "4000", "--quiet"], capture_output=True, text=True, timeout=300)
        assert sim.returncode == 0, sim.stderr
        runs.append(str(h5))
    png = tmp_path / "roughrank.png"
    fig = subprocess.run([sys.executable, os.path.join(ROOT, "scripts", "fig_roughrank.py"), *runs, "-o", str(png)],
                         capture_output=True, text=True, timeout=300, cwd=ROOT, env={**os.environ, "MPLBACKEND": "Agg"})
    assert "Traceback" not in fig.stderr and fig.returncode in (0, 1), fig.stderr
    assert png.stat().st_size > 10_000
