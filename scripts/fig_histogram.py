"""The invariant-measure experiment of the paper: a uniform disc (κ = ½, radius 0.1) in a 2 × 1 rectangle with
completely rough collisions. 10⁵ states are drawn on the bottom wall from the billiard measure (uniform position and
orientation, velocity in the coordinates (v, R√κ·ω) with density ∝ cos φ on the hemisphere around the normal) and
each is followed until it hits the bottom wall again. Left: the histogram of the return angles φ to the normal
against sin 2φ, the law they must follow if rough collisions preserve the billiard measure (paper §2.7); every
sample returns (within 148 collisions) and the KS p-value is 0.36. Middle: the empirical distribution function minus
sin²φ, for the return angles and the sampled starts, with the KS bands of 95% and 99%. The two curves are close for
a reason worth knowing: 45% of the samples go to the top wall and straight back, and the top and bottom walls only
reverse v_y, so their return angle is their start angle to 10⁻¹⁵ — they pass whatever the side walls do. Right: the
informative 55%, which meet a side wall on the way: the return angles of half of them (even sample numbers) against
the start angles of the other half (odd), independent samples that must follow the same law if the measure is
preserved (two-sample KS p ≈ 0.88). Why these parameters: the paper's table shape, ball and sample size; the bottom
wall is the paper's face x₂ = 0; seed 1 is fixed so the figure is reproducible.
"""
import sys

import numpy as np
from matplotlib.figure import Figure as MplFigure
from scipy import stats

from figlib import Figure, arguments
from rbx import analysis
from rbx.paths import FileError
from rbx.reader import read_returns as read_returns_file

P_PASS = 0.01       # KS p-value below which the law is rejected


