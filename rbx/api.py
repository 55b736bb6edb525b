"""The Python API (docs/reference.md §9): :func:`load`, :func:`simulate`, :func:`open` — the same engine as the
CLI, and the same code: ``rbx simulate`` runs an experiment into a file with :func:`run_to_file` too, so the API
and the CLI write the same file bit for bit.

    >>> import rbx
    >>> exp = rbx.load("configs/examples/strip.yaml")
    >>> exp2 = rbx.load(exp, {"ball.inertia": 0.2})       # a changed copy, validated as the YAML is
    >>> run = rbx.simulate(exp, collisions=1000)          # in memory: a rbx.Run
    >>> run.position.shape                                # (trajectories, records, 2)
    >>> run = rbx.simulate(exp, output="strip.h5")        # streamed to HDF5 (OUT.h5.partial, renamed at the end)
    >>> run = rbx.open("strip.h5")                        # the same rbx.Run, read back

The running part also lives here because the CLI shares it: :class:`StopFlag` (SIGINT/SIGTERM/SIGHUP stop a run between
blocks, so the file is checkpointed and closed cleanly), :func:`run_to_file`.
"""
import contextlib
import dataclasses
import os
import signal
import sys
import threading
import warnings
from collections.abc import Mapping

import numpy as np

from . import config as cfgmod
from . import driver
from .cluster import connect
from .ensembles import repeated_orbits, seed_change, unused_seed
from .driver import check_size, prepare_resume, resume_to_file
from .model import ConfigError, Experiment
from .progress import Progress
from .reader import Run
from .paths import after_hangup, check_path_text, renaming, stop_signals, work_written
from .simulation import MemorySink, Simulation, memory_refusal, records_bytes

# nothing heavy at import: the CLI takes StopFlag from here before it installs its signal handlers
__all__ = ["load", "simulate", "resume", "open"]

_OVERRIDES = ("collisions", "trajectories", "seed", "max_size")


def load(config, overrides=None, *, base=None):
    """A validated, immutable experiment -> :class:`rbx.model.Experiment`. Raises :class:`ConfigError` whose
    message names the file and the key (the CLI prints the same message).

    ``config``: a config file (YAML), a mapping of the same sections, or an experiment to change.

    ``overrides``: ``{key: value}``, each a dotted config key, made to the config before it is validated, so
    checked exactly as the YAML is (the same as ``rbx simulate --set KEY=VALUE``)::

        rbx.load("strip.yaml", {"ball.inertia": 0.2, "initial.position": [0, 0.5], "run.collisions": 5000})
        rbx.load(exp, overrides={"boundary.walls.top": {"rule": "exit"}})

    A mapping value is merged into the mapping already there (``{"ball": {"inertia": 0.2}}`` is
    ``{"ball.inertia": 0.2}``), except one that names its kind (a rule with ``rule:``, a table with ``kind:``,
    ``{sample: billiard}``), which replaces it. An unknown key is refused with a hint ("did you mean
    'run.collisions'?"). ``collisions``, ``trajectories``, ``seed`` and ``max_size`` stand for ``run.…`` and
    ``output.max_size`` (as :func:`simulate`'s keywords; their errors name them).

    ``base``: for a mapping, the file or folder its relative paths (``table: ../tables/strip.yaml``, the output
    path) are resolved from; default: the working folder. A mapping read from a config file (``yaml.safe_load``)
    needs ``base=`` that file; ``experiment.to_dict()`` gives one with its includes inlined and its paths absolute,
    which loads from any folder.

    A seed given (``seed`` or ``run.seed``) to an experiment that draws no random numbers (fixed starts, no random
    rule) changes nothing: a RuntimeWarning says so."""
    exp = _load(config, overrides, base=base)
    _warn_unused_seed(exp, overrides, stacklevel=3)
    return exp


def _warn_unused_seed(exp, overrides, stacklevel):
    """The RuntimeWarning of a seed given (``seed``, ``run.seed``) to an experiment that draws no random numbers."""
    overrides = overrides if isinstance(overrides, Mapping) else {}
    if overrides.get("seed") is not None or seed_change(overrides):
        message = unused_seed(exp)
        if message:
            key = "seed" if overrides.get("seed") is not None else "run.seed"      # the keyword, or the dotted key
            warnings.warn(f"{exp.source}: {key}: {message}", RuntimeWarning, stacklevel=stacklevel)


