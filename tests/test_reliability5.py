"""Fifth round: what lies under rbx's own names beside a run's output (the ``.partial``, ``.partial.new``, the
journals, the lock) is looked at before it is opened or written: a link is never written through, a FIFO never
opened, a directory or a file of another kind named for what it is, each in one line."""
import os
import subprocess

import pytest

import rbx
from tests.test_interrupt import assert_same_records, read_run, reference_run
from tests.test_reliability3 import killed_run, one_line, rbx_cli

#: a guard against a hang, not a bound: each command below is refused before it computes anything
HANG = 300


def _refused(res, name, *words):
    assert res.returncode == 2, (res.returncode, res.stderr)
    line = one_line(res)
    assert line.startswith(f"rbx: {name}: "), line
    for w in words:
        assert w in line, line
    return line


@pytest.mark.long
@pytest.mark.parametrize("how", ["in place", "into -o"])
def test_a_resume_with_force_never_writes_through_a_partial_that_is_a_link(how, tmp_path):
    """``--resume OUT.h5 --force`` (or ``--resume SRC -o OUT.h5 --force``) with ``OUT.h5.partial`` a symbolic
    link wrote the run's HDF5 over the link's target and made OUT.h5 the link."""
    ref = killed_run(tmp_path, out="src.h5")
    victim = tmp_path / "victim.txt"
    victim.write_text("precious data\n")
    if how == "in place":
        # an interrupted OUT.h5 (the killed run's .partial under its own name) beside a .partial that is a link
        os.rename(tmp_path / "src.h5.partial", tmp_path / "out.h5")
        args = ["--resume", "out.h5"]
    else:
        args = ["--resume", "src.h5.partial", "-o", "out.h5"]
    os.symlink("victim.txt", tmp_path / "out.h5.partial")
    res = rbx_cli("simulate", *args, "--force", "--quiet", cwd=tmp_path, timeout=HANG)
    _refused(res, "out.h5.partial", "symbolic link to victim.txt")
    assert victim.read_text() == "precious data\n"
    assert os.readlink(tmp_path / "out.h5.partial") == "victim.txt"
    # with the link gone, the same command finishes the run as an uninterrupted one
    os.remove(tmp_path / "out.h5.partial")
    res = rbx_cli("simulate", *args, "--force", "--quiet", cwd=tmp_path, timeout=HANG)
    assert res.returncode == 0, res.stderr
    assert not (tmp_path / "out.h5").is_symlink()
    assert_same_records(read_run(tmp_path / "out.h5"), ref)


@pytest.mark.long
@pytest.mark.parametrize("name", ["run.h5.partial.new", "run.h5.partial.journal", "run.h5.lock"])
def test_a_resume_refuses_a_link_under_its_own_names(name, tmp_path):
    killed_run(tmp_path)
    victim = tmp_path / "victim.txt"
    victim.write_text("precious data\n")
    if (tmp_path / name).exists():
        os.remove(tmp_path / name)
    os.symlink("victim.txt", tmp_path / name)
    res = rbx_cli("simulate", "--resume", "run.h5", "--force", "--quiet", cwd=tmp_path, timeout=HANG)
    _refused(res, name, "symbolic link to victim.txt")
    assert victim.read_text() == "precious data\n"


@pytest.mark.long
@pytest.mark.parametrize("name", ["run.h5.partial.journal", "run.h5.lock"])
@pytest.mark.parametrize("command", ["resume", "fresh"])
def test_a_fifo_under_a_journal_or_lock_name_is_refused_not_opened(name, command, tmp_path):
    """A FIFO named as the journal or the lock blocked the run until it was killed."""
    killed_run(tmp_path)
    if command == "fresh":
        os.remove(tmp_path / "run.h5.partial")
    if (tmp_path / name).exists():
        os.remove(tmp_path / name)
    os.mkfifo(tmp_path / name)
    args = ["--resume", "run.h5"] if command == "resume" else ["exp.yaml", "-o", "run.h5"]
    res = rbx_cli("simulate", *args, "--quiet", cwd=tmp_path, timeout=HANG)
    _refused(res, name, "a FIFO (named pipe)")
    assert (tmp_path / name).is_fifo()


