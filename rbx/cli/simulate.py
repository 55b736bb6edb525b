"""``rbx simulate CONFIG`` and ``rbx simulate --resume RUN.h5``: run an experiment into HDF5 (docs/reference.md
§4–5).

Two phases. *Setting up* (validate, allocate, compile the kernels: no file written yet): SIGINT, SIGTERM and SIGHUP
abort at once, with nothing to save. *Running*: the run writes ``OUT.h5.partial`` and these signals only set a flag that
the run polls between blocks (each well under a second of work, and the kernels hold no GIL), so the file is
checkpointed and closed cleanly. Either way the run ends by renaming ``OUT.h5.partial`` to ``OUT.h5``, marked
``complete = false`` unless it finished, and an interrupted command exits with 128 + the signal number (130,
143). An existing ``OUT.h5`` is replaced only with ``--force``. ``--resume`` continues such a file to its
requested length and writes the same records as an uninterrupted run.
"""
import os
import signal
import time

import click

from .common import (Command, Progress, UserError, check_cluster_options, check_memory, connect, display_path,
                     duration, hard_exit, parse_sets, pending_signal, quiet_option, report_and_exit, set_option,
                     setup_note, summary, user_errors, warn_repeated, watch_compiles)

OVERRIDES = ("collisions", "trajectories", "seed")


@click.command(cls=Command)
@click.argument("config", required=False)
@click.option("-o", "--output", "out", metavar="OUT.h5", help="HDF5 file to write (default: output.path).")
@click.option("--collisions", type=int, help="Override run.collisions.")
@click.option("--trajectories", type=int, help="Override run.trajectories.")
@click.option("--seed", type=int, help="Override run.seed.")
@set_option
@click.option("--max-size", "max_size", metavar="SIZE",
              help="Largest file the run may write (e.g. 50GB; default: output.max_size, 10 GiB).")
@click.option("--resume", metavar="RUN.h5",
              help="Continue the interrupted run in RUN.h5 to its requested length (in place, or into -o).")
@click.option("--force", is_flag=True, help="Overwrite an existing output file.")
@click.option("--scheduler", metavar="ADDRESS",
              help="Run the trajectories on the workers of a Dask cluster: its scheduler's address (tcp://HOST:PORT) "
                   "or scheduler file (docs/cluster.md). Same results as a local run.")
@click.option("--slices", type=click.IntRange(min=1), metavar="N",
              help="With --scheduler: tasks per round (default: 4 per worker thread).")
@click.option("--task-collisions", "task_collisions", type=click.IntRange(min=1), metavar="N",
              help="With --scheduler: collisions one task makes (default: 2e8, fewer for tables of many walls).")
@quiet_option
@click.option("--debug", is_flag=True, help="Show a traceback with user errors.")
def simulate(config, out, collisions, trajectories, seed, sets, max_size, resume, force, scheduler, slices,
             task_collisions, quiet, debug):
    """Run the experiment CONFIG (YAML) and write its trajectories to HDF5."""
    from ..api import StopFlag
    from ..paths import DiskFull

    began = time.perf_counter()
    stop = StopFlag(pending=pending_signal)
    overrides = {"collisions": collisions, "trajectories": trajectories, "seed": seed, "max_size": max_size}
    cluster = {"scheduler": scheduler, "slices": slices, "task_collisions": task_collisions}
    # the handlers go in first, so that Ctrl-C while numba loads is a clean stop too, never a traceback
    with stop.installed():
        try:
            stop.check()            # a signal noted before the handlers were in
            with user_errors():
                check_cluster_options(cluster)
                if resume is not None:
                    if sets:
                        raise UserError(None, "--set", "cannot be changed when resuming: the run continues with the "
                                                       "settings stored in its file")
                    code = _resume(config, resume, out, overrides, force, quiet, stop, cluster, began)
                else:
                    code = _simulate(config, out, overrides, parse_sets(sets), force, quiet, stop, cluster, began)
        except UserError as exc:
            report_and_exit(exc, debug)
        except DiskFull as exc:
            # no room for the lock or the copy a resume starts from: nothing of the run was written
            click.echo(f"rbx: {exc}; nothing was written", err=True)
            code = 1
        except (KeyboardInterrupt, Exception) as exc:
            # KeyboardInterrupt: raised by StopFlag only while setting up, before any file is written. Another
            # error after a signal: the KeyboardInterrupt raised inside a callback of Numba's compiler is lost
            # there, and the compile fails later ("RuntimeError: no compiled object yet", 1 in ~20 tries)
            if not (isinstance(exc, KeyboardInterrupt) or (stop.signum and not stop.running)):
                raise
            click.echo(f"rbx: interrupted by {signal.Signals(stop.signum or signal.SIGINT).name} before the run "
                       "started; nothing written", err=True)
            code = -(128 + (stop.signum or signal.SIGINT))
    if code is not None and code < 0:
        # a compile stopped midway: Python's exit ran Numba's and LLVM's finalisers on it and crashed (exit −11
        # after the line, 1 in ~8 tries at random instants); here, after the except block, the simulation it set
        # up is gone and its locks with it
        hard_exit(-code)
    if code:
        raise SystemExit(code)


