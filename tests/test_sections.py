"""Sections of phase space and the escape picture (docs/reference.md §10): ``rbx plot --kind birkhoff | poincare |
escape``.

- The Birkhoff map on a curved wall: arc length along the shrunk wall and sin ψ, checked against the arc's own
  geometry (a stadium's cap); the spin colour is the spin's share of the metric speed.
- The Poincaré section by a plane: crossings are on the plane, inside the table, and where the straight flight
  between two records crosses it; every upward crossing is found.
- The figures render with labelled axes; wrong options are one line and exit 2.
"""
import numpy as np
import pytest
from click.testing import CliRunner

import rbx
from rbx import analysis
from rbx.cli.main import cli
from rbx.cli.plot import make_figure

ALL = ["time", "position", "velocity", "angular_velocity", "orientation", "wall", "rank"]
RUNS = {
    "stadium": {"table": {"kind": "stadium", "radius": 0.5, "length": 1.0},
                "boundary": {"default": {"rule": "constant", "rank": 1}}, "ball": {"radius": 0.1},
                "initial": {"sample": "billiard"}, "run": {"collisions": 400, "trajectories": 3, "seed": 4},
                "output": {"record": ALL}},
    "box": {"table": {"kind": "box", "size": [1.0, 1.3, 0.8]}, "boundary": {"default": {"rule": "constant", "rank": 2}},
            "ball": {"radius": 0.1}, "initial": {"sample": "billiard"},
            "run": {"collisions": 400, "trajectories": 3, "seed": 4}, "output": {"record": ALL}},
    "open": {"table": {"kind": "sinai", "size": [2.0, 1.5], "radius": 0.4},
             # point particles: one escape rate (a spinning disc keeps its spin at specular walls, each its own rate)
             "boundary": {"default": {"rule": "constant", "rank": 0}, "walls": {"left": {"rule": "exit"}}},
             "ball": {"radius": 0.1}, "initial": {"sample": "point_particle"},
             "run": {"collisions": 400, "trajectories": 300, "seed": 4}, "output": {"record": ["time", "wall"]}},
}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sections")
    out = {}
    for name, cfg in RUNS.items():
        out[name] = str(folder / f"{name}.h5")
        rbx.simulate(cfg, output=out[name])
    return out


def _labelled(fig):
    axes = [ax for ax in fig.axes if ax.get_label() != "<colorbar>"]
    for ax in axes:
        for text in (ax.get_xlabel(), ax.get_ylabel()):
            assert text and "[" in text and "]" in text, text
    return axes


def test_birkhoff_on_a_curved_wall(runs):
    run = rbx.open(runs["stadium"])
    geom = run.geometry()
    left = run.wall_names.index("left")            # the left cap: a half circle of radius 0.5 about the origin
    at = run.wall == left
    pos, vel = run.position[at], run.velocity[at]
    assert len(pos) > 50
    s, sin_psi = analysis.birkhoff_coordinates(geom, run.wall[at], pos, vel)
    s0, length = analysis.wall_span(geom, left)
    rho = 0.5 - 0.1
    assert length == pytest.approx(np.pi * rho)
    phi = np.arctan2(pos[:, 1], pos[:, 0])           # in (π/2, 3π/2) on the left cap, mod 2π
    phi = np.mod(phi, 2 * np.pi)
    tangent = np.stack([-np.sin(phi), np.cos(phi)], axis=1)   # counter-clockwise along the circle
    np.testing.assert_allclose(sin_psi, np.sum(vel * tangent, axis=1) / np.linalg.norm(vel, axis=1), atol=1e-9)
    np.testing.assert_allclose(s - s0, rho * (phi - np.pi / 2), atol=1e-9)
    fig = make_figure(runs["stadium"], "birkhoff", wall="left")
    (ax,) = _labelled(fig)
    assert ax.get_xlim() == pytest.approx((0.0, length))
    assert "'left'" in ax.get_xlabel()


def test_spin_share():
    share = analysis.spin_fraction(np.array([[3.0, 0.0]]), np.array([4.0 / (0.5 * np.sqrt(0.25))]), 0.5, 0.25)
    assert share[0] == pytest.approx(0.8)


def test_poincare_crossings(runs):
    run = rbx.open(runs["box"])
    normal, offset = analysis.parse_plane("z=0.4")
    cut = analysis.plane_crossings(run.position, run.velocity, run.angular_velocity, run.time, normal, offset)
    z = run.position[..., 2]
    upward = (z[:, :-1] < 0.4) & (z[:, 1:] >= 0.4)
    assert len(cut["time"]) == upward.sum() > 20
    np.testing.assert_allclose(cut["position"][:, 2], 0.4, atol=1e-12)
    assert np.all(run.geometry().clearance(cut["position"]) >= -1e-12)
    j, k = cut["trajectory"], cut["record"]
    assert np.all((run.time[j, k] <= cut["time"]) & (cut["time"] <= run.time[j, k + 1]))
    # the crossing lies on the straight flight from record k to record k+1
    back = cut["position"] - (cut["time"] - run.time[j, k])[:, None] * run.velocity[j, k]
    np.testing.assert_allclose(back, run.position[j, k], atol=1e-12)
    n2, c2 = analysis.parse_plane("n=0,0,2;c=0.8")
    np.testing.assert_allclose(n2, normal)
    assert c2 == pytest.approx(offset)
    fig = make_figure(runs["box"], "poincare", plane="z=0.4")
    assert len(_labelled(fig)) == 2


def test_planes_of_any_scale_and_bad_planes():
    """A normal is scaled before its length is taken (components of 1e300 overflowed with a NumPy warning and were
    called 'all 0', of 1e-300 were 0); a NaN offset, a key given twice or a word are refused."""
    n, c = analysis.parse_plane("n=1e300,1e300,0;c=0")
    np.testing.assert_allclose(n, [2 ** -0.5, 2 ** -0.5, 0.0])
    assert c == 0.0
    n, c = analysis.parse_plane("n=1e-300,0,0;c=3e-300")
    np.testing.assert_allclose(n, [1.0, 0.0, 0.0])
    assert c == pytest.approx(3.0)
    for bad in ("n=1,0,0;c=nan", "z=nan", "z=inf", "n=1,0,0;c=0.2;c=3", "n=0,0,0;c=1", "n=1,2;c=1", "n=a,0,0;c=1",
                "q=1"):
        with pytest.raises(ValueError):
            analysis.parse_plane(bad)


def test_escape_figure(runs):
    fig = make_figure(runs["open"], "escape")
    (ax,) = _labelled(fig)
    assert ax.get_yscale() == "log"
    # the legend is the figure's, under the axes (plotting.legend_outside), not over the data
    (legend,) = fig.legends
    assert any("γ =" in t.get_text() for t in legend.get_texts())


@pytest.mark.parametrize("run,args,key", [
    ("stadium", ["--kind", "birkhoff", "--wall", "nowhere"], "--wall"),
    ("box", ["--kind", "birkhoff"], "2D run"),
    ("box", ["--kind", "poincare", "--plane", "w=3"], "--plane"),
    ("stadium", ["--kind", "poincare"], "3D run"),
    ("stadium", ["--kind", "escape"], "exit"),
])
def test_wrong_options_are_one_line(runs, run, args, key, tmp_path):
    result = CliRunner().invoke(cli, ["plot", runs[run], "-o", str(tmp_path / "x.png")] + args)
    assert result.exit_code == 2, result.output
    assert result.output.count("\n") == 1 and key in result.output and result.output.startswith("rbx: ")
