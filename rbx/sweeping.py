"""Running a study (:mod:`rbx.study` reads and checks it): ``rbx sweep``, :func:`sweep`; docs/studies.md.

Points run one after the other in this process, each on the engine's thread pool (or a Dask cluster:
``scheduler=``); :func:`run_point` runs one point and measures every observable. The results file (NetCDF,
h5netcdf) is rewritten atomically as points finish (spaced so that the writes take at most a twentieth of the run:
:data:`WRITE_SPACING`) as ``OUT.partial`` and renamed to ``OUT`` at the end; ``resume=True`` computes only the
points it lacks, and refuses a study whose canonical text changed (``study_digest``).
"""
import contextlib
import errno
import functools
import io
import json
import math
import os
import signal
import threading
import time
import warnings
from collections.abc import Mapping

import numpy as np

from . import __version__, observables as obs
from .analysis import scene_title, starts_phrase
from .api import cluster_for, flag, simulate
from .cluster import ClusterError, SchedulerUnreachable, connect
from .ensembles import distinct_orbits, start_groups
from .driver import OWN_SUFFIXES
from .dynamics import NothingMeasured, lyapunov
from .histogram import return_experiment
from .locks import LockNotWritable, acquire_lock, release_lock
from .model import ConfigError
from .paths import (ANY, NOT_WRITABLE, DiskFull, FileError, check_own_file, check_own_kind, check_own_names, check_own_objects,
                    check_replaceable, create_own, display_path, file_id, other_commands_file, place, shortened,
                    shortened_pair,
                    check_path_text, own_item, stop_signals, stored_text, what_it_is)
from .runfile import provenance
from .simulation import STATE_BYTES, memory_problem, memory_refusal, records_bytes
from .study import MAX_POINTS, Study, _representatives, load_study, needs

#: the layout of a study's results file, in its root attribute ``rbx_study``: a file of another is refused, not read
RESULTS_FORMAT = 1

__all__ = ["sweep", "run_point", "StudyInterrupted", "kept_points", "partial_path", "study_title"]


# ---- running ------------------------------------------------------------------------------------------------------

def run_point(study, point, scheduler=None):
    """Run one point and measure every observable -> ({name: Value}, collisions, seconds)."""

    need = needs(study)
    began = time.perf_counter()
    # copies of one orbit are run once: the values are the same, and their errors are not shrunk by the copies
    exp = distinct_orbits(study.experiment(point, need["fields"], need["every"]))
    runs = obs.PointRuns(exp)
    collisions = 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)     # repeated orbits: the study's numbers say it
        if need["simulate"]:
            runs.run = simulate(exp, scheduler=scheduler)
            collisions += int(np.sum(runs.run.final["collisions"]))
        if need["tangent"]:
            try:
                runs.lyapunov = lyapunov(exp, segments=need["segments"], warmup=need["warmup"],
                                         scheduler=scheduler)
                collisions += int(np.sum(runs.lyapunov.collisions))
            except NothingMeasured:
                # every orbit left the table during its warm-up (an exit as large as a wall, a long warm-up), or
                # too few segments were measured for an error: this point has no exponent (NaN, the figure and
                # a warning after the run say why), and the study goes on to the others
                pass
        if need["returns"]:
            with cluster_for(scheduler, "scheduler") as on:
                runs.returns = return_experiment(exp, cluster=on)
            collisions += int(np.sum(runs.returns.collisions))
    values = {name: (obs.Value(math.nan, math.nan) if obs.get(name).tangent and runs.lyapunov is None
                     else obs.get(name).compute(runs, options)) for name, options in study.measure}
    if need["tangent"]:
        values["lyapunov_regular"], values["lyapunov_orbits"] = (
            (0, 0) if runs.lyapunov is None else runs.lyapunov.regular(_threshold(study)))
    return values, collisions, time.perf_counter() - began


def _threshold(study):
    """The own λ₁ below which an orbit counts as regular: regular_share's threshold when measured, else its
    default."""
    return float(dict(study.measure).get("regular_share", {}).get("threshold", obs.REGULAR_THRESHOLD))


# ---- the results file -----------------------------------------------------------------------------------------------

def _empty(study, exp0):
    """The results dataset with every number NaN and ``done`` False."""
    import xarray as xr
    dims, shape = study.dims, study.shape
    coords = {}
    for i, (k, v) in enumerate(zip(study.keys, study.values)):
        dim = dims[0] if study.zip else dims[i]
        coords[k] = xr.Variable((dim,), v, {"units": _key_unit(k), "long_name": k})
    data = {}
    extra = {}
    for name, options in study.measure:
        rec = obs.get(name)
        if rec.coords is not None:
            extra.update(rec.coords(exp0))
        vdims = dims + ((rec.dim,) if rec.dim else ())
        vshape = shape + ((len(extra[rec.dim]),) if rec.dim else ())
        data[name] = xr.Variable(vdims, np.full(vshape, np.nan), {"units": rec.unit, "description": rec.description,
                                                                  "options": json.dumps(options)})
        data[f"{name}_stderr"] = xr.Variable(vdims, np.full(vshape, np.nan),
                                             {"units": rec.unit, "description": f"{rec.error} of {name}"})
        for c in rec.companions:
            if c.dim and not (name == "lyapunov" and options.get("spectrum")):
                continue
            cdims = dims + ((c.dim,) if c.dim else ())
            cshape = shape + ((len(extra[c.dim]),) if c.dim else ())
            data[f"{name}_{c.suffix}"] = xr.Variable(cdims, np.full(cshape, np.nan),
                                                     {"units": c.unit, "description": c.description})
    for dim, vals in extra.items():
        coords[dim] = xr.Variable((dim,), np.asarray(vals, dtype=str) if np.asarray(vals).dtype == object
                                  else np.asarray(vals))
    if needs(study)["tangent"]:
        thr = _threshold(study)
        data["lyapunov_orbits"] = xr.Variable(dims, np.zeros(shape, np.int64), {
            "units": "trajectory", "description": "trajectories whose own λ₁ was measured (those that left the "
                                                  "table before any collision was counted have none)"})
        data["lyapunov_regular"] = xr.Variable(dims, np.zeros(shape, np.int64), {
            "units": "trajectory", "threshold": thr,
            "description": f"of those, the regular ones: own λ₁ below {thr:g} per unit time (the point's λ₁ "
                           "pools them with the chaotic ones)"})
    counted = ("collisions the point's numbers count, over all its runs (a Lyapunov run's warm-up is not counted, "
               "and a run whose orbits all left during it counts 0)")
    data["collisions"] = xr.Variable(dims, np.zeros(shape, np.int64), {"units": "collision", "description": counted})
    data["wall_time"] = xr.Variable(dims, np.full(shape, np.nan), {"units": "s", "description":
                                                                    "wall-clock time of the point"})
    data["seed"] = xr.Variable(dims, np.zeros(shape, np.int64), {"description": "run.seed of the point"})
    data["done"] = xr.Variable(dims, np.zeros(shape, np.int8), {"description": "1: the point is computed"})
    ds = xr.Dataset(data, coords=coords)
    ds.attrs.update(_attrs(study, exp0))
    return ds


