"""Sixth round: a killed run's journal travels with its file (another disk, a read-only one), a small disk finishes
a run that fits it, a resume is checked against every key that makes its orbit, and a large study starts at once.
Each test was seen to fail on the code before its change."""
import os
import subprocess
import sys

import pytest

import rbx
from tests.test_interrupt import assert_same_records, read_run, strip_random, write_config
from tests.test_reliability3 import one_line, rbx_cli, tmpfs
from tests.test_reliability5 import KILL_MID_APPLY

#: a guard against a hang, not a bound
HANG = 600


def _refused(res, name, *words):
    assert res.returncode == 2, (res.returncode, res.stderr)
    line = one_line(res)
    assert line.startswith(f"rbx: {name}: "), line
    for w in words:
        assert w in line, line
    return line


def test_a_pending_journal_on_a_read_only_disk_is_read_and_resumed_into_a_writable_folder(tmp_path):
    """A run killed while copying its checkpoint's journal in, on a file system then made read-only: ``rbx.open``,
    ``rbx plot`` and ``--resume … -o`` each said 'finishing that needs to write the file: Read-only file system'.
    The journal is now applied in memory to read the file, and to the copy a resume into -o writes."""
    with tmpfs(tmp_path / "disk", "64m") as disk:
        write_config(disk, strip_random(300_000, trajectories=3, every=3))
        killed = subprocess.run([sys.executable, "-c", KILL_MID_APPLY.replace("{at}", "5"), "simulate", "exp.yaml",
                                 "-o", "o.h5", "--quiet"], cwd=disk, capture_output=True, text=True, timeout=900)
        assert killed.returncode == -9, killed.stderr
        assert (disk / "o.h5.partial.journal").exists()
        res = rbx_cli("simulate", disk / "exp.yaml", "-o", tmp_path / "ref.h5", "--quiet", cwd=tmp_path)
        assert res.returncode == 0, res.stderr
        res = subprocess.run(["mount", "-o", "remount,ro", str(disk)], capture_output=True, text=True)
        if res.returncode != 0:
            pytest.skip(f"cannot make the tmpfs read-only: {res.stderr.strip()}")
        with rbx.open(disk / "o.h5.partial") as run:
            assert not run.complete and run.read("time").shape[0] == 3
        res = rbx_cli("plot", disk / "o.h5.partial", "--kind", "orbit", "-o", tmp_path / "x.png", cwd=tmp_path)
        assert res.returncode == 0 and (tmp_path / "x.png").stat().st_size > 0, res.stderr
        res = rbx_cli("simulate", "--resume", disk / "o.h5.partial", "-o", tmp_path / "out.h5", "--quiet",
                      cwd=tmp_path)
        assert res.returncode == 0, res.stderr
        assert_same_records(read_run(tmp_path / "out.h5"), read_run(tmp_path / "ref.h5"))
        assert (disk / "o.h5.partial.journal").exists()         # the read-only folder as it was


@pytest.mark.parametrize("name", ["o.h5.partial", "o.h5"])
def test_a_killed_run_that_fits_a_small_disk_is_finished_there(name, tmp_path):
    """On a 3 MB disk a run whose file takes 1.8 MB, killed at 1.5 MB: its resume in place stopped at once ('the
    disk is full … the checkpoint's journal 1.4 MB': the first block of a resume adds the rest of the run to
    chunks committed before, all through the journal) and renamed the .partial to o.h5, whose resume then asked
    room for a copy ('would write about 2.28 MB but the disk has 1.63 MB free'), for ever. Now a block whose
    journal does not fit is written in parts, each committed; and o.h5 is continued in place (renamed, not
    copied) where the copy does not fit."""
    from tests.test_reliability import small_blocks
    write_config(tmp_path, strip_random(20_000, trajectories=3, every=3))
    res = rbx_cli("simulate", "exp.yaml", "-o", "ref.h5", "--quiet", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    with tmpfs(tmp_path / "disk", "3m") as disk:
        write_config(disk, strip_random(20_000, trajectories=3, every=3))
        killed = subprocess.run(small_blocks(work=1000, kill_at=12) + ["simulate", "exp.yaml", "-o", "o.h5",
                                                                       "--quiet"],
                                cwd=disk, capture_output=True, text=True, timeout=900)
        assert killed.returncode == -9, killed.stderr
        if name == "o.h5":         # as a run stopped for room leaves it: renamed, complete = false
            os.rename(disk / "o.h5.partial", disk / "o.h5")
            (disk / "filler").write_bytes(bytes(1_200_000))     # no room even in place: what to do, nothing moved
            res = rbx_cli("simulate", "--resume", name, "--quiet", cwd=disk)
            line = _refused(res, "o.h5", "written already, but the disk has",
                            "resume it into a file on another disk with -o")
            assert sorted(p.name for p in disk.iterdir()) == ["exp.yaml", "filler", "o.h5"], line
            os.remove(disk / "filler")
        res = rbx_cli("simulate", "--resume", name, "--quiet", cwd=disk)
        assert res.returncode == 0, res.stderr
        assert_same_records(read_run(disk / "o.h5"), read_run(tmp_path / "ref.h5"))
        assert sorted(p.name for p in disk.iterdir()) == ["exp.yaml", "o.h5"]
