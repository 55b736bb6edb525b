"""The invariant-measure experiment (paper §2.7; ``rbx histogram``, docs/reference.md §4) and Santaló's mean free
path.

Real runs at fixed seeds: billiard-measure samples on a wall are followed by the engine until they return to it,
and the return angles must follow the law of the billiard measure (KS against sin^(d−1) φ) — and must *not* when
the sampler is given a wrong spin scaling, which shows that the test can fail.
"""
import math
import os
import subprocess
import sys

import h5py
import numpy as np
import pytest
from scipy import stats

from rbx import analysis, config
from rbx.histogram import first_flight_times, return_experiment

P_PASS = 1e-3       # fixed seeds; correct runs give p ~ 0.2–0.8 here
P_FAIL = 1e-10      # the wrong-spin runs give p < 1e-30
M = 20_000

RECT = {"kind": "rectangle", "width": 2.0, "height": 1.0}
LSHAPE = {"kind": "polygon", "vertices": [[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]]}
BOX = {"kind": "box", "size": [1.0, 1.2, 0.8]}
ROUGH = {"rule": "constant", "rank": 1}
SMOOTH = {"rule": "constant", "rank": 0}
HEMISPHERE = {"rule": "hemisphere", "axis": [1.0, 0.0], "rough": ROUGH, "smooth": SMOOTH}
RANDOM = {"rule": "random", "choices": [SMOOTH, ROUGH], "probabilities": [0.5, 0.5]}
ROUGH3D = {"rule": "constant", "rank": 2}


def experiment(table, rule, wall, trajectories=M, seed=1, collisions=2000, inertia="uniform", radius=0.1):
    return config.from_dict({
        "table": table, "boundary": {"default": rule}, "ball": {"radius": radius, "inertia": inertia},
        "initial": {"sample": "billiard", "wall": wall} if wall else {"sample": "billiard"},
        "run": {"collisions": collisions, "trajectories": trajectories, "seed": seed},
        "output": {"record": []}})


# ---- the return-angle experiment -------------------------------------------------------------------------------


CASES = [
    ("rough", RECT, ROUGH, "bottom"),
    ("hemisphere", RECT, HEMISPHERE, "bottom"),
    ("random", RECT, RANDOM, "bottom"),
    ("rough-polygon", LSHAPE, ROUGH, "edge3"),            # edge3 carries the reflex-vertex arc
    ("rough-box", BOX, ROUGH3D, "bottom"),
]
IDS = [c[0] for c in CASES]


@pytest.mark.parametrize("name,table,rule,wall", CASES, ids=IDS)
def test_return_angles_follow_the_billiard_measure(name, table, rule, wall):
    res = return_experiment(experiment(table, rule, wall))
    n = 3 if table is BOX else 2
    assert res.d == analysis.velocity_dimension(n) == (6 if n == 3 else 3)
    assert res.not_returned <= 2, res.not_returned
    assert np.all(res.angle <= np.pi / 2)
    assert res.ks_pvalue > P_PASS, (name, res.ks_statistic, res.ks_pvalue)
    # the statistic is what scipy says for the exact CDF
    assert res.ks_statistic == pytest.approx(stats.kstest(res.angle, lambda x: np.sin(x) ** (res.d - 1)).statistic)


@pytest.mark.parametrize("name,table,rule,wall", CASES, ids=IDS)
def test_a_sampler_with_the_wrong_spin_scaling_fails(name, table, rule, wall):
    """Spin scaled by 2 at sampling: the start is off the billiard measure, so the return angles are too."""
    res = return_experiment(experiment(table, rule, wall), _spin_scale=2.0)
    assert res.ks_pvalue < P_FAIL, (name, res.ks_pvalue)


def test_specular_collisions_keep_the_law_too():
    """Rank 0 everywhere: spin never changes, the (v, R√κ·ω) angle law must still hold (a plain billiard in Q)."""
    res = return_experiment(experiment(RECT, SMOOTH, "bottom", trajectories=10_000, collisions=20_000))
    assert res.ks_pvalue > P_PASS


def test_other_inertia_and_the_whole_boundary():
    """A ring (κ = 1) and returns to the whole boundary (wall omitted: the next collision, on any wall)."""
    res = return_experiment(experiment(LSHAPE, ROUGH, None, trajectories=10_000, inertia="ring"))
    assert res.wall is None
    assert np.all(res.collisions == 1)
    assert res.ks_pvalue > P_PASS


