"""The write-ahead journal under a run's HDF5 file (rbx/journal.py): the file on disk changes only at commits, and
a process killed at any instant leaves either the last commit or the next one, never a mixture.

Kills are real: the process writing the file sends itself SIGKILL at a chosen step of a commit (the step's
function wrapped in a subprocess, no hook in rbx), and a fresh process opens what is left.
"""
import os
import random
import shutil
import subprocess
import sys
import textwrap
import threading

import h5py
import numpy as np
import pytest

import rbx
from rbx import journal
from rbx.journal import PAGE, JournaledFile
from rbx.paths import FileError
from rbx.reader import _open_h5
from tests.test_interrupt import assert_same_records, read_run, strip_random, write_config

RBX_MAIN = "from rbx.cli.main import main; sys.argv[0] = 'rbx'; main()"


# ---- the file object alone, against a bytearray ----------------------------------------------------------------

def test_reads_see_the_writes_and_a_crash_leaves_the_last_commit(tmp_path):
    """Random writes (across the committed length and page edges), truncates and commits through a JournaledFile,
    checked against a bytearray: every read returns what was written, the file on disk equals the model at each
    commit, and reopening the file without a commit (a crash) finds the last commit's bytes exactly."""
    rng = random.Random(5)
    path = str(tmp_path / "f.bin")
    jf = JournaledFile(path, create=True)
    model = bytearray()
    committed = bytes()
    for step in range(600):
        op = rng.random()
        if op < 0.6:
            size = max(len(model), 1)
            at = rng.randrange(0, size + 3 * PAGE)
            data = bytes(rng.getrandbits(8) for _ in range(rng.choice([1, 7, PAGE - 1, PAGE, 3 * PAGE + 5])))
            jf.seek(at)
            assert jf.write(data) == len(data)
            if len(model) < at:
                model.extend(bytes(at - len(model)))
            model[at:at + len(data)] = data
        elif op < 0.7:
            size = rng.randrange(0, len(model) + 2 * PAGE + 1)
            jf.truncate(size)
            model = model[:size] + bytes(max(0, size - len(model)))
        elif op < 0.85:
            at = rng.randrange(0, len(model) + 1)
            n = rng.randrange(0, 2 * PAGE)
            jf.seek(at)
            buf = bytearray(n)
            got = jf.readinto(buf)
            assert bytes(buf[:got]) == bytes(model[at:at + n])
        else:
            jf.commit()
            committed = bytes(model)
            with open(path, "rb") as fh:
                assert fh.read()[:len(committed)] == committed
            assert not os.path.exists(journal.journal_path(path))
        jf.seek(0, 2)
        assert jf.tell() == len(model)
    os.close(jf.fd)                      # a crash: no commit, no close
    again = JournaledFile(path)
    again.seek(0)
    assert again.read(len(committed)) == committed
    again.close(commit=False)


# ---- kills inside a commit of a real HDF5 file ----------------------------------------------------------------

WRITER = textwrap.dedent("""
    import os, signal, sys
    import numpy as np
    import rbx.journal as journal
    from rbx.runfile import open_journaled, commit

    path, stage = sys.argv[1], sys.argv[2]

    def die():
        os.kill(os.getpid(), signal.SIGKILL)

    h5 = open_journaled(path, create=True)
    ds = h5.create_dataset("x", shape=(4, 0), maxshape=(4, None), chunks=(4, 64), dtype="f8", fletcher32=True)
    ds.resize(100, axis=1)
    ds[:, :] = 1.0
    h5.attrs["version"] = 1
    h5.flush()
    commit(h5)
    if len(sys.argv) > 3:                             # a copy of the file as of this commit (a backup)
        import shutil
        shutil.copyfile(path, sys.argv[3])
    # the second version: the partly filled chunk rewritten in place, metadata changed, a new object
    ds.resize(300, axis=1)
    ds[:, :] = 2.0
    h5.attrs["version"] = 2
    h5.create_group("g").attrs["a"] = 2
    h5.flush()
    if stage == "before-commit":
        die()
    if stage == "journal-written":
        os.replace = lambda *a: die()                 # the journal is whole in .tmp, not yet renamed
    if stage == "half-applied":
        apply = journal._apply
        def half(fd, pages, overlay):
            apply(fd, pages[:len(pages) // 2], overlay)
            die()
        journal._apply = half
    if stage == "applied":
        os.remove = lambda *a: die()                  # applied, the journal not yet removed
    commit(h5)
    die()
""")


