"""``rbx histogram CONFIG``: the invariant-measure experiment (paper §2.7, docs/reference.md §4).

It writes two files: the figure (``-o FIG.png``) and the return angles in HDF5 (``--data OUT.h5``; by default
``output.path``, as before, or FIG.h5 beside the figure when the config has none). ``output.path`` is also where
``rbx simulate`` writes the same config's run: a file holding such a run (or a study's results) is never replaced,
not even with ``--force`` (:func:`rbx.paths.other_commands_file`): ``--data`` names another file."""
import os
import time

import click

from .common import (Command, Progress, UserError, cannot_write, check_cluster_options, check_figure_target,
                     check_memory, connect, display_path, duration, ending_on_signals, parse_sets, pending_signal,
                     plural, quiet_option, report_and_exit, set_option, summary, user_errors, written)


@click.command(cls=Command)
@click.argument("config", type=click.Path(dir_okay=False))
@click.option("-o", "--output", "out", type=click.Path(dir_okay=False),
              help="Figure to write (default: the HDF5 file's name with .png).")
@click.option("--data", "data", metavar="OUT.h5", type=click.Path(dir_okay=False),
              help="HDF5 file of the return angles (default: output.path, else FIG.h5 beside -o FIG.png). A run of "
                   "rbx simulate is never replaced, even with --force.")
@click.option("--trajectories", type=int, help="Override run.trajectories (the number of samples).")
@click.option("--seed", type=int, help="Override run.seed.")
@set_option
@click.option("--force", is_flag=True, help="Overwrite existing output files.")
@click.option("--scheduler", metavar="ADDRESS",
              help="Follow the samples on the workers of a Dask cluster: its scheduler's address (tcp://HOST:PORT) "
                   "or scheduler file (docs/cluster.md). Same results as a local run.")
@click.option("--slices", type=click.IntRange(min=1), metavar="N",
              help="With --scheduler: tasks per round (default: 4 per worker thread).")
@click.option("--task-collisions", "task_collisions", type=click.IntRange(min=1), metavar="N",
              help="With --scheduler: collisions one task makes.")
@quiet_option
@click.option("--debug", is_flag=True, help="Show a traceback with user errors.")
def histogram(config, out, data, trajectories, seed, sets, force, scheduler, slices, task_collisions, quiet, debug):
    """Test the invariance of the billiard measure (paper §2.7): return angles against cos φ·sin^(d−2) φ.

    Samples run.trajectories states from the billiard measure on the wall of initial: {sample: billiard, wall:
    NAME}, follows each until it returns to that wall (at most run.collisions collisions), writes the return
    angles to returns/angle in --data (default: output.path), prints the Kolmogorov–Smirnov statistic and p-value
    and draws the histogram against the predicted density."""
    from ..api import StopFlag
    cluster = {"scheduler": scheduler, "slices": slices, "task_collisions": task_collisions}
    began = time.perf_counter()
    # SIGINT/SIGTERM: KeyboardInterrupt while setting up and drawing; while the trajectories run, a flag polled
    # between blocks, so that no exception is raised while the main thread waits on the kernels' threads (one
    # full-suite run hung there for 120 s after Ctrl-C, its worker threads idle)
    stop = StopFlag(pending=pending_signal)
    try:
        with ending_on_signals(stop):
            _histogram(config, out, data, trajectories, seed, sets, force, quiet, cluster, began, stop)
    except UserError as exc:
        report_and_exit(exc, debug)


def _data_path(data, out, cfg, config):
    """Where the return angles go -> (path, the key it came from: --data, output.path or -o)."""
    if data is not None:
        if not data.strip():
            raise UserError(None, "--data", "an empty file name (give OUT.h5)")
        return os.path.abspath(os.path.expanduser(data)), "--data"
    if cfg.output.path is not None:
        return cfg.output.path, "output.path"
    if out:
        return os.path.splitext(os.path.abspath(out))[0] + ".h5", "-o"
    raise UserError(config, "output.path", "no output file: give output.path in the config, --data OUT.h5 or "
                                           "-o FIG.png")


