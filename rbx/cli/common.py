"""What every command shares: the user-error convention (exit 2, one line), the ``--scheduler`` options, the
progress bar. (Run files are opened with :class:`rbx.reader.Run`; its :class:`rbx.paths.FileError` becomes a
user error here.)

A user error is printed as ``rbx: <file>: <key>: <problem>`` on stderr (the parts that apply) and the command
exits with code 2, without a traceback (``--debug`` adds one). Commands built with ``cls=Command`` print click's
own usage errors (a bad option value, a missing argument, an unknown option or command) the same way
(:class:`OneLineUsage`).
"""
import contextlib
import os
import re
import signal
import sys
import threading

import click

from ..progress import (Progress, duration, is_terminal, per_second, plural, setup_note,  # noqa: F401 - the
                        watch_compiles)                                                  # commands' names

EXIT_USER_ERROR = 2


def display_path(path):
    """A path as the user would write it (:func:`rbx.paths.display_path`; imported when first needed, so that
    ``--help`` stays instant)."""
    from ..paths import display_path as display
    return display(path)


class UserError(Exception):
    """A mistake the user can fix: printed as ``rbx: <file>: <key>: <problem>``, exit code 2.

    ``file`` is None for mistakes that are not in a file (a command-line option: then ``key`` names it)."""

    def __init__(self, file, key, problem):
        self.file = None if file is None else str(file)
        self.key, self.problem = key, problem
        super().__init__(problem)

    def __str__(self):
        from ..paths import one_line
        return one_line(": ".join(str(x) for x in (display_path(self.file), self.key, self.problem) if x))


def fail(file, key, problem):
    raise UserError(file, key, problem)


def from_config_error(exc):
    """A :class:`rbx.config.ConfigError` (or :class:`rbx.paths.FileError`) as a :class:`UserError`."""
    return UserError(exc.file, exc.key, exc.problem)


@contextlib.contextmanager
def user_errors():
    """Turn the library's user errors (a bad config, a file that is not what is needed) into :class:`UserError`."""
    from ..model import ConfigError
    from ..paths import FileError
    try:
        yield
    except (ConfigError, FileError) as exc:
        raise from_config_error(exc) from None


#: ``--set KEY=VALUE``, the same for every command that reads a config
set_option = click.option(
    "--set", "sets", multiple=True, metavar="KEY=VALUE",
    help="Change a config key before the config is validated (VALUE in YAML; repeatable): --set ball.inertia=0.2 "
         "--set 'initial.position=[0, 0.5]' --set 'boundary.walls.top={rule: exit}'.")


def parse_sets(sets):
    """The ``--set KEY=VALUE`` options -> ``{key: value}`` in order, each VALUE read as YAML (as in a config file:
    ``0.2`` a number, ``[0, 0.5]`` a list, ``{rule: exit}`` a mapping, nothing after ``=`` null). A KEY given twice
    is refused."""
    from ..paths import stored_text
    from ..yamlfile import parse_yaml
    out = {}
    for item in sets:
        key, eq, text = item.partition("=")
        key = key.strip()
        if not eq or not key:
            raise UserError(None, "--set", f"expected KEY=VALUE (such as ball.inertia=0.2), got '{item}'")
        if key in out:
            raise UserError(None, "--set", f"{key} is set twice")
        if stored_text(text) != text:       # bytes that are not UTF-8 (a file name): no YAML holds them, a name
            out[key] = text                 # is what they can be
            continue
        with user_errors():
            out[key] = parse_yaml(text, None, f"--set {key}")
    return out


def warn_repeated(cfg, overrides, changes=None):
    """The warnings for settings that change nothing, on stderr: an ensemble of copies of one orbit
    (:func:`rbx.ensembles.repeated_orbits`), and a seed given by ``--seed`` or ``--set run.seed=`` (``changes``) to a
    run that draws no random numbers (:func:`rbx.ensembles.unused_seed`)."""
    from ..ensembles import repeated_orbits, seed_change, unused_seed
    message = repeated_orbits(cfg)
    if message:
        # the key to change: a list of starts that repeat each other, else the number of copies of one start
        key = "initial" if len(cfg.initial) > 1 else "run.trajectories"
        where = "--trajectories" if overrides.get("trajectories") is not None and key == "run.trajectories" else \
            f"{display_path(cfg.source)}: {key}"
        click.echo(f"rbx: warning: {where}: {message}", err=True)
    where = "--seed" if overrides.get("seed") is not None else (
        f"--set {seed_change(changes)}" if seed_change(changes) else None)
    message = unused_seed(cfg) if where else None
    if message:
        click.echo(f"rbx: warning: {where}: {message}", err=True)


