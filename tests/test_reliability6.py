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

