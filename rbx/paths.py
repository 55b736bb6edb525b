"""The files around a run, named and checked before rbx reads or replaces them: the errors a file raises
(:class:`FileError`, :class:`DiskFull`), the names beside a run's output (``OUT.h5.partial``, ``.partial.new``,
``.lock``), and what a path is (:func:`what_it_is`): rbx reads only regular files of a sane size
(:func:`config_file_problem`) and replaces only regular files (:func:`check_replaceable`) that it wrote itself
(:func:`check_own_kind`).

The lowest of the run-file modules: :mod:`rbx.locks`, :mod:`rbx.runfile`, :mod:`rbx.reader` and :mod:`rbx.driver` import it, it
imports none of them.
"""
import contextlib
import errno
import hashlib
import os
import secrets
import shutil
import signal
import stat

#: the largest config (or table, boundary) file rbx reads: a YAML config is a few kB
MAX_CONFIG_BYTES = 64 << 20

#: errno values that mean "no room": the disk full, a quota, a file size limit
NO_ROOM = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)
#: errno values that mean "not writable here": a mode, a read-only file system
NOT_WRITABLE = (errno.EACCES, errno.EPERM, errno.EROFS)


class FileError(Exception):
    """A file that cannot be read or written as asked: ``<file>: <key>: <problem>`` (the parts that apply)."""

    def __init__(self, file, key, problem):
        self.file = None if file is None else str(file)
        self.key, self.problem = key, problem
        super().__init__(": ".join(x for x in (self.file, key, problem) if x))


class DiskFull(OSError):
    """The disk has no room for the next block: the run stops between blocks, its file intact and resumable."""

    def __init__(self, message):
        super().__init__(errno.ENOSPC, message)

    def __str__(self):
        return self.strerror


def shortened(text, most=80):
    """``text`` cut to ``most`` characters (an ellipsis last): a value quoted in a message (a crafted attribute of
    300 kB made a 'line' of 300 kB)."""
    text = str(text)
    return text if len(text) <= most else f"{text[:most - 1]}…"