#: bytes per trajectory, generously, beyond a run's state (rbx.simulation.STATE_BYTES): for the return-angle
#: experiment its draws and results
EXTRA_BYTES_PER_TRAJECTORY = {"simulate": 0, "histogram": 800}


def check_memory(cfg, overrides, command="simulate", extra=None):
    """Refuse an ensemble whose state alone would not fit in this machine's memory, rather than spend minutes
    setting it up and then crash (``rbx histogram`` with 10⁹ samples died with MemoryError). ``extra``: bytes per
    trajectory beyond its state, where the command's own (:data:`EXTRA_BYTES_PER_TRAJECTORY`) do not say."""
    from ..simulation import STATE_BYTES, memory_problem
    extra = EXTRA_BYTES_PER_TRAJECTORY[command] if extra is None else extra
    problem = memory_problem(cfg.run.trajectories, STATE_BYTES + extra)
    if problem:
        file, key = (None, "--trajectories") if overrides.get("trajectories") else (cfg.source, "run.trajectories")
        raise UserError(file, key, problem)


_PENDING = []
#: set once a command has said its work is written (:func:`summary`): a signal after that is too late to stop it
_DONE = []


def note_interrupt(signum, frame):
    """The handler of SIGINT, SIGTERM and SIGHUP from :func:`rbx.cli.main.main` until a command installs its own:
    KeyboardInterrupt, and a note of the signal (:func:`pending_signal`, which each command's
    :class:`rbx.api.StopFlag` reads). The KeyboardInterrupt alone can be lost: raised inside a callback (a ctypes
    callback of LLVM's, a finaliser) it is printed as "Exception ignored" and dropped, and the command then ran as
    if nothing had come. Once the command said its work is written, the signal is ignored: it ended in 'interrupted
    …; nothing written' and exit 130 just after 'rbx: wrote fig.png', the figure replaced."""
    paths = sys.modules.get("rbx.paths")       # not imported here: a handler that imports can meet a half-made module
    if paths is not None:
        paths.after_hangup(signum)
    if _DONE or (paths is not None and paths.work_written()):
        return
    _PENDING.append(signum)
    if paths is None or not paths.renaming():   # a file being put in place: acted on after the rename
        raise KeyboardInterrupt


def quiet_noted_interrupts():
    """Where :func:`note_interrupt`'s KeyboardInterrupt is raised inside a callback (an import's module-lock
    callback, a finaliser), Python prints it as "Exception ignored in …" with a traceback and drops it; the signal
    is noted (:func:`pending_signal`) and the command says it in its own line, so that report is left out. Other
    such reports are printed as Python prints them."""
    default = sys.unraisablehook

    def hook(unraisable):
        if not isinstance(unraisable.exc_value, KeyboardInterrupt):
            default(unraisable)
    sys.unraisablehook = hook


def pending_signal():
    """The signal :func:`note_interrupt` saw first, or 0."""
    return _PENDING[0] if _PENDING else 0


def interrupted_exit(signum=None):
    """Ctrl-C (or ``signum``) in a command that writes nothing until it is done (plot, histogram, lyapunov): one
    line, exit 128 + signum (click would print 'Aborted!' and exit 1).

    By ``os._exit``, not ``sys.exit``: the kernels' threads cannot be interrupted, and Python's exit joins them,
    so a Ctrl-C in ``rbx lyapunov`` waited for the running segment (minutes for a long run). Nothing is being
    written here: the files the command had open were closed as the exception unwound to this point."""
    if signum is None:          # the signal that was noted (SIGTERM said SIGINT, exit 130 for 143), else Ctrl-C
        signum = pending_signal() or signal.SIGINT
    from ..paths import one_line
    said = f"wrote only {'; '.join(_WRITTEN)}" if _WRITTEN else "nothing written"
    click.echo(f"rbx: interrupted by {signal.Signals(signum).name}; {one_line(said)}", err=True)
    hard_exit(128 + int(signum))


#: what a command that writes several files has written so far (:func:`written`), for the line of an interrupt
_WRITTEN = []


def written(what):
    """Note that a command of several files has written ``what`` (``'hu.h5 (the samples), not the figure'``): an
    interrupt after it says so, where it said 'nothing written' with the data file already replaced."""
    _WRITTEN.append(what)