def _load(config, overrides=None, *, base=None):
    """:func:`load` without its warning (a study sets run.seed at every point, whatever its base draws)."""
    if overrides is not None and not isinstance(overrides, Mapping):
        raise TypeError(f"rbx.load: overrides is a mapping {{'ball.inertia': 0.2, …}}, not "
                        f"{type(overrides).__name__}")
    changes = dict(overrides or {})
    short = {k: changes.pop(k) for k in list(changes) if k in _OVERRIDES}
    if base is not None and not isinstance(config, Mapping):
        raise TypeError("rbx.load: base= is for a mapping (a file's paths are relative to its folder, an "
                        "experiment's are resolved already)")
    if isinstance(config, Experiment):
        config.check_unchanged()        # its resolved config is what a run's file records
        if not changes and not short:
            return config
        if config.resolved is None:       # made by hand, not from a config
            if changes:
                raise ConfigError(None, next(iter(changes)), "this experiment was not made from a config: only "
                                                            f"{', '.join(_OVERRIDES)} can be changed")
            return _override_by_hand(config, short)
        return _api_keys(lambda: cfgmod.from_dict(config.resolved, config.source, short, changes=changes,
                                                  includes=config.includes))
    if isinstance(config, Mapping):
        folder = _folder(base)
        return _api_keys(lambda: cfgmod.from_dict(dict(config), overrides=short, changes=changes, base=folder))
    if isinstance(config, (str, os.PathLike)):
        return _api_keys(lambda: cfgmod.load(os.fspath(config), short, changes=changes))
    raise TypeError(f"rbx.load takes a config path, a mapping or an Experiment, not {type(config).__name__}")


def _folder(base):
    """``base=``: a file (its folder) or a folder -> the folder, or None."""
    if base is None:
        return None
    path = os.path.abspath(os.path.expanduser(os.fspath(base)))
    if os.path.isfile(path):
        return os.path.dirname(path)
    if os.path.isdir(path):
        return path
    raise ConfigError(None, "base", f"no such file or folder: {path}")


def _api_keys(make):
    """Errors in overrides name the keyword argument (``collisions``), not the CLI option (``--collisions``)."""
    try:
        return make()
    except ConfigError as exc:
        name = (exc.key or "").lstrip("-").replace("-", "_")
        if exc.file is None and exc.key and exc.key.startswith("--") and name in _OVERRIDES:
            raise ConfigError(None, name, exc.problem) from None
        raise


def _override_by_hand(experiment, overrides):
    """An experiment made without a config (no ``resolved``) with its run settings replaced."""
    run = dataclasses.replace(experiment.run, **{k: v for k, v in overrides.items() if k != "max_size"})
    output = dataclasses.replace(experiment.output, **{k: v for k, v in overrides.items() if k == "max_size"})
    return experiment.replace(run=run, output=output)


def simulate(experiment, *, collisions=None, trajectories=None, seed=None, output=None, force=False,
             progress=False, max_size=None, scheduler=None, slices=None, task_collisions=None):
    """Run an experiment (an :class:`~rbx.model.Experiment`, a config path or a dict) -> :class:`Run`.

    ``collisions``, ``trajectories``, ``seed`` override ``run.*``, ``max_size`` ``output.max_size`` (bytes or a
    text such as '50 GB'); any other key is changed with :func:`load` first (``rbx.load(exp, {'ball.inertia':
    0.2})``). An ensemble whose trajectories would all repeat one orbit (one fixed start, several trajectories,
    no random numbers drawn) gives a RuntimeWarning. With ``output=None`` the run is kept in memory;
    else it is streamed to that HDF5 file as ``rbx simulate -o`` does (written as ``output.partial``, renamed at
    the end; an existing file is replaced only with ``force=True``) and read back. ``progress``: True for a
    progress bar on stderr, or a callable ``progress(done, total)``.

    Ctrl-C (SIGINT) while a file is written stops the run between blocks: the file is closed and renamed, marked
    ``complete = False`` (``rbx simulate --resume`` continues it), then KeyboardInterrupt is raised.

    ``scheduler``: run the trajectories on the workers of a Dask cluster (docs/reference.md §11; needs
    ``rbx[cluster]``): its scheduler's address (``tcp://host:8786``), the JSON file it wrote (``--scheduler-file``)
    or a ``distributed.Client``. The result is the local run's, bit for bit. ``slices`` (tasks per round) and
    ``task_collisions`` (collisions per task) tune how the run is cut (docs/cluster.md). An unreachable scheduler
    raises :class:`rbx.cluster.SchedulerUnreachable`, a task that fails mid-run :class:`rbx.cluster.ClusterError`
    (a file then holds every round finished before, ``complete = False``)."""
    overrides = {k: v for k, v in (("collisions", collisions), ("trajectories", trajectories), ("seed", seed),
                                   ("max_size", max_size)) if v is not None}
    if isinstance(output, bytes):       # a path in bytes, as rbx.open takes one
        output = os.fsdecode(output)
    if output is not None and not isinstance(output, (str, os.PathLike)):
        raise TypeError(f"output: a file path (str, bytes or os.PathLike), got {type(output).__name__}")
    force = flag("force", force)
    exp = _load(experiment, overrides or None)
    kept = records_bytes(exp) if output is None else 0          # a run in memory keeps its records there
    refusal = memory_refusal(exp.run.trajectories, records=kept)
    if refusal:     # refused as rbx simulate refuses it, not a MemoryError after minutes of setting up
        key, problem = refusal
        given = key in overrides
        raise ConfigError(None if given else exp.source, key if given else f"run.{key}",
                          problem + ("; record fewer fields, or every k-th collision (output.every), or write a file "
                                     "(output=)" if key == "collisions" else ""))
    repeated = repeated_orbits(exp)
    if repeated:
        warnings.warn(f"{exp.source}: {repeated}", RuntimeWarning, stacklevel=2)
    _warn_unused_seed(exp, overrides, stacklevel=3)
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
        path = os.path.abspath(os.fsdecode(os.fspath(output)))
        check_path_text(path, "output")
        check_target(path, force, exp)
        sim = Simulation(exp)
        stop = StopFlag()
        with stop.installed(), cluster_for(scheduler, "scheduler", slices, task_collisions) as sim.cluster:
            sim.compile_kernels()
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


