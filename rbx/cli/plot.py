"""``rbx plot OUT.h5 --kind K``: pictures from a run (docs/reference.md §4). Reads the file, picks records and
trajectories, computes with :mod:`rbx.analysis` and draws with :mod:`rbx.plotting`; never simulates."""
import os
import time

import click
import numpy as np

from .common import (Choice, Command, UserError, cannot_write, check_figure_target, display_path, duration,
                     interrupted_exit, plural, quiet_option, report_and_exit, summary, user_errors)

#: the plot kinds (``--kind``); kind K is drawn by the function ``_K`` below
KINDS = ("orbit", "orbit3d", "phase", "series", "diffusion", "escape", "birkhoff", "poincare", "sweep")
#: --coordinate name -> (field, component or None, axis label, dimensions where it exists)
COORDINATES = {
    "x": ("position", 0, "x [L]", (2, 3)), "y": ("position", 1, "y [L]", (2, 3)), "z": ("position", 2, "z [L]", (3,)),
    "vx": ("velocity", 0, "vₓ [L/T]", (2, 3)), "vy": ("velocity", 1, "v_y [L/T]", (2, 3)),
    "vz": ("velocity", 2, "v_z [L/T]", (3,)),
    "w": ("angular_velocity", None, "ω [rad/T]", (2,)), "wx": ("angular_velocity", 0, "ωₓ [rad/T]", (3,)),
    "wy": ("angular_velocity", 1, "ω_y [rad/T]", (3,)), "wz": ("angular_velocity", 2, "ω_z [rad/T]", (3,)),
    "theta": ("orientation", None, "θ [rad]", (2,)), "time": ("time", None, "t [T]", (2, 3)),
}
#: default number of trajectories drawn when --trajectories is not given
DEFAULT_TRAJECTORIES = {"orbit": 10, "orbit3d": 10, "phase": 20, "series": 1, "diffusion": None, "escape": None,
                        "birkhoff": 20, "poincare": 20, "sweep": None}


@click.command(cls=Command)
@click.argument("run_file", metavar="OUT.h5", type=click.Path())
@click.option("--kind", required=True, type=Choice(KINDS), help="Which picture.")
@click.option("-o", "--output", "out", type=click.Path(dir_okay=False),
              help="Figure to write (PNG, PDF, SVG; default: OUT_<kind>.png beside the run). An existing figure is "
                   "replaced; a missing folder, a link or another kind of file is refused.")
@click.option("--records", metavar="A:B[:C]", help="Record range, as a Python slice (record i = the state after "
                                                     "collision i·every). Default: all.")
@click.option("--trajectories", metavar="LIST", help="Trajectories to use: 0,1,2 or 0-9 or all. Default: the first "
                                                    "10 (orbit), 20 (phase), 1 (series), all (diffusion).")
@click.option("--color", "colour", type=Choice(["trajectory", "step"]), default="trajectory",
              show_default=True, help="phase: colour points by trajectory or by collision step.")
@click.option("--coordinate", default="x", show_default=True, type=Choice(list(COORDINATES)),
              help="series, diffusion: the coordinate to follow.")
@click.option("--scales", default="0.01,0.1,1", show_default=True,
              help="series: fractions of the run shown in the panels.")
@click.option("--fit-from", default=0.1, show_default=True, type=float,
              help="diffusion: fit the MSD over steps ≥ this fraction of the last step; escape: the first start "
                   "tried for the fit, as a quantile of the exit paths (below 0.5; later ones are tried until the "
                   "fitted law follows the survival).")
@click.option("--wall", "wall", help="birkhoff: the wall whose boundary map to draw (default: the whole boundary).")
@click.option("--plane", default="z=0.5", show_default=True,
              help="poincare: the section plane, z=0.5 (or x=, y=) or n=NX,NY,NZ;c=C for n·x = C.")
@click.option("--y", "y", metavar="OBSERVABLE", help="sweep: the variable to draw (default: the first measured).")
@click.option("--x", "x", metavar="KEY", help="sweep: the varied key on the x axis (default: the first).")
@click.option("--logx", is_flag=True, help="sweep: a log x axis.")
@click.option("--logy", is_flag=True, help="sweep: a log y axis.")
@click.option("--dpi", default=150, show_default=True, type=click.IntRange(10, 1200),
              help="Resolution of raster figures, in dots per inch (10 to 1200).")
