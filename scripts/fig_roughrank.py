"""The ball and start of Figure plate (κ = 2/5, radius 0.1, plates 1 apart) with roughness rank 1 on at least one
plate: horizontal projections of one orbit of 10⁶ collisions each, for the paper's three combinations — both plates
rank 1 with the rough direction drawn from 0°, 60°, 120° at every collision, independently (top left); top plate
rank 1 along x, bottom plate drawn as before (bottom left); top plate rank 2, bottom plate rank 1 along x (top
middle) — and, for comparison, rank 2 on both (bottom middle, the bounded orbit of Figure plate). Right: the largest
horizontal distance from the start reached up to each collision, on log–log axes. As soon as one plate has rank 1
the orbit is unbounded; how fast it runs away is decided by what no collision can change. A rough collision is a
reflection of (v, R√κ·ω) that leaves the states not slipping in its rough directions alone; if some state slips in
none of the directions of either plate, that part of the velocity is kept forever and the ball drifts ballistically
(excursion ∝ steps¹) at that velocity (predicted by rbx.analysis.conserved_drift, and matched to 10⁻³ or better) — here
for top rank 2 with bottom rank 1 along x, and for top rank 1 along x with random bottom directions (three
constraints on four velocity–spin components). For these two the panel draws the path minus the predicted drift
(x − v_x·t, y − v_y·t; the drift itself, a straight line some 3·10⁵ L long, is given in the title): bounded for the
deterministic rules (drawn at even collisions only, so one phase of a period-2 wobble) and a random walk for the random
ones. With random directions on both plates nothing is kept and the orbit is a random walk (excursion ∝ steps^½,
time-averaged MSD ∝ lag); with rank 2 on both it is bounded. Why these parameters: the paper's three boundary
conditions and ball, the start of Figure plate so that the bounded case is the same orbit, 10⁶ collisions (three
decades of growth) recorded every 10th.
"""
import numpy as np
from matplotlib.figure import Figure as MplFigure
from matplotlib.ticker import MaxNLocator

from rbx.model import Constant, Hemisphere, Random

from fig_plate import plates_measures, read_plates_orbit, record_plates, vector_length
from figlib import ROUNDING, Figure, arguments, fixed, geomspace

UNBOUNDED = 0.3      # growth exponent of the excursion above which an orbit is unbounded (bounded: 0)
BOUNDED = 0.05       # ... and below which it is bounded
DRIFT = 0.01         # relative error of the predicted drift velocity
MAX_POINTS = 20000   # points drawn per path
PLACES = {"both-random": (0, 0), "constant-random": (1, 0), "rank2-rank1": (0, 1), "rank2-rank2": (1, 1)}
NAMES = {"both-random": "both plates rank 1, directions drawn from 0°, 60°, 120°",
         "constant-random": "top rank 1 along x, bottom rank 1 drawn from 0°, 60°, 120°",
         "rank2-rank1": "top rank 2, bottom rank 1 along x",
         "rank2-rank2": "both plates rank 2 (Figure plate, for comparison)"}


def uses_random(rules):
    """True if any of the wall rules (``Experiment.wall_rules``) draws at random anywhere."""
    def walk(rule):
        if isinstance(rule, Random):
            return True
        return isinstance(rule, Hemisphere) and (walk(rule.rough) or walk(rule.smooth))
    return any(walk(r) for r in rules)


def kind_of(rules):
    """'both-random' | 'constant-random' | 'rank2-rank1' | 'rank2-rank2' from the plates' wall rules (bottom, top)."""
    desc = ["random" if isinstance(r, Random) else f"rank{r.rank}" if isinstance(r, Constant) else "other"
            for r in rules]
    bottom, top = desc
    if bottom == top == "random":
        return "both-random"
    if bottom == "random" and top == "rank1":
        return "constant-random"
    if top == "rank2" and bottom == "rank1":
        return "rank2-rank1"
    if top == bottom == "rank2":
        return "rank2-rank2"
    raise SystemExit(f"roughrank: unexpected boundary (bottom {bottom}, top {top})")


