"""The run lock: ``OUT.h5.lock`` (host, pid, start) held while a run writes ``OUT.h5.partial``, so that two runs —
two processes, or two threads of one process — never write one file.

A lock file appears whole or not at all: it is written under another name and linked to ``OUT.h5.lock`` (a file
system without hard links: created exclusively and written). So a lock that is empty or names no process was
never a live run's (a disk that filled while it was written, ``: > OUT.h5.lock``): it is taken over with a
warning, as is the lock of a process that no longer runs on this host. A lock is held by one thread: taking it
again from that thread is allowed (a resume takes its file's lock twice), from another thread of the process is
refused like another process's (two ``rbx.simulate(…, force=True)`` in two threads lost both runs). Locks still
held when the process exits are removed (``atexit``; :func:`release_held_locks` for an exit that skips it).
"""
import atexit
import contextlib
import errno
import glob
import os
import re
import secrets
import socket
import sys
import threading
import time

from .paths import NO_ROOM, NOT_WRITABLE, DiskFull, FileError, create_new, display_path, format_size, lock_path, open_regular

__all__ = ["lock_path", "acquire_lock", "release_lock", "lock_holder", "release_held_locks", "busy",
           "LockNotWritable", "taken_fresh"]

#: locks this process holds: lock path -> [times taken, the thread that holds it]
_HELD = {}
_GUARD = threading.RLock()   # re-entrant: a finaliser releasing a lock can run inside acquire_lock


class LockNotWritable(FileError):
    """The lock cannot be made or taken over where the file lies (a read-only file system, a folder without write
    permission): nothing can write there either, so a run that only reads that file may go on without its lock."""


