"""Faults of the run file found by a red-team (docs/reliability.md, third round): two runs of one process on one
file, limits on every path into a run, locks nothing clears, files that are not what they seem (devices, FIFOs,
links, huge or crafted files), a resumed state checked against its own config, kills between a link and a
remove. Real ``rbx`` processes (or the API in threads) on real files; a tmpfs or mknod only where the test may
(root), skipped with the reason otherwise."""
import contextlib
import os
import re
import shutil
import signal
import stat
import subprocess
import sys
import threading
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml

import rbx
import rbx.simulation as simulation
from tests.test_interrupt import RBX, assert_same_records, read_run, reference_run, scene, strip_random, write_config
from tests.test_reliability import small_blocks


def rbx_cli(*args, cwd, timeout=900, **kw):
    return subprocess.run([RBX, *map(str, args)], cwd=cwd, capture_output=True, text=True, timeout=timeout, **kw)


def one_line(res):
    """The one line rbx printed, besides the warning that the stale lock of a killed run was taken over (lines
    not starting with ``rbx:`` — a library's warnings — are not rbx's)."""
    assert "Traceback" not in res.stderr, res.stderr
    lines = [x for x in res.stderr.strip().splitlines() if x.startswith("rbx:") and "warning: a stale lock" not in x]
    assert len(lines) == 1, res.stderr
    return lines[0]


def killed_run(folder, out="run.h5", kill_at=3, cfg=None):
    """A run of ``exp.yaml`` SIGKILLed after its ``kill_at``-th checkpoint (tiny blocks): ``out.partial`` left,
    with its stale lock; and the uninterrupted run's file ``ref.h5`` -> its records."""
    write_config(folder, cfg or strip_random(30_000, trajectories=3, every=7, record=("time", "position", "wall")))
    reference_run(folder)
    killed = subprocess.run(small_blocks(kill_at=kill_at) + ["simulate", "exp.yaml", "-o", out, "--quiet"],
                            cwd=folder, capture_output=True, text=True, timeout=900)
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    assert (Path(folder) / f"{out}.partial").exists() and not (Path(folder) / out).exists()
    return read_run(Path(folder) / "ref.h5")


@contextlib.contextmanager
def tmpfs(folder, size):
    """A tmpfs of ``size`` mounted at ``folder`` (root only: skipped otherwise)."""
    folder.mkdir()
    res = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(folder)], capture_output=True,
                         text=True)
    if res.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({res.stderr.strip() or 'not root'})")
    try:
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], capture_output=True)


# ---- two runs of one process on one file -------------------------------------------------------------------------

def test_two_api_runs_with_force_on_one_file_in_two_threads_the_second_is_refused(tmp_path, monkeypatch):
    """The run lock was re-entrant within a process, so a second ``rbx.simulate(…, force=True)`` on the same file
    from another thread removed the first run's live .partial: one call returned while the file was a fragment
    equal to neither run, the other raised a raw FileNotFoundError. A lock is held by one thread: the second
    call is refused naming the first, which finishes its file. No timing: the first run waits (in its progress
    callback, after its first block) until the second call has returned."""
    monkeypatch.setattr(simulation, "BLOCK_WORK", 300)
    monkeypatch.setattr(simulation, "CHECKPOINT_SECONDS", 0)
    out = tmp_path / "t.h5"
    first = scene("strip-random", 3000, 2, 3, record=["time", "position"])
    second = dict(first, run=dict(first["run"], seed=2))
    started, refused = threading.Event(), threading.Event()
    outcome = {}

    def progress(done, total):
        started.set()
        assert refused.wait(300), "the second call never returned"

    def run_first():
        try:
            outcome["first"] = rbx.simulate(first, output=out, force=True, progress=progress)
        except BaseException as exc:     # noqa: BLE001 - reported by the main thread
            outcome["first"] = exc

    thread = threading.Thread(target=run_first)
    thread.start()
    try:
        assert started.wait(600), "the first run never started"
        with pytest.raises(rbx.FileError, match="another rbx run is writing it .another run of this process"):
            rbx.simulate(second, output=out, force=True)
        assert (tmp_path / "t.h5.partial").exists()           # the first run's file, still there
    finally:
        refused.set()
        thread.join()
    run = outcome["first"]
    assert isinstance(run, rbx.Run), run
    assert run.complete
    reference = rbx.simulate(first)                          # the same run in memory
    np.testing.assert_array_equal(run.time, reference.time)
    np.testing.assert_array_equal(run.position, reference.position)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.h5"]