def _simulate(config, out, overrides, changes, force, quiet, stop, cluster, began):
    from .. import config as cfgmod
    from ..driver import run_to_file
    from ..driver import check_size, check_target
    from ..paths import last_output
    from ..simulation import Simulation

    if config is None:
        raise UserError(None, "CONFIG", "missing: give an experiment config (YAML), or --resume RUN.h5")
    if out is not None and not out.strip():
        raise UserError(None, "-o", "an empty file name (give OUT.h5, or leave -o out to use output.path)")
    if out is not None and out.endswith(("/", os.sep)):
        raise UserError(None, "-o", f"'{out}' names a folder; give a file name such as {out.rstrip('/')}/run.h5")
    cfg = cfgmod.load(config, overrides, changes=changes, label="--set")
    path = os.path.abspath(os.path.expanduser(out)) if out else cfg.output.path
    if path is None:
        raise UserError(config, "output.path", "no output file: give output.path in the config or -o OUT.h5")
    key = "-o" if out else "output.path"
    check_memory(cfg, overrides)
    check_target(path, force, key, file=None if out else cfg.source, force_hint="--force",
                 config_source=(cfg.source,) + tuple(cfg.includes))
    check_size(cfg, path, (None, "--max-size") if overrides["max_size"] is not None else None, option="--max-size")
    last_output(path)
    with connect(cluster) as on:           # first: an unreachable scheduler is said before any work
        try:
            sim = Simulation(cfg)
        except MemoryError:
            file, key = (None, "--trajectories") if overrides["trajectories"] else (cfg.source, "run.trajectories")
            raise UserError(file, key, f"{cfg.run.trajectories} trajectories do not fit in the free memory") \
                from None
        sim.cluster = on
        warn_repeated(cfg, overrides, changes)       # after every refusal: a user error stays one line
        watch_compiles()
        sim.compile_kernels()
        if stop.start_running():
            raise KeyboardInterrupt
        return _execute(sim, path, stop, quiet, 0,
                        lambda **how: run_to_file(sim, path, force=force, force_hint="--force", **how), began)


def _resume(config, run_file, out, overrides, force, quiet, stop, cluster, began):
    """``--resume RUN``: the library's resume (:func:`rbx.driver.prepare_resume`, :func:`rbx.driver.resume_to_file`,
    which :func:`rbx.resume` calls too), with the command's lines and exit codes."""
    from ..driver import prepare_resume, resume_to_file

    if config is not None:
        raise UserError(None, "--resume", "give either CONFIG or --resume RUN.h5, not both")
    for name in OVERRIDES:
        if overrides[name] is not None:
            raise UserError(None, f"--{name}", "cannot be changed when resuming: the run continues with the "
                                               "settings stored in its file")
    r = prepare_resume(run_file, out, force=force, max_size=overrides["max_size"])
    shown = display_path(r.source)
    for note in r.notes:
        click.echo(f"rbx: {shown}: warning: {note}", err=True)
    if r.state == "complete":
        click.echo(f"rbx: {shown}: the run is complete; nothing to resume", err=True)
        return 0
    if r.state == "renamed":
        click.echo(f"rbx: {shown}: the run was complete (stopped before its rename): renamed to "
                   f"{display_path(r.path)}", err=True)
        return 0
    with connect(cluster) as r.sim.cluster:
        watch_compiles()
        r.sim.compile_kernels()
        if stop.start_running():
            raise KeyboardInterrupt
        return _execute(r.sim, r.path, stop, quiet, r.done, lambda **how: resume_to_file(r, **how), began)