@quiet_option
@click.option("--debug", is_flag=True, help="Show a traceback with user errors.")
@click.pass_context
def plot(ctx, run_file, kind, out, records, trajectories, colour, coordinate, scales, fit_from, wall, plane, y, x,
         logx, logy, dpi, quiet, debug):
    """Draw a picture of the run OUT.h5 (written by rbx simulate), or of a study's results (rbx sweep).

    \b
    --kind
      orbit      the centre's path in the table, drawn to scale (a 3D run: its horizontal projection)
      orbit3d    3D runs: the path in 3D beside its horizontal projection
      phase      boundary map, and tangential velocity against spin, at each collision
      series     a --coordinate against the collision step, over several --scales
      diffusion  ensemble mean-square displacement along --coordinate with the fitted D (per collision and,
                 with time recorded, per unit time; only a slope where free corridors make the horizon
                 infinite) and the displacements' distribution
      escape     survival of the exit paths (walls with the rule exit): the fitted rate, and the trapped share
                 where survival levels off
      birkhoff   2D runs: the boundary map (arc length, sin ψ) coloured by the spin, one --wall or all
      poincare   3D runs: the section by a --plane, coloured by the spin
      sweep      a study's .nc file (rbx sweep): --y against --x with error bars"""
    began = time.perf_counter()
    try:
        _check_kind_options(ctx, kind)
        result = None
        if run_file.endswith(".nc") or kind == "sweep":       # a study's results (rbx sweep), not a run file
            from .sweep import plot_sweep
            path = plot_sweep(run_file, kind, out, y, x, logx, logy, dpi)
        else:
            path, result = _plot(run_file, kind, out, records, trajectories, colour, coordinate, scales, fit_from,
                                 dpi, wall=wall, plane=plane)
    except UserError as exc:
        report_and_exit(exc, debug)
    except KeyboardInterrupt:
        interrupted_exit()
    summary(quiet, f"wrote {display_path(path)}: {kind} of {display_path(run_file)} in "
                   f"{duration(time.perf_counter() - began)}")
    if result:
        click.echo(result)


#: the options that apply to some kinds only (the others refuse them rather than ignore them)
KIND_OPTIONS = {"colour": ("--color", ("phase",)), "coordinate": ("--coordinate", ("series", "diffusion")),
                "scales": ("--scales", ("series",)), "fit_from": ("--fit-from", ("diffusion", "escape")),
                "wall": ("--wall", ("birkhoff",)), "plane": ("--plane", ("poincare",)),
                "y": ("--y", ("sweep",)), "x": ("--x", ("sweep",)), "logx": ("--logx", ("sweep",)),
                "logy": ("--logy", ("sweep",)),
                # the escape plot reads each trajectory's end (its whole run), a study's figure its points
                "records": ("--records", tuple(k for k in KINDS if k not in ("escape", "sweep"))),
                "trajectories": ("--trajectories", tuple(k for k in KINDS if k != "sweep"))}


def _check_kind_options(ctx, kind):
    """An option given on the command line that the kind does not use is refused in one line: ``--coordinate vx``
    with ``--kind orbit`` drew the orbit as if it had not been given."""
    from click.core import ParameterSource
    for name, (option, kinds) in KIND_OPTIONS.items():
        if kind not in kinds and ctx.get_parameter_source(name) == ParameterSource.COMMANDLINE:
            if len(kinds) <= 3:
                used = " and ".join(f"--kind {k}" for k in kinds)
                raise UserError(None, option, f"is for {used} only; --kind {kind} does not use it")
            raise UserError(None, option, f"--kind {kind} does not use it")


def _plot(run_file, kind, out, records, trajectories, colour, coordinate, scales, fit_from, dpi, wall=None,
          plane="z=0.5"):
    path = out or f"{os.path.splitext(run_file)[0]}_{kind}.png"
    if out is not None or os.path.exists(run_file):    # (a missing run is said by its own line)
        check_figure_target(path)                        # before the figure is made: said at once
    fig = make_figure(run_file, kind, parse_records(records), trajectories, colour=colour, coordinate=coordinate,
                      scales=parse_scales(scales), fit_from=fit_from, wall=wall, plane=plane)
    from ..paths import FileError
    from ..plotting import save
    try:
        save(fig, path, dpi=dpi)
    except (OSError, ValueError, RuntimeError, FileError) as exc:     # RuntimeError: a format's tool missing (pgf: LaTeX)
        cannot_write(path, exc)
    return path, getattr(fig, "rbx_result", None)     # what the picture measured, for stdout (escape)


def make_figure(run_file, kind, records=slice(None), trajectories=None, **options):
    """The Figure of one picture of a run file -> matplotlib Figure (for the CLI, figure scripts and tests).

    ``trajectories``: text as for --trajectories, or None for the kind's default; ``options``: colour,
    coordinate, scales, fit_from, wall, plane. Problems with the file or the selection raise :class:`UserError`."""
    from ..reader import Run

    with user_errors():
        if os.path.isfile(run_file) and run_file.endswith((".yaml", ".yml")):
            raise UserError(run_file, None, "is a config, not a run: run it first, rbx simulate "
                                            f"{display_path(run_file)} -o OUT.h5, then rbx plot OUT.h5 --kind {kind}")
        run = Run.open(run_file)
        with run:
            traj = parse_trajectories(trajectories, run.trajectories, DEFAULT_TRAJECTORIES[kind], run.path)
            if kind != "escape":        # the escape plot reads the final states, not the records
                check_records(records, len(run.step), run.path, run)
            if kind == "sweep":
                raise UserError(run.path, None, "--kind sweep draws the results of rbx sweep (a .nc file), not a run")
            try:
                return _BUILDERS[kind](run, records, traj, **options)
            except ValueError as exc:
                raise UserError(run.path, None, str(exc)) from None