@pytest.mark.long
def test_a_fifo_or_directory_named_as_a_files_journal_is_named_when_the_file_is_opened(tmp_path):
    """``rbx.open`` reads a file's journal first: a FIFO there blocked, a directory was reported as the file
    needing a write."""
    killed_run(tmp_path)
    journal = tmp_path / "run.h5.partial.journal"
    os.mkfifo(journal)
    with pytest.raises(rbx.FileError, match="a FIFO"):
        rbx.open(str(tmp_path / "run.h5.partial"))
    os.remove(journal)
    journal.mkdir()
    with pytest.raises(rbx.FileError) as err:
        rbx.open(str(tmp_path / "run.h5.partial"))
    assert err.value.file.endswith("run.h5.partial.journal") and "is a directory" in err.value.problem
    res = rbx_cli("simulate", "--resume", "run.h5", "--quiet", cwd=tmp_path, timeout=HANG)
    line = _refused(res, "run.h5.partial.journal", "a directory")
    assert "needs to write" not in line


@pytest.mark.long
def test_a_lock_that_is_not_text_is_taken_over_as_damaged(tmp_path):
    """A lock of bytes that are not UTF-8 was a UnicodeDecodeError traceback on every run of its output."""
    killed_run(tmp_path)
    (tmp_path / "run.h5.lock").write_bytes(b"\xff\xfe garbage\x89")
    res = rbx_cli("simulate", "--resume", "run.h5", "--quiet", cwd=tmp_path, timeout=HANG)
    assert res.returncode == 0, res.stderr
    assert "Traceback" not in res.stderr
    warnings = [x for x in res.stderr.splitlines() if x.startswith("rbx:")]
    assert len(warnings) == 1 and "run.h5.lock: warning: a damaged lock" in warnings[0], res.stderr
    assert not (tmp_path / "run.h5.lock").exists()
    # a fresh run over it, and one with --force over a complete output, the same
    (tmp_path / "run.h5.lock").write_bytes(b"\x89HDF\r\n\x1a\n\xff")
    res = rbx_cli("simulate", "exp.yaml", "-o", "run.h5", "--force", "--quiet", cwd=tmp_path, timeout=HANG)
    assert res.returncode == 0 and "a damaged lock" in res.stderr and "Traceback" not in res.stderr, res.stderr


@pytest.mark.long
def test_a_run_file_under_a_lock_name_is_neither_a_traceback_nor_removed(tmp_path):
    """``rbx simulate c.yaml -o i.h5.lock --force`` wrote a run file under i.h5's lock name: every later run of
    i.h5 was a traceback. The file is not a lock: it is named, and kept."""
    killed_run(tmp_path, out="i.h5")
    for name in ("i.h5.lock", "i.h5.journal", "i.h5.partial.new"):
        was = (tmp_path / name).read_bytes() if (tmp_path / name).exists() else None    # the killed run's lock
        res = rbx_cli("simulate", "exp.yaml", "-o", name, "--force", "--quiet", cwd=tmp_path, timeout=HANG)
        _refused(res, "-o", f"{name} is the name rbx gives i.h5's")
        assert ((tmp_path / name).read_bytes() if (tmp_path / name).exists() else None) == was
    os.remove(tmp_path / "i.h5.lock")
    os.rename(tmp_path / "ref.h5", tmp_path / "i.h5.lock")       # a run file put there by hand
    before = (tmp_path / "i.h5.lock").read_bytes()
    for args in (["--resume", "i.h5"], ["exp.yaml", "-o", "i.h5", "--force"]):
        res = rbx_cli("simulate", *args, "--quiet", cwd=tmp_path, timeout=HANG)
        _refused(res, "i.h5.lock", "not a lock rbx made", "move the file elsewhere")
    assert (tmp_path / "i.h5.lock").read_bytes() == before


@pytest.mark.long
def test_an_unrelated_file_named_as_a_journal_is_named_with_what_to_do(tmp_path):
    """``-o x.h5.journal`` beside a complete x.h5 made ``rbx.open('x.h5')`` refuse it as 'is not an rbx journal
    (or is cut short)'."""
    killed_run(tmp_path)
    (tmp_path / "x.h5.journal").write_text("notes of the day\n")
    os.rename(tmp_path / "ref.h5", tmp_path / "x.h5")
    with pytest.raises(rbx.FileError) as err:
        rbx.open(str(tmp_path / "x.h5"))
    assert err.value.file.endswith("x.h5.journal")
    assert "not a journal rbx wrote" in err.value.problem and "x.h5's journal" in err.value.problem
    assert "move it elsewhere" in err.value.problem
    os.rename(tmp_path / "x.h5.journal", tmp_path / "notes.txt")
    with rbx.open(str(tmp_path / "x.h5")) as run:
        assert run.complete


