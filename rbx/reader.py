"""Reading rbx's HDF5 files: a run file opened and checked against its layout (:mod:`rbx.runfile` describes it),
and the one reader of its records, :class:`Run`.

:func:`open_h5` opens an existing file for reading or says why it cannot be read (not found, but its run lies in
``OUT.h5.partial``; a directory; a device; a torn file; a pending journal, applied under the run's lock or in
memory); :func:`check_layout` checks every dataset's shape and dtype before anything reads it; :class:`Run` is
the run for ``rbx plot``, ``rbx simulate --resume``, the figure scripts and the Python API (:func:`rbx.open`), and
holds a run made in memory (:func:`rbx.simulate` without ``output``) the same way; :func:`read_returns` reads the
``returns/`` group ``rbx histogram`` writes. A file that is not what the caller needs raises :class:`FileError`
(``<file>: <key>: <problem>``; the CLI prints it as one line and exits 2).
"""
import contextlib
import os

import h5py
import numpy as np
import yaml

from . import journal
from .analysis import scene_title
from .config import loads
from .locks import acquire_lock, lock_holder, release_lock
from .locks import busy as _busy
from .model import FIELD, RECORD_FIELDS, ConfigError
from .paths import (MAX_CONFIG_BYTES, FileError, check_own_objects, display_path, file_id, shortened, stored_text,
                    what_it_is)
from .progress import plural
from .runfile import (INDEX_DATASETS, REQUIRED_ATTRS, ROOT_ATTRS, SCHEMA_VERSION, STATE_GROUPS, _plain, _text,
                      is_true, latest_state, root_attrs)
from .yamlfile import FILE_KINDS


# ---- opening a file for reading ----------------------------------------------------------------------------------

def _open_h5(path, mode="r"):
    """Open an existing HDF5 file -> ``h5py.File``, or raise :class:`FileError` saying why not."""
    path = str(path)
    if not os.path.exists(path):
        partial = f"{path}.partial"
        if not path.endswith(".partial") and os.path.isfile(partial):
            holder = lock_holder(path)
            if holder is not None:      # still being written: not a run stopped or killed, and not yet readable
                raise _busy(path, holder)
            # a run stopped or killed before it was renamed to its output (a resume in place renames OUT.h5 to its
            # .partial while it runs): the records are there
            show = display_path(partial)
            raise FileError(path, None, f"file not found, but {show} holds its run, stopped or killed before it was "
                                        f"renamed: read {show}, or continue it with rbx simulate --resume "
                                        f"{display_path(path)}")
        raise FileError(path, None, "file not found")
    if os.path.isdir(path):
        raise FileError(path, None, "is a directory, not an HDF5 file")
    what = what_it_is(os.path.realpath(path))
    if what != "a regular file":       # a FIFO would block the read for ever; a device is no run
        raise FileError(path, None, f"is {what}, not a regular file: not an HDF5 file")
    if journal.pending(path):
        view = _finish_journal(path, mode)
        if view is not None:
            return view
    if journal.torn(path):
        holder = lock_holder(path)
        if holder is not None:      # a live run copying a checkpoint in: its file is locked meanwhile
            raise _busy(path, holder)
        raise FileError(path, None, "is torn: its run was killed while a checkpoint was being copied into it, and "
                                    f"the journal that finishes it ({os.path.basename(journal.journal_path(path))}) "
                                    "is gone; put that journal back beside the file, else run the config again")
    try:
        is_hdf5 = h5py.is_hdf5(path)
    except OSError as exc:
        raise FileError(path, None, f"cannot read: {exc.strerror or exc}") from None
    if not is_hdf5:
        raise FileError(path, None, _not_hdf5(path))
    try:
        return h5py.File(path, mode)
    except OSError as exc:
        holder = lock_holder(path)
        if holder is not None:      # HDF5's own lock on a file another run writes: say whose
            raise _busy(path, holder) from None
        if "unable to lock file" in str(exc):
            raise FileError(path, None, "is open in another program, which holds HDF5's lock on it (a run writing "
                                        "it?); try again when it has closed the file") from None
        if path.endswith(".partial"):
            raise FileError(path, None, f"cannot open the HDF5 file: its structure is damaged ({_first_line(exc)}), "
                                        "most likely by a kill while HDF5 was writing it; its records cannot be "
                                        "recovered: remove it and run the config again") from None
        raise FileError(path, None, f"cannot open the HDF5 file (damaged or locked by another program?): "
                                    f"{_first_line(exc)}") from None


