"""The run driver: a run into its file, from the first check to the last rename (docs/reference.md §4–5).

The file's lifecycle: the checks before anything is written (:func:`check_target`: what the output is, the
``.partial`` and lock beside it; :func:`check_size`: ``output.max_size`` and the free space, for a new run and a
resumed one alike), ``OUT.h5.partial.new`` made under the run's lock (:func:`create`, :mod:`rbx.locks`), renamed
to ``OUT.h5.partial`` once its structure is on disk (:func:`publish_new`), the run streamed into it
(:func:`stream`) and renamed to ``OUT.h5`` however it ends (:func:`publish`). :func:`run_to_file` runs a new
simulation so; :func:`prepare_resume` and :func:`resume_to_file` continue an interrupted run (the source's lock, a
copy unless it is resumed in place, the journal, the state checked against its own config,
:mod:`rbx.continuation`), for ``rbx simulate --resume`` and :func:`rbx.resume` alike.

The file's layout (what is written inside) is :mod:`rbx.runfile`'s; this module decides which file is written,
when, and under which name.
"""
import contextlib
import dataclasses
import errno
import functools
import os
import shutil
import weakref

import h5py
import numpy as np
import yaml

from . import continuation, journal
from .config import loads
from .locks import LockNotWritable, acquire_lock, lock_holder, lock_path, release_lock, taken_fresh
from .locks import busy as _busy
from .progress import plural
from .paths import (ANY, NO_ROOM, DiskFull, FileError, check_own_file, check_own_kind, check_own_names,
                    check_replaceable, copy_to_new, creation_path, display_path, file_id, format_size, other_commands_file, place,
                    shortened, temporary_path, what_it_is)
from .reader import Run
from .runfile import (PROVENANCE_ATTRS, ROOT_ATTRS, H5Sink, _text, close_journal, commit, config_yaml, data_bytes,
                      file_path, fill_returns, is_true, journal_of, open_journaled)

# ---- the .partial lifecycle --------------------------------------------------------------------------------------

#: HDF5's metadata, the root attributes (the config's text) and the dimension scales, generously
METADATA_BYTES = 512 << 10


def estimated_size(cfg):
    """Bytes a run of ``cfg`` writes, about: every chunk of every recorded field (a trajectory may end early, so
    this is the most; chunks are allocated whole, :func:`rbx.runfile.data_bytes`), the two saved states, and
    HDF5's metadata -> int."""
    return data_bytes(cfg) + METADATA_BYTES


def _nearest_folder(path):
    """The folder ``path`` is (or will be) in, or its nearest existing parent (the folder is made later)."""
    folder = os.path.dirname(os.path.abspath(path)) or "."
    while not os.path.isdir(folder) and os.path.dirname(folder) != folder:
        folder = os.path.dirname(folder)
    return folder


def free_space(path):
    """Bytes free on the disk ``path`` is (or will be) on, asking its nearest existing folder -> int, or None."""
    try:
        return shutil.disk_usage(_nearest_folder(path)).free
    except OSError:
        return None


def read_only(path):
    """True when the disk ``path`` is (or will be) on is mounted read-only: no room to ask of it."""
    try:
        return bool(os.statvfs(_nearest_folder(path)).f_flag & os.ST_RDONLY)
    except (OSError, AttributeError):
        return False


def returns_bytes(cfg):
    """Bytes the file of a return-angle experiment (``rbx histogram``) takes, at most: per sample its angle, its
    trajectory, its collisions and its initial angle (:func:`rbx.runfile.fill_returns`), and HDF5's metadata."""
    return 32 * cfg.run.trajectories + METADATA_BYTES


def check_size(cfg, path, key_file=None, written=0, option="max_size=", hint="", need=None, what=None):
    """Refuse a run whose file would be larger than ``output.max_size`` or than the free space where it goes:
    raises :class:`FileError` before anything is written. ``key_file``: (file, key) the limit is named by;
    ``written``: bytes of the file already on that disk (a run resumed in place: only the rest must fit);
    ``option``: how the caller raises the limit (``max_size=`` in Python, ``--max-size`` on the command line);
    ``hint``: what to do when the disk is short, added to that line. ``need`` and ``what``: the file's size and
    what it holds, for a file that is not a run's records (default: :func:`estimated_size` and the records)."""
    # compression: the size before it (what it saves depends on the numbers, unknown before the run)
    raw = "" if cfg.output.compression == "none" or need is not None else " before compression"
    if need is None:
        need = estimated_size(cfg)
        what = (f"{plural(cfg.run.trajectories, 'trajectory')} × "
                f"{plural(cfg.run.collisions // cfg.output.every + 1, 'record')} of {', '.join(cfg.output.record)}")
    if need > cfg.output.max_size:
        file, key = key_file or (cfg.source, "output.max_size")
        how = f"give a larger {option}" if key in ("--max-size", "max_size") else \
            f"raise output.max_size or give {option}"
        raise FileError(file, key, f"the run would write about {format_size(need)}{raw} ({what}), more than the "
                                   f"limit {format_size(cfg.output.max_size)}; {how} if that is meant")
    free = free_space(path)
    if free is None:
        return
    if need - written > free:
        if read_only(path):     # its free space is no measure of anything: it cannot be written at all
            raise FileError(path, None, f"its folder {display_path(_nearest_folder(path))} is on a read-only file "
                                        "system: give an output on a writable disk")
        more = f", {format_size(written)} of it written already," if written else ""
        raise FileError(path, None, f"the run would write about {format_size(need)}{raw}{more} but the disk has "
                                    f"{format_size(free)} free{hint}")