def test_the_return_experiment_says_when_its_set_up_is_done_and_stops_there_if_told(monkeypatch):
    """``on_run`` is called once, after the states are drawn and the kernels compiled, before any block runs:
    `rbx histogram` switches there from aborting at a Ctrl-C to flagging it (a Ctrl-C while 10⁷ states were drawn
    waited 5-8 s for the first block). Told to stop there, nothing runs."""
    from rbx.simulation import Simulation
    events = []
    compile_kernels = Simulation.compile_kernels
    monkeypatch.setattr(Simulation, "compile_kernels", lambda sim: (events.append("compiled"), compile_kernels(sim)))
    cfg = experiment(RECT, ROUGH, "bottom", trajectories=200)

    def on_run(answer):
        events.append("on_run")
        return answer
    blocks = lambda done, total: events.append("block")      # noqa: E731
    with pytest.raises(KeyboardInterrupt):
        return_experiment(cfg, progress=blocks, on_run=lambda: on_run(True))
    assert events == ["compiled", "on_run"]
    events.clear()
    result = return_experiment(cfg, progress=blocks, on_run=lambda: on_run(False))
    assert events[:2] == ["compiled", "on_run"] and events[2:] and set(events[2:]) == {"block"}
    assert result.samples == 200


def test_trajectories_that_do_not_return_are_counted():
    """From the bottom of a rectangle a return takes at least two collisions (top, or a side and then …)."""
    res = return_experiment(experiment(RECT, ROUGH, "bottom", trajectories=2000, collisions=1))
    assert res.not_returned == 2000 and len(res.angle) == 0
    res = return_experiment(experiment(RECT, ROUGH, "bottom", trajectories=2000, collisions=2))
    assert 0 < res.not_returned < 2000
    assert len(res.angle) == 2000 - res.not_returned
    assert np.all(res.collisions[res.returned] == 2)
    # the returned angles are the fast returns only: no p-value (a test of the truncation), D describes them
    assert np.isnan(res.ks_pvalue) and 0 < res.ks_statistic < 1


def test_ten_to_the_five_samples_in_two_dimensions():
    # the paper's sample size (its run time is in docs/benchmarks.md's territory, not a test's)
    cfg = experiment(RECT, ROUGH, "bottom", trajectories=100_000)
    res = return_experiment(cfg)
    print(f"\n10^5 return angles in 2D: KS D = {res.ks_statistic:.4g}, p = {res.ks_pvalue:.3g}")
    assert res.returned.all()
    assert res.ks_pvalue > P_PASS


# ---- Santaló's mean free path ----------------------------------------------------------------------------------


def test_santalo_constants():
    """|S^(d−1)|/|B^(d−1)| from the sphere and ball volumes: |S^(d−1)| = 2π^(d/2)/Γ(d/2), |B^k| = π^(k/2)/Γ(k/2+1).
    d = 3 (disc + its angle): 4π/π = 4; d = 6 (ball + SO(3)): π³/(8π²/15) = 15π/8; d = 2 (point particle): π."""
    def sphere(d):
        return 2 * math.pi ** (d / 2) / math.gamma(d / 2)

    def ball(k):
        return math.pi ** (k / 2) / math.gamma(k / 2 + 1)
    for d in range(2, 9):
        assert analysis.santalo_constant(d) == pytest.approx(sphere(d) / ball(d - 1), rel=1e-14)
    assert analysis.santalo_constant(2) == pytest.approx(math.pi)
    assert analysis.santalo_constant(3) == pytest.approx(4.0)
    assert analysis.santalo_constant(6) == pytest.approx(15 * math.pi / 8)
    assert sphere(3) == pytest.approx(4 * math.pi) and ball(2) == pytest.approx(math.pi)
    assert sphere(6) == pytest.approx(math.pi ** 3) and ball(5) == pytest.approx(8 * math.pi ** 2 / 15)