@pytest.mark.parametrize("stage, version", [("before-commit", 1), ("journal-written", 1), ("half-applied", 2),
                                            ("applied", 2)])
def test_a_kill_at_any_step_of_a_commit_leaves_the_old_or_the_new_file(stage, version, tmp_path):
    path = tmp_path / "run.h5.partial"
    res = subprocess.run([sys.executable, "-c", WRITER, str(path), stage], capture_output=True, text=True,
                         timeout=300)
    assert res.returncode == -9, res.stderr
    assert journal.pending(path) == (stage in ("half-applied", "applied"))
    assert os.path.exists(f"{journal.journal_path(path)}.tmp") == (stage == "journal-written")
    with _open_h5(path) as f:                      # what every reader calls: applies a pending journal first
        assert f.attrs["version"] == version
        x = f["x"][...]
        assert x.shape == ((4, 100) if version == 1 else (4, 300))
        assert np.all(x == float(version))         # read through the chunks' checksums
        assert ("g" in f) == (version == 2)
    assert not journal.pending(path)
    # a reader leaves a .journal.tmp (it changes nothing: it never reached its commit point); a writer removes it
    JournaledFile(path).close(commit=False)
    assert not os.path.exists(f"{journal.journal_path(path)}.tmp")


def _killed_writer(path, stage="half-applied"):
    res = subprocess.run([sys.executable, "-c", WRITER, str(path), stage], capture_output=True, text=True,
                         timeout=300)
    assert res.returncode == -9 and journal.pending(path), res.stderr


def test_a_journal_copied_with_its_file_applies_to_the_copy(tmp_path):
    """A journal names its file by the pages it changes, not by inode: copied with its file (a folder moved to
    another disk, restored from a backup) it finishes the copy's checkpoint. It was refused as written for another
    file, and the file without it is torn."""
    src = tmp_path / "a.h5.partial"
    _killed_writer(src)
    assert journal.torn(src)                       # halfway through: HDF5 would refuse it
    copy = tmp_path / "b.h5.partial"
    shutil.copyfile(src, copy)
    shutil.copyfile(journal.journal_path(src), journal.journal_path(copy))
    for path in (copy, src):
        with _open_h5(path) as f:
            assert f.attrs["version"] == 2 and np.all(f["x"][...] == 2.0)
        assert not journal.pending(path) and not journal.torn(path)
    assert open(src, "rb").read() == open(copy, "rb").read()


