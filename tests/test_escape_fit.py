"""The escape plot's fitted law follows the survival over the window it claims (rbx.escape):

- on survival drawn from a known law (a fast transient, a trapped share, one exponential rate for the rest) the
  fit finds the rate and the level, starts after the transient and follows the data;
- on the rough open Sinai table (configs/examples/escape-sinai.yaml made rough: a fifth of the orbits trapped,
  the others leaving ever more slowly) the drawn curve stays within the Kaplan–Meier curve's noise over all of
  its window (one exponential fitted to the trajectories that leave ran 0.02 under the data at s = 181);
- where no exponential follows (a rough rectangle with a hole for a floor), no rate is drawn or printed;
- a trapped share is read only where survival levels off: a few orbits still inside a tail that is still falling
  (a specular rectangle open on one whole wall) are said to be no trapped share; the exits the legend counts are
  those rbx simulate's summary counts as ended earlier, plus those at the run's last collision, both said.
"""
import os

import numpy as np
import pytest

import rbx
from rbx.cli.plot import make_figure
from rbx.dynamics import escape_times, survival
from rbx.escape import FOLLOWS, fit_escape, levels_off

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SINAI = os.path.join(ROOT, "configs", "examples", "escape-sinai.yaml")
RECTANGLE = os.path.join(ROOT, "configs", "examples", "rectangle.yaml")


def known_survival(n, seed):
    """n starts: 30 % leave at rate 1 (the transient), 20 % never leave (censored at s = 4000), 50 % leave at
    rate 0.02 -> (path, exited)."""
    rng = np.random.default_rng(seed)
    kind = rng.choice(3, size=n, p=[0.3, 0.2, 0.5])
    path = np.where(kind == 0, rng.exponential(1.0, n), np.where(kind == 1, 4000.0, rng.exponential(50.0, n)))
    return path, kind != 1


def test_a_known_law_is_recovered_after_its_transient():
    path, exited = known_survival(6000, 1)
    fit = fit_escape(path, exited, fit_from=0.1, trapped=True)
    assert fit.follows and fit.gap <= FOLLOWS
    assert abs(fit.rate - 0.02) < 3 * fit.rate_err, (fit.rate, fit.rate_err)
    assert fit.rate_err < 0.1 * fit.rate
    # the level it tends to is the trapped share, 0.2 (binomial error 0.005)
    assert fit.survival0 * fit.level == pytest.approx(0.2, abs=0.02)
    # the window starts after the transient: by then 1 − e^(−s₀) of the fast ones have left, nearly all
    assert fit.start > 3.0
    # fitted from the first exit, the transient bends the data away from any one exponential: refused
    first = fit_escape(path, exited, fit_from=0.0, trapped=True)
    assert first.start > 0.0


def test_without_a_trapped_share_the_law_is_one_exponential():
    rng = np.random.default_rng(2)
    path = rng.exponential(40.0, 4000)
    fit = fit_escape(path, np.ones(len(path), bool), fit_from=0.1, trapped=False)
    assert fit.follows and fit.level == 0.0 and fit.start == pytest.approx(np.quantile(path, 0.1))
    assert abs(fit.rate - 1 / 40) < 3 * fit.rate_err


def fitted_line(fig):
    lines = [line for line in fig.axes[0].get_lines() if "γ =" in line.get_label()]
    return lines[0].get_data() if lines else None


@pytest.mark.long
def test_the_drawn_fit_follows_the_rough_sinai_survival(tmp_path):
    run = str(tmp_path / "esc.h5")
    rbx.simulate(rbx.load(SINAI, {"boundary.default": {"rule": "constant", "rank": 1}}), output=run)
    esc = escape_times(rbx.open(run))
    assert 0.15 < np.mean(~esc.exited) < 0.3          # the case: a fifth trapped
    s, S = survival(esc.path, esc.exited)
    fig = make_figure(run, "escape")
    x, y = fitted_line(fig)
    assert x.max() > 150.0                              # the window reaches the slow part
    n0 = int(np.sum(esc.path >= x.min()))
    data = S[np.searchsorted(s, x, side="right") - 1]
    gap = np.max(np.abs(data - y)) * np.sqrt(n0) / data[0]
    assert gap <= FOLLOWS, gap
    # what rbx plot prints (tests/test_new_user.py: through the CLI) is the drawn fit
    said = fig.rbx_result
    assert f"fitted over {x.min():.3g} ≤ s ≤ {x.max():.3g}" in said and "trapped share" in said, said


