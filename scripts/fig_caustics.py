"""A uniform disc (κ = ½, radius 0.1) in a circular table of radius 1 with completely rough (no-slip) collisions; the
path of its centre, which moves in the circle of radius 0.9. Left: the first 160 of 10⁵ free flights. They touch
two concentric circles (dashed) alternately, each segment at its midpoint (dots), and the angle between the two
segments at a collision is the same all along the orbit. Right: how far the collisions depart from this, over all
10⁵. Why these parameters: κ = ½ is the paper's case (its eq. (update2)); the initial state (at (0.3, 0), moving
along y, spin −15) gives two well separated caustics, radii 0.300 and 0.686, and advances the collision point by
about 0.61 of a turn every two flights, so the segments spread evenly round the annulus instead of bunching into a
star; 10⁵ collisions let rounding accumulate far beyond what is drawn. The caustic radii and the vertex angle are
also computed in closed form from the initial state (the collision map of docs/reference.md §1), an independent check.
"""
import numpy as np
from matplotlib.figure import Figure as MplFigure

from figlib import ROUNDING, Figure, arguments
from rbx import orbits
from rbx.reader import Run
from rbx.plotting import draw_table_2d

SHOWN = 160          # segments drawn in the orbit panel
BOUND = 1e-9         # what "constant", "exactly alternating" and "at the midpoint" mean on 10⁵ double-precision steps
COLOURS = ("tab:red", "tab:blue")


def read_circle_run(path):
    """-> (positions, velocities, spins) per trajectory (each cut at its count), geometry, title, R, κ."""
    with Run.open(path) as run:
        run.require(["position", "velocity", "angular_velocity"], "the caustics measurement")
        if run.table_kind != "circle":
            raise SystemExit(f"{path}: expected a run in a circle table, got {run.table_kind}")
        ids = list(range(run.trajectories))
        p, v, w = (run.read(f, ids) for f in ("position", "velocity", "angular_velocity"))
        orbits_ = [(p[j, :c], v[j, :c], w[j, :c]) for j, c in enumerate(run.count)]
        return orbits_, run.geometry(), run.scene(), run.radius, run.kappa


def draw_orbit(ax, geom, points, result, shown, legend=True):
    """The table, the first ``shown`` segments from the initial position, the two caustic circles (even segments
    red, odd blue) and the midpoints of the drawn segments, coloured by the circle they should touch."""
    lo, hi = np.array([-1.0, -1.0]), np.array([1.0, 1.0])
    draw_table_2d(ax, geom, lo, hi)
    ax.plot(points[:shown + 2, 0], points[:shown + 2, 1], color="0.25", lw=0.45)
    ax.plot(points[0, 0], points[0, 1], "o", color="k", ms=3.5)
    t = np.linspace(0, 2 * np.pi, 400)
    pts = points[1:shown + 2]
    mid = 0.5 * (pts[1:] + pts[:-1])
    for parity, (r, colour) in enumerate(zip(result.caustics.radii, COLOURS)):
        name = "segments 1–2, 3–4, …" if parity == 0 else "segments 2–3, 4–5, …"
        ax.plot(r * np.cos(t), r * np.sin(t), color=colour, lw=1.1, ls=(0, (4, 2)),
                label=f"caustic, radius {r:.4f} L ({name})")
        ax.plot(mid[parity::2, 0], mid[parity::2, 1], ".", color=colour, ms=3.0)
    ax.set_aspect("equal")
    ax.set_xlim(-1.05, 1.05)
    ax.set_ylim(-1.05, 1.05)
    ax.set_xticks([-1, 0, 1])
    ax.set_yticks([-1, 0, 1])
    if legend:
        # below the axes: inside, it covered the orbit and the table's rim
        ax.legend(fontsize=6.5, loc="upper center", bbox_to_anchor=(0.5, -0.16))


def binned_max(x, bins=500):
    """(bin centres, max of |x| in each bin) for a log plot of a long series."""
    x = np.abs(np.asarray(x, float))
    edges = np.linspace(0, len(x), min(bins, len(x)) + 1).astype(int)
    centres = 0.5 * (edges[1:] + edges[:-1])
    return centres, np.array([x[a:b].max() for a, b in zip(edges[:-1], edges[1:])])


