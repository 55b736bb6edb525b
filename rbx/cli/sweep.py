"""``rbx sweep STUDY.yaml -o RESULTS.nc``: a parameter study (docs/studies.md; :mod:`rbx.study`, :mod:`rbx.sweeping`)."""
import shlex
import signal
import time
import warnings

import click

from .common import (Command, Progress, UserError, cannot_write, check_figure_target, display_path, duration,
                     ending_on_signals, hard_exit, parse_sets, pending_signal, plural, quiet_option, report_and_exit,
                     summary, user_errors)


@click.command(cls=Command)
@click.argument("study", metavar="STUDY.yaml", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), metavar="RESULTS.nc",
              help="The results file (NetCDF; written as RESULTS.nc.partial as points finish, renamed at the end).")
@click.option("--scheduler", metavar="ADDRESS",
              help="Run every point's trajectories on a Dask cluster: its scheduler's address (tcp://HOST:PORT) or "
                   "scheduler file (docs/cluster.md). Same numbers as a local run.")
@click.option("--resume", is_flag=True, help="Continue RESULTS.nc(.partial): compute only the missing points "
                                            "(refused if the study changed).")
@click.option("--force", is_flag=True, help="Replace an existing RESULTS.nc.")
@click.option("--trajectories", type=click.IntRange(min=1), metavar="M",
              help="Override ensemble.trajectories (the trajectories of every point).")
@click.option("--collisions", type=click.IntRange(min=1), metavar="N",
              help="Override ensemble.collisions (the collisions of every trajectory).")
@click.option("--set", "sets", multiple=True, metavar="KEY=VALUE",
              help="Change a config key of the study's base at every point, after the study's own set: (VALUE in "
                   "YAML; repeatable): --set ball.radius=0.05. Give it again with --resume.")
@quiet_option
@click.option("--debug", is_flag=True, help="Show a traceback with user errors.")
def sweep(study, output, scheduler, resume, force, trajectories, collisions, sets, quiet, debug):
    """Run the study STUDY.yaml: the observables of `measure` at every point of `vary`, an ensemble per point,
    with standard errors, into RESULTS.nc (xarray.open_dataset reads it)."""
    from ..api import StopFlag
    from ..sweeping import StudyInterrupted
    began = time.perf_counter()
    stop = StopFlag(pending=pending_signal)
    bar = Progress("sweep", delay=0.0, quiet=quiet, unit="points")       # over the whole study
    counts = []                         # (finished, total) as the study reports them: the first is where it began

    def progress(finished, total):
        counts.append((finished, total))
        bar(finished, total)
        # a signal whose KeyboardInterrupt was lost (raised inside a finaliser while a results file was read or
        # written: Python drops it) is noted on the flag: acted on after each point. A Ctrl-C during a resume of a
        # file with 20 000 attributes let the study run to the end, exit 0
        stop.check()
    checks = Progress("checking", delay=2.0, quiet=quiet, unit="configs")

    def checking(done, total):
        # a study at its grid bound checks its points' configs for minutes before the first runs: said, not silent
        if done == 0 and total >= LONG_CHECK and not quiet:
            click.echo(f"rbx: {display_path(study)}: checking {plural(total, 'config')} of its points before the "
                       "first one runs", err=True)
        checks(done, total)
        if done >= total:
            checks.close()
    interrupted = None
    try:
        if resume and force:
            raise UserError(None, "--resume", "give --resume or --force, not both")
        changes = {"sets": parse_sets(sets), "ensemble": {"trajectories": trajectories, "collisions": collisions}}
        with ending_on_signals(stop):
            try:
                ds = _sweep(study, output, scheduler, resume, force, progress, checking, changes,
                            _again(sets, trajectories, collisions))
            except StudyInterrupted as exc:
                stop.running = True     # a second signal now only notes itself: the line below is printed
                interrupted = exc
            except KeyboardInterrupt:
                # while the study was set up: a resumed study's file is as it was, and is said to be kept
                kept = _kept(output) if resume else None
                if kept is None:
                    raise
                stop.running = True
                interrupted = kept
    except UserError as exc:
        bar.close()
        report_and_exit(exc, debug)
    bar.close()
    if interrupted is not None:
        _interrupted(interrupted, stop.signum or signal.SIGINT, study, _again(sets, trajectories, collisions))
    points = int(ds["done"].size)
    if not counts or counts[0][0] == counts[0][1]:
        summary(quiet, f"nothing to do: {display_path(output)} holds all {plural(points, 'point')} of the study")
        return
    ran = counts[-1][0] - counts[0][0]
    summary(quiet, f"wrote {display_path(output)}: {plural(points, 'point')} × "
                   f"{plural(int(ds.attrs['ensemble_trajectories']), 'trajectory')} × "
                   f"{plural(int(ds.attrs['ensemble_collisions']), 'collision')}"
                   + (f" ({ran} run now, {counts[0][0]} before)" if counts[0][0] else "") +
                   f" in {duration(time.perf_counter() - began)}")


