"""Faults around the run file (docs/reliability.md): the run lock, a disk that fills up after rbx's room
check, Ctrl-C while Python starts, resuming a compensated run. Real ``rbx`` processes on real files."""
import os
import resource
import signal
import socket
import subprocess
import sys
import time

import h5py
import pytest

import rbx.locks as locks
import rbx.runfile as runfile
from tests.test_interrupt import (RBX, assert_same_records, check_valid_partial, invoke, read_run, reference_run,
                                  scene, strip_random, tiny_blocks, write_config)  # noqa: F401 - tiny_blocks: a fixture

#: ``python -c`` running the CLI with small blocks (BLOCK_WORK), and SIGKILLing itself after checkpoint KILL_AT
SMALL_BLOCKS = ("import os, sys, rbx.simulation as s, rbx.runfile as f; s.BLOCK_WORK = {work}; s.CHECKPOINT_SECONDS = 0; "
                "c = f.H5Sink.checkpoint; n = [0]\n"
                "def cp(self, sim):\n"
                "    c(self, sim); n[0] += 1\n"
                "    if n[0] == {kill_at}: os.kill(os.getpid(), 9)\n"
                "f.H5Sink.checkpoint = cp\n"
                "from rbx.cli.main import main; sys.argv[0] = 'rbx'; main()")


def small_blocks(work=3000, kill_at=0):
    return [sys.executable, "-c", SMALL_BLOCKS.format(work=work, kill_at=kill_at)]


def wait_for(path, proc):
    deadline = time.monotonic() + 900     # a guard against a hang, not a bound: a first compile on a busy machine
    while not os.path.exists(path):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "the run never started writing"
        time.sleep(0.01)


def rbx(*args, cwd, env=None, **kw):
    return subprocess.run([RBX, *map(str, args)], cwd=cwd, capture_output=True, text=True, timeout=900,
                          env=None if env is None else dict(os.environ, **env), **kw)


# ---- the run lock ------------------------------------------------------------------------------------------------