def resume(path, *, output=None, force=False, max_size=None, progress=False, scheduler=None, slices=None,
           task_collisions=None):
    """Continue the interrupted run in ``path`` to its requested length -> :class:`Run` (as
    ``rbx simulate --resume``, the same code: the records are those of an uninterrupted run, bit for bit).

    ``path``: the run's file (``OUT.h5.partial`` left by a kill, or ``OUT.h5`` marked ``complete = False``;
    ``OUT.h5`` when only ``OUT.h5.partial`` exists names that). ``output``: write the continued run there instead
    (the file read is left as it was); by default the run's own output, its ``.partial`` worked on in place.
    ``force``: replace an existing ``output``. ``max_size``: the largest file the run may reach (bytes or '50
    GB'; default: the stored ``output.max_size``). The saved state is checked against the stored config before
    anything runs. A complete run is returned as it is (a complete ``.partial`` left by a kill before its rename
    is renamed first). ``progress``, ``scheduler``, ``slices``, ``task_collisions``: as for :func:`simulate`.

    Raises :class:`FileError` or :class:`ConfigError` for a file that cannot be continued (in one line, naming
    the file and key), :class:`rbx.paths.DiskFull` when there is no room, KeyboardInterrupt after Ctrl-C (the
    file then holds the records so far, ``complete = False``)."""
    if scheduler is None and (slices is not None or task_collisions is not None):
        raise TypeError("slices and task_collisions cut a run for a cluster: give scheduler too")
    named = {}
    for name, value in (("path", path), ("output", output)):
        if value is None and name == "output":
            continue
        if not isinstance(value, (str, bytes, os.PathLike)):
            # as rbx.load does: os.fspath's own words ('expected str, bytes or os.PathLike object') or worse (a
            # bytes path: 'endswith first arg must be bytes…') came from deep inside
            raise TypeError(f"rbx.resume: {name} is the path of a run file (a str or os.PathLike), not "
                            f"{type(value).__name__}")
        named[name] = os.fsdecode(os.fspath(value))     # a bytes path as the str the rest of rbx reads
        check_path_text(named[name], name)
        if not named[name].strip():
            raise ValueError(f"rbx.resume: {name} is empty: give the path of a run file")
    path, output = named["path"], named.get("output")
    force = flag("force", force)
    r = _api_keys(lambda: prepare_resume(path, output, force=force, max_size=max_size, out_key="output",
                                         size_key="max_size", force_hint="force=True"))
    for note in r.notes:
        warnings.warn(f"{r.source}: {note}", RuntimeWarning, stacklevel=2)
    if r.state != "continue":
        return Run.open(r.path if r.state == "renamed" else r.source)
    bar = _progress(progress)
    stop = StopFlag()
    try:
        with stop.installed(), cluster_for(scheduler, "scheduler", slices, task_collisions) as r.sim.cluster:
            r.sim.compile_kernels()
            if stop.start_running():
                raise KeyboardInterrupt
            resume_to_file(r, progress=bar, should_stop=stop,
                           report=lambda message: warnings.warn(message, RuntimeWarning, stacklevel=3))
    finally:
        if hasattr(bar, "close"):
            bar.close()
    if stop():
        raise KeyboardInterrupt(f"interrupted; {r.path} holds the records so far (complete = false)")
    return Run.open(r.path)


