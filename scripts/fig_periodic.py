"""A uniform disc (κ = ½, radius 0.1) in wedges with completely rough collisions; the path of its centre, which
moves in the wedge whose walls are moved in by 0.1 (dashed). Left: bounded orbits of 1000 free flights in the 60°
wedge and in the 87.91° wedge; each retraces a closed polygon, of 4 and of 10 collisions. Right: a typical
bounded orbit, in the 90° wedge (first 200 of 10⁶ flights): it never closes and fills a band; below it, the
signed gap between the closed-form supremum of the distance from the shrunk vertex (predicted from the initial
state) and the largest distance reached so far, relative to the supremum, on a log scale of its size: positive
(blue) it closes in steps as the orbit fills its band; after about 3·10⁵ collisions it turns negative (red), the
computed orbit reaching −8.3·10⁻¹¹ of the supremum beyond it, the rounding of 10⁶ double-precision collisions
(the invariant s·n, constant in exact arithmetic, spreads by 1.4·10⁻¹¹ of its value).
Why these angles: two rough collisions, one on each wall, rotate the velocity (R√κ·ω, v) by 2γ with
cos γ = (κ − cos β)/(1 + κ), β the vertex angle, and because the wedge looks the same at every scale the distance
from the vertex times the normal speed is the same at every collision, so the position repeats when the velocity
does. γ = π/2 at 60° (period 4) and γ = 2π/5 at arccos((7 − 3√5)/8) ≈ 87.91° (period 10) are the simplest
periodic cases; at 90° cos γ = 1/3 (γ is the tetrahedral angle the paper mentions), not a rational turn, so that
orbit is the generic quasi-periodic one, bounded by a distance computed in closed form. The initial states are
ones that stay bounded (many others escape to infinity); the paper does not give its angles or initial states.
"""
import os

import numpy as np
from matplotlib.figure import Figure as MplFigure

from figlib import ROUNDING, Figure, arguments, geomspace
from rbx import orbits
from rbx.reader import Run
from rbx.plotting import draw_table_2d

TYPICAL_SHOWN = 200
PERIOD_TOL = 1e-9    # relative to the orbit's size and speed (orbits.collision_states)


def initial_spin(config, j=0):
    init = config["initial"]
    state = init[j] if isinstance(init, list) else init
    return float(state.get("angular_velocity", 0.0))


def read_wedge_run(path, need):
    """-> dict with the fields of trajectory 0 cut at its count, and what the figure needs to know of the run."""
    with Run.open(path) as run:
        run.require(need, "the wedge figure")
        if run.table_kind != "wedge":
            raise SystemExit(f"{path}: expected a run in a wedge, got {run.table_kind}")
        n = int(run.count[0])
        out = {f: run.read(f, [0])[0, :n] for f in need}
        out.update(angle=float(run.config["table"]["angle_deg"]), R=run.radius, kappa=run.kappa,
                   requested=int(run.config["run"]["collisions"]), flights=n - 1, geom=run.geometry(),
                   title=run.scene(), spin0=initial_spin(run.config), name=os.path.splitext(os.path.basename(path))[0])
        return out


def predict(r):
    return orbits.wedge_prediction(r["position"][0], r["velocity"][0], r["spin0"], r["angle"], r["R"], r["kappa"])


def draw_wedge_orbit(ax, r, shown, sup=None, apex=None, lw=0.5):
    p = r["position"][:shown + 1]
    lo, hi = p.min(axis=0), p.max(axis=0)
    draw_table_2d(ax, r["geom"], np.minimum(lo, 0), hi)
    ax.plot(p[:, 0], p[:, 1], color="tab:blue", lw=lw)
    ax.plot(p[1:, 0], p[1:, 1], ".", color="tab:blue", ms=3)
    ax.plot(p[0, 0], p[0, 1], "o", color="k", ms=3.5)
    if sup is not None and np.isfinite(sup):
        phi = np.linspace(0, np.radians(r["angle"]), 200)
        ax.plot(apex[0] + sup * np.cos(phi), apex[1] + sup * np.sin(phi), color="tab:red", lw=0.9, ls=(0, (4, 2)),
                label=f"closed-form supremum of the distance from the shrunk vertex: {sup:.4f} L")
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("x [L]")
    ax.set_ylabel("y [L]")