def _again(sets, trajectories, collisions):
    """The options a --resume must give again (part of the study's digest) -> list of arguments."""
    again = [a for item in sets for a in ("--set", item)]
    return again + [a for flag, v in (("--trajectories", trajectories), ("--collisions", collisions)) if v is not None
                    for a in (flag, str(v))]


def _kept(output):
    """The results file a resume would continue and what it holds -> StudyInterrupted(path, kept, total), or None."""
    import os

    from ..sweeping import StudyInterrupted, kept_points, partial_path
    for path in (partial_path(output), output):
        if os.path.exists(path):
            found, kept, total = kept_points(path)
            return StudyInterrupted(found, kept, total) if kept else None
    return None


def _interrupted(exc, signum, study, again=()):
    """The line of a study stopped by a signal: what its results file keeps and how to continue; exit 128 + signum."""
    name = signal.Signals(signum).name
    if exc.path is None or exc.kept == 0:
        click.echo(f"rbx: interrupted by {name}; no finished point to keep, nothing written", err=True)
    elif not exc.path.endswith(".partial"):
        click.echo(f"rbx: {display_path(exc.path)}: interrupted by {name}; the file holds all {exc.total} points, "
                   "as it did", err=True)
    else:
        click.echo(f"rbx: {display_path(exc.path)}: interrupted by {name} after {exc.kept} of "
                   f"{plural(exc.total, 'point')}; the file holds those {exc.kept}. Continue with: "
                   f"rbx sweep {shlex.quote(study)} -o {shlex.quote(display_path(exc.path[:-len('.partial')]))} "
                   + "".join(f"{shlex.quote(a)} " for a in again) + "--resume", err=True)
    hard_exit(128 + int(signum))


#: a study with this many configs to check before its first point runs says so first
LONG_CHECK = 10_000


def _sweep(study, output, scheduler, resume, force, progress, checking=None, changes=None, again=()):
    from ..cluster import ClusterError, SchedulerUnreachable
    from ..paths import DiskFull, last_output
    from ..study import load_study
    from ..sweeping import StudyWarning
    from ..sweeping import sweep as run
    from .common import _quiet_dask
    last_output(output)
    if scheduler is not None:
        _quiet_dask()        # Dask's own log lines of a lost connection: rbx says itself what went wrong
    with user_errors():
        try:
            with warnings.catch_warnings(record=True) as said:      # one line each, as the other commands say them
                warnings.simplefilter("always", RuntimeWarning)
                st = load_study(study, progress=checking, **(changes or {}))
            for w in said:
                click.echo(f"rbx: warning: {w.message}", err=True)
            with warnings.catch_warnings(record=True) as said:
                warnings.simplefilter("always", StudyWarning)
                ds = run(st, output, scheduler=scheduler, resume=resume, force=force, progress=progress)
            for w in said:
                if issubclass(w.category, StudyWarning):
                    click.echo(f"rbx: warning: {w.message}", err=True)
                else:       # anything else as Python would have shown it
                    warnings.showwarning(w.message, w.category, w.filename, w.lineno)
            return ds
        except SchedulerUnreachable as exc:
            raise UserError(None, "--scheduler", exc.problem) from None
        except ValueError as exc:        # an argument the library refuses, said as the user's error
            raise UserError(study, None, str(exc)) from None
        except ClusterError as exc:         # as rbx simulate says a lost cluster: one line, exit 1
            click.echo(_cluster_lost(exc, study, output, again), err=True)
            raise SystemExit(1) from None
        except DiskFull as exc:          # as rbx simulate's full disk: one line, exit 1
            click.echo(f"rbx: {exc}", err=True)
            raise SystemExit(1) from None