def _killed_partial(tmp, force_hint, what_force_does):
    """The refusal of a ``.partial`` a killed run left (no run holds its lock): how to continue that run (the CLI's
    or the API's words, by ``force_hint``), or to remove it, or to ``what_force_does`` with ``force_hint``."""
    again = (f"rbx simulate --resume {display_path(tmp)}" if force_hint.startswith("--") else
             f"rbx.resume({display_path(tmp)!r})")
    return FileError(tmp, None, f"exists, left by a run that was killed (no run holds its lock): continue that run "
                                f"with {again}; or remove it, or use {force_hint} to {what_force_does}")


def check_target(path, force, key, file=None, config_source=None, partial_ok=False, force_hint="--force",
                 mine="run"):
    """Refuse to write ``path`` when it is a folder, the config or a file it includes (``config_source``: the
    config's path, or a sequence of it and its includes), or (without ``force``) when it exists or
    a run may still be writing its ``.partial``. Raises :class:`FileError`; ``key``/``file`` name where the path
    came from (``-o``, ``output.path``, ``output``), ``force_hint`` how to force (``--force``, ``force=True``);
    ``mine``: the kind of file the caller writes (:func:`rbx.paths.rbx_kind`): another command's is never replaced."""
    show = display_path(path)
    check_own_names(path)        # before the lock is read: a FIFO named as the lock would block its read
    holder = lock_holder(path)
    if holder is not None:
        raise _busy(path, holder)
    if os.path.isdir(path) and not os.path.islink(path):
        raise FileError(file, key, f"{show} is a directory; give a file name such as run.h5")
    check_replaceable(path, key, file)       # a device, FIFO, socket or link: never replaced, even with force
    check_not_own_name(path, key, file)
    sources = [config_source] if isinstance(config_source, str) else list(config_source or ())
    for i, source in enumerate(sources):
        if source and os.path.exists(path) and os.path.exists(source) and os.path.samefile(path, source):
            raise FileError(file, key, f"{show} is the config file itself" if i == 0 else
                            f"{show} is a file the config includes ({display_path(source)})")
    forget_second_name(temporary_path(path), path)
    for p in (path, temporary_path(path)):      # a study's results under these names: never taken for a run's
        problem = other_commands_file(p, mine)
        if problem is not None:
            raise problem
    if os.path.exists(path) and not force:
        raise FileError(path, None, f"exists; use {force_hint} to overwrite it")
    check_own_kind(path, key, file)     # with force: never a config, a table or notes named as the output
    tmp = temporary_path(path)
    if os.path.exists(tmp) and not force and not partial_ok:
        # no live run holds the lock (checked above): a killed run left it
        raise _killed_partial(tmp, force_hint, "start this one over it")


#: the endings rbx gives the files beside a run's output ``OUT.h5``, and what each is
OWN_SUFFIXES = ((".lock", "lock"), (".journal", "journal"), (".partial.new", "new file"),
                (".partial", "unfinished run file"))


def check_not_own_name(path, key, file=None):
    """Refuse an output named as rbx names the files beside another output (``OUT.h5.lock``, a ``.journal``,
    ``OUT.h5.partial.new``, ``OUT.h5.partial``): written there, it would replace a live run's lock, or a finished
    run would be taken for the ``.partial`` a killed run left (called that, removed by ``--force`` to OUT.h5,
    renamed by ``--resume``). Raises :class:`FileError`."""
    for suffix, what in OWN_SUFFIXES:
        if path.endswith(suffix) and len(os.path.basename(path)) > len(suffix):
            raise FileError(file, key, f"{display_path(path)} is the name rbx gives "
                                       f"{display_path(path[:-len(suffix)])}'s {what}; give another name, such as "
                                       "run.h5")


def forget_second_name(tmp, path):
    """Remove ``tmp`` (``OUT.h5.partial``) when it is ``path`` itself under a second name: the run that linked it
    to ``path`` was killed before it removed ``tmp`` (a resume said "exists" for ever, the ``.partial`` was never
    cleaned up). Only a regular file that is the same inode as ``path``; a live run's is not touched (the
    caller checked the lock) -> True if removed."""
    try:
        a, b = os.lstat(tmp), os.lstat(path)
    except OSError:
        return False
    if (a.st_ino, a.st_dev) != (b.st_ino, b.st_dev) or not os.path.isfile(tmp) or os.path.islink(tmp):
        return False
    if lock_holder(path) is not None:
        return False
    with contextlib.suppress(FileNotFoundError):
        os.remove(tmp)
    return True


