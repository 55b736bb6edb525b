"""Three orbits of a uniform disc (κ = ½, radius 0.1) in a circular table of radius 1 with completely rough
collisions, from three initial conditions; the first 120 free flights of each (of 2·10⁴ measured). Each orbit has
its own constant vertex angle and its own pair of concentric caustic circles (dashed), touched alternately at the
segments' midpoints (dots). Why these initial states: they cover the range of shapes. One without spin whose
caustics lie well inside (radii 0.20 and 0.50, vertex angle 46°), one spinning fast near the rim (0.65 and 0.84,
vertex angle 116°) and one whose outgoing segment runs almost back along the incoming one (vertex angle 14°: the
rough collision reverses most of the tangential velocity). None of them closes after a few turns. 2·10⁴
collisions each keep the run well under a second while rounding has time to show.
"""
import numpy as np
from matplotlib.figure import Figure as MplFigure

from figlib import ROUNDING, Figure, arguments
from fig_caustics import BOUND, draw_orbit, read_circle_run
from rbx import orbits

SHOWN = 120


def main():
    args = arguments(__doc__)
    fig = Figure("circle", caption=__doc__)
    tracks, geom, title, R, kappa = read_circle_run(args.data[0])
    rho = geom.circle[1]
    results = [orbits.circle_orbit(p, v, w, rho, R, kappa) for p, v, w in tracks]

    for k, res in enumerate(results, 1):
        c = res.caustics
        fig.measure(f"orbit {k}: collisions", res.collisions)
        fig.measure(f"orbit {k}: vertex angle (mean; closed form {res.predicted_vertex_angle:.12f})",
                    res.vertex_angle, "rad")
        # spreads and offsets of 1e-12 and below are rounding: the record keeps their size
        fig.measure(f"orbit {k}: spread (max − min) of the vertex angle", res.vertex_angle_spread, "rad",
                    digits=ROUNDING)
        fig.measure(f"orbit {k}: caustic radii (segments 1–2, 3–4, … / 2–3, 4–5, …)",
                    f"{c.radii[0]:.12f} / {c.radii[1]:.12f}", "L")
        fig.measure(f"orbit {k}: spreads of the two radii", f"{c.spreads[0]:.2g} / {c.spreads[1]:.2g}", "L")
        fig.measure(f"orbit {k}: largest offset of the foot of the perpendicular from the midpoint",
                    res.midpoint_offset, "L", digits=ROUNDING)

    worst = lambda f: max(f(r) for r in results)
    fig.check("vertex angle constant: largest spread over the three orbits [rad]",
              worst(lambda r: r.vertex_angle_spread), "<=", BOUND, digits=ROUNDING)
    fig.check("vertex angles = closed form from each initial state [rad]",
              worst(lambda r: abs(r.vertex_angle - r.predicted_vertex_angle)), "<=", BOUND, digits=ROUNDING)
    fig.check("segments alternate between two circles: largest distance of a line from its circle",
              worst(lambda r: r.caustics.alternation), "<=", BOUND, digits=ROUNDING)
    fig.check("two circles per orbit: smallest difference of the radii",
              min(r.caustics.separation for r in results), ">=", 0.1)
    fig.check("caustic radii = closed form", worst(lambda r: r.radius_error), "<=", BOUND, digits=ROUNDING)
    fig.check("touched at the midpoints: largest offset", worst(lambda r: r.midpoint_offset), "<=", BOUND,
              digits=ROUNDING)
    fig.check("three different orbits: smallest difference of vertex angles [rad]",
              min(abs(a.vertex_angle - b.vertex_angle) for i, a in enumerate(results) for b in results[i + 1:]),
              ">=", 0.1)

    out = MplFigure(figsize=(12.0, 5.3), layout="constrained")
    out.suptitle(f"circle · {title}", fontsize=9)
    axes = out.subplots(1, len(results))
    for k, (ax, (p, _, w), res) in enumerate(zip(np.atleast_1d(axes), tracks, results), 1):
        draw_orbit(ax, geom, p, res, SHOWN)
        ax.set_title(f"orbit {k}: ω₀ = {w[0]:g} 1/T, vertex angle {np.degrees(res.vertex_angle):.3f}°\n"
                     f"first {SHOWN} of {res.collisions} free flights", fontsize=8.5)
        ax.set_xlabel("x [L]")
        ax.set_ylabel("y [L]")
    fig.save(out, args)


if __name__ == "__main__":
    main()
