"""What a new user met next, through the real ``rbx`` (subprocesses) and its figures:

- the escape plot says what it measured: on a table that traps orbits (a rough rectangle whose floor is a hole)
  the trapped share with its Wilson interval (the ``trapped_share`` observable of rbx sweep), the exponential fitted
  to the trajectories that leave and drawn only over its window, no small-hole rate for a hole that is a whole
  wall; on a Sinai table with a small gate, the small-hole rate and no trapped share;
- the one-time compile is said as such, and ``scripts/warm_up.py`` (``make warm-up``, part of ``make
  reproduce-figures``) fills the kernel cache so that an example's first run compiles nothing;
- the smaller points: diffusion per unit time as well as per collision; an option a plot kind does not use is
  refused (``--coordinate`` with ``--kind orbit`` was ignored); the 3D kinds name every 3D table; ``plot --help``
  describes every kind; ``--dpi``'s help holds no development note; "1 trajectory"; a 200-frame GIF well under
  the 7 MB it was; a bare ``rbx`` shows the help and exits 0; the Birkhoff map of an unbounded wall (the strip's).
"""
import os
import re
import subprocess
import sys

import h5py
import matplotlib
import numpy as np
import pytest
import yaml

import rbx
from rbx.analysis import wilson
from rbx.cli.plot import KINDS, make_figure
from tests.test_interrupt import RBX

matplotlib.use("Agg")
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
EXAMPLES = os.path.join(ROOT, "configs", "examples")

#: a rough 2 × 1 rectangle whose floor is a hole, billiard-measure starts: a few per cent of the orbits never reach
#: the floor (rough tables trap), the rest leave within a path of about 20
TRAP = {"table": {"kind": "rectangle", "width": 2.0, "height": 1.0},
        "boundary": {"default": {"rule": "constant", "rank": 1}, "walls": {"bottom": {"rule": "exit"}}},
        "ball": {"radius": 0.1, "inertia": "uniform"}, "initial": {"sample": "billiard"},
        "run": {"collisions": 2000, "trajectories": 1000, "seed": 1},
        "output": {"path": "trap.h5", "record": ["time", "wall", "rank"], "every": 10}}


def cli(*args, cwd, env=None):
    return subprocess.run([RBX, *map(str, args)], capture_output=True, text=True, cwd=cwd, timeout=900,
                          env=None if env is None else {**os.environ, **env})


def one_line(res):
    assert res.returncode == 2, (res.returncode, res.stdout, res.stderr)
    assert "Traceback" not in res.stderr and res.stderr.count("\n") == 1, res.stderr
    return res.stderr.rstrip("\n")


def legend(fig):
    return [t.get_text() for leg in fig.legends for t in leg.get_texts()]


# ---- the escape plot ------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def trap(tmp_path_factory):
    folder = tmp_path_factory.mktemp("trap")
    (folder / "trap.yaml").write_text(yaml.safe_dump(TRAP))
    res = cli("simulate", "trap.yaml", "-o", "trap.h5", "--quiet", cwd=folder)
    assert res.returncode == 0, res.stderr
    return folder


