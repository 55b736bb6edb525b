"""Pictures that said less than they showed, as a referee read them: lines of a study that coincide, the last exit
of an escape plot, the bins of a histogram, a periodic orbit's section, and a mass distribution given as text."""
import os

import matplotlib
import numpy as np
import pytest

import rbx
from rbx import plotting
from rbx.model import ConfigError

matplotlib.use("Agg")
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
EXAMPLES = os.path.join(ROOT, "configs", "examples")


def test_lines_of_a_study_that_take_the_same_values_stay_apart():
    """Shares of few orbits are k/n, so two lines of a two-key study often coincide: drawn alike, the later one hid
    the earlier (a reader saw a line stop). Each line has its own marker and dashes, the later ones smaller."""
    series = [{"x": [0.2, 0.5, 1.0], "y": y, "err": None, "label": f"R = {r}"}
              for r, y in ((0.05, [0.125, 0.25, 0.0]), (0.1, [0.0, 0.25, 0.125]), (0.15, [0.375, 0.25, 0.125]))]
    fig = plotting.sweep_figure([{"series": series, "xlabel": "κ", "ylabel": "share"}], "t")
    lines = [c.lines[0] for c in fig.axes[0].containers]
    assert len({line.get_marker() for line in lines}) == 3 and len({line.get_linestyle() for line in lines}) == 3
    sizes = [line.get_markersize() for line in lines]
    assert sizes == sorted(sizes, reverse=True) and sizes[0] > sizes[-1]


def test_an_escape_plot_where_every_orbit_left_shows_the_last_exit():
    """Every orbit left, the last at s = 1220: S = 0 has no place on a log axis, and the last level (1/n) ran to the
    right edge like an orbit that stays. The drop at the last exit is drawn, and the legend says where it is."""
    s = np.array([0.0, 1.0, 2.0, 5.0, 9.0])
    S = np.array([1.0, 0.75, 0.5, 0.25, 0.0])
    fig = plotting.escape_figure(s, S, None, 4, 4, "t")
    labels = fig.axes[0].get_legend_handles_labels()[1]
    assert "the last orbit leaves at s = 9: S = 0 from there (off the log axis)" in labels, labels
    drop = [line for line in fig.axes[0].get_lines() if list(line.get_xdata()) == [9.0, 9.0]]
    assert drop and drop[0].get_ydata()[0] == 0.25 and drop[0].get_ydata()[1] == fig.axes[0].get_ylim()[0]
    # one that stays: no such line
    fig = plotting.escape_figure(s[:4], S[:4], None, 3, 4, "t")
    assert not any("last orbit" in t for t in fig.axes[0].get_legend_handles_labels()[1])


def test_the_displacement_histograms_bins_are_outlined():
    """Two neighbouring bins of one height read as one bar twice as wide (a referee asked whether the tails were
    merged): each bar of equal width is outlined."""
    from matplotlib.figure import Figure
    ax = Figure().add_subplot()
    plotting.displacement_histogram(ax, np.array([-3.0, -2.0, 0.0, 0.5, 1.0, 4.0] * 3), "x", 100)
    widths = {round(p.get_width(), 12) for p in ax.patches}
    assert len(ax.patches) == 10 and len(widths) == 1
    assert all(tuple(p.get_edgecolor()[:3]) == (1.0, 1.0, 1.0) and p.get_linewidth() > 0 for p in ax.patches)


def test_a_periodic_orbits_section_says_it_is_one():
    """The 60° wedge's orbit has period 4: its Birkhoff map on one wall was two dots, each hit 250 times, in an
    empty frame that looked like a plot that failed. The panel says how many points fall on how many places."""
    x = np.tile([0.3, 1.72], 250)
    y = np.tile([0.02, -0.97], 250)
    assert plotting.repeated_points(x, y) == "500 points on 2 places: a periodic orbit, each hit about 250 times"
    rng = np.random.default_rng(0)
    assert plotting.repeated_points(rng.uniform(size=500), rng.uniform(size=500)) is None   # a chaotic section
    assert plotting.repeated_points([0.1, 0.2], [0.3, 0.4]) is None         # two points, each once: nothing to say
    fig = plotting.section_figure([{"x": x, "y": y, "xlabel": "s", "ylabel": "sin ψ"}], np.tile([0.1, -0.3], 250),
                                  "t", "spin")
    assert any("a periodic orbit" in t.get_text() for t in fig.axes[0].texts)


@pytest.mark.parametrize("given, words", [("0.3", "is the text '0.3', not a number: give κ as a number (inertia: "
                                                   "0.3, no quotes)"),
                                          ("unifrom", "unknown mass distribution 'unifrom' for a 2D ball")])
def test_a_mass_distribution_given_as_text_is_named_as_such(given, words):
    """κ written "0.3" (quoted in YAML, or a string in Python) was refused as an unknown mass distribution '0.3'."""
    with pytest.raises(ConfigError, match="ball.inertia: " + words.replace("(", r"\(").replace(")", r"\)")):
        rbx.load(os.path.join(EXAMPLES, "circle.yaml"), {"ball.inertia": given})
    with pytest.raises(ConfigError, match=words.replace("(", r"\(").replace(")", r"\)")):
        rbx.model.Ball(0.1, given, 2)
