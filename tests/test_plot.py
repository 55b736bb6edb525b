"""``rbx plot`` and the analysis behind it, on small real runs written by ``rbx simulate`` in a temporary folder.

Every kind renders (in-process: the Figure's axes carry labels with units and the title names the scene and
rule; through the CLI in a subprocess: a PNG of reasonable size), the coordinates the pictures show obey the
physics they should (conserved planes, the closed-form rough map, caustic periodicity), and bad files give exit
code 2 with one line.
"""
import math
import os
import subprocess
import sys

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from rbx import analysis
from rbx.cli.main import cli
from rbx.cli.plot import make_figure
from rbx.cli.common import UserError
from rbx.reader import Run

ROUGH = "{rule: constant, rank: 1}"
RUNS = {
    "strip": f"""table: {{kind: strip, width: 1.0}}
boundary: {{default: {{rule: hemisphere, axis: [1.0, 0.0], rough: {ROUGH}, smooth: {{rule: constant, rank: 0}}}}}}
ball: {{radius: 0.1}}
initial: {{position: [0.0, 0.5], velocity: [0.6, 0.8], angular_velocity: 0.0, orientation: 0.3}}
run: {{collisions: 3000}}
""",
    "random": """table: {kind: strip, width: 1.0}
boundary: {default: {rule: random, choices: [{rule: constant, rank: 0}, {rule: constant, rank: 1}],
                     probabilities: [0.5, 0.5]}}
ball: {radius: 0.1}
initial: {sample: billiard, wall: bottom}
run: {collisions: 1000, trajectories: 40, seed: 3}
output: {record: [position], every: 5}
""",
    "lshape": f"""table: {{kind: polygon, vertices: [[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]]}}
boundary: {{default: {ROUGH}}}
ball: {{radius: 0.1}}
initial: {{sample: billiard}}
run: {{collisions: 300, trajectories: 3, seed: 1}}
""",
    "circle": f"""table: {{kind: circle, radius: 1.0}}
boundary: {{default: {ROUGH}}}
ball: {{radius: 0.1}}
initial: [{{position: [0.2, 0.1], velocity: [0.6, 0.8], angular_velocity: 1.0}},
          {{position: [0.5, 0.0], velocity: [0.1, 1.0], angular_velocity: -2.0}}]
run: {{collisions: 200}}
""",
    "plates": """table: {kind: plates, gap: 1.0}
boundary: {default: {rule: constant, rank: 2}}
ball: {radius: 0.1}
initial: {position: [0, 0, 0.5], velocity: [0.6, 0.3, 0.7], angular_velocity: [0.2, -1.0, 0.5]}
run: {collisions: 400}
""",
    "box": """table: {kind: box, size: [1.0, 1.2, 0.8]}
boundary: {default: {rule: constant, rank: 2}}
ball: {radius: 0.1}
initial: {sample: billiard}
run: {collisions: 100, trajectories: 2, seed: 2}
""",
}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """name -> path of a real HDF5 run, written by `rbx simulate` (in-process, through the CLI)."""
    folder = tmp_path_factory.mktemp("runs")
    out = {}
    for name, text in RUNS.items():
        conf = folder / f"{name}.yaml"
        conf.write_text(text)
        h5 = folder / f"{name}.h5"
        result = CliRunner().invoke(cli, ["simulate", str(conf), "-o", str(h5), "--quiet"])
        assert result.exit_code == 0, result.output
        out[name] = str(h5)
    return out


def labelled(fig):
    """Every data axes has x and y labels (and z in 3D) with units in brackets; colour bars are skipped."""
    axes = [ax for ax in fig.axes if ax.get_label() != "<colorbar>"]
    assert axes
    for ax in axes:
        labels = [ax.get_xlabel(), ax.get_ylabel()] + ([ax.get_zlabel()] if hasattr(ax, "get_zlabel") else [])
        for text in labels:
            assert text and "[" in text and "]" in text, (text, labels)
    return axes


CASES = [("orbit", "lshape", {}), ("orbit", "circle", {}), ("orbit", "strip", {"records": slice(0, 200)}),
         ("orbit", "plates", {}), ("orbit3d", "plates", {}), ("orbit3d", "box", {}),
         ("phase", "lshape", {}), ("phase", "strip", {"colour": "step"}), ("phase", "plates", {}),
         ("series", "strip", {}), ("series", "random", {"trajectories": "0,1,2"}), ("diffusion", "random", {})]


@pytest.mark.parametrize("kind,run,options", CASES, ids=[f"{k}-{r}" for k, r, _ in CASES])
def test_every_kind_renders_with_labelled_axes(runs, kind, run, options):
    options = dict(options)
    records = options.pop("records", slice(None))
    trajectories = options.pop("trajectories", None)
    fig = make_figure(runs[run], kind, records, trajectories, **options)
    axes = labelled(fig)
    title = fig._suptitle.get_text()
    assert (" in a " in title or " between plates " in title) and "·" in title
    assert {"strip": "hemisphere", "random": "random", "lshape": "rough", "circle": "rough", "plates": "rough",
            "box": "rough"}[run] in title
    if kind == "orbit3d":
        assert axes[0].name == "3d" and len(axes) == 2
    if kind == "series":
        assert len(axes) == 3
        ends = [ax.get_lines()[0].get_xdata().max() for ax in axes]
        assert ends[0] < ends[1] < ends[2]            # 1/100, 1/10 and all of the run


@pytest.mark.long
@pytest.mark.parametrize("kind,run", [("orbit", "lshape"), ("orbit3d", "plates"), ("phase", "lshape"),
                                      ("series", "strip"), ("diffusion", "random")])
def test_cli_writes_a_png(runs, tmp_path, kind, run):
    png = tmp_path / f"{kind}.png"
    exe = os.path.join(os.path.dirname(sys.executable), "rbx")
    r = subprocess.run([exe, "plot", runs[run], "--kind", kind, "-o", str(png)], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    data = png.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert 20_000 < len(data) < 5_000_000
    from matplotlib.image import imread
    height, width = imread(str(png)).shape[:2]
    assert width >= 600 and height >= 300


def test_default_figure_path_beside_the_run(runs, tmp_path):
    import shutil
    h5 = tmp_path / "copy.h5"
    shutil.copy(runs["circle"], h5)
    result = CliRunner().invoke(cli, ["plot", str(h5), "--kind", "orbit"])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "copy_orbit.png").stat().st_size > 20_000