def _cluster_lost(exc, study, output, again):
    """The line of a study stopped by a lost cluster: what went wrong, what the results file keeps, how to go on."""
    import os

    from ..sweeping import kept_points, partial_path
    said = f"--scheduler: {exc.problem}"       # the option this command was given (the API's key is scheduler)
    path, kept, total = kept_points(partial_path(os.path.abspath(output)))
    if not kept:
        return f"rbx: {said}; the study stopped before its first point was written, nothing was kept"
    return (f"rbx: {display_path(path)}: {said}; the study stopped, the file holds the {kept} of {total} points "
            f"finished before. Continue with: rbx sweep {shlex.quote(study)} -o {shlex.quote(display_path(output))} "
            + "".join(f"{shlex.quote(a)} " for a in again) + "--resume (with --scheduler, or locally)")


# ---- rbx plot RESULTS.nc --kind sweep ---------------------------------------------------------------------------

def plot_sweep(path, kind, out, y, x, logx, logy, dpi):
    """``rbx plot RESULTS.nc --kind sweep``: the figure of :func:`sweep_panel`, written -> its path."""
    import os

    from ..paths import FileError
    from ..plotting import save, sweep_figure
    if kind != "sweep":
        raise UserError(path, "--kind", f"a study's results file is drawn with --kind sweep, not {kind}")
    ds = open_results(path)
    if not ds["done"].values.any():     # empty axes with exit 0: an empty selection is refused, as for a run
        raise UserError(path, "done", "no point of the study is done: nothing to draw (continue it with rbx sweep "
                                      "--resume)")
    try:
        panel, title = sweep_panel(ds, y, x, logx, logy, path)
        fig = sweep_figure([panel], title)
    except (ValueError, TypeError) as exc:
        # a file edited by hand in a way no check above names (a numeric key's values as text): one line, not a
        # traceback (--debug shows it)
        raise _not_written(path, None, f"cannot be drawn ({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})"
                           ) from exc
    out = out or f"{os.path.splitext(path)[0]}_sweep.png"
    check_figure_target(out)
    try:
        save(fig, out, dpi=dpi)
    except (OSError, ValueError, RuntimeError, FileError) as exc:     # RuntimeError: a format's tool missing (pgf: LaTeX)
        cannot_write(out, exc)
    return out


def open_results(path):
    """A study's results file -> xarray.Dataset (loaded), or a UserError."""
    import os
    from ..paths import FileError
    from ..sweeping import read_results
    if not os.path.exists(path):
        raise UserError(path, None, "file not found")
    try:
        ds = read_results(path)
    except FileError as exc:
        raise UserError(exc.file, exc.key, exc.problem) from None
    except Exception as exc:
        raise UserError(path, None, f"not a NetCDF file rbx sweep wrote ({str(exc).splitlines()[0]})") from None
    if "rbx_study" not in ds.attrs:
        raise UserError(path, None, "not a results file of rbx sweep")
    _check_results_attrs(ds, path)
    import json

    import numpy as np

    from ..sweeping import shown_values, value_problem
    zipped = ds.attrs.get("zip", 0)
    if not (np.ndim(zipped) == 0 and str(zipped) in ("0", "1")):     # 'maybe' ended the figure in a traceback
        raise _not_written(path, "zip", f"is {str(zipped)[:40]!r}, not 0 or 1")
    varied = json.loads(ds.attrs["varied"])
    for key in varied:
        # a point's place on the x axis: a number that is no number, or a value twice (where a study refuses it),
        # drew a figure of points that no study makes
        values = np.asarray(ds[key].values)
        if values.dtype.kind in "fc" and not np.all(np.isfinite(values)):
            raise _not_written(path, key, f"holds {shown_values(values)}, a value that is not a number")
        if str(zipped) == "0" and len(np.unique(values)) != len(values):
            raise _not_written(path, key, f"holds {shown_values(values)}, a value twice")
    dims = list(ds["done"].dims)

    def label(index):           # the point by its varied values, as a study names its points
        return ", ".join(f"{k} = {ds[k].values[int(index[dims.index(ds[k].dims[0])])]}"
                         for k in varied if ds[k].dims[0] in dims)
    problem = value_problem(ds, json.loads(ds.attrs["measure"]), label)
    if problem is not None:         # drawn, it was a traceback (a negative error bar) or a figure of impossible numbers
        raise _not_written(path, *problem)
    return ds


def _not_written(path, key, problem):
    """The refusal of a results file edited by hand (or damaged) -> :class:`UserError`."""
    return UserError(path, key, f"{problem}: the file was not written as rbx sweep writes it; run the study again")