@pytest.mark.long
def test_a_table_that_traps_gets_its_trapped_share_with_its_interval(trap):
    res = cli("plot", "trap.h5", "--kind", "escape", "-o", "escape.png", "--quiet", cwd=trap)
    assert res.returncode == 0, res.stderr
    esc = rbx.escape_times(rbx.open(str(trap / "trap.h5")))
    k, n = int(np.sum(~esc.exited)), len(esc.exited)
    assert 0 < k < n // 5            # a few per cent trapped: the case the plot must recognise
    share, low, high = wilson(k, n)
    # the observable of a study gives the same share and says that survival has levelled off
    from rbx.observables import PointRuns, get
    value = get("trapped_share").compute(PointRuns(rbx.open(str(trap / "trap.h5")).experiment,
                                                   rbx.open(str(trap / "trap.h5"))), {})
    assert value.value == share and value.companions["levelled"] == 1.0
    said = res.stdout
    assert f"trapped share {100 * share:.3g} % (Wilson interval, z = 1: {100 * low:.3g}–{100 * high:.3g} %) of " \
           f"{n} starts" in said, said
    # the rate and the level are fitted together (rbx.escape), and only over a window where the curve follows the
    # data (tests/test_escape_fit.py); the drawn curve is what the text says, and levels off above the share's
    # interval's floor
    m = re.search(r"escape rate γ = ([0-9.e+-]+) ± ([0-9.e+-]+) per unit path \(fitted over ([0-9.e+-]+) ≤ s ≤ "
                  r"([0-9.e+-]+), with the level", said)
    assert m or said.startswith("no escape rate"), said
    fig = make_figure(str(trap / "trap.h5"), "escape")
    texts = legend(fig)
    assert any(t.startswith("trapped share") for t in texts), texts
    assert not any("small-hole" in t for t in texts), texts        # the hole is a whole wall
    fits = [line for line in fig.axes[0].get_lines() if "γ =" in line.get_label()]
    assert len(fits) == (1 if m else 0)
    if m:
        x, y = fits[0].get_data()
        assert f"{x.min():.3g}" == m.group(3) and f"{x.max():.3g}" == m.group(4)
        assert np.all(y > low)