# ---- options ---------------------------------------------------------------------------------------------------


def parse_records(text):
    """'A:B', 'A:', ':B', 'A:B:C' -> slice (Python semantics)."""
    if text is None:
        return slice(None)
    parts = text.split(":")
    try:
        if len(parts) not in (2, 3):
            raise ValueError
        vals = [int(p) if p.strip() else None for p in parts]
    except ValueError:
        raise UserError("--records", None, f"expected A:B or A:B:C (integers, either may be empty), got '{text}'") \
            from None
    if len(vals) == 3 and vals[2] is not None and vals[2] <= 0:
        raise UserError("--records", None, f"the stride must be positive, got {vals[2]}")
    return slice(*vals)


def check_records(records, available, file, run=None):
    """Refuse a --records range that selects nothing (it drew a blank figure), a run that holds no records yet (a
    run stopped before its first block was saved) and a ``run`` that recorded no field (``output.record: []``)."""
    if available == 0 and run is not None and run.complete and not run.fields:
        raise UserError(file, None, "recorded no fields (output.record: []): record what the picture needs (its "
                                    "config's output.record) and run it again; --kind escape draws such a run, from "
                                    "its final states")
    if available == 0:
        raise UserError(file, None, "holds no records yet (stopped before its first block was saved): resume it "
                                    "with rbx simulate --resume, then draw it")
    if len(range(available)[records]) == 0:
        a, b, c = records.start, records.stop, records.step
        text = ":".join("" if v is None else str(v) for v in ((a, b) if c is None else (a, b, c)))
        raise UserError(file, "--records", f"{text} selects no records (the run has {available}: 0–{available - 1})")


def parse_trajectories(text, available, default, file):
    """'0,1,2', '0-9', 'all' -> sorted list of trajectory indices (default: the first ``default`` or all)."""
    if text is None or text.strip() == "all":
        count = available if text is not None or default is None else min(default, available)
        return list(range(count))
    out = set()
    try:
        for part in text.split(","):
            if "-" in part.strip()[1:]:
                a, b = (int(x) for x in part.split("-", 1))
                for j in (a, b):
                    if j < 0 or j >= available:   # checked before the range is made: 0-10¹¹ filled the memory
                        raise UserError(file, "--trajectories", f"trajectory {j} does not exist (the run has "
                                                                f"{available}: 0–{available - 1})")
                out.update(range(a, b + 1))
            else:
                out.add(int(part))
    except ValueError:
        raise UserError("--trajectories", None, f"expected a list like 0,1,2 or 0-9 or all, got '{text}'") from None
    bad = [j for j in sorted(out) if j < 0 or j >= available]
    if bad:
        raise UserError(file, "--trajectories", f"trajectory {bad[0]} does not exist (the run has {available}: "
                                                f"0–{available - 1})")
    if not out:
        raise UserError("--trajectories", None, "no trajectory selected")
    return sorted(out)


def parse_scales(text):
    try:
        vals = [float(x) for x in text.split(",")]
    except ValueError:
        vals = []
    if not vals or any(not 0 < v <= 1 for v in vals):
        raise UserError("--scales", None, f"expected fractions in (0, 1] separated by commas, got '{text}'")
    return vals


# ---- assembling the data of each picture -----------------------------------------------------------------------


def _span(items):
    items = list(items)
    if len(items) > 1 and items == list(range(items[0], items[-1] + 1)):
        return f"{items[0]}–{items[-1]}"
    return ",".join(str(i) for i in items[:8]) + ("…" if len(items) > 8 else "")


def _title(run, what, traj, rec):
    steps = run.step[rec]
    trange = f"trajectory {traj[0]}" if len(traj) == 1 else f"trajectories {_span(traj)}"
    srange = f"collisions {steps.min()}–{steps.max()}" if len(steps) else "no records kept (output.record: [])"
    extra = "" if run.complete else " · INCOMPLETE RUN"
    every = f" (a record every {run.every} collisions)" if run.every > 1 and len(steps) else ""
    return f"{run.scene()}\n{what} · {trange} of {run.trajectories} · {srange}{every}{extra}"


def _stride(run, rec):
    """Collisions between two consecutive selected records: ``output.every`` times the stride of ``--records``.
    Above 1 the records are not consecutive collisions: no straight flight joins them (orbits are drawn as points)
    and no plane crossing can be found between them."""
    return run.every * (rec.step or 1)


def _paths(run, rec, traj):
    run.require(["position"], "this picture")
    pos = run.read("position", traj, rec)
    return [p[np.all(np.isfinite(p), axis=1)] for p in pos]


def _orbit(run, rec, traj, **_):
    from .. import plotting
    paths = _paths(run, rec, traj)
    what = "orbit of the centre" if run.dimension == 2 else "horizontal projection of the orbit"
    return plotting.orbit_figure(paths, run.geometry(), _title(run, what, traj, rec),
                                 labels=[f"trajectory {j}" for j in traj], points_only=_stride(run, rec) > 1,
                                 stride=_stride(run, rec))