def open(path):   # noqa: A001 - the name docs/reference.md §9 gives it
    """A run file read back -> :class:`Run`. Raises :class:`FileError` if ``path`` is not an rbx run file."""
    if not isinstance(path, (str, bytes, os.PathLike)):
        raise TypeError(f"rbx.open: path is the path of a run file (a str or os.PathLike), not {type(path).__name__}")
    path = os.fsdecode(os.fspath(path))                 # a bytes path is the path it names
    check_path_text(path, "path")
    return Run.open(path)


def flag(name, value):
    """A True/False argument -> bool; anything else is a TypeError (``force="no"`` is truthy, and replaced a run)."""
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    raise TypeError(f"{name}: True or False, not {value!r}")


def _progress(progress):
    if progress is True:
        return Progress("simulate", delay=0.5)
    if progress is False or progress is None:
        return None
    if callable(progress):
        return progress
    raise TypeError("progress: True, False or a callable progress(done, total)")


# ---- running into a file: shared with `rbx simulate` -------------------------------------------------------------

def check_target(path, force, experiment, key="output", file=None, force_hint="force=True", partial_ok=False,
                 size_key=None):
    """Refuse to write ``path`` (see :func:`rbx.driver.check_target`), or a run whose file would exceed
    ``output.max_size`` or the free disk space (:func:`rbx.driver.check_size`): raises :class:`FileError`."""
    driver.check_target(path, force, key, file=file,
                        config_source=(experiment.source,) + tuple(experiment.includes) if experiment is not None
                        else None, partial_ok=partial_ok, force_hint=force_hint)
    if experiment is not None:
        check_size(experiment, path, size_key)


def cluster_for(scheduler, key, slices=None, task_collisions=None):
    """A context manager giving the :class:`rbx.cluster.Cluster` of ``scheduler`` (connected now, closed at the
    end), or None when ``scheduler`` is None (a local run). Raises :class:`rbx.cluster.SchedulerUnreachable`
    naming ``key``."""
    if scheduler is None:
        return contextlib.nullcontext(None)
    return connect(scheduler, key=key, slices=slices, task_collisions=task_collisions)


def run_to_file(sim, path, *, progress=None, should_stop=None, report=None, force=False):
    """Run a new ``sim`` into ``path`` (:func:`rbx.driver.run_to_file`)."""
    return driver.run_to_file(sim, path, progress=progress, should_stop=should_stop, report=report, force=force)


class StopFlag:
    """SIGINT, SIGTERM or SIGHUP (:func:`rbx.paths.stop_signals`) while setting up: KeyboardInterrupt at once
    (nothing is written yet). While running: a flag that the run polls between blocks, so the file is checkpointed
    and closed cleanly.

    A second signal while running does not abort harder: the kernels hand back control only between blocks
    (well under a second each), and aborting in the middle of an HDF5 write could damage the file."""

    def __init__(self, pending=None):
        self.signum = 0
        self.running = False
        #: a callable -> the number of a signal that came before this flag's handlers were installed (0: none):
        #: the command line's own handler notes it, since the KeyboardInterrupt it raised can be lost (raised in a
        #: callback, Python drops it as "Exception ignored")
        self.pending = pending

    def __call__(self):
        return self.signum != 0

    def check(self):
        """Setting up: KeyboardInterrupt if a signal came already (one that came before the handlers were
        installed, whose own KeyboardInterrupt may have been lost)."""
        if self.signum and not self.running:
            raise KeyboardInterrupt

    def start_running(self):
        """Switch from aborting to flagging -> True if a signal came already (then abort instead)."""
        self.running = True
        return self()

    def _handler(self, signum, frame):
        after_hangup(signum)
        if work_written():          # the command's last output is in place: too late to stop it
            return
        self.signum = self.signum or signum
        if not self.running and not renaming():     # a rename under way: acted on by the next check(), after it
            raise KeyboardInterrupt

    @contextlib.contextmanager
    def installed(self):
        if threading.current_thread() is not threading.main_thread():   # signal handlers live in the main thread
            yield
            return
        old = {s: signal.signal(s, self._handler) for s in stop_signals()}
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
            came = self.pending() if self.pending is not None else 0
            self.signum = self.signum or came   # the command's check() or start_running() then stops it
            yield
        finally:
            sys.unraisablehook = hook
            for s, h in old.items():
                signal.signal(s, h)