def read_returns(path):
    try:
        r = read_returns_file(path)
    except FileError as exc:       # a damaged or crafted file: one line, exit 2, as arguments() refuses one
        print(f"rbx: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    a = r["attrs"]
    return dict(angle=r["angle"], initial=r["initial_angle"], collisions=r["collisions"], trajectory=r["trajectory"],
                d=int(r["velocity_dimension"]), samples=int(r["samples"]), not_returned=int(r["not_returned"]),
                wall=str(r["wall"]), kappa=float(a["kappa"]), radius=float(a["radius"]), table=str(a["table_kind"]))


def ks_band(n, level):
    """Asymptotic Kolmogorov–Smirnov critical value of sup |F_n − F| at the given confidence (for two samples of
    sizes n, m pass n·m/(n + m))."""
    return stats.kstwobign.ppf(level) / np.sqrt(n)


def side_wall_comparison(angle, trajectory, initial_angle):
    """The returns that changed their angle (met a side wall: the top and bottom walls keep φ exactly) against
    the starts of other such samples -> (start angle of each return, mask of side-wall returns, side-wall return
    angles of even samples, side-wall start angles of odd samples, two-sample KS result). The return map
    preserves the measure and keeps φ on the others, so the side-wall returns must have the law of the side-wall
    starts; even against odd makes the two samples independent, as the two-sample test assumes."""
    start = initial_angle[trajectory]
    side = np.abs(angle - start) > 1e-9
    even = trajectory % 2 == 0
    returned_side, started_side = angle[side & even], start[side & ~even]
    return start, side, returned_side, started_side, stats.ks_2samp(returned_side, started_side)


def main():
    args = arguments(__doc__)
    fig = Figure("histogram", caption=__doc__)
    r = read_returns(args.data[0])
    d = r["d"]
    D, p = analysis.ks_cos_law(r["angle"], d)
    D0, p0 = analysis.ks_cos_law(r["initial"], d)
    Dw, pw = analysis.ks_cos_law(r["angle"], d - 1)          # the law of a point particle (no spin): cos φ
    start, side, returned_side, started_side, two = side_wall_comparison(r["angle"], r["trajectory"], r["initial"])
    fig.measure("samples drawn on the wall", r["samples"])
    fig.measure("samples that returned", len(r["angle"]))
    fig.measure("collisions to return: mean, largest", f"{r['collisions'].mean():.3f}, {r['collisions'].max()}")
    fig.measure("velocity dimension d (density ∝ cos φ sin^(d−2) φ)", d)
    fig.measure("return angles against sin 2φ: KS statistic, p-value", f"{D:.5f}, {p:.4f}")
    fig.measure("sampled starts against sin 2φ: KS statistic, p-value", f"{D0:.5f}, {p0:.4f}")
    fig.measure("return angles against cos φ (point particle): KS statistic, p-value", f"{Dw:.4f}, {pw:.3g}")
    fig.measure("returns with the start angle kept (top wall only), largest |change|",
                f"{np.mean(~side):.4f}, {np.max(np.abs(r['angle'] - start)[~side], initial=0):.2g}")
    fig.measure("returns that met a side wall: fraction", float(np.mean(side)))
    fig.measure("side-wall returns (even samples) against side-wall starts (odd): two-sample KS statistic, p",
                f"{two.statistic:.5f}, {two.pvalue:.4f}")
    fig.check("return angles follow sin 2φ: KS p-value", p, ">=", P_PASS, digits=4)
    fig.check("every sample returned", r["not_returned"], "<=", 0)
    fig.check("the sampler draws the billiard measure: KS p-value of the starts", p0, ">=", P_PASS, digits=4)
    fig.check("returns via a side wall keep the law of their starts: two-sample KS p-value", two.pvalue, ">=",
              P_PASS, digits=4)

    out = MplFigure(figsize=(17.0, 4.8), layout="constrained")
    out.suptitle(f"histogram · disc (R = {r['radius']:g}, κ = {r['kappa']:.3g}) in a 2 × 1 {r['table']} · rough: "
                 f"return angles to wall '{r['wall']}' of {r['samples']} billiard-measure samples", fontsize=9)
    ax, ax2, ax3 = out.subplots(1, 3)
    u = np.linspace(0, np.pi / 2, 400)
    ax.hist(r["angle"], bins=50, range=(0, np.pi / 2), density=True, color="tab:blue", alpha=0.6,
            label=f"{len(r['angle'])} return angles")
    ax.plot(u, analysis.cos_law_pdf(u, d), "k-", lw=1.4, label=f"sin 2φ (KS p = {p:.2f})")
    ax.plot(u, analysis.cos_law_pdf(u, d - 1), "--", color="tab:red", lw=1.0,
            label=f"cos φ, a point particle (KS p = {pw:.0e})" if pw > 0 else "cos φ, a point particle (KS p = 0)")
    ax.set_xlim(0, np.pi / 2)
    ax.set_ylim(0, 1.25)
    ax.set_xlabel("return angle φ to the normal in (v, R√κ·ω) [rad]")
    ax.set_ylabel("density [1/rad]")
    ax.legend(fontsize=7.5, loc="upper left")
    for x, colour, name, stat in ((r["angle"], "tab:blue", "return angles", D), (r["initial"], "tab:orange",
                                                                                  "sampled starts", D0)):
        xs = np.sort(x)
        ecdf = np.arange(1, len(xs) + 1) / len(xs)
        ax2.plot(xs, ecdf - analysis.cos_law_cdf(xs, d), color=colour, lw=0.8, label=f"{name} (KS D = {stat:.4f})")
    n = len(r["angle"])
    for level, style in ((0.95, "--"), (0.99, ":")):
        b = ks_band(n, level)
        ax2.axhline(b, color="0.3", ls=style, lw=0.9, label=f"sampling noise: {round(100 * level)}% Kolmogorov–Smirnov band")
        ax2.axhline(-b, color="0.3", ls=style, lw=0.9)
    ax2.set_xlim(0, np.pi / 2)
    ax2.set_ylim(-2.2 * ks_band(n, 0.99), 2.2 * ks_band(n, 0.99))
    ax2.set_xlabel("angle φ to the normal [rad]")
    ax2.set_ylabel("empirical distribution function − sin²φ")
    ax2.set_title("departure from the predicted distribution function", fontsize=8.5)
    ax2.legend(fontsize=7.5, loc="upper right")

    grid = np.linspace(0, np.pi / 2, 2000)
    ecdf = lambda x: np.searchsorted(np.sort(x), grid, side="right") / len(x)
    ax3.plot(grid, ecdf(returned_side) - ecdf(started_side), color="tab:purple", lw=0.9,
             label=f"returns (n = {len(returned_side)}) − starts (n = {len(started_side)}): "
                   f"KS D = {two.statistic:.4f}, p = {two.pvalue:.2f}")
    n_eff = len(returned_side) * len(started_side) / (len(returned_side) + len(started_side))
    for level, style in ((0.95, "--"), (0.99, ":")):
        b = ks_band(n_eff, level)
        ax3.axhline(b, color="0.3", ls=style, lw=0.9, label=f"sampling noise: {round(100 * level)}% two-sample Kolmogorov–Smirnov band")
        ax3.axhline(-b, color="0.3", ls=style, lw=0.9)
    ax3.set_xlim(0, np.pi / 2)
    ax3.set_ylim(-2.2 * ks_band(n_eff, 0.99), 2.2 * ks_band(n_eff, 0.99))
    ax3.set_xlabel("return angle φ to the normal [rad]")
    ax3.set_ylabel("difference of empirical distribution functions")
    ax3.set_title(f"the {100 * np.mean(side):.0f}% that meet a side wall: returns (even samples) against starts (odd)",
                  fontsize=8.5)
    ax3.legend(fontsize=7.5, loc="upper right")
    fig.save(out, args)


if __name__ == "__main__":
    main()