@pytest.mark.long
def test_a_small_gate_gets_the_small_hole_rate_and_no_trapped_share(tmp_path):
    config = os.path.join(EXAMPLES, "escape-sinai.yaml")
    # point-particle starts: one rate (billiard-measure starts of a disc keep their spins under these specular
    # walls, each orbit its own rate: tests/test_escape_fit.py)
    res = cli("simulate", config, "-o", "esc.h5", "--collisions", "1000", "--trajectories", "400", "--quiet",
              "--set", "initial={sample: point_particle}", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    fig = make_figure(str(tmp_path / "esc.h5"), "escape")
    texts = legend(fig)
    assert any(t.startswith("small-hole rate") for t in texts), texts
    assert not any("trapped" in t for t in texts), texts


@pytest.mark.long
def test_the_small_hole_rate_follows_the_velocity_space_the_orbits_fill():
    """|hole|/(C_d·|table|) with d the velocity dimension the orbits fill: a point particle under specular walls
    keeps no spin (d = 2, C = π: the classic small-hole rate), a disc with spin d = 3 (C = 4); point-particle starts
    under a rough wall gain spin (d = 3). Drawn with d = 3 for point-particle starts, the reference line lay 21 %
    below the classic rate the data followed."""
    from rbx.analysis import orbit_velocity_dimension, santalo_constant
    config = os.path.join(EXAMPLES, "escape-sinai.yaml")
    point = {"initial": {"sample": "point_particle"}}
    assert orbit_velocity_dimension(rbx.load(config)) == 3              # billiard-measure starts carry spin
    assert orbit_velocity_dimension(rbx.load(config, point)) == 2
    assert orbit_velocity_dimension(rbx.load(config, {**point, "boundary.default.rank": 1})) == 3
    still = {"initial": [{"position": [0.3, 0.3], "velocity": [1.0, 0.2]}]}
    assert orbit_velocity_dimension(rbx.load(config, still)) == 2        # explicit starts without spin
    spun = {"initial": [{"position": [0.3, 0.3], "velocity": [1.0, 0.2], "angular_velocity": 0.5}]}
    assert orbit_velocity_dimension(rbx.load(config, spun)) == 3
    assert santalo_constant(2) == pytest.approx(np.pi) and santalo_constant(3) == pytest.approx(4.0)
    from rbx.analysis import starts_phrase        # said in the escape plot's and a study's title
    assert [starts_phrase(rbx.load(config, c)) for c in ({}, point, still)] == \
        ["billiard-measure starts", "point-particle starts", "fixed starts"]
    assert starts_phrase(rbx.load(config, {"initial": {"sample": "billiard", "wall": "floor"}})) == \
        "billiard-measure starts on floor"


# ---- the one-time compile -------------------------------------------------------------------------------------


@pytest.mark.long
def test_the_warm_up_fills_the_cache(tmp_path):
    """A fresh kernel cache warmed by scripts/warm_up.py: the example's first run loads (nothing compiled). (That a
    first run in a cold cache says it compiled, once, and the next loads: tests/test_cli_simulate.py.) Seconds are
    not asserted."""
    example = os.path.join(EXAMPLES, "strip.yaml")     # the example whose loop compiles fastest (2 s, the wedge's 4)
    warm = {"NUMBA_CACHE_DIR": str(tmp_path / "warm")}
    res = subprocess.run([sys.executable, os.path.join(ROOT, "scripts", "warm_up.py"), example], capture_output=True,
                         text=True, cwd=tmp_path, timeout=900, env={**os.environ, **warm})
    assert res.returncode == 0 and "the kernels of 1 example are in the cache" in res.stdout, res.stderr
    after = cli("simulate", example, "-o", "c.h5", cwd=tmp_path, env=warm)
    assert "setting up" in after.stderr and "compiling" not in after.stderr, after.stderr


# ---- the smaller points ---------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def lorentz(tmp_path_factory):
    folder = tmp_path_factory.mktemp("lorentz")
    res = cli("simulate", os.path.join(EXAMPLES, "lorentz.yaml"), "-o", "gas.h5", "--collisions", "2000",
              "--trajectories", "32", "--quiet", cwd=folder)
    assert res.returncode == 0, res.stderr
    return folder / "gas.h5"


@pytest.mark.long
def test_diffusion_is_given_per_unit_time_as_well_as_per_collision(lorentz):
    fig = make_figure(str(lorentz), "diffusion")
    text = " ".join(legend(fig))
    # (this gas has free corridors: the number is b, half the MSD's slope over the window, not D)
    m = re.search(r"b = ([0-9.e+-]+) ± [0-9.e+-]+ L²/collision.*= ([0-9.e+-]+) ± [0-9.e+-]+ L²/T per unit time "
                  r"\(mean time per collision ([0-9.e+-]+) T\)", text, re.S)
    assert m, text
    per_collision, per_time, tau = (float(m.group(i)) for i in (1, 2, 3))
    run = rbx.open(str(lorentz))
    assert tau == pytest.approx(np.mean(run.time[:, -1] - run.time[:, 0]) / (run.step[-1] - run.step[0]), rel=1e-3)
    # each printed to its error's second digit: equal within half a unit of the last digit of each
    last = [10.0 ** -len(m.group(i).split(".")[1]) if "." in m.group(i) else 1.0 for i in (1, 2)]
    assert abs(per_time - per_collision / tau) <= last[1] / 2 + last[0] / 2 / tau + 1e-12, (per_time, per_collision)
    # the same coefficient from the displacements against each trajectory's own time, to its statistical error
    dx = run.position[:, -1, 0] - run.position[:, 0, 0]
    direct = np.mean(dx ** 2) / (2 * np.mean(run.time[:, -1] - run.time[:, 0]))
    assert per_time == pytest.approx(direct, rel=0.5)


@pytest.mark.long
def test_the_diffusion_of_the_orientation_is_in_radians_and_its_options_are_checked(tmp_path):
    """theta was labelled in L, L² and 1/L; --coordinate z of a 2D run said the table was bounded along z; --fit-from
    −1 was taken and NaN said the window held too few records; a window whose interval reaches 0 gave a negative D,
    exit 0, without a word."""
    from rbx.cli.common import UserError
    out = str(tmp_path / "strip.h5")
    graph = os.path.join(ROOT, "configs", "experiments", "graphRandom", "ensemble.yaml")    # the random strip
    rbx.simulate(rbx.load(graph, {"run.trajectories": 64, "run.collisions": 400,
                                  "output.record": ["time", "position", "orientation"], "output.every": 1}),
                 output=out)
    fig = make_figure(out, "diffusion", coordinate="theta")
    labels = [ax.get_ylabel() for ax in fig.axes] + [ax.get_xlabel() for ax in fig.axes]
    assert "MSD ⟨Δtheta²⟩ [rad²]" in labels and "displacement Δtheta [rad]" in labels and "density [1/rad]" in labels
    assert "L²" not in " ".join(legend(fig)) and "rad²/collision" in " ".join(legend(fig))
    with pytest.raises(UserError, match="a 2D run has no coordinate z") as info:
        make_figure(out, "diffusion", coordinate="z")
    assert info.value.key == "--coordinate"
    for wrong in (-1.0, float("nan"), 1.0):
        with pytest.raises(UserError, match=r"in \[0, 1\)") as info:
            make_figure(out, "diffusion", fit_from=wrong)
        assert info.value.key == "--fit-from"
    late = make_figure(out, "diffusion", fit_from=0.99)           # 4 records: the interval reaches below 0
    assert late.rbx_result.endswith("its interval reaches 0 or below: no diffusion can be read from this window "
                                    "(fit from earlier, or run longer)"), late.rbx_result
    assert "its interval reaches" not in make_figure(out, "diffusion").rbx_result


@pytest.mark.long
def test_an_option_the_kind_does_not_use_is_refused(lorentz):
    line = one_line(cli("plot", lorentz, "--kind", "orbit", "--coordinate", "vx", cwd=lorentz.parent))
    assert line == "rbx: --coordinate: is for --kind series and --kind diffusion only; --kind orbit does not use it"
    line = one_line(cli("plot", lorentz, "--kind", "series", "--wall", "scatterer", cwd=lorentz.parent))
    assert line.startswith("rbx: --wall: is for --kind birkhoff only")
    res = cli("plot", lorentz, "--kind", "series", "--coordinate", "vx", "-o", "s.png", "--quiet", cwd=lorentz.parent)
    assert res.returncode == 0, res.stderr
    # the escape plot reads each trajectory's whole run: a --records range changed nothing but its title
    line = one_line(cli("plot", lorentz, "--kind", "escape", "--records", "0:5", cwd=lorentz.parent))
    assert line == "rbx: --records: --kind escape does not use it", line
    # a study's figure draws its points: records and trajectories of runs are not in its file
    for option, value in (("--records", "0:5"), ("--trajectories", "0")):
        line = one_line(cli("plot", "study.nc", "--kind", "sweep", option, value, cwd=lorentz.parent))
        assert line == f"rbx: {option}: --kind sweep does not use it", line


@pytest.mark.long
def test_the_3d_kinds_name_every_3d_table(lorentz):
    for kind in ("orbit3d", "poincare"):
        line = one_line(cli("plot", lorentz, "--kind", kind, cwd=lorentz.parent))
        assert "sphere" in line and "cylinder" in line and "(plates or box)" not in line, line


def test_plot_help_describes_every_kind_and_dpi_without_a_development_note():
    res = subprocess.run([RBX, "plot", "--help"], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0
    for kind in KINDS:
        assert re.search(rf"^\s+{kind}\s+\S", res.stdout, re.M), (kind, res.stdout)
    dpi = res.stdout[res.stdout.index("--dpi"):]
    dpi = dpi[:dpi.index("--quiet")]
    assert "memory" not in dpi and "100 000" not in dpi, dpi


@pytest.mark.long
def test_one_trajectory_is_singular(tmp_path):
    """A hole nobody reaches: one trajectory flying between the side walls of a rectangle whose floor is a hole."""
    config = dict(TRAP, boundary={"default": {"rule": "constant", "rank": 0}, "walls": {"bottom": {"rule": "exit"}}},
                  initial={"position": [1.0, 0.5], "velocity": [1.0, 0.0], "angular_velocity": 0.0},
                  run={"collisions": 50})
    (tmp_path / "one.yaml").write_text(yaml.safe_dump(config))
    res = cli("simulate", "one.yaml", "-o", "one.h5", cwd=tmp_path)
    assert res.returncode == 0 and "1 trajectory × 50 collisions" in res.stderr, res.stderr
    assert ": rectangle, 1 trajectory × 6 records of " in repr(rbx.open(str(tmp_path / "one.h5")))
    line = one_line(cli("plot", "one.h5", "--kind", "escape", cwd=tmp_path))
    assert "the trajectory did not reach an exit wall in 50 collisions" in line and "1 trajectories" not in line, line


@pytest.mark.heavy
def test_a_200_frame_gif_is_small(tmp_path):
    res = cli("simulate", os.path.join(EXAMPLES, "circle.yaml"), "-o", "c.h5", "--collisions", "300", "--quiet",
              cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    res = cli("animate", "c.h5", "-o", "c.gif", "--quiet", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    from PIL import Image
    with Image.open(tmp_path / "c.gif") as gif:
        assert gif.n_frames == 200
    # one palette, no dithering: a frame stores only the rectangle where the ball moved (it was 7.3 MB)
    assert os.path.getsize(tmp_path / "c.gif") < 2_000_000, os.path.getsize(tmp_path / "c.gif")


def test_a_bare_rbx_shows_the_help_and_exits_0():
    res = subprocess.run([RBX], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert res.stdout.startswith("Usage: rbx") and "simulate" in res.stdout and res.stderr == ""


@pytest.mark.long
def test_the_birkhoff_map_of_the_strips_unbounded_wall(tmp_path):
    res = cli("simulate", os.path.join(EXAMPLES, "strip.yaml"), "-o", "strip.h5", "--collisions", "500", "--quiet",
              cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    res = cli("plot", "strip.h5", "--kind", "birkhoff", "--wall", "bottom", "-o", "b.png", cwd=tmp_path)
    assert res.returncode == 0 and "NaN" not in res.stderr and (tmp_path / "b.png").stat().st_size > 10_000, \
        res.stderr
    fig = make_figure(str(tmp_path / "strip.h5"), "birkhoff", wall="bottom")
    lo, hi = fig.axes[0].get_xlim()
    points = np.concatenate([c.get_offsets() for c in fig.axes[0].collections])
    with h5py.File(tmp_path / "strip.h5") as f:
        hits = int(np.sum(f["collisions/wall"][0, 1:] == 0))
    assert len(points) == hits > 0 and np.isfinite([lo, hi]).all()
    assert lo <= points[:, 0].min() and points[:, 0].max() <= hi
    line = one_line(cli("plot", "strip.h5", "--kind", "birkhoff", cwd=tmp_path))
    assert line.endswith("the table is unbounded: choose one wall with --wall"), line


@pytest.mark.long
def test_a_complete_run_that_recorded_nothing_is_said_so_and_its_escape_drawn(tmp_path):
    """A run with output.record: [] was refused by every --kind as 'holds no records yet … resume it', while its
    resume said it was complete. Its escape plot reads the final states; the other kinds say what it lacks."""
    from rbx.cli.common import UserError
    out = str(tmp_path / "none.h5")
    rbx.simulate(rbx.load(os.path.join(EXAMPLES, "escape-sinai.yaml"),
                          {"output.record": [], "run.trajectories": 200}), output=out)
    fig = make_figure(out, "escape")
    assert fig.texts[0].get_text().endswith("no records kept (output.record: [])"), fig.texts[0].get_text()
    assert "(every one exited) · billiard-measure starts" in fig.texts[0].get_text()       # which starts: 4 or π
    with pytest.raises(UserError, match=r"recorded no fields \(output.record: \[\]\)"):
        make_figure(out, "orbit")


def test_copies_of_one_orbit_count_once_in_the_escape_plot(tmp_path):
    """[A, A, B] fixed starts with no random numbers drawn: A's exit counted twice made survival fall by a half in one
    step. The plot counts the distinct orbits."""
    out = str(tmp_path / "copies.h5")
    a = {"position": [0.5, 0.3], "velocity": [0.6, 0.8]}
    b = {"position": [1.5, 1.2], "velocity": [-0.8, 0.6]}
    with pytest.warns(RuntimeWarning, match="only 2 of the 3 trajectories"):
        rbx.simulate(rbx.load(os.path.join(EXAMPLES, "escape-sinai.yaml"),
                              {"initial": [a, a, b], "run.trajectories": 3, "run.collisions": 3000}), output=out)
    fig = make_figure(out, "escape")
    survival = [t for t in legend(fig) if t.startswith("Kaplan–Meier survival")]
    assert survival and "of 2 exited" in survival[0], survival