def shortened_pair(a, b, most=40):
    """Two texts that differ, each cut to ``most`` characters about where they first differ (an ellipsis where a
    part is left out) -> (a, b): cut from the start, '["lyapunov", "mean_free_path", "regular_sharf"]' and its
    study's '…"regular_share"]' were quoted as the same 40 characters."""
    a, b = str(a), str(b)
    if len(a) <= most and len(b) <= most:
        return a, b
    first = next((i for i, (x, y) in enumerate(zip(a, b)) if x != y), min(len(a), len(b)))
    start = max(0, first - most // 2)

    def cut(text):
        part = text[start:]
        part = part if len(part) <= most else f"{part[:most - 1]}…"
        return f"…{part}" if start else part
    return cut(a), cut(b)


def one_line(text):
    """``text`` with its control characters written as escapes ('a\\nb'): a file name holding a newline split a
    one-line message in two; bytes of a name that are not UTF-8 as ``\\xff`` (:func:`stored_text`)."""
    text = stored_text(str(text))
    if not any(c < " " or c == "\x7f" for c in text):
        return text
    return "".join(repr(c)[1:-1] if c < " " or c == "\x7f" else c for c in text)


def display_path(path):
    """A path as the user would write it: relative to the working directory when it lies below it, and on one line
    (:func:`one_line`). For messages only: never opened."""
    if path is None:
        return None
    path = str(path)
    if not os.path.isabs(path):
        return one_line(path)
    try:
        rel = os.path.relpath(path)
    except (ValueError, OSError):   # another drive (Windows); a working directory that was deleted
        return one_line(path)
    return one_line(path if rel.startswith("..") else rel)


def format_size(nbytes):
    """'2.3 TB', '512 MB', … (decimal units, as disks are sold)."""
    for unit, scale in (("PB", 1e15), ("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if nbytes >= scale:
            return f"{nbytes / scale:.3g} {unit}"
    return f"{int(nbytes)} bytes"


def temporary_path(path):
    """Where a run writes until it stops: beside the target, renamed over it at the end."""
    return f"{path}.partial"


def creation_path(path):
    """Where a new run's file is made, before its structure is complete: ``OUT.h5.partial.new``, renamed to
    ``OUT.h5.partial`` once the structure is on disk (:func:`rbx.driver.stream`), so that a ``.partial`` is never
    a torn HDF5 file. A leftover one (a run killed in its first milliseconds) holds no records: the next run
    removes it."""
    return f"{temporary_path(path)}.new"


def lock_path(path):
    """The lock file of a run writing ``path`` (``OUT.h5`` -> ``OUT.h5.lock``; a ``.partial`` is locked by its
    output's lock)."""
    path = os.path.abspath(str(path))
    if path.endswith(".partial"):
        path = path[:-len(".partial")]
    return f"{path}.lock"


#: what is wrong with a path that holds a NUL character: the system's calls take none (Python raises ValueError)
NUL_PROBLEM = "holds a NUL character (\\0), which no file name can"


def path_text_problem(path):
    """What is wrong with ``path`` (a str) as a file name -> None, :data:`NUL_PROBLEM` (a NUL character), or a
    character that is no byte of a name (a lone surrogate such as ``'\\ud800'``: only ``'\\udc80'`` …
    ``'\\udcff'`` stand for bytes, those of a name that is not UTF-8)."""
    if "\0" in path:
        return NUL_PROBLEM
    try:
        os.fsencode(path)
    except UnicodeEncodeError as e:
        return f"holds {e.object[e.start:e.end]!r}, a character that no file name can"
    return None


def check_path_text(path, key, file=None):
    """Raise :class:`FileError` (``file``, ``key``) where the path ``path`` (a str) holds a NUL character: it was
    a traceback from the first system call given it."""
    problem = path_text_problem(path)
    if problem:
        raise FileError(file, key, f"{shortened(repr(path))} {problem}")


def stored_text(text):
    """``text`` as rbx stores it in its files (a config's names, the command line): the same str, or, where it
    holds bytes that are not UTF-8 (a file name such as ``b'\\xff.h5'``, which Python reads as the lone surrogate
    ``'\\udcff'``), those bytes written as ``\\xff`` escapes. HDF5 and YAML store UTF-8 text only; the name
    stored is a record of what was run, the file itself keeps its real name."""
    try:
        return text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
    except UnicodeEncodeError:                     # a surrogate that stands for no byte
        return text.encode("utf-8", "backslashreplace").decode("utf-8")


def what_it_is(path):
    """What ``path`` names, by its own entry (a link is not followed) -> None (nothing there), 'a regular file',
    'a directory', 'a symbolic link to X' ('…, which does not exist'), 'a character device', 'a block device',
    'a FIFO (named pipe)', 'a socket'."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return None
    except OSError:
        return "unreadable"
    mode = st.st_mode
    if stat.S_ISLNK(mode):
        try:
            target = os.readlink(path)
        except OSError:
            target = "?"
        return f"a symbolic link to {target}" + ("" if os.path.exists(path) else ", which does not exist")
    for test, name in ((stat.S_ISREG, "a regular file"), (stat.S_ISDIR, "a directory"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def check_replaceable(path, key=None, file=None):
    """Raise :class:`FileError` unless ``path`` is nothing yet or a regular file: rbx replaces only regular files
    (with ``--force``), never a device (``-o /dev/null --force`` as root would have replaced the system's), a
    FIFO, a socket or a symbolic link (a dangling one was found only after the whole run, when the rename
    refused it)."""
    what = what_it_is(path)
    if what is None or what == "a regular file" or what == "a directory":   # a directory: the caller says so
        return
    show = display_path(path)
    if what.startswith("a symbolic link"):
        raise FileError(file, key, f"{show} is {what}; rbx writes only regular files and does not write through "
                                   "links: give the file's own path, or remove the link")
    raise FileError(file, key, f"{show} is {what}, not a regular file; rbx replaces only regular files: give "
                               "a file name such as run.h5")


#: the files :func:`place` put in place in this process (absolute paths), the one it is putting in place now, and
#: the outputs whose placing ends a command (:func:`last_output`): what the signal handlers read (rbx.api.StopFlag,
#: rbx.cli.common.note_interrupt)
PLACED, PLACING, LAST = [], [], set()


def last_output(path):
    """Note that once ``path`` is put in place (:func:`place`), the command's work is written (:func:`work_written`)."""
    LAST.add(os.path.abspath(path))


def forget_placed():
    """Start afresh (a command's start and end): :func:`work_written` speaks of one command's outputs."""
    PLACED.clear()
    LAST.clear()


def stop_signals():
    """The signals that stop a run between blocks (its file saved, resumable) and abort a command's set-up: SIGINT
    (Ctrl-C), SIGTERM (``kill``'s default) and SIGHUP (the terminal closed, an ssh session lost), the last only
    where it is not ignored: under ``nohup`` it stays ignored and the run goes on."""
    names = ["SIGINT", "SIGTERM"]
    hup = getattr(signal, "SIGHUP", None)
    if hup is not None and signal.getsignal(hup) is not signal.SIG_IGN:
        names.append("SIGHUP")
    return tuple(getattr(signal, name) for name in names)


def after_hangup(signum):
    """Called by the handlers of :func:`stop_signals`: after SIGHUP the terminal is gone, and a line written to it
    fails (EIO), which would end the command in a traceback before its exit code. Standard output and error that
    are terminals (character devices) are sent to the null device from here; a file or a pipe keeps them."""
    if signum != getattr(signal, "SIGHUP", None):
        return
    try:
        null = os.open(os.devnull, os.O_WRONLY)
        try:
            for fd in (1, 2):
                try:
                    if stat.S_ISCHR(os.fstat(fd).st_mode):
                        os.dup2(null, fd)
                except OSError:      # closed
                    pass
        finally:
            os.close(null)
    except OSError:
        pass


def work_written():
    """True once a command's last output is being put in place or is in place: a signal then changes nothing (it
    ended in 'nothing written' and exit 130 with the results in place)."""
    return any(os.path.abspath(p) in LAST for p in PLACED + PLACING)


def renaming():
    """True while :func:`place` puts a file in place: a signal then is acted on after the rename, by a check that
    knows the file is there (a KeyboardInterrupt raised just after the rename said 'nothing written')."""
    return bool(PLACING)


def file_id(path):
    """Which file ``path`` is -> (device, inode), or None when there is none: a file put at a name meanwhile (moved
    there) is another file, though of the same kind."""
    try:
        st = os.lstat(path)
    except OSError:
        return None
    return st.st_dev, st.st_ino


#: ``only`` of :func:`place`: whatever ``check`` allows (--force)
ANY = object()


def place(tmp, path, replace, check=None, only=ANY):
    """Put the finished file ``tmp`` in place as ``path`` in one rename. Without ``replace``, a file at ``path``
    is never replaced, not even one that appeared while ``tmp`` was written: a hard link fails on an existing name
    (where the file system has no hard links: checked, then renamed), and :class:`FileExistsError` is raised with
    ``tmp`` left as it is. With ``replace``, only a regular file is replaced (:func:`check_replaceable`) that
    ``check(path)`` accepts (the caller's test of what the file is, done again here: a config put under the name
    while a study ran is not replaced by it), and only the file ``only`` (:func:`file_id`; None: none) if given:
    a resume without --force replaces the file it continues, not another moved there meanwhile
    (FileExistsError)."""
    check_replaceable(path)
    if replace and check is not None:
        check(path)
    if replace and only is not ANY and file_id(path) not in (only, None):
        raise FileExistsError(errno.EEXIST, "another file is there", path)
    PLACING.append(path)
    try:
        if replace:
            os.replace(tmp, path)
        else:
            try:
                os.link(tmp, path)              # fails if path exists
            except FileExistsError:
                raise
            except OSError:                     # no hard links here
                if os.path.lexists(path):
                    raise FileExistsError(errno.EEXIST, os.strerror(errno.EEXIST), path) from None
                os.replace(tmp, path)
            else:
                os.remove(tmp)
        PLACED.append(os.path.abspath(path))
    finally:
        PLACING.pop()


#: the first bytes of the files rbx writes (HDF5: run files, return-angle files, a study's NetCDF results) and of
#: a run file torn while its journal was copied in (:data:`rbx.journal.TORN`)
OWN_SIGNATURES = (b"\x89HDF\r\n\x1a\n", b"\x89RBXtorn")


def check_own_kind(path, key=None, file=None):
    """Raise :class:`FileError` when ``path`` is a regular file with something in it that rbx did not write (not
    HDF5): ``--force`` replaces a run, a return-angle file or a study's results, never a config, a table or a
    user's notes that happen to be named as the output."""
    fd, _ = open_regular(path) if os.path.lexists(path) else (None, None)
    if fd is None:
        return
    try:
        head = os.pread(fd, 8, 0)
    finally:
        os.close(fd)
    if head and not any(head == sig[:len(head)] for sig in OWN_SIGNATURES):
        raise FileError(file, key, f"{display_path(path)} exists and is not an HDF5 file (a config, a table, "
                                   "notes?): rbx writes only over its own files; give another name")


def check_own_file(path, mine, key=None):
    """Raise :class:`FileError` unless ``--force`` may replace ``path`` by the output of a command that writes rbx's
    files of kind ``mine`` ('run', 'returns' or 'study'): never another command's file
    (:func:`other_commands_file`), nor a file rbx did not write (:func:`check_own_kind`). The test every such
    command makes of its output's name before it starts and again at the rename (:func:`place`)."""
    problem = other_commands_file(path, mine)
    if problem is not None:
        raise problem
    check_own_kind(path, key)


def foreign_object(group, prefix=""):
    """The first group or dataset under the open HDF5 ``group`` that is not the file's own -> ``(name, what)``, its
    name (after ``prefix``) and what it is: 'datatype' (a committed HDF5 datatype, no values), 'link' (soft or external: an external link is opened by the mere lookup,
    and one to a FIFO held the reader for ever, deaf to SIGTERM), 'virtual' or 'external' (a dataset whose values
    are read from other files), 'second name' (an object reached under another name already: a group hard-linked
    into itself made the walk, and every reader, loop for ever); None when every one is its own. Nothing is
    followed: each name is looked at as a link first."""
    import h5py
    todo = [(prefix, group)]
    seen = {group.id}
    while todo:
        prefix, group = todo.pop()
        for name in group:
            where = f"{prefix}{name}"
            item, what = own_item(group, name)
            if what:
                return where, what
            if item.id in seen:                  # rbx gives each group and dataset one name
                return where, "second name"
            seen.add(item.id)
            if isinstance(item, h5py.Group):
                todo.append((f"{where}/", item))
    return None


def own_item(group, name):
    """The member ``name`` of the open HDF5 ``group``, looked at as a link first -> (item, None) for a group or a
    dataset of the file's own, or (None, 'link' | 'datatype' | 'virtual' | 'external') (see
    :func:`foreign_object`, which asks it of every member; a reader of one dataset asks it alone)."""
    import h5py
    if not isinstance(group.get(name, getlink=True), h5py.HardLink):
        return None, "link"
    item = group[name]
    if isinstance(item, h5py.Group):
        return item, None
    if not isinstance(item, h5py.Dataset):
        return None, "datatype"         # a committed datatype: no values at all
    if item.is_virtual or item.external:
        return None, "virtual" if item.is_virtual else "external"
    return item, None


def check_own_objects(path, group, fix, prefix="", noun="variable"):
    """Raise :class:`FileError` naming the first group or dataset under ``group`` (of the HDF5 file ``path``, open;
    its name in the file ``prefix`` + name) that is not the file's own (:func:`foreign_object`): the one message for
    every reader. ``noun``: what the file holds there ('variable', 'dataset'); ``fix``: what to do, said after the
    problem."""
    found = foreign_object(group, prefix)
    if found is None:
        return
    where, what = found
    if what == "link":
        raise FileError(path, where, f"is a link, not a {noun} of this file: its values lie elsewhere; {fix}")
    if what == "datatype":
        raise FileError(path, where, f"is an HDF5 committed datatype, not a {noun}; {fix}")
    if what == "second name":
        raise FileError(path, where, f"is a second name (a hard link) of a group or dataset the file holds under "
                                     f"another name, not a {noun} of its own; {fix}")
    raise FileError(path, where, f"is an HDF5 {what} dataset: its values lie in other files; {fix}")


def rbx_kind(path):
    """Which of rbx's HDF5 files ``path`` is, by its root attributes and groups -> 'study' (a study's results, rbx
    sweep), 'returns' (the return angles of rbx histogram: ``returns/``, no ``collisions/``), 'run' (a run of rbx
    simulate), or None (not one of them, unreadable, or nothing there). A file named as another command's output (``k.h5.partial``) is told apart by it: each command
    took the other's unfinished file for its own (``--force`` removed it, ``--resume`` failed on it)."""
    fd, _ = open_regular(path) if os.path.lexists(path) else (None, None)
    if fd is None:
        return None
    os.close(fd)
    if os.path.lexists(path + JOURNAL_SUFFIX):
        # a journal beside it: a run killed while a checkpoint was copied in (a torn file HDF5 cannot open until the
        # journal is applied); only runs are written through a journal (rbx.journal)
        return "run"
    try:
        import h5py
        with h5py.File(path, "r", locking=False) as f:
            attrs, groups = set(f.attrs), set(f)
    except Exception:       # not HDF5, damaged, torn: what the caller's own checks say
        return None
    if "rbx_study" in attrs:
        return "study"
    if {"rbx_version", "dimension", "config"} <= attrs:
        return "returns" if "returns" in groups and "collisions" not in groups else "run"
    return None


def other_commands_file(path, mine, renaming=True):
    """The refusal of ``path`` when it is rbx's file of another command than ``mine`` ('run', 'returns' or
    'study'), however it is asked (``--force``, ``--resume``): what it is and how to go on with it (``renaming``: and
    to give the output another name) -> :class:`FileError`, or None."""
    kind = rbx_kind(path)
    if kind is None or kind == mine:
        return None
    unfinished = path.endswith(".partial")
    if kind == "run":
        what = "the unfinished run file of rbx simulate" if unfinished else "a run file of rbx simulate"
        then = (f"continue it with rbx simulate --resume {display_path(path)}, or remove it" if unfinished
                else "remove it if it is not needed")
    elif kind == "returns":
        what, then = "the return angles of rbx histogram", "remove it if it is not needed"
    else:
        what = "the unfinished results of a study (rbx sweep)" if unfinished else "a study's results (rbx sweep)"
        then = ("continue them with rbx sweep STUDY -o NAME --resume (NAME without .partial), or remove it"
                if unfinished else "remove it if it is not needed")
    tail = ("" if not renaming else "; give the return angles another name (--data)" if mine == "returns" else
            f"; give this {'study' if mine == 'study' else 'run'}'s output another name")
    return FileError(path, None, f"is {what}: {then}{tail}")


#: the name of a run file's write-ahead journal beside it (``rbx.journal.journal_path``: this module imports no other)
JOURNAL_SUFFIX = ".journal"


#: the first bytes of the figures rbx plot and rbx animate write (PNG, PDF, SVG, PostScript, JPEG, TIFF, GIF; an MP4
#: is known by its ``ftyp`` box at byte 4): such a file, or an empty one, is replaced; anything else named as the
#: figure (a run, a config, notes) is not
FIGURE_SIGNATURES = (b"\x89PNG\r\n\x1a\n", b"%PDF-", b"<?xml", b"<svg", b"%!PS", b"\xff\xd8\xff", b"II*\x00",
                     b"MM\x00*", b"GIF8", b"\x1f\x8b")      # the last: gzip, an .svgz
#: formats matplotlib writes with no signature to know them by (raw pixels): such a file named as the figure is
#: taken for one
UNSIGNED_FORMATS = (".raw", ".rgba")


def check_figure_file(path):
    """Raise :class:`FileError` when ``path`` is a file whose first bytes are no figure's
    (:data:`FIGURE_SIGNATURES`): a figure replaces only a figure (or an empty file, or nothing)."""
    if not os.path.isfile(path):
        return
    try:
        with open(path, "rb") as f:
            head = f.read(12)
    except OSError as exc:
        raise FileError(path, None, f"cannot read it: {exc.strerror or exc}") from None
    webp = head[:4] == b"RIFF" and head[8:12] == b"WEBP"
    if head and head[4:8] != b"ftyp" and not webp and not path.lower().endswith(UNSIGNED_FORMATS) \
            and not any(head[:len(sig)] == sig[:len(head)] for sig in FIGURE_SIGNATURES):
        raise FileError(path, None, "exists and is not a figure (not a PNG, PDF, SVG, PostScript, JPEG, TIFF, GIF, "
                                    "WebP or MP4 file: a run, a config, notes?); rbx replaces only figures: give "
                                    "another name")


def create_new(name_of, mode=0o666, tries=16):
    """A new file under a name no one can know in advance -> (its name, a descriptor open for writing).
    ``name_of(token)`` gives the name for a random token of 8 hex digits. Each name is created exclusively and never
    through a link (``O_EXCL``, ``O_NOFOLLOW``), so whatever is at a name already (a link, a FIFO, a file planted
    there) is never opened nor removed: a taken name is passed over for the next. The permissions are ``mode``
    less the umask, as for any new file. Raises FileExistsError after ``tries`` taken names."""
    for _ in range(tries):
        name = name_of(secrets.token_hex(4))
        try:
            return name, os.open(name, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0), mode)
        except FileExistsError:
            continue
    raise FileExistsError(errno.EEXIST, "every new name tried exists", name)


@contextlib.contextmanager
def written_whole(path, replace=True):
    """A new name beside ``path`` (its folder, its extension last, so that a writer that reads the format off the
    name still does) to write a figure or an animation to -> yields it; once written, it replaces ``path`` in one
    rename (:func:`place`): only a figure (:func:`check_figure_file`, tested again at the rename: a file put there
    while the figure was drawn is not replaced), and without ``replace`` nothing at all (FileExistsError). A
    failure (a full disk, Ctrl-C) removes it and leaves ``path`` as it was: a figure written in place was left
    truncated, where a good one had been."""
    folder, name = os.path.split(os.path.abspath(path))
    ext = os.path.splitext(name)[1] or (name if name.count(".") == 1 and name.startswith(".") else "")  # '.png'
    # short (a name of 250 characters must still have room) and hidden; the extension last. The part after
    # '.rbx-' names the file it will replace (a hash of its name), so that a later write of the same file finds
    # the new names that a killed writer left behind (SIGKILL runs no clean-up) and removes them
    prefix = f".rbx-{hashlib.sha1(name.encode('utf-8', 'surrogateescape')).hexdigest()[:8]}-"
    _remove_abandoned(folder, prefix, ext)
    tmp, fd = create_new(lambda token: os.path.join(folder, f"{prefix}{token}{ext}"))
    try:
        # held while the file is written: a name whose lock can be taken belongs to no live writer
        _try_lock(fd)
        yield tmp
        place(tmp, path, replace, check=check_figure_file)
    except BaseException:
        with contextlib.suppress(OSError):
            os.remove(tmp)
        raise
    finally:
        os.close(fd)        # releases the lock


def copy_to_new(source, target):
    """Copy the file ``source`` to ``target`` under a new name: whatever is at ``target`` is removed first (the
    caller may replace it), and the copy is created exclusively, never through a link. A copy written into the file
    at ``target`` (``shutil.copyfile`` truncates it) wrote into every other name of that file: a hard link there to
    another run's live ``.partial`` had that run's records replaced."""
    if os.path.lexists(target):
        os.remove(target)
    fd = os.open(target, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0), 0o666)
    with os.fdopen(fd, "wb") as out, open(source, "rb") as src:
        shutil.copyfileobj(src, out, 8 << 20)


def _try_lock(fd):
    """Take an exclusive ``flock`` on ``fd`` without waiting -> True, or False where it is held elsewhere (or no
    lock can be taken here: no ``fcntl``, a file system without locks)."""
    try:
        import fcntl        # POSIX only
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return True
    except (ImportError, OSError):
        return False


def _remove_abandoned(folder, prefix, ext):
    """Remove the regular files ``prefix*ext`` in ``folder`` that no writer holds (:func:`written_whole`): the
    remains of a writer killed mid-write. One whose lock cannot be taken is left (a live writer, or a file system
    without locks, where nothing tells the two apart)."""
    try:
        names = [n for n in os.listdir(folder) if n.startswith(prefix) and n.endswith(ext)]
    except OSError:
        return
    for n in names:
        own = os.path.join(folder, n)
        try:
            fd = os.open(own, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0))
        except OSError:
            continue
        try:
            if stat.S_ISREG(os.fstat(fd).st_mode) and _try_lock(fd):
                with contextlib.suppress(OSError):
                    os.remove(own)
        finally:
            os.close(fd)


def open_regular(path):
    """Open ``path`` for reading without following a symbolic link and without waiting on a FIFO -> (fd, None)
    for a regular file, (None, what it is: :func:`what_it_is`) for anything else, never read. Other errors of
    the open (nothing there, no permission) are raised as they are."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0))
    except OSError as exc:
        if exc.errno != errno.ELOOP and not os.path.islink(path):
            raise
        return None, what_it_is(path)
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        return None, what_it_is(path)
    return fd, None


#: how much longer than an output's name the longest name rbx makes beside it may be: its lock's, while written
#: (``OUT.h5.lock.new.<pid>.<thread>.<8 random hex digits>``, rbx.locks), and the journal's (``OUT.h5.partial.journal.tmp``)
OWN_NAME_ROOM = 48


def own_names(path):
    """The files rbx makes beside a run's output ``path`` and writes or reads itself: its ``.partial``, the
    ``.partial.new`` of a new run, the journals of these and of the output, and the run's lock -> list of paths."""
    tmp = temporary_path(path)
    new = creation_path(path)
    journals = [f"{path}.journal", f"{tmp}.journal", f"{new}.journal"]
    # and the scratch names written before a rename: a journal's before its commit, a study's results before they
    # replace its .partial (a link there was written through, a FIFO there waited for ever)
    return [tmp, new, *journals, *(f"{j}.tmp" for j in journals), f"{tmp}.tmp", lock_path(path)]


def create_own(path):
    """Open a new scratch file of rbx's at ``path`` for writing -> its descriptor. A regular file there (left by a
    killed writer) is removed; anything else (a symbolic link, a FIFO, a folder) is refused as :class:`FileError`,
    and the file is created exclusively, never through a name that appeared meanwhile (``FileExistsError``): a
    link named as a journal's or a study's scratch file was written through, and the file it named overwritten."""
    what = what_it_is(path)
    if what == "a regular file":
        os.remove(path)
    elif what is not None:
        raise _not_own(path, what)
    return os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0), 0o666)