def _key_unit(key):
    if key in obs.PARAMETERS:
        return obs.PARAMETERS[key][2]
    return "L" if key.startswith("table.") else "1"


_PUNCT = "(),;:"


def study_title(study, exp0=None):
    """What the whole study shows: the scene's title (:func:`rbx.analysis.scene_title`) with each word that
    changes from point to point given as its range over the points ('κ = 0.05–1'), then the varied keys and their
    ranges ('ball.inertia: 8 values, 0.05–1') -> str. (The first point's title alone named its κ as the study's.)"""
    need = needs(study)
    # the words that change from point to point, read off the points that stand for the study (each value of each
    # key of a large grid once: building all 10⁵ configs of one took 67 s before its first point)
    experiments = [study.experiment(p, need["fields"], need["every"]) for p in _representatives(study)[0]]
    titles = [scene_title(e) for e in experiments]
    words = [t.split(" ") for t in titles]
    if len({len(w) for w in words}) == 1:
        merged = []
        for column in zip(*words):
            if len(set(column)) == 1:
                merged.append(column[0])
                continue
            core = [w.strip(_PUNCT) for w in column]
            head = column[0][:len(column[0]) - len(column[0].lstrip(_PUNCT))]
            tail = column[0][len(column[0].rstrip(_PUNCT)):]
            try:
                nums = [float(w) for w in core]
                span = f"{min(nums):g}–{max(nums):g}"
            except ValueError:
                span = "/".join(dict.fromkeys(core))
            merged.append(head + span + tail)
        scene = " ".join(merged)
    else:                 # the description changes shape from point to point: name the first and say so
        scene = f"{titles[0]} (at the first point)"
    varied = []
    for key, values in zip(study.keys, study.values):
        nums = [float(v) for v in values if isinstance(v, (int, float)) and not isinstance(v, bool)]
        span = f"{min(nums):g}–{max(nums):g}" if len(nums) == len(values) and len(values) > 1 else \
            ", ".join(str(v) for v in values)
        varied.append(f"{key}: {len(values)} value{'s' if len(values) != 1 else ''}, {span}")
    starts = dict.fromkeys(starts_phrase(e) for e in experiments)
    return (f"{scene} · {'/'.join(starts)}\nvaried{' together' if study.zip and len(study.keys) > 1 else ''}: "
            + "; ".join(varied))


def _attrs(study, exp0):
    """The results file's attributes. ``ensemble_orbits``: how many distinct orbits each point's ensemble holds (its
    trajectories, unless fixed starts with no random numbers repeat each other: a study's figure says so)."""
    p = provenance()
    groups = start_groups(exp0)
    orbits = study.ensemble["trajectories"] if groups is None else int(len(np.unique(groups)))
    values = {"rbx_study": RESULTS_FORMAT, "study": study.source, "study_canonical": study.text, "study_digest": study.digest,
            "study_file": study.file or "", "title": study_title(study, exp0), "varied": json.dumps(study.keys),
            "zip": int(study.zip), "measure": json.dumps([n for n, _ in study.measure]),
            "ensemble_trajectories": study.ensemble["trajectories"], "ensemble_orbits": orbits,
            "ensemble_collisions": study.ensemble["collisions"], "ensemble_seed": study.ensemble["seed"],
            "rbx_version": __version__, "numba_version": p["numba_version"], "numpy_version": p["numpy_version"],
            "python_version": p["python_version"], "created": p["created"], "host": p["host"],
            "command": p["command"], "complete": 0}
    return {k: stored_text(v) if isinstance(v, str) else v for k, v in values.items()}


def _store(ds, index, study, values, collisions, seconds, seed):
    # into the variables' arrays by position (xarray's labelled assignment took 13 ms a point)
    at = tuple(int(i) for i in index)

    def put(name, x):
        ds[name].values[at] = x
    for name, _ in study.measure:
        v = values[name]
        put(name, v.value)
        put(f"{name}_stderr", v.stderr)
        for suffix, x in v.companions.items():
            key = f"{name}_{suffix}"
            if key in ds:
                put(key, x)
    for name in ("lyapunov_orbits", "lyapunov_regular"):
        if name in values and name in ds:
            put(name, values[name])
    put("collisions", collisions)
    put("wall_time", seconds)
    put("seed", seed)
    put("done", 1)


#: the results file is rewritten after a finished point once the points since the last write (or since the start)
#: took this many times as long as a write (and at the end): writing it after every point cost 0.2 s a
#: point, more than a point of 10⁶ collisions (0.14 s); so the writes cost at most 1/20 of the run, and a kill
#: loses at most the points of the last ~20 writes' time, which --resume runs again (the same numbers)
WRITE_SPACING = 20
#: what a write is taken to cost before this process has timed one (8 points of one observable: 16 ms CPU, 40 ms
#: wall here); so the first write comes after a second of points, not after the first point: written after the
#: first point of 10⁶ collisions, it made a study 1.11 times as long as one run of the same collisions (CPU)
FIRST_WRITE_COST = 0.05
_write_cost = None          # the last write's time in this process