def _orbit3d(run, rec, traj, **_):
    from .. import plotting
    if run.dimension != 3:
        raise UserError(run.path, None, "orbit3d needs a 3D run (a table in three dimensions: plates, box, sphere, "
                                        "cylinder, a 3D sinai or lorentz, …); this one is 2D: use --kind orbit")
    return plotting.orbit3d_figure(_paths(run, rec, traj), run.geometry(), _title(run, "orbit", traj, rec),
                                   labels=[f"trajectory {j}" for j in traj], points_only=_stride(run, rec) > 1,
                                   stride=_stride(run, rec))


def _phase(run, rec, traj, colour="trajectory", **_):
    from .. import analysis, plotting
    run.require(["position", "velocity", "angular_velocity", "wall"], "the phase portrait")
    wall = run.read("wall", traj, rec)
    pos = run.read("position", traj, rec)
    vel = run.read("velocity", traj, rec)
    spin = run.read("angular_velocity", traj, rec)
    steps = np.broadcast_to(run.step[rec], wall.shape)
    which = np.broadcast_to(np.arange(len(traj))[:, None], wall.shape)
    at = wall >= 0                                     # records made at a collision (not record 0, not past the end)
    wall, pos, vel, spin, steps, which = wall[at], pos[at], vel[at], spin[at], steps[at], which[at]
    if len(wall) == 0:
        raise ValueError("no collisions in the selected records")
    geom = run.geometry()
    s, nu = analysis.locate(geom, wall, pos) if run.dimension == 2 else (None, _normals_3d(geom, wall, pos))
    tangents = [w.tangents for w in geom.wall_list]
    if run.dimension == 3 and any(t is None for t in tangents):
        curved = [w.name for w in geom.wall_list if w.tangents is None]
        raise UserError(run.path, "--kind phase", f"the spin planes are drawn in a flat wall's own axes, and "
                                                  f"'{curved[0]}' is curved: use --kind poincare")
    panels = []
    if run.dimension == 2:
        _, sin_psi = analysis.birkhoff_coordinates(geom, wall, pos, vel)
        total = analysis.boundary_length(geom)
        if np.isfinite(total):
            panels.append(dict(x=s, y=sin_psi, xlabel="arc length s along the shrunk boundary [L]",
                               ylabel="sin ψ = v·t/|v| [–]", ylim=(-1.05, 1.05), xlim=(0.0, total),
                               vlines=analysis.wall_joints(geom), walls=_wall_names(geom, run.wall_names),
                               title="Birkhoff coordinates of the boundary map"))
        else:  # unbounded walls (strip, wedge): one panel per wall, s counter-clockwise from the wall's origin, as
            # in --kind birkhoff --wall (the strip's top wall: s = −x; its own axis +x had s run the other way)
            for w, name in enumerate(run.wall_names):
                on = wall == w
                panels.append(dict(x=s[on], y=sin_psi[on], select=on, xlabel=_along(geom, w, name),
                                   ylabel="sin ψ = v·t/|v| (t: the counter-clockwise tangent) [–]", ylim=(-1.05, 1.05),
                                   title=f"boundary map on wall '{name}'"))
    planes = analysis.spin_planes(wall, nu, vel, spin, run.radius, run.kappa, tangents)
    for k, (x, y, xn, yn) in enumerate(planes):
        lim = 1.15 * float(np.max(np.abs(np.concatenate([x, y])))) or 1.0
        panel = dict(x=x, y=y, xlabel=f"{xn} [L/T]", ylabel=f"{yn} [L/T]", equal=True, xlim=(-lim, lim),
                     ylim=(-lim, lim), title=SPIN_PLANE_TITLES[len(planes)][k])
        if run.dimension == 2:
            panel["lines"] = [(-np.sqrt(run.kappa), "no slip: v·t + Rω = 0")]
        else:
            panel["lines"] = [(np.sqrt(run.kappa), "no slip")]
        panels.append(panel)
    categorical = colour == "trajectory"
    return plotting.phase_figure(panels, [traj[k] for k in which] if categorical else steps,
                                 _title(run, "phase portrait at collisions", traj, rec),
                                 colour_label="collision step", categorical=categorical,
                                 labels=[f"trajectory {j}" for j in traj])


#: what each spin panel of the phase portrait shows (2D: one plane; 3D: one per tangent axis of the wall, whose
#: panels were both titled "tangential velocity against spin at collisions")
SPIN_PLANE_TITLES = {
    1: ("tangential velocity against spin at collisions",),
    2: ("velocity along e₁ against spin about e₂\n(e₁: the wall's first tangent axis)",
        "velocity along e₂ against spin about e₁\n(e₂ = ν × e₁, ν the wall's normal)")}