@contextlib.contextmanager
def ending_on_signals(stop):
    """Run a command that writes nothing until it is done (histogram, lyapunov) under the signal handlers of
    ``stop`` (:class:`rbx.api.StopFlag`): a KeyboardInterrupt, or an error that follows a signal (Numba's compiler
    can lose the KeyboardInterrupt and fail later), ends it by :func:`interrupted_exit` naming the signal. User
    errors pass on."""
    try:
        with stop.installed():
            stop.check()            # a signal noted before the handlers were in
            yield
    except KeyboardInterrupt:
        interrupted_exit(stop.signum or signal.SIGINT)
    except Exception as exc:
        if not stop.signum or isinstance(exc, UserError):
            raise
        interrupted_exit(stop.signum)


def hard_exit(code):
    """End the process now with ``code``, without Python's exit: it joins the kernels' threads (which cannot be
    interrupted) and runs the finalisers of Numba and LLVM, which crashed (exit −11, after the line was printed)
    when a Ctrl-C had stopped a compile midway. The output is flushed and the run locks this process holds are
    removed first; nothing else is being written when a command ends this way."""
    from ..locks import release_held_locks
    sys.stdout.flush()
    sys.stderr.flush()
    release_held_locks()
    os._exit(code)


def report_and_exit(exc, debug):
    """Print a user error as one line on stderr and exit 2 (with the traceback too under ``--debug``)."""
    if debug:
        import traceback
        traceback.print_exc()
    from ..paths import one_line
    click.echo(f"rbx: {one_line(exc)}", err=True)
    sys.exit(EXIT_USER_ERROR)


def usage_line(exc, command_path):
    """One of click's usage errors as the line printed after ``rbx: ``: the option, argument or command at fault
    first, then the problem, on one line (click's own message may span several: the choices of a missing option).

    ``rbx: --collisions: 'abc' is not a valid integer.``, ``rbx: --colisions: No such option of rbx simulate; did
    you mean --collisions? (see 'rbx simulate --help')``, ``rbx: simlate: No such command; did you mean simulate?
    (commands: animate, …)``."""
    def flat(text):
        return " ".join(str(text).split())

    see = f" (see '{command_path} --help')"
    if isinstance(exc, click.BadParameter) and exc.param is not None and exc.ctx is not None:
        where = ", ".join(x.strip("'") for x in exc.param.get_error_hint(exc.ctx).split(" / "))
        named = re.match(r"(?:File|Path|Directory) '(.+)' (.+?)\.?$", flat(exc.message or ""))
        if isinstance(exc.param, click.Argument) and named:
            # a file argument: the file the user gave, not the argument's placeholder ('STUDY.yaml: File 'x' …')
            return f"{display_path(named.group(1))}: {named.group(2)} (given as {where})"
        return f"{where}: {flat(exc.message or exc.format_message())}"
    if isinstance(exc, click.NoSuchOption):
        maybe = f"; did you mean {' or '.join(exc.possibilities)}?" if exc.possibilities else ""
        return f"{exc.option_name}: No such option of {command_path}{maybe}{see}"
    if isinstance(exc, click.BadOptionUsage):
        return f"{exc.option_name}: {flat(exc.format_message())}{see}"
    group = exc.ctx.command if exc.ctx is not None and isinstance(exc.ctx.command, click.Group) else None
    commands = f"(commands: {', '.join(group.list_commands(exc.ctx))}; see '{command_path} --help')" if group else see
    if hasattr(exc, "command_name"):       # click.exceptions.NoSuchCommand (click >= 8.4)
        maybe = f"; did you mean {' or '.join(exc.possibilities)}?" if exc.possibilities else ""
        return f"{exc.command_name}: No such command{maybe} {commands}"
    return f"{command_path.split()[-1]}: {flat(exc.format_message())}{see}"


class OneLineUsage:
    """Mixed into click's command classes (:class:`Command`, :class:`Group`): a usage error (unknown option,
    missing argument, bad value, unknown command), found while parsing the command line or raised by a command
    while it runs, is one line ``rbx: <option or argument>: <problem>`` on stderr and exit 2, like every other
    user error, never click's usage block."""

    def make_context(self, info_name, args, parent=None, **extra):
        try:
            return super().make_context(info_name, args, parent=parent, **extra)
        except click.UsageError as exc:
            path = f"{parent.command_path} {info_name}" if parent is not None else info_name
            self._usage_exit(exc, path)

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except click.UsageError as exc:     # a group's unknown command; a command's own ctx.fail
            self._usage_exit(exc, exc.ctx.command_path if exc.ctx is not None else ctx.command_path)

    @staticmethod
    def _usage_exit(exc, command_path):
        click.echo(f"rbx: {usage_line(exc, command_path)}", err=True)
        raise click.exceptions.Exit(EXIT_USER_ERROR) from None


