"""A uniform ball (κ = 2/5, radius 0.1) between two parallel plates 1 apart, completely rough (rank 2) on both. Top
left: the path of its centre for the first 200 collisions, in space. Top right: its horizontal projection, the first
60 collisions as a path over every 10th of all 10⁶ collision points (grey), with the circle reached in the first 10³
collisions. Bottom left: the largest horizontal distance from the start reached up to each collision. Bottom right:
the time-averaged mean-square displacement of the horizontal position, the mean of |(x, y)(i + lag) − (x, y)(i)|²
over every collision i of the orbit, against the lag (it oscillates, as the orbit is quasi-periodic, without
growing), with the slope a diffusing orbit would have (∝ lag) and the level a bounded stationary orbit reaches (twice
the variance of (x, y) over the orbit). The orbit is bounded: it fills a thin elliptical ring, its excursion (0.4967)
is reached at the second collision and never exceeded in the next 10⁶, and the time-averaged mean-square displacement
does not grow with the lag (growth exponent in the table). Why: between parallel plates the rank-2 map acts on the
pairs (v_x, R√κ·ω_y) and (v_y, −R√κ·ω_x) as the same reflection, one per plate; no state except a spin about the
normal (which does not move the ball) is left alone by both plates (rbx.analysis.conserved_drift gives 0), so each
pair turns by a fixed rotation every two collisions, the horizontal velocity is quasi-periodic with mean zero and the
position stays within a fixed distance. Why these parameters: the paper's uniform ball; a start whose horizontal spin
is not perpendicular to its horizontal velocity (v = (0.2, −0.4, 0.7), ω = (1, −2, −0.3)) — with ω perpendicular to
v, as in configs/examples/plates.yaml, the orbit stays in one vertical plane and its projection is a segment; the
same start in Figure roughrank; 10⁶ collisions (a fraction of a second) are far longer than the excursion takes to
saturate.
"""
import math

import numpy as np
from matplotlib.figure import Figure as MplFigure
from matplotlib.ticker import MaxNLocator

from figlib import ROUNDING, Figure, arguments, fixed, geomspace
from rbx import analysis
from rbx.reader import Run

SHOWN_3D = 200       # collisions drawn in space
SHOWN_2D = 60        # collisions drawn as a path in the horizontal projection
GROWTH = 1.05        # "does not grow": excursion over the whole run / excursion over the first window
BOUNDED_TAMSD = 0.1  # growth exponent of the time-averaged MSD that counts as bounded (diffusion 1, ballistic 2)


def read_plates_orbit(path):
    """-> dict: steps, time, position (T, 3) of trajectory 0, the run's geometry, start, radius, κ, wall rules."""
    with Run.open(path) as run:
        run.require(["time", "position"], "the horizontal excursion")
        if run.table_kind != "plates":
            raise SystemExit(f"{path}: expected a run between plates, got {run.table_kind}")
        c = int(run.count[0])
        return dict(steps=run.step[:c], time=run.read("time", [0])[0, :c], position=run.read("position", [0])[0, :c],
                    geom=run.geometry(), init=run.config["initial"], R=run.radius, kappa=run.kappa,
                    rules=run.experiment.wall_rules, title=run.scene(), every=run.every, name=path)