def test_santalo_by_direct_integration_in_angle_position_space():
    """Without the engine: Q = rectangle × (angle circle), unit velocities with density ∝ cos φ in R³ drawn by
    rejection from the uniform sphere; the flight ends on the rectangle's walls only (the angle is periodic).
    Its mean is 4·|Q|/|∂Q| = 4·A/P — which fixes the constant 4 = |S²|/|B²| of the d = 3 formula."""
    rng = np.random.default_rng(3)
    a, b = 1.8, 0.8
    N = 400_000
    g = rng.standard_normal((3 * N, 3))
    u = g / np.linalg.norm(g, axis=1, keepdims=True)
    u = u[rng.uniform(size=3 * N) < np.abs(u[:, 2])][:N]           # cos-weighted about the z axis (= the normal)
    u[:, 2] = np.abs(u[:, 2])
    # walls of the rectangle chosen by length; on a wall of length ℓ: normal, tangent in the plane, angle axis
    wall = rng.choice(4, size=len(u), p=np.array([a, b, a, b]) / (2 * (a + b)))
    length = np.where(wall % 2 == 0, a, b)
    depth = np.where(wall % 2 == 0, b, a)
    s = rng.uniform(size=len(u)) * length
    vt, vn = u[:, 0], u[:, 2]                                        # u[:, 1] runs along the (periodic) angle
    t_far = depth / vn
    t_side = np.where(vt > 0, (length - s) / np.where(vt > 0, vt, 1), np.where(vt < 0, s / -np.where(vt < 0, vt, -1),
                                                                                np.inf))
    tau = np.minimum(t_far, t_side)
    mean, se = tau.mean(), tau.std() / math.sqrt(len(tau))
    assert abs(mean - 4 * a * b / (2 * (a + b))) < 4 * se


@pytest.mark.parametrize("name,table,rule,seed", [   # own seeds: the same seed would share velocity draws
    ("rectangle", RECT, ROUGH, 41), ("circle", {"kind": "circle", "radius": 1.0}, ROUGH, 42),
    ("L-polygon", LSHAPE, RANDOM, 43), ("box", BOX, ROUGH3D, 44)])
def test_mean_free_path_on_the_whole_boundary_is_santalos(name, table, rule, seed):
    """Mean first flight time of billiard-measure samples on the whole boundary, unit speed in (v, R√κ·ω):
    4·A/P for a disc, 15π/8·V/S for a ball, with A, P (V, S) of the shrunk table."""
    cfg = experiment(table, rule, None, trajectories=100_000, seed=seed)
    tau = first_flight_times(cfg)
    assert np.all(np.isfinite(tau))
    geom = cfg.geometry()
    expected = analysis.santalo_mean_free_path(geom)
    mean, se = tau.mean(), tau.std() / math.sqrt(len(tau))
    print(f"\n{name}: mean free path {mean:.5f} ± {se:.5f}, Santaló {expected:.5f}")
    assert abs(mean - expected) < 4 * se
    # the closed forms
    vol, surf = analysis.table_measure(geom)
    if name == "rectangle":
        assert (vol, surf) == pytest.approx((1.8 * 0.8, 2 * (1.8 + 0.8)))
        assert expected == pytest.approx(4 * vol / surf)
    if name == "circle":
        assert expected == pytest.approx(2 * 0.9)
    if name == "box":
        assert (vol, surf) == pytest.approx((0.8 * 1.0 * 0.6, 2 * (0.8 * 1.0 + 0.8 * 0.6 + 1.0 * 0.6)))
        assert expected == pytest.approx(15 * math.pi / 8 * vol / surf)


def test_shrunk_polygon_area_with_a_reflex_arc():
    """The divergence-theorem measure of the shrunk L against its closed form: two overlapping 1.8 × 0.8 bars plus
    the corner square [0.9, 1]² minus a quarter disc of radius R = 0.1 at the reflex vertex; the perimeter has six
    segments and a quarter circle."""
    geom = experiment(LSHAPE, ROUGH, None, trajectories=1).geometry()
    area, perimeter = analysis.table_measure(geom)
    R = 0.1
    assert area == pytest.approx(2 * 1.8 * 0.8 - 0.8 * 0.8 + R * R * (1 - math.pi / 4), rel=1e-13)
    assert perimeter == pytest.approx(1.8 + 0.8 + 0.9 + 0.9 + 0.8 + 1.8 + R * math.pi / 2, rel=1e-13)


# ---- the command -----------------------------------------------------------------------------------------------


def rbx(*args, cwd=None):
    exe = os.path.join(os.path.dirname(sys.executable), "rbx")
    return subprocess.run([exe, *args], capture_output=True, text=True, cwd=cwd, timeout=300)