def test_a_journal_beside_another_file_is_refused_saying_what_the_file_is_without_it(tmp_path):
    """A journal whose pages match neither what the file held nor what they become is another file's: refused,
    and the line says whether the file is whole without it (move it away) or torn (put its own journal back)."""
    torn_file = tmp_path / "a.h5.partial"
    _killed_writer(torn_file)
    whole = tmp_path / "b.h5.partial"
    _killed_writer(whole, "applied")               # every page copied in, the journal not yet removed
    other = tmp_path / "c.h5.partial"
    _killed_writer(other)
    with open(journal.journal_path(other), "rb") as fh:   # made another run's: its first page, before and after
        raw = bytearray(fh.read())
    count = journal.HEADER.unpack_from(raw, len(journal.MAGIC))[1]
    before = len(journal.MAGIC) + journal.HEADER.size + 8 * count
    raw[before:before + 4] = bytes(4)
    page = before + 4 * count
    raw[page:page + PAGE] = bytes(range(256)) * (PAGE // 256)
    raw[-4:] = journal.CRC.pack(journal.zlib.crc32(bytes(raw[:-4])))
    for path, words in ((whole, "is whole without it"), (torn_file, "is torn")):
        with open(journal.journal_path(path), "wb") as fh:
            fh.write(raw)
        with pytest.raises(FileError, match="was written for another file") as info:
            _open_h5(path)
        assert words in str(info.value), info.value
        assert journal.pending(path)               # nothing applied, nothing removed


@pytest.mark.parametrize("cut", [False, True])
def test_a_journal_beside_the_file_as_of_the_checkpoint_before_is_refused(cut, tmp_path):
    """A copy of the file as of the checkpoint before the journal's (a backup), with the journal beside it: each of
    the journal's pages is as the journal found it, but the bytes its checkpoint wrote past the old end (new chunks,
    new HDF5 objects) are not in the copy. It was applied, and the whole, resumable copy became a file whose
    structure points into zeros. Now refused in one line saying the file is whole without it; nothing changed."""
    path = tmp_path / "a.h5.partial"
    backup = tmp_path / "b.h5.partial"
    res = subprocess.run([sys.executable, "-c", WRITER, str(path), "applied", str(backup)], capture_output=True,
                         text=True, timeout=300)
    assert res.returncode == -9 and journal.pending(path), res.stderr
    if not cut:          # the copy as long as the file, the bytes past its old end as the disk had them: zeros
        with open(backup, "r+b") as fh:
            fh.truncate(os.path.getsize(path))
    shutil.copyfile(journal.journal_path(path), journal.journal_path(backup))
    before = backup.read_bytes()
    with pytest.raises(FileError, match="was written for another file") as info:
        _open_h5(backup)
    assert "is whole without it" in str(info.value), info.value
    assert backup.read_bytes() == before and journal.pending(backup)
    os.remove(journal.journal_path(backup))       # as the line says: moved away, the copy reads as it was
    with _open_h5(backup) as f:
        assert f.attrs["version"] == 1 and np.all(f["x"][...] == 1.0) and "g" not in f
    with _open_h5(path) as f:                     # its own file it finishes
        assert f.attrs["version"] == 2 and np.all(f["x"][...] == 2.0)


@pytest.mark.parametrize("stage, words", [("applied", "is whole without it"), ("half-applied", "is torn")])
def test_a_damaged_journal_says_what_the_file_is_without_it(stage, words, tmp_path):
    path = tmp_path / "a.h5.partial"
    _killed_writer(path, stage)
    with open(journal.journal_path(path), "r+b") as fh:
        fh.seek(100)
        fh.write(b"\xff" * 8)
    with pytest.raises(FileError, match="is damaged") as info:
        _open_h5(path)
    assert words in str(info.value), info.value
    if stage == "applied":                         # as the line says: moved away, the file reads whole
        os.rename(journal.journal_path(path), tmp_path / "moved")
        with _open_h5(path) as f:
            assert f.attrs["version"] == 2


def test_a_torn_file_without_its_journal_is_refused_not_read(tmp_path):
    """The journal of a file killed halfway through copying it in, removed: HDF5 opened the torn file (a mixture of
    two checkpoints) and rbx read it silently. Its signature stays replaced until the copying-in ends: refused in
    one line naming the journal to put back."""
    path = tmp_path / "a.h5.partial"
    _killed_writer(path)
    saved = tmp_path / "saved.journal"
    os.rename(journal.journal_path(path), saved)
    with pytest.raises(FileError, match="is torn: .* the journal that finishes it .a.h5.partial.journal. is gone"):
        _open_h5(path)
    assert not h5py.is_hdf5(path)
    os.rename(saved, journal.journal_path(path))  # put back: the checkpoint finishes
    with _open_h5(path) as f:
        assert f.attrs["version"] == 2


@pytest.mark.long
def test_a_new_run_over_a_journal_left_without_its_file_is_forced_and_never_takes_it(tmp_path):
    """A killed run's journal whose .partial was removed (or moved away) by hand: a new run keeps it and says so
    (it may be the only thing that finishes the file elsewhere); with --force it is removed, and never applied to
    the new file (seen in review: a new file silently became the old one)."""
    src = tmp_path / "run.h5.partial"
    res = subprocess.run([sys.executable, "-c", WRITER, str(src), "half-applied"], capture_output=True, text=True,
                         timeout=300)
    assert res.returncode == -9 and journal.pending(src)
    src.unlink()
    cfg = strip_random(3000, trajectories=2, every=1, record=("time",))
    write_config(tmp_path, cfg)
    args = [sys.executable, "-c", f"import sys; {RBX_MAIN}", "simulate", "exp.yaml", "-o", "run.h5", "--quiet"]
    res = subprocess.run(args, cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert res.returncode == 2 and "run.h5.partial.journal" in res.stderr and "is not here" in res.stderr, res.stderr
    res = subprocess.run(args + ["--force"], cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert res.returncode == 0, res.stderr
    assert sorted(f.name for f in tmp_path.glob("run.h5*")) == ["run.h5"]
    assert rbx.open(tmp_path / "run.h5").complete


def test_a_reader_that_cannot_take_the_run_lock_reads_the_journal_in_memory_and_writes_nothing(tmp_path):
    """A reader applies a pending journal only under the run's lock (so that no resume writes the file meanwhile).
    Where another holds the lock (here another thread of this process, which has not opened the file), the reader
    reads the file with its journal applied in memory: the file and its journal are left as they are. It was
    refused (`another rbx run is writing it`)."""
    from rbx.locks import acquire_lock, release_lock
    path = tmp_path / "o.h5.partial"
    _killed_writer(path)
    before = path.read_bytes()
    holder = threading.Thread(target=acquire_lock, args=(str(tmp_path / "o.h5"),))
    holder.start()
    holder.join()
    try:
        with _open_h5(path) as f:
            assert f.attrs["version"] == 2 and np.all(f["x"][...] == 2.0)
        assert journal.pending(path) and path.read_bytes() == before
    finally:
        release_lock(str(tmp_path / "o.h5"))
    with _open_h5(path) as f:                     # the lock free: finished in the file
        assert f.attrs["version"] == 2
    assert not journal.pending(path) and not os.path.exists(tmp_path / "o.h5.lock")


def test_a_file_being_written_is_locked_against_hdf5_readers(tmp_path):
    """h5py's fileobj driver takes no lock; the journal takes HDF5's (flock), so a reader opening a .partial that a
    run writes is refused, naming the run, as before the journal (it could otherwise read a commit half copied)."""
    path = tmp_path / "run.h5.partial"
    writer = textwrap.dedent(f"""
        import sys, time
        from rbx.locks import acquire_lock
        from rbx.runfile import commit, open_journaled
        acquire_lock({str(tmp_path / "run.h5")!r})
        h5 = open_journaled({str(path)!r}, create=True)
        h5.flush()
        commit(h5)
        print("ready", flush=True)
        time.sleep(300)
    """)
    proc = subprocess.Popen([sys.executable, "-c", writer], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "ready"
        with pytest.raises(FileError, match="another rbx run is writing it"):
            _open_h5(str(path))
        (tmp_path / "run.h5.lock").unlink()      # a lock by another program than rbx
        with pytest.raises(FileError, match="open in another program"):
            _open_h5(str(path))
    finally:
        proc.kill()
        proc.wait()
    with _open_h5(str(path)) as f:                # the writer gone, its lock with it
        assert isinstance(f, h5py.File)


def test_room_reserved_by_a_killed_run_is_not_taken_for_the_committed_file(tmp_path):
    """After a kill the file can be longer than HDF5's end (rbx.runfile.H5Sink._reserve's room). Reopened, the
    committed length is HDF5's end of file from its superblock, so new writes there need no journal."""
    from rbx.runfile import close_journal, open_journaled
    path = str(tmp_path / "f.h5")
    h5 = open_journaled(path, create=True)
    h5.create_dataset("x", data=np.arange(1000.0))
    h5.close()
    close_journal(h5)
    end = os.path.getsize(path)
    fd = os.open(path, os.O_RDWR)
    os.posix_fallocate(fd, 0, end + (4 << 20))
    os.close(fd)
    jf = JournaledFile(path)
    assert jf.committed == end and os.path.getsize(path) == end + (4 << 20)
    jf.close(commit=False)


# ---- a real run killed inside a commit ----------------------------------------------------------------------------

@pytest.mark.long
def test_a_run_killed_inside_a_commit_is_read_and_resumed_exactly(tmp_path):
    """`rbx simulate` killed halfway through copying its third checkpoint's journal into the file: the .partial
    reads (the API applies the journal), and `rbx simulate --resume` ends with the uninterrupted run's records."""
    cfg = strip_random(60_000, trajectories=3, every=7, record=("time", "position", "wall", "rank"))
    write_config(tmp_path, cfg)
    ref = subprocess.run([sys.executable, "-c", f"import sys; {RBX_MAIN}", "simulate", "exp.yaml", "-o", "ref.h5",
                          "--quiet"], cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert ref.returncode == 0, ref.stderr
    killer = ("import os, signal, sys, rbx.simulation as s, rbx.journal as j; s.BLOCK_WORK = 3000; s.CHECKPOINT_SECONDS = 0\n"
              "n = [0]; apply = j._apply\n"
              "def half(fd, pages, overlay):\n"
              "    n[0] += 1\n"
              "    if n[0] == 4:\n"          # the skeleton's commit, then two checkpoints, then the third
              "        apply(fd, pages[:len(pages) // 2], overlay); os.kill(os.getpid(), signal.SIGKILL)\n"
              "    apply(fd, pages, overlay)\n"
              "j._apply = half\n" + RBX_MAIN)
    res = subprocess.run([sys.executable, "-c", killer, "simulate", "exp.yaml", "-o", "run.h5", "--quiet"],
                         cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert res.returncode == -9, res.stderr
    partial = tmp_path / "run.h5.partial"
    assert journal.pending(partial)
    run = rbx.open(partial)                        # a reader finishes the commit
    assert not run.complete and not journal.pending(partial)
    saved = run.final["collisions"]                # the third checkpoint's state: the commit was past its point
    res = subprocess.run([sys.executable, "-c", f"import sys; {RBX_MAIN}", "simulate", "--resume",
                          "run.h5.partial", "--quiet"], cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert res.returncode == 0, res.stderr
    # the reader finished the commit under the run's lock, taking the killed run's stale lock over (silently: a
    # reader names no run); nothing had to be read raw or cut back
    assert res.stderr.strip() == "", res.stderr
    assert not (tmp_path / "run.h5.lock").exists()
    assert_same_records(read_run(tmp_path / "run.h5"), read_run(tmp_path / "ref.h5"))
    assert 0 < saved.min() and saved.max() < 60_000


# ---- an I/O error at any write ------------------------------------------------------------------------------------

EIO_WRITER = textwrap.dedent("""
    import atexit, errno, os, sys
    import rbx.simulation as s; s.BLOCK_WORK = 3000; s.CHECKPOINT_SECONDS = 0
    calls = [0]
    at, times = int(sys.argv[1]), int(sys.argv[2])
    pwrite, pwritev = os.pwrite, os.pwritev
    def fail():
        calls[0] += 1
        if at <= calls[0] < at + times:
            raise OSError(errno.EIO, "Input/output error")
    def failing_pwrite(*a):
        fail()
        return pwrite(*a)
    def failing_pwritev(*a):
        fail()
        return pwritev(*a)
    os.pwrite, os.pwritev = failing_pwrite, failing_pwritev
    atexit.register(lambda: print("writes", calls[0], file=sys.stderr))
    from rbx.cli.main import main
    sys.argv[0:3] = ["rbx"]
    main()
""")


@pytest.mark.long
@pytest.mark.parametrize("instants", [pytest.param("all", marks=pytest.mark.heavy), "quick"])
def test_an_io_error_at_any_write_is_one_line_and_the_file_resumes_exactly(tmp_path, instants):
    """Every write of the run file goes through os.pwrite or os.pwritev (the journal's); each is made to fail
    with EIO, at instants spread over the run (the file's creation, blocks, the journal, its copy into the file,
    the last commit), once or from then on. Each time: exit 1 and one line; no journal left beside a renamed
    file; resumed, the records are the uninterrupted run's, bit for bit. (h5py's file-object callbacks cannot
    raise: the journal's first version let the error through them, and the run printed ~100 lines of
    tracebacks, or crashed with exit −11 after its line.)"""
    cfg = strip_random(60_000, trajectories=3, every=7, record=("time", "position", "wall", "rank"))
    write_config(tmp_path, cfg)

    def run(*args):
        return subprocess.run([sys.executable, "-c", EIO_WRITER, *map(str, args)], cwd=tmp_path,
                              capture_output=True, text=True, timeout=900)

    res = run(10 ** 9, 0, "simulate", "exp.yaml", "-o", "ref.h5", "--quiet")
    assert res.returncode == 0, res.stderr
    total = int(res.stderr.split()[-1])
    assert total > 100                      # the blocks are small: many commits
    reference = read_run(tmp_path / "ref.h5")
    every = (3, total // 3, total // 2, total - 6, total - 3, total - 2, total - 1, total)
    # make test: the file's creation, a block's write, the last commit's copy (make stress: all eight, each once
    # and from then on)
    cases = [(a, t) for a in every for t in (1, 10 ** 9)] if instants == "all" else \
        [(3, 1), (total // 2, 10 ** 9), (total - 1, 1)]
    for at, times in cases:
        for f in tmp_path.glob("run.h5*"):
            f.unlink()
        res = run(at, times, "simulate", "exp.yaml", "-o", "run.h5", "--quiet")
        lines = [x for x in res.stderr.splitlines() if not x.startswith("writes ")]
        assert res.returncode == 1 and len(lines) == 1, (at, times, res.stderr)
        assert lines[0].startswith("rbx: ") and "Input/output error" in lines[0], lines
        left = sorted(f.name for f in tmp_path.glob("run.h5*"))
        assert left in ([], ["run.h5"], ["run.h5.partial"], ["run.h5.partial", "run.h5.partial.journal"]), left
        if not left:
            assert "nothing was saved" in lines[0]
            continue
        assert f"--resume {left[0]}" in lines[0]
        res = subprocess.run([sys.executable, "-c", f"import sys; {RBX_MAIN}", "simulate", "--resume", left[0],
                              "--quiet"], cwd=tmp_path, capture_output=True, text=True, timeout=900)
        assert res.returncode == 0, (at, times, res.stderr)
        assert sorted(f.name for f in tmp_path.glob("run.h5*")) == ["run.h5"]
        assert_same_records(read_run(tmp_path / "run.h5"), reference)


def test_a_journal_an_older_rbx_left_is_applied_to_its_own_file_only(tmp_path):
    """Journals written before they named their file by content named it by inode: one left by a kill of an older
    rbx still finishes its file, and is refused beside a copy, saying what the file is without it."""
    path = tmp_path / "a.h5.partial"
    _killed_writer(path)
    jpath = journal.journal_path(path)
    with open(jpath, "rb") as fh:
        raw = fh.read()
    size, count = journal.HEADER.unpack_from(raw, len(journal.MAGIC))[:2]
    at = len(journal.MAGIC) + journal.HEADER.size
    numbers = raw[at:at + 8 * count]
    pages = raw[at + 12 * count:-journal.CRC.size]

    def first_journal(st):
        body = journal.MAGIC_1 + journal.HEADER_1.pack(st.st_ino, st.st_dev, size, count) + numbers + pages
        return body + journal.CRC.pack(journal.zlib.crc32(body))
    copy = tmp_path / "b.h5.partial"
    shutil.copyfile(path, copy)
    for p in (path, copy):
        with open(journal.journal_path(p), "wb") as fh:
            fh.write(first_journal(os.stat(path)))
    with pytest.raises(FileError, match="was written for another file .* by an older rbx") as info:
        _open_h5(copy)
    assert "is torn" in str(info.value)
    with _open_h5(path) as f:
        assert f.attrs["version"] == 2 and np.all(f["x"][...] == 2.0)


def test_a_view_refused_by_a_live_writers_lock_closes_its_file_once(tmp_path):
    """Reading a file a live run holds (its lock taken): the view closed its file descriptor when the shared lock
    was refused and kept the number, so its __del__ closed it again later, by then a file the caller had opened
    meanwhile: a script polling a run with rbx.open wrote its own log line into another file."""
    import fcntl
    import gc
    path = tmp_path / "run.h5"
    path.write_bytes(bytes(2 * PAGE))
    writer = os.open(path, os.O_RDWR)
    fcntl.flock(writer, fcntl.LOCK_EX)                  # what a live run holds while it writes
    try:
        for _ in range(3):
            mine = None
            try:
                journal.JournalView(str(path), shared=True)
            except OSError as exc:
                assert "open in another program" in str(exc)
                mine = open(tmp_path / "mylog.txt", "w")     # takes the number the view gave back
            gc.collect()                # the error and its view are gone: the view's __del__ must not close it
            mine.write("my line\n")
            mine.close()                # a descriptor closed under it: OSError (EBADF) here
            assert (tmp_path / "mylog.txt").read_text() == "my line\n"
    finally:
        os.close(writer)


def test_a_link_found_at_the_journals_scratch_name_is_left_alone(tmp_path):
    """A link put at ``FILE.journal.tmp`` while a run writes: the commit fails, as an I/O error does (the run stops
    at its last commit, resumable), and the error's line says to remove it. The failed commit removed the link
    itself, while its line asked the user to. (A regular file there is a killed writer's scratch file, replaced as
    every scratch name of rbx's is: ``paths.create_own``.)"""
    path = str(tmp_path / "f.bin")
    jf = JournaledFile(path, create=True)
    jf.write(b"first")
    jf.commit()
    scratch = tmp_path / "f.bin.journal.tmp"
    victim = tmp_path / "notes.txt"
    victim.write_text("mine\n")
    scratch.symlink_to(victim)
    jf.seek(0)
    jf.write(b"second")
    with pytest.raises(OSError, match="remove it"):
        jf.commit()
    jf.close(commit=False)
    assert scratch.is_symlink() and victim.read_text() == "mine\n"
    with open(path, "rb") as f:
        assert f.read() == b"first"                  # the last commit
