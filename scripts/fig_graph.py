"""One orbit of a uniform disc (κ = ½, radius 0.1) in a strip of width 1 whose rule depends on where the disc is
touched: the half of its rim on one side of a diameter fixed in the body is rough (rank 1), the other half smooth
(specular). Top three panels: the position x of the centre along the channel against the collision step, for the
first 10³, the first 3·10⁴ and all 10⁶ collisions of the same orbit (after the first flight every flight lasts
exactly one time unit, so the step is the time). Bottom: the memory of the velocity v_x along the channel, the
largest |autocorrelation| in logarithmic bins of the lag. What we measure: the range of x at each scale and how it
grows, and that memory. The orbit is neither bounded nor a random walk: the largest |ρ| per lag bin stays between
0.015 and 0.1 out to 10⁵ collisions, above the ≤ 0.007 that noise gives, where a random rule (Figure graphRandom)
forgets within ten collisions; x moves in long regular swings and sawtooth runs, and its range grows 280-fold from
10³ to 10⁶ collisions (a random walk: about √1000 ≈ 32), about as steps^0.7 (0.7–1.3 over eight starts we
tried). That is the apparently quasi-periodic long-range behaviour the paper points out. Why these parameters: the
paper's disc and strip; |v_y| = 0.8 with a gap of 0.8 for the centre gives flights of exactly one time unit; 10⁶
collisions (under a second to simulate) give three decades of time scales; half the collisions are rough, as the
hemispheres are met equally often.
"""
import numpy as np
from matplotlib.figure import Figure as MplFigure

from figlib import ROUNDING, Figure, arguments, geomspace, log10
from rbx import analysis
from rbx.reader import Run

SCALES = (1e-3, 3e-2, 1.0)      # fractions of the run drawn in the three panels (10³, 3·10⁴, 10⁶ collisions)
MEMORY_FROM = 100               # "long range": lags from 100 collisions ...
MEMORY_TO = 0.1                 # ... to a tenth of the run
MEMORY = 0.03                   # largest |ρ| at long lags that counts as memory (noise: ~0.005 on 10⁶ collisions)
FLIGHT_SPREAD = 1e-9            # relative spread of the flight times that counts as constant
LN10 = 2.302585092994046        # ln 10


def read_orbit(path):
    """-> (steps, time, x, rank, run title) of trajectory 0 of a strip run recorded at every collision."""
    with Run.open(path) as run:
        run.require(["time", "position", "rank"], "the x-against-step figure")
        if run.table_kind != "strip":
            raise SystemExit(f"{path}: expected a run in a strip, got {run.table_kind}")
        if run.every != 1:
            raise SystemExit(f"{path}: needs every collision recorded (output.every = 1)")
        c = int(run.count[0])
        t = run.read("time", [0])[0, :c]
        x = run.read("position", [0])[0, :c, 0]
        rank = run.read("rank", [0])[0, :c]
        return run.step[:c], t, x, rank, run.scene()


def autocorrelation(v, maxlag):
    """Normalised autocorrelation ρ(L) of a series (mean removed), L = 0 … maxlag, by FFT -> (maxlag + 1,)."""
    v = np.asarray(v, float) - np.mean(v)
    n = len(v)
    f = np.fft.rfft(v, n=2 * n)
    # |f|² as re² + im², not f·conj(f): NumPy's complex product fuses a multiply and an add (FMA) in its AVX2 and
    # AVX-512 loops and not in the others, so its last bits depend on the CPU
    ac = np.fft.irfft(f.real * f.real + f.imag * f.imag)[:maxlag + 1]
    ac /= np.arange(n, n - maxlag - 1, -1)          # unbiased: the mean over the pairs at each lag
    return ac / ac[0]


def running_range(x):
    return np.maximum.accumulate(x) - np.minimum.accumulate(x)