@pytest.mark.long
def test_a_second_run_or_resume_while_a_run_writes_is_refused_naming_it(tmp_path):
    """While a run writes run.h5.partial it holds run.h5.lock (host, pid, start). A second run on the same output
    (with --force too: it used to remove the running run's .partial), a resume of the .partial (with HDF5's own
    file locking off too, as on NFS/Lustre) are one line naming the holder, exit 2, and the first run goes on."""
    write_config(tmp_path, strip_random(10**9, trajectories=2, every=1000, record=("time", "position", "wall")))
    first = subprocess.Popen([RBX, "simulate", "exp.yaml", "-o", "run.h5", "--quiet"], cwd=tmp_path,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        wait_for(tmp_path / "run.h5.partial", first)
        lock = (tmp_path / "run.h5.lock").read_text()
        assert f"pid: {first.pid}\n" in lock and f"host: {socket.gethostname()}\n" in lock and "started: " in lock
        attempts = {"simulate": ("simulate", "exp.yaml", "-o", "run.h5"),
                    "simulate --force": ("simulate", "exp.yaml", "-o", "run.h5", "--force"),
                    "resume": ("simulate", "--resume", "run.h5.partial")}
        for name, args in attempts.items():
            for env in ({}, {"HDF5_USE_FILE_LOCKING": "FALSE"}):
                res = rbx(*args, "--quiet", cwd=tmp_path, env=env)
                assert res.returncode == 2, (name, env, res.stderr)
                line, = res.stderr.strip().splitlines()
                assert line.startswith("rbx: run.h5") and "another rbx run is writing it" in line, (name, line)
                assert f"pid {first.pid} on {socket.gethostname()}" in line, (name, line)
                assert first.poll() is None and (tmp_path / "run.h5.partial").exists(), name
        first.send_signal(signal.SIGTERM)
        _, err = first.communicate(timeout=60)
    finally:
        if first.poll() is None:
            first.kill()
    assert first.returncode == 143, err
    assert not (tmp_path / "run.h5.lock").exists()          # removed on the way out
    check_valid_partial(tmp_path / "run.h5", every=1000)    # the first run's file, untouched by the others


@pytest.mark.long
def test_a_stale_lock_of_a_killed_run_is_taken_over_and_the_resume_is_exact(tmp_path):
    """SIGKILL (here after the 4th checkpoint) leaves run.h5.lock behind. Its pid no longer runs on this host:
    the resume says so in one warning line, takes the lock over and writes the uninterrupted run's records."""
    write_config(tmp_path, strip_random(60_000, trajectories=3, every=7, record=("time", "position", "wall", "rank")))
    reference_run(tmp_path)
    assert not (tmp_path / "ref.h5.lock").exists()          # a normal end removes it
    killed = subprocess.run(small_blocks(kill_at=4) + ["simulate", "exp.yaml", "-o", "run.h5", "--quiet"],
                            cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    lock = (tmp_path / "run.h5.lock").read_text()
    pid = int(lock.split("pid: ")[1].split()[0])
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)                                      # its process is gone
    # a new run on that output still refuses the leftover .partial (it may be resumed), with the hint
    res = rbx("simulate", "exp.yaml", "-o", "run.h5", "--quiet", cwd=tmp_path)
    assert res.returncode == 2 and "--resume run.h5.partial" in res.stderr, res.stderr
    res = rbx("simulate", "--resume", "run.h5.partial", "--quiet", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    line, = res.stderr.strip().splitlines()
    assert line.startswith("rbx: run.h5.lock: warning: a stale lock") and f"pid {pid} " in line, line
    assert not (tmp_path / "run.h5.lock").exists() and not (tmp_path / "run.h5.partial").exists()
    assert_same_records(read_run(tmp_path / "run.h5"), read_run(tmp_path / "ref.h5"))


def test_which_locks_are_stale(tmp_path, monkeypatch):
    """Only a lock whose process is known to be gone is taken over: same host and its pid not running, or running
    a process started at another time (the pid reused). Another host's lock is never judged from here."""
    out = tmp_path / "run.h5"
    lock = tmp_path / "run.h5.lock"
    host = socket.gethostname()
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    me = os.getpid()
    cases = {  # lock text -> stale?
        f"host: {host}\npid: {gone.pid}\nstarted: x\nprocess_start: 1\n": True,
        f"host: {host}\npid: {os.getppid()}\nstarted: x\nprocess_start: 1\n": True,     # pid reused since
        f"host: {host}\npid: {os.getppid()}\nstarted: x\nprocess_start: "
        f"{locks._process_start(os.getppid())}\n": False,                              # that very process
        f"host: {host}-elsewhere\npid: {gone.pid}\nstarted: x\nprocess_start: 1\n": False,
    }
    warned = []
    for text, stale in cases.items():
        lock.write_text(text)
        if stale:
            locks.acquire_lock(out, warn=warned.append)
            assert f"pid: {me}\n" in lock.read_text() and "stale lock" in warned[-1]
            locks.release_lock(out)
            assert not lock.exists()
        else:
            with pytest.raises(runfile.FileError, match="another rbx run is writing it"):
                locks.acquire_lock(out, warn=warned.append)
            assert lock.read_text() == text                  # left alone
    lock.unlink()
    # this process may take its own lock twice (a resume holds it from reading the file to renaming it)
    locks.acquire_lock(out)
    locks.acquire_lock(out)
    locks.release_lock(out)
    assert lock.exists()
    locks.release_lock(out)
    assert not lock.exists()


# ---- a disk that fills up after the room check ----------------------------------------------------------------------

@pytest.mark.long
def test_a_write_that_meets_a_full_file_system_stops_cleanly_and_resumes_exactly(tmp_path):
    """Another program fills the disk between rbx's check of the room for a block and its write: simulated by a
    file size limit (RLIMIT_FSIZE, SIGXFSZ ignored, so a write fails with EFBIG as with ENOSPC) that the free-space
    check does not see. HDF5 meeting the failed write crashed (exit -11, dozens of tracebacks); rbx reserves the
    block's room in the file first (posix_fallocate), so the run stops between blocks: one line, exit 1, the file
    readable with its last checkpoint, the lock removed; resumed without the limit, the records are exact."""
    write_config(tmp_path, strip_random(30_000, trajectories=3, every=1, record=("time", "position", "wall")))
    reference_run(tmp_path)
    limit = 2 << 20      # the blocks' records come to ~2.5 MB: a block meets the limit

    def limited():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    res = subprocess.run(small_blocks() + ["simulate", "exp.yaml", "-o", "run.h5", "--quiet"], cwd=tmp_path,
                         capture_output=True, text=True, timeout=900, preexec_fn=limited)
    assert res.returncode == 1, res.stderr
    line, = res.stderr.strip().splitlines()
    assert line.startswith("rbx: run.h5: the file is not allowed to grow") and "--resume run.h5" in line, line
    assert not (tmp_path / "run.h5.lock").exists() and not (tmp_path / "run.h5.partial").exists()
    assert os.path.getsize(tmp_path / "run.h5") <= limit
    part = read_run(tmp_path / "run.h5")      # the last checkpoint, and maybe a block's records past it
    assert not part["attrs"]["complete"] and 0 < part["final/collisions"].max() < 30_000
    assert (part["collisions/count"] >= 1 + part["final/collisions"]).all()
    res = rbx("simulate", "--resume", "run.h5", "--quiet", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert_same_records(read_run(tmp_path / "run.h5"), read_run(tmp_path / "ref.h5"))
    # the room reserved for the last block is given back: the file is no larger than the uninterrupted one
    assert os.path.getsize(tmp_path / "run.h5") <= os.path.getsize(tmp_path / "ref.h5") + (256 << 10)



@pytest.mark.long
def test_a_killed_run_resumed_in_place_on_a_disk_still_full_stops_cleanly_and_resumes_later(tmp_path):
    """A SIGKILLed run leaves OUT.h5.partial; --resume continues it in place. On a disk still full (a file size
    limit a little above the file's size) the resume cuts the records back to the saved state and stops before
    its first block: one line saying the file cannot grow (after the stale lock's warning), exit 1, the file
    renamed to OUT.h5 with its checkpoint; resumed with room, the records are the uninterrupted run's."""
    write_config(tmp_path, strip_random(30_000, trajectories=3, every=1, record=("time", "position", "wall")))
    reference_run(tmp_path)
    res = subprocess.run(small_blocks(kill_at=3) + ["simulate", "exp.yaml", "-o", "run.h5", "--quiet"],
                         cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert res.returncode == -9 and (tmp_path / "run.h5.partial").exists()
    limit = os.path.getsize(tmp_path / "run.h5.partial") + 1000

    def limited():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    res = subprocess.run([RBX, "simulate", "--resume", "run.h5.partial", "--quiet"], cwd=tmp_path,
                         capture_output=True, text=True, timeout=900, preexec_fn=limited)
    assert res.returncode == 1, res.stderr
    stale, line = res.stderr.strip().splitlines()
    assert stale.startswith("rbx: run.h5.lock: warning: a stale lock")
    assert line.startswith("rbx: run.h5: the file is not allowed to grow") and "--resume run.h5" in line, line
    assert not (tmp_path / "run.h5.partial").exists() and not (tmp_path / "run.h5.lock").exists()
    part = read_run(tmp_path / "run.h5")
    assert not part["attrs"]["complete"] and 0 < part["final/collisions"].max() < 30_000
    res = rbx("simulate", "--resume", "run.h5", "--quiet", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert_same_records(read_run(tmp_path / "run.h5"), read_run(tmp_path / "ref.h5"))

# ---- compensated summation --------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["strip-random", "circle-rough"])
def test_an_interrupted_compensated_run_resumes_bit_for_bit(name, tmp_path, tiny_blocks):
    """numerics.compensated carries error terms of the sums of time and position from block to block; they are
    saved with the state (final/compensation), so a resumed run continues them exactly."""
    cfg = scene(name, 3000, 2, 3)
    cfg["numerics"] = {"compensated": True}
    exp = write_config(tmp_path, cfg)
    tiny_blocks(None)
    assert invoke(exp, "-o", tmp_path / "ref.h5").exit_code == 0
    tiny_blocks(3)
    assert invoke(exp, "-o", tmp_path / "run.h5").exit_code == 130
    with h5py.File(tmp_path / "run.h5", "r") as f:
        assert f["final/compensation"].shape == (2, 3)
    tiny_blocks(None)
    res = invoke("--resume", tmp_path / "run.h5")
    assert res.exit_code == 0, res.stderr
    assert_same_records(read_run(tmp_path / "run.h5"), read_run(tmp_path / "ref.h5"))


def test_a_compensated_run_saved_without_its_error_terms_is_refused(tmp_path, tiny_blocks):
    """A file from an rbx that did not save them cannot be continued exactly: one line, exit 2."""
    cfg = scene("strip-random", 3000, 2, 3)
    cfg["numerics"] = {"compensated": True}
    exp = write_config(tmp_path, cfg)
    tiny_blocks(3)
    assert invoke(exp, "-o", tmp_path / "run.h5").exit_code == 130
    with h5py.File(tmp_path / "run.h5", "r+") as f:
        for group in ("final", "final_previous"):
            state = {k: f[group][k][...] for k in f[group] if k != "compensation"}
            del f[group]["compensation"]
            f[group].attrs["digest"] = runfile.state_digest(state)
    tiny_blocks(None)
    res = invoke("--resume", tmp_path / "run.h5")
    assert res.exit_code == 2
    line, = res.stderr.strip().splitlines()
    assert "final/compensation: missing" in line and "numerics.compensated" in line
    assert not (tmp_path / "run.h5.lock").exists()


# ---- resuming into another file; a run killed just before its rename ----------------------------------------------

@pytest.mark.long
def test_two_resumes_into_one_other_file_the_second_is_refused_naming_the_first(tmp_path):
    """--resume RUN.h5 -o OTHER.h5 takes OTHER's lock (as a new run takes its output's) before writing: a second
    resume (of another file) into the same OTHER, with --force too, is one line naming the first, exit 2, and the
    first goes on (without the lock the second was refused only by the leftover-.partial check, in other words,
    and with --force it truncated the first's OTHER.h5.partial)."""
    write_config(tmp_path, strip_random(10**9, trajectories=2, every=1000, record=("time", "position", "wall")))
    run = subprocess.Popen([RBX, "simulate", "exp.yaml", "-o", "a.h5", "--quiet"], cwd=tmp_path,
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    wait_for(tmp_path / "a.h5.partial", run)
    time.sleep(1)
    run.send_signal(signal.SIGTERM)
    assert run.communicate(timeout=120) and run.returncode == 143
    (tmp_path / "b.h5").write_bytes((tmp_path / "a.h5").read_bytes())
    first = subprocess.Popen([RBX, "simulate", "--resume", "a.h5", "-o", "other.h5", "--quiet"], cwd=tmp_path,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        wait_for(tmp_path / "other.h5.partial", first)
        for extra in ((), ("--force",)):
            res = subprocess.run([RBX, "simulate", "--resume", "b.h5", "-o", "other.h5", "--quiet", *extra],
                                 cwd=tmp_path, capture_output=True, text=True, timeout=300)
            assert res.returncode == 2, (extra, res.stderr)
            line, = res.stderr.strip().splitlines()
            assert line.startswith("rbx: other.h5: another rbx run is writing it"), (extra, line)
            assert f"pid {first.pid} on {socket.gethostname()}" in line, (extra, line)
            assert first.poll() is None and (tmp_path / "other.h5.partial").exists(), extra
            assert not (tmp_path / "b.h5.lock").exists(), extra       # the refused one let go of its own lock
        first.send_signal(signal.SIGTERM)
        _, err = first.communicate(timeout=120)
    finally:
        if first.poll() is None:
            first.kill()
    assert first.returncode == 143, err
    assert not (tmp_path / "other.h5.lock").exists() and not (tmp_path / "a.h5.lock").exists()
    check_valid_partial(tmp_path / "other.h5", every=1000)


#: ``python -c`` running the CLI, SIGKILLing itself when the run, marked complete, is about to be renamed
KILL_BEFORE_RENAME = ("import os, sys, rbx.driver as f; p = f.publish\n"
                      "def publish(tmp, path, complete, *a):\n"
                      "    if complete: os.kill(os.getpid(), 9)\n"
                      "    p(tmp, path, complete, *a)\n"
                      "f.publish = publish\n"
                      "from rbx.cli.main import main; sys.argv[0] = 'rbx'; main()")


@pytest.mark.long
def test_a_run_killed_between_marking_it_complete_and_its_rename_is_finished_by_resume(tmp_path):
    """SIGKILL after the .partial was marked complete and closed, before its rename (1 of 100 random kills in
    scripts/stress.py): a new run on that output says to resume the .partial; resuming it renames it (the same
    file: no simulation), exit 0, the lock taken over and removed; the records are the uninterrupted run's.
    (It used to say "nothing to resume" and leave the .partial.)"""
    write_config(tmp_path, strip_random(3000, trajectories=2, every=7, record=("time", "position", "wall")))
    reference_run(tmp_path)
    killed = subprocess.run([sys.executable, "-c", KILL_BEFORE_RENAME, "simulate", "exp.yaml", "-o", "run.h5",
                             "--quiet"], cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    partial = tmp_path / "run.h5.partial"
    with h5py.File(partial, "r") as f:
        assert bool(f.attrs["complete"])
    assert not (tmp_path / "run.h5").exists() and (tmp_path / "run.h5.lock").exists()
    res = rbx("simulate", "exp.yaml", "-o", "run.h5", "--quiet", cwd=tmp_path)
    assert res.returncode == 2 and "--resume run.h5.partial" in res.stderr, res.stderr
    inode = os.stat(partial).st_ino
    res = rbx("simulate", "--resume", "run.h5.partial", "--quiet", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    stale, line = res.stderr.strip().splitlines()
    assert stale.startswith("rbx: run.h5.lock: warning: a stale lock"), stale
    assert line == "rbx: run.h5.partial: the run was complete (stopped before its rename): renamed to run.h5", line
    assert not partial.exists() and not (tmp_path / "run.h5.lock").exists()
    assert os.stat(tmp_path / "run.h5").st_ino == inode       # renamed, not written again
    ref = read_run(tmp_path / "ref.h5")
    ref["attrs"]["config"] = ref["attrs"]["config"].replace("/ref.h5", "/run.h5")   # the config names its file
    assert_same_records(read_run(tmp_path / "run.h5"), ref)
    # done: resuming the result again has nothing to do
    res = rbx("simulate", "--resume", "run.h5", "--quiet", cwd=tmp_path)
    assert res.returncode == 0 and "nothing to resume" in res.stderr, res.stderr