def draw_gap(ax, s_run, supremum):
    """(closed-form supremum − largest distance so far) / supremum against the collision, signed: its size on a
    log axis, the collisions where it is positive and where it is negative in two colours (a negative value is the
    computed orbit past the closed-form bound, by rounding), so no value is hidden or clipped."""
    idx = np.unique(geomspace(1, len(s_run), 2000).astype(int)) - 1
    gap = (supremum - s_run[idx]) / supremum
    n = idx + 1
    pos, neg = gap > 0, gap < 0
    ax.loglog(n, np.where(pos, gap, np.nan), drawstyle="steps-post", color="tab:blue", lw=1.0,
              label="gap > 0: largest distance below the supremum")
    if neg.any():
        first = int(np.argmax(s_run > supremum)) + 1
        ax.loglog(n, np.where(neg, -gap, np.nan), drawstyle="steps-post", color="tab:red", lw=1.6,
                  label=f"gap < 0: largest distance above the supremum (from collision {first})")
        ax.annotate(f"{gap[-1]:.2g}", xy=(n[-1], -gap[-1]), xytext=(-4, 6), textcoords="offset points",
                    ha="right", fontsize=7.5, color="tab:red")
    if (gap == 0).any():
        ax.plot([], [], " ", label=f"gap = 0 at {(gap == 0).sum()} of the plotted collisions")
    ax.set_xlim(1, len(s_run))
    ax.set_xlabel("collisions")
    ax.set_ylabel("|gap| = |supremum − largest\ndistance so far| / supremum")
    ax.set_ylim(1e-13, 10)
    ax.set_title(f"distance from the shrunk vertex: closed-form supremum − largest so far,\nrelative; "
                 f"{gap[-1]:.2g} after {len(s_run)} collisions (negative: past the supremum by rounding)",
                 fontsize=8.5)
    ax.legend(fontsize=7, loc="upper right")