# ---- limits on every path into a run -----------------------------------------------------------------------------

@pytest.mark.long
def test_a_resume_keeps_the_size_limit(tmp_path):
    """``--resume X.partial --max-size 1KB`` was accepted and the limit ignored; a .partial whose stored config
    asks more than output.max_size resumed without an estimate (20 GB in 120 s). The resumed run's file is
    checked as a new run's: against --max-size (or max_size=), else the stored output.max_size, before any work."""
    killed_run(tmp_path)
    before = (tmp_path / "run.h5.partial").read_bytes()
    res = rbx_cli("simulate", "--resume", "run.h5.partial", "--max-size", "1KB", cwd=tmp_path)
    assert res.returncode == 2, res.stderr
    line = one_line(res)
    assert line.startswith("rbx: --max-size: the run would write about") and "more than the limit 1" in line, line
    with pytest.raises(rbx.FileError, match="max_size: the run would write about"):
        rbx.resume(tmp_path / "run.h5.partial", max_size="1KB")
    assert (tmp_path / "run.h5.partial").read_bytes() == before and not (tmp_path / "run.h5").exists()
    # the stored config asks 10¹² collisions (hours, 16 TB): refused by the stored limit (10 GiB)
    rbx.open(tmp_path / "run.h5.partial")          # applies a journal a kill may have left, before h5py edits it
    with h5py.File(tmp_path / "run.h5.partial", "r+") as f:
        cfg = yaml.safe_load(f.attrs["config"])
        cfg["run"]["collisions"] = 10**12
        f.attrs["config"] = yaml.safe_dump(cfg, sort_keys=False)
        f.attrs["collisions_requested"] = 10**12        # written with the config: the file stays self-consistent
    res = rbx_cli("simulate", "--resume", "run.h5.partial", cwd=tmp_path, timeout=300)
    assert res.returncode == 2, res.stderr
    line = one_line(res)
    assert "run.h5.partial: config: output.max_size: the run would write about" in line, line


# ---- locks nothing clears -----------------------------------------------------------------------------------------