# ---- what the pictures show ------------------------------------------------------------------------------------


def read(path, *fields):
    with Run.open(path) as run:
        traj = list(range(run.trajectories))
        return run, run.geometry(), [run.read(f, traj) for f in fields]


def test_plates_rank2_spin_planes_are_circles(runs):
    """Completely rough plates: v·e₁² + κR²(ω·e₂)² and v·e₂² + κR²(ω·e₁)² are conserved by the map at either
    plate, so each picture plane shows a circle."""
    run, geom, (wall, pos, vel, spin) = read(runs["plates"], "wall", "position", "velocity", "angular_velocity")
    at = wall[0] >= 0
    _, nu = analysis.locate(geom, wall[0][at], pos[0][at])
    planes = analysis.spin_planes(wall[0][at], nu, vel[0][at], spin[0][at], run.radius, run.kappa,
                                  [w.tangents for w in geom.wall_list])
    for x, y, _, _ in planes:
        r = np.hypot(x, y)
        assert r.std() < 1e-9 * r.mean()


def test_spin_plane_follows_the_closed_form_rough_map(runs):
    """At each collision, (v₀, v·Jν) after = [[(κ−1)/(1+κ), 2√κ/(1+κ)], [2√κ/(1+κ), (1−κ)/(1+κ)]]·before
    (docs/reference.md §1), with the plane's axis v·t = −v·Jν; 'before' is the previous record (a free flight changes
    neither)."""
    run, geom, (wall, pos, vel, spin) = read(runs["lshape"], "wall", "position", "velocity", "angular_velocity")
    k = run.kappa
    T = np.array([[(k - 1) / (1 + k), 2 * math.sqrt(k) / (1 + k)], [2 * math.sqrt(k) / (1 + k), (1 - k) / (1 + k)]])
    for j in range(run.trajectories):
        w, p, v, s = wall[j, 1:], pos[j, 1:], vel[j], spin[j]
        _, nu = analysis.locate(geom, w, p)
        [(after_t, after_0, _, _)] = analysis.spin_planes(w, nu, v[1:], s[1:], run.radius, k)
        [(before_t, before_0, _, _)] = analysis.spin_planes(w, nu, v[:-1], s[:-1], run.radius, k)
        predicted = T @ np.array([before_0, -before_t])
        np.testing.assert_allclose(after_0, predicted[0], atol=1e-10)
        np.testing.assert_allclose(-after_t, predicted[1], atol=1e-10)


def test_birkhoff_coordinates_in_a_polygon(runs):
    """s lies in its wall's stretch of the boundary, agrees with the position on straight walls, |sin ψ| ≤ 1."""
    run, geom, (wall, pos, vel) = read(runs["lshape"], "wall", "position", "velocity")
    at = wall >= 0
    w, p, v = wall[at], pos[at], vel[at]
    s, sin_psi = analysis.birkhoff_coordinates(geom, w, p, v)
    edges = [0.0] + analysis.wall_joints(geom) + [analysis.boundary_length(geom)]
    assert len(edges) == 7
    assert np.all((s >= np.take(edges, w) - 1e-12) & (s <= np.take(edges, w + 1) + 1e-12))
    assert np.all(np.abs(sin_psi) <= 1)
    bottom = w == 0
    np.testing.assert_allclose(s[bottom], p[bottom, 0] - 0.1, atol=1e-12)
    np.testing.assert_allclose(sin_psi[bottom], v[bottom, 0] / np.linalg.norm(v[bottom], axis=1), atol=1e-12)
    left = w == 5                                      # traversed downwards: s = total − (y − R)
    np.testing.assert_allclose(s[left], edges[-1] - (p[left, 1] - 0.1), atol=1e-12)


def test_circle_collisions_repeat_with_period_two_in_birkhoff_coordinates(runs):
    """Paper Proposition (circular rough billiard): the vertex angle is constant and the segments touch two
    caustic circles alternately, so sin ψ repeats every second collision."""
    run, geom, (wall, pos, vel) = read(runs["circle"], "wall", "position", "velocity")
    for j in range(run.trajectories):
        s, sin_psi = analysis.birkhoff_coordinates(geom, wall[j, 1:], pos[j, 1:], vel[j, 1:])
        np.testing.assert_allclose(sin_psi[2:], sin_psi[:-2], atol=1e-9)
        assert np.all((s >= 0) & (s <= 2 * math.pi * 0.9 + 1e-12))


# ---- diffusion -------------------------------------------------------------------------------------------------


def test_diffusion_fit_recovers_a_known_coefficient():
    """±1 random walks: MSD = t, D = 1/2 per step; the 95% interval covers it about 95% of the time."""
    rng = np.random.default_rng(0)
    t = np.arange(0, 201, 5.0)
    hits, reps = 0, 200
    for _ in range(reps):
        steps = rng.choice([-1.0, 1.0], size=(60, 200))
        x = np.concatenate([np.zeros((60, 1)), np.cumsum(steps, axis=1)], axis=1)[:, ::5]
        fit = analysis.fit_diffusion(t, x)
        hits += fit.low <= 0.5 <= fit.high
    assert 0.88 <= hits / reps <= 0.99
    assert fit.trajectories == 60 and fit.start >= 20 and fit.stop == 200


def test_diffusion_fit_skips_trajectories_that_ended_early():
    rng = np.random.default_rng(1)
    x = np.cumsum(rng.standard_normal((30, 101)), axis=1)
    x[:, 0] = 0
    x[3, 50:] = np.nan
    fit = analysis.fit_diffusion(np.arange(101.0), x)
    assert fit.trajectories == 29
    assert np.isfinite(analysis.mean_square_displacement(x)).all()
    with pytest.raises(ValueError):
        analysis.fit_diffusion(np.arange(101.0), x[3:4])


@pytest.mark.long
def test_diffusion_figure_reports_the_fit(runs):
    fig = make_figure(runs["random"], "diffusion")
    left, right = labelled(fig)
    legend = " ".join(t.get_text() for t in fig.legends[0].get_texts())
    assert "D = " in legend and "95% CI" in legend
    with Run.open(runs["random"]) as run:
        x = run.read("position", list(range(run.trajectories)))[..., 0]
        fit = analysis.fit_diffusion(run.step.astype(float), x)
    assert fit.low < fit.coefficient < fit.high and fit.coefficient > 0
    assert f"D = {analysis.plus_minus(fit.coefficient, fit.half_width)} L²/collision" in legend, legend
    # the Gaussian panel tests the displacements against the fitted variance only where there are enough of them
    from rbx.plotting import MIN_KS_SAMPLES
    assert ("KS p = " in legend) == (x.shape[0] >= MIN_KS_SAMPLES), legend
    few = " ".join(t.get_text() for t in make_figure(runs["random"], "diffusion", trajectories="0-2").legends[0]
                   .get_texts())
    assert "KS p" not in few and f"no KS test: 3 trajectories, fewer than {MIN_KS_SAMPLES}" in few, few