def main():
    args = arguments(__doc__)
    fig = Figure("periodic", caption=__doc__)
    typical_paths = [d for d in args.data if os.path.basename(d).startswith("typical")]
    periodic_paths = [d for d in args.data if d not in typical_paths]
    if len(typical_paths) != 1 or not periodic_paths:
        raise SystemExit("expected one data file named typical*.h5 and at least one other (the periodic orbits)")

    periodic = []
    for path in periodic_paths:
        r = read_wedge_run(path, ["position", "velocity", "angular_velocity", "wall"])
        pred = predict(r)
        states = orbits.collision_states(r["position"][1:], r["velocity"][1:], r["angular_velocity"][1:],
                                         r["R"], r["kappa"])
        per = orbits.detect_period(states, tol=PERIOD_TOL)
        apex = pred.apex
        s_max = orbits.max_distance(r["position"][1:], apex)
        name = f"{r['angle']:.6g}° wedge"
        fig.measure(f"{name}: free flights (of {r['requested']} asked)", r["flights"])
        fig.measure(f"{name}: detected period (collisions)", per.period if per.period else "none")
        fig.measure(f"{name}: tolerance: largest relative difference of state[i+p] and state[i]", per.mismatch,
                    digits=ROUNDING)
        fig.measure(f"{name}: smallest mismatch of a shorter period", per.shorter)
        fig.measure(f"{name}: closed-form period (2γ a rational turn)", pred.period if pred.period else "none")
        fig.measure(f"{name}: largest distance from the vertex", orbits.max_distance(r["position"]), "L")
        fig.check(f"{name}: bounded: free flights completed", r["flights"], ">=", r["requested"])
        fig.check(f"{name}: periodic: relative mismatch at the detected period", per.mismatch, "<=", PERIOD_TOL,
                  digits=ROUNDING)
        fig.check(f"{name}: detected period − closed-form period, absolute",
                  abs(per.period - pred.period) if per.period and pred.period else np.inf, "<=", 0)
        fig.check(f"{name}: no shorter period: smallest mismatch below it", per.shorter, ">=", 1e-3)
        fig.check(f"{name}: distance from the shrunk vertex ≤ closed-form bound", s_max / pred.supremum, "<=",
                  1 + 1e-9)
        periodic.append((r, per))

    t = read_wedge_run(typical_paths[0], ["position", "velocity", "wall"])
    pred = predict(t)
    p, v, w = t["position"], t["velocity"], t["wall"]
    inv = orbits.wedge_invariant(p[1:], v[1:], w[1:], t["angle"], t["R"])
    s = np.linalg.norm(p[1:] - pred.apex, axis=1)
    s_run = np.maximum.accumulate(s)
    first = min(1000, len(p) - 1)
    # the spin is not recorded in the long run: compare positions and velocities only (a period would show there)
    head = orbits.detect_period(orbits.collision_states(p[1:first + 1], v[1:first + 1], np.zeros(first), t["R"],
                                                        t["kappa"]), tol=PERIOD_TOL)
    name = f"typical orbit, {t['angle']:.6g}° wedge"
    inv_spread = orbits.spread(inv) / abs(pred.invariant)
    fig.measure(f"{name}: free flights (of {t['requested']} asked)", t["flights"])
    gap = lambda k: (pred.supremum - float(s_run[k - 1])) / pred.supremum
    fig.measure(f"{name}: largest distance from the vertex over all collisions", orbits.max_distance(p), "L")
    fig.measure(f"{name}: largest distance from the shrunk vertex", float(s.max()), "L")
    fig.measure(f"{name}: closed-form supremum of that distance (from the initial state)", pred.supremum, "L")
    fig.measure(f"{name}: (supremum − largest distance) / supremum after {first} collisions", gap(first), digits=4)
    # the orbit past its supremum by rounding, and the spread of an invariant: their size is what they say
    fig.measure(f"{name}: (supremum − largest distance) / supremum after {len(s)} collisions", gap(len(s)),
                digits=ROUNDING)
    fig.measure(f"{name}: relative spread of the invariant s·n", inv_spread, digits=ROUNDING)
    fig.measure(f"{name}: no period up to {head.length // 2}; smallest relative mismatch", head.mismatch)
    fig.check(f"{name}: bounded: free flights completed", t["flights"], ">=", t["requested"])
    fig.check(f"{name}: s·n constant (relative spread)", inv_spread, "<=", 1e-9, digits=ROUNDING)
    fig.check(f"{name}: bounded by the closed-form supremum, to rounding: (supremum − largest distance) / supremum",
              gap(len(s)), ">=", -1e-9, digits=ROUNDING)
    fig.check(f"{name}: the band is filled: (supremum − largest distance) / supremum", gap(len(s)), "<=", 1e-6,
              digits=ROUNDING)
    fig.check(f"{name}: not periodic: smallest mismatch of the first 1000 collisions", head.mismatch, ">=", 1e-3)

    out = MplFigure(figsize=(11.0, 8.6), layout="constrained")
    out.suptitle("periodic · disc (R = 0.1, κ = 0.5) in wedges · rough", fontsize=9)
    gs = out.add_gridspec(len(periodic), 2, width_ratios=[1, 1.35])
    for k, (r, per) in enumerate(periodic):
        ax = out.add_subplot(gs[k, 0])
        draw_wedge_orbit(ax, r, r["flights"])
        label = (f"period {per.period} (state repeats to {per.mismatch:.1e}, relative)" if per.period
                 else "no period found")
        ax.set_title(f"{r['angle']:.4g}° wedge: {r['flights']} free flights, {label}", fontsize=8.5)
    right = gs[:, 1].subgridspec(2, 1, height_ratios=[2.3, 1])
    ax = out.add_subplot(right[0])
    shown = min(TYPICAL_SHOWN, t["flights"])
    draw_wedge_orbit(ax, t, shown, pred.supremum, pred.apex, lw=0.4)
    ax.set_title(f"{t['angle']:.4g}° wedge, a typical bounded orbit: first {shown} of {t['flights']} free flights",
                 fontsize=8.5)
    ax.legend(fontsize=7, loc="upper right")
    ax2 = out.add_subplot(right[1])
    draw_gap(ax2, s_run, pred.supremum)
    fig.save(out, args)


if __name__ == "__main__":
    main()
