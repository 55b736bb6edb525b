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

import h5py
import numpy as np
import pytest

import rbx
from rbx import journal
from rbx.journal import PAGE, JournaledFile
from rbx.runfile import FileError, _open_h5
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
    assert os.path.exists(journal.journal_path(path)) == (stage in ("half-applied", "applied"))
    assert journal.pending(path) == (stage != "before-commit")
    with _open_h5(path) as f:                      # what every reader calls: applies a pending journal first
        assert f.attrs["version"] == version
        x = f["x"][...]
        assert x.shape == ((4, 100) if version == 1 else (4, 300))
        assert np.all(x == float(version))         # read through the chunks' checksums
        assert ("g" in f) == (version == 2)
    assert not journal.pending(path) and not os.path.exists(f"{journal.journal_path(path)}.tmp")


def test_a_journal_copied_with_its_file_is_refused_in_one_line(tmp_path):
    """A journal names the file (inode) it was made for: applied to a copy it could write pages of one file into
    another, so it is refused, and says why."""
    src = tmp_path / "a.h5.partial"
    res = subprocess.run([sys.executable, "-c", WRITER, str(src), "half-applied"], capture_output=True, text=True,
                         timeout=300)
    assert res.returncode == -9 and journal.pending(src)
    copy = tmp_path / "b.h5.partial"
    shutil.copyfile(src, copy)
    shutil.copyfile(journal.journal_path(src), journal.journal_path(copy))
    with pytest.raises(FileError, match="was written for another file"):
        _open_h5(copy)
    with _open_h5(src) as f:                       # the original is recovered as usual
        assert f.attrs["version"] == 2


# ---- a real run killed inside a commit ----------------------------------------------------------------------------

def test_a_run_killed_inside_a_commit_is_read_and_resumed_exactly(tmp_path):
    """`rbx simulate` killed halfway through copying its third checkpoint's journal into the file: the .partial
    reads (the API applies the journal), and `rbx simulate --resume` ends with the uninterrupted run's records."""
    cfg = strip_random(60_000, trajectories=3, every=7, record=("time", "position", "wall", "rank"))
    write_config(tmp_path, cfg)
    ref = subprocess.run([sys.executable, "-c", f"import sys; {RBX_MAIN}", "simulate", "exp.yaml", "-o", "ref.h5",
                          "--quiet"], cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert ref.returncode == 0, ref.stderr
    killer = ("import os, signal, sys, rbx.simulation as s, rbx.journal as j; s.BLOCK_WORK = 3000\n"
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
    # the killed run's lock is taken over (one warning line); nothing had to be read raw or cut back
    line, = res.stderr.strip().splitlines()
    assert "stale lock" in line, res.stderr
    assert_same_records(read_run(tmp_path / "run.h5"), read_run(tmp_path / "ref.h5"))
    assert 0 < saved.min() and saved.max() < 60_000