@pytest.mark.long
def test_a_lock_a_full_disk_left_empty_blocks_nothing(tmp_path):
    """Under ``ulimit -f 0`` the run's lock was created but could not be written: the command said
    ``cannot write: File too large`` with exit 2 and left an empty OUT.h5.lock, which every later run took for
    a live run's ("pid ? on ? since ?"), ``--force`` included; ``: > e.h5.lock`` did the same. A lock is now
    written under another name and linked whole; one that names no process is taken over with a warning; a
    disk without room is exit 1, one line, nothing left."""
    write_config(tmp_path, strip_random(200, trajectories=2, every=1, record=("time", "position")))
    res = rbx_cli("simulate", "exp.yaml", "-o", "warm.h5", "--quiet", cwd=tmp_path)   # the kernel in the cache
    assert res.returncode == 0, res.stderr
    res = subprocess.run(["bash", "-c", f"trap '' XFSZ; ulimit -f 0; exec {RBX} simulate exp.yaml -o z.h5"],
                         cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert res.returncode == 1, res.stderr
    line = one_line(res)
    assert "File too large" in line and "nothing was saved" in line, line
    assert res.stderr == line + "\n"           # Numba's warning that it could make no semaphore is not shown
    # rbx histogram on the same disk: the same one line, which says the reason once
    hist = Path(__file__).resolve().parents[1] / "configs" / "experiments" / "histogram.yaml"
    res = subprocess.run(["bash", "-c", f"trap '' XFSZ; ulimit -f 0; exec {RBX} histogram {hist} --trajectories 20 "
                          "-o h.png --data h.h5 --quiet"], cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert res.returncode == 1 and res.stderr.count("\n") == 1, res.stderr
    assert res.stderr.count("no room on the disk") == 1 and "nothing was saved" in res.stderr, res.stderr
    assert not list(tmp_path.glob("h.*"))
    assert sorted(p.name for p in tmp_path.glob("z.h5*")) == []
    res = rbx_cli("simulate", "exp.yaml", "-o", "z.h5", "--quiet", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    (tmp_path / "e.h5.lock").write_text("")
    res = rbx_cli("simulate", "exp.yaml", "-o", "e.h5", "--quiet", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert one_line(res) == "rbx: e.h5.lock: warning: an empty lock (left by a run that could not write it: a full " \
                            "disk?) was taken over"
    assert sorted(p.name for p in tmp_path.glob("e.h5*")) == ["e.h5"]


def test_a_tiny_run_fits_a_small_disk(tmp_path):
    """On a 3 MB disk a run of 10 collisions recording ``time`` (estimate 1.05 MB) stopped at its first block
    asking 3.41 MB (two chunks of 256 kB per dataset, doubled for the journal), and every resume did the same.
    The room asked for follows the chunks the block really touches."""
    with tmpfs(tmp_path / "disk", "3m") as disk:
        write_config(tmp_path, strip_random(10, trajectories=2, every=1, record=("time",)))
        res = rbx_cli("simulate", "exp.yaml", "-o", disk / "run.h5", cwd=tmp_path)
        assert res.returncode == 0, res.stderr
        assert rbx.open(disk / "run.h5").complete


# ---- what a file is ------------------------------------------------------------------------------------------------

@pytest.mark.long
def test_force_replaces_only_regular_files(tmp_path):
    """``--force`` turned a device node (``mknod mynull c 1 3``) into an HDF5 file (as root, ``-o /dev/null
    --force`` would have replaced the system's). A device, a FIFO or a link is refused in one line before any
    work, with ``--force`` too, and left as it was."""
    write_config(tmp_path, strip_random(100, trajectories=2, every=1, record=("time",)))
    (tmp_path / "real.h5").write_bytes(b"mine")
    os.mkfifo(tmp_path / "fifo")
    os.symlink("real.h5", tmp_path / "link.h5")
    nodes = {"fifo": "a FIFO (named pipe)", "link.h5": "a symbolic link to real.h5"}
    try:
        os.mknod(tmp_path / "mynull", 0o666 | stat.S_IFCHR, os.makedev(1, 3))
        nodes["mynull"] = "a character device"
    except (PermissionError, OSError) as exc:
        print(f"mknod not permitted here ({exc}): the device case is not tried")
    for name, what in nodes.items():
        before = os.lstat(tmp_path / name)
        res = rbx_cli("simulate", "exp.yaml", "-o", name, "--force", cwd=tmp_path)
        assert res.returncode == 2, (name, res.stderr)
        line = one_line(res)
        assert f"-o: {name} is {what}" in line and "regular file" in line, line
        after = os.lstat(tmp_path / name)
        assert (after.st_mode, after.st_ino) == (before.st_mode, before.st_ino), name
        assert not (tmp_path / f"{name}.partial").exists()
    assert (tmp_path / "real.h5").read_bytes() == b"mine"


def test_a_dangling_link_as_output_is_refused_before_the_run(tmp_path):
    """A dangling symlink as ``-o``: the whole run was computed, then refused at the rename ("appeared while
    this run was writing (another run?)"). It is said at the start, for what it is."""
    write_config(tmp_path, strip_random(100, trajectories=2, every=1, record=("time",)))
    os.symlink("nowhere/run.h5", tmp_path / "out.h5")
    res = rbx_cli("simulate", "exp.yaml", "-o", "out.h5", cwd=tmp_path)
    assert res.returncode == 2, res.stderr
    line = one_line(res)
    assert line.startswith("rbx: -o: out.h5 is a symbolic link to nowhere/run.h5, which does not exist"), line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["exp.yaml", "out.h5"]      # nothing was run


@pytest.mark.long
def test_a_config_that_is_a_device_a_fifo_or_huge_is_refused_in_one_line(tmp_path):
    """``rbx simulate /dev/zero`` read without bound (2.7 GB, then a MemoryError traceback); a FIFO as the config
    waited for ever. A config must be a regular file of at most 64 MiB."""
    os.mkfifo(tmp_path / "fifo.yaml")
    with open(tmp_path / "huge.yaml", "wb") as fh:
        fh.truncate(65 << 20)
    cases = {"/dev/zero": "/dev/zero: is a character device, not a regular file",
             "fifo.yaml": "fifo.yaml: is a FIFO (named pipe), not a regular file",
             "huge.yaml": "huge.yaml: is 68.2 MB, larger than a config can be (64 MiB)"}
    for config, said in cases.items():
        res = rbx_cli("simulate", config, cwd=tmp_path, timeout=120)
        assert res.returncode == 2, (config, res.stderr)
        assert one_line(res).startswith(f"rbx: {said}"), res.stderr
    with pytest.raises(rbx.ConfigError, match="is a FIFO"):
        rbx.load(tmp_path / "fifo.yaml")


def crafted(tmp_path, change):
    """A complete 1-trajectory run file with one dataset changed by ``change(collisions_group)``."""
    path = tmp_path / "crafted.h5"
    rbx.simulate(scene("strip-random", 500, 1, 1, record=["time", "position"]), output=path, force=True)
    with h5py.File(path, "r+") as f:
        change(f["collisions"])
    return path


def _replace(g, name, **kw):
    del g[name]
    g.create_dataset(name, **kw)


CRAFTED = {
    "step shorter than the records": (lambda g: g["step"].resize(100, axis=0), "collisions/time: has shape (1, 501)"),
    "time declared (1, 10^12)": (lambda g: _replace(g, "time", shape=(1, 10**12), dtype="f8", chunks=(1, 4096)),
                                 "collisions/time: has shape (1, 1000000000000)"),
    "position of shape (1, 501, 7)": (lambda g: _replace(g, "position", data=np.zeros((1, 501, 7))),
                                      "collisions/position: has shape (1, 501, 7)"),
    "time of integers": (lambda g: _replace(g, "time", data=np.zeros((1, 501), np.int64)),
                         "collisions/time: has dtype int64"),
    "count beyond the records": (lambda g: g["count"].write_direct(np.array([10**6])),
                                 "collisions/count: holds 1000000"),
}


@pytest.mark.parametrize("case", list(CRAFTED))
def test_a_crafted_run_file_is_refused_on_open_and_by_plot(case, tmp_path):
    """``step`` shorter than the records gave an IndexError traceback from ``plot --kind series``; ``time``
    declared (1, 10¹²) a MemoryError from ``plot`` and from ``rbx.open(f).time``; ``position`` of shape
    (1, 5001, 7) was drawn. The reader checks every dataset's shape and dtype against the layout: FileError,
    and one line with exit 2 from ``rbx plot``."""
    change, said = CRAFTED[case]
    path = crafted(tmp_path, change)
    with pytest.raises(rbx.FileError, match=f"crafted.h5: {said}".replace("(", r"\(").replace(")", r"\)")):
        rbx.open(path).time
    res = rbx_cli("plot", path, "--kind", "series", "--coordinate", "x", "-o", tmp_path / "x.png", cwd=tmp_path)
    assert res.returncode == 2, res.stderr
    assert said in one_line(res)
    assert not (tmp_path / "x.png").exists()


# ---- resuming -----------------------------------------------------------------------------------------------------

@pytest.mark.long
def test_a_resume_checks_the_saved_state_against_its_config(tmp_path):
    """With the stored radius changed from 0.1 to 0.2 the resume exited 0 and marked the file complete with
    centres at y = 0.1, outside the shrunk table. The stored config must agree with the root attributes written
    with the run, and every running centre must lie in its shrunk table."""
    killed_run(tmp_path)
    rbx.open(tmp_path / "run.h5.partial")

    def edit(radius_attr):
        with h5py.File(tmp_path / "run.h5.partial", "r+") as f:
            cfg = yaml.safe_load(f.attrs["config"])
            cfg["ball"]["radius"] = 0.2
            f.attrs["config"] = yaml.safe_dump(cfg, sort_keys=False)
            if radius_attr:
                f.attrs["radius"] = 0.2
    edit(radius_attr=False)
    res = rbx_cli("simulate", "--resume", "run.h5.partial", cwd=tmp_path)
    assert res.returncode == 2, res.stderr
    assert "run.h5.partial: config: radius: is 0.2 but the run was made with 0.1" in one_line(res)
    edit(radius_attr=True)       # the attribute changed too: the state itself does not fit
    res = rbx_cli("simulate", "--resume", "run.h5.partial", cwd=tmp_path)
    assert res.returncode == 2, res.stderr
    line = one_line(res)
    assert re.search(r"run\.h5\.partial: final(_previous)?/position: trajectory \d+ is at \[.*, 0\.1\], outside "
                     "the table of the stored config", line), line
    assert not (tmp_path / "run.h5").exists() and not rbx.open(tmp_path / "run.h5.partial").complete


KILL_AFTER_LINK = ("import os, sys\n"
                   "remove = os.remove\n"
                   "def remove_or_die(p, *a, **k):\n"
                   "    p = os.fspath(p)\n"
                   "    if p.endswith('run.h5.partial') and os.path.exists(p[:-8]) and os.path.samefile(p, p[:-8]):\n"
                   "        os.kill(os.getpid(), 9)\n"
                   "    return remove(p, *a, **k)\n"
                   "os.remove = remove_or_die\n"
                   "from rbx.cli.main import main; sys.argv[0] = 'rbx'; main()")


@pytest.mark.long
def test_a_kill_between_the_final_link_and_the_remove_is_cleaned_up(tmp_path):
    """Killed between linking OUT.h5.partial to OUT.h5 and removing the .partial, the two names were one inode;
    ``--resume OUT.h5.partial`` then always said ``OUT.h5: exists; use --force``. The second name is removed
    (the rename was done), by the resume (which then finds run.h5 complete) and by the next run's check."""
    write_config(tmp_path, strip_random(3000, trajectories=2, every=3, record=("time", "position")))
    reference_run(tmp_path)
    for then in ("resume", "a new run"):
        for f in tmp_path.glob("run.h5*"):
            f.unlink()
        killed = subprocess.run([sys.executable, "-c", KILL_AFTER_LINK, "simulate", "exp.yaml", "-o", "run.h5",
                                 "--quiet"], cwd=tmp_path, capture_output=True, text=True, timeout=900)
        assert killed.returncode == -signal.SIGKILL, killed.stderr
        assert os.path.samefile(tmp_path / "run.h5", tmp_path / "run.h5.partial")
        if then == "resume":
            res = rbx_cli("simulate", "--resume", "run.h5.partial", cwd=tmp_path)
            # run.h5 holds the complete run under its one name: nothing is left to rename or resume
            assert res.returncode == 0, res.stderr
            assert "rbx: run.h5: the run is complete; nothing to resume" in one_line(res), res.stderr
        else:
            res = rbx_cli("simulate", "exp.yaml", "-o", "run.h5", cwd=tmp_path)
            assert res.returncode == 2 and "run.h5: exists; use --force" in one_line(res), res.stderr
        assert sorted(p.name for p in tmp_path.glob("run.h5*")) in (["run.h5"], ["run.h5", "run.h5.lock"]), then
        assert_same_records(read_run(tmp_path / "run.h5"), read_run(tmp_path / "ref.h5"))


@pytest.mark.long
def test_resuming_the_output_name_of_a_killed_run_resumes_its_partial(tmp_path):
    """After a kill only OUT.h5.partial exists: ``--resume OUT.h5`` said ``file not found`` without naming it
    (24 of 24 tries). It resumes OUT.h5.partial; so does ``rbx.resume('OUT.h5')``, the same code."""
    reference = killed_run(tmp_path)
    shutil.copyfile(tmp_path / "run.h5.partial", tmp_path / "copy.h5.partial")
    res = rbx_cli("simulate", "--resume", "run.h5", "--quiet", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert sorted(p.name for p in tmp_path.glob("run.h5*")) == ["run.h5"]
    assert_same_records(read_run(tmp_path / "run.h5"), reference)
    run = rbx.resume(tmp_path / "copy.h5")
    assert run.complete and run.path == str(tmp_path / "copy.h5")
    assert_same_records(read_run(tmp_path / "copy.h5"), reference)


@pytest.mark.long
def test_a_run_on_a_file_system_made_read_only_resumes_into_a_writable_folder(tmp_path):
    """A killed run whose folder became read-only, resumed into a writable ``-o``: the stale lock could not be
    taken over (``OSError: [Errno 30] … 'e.h5.lock' -> 'e.h5.lock.stale.N'``, a traceback). Nothing can write
    there, so the file is read without its lock; in place it is one line."""
    with tmpfs(tmp_path / "disk", "64m") as disk:
        reference = killed_run(disk, out="e.h5")
        assert (disk / "e.h5.lock").exists()
        res = subprocess.run(["mount", "-o", "remount,ro", str(disk)], capture_output=True, text=True)
        if res.returncode != 0:
            pytest.skip(f"cannot make the tmpfs read-only: {res.stderr.strip()}")
        res = rbx_cli("simulate", "--resume", disk / "e.h5.partial", "-o", tmp_path / "out.h5", "--quiet",
                      cwd=tmp_path)
        assert res.returncode == 0, res.stderr
        assert_same_records(read_run(tmp_path / "out.h5"), reference)
        res = rbx_cli("simulate", "--resume", disk / "e.h5.partial", cwd=tmp_path)
        assert res.returncode == 2, res.stderr
        assert "cannot be resumed in place" in one_line(res)


def test_a_complete_file_has_one_layout_however_many_checkpoints_its_run_took(tmp_path, monkeypatch):
    """Whether a file held ``final_previous/`` depended on how many checkpoints its run took (one a second: on the
    machine's speed, a cluster's rounds), so two uninterrupted runs of one config differed in layout. A complete
    file holds ``final/`` alone; an interrupted one keeps both saved states for its resume."""
    cfg = scene("strip-random", 3000, 2, 3, record=["time", "position"])
    rbx.simulate(cfg, output=tmp_path / "once.h5")                  # one checkpoint, at the end
    monkeypatch.setattr(simulation, "BLOCK_WORK", 300)
    monkeypatch.setattr(simulation, "CHECKPOINT_SECONDS", 0)        # one after every block
    rbx.simulate(cfg, output=tmp_path / "often.h5")
    with h5py.File(tmp_path / "once.h5") as a, h5py.File(tmp_path / "often.h5") as b:
        assert sorted(a) == sorted(b) == ["collisions", "final"]
        assert sorted(a["final"]) == sorted(b["final"])
    assert_same_records(read_run(tmp_path / "once.h5"), read_run(tmp_path / "often.h5"))


@pytest.mark.long
def test_a_run_file_that_is_a_fifo_or_a_device_is_refused_saying_what_it_is(tmp_path):
    """A run file must be a regular file, checked before anything opens it (a FIFO opened for reading waits for a
    writer): one line saying what it is, exit 2, without waiting. (Before, h5py's signature check refused a FIFO as
    'not an HDF5 file (or unreadable)'.)"""
    os.mkfifo(tmp_path / "pipe.h5")
    for args in (("plot", "pipe.h5", "--kind", "orbit"), ("simulate", "--resume", "pipe.h5"),
                 ("plot", "/dev/zero", "--kind", "orbit")):
        res = rbx_cli(*args, cwd=tmp_path, timeout=120)
        assert res.returncode == 2, (args, res.stderr)
        assert "not a regular file: not an HDF5 file" in one_line(res), res.stderr
    with pytest.raises(rbx.FileError, match="pipe.h5: is a FIFO"):
        rbx.open(tmp_path / "pipe.h5")


def test_resuming_into_a_symbolic_link_is_refused_before_any_work(tmp_path):
    """The run's own file a link to an unfinished run elsewhere: the resume computed the whole run, then refused
    the link at the final rename and exited 0, the records left in the .partial."""
    import subprocess
    import sys
    from pathlib import Path
    import h5py
    import rbx
    root = Path(__file__).resolve().parents[1]
    victim = tmp_path / "elsewhere.h5"
    rbx.simulate(str(root / "configs" / "examples" / "strip.yaml"), collisions=50, output=victim)
    with h5py.File(victim, "r+") as f:
        f.attrs["complete"] = False
    before = victim.read_bytes()
    (tmp_path / "link.h5").symlink_to(victim)
    res = subprocess.run([str(Path(sys.executable).with_name("rbx")), "simulate", "--resume", "link.h5"],
                         cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert res.returncode == 2 and res.stderr.count("\n") == 1 and "symbolic link" in res.stderr, res.stderr
    assert not (tmp_path / "link.h5.partial").exists() and (tmp_path / "link.h5").is_symlink()
    assert victim.read_bytes() == before


@pytest.mark.long
def test_a_figure_that_cannot_be_written_whole_leaves_the_one_it_would_replace(tmp_path):
    """rbx plot -o good.png on a full disk (here a size limit) wrote in place: the good figure was left truncated
    (exit 2), a new name a 0-byte file. A figure and an animation are written beside their name and renamed to it:
    the old file stays whole, nothing else is left, and a full disk is exit 1, one line, as for a run."""
    write_config(tmp_path, strip_random(200, trajectories=1, every=1, record=("time", "position", "velocity",
                                                                               "orientation")))
    assert rbx_cli("simulate", "exp.yaml", "-o", "r.h5", "--quiet", cwd=tmp_path).returncode == 0
    for command, name in ((["plot", "r.h5", "--kind", "orbit"], "good.png"),
                          (["animate", "r.h5", "--frames", "20"], "good.gif")):
        res = rbx_cli(*command, "-o", name, "--quiet", cwd=tmp_path)
        assert res.returncode == 0, res.stderr
        good = (tmp_path / name).read_bytes()
        args = " ".join(command)
        res = subprocess.run(["bash", "-c", f"trap '' XFSZ; ulimit -f 4; exec {RBX} {args} -o {name} "
                              "--quiet"], cwd=tmp_path, capture_output=True, text=True, timeout=900)
        assert res.returncode == 1 and res.stderr.count("\n") == 1, res.stderr
        assert "no room on the disk" in res.stderr and "nothing was replaced" in res.stderr, res.stderr
        assert (tmp_path / name).read_bytes() == good
        assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []
