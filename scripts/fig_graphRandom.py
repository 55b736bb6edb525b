"""The disc, strip and start of Figure graph, but each collision is rough (rank 1) or specular (rank 0) with
probability ½, drawn independently. Left: one orbit, x along the channel against the step at the three time scales
of Figure graph, and the memory of its velocity v_x (largest |autocorrelation| per logarithmic lag bin): it is gone
after about ten collisions, against the long memory of the hemisphere rule. Right: 4000 trajectories from the same
start, different only in their random draws. Top: the apparent diffusion coefficient MSD/(2·step); middle: the mean-
square displacement on log–log axes; bottom: the displacement after 10⁴ collisions against the Gaussian of the exact
variance. The MSD grows linearly (log–log slope 1), and the fitted D agrees with the exact value. The exact value:
in the coordinates u = (R√κ·ω, v_x) a rough collision is a reflection, so the moments of the walk obey a closed
linear recursion (rbx.analysis.strip_random_rank_msd); with p = ½ the velocity correlation falls by (1 − κ)/(1 + κ)
= ⅓ per collision and D = τ²|u|²(1 + 1/κ)/4 = 0.2784 L² per collision. Why the ensemble starts from one state:
|v_y|, and with it the flight time τ, never changes in a strip, so each trajectory has its own D ∝ 1/v_y² per
collision. An earlier ensemble drawn from the billiard measure mixed such D's: their mean is infinite
(logarithmically), a few grazing starts carried half of the MSD, and the fit (D with a ±40% interval, intercept c ≈
−120 to −500 L², an apparently superlinear MSD) measured that noise — not a transient nor a bad window: the exact
MSD of this start is linear after ~10 collisions with c = −0.64 L², and the intercept fitted here, 36 ± 93 L², shows
how loosely a fit pins c down. 4000 trajectories give D to about ±5%; 10⁴ collisions are 1000 times the transient; x
every 20 collisions keeps the file small.
"""
import numpy as np
from matplotlib.figure import Figure as MplFigure
from scipy import stats

from fig_graph import SCALES, draw_memory, draw_scales, orbit_measures, read_orbit, record_orbit
from figlib import ROUNDING, Figure, arguments, geomspace
from rbx import analysis
from rbx.reader import Run

FIT_FROM = 0.1          # the diffusion fit uses the last 90% of the run
MEMORYLESS = 0.02       # largest |ρ| at long lags for "no memory" (noise: ~0.006 on 10⁶ collisions)


def rank_one_probability(boundary):
    """p of a boundary whose rule on every wall is random between constant rank 0 and rank 1 rules."""
    rule = boundary.get("default")
    if boundary.get("walls") or not rule or rule.get("rule") != "random":
        raise SystemExit("graphRandom needs one random rule on both walls (boundary: default: {rule: random, …})")
    p = 0.0
    for choice, prob in zip(rule["choices"], rule["probabilities"]):
        if choice.get("rule") != "constant":
            raise SystemExit("graphRandom: the random rule must choose among constant rules")
        p += prob if int(choice.get("rank", 0)) == 1 else 0.0
    return p


def read_ensemble(path):
    with Run.open(path) as run:
        run.require(["position"], "the mean-square displacement")
        if run.table_kind != "strip":
            raise SystemExit(f"{path}: expected a run in a strip, got {run.table_kind}")
        init = run.config["initial"]
        if "sample" in init:
            raise SystemExit(f"{path}: the ensemble must start from one state (see the caption)")
        x = run.read("position", list(range(run.trajectories)))[:, :, 0]
        return dict(steps=run.step.astype(float), x=x, init=init, width=float(run.config["table"]["width"]),
                    R=run.radius, kappa=run.kappa, p=rank_one_probability(run.config["boundary"]),
                    title=run.scene())


def split_runs(paths):
    """-> (orbit path, ensemble path): the run with one trajectory is the orbit."""
    counts = {}
    for p in paths:
        with Run.open(p) as run:
            counts[p] = run.trajectories
    orbit = [p for p in paths if counts[p] == 1]
    ensemble = [p for p in paths if counts[p] > 1]
    if len(orbit) != 1 or len(ensemble) != 1:
        raise SystemExit("graphRandom needs two runs: one orbit (1 trajectory) and one ensemble (> 1)")
    return orbit[0], ensemble[0]