def _normals_3d(geom, wall, pos):
    """Inward unit normals at 3D collision points, from each wall's patch (flat, sphere or cylinder)."""
    nu = np.full(pos.shape, np.nan)
    for w, spec in enumerate(geom.wall_list):
        on = wall == w
        if not on.any():
            continue
        patch = spec.patches[0]
        if patch[0] == "flat":
            nu[on] = patch[2]
        elif patch[0] == "sphere":
            d = pos[on] - patch[1]
            nu[on] = patch[3] * d / np.linalg.norm(d, axis=1)[:, None]
        elif patch[0] == "cylinder":
            d = pos[on].copy()
            d[:, :2] -= np.asarray(patch[1], float)[:2]
            d[:, 2] = 0.0
            nu[on] = -d / np.linalg.norm(d, axis=1)[:, None]
    return nu


def _coordinate(run, name, traj, rec):
    field, comp, label, dims = COORDINATES[name]
    if run.dimension not in dims:
        raise UserError(run.path, None, f"--coordinate {name} does not exist in a {run.dimension}D run")
    run.require([field], f"--coordinate {name}")
    data = run.read(field, traj, rec)
    return (data if comp is None else data[..., comp]), label


def _series(run, rec, traj, coordinate="x", scales=(0.01, 0.1, 1.0), **_):
    from .. import plotting
    values, label = _coordinate(run, coordinate, traj, rec)
    return plotting.series_figure(run.step[rec], list(values), _title(run, f"{coordinate} against step", traj, rec),
                                  label, labels=[f"trajectory {j}" for j in traj], scales=scales,
                                  points_only=_stride(run, rec) > 1)


def _diffusion(run, rec, traj, coordinate="x", fit_from=0.1, **_):
    from .. import analysis, plotting
    problem = analysis.diffusion_problem(run.geometry(), coordinate)
    if problem:
        own = coordinate not in analysis.DIFFUSING or "has no coordinate" in problem
        raise UserError(run.path, "--coordinate" if own else "--kind diffusion", problem)
    if not 0.0 <= fit_from < 1.0:       # NaN too
        raise UserError(None, "--fit-from", f"diffusion: the share of the run skipped before the fit, in [0, 1), got "
                                            f"{fit_from}")
    if len(traj) < 2:
        raise ValueError("the diffusion plot needs an ensemble: at least 2 trajectories")
    x, _ = _coordinate(run, coordinate, traj, rec)
    _refuse_one_orbit(run, traj, x, "diffusion", "a diffusion coefficient", "its error would be 0 and the "
                                                                          "histogram of displacements one bar")
    keep = _distinct(run, traj)         # copies of one orbit are one sample (D = −0.0065 ± 0.003 from copies)
    traj, x = [t for t, k in zip(traj, keep) if k], x[keep]
    steps = run.step[rec].astype(float)
    if len(steps) < 3:
        raise ValueError("the diffusion plot needs at least 3 records")
    t = steps - steps[0]
    msd = analysis.mean_square_displacement(x)
    fit = analysis.fit_diffusion(t, x, fit_from=fit_from)
    full = np.all(np.isfinite(x), axis=1)
    per_time = None
    if "time" in run.fields:
        # D per unit time: D per collision over the mean time per collision (each complete trajectory's own time
        # over its own collisions, averaged); a ratio of ensemble means, as diffusion in time is asymptotically
        clock = run.read("time", traj, rec)[full]
        span = float(steps[-1] - steps[0])
        tau = float(np.mean(clock[:, -1] - clock[:, 0])) / span if span > 0 else np.nan
        if np.isfinite(tau) and tau > 0:
            per_time = tau
    # an infinite horizon (a free corridor along the coordinate, decided from the table's geometry): the MSD grows
    # as t·log t, and the slope drawn is no diffusion coefficient
    horizon = analysis.horizon_problem(run.geometry(), coordinate)
    fig = plotting.diffusion_figure(t, msd, fit, (x[full, -1] - x[full, 0]),
                                    _title(run, f"diffusion along {coordinate}", traj, rec), coordinate=coordinate,
                                    time_per_step=per_time, horizon=horizon and horizon[0])
    from ..analysis import plus_minus
    ci = (f"({round(100 * fit.confidence)}% CI, {fit.trajectories} trajectories, fitted over steps "
          f"{fit.start:.0f}–{fit.stop:.0f})")
    unit = "rad" if coordinate == "theta" else "L"
    if horizon:
        said = (f"slope of the MSD along {coordinate}, fitted as 2bt + c: b = "
                f"{plus_minus(fit.coefficient, fit.half_width)} {unit}²/collision {ci}")
    else:
        said = (f"diffusion coefficient along {coordinate}: D = {plus_minus(fit.coefficient, fit.half_width)} "
                f"{unit}²/collision {ci}")
    if per_time:
        said += f" = {plus_minus(fit.coefficient / per_time, fit.half_width / per_time)} {unit}²/T"
    if horizon:
        said += f"; not a diffusion coefficient: {horizon[1]}"
    elif not fit.low > 0:
        # the MSD does not grow over the window beyond its spread (a window of a few records, or no diffusion)
        said += ("; its interval reaches 0 or below: no diffusion can be read from this window (fit from earlier, "
                 "or run longer)")
    fig.rbx_result = said
    return fig