# ---- errors ----------------------------------------------------------------------------------------------------


def plot_error(*args):
    result = CliRunner().invoke(cli, ["plot", *args])
    assert result.exit_code == 2, (result.output, result.exception)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("rbx: ") and "Traceback" not in result.output
    return lines[0]


def test_missing_and_foreign_files(tmp_path):
    assert "file not found" in plot_error(str(tmp_path / "nope.h5"), "--kind", "orbit")
    text = tmp_path / "text.h5"
    text.write_text("not hdf5\n")
    assert plot_error(str(text), "--kind", "orbit") == f"rbx: {text}: not an HDF5 file (or unreadable)"
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f["x"] = np.arange(3)
    assert "not an rbx run" in plot_error(str(other), "--kind", "phase")
    assert "is a directory" in plot_error(str(tmp_path), "--kind", "orbit")


def test_histogram_output_is_not_a_run(tmp_path):
    path = tmp_path / "returns.h5"
    with h5py.File(path, "w") as f:
        for k, v in dict(dimension=2, config="table: {kind: rectangle}", table_kind="rectangle", radius=0.1,
                         kappa=0.5, wall_names=["a"]).items():
            f.attrs[k] = v
        f["returns/angle"] = np.zeros(3)
    assert "rbx histogram" in plot_error(str(path), "--kind", "orbit")


def test_missing_fields_and_wrong_kinds(runs):
    msg = plot_error(runs["random"], "--kind", "phase")
    assert "collisions/velocity" in msg and "output.record" in msg
    assert "3D run" in plot_error(runs["circle"], "--kind", "orbit3d")
    assert "at least 2 trajectories" in plot_error(runs["strip"], "--kind", "diffusion")
    assert "does not exist in a 2D run" in plot_error(runs["strip"], "--kind", "series", "--coordinate", "z")
    assert "trajectory 7 does not exist" in plot_error(runs["lshape"], "--kind", "orbit", "--trajectories", "0,7")
    assert "--records" in plot_error(runs["lshape"], "--kind", "orbit", "--records", "abc")
    assert "--scales" in plot_error(runs["strip"], "--kind", "series", "--scales", "0,2")
    with pytest.raises(UserError):
        make_figure(runs["lshape"], "orbit", trajectories="-3")


def test_incomplete_runs_are_plotted_and_marked(runs, tmp_path):
    import shutil
    h5 = tmp_path / "partial.h5"
    shutil.copy(runs["lshape"], h5)
    with h5py.File(h5, "a") as f:
        f.attrs["complete"] = False
    fig = make_figure(str(h5), "orbit")
    assert "INCOMPLETE" in fig._suptitle.get_text()


def test_displacement_panel_draws_a_gaussian_density(runs):
    """The displacement panel's curve is the Gaussian of the fitted MSD at the last step (a density: area 1)."""
    fig = make_figure(runs["random"], "diffusion")
    curve = fig.axes[1].get_lines()[0]
    x, y = curve.get_xdata(), curve.get_ydata()
    trapezoid = getattr(np, "trapezoid", None) or np.trapz      # NumPy 2 renamed it; the oldest NumPy supported is 1.26
    assert trapezoid(y, x) == pytest.approx(1.0, abs=1e-3)
    assert x[np.argmax(y)] == pytest.approx(0.0, abs=(x[1] - x[0]))


# ---- readable pictures on every example scene --------------------------------------------------------------------

EXAMPLES = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "configs", "examples")
SCENES = sorted(f[:-5] for f in os.listdir(EXAMPLES) if f.endswith(".yaml") and f != "lyapunov-sinai.yaml")


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    """scene -> a short run of configs/examples/<scene>.yaml with every field recorded at every collision."""
    import dataclasses
    import rbx
    from rbx.model import FIELDS
    folder = tmp_path_factory.mktemp("scenes")
    out = {}
    for scene in SCENES:
        config = os.path.join(EXAMPLES, scene + ".yaml")
        exp = rbx.load(config)
        over = {"collisions": 120}
        if isinstance(exp.initial[0], str):          # sampled starts: a small ensemble
            over["trajectories"] = 4
        exp = rbx.load(config, over)
        if "position" in exp.output.record:
            exp = exp.replace(output=dataclasses.replace(exp.output, record=tuple(f.name for f in FIELDS), every=1))
        path = str(folder / f"{scene}.h5")
        rbx.simulate(exp, output=path, force=True)
        out[scene] = path
    return out


def overlaps(a, b, slack=0.5):
    return a.x0 < b.x1 - slack and b.x0 < a.x1 - slack and a.y0 < b.y1 - slack and b.y0 < a.y1 - slack