def main():
    args = arguments(__doc__)
    fig = Figure("caustics", caption=__doc__)
    (track,), geom, title, R, kappa = read_circle_run(args.data[0])
    p, v, w = track
    rho = geom.circle[1]
    res = orbits.circle_orbit(p, v, w, rho, R, kappa)
    c = res.caustics

    fig.measure("collisions", res.collisions)
    fig.measure("vertex angle (mean)", res.vertex_angle, "rad")
    fig.measure("vertex angle, closed form from the initial state", res.predicted_vertex_angle, "rad")
    # spreads, offsets and distances of 1e-12 and below are rounding: the record keeps their size
    fig.measure("spread (max − min) of the vertex angle", res.vertex_angle_spread, "rad", digits=ROUNDING)
    fig.measure("caustic radius of segments 1–2, 3–4, … (mean)", c.radii[0], "L")
    fig.measure("its closed form from the initial state", res.predicted_radii[0], "L")
    fig.measure("its spread (max − min)", c.spreads[0], "L", digits=ROUNDING)
    fig.measure("caustic radius of segments 2–3, 4–5, … (mean)", c.radii[1], "L")
    fig.measure("its closed form from the initial state", res.predicted_radii[1], "L")
    fig.measure("its spread (max − min)", c.spreads[1], "L", digits=ROUNDING)
    fig.measure("largest offset of the foot of the perpendicular from the segment's midpoint", res.midpoint_offset,
                "L", digits=ROUNDING)
    fig.measure("largest distance of a collision point from the circle of radius ρ = R_table − R", res.off_circle,
                "L", digits=ROUNDING)

    fig.check("vertex angle constant: spread over the orbit [rad]", res.vertex_angle_spread, "<=", BOUND,
              digits=ROUNDING)
    fig.check("vertex angle = closed form from the initial state [rad]",
              abs(res.vertex_angle - res.predicted_vertex_angle), "<=", BOUND, digits=ROUNDING)
    fig.check("segments alternate between two circles: largest distance of a line from its circle",
              c.alternation, "<=", BOUND, digits=ROUNDING)
    fig.check("two circles, not one: difference of the radii", c.separation, ">=", 0.1)
    fig.check("caustic radii = closed form", res.radius_error, "<=", BOUND, digits=ROUNDING)
    fig.check("touched at the midpoints: largest offset", res.midpoint_offset, "<=", BOUND, digits=ROUNDING)

    pts = p[1:]
    out = MplFigure(figsize=(10.5, 5.0), layout="constrained")
    out.suptitle(f"caustics · {title}", fontsize=9)
    ax, ax2 = out.subplots(1, 2, gridspec_kw={"width_ratios": [1, 1.15]})
    draw_orbit(ax, geom, p, res, SHOWN)
    ax.set_title(f"first {SHOWN} of {res.collisions} free flights; vertex angle {np.degrees(res.vertex_angle):.4f}°",
                 fontsize=8.5)
    ax.set_xlabel("x [L]")
    ax.set_ylabel("y [L]")
    va = orbits.vertex_angles(pts)
    d = orbits.line_distances(pts)
    dev_r = np.where(np.arange(len(d)) % 2 == 0, d - c.radii[0], d - c.radii[1])
    floor = 1e-18
    for series, label, colour in ((va - res.vertex_angle, "vertex angle − mean [rad]", "k"),
                                  (dev_r, "line's distance − its circle's radius [L]", "tab:purple"),
                                  (orbits.midpoint_offsets(pts), "foot of perpendicular − midpoint [L]",
                                   "tab:green")):
        x, y = binned_max(series)
        ax2.semilogy(x + 1, np.maximum(y, floor), lw=1.0, color=colour, label=label)
    ax2.axhline(BOUND, color="tab:red", lw=1.0, ls="--",
                label=f"largest deviation still taken as rounding ({BOUND:g})")
    ax2.set_ylim(1e-17, 1e-7)
    ax2.set_xlim(0, res.collisions)
    ax2.set_xlabel("collision number")
    ax2.set_ylabel(f"largest |deviation| per bin of {max(1, len(va) // 500)} collisions\n[rad or L, see legend]")
    ax2.set_title("departures from a constant vertex angle, two caustics and tangency at the midpoints,\n"
                  f"all {res.collisions} collisions", fontsize=8.5)
    ax2.legend(fontsize=7, loc="upper left")
    fig.save(out, args)


if __name__ == "__main__":
    main()
