"""``rbx simulate CONFIG`` and ``rbx simulate --resume RUN.h5``: run an experiment into HDF5 (SPEC §4–5).

Two phases. *Setting up* (validate, allocate, compile the kernels: no file written yet): SIGINT/SIGTERM abort at
once, with nothing to save. *Running*: the run writes ``OUT.h5.partial`` and SIGINT/SIGTERM only set a flag that
the run polls between blocks (each well under a second of work, and the kernels hold no GIL), so the file is
checkpointed and closed cleanly. Either way the run ends by renaming ``OUT.h5.partial`` to ``OUT.h5``, marked
``complete = false`` unless it finished, and an interrupted command exits with 128 + the signal number (130,
143). An existing ``OUT.h5`` is replaced only with ``--force``. ``--resume`` continues such a file to its
requested length and writes the same records as an uninterrupted run.
"""
import contextlib
import os
import signal
import threading

import click

from .common import Command, Progress, UserError, display_path, from_config_error, report_and_exit

OVERRIDES = ("collisions", "trajectories", "seed")


@click.command(cls=Command)
@click.argument("config", required=False)
@click.option("-o", "--output", "out", metavar="OUT.h5", help="HDF5 file to write (default: output.path).")
@click.option("--collisions", type=int, help="Override run.collisions.")
@click.option("--trajectories", type=int, help="Override run.trajectories.")
@click.option("--seed", type=int, help="Override run.seed.")
@click.option("--resume", metavar="RUN.h5",
              help="Continue the interrupted run in RUN.h5 to its requested length (in place, or into -o).")
@click.option("--force", is_flag=True, help="Overwrite an existing output file.")
@click.option("--quiet", is_flag=True, help="No progress bar.")
@click.option("--debug", is_flag=True, help="Show a traceback with user errors.")
def simulate(config, out, collisions, trajectories, seed, resume, force, quiet, debug):
    """Run the experiment CONFIG (YAML) and write its trajectories to HDF5."""
    stop = StopFlag()
    overrides = {"collisions": collisions, "trajectories": trajectories, "seed": seed}
    # the handlers go in first, so that Ctrl-C while numba loads is a clean stop too, never a traceback
    with stop.installed():
        try:
            if resume is not None:
                code = _resume(config, resume, out, overrides, force, quiet, stop)
            else:
                code = _simulate(config, out, overrides, force, quiet, stop)
        except UserError as exc:
            report_and_exit(exc, debug)
        except KeyboardInterrupt:   # raised by StopFlag only while setting up, before any file is written
            click.echo(f"rbx: interrupted by {signal.Signals(stop.signum).name} before the run started; "
                       "nothing written", err=True)
            code = 128 + stop.signum
    if code:
        raise SystemExit(code)


def _simulate(config, out, overrides, force, quiet, stop):
    from .. import config as cfgmod
    from ..output import open_for_writing, temporary_path
    from ..simulate import Simulation

    if config is None:
        raise UserError(None, "CONFIG", "missing: give an experiment config (YAML), or --resume RUN.h5")
    try:
        cfg = cfgmod.load(config, overrides)
    except cfgmod.ConfigError as exc:
        raise from_config_error(exc) from None
    path = os.path.abspath(out) if out else cfg.output.path
    if path is None:
        raise UserError(config, "output.path", "no output file: give output.path in the config or -o OUT.h5")
    _check_target(path, force, "-o" if out else "output.path", cfg.source)
    _check_memory(cfg, overrides)
    try:
        sim = Simulation(cfg)
    except MemoryError:
        file, key = (None, "--trajectories") if overrides["trajectories"] else (cfg.source, "run.trajectories")
        raise UserError(file, key, f"{cfg.run.trajectories} trajectories do not fit in the free memory") from None
    _compile(sim)
    if stop.start_running():
        raise KeyboardInterrupt
    try:
        h5 = open_for_writing(path)
    except OSError as exc:
        raise UserError(temporary_path(path), None, f"cannot write: {exc.strerror or exc}") from None
    return _execute(sim, h5, temporary_path(path), path, stop, quiet, fresh=True, done=0)


def _resume(config, run_file, out, overrides, force, quiet, stop):
    import shutil

    import h5py

    from ..config import ConfigError
    from ..output import temporary_path
    from ..resume import load, make_consistent, version_note
    from .common import open_run

    if config is not None:
        raise UserError(None, "--resume", "give either CONFIG or --resume RUN.h5, not both")
    for name in OVERRIDES:
        if overrides[name] is not None:
            raise UserError(None, f"--{name}", "cannot be changed when resuming: the run continues with the "
                                               "settings stored in its file")
    source = os.path.abspath(run_file)
    # a killed run leaves only OUT.h5.partial: resuming it writes OUT.h5, working on the .partial in place
    default = source[:-len(".partial")] if source.endswith(".partial") else source
    path = os.path.abspath(out) if out else default
    tmp = temporary_path(path)
    in_place = tmp == source
    with open_run(run_file, need=("collisions/count", "collisions/step")) as f:
        if bool(f.attrs["complete"]):
            click.echo(f"rbx: {display_path(run_file)}: the run is complete; nothing to resume", err=True)
            return 0
        note = version_note(f)
        try:
            sim, write_initial, done = load(f, run_file)
        except ConfigError as exc:
            raise from_config_error(exc) from None
        except MemoryError:
            raise UserError(run_file, "run.trajectories", "the trajectories do not fit in the free memory") from None
    if path != source:
        _check_target(path, force, "-o", None, partial_ok=in_place)
    if os.path.exists(tmp) and not force and not in_place:
        raise UserError(tmp, None, "exists: another run may be writing it, or an earlier one was killed; "
                                   "remove it or use --force")
    if note:
        click.echo(f"rbx: {display_path(run_file)}: warning: {note}", err=True)
    _compile(sim)
    if stop.start_running():
        raise KeyboardInterrupt
    # work on a copy (unless resuming a .partial): if this attempt dies badly, the file it started from is intact
    try:
        if not in_place:
            shutil.copyfile(source, tmp)
        h5 = h5py.File(tmp, "r+")
    except OSError as exc:
        if os.path.exists(tmp) and not in_place:
            os.remove(tmp)
        raise UserError(tmp, None, f"cannot write: {exc.strerror or exc}") from None
    try:
        make_consistent(h5, sim, write_initial)
    except BaseException:
        h5.close()
        if not in_place:
            os.remove(tmp)
        raise
    return _execute(sim, h5, tmp, path, stop, quiet, fresh=False, done=done, write_initial=write_initial)