def _execute(sim, path, stop, quiet, done, start, began):
    """Run ``sim`` into ``path`` with ``start(progress=, should_stop=, report=)`` (:func:`rbx.driver.run_to_file`
    for a new run, :func:`rbx.driver.resume_to_file` for a resumed one: the same code as the API) -> exit code. A run
    that finished ends with the summary line (unless ``quiet``); ``began``: when the command started.

    The file is renamed from ``.partial`` to ``path`` however the run ends (complete, interrupted, or an
    unexpected error), so ``path`` always holds every record computed so far, and ``complete`` says whether that
    is all of them (docs/reference.md §4)."""
    from ..cluster import ClusterError
    from ..paths import NOT_WRITABLE, DiskFull, temporary_path
    from ..simulation import NonFiniteState

    progress = Progress("simulate", quiet=quiet, start=done, trajectories=sim.M)
    complete = False
    failure = None
    notes = []
    try:
        # the notes of the run's last steps (where its records are kept) are said after the run; a run that failed
        # says where its records are in its own line, and a note of that failure's consequence (the rename of its
        # unfinished file, refused by the same read-only folder) would come first and name no cause
        complete = start(progress=progress, should_stop=stop, report=notes.append)
    except (OSError, ClusterError, NonFiniteState) as exc:   # disk full, file system gone, cluster lost, NaN
        failure = exc
    finally:
        progress.close()
    for note in notes if failure is None else ():
        click.echo(f"rbx: {note}", err=True)
    if failure is not None:
        where = temporary_path(path) if os.path.exists(temporary_path(path)) else path
        if isinstance(failure, ClusterError):
            click.echo(f"rbx: {display_path(where)}: {failure}; the run stopped, the file holds every record up to "
                       "its last checkpoint (complete = false). Continue with: "
                       f"rbx simulate --resume {display_path(where)} (with --scheduler, or locally)", err=True)
        elif isinstance(failure, NonFiniteState):
            click.echo(f"rbx: {display_path(where)}: {failure}; the run stopped, the file holds every record up to "
                       "its last checkpoint (complete = false)", err=True)
        elif isinstance(failure, DiskFull) and not os.path.exists(where):
            click.echo(f"rbx: {display_path(where)}: {failure}; nothing was saved (the run stopped before its file "
                       "was made)", err=True)
        elif isinstance(failure, DiskFull):
            click.echo(f"rbx: {display_path(where)}: {failure}; the run stopped, the file holds every record up to "
                       "its last checkpoint (complete = false). Free some space, then continue with: "
                       f"rbx simulate --resume {display_path(where)} (or continue it on another disk: add -o "
                       "with a file there)", err=True)
        elif not os.path.isdir(os.path.dirname(os.path.abspath(where))):
            click.echo(f"rbx: {display_path(where)}: its folder {display_path(os.path.dirname(where) or '.')} is "
                       "gone (removed while the run wrote?): nothing was saved", err=True)
        elif not os.path.exists(where):
            click.echo(f"rbx: {display_path(where)}: writing failed: {failure.strerror or failure}; nothing was "
                       "saved (the run stopped before its file was made)", err=True)
        else:
            denied = getattr(failure, "errno", None) in NOT_WRITABLE
            click.echo(f"rbx: {display_path(where)}: writing failed: {failure.strerror or failure}"
                       + (" (its folder can no longer be written?)" if denied else "")
                       + "; the file holds every record up to its last checkpoint (complete = false). "
                       + ("Once it can be written, continue" if denied else "Continue")
                       + f" with: rbx simulate --resume {display_path(where)}", err=True)
        return 1
    if not complete:
        made = int(sim.ncoll[sim.alive].min()) if sim.alive.any() else sim.cfg.run.collisions
        where = temporary_path(path) if os.path.exists(temporary_path(path)) else path   # kept apart: see stream
        click.echo(f"rbx: {display_path(where)}: interrupted by {signal.Signals(stop.signum).name} after {made} of "
                   f"{sim.cfg.run.collisions} collisions; the file holds every record so far (complete = false). "
                   f"Continue with: rbx simulate --resume {display_path(where)}", err=True)
        return 128 + stop.signum
    ran = time.perf_counter() - progress.start
    N = sim.cfg.run.collisions
    ended = int((~sim.alive & (sim.ncoll < N)).sum())
    summary(quiet, f"wrote {display_path(path)}: {sim.M} trajector{'y' if sim.M == 1 else 'ies'} × {N} collisions"
                   + (f" (resumed at {done})" if done else "")
                   + (f", {ended} of them ended earlier ({'an exit or ' if sim.rules.uses_exit else ''}no wall "
                      "ahead)" if ended else "")
                   + f" in {duration(ran)} ({setup_note(progress.start - began)})")
    if ended and sim.geom.lattice is not None and not sim.rules.uses_exit:
        # a closed gas has no escape: a flight that met no scatterer within MAX_PERIODIC_FLIGHT cells was ended
        from ..geometry import MAX_PERIODIC_FLIGHT
        click.echo(f"rbx: warning: {display_path(path)}: {ended} trajector{'y' if ended == 1 else 'ies'} of the "
                   f"periodic table flew {MAX_PERIODIC_FLIGHT:.0e} cell lengths without meeting an obstacle (along a "
                   "corridor of the lattice) and ended there", err=True)
    return 0