def orbit_measures(steps, t, x, rank, scales=SCALES):
    """What Figures graph and graphRandom measure on one orbit -> dict."""
    N = int(steps[-1])
    dt = np.diff(t[1:])                              # every flight after the first (which starts mid-strip)
    vx = np.diff(x[1:]) / dt                         # the velocity after each collision (straight flights)
    upto = [max(1, int(round(f * N))) for f in scales]
    rr = running_range(x)
    n = np.unique(np.round(geomspace(1, N, 200)).astype(int))
    lo = max(1, N // 1000)
    maxlag = max(2, int(MEMORY_TO * len(vx)))
    rho = autocorrelation(vx, maxlag)
    lags = np.arange(len(rho))
    window = lags >= min(MEMORY_FROM, maxlag)
    return {
        "collisions": N,
        "flight time": float(np.mean(dt)),
        "flight spread": float(np.ptp(dt) / np.mean(dt)),
        "rough fraction": float(np.mean(rank[1:] == 1)),
        "scales": upto,
        "ranges": [float(rr[k]) for k in upto],
        "range exponent": analysis.growth_exponent(n, rr[n], lo, N),
        "exponent window": (lo, N),
        "rho": rho,
        "rho1": float(rho[1]),
        "rho2": float(rho[2]),
        "memory": float(np.max(np.abs(rho[window]))),
        "memory lag": int(lags[window][np.argmax(np.abs(rho[window]))]),
        "memory window": (int(min(MEMORY_FROM, maxlag)), maxlag),
        # Bartlett: the standard deviation of an estimated ρ(L) at lags beyond the correlations
        "noise": float(np.sqrt((1 + 2 * np.sum(rho[1:21] ** 2)) / len(vx))),
        "mean vx": float(np.mean(vx)),
    }


def record_orbit(fig, m, prefix=""):
    fig.measure(f"{prefix}collisions", m["collisions"])
    fig.measure(f"{prefix}flight time (after the first flight)", m["flight time"], "T")
    fig.measure(f"{prefix}relative spread (max − min)/mean of the flight times", m["flight spread"], digits=ROUNDING)
    fig.measure(f"{prefix}fraction of rough (rank 1) collisions", m["rough fraction"])
    for n, r in zip(m["scales"], m["ranges"]):
        fig.measure(f"{prefix}range (max − min) of x over the first {n} collisions", r, "L")
    lo, hi = m["exponent window"]
    fig.measure(f"{prefix}growth exponent a of the range of x ∝ stepsᵃ ({lo} to {hi} collisions)",
                m["range exponent"], digits=4)
    fig.measure(f"{prefix}autocorrelation of v_x at lags 1, 2", f"{m['rho1']:.4f}, {m['rho2']:.4f}")
    a, b = m["memory window"]
    fig.measure(f"{prefix}largest |autocorrelation of v_x| at lags {a}–{b} (at lag {m['memory lag']})",
                m["memory"], digits=4)
    fig.measure(f"{prefix}noise of an estimated autocorrelation (Bartlett, from lags 1–20)", m["noise"], digits=4)


def envelope(steps, x, bins=3000):
    """For drawing a long series: the minimum and maximum of each of ``bins`` bins, interleaved, so the line
    looks as the full series would at that resolution -> (steps, values)."""
    if len(x) <= 2 * bins:
        return steps, x
    edges = np.linspace(0, len(x), bins + 1).astype(int)
    lo = np.minimum.reduceat(x, edges[:-1])
    hi = np.maximum.reduceat(x, edges[:-1])
    mid = steps[(edges[:-1] + edges[1:]) // 2]
    return np.repeat(mid, 2), np.column_stack([lo, hi]).ravel()


def draw_scales(axes, steps, x, upto, colour="tab:blue"):
    for ax, n in zip(axes, upto):
        sel = slice(0, n + 1)
        ax.plot(*envelope(steps[sel], x[sel]), color=colour, lw=0.6 if n <= 5000 else 0.35)
        ax.set_xlim(0, n)
        ax.set_ylabel("x [L]")
        ax.set_xlabel("collisions (∝ time: the flight time is constant)")
        ax.set_title(f"the first {n} collisions: range of x {np.ptp(x[sel]):.4g} L", fontsize=8.5)


def memory_envelope(rho, bins=60):
    """(lag bin centres, largest |ρ| in each bin, lags in each bin) over logarithmic bins of the lags
    1 … len(rho) − 1."""
    edges = np.unique(np.round(geomspace(1, len(rho), bins + 1)).astype(int))
    centres = np.sqrt(edges[:-1] * np.maximum(edges[1:] - 1, edges[:-1]))
    top = np.array([np.max(np.abs(rho[a:b])) for a, b in zip(edges[:-1], edges[1:])])
    return centres, top, np.diff(edges)


def draw_memory(ax, m, level, level_label, colour="tab:blue"):
    """Largest |ρ| per logarithmic lag bin, the largest that noise alone gives in such a bin (σ·√(2 ln n) for n
    lags), and a reference level of |ρ| (``level_label`` says what it separates)."""
    lag, top, size = memory_envelope(m["rho"])
    ax.loglog(lag, top, ".-", color=colour, lw=0.9, ms=3, label="largest |ρ(L)| in the lag bin")
    # ln = log10·ln 10 with figlib's log10 (the same bits on every CPU; np.log's last bits are the CPU's)
    ax.loglog(lag, m["noise"] * np.sqrt(2 * LN10 * log10(np.maximum(size, 2))), "--", color="tab:green", lw=1.0,
              label="largest that noise gives in the bin")
    a, b = m["memory window"]
    ax.axvspan(a, b, color="0.9", zorder=0, label=f"long range: lags {a}–{b}")
    ax.axhline(level, color="tab:red", lw=0.9, ls=":", label=f"{level_label} ({level:g})")
    ax.set_xlim(1, len(m["rho"]))
    ax.set_ylim(3e-4, 1.2)
    ax.set_xlabel("lag L [collisions]")
    ax.set_ylabel("|autocorrelation ρ(L) of v_x|")


def main():
    args = arguments(__doc__)
    fig = Figure("graph", caption=__doc__)
    steps, t, x, rank, title = read_orbit(args.data[0])
    m = orbit_measures(steps, t, x, rank)
    record_orbit(fig, m)

    fig.check("flight time constant: (max − min)/mean", m["flight spread"], "<=", FLIGHT_SPREAD, digits=ROUNDING)
    fig.check("both halves of the rim are met: rough fraction ≥", m["rough fraction"], ">=", 0.2)
    fig.check("both halves of the rim are met: rough fraction ≤", m["rough fraction"], "<=", 0.8)
    fig.check("long-range memory, unlike a random rule: largest |ρ(L)| at long lags", m["memory"], ">=", MEMORY,
              digits=4)
    fig.check("x unbounded, and faster than a random walk (≈ √1000 ≈ 32): range at 10⁶ / range at 10³ collisions",
              m["ranges"][-1] / m["ranges"][0], ">=", 100)

    out = MplFigure(figsize=(9.0, 11.0), layout="constrained")
    out.suptitle(f"graph · {title}\none orbit, x along the channel at three time scales", fontsize=9)
    axes = out.subplots(4, 1, gridspec_kw={"height_ratios": [1, 1, 1, 0.9]})
    draw_scales(axes[:3], steps, x, m["scales"])
    draw_memory(axes[3], m, MEMORY, "long-range memory: |ρ| above")
    axes[3].set_title(f"autocorrelation ρ of the velocity v_x along the channel: largest |ρ| at long lags "
                      f"{m['memory']:.3f} (lag {m['memory lag']}); the range of x grows as "
                      f"steps^{m['range exponent']:.2f}", fontsize=8.5)
    axes[3].legend(fontsize=7, loc="lower left", ncol=2)
    fig.save(out, args)


if __name__ == "__main__":
    main()