def _check_results_attrs(ds, path):
    """The attributes a study's figure reads, checked for what they are (a file edited by hand gave a KeyError,
    JSONDecodeError, IndexError or TypeError traceback): ``measure`` and ``varied`` JSON lists of the file's
    variables, ``done`` and ``wall_time`` present, the ensemble's size whole numbers."""
    import json

    import numpy as np

    def bad(key, problem):
        raise _not_written(path, key, problem)
    for key in ("measure", "varied"):
        try:
            names = json.loads(ds.attrs[key])
        except KeyError:
            bad(key, "missing")
        except (TypeError, ValueError, RecursionError):     # RecursionError: '[' nested 100 000 deep
            bad(key, f"is not a JSON list ({str(ds.attrs[key])[:40]!r})")
        if not (isinstance(names, list) and names and all(isinstance(n, str) for n in names)):
            bad(key, f"is not a list of names ({str(ds.attrs[key])[:40]!r})")
        missing = [n for n in names if n not in ds.variables]
        if missing:
            bad(key, f"names '{missing[0]}', which the file does not hold")
        dims = [ds[n].ndim for n in names]
        if key == "varied" and any(d != 1 for d in dims):
            bad(key, f"names '{names[dims.index(next(d for d in dims if d != 1))]}', which is not a coordinate")
        if key == "measure" and any(d == 0 for d in dims):
            bad(key, f"names '{names[dims.index(0)]}', which holds no value per point")
    for name in ("done", "wall_time"):
        if name not in ds.data_vars:
            bad(name, "missing")
        if ds[name].dtype.kind not in "iufb":
            bad(name, f"holds {ds[name].dtype} values, not numbers")
    for key in ("ensemble_trajectories", "ensemble_collisions", "ensemble_orbits"):
        value = ds.attrs.get(key, 1)            # ensemble_orbits: files written before it have none
        if not (isinstance(value, (int, np.integer)) and not isinstance(value, bool) and value >= 1):
            bad(key, f"is not a whole number ≥ 1 ({value!r})")


#: at most this many lines get a legend entry each; more are coloured along a colour bar of their key's values
MAX_LEGEND_LINES = 10
#: the most characters of a line of the title a results file holds that the study plot draws
TITLE_LINE = 200


