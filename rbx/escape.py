"""The exponential law fitted to the survival of an open table, over a window where it follows the data.

The survival S(s) of the exit paths (Kaplan–Meier, :func:`rbx.dynamics.survival`) of a chaotic table with a hole
decays as one exponential after a transient. A table that traps orbits (a rough one: a share q of the starts never
reaches the hole) levels off instead, and the orbits that do leave need not decay at one rate: on the rough open
Sinai table their rate falls from 0.016 to 0.010 per unit path between the first exits and the last, so one
exponential fitted to all of them ran under the data (0.27 at s = 181 where the survival was 0.29). Here the model

    S(s) = S(s₀)·[q + (1 − q)·exp(−γ (s − s₀))]   for s ≥ s₀

(q = 0 where survival does not level off) is fitted by maximum likelihood to the trajectories still inside at s₀,
q and γ together, and s₀ is the first of a few starts at which the fitted curve follows the Kaplan–Meier curve
over the whole window within its noise: the largest gap between them, in units of 1/√n₀ (n₀ trajectories at risk
at s₀), at most :data:`FOLLOWS` — a Kolmogorov–Smirnov statistic of the window; 1.3 is its 1 % point for data drawn
from the model itself, q and γ fitted (150 samples of 2000 starts: 1.09 with q, 1.29 without).
Where no start passes, no rate is given: the decay is not exponential.

A trapped share is read only where the data show survival levelling off (:func:`levels_off`): over the later half
of what the orbits still inside were followed, the Kaplan–Meier curve is nearly flat, at least
:data:`PLATEAU_CENSORED` of them are still inside, and the few exits there are far fewer than the rate before
predicts. A few orbits still inside a curve that is still falling (a slow tail: a specular rectangle open on one
whole wall had 1 of 3000 inside after 2000 collisions, and none after 40 000) are no trapped share.
"""
import math
from dataclasses import dataclass

import numpy as np

from .dynamics import exponential_rate, survival

#: the largest gap between the fitted curve and the Kaplan–Meier curve, in units of 1/√n₀, for the fit to follow
#: the data: the 1 % point of the gap of data drawn from the model (with 1.63, Kolmogorov's 1 % point for a law
#: given in advance, a fit 0.03 under the rough Sinai table's data passed)
FOLLOWS = 1.3
#: the starts s₀ tried, as quantiles of the exit paths (after --fit-from): the transient is left out step by step
STARTS = (0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8)
#: fewer exits than this in a window leave too little to judge a fit by
MIN_EXITS = 20
#: survival has levelled off when, over the later half of what the orbits still inside were followed (the late
#: stretch), the trajectories exit at most at PLATEAU_RATIO of the rate they had before, and that shortfall is no
#: chance (Poisson tail below PLATEAU_P); the Kaplan–Meier curve falls by at most PLATEAU_DROP of its value over the
#: stretch (a tail falling as 1/s loses half; the rough Sinai table's plateau lost 9 %); and at least
#: PLATEAU_CENSORED orbits are still inside at the end of it
PLATEAU_RATIO, PLATEAU_P, PLATEAU_DROP, PLATEAU_CENSORED = 0.1, 1e-3, 0.25, 10


@dataclass(frozen=True)
class EscapeFit:
    """The fitted survival over ``start`` ≤ s ≤ ``stop``: S(s) = ``survival0``·[q + (1 − q)·exp(−γ (s − start))]."""
    rate: float               # γ per unit path (or time)
    rate_err: float           # its standard error (the inverse of the observed information)
    level: float              # q: the share of those inside at ``start`` that never leave (0 when not fitted)
    start: float
    stop: float
    survival0: float          # the Kaplan–Meier survival at ``start``
    exits: int                # exits inside the window
    at_risk: int              # trajectories still inside at ``start``
    gap: float                # the largest gap to the Kaplan–Meier curve over the window, in units of 1/√at_risk
    follows: bool             # gap ≤ FOLLOWS
    trapped: bool             # q fitted (survival levels off) or 0

    def survival(self, s):
        s = np.asarray(s, float)
        return self.survival0 * (self.level + (1.0 - self.level) * np.exp(-self.rate * (s - self.start)))


def fit_escape(path, exited, fit_from=0.1, trapped=False):
    """The first window that the model follows (see the module) -> :class:`EscapeFit`, or, when none does, the
    fit of the first window tried with ``follows`` False.

    ``path``, ``exited``: each trajectory's exit (or censored) path and whether it exited. The starts are the
    quantiles ``fit_from`` and :data:`STARTS` above it of the exit paths. ``trapped``: survival levels off, and q
    is fitted with γ, the window running to the last exit; else q = 0 and the window ends at the 1 − ``fit_from``
    quantile (the few latest exits, of rare long stays, left out)."""
    if not 0.0 <= fit_from < 0.5:       # NaN too: the window would be empty ('fewer than 20 exits' of 40 000)
        raise ValueError(f"fit_from is a quantile of the exit paths in [0, 0.5), not {fit_from!r}")
    path = np.asarray(path, float)
    exited = np.asarray(exited, bool)
    leaving = np.sort(path[exited])
    if len(leaving) == 0:
        raise ValueError("no trajectory exited")
    s, S = survival(path, exited)
    stop = float(leaving[-1]) if trapped else float(np.quantile(leaving, 1.0 - fit_from))
    quantiles = [fit_from] + [q for q in STARTS if q > fit_from and (trapped or q < 1.0 - fit_from - 0.1)]
    first = None
    for q in quantiles:
        start = 0.0 if q == 0 else float(np.quantile(leaving, q))
        fit = _fit_window(path, exited, s, S, start, stop, trapped)
        if fit is None:
            continue
        if fit.follows:
            return fit
        first = first or fit
    if first is None:
        raise ValueError(f"fewer than {MIN_EXITS} exits in any window: too few to fit a rate")
    return first