def _process_start(pid):
    """The start time of process ``pid`` in clock ticks since boot (Linux), or None where that is not known: with
    the pid it tells a lock's process apart from a later one that reused its pid."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return int(fh.read().rsplit(")", 1)[1].split()[19])
    except (OSError, ValueError, IndexError):
        return None


def _lock_text():
    return (f"host: {socket.gethostname()}\npid: {os.getpid()}\n"
            f"started: {time.strftime('%Y-%m-%d %H:%M:%S %z')}\nprocess_start: {_process_start(os.getpid())}\n")


#: the most a lock file rbx writes can hold (host, pid, start: about 100 bytes); a larger file is not a lock
MAX_LOCK_BYTES = 4096


class NotALock(FileError):
    """A file under a lock's name that no run wrote and that rbx will not take over: not a regular file (a FIFO,
    a directory, a link), or larger than a lock can be (a run's file written under that name)."""


def _read_lock(lock):
    """A lock file's fields -> dict (empty when it cannot be read, or holds no pid: not a lock a run wrote; a lock
    of bytes that are not text, a damaged one: ``{'damaged': '…'}``). Raises :class:`NotALock` for what is not a
    lock file (never opened as one: a FIFO would block the read for ever)."""
    try:
        fd, other = open_regular(lock)
    except OSError:
        return {}
    if fd is None:
        links = " (rbx does not write through links)" if os.path.islink(lock) else ""
        raise NotALock(display_path(lock), None, f"is {other}, not a lock file rbx made: remove it{links}")
    try:
        st = os.fstat(fd)
        if st.st_size > MAX_LOCK_BYTES:
            raise NotALock(display_path(lock), None, f"is a file of {format_size(st.st_size)}, not a lock rbx made "
                                                     f"(a lock holds a few lines); rbx keeps its run's lock under "
                                                     "this name: move the file elsewhere, then run again")
        data = os.read(fd, MAX_LOCK_BYTES)
    except NotALock:
        raise
    except OSError:
        return {}
    finally:
        os.close(fd)
    try:
        text = data.decode()
    except UnicodeDecodeError:
        return {"damaged": f"{len(data)} bytes that are not a lock's text"}
    fields = {}
    for line in text.splitlines():
        key, _, value = line.partition(":")
        fields[key.strip()] = value.strip()
    return fields if fields.get("pid") else {}


def _holder(fields):
    return f"pid {fields.get('pid', '?')} on {fields.get('host', '?')} since {fields.get('started', '?')}"


def _is_stale(fields):
    """True if the lock's process is known to be gone: on this host, its pid no longer runs (or runs a process
    started later, which reused the pid). A lock of another host is never judged stale."""
    if fields.get("host") != socket.gethostname():
        return False
    try:
        pid = int(fields.get("pid", ""))
    except ValueError:
        return False
    if pid <= 0:
        return False
    if pid == os.getpid():
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:   # another user's live process
        return False
    recorded = fields.get("process_start")
    now = _process_start(pid)
    return recorded not in (None, "None", "") and now is not None and str(now) != recorded


def busy(path, holder):
    """The error for a ``path`` whose lock ``holder`` (a live run) holds."""
    return FileError(path, None, f"another rbx run is writing it ({holder}; lock {display_path(lock_path(path))}): "
                                 "wait for it to end or stop it (a lock of a process on another host that is gone: "
                                 "remove it)")


def _other_thread(lock):
    held = _HELD.get(lock)
    return held is not None and held[1] != threading.get_ident()


def _own_holder():
    return f"another run of this process, pid {os.getpid()} on {socket.gethostname()}"


def lock_holder(path):
    """Who holds the lock of a run writing ``path`` -> 'pid N on HOST since TIME', or None when no live run does
    (no lock, a stale or empty one, or this thread's own)."""
    lock = lock_path(path)
    if lock in _HELD:
        return _own_holder() if _other_thread(lock) else None
    if not os.path.lexists(lock):
        return None
    fields = _read_lock(lock)
    if not fields or "damaged" in fields or _is_stale(fields) or fields.get("pid") == str(os.getpid()):
        return None
    return _holder(fields)


def taken_fresh(lock):
    """True if this thread took ``lock`` once only (it was free: no live run is making this file)."""
    held = _HELD.get(lock)
    return held is not None and held[0] == 1


def acquire_lock(path, warn=None):
    """Take the lock of a run writing ``path`` (``OUT.h5.lock``, holding the host, pid and start time): held while
    the run writes, released by :func:`release_lock` (and, should the process end without that, at its exit).
    A lock whose process is gone (same host, pid not running: a SIGKILLed run), or that names no process (empty:
    never a live run's), is stale: said through ``warn(message)`` (default: one line on stderr) and taken over.
    Raises :class:`FileError` naming the holder when a live process, or another thread of this one, holds it;
    :class:`DiskFull` when there is no room for it; :class:`LockNotWritable` when its folder cannot be written.
    Taking a lock this thread holds already is allowed."""
    lock = lock_path(path)
    with _GUARD:
        if lock in _HELD:
            if _other_thread(lock):
                raise busy(path, _own_holder())
            _HELD[lock][0] += 1
            return lock
        try:
            os.makedirs(os.path.dirname(lock), exist_ok=True)
        except OSError as exc:
            raise _cannot(lock, exc, "make the folder of the run's lock file") from None
        for _ in range(5):
            try:
                _create(lock)
            except FileExistsError:
                fields = _read_lock(lock)
                if not fields:         # a lock written by an rbx without whole locks, this instant: look again
                    time.sleep(0.05)
                    fields = _read_lock(lock)
                if not fields or "damaged" in fields or _is_stale(fields):
                    _take_over(lock, fields, warn)
                    continue
                raise busy(path, _holder(fields)) from None
            except OSError as exc:
                raise _cannot(lock, exc, "create the run's lock file") from None
            _HELD[lock] = [1, threading.get_ident()]
            _at_exit()
            return lock
    raise FileError(path, None, f"cannot take the lock {display_path(lock)}: other runs keep taking it")


def _cannot(lock, exc, what):
    """The error for a lock that cannot be made or removed: no room, a folder rbx cannot write, or another."""
    if exc.errno in NO_ROOM:
        return DiskFull(f"{display_path(lock)}: cannot {what}: {exc.strerror}: no room on the disk (or a size "
                        "limit, ulimit -f?)")
    if exc.errno in NOT_WRITABLE:
        return LockNotWritable(lock, None, f"cannot {what}: {exc.strerror}")
    return FileError(lock, None, f"cannot {what}: {exc.strerror or exc}")


def _create(lock):
    """Make ``lock`` whole at once: written under another name, then linked (fails if ``lock`` exists). Where
    the file system has no hard links, created exclusively and written."""
    # a name of its own, created exclusively: whatever is at the name already (a link, a FIFO, a file) is never
    # opened. The random part makes it unknown in advance (a link put at a name known from the pid and the thread
    # had the lock written through it into a file outside the run, and a FIFO held the open past SIGTERM)
    aside, fd = create_new(lambda token: f"{lock}.new.{os.getpid()}.{threading.get_ident()}.{token}", 0o644)
    try:
        try:
            os.write(fd, _lock_text().encode())
        finally:
            os.close(fd)
        try:
            os.link(aside, lock)
            return
        except (FileExistsError, FileNotFoundError):
            raise
        except OSError as exc:
            if exc.errno not in (errno.EPERM, errno.EOPNOTSUPP, errno.EXDEV, errno.EMLINK, errno.ENOSYS):
                raise
        fd = os.open(lock, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        try:
            os.write(fd, _lock_text().encode())
        except OSError:
            os.close(fd)
            os.remove(lock)
            raise
        os.close(fd)
    finally:
        with contextlib.suppress(OSError):
            os.remove(aside)


def _take_over(lock, fields, warn):
    """Remove a stale lock, unless another process took it over first (then the loop sees its live lock)."""
    # a name nobody can know in advance, and found free: the rename replaces whatever is at its target (a file put at
    # ``OUT.h5.lock.stale.<pid>``, the pid known from ``exec``, was replaced, then removed)
    while True:
        aside = f"{lock}.stale.{os.getpid()}.{secrets.token_hex(4)}"
        if not os.path.lexists(aside):
            break
    try:
        os.rename(lock, aside)     # one process wins this; the others find no lock, or a new live one
    except FileNotFoundError:
        return
    except OSError as exc:
        raise _cannot(lock, exc, "take over the stale lock") from None
    if _read_lock(aside) != fields:            # not the stale lock but one taken meanwhile: put it back
        with contextlib.suppress(OSError):
            os.link(aside, lock)
        os.remove(aside)
        return
    os.remove(aside)
    if fields.get("pid", "").isdigit():
        # the file a killed run wrote its lock in before linking it (``_create``): its process is gone, so is its use
        # only names of the form _create makes (``.new.<pid>.<thread>.<8 hex digits>``, before the random part
        # ``.new.<pid>.<thread>``): a user's file named ``OUT.h5.lock.new.<pid>.notes`` is not one
        mine = re.compile(re.escape(f"{os.path.basename(lock)}.new.{fields['pid']}.") + r"[0-9]+(\.[0-9a-f]{8})?")
        for left in glob.glob(f"{glob.escape(lock)}.new.{fields['pid']}.*"):
            with contextlib.suppress(OSError):
                if mine.fullmatch(os.path.basename(left)) and os.path.isfile(left) and not os.path.islink(left):
                    os.remove(left)
    what = (f"a damaged lock ({fields['damaged']}: no run's)" if "damaged" in fields else
            f"a stale lock ({_holder(fields)}, a process that no longer runs: killed?)" if fields else
            "an empty lock (left by a run that could not write it: a full disk?)")
    message = f"{display_path(lock)}: warning: {what} was taken over"
    if warn is None:
        sys.stderr.write(f"rbx: {message}\n")
    else:
        warn(message)


def release_lock(path):
    """Give back the lock of ``path`` taken by :func:`acquire_lock` (removed when its last taker gives it back)."""
    lock = lock_path(path)
    with _GUARD:
        if lock not in _HELD:
            return
        _HELD[lock][0] -= 1
        if _HELD[lock][0] <= 0:
            del _HELD[lock]
            _remove_own_lock(lock)


def _remove_own_lock(lock):
    try:
        fields = _read_lock(lock)
    except NotALock:         # not ours any more: left alone
        return
    if fields.get("pid") == str(os.getpid()):
        with contextlib.suppress(OSError):
            os.remove(lock)


_EXIT_HOOK = []


def _at_exit():
    """Once per process: remove the locks still held when it exits (an error or a signal between taking a lock
    and the end of the run). Not in a forked child: its parent holds them."""
    if _EXIT_HOOK:
        return
    owner = os.getpid()

    def release_all():
        if os.getpid() == owner:
            release_held_locks()

    atexit.register(release_all)
    _EXIT_HOOK.append(release_all)


def release_held_locks():
    """Remove every lock this process still holds: what the exit hook does, for an exit that skips Python's own
    (``rbx.cli.common.hard_exit``)."""
    for lock in list(_HELD):
        _HELD.pop(lock, None)
        _remove_own_lock(lock)