def sweep_panel(ds, y=None, x=None, logx=False, logy=False, path=None, label=None):
    """The panel spec of :func:`rbx.plotting.sweep_figure` for variable ``y`` (default: the first measured)
    against the varied key ``x`` (default: the first), one line per value of a second varied key (or of the
    variable's own extra dimension, such as wall), error bars from ``<y>_stderr`` or the Wilson bounds
    ``<y>_low``/``<y>_high``, the reference companions (Santaló's, Kac's value: :func:`rbx.observables.references`)
    dashed, and a note saying why where finished points hold no value -> (panel, title)."""
    import json

    import numpy as np

    from ..observables import caveats, error_bars, expected_line, missing_reason, parameter_label, variable_label
    from ..observables import references as reference_names
    varied = json.loads(ds.attrs["varied"])
    measured = json.loads(ds.attrs["measure"])
    y = y or measured[0]
    if y not in ds.data_vars or y.endswith("_stderr") or y in ("done", "seed"):
        choices = [v for v in ds.data_vars if not v.endswith("_stderr") and v not in ("done", "seed")]
        raise UserError(path, "--y", f"no variable '{y}' in this study (variables: {', '.join(choices)})")
    x = x or varied[0]
    if x not in varied:
        raise UserError(path, "--x", f"'{x}' was not varied (varied: {', '.join(varied)})")
    var = ds[y]
    xdim = ds[x].dims[0]
    other = [d for d in var.dims if d != xdim]
    if len(other) > 1:
        raise UserError(path, "--y", f"{y} has {len(other) + 1} dimensions ({', '.join(var.dims)}): one line per "
                                     "value of one other is drawn; select with a study of fewer keys")
    unit = var.attrs.get("units", "")
    xunit = ds[x].attrs.get("units", "")
    ylabel, ysym = variable_label(y, unit)             # symbols and units from the registry: 'λ₁ [1/T]'
    xlabel, _ = parameter_label(x, xunit)            # a known config key as a symbol: 'κ'
    if other and other[0] in varied:
        osym = parameter_label(other[0])[1]
    else:
        osym = other[0] if other else None
    xs = ds[x].values
    done = ds["done"]
    series, references = [], []

    def error(sel):
        if f"{y}_low" in ds and f"{y}_high" in ds:
            v = var.isel(sel).values
            return np.vstack([v - ds[f"{y}_low"].isel(sel).values, ds[f"{y}_high"].isel(sel).values - v])
        return ds[f"{y}_stderr"].isel(sel).values if f"{y}_stderr" in ds else None

    def pick(array, sel):
        return array.isel({d: i for d, i in sel.items() if d in array.dims}).values.reshape(-1)

    # dashed beside the points: the values of the same quantity to compare with (Santaló's, Kac's), as the
    # observable's record marks them; a share, a flag or a statistic in the same unit is not one
    dashed = [c for c in reference_names(y) if c in ds.data_vars]
    lines = [{}] if not other else [{other[0]: i} for i in range(ds.sizes[other[0]])]
    # many lines: coloured along a colour bar of the second key's values, not a legend entry each (41 entries
    # collapsed the figure's layout)
    shaded = len(lines) > MAX_LEGEND_LINES and np.asarray(ds[other[0]].values).dtype.kind in "iuf"
    for k, sel in enumerate(lines):
        keep = pick(done, sel).astype(bool)
        err = error(sel)
        if err is not None:
            err = err[..., keep]
        name = f"{osym} = {_fmt(ds[other[0]].values[sel[other[0]]])}" if other else (label or ysym)
        line = {"x": xs[keep], "y": pick(var, sel)[keep], "err": err, "label": None if shaded else name}
        if shaded:
            line["shade"] = float(ds[other[0]].values[sel[other[0]]])
        series.append(line)
        for comp in dashed:
            c = ds[comp]
            # one grey line where the reference is the same beside every line (Santaló's value does not depend on
            # κ), else one per line in its colour (the largest drift of each)
            shared = not other or other[0] not in c.dims or all(
                np.array_equal(pick(c, {other[0]: 0}), pick(c, {other[0]: i}), equal_nan=True)
                for i in range(ds.sizes[other[0]]))
            if set(c.dims) <= set(var.dims) and (k == 0 or not shared):
                words = variable_label(comp, units=False)[0]
                ref = {"x": xs[keep], "y": pick(c, sel)[keep], "label": words if k == 0 else None,
                       "color": "0.3" if shared else f"C{k}"}
                if shaded and not shared:       # in its line's colour along the bar; the legend says so in grey
                    ref.update(shade=line["shade"], label=None)
                    if k == 0:
                        references.append({"x": [], "y": [], "label": f"{words} (each in its line's colour)",
                                           "color": "0.3"})
                references.append(ref)
    if expected_line(y) is not None:         # a ratio to a closed form: 1 where the closed form holds
        value, words = expected_line(y)
        references.append({"x": None, "y": value, "label": words, "color": "0.3"})
    M, N = ds.attrs["ensemble_trajectories"], ds.attrs["ensemble_collisions"]
    seconds = float(np.nansum(ds["wall_time"].values))
    panel = {"series": series, "references": references, "xlabel": xlabel, "ylabel": ylabel, "logx": logx,
             "logy": logy}
    if shaded:
        panel["shade_label"] = parameter_label(other[0])[0] if other[0] in varied else other[0]
    notes = []
    if any(s["err"] is not None and np.any(np.asarray(s["err"]) > 0) for s in series) and error_bars(y):
        notes.append(error_bars(y))            # what a bar is, from the observable's record
    finished = done.values.astype(bool)
    values = np.asarray(var.values, float).reshape(finished.shape + (-1,))
    empty = int(np.sum(finished & ~np.any(np.isfinite(values), axis=-1)))
    if empty:                                   # points that ran but hold no number: a gap says why
        why = missing_reason(y) or "no value"
        notes.append(f"{empty} of {int(finished.sum())} points: {why}")
    for flag, text in caveats(y):               # points whose value is not what the name promises
        if flag in ds:
            off = int(np.sum(finished & (np.asarray(ds[flag].values, float).reshape(finished.shape) == 0)))
            if off:
                notes.append(f"{off} of {int(finished.sum())} points: {text}")
    # what a point's value pools and where the coefficient is no coefficient: legend lines beside the bars they
    # explain (in the title they made it five or six lines above a panel)
    if y == "lyapunov" or y.startswith("lyapunov_per_collision") or y.startswith("lyapunov_spectrum"):
        notes.append(pooled_note(ds, ysym, int(M)))
    note = horizon_note(ds, y)
    if note:
        notes.append(note)
        panel["ylabel"] = ylabel.replace("diffusion coefficient", "slope of the MSD (no coefficient)")
    if notes:
        # wrapped to the width of a panel: one long line ran off both edges, and beside a colour bar it squeezed the
        # axes to nothing (matplotlib: 'constrained_layout not applied')
        import textwrap
        panel["note"] = "\n".join(textwrap.fill(n, 70, subsequent_indent="  ") for n in notes)
    orbits = int(ds.attrs.get("ensemble_orbits", M))
    ensemble = plural(int(M), "trajectory")
    if orbits < M:      # fixed starts, no random numbers: the bars are the spread of copies (rbx sweep warned)
        ensemble += f" (copies of {plural(orbits, 'orbit')})"
    # the axes name what is drawn against what; the title says what was run
    # the file's title as rbx writes it: two lines of a few dozen characters. Cut to that: a crafted title of 10 MB
    # held matplotlib for minutes, 5 GB resident, past SIGTERM
    from ..paths import shortened
    written = "\n".join(shortened(line, TITLE_LINE) for line in str(ds.attrs.get("title", "")).split("\n", 2)[:2])
    title = (f"{written}\n{ensemble} × {plural(int(N), 'collision')} per point · "
             f"{int(done.values.sum())} of {done.size} points · {duration(seconds)} computing them")
    return panel, title