def _write(ds, path):
    """Write ``ds`` to ``path`` atomically: made in memory, written to a temporary file in the same folder,
    flushed to disk, renamed. A write that fails (a full disk, a file-size limit) leaves ``path`` as it was and
    raises :class:`rbx.paths.DiskFull` (HDF5 itself never meets the failure: made on the disk, a full disk gave an
    h5py traceback, then a segmentation fault as the half-written file was closed)."""
    global _write_cost
    began = time.perf_counter()
    tmp = f"{path}.tmp"
    image = io.BytesIO()
    _to_netcdf(ds, image)
    made = False
    try:
        fd = create_own(tmp)         # never through a link or into a FIFO someone put at this name
        made = True
        with open(fd, "wb") as fh:
            fh.write(image.getbuffer())
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except FileExistsError:
        raise FileError(display_path(tmp), None, "appeared while the study ran (not made by rbx): rbx writes nothing "
                                                 "through it; remove it and run the study again (--resume keeps the "
                                                 "points written before)") from None
    except OSError as exc:
        # a full disk or a size limit; or the folder removed or made read-only while the study ran (a traceback)
        if made:
            with contextlib.suppress(OSError):
                os.remove(tmp)
        size = _bytes_text(len(image.getbuffer()))
        folder = os.path.dirname(os.path.abspath(path))
        denied = exc.errno in NOT_WRITABLE
        if not os.path.isdir(folder):
            kept = (f"its folder {display_path(folder)} is gone (removed while the study ran?): nothing of the "
                    "study is kept")
        elif denied:                            # not the room: the folder (made read-only while the study ran?)
            kept = (f"its folder {display_path(folder)} cannot be written; "
                    + (f"{display_path(path)} is as it was: once the folder can be written, continue with --resume"
                       if os.path.exists(path) else "nothing of the study was on disk yet, so no point is kept"))
        elif exc.errno == errno.EFBIG:          # a file-size limit, not the disk
            kept = ((f"{display_path(path)} is as it was (a write makes a whole new copy, {size}, beside it): "
                     "raise the limit and continue with --resume") if os.path.exists(path) else
                    f"nothing of the study was on disk yet, so no point is kept (its results need {size}): raise "
                    "the limit and run the study again")
        elif os.path.exists(path):
            kept = (f"{display_path(path)} is as it was (a write makes a whole new copy, {size}, beside it before "
                    "replacing it, so it needs that much free): free some room and continue with --resume")
        else:
            kept = (f"nothing of the study was on disk yet, so no point is kept (its results need {size} free): "
                    "free some room and run the study again")
        why = exc.strerror or str(exc)
        if exc.errno == errno.EFBIG:            # not the disk: said as rbx simulate and rbx histogram say it
            why += ": a file-size limit (ulimit -f?)"
        raise DiskFull(f"{display_path(path)}: cannot write the study's results ({why}); " + kept) from None
    _write_cost = time.perf_counter() - began


def _bytes_text(n):
    """A size for people: ``14.5 kB``, ``3.2 MB``."""
    for factor, unit in ((1e9, "GB"), (1e6, "MB"), (1e3, "kB")):
        if n >= factor:
            return f"{n / factor:.3g} {unit}"
    return f"{n} bytes"


def _to_netcdf(ds, path):
    """``ds`` into a new NetCDF-4 file at ``path`` through h5netcdf, each variable as it is (xarray reads it back
    identical, tested): a third cheaper than ``Dataset.to_netcdf``, whose encoding pass (fill values, chunks,
    CF conventions) the results' plain arrays do not need (8 points: 15 → 10 ms CPU, the study's last write)."""
    import h5netcdf
    import h5py
    with warnings.catch_warnings(), h5netcdf.File(path, "w", invalid_netcdf=True) as f:
        warnings.simplefilter("ignore", UserWarning)        # "invalid netcdf features": a dotted name, a flag
        f.attrs.update(ds.attrs)
        for dim, size in ds.sizes.items():
            f.dimensions[dim] = size
        for name, var in ds.variables.items():
            data = np.asarray(var.values)
            if data.dtype.kind in "OU":                     # text (wall names): HDF5 variable-length strings
                out = f.create_variable(name, var.dims, dtype=h5py.string_dtype(), data=data.astype(object))
            else:
                out = f.create_variable(name, var.dims, data=data)
            out.attrs.update(var.attrs)


def read_results(path):
    """A study's results file -> :class:`xarray.Dataset`, loaded. Only a regular file is opened (a FIFO held the
    open for ever), and a variable no study writes (a dataset added by hand) is refused before anything is loaded
    (it ended the figure in a traceback, and a large one was read whole first)."""
    import stat as stat_
    import xarray as xr
    if not stat_.S_ISREG(os.stat(path).st_mode):
        raise FileError(path, None, f"is {what_it_is(path)}, not a regular file: not a study's results")
    import h5py
    with h5py.File(path, "r", locking=False) as f:
        version = f.attrs.get("rbx_study")
        if version is not None and not _is_format(version):
            shown = shortened(repr(np.asarray(version).tolist()))
            raise FileError(path, "rbx_study", f"is {shown}: this rbx reads the results format {RESULTS_FORMAT} (a "
                                               "file of another version of rbx, or edited)")
        check_own_objects(path, f, "a study's results hold their own (the file was changed after rbx wrote it)")
        _check_sizes(path, f)
    # phony_dims: a variable without dimension scales is named in a refusal, not warned about by the reader
    with xr.open_dataset(path, engine="h5netcdf", phony_dims="access") as ds:
        try:
            varied = set(json.loads(str(ds.attrs.get("varied", "[]"))))
        except (ValueError, TypeError, RecursionError):
            varied = set()          # said where the attribute is read
        for name in ds.data_vars:
            if str(name) not in varied and not _written_variable(str(name)):
                raise FileError(path, str(name), "is a variable rbx sweep does not write: the file was changed "
                                                 "after rbx wrote it")
        return ds.load()


def _is_format(value):
    """The root attribute ``rbx_study`` names the results format this rbx writes and reads (:data:`RESULTS_FORMAT`;
    NetCDF stores the number as an array of one)."""
    a = np.asarray(value)
    return a.ndim <= 1 and a.size == 1 and a.dtype.kind in "iu" and int(a.reshape(())) == RESULTS_FORMAT


