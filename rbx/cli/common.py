"""What every command shares: the user-error convention (exit 2, one line), opening run files, the progress bar.

A user error is printed as ``rbx: <file>: <key>: <problem>`` on stderr (the parts that apply) and the command
exits with code 2, without a traceback (``--debug`` adds one). Commands built with ``cls=Command`` print click's
own usage errors (a bad option value, a missing argument) the same way.
"""
import os
import sys
import time

import click

EXIT_USER_ERROR = 2


def display_path(path):
    """A path as the user would write it: relative to the working directory when it lies below it."""
    if path is None:
        return None
    path = str(path)
    if not os.path.isabs(path):
        return path
    try:
        rel = os.path.relpath(path)
    except ValueError:   # another drive (Windows)
        return path
    return path if rel.startswith("..") else rel


class UserError(Exception):
    """A mistake the user can fix: printed as ``rbx: <file>: <key>: <problem>``, exit code 2.

    ``file`` is None for mistakes that are not in a file (a command-line option: then ``key`` names it)."""

    def __init__(self, file, key, problem):
        self.file = None if file is None else str(file)
        self.key, self.problem = key, problem
        super().__init__(problem)

    def __str__(self):
        return ": ".join(str(x) for x in (display_path(self.file), self.key, self.problem) if x)


def fail(file, key, problem):
    raise UserError(file, key, problem)


def from_config_error(exc):
    """A :class:`rbx.config.ConfigError` as a :class:`UserError`."""
    return UserError(exc.file, exc.key, exc.problem)


def report_and_exit(exc, debug):
    """Print a user error as one line on stderr and exit 2 (with the traceback too under ``--debug``)."""
    if debug:
        import traceback
        traceback.print_exc()
    click.echo(f"rbx: {exc}", err=True)
    sys.exit(EXIT_USER_ERROR)


class Command(click.Command):
    """A click command whose usage errors are one line and exit 2 like every other user error:
    ``rbx: --collisions: 'abc' is not a valid integer.``, ``rbx: simulate: No such option: --colisions …``."""

    def make_context(self, info_name, args, parent=None, **extra):
        try:
            return super().make_context(info_name, args, parent=parent, **extra)
        except click.UsageError as exc:
            if isinstance(exc, click.BadParameter) and exc.param is not None and exc.ctx is not None:
                # the option or argument as the key: rbx: --collisions: 'abc' is not a valid integer.
                where = ", ".join(x.strip("'") for x in exc.param.get_error_hint(exc.ctx).split(" / "))
                line = f"{where}: {exc.message}"
            else:
                name = exc.ctx.command_path if exc.ctx is not None else info_name
                line = f"{info_name}: {exc.format_message()} (see '{name} --help')"
            click.echo(f"rbx: {line}", err=True)
            raise click.exceptions.Exit(EXIT_USER_ERROR) from None


# ---- run files ----------------------------------------------------------------------------------------------

#: root attributes every rbx run file has (SPEC §5)
RUN_ATTRS = ("rbx_version", "dimension", "config", "complete")


def open_run(path, need=(), mode="r"):
    """Open an rbx HDF5 run file -> ``h5py.File`` (use it in a ``with``), or raise :class:`UserError` naming the file.

    Checks that the file exists, is HDF5, is an rbx run (root attributes ``rbx_version``, ``dimension``,
    ``config``, ``complete``) of a schema this rbx can read, and holds every dataset or group in ``need``
    (e.g. ``("collisions/position", "collisions/count")`` or ``("returns/angle",)``). An incomplete run opens
    fine: callers that care look at ``f.attrs["complete"]``.
    """
    import h5py

    from ..output import SCHEMA_VERSION

    if not os.path.exists(path):
        raise UserError(path, None, "file not found")
    if os.path.isdir(path):
        raise UserError(path, None, "is a directory, not an HDF5 file")
    try:
        is_hdf5 = h5py.is_hdf5(path)
    except OSError as exc:
        raise UserError(path, None, f"cannot read: {exc.strerror or exc}") from None
    if not is_hdf5:
        raise UserError(path, None, "not an HDF5 file (is it the right file? rbx writes .h5 files)")
    try:
        f = h5py.File(path, mode)
    except OSError as exc:
        raise UserError(path, None, f"cannot open the HDF5 file (damaged or locked by another program?): "
                                    f"{_first_line(exc)}") from None
    try:
        missing = [a for a in RUN_ATTRS if a not in f.attrs]
        if missing:
            raise UserError(path, None, f"not an rbx run file (no root attribute '{missing[0]}')")
        schema = int(f.attrs.get("schema_version", 1))
        if schema > SCHEMA_VERSION:
            raise UserError(path, "schema_version", f"is {schema}: written by a newer rbx (this one reads up to "
                                                    f"{SCHEMA_VERSION}); upgrade rbx")
        for name in need:
            if name not in f:
                field = name.rsplit("/", 1)[-1]
                why = (f" (the run did not record it: add '{field}' to output.record)"
                       if name.startswith("collisions/") and field not in ("count", "step") else "")
                raise UserError(path, name, f"not in this file{why}")
    except UserError:
        f.close()
        raise
    except Exception as exc:   # a damaged file can fail on the first read rather than on opening
        f.close()
        raise UserError(path, None, f"cannot read the HDF5 file (damaged?): {_first_line(exc)}") from None
    return f


def _first_line(exc):
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


# ---- progress -----------------------------------------------------------------------------------------------

class Progress:
    """A one-line progress bar on stderr that appears only once a run has taken more than ``delay`` seconds.

    ``start``: work already done before this process began (a resumed run), left out of the time estimate."""

    def __init__(self, label, delay=2.0, quiet=False, start=0):
        self.label, self.delay, self.quiet, self.first = label, delay, quiet, start
        self.start = time.perf_counter()
        self.last = 0.0
        self.shown = False

    def __call__(self, done, total):
        now = time.perf_counter() - self.start
        if self.quiet or now < self.delay or (now - self.last < 0.5 and done < total):
            return
        self.last = now
        frac = done / total if total else 1.0
        rate = (done - self.first) / now if now > 0 else 0.0
        eta = (total - done) / rate if rate > 0 else float("inf")
        bar = "#" * int(30 * frac)
        click.echo(f"\r{self.label} [{bar:<30}] {100 * frac:5.1f}%  {now:6.1f}s  eta {eta:6.1f}s", err=True, nl=False)
        self.shown = True

    def close(self):
        if self.shown:
            click.echo("", err=True)
