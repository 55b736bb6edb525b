"""A write-ahead journal under HDF5: a run's file changes only at its checkpoints, all at once.

HDF5 keeps no journal of its own. A process killed while HDF5 flushed its metadata, or while it rewrote a partly
filled chunk in place, could leave a file that no longer opened (about 1 kill in 100 at the worst instants,
docs/reliability.md). :class:`JournaledFile` is the file object h5py's ``fileobj`` driver writes a run's file
through (:func:`rbx.runfile.open_journaled`). It splits the file at ``committed``, its length at the last commit:

- bytes *below* it (what the last committed state of the file is made of) are never written in place between
  commits: a write there goes to an overlay of pages in memory, and reads see the overlay;
- bytes *at or above* it are written to the file at once: no committed structure points there yet.

:meth:`JournaledFile.commit` (at each checkpoint, after HDF5's flush) writes the overlay's pages that differ from
the file (HDF5 rewrites a chunk whole for a few records) to ``FILE.journal.tmp`` with a CRC-32, renames it to
``FILE.journal`` (the commit point: a rename is atomic), copies the pages into the file, and removes the
journal. A kill at any instant leaves one of two files: the last commit (no journal, or a
``.journal.tmp`` that changes nothing and that the next writer removes), or the new one (a whole ``.journal``
that :func:`recover` copies in again before the file is next opened: copying it twice writes the same bytes).

The journal names its file by content, not by inode, so that it still applies to a copy of the pair (a folder
moved to another disk, restored from a backup): it holds a CRC-32 of each page as the file had it before the
commit, and it is applied only to a file each of whose pages is either that (not copied in yet) or the page the
journal holds (copied in already), and that holds the random mark the commit wrote past the bytes HDF5 wrote
straight to the file since the last commit (a copy of the file made one checkpoint earlier has the same pages but
not those bytes); any other file is refused. While its pages are copied in, the file's HDF5
signature is replaced by :data:`TORN` (the first write of the copying-in; page 0 is written last and puts the
signature back), so a file whose journal was lost halfway through is refused by HDF5 and named as torn by rbx
(:func:`torn`), never read as if it were whole. Where the file cannot be written (a read-only file system), a
reader applies the journal in memory (:class:`JournalView`), and a resume into another folder applies it to its
copy (:func:`recover` with ``journal=``). A journal left without its file is kept: a new run on that output stops
and names it (its file may live on elsewhere, torn), and ``--force`` removes it (:func:`rbx.driver.create`).

A write or read the system refuses (an I/O error, the disk full) is kept as the file's ``failure`` rather than
raised through h5py's callbacks (:func:`_failing`); from then on nothing is committed, and the next commit raises
it: the file stays at its last commit (or with its journal, if the copying-in failed). The file is locked
(``flock``) as HDF5 locks a file it writes, so HDF5 readers are refused meanwhile.

It guards against a process being killed, not against the machine losing power: nothing is fsynced at a commit
(the system's page cache keeps the order of writes of a killed process; an fsync per checkpoint would wait for
the disk).
"""
import contextlib
import errno
import math
import os
import struct
import zlib

from .paths import JOURNAL_SUFFIX, FileError, create_own, open_regular

#: the overlay's page size: a write below ``committed`` copies the pages it touches
PAGE = 4096
MAGIC = b"rbx journal 3\n"
#: after the magic: the file's length (HDF5's) once the journal is applied, page count, and a random mark the commit
#: wrote into the file (where, and its 8 bytes); then the page numbers (u8 each), then the CRC-32 of each page as the
#: file had it before (u4 each), then the pages, then a CRC-32 of all that. The rename is what makes a journal
#: whole; the CRC catches a journal changed since (6.6 GB/s here, against 1.3 GB/s for BLAKE2b: it is computed at
#: every checkpoint)
HEADER = struct.Struct("<QQQ8s")
CRC = struct.Struct("<I")
#: the journals before: no mark (the bytes written past the old end were checked by nothing)
MAGIC_2 = b"rbx journal 2\n"
HEADER_2 = struct.Struct("<QQ")
#: the first journals rbx wrote named their file by inode and device: file inode, file device, length, page count
MAGIC_1 = b"rbx journal 1\n"
HEADER_1 = struct.Struct("<QQQQ")


class JournalError(Exception):
    """A journal that cannot be applied (damaged, or made for another file)."""