def _check_sizes(path, f):
    """Refuse (:class:`FileError`) a results file (``f``, open) larger once read than any study's: a file of 7 kB can
    declare 2·10⁹ points (its chunks never written), which reading it allocated (15 GiB per variable, the coordinates
    before anything else). No dimension may be longer than :data:`MAX_POINTS`, nor all the variables together
    larger than the memory this process may have."""
    import h5py
    shapes = {name: (item.shape, item.dtype.itemsize) for name, item in f.items() if isinstance(item, h5py.Dataset)}
    for name, (shape, _) in shapes.items():
        if shape and max(shape) > MAX_POINTS:     # no key takes more values, no table has as many walls
            raise FileError(path, name, f"has a dimension of {max(shape)}; a study has at most {MAX_POINTS} points: "
                                        "the file was changed after rbx wrote it")
    problem = memory_problem(1, sum(int(np.prod(shape, dtype=np.float64)) * size for shape, size in shapes.values()))
    if problem:
        raise FileError(path, None, f"its variables would not fit in memory ({problem})")


#: the variables every study writes besides its observables' (:func:`_empty`)
_EVERY_STUDY = frozenset({"collisions", "wall_time", "seed", "done", "lyapunov_orbits", "lyapunov_regular"})


def _written_variable(name):
    """Whether a study can write a data variable named ``name``: one of :data:`_EVERY_STUDY`, an observable, its
    standard error or one of its companions (the registry of observables, :mod:`rbx.observables`)."""
    if name in _EVERY_STUDY or name in obs.REGISTRY:
        return True
    return any(name == f"{o}_stderr" or any(name == f"{o}_{c.suffix}" for c in rec.companions)
               for o, rec in obs.REGISTRY.items())


def partial_path(output):
    return f"{output}.partial"


def sweep(study, output=None, *, scheduler=None, resume=False, force=False, progress=None, base=None,
          trajectories=None, collisions=None, sets=None):
    """Run a study -> :class:`xarray.Dataset` (docs/studies.md).

    ``study``: a study file or mapping (``base=``: the file or folder a mapping's relative paths start from);
    ``trajectories``, ``collisions`` replace its ``ensemble`` entries and ``sets`` (``{dotted config key: value}``)
    changes the base at every point after the study's own ``set``, as ``rbx sweep --trajectories M --collisions N
    --set KEY=VALUE`` do (a shipped study shortened without copying it; checked as they are, an error naming such
    a key ``--set KEY``; part of the study's digest, so a resume gives them again);
    ``output``: the results file (NetCDF via h5netcdf), committed after every point as ``output.partial`` and
    renamed at the end; an existing one is refused unless ``force`` (start again) or ``resume`` (compute only
    the points it lacks; a study whose canonical text changed is refused). ``scheduler``: a Dask scheduler
    address, scheduler file or ``distributed.Client`` that every point's runs use (the same numbers as a local
    run). ``progress(done, total)``: called after each point. A bad study raises :class:`rbx.ConfigError`.

    The results file is written under the run lock ``output.lock`` that ``rbx simulate`` takes too: a second
    sweep, or a run, writing the same file is refused, naming the one that holds it."""
    changes = {"sets": sets, "ensemble": {"trajectories": trajectories, "collisions": collisions}}
    force, resume = flag("force", force), flag("resume", resume)
    if progress is not None and not callable(progress):
        raise TypeError(f"rbx.sweep: progress is a callable progress(done, total) or None, not {progress!r}")
    if base is not None and not isinstance(base, (str, os.PathLike)):
        raise TypeError(f"rbx.sweep: base is the file or folder a mapping's paths start from, not {base!r}")
    if study is None or not isinstance(study, (str, bytes, os.PathLike, Mapping, Study)):
        raise TypeError(f"rbx.sweep: study is a study file's path, a mapping or a loaded Study, not "
                        f"{type(study).__name__}")
    if isinstance(study, bytes):         # a path in bytes, as rbx.open and rbx.simulate take one
        study = os.fsdecode(study)
    if isinstance(study, Study) and (sets or trajectories is not None or collisions is not None):
        raise TypeError("rbx.sweep: trajectories, collisions and sets change a study file or mapping, not a loaded "
                        "Study (give them to load_study)")
    if sets is not None and not isinstance(sets, Mapping):
        raise TypeError(f"rbx.sweep: sets is a mapping {{'ball.inertia': 0.2, …}}, not {type(sets).__name__}")
    for key in sets or ():      # {1: 2} ended in "unsupported operand type(s) for +: 'int' and 'str'"
        if not isinstance(key, str):
            raise TypeError(f"rbx.sweep: the keys of sets are dotted config keys such as 'ball.inertia', not "
                            f"{key!r} ({type(key).__name__})")
    if output is None:
        return _sweep(study, None, scheduler, resume, force, progress, base, changes)
    if not isinstance(output, (str, bytes, os.PathLike)):
        raise TypeError(f"rbx.sweep: output is a file path (a str or os.PathLike), not {type(output).__name__}")
    given = os.fsdecode(os.fspath(output))
    check_path_text(given, "output")
    if not given.strip() or given.endswith(os.sep) or os.path.isdir(given):
        # '' and a folder were taken as the folder's own name: every point ran, then the results and the lock went
        # beside it, in the folder above ('/' as output: '/.partial'), and the end said the disk was full
        raise FileError(None, "-o", "an empty file name" if not given.strip() else
                        f"{given} is a folder: give the results a file name, such as results.nc")
    output = os.path.abspath(given)        # a bytes path is the path it names
    _check_not_own_name(output)
    check_own_names(output)        # a FIFO named as the lock would block its read
    try:
        acquire_lock(output)
    except LockNotWritable as exc:
        partial = partial_path(output)
        if resume and os.path.exists(partial):
            # the finished points are in the .partial; a sweep resumes only beside its output: say how to go on
            raise FileError(partial, None, f"cannot be resumed in place: its folder cannot be written ({exc.problem})"
                                           f"; copy it to a writable folder and resume there: rbx sweep STUDY -o "
                                           f"FOLDER/{os.path.basename(output)} --resume") from None
        raise
    try:
        return _sweep(study, output, scheduler, resume, force, progress, base, changes)
    finally:
        release_lock(output)


def _own_results_note(output, partial, st):
    """Where ``partial`` (of another study: a killed --force run of it under this name) stands beside ``output``
    holding this study's results: a note saying so and how to keep them (the refusal said only 'the study
    changed', as if the results were lost) -> text, or ''."""
    if not os.path.isfile(output):
        return ""
    try:
        ds = read_results(output)
    except Exception:   # noqa: BLE001 - not results of this study: nothing to add
        return ""
    if ds.attrs.get("study_digest") != st.digest or "done" not in ds:
        return ""
    done, total = int(np.sum(ds["done"].values)), int(ds["done"].size)
    return (f"; {display_path(output)} holds this study's results ({done} of {total} points): to go on with them, "
            f"remove {display_path(partial)} (another study's, left by a killed run)")


def _check_not_own_name(output):
    """Refuse results named as rbx names the files beside another output (``X.nc.partial``, ``X.nc.lock``, …): a
    sweep wrote its results there, which ``--resume -o X.nc`` then took for its own unfinished results (and
    ``--force`` removed), or over a live run's lock. As ``rbx simulate`` refuses such an output."""
    for suffix, what in OWN_SUFFIXES:
        if output.endswith(suffix) and len(os.path.basename(output)) > len(suffix):
            raise FileError(None, "-o", f"{display_path(output)} is the name rbx gives "
                                        f"{display_path(output[:-len(suffix)])}'s {what}; give another name, such "
                                        "as results.nc")


def _sweep(study, output, scheduler, resume, force, progress, base, changes):
    st = load_study(study, base, **changes)      # the path of rbx sweep --set, --trajectories, --collisions
    points = st.points()
    need = needs(st)
    exp0 = st.experiment(points[0][1], need["fields"], need["every"])
    kept = records_bytes(exp0)          # a point keeps the records its observables read in memory
    refusal = memory_refusal(st.ensemble["trajectories"], records=kept)
    if refusal:         # before anything is written, and named by the study's own key
        key, problem = refusal
        raise ConfigError(st.file, f"ensemble.{key}", f"{problem}: fewer {'collisions ' if key == 'collisions' else ''}"
                                                      "per point")
    ds = None
    if output is not None:
        partial = partial_path(output)
        for p in (output, partial):      # never over the study, its base or a file they include
            for f, what in ((st.file, "the study file"), (exp0.source, "the study's base config"),
                            *((f, "a file the study's base includes") for f in exp0.includes)):
                if f and os.path.isfile(f) and os.path.exists(p) and os.path.samefile(p, f):
                    raise FileError(p, "-o", f"is {what}: give the results a file of their own, such as "
                                             "results.nc")
        for p in (output, partial):      # a run of rbx simulate under these names: never taken for the study's
            problem = other_commands_file(p, "study")
            if problem is not None:
                raise problem
        for p in (output, partial):      # a link or a device is said as what it is before a resume reads through it
            check_replaceable(p, "-o", None)
        if resume:
            source = partial if os.path.exists(partial) else output if os.path.exists(output) else None
            if source is not None:
                try:
                    ds = read_results(source)
                except FileError:
                    raise
                except Exception as exc:     # not a results file
                    raise FileError(source, None, f"cannot read as a study's results: {exc}") from None
                if ds.attrs.get("study_digest") != st.digest:
                    # what changed, where the file says it: an option given now (--collisions) reads as "the study
                    # changed", and --force would throw the finished points away
                    now = {"ensemble_trajectories": (st.ensemble["trajectories"], "--trajectories"),
                           "ensemble_collisions": (st.ensemble["collisions"], "--collisions"),
                           "ensemble_seed": (st.ensemble["seed"], "ensemble.seed")}
                    changed = [f"{key} {ds.attrs.get(key)} in the file, {value} now ({option} or the study's "
                               f"ensemble)" for key, (value, option) in now.items()
                               if key in ds.attrs and str(ds.attrs[key]) != str(value)]
                    what = changed[0] if changed else "its text, its base or a file it includes"
                    raise FileError(source, "--resume", f"the study changed since this file was started ({what}): "
                                                        "resume with the study and options it was started with, or "
                                                        "run it afresh with --force, which discards its "
                                                        f"{int(np.sum(ds['done'].values)) if 'done' in ds else 0} "
                                                        "finished points" + _own_results_note(output, partial, st))
                template = _empty(st, exp0)
                _check_resumable(ds, template, source, st, points)
                ds.attrs["study"] = template.attrs["study"]     # the study's own text as it is now (its comments)
                if source == output and int(ds["done"].values.min()) == 1:
                    return ds
        elif not force:
            for p in (output, partial):
                if os.path.lexists(p):
                    raise FileError(p, None, "exists: --force starts the study again, --resume continues it")
        for p in (output, partial):       # replaced only if a regular file rbx wrote: never a device, a FIFO, a
            check_replaceable(p, "-o", None)  # link, a study file or notes
            check_own_kind(p, "-o", None)
        # the results may replace a file at the end only if they may now: a file that appears while the study runs
        # is not replaced without --force (nor, with it, one of another kind)
        replace = force or (resume and os.path.lexists(output))
        # and a resume without --force replaces only the file it continues: another put there meanwhile is not
        replaces = ANY if force else file_id(output)
        os.makedirs(os.path.dirname(output), exist_ok=True)
    if ds is None:
        ds = _empty(st, exp0)
    done = ds["done"].values
    todo = [(i, p) for i, p in points if not done[i]]
    total, finished = len(points), len(points) - len(todo)
    stored = finished       # the finished points the results file on disk holds
    client = _client(scheduler)
    try:
        if progress is not None:
            progress(finished, total)
        written = time.perf_counter()   # when the file was last written (the start counts as one)
        for index, point in todo:
            try:
                values, collisions, seconds = run_point(st, point, scheduler=client)
            except SchedulerUnreachable as exc:
                if client is None:
                    raise
                # the cluster the study started on is lost (its scheduler killed, its workers gone): a run that
                # stopped, not a bad address
                raise ClusterError(exc.key, exc.problem) from None
            except ConfigError as exc:      # this point's experiment is refused, or measures nothing
                raise _failed_point(exc, st, index, finished, total, output) from None
            except MemoryError:
                if kept > st.ensemble["trajectories"] * STATE_BYTES:      # the records, more than the state
                    raise ConfigError(st.file, "ensemble.collisions", "the records a point keeps do not fit in this "
                                                                      "process's memory: fewer collisions per point") \
                        from None
                raise ConfigError(st.file, "ensemble.trajectories",
                                  f"{st.ensemble['trajectories']} trajectories of a point do not fit in this "
                                  "process's memory: fewer per point") from None
            _store(ds, index, st, values, collisions, seconds, st.seed(point))
            finished += 1
            if output is not None and finished < total and (
                    time.perf_counter() - written >= WRITE_SPACING * (_write_cost or FIRST_WRITE_COST)):
                _write(ds, partial)
                written, stored = time.perf_counter(), finished
            if progress is not None:
                progress(finished, total)
    except BaseException as exc:
        # the points finished since the last write are kept too (a Ctrl-C, a lost cluster, a point that failed):
        # --resume then runs only the others
        if output is not None and finished > stored:
            _write_held(ds, partial)
        if isinstance(exc, KeyboardInterrupt) and output is not None:
            raise StudyInterrupted(*kept_points(partial, st.digest)[:2], total) from None
        raise
    finally:
        if client is not None and client is not scheduler:
            client.close()
    _warn_missing_errors(st, ds)
    _warn_missing_values(st, ds)
    ds.attrs["complete"] = 1
    if output is not None:
        _write(ds, partial)
        try:
            place(partial, output, replace, check=functools.partial(check_own_file, mine="study", key="-o"),
                  only=replaces)
        except FileExistsError:
            raise FileError(output, None, "appeared while the study ran (another program?) and was not replaced; "
                                          f"the results are in {display_path(partial)}") from None
        except FileError as exc:     # a link, a FIFO, another command's file put there meanwhile: not replaced
            raise FileError(exc.file, exc.key, f"{exc.problem}; it was put there while the study ran and was not "
                                               f"replaced: the results are in {display_path(partial)}") from None
        except OSError as exc:       # the folder removed or made read-only just now
            where = (f"the results are in {display_path(partial)}" if os.path.exists(partial) else
                     "nothing of the study is kept")
            raise DiskFull(f"{display_path(output)}: cannot put the study's results in place "
                           f"({exc.strerror or exc}); {where}") from None
    return ds


