"""``rbx``: the command-line entry point (docs/reference.md §4)."""
import contextlib
import errno
import io
import os
import signal
import sys
import warnings

import click

from .. import __version__
from .. import environment
from ..paths import one_line, stop_signals
from .common import OWN_PROCESS, Group, Interrupted, note_interrupt, pending_signal, quiet_noted_interrupts
from .simulate import simulate
from . import histogram, lyapunov, plot, sweep


@click.group(cls=Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="rbx")
def cli():
    """Simulate non-standard (rough) billiards: a spinning disc or ball in a table, with the strict collision
    maps of Cox, Feres and Ward."""


cli.add_command(simulate)
for _command in (plot.plot, histogram.histogram, lyapunov.lyapunov, sweep.sweep):
    cli.add_command(_command)
cli.add_command(__import__("rbx.cli.animate", fromlist=["animate"]).animate)


def main():
    # imported: Ctrl-C is a KeyboardInterrupt again, and noted, so that a command sees it even where it was lost
    # (and where it is lost, inside a callback, Python's report of it is left out: the command says it)
    quiet_noted_interrupts()
    OWN_PROCESS.append(True)
    signal.signal(signal.SIGINT, note_interrupt)
    # SIGTERM and SIGHUP too, until a command installs its own; one ignored by whoever started rbx (nohup) stays so
    for s in stop_signals()[1:]:
        if signal.getsignal(s) is not signal.SIG_IGN:
            signal.signal(s, note_interrupt)
    try:
        _main()
    except (KeyboardInterrupt, Interrupted):   # Ctrl-C before a command installed its own handler (importing)
        # nothing is written before a command's own handlers are in: the same line as a command's set-up phase
        sys.stderr.write(f"rbx: interrupted by {signal.Signals(pending_signal() or signal.SIGINT).name}; "
                         "nothing written\n")
        sys.exit(128 + int(pending_signal() or signal.SIGINT))
    finally:
        # the command has ended and said how: a signal while the interpreter shuts down (up to half a second of
        # Numba's and HDF5's clean-up) found Python's handlers already gone and killed the process by the signal,
        # after 'rbx: wrote …' and with the work in place; from here on it changes nothing
        for s in stop_signals():
            with contextlib.suppress(ValueError, OSError):
                signal.signal(s, signal.SIG_IGN)


def _main():
    """The command line's run after the signal handlers are in: everything that can take time, Numba's import
    for the environment's check included, is inside :func:`main`'s handling of an interrupt."""
    try:
        os.getcwd()
    except OSError:   # deleted under us: relative paths mean nothing, and Numba's compiler needs it too
        sys.stderr.write("rbx: the working directory no longer exists; change to an existing folder\n")
        sys.exit(2)
    problem = environment.problem()     # rbx's variables and Numba's that stop it: before any work, one line
    if problem:
        sys.stderr.write(f"rbx: {problem[0]}: {one_line(problem[1])}\n")
        sys.exit(2)
    # Numba's thread pool asks for a semaphore when it starts and, where none can be made (a full or size-limited
    # disk, no /dev/shm), warns in five lines that its start-up is then not safe across processes. rbx runs its
    # slices on its own threads (rbx.engine.run_slices) and never starts Numba's pool in two processes at once
    # that share anything; what fails next on such a disk is said in rbx's own one line
    warnings.filterwarnings("ignore", message="Could not obtain multiprocessing lock")
    # NumPy's floating-point warnings on values no run writes (positions near 1e300 in a crafted file) came out as
    # several lines each, with the source line that raised them; the command's own line says what it could not do
    for numeric in ("overflow encountered", "invalid value encountered", "divide by zero encountered",
                    "underflow encountered", "Mean of empty slice", "Degrees of freedom <= 0"):
        warnings.filterwarnings("ignore", message=numeric, category=RuntimeWarning)
    sys.stdout = _checked_stdout(sys.stdout)
    try:
        cli(prog_name="rbx")
    except StdoutError as exc:
        # a full disk behind stdout (>/dev/full), a closed stdout: one line, not a traceback (a pipe whose reader
        # left, EPIPE, click ends with exit 1 itself)
        sys.stderr.write(f"rbx: stdout: cannot write: {exc.strerror or exc}\n")
        _silence_stdout()
        sys.exit(1)


class StdoutError(OSError):
    """Writing to stdout failed (the OSError of the write, tagged as stdout's)."""


class _StdoutFile(io.FileIO):
    def write(self, data):
        try:
            return super().write(data)
        except OSError as exc:
            raise StdoutError(exc.errno, exc.strerror) from None


class _ClosedStdout(io.TextIOBase):
    """Stands for a stdout that was closed before rbx started: writing to it is an error said in one line."""
    encoding = "utf-8"

    def writable(self):
        return True

    def write(self, text):
        raise StdoutError(errno.EBADF, "it was closed before rbx started")


def _checked_stdout(stdout):
    """``stdout`` with its writes' errors tagged (:class:`StdoutError`), over the same file descriptor and with
    the same encoding and buffering; a stdout closed from the start (None) is one that refuses writes."""
    if stdout is None:
        return _ClosedStdout()
    try:
        fd = stdout.fileno()
    except (AttributeError, OSError, ValueError):       # not a file (a test's capture): as it is
        return stdout
    stdout.flush()
    return io.TextIOWrapper(io.BufferedWriter(_StdoutFile(fd, "w", closefd=False)),
                            encoding=stdout.encoding, errors=stdout.errors, line_buffering=stdout.line_buffering)


def _silence_stdout():
    """Point file descriptor 1 at the null device: Python's own flush of stdout at exit would fail again and print
    'Exception ignored …'."""
    try:
        fd = os.open(os.devnull, os.O_WRONLY)
        os.dup2(fd, 1)
        os.close(fd)
    except OSError:
        pass
