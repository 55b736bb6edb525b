"""``rbx simulate CONFIG``: run an experiment and write its HDF5 file (SPEC §4–5)."""
import os
import signal

import click

from .common import Progress, UserError, report_and_exit


@click.command()
@click.argument("config", type=click.Path(dir_okay=False))
@click.option("-o", "--output", "out", type=click.Path(dir_okay=False), help="HDF5 file to write (default: output.path).")
@click.option("--collisions", type=int, help="Override run.collisions.")
@click.option("--trajectories", type=int, help="Override run.trajectories.")
@click.option("--seed", type=int, help="Override run.seed.")
@click.option("--force", is_flag=True, help="Overwrite an existing output file.")
@click.option("--quiet", is_flag=True, help="No progress bar.")
@click.option("--debug", is_flag=True, help="Show a traceback with user errors.")
def simulate(config, out, collisions, trajectories, seed, force, quiet, debug):
    """Run the experiment CONFIG (YAML) and write trajectories to HDF5."""
    try:
        code = _simulate(config, out, collisions, trajectories, seed, force, quiet)
    except UserError as exc:
        report_and_exit(exc, debug)
    if code:
        raise SystemExit(code)


def _simulate(config, out, collisions, trajectories, seed, force, quiet):
    from .. import config as cfgmod
    from ..output import H5Sink, open_for_writing, temporary_path
    from ..simulate import Simulation

    overrides = {k: v for k, v in (("collisions", collisions), ("trajectories", trajectories), ("seed", seed))
                 if v is not None}
    try:
        cfg = cfgmod.load(config, overrides)
    except cfgmod.ConfigError as exc:
        raise UserError(exc.file, exc.key, exc.problem) from None
    path = os.path.abspath(out) if out else cfg.output.path
    if path is None:
        raise UserError(config, "output.path", "no output file: give output.path in the config or -o OUT.h5")
    if os.path.exists(path) and not force:
        raise UserError(path, None, "exists; use --force to overwrite it")
    sim = Simulation(cfg)
    stop = _StopFlag()
    progress = Progress("simulate", quiet=quiet)
    try:
        h5 = open_for_writing(path)
    except OSError as exc:
        raise UserError(path, None, f"cannot write: {exc.strerror or exc}") from None
    with stop.installed(), h5:
        sink = H5Sink(h5, cfg, sim.geom)
        complete = sim.run(sink, progress=progress, should_stop=stop)
        h5.attrs["complete"] = bool(complete)
    progress.close()
    os.replace(temporary_path(path), path)
    if not complete:
        click.echo(f"rbx: {path}: interrupted; the file holds what was computed (complete = false)", err=True)
        return 128 + stop.signum
    return 0


class _StopFlag:
    """SIGINT/SIGTERM set a flag that the run polls between blocks, so the file is closed cleanly."""

    def __init__(self):
        self.signum = 0

    def __call__(self):
        return self.signum != 0

    def _handler(self, signum, frame):
        self.signum = signum

    def installed(self):
        import contextlib

        @contextlib.contextmanager
        def ctx():
            old = {s: signal.signal(s, self._handler) for s in (signal.SIGINT, signal.SIGTERM)}
            try:
                yield
            finally:
                for s, h in old.items():
                    signal.signal(s, h)
        return ctx()