def readable(fig):
    """What matplotlib can tell about a drawn figure: data inside the axis limits (2D axes), no legend over any
    data axes, no two tick labels of an axis overlapping -> list of problems (empty: readable)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    FigureCanvasAgg(fig)
    fig.set_dpi(40)
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    problems = []
    page = fig.bbox
    texts = [fig._suptitle] if fig._suptitle is not None else []
    texts += [t for ax in fig.axes for t in (ax.title, ax.xaxis.label, ax.yaxis.label)]
    edge = 1.0                      # px at 40 dpi (1.8 pt): a rotated label's box reaches ~0.7 px past the edge
    for t in texts:                 # titles and axis labels inside the figure, not cut off at its edges
        if t.get_visible() and t.get_text():
            b = t.get_window_extent(renderer)
            if b.x0 < page.x0 - edge or b.x1 > page.x1 + edge or b.y0 < page.y0 - edge or b.y1 > page.y1 + edge:
                problems.append(f"the text '{t.get_text()[:40]}…' runs past the figure's edge")
    data_axes = [ax for ax in fig.axes if ax.get_label() != "<colorbar>"]
    for ax in data_axes:
        if ax.name != "3d":
            # the data: lines that are not the table's outline (drawn over a wider range and clipped) and scatter
            # points; on a log axis only the positive values can be shown
            from rbx.tables import SHRUNK_STYLE, TABLE_STYLE
            table = {TABLE_STYLE["color"], SHRUNK_STYLE["color"]}
            pts = [line.get_xydata() for line in ax.get_lines() if line.get_color() not in table
                   and line.get_transform() is ax.transData and type(line).__name__ != "_AxLine"]
            pts += [np.asarray(c.get_offsets()) for c in ax.collections if type(c).__name__ == "PathCollection"]
            pts = np.concatenate([p.reshape(-1, 2) for p in pts if np.size(p)] or [np.zeros((0, 2))]).astype(float)
            pts = pts[np.all(np.isfinite(pts), axis=1)]
            for k, scale in enumerate((ax.get_xscale(), ax.get_yscale())):
                if scale == "log":
                    pts = pts[pts[:, k] > 0]
            (x0, x1), (y0, y1) = sorted(ax.get_xlim()), sorted(ax.get_ylim())
            tol = 1e-6 * max(x1 - x0, y1 - y0)
            if len(pts) and not (x0 - tol <= pts[:, 0].min() and pts[:, 0].max() <= x1 + tol
                                 and y0 - tol <= pts[:, 1].min() and pts[:, 1].max() <= y1 + tol):
                problems.append(f"data {pts.min(axis=0)}–{pts.max(axis=0)} outside the limits {(x0, x1, y0, y1)}")
        axes_box = ax.get_window_extent(renderer)
        for other in data_axes:         # another panel's axis labels over this one's data (a squeezed panel)
            for label in (other.xaxis.label, other.yaxis.label) if other is not ax and ax.name != "3d" else ():
                if label.get_visible() and label.get_text() and overlaps(label.get_window_extent(renderer),
                                                                          axes_box):
                    problems.append(f"the label '{label.get_text()[:30]}' lies over the axes '{ax.get_title()}'")
        for legend in [a.get_legend() for a in data_axes if a.get_legend()] + list(fig.legends):
            if overlaps(legend.get_window_extent(renderer), axes_box):
                problems.append(f"a legend covers the axes '{ax.get_title()}'")
        for axis in ax._axis_map.values():
            boxes = [t.get_window_extent(renderer) for t in axis.get_ticklabels()
                     if t.get_visible() and t.get_text()]
            boxes = [b for b in boxes if axes_box.x0 - 200 < b.x0 < axes_box.x1 + 200]
            for i in range(len(boxes)):
                for j in range(i + 1, len(boxes)):
                    if overlaps(boxes[i], boxes[j]):
                        problems.append(f"tick labels overlap on {axis.axis_name} of '{ax.get_title()}'")
    return problems


@pytest.mark.long
@pytest.mark.parametrize("scene", SCENES)
def test_every_kind_on_every_scene_is_readable(scenes, scene):
    """Every kind that applies to the scene renders readably; one that does not says why (a UserError)."""
    from rbx.cli.plot import KINDS
    drawn = []
    for kind in KINDS:
        try:
            fig = make_figure(scenes[scene], kind)
        except UserError as exc:
            assert exc.problem and "\n" not in str(exc)
            continue
        assert readable(fig) == [], (kind, readable(fig))
        drawn.append(kind)
    assert "orbit" in drawn or scene == "escape-sinai"   # that example records no positions


def test_a_wide_table_under_a_long_title_keeps_its_labels(tmp_path):
    """Ten trajectories in the 2 × 1 rectangle: five lines of title (scene, rule, selection, the panel's note) over
    a figure sized for the table's shape cut the x label off at the bottom (plotting.grow_to_fit)."""
    import dataclasses
    import rbx
    path = str(tmp_path / "rectangle.h5")
    exp = rbx.load(os.path.join(EXAMPLES, "rectangle.yaml"), {"collisions": 1000, "trajectories": 16})
    exp = exp.replace(output=dataclasses.replace(exp.output, record=("position",), every=1))
    rbx.simulate(exp, output=path)
    fig = make_figure(path, "orbit")
    assert len(fig._suptitle.get_text().split("\n")) + len(fig.axes[0].get_title().split("\n")) >= 5
    assert readable(fig) == []


def test_the_readability_check_can_fail():
    """A legend over the data, tick labels run together and data beyond the limits are all caught."""
    from matplotlib.figure import Figure
    fig = Figure(figsize=(2, 2))
    ax = fig.add_subplot()
    ax.plot([0, 1e6], [0, 1], label="a long legend entry over the data")
    ax.legend(loc="center")
    ax.set_xticks(np.linspace(0, 1e6, 30))
    ax.set_xlim(0, 5e5)
    fig.suptitle("a title far too long for a figure two inches wide, which runs past both of its edges")
    problems = " | ".join(readable(fig))
    assert "legend covers" in problems and "tick labels overlap" in problems and "outside the limits" in problems
    assert "runs past the figure's edge" in problems


def test_a_long_title_is_broken_to_the_figure_width():
    """rbx's builders break a title that is wider than their figure (at its " · " separators first): a long scene
    phrase over a narrow, tall table ran past both edges of the picture and was cut off."""
    from rbx import plotting
    title = ("disc (R = 0.1, κ = 0.5) in a periodic Lorentz gas, centred lattice, cell 1 × 1.73205, scatterer "
             "radius 0.36 · random (specular 0.5, rough 0.5)\norbit of the centre · trajectories 0–9 of 16")
    fig = plotting.series_figure(np.arange(50), [np.sin(np.arange(50))], title, "x [L]")
    fig.set_size_inches(4.0, fig.get_figheight())
    plotting.fit_title(fig)
    lines = fig._suptitle.get_text().split("\n")
    assert len(lines) > 2
    assert readable(fig) == []
    # the words and their order are kept
    assert " ".join(fig._suptitle.get_text().split()) == " ".join(title.replace("\n", " ").split())


def test_long_strip_orbit_is_not_one_pixel_high(scenes):
    fig = make_figure(scenes["strip"], "orbit")
    readable(fig)
    box = fig.axes[0].get_window_extent()
    assert box.height > 0.2 * box.width


def test_long_orbits_are_thinned(scenes):
    from rbx import plotting
    fig = make_figure(scenes["box"], "orbit3d")
    paths = [line for line in fig.axes[0].get_lines()
             if line.get_color() not in ("0.15", "0.45") and len(line.get_data_3d()[0]) > 1]
    flights = sum(len(line.get_data_3d()[0]) - 1 for line in paths)
    # m trajectories share ORBIT3D_SEGMENTS/√m flights (each cut at the same record)
    assert 0 < flights <= plotting.ORBIT3D_SEGMENTS / np.sqrt(len(paths)) + len(paths)


@pytest.mark.long
def test_poincare_axes_are_named_with_their_sign(scenes):
    """The in-plane axes of a section by y = c are x and e₂ = e_y × e_x = −e_z: the vertical axis shows −z and is
    named so (it was named z, and the cylinder's z from 0.1 to 1.4 ran from −1.4 to −0.1); by z = c: x and y."""
    fig = make_figure(scenes["cylinder"], "poincare", plane="y=0.1")
    assert fig.axes[0].get_xlabel().startswith("x ") and fig.axes[0].get_ylabel().startswith("−z ")
    ys = np.concatenate([np.asarray(c.get_offsets())[:, 1] for c in fig.axes[0].collections])
    assert ys.max() <= -0.1 + 1e-9                   # −z of the free region 0.1 ≤ z ≤ 1.4
    fig = make_figure(scenes["cylinder"], "poincare", plane="z=0.75")
    assert fig.axes[0].get_xlabel().startswith("x ") and fig.axes[0].get_ylabel().startswith("y ")


def test_a_run_without_records_is_said_to_hold_none_not_a_bad_range():
    # a .partial stopped before its first block was saved: "--records: : selects no records (the run has 0: 0–-1)"
    # blamed an option the user never gave
    from rbx.cli.common import UserError
    from rbx.cli.plot import check_records
    with pytest.raises(UserError) as info:
        check_records(slice(None), 0, "o.h5.partial")
    assert "holds no records yet" in str(info.value) and "--records" not in str(info.value), str(info.value)
    with pytest.raises(UserError, match="selects no records"):
        check_records(slice(5, 9), 3, "o.h5")


def test_strided_records_are_drawn_as_points(scenes):
    """Every 2nd record: the collisions between them are missing, so no straight flight joins two of them; the
    orbit is drawn as points, as for a run that records every 2nd collision."""
    fig = make_figure(scenes["circle"], "orbit", records=slice(None, None, 2))
    drawn = [line for line in fig.axes[0].get_lines() if line.get_label().startswith("trajectory")]
    assert drawn and all(line.get_linestyle() == "None" and line.get_marker() == "." for line in drawn)
    fig = make_figure(scenes["circle"], "orbit")
    drawn = [line for line in fig.axes[0].get_lines() if line.get_label().startswith("trajectory")]
    assert drawn and all(line.get_linestyle() == "-" for line in drawn)


def test_many_trajectories_share_fewer_flights():
    """m trajectories are drawn with ORBIT_SEGMENTS/√m flights in all (ten: 250, not 800, which was a knot), each
    cut at the same record; one is cut at PER_TRAJECTORY; a short run is not cut."""
    from rbx import plotting
    ten = [np.zeros((1000, 2)) for _ in range(10)]
    shown, k = plotting._thin(ten, plotting.ORBIT_SEGMENTS)
    assert k == int(plotting.ORBIT_SEGMENTS / np.sqrt(10)) // 10 == 25
    assert [len(p) for p in shown] == [k + 1] * 10
    shown, k = plotting._thin(ten[:1], plotting.ORBIT_SEGMENTS)
    assert k == plotting.PER_TRAJECTORY and len(shown[0]) == k + 1
    shown, k = plotting._thin([np.zeros((20, 2))] * 4, plotting.ORBIT_SEGMENTS)
    assert k is None and [len(p) for p in shown] == [20] * 4
    # a periodic table's walks are drawn whole, up to PER_TRAJECTORY_PERIODIC flights each
    import types
    lattice = types.SimpleNamespace(lattice=(np.zeros(2), np.ones(2)))
    shown, k = plotting._thin(ten, plotting.ORBIT_SEGMENTS, lattice)
    assert k is None and [len(p) for p in shown] == [1000] * 10
    shown, k = plotting._thin([np.zeros((30_000, 2))] * 2, plotting.ORBIT_SEGMENTS, lattice)
    assert k == plotting.PER_TRAJECTORY_PERIODIC and [len(p) for p in shown] == [k + 1] * 2


def test_few_points_in_phase_are_as_large_as_the_legend_markers(runs):
    """A periodic orbit in the phase portrait is a handful of points: drawn no smaller than the legend's."""
    fig = make_figure(runs["circle"], "phase", records=slice(0, 6))
    sizes = [float(np.sqrt(c.get_sizes()).min()) for ax in fig.axes for c in ax.collections if len(c.get_sizes())]
    legend = [ax.get_legend() for ax in fig.axes if ax.get_legend()][0]
    markers = [h.get_markersize() for h in legend.legend_handles if hasattr(h, "get_marker") and h.get_marker() == "o"]
    assert sizes and markers and min(sizes) >= max(markers)


def test_one_style_sheet(runs):
    from rbx import plotting
    assert os.path.isfile(plotting.STYLE)
    fig = make_figure(runs["lshape"], "orbit")
    assert fig.axes[0].xaxis.get_major_ticks()[0].label1.get_fontsize() == 8.0   # xtick.labelsize of the sheet


# ---- refusals (one line, exit 2) ---------------------------------------------------------------------------------

def rbx_fails(*args):
    exe = os.path.join(os.path.dirname(sys.executable), "rbx")
    r = subprocess.run([exe, *args], capture_output=True, text=True, timeout=300)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and lines[0].startswith("rbx: "), (r.returncode, r.stderr)
    return lines[0]


@pytest.mark.long
def test_a_figure_is_written_only_where_a_careful_user_expects(runs, tmp_path):
    """rbx plot -o makes no folder (a typo in the folder made a new tree without a word), writes through no
    symbolic link, and replaces a figure but no other file (a run, a config, notes named as the figure)."""
    run = runs["lshape"]
    missing = tmp_path / "no" / "such" / "x.png"
    line = rbx_fails("plot", run, "--kind", "orbit", "-o", str(missing))
    assert line == f"rbx: {missing}: the folder {missing.parent} does not exist (rbx makes no folders for a figure: " \
                   "create it first, or give another path)", line
    assert not (tmp_path / "no").exists()
    notes = tmp_path / "notes.txt"
    notes.write_text("mine\n")
    link = tmp_path / "link.png"
    link.symlink_to(notes)
    line = rbx_fails("plot", run, "--kind", "orbit", "-o", str(link))
    assert "is a symbolic link" in line and "does not write through links" in line, line
    line = rbx_fails("plot", run, "--kind", "orbit", "-o", str(notes))
    assert line.endswith("exists and is not a figure (not a PNG, PDF, SVG, PostScript, JPEG, TIFF, GIF, WebP or MP4 "
                         "file: a run, a config, notes?); rbx replaces only figures: give another name"), line
    assert notes.read_text() == "mine\n"
    # a figure is replaced, as before, in each format rbx writes (a WebP, an .svgz or raw pixels it had written
    # itself were called "not a figure")
    exe = os.path.join(os.path.dirname(sys.executable), "rbx")
    from rbx.cli.common import check_figure_target
    from rbx.plotting import save
    from matplotlib.figure import Figure as MplFigure
    for ext in ("webp", "svgz", "raw"):
        fig = MplFigure()
        fig.add_subplot().plot([0, 1])
        save(fig, str(tmp_path / f"f.{ext}"))
        check_figure_target(str(tmp_path / f"f.{ext}"))
    png = tmp_path / "x.png"
    for _ in range(2):
        r = subprocess.run([exe, "plot", run, "--kind", "orbit", "-o", str(png), "--quiet"], capture_output=True,
                           text=True, timeout=300)
        assert r.returncode == 0 and r.stderr == "", r.stderr


def test_a_mistyped_kind_and_a_config_given_for_a_run_say_what_to_do(runs):
    line = rbx_fails("plot", runs["lshape"], "--kind", "orbits")
    assert line.endswith("; did you mean orbit?"), line
    config = os.path.join(EXAMPLES, "circle.yaml")
    line = rbx_fails("plot", config, "--kind", "orbit")
    assert "circle.yaml: is a config, not a run: run it first, rbx simulate " in line, line
    assert line.endswith("circle.yaml -o OUT.h5, then rbx plot OUT.h5 --kind orbit"), line


@pytest.mark.long
def test_meaningless_selections_and_analyses_are_refused(runs, scenes):
    line = rbx_fails("plot", runs["lshape"], "--kind", "orbit", "--records", "100:50")
    assert ": --records: 100:50 selects no records" in line
    # a Poincaré section over every 3rd record joined collisions three apart: 79 of 161 points outside a cylinder
    line = rbx_fails("plot", scenes["cylinder"], "--kind", "poincare", "--plane", "z=0.75", "--records", "::3")
    assert ": --records: a Poincaré section needs consecutive collisions" in line
    line = rbx_fails("plot", scenes["box"], "--kind", "diffusion")
    assert "--kind diffusion: the box table is bounded along x" in line
    line = rbx_fails("plot", scenes["lorentz"], "--kind", "diffusion", "--coordinate", "time")
    assert "--coordinate: the time is not a random coordinate" in line


def test_an_infinite_horizon_gives_a_slope_not_d_and_no_gaussian(scenes):
    """On the square Lorentz gas (free corridors along x) the fitted number is half the MSD's slope over the
    window: the legend and stdout call it b, never D with a confidence interval, and the displacement panel draws
    no Gaussian of the fitted variance (the MSD grows as t·log t)."""
    fig = make_figure(scenes["lorentz"], "diffusion")
    said = fig.rbx_result
    assert said.startswith("slope of the MSD along x, fitted as 2bt + c: b = ") and "D = " not in said, said
    labels = [t.get_text() for leg in fig.legends for t in leg.get_texts()]
    assert not any("D = " in t for t in labels), labels
    assert any(t.startswith("fit 2bt + c, over the fit window only: b = ") and "not D" in t for t in labels), labels
    assert fig.axes[1].get_lines()[0].get_label().startswith("no Gaussian"), fig.axes[1].get_lines()
    assert not any("KS p" in t for t in labels)


# ---- rbx animate ---------------------------------------------------------------------------------------------------

def test_animate_writes_a_gif_with_the_frames_asked(scenes, tmp_path):
    from PIL import Image
    gif = tmp_path / "orbit.gif"
    result = CliRunner().invoke(cli, ["animate", scenes["circle"], "-o", str(gif), "--frames", "7", "--fps", "10",
                                      "--dpi", "30"])
    assert result.exit_code == 0, result.output
    with Image.open(gif) as im:
        assert im.format == "GIF" and im.n_frames == 7
        first = np.asarray(im.convert("RGB"))
        im.seek(6)
        last = np.asarray(im.convert("RGB"))
    assert np.any(first != last)                 # the ball moved


def test_animation_interpolates_the_free_flight():
    from rbx.cli.animate import ball_frames
    t, pos, theta = ball_frames(np.array([0.0, 1.0, 3.0]), np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 2.0]]),
                                np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]]), np.array([0.0, 1.0, 0.0]), 7)
    np.testing.assert_allclose(t, [0, 0.5, 1, 1.5, 2, 2.5, 3])
    np.testing.assert_allclose(pos[:, 0], [0, 0.5, 1, 1, 1, 1, 1])
    np.testing.assert_allclose(pos[:, 1], [0, 0, 0, 0.5, 1, 1.5, 2])
    np.testing.assert_allclose(theta, [0, 0.5, 1, 0.75, 0.5, 0.25, 0])