class Choice(click.Choice):
    """click's Choice with a did-you-mean (``--kind orbits``: did you mean orbit?), as commands and options have."""

    def convert(self, value, param, ctx):
        try:
            return super().convert(value, param, ctx)
        except click.BadParameter as exc:
            import difflib
            close = difflib.get_close_matches(str(value), [str(c) for c in self.choices], n=1)
            if not close:
                raise
            exc.message = f"{exc.message.rstrip('.')}; did you mean {close[0]}?"
            raise exc


class Command(OneLineUsage, click.Command):
    """A command of rbx (``@click.command(cls=Command)``): usage errors are one line, exit 2. A command that runs
    kernels (:data:`COMPILING`) says on stderr, before a first compile, that it compiles: to a terminal, as the
    progress bar is drawn (not with ``--quiet``); a program reading stderr gets the summary line, which says the
    same after the fact, and a refusal there stays one line."""

    def invoke(self, ctx):
        if self.name in COMPILING and not ctx.params.get("quiet") and is_terminal(sys.stderr):
            announce_compiles()
        from ..paths import forget_placed
        forget_placed()         # what an earlier command of this process put in place is not this one's work
        try:
            return super().invoke(ctx)
        finally:
            forget_placed()


#: the commands that run kernels: a first run of a scene compiles them, silent for seconds without a word
COMPILING = ("simulate", "histogram", "lyapunov", "sweep")
#: the line said when Numba starts a first compile in this process
COMPILE_NOTICE = ("rbx: compiling kernels for this scene, once (3–15 s each; the next run loads them from the "
                  "cache)…")
_ANNOUNCING = {"registered": False}


def announce_compiles():
    """Say :data:`COMPILE_NOTICE` on stderr when Numba starts its first compile in this process (its
    ``numba:compile`` events: a kernel loaded from the disk cache raises none, so a warm run says nothing)."""
    if _ANNOUNCING["registered"]:
        return
    try:
        from numba.core import event
    except ImportError:         # pragma: no cover - a Numba without the event API: no notice
        return

    class Notice(event.Listener):
        said = False

        def on_start(self, ev):
            if not self.said:
                self.said = True
                click.echo(COMPILE_NOTICE, err=True)

        def on_end(self, ev):
            pass

    event.register("numba:compile", Notice())
    _ANNOUNCING["registered"] = True


class Group(OneLineUsage, click.Group):
    """The ``rbx`` group: its own usage errors (``rbx --bogus``, ``rbx simlate``) are one line, exit 2, too. A bare
    ``rbx`` is no mistake: it shows the help (the commands) and exits 0, as ``rbx --help`` does."""

    def make_context(self, info_name, args, parent=None, **extra):
        if not args and parent is None:
            args = ["--help"]
        return super().make_context(info_name, args, parent=parent, **extra)

    def invoke(self, ctx):
        # a Ctrl-C that reaches here came before the command installed its own handling (while it imported or set
        # up): click would print 'Aborted!' and exit 1; rbx's entry point says 'interrupted' and exits 130
        try:
            return super().invoke(ctx)
        except KeyboardInterrupt as exc:
            raise Interrupted() from exc


class Interrupted(BaseException):
    """A Ctrl-C carried past click (which turns a KeyboardInterrupt into 'Aborted!', exit 1) to ``rbx.cli.main``."""


# ---- the Dask cluster of --scheduler (simulate, histogram, lyapunov) ---------------------------------------

def check_cluster_options(cluster):
    """--slices and --task-collisions only with --scheduler."""
    if cluster["scheduler"] is None:
        for name in ("slices", "task_collisions"):
            if cluster[name] is not None:
                raise UserError(None, "--" + name.replace("_", "-"), "only with --scheduler (it cuts a run into "
                                                                      "tasks for a Dask cluster)")