def write_config(path, **over):
    cfg = {"table": "{kind: rectangle, width: 2.0, height: 1.0}", "boundary": "{default: {rule: constant, rank: 1}}",
           "ball": "{radius: 0.1}", "initial": "{sample: billiard, wall: bottom}",
           "run": "{collisions: 500, trajectories: 3000, seed: 2}", "output": "{path: returns.h5}"}
    cfg.update(over)
    path.write_text("".join(f"{k}: {v}\n" for k, v in cfg.items()))
    return path


@pytest.mark.long
def test_cli_writes_angles_figure_and_ks(tmp_path):
    conf = write_config(tmp_path / "h.yaml")
    r = rbx("histogram", str(conf), "-o", str(tmp_path / "h.png"))
    assert r.returncode == 0, r.stderr
    assert "Kolmogorov–Smirnov" in r.stdout and "p = " in r.stdout
    with h5py.File(tmp_path / "returns.h5") as f:
        angle = f["returns/angle"][...]
        attrs = dict(f["returns"].attrs)
        assert f.attrs["complete"] and f.attrs["table_kind"] == "rectangle"
    assert len(angle) == attrs["returned"] == 3000 - attrs["not_returned"]
    assert attrs["ks_pvalue"] == pytest.approx(stats.kstest(angle, lambda x: np.sin(x) ** 2).pvalue)
    assert attrs["ks_pvalue"] > P_PASS and attrs["wall"] == "bottom" and attrs["velocity_dimension"] == 3
    assert f"p = {attrs['ks_pvalue']:.4g}" in r.stdout
    png = (tmp_path / "h.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20_000
    # again without --force: refused, one line, exit 2; with --force: fine
    r = rbx("histogram", str(conf), "-o", str(tmp_path / "h.png"))
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "--force" in r.stderr
    assert rbx("histogram", str(conf), "-o", str(tmp_path / "h.png"), "--force").returncode == 0


@pytest.mark.long
def test_cli_user_errors(tmp_path):
    conf = write_config(tmp_path / "explicit.yaml", initial="{position: [1.0, 0.5], velocity: [1.0, 0.3]}")
    r = rbx("histogram", str(conf))
    assert r.returncode == 2 and r.stderr.startswith("rbx: ") and "initial" in r.stderr
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr
    r = rbx("histogram", str(tmp_path / "missing.yaml"))
    assert r.returncode == 2 and "missing.yaml" in r.stderr and "Traceback" not in r.stderr


@pytest.mark.long
def test_cli_writes_only_where_its_files_may_go_and_says_so_before_sampling(tmp_path):
    """The figure as rbx plot's -o: not through a link, not over a file that is not a figure (even with --force),
    not into a missing folder; and a read-only folder for the return angles is found before the samples are drawn
    (they were drawn, then lost to a traceback). Each one line, exit 2, nothing written."""
    conf = write_config(tmp_path / "h.yaml")
    (tmp_path / "notes.txt").write_text("mine\n")
    os.symlink(tmp_path / "notes.txt", tmp_path / "link.png")
    (tmp_path / "text.png").write_text("mine\n")
    for fig, words in (("link.png", "symbolic link"), ("text.png", "is not a figure"),
                       ("no/such/h.png", "does not exist")):
        r = rbx("histogram", str(conf), "-o", str(tmp_path / fig), "--data", str(tmp_path / "a.h5"), "--force")
        assert r.returncode == 2 and r.stderr.count("\n") == 1 and words in r.stderr, (fig, r.stderr)
    assert (tmp_path / "notes.txt").read_text() == (tmp_path / "text.png").read_text() == "mine\n"
    assert not (tmp_path / "a.h5").exists() and not (tmp_path / "no").exists()
    from tests.test_reliability3 import tmpfs
    with tmpfs(tmp_path / "ro", "1m") as ro:
        subprocess.run(["mount", "-o", "remount,ro", str(ro)], check=True)
        r = rbx("histogram", str(conf), "-o", str(tmp_path / "h.png"), "--data", str(ro / "a.h5"))
        assert r.returncode == 2 and r.stderr.count("\n") == 1 and "cannot be written" in r.stderr, r.stderr
        assert "Traceback" not in r.stderr and not (tmp_path / "h.png").exists()


@pytest.mark.long
def test_cli_reports_trajectories_that_did_not_return(tmp_path):
    conf = write_config(tmp_path / "short.yaml", run="{collisions: 2, trajectories: 500, seed: 2}")
    r = rbx("histogram", str(conf))
    assert r.returncode == 0, r.stderr
    assert "did not return within 2 collisions" in r.stderr
    with h5py.File(tmp_path / "returns.h5") as f:
        missing = int(f["returns"].attrs["not_returned"])
        assert np.isnan(f["returns"].attrs["ks_pvalue"])          # the file gives no p-value either
    assert 0 < missing < 500
    # the slow returns are the ones left out: a p-value of the others would test the truncation, so none is given,
    # and stdout says why and what to do
    assert "p = " not in r.stdout, r.stdout
    assert f"{missing} of 500 samples did not return" in r.stdout and "raise run.collisions" in r.stdout
    assert "biased" in r.stdout


def test_the_histogram_figure_gives_no_p_value_when_samples_did_not_return():
    from rbx import plotting
    angle = np.linspace(0.1, 1.4, 50)
    full = plotting.histogram_figure(angle, 3, 0.05, 0.5, "t")
    assert "p = 0.5" in full.axes[0].get_legend_handles_labels()[1][1]
    cut = plotting.histogram_figure(angle, 3, 0.05, 0.5, "t", not_returned=12)
    labels = " ".join(cut.axes[0].get_legend_handles_labels()[1])
    assert "p = " not in labels and "12 of 62 samples did not return" in labels and "no KS test" in labels and "run.collisions" in labels


def test_cli_refuses_a_histogram_of_no_return(tmp_path):
    """No sample returned: nothing to compare, so one line, exit 2, and neither file written (the angles would be
    an empty list); no NumPy warning either."""
    conf = write_config(tmp_path / "none.yaml", run="{collisions: 1, trajectories: 200, seed: 2}")
    r = rbx("histogram", str(conf), "-o", str(tmp_path / "none.png"))
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert r.stderr.count("\n") == 1 and r.stderr.startswith(f"rbx: {conf}: run.collisions: "), r.stderr
    assert "no sample returned" in r.stderr and "raise run.collisions" in r.stderr
    assert "Warning" not in r.stderr + r.stdout
    assert not (tmp_path / "none.png").exists() and not (tmp_path / "returns.h5").exists()


@pytest.mark.long
def test_a_figure_that_cannot_be_written_says_the_samples_are_kept(tmp_path):
    """The samples are written first; a figure that then fails (here a .pgf without LaTeX) said only that, exit 2,
    and the user did not know the samples were there."""
    import shutil
    if shutil.which("xelatex"):
        pytest.skip("LaTeX is installed: a .pgf figure is written")
    conf = write_config(tmp_path / "c.yaml", run="{collisions: 1000, trajectories: 50, seed: 2}")
    r = rbx("histogram", str(conf), "-o", str(tmp_path / "h.pgf"), "--quiet")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "Traceback" not in r.stderr, r.stderr
    assert "cannot write the figure" in r.stderr and "the samples are kept in" in r.stderr, r.stderr
    assert (tmp_path / "returns.h5").exists() and not (tmp_path / "h.pgf").exists()


def test_a_killed_runs_partial_under_the_samples_name_is_named_and_kept(tmp_path):
    """rbx histogram --data k.h5 --force beside a killed rbx simulate's k.h5.partial said "remove it or use
    --force" (given already). It says whose file it is and how to continue it, and leaves it."""
    import rbx as api
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    api.simulate(api.load(os.path.join(root, "configs", "examples", "strip.yaml")), collisions=20,
                 output=str(tmp_path / "run.h5"))
    (tmp_path / "returns.h5.partial").write_bytes((tmp_path / "run.h5").read_bytes())
    conf = write_config(tmp_path / "c.yaml", run="{collisions: 1000, trajectories: 50, seed: 2}")
    r = rbx("histogram", str(conf), "-o", str(tmp_path / "h.png"), "--force", "--quiet", cwd=tmp_path)
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert "returns.h5.partial: is the unfinished run file of rbx simulate" in r.stderr and \
        "rbx simulate --resume" in r.stderr and "--force" not in r.stderr, r.stderr
    assert (tmp_path / "returns.h5.partial").read_bytes() == (tmp_path / "run.h5").read_bytes()


@pytest.mark.long
def test_the_config_named_as_the_figure_is_refused_as_such(tmp_path):
    """rbx histogram c.yaml -o c.yaml said "exists; use --force to overwrite it", then, with --force, that it is no
    figure: it says at once that it is the config."""
    conf = write_config(tmp_path / "c.yaml", run="{collisions: 1000, trajectories: 50, seed: 2}")
    for extra in ((), ("--force",)):
        r = rbx("histogram", str(conf), "-o", str(conf), *extra, cwd=tmp_path)
        assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
        assert r.stderr.endswith("c.yaml: -o: is the config: give the figure a name of its own, such as "
                                 "histogram.png\n"), r.stderr
    assert conf.read_text().startswith("table:") and not (tmp_path / "returns.h5").exists()


@pytest.mark.long
def test_returns_to_an_exit_are_refused_not_tested(tmp_path):
    """A contact with an exit wall is the arriving state, no map applied (its angle to the normal above 90°): sampled
    on the escape example's gate, rbx histogram reported KS D = 1, p = 0 against the billiard measure, exit 0, with
    an empty histogram. Refused in one line by the command, the API and the study observable alike; without a wall,
    a table with an exit is refused too (its next contact may be the exit)."""
    from rbx.observables import get
    example = os.path.join(os.path.dirname(__file__), "..", "configs", "examples", "escape-sinai.yaml")
    gate = config.load(example, changes={"initial": {"sample": "billiard", "wall": "gate"}})
    r = rbx("histogram", example, "--set", "initial={sample: billiard, wall: gate}", "--trajectories", "50",
            "--data", str(tmp_path / "g.h5"), "-o", str(tmp_path / "g.png"))
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert "initial.wall: the sampled wall 'gate' has the rule exit" in r.stderr, r.stderr
    assert not os.listdir(tmp_path)
    with pytest.raises(ValueError, match="the sampled wall 'gate' has the rule exit"):
        return_experiment(gate)
    assert "has the rule exit" in get("return_angle_ks").problem(gate, {})
    whole = config.load(example)                        # states on every wall: the next contact may be the gate
    with pytest.raises(ValueError, match="wall 'gate' has the rule exit, and without initial.wall"):
        return_experiment(whole)
    floor = config.load(example, changes={"initial": {"sample": "billiard", "wall": "floor"}})
    # on a wall without exit in a table with one: orbits leave before they return (they were 'not returned: raise
    # run.collisions', and a hundred times the collisions changed nothing)
    with pytest.raises(ValueError, match="wall 'gate' has the rule exit: orbits leave through it before they return"):
        return_experiment(floor)
    closed = config.load(example, changes={"initial": {"sample": "billiard", "wall": "floor"},
                                           "boundary.walls.gate": {"rule": "constant", "rank": 0}})
    assert return_experiment(closed.replace(run={"collisions": 50, "trajectories": 4, "seed": 1})).samples == 4


def test_a_return_loop_shares_each_blocks_work_among_the_trajectories_still_out(monkeypatch):
    """Nothing recorded, a block's work was split among all M trajectories whether or not they had returned, and
    every block checked all M states: a return loop of 2·10⁶ samples, whose last blocks ran a few stragglers one
    collision a block, did not finish in 7 minutes (8.7 s now). The blocks now grow as trajectories return, and
    only the trajectories alive when a block began are checked after it. The same return angles either way."""
    from rbx import simulation
    exp = experiment(RECT, ROUGH, "bottom", trajectories=400, collisions=5000)
    before = return_experiment(exp)
    monkeypatch.setattr(simulation, "BLOCK_WORK", 400)      # one collision a trajectory while all 400 are out
    blocks, checked = [], []
    real_advance, real_check = simulation.Simulation.advance, simulation.Simulation.check_finite

    def advance(self, stop, bufs):
        blocks.append(int(self.alive.sum()))
        return real_advance(self, stop, bufs)

    def check(self, *rows):
        checked.append(self.M if not rows or rows[0] is None else len(rows[0]))
        return real_check(self, *rows)
    monkeypatch.setattr(simulation.Simulation, "advance", advance)
    monkeypatch.setattr(simulation.Simulation, "check_finite", check)
    after = return_experiment(exp)
    np.testing.assert_array_equal(after.angle, before.angle)
    np.testing.assert_array_equal(after.collisions, before.collisions)
    longest = int(after.collisions.max())
    assert longest > 30                                       # a tail of stragglers, or the test shows nothing
    # a collision a block while all are out, then longer blocks: far fewer blocks than collisions of the longest
    assert len(blocks) - 1 < longest / 2, (len(blocks), longest)
    # after each block, the trajectories alive when it began (blocks[0] is the compile's call, which runs none)
    assert checked[0] == 400 and checked[1:] == blocks[1:] and checked[-1] < 400, (checked, blocks)