def create(path, force=False, force_hint="force=True"):
    """Open a new file for a new run (folders made as needed) -> ``h5py.File`` at :func:`creation_path`
    (``OUT.h5.partial.new``), which :func:`stream` renames to ``OUT.h5.partial`` once the run's structure is
    written and on disk (:func:`publish_new`). OSError if it cannot.

    The run's lock (:func:`acquire_lock`, ``OUT.h5.lock``) is taken first and held until :func:`stream` ends; a
    ``.partial`` that exists is refused (and its rename later does not replace one that appeared meanwhile):
    of two runs started on one output, the second fails here instead of both writing one file. With ``force`` a
    leftover ``.partial`` is removed first (never one a live run holds the lock of). A leftover ``.partial.new``
    is removed when no run holds the lock (a killed run's: it holds no records); the ``.partial.new`` of a run
    of this same process (which holds the lock already) is created exclusively, so the second fails.
    ``force_hint``: how the caller forces (``--force``, ``force=True``), in the words of a refusal."""
    os.makedirs(os.path.dirname(os.path.abspath(path)) or ".", exist_ok=True)
    tmp, new = temporary_path(path), creation_path(path)
    lock = acquire_lock(path)   # first: --force must not remove the .partial of a run still writing it
    try:
        if force and os.path.exists(tmp):
            os.remove(tmp)
        if os.path.exists(tmp):
            raise FileExistsError(tmp)
        if taken_fresh(lock):      # the lock was free: no live run is making this file
            with contextlib.suppress(FileNotFoundError):
                os.remove(new)
            journal.discard(new)       # a .partial.new holds no records: its journal finishes nothing
            orphan = journal.journal_path(tmp)
            if os.path.exists(orphan) and not force:
                # the .partial it finishes was moved away (or removed): if a kill tore that file, this journal is
                # the only thing that can finish it, and this run's own journal would take its name
                release_lock(path)
                raise FileError(orphan, None, f"the journal of a killed run's {display_path(tmp)}, which is not "
                                              "here (moved away?): it is what finishes that file; put it back "
                                              f"beside the file, or remove it (or use {force_hint}) to start this run")
            journal.discard(tmp)
        return open_journaled(new, create=True)
    except (FileExistsError, OSError) as exc:
        release_lock(path)
        for busy in (tmp, new):
            if os.path.exists(busy):
                raise FileError(busy, None, "exists: another run is writing it (or was killed); remove it or use "
                                            f"{force_hint}") from None
        raise exc
    except BaseException:
        release_lock(path)
        raise


def _is_complete_run(path):
    try:
        with h5py.File(path, "r") as f:
            return bool(is_true(f.attrs.get("complete", False)))
    except Exception:   # noqa: BLE001 - not an rbx run, or damaged: not a result worth keeping over the new one
        return False


def publish_new(h5, tmp):
    """Rename a file made by :func:`create` (open as ``h5``, at ``tmp + '.new'``) to ``tmp`` once its structure is
    written: flushed and fsynced first, so that ``tmp`` is a whole HDF5 file from the instant it exists (a kill
    while HDF5 wrote the structure of a new ``.partial`` used to leave a torn file). Not over a ``tmp`` that
    appeared meanwhile: :class:`FileError`. Nothing to do for any other file (a resumed one)."""
    new = f"{tmp}.new"
    if os.path.abspath(file_path(h5)) != os.path.abspath(new):
        return
    h5.flush()
    commit(h5)
    jf = journal_of(h5)
    if jf is not None:
        os.fsync(jf.fd)
    try:
        os.link(new, tmp)                  # atomic, and fails if tmp exists
    except FileExistsError:
        raise FileError(tmp, None, "appeared while this run was starting (another run?); remove it or use "
                                   "--force") from None
    except OSError:                        # a file system without hard links: check, then rename
        if os.path.exists(tmp):
            raise FileError(tmp, None, "appeared while this run was starting (another run?)") from None
        os.replace(new, tmp)
    else:
        os.remove(new)
    if jf is not None:
        jf.rename(tmp)
    _fsync_folder(tmp)