def _compile(sim):
    """Compile (or load from the cache) the kernels now, while Ctrl-C can still abort at once: a first compile
    takes several seconds, and once the run has started a signal is only seen between blocks."""
    sim.advance(0, sim.block_buffers(0))   # no trajectory is below collision 0: nothing moves


def _execute(sim, h5, tmp, path, stop, quiet, fresh, done, write_initial=None):
    """Run ``sim`` into the open file ``h5`` (at ``tmp``), then rename it to ``path`` -> exit code.

    The rename happens however the run ends (complete, interrupted, or an unexpected error), so ``path`` always
    holds every record computed so far, and ``complete`` says whether that is all of them (SPEC §4)."""
    from ..output import H5Sink

    progress = Progress("simulate", quiet=quiet, start=done)
    complete = False
    failure = None
    try:
        with h5:
            sink = H5Sink(h5, sim.cfg, sim.geom, fresh=fresh)
            complete = sim.run(sink, progress=progress, should_stop=stop, write_initial=write_initial)
            h5.attrs["complete"] = bool(complete)
    except OSError as exc:   # disk full, file system gone: not a bug, and nothing a traceback would explain
        failure = exc
    finally:
        progress.close()
        _rename(tmp, path)
    if failure is not None:
        click.echo(f"rbx: {display_path(path)}: writing failed: {failure}; the file holds the records written "
                   "before (complete = false)", err=True)
        return 1
    if not complete:
        made = int(sim.ncoll[sim.alive].min()) if sim.alive.any() else sim.cfg.run.collisions
        click.echo(f"rbx: {display_path(path)}: interrupted by {signal.Signals(stop.signum).name} after {made} of "
                   f"{sim.cfg.run.collisions} collisions; the file holds every record so far (complete = false). "
                   f"Continue with: rbx simulate --resume {display_path(path)}", err=True)
        return 128 + stop.signum
    return 0


def _rename(tmp, path):
    try:
        os.replace(tmp, path)
    except OSError as exc:
        click.echo(f"rbx: {display_path(path)}: cannot rename {display_path(tmp)} to it: {exc.strerror or exc}; "
                   f"the records are in {display_path(tmp)}", err=True)


def _check_target(path, force, key, config_source, partial_ok=False):
    """Refuse to overwrite an existing file (or the config itself, or a run still writing) without --force."""
    from ..output import temporary_path

    file = None if key == "-o" else config_source
    if os.path.isdir(path):
        raise UserError(file, key, f"{display_path(path)} is a directory; give a file name such as run.h5")
    if config_source and os.path.exists(path) and os.path.samefile(path, config_source):
        raise UserError(file, key, f"{display_path(path)} is the config file itself")
    if os.path.exists(path) and not force:
        raise UserError(path, None, "exists; use --force to overwrite it")
    tmp = temporary_path(path)
    if os.path.exists(tmp) and not force and not partial_ok:
        raise UserError(tmp, None, "exists: another run may be writing it, or an earlier one was killed "
                                   "(try: rbx simulate --resume " + display_path(tmp) + "); remove it or use --force")


#: bytes of state per trajectory, generously (position, velocity, spin and orientation matrices, counters, key)
BYTES_PER_TRAJECTORY = 400


def _check_memory(cfg, overrides):
    """Refuse an ensemble whose state alone would not fit in this machine's memory, rather than spend minutes
    setting it up and then crash."""
    M = cfg.run.trajectories
    try:
        available = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):   # not a POSIX system: let the allocation decide
        return
    need = M * BYTES_PER_TRAJECTORY
    if need > available:
        file, key = (None, "--trajectories") if overrides.get("trajectories") else (cfg.source, "run.trajectories")
        raise UserError(file, key, f"{M} trajectories need about {need / 2**30:.3g} GiB of memory, more than this "
                                   f"machine has ({available / 2**30:.3g} GiB)")


class StopFlag:
    """SIGINT/SIGTERM while setting up: KeyboardInterrupt at once (nothing is written yet). While running: a flag
    that the run polls between blocks, so the file is checkpointed and closed cleanly.

    A second signal while running does not abort harder: the kernels hand back control only between blocks
    (well under a second each), and aborting in the middle of an HDF5 write could damage the file."""

    def __init__(self):
        self.signum = 0
        self.running = False

    def __call__(self):
        return self.signum != 0

    def start_running(self):
        """Switch from aborting to flagging -> True if a signal came already (then abort instead)."""
        self.running = True
        return self()

    def _handler(self, signum, frame):
        self.signum = self.signum or signum
        if not self.running:
            raise KeyboardInterrupt

    @contextlib.contextmanager
    def installed(self):
        if threading.current_thread() is not threading.main_thread():   # signal handlers live in the main thread
            yield
            return
        old = {s: signal.signal(s, self._handler) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            yield
        finally:
            for s, h in old.items():
                signal.signal(s, h)