def connect(cluster):
    """The :class:`rbx.cluster.Cluster` of ``--scheduler`` as a context manager (None: a local run); an
    unreachable scheduler is a user error."""
    from ..api import cluster_for
    from ..cluster import SchedulerUnreachable
    if cluster["scheduler"] is not None:
        _quiet_dask()
    try:
        on = cluster_for(cluster["scheduler"], "--scheduler", cluster["slices"], cluster["task_collisions"])
    except SchedulerUnreachable as exc:
        raise UserError(None, exc.key, exc.problem) from None
    if cluster["scheduler"] is not None and on.threads() == 0:
        click.echo("rbx: warning: --scheduler: the cluster has no workers yet: the run waits for them"
                   + ("" if cluster["slices"] else " (and is cut for one worker thread; --slices to cut it finer)"),
                   err=True)
    return on


def _quiet_dask():
    """Dask's client logs its connection's ups and downs to stderr; rbx says itself what went wrong."""
    import logging
    try:
        import distributed  # noqa: F401 - it sets its loggers' levels when imported: set them after
    except ImportError:
        return
    for name in ("distributed", "distributed.client", "distributed.comm", "distributed.core",
                 "distributed.batched"):
        logging.getLogger(name).setLevel(logging.CRITICAL)


# ---- progress (the bar itself is in rbx.progress, which the library uses too) -------------------------------

#: set by the console script's entry point (rbx.cli.main.main): the process is rbx's own, so its signal handling may
#: change for good (not under a test runner invoking commands in its own process)
OWN_PROCESS = []


def summary(quiet, message):
    """The one line a command ends with on stderr (``rbx: wrote run.h5: …``), unless ``--quiet``. Its work is
    written: from here a signal changes nothing (:func:`note_interrupt`); in rbx's own process SIGINT, SIGTERM and
    SIGHUP are ignored from here on, so that one during Python's exit, after its handlers are gone, does not kill the
    process (a finished study's command killed by SIGINT just after 'rbx: wrote …')."""
    _DONE.append(True)
    if OWN_PROCESS and threading.current_thread() is threading.main_thread():
        from ..paths import stop_signals
        for s in stop_signals():
            signal.signal(s, signal.SIG_IGN)
    if not quiet:
        from ..paths import one_line
        click.echo(f"rbx: {one_line(message)}", err=True)


#: ``--quiet``, the same for every command
quiet_option = click.option("--quiet", is_flag=True, help="No progress bar and no summary line on stderr.")


# ---- where a figure is written (rbx plot, rbx animate) -------------------------------------------------------------

def check_figure_target(path):
    """Refuse, as a :class:`UserError`, to write a figure at ``path`` where that would surprise: into a folder that
    does not exist (it was made without a word, so a typo made a folder tree), through a symbolic link or onto a
    device or FIFO, or over a file that is not a figure (its first bytes: :data:`rbx.paths.FIGURE_SIGNATURES`)."""
    from ..paths import FileError, check_figure_file, check_replaceable, last_output
    last_output(path)       # a figure is what its command writes last: a signal once it is in place changes nothing
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise UserError(path, None, f"the folder {display_path(folder)} does not exist (rbx makes no folders for a "
                                    "figure: create it first, or give another path)")
    try:
        check_replaceable(path)
    except FileError as exc:
        raise UserError(None, None, exc.problem) from None
    try:
        check_figure_file(path)
    except FileError as exc:
        raise UserError(exc.file, None, exc.problem) from None


def cannot_write(path, exc, what="the figure", kept=""):
    """A figure or an animation that could not be written -> raises: a full disk (or a size limit) is not the
    user's input, one line and exit 1 (as for a run); anything else a :class:`UserError` (exit 2). ``kept``: what
    the command wrote before that stays (rbx histogram's samples), said at the end of the line."""
    from ..paths import NO_ROOM, FileError
    kept = f"; {kept}" if kept else ""
    if isinstance(exc, FileError):      # what was found at the name when the figure was to replace it
        raise UserError(exc.file or path, exc.key, f"{exc.problem}; nothing was replaced{kept}")
    if isinstance(exc, FileExistsError):     # without --force: a file that appeared meanwhile is not replaced
        raise UserError(path, None, f"appeared while {what} was made (another program?) and was not replaced; "
                                    f"give another name, or --force to replace it{kept}")
    reason = getattr(exc, "strerror", None) or exc
    if getattr(exc, "errno", None) in NO_ROOM:
        click.echo(f"rbx: {display_path(path)}: cannot write {what}: {reason}: no room on the disk (or a size limit, "
                   f"ulimit -f?); nothing was replaced{kept}", err=True)
        raise SystemExit(1)
    raise UserError(path, None, f"cannot write {what}: {reason}{kept}")