def plates_measures(o, first=1000):
    """Excursion, its growth, the time-averaged MSD and the conserved drift of one orbit between plates -> dict."""
    steps, xy, t = o["steps"], o["position"][:, :2], o["time"]
    N = int(steps[-1])
    n1 = min(first, max(1, N // 10))
    k1 = int(np.searchsorted(steps, n1))
    exc = analysis.running_excursion(xy)
    lags_coll = np.unique(np.round(geomspace(max(10, o["every"]), max(N // 100, 20 * o["every"]), 16)
                                   / o["every"]).astype(int)) * o["every"]
    tamsd = analysis.time_averaged_msd(xy, lags_coll // o["every"])
    rough = analysis.rough_directions(o["rules"], o["geom"])
    init = o["init"]
    speed = vector_length(np.asarray(init["velocity"], float)[:2])
    drift = analysis.conserved_drift(init["velocity"], init["angular_velocity"], rough, o["R"], o["kappa"])[:2]
    measured = (xy[-1] - xy[1]) / (t[-1] - t[1])
    # what is left after the conserved drift: bounded, or a random walk
    rest = xy - xy[:1] - np.outer(t - t[0], drift)
    rest_exc = analysis.running_excursion(rest)
    rest_tamsd = analysis.time_averaged_msd(rest, lags_coll // o["every"])
    return dict(steps=steps, rest=rest, rest_excursion=rest_exc,
                rest_exponent=analysis.growth_exponent(steps, rest_exc, steps[k1], N),
                rest_tamsd_exponent=analysis.growth_exponent(lags_coll, rest_tamsd, 0, np.inf),
                drifts=bool(vector_length(drift) > 1e-6 * speed),
N=N, n1=int(steps[k1]), e1=float(exc[k1]), eN=float(exc[-1]), excursion=exc,
                exponent=analysis.growth_exponent(steps, exc, steps[k1], N),
                lags=lags_coll, tamsd=tamsd, tamsd_exponent=analysis.growth_exponent(lags_coll, tamsd, 0, np.inf),
                drift=drift, measured_drift=measured,
                drift_error=vector_length(measured - drift) / max(vector_length(drift), 1e-300), speed=speed)


def vector_length(v):
    """|v| of a short vector by math.hypot: np.linalg.norm of a vector is a BLAS dot product, whose last bits
    depend on the CPU."""
    return math.hypot(*np.asarray(v, float).tolist())


def record_plates(fig, m, prefix=""):
    fig.measure(f"{prefix}collisions", m["N"])
    fig.measure(f"{prefix}largest horizontal distance from the start, first {m['n1']} collisions", m["e1"], "L")
    fig.measure(f"{prefix}largest horizontal distance from the start, all {m['N']} collisions", m["eN"], "L")
    # a bounded orbit's exponent is the rounding of a fit to a constant: its size is what it says
    fig.measure(f"{prefix}growth exponent of that excursion ({m['n1']} to {m['N']} collisions)", m["exponent"],
                digits=ROUNDING if abs(m["exponent"]) < 1e-3 else 4)
    fig.measure(f"{prefix}growth exponent of the time-averaged MSD (lags {m['lags'][0]}–{m['lags'][-1]})",
                m["tamsd_exponent"], digits=4)
    fig.measure(f"{prefix}conserved (slip-free) horizontal velocity, predicted",
                f"({fixed(m['drift'][0], 6)}, {fixed(m['drift'][1], 6)})", "L/T")
    fig.measure(f"{prefix}mean horizontal velocity over the run, measured",
                f"({fixed(m['measured_drift'][0], 6)}, {fixed(m['measured_drift'][1], 6)})", "L/T")
    if m["drifts"]:
        fig.measure(f"{prefix}after subtracting the drift: largest distance from the start, first {m['n1']} / all",
                    f"{m['rest_excursion'][int(np.searchsorted(m['steps'], m['n1']))]:.6g} / "
                    f"{m['rest_excursion'][-1]:.6g}", "L")
        fig.measure(f"{prefix}after subtracting the drift: growth exponent of that excursion", m["rest_exponent"],
                    digits=ROUNDING if abs(m["rest_exponent"]) < 1e-3 else 4)
        fig.measure(f"{prefix}after subtracting the drift: growth exponent of the time-averaged MSD",
                    m["rest_tamsd_exponent"], digits=4)


def draw_plates(ax, gap, lo, hi):
    X, Y = np.meshgrid([lo[0], hi[0]], [lo[1], hi[1]])
    for z in (0.0, gap):
        ax.plot_surface(X, Y, np.full_like(X, z), color="0.5", alpha=0.15, linewidth=0)


def draw_tamsd(ax, m, xy, every, points=120):
    """The time-averaged MSD of the horizontal position against the lag (log–log) on a dense grid of lags (the
    lags of the fitted exponent marked), with the slope of diffusion through its first point and the plateau of a
    bounded stationary orbit, 2·(var x + var y)."""
    lags, tamsd = m["lags"], m["tamsd"]
    dense = np.unique(np.round(geomspace(lags[0], lags[-1], points) / every).astype(int)) * every
    values = analysis.time_averaged_msd(xy, dense // every)
    ax.loglog(dense, values, ".", color="tab:blue", ms=4,
              label="⟨|r(i + lag) − r(i)|²⟩ over collisions i, r = (x, y)")
    ax.loglog(lags, tamsd, "o", mfc="none", mec="k", ms=6, label="the lags of the fitted growth exponent")
    ax.loglog(lags, tamsd[0] * lags / lags[0], "k:", lw=0.9, label="∝ lag (diffusion)")
    plateau = 2 * float(np.sum(np.var(xy, axis=0)))
    ax.axhline(plateau, color="tab:red", ls="--", lw=0.9, label=f"2·(var x + var y) = {plateau:.4f} L²")
    ax.set_ylim(0.5 * min(values[values > 0].min(), tamsd.min(), plateau), 30 * max(values.max(), plateau))
    ax.set_xlabel("lag [collisions]")
    ax.set_ylabel("time-averaged mean-square displacement [L²]")
    ax.set_title(f"time-averaged MSD: growth exponent {m['tamsd_exponent']:.3f} (diffusion 1, ballistic 2)",
                 fontsize=8.5)
    ax.legend(fontsize=7, loc="upper left")


def main():
    args = arguments(__doc__)
    fig = Figure("plate", caption=__doc__)
    o = read_plates_orbit(args.data[0])
    m = plates_measures(o)
    record_plates(fig, m)
    dt = np.diff(o["time"][1:])
    fig.measure("relative spread of the flight times (|v_z| is kept)", float(np.ptp(dt) / np.mean(dt)),
                digits=ROUNDING)

    fig.check(f"bounded: excursion over {m['N']} / over {m['n1']} collisions", m["eN"] / m["e1"], "<=", GROWTH)
    fig.check("bounded: growth exponent of the time-averaged MSD", m["tamsd_exponent"], "<=", BOUNDED_TAMSD,
              digits=4)
    fig.check("no conserved slip-free motion: |mean horizontal velocity| / |initial horizontal velocity|",
              vector_length(m["measured_drift"]) / m["speed"], "<=", 1e-3, digits=4)

    p = o["position"]
    gap = o["geom"].size
    out = MplFigure(figsize=(13.0, 10.5), layout="constrained")
    out.suptitle(f"plate · {o['title']}", fontsize=9)
    ax = out.add_subplot(2, 2, 1, projection="3d")
    q = p[:SHOWN_3D + 1]
    ax.plot(q[:, 0], q[:, 1], q[:, 2], color="tab:blue", lw=0.6)
    ax.plot([q[0, 0]], [q[0, 1]], [q[0, 2]], "o", color="k", ms=3)
    lo, hi = q[:, :2].min(axis=0) - 0.1, q[:, :2].max(axis=0) + 0.1
    draw_plates(ax, gap, lo, hi)
    span = max(hi - lo)
    ax.set_box_aspect((max(hi[0] - lo[0], 0.3 * span), max(hi[1] - lo[1], 0.3 * span), gap))
    for axis in (ax.xaxis, ax.yaxis):
        axis.set_major_locator(MaxNLocator(4))
    ax.set_xlabel("x [L]")
    ax.set_ylabel("y [L]")
    ax.set_zlabel("z [L]")
    ax.set_title(f"the first {SHOWN_3D} collisions in space", fontsize=8.5)

    ax = out.add_subplot(2, 2, 2)
    ax.plot(p[::10, 0], p[::10, 1], ".", color="0.6", ms=1, alpha=0.5, rasterized=True,
            label=f"every 10th of all {m['N']} collision points")
    ax.plot(p[:SHOWN_2D + 1, 0], p[:SHOWN_2D + 1, 1], color="tab:blue", lw=0.6,
            label=f"the first {SHOWN_2D} collisions")
    u = np.linspace(0, 2 * np.pi, 400)
    ax.plot(p[0, 0] + m["e1"] * np.cos(u), p[0, 1] + m["e1"] * np.sin(u), "k--", lw=0.9,
            label=f"reached in the first {m['n1']}: {m['e1']:.4f} L")
    ax.plot(p[0, 0], p[0, 1], "o", color="k", ms=3)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [L]")
    ax.set_ylabel("y [L]")
    ax.set_title("horizontal projection", fontsize=8.5)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.13), markerscale=8)

    ax = out.add_subplot(2, 2, 3)
    s = o["steps"]
    i = np.unique(geomspace(1, len(s) - 1, 2000).astype(int))
    ax.semilogx(s[i], m["excursion"][i], color="tab:blue", lw=1.0, label="largest |(x, y) − (x₀, y₀)| so far")
    ax.axvline(m["n1"], color="0.5", lw=0.8, ls=":", label=f"{m['n1']} collisions")
    ax.set_ylim(0, 1.3 * m["eN"])
    ax.set_xlim(1, m["N"])
    ax.set_xlabel("collisions")
    ax.set_ylabel("horizontal excursion [L]")
    ax.set_title(f"excursion: {m['e1']:.4f} L after {m['n1']}, {m['eN']:.4f} L after {m['N']} collisions",
                 fontsize=8.5)
    ax.legend(fontsize=7, loc="lower right")

    ax = out.add_subplot(2, 2, 4)
    draw_tamsd(ax, m, p[:, :2], o["every"])
    fig.save(out, args)


if __name__ == "__main__":
    main()