def _not_hdf5(path):
    """What a file that is not HDF5 is, where its text says (a config, a study, a table or a boundary file, by
    their keys: :data:`rbx.yamlfile.FILE_KINDS`), and what to do with it -> the problem of a :class:`FileError`."""
    try:
        with open(path, "rb") as f:
            data = yaml.safe_load(f.read(1 << 16).decode("utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        data = None
    if isinstance(data, dict):
        keys = {str(k) for k in data}
        for name, marks, todo in FILE_KINDS.values():
            if keys & set(marks):
                return f"is {name} ({', '.join(marks)}), not a run file: {todo.rstrip(':')}"
    return "not an HDF5 file (or unreadable)"


def _finish_journal(path, mode):
    """Apply the pending journal of ``path`` (its run was killed inside a commit, after the commit point) under the
    run's lock, so that no resume writes the file meanwhile: a reader that copied the journal's pages in without it
    wrote an older checkpoint's pages over the file a resume had finished in the meantime -> None, or the file
    opened for reading with its journal applied in memory (:func:`_open_view`) where the lock cannot be taken (a
    live run holds it, a read-only folder) or the file cannot be written."""
    try:
        acquire_lock(path, warn=lambda message: None)    # a killed run's stale lock: taken over without a word
    except (FileError, OSError) as exc:      # a live run holds it, a read-only folder, no room for the lock
        if mode != "r":
            raise
        holder = lock_holder(path)
        try:
            return _open_view(path, shared=True)
        except FileError:
            if holder is not None:      # a live run: it finishes the journal itself, and names itself
                raise _busy(path, holder) from None
            raise exc from None
    try:
        if journal.pending(path):       # looked at again under the lock: a resume may have applied it meanwhile
            journal.recover(path)
    except journal.JournalError as exc:
        raise FileError(journal.journal_path(path), None, str(exc)) from None
    except OSError as exc:
        if mode == "r":       # the file cannot be written (a read-only file system): read it as finished
            return _open_view(path)
        raise FileError(path, None, "its run was killed while saving a checkpoint, and finishing that needs "
                                    f"to write the file: {exc.strerror or exc}") from None
    finally:
        release_lock(path)
    return None


def _open_view(path, shared=False):
    """Open for reading a file whose pending journal cannot be copied into it: applied in memory
    (:class:`rbx.journal.JournalView`) -> ``h5py.File``."""
    try:
        view = journal.JournalView(path, shared=shared)
    except journal.JournalError as exc:
        raise FileError(journal.journal_path(path), None, str(exc)) from None
    except OSError as exc:
        raise FileError(path, None, f"cannot read: {exc.strerror or exc}") from None
    try:
        f = h5py.File(view, "r")
    except Exception as exc:   # noqa: BLE001 - HDF5's own words on a damaged file
        view.close()
        raise FileError(path, None, f"cannot open the HDF5 file (damaged?): {_first_line(exc)}") from None
    f._rbx_journal_view = view
    return f


def _check_rbx_file(f, path, group):
    """An rbx file of a schema this rbx reads, holding ``group`` (``collisions`` or ``returns``)."""
    if group == "collisions" and "collisions" not in f and "returns" in f:
        raise FileError(path, None, "not an rbx run: it holds return angles from rbx histogram (returns/), no "
                                    "collisions/")
    missing = [a for a in REQUIRED_ATTRS if a not in f.attrs]
    if missing and not len(f.attrs) and not len(f) and path.endswith(".partial"):
        raise FileError(path, None, "holds nothing yet: its run was stopped before writing anything; remove it and "
                                    "run the config again")
    if missing:
        raise FileError(path, None, f"not an rbx run file (no root attribute '{missing[0]}')")
    if is_true(f.attrs["complete"]) is None:
        raise FileError(path, "complete", f"is {_attr(f.attrs['complete'])!r}, not true or false (a boolean): the "
                                          "attribute was changed since rbx wrote it")
    schema = f.attrs.get("schema_version", 1)
    if not (np.ndim(schema) == 0 and np.asarray(schema).dtype.kind in "iu"):
        raise FileError(path, "schema_version", f"is {_kind(schema)}, not a whole number: the attribute was changed "
                                                "since rbx wrote it")
    if int(schema) > SCHEMA_VERSION:        # before the rest: a newer rbx may write them otherwise
        raise FileError(path, "schema_version", f"is {int(schema)}: written by a newer rbx (this one reads up to "
                                                f"{SCHEMA_VERSION}); upgrade rbx")
    problem = root_attribute_problem(f.attrs)
    if problem:
        raise FileError(path, *problem)
    missing = [a for a in ROOT_ATTRS if a not in f.attrs and a != "schema_version"]
    if missing:
        raise FileError(path, None, f"not an rbx run file (no root attribute '{missing[0]}')")
    link = f.get(group, getlink=True)            # looked at as a link first: an external link opens its file
    if link is not None and not isinstance(link, h5py.HardLink):
        raise FileError(path, group, "is a link, not a group of this file: an rbx file holds its own (a crafted "
                                     "file)")
    if group not in f:
        raise FileError(path, None, f"not an rbx {'run' if group == 'collisions' else 'return-angle'} file "
                                    f"(no group '{group}/')")
    if group == "collisions":
        for k in INDEX_DATASETS:
            if k not in f["collisions"]:
                raise FileError(path, f"collisions/{k}", "not in this file (a damaged run?)")


def _is_text(v):
    """UTF-8 text (h5py hands bytes that are not UTF-8 back as lone surrogates)."""
    try:
        if isinstance(v, str):
            v.encode("utf-8")
        elif isinstance(v, bytes):
            v.decode("utf-8")
        else:
            return False
        return True
    except UnicodeError:
        return False


def _kind(v):
    """An attribute's value for a message: its type and its value, cut short."""
    x = _attr(v)
    return f"{type(v).__name__} " + (f"'{shortened(stored_text(x), 40)}'" if isinstance(x, str) else
                                     shortened(repr(x), 40))


def root_attribute_problem(attrs):
    """The first root attribute of an rbx file that is not of the kind rbx writes -> (name, what is wrong), or
    None: ``config`` UTF-8 text, ``wall_names`` a non-empty list of names (``schema_version``, a whole number, is
    checked before: :func:`_check_rbx_file`). Edited by hand, they were read as 'damaged?' in Python's words
    (``object of type 'numpy.int64' has no len()``), or blamed on another part of the file."""
    config = attrs.get("config")
    if config is not None and not _is_text(config):
        return "config", (f"is {_kind(config)}, not YAML text (UTF-8): the attribute was changed since rbx wrote "
                          "it")
    names = attrs.get("wall_names")
    if names is not None and not (np.ndim(names) == 1 and len(names) > 0 and all(_is_text(x) for x in names)):
        return "wall_names", (f"is {_kind(names)}, not the list of the table's wall names: the attribute was "
                              "changed since rbx wrote it")
    return None


def check_layout(f, path):
    """Every dataset of ``collisions/`` as the layout says (module docstring) before anything reads it: the record
    fields (T, N) + their tail in dimension n with their dtype, ``count`` (T,) integers within 0 … N, ``step``
    (N,) integers, T the config's trajectories. Raises :class:`FileError` naming the dataset. A crafted file
    (``step`` shorter than the records, ``time`` declared (1, 10¹²), ``position`` of shape (1, 5001, 7)) gave an
    IndexError, a MemoryError or a wrong picture."""
    g = f["collisions"]
    n = int(f.attrs["dimension"]) if np.ndim(f.attrs["dimension"]) == 0 else 0
    if n not in (2, 3):
        raise FileError(path, "dimension", f"is {f.attrs['dimension']!r}; the layout has 2 or 3")
    for key in ("kappa", "radius"):        # the ball's, read by the plots (κ = NaN drew an empty Birkhoff map)
        value = f.attrs.get(key)
        if value is not None and not (np.ndim(value) == 0 and np.asarray(value).dtype.kind in "iuf"
                                      and np.isfinite(value) and value > 0):
            raise FileError(path, key, f"is {value}; the layout says a positive number (a damaged or crafted "
                                       "file)")

    def fail(name, problem):
        raise FileError(path, f"collisions/{name}", f"{problem} (a damaged or crafted file)")

    for group in ("collisions",) + STATE_GROUPS:
        # a link to another file (or elsewhere in this one) is refused before it is followed: its values would be
        # read from a file rbx never wrote (an external link is opened by the mere lookup)
        if group in f and not isinstance(f.get(group, getlink=True), h5py.HardLink):
            raise FileError(path, group, "is a link, not a group of this file: a run file holds its own records (a "
                                         "crafted file)")
        if not isinstance(f.get(group), h5py.Group):
            continue
        # its values would be read from other files, which rbx never wrote (and a reader trusts)
        check_own_objects(path, f[group], "a run file holds its own (a crafted file)", f"{group}/", "dataset")
        for name in f[group]:
            if not isinstance(f[group][name], h5py.Dataset):
                raise FileError(path, f"{group}/{name}", "is not a dataset (a damaged or crafted file)")
    count, step = g["count"], g["step"]
    if count.ndim != 1 or count.dtype.kind not in "iu":
        fail("count", f"has shape {count.shape} and dtype {count.dtype}; the layout says (T,) integers")
    if step.ndim != 1 or step.dtype.kind not in "iu":
        fail("step", f"has shape {step.shape} and dtype {step.dtype}; the layout says (N,) integers")
    T, N = count.shape[0], step.shape[0]
    config = f.attrs.get("config")
    if config is not None and len(config) > MAX_CONFIG_BYTES:
        # as a config file is bounded: 80 MB of text took 44 s to parse before a plot
        raise FileError(path, "config", f"the root attribute holds {len(config) / 2**20:.3g} MiB of text, more than "
                                        f"the {MAX_CONFIG_BYTES >> 20} MiB a config may have (a damaged or crafted "
                                        "file)")
    requested = f.attrs.get("collisions_requested")
    try:
        run = (yaml.safe_load(_text(f.attrs["config"])) or {}).get("run", {})
        wanted = int(run.get("trajectories", T))
        length = run.get("collisions", requested)
    except Exception:   # noqa: BLE001 - an unreadable config is said by the reader, with its own key
        wanted, length = T, requested
    if T != wanted:
        fail("count", f"has {T} trajectories, the stored config {wanted}")
    # the run's length as asked, which a resume never changes: the stored config's run.collisions (an edited value
    # was kept, and shown as the run's)
    if requested is not None and not (np.ndim(requested) == 0 and np.asarray(requested).dtype.kind in "iu"
                                      and requested == length):
        raise FileError(path, "collisions_requested", f"is {_attr(requested)!r}, where the stored config's "
                                                      f"run.collisions is {length!r} (a damaged or crafted file)")
    for name in RECORD_FIELDS:
        if name not in g:
            continue
        ds, field = g[name], FIELD[name]
        shape = (T, N) + tuple(field.shape(n))
        if not isinstance(ds, _h5_dataset()) or ds.shape != shape:
            fail(name, f"has shape {getattr(ds, 'shape', None)}; the layout says {shape} ({T} trajectories × {N} "
                       "records, as count and step)")
        want = np.dtype(field.dtype)
        if ds.dtype.kind != want.kind or ds.dtype.itemsize != want.itemsize:
            fail(name, f"has dtype {ds.dtype}; the layout says {want}")
    c = count[...]
    if c.size and (c.min() < 0 or c.max() > N):
        fail("count", f"holds {int(c.min())} … {int(c.max())}; the layout says 0 … {N} (the records)")


def _check_step(step, every, path):
    """``collisions/step`` (read) is record × ``output.every``, as every run writes it: checked a million records
    at a time (no array as long as the file's made)."""
    for at in range(0, len(step), 1 << 20):
        part = step[at:at + (1 << 20)]
        wrong = np.flatnonzero(part != np.arange(at, at + len(part), dtype=np.int64) * every)
        if wrong.size:
            r = at + int(wrong[0])
            raise FileError(path, "collisions/step", f"holds {int(step[r])} at record {r}; the layout says record × "
                                                     f"output.every ({r * every}) (a damaged or crafted file)")


#: the kinds of numbers the saved state's arrays hold (the others are floating point)
FINAL_KINDS = {"alive": "b", "collisions": "iu", "draws": "iu", "last_wall": "iu", "last_rank": "iu"}
FINAL_WORDS = {"b": "booleans", "iu": "integers", "f": "floating-point numbers"}


def _check_final(final, T, path, walls=None):
    """The saved state read from ``final/``: one row per trajectory in every array; the state of every running
    trajectory finite, its counters not negative, its last wall one of the table's ``walls`` (or −1)."""
    for k, v in final.items():
        if np.ndim(v) == 0 or np.shape(v)[0] != T:
            raise FileError(path, f"final/{k}", f"has shape {np.shape(v)}; the layout says {T} trajectories first "
                                                "(a damaged or crafted file)")
        # 'alive' as bytes read as all False: 0 exits of 2000 were reported
        kind = np.asarray(v).dtype.kind
        want = FINAL_KINDS.get(k, "f")
        if kind not in want:
            raise FileError(path, f"final/{k}", f"has dtype {np.asarray(v).dtype}; the layout says "
                                                f"{FINAL_WORDS[want]} (a damaged or crafted file)")
    alive = np.asarray(final.get("alive", np.ones(T, bool))).astype(bool)
    for k, v in final.items():
        v = np.asarray(v)
        if v.dtype.kind == "f":
            ok = np.isfinite(v[alive]).reshape(int(alive.sum()), int(np.prod(v.shape[1:]))).all(axis=1)
            problem = "is not finite for a running trajectory"
        elif k in ("collisions", "draws"):
            ok, problem = v >= 0, "is negative"
        elif k == "last_wall" and walls is not None:
            ok, problem = (v >= -1) & (v < walls), f"names no wall of the table (0 … {walls - 1}, or −1)"
        else:
            continue
        if not np.all(ok):
            j = int(np.nonzero(alive)[0][np.argmin(ok)]) if v.dtype.kind == "f" else int(np.argmin(ok))
            raise FileError(path, f"final/{k}", f"{problem}: trajectory {j} (a damaged or crafted file)")


def _h5_dataset():
    return h5py.Dataset


def _first_line(exc):
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def _attr(v):
    """An HDF5 attribute as plain Python (text, list of text, number, bool)."""
    if isinstance(v, bytes):
        return v.decode("utf-8", "replace")
    if isinstance(v, np.ndarray):
        return [_attr(x) for x in v.tolist()]
    if isinstance(v, np.generic):
        return v.item()
    return v


def read_experiment(config_text, source):
    """The validated experiment of a stored ``config`` attribute -> :class:`rbx.model.Experiment`; a config that
    does not validate raises :class:`rbx.model.ConfigError` naming ``source`` and ``config: <key>``."""
    if not isinstance(config_text, str):
        raise ConfigError(source, "config", "the root attribute is not YAML text")
    try:
        return loads(config_text, source)
    except ConfigError as exc:
        raise ConfigError(source, f"config: {exc.key}" if exc.key else "config", exc.problem) from None


# ---- the one reader ---------------------------------------------------------------------------------------------

class Run:
    """A run: its records (the ``collisions/`` datasets of docs/reference.md §5 by name), final state and experiment.

    File-backed (:meth:`open`, :func:`rbx.open`) or in memory (:meth:`from_memory`, :func:`rbx.simulate` without
    ``output``); both behave the same. ``run.position``, ``run.time``, … are read-only numpy arrays shaped as in
    the file (trajectory axis first; rows past ``count[j]`` are NaN / −1); ``run.read(field, trajectories,
    records)`` reads a part of one. Metadata: ``count``, ``step``, ``final`` (dict of arrays), ``complete``,
    ``experiment`` (validated from the stored config), ``config`` (the stored config as a dict), ``attrs`` (the
    root attributes), ``fields`` (what was recorded), ``dimension``, ``table_kind``, ``wall_names``, ``radius``,
    ``kappa``, ``every``, ``trajectories``, ``records``, ``path`` (None in memory).

    A file-backed run opens its file for each read; ``with run: …`` keeps it open for many reads (and gives
    ``run.h5``, the open ``h5py.File``)."""

    def __init__(self, attrs, count, step, final, fields, path=None, arrays=None, experiment=None, config=None):
        self.attrs = attrs
        self.path = path
        self.count, self.step = _frozen(count), _frozen(step)
        self.final = {k: _frozen(v) for k, v in final.items()}
        self.fields = tuple(fields)
        self._arrays = {} if arrays is None else {k: _frozen(v) for k, v in arrays.items()}
        self._experiment = experiment
        self._h5, self._depth = None, 0
        self._file = None           # which file (device, inode) the path named when it was read: see _open
        self.dimension = int(attrs["dimension"])
        self.table_kind = str(attrs["table_kind"])
        self.wall_names = list(attrs["wall_names"])
        self.radius, self.kappa = float(attrs["radius"]), float(attrs["kappa"])
        self.complete = bool(attrs["complete"])
        source = path or "<run>"
        try:
            # an in-memory run is given its config already parsed (parsing it again took 2 s for 10 000 states)
            self.config = yaml.safe_load(attrs["config"]) if config is None else config
        except yaml.YAMLError:
            raise FileError(source, "config", "the root attribute is not valid YAML") from None
        if not isinstance(self.config, dict) or not isinstance(self.config.get("table"), dict):
            raise FileError(source, "config", "the root attribute has no resolved 'table' mapping")
        out = self.config.get("output")
        self.every = int((out.get("every", 1) if isinstance(out, dict) else 1) or 1)
        self.trajectories, self.records = len(self.count), len(self.step)

    # -- making one --------------------------------------------------------------------------------------------
    @classmethod
    def open(cls, path):
        """Read the run file at ``path`` (checked: an rbx run of a schema this rbx reads) -> :class:`Run`.
        Raises :class:`FileError`."""
        path = str(path)
        ident = file_id(path)
        with _open_h5(path) as f:
            try:
                _check_rbx_file(f, path, "collisions")
                g = f["collisions"]
                attrs = {k: _attr(f.attrs[k]) for k in f.attrs}
                fields = [k for k in RECORD_FIELDS if k in g]
                check_layout(f, path)
                final, _, _ = latest_state(f)
                _check_final(final, len(g["count"]), path, len(attrs["wall_names"]))
                run = cls(attrs, g["count"][...], g["step"][...], final, fields, path=path)
                run._file = ident
                try:
                    run.experiment      # checks the attributes written with the run against its stored config
                except ConfigError:     # a config this rbx does not validate: said when something needs it
                    pass
                # an unfinished run's records past its saved state may be a block a kill cut short (written before
                # the journal): a resume drops them, a reader is not refused for them
                upto = run.records if run.complete else \
                    min(run.records, 1 + int(np.max(final["collisions"], initial=-1)) // run.every) \
                    if "collisions" in final else 0
                _check_step(run.step[:upto], run.every, path)
                return run
            except FileError:
                raise
            except Exception as exc:   # a damaged file can fail on the first read rather than on opening
                raise FileError(path, None, f"cannot read the HDF5 file (damaged?): {_first_line(exc)}") from None

    @classmethod
    def from_memory(cls, experiment, sink, complete):
        """The run of ``experiment`` collected by a :class:`rbx.simulation.MemorySink` -> :class:`Run`."""
        M = experiment.run.trajectories
        arrays = sink.records
        count = np.zeros(M, np.int64) if sink.count is None else np.asarray(sink.count, np.int64)
        nrec = next(iter(arrays.values())).shape[1] if arrays else 0
        step = np.arange(nrec, dtype=np.int64) * experiment.output.every
        attrs = root_attrs(experiment, complete)
        return cls(attrs, count, step, sink.final or {}, [f for f in RECORD_FIELDS if f in arrays], arrays=arrays,
                   experiment=experiment, config=_plain(experiment.resolved))

    # -- reading -----------------------------------------------------------------------------------------------
    def _open(self):
        """The run's file, opened again for a read -> ``h5py.File``. Refused (:class:`FileError`) when another file
        has been put at its path since it was read: its records would be read beside this run's counts, steps and
        config (a run of 8 trajectories moved over one of 64 was read without a word)."""
        if self._file is not None and file_id(self.path) != self._file:
            raise FileError(self.path, None, "is another file than the one opened: it was replaced since (by "
                                             "another run?); open it again (rbx.open) to read what it holds now")
        return _open_h5(self.path)

    def __enter__(self):
        if self.path is not None:
            if self._h5 is None:
                self._h5 = self._open()
            self._depth += 1
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        if self._h5 is not None:
            self._depth -= 1
            if self._depth <= 0:
                self._h5.close()
                self._h5, self._depth = None, 0

    @property
    def h5(self):
        """The open ``h5py.File`` inside ``with run:`` (file-backed runs)."""
        if self._h5 is None:
            raise RuntimeError("run.h5 exists only inside 'with run:' for a run read from a file")
        return self._h5

    @contextlib.contextmanager
    def _reading(self):
        try:
            if self._h5 is not None:
                yield self._h5["collisions"]
            else:
                with self._open() as f:
                    yield f["collisions"]
        except (OSError, KeyError, ValueError) as exc:
            # a chunk whose Fletcher-32 checksum does not match (its bytes changed on disk), or a damaged header
            raise FileError(self.path, "collisions", f"damaged: cannot read the records ({_first_line(exc)})") \
                from None

    def require(self, fields, why):
        """Raise :class:`FileError` unless every field in ``fields`` was recorded (``why``: what needs them)."""
        missing = [f for f in fields if f not in self.fields]
        if missing:
            f = missing[0]
            raise FileError(self.path or "<run>", f"collisions/{f}",
                            f"not in this file: {why} needs {', '.join(fields)} (the run did not record it: add "
                            f"'{f}' to output.record)")

    def read(self, field, trajectories=None, records=slice(None)):
        """One recorded field for some trajectories (None: all; else a sorted list) and a record slice ->
        (len(trajectories), records, …) array."""
        self.require([field], f"reading '{field}'")
        idx = slice(None) if trajectories is None else sorted(trajectories)
        if isinstance(idx, list) and idx == list(range(idx[0], idx[-1] + 1)):
            idx = slice(idx[0], idx[-1] + 1)       # a contiguous block reads much faster than a point selection
        if self.path is None or field in self._arrays:
            data = self._arrays[field]
            return data[idx][:, records]
        with self._reading() as g:
            ds = g[field]
            start, stop, stride = records.indices(ds.shape[1])
            data = ds[idx, start:stop]
            if stride != 1:
                data = data[:, ::stride]
        self._check_values(field, data, np.arange(self.trajectories)[idx],
                           np.arange(start, stop, stride)[:data.shape[1]])
        return data

    def _check_values(self, name, data, rows, records):
        """Refuse values no run writes in what was just read (``data``: trajectories ``rows`` × ``records``): a
        number that is not finite within the records a trajectory wrote (``count``), a wall index that names no
        wall of the table, a rank below −1. Only what is read is checked, as it is read: a file is never read
        whole for it. Raises :class:`FileError` naming the dataset, the trajectory and the record."""
        if data.size == 0:
            return
        if self.complete:
            # a finished run leaves the slots past a trajectory's last record at their fill (NaN, −1); an unfinished
            # one may hold there a block a kill cut short, which a resume writes again
            past = records[None, :] >= self.count[rows][:, None]
            if past.any():
                slots = data[past].reshape(int(past.sum()), -1)       # those slots alone, in row-major order
                filled = np.isnan(slots).all(axis=1) if data.dtype.kind == "f" else (slots == -1).all(axis=1)
                if not filled.all():
                    j, r = (int(x) for x in np.argwhere(past)[int(np.argmin(filled))])
                    raise FileError(self.path, f"collisions/{name}",
                                    f"holds a value at trajectory {int(rows[j])}, record {int(records[r])}, past the "
                                    f"{int(self.count[rows[j]])} records collisions/count says it wrote; no run writes "
                                    "that (a damaged or crafted file)")
        walls = len(self.wall_names)
        if name == "time" and data.shape[1] > 1:
            # a trajectory's time never runs back (a file edited to reverse it was drawn and animated); NaN
            # differences (past a trajectory's end, or a NaN the check below names) compare False
            with np.errstate(invalid="ignore"):
                back = np.diff(data, axis=1) < 0
            if back.any():
                j, r = (int(x) for x in np.argwhere(back)[0])
                raise FileError(self.path, "collisions/time", f"runs back at trajectory {int(rows[j])}, from record "
                                                              f"{int(records[r])} ({data[j, r]:.17g}) to the next "
                                                              f"({data[j, r + 1]:.17g}); no run writes that (a "
                                                              "damaged or crafted file)")
        if data.dtype.kind == "f":
            with np.errstate(all="ignore"):
                if np.isfinite(np.add.reduce(data, axis=None)):
                    return        # a NaN or an infinity anywhere makes the sum one: one pass, no array made
            bad = ~np.isfinite(data)
            if bad.ndim > 2:
                bad = bad.any(axis=tuple(range(2, bad.ndim)))
            bad &= records[None, :] < self.count[rows][:, None]     # past count: NaN, as written
            what = "a number that is not finite"
        elif name == "wall":
            if data.min() >= -1 and data.max() < walls:
                return
            bad = (data < -1) | (data >= walls)
            what = f"a wall index the table does not have (its {walls} walls are 0 … {walls - 1}; −1 before the " \
                   "first collision)"
        elif name == "rank":
            top = self.dimension - 1        # ranks run 0 … n − 1 (−1 before the first collision and at an exit)
            if data.min() >= -1 and data.max() <= top:
                return
            bad = (data < -1) | (data > top)
            what = f"a roughness rank outside −1 … {top} (a {self.dimension}D ball)"
        else:
            return
        if bad.any():
            j, r = (int(x) for x in np.argwhere(bad)[0])
            value = data[j, r]
            shown = value.tolist() if np.ndim(value) else value.item()
            raise FileError(self.path, f"collisions/{name}", f"holds {shown} at trajectory {int(rows[j])}, record "
                                                             f"{int(records[r])}: {what}; no run writes that (a "
                                                             "damaged or crafted file)")

    def __getattr__(self, name):
        if name in FIELD and not name.startswith("_"):
            if name not in self.fields:
                raise AttributeError(f"{self.path or 'this run'}: the run did not record '{name}' (recorded: "
                                     f"{', '.join(self.fields) or 'nothing'}; add it to output.record)")
            if name not in self._arrays:
                with self._reading() as g:
                    try:
                        data = g[name][...]
                    except MemoryError:
                        raise FileError(self.path, f"collisions/{name}",
                                        f"{g[name].nbytes / 1e9:.3g} GB do not fit in the free memory: read a part "
                                        f"with run.read('{name}', trajectories, records)") from None
                self._check_values(name, data, np.arange(self.trajectories), np.arange(self.records))
                self._arrays[name] = _frozen(data)
            return self._arrays[name]
        raise AttributeError(f"'Run' object has no attribute '{name}'")

    def __dir__(self):
        return sorted(set(super().__dir__()) | set(self.fields))

    def __repr__(self):
        where = self.path or "in memory"
        return (f"<rbx.Run {where}: {self.table_kind}, {plural(self.trajectories, 'trajectory')} × "
                f"{plural(self.records, 'record')} "
                f"of {', '.join(self.fields) or 'nothing'}{'' if self.complete else ', INCOMPLETE'}>")

    @property
    def experiment(self):
        """The validated :class:`rbx.model.Experiment` of the stored config (raises ConfigError if it does not
        validate with this rbx)."""
        if self._experiment is None:
            exp = read_experiment(self.attrs["config"], self.path or "<run>")
            if list(exp.wall_names) != list(self.wall_names):   # what collisions/wall indexes: the plots read both
                raise FileError(self.path or "<run>", "wall_names",
                                f"the root attribute names {len(self.wall_names)} walls "
                                f"({shortened(', '.join(map(str, self.wall_names)))}), the stored config's table "
                                f"{len(exp.wall_names)} ({', '.join(exp.wall_names)}): a damaged or crafted file")
            check_written_with(self.path or "<run>", {"radius": self.radius, "kappa": self.kappa,
                                                      "table_kind": self.table_kind, "dimension": self.dimension}, exp)
            self._experiment = exp
        return self._experiment

    def geometry(self):
        """The shrunk table the centre moved in (:class:`rbx.geometry.Geometry`)."""
        return self.experiment.geometry()

    def scene(self):
        """A title naming the scene and rule: 'disc (R = 0.1, κ = 0.5) in a 2 × 1 rectangle · rough'."""
        return scene_title(self.experiment)

    def to_xarray(self):
        """The records as an ``xarray.Dataset`` (needs the optional extra ``rbx[xarray]``).

        One variable per recorded field with dimensions ``trajectory``, ``record`` and, for vectors and the 3D
        spin, ``axis`` (x, y[, z]); the 3D orientation matrix has ``axis`` (row: space frame) and ``axis2``
        (column: body frame). Variable ``count`` (trajectory); coordinates ``trajectory``, ``record``, ``step``
        (the collision number of each record, along ``record``), ``axis``, ``axis2``. Each variable carries
        ``units`` and ``description`` (:data:`rbx.model.FIELDS`); the dataset's attributes are the root
        attributes of the file (``config``, ``complete``, …)."""
        try:
            import xarray as xr
        except ImportError:
            raise ImportError("Run.to_xarray needs xarray: pip install 'rbx[xarray]'") from None
        n = self.dimension
        names = ["x", "y", "z"][:n]
        tails = {0: (), 1: ("axis",), 2: ("axis", "axis2")}
        data = {}
        for name in self.fields:
            f = FIELD[name]
            values = getattr(self, name)
            data[name] = xr.Variable(("trajectory", "record") + tails[len(f.shape(n))], values,
                                     attrs={"units": f.units, "description": f.description})
        units, text = INDEX_DATASETS["count"]
        data["count"] = xr.Variable(("trajectory",), self.count, attrs={"units": units, "description": text})
        coords = {"trajectory": np.arange(self.trajectories), "record": np.arange(self.records),
                  "step": ("record", self.step, {"units": "1", "description": INDEX_DATASETS["step"][1]}),
                  "axis": names}
        if n == 3 and "orientation" in self.fields:
            coords["axis2"] = names
        attrs = {k: int(v) if isinstance(v, bool) else v for k, v in self.attrs.items()}   # netCDF has no bool
        return xr.Dataset(data, coords=coords, attrs=attrs)


def _frozen(a):
    a = np.asarray(a)
    if a.flags.writeable:
        a = a.view()
        a.flags.writeable = False
    return a



def _check_returns_objects(f, path):
    """Refuse (:class:`FileError`) return angles whose ``returns/`` is not the file's own or larger than memory
    once read: an external link, a virtual or an external dataset to a FIFO held the reader for ever, and a dataset
    declared 10¹¹ samples long in a file of 650 kB (its chunks never written) ended in a MemoryError."""
    check_own_objects(path, f["returns"], "return angles hold their own (a crafted file)", "returns/", "dataset")
    total = 0
    for name, item in f["returns"].items():
        if not isinstance(item, h5py.Dataset):
            raise FileError(path, f"returns/{name}", "is not a dataset (a damaged or crafted file)")
        total += int(np.prod(item.shape, dtype=np.float64)) * item.dtype.itemsize
    from .simulation import memory_problem
    problem = memory_problem(1, total)
    if problem:
        raise FileError(path, "returns", f"its datasets would not fit in memory ({problem}; a damaged or crafted "
                                         "file)")


def read_returns(path):
    """Read a file written by ``rbx histogram`` -> dict: the ``returns/`` datasets (``angle``, ``trajectory``,
    ``collisions``, ``initial_angle``), its attributes (:data:`RETURNS_ATTRS`) and ``attrs`` (the root
    attributes). Raises :class:`FileError`."""
    path = str(path)
    with _open_h5(path) as f:
        _check_rbx_file(f, path, "returns")
        _check_returns_objects(f, path)
        g = f["returns"]
        out = {k: g[k][...] for k in g}
        out.update({k: _attr(v) for k, v in g.attrs.items()})
        out["attrs"] = {k: _attr(f.attrs[k]) for k in f.attrs}
    _check_returns_values(out, path)
    try:
        exp = read_experiment(out["attrs"]["config"], path)
    except ConfigError:         # a config this rbx does not validate: said where it is needed
        exp = None
    if exp is not None:
        check_written_with(path, out["attrs"], exp)
    return out


def check_written_with(path, attrs, exp):
    """The root attributes written with a file from its config (``attrs``: the radius, κ, table kind and
    dimension, as read) against its stored config's experiment ``exp``: the plots read the attributes (κ = 9
    coloured a Birkhoff map whose title said κ = 0.5) and a resume continues with the config. Raises
    :class:`FileError` naming the first that differs."""
    for key, expected in (("radius", exp.ball.radius), ("kappa", exp.ball.kappa), ("table_kind", exp.table_kind),
                          ("dimension", exp.dimension)):
        if key in attrs and attrs[key] != expected:
            raise FileError(path, f"config: {key}", f"is {shortened(repr(expected))} but the run was made with "
                                                    f"{shortened(repr(attrs[key]))} (root attribute '{key}'): the "
                                                    "stored config, or the attribute, was changed since rbx wrote the "
                                                    "file")


def _check_returns_values(out, path):
    """The return angles' numbers as rbx histogram writes them, each against the others and the stored config
    (:class:`FileError` naming the first that is not): K returns (``angle``, ``trajectory``, ``collisions``, each
    (K,)), ``samples`` = ``returned`` + ``not_returned`` with ``returned`` = K and ``initial_angle`` (samples,),
    angles in [0, π/2], each return a sample's index once, in order, after 1 … ``collisions_requested``
    collisions, ``velocity_dimension`` = n + n(n−1)/2, and ``wall`` the sampled wall of the config. Edited by hand,
    such files were read and drawn (a KS test 'passed' on 5000 samples of which 2000 had angles)."""
    def fail(key, problem):
        raise FileError(path, key, f"{problem} (a damaged or crafted file)")

    def whole(key):
        v = out.get(key)
        if v is None or np.ndim(v) != 0 or np.asarray(v).dtype.kind not in "iu" or v < 0:
            fail(f"returns@{key}", f"is {v!r}, not a count")
        return int(v)
    samples, returned, missing = whole("samples"), whole("returned"), whole("not_returned")
    if samples != returned + missing:
        fail("returns@samples", f"is {samples}, not returned + not_returned = {returned} + {missing}")
    for name, length in (("angle", returned), ("trajectory", returned), ("collisions", returned),
                         ("initial_angle", samples)):
        if name not in out or np.ndim(out[name]) != 1 or len(out[name]) != length:
            fail(f"returns/{name}", f"has shape {np.shape(out.get(name))}; the layout says ({length},)")
    for name in ("angle", "initial_angle"):
        a = np.asarray(out[name], dtype=float)
        if not np.all((a >= 0) & (a <= np.pi / 2)):
            fail(f"returns/{name}", "holds angles outside [0, π/2] (the angle to the wall's normal)")
    index, count = np.asarray(out["trajectory"]), np.asarray(out["collisions"])
    if index.dtype.kind not in "iu" or (index.size and (index.min() < 0 or index.max() >= samples
                                                        or np.any(np.diff(index) <= 0))):
        fail("returns/trajectory", f"is not the increasing indexes of returned samples among {samples}")
    most = out["attrs"].get("collisions_requested")
    if count.dtype.kind not in "iu" or (count.size and (count.min() < 1 or (most is not None and count.max() > most))):
        fail("returns/collisions", f"holds counts outside 1 … {most} (run.collisions)")
    n = out["attrs"].get("dimension")
    if n in (2, 3) and out.get("velocity_dimension") != n + n * (n - 1) // 2:
        fail("returns@velocity_dimension", f"is {out.get('velocity_dimension')!r}; in {n}D it is "
                                           f"{n + n * (n - 1) // 2}")
    try:
        initial = (yaml.safe_load(_text(out["attrs"]["config"])) or {}).get("initial") or {}
        wall = initial.get("wall") or "" if isinstance(initial, dict) else None
    except Exception:   # noqa: BLE001 - an unreadable config is said where it is read
        wall = None
    if wall is not None and out.get("wall") != wall:
        fail("returns@wall", f"is {out.get('wall')!r}, where the stored config samples on {wall or 'the whole boundary'!r}")
