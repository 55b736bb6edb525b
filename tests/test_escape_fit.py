"""The escape plot's fitted law follows the survival over the window it claims (rbx.escape):

- on survival drawn from a known law (a fast transient, a trapped share, one exponential rate for the rest) the
  fit finds the rate and the level, starts after the transient and follows the data;
- on the rough open Sinai table (configs/examples/escape-sinai.yaml made rough: a fifth of the orbits trapped,
  the others leaving ever more slowly) the drawn curve stays within the Kaplan–Meier curve's noise over all of
  its window (one exponential fitted to the trajectories that leave ran 0.02 under the data at s = 181);
- where no exponential follows (a rough rectangle with a hole for a floor), no rate is drawn or printed.
"""
import os

import numpy as np
import pytest

import rbx
from rbx.cli.plot import make_figure
from rbx.dynamics import escape_times, survival
from rbx.escape import FOLLOWS, fit_escape

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SINAI = os.path.join(ROOT, "configs", "examples", "escape-sinai.yaml")


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