def _check_data_target(path, key, force, cfg, config):
    """The return angles may replace an existing file only with --force (as the figure), never the config or a
    file it includes, and never another command's file, a run of ``rbx simulate`` above all, with or without
    --force (:func:`rbx.paths.other_commands_file`): the two commands share output.path, and --force once replaced a
    simulation this way."""
    from ..driver import check_target
    file = config if key == "output.path" else None
    with user_errors():
        check_target(path, force, key, file=file, config_source=(cfg.source,) + tuple(cfg.includes),
                     force_hint="--force", mine="returns")


def _histogram(config, out, data, trajectories, seed, sets, force, quiet, cluster, began, stop):
    from .. import config as cfgmod
    from .. import plotting
    from ..analysis import scene_title
    from ..cluster import ClusterError
    from ..histogram import exit_problem, return_experiment
    from ..driver import check_size, returns_bytes, write_returns
    from ..paths import NO_ROOM, DiskFull, FileError, written_whole

    check_cluster_options(cluster)

    overrides = {k: v for k, v in (("trajectories", trajectories), ("seed", seed)) if v is not None}
    changes = parse_sets(sets)
    with user_errors():
        cfg = cfgmod.load(config, overrides, changes=changes, label="--set")
    check_memory(cfg, overrides, "histogram")
    if cfg.initial[0] != "sample":
        raise UserError(config, "initial", "rbx histogram samples its states: use initial: {sample: billiard, "
                                           "wall: NAME}")
    problem = exit_problem(cfg)
    if problem:
        raise UserError(config, "initial.wall" if cfg.initial[1] is not None else "initial", problem)
    h5_path, key = _data_path(data, out, cfg, config)
    fig_path = os.path.abspath(out) if out else os.path.splitext(h5_path)[0] + ".png"
    if fig_path == h5_path:
        raise UserError(None, "--data", f"{display_path(h5_path)} is the figure too: give the figure -o another name")
    _check_data_target(h5_path, key, force, cfg, config)
    with user_errors():       # output.max_size and the free space, before the samples are drawn (as rbx simulate)
        check_size(cfg, h5_path, need=returns_bytes(cfg), what=f"{plural(cfg.run.trajectories, 'sample')}' return "
                   "angles", option="--set output.max_size=", hint="; free some space, or write the return angles "
                   "to another disk with --data")
    for source, what in ((config, "the config"), *((f, "a file the config includes") for f in cfg.includes)):
        # never offered --force for it (which then refused it as no figure)
        if source and os.path.isfile(source) and os.path.exists(fig_path) and os.path.samefile(fig_path, source):
            raise UserError(fig_path, "-o", f"is {what}: give the figure a name of its own, such as histogram.png")
    if os.path.exists(fig_path) and not force:
        raise UserError(fig_path, None, "exists; use --force to overwrite it")
    # where the figure goes, as rbx plot -o: no folder made, no link written through, only a figure replaced; and
    # both files' folders writable: found before the samples are drawn, not after (they were lost)
    check_figure_target(fig_path)
    for path, name in ((h5_path, key), (fig_path, "-o")):
        if not os.path.isdir(os.path.dirname(path)):
            raise UserError(path, None, f"the folder {display_path(os.path.dirname(path))} does not exist (rbx "
                                        f"makes no folders: create it first, or give {name} another path)")
        if not os.access(os.path.dirname(path), os.W_OK):
            raise UserError(path, None, f"its folder {display_path(os.path.dirname(path))} cannot be written (a "
                                        f"read-only file system, or no permission): give {name} in a writable "
                                        "folder")

    with connect(cluster) as on:
        progress = Progress("histogram", quiet=quiet, trajectories=cfg.run.trajectories)
        try:
            result = return_experiment(cfg, progress=progress, cluster=on, should_stop=stop,
                                       on_run=stop.start_running)
        except ClusterError as exc:     # the cluster failed mid-run: not the user's input, exit 1
            click.echo(f"rbx: {exc}; nothing written", err=True)
            raise SystemExit(1) from None
        finally:
            stop.running = False        # a signal from here on aborts at once again
            progress.close()
    stop.check()        # a signal while the last block ran was noted, not acted on: it wrote both files, exit 0
    if len(result.angle) == 0:       # nothing to compare: neither an empty list of angles nor a figure is written
        raise UserError(config, "run.collisions",
                        f"no sample returned within {plural(cfg.run.collisions, 'collision')}: nothing to compare, "
                        "nothing written; raise run.collisions")
    if not os.path.isdir(os.path.dirname(h5_path)):     # it was there at the start: removed since, not remade
        click.echo(f"rbx: {display_path(h5_path)}: its folder {display_path(os.path.dirname(h5_path))} is gone "
                   "(removed while the samples were drawn?): nothing was saved", err=True)
        raise SystemExit(1)
    names = cfg.wall_names
    wall = "the whole boundary (next collision)" if result.wall is None else f"wall '{names[result.wall]}'"
    title = scene_title(cfg)
    fig = plotting.histogram_figure(result.angle, result.d, result.ks_statistic, result.ks_pvalue,
                                    f"{title}\nreturn angles to {wall}: {len(result.angle)} of {result.samples} "
                                    f"billiard-measure samples", not_returned=result.not_returned)

    def save_samples():
        try:
            with user_errors():     # a lock that cannot be made, a file of another kind: one line
                write_returns(h5_path, cfg, result, replace=force)
            written(f"{display_path(h5_path)} (the samples), not the figure")
        except OSError as exc:
            if exc.errno in NO_ROOM:     # not the user's input: the disk filled meanwhile (or a size limit), exit 1
                why = exc.strerror if isinstance(exc, DiskFull) else (     # rbx's own says it already
                    f"{exc.strerror}: no room on the disk (or a size limit, ulimit -f?)")
                click.echo(f"rbx: {display_path(h5_path)}: cannot write: {why}; nothing was saved", err=True)
                raise SystemExit(1) from None
            raise UserError(h5_path, None, f"cannot write: {exc.strerror or exc}") from None

    # The figure is drawn beside its name first; the samples are put in place once it is drawn, then the figure:
    # the two renames follow each other. Put in place before the figure was drawn (seconds), the samples of a run
    # killed meanwhile stood beside the figure of the run before (--force), and nothing said so.
    saved = False
    try:
        with written_whole(fig_path, replace=force) as tmp:
            try:
                fig.savefig(tmp, dpi=150)
            except (OSError, ValueError, RuntimeError) as exc:  # RuntimeError: a format's tool missing (pgf: LaTeX)
                save_samples()
                saved = True
                raise exc from None     # the figure's new name is removed; the samples are kept
            save_samples()
            saved = True
            stop.check()    # a signal while the samples were put in place, acted on now that they are there
    except (OSError, ValueError, RuntimeError, FileError) as exc:
        if not saved:           # the figure's name could not be made: the samples are saved all the same
            save_samples()
        # where they are kept, and what reads them (no plot kind draws return angles)
        cannot_write(fig_path, exc, kept=f"the samples are kept in {display_path(h5_path)} (returns/angle; "
                                         "rbx.reader.read_returns reads them)")

    d = result.d
    click.echo(f"{result.samples} samples on {wall}, {result.samples - result.not_returned} returned "
               f"in {result.seconds:.2f} s")
    if result.not_returned:
        click.echo(f"rbx: warning: {plural(result.not_returned, 'trajectory')} did not return within "
                   f"{plural(cfg.run.collisions, 'collision')} (run.collisions); "
                   f"{'it is' if result.not_returned == 1 else 'they are'} left out", err=True)
    law = f"Kolmogorov–Smirnov against the law of the billiard measure (density {plotting.density_name(d)}, d = {d})"
    if result.not_returned:          # the slow returns are missing: a p-value would test the truncation
        click.echo(f"{law}: not valid, no p-value: "
                   f"{plotting.censored_note(result.not_returned, result.samples)}")
    else:
        click.echo(f"{law}: D = {result.ks_statistic:.4g}, p = {result.ks_pvalue:.4g}")
    summary(quiet, f"wrote {display_path(h5_path)} (returns/angle) and {display_path(fig_path)}: {result.samples} "
                   f"samples in {duration(time.perf_counter() - began)}")