def _distinct(run, traj):
    """Which of the selected trajectories ``traj`` to keep: the first of each orbit that several copy (fixed starts,
    no random numbers drawn: :func:`rbx.ensembles.start_groups`) -> boolean array."""
    from ..ensembles import orbit_rows
    try:
        rows = orbit_rows(run.experiment, traj)
    except Exception:       # noqa: BLE001 - a run whose config cannot say: every trajectory counts
        return np.ones(len(traj), bool)
    return np.isin(traj, rows)


def _refuse_one_orbit(run, traj, values, kind, what, why):
    """An ensemble statistic of trajectories that are all the same orbit means nothing: refused in one line
    (``values``: the selected trajectories' data, one row each, compared bit for bit)."""
    if len(traj) < 2 or not all(np.array_equal(values[0], v, equal_nan=True) for v in values[1:]):
        return
    from ..ensembles import start_groups
    cause = ""
    try:
        group = start_groups(run.experiment)
    except Exception:       # a stored config this rbx no longer validates: the data say enough
        group = None
    if group is not None and len(set(group[traj].tolist())) == 1:
        cause = " (they start from the same state and no rule draws random numbers)"
    raise UserError(run.path, f"--kind {kind}",
                    f"the {len(traj)} trajectories are copies of one orbit{cause}: {what} needs independent "
                    f"trajectories ({why}); run an ensemble: initial: {{sample: billiard}}, a list of different "
                    "states, or a random rule")


def _escape(run, rec, traj, fit_from=0.1, **_):
    from .. import plotting
    from ..dynamics import escape_times
    from ..model import Exit
    exp = run.experiment
    if not any(isinstance(leaf, Exit) for r in exp.wall_rules for leaf in _leaves(r)):
        raise ValueError("no wall of this run has the rule exit: nothing can escape (give a wall {rule: exit})")
    out = escape_times(run)
    sel = np.asarray(traj)
    path, exited = out.path[sel], out.exited[sel]
    _refuse_one_orbit(run, traj, np.column_stack([path, exited, out.wall[sel]]), "escape", "an escape rate",
                      "every one leaves at the same moment")
    keep = _distinct(run, traj)         # copies of one orbit are one sample (survival fell by half in one step)
    traj, path, exited, sel = [t for t, k in zip(traj, keep) if k], path[keep], exited[keep], sel[keep]
    if not exited.any():
        who = f"none of the {plural(len(sel), 'trajectory')} reached" if len(sel) > 1 else "the trajectory did not reach"
        raise ValueError(f"{who} an exit wall in {plural(exp.run.collisions, 'collision')}")
    if not 0.0 <= fit_from < 0.5:
        raise UserError(None, "--fit-from", f"escape: a quantile in [0, 0.5), got {fit_from}")
    from ..analysis import starts_phrase
    from ..dynamics import survival
    from ..escape import FOLLOWS, fit_escape
    s, S = survival(path, exited)
    walls = sorted({run.wall_names[w] for w in out.wall[sel][exited]})
    trapped = _trapped(run, path, exited)
    # the model and its window (rbx.escape): where survival levels off, the trapped share q and the rate γ of the
    # others fitted together; the window starts after the transient, where the fitted curve follows the data
    from ..analysis import plus_minus, spin_mixture
    mixture = spin_mixture(exp)     # each orbit keeps its spin and leaves at its own rate: no one rate to fit
    try:
        fit = None if mixture else fit_escape(path, exited, fit_from=fit_from, trapped=trapped is not None)
    except ValueError:
        fit = None
    expected = None if trapped is not None else _small_hole_rate(exp)
    if mixture:     # the mean rate at the start, drawn from s = 0: the survival leaves it as the slow orbits remain
        from ..observables import hole_rate
        start, classic = hole_rate(exp), hole_rate(exp, d=exp.dimension)
        if start is not None and trapped is None:
            expected = (start[0], f"mean rate at the start |hole|/({start[2]}·|table|) = {start[0]:.4g} (each orbit's "
                                  f"own: c·|hole|/({classic[2]}·|table|), c its share of speed in the plane)")
    censored = int(np.sum(~exited))
    inside = f"{censored} still inside: censored" if censored else "every one exited"
    title = _title(run, f"escape through {', '.join(walls)} ({inside}) · {starts_phrase(run.experiment)}", traj,
                   rec)
    # a trajectory that exits at its last collision ended with the run: rbx simulate's summary does not count it
    # among those that "ended earlier"; the legend says both
    at_last = int(np.sum(exited & (np.asarray(run.final["collisions"])[sel] >= exp.run.collisions)))
    falling = censored if trapped is None else 0
    fig = plotting.escape_figure(s, S, fit, int(exited.sum()), len(sel), title,
                                 unit="path length in (x, R√κ·θ) [L]", expected=expected, trapped=trapped,
                                 at_last=at_last, falling=falling,
                                 no_rate=mixture and "specular walls keep each orbit's spin: each leaves at its own "
                                                     "rate, a mixture with no single rate (the text output says more)")
    if mixture:
        c_n, c_d = (classic[2], start[2]) if start is not None else ("C_n", "C_d")
        said = ("no escape rate: every wall is specular, so each orbit keeps its spin and moves at its own share c "
                f"of its speed in (v, R√κ·ω); it leaves at its own rate c·|hole|/({c_n}·|table|) per unit path, and "
                "the survival is a mixture of exponentials whose fast-spinning orbits (c near 0) hardly leave: no "
                f"single rate (the mean at the start, over these starts, is |hole|/({c_d}·|table|)"
                + (f" = {start[0]:.4g}" if start is not None else "")
                + "); point-particle starts (initial: {sample: point_particle}) give the classic billiard's rate")
    elif fit is not None and fit.follows:
        said = (f"escape rate γ = {plus_minus(fit.rate, fit.rate_err)} per unit path (fitted over {fit.start:.3g} ≤ s "
                f"≤ {fit.stop:.3g}")
        said += (f", with the level it tends to, S(s₀)·q = {100 * fit.survival0 * fit.level:.3g} %: "
                 f"S(s) = S(s₀)·[q + (1 − q)·exp(−γ(s − s₀))])" if fit.trapped else ")")
    else:
        said = (f"no escape rate: no exponential follows the survival from any of the starts tried (quantiles of "
                f"the exit paths from {fit_from:g} up; the decay is not exponential; largest gap allowed {FOLLOWS} "
                "in units of 1/√n)")
    if trapped is not None:
        share, low, high = trapped
        said += (f"; trapped share {100 * share:.3g} % (Wilson interval, z = 1: {100 * low:.3g}–{100 * high:.3g} %) "
                 f"of {len(sel)} starts")
    elif falling:
        said += (f"; survival still falling at the end of the run ({falling} of {len(sel)} still inside): no trapped "
                 "share can be read; run longer")
        if fit is not None and fit.follows:
            # a table that traps bends the curve towards its plateau only later: the rate read before that
            # depends on the window (a short run of a rough Sinai table: 0.0126 ± 0.0004, the whole run 0.0110)
            said += " (a longer run may bend the curve towards a level and change the rate)"
    fig.rbx_result = said
    return fig