def test_animate_refuses_what_it_cannot_draw(runs):
    result = CliRunner().invoke(cli, ["animate", runs["random"], "-o", "x.gif"])
    assert result.exit_code == 2 and "collisions/time" in result.stderr and len(result.stderr.splitlines()) == 1
    result = CliRunner().invoke(cli, ["animate", runs["plates"], "-o", "x.gif"])
    assert result.exit_code == 2 and "3D" in result.stderr


def test_animate_writes_only_where_a_figure_may_go(scenes, tmp_path):
    # as rbx plot -o: no folder made, no link written through, no file that is not a figure replaced
    (tmp_path / "notes.gif").write_text("my notes")
    os.symlink(tmp_path / "elsewhere.gif", tmp_path / "link.gif")
    for out, said in ((tmp_path / "no" / "such" / "o.gif", "does not exist"), (tmp_path / "link.gif", "link"),
                      (tmp_path / "notes.gif", "is not a figure")):
        result = CliRunner().invoke(cli, ["animate", scenes["circle"], "-o", str(out), "--frames", "3"])
        assert result.exit_code == 2 and said in result.stderr and len(result.stderr.splitlines()) == 1, \
            result.stderr
    assert not (tmp_path / "no").exists() and not (tmp_path / "elsewhere.gif").exists()
    assert (tmp_path / "notes.gif").read_text() == "my notes"