def main():
    args = arguments(__doc__)
    fig = Figure("roughrank", caption=__doc__)
    scenes = {}
    for path in args.data:
        o = read_plates_orbit(path)
        scenes[kind_of(o["rules"])] = (o, plates_measures(o))
    title = next(iter(scenes.values()))[0]["title"].split(" · ")[0]

    for k in PLACES:
        if k not in scenes:
            continue
        o, m = scenes[k]
        record_plates(fig, m, prefix=f"{k}: ")
    for k, (o, m) in scenes.items():
        random = uses_random(o["rules"])
        if k == "rank2-rank2":
            fig.check(f"{k}: bounded: growth exponent of the excursion", m["exponent"], "<=", BOUNDED,
                      digits=ROUNDING if abs(m["exponent"]) < 1e-3 else 4)
            continue
        fig.check(f"{k}: unbounded: growth exponent of the excursion", m["exponent"], ">=", UNBOUNDED, digits=4)
        if m["drifts"]:
            fig.check(f"{k}: drifts at the conserved slip-free velocity: relative error", m["drift_error"], "<=",
                      DRIFT, digits=4)
        else:
            fig.check(f"{k}: nothing conserved: |mean velocity| / |initial horizontal velocity|",
                      vector_length(m["measured_drift"]) / m["speed"], "<=", DRIFT, digits=4)
        what = "after the drift" if m["drifts"] else "the orbit"
        if random:
            fig.check(f"{k}: {what} is a random walk: time-averaged MSD exponent ≥", m["rest_tamsd_exponent"],
                      ">=", 0.8, digits=4)
            fig.check(f"{k}: {what} is a random walk: time-averaged MSD exponent ≤", m["rest_tamsd_exponent"],
                      "<=", 1.2, digits=4)
        else:
            fig.check(f"{k}: {what} is bounded (deterministic rules): growth exponent of its excursion",
                      m["rest_exponent"], "<=", BOUNDED, digits=ROUNDING if abs(m["rest_exponent"]) < 1e-3 else 4)

    out = MplFigure(figsize=(15.0, 9.0), layout="constrained")
    out.suptitle(f"roughrank · {title}: horizontal projections of one orbit of 10⁶ collisions per boundary "
                 "condition", fontsize=9)
    grid = out.add_gridspec(2, 3, width_ratios=[1, 1, 1.25])
    for k, (row, col) in PLACES.items():
        if k not in scenes:
            continue
        o, m = scenes[k]
        ax = out.add_subplot(grid[row, col])
        colour = f"C{list(PLACES).index(k)}"
        p = o["position"]
        every = max(1, len(p) // MAX_POINTS)
        head = f"{k}: {NAMES[k]}\n"
        if m["drifts"]:
            # the drift is a straight line 10⁵ times longer than the motion around it: draw what is left after it
            d, r = m["drift"], m["rest"]
            q = r[::every]
            ax.plot(q[:, 0], q[:, 1], color=colour, lw=0.4)
            ax.plot(r[0, 0], r[0, 1], "o", color="k", ms=3)
            ax.set_xlabel(r"$x - v_x t$ [L]")
            ax.set_ylabel(r"$y - v_y t$ [L]")
            ax.set_title(head + rf"drift $(v_x, v_y)$ = ({fixed(d[0], 4)}, {fixed(d[1], 4)}) L/T (predicted): "
                         f"{m['eN']:.3g} L in {m['N']} collisions;\ndrawn: the path minus the drift, its excursion ∝ "
                         f"steps^{m['rest_exponent']:.2f}", fontsize=7.5)
        else:
            q = p[::every]
            ax.plot(q[:, 0], q[:, 1], color=colour, lw=0.4)
            ax.plot(p[0, 0], p[0, 1], "o", color="k", ms=3)
            ax.set_xlabel("x [L]")
            ax.set_ylabel("y [L]")
            ax.set_title(head + f"excursion {m['e1']:.4g} L after {m['n1']}, {m['eN']:.4g} L after {m['N']}",
                         fontsize=7.5)
        ax.set_aspect("equal", adjustable="datalim")
        ax.xaxis.set_major_locator(MaxNLocator(5))

    ax = out.add_subplot(grid[:, 2])
    for k in PLACES:
        if k not in scenes:
            continue
        o, m = scenes[k]
        s = o["steps"]
        i = np.unique(geomspace(1, len(s) - 1, 2000).astype(int))
        ax.loglog(s[i], m["excursion"][i], color=f"C{list(PLACES).index(k)}", lw=1.2,
                  label=f"{k}: exponent {m['exponent']:.3f}")
    n = geomspace(1e3, 1e6, 10)
    ax.loglog(n, 0.5 * n, "k:", lw=0.9, label="∝ steps (ballistic)")
    ax.loglog(n, 0.5 * np.sqrt(n), "k--", lw=0.9, label="∝ steps^½ (random walk)")
    ax.axvspan(1e3, 1e6, color="0.93", zorder=0, label="where the exponent is fitted")
    ax.set_xlabel("collisions")
    ax.set_ylabel("largest horizontal distance from the start so far [L]")
    ax.set_title("growth of the horizontal excursion", fontsize=8.5)
    ax.legend(fontsize=7, loc="upper left")
    fig.save(out, args)


if __name__ == "__main__":
    main()
