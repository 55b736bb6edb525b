"""The examples record what the plot kinds they are made for need: each ``configs/examples/*.yaml`` names its kinds
in its first line (``# plots: orbit, phase, birkhoff --wall bottom``), and a short run of it *as it ships* (its
trajectories, recorded fields and ``every``; fewer collisions; the real ``rbx simulate`` in a process) draws every
one of them through the CLI's own :func:`rbx.cli.plot.make_figure` — the Lorentz gas recorded no spin, so its phase portrait was refused, and the
rectangle recorded every 10th collision while its orbit's subtitle said "lines: the first 25 collisions".
``make gallery`` (scripts/gallery.py) draws docs/gallery.md from the same runs."""
import importlib.util
import os
import subprocess
import sys

import h5py
import matplotlib
import numpy as np
import pytest
import yaml

import rbx
from rbx.cli.plot import KINDS, make_figure
from tests.test_plot import readable

matplotlib.use("Agg")
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
EXAMPLES = os.path.join(ROOT, "configs", "examples")
_spec = importlib.util.spec_from_file_location("gallery", os.path.join(ROOT, "scripts", "gallery.py"))
gallery = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(gallery)


def examples():
    return sorted(f[:-5] for f in os.listdir(EXAMPLES) if f.endswith(".yaml"))


def test_every_example_names_the_plot_kinds_it_is_made_for():
    for name in examples():
        kinds = gallery.example_kinds(os.path.join(EXAMPLES, f"{name}.yaml"))
        assert kinds, f"{name}.yaml: no '# plots: …' first line"
        assert all(kind in KINDS for kind, _ in kinds), (name, kinds)


@pytest.mark.long
@pytest.mark.parametrize("name", examples())
def test_an_example_as_it_ships_runs_and_draws_every_kind_it_lists(name, tmp_path):
    """The real ``rbx simulate`` of the example (fewer collisions) writes a complete file of the records it asks
    for, and every kind the example lists is drawn from that file."""
    import matplotlib.pyplot as plt
    config = os.path.join(EXAMPLES, f"{name}.yaml")
    exp = rbx.load(config)
    collisions = min(300, exp.run.collisions)
    out = tmp_path / "run.h5"
    res = subprocess.run([sys.executable, "-c", "from rbx.cli.main import main; main()", "simulate", config,
                          "-o", str(out), "--collisions", str(collisions), "--quiet"],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    _check_file(out, collisions)
    for kind, options in gallery.example_kinds(config):
        fig = make_figure(str(tmp_path / "run.h5"), kind, **options)   # a UserError here: the example lacks a field
        if kind == "orbit":
            # what the subtitle says is drawn is what is drawn: lines only where every collision is recorded
            subtitle = fig.axes[0].get_title()
            if exp.output.every > 1:
                assert "lines" not in subtitle, subtitle
        plt.close(fig)
        if kind == "phase" and name == "strip":   # coloured by the step, the colour bar beside the legend squeezed
            # a panel until its label lay over the other (5 examples; the strip's is the quickest to draw)
            fig = make_figure(str(out), kind, colour="step", **options)
            assert readable(fig) == [], readable(fig)
            plt.close(fig)


def _check_file(out, collisions):
    with h5py.File(out) as f:
        assert f.attrs["complete"]
        n = int(f.attrs["dimension"])
        cfg = yaml.safe_load(f.attrs["config"])
        assert cfg["run"]["collisions"] == collisions
        g = f["collisions"]
        M = cfg["run"]["trajectories"]
        count = g["count"][:]
        assert count.shape == (M,)
        every = cfg["output"]["every"]
        assert np.all(count <= collisions // every + 1) and np.all(count >= 1)
        if "position" in g:
            assert g["position"].shape[:2] == (M, g["step"].shape[0]) and g["position"].shape[2] == n
            np.testing.assert_array_equal(g["step"][:], np.arange(g["step"].shape[0]) * every)
        if "wall" in g:
            assert np.all(g["wall"][:, 0] == -1)
        assert np.all(f["final/collisions"][:] <= collisions)


def test_an_orbit_of_records_that_skip_collisions_says_it_draws_points(tmp_path):
    """A run recording every 10th collision: its orbit is drawn as points, and the subtitle says so (it said "lines:
    the first 25 collisions")."""
    import matplotlib.pyplot as plt
    exp = rbx.load(os.path.join(EXAMPLES, "rectangle.yaml"), {"output.every": 10})     # 100 trajectories
    rbx.simulate(exp, collisions=1000, output=str(tmp_path / "run.h5"))
    fig = make_figure(str(tmp_path / "run.h5"), "orbit")
    subtitle = " ".join(fig.axes[0].get_title().split())        # the title is wrapped to the figure
    assert subtitle.startswith("points: the first") and "records" in subtitle and "one every 10 collisions" in \
        subtitle, subtitle
    plt.close(fig)


def test_the_gallery_shows_what_the_examples_list():
    """docs/gallery.md has a picture, on disk, of each kind each example lists, and no other."""
    text = open(os.path.join(ROOT, "docs", "gallery.md")).read()
    shown = {line.split("(gallery/")[1].rstrip(")") for line in text.splitlines() if line.startswith("![")}
    listed = {f"{name}-{kind}.png" for name in examples() if f"{name}.yaml" not in gallery.SAME_SCENE
              for kind, _ in gallery.example_kinds(os.path.join(EXAMPLES, f"{name}.yaml"))}
    assert shown == listed, (shown ^ listed)
    assert all(os.path.exists(os.path.join(ROOT, "docs", "gallery", name)) for name in shown)