def _trapped(run, path, exited):
    """The trapped share -> (share, low, high) (the ``trapped_share`` observable: Wilson interval, z = 1) where
    survival levels off (:func:`rbx.escape.levels_off`), else None."""
    from ..analysis import wilson
    from ..escape import levels_off
    if not levels_off(path, exited):
        return None
    if len(path) == run.trajectories:       # the whole run: the observable of rbx sweep, the same numbers
        from ..observables import PointRuns, get
        value = get("trapped_share").compute(PointRuns(run.experiment, run), {})
        return float(value.value), float(value.companions["low"]), float(value.companions["high"])
    share, low, high = wilson(int(np.sum(~exited)), len(path))
    return share, low, high


def _small_hole_rate(exp):
    """(rate, label) of the small-hole escape rate (:func:`rbx.observables.small_hole_rate`), or None where it does
    not apply."""
    from ..observables import small_hole_rate
    small = small_hole_rate(exp)
    if small is None:
        return None
    rate, share, constant = small
    # the limit of a vanishing hole: a hole of finite size differs from it, and leaves more slowly where a short
    # periodic orbit runs through it (the example's gate, docs/dynamics.md)
    return rate, (f"small-hole rate |hole|/({constant}·|table|) = {rate:.4g} (hole {100 * share:.2g} % of the boundary),\n"
                  "the limit of a vanishing hole: a finite one differs, slower where a short periodic orbit runs "
                  "through it")


def _leaves(rule):
    from ..model import rule_leaves
    return rule_leaves(rule)


def _birkhoff(run, rec, traj, wall=None, **_):
    from .. import analysis, plotting
    if run.dimension != 2:
        raise UserError(run.path, None, "birkhoff needs a 2D run; this one is 3D: use --kind poincare --plane ...")
    run.require(["position", "velocity", "angular_velocity", "wall"], "the Birkhoff map")
    walls = run.read("wall", traj, rec)
    at = walls >= 0
    geom = run.geometry()
    w_sel = None
    if wall is not None:
        if wall not in run.wall_names:
            raise UserError(None, "--wall", f"no wall named '{wall}' (walls: {', '.join(run.wall_names)})")
        w_sel = run.wall_names.index(wall)
        at &= walls == w_sel
    pos = run.read("position", traj, rec)[at]
    vel = run.read("velocity", traj, rec)[at]
    spin = run.read("angular_velocity", traj, rec)[at]
    if len(pos) == 0:
        raise ValueError("no collisions " + (f"with wall '{wall}' " if wall else "") + "in the selected records")
    s, sin_psi = analysis.birkhoff_coordinates(geom, walls[at], pos, vel)
    colour = analysis.spin_fraction(vel, spin, run.radius, run.kappa)
    panel = dict(y=sin_psi, ylabel="sin ψ = v·t/|v| (t: the counter-clockwise tangent) [–]", ylim=(-1.05, 1.05))
    if w_sel is not None:
        s0, length = analysis.wall_span(geom, w_sel)
        panel.update(x=s - s0, xlabel=f"arc length along wall '{wall}' of the shrunk table [L]",
                     title=f"boundary map on wall '{wall}'")
        if np.isfinite(length):
            panel["xlim"] = (0.0, length)
        else:   # an unbounded wall (the strip's): the axis spans the collisions, from where the wall's arc starts
            panel["xlabel"] = _along(geom, w_sel, wall)
    else:
        total = analysis.boundary_length(geom)
        if not np.isfinite(total):
            raise ValueError("the table is unbounded: choose one wall with --wall")
        panel.update(x=s, xlabel="arc length s along the shrunk boundary [L]", xlim=(0.0, total),
                     vlines=analysis.wall_joints(geom), walls=_wall_names(geom, run.wall_names),
                     title="Birkhoff map of the whole boundary")
    return plotting.section_figure([panel], colour, _title(run, "Birkhoff section at collisions", traj, rec),
                                   "spin share v₀/|(v, v₀)|, v₀ = R√κ·ω [–]")