def _check_resumable(ds, template, path, study=None, points=()):
    """Refuse (:class:`FileError` naming the variable) a results file to resume whose variables are not those this
    study writes, of their shapes: a file with the study's digest but ``done`` missing, of another shape or not
    0/1 (damaged, or made by hand) gave a traceback, or was taken as finished. Refused too: coordinates other than
    the study's values (compared exactly: the points computed now would be stored under the file's labels), and
    points marked done that hold a non-finite value where their observable always gives a number, a seed other
    than the study's for the point, or a non-finite wall time (their values would be kept as results)."""
    fix = "not the results of this study as rbx sweep writes them: run it afresh with --force"
    for name, var in template.variables.items():
        if name not in ds.variables:
            raise FileError(path, name, f"missing; {fix}")
        got = ds.variables[name]
        if got.dims != var.dims or got.shape != var.shape:
            raise FileError(path, name, f"has dimensions {dict(zip(got.dims, got.shape))}, where this study's "
                                        f"are {dict(zip(var.dims, var.shape))}; {fix}")
        if var.dtype.kind in "iufb" and got.dtype.kind not in "iufb":
            raise FileError(path, name, f"holds {got.dtype} values, not numbers; {fix}")
        if var.dtype.kind == "f" and got.dtype != var.dtype:   # whole numbers, or float32's rounded values
            raise FileError(path, name, f"holds {got.dtype} values where this study writes {var.dtype}; {fix}")
    done = ds["done"].values
    if not np.all((done == 0) | (done == 1)):
        raise FileError(path, "done", f"holds values other than 0 and 1; {fix}")
    for key in ("measure", "varied", "zip", "ensemble_trajectories", "ensemble_collisions", "ensemble_seed",
                "ensemble_orbits", "study_canonical"):
        # the attributes a figure of the finished file reads, and the study's own text: carried into it by the
        # resume (a file edited by hand then gave tracebacks when plotted, or named another study)
        if key in template.attrs and str(ds.attrs.get(key)) != str(template.attrs[key]):
            theirs, mine = shortened_pair(ds.attrs.get(key), template.attrs[key])
            raise FileError(path, key, f"is {theirs!r} where this study's is {mine!r}; {fix}")
    for name, var in template.coords.items():
        mine, theirs = np.asarray(var.values), np.asarray(ds[name].values)
        if mine.dtype.kind in "OUS":
            mine, theirs = mine.astype(str), theirs.astype(str)
        if theirs.dtype.kind in "iufb" and mine.dtype.kind in "iufb" or mine.dtype.kind == theirs.dtype.kind:
            equal = theirs.shape == mine.shape and bool(np.all(theirs == mine))
        else:
            equal = False
        if not equal:
            raise FileError(path, name, f"holds the values {shown_values(theirs)} where this study's are "
                                        f"{shown_values(mine)}; {fix}")
    if study is None:
        return
    finished = done.astype(bool)
    problem = value_problem(ds, [n for n, _ in study.measure], lambda i: _point_label(study, i))
    if problem is not None:
        raise FileError(path, problem[0], f"{problem[1]}; {fix}")
    seeds = np.asarray(ds["seed"].values)
    for index, point in points:
        if finished[index] and int(seeds[index]) != study.seed(point):
            raise FileError(path, "seed", f"holds {int(seeds[index])} at the point "
                                          f"{_point_label(study, index)}, where this study's seed is "
                                          f"{study.seed(point)}; {fix}")


#: variables that are shares (a value in [0, 1]); each observable's companions named ``low`` and ``high`` too
SHARES = ("regular_share", "trapped_share", "wall_share", "return_angle_ks", "trapped_share_levelled",
          "return_path_unreturned")


