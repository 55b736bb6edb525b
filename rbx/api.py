"""The Python API (SPEC §9): :func:`load`, :func:`simulate`, :func:`open` — the same engine as the CLI, and the
same code: ``rbx simulate`` runs an experiment into a file with :func:`run_to_file` too, so the API and the CLI
write the same file bit for bit.

    >>> import rbx
    >>> exp = rbx.load("configs/examples/strip.yaml")
    >>> run = rbx.simulate(exp, collisions=1000)          # in memory: a rbx.Run
    >>> run.position.shape                                # (trajectories, records, 2)
    >>> run = rbx.simulate(exp, output="strip.h5")        # streamed to HDF5 (OUT.h5.partial, renamed at the end)
    >>> run = rbx.open("strip.h5")                        # the same rbx.Run, read back

The running part also lives here because the CLI shares it: :class:`StopFlag` (SIGINT/SIGTERM stop a run between
blocks, so the file is checkpointed and closed cleanly), :func:`compile_kernels`, :func:`run_to_file`.
"""
import contextlib
import dataclasses
import os
import signal
import sys
import threading
import warnings

# nothing heavy at import: the CLI takes StopFlag from here before it installs its signal handlers
__all__ = ["load", "simulate", "open"]

_OVERRIDES = ("collisions", "trajectories", "seed", "max_size")


def load(path_or_dict, overrides=None):
    """A validated, immutable experiment from a config file (YAML) or a mapping -> :class:`rbx.model.Experiment`.

    Relative paths in a mapping are resolved from the working directory. Raises :class:`ConfigError` whose message
    names the file and the key (the CLI prints the same message). ``overrides``: ``{'collisions': N, …}``."""
    from . import config
    from .model import Experiment
    if isinstance(path_or_dict, Experiment):
        return path_or_dict if not overrides else _override(path_or_dict, overrides)
    if isinstance(path_or_dict, dict):
        return _api_keys(lambda: config.from_dict(path_or_dict, overrides=overrides))
    if isinstance(path_or_dict, (str, os.PathLike)):
        return _api_keys(lambda: config.load(os.fspath(path_or_dict), overrides))
    raise TypeError(f"rbx.load takes a config path or a dict, not {type(path_or_dict).__name__}")


def _api_keys(make):
    """Errors in overrides name the keyword argument (``collisions``), not the CLI option (``--collisions``)."""
    from .model import ConfigError
    try:
        return make()
    except ConfigError as exc:
        name = (exc.key or "").lstrip("-").replace("-", "_")
        if exc.file is None and exc.key and exc.key.startswith("--") and name in _OVERRIDES:
            raise ConfigError(None, name, exc.problem) from None
        raise


def _override(experiment, overrides):
    """``experiment`` with run settings replaced, validated as the config validates them."""
    from . import config
    if experiment.resolved is not None:   # validate the new values exactly as a config would be
        checked = _api_keys(lambda: config.from_dict(experiment.resolved, experiment.source, overrides))
        run, output = checked.run, checked.output
    else:
        run = dataclasses.replace(experiment.run, **{k: v for k, v in overrides.items() if k != "max_size"})
        output = dataclasses.replace(experiment.output, **{k: v for k, v in overrides.items() if k == "max_size"})
    return experiment.replace(run=run, output=output)


def simulate(experiment, *, collisions=None, trajectories=None, seed=None, output=None, force=False,
             progress=False, max_size=None, scheduler=None, slices=None, task_collisions=None):
    """Run an experiment (an :class:`~rbx.model.Experiment`, a config path or a dict) -> :class:`Run`.

    ``collisions``, ``trajectories``, ``seed`` override ``run.*``, ``max_size`` ``output.max_size`` (bytes or a
    text such as '50 GB'). With ``output=None`` the run is kept in memory;
    else it is streamed to that HDF5 file as ``rbx simulate -o`` does (written as ``output.partial``, renamed at
    the end; an existing file is replaced only with ``force=True``) and read back. ``progress``: True for a
    progress bar on stderr, or a callable ``progress(done, total)``.

    Ctrl-C (SIGINT) while a file is written stops the run between blocks: the file is closed and renamed, marked
    ``complete = False`` (``rbx simulate --resume`` continues it), then KeyboardInterrupt is raised.

    ``scheduler``: run the trajectories on the workers of a Dask cluster (SPEC §11; needs ``rbx[cluster]``): its
    scheduler's address (``tcp://host:8786``), the JSON file it wrote (``--scheduler-file``) or a
    ``distributed.Client``. The result is the local run's, bit for bit. ``slices`` (tasks per round) and
    ``task_collisions`` (collisions per task) tune how the run is cut (docs/cluster.md). An unreachable scheduler
    raises :class:`rbx.cluster.SchedulerUnreachable`, a task that fails mid-run :class:`rbx.cluster.ClusterError`
    (a file then holds every round finished before, ``complete = False``)."""
    from .runfile import Run
    from .simulation import MemorySink, Simulation
    overrides = {k: v for k, v in (("collisions", collisions), ("trajectories", trajectories), ("seed", seed),
                                   ("max_size", max_size)) if v is not None}
    exp = load(experiment, overrides or None)
    if scheduler is None and (slices is not None or task_collisions is not None):
        raise TypeError("slices and task_collisions cut a run for a cluster: give scheduler too")
    bar = _progress(progress)
    try:
        if output is None:
            sim = Simulation(exp)
            with cluster_for(scheduler, "scheduler", slices, task_collisions) as sim.cluster:
                sink = MemorySink()
                complete = sim.run(sink, progress=bar)
            return Run.from_memory(exp, sink, complete)
        path = os.path.abspath(os.fspath(output))
        check_target(path, force, exp)
        sim = Simulation(exp)
        stop = StopFlag()
        with stop.installed(), cluster_for(scheduler, "scheduler", slices, task_collisions) as sim.cluster:
            compile_kernels(sim)
            if stop.start_running():
                raise KeyboardInterrupt
            run_to_file(sim, path, progress=bar, should_stop=stop, force=force,
                        report=lambda message: warnings.warn(message, RuntimeWarning, stacklevel=3))
        if stop():
            raise KeyboardInterrupt(f"interrupted; {output} holds the records so far (complete = false)")
        return Run.open(path)
    finally:
        if hasattr(bar, "close"):
            bar.close()


