"""Faults of the run file found by a red-team after the third round (docs/reliability.md): a kill during a resume
into the run's own file, the room a block asks for on a small disk, run files holding values no run writes, and
the API's arguments. Real ``rbx`` processes on real files (a tmpfs where the test may mount one, skipped with the
reason otherwise)."""
import os
import signal
import subprocess
import sys

import h5py
import numpy as np
import pytest

import rbx
from tests.test_interrupt import assert_same_records, read_run, strip_random, write_config
from tests.test_reliability import small_blocks
from tests.test_reliability3 import one_line, rbx_cli, tmpfs

ALL = ("time", "position", "velocity", "angular_velocity", "orientation", "wall", "rank")


# ---- the room a block asks for -------------------------------------------------------------------------------------

def test_runs_that_fit_a_small_disk_finish_and_resume_there(tmp_path):
    """On a 3 MB disk, runs of 6000–10 000 collisions passed the up-front size check, then every block asked
    3.3–4.3 MB (two chunks per dataset, doubled for the journal: the whole file's chunks, twice) and the run never
    finished, nor did its resume. A block now asks for the chunks it makes, the pages of committed chunks it
    changes (the journal keeps those alone) and the checkpoint's state: each run finishes, with the records of
    the same run written elsewhere; so does a run checkpointed after every block, killed, and resumed in place on
    that disk."""
    with tmpfs(tmp_path / "disk", "3m") as disk:
        for M, collisions, record in ((3, 10_000, ALL), (2, 10_000, ALL), (3, 6000, ("time", "position", "velocity"))):
            write_config(tmp_path, strip_random(collisions, trajectories=M, every=1, record=record))
            res = rbx_cli("simulate", "exp.yaml", "-o", "ref.h5", "--force", "--quiet", cwd=tmp_path)
            assert res.returncode == 0, res.stderr
            res = rbx_cli("simulate", "exp.yaml", "-o", disk / "run.h5", "--quiet", cwd=tmp_path)
            assert res.returncode == 0, (M, collisions, res.stderr)
            assert_same_records(read_run(disk / "run.h5"), read_run(tmp_path / "ref.h5"))
            os.remove(disk / "run.h5")
        # checkpoints after every block of 3000 collisions' work: committed chunks rewritten through the journal
        write_config(tmp_path, strip_random(10_000, trajectories=3, every=1, record=ALL))
        res = rbx_cli("simulate", "exp.yaml", "-o", "ref.h5", "--force", "--quiet", cwd=tmp_path)
        assert res.returncode == 0, res.stderr
        killed = subprocess.run(small_blocks(kill_at=4) + ["simulate", "exp.yaml", "-o", disk / "run.h5", "--quiet"],
                                cwd=tmp_path, capture_output=True, text=True, timeout=900)
        assert killed.returncode == -signal.SIGKILL, killed.stderr
        resumed = subprocess.run(small_blocks() + ["simulate", "--resume", disk / "run.h5", "--quiet"],
                                 cwd=tmp_path, capture_output=True, text=True, timeout=900)
        assert resumed.returncode == 0, resumed.stderr
        assert sorted(p.name for p in disk.iterdir()) == ["run.h5"]
        assert_same_records(read_run(disk / "run.h5"), read_run(tmp_path / "ref.h5"))