def check_own_names(path):
    """Raise :class:`FileError` unless each file rbx makes beside ``path`` (:func:`own_names`) is nothing yet or a
    regular file: rbx writes only through names it made, never through a symbolic link someone put there
    (``--resume OUT.h5 --force`` with ``OUT.h5.partial`` a link wrote HDF5 over the link's target), and never
    opens a FIFO (the open waits for a writer for ever) or reads a directory as a journal or a lock. A name too long
    for those beside it is refused first: they said 'unreadable, not a regular file: remove it' of files that
    were not there."""
    name = os.fsencode(os.path.basename(os.path.abspath(path)))
    try:
        most = os.pathconf(os.path.dirname(os.path.abspath(path)) or ".", "PC_NAME_MAX")
    except (OSError, ValueError, AttributeError):       # a folder that is not there yet, or no pathconf
        most = 255
    if len(name) + OWN_NAME_ROOM > most:
        raise FileError(display_path(path), None, f"its name is {len(name)} bytes long; rbx keeps its own files "
                                                  f"beside it under names up to {OWN_NAME_ROOM} bytes longer, and "
                                                  f"this file system takes names of at most {most} bytes: give a "
                                                  f"name of at most {most - OWN_NAME_ROOM} bytes")
    for own in own_names(path):
        what = what_it_is(own)
        if what is None or what == "a regular file":
            continue
        raise _not_own(own, what)