def open(path):   # noqa: A001 - the SPEC's name
    """A run file read back -> :class:`Run`. Raises :class:`FileError` if ``path`` is not an rbx run file."""
    from .runfile import Run
    return Run.open(os.fspath(path))


def _progress(progress):
    if progress is True:
        from .cli.common import Progress
        return Progress("simulate", delay=0.5)
    if progress is False or progress is None:
        return None
    if callable(progress):
        return progress
    raise TypeError("progress: True, False or a callable progress(done, total)")


# ---- running into a file: shared with `rbx simulate` -------------------------------------------------------------

def check_target(path, force, experiment, key="output", file=None, force_hint="force=True", partial_ok=False,
                 size_key=None):
    """Refuse to write ``path`` (see :func:`rbx.runfile.check_target`), or a run whose file would exceed
    ``output.max_size`` or the free disk space (:func:`rbx.runfile.check_size`): raises :class:`FileError`."""
    from .runfile import check_size
    from .runfile import check_target as check
    check(path, force, key, file=file,
          config_source=(experiment.source,) + tuple(experiment.includes) if experiment is not None else None,
          partial_ok=partial_ok, force_hint=force_hint)
    if experiment is not None:
        check_size(experiment, path, size_key)


def compile_kernels(sim):
    """Compile (or load from the cache) the kernels now, while Ctrl-C can still abort at once: a first compile
    takes several seconds, and once the run has started a signal is only seen between blocks. (Not for a run on
    a cluster: its workers compile, the client never runs a kernel.)"""
    if sim.cluster is None:
        sim.advance(0, sim.block_buffers(0))   # no trajectory is below collision 0: nothing moves


def cluster_for(scheduler, key, slices=None, task_collisions=None):
    """A context manager giving the :class:`rbx.cluster.Cluster` of ``scheduler`` (connected now, closed at the
    end), or None when ``scheduler`` is None (a local run). Raises :class:`rbx.cluster.SchedulerUnreachable`
    naming ``key``."""
    if scheduler is None:
        return contextlib.nullcontext(None)
    from .cluster import connect
    return connect(scheduler, key=key, slices=slices, task_collisions=task_collisions)


def run_to_file(sim, path, *, progress=None, should_stop=None, report=None, force=False):
    """Run a new ``sim`` into ``path`` through ``path.partial`` -> True if it finished (see
    :func:`rbx.runfile.stream`; ``force``: replace an existing ``path``). Raises :class:`FileError` if the file
    cannot be created, OSError if writing fails midway (the file then holds what was written, ``complete =
    False``)."""
    from .runfile import FileError, create, stream, temporary_path
    tmp = temporary_path(path)
    try:
        h5 = create(path, force=force)
    except OSError as exc:
        raise FileError(tmp, None, f"cannot write: {exc.strerror or exc}") from None
    return stream(sim, h5, tmp, path, fresh=True, progress=progress, should_stop=should_stop, report=report,
                  replace=force)


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
        hook = sys.unraisablehook

        def quiet(unraisable):
            # the KeyboardInterrupt of a signal that came while Numba's compiler ran a ctypes callback (LLVM's
            # object cache): Python prints it as "Exception ignored …" with a traceback, then the compile fails and
            # the command reports the interrupt in its one line
            if self.signum and isinstance(unraisable.exc_value, KeyboardInterrupt):
                return
            hook(unraisable)
        sys.unraisablehook = quiet
        try:
            yield
        finally:
            sys.unraisablehook = hook
            for s, h in old.items():
                signal.signal(s, h)