def value_problem(ds, measured, label=lambda index: str(tuple(int(i) for i in index))):
    """The first impossible number at a point marked done of the results ``ds`` -> (variable, what is wrong at how
    many points, naming the first with ``label(index)``), or None. Read before a resume keeps the points and before
    a figure draws them (a share of 5, a negative error bar, λ₁ = inf, −2 orbits were kept, or drawn, or ended the
    figure in a traceback): every observable's value, error and companions are NaN (no value) or finite; errors are
    ≥ 0; shares and interval bounds lie in [0, 1] with low ≤ value ≤ high; collisions and orbit counts are whole
    numbers ≥ 0, with no more regular orbits than orbits; a wall time is finite and ≥ 0; ``done`` is 0 or 1; an
    observable that is never NaN (``Observable.never_nan``) is a number; and each value is there or not as the file's own numbers say
    (``Observable.has_value``)."""
    # the layout first: every variable per point (the points' dimensions, those of done, first), of numbers; a
    # variable on another dimension, an empty one, or a done of one value ended a figure in a traceback, or named
    # another variable
    points = ds["done"].sizes
    if not points or 0 in points.values():
        return "done", f"holds {'no value per point' if not points else 'no point'} (dimensions {dict(points)})"
    for name, var in ds.data_vars.items():
        if tuple(var.dims[:len(points)]) != tuple(points) or any(var.sizes[k] != n for k, n in points.items()):
            return name, (f"has dimensions {dict(var.sizes)}, where each variable has the points' "
                          f"{dict(points)} first")
        if var.dtype.kind not in "iufb":
            return name, f"holds {var.dtype} values, not numbers"
    done = np.asarray(ds["done"].values, float)
    if not np.all((done == 0) | (done == 1)):
        bad = ~((done == 0) | (done == 1))
        return "done", f"is neither 0 nor 1 at {int(bad.sum())} points (the first: {label(np.argwhere(bad)[0])})"
    finished = done.astype(bool)

    def values(name):
        return np.asarray(ds[name].values, float).reshape(done.shape + (-1,))

    checks = [(name, np.isfinite, "is not a number") for name in measured
              if name in ds and name in obs.REGISTRY and obs.REGISTRY[name].never_nan]
    for name in measured:
        own = [v for v in ds.data_vars if v == name or v.startswith(f"{name}_")]
        checks += [(v, lambda x: np.isnan(x) | np.isfinite(x), "is infinite") for v in own]
        # every standard error: the observable's and its companions' (lyapunov_per_collision_stderr = −1 was kept,
        # then ended the figure in matplotlib's error)
        checks += [(v, lambda x: np.isnan(x) | (np.isfinite(x) & (x >= 0)), "is not an error (a number ≥ 0, or none)")
                   for v in own if v.endswith("_stderr")]
        rec = obs.REGISTRY.get(name)
        for c in rec.companions if rec is not None else ():
            if c.least is not None and f"{name}_{c.suffix}" in ds:     # Santaló's mean free path of −1 was drawn
                checks.append((f"{name}_{c.suffix}", lambda x, least=c.least: np.isnan(x) | (x >= least),
                               f"is below {c.least:g}, the least its quantity can be"))
        shares = [v for v in own if v in SHARES or (name in SHARES and v in (f"{name}_low", f"{name}_high"))]
        checks += [(v, lambda x: np.isnan(x) | ((x >= 0) & (x <= 1)), "is not a share (a number in [0, 1])")
                   for v in shares]
    whole = lambda x: np.isfinite(x) & (x >= 0) & (x == np.floor(x))     # noqa: E731
    checks += [(v, whole, f"is not a count of {what}") for v, what in
               (("collisions", "collisions"), ("lyapunov_orbits", "orbits"), ("lyapunov_regular", "orbits"))
               if v in ds]
    if "lyapunov_orbits" in ds and "ensemble_trajectories" in ds.attrs:
        most = int(ds.attrs["ensemble_trajectories"])
        checks.append(("lyapunov_orbits", lambda x: ~(x > most), f"is more than the {most} trajectories of a point"))
    if "wall_time" in ds:
        checks.append(("wall_time", lambda x: np.isfinite(x) & (x >= 0), "is not a time (a number ≥ 0)"))
    for name, ok, what in checks:
        bad = finished & ~np.all(ok(values(name)), axis=-1)
        if bad.any():
            return name, f"{what} at {int(bad.sum())} of the points marked done (the first: " \
                         f"{label(np.argwhere(bad)[0])})"
    for name in measured:
        # a NaN where the file's own numbers say the point has a value (a value removed by hand) was kept by a
        # resume, with a warning that named a cause the file contradicts
        rec = obs.REGISTRY.get(name)
        if rec is None or not rec.has_value or name not in ds:
            continue
        where, said, unsaid, *error_too = rec.has_value
        error_too = error_too[0] if error_too else not rec.error.startswith("none")

        def get(key):
            """A companion's values (``get("unreturned")``), another variable's (``lyapunov_orbits``) or an
            attribute of the study (``ensemble_trajectories``)."""
            if f"{name}_{key}" in ds:
                return values(f"{name}_{key}")
            if key in ds:
                return values(key)
            return float(ds.attrs[key])
        try:
            has = np.asarray(where(get), bool)
        except (KeyError, TypeError, ValueError):        # not in the file, or not a number: nothing says
            continue
        if has.ndim < len(done.shape) + 1:
            has = np.broadcast_to(has, done.shape + (1,))
        expected, none = finished & np.all(has, axis=-1), finished & ~np.any(has, axis=-1)
        for v in (name, f"{name}_stderr") if error_too else (name,):
            if v in ds:
                nan = np.isnan(values(v))
                for bad, what, says in ((expected & np.any(nan, axis=-1), "NaN", said),
                                        (none & ~np.all(nan, axis=-1), "a number", unsaid)):
                    if bad.any():
                        return v, f"is {what} at {int(bad.sum())} of the points marked done where the file says " \
                                  f"{says} (the first: {label(np.argwhere(bad)[0])})"
    orders = [(f"{n}_low", n) for n in measured if f"{n}_low" in ds] + \
             [(n, f"{n}_high") for n in measured if f"{n}_high" in ds]
    if "lyapunov_regular" in ds and "lyapunov_orbits" in ds:
        orders.append(("lyapunov_regular", "lyapunov_orbits"))
    for low, high in orders:
        a, b = values(low), values(high)
        bad = finished & np.any(a > b, axis=-1)         # a NaN compares False: no value is no disorder
        if bad.any():
            return low, f"is above {high} at {int(bad.sum())} of the points marked done (the first: " \
                        f"{label(np.argwhere(bad)[0])})"
    return None


