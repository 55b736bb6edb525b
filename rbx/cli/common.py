"""What every command shares: the user-error convention (exit 2, one line) and the progress bar."""
import sys
import time

import click

EXIT_USER_ERROR = 2


class UserError(Exception):
    """A mistake the user can fix: printed as ``rbx: <file>: <key>: <problem>``, exit code 2."""

    def __init__(self, file, key, problem):
        self.file, self.key, self.problem = str(file), key, problem
        super().__init__(": ".join(str(x) for x in (file, key, problem) if x))


def fail(file, key, problem):
    raise UserError(file, key, problem)


def report_and_exit(exc, debug):
    """Print a user error as one line on stderr and exit 2 (with the traceback too under ``--debug``)."""
    if debug:
        import traceback
        traceback.print_exc()
    click.echo(f"rbx: {exc}", err=True)
    sys.exit(EXIT_USER_ERROR)


class Progress:
    """A one-line progress bar on stderr that appears only once a run has taken more than ``delay`` seconds."""

    def __init__(self, label, delay=2.0, quiet=False):
        self.label, self.delay, self.quiet = label, delay, quiet
        self.start = time.perf_counter()
        self.last = 0.0
        self.shown = False

    def __call__(self, done, total):
        now = time.perf_counter() - self.start
        if self.quiet or now < self.delay or (now - self.last < 0.5 and done < total):
            return
        self.last = now
        frac = done / total if total else 1.0
        eta = now * (1 - frac) / frac if frac > 0 else float("inf")
        bar = "#" * int(30 * frac)
        click.echo(f"\r{self.label} [{bar:<30}] {100 * frac:5.1f}%  {now:6.1f}s  eta {eta:6.1f}s", err=True, nl=False)
        self.shown = True

    def close(self):
        if self.shown:
            click.echo("", err=True)