def _wall_names(geom, names):
    """[(s at the middle of each wall, its name, its length)] along the whole boundary: the axis of a Birkhoff map
    marked the joints between walls but named no wall"""
    from .. import analysis
    out = []
    for w, name in enumerate(names):
        try:
            s0, length = analysis.wall_span(geom, w)
        except ValueError:                 # a wall the centre cannot touch
            continue
        out.append((s0 + 0.5 * length, name, length))
    return out


def _along(geom, w, name):
    """The axis label of s on an unbounded 2D wall: counter-clockwise from the wall's origin, and which way that is
    (the phase portrait and the Birkhoff map share it)."""
    from .. import analysis
    return f"arc length s along wall '{name}', counter-clockwise ({analysis.ccw_direction(geom, w)}) [L]"


def _poincare(run, rec, traj, plane="z=0.5", **_):
    from .. import analysis, plotting
    if run.dimension != 3:
        raise UserError(run.path, None, "poincare needs a 3D run (a table in three dimensions: plates, box, sphere, "
                                        "cylinder, a 3D sinai or lorentz, …); this one is 2D: use --kind birkhoff")
    try:
        normal, offset = analysis.parse_plane(plane)
    except ValueError as exc:
        raise UserError(None, "--plane", str(exc)) from None
    if run.every != 1:
        raise ValueError(f"a Poincaré section needs every collision recorded (output.every: 1, this run has "
                         f"{run.every})")
    if _stride(run, rec) != 1:
        # the crossing is found on the flight between two consecutive records: a stride made chords of several
        # flights, and 79 of 161 points fell outside the cylinder
        raise UserError(run.path, "--records", f"a Poincaré section needs consecutive collisions: no stride "
                                           f"(this selection takes every {rec.step}th record)")
    run.require(["time", "position", "velocity", "angular_velocity"], "the Poincaré section")
    cut = analysis.plane_crossings(run.read("position", traj, rec), run.read("velocity", traj, rec),
                                   run.read("angular_velocity", traj, rec), run.read("time", traj, rec), normal,
                                   offset)
    if len(cut["time"]) == 0:
        raise ValueError(f"no orbit crosses the plane {plane} in the selected records")
    e1, e2 = analysis.plane_axes(normal)
    p, v = cut["position"], cut["velocity"]
    spin = analysis.spin_fraction(v, cut["angular_velocity"], run.radius, run.kappa) @ normal
    speed = np.linalg.norm(v, axis=1)
    def axis_name(e, other):
        """x, y, z for an in-plane axis along one of them, −x … against it (e₂ = n × e₁ may point down: the y = c
        plane's vertical axis is −z), else e₁ or e₂"""
        i = int(np.argmax(np.abs(e)))
        return ("" if e[i] > 0 else "−") + "xyz"[i] if abs(e[i]) > 0.999 else other
    ax1, ax2 = axis_name(e1, "e₁"), axis_name(e2, "e₂")
    panels = [dict(x=p @ e1, y=p @ e2, xlabel=f"{ax1} on the plane [L]", ylabel=f"{ax2} on the plane [L]",
                   equal=True, title=f"crossing points of {plane} (upward)"),
              dict(x=(v @ e1) / speed, y=(v @ e2) / speed, xlabel=f"v·{ax1}/|v| [–]", ylabel=f"v·{ax2}/|v| [–]",
                   equal=True, xlim=(-1.05, 1.05), ylim=(-1.05, 1.05), title="direction of the centre's velocity")]
    return plotting.section_figure(panels, spin, _title(run, f"Poincaré section by {plane}", traj, rec),
                                   "spin share along the normal R√κ·ω·n/|(v, R√κ·ω)| [–]")


#: each plot kind is drawn by the function ``_<kind>`` of this module
_BUILDERS = {kind: globals()["_" + kind] for kind in KINDS if kind != "sweep"}