KILL_MID_APPLY = """
import os, signal, sys
import rbx.simulation as s
s.BLOCK_WORK = 3000
s.CHECKPOINT_SECONDS = 0
import rbx.journal as j
seen = [0]
real = j._apply
def _apply(fd, pages, overlay):
    seen[0] += 1
    if seen[0] == {at}:
        real(fd, pages[:len(pages) // 2], overlay)     # half of the checkpoint's pages copied in, then killed
        os.kill(os.getpid(), signal.SIGKILL)
    return real(fd, pages, overlay)
j._apply = _apply
from rbx.cli.main import main
sys.argv[0] = "rbx"
main()
"""


@pytest.mark.long
def test_a_journal_of_a_copied_folder_finishes_the_copy_and_a_torn_file_is_refused_everywhere(tmp_path):
    """A run killed while its checkpoint's journal was copied in, its folder then copied (new inodes, as a move to
    another disk or a backup restore makes): the journal was refused as written for another file, with the advice
    to remove it 'to read the file as of its previous checkpoint' — false, the file without it is torn — and the
    torn file was read by ``rbx.open`` and ``rbx plot`` without a word, its resume a KeyError traceback. The copy
    now resumes bit for bit; the torn file without its journal is refused in one line by all three."""
    import shutil
    import sys
    from tests.test_interrupt import strip_random, write_config
    first = tmp_path / "first"
    first.mkdir()
    write_config(first, strip_random(300_000, trajectories=3, every=3))
    killed = subprocess.run([sys.executable, "-c", KILL_MID_APPLY.replace("{at}", "5"), "simulate", "exp.yaml",
                             "-o", "o.h5", "--quiet"], cwd=first, capture_output=True, text=True, timeout=900)
    assert killed.returncode == -9, killed.stderr
    assert (first / "o.h5.partial.journal").exists()
    copy, torn = tmp_path / "copy", tmp_path / "torn"
    shutil.copytree(first, copy)
    shutil.copytree(first, torn)
    reference_run(first)
    res = rbx_cli("simulate", "--resume", "o.h5", "--quiet", cwd=copy, timeout=HANG)
    assert res.returncode == 0, res.stderr
    assert_same_records(read_run(copy / "o.h5"), read_run(first / "ref.h5"))
    # the journal removed: the file is half of a checkpoint, and nothing reads it
    os.remove(torn / "o.h5.partial.journal")
    with pytest.raises(rbx.FileError, match="is torn"):
        rbx.open(torn / "o.h5.partial")
    res = rbx_cli("plot", "o.h5.partial", "--kind", "orbit", "-o", "x.png", cwd=torn, timeout=HANG)
    _refused(res, "o.h5.partial", "is torn", "put that journal back")
    assert not (torn / "x.png").exists()
    res = rbx_cli("simulate", "--resume", "o.h5", "-o", "other.h5", "--quiet", cwd=torn, timeout=HANG)
    _refused(res, "o.h5.partial", "is torn", "run the config again")
    assert not (torn / "other.h5.partial").exists() and not (torn / "other.h5").exists()


@pytest.mark.long
def test_the_stale_lock_of_a_killed_run_is_taken_over_with_the_file_it_was_written_in(tmp_path):
    """A run killed right after it linked its lock left ``OUT.h5.lock.new.PID.TID`` for ever: the next runs took
    the stale lock over but never removed it."""
    killed_run(tmp_path)
    fields = dict(line.split(": ", 1) for line in (tmp_path / "run.h5.lock").read_text().splitlines())
    left = tmp_path / f"run.h5.lock.new.{fields['pid']}.139805260827520"
    os.link(tmp_path / "run.h5.lock", left)
    other = tmp_path / "run.h5.lock.new.1.7"        # another process's (pid 1 runs): not touched
    other.write_text("x")
    res = rbx_cli("simulate", "--resume", "run.h5", "--quiet", cwd=tmp_path, timeout=HANG)
    assert res.returncode == 0 and "warning: a stale lock" in res.stderr, res.stderr
    assert not left.exists() and other.exists()


@pytest.mark.long
def test_a_new_run_beside_a_killed_runs_partial_says_it_was_killed(tmp_path):
    """``rbx simulate c.yaml -o o.h5`` beside a killed run's ``o.h5.partial`` (its lock stale) said 'another run
    may be writing it, or an earlier one was killed': the lock tells which."""
    killed_run(tmp_path)
    res = rbx_cli("simulate", "exp.yaml", "-o", "run.h5", "--quiet", cwd=tmp_path, timeout=HANG)
    line = _refused(res, "run.h5.partial", "left by a run that was killed",
                    "continue that run with rbx simulate --resume run.h5.partial")
    assert "may be writing" not in line
    assert (tmp_path / "run.h5.partial").exists()