def test_panels_are_lettered_in_reading_order_and_once():
    """plotting.letter_panels (called by plotting.save and the paper figures' figlib): (a), (b), … before the titles
    of a figure's grid panels, row by row; a colour bar is no panel, a one-panel figure gets no letter, the title's
    own font size is kept, and lettering again changes nothing."""
    from matplotlib.figure import Figure

    from rbx.plotting import letter_panels
    fig = Figure(layout="constrained")
    grid = fig.add_gridspec(2, 3)
    right = fig.add_subplot(grid[:, 2])           # spans both rows: the third panel of the first row
    top = [fig.add_subplot(grid[0, k]) for k in range(2)]
    bottom = fig.add_subplot(grid[1, :2])
    top[0].set_title("orbit", fontsize=7)
    fig.colorbar(top[1].imshow(np.zeros((2, 2))), ax=top[1])
    letter_panels(fig)
    letter_panels(fig)
    assert [top[0].get_title(), top[1].get_title(), right.get_title(), bottom.get_title()] == \
        ["(a) orbit", "(b)", "(c)", "(d)"]
    assert top[0].title.get_fontsize() == 7
    assert len(fig.axes) == 5 and sum(ax.get_title().startswith("(") for ax in fig.axes) == 4
    single = Figure()
    single.add_subplot().set_title("alone")
    letter_panels(single)
    assert single.axes[0].get_title() == "alone"