def _fsync_folder(path):
    """Make a rename in ``path``'s folder durable (where the system allows opening a folder)."""
    with contextlib.suppress(OSError):
        fd = os.open(os.path.dirname(os.path.abspath(path)) or ".", os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def stream(sim, h5, tmp, path, **options):
    """:func:`_stream`, a disk that filled while HDF5 or the journal wrote (another program took the room) said as
    such (:class:`DiskFull`), not as a bare ``No space left on device``: the file is at its last checkpoint."""
    try:
        return _stream(sim, h5, tmp, path, **options)
    except DiskFull:
        raise
    except OSError as exc:
        if exc.errno == errno.EFBIG:
            raise DiskFull("the file is not allowed to grow (a file size limit, ulimit -f?) while writing") from None
        if exc.errno in NO_ROOM:
            raise DiskFull(f"the disk is full ({exc.strerror}) while writing") from None
        raise


def _stream(sim, h5, tmp, path, *, fresh=True, progress=None, should_stop=None, write_initial=None, report=None,
            replace=False, only=ANY):
    """Run ``sim`` into the open file ``h5`` (at ``tmp``, or made by :func:`create` and renamed to ``tmp`` once
    its structure is written: :func:`publish_new`), mark it complete or not, close it and rename it to ``path``
    -> True if the run finished (False: ``should_stop()`` said stop). The config stored in the file names
    ``path`` as its ``output.path``.

    The rename happens however the run ends (complete, interrupted, an error), so the records computed so far
    are in ``path`` and ``complete`` says whether that is all of them (docs/reference.md §4), with two exceptions
    that keep what is already there: a run that did not finish never replaces a *complete* ``path`` (``--force`` then
    Ctrl-C used to leave a fragment in place of a finished result), and without ``replace`` (``--force``) a
    ``path`` that appeared while this run was writing (another run) is not replaced either. Either way the
    records stay in ``tmp``: said through ``report(message)`` for an unfinished run, a :class:`FileError` for a
    finished one. A rename that fails is passed to ``report``. Errors writing (OSError) propagate."""
    complete = False
    sink = None
    new = os.path.abspath(file_path(h5)) == os.path.abspath(f"{tmp}.new")
    raised = True
    try:
        try:
            with h5:
                sink = H5Sink(h5, sim.cfg, fresh=fresh, path=path)
                if not fresh:
                    _store_path(h5, sim.cfg, path)
                publish_new(h5, tmp)
                new = False
                try:
                    complete = sim.run(sink, progress=progress, should_stop=should_stop, write_initial=write_initial)
                finally:
                    with contextlib.suppress(Exception):   # an error writing must not hide the error itself
                        sink.settle(complete)
                h5.attrs["complete"] = bool(complete)
                raised = False
        finally:
            # the last commit: what HDF5 wrote when it closed the file; none after an error (the file then stays at
            # its last checkpoint exactly: its records are those the saved state accounts for), nor if it fails
            failure = close_journal(h5, commit=not raised)
            if failure is not None:
                complete = False
        if failure is not None:
            raise failure
        return complete
    finally:
        try:
            if new:      # stopped before its structure was written: nothing worth keeping
                with contextlib.suppress(OSError):
                    os.remove(f"{tmp}.new")
                journal.discard(f"{tmp}.new")
            elif journal.pending(tmp):
                # a commit failed after its commit point: the file is whole only with its journal, which is
                # applied when the .partial is next opened (resumed), so the .partial is not renamed
                pass
            else:
                if sink is not None and sink.reserved and journal_of(h5) is None:
                    trim(tmp)        # a journaled file was cut to HDF5's end when it closed (JournaledFile.close)
                publish(tmp, path, complete, replace, report, only)
        finally:
            # the run's lock (taken by create, or by rbx.resume.load for the file resumed), released last
            release_lock(path)
            for release in getattr(sim, "locks", ()):
                release()


def _store_path(h5, cfg, path):
    """A resumed run written to another file (``--resume RUN.h5 -o OUT.h5``): its stored config names that file."""
    try:
        stored = yaml.safe_load(_text(h5.attrs["config"]))
        if (stored.get("output") or {}).get("path") == os.path.abspath(path):
            return
    except Exception:   # noqa: BLE001 - unreadable: written anew below
        pass
    h5.attrs["config"] = config_yaml(cfg, path)




def trim(path):
    """Give back the room :meth:`H5Sink._reserve` allocated and HDF5 did not use: HDF5 cuts the file to its own
    end when it closes a file it opened for writing (it keeps a longer file it made longer itself)."""
    with contextlib.suppress(Exception):
        with h5py.File(path, "r+"):
            pass


def publish(tmp, path, complete, replace, report, only=ANY):
    """Rename ``tmp`` to ``path`` by the rules of :func:`stream` (also the last step of a resume in place).
    ``only`` (a resume without --force): the file (:func:`file_id`) that may be replaced, the one at ``path`` when
    the resume started (None: nothing); another one put there meanwhile is not (a run moved there was replaced by
    the resumed one, exit 0)."""

    def say(message):
        if report is not None:
            report(message)

    if not complete and os.path.exists(path) and _is_complete_run(path):
        say(f"{display_path(path)}: kept: it holds a complete run and this one did not finish; the records so far "
            f"are in {display_path(tmp)}")
        return
    try:
        # no run's file is replaced without --force, not even one that appeared while this run wrote; with it,
        # neither a device or a link put there, nor another command's file, nor a file rbx did not write
        place(tmp, path, replace, check=functools.partial(check_own_file, mine="run"), only=only)
    except FileError as exc:
        # refused: a complete run not in place is an error (as when a file appeared), an unfinished one a note
        problem = exc.problem if exc.file is None else f"{display_path(exc.file)}: {exc.problem}"
        if complete:
            raise FileError(None, None, f"{problem}; the records are in {display_path(tmp)}") from None
        say(f"{problem}; the records are in {display_path(tmp)}")
    except FileExistsError:
        message = (f"appeared while this run was writing (another run?) and was not replaced; the records are in "
                   f"{display_path(tmp)}")
        if complete:
            raise FileError(path, None, message) from None
        say(f"{display_path(path)}: {message}")
    except OSError as exc:
        if not os.path.lexists(tmp):
            # its folder removed while the run wrote: nothing is where the records would be
            raise FileNotFoundError(errno.ENOENT, f"the folder {display_path(os.path.dirname(path) or '.')} is "
                                                  "gone (removed while the run wrote?): nothing was saved",
                                    path) from None
        message = f"cannot rename {display_path(tmp)} to it: {exc.strerror or exc}; the records are in " \
                  f"{display_path(tmp)}"
        if complete:
            # the run is not where it was asked for (a folder or an immutable file there): an error, not "wrote"
            raise FileError(path, None, message) from None
        say(f"{display_path(path)}: {message}")





def write_returns(path, cfg, result, force_hint="--force", replace=False):
    """Write a return-angle experiment (:class:`rbx.histogram.Returns`) to a new HDF5 file (via ``path.partial``,
    renamed at the end).

    Root attributes :data:`rbx.runfile.ROOT_ATTRS`; group ``returns/``: ``angle`` (K,) return angles [rad],
    ``trajectory`` (K,) their trajectory indices, ``collisions`` (K,) collisions to return, ``initial_angle`` (M,)
    sampled angles; attributes :data:`rbx.runfile.RETURNS_ATTRS` (:func:`rbx.runfile.fill_returns`). A file at
    ``path`` is replaced only with ``replace`` (--force), and then only one of return angles (:func:`place`)."""
    new = creation_path(path)
    made = False
    try:
        try:
            h5 = create(path, force_hint=force_hint)
        except FileError as exc:
            tmp = temporary_path(path)
            problem = other_commands_file(tmp, "returns") if exc.file and \
                os.path.abspath(exc.file) == os.path.abspath(tmp) else None
            if problem is not None:
                # a killed rbx simulate's .partial under the samples' name: never removed (not even with --force,
                # which the refusal offered though it was given): what it is, and how to go on
                raise problem from None
            raise
        made = True
        try:
            with h5:
                fill_returns(h5, cfg, result, path)
        finally:
            failure = close_journal(h5)
        if failure is not None:
            raise failure
        # never over a file that appeared while the samples were drawn (a run that finished meanwhile) without
        # --force, nor with it over a file of another kind
        try:
            place(new, path, replace, check=functools.partial(check_own_file, mine="returns"))
        except FileExistsError:
            raise FileError(path, None, "appeared while the samples were drawn (another run?) and was not "
                                        f"replaced; nothing was saved: give the return angles another name "
                                        f"(--data), or {force_hint} to replace it") from None
    except BaseException:
        if made:       # a file left half written (a full disk) holds nothing worth keeping, and takes the room
            with contextlib.suppress(OSError):
                os.remove(new)
            journal.discard(new)
        raise
    finally:
        release_lock(path)


# ---- a new run ----------------------------------------------------------------------------------------------------

def run_to_file(sim, path, *, progress=None, should_stop=None, report=None, force=False, force_hint="force=True"):
    """Run a new ``sim`` into ``path`` through ``path.partial`` -> True if it finished (see :func:`stream`;
    ``force``: replace an existing ``path``). Raises :class:`FileError` if the file cannot be created,
    :class:`DiskFull` if there is no room for it, OSError if writing fails midway (the file then holds what was
    written, ``complete = False``)."""
    tmp = temporary_path(path)
    try:
        h5 = create(path, force=force, force_hint=force_hint)
    except DiskFull:
        raise
    except OSError as exc:
        if exc.errno in NO_ROOM:     # not the user's input: the disk (or a size limit) has no room
            raise DiskFull(f"cannot write: {exc.strerror}: no room on the disk (or a size limit, ulimit -f?)") \
                from None
        raise FileError(tmp, None, f"cannot write: {exc.strerror or exc}") from None
    return stream(sim, h5, tmp, path, fresh=True, progress=progress, should_stop=should_stop, report=report,
                  replace=force)


# ---- resuming a run -----------------------------------------------------------------------------------------------

@dataclasses.dataclass
class Resumption:
    """An interrupted run made ready to continue (:func:`prepare_resume`).

    ``state``: 'continue' (``sim`` set up from the file's saved state), 'renamed' (the file held a complete run
    killed before its rename, which was done now), or 'complete' (nothing to do). ``source``: the file read,
    ``path``: the file written in the end, ``tmp``: its ``.partial`` (``source`` itself when resumed in place),
    ``done``: collisions already made, ``notes``: warnings to show (another rbx version, chunks read raw)."""
    state: str
    source: str
    path: str
    tmp: str = None
    in_place: bool = False
    force: bool = False
    sim: object = None
    write_initial: bool = False
    done: int = 0
    notes: list = dataclasses.field(default_factory=list)
    #: the source (OUT.h5) is renamed to ``tmp`` and continued in place: the disk has no room for a copy
    move: bool = False
    #: without --force, the file (:func:`file_id`) the end may replace at ``path``: the one there when the resume
    #: started (its own earlier file), or None if there was none; a file put there meanwhile is not replaced.
    #: With --force: :data:`ANY`
    replaces: object = None


#: root attributes a resumed run file may hold beside rbx's own (notes a user added); a file with more is refused
MAX_EXTRA_ATTRS = 64


def resumed_source(run_file):
    """The file ``--resume RUN`` reads -> absolute path: RUN itself, or ``RUN.partial`` when RUN does not exist
    and its run was interrupted (killed: only ``OUT.h5.partial`` is left; ``--resume OUT.h5`` said "file not
    found")."""
    source = os.path.abspath(os.fspath(run_file))
    if not os.path.lexists(source) and os.path.isfile(temporary_path(source)):
        return temporary_path(source)
    return source


def prepare_resume(run_file, output=None, *, force=False, max_size=None, out_key="-o", size_key="--max-size",
                   force_hint="--force"):
    """Read the interrupted run in ``run_file`` and set it up to continue into ``output`` (default: the run's own
    output, working on its ``.partial`` in place) -> :class:`Resumption`. Nothing is written yet, except the rename
    of a complete ``.partial`` (``state`` 'renamed').

    Checked before any work: the source's lock (a run still writing it is named; a source on a read-only file
    system, where nothing can write it, is read without), the saved state against the stored config
    (:func:`rbx.continuation.load`), the output (:func:`check_target`) and the size the run's file will reach
    against ``output.max_size`` (or ``max_size``: bytes or a text such as '50 GB', named by ``size_key``) and the
    free space. Raises :class:`FileError` or :class:`rbx.model.ConfigError`."""
    source = resumed_source(run_file)
    problem = other_commands_file(source, "run", renaming=False)    # a study's results: how to continue them
    if problem is not None:
        raise problem
    default = source[:-len(".partial")] if source.endswith(".partial") else source
    if forget_second_name(temporary_path(default), default) and source != default:
        # OUT.h5.partial was OUT.h5 under a second name (a kill between the final link and the remove): one file,
        # now under its one name; it was taken as the source, then removed as a second name (a traceback)
        source = default
    path = os.path.abspath(os.fspath(output)) if output else default
    if output:
        check_not_own_name(path, out_key)      # before the source is locked or read
    tmp = temporary_path(path)
    in_place = tmp == source
    # rbx's own files beside the source and the output (the .partial, its journal, the lock) must be nothing or
    # regular files before any is opened or written: a .partial that is a link was written through with --force
    for out in {default, path}:
        check_own_names(out)
    # the source's lock before its file is read: a run still writing it is named in one line (reading a file that
    # HDF5 is writing can fail as "damaged"); continuation.load holds it on for the run
    unlocked = _lock_source(source, in_place, out_key)
    locked = unlocked is None
    notes = []
    own = False          # the output is the run's own earlier file, which this continuation replaces
    try:
        run = Run.open(source)
        if not run.complete and not in_place and path == default and locked and os.path.lexists(tmp) and not force:
            # OUT.h5 and OUT.h5.partial, and no live run holds their lock (this one does): a resume of OUT.h5 into
            # its .partial was killed. Go on from the further of the two (said in a note), or say what to do
            run.close()
            source, note = _leftover_partial(source, tmp, path, force_hint)
            notes += [note] if note else []
            in_place = own = tmp == source
            run = Run.open(source)
        elif in_place and not force and os.path.isfile(path) and not os.path.islink(path):
            own = _continues(source, path)      # --resume OUT.h5.partial beside the OUT.h5 it continues
        if run.complete:
            run.close()
            if not source.endswith(".partial"):
                return Resumption("complete", source, path, notes=_newer_partial(source, locked, force_hint))
            if output and path != default:
                raise FileError(None, out_key, f"{display_path(source)} holds a complete run that was not yet "
                                               "renamed; resume it without -o to rename it to its own output")
            finish_complete(source, path, force or own)
            return Resumption("renamed", source, path, notes=notes)
        if not locked and lock_path(path) == lock_path(source):
            # OUT.h5 resumed into itself works on a copy beside it (OUT.h5.partial), which its folder cannot take:
            # the copy failed naming that .partial ("cannot write"), a file that is not there
            run.close()
            raise _not_in_place(source, unlocked, out_key)
        note = continuation.version_note(run)
        with run:
            extra = [a for a in run.h5.attrs if a not in ROOT_ATTRS and a not in PROVENANCE_ATTRS]
            if len(extra) > MAX_EXTRA_ATTRS:
                # a resume changes root attributes, and each change rewrites an object header of that many: 5 000
                # took minutes inside HDF5, where no signal is seen (it was killed with SIGKILL, its locks left)
                raise FileError(source, None, f"holds {len(extra)} root attributes that rbx does not write (the "
                                              f"first: {shortened(extra[0], 40)}), more than the {MAX_EXTRA_ATTRS} a "
                                              "resume takes: remove them (h5py: del f.attrs[name]) and resume again")
            try:
                sim, write_initial, done = continuation.load(run, source, lock=locked)
            except MemoryError:
                raise FileError(source, "run.trajectories", "the trajectories do not fit in the free memory") \
                    from None
    finally:
        if locked:
            release_lock(source)
    # the output must be a file rbx may replace, before the run: a link or a device was refused only at the final
    # rename, after the whole run, with exit 0 (the records left in the .partial)
    check_replaceable(path, out_key if output else None)
    if output and path != source:
        # a resume does not know the config it was started from: a -o that names it (or any file rbx did not
        # write) was written over with HDF5, --force or not
        check_own_kind(path, out_key)
    if lock_path(path) != lock_path(source):
        # -o OTHER.h5: OTHER's own lock too, held to the final rename like a new run's, so that two resumes into
        # one OTHER cannot write one OTHER.h5.partial (with --force the second truncated it)
        acquire_lock(path)
        sim.locks.append(weakref.finalize(sim, release_lock, path))
    if path != source:
        check_target(path, force or own, out_key, partial_ok=True, force_hint=force_hint)
    if os.path.lexists(tmp) and not force and not in_place:
        # this resume holds the output's lock: no live run writes tmp, a killed one left it
        raise _killed_partial(tmp, force_hint, "write this one over it")
    # every limit a new run has: output.max_size (or the one given now) and the free space, for the whole file
    cfg = sim.cfg
    if max_size is not None:
        cfg = loads(run.attrs["config"], source, {"max_size": max_size})
        key_file = (None, size_key)
    else:
        key_file = (source, "config: output.max_size")
    move = False
    movable = not in_place and path == source and not os.path.lexists(tmp)
    if movable:
        # OUT.h5 resumed into itself works on a copy (OUT.h5.partial). Where the disk has no room for the copy and
        # the rest of the run, it is continued in place under its .partial name instead, renamed rather than
        # copied: the journal keeps the file whole at every instant, and a stop ends with it renamed back
        free = free_space(path)
        move = free is not None and estimated_size(cfg) > free
    written = os.path.getsize(source) if in_place or movable else 0
    other = "-o" if out_key.startswith("-") else f"{out_key}="
    check_size(cfg, path, key_file, written=written,
               option=size_key if size_key.startswith("--") else f"{size_key}=",
               hint=f"; free some space, or resume it into a file on another disk with {other}")
    if (in_place or move) and os.stat(source).st_nlink > 1:
        # written in place, a file with a second name changes under that name too: a hard link to another run's
        # live .partial had both runs write one file (the run lock is taken by name), and a backup made with links
        # would change with it
        raise FileError(display_path(source), None, "has another name (a hard link): rbx continues a run in place "
                                                    "only in a file of one name, which no other run can be writing; "
                                                    "resume a copy of it (cp), or remove the other name")
    notes += [note] if note else []
    for field, chunks in sim.torn_chunks.items():
        notes.append(f"collisions/{field}: {len(chunks)} chunk(s) of the last saved records failed their checksum "
                     "(torn by the kill while HDF5 rewrote them): the saved records were read from the raw bytes "
                     "of the chunks")
    return Resumption("continue", source, path, tmp, in_place, force or own or path == source, sim, write_initial,
                      done, notes, move, ANY if force else file_id(path))


def _newer_partial(source, locked, force_hint):
    """``--resume OUT.h5`` of a complete OUT.h5 beside an ``OUT.h5.partial`` that a killed run left (a run with
    --force over the complete file): a note saying so and how to continue it -> list of notes."""
    tmp = temporary_path(source)
    if not locked or not os.path.isfile(tmp) or os.path.islink(tmp):
        return []
    show = display_path(tmp)
    again = (f"rbx simulate --resume {show} {force_hint}" if force_hint.startswith("--") else
             f"rbx.resume({show!r}, {force_hint})")
    return [f"{show} exists, left by a run of this output that was killed (no run holds its lock): to continue that "
            f"run, replacing {display_path(source)} when it ends: {again}; else remove it"]


def _identity(run):
    """What one run keeps through its resumes: its first start (when, where), its scene and its config but for the
    file it names as its output (a resume into -o OTHER names OTHER)."""
    config = dict(run.config)
    config["output"] = {k: v for k, v in (config.get("output") or {}).items() if k != "path"}
    return (run.attrs.get("created"), run.attrs.get("host"), run.dimension, run.table_kind, config)


def _collisions(run):
    """Collisions each trajectory of ``run`` made, by its saved state (zeros when none was saved) -> array."""
    made = run.final.get("collisions")
    return np.zeros(run.trajectories, np.int64) if made is None else np.asarray(made, np.int64)


def _continues(partial, path):
    """Whether ``partial`` holds the run in ``path`` (an unfinished one) as far or further: a resume of ``path``
    into ``partial`` made it (a copy of ``path``, continued). Either unreadable: False."""
    try:
        a, b = Run.open(partial), Run.open(path)
    except FileError:
        return False
    return (not b.complete and _identity(a) == _identity(b) and a.trajectories == b.trajectories
            and bool(np.all(_collisions(a) >= _collisions(b))))


def _is_prefix(part, whole):
    """Whether the bytes of file ``part`` are the first bytes of file ``whole`` (a copy a kill cut short)."""
    try:
        if os.path.getsize(part) > os.path.getsize(whole):
            return False
        with open(part, "rb") as a, open(whole, "rb") as b:
            while True:
                x = a.read(1 << 20)
                if x != b.read(len(x)):
                    return False
                if not x:
                    return True
    except OSError:
        return False


def _leftover_partial(source, tmp, path, force_hint):
    """``--resume OUT.h5`` finds ``OUT.h5.partial`` and no live run holding their lock: what a resume of OUT.h5
    killed left (it works on a copy of OUT.h5 at OUT.h5.partial; SIGKILLed, both stay, with a stale lock) ->
    (the file to go on from, a note for the user or None). The further of the two is resumed: the .partial
    when it holds this run as far or further (it then replaces OUT.h5 when it ends); OUT.h5 when the .partial
    is a copy cut short, or lies behind (it is removed: every record in it is in OUT.h5). A .partial of another
    run is never touched: :class:`FileError` saying what to do. (It said "another run may be writing it" and
    asked for --force, which copied OUT.h5 over the further .partial.)"""
    show, shown = display_path(tmp), display_path(source)
    what = what_it_is(tmp)
    if what != "a regular file":
        raise FileError(tmp, None, f"is {what}, not a regular file: remove it to resume {shown}")
    if _continues(tmp, source):
        done = int(_collisions(Run.open(tmp)).max(initial=0))
        return tmp, (f"resumed in place of {shown}: the copy a killed resume of {shown} left, further along "
                     f"(collision {done}); it replaces {shown} when it ends")
    ahead = _continues(source, tmp)
    if ahead or _is_prefix(tmp, source):
        os.remove(tmp)
        journal.discard(tmp)
        return source, (f"removed {show}, {'a copy of it cut short' if not ahead else 'an earlier copy of it'} by a "
                        "killed resume; every record in it is in " + shown)
    again = (f"rbx simulate --resume {show} {force_hint}" if force_hint.startswith("--") else
             f"rbx.resume({show!r}, {force_hint})")
    raise FileError(tmp, None, f"holds another run than {shown} (its run was killed: no run holds the lock); "
                               f"to continue that run, replacing {display_path(path)} when it ends: {again}; to "
                               f"continue {shown}: remove {show}")


def _lock_source(source, in_place, out_key="-o"):
    """Take the lock of the file a resume reads -> None; the problem (text) when its folder cannot be written (a
    read-only file system: nothing can write the file there either) and the run may be written elsewhere. In
    place it must be taken: :class:`FileError` (:func:`_not_in_place`)."""
    try:
        acquire_lock(source)
    except LockNotWritable as exc:
        if not os.path.lexists(source):     # nothing to resume: said as such, not as a folder to write elsewhere
            raise FileError(source, None, "file not found") from None
        if in_place:
            raise _not_in_place(source, exc.problem, out_key) from None
        return exc.problem
    return None


def _not_in_place(source, problem, out_key):
    """The refusal of a resume that would write beside ``source``, whose folder cannot be written (``problem``:
    why the lock could not be made): say so, and the way on, an output elsewhere."""
    other = "-o" if out_key.startswith("-") else f"{out_key}="
    return FileError(source, None, f"cannot be resumed in place: its folder cannot be written ({problem}); resume "
                                   f"it into a writable folder with {other}")


def resume_to_file(r, *, progress=None, should_stop=None, report=None):
    """Continue the run :func:`prepare_resume` set up -> True if it finished (see :func:`stream`). Works on a copy
    of the source (unless resumed in place): if this attempt dies badly, the file it started from is intact.
    Raises :class:`DiskFull` when the copy finds no room (the source unchanged), OSError if writing fails
    midway."""
    sim, tmp = r.sim, r.tmp
    try:
        if r.move:
            journal.discard(tmp)
            os.rename(r.source, tmp)
        elif not r.in_place:
            journal.discard(tmp)            # a journal left by a .partial that was removed by hand is not this copy's
            copy_to_new(r.source, tmp)
            if journal.pending(r.source):   # a source that cannot be written (read-only): its journal goes to the copy
                journal.recover(tmp, journal=journal.journal_path(r.source))
        h5 = open_journaled(tmp)
    except journal.JournalError as exc:
        with contextlib.suppress(OSError):
            os.remove(tmp)
        raise FileError(journal.journal_path(r.source), None, str(exc)) from None
    except OSError as exc:
        if os.path.exists(tmp) and not r.in_place and not r.move:
            os.remove(tmp)
        if exc.errno in NO_ROOM:           # not the user's input: the disk is still full
            what = "to continue the run" if r.in_place or r.move else \
                f"for the copy of {display_path(r.source)} a resume works on"
            if exc.errno == errno.EFBIG:      # a file size limit, not the disk
                raise DiskFull(f"the file is not allowed to grow (a file size limit, ulimit -f?): no room {what} "
                               f"({display_path(r.source)} is unchanged)") from None
            raise DiskFull(f"the disk is full: no room {what}; free some space and resume again, or resume it into "
                           f"a file on another disk ({display_path(r.source)} is unchanged)") from None
        raise FileError(tmp, None, f"cannot write: {exc.strerror or exc}") from None
    try:
        try:
            continuation.make_consistent(h5, sim, r.write_initial)
        except (KeyError, ValueError, RuntimeError) as exc:
            # HDF5 refusing to change the file's structure ("message not aligned"): the file is torn, as a kill
            # while a checkpoint's journal was copied in leaves it once the journal is gone
            raise FileError(display_path(r.source), None, f"its HDF5 structure is damaged ({_reason(exc)}): "
                                                          "it cannot be continued; run the config again") from None
    except BaseException:
        with contextlib.suppress(Exception):
            h5.close()
        close_journal(h5, commit=False)        # the file as it was: nothing of the attempt reaches it
        if not r.in_place and not r.move:
            os.remove(tmp)
        raise
    return stream(sim, h5, tmp, r.path, fresh=False, write_initial=r.write_initial, replace=r.force,
                  progress=progress, should_stop=should_stop, report=report,
                  only=r.replaces)


def _reason(exc):
    """An exception's own words (a KeyError's without the quotes its str adds)."""
    return str(exc.args[0] if isinstance(exc, KeyError) and exc.args else exc).strip()


def finish_complete(partial, path, force=False):
    """Rename the complete run ``partial`` (``OUT.h5.partial``, marked ``complete = true``: its process was killed
    before the rename) to ``path`` as the end of a run would have: under the run's lock (a stale one is taken
    over), never over an existing file without ``force``. Raises :class:`rbx.FileError`."""
    acquire_lock(path)
    try:
        if forget_second_name(partial, path):
            return          # the rename was done: only the .partial's second name was left
        check_target(path, force, None, partial_ok=True)
        publish(partial, path, True, force, _rename_failed)
    finally:
        release_lock(path)


def _rename_failed(message):
    raise FileError(None, None, message)