def test_no_rate_where_no_exponential_follows():
    """Survival through two rates in equal shares (2 and 30) and a trapped share: from the 0.1 quantile on, the
    decay bends until the fast ones have left, so the window starts late or not at all; the figure of a fit that
    does not follow draws no line and says so."""
    from rbx.plotting import escape_figure
    rng = np.random.default_rng(3)
    n = 4000
    path = np.concatenate([np.where(rng.random(n) < 0.5, rng.exponential(2.0, n), rng.exponential(30.0, n)),
                           np.full(200, 1e4)])
    exited = path < 1e4
    fit = fit_escape(path, exited, fit_from=0.1, trapped=True)
    assert fit.start >= np.quantile(path[exited], 0.5) or not fit.follows
    s, S = survival(path, exited)
    fig = escape_figure(s, S, None, int(exited.sum()), len(path), "two rates", trapped=(0.05, 0.045, 0.055))
    texts = [t.get_text() for leg in fig.legends for t in leg.get_texts()]
    assert fitted_line(fig) is None
    assert any(t.startswith("no exponential law follows") for t in texts), texts


def test_levelling_off_needs_a_flat_late_stretch_with_orbits_in_it():
    path, exited = known_survival(6000, 1)              # a fifth never leaves: a plateau
    assert levels_off(path, exited)
    # a tail falling as 2/s (no plateau) followed up to s = 6000: one orbit of 3000 still inside; up to s = 300: 21
    # still inside, and its Kaplan–Meier curve halves over the late stretch
    tail = 2.0 / np.random.default_rng(1).random(3000)
    for end, inside in ((6000.0, 1), (300.0, 17)):
        path, exited = np.minimum(tail, end), tail < end
        assert np.sum(~exited) == inside
        assert not levels_off(path, exited)
    assert not levels_off(path, np.ones(len(path), bool))      # nothing inside: nothing to read


def legend(fig):
    return [t.get_text() for leg in fig.legends for t in leg.get_texts()]


@pytest.mark.long
def test_a_few_orbits_inside_a_falling_tail_are_no_trapped_share(tmp_path):
    """A specular rectangle open on its whole left wall traps nothing (every orbit leaves by 40 000 collisions),
    but its tail is slow: after 2000 collisions one orbit of 3000 is still inside. That is no trapped share."""
    run = str(tmp_path / "rect.h5")
    exp = rbx.load(RECTANGLE, {"boundary": {"default": {"rule": "constant", "rank": 0}, "walls": {"left": {"rule": "exit"}}},
                               "initial.wall": None, "run.trajectories": 3000, "run.collisions": 2000,
                               "output.record": ["wall"], "output.every": 100})
    rbx.simulate(exp, output=run)
    esc = escape_times(rbx.open(run))
    assert 0 < np.sum(~esc.exited) < 10
    fig = make_figure(run, "escape")
    said, texts = fig.rbx_result, legend(fig)
    assert "; trapped share" not in said and not any(t.startswith("trapped share") for t in texts), (said, texts)
    # a study's escape_rate is the figure's number, and none where the figure finds no exponential law
    from rbx.observables import PointRuns, get
    value = get("escape_rate").compute(PointRuns(rbx.open(run).experiment, rbx.open(run)), {"fit_from": 0.1})
    # (this rectangle's decay is not exponential: a study gave it 0.260 ± 0.006 while the figure said no rate)
    assert said.startswith("no escape rate") and np.isnan(value.value), (said, value)
    inside = f"({np.sum(~esc.exited)} of 3000 still inside)"
    assert f"survival still falling at the end of the run {inside}: no trapped share can be read; run longer" in said
    assert f"still falling at the end of the run {inside}: no trapped share can be read; run longer" in texts
    # a rate read while the curve still falls is of its window: said so where one is given
    assert ("escape rate γ = " in said) == ("(a longer run may bend the curve towards a level and change the rate)"
                                             in said), said