def test_a_3d_box_table_built_from_pieces_draws_its_walls():
    """The horizontal projection of a Sinai box (a box of planes with a sphere) draws the box and the shrunk box:
    the box's x face extends without end along x, and taking its extent for the box's length drew nothing."""
    import rbx
    from matplotlib.figure import Figure
    from rbx import tables
    exp = rbx.load(os.path.join(EXAMPLES, "sinai3d.yaml"))
    geom = exp.geometry()
    ax = Figure().add_subplot()
    tables.draw(ax, geom, np.zeros(3), np.array(exp.table["size"], float))
    ends = [line.get_xydata().max(axis=0) for line in ax.get_lines()]
    lx, ly = exp.table["size"][:2]
    R = exp.ball.radius
    assert any(np.allclose(e, [lx, ly]) for e in ends)                  # the box
    assert any(np.allclose(e, [lx - R, ly - R]) for e in ends)          # the shrunk box


def test_trajectory_colours_are_not_grey_and_are_explained_when_not_listed():
    """Grey is the whole run's density and the table's outline, so no trajectory is drawn grey; a phase portrait
    of more trajectories than its legend lists says what its colours are."""
    from rbx import plotting
    for i in range(plotting.MAX_LEGEND):
        r, g, b, _ = plotting._colour(i)
        assert max(r, g, b) - min(r, g, b) > 0.2, i
    rng = np.random.default_rng(0)
    n = 16
    colour = np.repeat(np.arange(n), 20)
    x, y = rng.uniform(-1, 1, (2, len(colour)))
    fig = plotting.phase_figure([{"x": x, "y": y, "xlabel": "s [L]", "ylabel": "sin ψ [-]"}], colour, "title",
                                "trajectory", labels=[f"trajectory {j}" for j in range(n)])
    texts = [t.get_text() for lg in [a.get_legend() for a in fig.axes if a.get_legend()] + list(fig.legends)
             for t in lg.get_texts()]
    assert any("colour: trajectory" in t and "16" in t for t in texts), texts
    assert readable(fig) == []


def test_the_box_phase_portrait_says_what_each_panel_shows_and_leaves_its_structure_visible(tmp_path):
    """The box example's phase portrait (8 × 10 000 collisions) had two panels titled alike and markers of 2 pt²
    each, drawn trajectory after trajectory: the markers covered the panels twice over and the last trajectory
    hid the others."""
    config = os.path.join(os.path.dirname(__file__), "..", "configs", "examples", "box.yaml")
    h5 = tmp_path / "box.h5"
    result = CliRunner().invoke(cli, ["simulate", config, "-o", str(h5), "--quiet"])
    assert result.exit_code == 0, result.output
    fig = make_figure(str(h5), "phase")
    axes = [ax for ax in fig.axes if ax.get_label() != "<colorbar>"]
    titles = [ax.get_title() for ax in axes]
    assert len(axes) == 2 and len(set(titles)) == 2, titles
    assert "e₁" in titles[0].split("\n")[0] and "e₂" in titles[1].split("\n")[0]
    fig.canvas.draw()
    for ax in axes:
        (dots,) = [c for c in ax.collections if len(c.get_offsets()) > 1000]
        n = len(dots.get_offsets())
        box = ax.get_window_extent()
        area = box.width * box.height * (72.0 / fig.dpi) ** 2          # pt²
        assert n >= 70_000 and n * float(dots.get_sizes()[0]) < 0.5 * area   # ink under half the panel
        last = np.unique(dots.get_facecolors()[-2000:], axis=0)          # the points drawn last, on top
        assert len(last) == 8                                            # come from every trajectory
    assert readable(fig) == []