#: what stands in place of HDF5's signature (the file's first 8 bytes) while a journal's pages are copied in
TORN = b"\x89RBXtorn"


def _failing(fallback):
    """An I/O method HDF5 calls through h5py, which must not raise: h5py's callbacks print an exception as
    unraisable, and the next callback can then crash the process (seen: a segmentation fault after an EIO). An
    OSError (an I/O error, the disk full) is kept as the file's ``failure``; from then on every write is held in
    memory (``cut`` = ∞) and none is committed again: the file stays at its last commit, and :meth:`commit` raises
    the failure at the next checkpoint. The method is tried once more that way; ``fallback(self, *args)`` is its
    result if that fails too."""
    def decorate(method):
        def wrapped(self, *args):
            try:
                return method(self, *args)
            except OSError as exc:
                if self.failure is None:
                    self.failure = exc
                self.cut = math.inf
            try:
                return method(self, *args)
            except OSError:
                return fallback(self, *args)
        wrapped.__name__, wrapped.__doc__ = method.__name__, method.__doc__
        return wrapped
    return decorate


def _zeros(self, buf):
    n = min(len(buf), max(0, self.size - self.pos))
    memoryview(buf).cast("B")[:n] = bytes(n)
    self.pos += n
    return n


def _skip(self, data):
    n = len(memoryview(data).cast("B"))
    self.pos += n
    self.size = max(self.size, self.pos)
    return n


def _resize(self, size=None):
    self.size = self.pos if size is None else size
    return self.size


def journal_path(path):
    return f"{path}{JOURNAL_SUFFIX}"