@pytest.mark.long
def test_the_exits_counted_agree_with_the_summary(tmp_path):
    """escape-sinai.yaml with point-particle starts run for 100 collisions: some orbits exit at their 100th
    collision. rbx simulate's summary counts those that ended earlier; the legend gives the exits, and how many of
    them were at the last collision. The survival is still falling at the end: no trapped share."""
    run = str(tmp_path / "esc.h5")
    rbx.simulate(rbx.load(SINAI, {"initial": {"sample": "point_particle"}}), collisions=100, output=run)
    final = rbx.open(run).final
    exited = escape_times(rbx.open(run)).exited
    np.testing.assert_array_equal(rbx.escape_times(run).exited, exited)       # a path, as rbx.open takes it
    with pytest.raises(TypeError, match="a run .* or a run file's path, not int"):
        rbx.escape_times(5)
    earlier = int(np.sum(~final["alive"] & (final["collisions"] < 100)))    # rbx simulate's "ended earlier"
    at_last = int(np.sum(exited & (final["collisions"] == 100)))
    assert at_last > 0 and earlier + at_last == exited.sum()
    fig = make_figure(run, "escape")
    texts = legend(fig)
    assert f"Kaplan–Meier survival ({exited.sum()} of 2000 exited: {earlier} before the run's last collision, " \
           f"{at_last} at it)" in texts, texts
    assert "no trapped share can be read" in fig.rbx_result and "trapped share:" not in " ".join(texts)
    # a rate is fitted, of a curve still falling: said to be of its window; a study's escape_rate is that number
    assert "escape rate γ = " in fig.rbx_result and "a longer run may bend the curve" in fig.rbx_result, \
        fig.rbx_result
    from rbx.observables import PointRuns, get
    value = get("escape_rate").compute(PointRuns(rbx.open(run).experiment, rbx.open(run)), {"fit_from": 0.1})
    from rbx.analysis import plus_minus
    assert f"escape rate γ = {plus_minus(value.value, value.stderr)} " in fig.rbx_result, (fig.rbx_result, value)


def test_the_fit_window_is_checked_where_the_fit_is_asked_for():
    """fit_escape(fit_from=0.5) said 'fewer than 20 exits in any window' of 40 000 exits; the CLI said the range."""
    from rbx.escape import fit_escape
    path = np.random.default_rng(1).exponential(10.0, 1000)
    for wrong in (0.5, -0.1, float("nan")):
        with pytest.raises(ValueError, match=r"fit_from is a quantile of the exit paths in \[0, 0.5\)"):
            fit_escape(path, np.ones(1000, bool), fit_from=wrong)
    assert fit_escape(path, np.ones(1000, bool), fit_from=0.1).rate == pytest.approx(0.1, rel=0.15)


@pytest.mark.long
def test_spinning_starts_under_specular_walls_have_no_single_rate(tmp_path):
    """A specular wall keeps each disc's spin: an orbit whose share of speed in the plane is c leaves at its own rate
    c·ℓ/(πA), so the survival of billiard-measure starts is a mixture of exponentials (the escape example's, said to
    be 'close to gate/(4A)', fell more slowly than that from a third of its orbits on). No rate is fitted or stored;
    the plot draws the mean rate at the start, ℓ/(4A) (0.15 over 4 × the centre's table 1.8 × 1.3 less the disc of
    radius 0.5), and the survival lies above it later. Point-particle starts get the classic rate and line."""
    run = str(tmp_path / "esc.h5")
    rbx.simulate(rbx.load(SINAI), collisions=2000, output=run)
    fig = make_figure(run, "escape")
    rate = 0.15 / (4 * (1.8 * 1.3 - np.pi * 0.5 ** 2))
    assert fig.rbx_result.startswith("no escape rate: every wall is specular, so each orbit keeps its spin") and \
        f"|hole|/(4·|table|) = {rate:.4g}" in fig.rbx_result and "escape rate γ" not in fig.rbx_result, fig.rbx_result
    assert any(t.startswith(f"mean rate at the start |hole|/(4·|table|) = {rate:.4g}") for t in legend(fig))
    # the mixture, measured: at the start the survival falls at the mean rate; later more slowly than it
    esc = escape_times(rbx.open(run))
    s, S = survival(esc.path, esc.exited)
    early = S[np.searchsorted(s, 20.0)]
    assert abs(-np.log(early) / 20.0 - rate) < 0.15 * rate, (-np.log(early) / 20.0, rate)
    # at s = 150, more orbits inside than one exponential at the mean rate leaves, by over 3 Poisson errors
    inside, expected = 2000 * S[np.searchsorted(s, 150.0)], 2000 * np.exp(-rate * 150.0)
    assert inside > expected + 3 * np.sqrt(expected), (inside, expected)
    from rbx.observables import PointRuns, get
    value = get("escape_rate").compute(PointRuns(rbx.open(run).experiment, rbx.open(run)), {"fit_from": 0.1})
    assert np.isnan(value.value) and np.isnan(value.companions["small_hole"])
    # no spin: one rate, near the classic billiard's small-hole rate ℓ/(πA), and its line
    pp = str(tmp_path / "pp.h5")
    rbx.simulate(rbx.load(SINAI, {"initial": {"sample": "point_particle"}}), collisions=2000, output=pp)
    fig = make_figure(pp, "escape")
    assert fig.rbx_result.startswith("escape rate γ = ") and \
        any(t.startswith(f"small-hole rate |hole|/(π·|table|) = {4 * rate / np.pi:.4g}") for t in legend(fig))