def ensemble_measures(e):
    steps, x = e["steps"], e["x"]
    init = e["init"]
    msd = analysis.mean_square_displacement(x)
    fit = analysis.fit_diffusion(steps, x, fit_from=FIT_FROM)
    exact, D, c = analysis.strip_random_rank_msd(steps.astype(int), init["position"], init["velocity"],
                                                 init["angular_velocity"], e["width"], e["R"], e["kappa"], e["p"])
    window = steps >= fit.start
    slope = analysis.growth_exponent(steps, msd, fit.start, fit.stop)
    dx = x[:, -1] - x[:, 0]
    ks = stats.kstest(dx, stats.norm(0.0, np.sqrt(exact[-1])).cdf).pvalue
    v = np.asarray(init["velocity"], float)
    tau = (e["width"] - 2 * e["R"]) / abs(v[1])
    u2 = v[0] ** 2 + e["kappa"] * e["R"] ** 2 * float(init["angular_velocity"]) ** 2
    # squared displacements of single trajectories: the standard error of the MSD at each record
    sq = (x - x[:, :1]) ** 2
    se = sq.std(axis=0, ddof=1) / np.sqrt(x.shape[0])
    return dict(msd=msd, se=se, fit=fit, exact=exact, D=D, c=c, slope=slope, window=window, dx=dx, ks=ks,
                tau=tau, u2=u2, closed=tau ** 2 * u2 * (1 + 1 / e["kappa"]) / 4 if e["p"] == 0.5 else np.nan)


def draw_ensemble(axes, e, m):
    steps, fit = e["steps"], m["fit"]
    ok = steps > 0
    s = steps[ok]
    ax = axes[0]
    ax.fill_between(s, (m["msd"][ok] - 2 * m["se"][ok]) / (2 * s), (m["msd"][ok] + 2 * m["se"][ok]) / (2 * s),
                    color="tab:blue", alpha=0.2, lw=0, label="ensemble ± 2 standard errors")
    ax.semilogx(s, m["msd"][ok] / (2 * s), ".", color="tab:blue", ms=2.5, label="ensemble MSD/(2·step)")
    ax.semilogx(s, m["exact"][ok] / (2 * s), "k-", lw=1.0, label=f"exact expectation → D = {m['D']:.4f}")
    ax.axhspan(fit.low, fit.high, xmin=0, xmax=1, color="tab:orange", alpha=0.3, lw=0,
               label=f"fitted D = {fit.coefficient:.4f} ± {fit.half_width:.4f} ({round(100 * fit.confidence)}%)")
    ax.axvspan(fit.start, fit.stop, color="0.92", zorder=0, label="fit window")
    ax.set_ylim(0, 1.35 * m["D"])
    ax.set_xlim(s[0], s[-1])
    ax.set_xlabel("collisions since the start (∝ time)")
    ax.set_ylabel("MSD/(2·step) [L²/collision]")
    ax.set_title(f"{fit.trajectories} trajectories from one start: apparent diffusion coefficient", fontsize=8.5)
    ax.legend(fontsize=7, loc="lower right")

    ax = axes[1]
    ax.loglog(s, m["msd"][ok], ".", color="tab:blue", ms=2.5, label="ensemble MSD")
    ax.loglog(s, m["exact"][ok], "k-", lw=1.0, label=f"exact: 2Dt + c, c = {m['c']:.2f} L², + transient")
    t = geomspace(fit.start, fit.stop, 100)
    ax.loglog(t, fit.msd(t), "-", color="tab:orange", lw=2.5, alpha=0.6,
              label=f"fit 2Dt + c: c = {fit.intercept:.0f} ± {fit.intercept_half_width:.0f} L²")
    ax.loglog(s, 2 * m["D"] * s, ":", color="0.4", lw=1.0, label="slope 1")
    ax.set_xlabel("collisions since the start (∝ time)")
    ax.set_ylabel("MSD ⟨(x − x₀)²⟩ [L²]")
    ax.set_title(f"mean-square displacement: log–log slope {m['slope']:.3f} over the fit window", fontsize=8.5)
    ax.legend(fontsize=7, loc="upper left")

    ax = axes[2]
    dx = m["dx"]
    sd = np.sqrt(m["exact"][-1])
    ax.hist(dx, bins=60, density=True, color="tab:blue", alpha=0.55,
            label=f"x − x₀ after {steps[-1]:.0f} collisions")
    u = np.linspace(-4.5 * sd, 4.5 * sd, 300)
    ax.plot(u, stats.norm.pdf(u, 0, sd), "k-", lw=1.1, label=f"Gaussian, exact variance (KS p = {m['ks']:.2g})")
    ax.set_xlabel("displacement along the channel [L]")
    ax.set_ylabel("density [1/L]")
    ax.legend(fontsize=7, loc="upper left")