def shown_values(values, most=4):
    """Up to ``most`` of ``values``, as a short list for a message."""
    shown = ", ".join(str(v) if not isinstance(v, float) else f"{v:g}" for v in values.ravel()[:most].tolist())
    return f"[{shown}{', …' if values.size > most else ''}]"


class StudyWarning(RuntimeWarning):
    """What a finished study holds that its numbers alone would not say (``rbx sweep`` prints each in one line)."""


class NoErrorBars(StudyWarning):
    """Numbers of a study stored without a standard error (one orbit in one segment): said once, after the run."""


def _warn_missing_errors(study, ds):
    """Warn once for each measured observable whose finished points hold a value and no standard error (one
    trajectory, or copies of one orbit, in one segment; energy_drift of one orbit): they were stored as NaN and drawn
    without a bar, without a word."""
    done = ds["done"].values.astype(bool)
    for name, _ in study.measure:
        err = f"{name}_stderr"
        if name not in ds or err not in ds or not obs.get(name).bars:      # a p-value has no error by design
            continue
        value = np.asarray(ds[name].values, float)[done].reshape(int(done.sum()), -1)
        bar = np.asarray(ds[err].values, float)[done].reshape(int(done.sum()), -1)
        lacking = int(np.sum(np.any(np.isfinite(value) & ~np.isfinite(bar), axis=1)))     # points (any wall, …)
        if lacking:
            warnings.warn(f"{display_path(study.file) if study.file else 'the study'}: measure.{name}: "
                          f"{lacking} of {int(done.sum())} finished points hold no standard error: one orbit per "
                          "point gives no spread to take it from (more trajectories, of distinct orbits, or more "
                          "segments where the observable takes that option)",
                          NoErrorBars, stacklevel=3)


class NoValue(StudyWarning):
    """Points of a study that ran and hold no value (NaN) for an observable that may give none (its ``missing``
    says when): said once per observable, after the run, naming the first such point."""


def _warn_missing_values(study, ds):
    """Warn once for each measured observable with finished points that hold no value at all (every orbit left
    during a Lyapunov warm-up, no exponential law in a survival, …): the study went on past them, and a NaN in a
    file or a gap in a figure should not be the only trace."""
    done = ds["done"].values.astype(bool)
    for name, _ in study.measure:
        why = obs.get(name).missing
        if name not in ds or not why:
            continue
        value = np.asarray(ds[name].values, float)
        empty = done & np.all(np.isnan(value.reshape(done.shape + (-1,))), axis=-1)
        if empty.any():
            warnings.warn(f"{display_path(study.file) if study.file else 'the study'}: measure.{name}: "
                          f"{int(empty.sum())} of {int(done.sum())} finished points are NaN (the first: "
                          f"{_point_label(study, np.argwhere(empty)[0])}): {why}", NoValue, stacklevel=3)


def _failed_point(exc, study, index, finished, total, output):
    """The error of a point that cannot be computed (a combination of values the config refuses, orbits that all
    left before being measured), naming the point and what is kept -> ConfigError. The finished points are written
    before it is raised; a --resume of the same study stops at the same point again."""
    problem = exc.problem
    if "(at the point " not in problem:
        problem += f" (at the point {_point_label(study, index)})"
    if not finished:
        return ConfigError(exc.file, exc.key, f"{problem}; no point was finished")
    if output is None:
        return ConfigError(exc.file, exc.key, f"{problem}; the {finished} of {total} points finished before it are "
                                              "lost with it (no output file keeps them: give one)")
    return ConfigError(exc.file, exc.key, f"{problem}; the {finished} of {total} points finished before it are kept "
                                          f"in {display_path(partial_path(output))} (--resume stops here again: "
                                          "change the study, which then starts afresh with --force)")


def _point_label(study, index):
    index = tuple(int(i) for i in np.atleast_1d(index))
    if study.zip:
        return ", ".join(f"{k} = {v[index[0]]}" for k, v in zip(study.keys, study.values))
    return ", ".join(f"{k} = {v[i]}" for k, v, i in zip(study.keys, study.values, index))


class StudyInterrupted(KeyboardInterrupt):
    """A study stopped by a signal: ``path`` (None: nothing of the study written) holds ``kept`` of its ``total``
    points, which ``resume=True`` (``rbx sweep --resume``) continues."""

    def __init__(self, path, kept, total):
        super().__init__(path, kept, total)
        self.path, self.kept, self.total = path, kept, total


def kept_points(path, digest=None):
    """The finished points a results file holds -> (path, number, points of its study), or (None, 0, 0) when
    there is no such file (or it is another study's, or unreadable)."""
    if not os.path.isfile(path):         # nothing there, or a FIFO or a device, which would hold the open
        return None, 0, 0
    try:
        import h5py
        # the one variable it needs, looked at as a link first (an external link is opened by the lookup), not the
        # whole file read as a resume does: that walk of a file of 200 000 objects (edited in) took 33 s after a
        # signal had stopped the study, and was a hang to whoever sent it
        with h5py.File(path, "r") as f:
            item, foreign = own_item(f, "done")          # missing: no link either
            if foreign or not isinstance(item, h5py.Dataset) or item.size > MAX_POINTS:
                return None, 0, 0
            if digest is not None and f.attrs.get("study_digest") != digest:
                return None, 0, 0
            done = np.asarray(item[()])
        return path, int(np.sum(done == 1)), int(done.size)
    except Exception:         # not a results file, or one without a readable 'done'
        return None, 0, 0


def _write_held(ds, path):
    """:func:`_write`, with SIGINT, SIGTERM and SIGHUP held off meanwhile (a second Ctrl-C would cut the write short)
    and a failure let pass: the file on disk then stays as it was (the write replaces it whole or not at all)."""
    main = threading.current_thread() is threading.main_thread()
    old = {s: signal.signal(s, signal.SIG_IGN) for s in stop_signals()} if main else {}
    try:
        _write(ds, path)
    except Exception:
        pass
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def _client(scheduler):
    """One Dask client for the whole study (each point's runs would otherwise connect anew)."""
    if scheduler is None or not isinstance(scheduler, (str, os.PathLike)):
        return scheduler
    cluster = connect(scheduler, key="scheduler")
    return cluster.client