@pytest.mark.long
def test_an_orbit_of_one_trajectory_is_not_called_each_trajectory(tmp_path):
    # the subtitle said "the first … collisions of each trajectory" of a run of one trajectory
    exe = os.path.join(os.path.dirname(sys.executable), "rbx")
    titles = {}
    for m in (1, 2):
        h5, png = tmp_path / f"s{m}.h5", tmp_path / f"s{m}.png"
        r = subprocess.run([exe, "simulate", os.path.join(EXAMPLES, "sinai.yaml"), "-o", str(h5), "--collisions",
                            "3000", "--trajectories", str(m), "--quiet"], capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, r.stderr
        r = subprocess.run([exe, "plot", str(h5), "--kind", "orbit", "-o", str(png)], capture_output=True,
                           text=True, timeout=300)
        assert r.returncode == 0 and png.exists(), r.stderr
        titles[m] = " ".join(make_figure(str(h5), "orbit").axes[0].get_title().split())
    assert titles[1].startswith("lines: the first ") and " collisions of the trajectory; grey" in titles[1], titles
    assert " collisions of each trajectory; grey" in titles[2], titles


def test_phase_and_birkhoff_put_a_collision_at_the_same_s(runs):
    """One convention for the arc length on an unbounded wall: counter-clockwise (the table on the left), so on the
    strip's top wall s = −x, and the same collision lands at the same (s, sin ψ) in the phase portrait and in the
    Birkhoff map (the phase portrait measured s along +x there, the Birkhoff map along −x)."""
    run = Run.open(runs["strip"])
    with run:
        top = run.wall_names.index("top")
        wall = run.read("wall", [0], slice(None))[0]
        x = run.read("position", [0], slice(None))[0][wall == top, 0]
        vx = run.read("velocity", [0], slice(None))[0][wall == top, 0]
        speed = np.linalg.norm(run.read("velocity", [0], slice(None))[0][wall == top], axis=1)
    assert len(x) > 100

    def points(fig, title):
        ax = [a for a in fig.axes if a.get_title().endswith(title)][0]
        xy = np.concatenate([c.get_offsets() for c in ax.collections])
        return xy[np.lexsort(xy.T[::-1])], ax.get_xlabel()
    phase, label = points(make_figure(runs["strip"], "phase", trajectories="0"), "boundary map on wall 'top'")
    birk, label2 = points(make_figure(runs["strip"], "birkhoff", trajectories="0", wall="top"),
                          "boundary map on wall 'top'")
    np.testing.assert_allclose(phase, birk, rtol=0, atol=1e-12)
    assert label == label2 and "counter-clockwise (towards −x)" in label
    # the closed form: on the top wall the counter-clockwise tangent is −x, so s = −x and sin ψ = −vₓ/|v|
    expected = np.column_stack([-x, -vx / speed])
    np.testing.assert_allclose(phase, expected[np.lexsort(expected.T[::-1])], rtol=0, atol=1e-12)


def _example_run(tmp_path, name, collisions):
    import rbx
    exp = rbx.load(os.path.join(EXAMPLES, name + ".yaml"), {"collisions": collisions})
    path = str(tmp_path / f"{name}.h5")
    rbx.simulate(exp, output=path, force=True)
    return path


def test_the_density_of_a_long_orbit_shows_between_its_drawn_flights(tmp_path):
    """The rough circle's orbit drew 250 chords over the grey density of the whole run that its title promised:
    the chords covered the annulus and no grey could be seen. Rendered, the grey of the density now shows in
    more of the orbit's disc than the lines' colour."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.colors import to_rgb
    fig = make_figure(_example_run(tmp_path, "circle", 2000), "orbit")
    assert "grey: the whole run" in fig.axes[0].get_title()
    FigureCanvasAgg(fig)
    fig.set_dpi(100)
    fig.canvas.draw()
    image = np.asarray(fig.canvas.buffer_rgba())[..., :3].astype(float) / 255
    box = fig.axes[0].get_window_extent()
    h = image.shape[0]
    inside = image[int(h - box.y1) + 5:int(h - box.y0) - 5, int(box.x0) + 5:int(box.x1) - 5]
    line = np.all(np.abs(inside - to_rgb(fig.axes[0].get_lines()[-1].get_color())) < 0.25, axis=-1)
    grey = (np.ptp(inside, axis=-1) < 0.03) & (inside.mean(axis=-1) < 0.97) & (inside.mean(axis=-1) > 0.4)
    assert grey.sum() > line.sum() > 0, (grey.sum(), line.sum())


def test_an_orbit_between_plates_is_drawn_as_a_stretch_a_few_gaps_long(tmp_path):
    """Between plates the orbit drifts (580 L along y in 2000 collisions of the example): its first 250 flights ran
    80 L along plates 1 apart, a block of ink at one end of the drawn planes, and the whole walk's projection was a
    solid block. Both panels now show a stretch at most STRETCH times the gap it spans, and say how far the whole
    run went."""
    fig = make_figure(_example_run(tmp_path, "plates", 2000), "orbit3d")
    ax3, ax2 = fig.axes[0], fig.axes[1]
    drawn = [line for line in ax3.get_lines() if line.get_label().startswith("trajectory")]
    xyz = np.concatenate([np.column_stack(line.get_data_3d()) for line in drawn])
    height = np.ptp(xyz[:, 2])
    assert 0.5 < height <= 1.0 and np.max(np.ptp(xyz[:, :2], axis=0)) <= 6 * height + 1.0   # plotting.STRETCH
    flat = [line for line in ax2.get_lines() if line.get_label().startswith("trajectory")]
    assert sum(len(line.get_xdata()) for line in flat) == len(xyz)
    assert "whole run" in ax2.get_title() and "−5" in ax2.get_title()
    assert readable(fig) == []
    # the orbit kind draws the same stretch from above, not the whole drift over its density
    fig = make_figure(str(tmp_path / "plates.h5"), "orbit")
    flat = np.concatenate([line.get_xydata() for line in fig.axes[0].get_lines()
                           if line.get_label().startswith("trajectory")])
    assert len(flat) == len(xyz) and not fig.axes[0].collections      # no density
    assert "whole run" in fig.axes[0].get_title()


def test_a_birkhoff_map_names_its_walls_over_their_stretches(runs):
    """The whole boundary's Birkhoff map marked the joints between walls and named none: each wall's name now
    stands over the middle of its stretch of s (the L-shaped polygon: six edges, in boundary order)."""
    run = Run.open(runs["lshape"])
    with run:
        geom, names = run.geometry(), run.wall_names
    for kind in ("birkhoff", "phase"):
        fig = make_figure(runs["lshape"], kind)
        (top,) = fig.axes[0].child_axes
        labels = [t.get_text().strip() for t in top.get_xticklabels()]
        assert labels == list(names), labels
        middles = [s0 + length / 2 for s0, length in (analysis.wall_span(geom, w) for w in range(len(names)))]
        np.testing.assert_allclose(top.get_xticks(), middles)


def test_a_figure_is_written_whole_under_any_name_the_file_system_takes(tmp_path):
    """Written beside its name and renamed (rbx.paths.written_whole): a name of 250 characters failed with 'File
    name too long' (the temporary name was longer), '.png' with "Format 'part' is not supported"."""
    from matplotlib.figure import Figure
    from rbx.plotting import save
    for name in ("a" * 246 + ".png", ".png", "b.svg", "noext"):
        fig = Figure()
        fig.add_subplot().plot([0, 1], [1, 0])
        save(fig, str(tmp_path / name))
        assert (tmp_path / name).stat().st_size > 0
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([".png", "a" * 246 + ".png", "b.svg", "noext"])
    assert (tmp_path / ".png").read_bytes()[:4] == (tmp_path / "noext").read_bytes()[:4] == b"\x89PNG"