def main():
    args = arguments(__doc__)
    fig = Figure("graphRandom", caption=__doc__)
    orbit_path, ensemble_path = split_runs(args.data)
    steps, t, x, rank, title = read_orbit(orbit_path)
    o = orbit_measures(steps, t, x, rank)
    e = read_ensemble(ensemble_path)
    m = ensemble_measures(e)
    fit = m["fit"]

    record_orbit(fig, o, prefix="orbit: ")
    fig.measure("ensemble: trajectories × collisions", f"{e['x'].shape[0]} × {e['steps'][-1]:.0f}")
    fig.measure("probability p of a rough collision", e["p"])
    fig.measure("flight time τ and |u|² = v_x² + κR²ω² of the start", f"{m['tau']:.6g}, {m['u2']:.6g}")
    fig.measure(f"fitted D (steps {fit.start:.0f}–{fit.stop:.0f}), {round(100 * fit.confidence)}% interval",
                f"{fit.coefficient:.5f} ± {fit.half_width:.5f}", "L²/collision")
    fig.measure("exact D from the moment recursion", m["D"], "L²/collision")
    fig.measure("closed form τ²|u|²(1 + 1/κ)/4 (p = ½)", m["closed"], "L²/collision")
    fig.measure("fitted intercept c, 95% interval", f"{fit.intercept:.1f} ± {fit.intercept_half_width:.1f}", "L²")
    fig.measure("exact intercept c", m["c"], "L²")
    fig.measure("log–log slope of the MSD over the fit window", m["slope"], digits=4)
    fig.measure("KS p-value of the final displacement against the Gaussian of the exact variance", m["ks"], digits=4)

    fig.check("orbit: flight time constant: (max − min)/mean", o["flight spread"], "<=", 1e-9, digits=ROUNDING)
    fig.check("orbit: rough fraction = p: |fraction − p|", abs(o["rough fraction"] - e["p"]), "<=", 0.01)
    fig.check("orbit: no long-range memory: largest |ρ(L)| at long lags", o["memory"], "<=", MEMORYLESS, digits=4)
    fig.check("MSD grows linearly: log–log slope ≥", m["slope"], ">=", 0.9, digits=4)
    fig.check("MSD grows linearly: log–log slope ≤", m["slope"], "<=", 1.1, digits=4)
    fig.check("fitted D = exact D: relative difference", abs(fit.coefficient - m["D"]) / m["D"], "<=", 0.1)

    out = MplFigure(figsize=(14.0, 10.5), layout="constrained")
    out.suptitle(f"graphRandom · {title}", fontsize=9)
    left, right = out.subfigures(1, 2, width_ratios=[1.15, 1])
    la = left.subplots(4, 1, gridspec_kw={"height_ratios": [1, 1, 1, 0.9]})
    draw_scales(la[:3], steps, x, o["scales"], colour="tab:purple")
    draw_memory(la[3], o, MEMORYLESS, "no long-range memory: |ρ| below", colour="tab:purple")
    k, p = e["kappa"], e["p"]
    la[3].set_title(f"memory of v_x: largest |ρ| at long lags {o['memory']:.4f}; ρ(1) = {o['rho1']:.3f} "
                    f"(exact (1 + (1−2p)κ)/(1 + κ) = {(1 + (1 - 2 * p) * k) / (1 + k):.3f})", fontsize=8.5)
    la[3].legend(fontsize=7, loc="upper right", ncol=2)
    left.suptitle("one orbit of 10⁶ collisions", fontsize=9)
    draw_ensemble(right.subplots(3, 1), e, m)
    fig.save(out, args)


if __name__ == "__main__":
    main()