def _not_own(path, what):
    """The refusal of a name rbx keeps its own files under that holds something else (``what``) -> FileError."""
    return FileError(display_path(path), None, f"is {what}, not a regular file; rbx keeps its own files under this "
                                               "name and writes nothing through it: remove it (or rename it), then "
                                               "run again")


def config_file_problem(path, limit=MAX_CONFIG_BYTES):
    """Why the file at ``path`` is not one to read a config from -> None (a regular file of at most ``limit``
    bytes), or the problem: a device (``/dev/zero`` was read without bound), a FIFO (reading it waited for ever),
    a socket, a file larger than ``limit``. Raises FileNotFoundError / IsADirectoryError / PermissionError /
    OSError as ``open`` would."""
    st = os.stat(path)
    if stat.S_ISDIR(st.st_mode):
        raise IsADirectoryError(errno.EISDIR, os.strerror(errno.EISDIR), path)
    if not stat.S_ISREG(st.st_mode):
        what = what_it_is(os.path.realpath(path))
        if what in (None, "a regular file", "not a regular file"):     # /dev/stdin: a pipe with no name to look at
            return "is not a regular file: give a YAML file"
        return f"is {what}, not a regular file: give a YAML file"
    if st.st_size > limit:
        return (f"is {format_size(st.st_size)}, larger than a config can be ({limit >> 20} MiB): give a YAML "
                "config file")
    return None