class JournaledFile:
    """A file h5py's ``fileobj`` driver reads and writes (``h5py.File(JournaledFile(path), mode)``): the methods
    that driver calls (``seek``, ``tell``, ``readinto``, ``write``, ``truncate``, ``flush``) with the file split as
    the module says. ``create``: a new file (exclusive: an existing one is an error); else an existing one, whose
    journal (if any) is applied first. ``repr`` is the path: h5py names the file by it (``h5.filename``)."""

    def __init__(self, path, create=False):
        self.path = str(path)
        if create:
            self.fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o666)
        else:
            recover(self.path)
            self.fd = os.open(self.path, os.O_RDWR)
        try:
            _lock(self.fd)
        except BaseException:
            fd, self.fd = self.fd, None         # closed once, and never again by close()
            os.close(fd)
            raise
        self.pos = 0
        #: the first OSError of a write or read (then nothing more is committed: the file stays at its last commit)
        self.failure = None
        #: HDF5's length of the file (its last truncate or the end of its furthest write)
        self.size = os.fstat(self.fd).st_size
        # the committed file ends where HDF5's superblock says: past it lies at most the room a killed run had
        # reserved (rbx.runfile.H5Sink._reserve), which new writes may use without the journal
        end = _hdf5_end(self.fd)
        if end is not None and end <= self.size:
            self.size = end
        self._commit_at(self.size)

    def __repr__(self):
        return self.path

    def _commit_at(self, size):
        self.committed = size
        #: the first byte not covered by the overlay's pages: bytes below go to the overlay
        self.cut = -(-size // PAGE) * PAGE
        self.overlay = {}

    # ---- what h5py's fileobj driver calls -----------------------------------------------------------------------
    def seekable(self):
        return True

    def readable(self):
        return True

    def writable(self):
        return True

    def seek(self, offset, whence=0):
        if whence == 0:
            self.pos = offset
        elif whence == 1:
            self.pos += offset
        else:
            self.pos = self.size + offset
        return self.pos

    def tell(self):
        return self.pos

    def _page(self, k):
        page = self.overlay.get(k)
        if page is None:
            page = bytearray(os.pread(self.fd, PAGE, k * PAGE).ljust(PAGE, b"\0") if self.failure is None
                             else PAGE)      # after a failure: the file is not read again
            self.overlay[k] = page
        return page

    def read(self, size=-1):
        size = max(0, self.size - self.pos) if size is None or size < 0 else size
        buf = bytearray(size)
        return bytes(buf[:self.readinto(buf)])

    @_failing(_zeros)
    def readinto(self, buf):
        mv = memoryview(buf).cast("B")
        n = min(len(mv), max(0, self.size - self.pos))
        pos, done = self.pos, 0
        while done < n:
            at = pos + done
            k, off = divmod(at, PAGE)
            page = self.overlay.get(k) if at < self.cut else None
            if page is not None:
                m = min(PAGE - off, n - done)
                mv[done:done + m] = page[off:off + m]
            else:
                # from the file, up to the next page the overlay holds (one read, not one per page)
                end = n
                if at < self.cut and self.overlay:
                    q = k + 1
                    while q * PAGE < min(pos + n, self.cut):
                        if q in self.overlay:
                            end = q * PAGE - pos
                            break
                        q += 1
                m = end - done
                got = os.preadv(self.fd, [mv[done:done + m]], at)
                if got < m:      # within HDF5's length but past the file's (a truncate that grew it): zeros
                    mv[done + got:done + m] = bytes(m - got)
            done += m
        self.pos += n
        return n

    def _put(self, at, mv):
        """Write the bytes ``mv`` at ``at``: below ``cut`` into the overlay's pages, the rest into the file."""
        n, done = len(mv), 0
        while done < n and at + done < self.cut:
            k, off = divmod(at + done, PAGE)
            m = min(PAGE - off, n - done)
            if m == PAGE:              # the whole page: nothing of the file's to keep
                self.overlay[k] = bytearray(mv[done:done + PAGE])
            else:
                self._page(k)[off:off + m] = mv[done:done + m]
            done += m
        while done < n:
            done += os.pwrite(self.fd, mv[done:], at + done)

    def _grow(self, end):
        """HDF5's length grows to ``end``: the bytes between the old length and ``end`` read as zeros, as in any
        file, though the file may still hold bytes there from before a truncate (kept for the reservation)."""
        stale_end = min(end, max(os.fstat(self.fd).st_size, self.cut))
        at = self.size
        while at < stale_end:
            m = min(stale_end - at, 1 << 20)
            self._put(at, memoryview(bytes(m)))
            at += m
        self.size = end

    @_failing(_skip)
    def write(self, data):
        mv = memoryview(data).cast("B")
        if self.pos > self.size:
            self._grow(self.pos)
        self._put(self.pos, mv)
        self.pos += len(mv)
        self.size = max(self.size, self.pos)
        return len(mv)

    @_failing(_resize)
    def truncate(self, size=None):
        """HDF5's new length. The file itself is cut only at :meth:`close` (and never below ``committed`` before
        a commit): room reserved past HDF5's end (rbx.runfile.H5Sink._reserve) stays reserved meanwhile."""
        size = self.pos if size is None else size
        if size > self.size:
            self._grow(size)
            if size > os.fstat(self.fd).st_size:
                os.ftruncate(self.fd, size)
        self.size = size
        return size

    def flush(self):
        pass

    # ---- commits ------------------------------------------------------------------------------------------------
    def commit(self):
        """Make the file what HDF5 last wrote, all at once (the module says how) -> bytes journalled. After a
        failed write (``failure``) HDF5's picture of the file is not what it wrote: that failure is raised, and the
        file stays at its last commit."""
        if self.failure is not None:
            raise self.failure
        pages, before = _changed(self.fd, self.overlay) if self.overlay else ([], [])
        if not pages:      # nothing below ``committed`` changed: what HDF5 wrote past it is the commit
            self._commit_at(self.size)
            return 0
        if pages[0] != 0:
            # page 0 always, changed or not: its CRC before pins the file's old superblock (HDF5's end of file)
            pages.insert(0, 0)
            before.insert(0, zlib.crc32(_file_page(self.fd, 0)))
            self._page(0)
        # HDF5 wrote the bytes past the overlay straight to the file, and the journal's pages point into them: a
        # copy of the file made one checkpoint earlier has the same pages below, but not these. A random mark
        # written past them, where neither the journal nor HDF5 writes before the journal is gone, names the file
        # that holds them (reading them back for a CRC cost 15 % of a run writing 700 MB/s)
        mark_at, mark = max(self.size, self.cut), os.urandom(8)
        parts = [MAGIC + HEADER.pack(self.size, len(pages), mark_at, mark) +
                 struct.pack(f"<{len(pages)}Q", *pages) + struct.pack(f"<{len(pages)}I", *before)] + \
            [self.overlay[k] for k in pages]
        crc = 0
        for part in parts:
            crc = zlib.crc32(part, crc)
        parts.append(CRC.pack(crc))
        final = journal_path(self.path)
        tmp = f"{final}.tmp"
        written = False
        try:
            _write_all(self.fd, [mark], mark_at)
            try:
                _write_journal(tmp, parts)
            except OSError as exc:
                if exc.errno not in (errno.ENOSPC, errno.EDQUOT) or os.fstat(self.fd).st_size <= mark_at + len(mark):
                    raise
                # no room for the journal: give back the room reserved in the file past HDF5's end for writes that
                # went elsewhere (chunks put in room freed inside the file), and try once more
                os.ftruncate(self.fd, mark_at + len(mark))
                _write_journal(tmp, parts)
            written = True
            os.replace(tmp, final)           # the commit point
        except OSError as exc:               # not committed: the file is as it was
            self.failure = self.failure or exc
            if written:                      # only the journal this commit wrote (not a file found at its name)
                with contextlib.suppress(OSError):
                    os.remove(tmp)
            raise
        try:
            _copy_in(self.fd, pages, self.overlay)
        except OSError as exc:               # committed, not applied: the journal stays, the next open applies it
            self.failure = self.failure or exc
            raise
        os.remove(final)
        self._commit_at(self.size)
        return sum(len(p) for p in parts)

    def close(self, commit=True):
        """Commit (unless ``commit`` is False: the file stays at its last commit) and close the file, cut to
        HDF5's length."""
        if self.fd is None:
            return
        try:
            if commit and self.failure is None:
                self.commit()
                if os.fstat(self.fd).st_size > self.size:
                    os.ftruncate(self.fd, self.size)
            elif not os.path.exists(journal_path(self.path)):
                # the file stays at its last commit: what lies past it (writes never committed, room reserved for
                # them) is given back, or every later attempt found that much less room on a small disk
                with contextlib.suppress(OSError):
                    if os.fstat(self.fd).st_size > self.committed:
                        os.ftruncate(self.fd, self.committed)
        finally:
            os.close(self.fd)
            self.fd = None

    def rename(self, path):
        """The file was renamed (or linked) to ``path`` with no journal pending: the next commit journals there."""
        self.path = str(path)


def _write_journal(tmp, parts):
    """Write the journal ``parts`` to ``tmp``, a name created here (a failed write removes it). A regular file found
    there is a killed writer's and is replaced (:func:`rbx.paths.create_own`); anything else is left alone, and
    the commit fails."""
    try:
        fd = create_own(tmp)        # never through a link or into a FIFO someone put at this name
    except FileError as exc:        # the commit fails as any I/O error does: the run stops at its last checkpoint
        raise OSError(errno.EEXIST, f"{exc}") from None
    except FileExistsError:
        raise OSError(errno.EEXIST, f"{tmp}: appeared while the run wrote its journal; rbx writes nothing through "
                                    "it: remove it, then resume") from None
    try:
        _write_all(fd, parts, 0)
    except BaseException:
        os.close(fd)
        with contextlib.suppress(OSError):
            os.remove(tmp)
        raise
    os.close(fd)


def _lock(fd, shared=False):
    """Lock the file as HDF5 locks a file it writes (``flock``, exclusive), so that HDF5 refuses to open it for
    reading meanwhile, as it did before rbx wrote through a file object (h5py's fileobj driver takes no lock):
    ``rbx.reader._open_h5`` then says which run writes it. Not where HDF5 would not lock either
    (``HDF5_USE_FILE_LOCKING=FALSE``), nor where the file system has no locks."""
    if os.environ.get("HDF5_USE_FILE_LOCKING", "").upper() in ("FALSE", "0"):
        return
    import fcntl            # POSIX only: imported where the lock is taken
    try:
        fcntl.flock(fd, (fcntl.LOCK_SH if shared else fcntl.LOCK_EX) | fcntl.LOCK_NB)
    except OSError as exc:
        if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
            raise OSError(exc.errno, "the file is open in another program (an HDF5 lock is held on it)") from None
        # ENOLCK, EOPNOTSUPP, ENOSYS: a file system without locks, as HDF5 itself would find


#: HDF5's superblock: its signature, and where versions 0/1 and 2/3 keep the base and end-of-file addresses
SIGNATURE = b"\x89HDF\r\n\x1a\n"


def _hdf5_end(fd):
    """HDF5's end-of-file address, read from the superblock at the start of the file -> bytes, or None where it
    cannot be read (another layout: the caller keeps the file's length)."""
    head = os.pread(fd, 48, 0)
    if len(head) < 48 or not head.startswith(SIGNATURE):
        return None
    version = head[8]
    if version in (0, 1) and head[13] == 8:
        at = 24 if version == 0 else 28
        base, end = struct.unpack_from("<Q", head, at)[0], struct.unpack_from("<Q", head, at + 16)[0]
    elif version in (2, 3) and head[9] == 8:
        base, end = struct.unpack_from("<Q", head, 12)[0], struct.unpack_from("<Q", head, 28)[0]
    else:
        return None
    return base + end


def _write_all(fd, parts, offset):
    """Write the buffers ``parts`` one after another at ``offset`` (pwritev, as many calls as it takes)."""
    views = [memoryview(p) for p in parts if len(p)]
    while views:
        done = os.pwritev(fd, views[:1024], offset)
        offset += done
        while views and done >= len(views[0]):
            done -= len(views[0])
            views.pop(0)
        if done:
            views[0] = views[0][done:]


def _changed(fd, overlay):
    """The pages of ``overlay`` whose bytes differ from the file's, sorted -> (page numbers, the CRC-32 of each as
    the file has it: what the journal checks a file against before it applies to it). HDF5 rewrites a
    partly filled chunk whole (its checksum covers it all), so most pages of a chunk a block adds a few records
    to are written unchanged: only the changed ones are journalled (the room a checkpoint's journal takes then
    follows the records written, not the chunks touched: rbx.runfile.H5Sink asks for that much)."""
    pages = sorted(overlay)
    changed, before = [], []
    i = 0
    while i < len(pages):
        j = i + 1
        while j < len(pages) and pages[j] == pages[j - 1] + 1 and j - i < 256:
            j += 1
        on_disk = os.pread(fd, (j - i) * PAGE, pages[i] * PAGE)
        for n, k in enumerate(pages[i:j]):
            page = on_disk[n * PAGE:(n + 1) * PAGE]
            if page != overlay[k]:
                changed.append(k)
                before.append(zlib.crc32(page.ljust(PAGE, b"\0")))
        i = j
    return changed, before


def _copy_in(fd, pages, overlay):
    """Copy a journal's pages (sorted page numbers, ``overlay[k]`` their bytes) into the file so that a kill
    halfway leaves a file HDF5 refuses and rbx names as torn (:func:`torn`): its signature replaced by
    :data:`TORN` first, page 0 (which puts it back) written last."""
    marked = os.pread(fd, len(SIGNATURE), 0) == SIGNATURE
    if marked:
        _write_all(fd, [TORN], 0)
    _apply(fd, [k for k in pages if k != 0], overlay)
    if 0 in overlay and 0 in pages:
        _write_all(fd, [overlay[0]], 0)
    elif marked or os.pread(fd, len(TORN), 0) == TORN:
        _write_all(fd, [SIGNATURE], 0)


def torn(path_or_fd):
    """Whether a file's pages were being copied in from its journal when its writer was killed (its first bytes
    are :data:`TORN`): without that journal it is neither its last checkpoint nor the next one."""
    if isinstance(path_or_fd, int):
        return os.pread(path_or_fd, len(TORN), 0) == TORN
    try:
        with open(path_or_fd, "rb") as fh:
            return fh.read(len(TORN)) == TORN
    except OSError:
        return False


def _file_page(fd, k):
    """Page ``k`` of the file as the journal's CRCs and pages see it (a :data:`TORN` mark read as the signature)."""
    page = os.pread(fd, PAGE, k * PAGE).ljust(PAGE, b"\0")
    if k == 0 and page.startswith(TORN):
        page = SIGNATURE + page[len(TORN):]
    return page


def _apply(fd, pages, overlay):
    """Write the pages (sorted page numbers, ``overlay[k]`` their bytes) into the file: one write per run of
    consecutive pages."""
    i = 0
    while i < len(pages):
        j = i + 1
        while j < len(pages) and pages[j] == pages[j - 1] + 1:
            j += 1
        _write_all(fd, [overlay[k] for k in pages[i:j]], pages[i] * PAGE)
        i = j


class _Journal:
    """A journal as read: the file's length once applied, its pages, each page's CRC-32 before (None: a first
    journal, which names its file by ``inode`` = (inode, device) instead)."""

    def __init__(self, size, pages, before=None, inode=None, mark=None):
        self.size, self.pages, self.before, self.inode = size, pages, before, inode
        #: (where the commit wrote its mark into the file, the mark); None: an older journal
        self.mark = mark


def _damaged(problem):
    exc = JournalError(problem)
    exc.damaged = True
    return exc


def _read_journal(jpath):
    """-> :class:`_Journal`; JournalError if it is not a whole journal (``damaged`` set when it is an rbx journal
    changed or cut short since it was written)."""
    fd, other = open_regular(jpath)
    if fd is None:     # never read: a FIFO would wait for a writer for ever, a link may lead anywhere (/dev/zero)
        raise JournalError(f"is {other}, not a journal rbx wrote: rbx keeps a file's journal under "
                           f"this name and reads it before the file; remove it (or rename it), then run again")
    with os.fdopen(fd, "rb") as fh:
        from .simulation import memory_problem
        problem = memory_problem(1, os.fstat(fh.fileno()).st_size)
        if problem:     # it is read whole: a file of 4 GB put at the name ended in a MemoryError traceback
            raise JournalError(f"is larger than this process may hold ({problem}): not a journal rbx wrote; rbx "
                               "keeps a file's journal under this name and reads it before the file; move it "
                               "elsewhere (or rename it), then run again")
        raw = fh.read()
    first = raw[:len(MAGIC_1)] == MAGIC_1
    second = raw[:len(MAGIC_2)] == MAGIC_2
    header = HEADER_1 if first else HEADER_2 if second else HEADER
    at = len(MAGIC) + header.size
    if not raw or not any(raw.startswith(m[:len(raw)]) for m in (MAGIC, MAGIC_2, MAGIC_1)):
        raise JournalError(f"is not a journal rbx wrote ({len(raw)} bytes that do not begin as one); rbx keeps "
                           f"{os.path.basename(jpath[:-len('.journal')])}'s journal under this name and reads it "
                           "before that file: move it elsewhere (or rename it), then run again")
    if len(raw) < at + CRC.size:
        raise _damaged("is an rbx journal cut short (damaged)")
    body, (crc,) = raw[:-CRC.size], CRC.unpack(raw[-CRC.size:])
    if zlib.crc32(body) != crc:
        raise _damaged("is damaged (its checksum does not match)")
    mark = None
    if first:
        ino, dev, size, count = header.unpack_from(body, len(MAGIC))
    elif second:
        size, count = header.unpack_from(body, len(MAGIC))
    else:
        size, count, mark_at, mark_bytes = header.unpack_from(body, len(MAGIC))
        mark = (mark_at, mark_bytes)
    per_page = 8 + PAGE + (0 if first else 4)
    if len(body) != at + count * per_page:
        raise _damaged("is damaged (its length does not match its page count)")
    numbers = struct.unpack_from(f"<{count}Q", body, at)
    at += 8 * count
    before = None
    if not first:
        before = dict(zip(numbers, struct.unpack_from(f"<{count}I", body, at)))
        at += 4 * count
    pages = {k: body[at + i * PAGE:at + (i + 1) * PAGE] for i, k in enumerate(numbers)}
    return _Journal(size, pages, before, (ino, dev) if first else None, mark)


def _without_it(torn_file):
    """What a file is without a journal that cannot be applied to it, and so what to do."""
    if torn_file:
        return ("the file is torn (its run was killed while this checkpoint was being copied into it), and only "
                "the journal that run left can finish it: put that journal back beside the file (from where the "
                "run was killed, or a backup), else run the config again")
    return ("the file is whole without it (as of the last checkpoint copied into it): move the journal away, then "
            "run again")


def _check_file(fd, j):
    """The journal ``j`` belongs to the file open as ``fd``: each of its pages is either as it was before the
    commit or as the journal makes it (a copy of the file is the file); JournalError otherwise."""
    if j.inode is not None:
        st = os.fstat(fd)
        if (st.st_ino, st.st_dev) != j.inode:
            raise JournalError(f"was written for another file (inode {j.inode[0]}, this file's is {st.st_ino}) by "
                               f"an older rbx, which named a file by its inode: a copy of the folder, or the journal "
                               f"of an earlier run; {_without_it(torn(fd))}")
        return
    for k, page in j.pages.items():
        now = _file_page(fd, k)
        if now != page and zlib.crc32(now) != j.before[k]:
            raise JournalError(f"was written for another file: page {k} of this file is neither as the journal "
                               "found it nor as it makes it (the journal an earlier run left, or the file was "
                               f"changed or replaced since its run was killed); {_without_it(torn(fd))}")
    if j.mark is not None and os.pread(fd, len(j.mark[1]), j.mark[0]) != j.mark[1]:
        raise JournalError("was written for another file: this file lacks the bytes its checkpoint wrote past the "
                           "file's end before it (a copy of the file as of an earlier checkpoint, such as a backup, "
                           f"or the file was changed since its run was killed); {_without_it(torn(fd))}")


def _read_checked(jpath, path):
    """Read the journal ``jpath`` of the file ``path`` -> :class:`_Journal`, or None if there is none; a damaged one
    is a JournalError that says what the file is without it."""
    try:
        return _read_journal(jpath)
    except FileNotFoundError:     # none, or another process applied it a moment ago
        return None
    except JournalError as exc:
        if getattr(exc, "damaged", False):
            raise JournalError(f"{exc}: {_without_it(torn(path))}") from None
        raise


def pending(path):
    """Whether ``path`` has a journal not yet applied (its writer was killed inside a commit, after the commit
    point): :func:`recover` is due before the file is read. (A ``.journal.tmp``, a commit that did not reach its
    commit point, changes nothing: the next writer removes it.)"""
    return os.path.exists(journal_path(path))


def recover(path, journal=None):
    """Finish a commit that a kill interrupted: apply ``FILE.journal`` (if any) to ``path`` and remove it; remove a
    ``FILE.journal.tmp`` (a commit that never reached its commit point) -> True if a journal was applied.
    ``journal``: apply that journal (another file's: ``path`` is a copy of it) and leave it where it is.
    JournalError if the journal is damaged or does not belong to the file (:func:`_check_file`). Call it only
    where no live process writes ``path`` (rbx holds the run's lock)."""
    jpath = journal or journal_path(path)
    if journal is None:
        with contextlib.suppress(OSError):       # a read-only folder: it changes nothing anyway
            os.remove(f"{jpath}.tmp")
    j = _read_checked(jpath, path)
    if j is None:
        return False
    fd = os.open(path, os.O_RDWR)
    try:
        _check_file(fd, j)
        _copy_in(fd, sorted(j.pages), j.pages)
        if os.fstat(fd).st_size < j.size:
            os.ftruncate(fd, j.size)
    finally:
        os.close(fd)
    if journal is None:
        with contextlib.suppress(FileNotFoundError):
            os.remove(jpath)
    return True


class JournalView(JournaledFile):
    """A file with its pending journal applied in memory, for reading where the file cannot be written (a
    read-only file system) or its run's lock cannot be taken to apply the journal: ``h5py.File(JournalView(path),
    "r")``. JournalError as :func:`recover`. ``shared``: the file locked for reading (``flock``, shared) as long
    as the view is open, as HDF5 locks a file it reads: OSError where a writer has it open."""

    def __init__(self, path, shared=False):
        self.path = str(path)
        j = _read_checked(journal_path(self.path), self.path)
        self.fd = os.open(self.path, os.O_RDONLY)
        try:
            if shared:
                _lock(self.fd, shared=True)
            if j is not None:
                _check_file(self.fd, j)
            pages = dict(j.pages) if j is not None else {}
            if 0 not in pages:
                pages[0] = _file_page(self.fd, 0)
            size = os.fstat(self.fd).st_size
        except BaseException:
            # closed here, and forgotten: __del__ would close the same number again later, by then perhaps a file
            # the caller has opened since (a line of its log went into another file)
            fd, self.fd = self.fd, None
            os.close(fd)
            raise
        self.pos, self.failure = 0, None
        self.size = max(size, j.size if j is not None else 0)
        self.overlay = {k: bytearray(v) for k, v in pages.items()}
        self.committed, self.cut = self.size, (max(pages) + 1) * PAGE

    def writable(self):
        return False

    def close(self, commit=False):
        if self.fd is not None:
            os.close(self.fd)
            self.fd = None

    def __del__(self):
        self.close()


def discard(path):
    """Remove ``path``'s journal files (the file itself is being removed or replaced)."""
    for p in (journal_path(path), f"{journal_path(path)}.tmp"):
        with contextlib.suppress(FileNotFoundError):
            os.remove(p)