def horizon_note(ds, y):
    """Where the gas has free corridors (``diffusion_horizon`` > 0: an infinite horizon), the mean-square
    displacement grows as t·log t and a point's ``diffusion`` is the slope over its segments, not a coefficient ->
    one line for the title, or '' (the study plot said 'diffusion coefficient' with error bars on such a gas)."""
    import numpy as np
    if not y.startswith("diffusion") or "diffusion_horizon" not in ds:
        return ""
    done = ds["done"].values.astype(bool)
    width = ds["diffusion_horizon"].values[done]
    open_points = int(np.sum(width > 0))
    if not open_points:
        return ""
    return (f"not a diffusion coefficient at {open_points} of {int(done.sum())} points: free corridors (up to "
            f"{float(width.max()):.3g} wide) make the horizon infinite and the MSD grow as t·log t; drawn: the slope "
            "over the segments")


def pooled_note(ds, ysym, M):
    """What a point's λ₁ is an average of, as the results file lets one say it: every orbit of the point pooled,
    regular and chaotic alike, and how many were regular (``lyapunov_regular`` of ``lyapunov_orbits``, or the
    ``regular_share`` measured beside it) -> one line for the title. (``rbx lyapunov`` says it; the plot did not.)"""
    import numpy as np
    done = ds["done"].values.astype(bool)
    points = int(done.sum())
    pooled = f"{ysym} pools each point's {plural(M, 'orbit')}"
    if "lyapunov_orbits" in ds and "lyapunov_regular" in ds:
        measured = ds["lyapunov_orbits"].values[done]
        regular = ds["lyapunov_regular"].values[done]
        thr = float(ds["lyapunov_regular"].attrs.get("threshold", np.nan))
        fewer = int(np.sum(measured < M))
        if points and not np.any(measured > 0):     # "only 0–0 …; none is regular" said of no orbit at all
            return f"no point has an orbit that stayed past its warm-up: {ysym} is measured nowhere"
        if fewer:
            low, high = int(measured.min()), int(measured.max())
            pooled += (f" (at {fewer} of {points} points only {low if low == high else f'{low}–{high}'}: the "
                       "others left the table first)")
        mixed = int(np.sum(regular > 0))
        if not mixed:
            return f"{pooled}; none is regular (own {ysym} < {thr:g})"
        share = regular / np.maximum(measured, 1)
        return (f"{pooled}, regular and chaotic alike: {mixed} of {points} points have regular ones (own {ysym} < "
                f"{thr:g}), up to {100 * float(share.max()):.0f}% of their orbits")
    if "regular_share" in ds:
        share = ds["regular_share"].values[done]
        share = share[np.isfinite(share)]
        mixed = int(np.sum(share > 0))
        if not mixed:
            return f"{pooled}; none is regular (regular_share 0)"
        return (f"{pooled}, regular and chaotic alike: {mixed} of {share.size} points have regular ones, up to "
                f"{100 * float(share.max()):.0f}% of their orbits")
    return f"{pooled}, regular and chaotic alike (how many were regular: measure regular_share)"


def _fmt(v):
    try:
        return f"{float(v):.4g}"
    except (TypeError, ValueError):
        return str(v)