def levels_off(path, exited):
    """Whether survival has levelled off by the end of the run (see :data:`PLATEAU_RATIO`) -> bool.

    The orbits still inside at the end (censored) were followed over paths whose median is s_end; the late
    stretch runs from s_end/2 on. A table that traps (a share of orbits never reaching the exit) has almost no
    exits there; a tail that is still falling, however slowly, has about as many as the rate before predicts, or
    its Kaplan–Meier curve still falls, or too few orbits are left in it to tell."""
    from scipy import stats
    path = np.asarray(path, float)
    exited = np.asarray(exited, bool)
    if exited.all() or not exited.any():
        return False
    half = 0.5 * float(np.median(path[~exited]))
    if int(np.sum(~exited & (path >= half))) < PLATEAU_CENSORED:
        return False
    early, _, k_early = exponential_rate(path, exited, 0.0, half)
    late = exited & (path >= half)
    exposure = float(np.sum(np.maximum(path - half, 0.0)))
    predicted = early * exposure
    if k_early == 0 or int(late.sum()) > PLATEAU_RATIO * predicted \
            or stats.poisson.cdf(int(late.sum()), predicted) > PLATEAU_P:
        return False
    # the Kaplan–Meier curve over the stretch: each exit past s_end/2 takes 1/(those at risk) of what is left
    ordered = np.sort(path)
    at_risk = (len(path) - np.searchsorted(ordered, np.sort(path[late]), side="left")).astype(float)
    kept = float(np.prod(1.0 - 1.0 / at_risk)) if len(at_risk) else 1.0
    return 1.0 - kept <= PLATEAU_DROP


def _fit_window(path, exited, s, S, start, stop, trapped):
    at = path >= start
    n0 = int(np.sum(at))
    k = int(np.sum(exited & at & (path <= stop)))
    if k < MIN_EXITS:
        return None
    S0 = float(S[np.searchsorted(s, start, side="left") - 1]) if start > 0 else 1.0   # just before start
    if trapped:
        rate, err, level = _cure_fit(path[at] - start, exited[at] & (path[at] <= stop), stop - start)
    else:
        rate, err, _ = exponential_rate(path, exited, start, stop)
        level = 0.0
    fit = EscapeFit(rate, err, level, start, stop, S0, k, n0, math.nan, False, trapped)
    # the gap on both sides of each step of the Kaplan–Meier curve inside the window
    inside = (s >= start) & (s <= stop)
    after = S[inside]
    before = np.concatenate([[S0], after[:-1]])
    model = fit.survival(s[inside])
    gap = float(np.max(np.maximum(np.abs(after - model), np.abs(before - model)), initial=0.0)) / S0
    gap *= math.sqrt(n0)
    return EscapeFit(rate, err, level, start, stop, S0, k, n0, gap, gap <= FOLLOWS, trapped)


def _cure_fit(t, exited, horizon):
    """Maximum likelihood of S(t) = q + (1 − q)·exp(−γ t) for times ``t`` ≥ 0 (exits and right-censored, censored at
    ``horizon`` at the latest) -> (γ, its standard error, q).

    An exit at t contributes (1 − q)·γ·exp(−γ t), a trajectory censored at t the survival q + (1 − q)·exp(−γ t)."""
    from scipy import optimize
    t = np.minimum(np.asarray(t, float), horizon)
    e = np.asarray(exited, bool)
    te, tc = t[e], t[~e]
    k, n = len(te), len(t)

    def nll(q, g):
        with np.errstate(divide="ignore"):
            return -(k * math.log1p(-q) + k * math.log(g) - g * math.fsum(te.tolist())
                     + float(np.sum(np.log(q + (1.0 - q) * np.exp(-g * tc)))))

    def nll_free(x):           # over the real line: q = logistic(x₀), γ = exp(x₁)
        return nll(1.0 / (1.0 + math.exp(-x[0])), math.exp(x[1]))

    q0 = min(max((n - k) / n, 1e-3), 1 - 1e-3)
    g0 = k / max(float(np.sum(t[e])) + 1e-300, 1e-300)
    best = optimize.minimize(nll_free, [math.log(q0 / (1 - q0)), math.log(g0)], method="Nelder-Mead",
                             options={"xatol": 1e-10, "fatol": 1e-10, "maxiter": 4000})
    q, g = 1.0 / (1.0 + math.exp(-best.x[0])), math.exp(best.x[1])
    # the observed information in (q, γ) by central differences; γ's variance is its inverse's (1, 1) entry
    h = np.array([1e-4 * min(q, 1 - q), 1e-4 * g])
    x0 = np.array([q, g])
    H = np.empty((2, 2))
    for i in range(2):
        for j in range(2):
            ei, ej = np.eye(2)[i] * h[i], np.eye(2)[j] * h[j]
            H[i, j] = (nll(*(x0 + ei + ej)) - nll(*(x0 + ei - ej)) - nll(*(x0 - ei + ej))
                       + nll(*(x0 - ei - ej))) / (4 * h[i] * h[j])
    try:
        var = float(np.linalg.inv(H)[1, 1])
    except np.linalg.LinAlgError:
        var = math.nan
    return g, (math.sqrt(var) if var > 0 else math.inf), q
