"""Interrupted runs lose nothing (docs/reference.md §4): SIGINT/SIGTERM stop a real ``rbx simulate`` within a second or two and
leave a valid HDF5 file marked ``complete = false``; ``rbx simulate --resume`` then writes exactly the records an
uninterrupted run writes, record by record, bit for bit.

The real-process tests show what a user sees. The in-process tests make the interruption deterministic: blocks
are made tiny (``BLOCK_WORK``) and the process sends itself SIGINT from the progress callback after a chosen
block, so every scene is cut at a known point, resumed, cut again and resumed to the end.
"""
import copy
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml
from click.testing import CliRunner

import rbx
import rbx.cli.common as common
import rbx.runfile as runfile
import rbx.simulation as simulate
from rbx.cli.main import cli
from tests.catalog import SCENES

RBX = str(Path(sys.executable).with_name("rbx"))


def write_config(folder, cfg, name="exp.yaml"):
    path = Path(folder) / name
    path.write_text(yaml.safe_dump(cfg, sort_keys=False))
    return path


def strip_random(collisions, trajectories=3, every=3, record=("time", "position", "velocity", "angular_velocity",
                                                               "orientation", "wall", "rank")):
    cfg = copy.deepcopy(SCENES["strip-random"])
    cfg["run"] = {"collisions": collisions, "trajectories": trajectories, "seed": 11}
    cfg["output"] = {"record": list(record), "every": every}
    return cfg


def reference_run(folder, config="exp.yaml", out="ref.h5", force=False):
    """The uninterrupted run of ``config`` written to ``out``, in this process: ``rbx.simulate(output=)`` writes
    the file ``rbx simulate -o`` writes (the same driver), without the start-up of another Python -> its path."""
    path = Path(folder) / out
    rbx.simulate(str(Path(folder) / config), output=str(path), force=force).close()
    return path


def read_run(path):
    """Everything a run file holds: root attributes, collisions/*, final/* -> dict."""
    with h5py.File(path, "r") as f:
        out = {"attrs": {k: f.attrs[k] for k in f.attrs}}
        for group in ("collisions", "final"):
            if group in f:
                out.update({f"{group}/{k}": f[group][k][...] for k in f[group]})
    return out


def assert_same_records(a, b):
    keys = sorted(k for k in b if k != "attrs")
    assert sorted(k for k in a if k != "attrs") == keys
    for k in keys:
        x, y = a[k], b[k]
        assert x.shape == y.shape, k
        assert x.dtype == y.dtype, k
        # bit for bit (NaN marks rows past a trajectory's end)
        assert np.array_equal(x, y, equal_nan=x.dtype.kind == "f"), k
    assert without_path(a["attrs"]["config"]) == without_path(b["attrs"]["config"])


def without_path(config):
    """A stored config without its output.path: each file names itself there."""
    cfg = yaml.safe_load(config)
    cfg["output"].pop("path", None)
    return cfg


def check_valid_partial(path, every, width=1.0, R=0.1):
    """An interrupted file: complete = false, count and step consistent with final/, records physically sane."""
    run = read_run(path)
    assert not bool(run["attrs"]["complete"])
    count, step = run["collisions/count"], run["collisions/step"]
    made = run["final/collisions"]
    np.testing.assert_array_equal(count, 1 + made // every)
    assert len(step) == count.max()
    np.testing.assert_array_equal(step, np.arange(len(step)) * every)
    t = run["collisions/time"]
    for j, c in enumerate(count):
        assert np.all(np.diff(t[j, :c]) > 0)
        y = run["collisions/position"][j, :c, 1]
        assert np.all((y > R - 1e-9) & (y < width - R + 1e-9))
        wall = run["collisions/wall"][j, :c]
        assert wall[0] == -1 and set(np.unique(wall[1:])) <= {0, 1}
        assert np.all(np.isnan(t[j, c:]))
    return run


# ---- real processes -----------------------------------------------------------------------------------------------

def start_and_signal(args, partial, sig, cwd, delay):
    """Start ``args``, wait until the run writes ``partial`` and ``delay`` more seconds, send ``sig`` -> the
    completed process. No bound on how long anything takes (a loaded machine stretches everything): a process that
    did not stop within 60 s of the signal, with hours of work left, fails."""
    proc = subprocess.Popen(args, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 900      # a guard against a hang, not a bound: a first compile on a busy machine
    while not os.path.exists(partial):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "the run never started writing"
        time.sleep(0.01)
    time.sleep(delay)
    assert proc.poll() is None, "the run ended before the signal: make it longer"
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=60)
    return subprocess.CompletedProcess(args, proc.returncode, out, err)


@pytest.mark.long
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_signal_stops_a_real_run_quickly_and_leaves_a_valid_file(sig, tmp_path):
    # 10⁹ collisions: hours of work, so the signal always lands mid-run
    cfg = strip_random(10**9, trajectories=2, every=1000, record=("time", "position", "wall"))
    write_config(tmp_path, cfg)
    out = tmp_path / "run.h5"
    res = start_and_signal([RBX, "simulate", "exp.yaml", "-o", "run.h5"], f"{out}.partial", sig, tmp_path,
                           delay=1.0)
    assert res.returncode == 128 + sig, res.stderr
    assert "Traceback" not in res.stderr
    assert f"interrupted by {sig.name}" in res.stderr and "--resume run.h5" in res.stderr
    # it stops at the next block (a fraction of a second of work), not after the hours of work asked: the 60 s
    # guard of start_and_signal and the collisions done say so without timing anything
    assert out.exists() and not Path(f"{out}.partial").exists()
    assert not Path(f"{out}.lock").exists()                  # the run's lock goes with it
    run = check_valid_partial(out, every=1000)
    assert 0 < run["final/collisions"].min() < 10**9


def test_a_signal_while_setting_up_aborts_at_once(tmp_path):
    """A signal while the run sets up (here: waiting for its kernel, which another process holds the compile lock
    of, as a first compile does for seconds) aborts at once, writes nothing, and prints one line (no traceback).
    "At once" without a clock: the lock is still held by this test when the process has ended."""
    from rbx import _jit, config, engine
    from rbx.simulation import Simulation
    cfg = strip_random(1000)
    write_config(tmp_path, cfg)
    spec = engine.compiled_spec(Simulation(config.from_dict(cfg, str(tmp_path / "exp.yaml"))).spec())
    lock = os.path.join(_jit.CACHE_DIR, f".advance-{spec}.lock")    # taken by a process's first run of a kernel
    with _jit.compile_lock_at(lock):
        proc = subprocess.Popen([RBX, "simulate", "exp.yaml", "-o", "run.h5"], cwd=tmp_path,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        wait_until_open(proc, lock)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)      # a guard against a hang: the lock is never released meanwhile
    assert proc.returncode == 130, err
    assert err.strip() == "rbx: interrupted by SIGINT before the run started; nothing written"
    assert not list(tmp_path.glob("run.h5*"))


def wait_until_open(proc, path, closed=False, timeout=900):
    """Wait until the process has a file open (from /proc/PID/fd) whose path is ``path`` or matches it (a compiled
    regular expression), and with ``closed`` until it has closed it again: a compile lock opened and closed means
    the kernel is compiled or loaded and the run is about to start. Polled every millisecond; the lock is held for
    the whole load or compile (tens of ms at the least)."""
    deadline = time.monotonic() + timeout
    seen = False
    while True:
        assert proc.poll() is None, proc.communicate()
        links = set()
        try:
            for fd in os.listdir(f"/proc/{proc.pid}/fd"):
                try:
                    links.add(os.readlink(f"/proc/{proc.pid}/fd/{fd}"))
                except OSError:        # closed meanwhile
                    pass
        except OSError:
            pass
        if any(link == path if isinstance(path, str) else path.search(link) for link in links):
            seen = True
            if not closed:
                return
        elif seen:
            return
        assert time.monotonic() < deadline, f"{path} never {'closed' if seen else 'opened'}"
        time.sleep(0.001)


@pytest.mark.long
def test_real_interrupt_then_real_resume_equals_an_uninterrupted_run(tmp_path):
    """Interrupt a real process running with tiny blocks, resume it with a real process and the normal block
    size (so the block boundaries differ too), and compare with an uninterrupted run."""
    cfg = strip_random(60_000, trajectories=3, every=7, record=("time", "position", "angular_velocity", "wall", "rank"))
    write_config(tmp_path, cfg)
    small_blocks = ("import sys, rbx.simulation as s; s.BLOCK_WORK = 600; s.CHECKPOINT_SECONDS = 0; from rbx.cli.main import cli; "
                    "cli(sys.argv[1:], prog_name='rbx')")
    args = [sys.executable, "-c", small_blocks, "simulate", "exp.yaml", "-o", "run.h5"]
    res = start_and_signal(args, tmp_path / "run.h5.partial", signal.SIGINT, tmp_path, delay=0.3)
    assert res.returncode == 130, res.stderr
    part = check_valid_partial(tmp_path / "run.h5", every=7)
    assert part["final/collisions"].max() < 60_000
    res = subprocess.run([RBX, "simulate", "--resume", "run.h5", "--quiet"], cwd=tmp_path, capture_output=True,
                         text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    ref = CliRunner().invoke(cli, ["simulate", str(tmp_path / "exp.yaml"), "-o", str(tmp_path / "ref.h5"),
                                   "--quiet"], catch_exceptions=False)
    assert ref.exit_code == 0, ref.stderr
    resumed, reference = read_run(tmp_path / "run.h5"), read_run(tmp_path / "ref.h5")
    assert bool(resumed["attrs"]["complete"])
    assert_same_records(resumed, reference)
    line, = runfile._text(resumed["attrs"]["resumed"]).splitlines()     # the resume's own provenance
    assert f"from collision {int(part['final/collisions'].max())}: " in line and "simulate --resume run.h5" in line


# ---- deterministic interruptions in-process ----------------------------------------------------------------------

@pytest.fixture
def tiny_blocks(monkeypatch):
    """Blocks of a few hundred collisions, and a way to send SIGINT to this process after the k-th block."""
    monkeypatch.setattr(simulate, "BLOCK_WORK", 300)
    monkeypatch.setattr(simulate, "CHECKPOINT_SECONDS", 0)
    when = {"block": None, "seen": 0}
    original = common.Progress.__call__

    def progress(self, done, total):
        when["seen"] += 1
        if when["seen"] == when["block"]:
            os.kill(os.getpid(), signal.SIGINT)
        return original(self, done, total)

    monkeypatch.setattr(common.Progress, "__call__", progress)

    def interrupt_after(block):
        when["block"], when["seen"] = block, 0
    return interrupt_after


def invoke(*args):
    return CliRunner().invoke(cli, ["simulate", *map(str, args), "--quiet"], catch_exceptions=False)


def scene(name, collisions, trajectories, every, record=None, initial=None):
    cfg = copy.deepcopy(SCENES[name])
    cfg["run"] = {"collisions": collisions, "trajectories": trajectories, "seed": 5}
    cfg["output"] = {"every": every}
    if record is not None:
        cfg["output"]["record"] = record
    if initial is not None:
        cfg["initial"] = initial
    return cfg


ESCAPING = [  # the second trajectory flies parallel to the walls: no wall ahead, it ends at once (count = 1)
    {"position": [0.0, 0.5], "velocity": [0.6, 0.8], "angular_velocity": 1.0},
    {"position": [0.0, 0.5], "velocity": [1.0, 0.0]},
    {"position": [0.3, 0.2], "velocity": [-0.3, 0.9], "angular_velocity": -2.0}]

RESUME_SCENES = {
    "strip-random-every3": scene("strip-random", 2000, 3, 3),
    "plates-random-direction-every2": scene("plates-random-direction", 1500, 2, 2),
    "box-hemisphere-every5": scene("box-hemisphere", 1500, 2, 5),
    "strip-escape-every4": scene("strip-random", 2000, 3, 4, initial=ESCAPING),
    "rectangle-sampled-every3": scene("rectangle-random", 1500, 4, 3, initial={"sample": "billiard"}),
    "star-hemisphere-every1": scene("star-polygon-hemisphere", 1200, 2, 1),
    "strip-final-state-only": scene("strip-random", 3000, 3, 1, record=[]),
}


@pytest.mark.parametrize("name", list(RESUME_SCENES))
def test_resume_twice_equals_an_uninterrupted_run(name, tmp_path, tiny_blocks):
    exp = write_config(tmp_path, RESUME_SCENES[name])
    ref, run = tmp_path / "ref.h5", tmp_path / "run.h5"
    tiny_blocks(None)
    assert invoke(exp, "-o", ref).exit_code == 0

    tiny_blocks(3)
    first = invoke(exp, "-o", run)
    assert first.exit_code == 130, first.stderr
    assert "complete = false" in first.stderr
    cut1 = read_run(run)
    assert not bool(cut1["attrs"]["complete"])

    tiny_blocks(4)
    second = invoke("--resume", run)
    assert second.exit_code == 130, second.stderr
    cut2 = read_run(run)
    assert cut1["final/collisions"].max() < cut2["final/collisions"].max() < RESUME_SCENES[name]["run"]["collisions"]

    tiny_blocks(None)
    third = invoke("--resume", run)
    assert third.exit_code == 0, third.stderr
    resumed = read_run(run)
    assert bool(resumed["attrs"]["complete"])
    assert_same_records(resumed, read_run(ref))
    # the provenance says when and from where each part was computed: one line per resume
    assert runfile._text(read_run(ref)["attrs"]["resumed"]) == ""
    lines = runfile._text(resumed["attrs"]["resumed"]).splitlines()
    assert len(lines) == 2
    for line, cut in zip(lines, (cut1, cut2)):
        assert f"from collision {int(cut['final/collisions'].max())}:" in line
        assert f"on {os.uname().nodename}" in line and "numba " in line


def test_resume_of_a_run_stopped_before_its_first_block(tmp_path, monkeypatch):
    """The signal arrives while record 0 is written: no block ran, there is no final/ yet; resume starts over."""
    exp = write_config(tmp_path, scene("strip-random", 500, 2, 3))
    assert invoke(exp, "-o", tmp_path / "ref.h5").exit_code == 0
    write = runfile.H5Sink.write

    def write_then_signal(self, block, nrec):
        write(self, block, nrec)
        os.kill(os.getpid(), signal.SIGINT)

    monkeypatch.setattr(runfile.H5Sink, "write", write_then_signal)
    res = invoke(exp, "-o", tmp_path / "run.h5")
    assert res.exit_code == 130
    cut = read_run(tmp_path / "run.h5")
    assert "final/collisions" not in cut and list(cut["collisions/count"]) == [1, 1]
    monkeypatch.setattr(runfile.H5Sink, "write", write)
    assert invoke("--resume", tmp_path / "run.h5").exit_code == 0
    assert_same_records(read_run(tmp_path / "run.h5"), read_run(tmp_path / "ref.h5"))


def test_resume_drops_records_written_after_the_last_checkpoint(tmp_path, tiny_blocks):
    """A hard kill between a block's records and its checkpoint leaves records the saved state does not account
    for: resume cuts them and recomputes them."""
    exp = write_config(tmp_path, scene("strip-random", 2000, 3, 3))
    assert invoke(exp, "-o", tmp_path / "ref.h5").exit_code == 0
    tiny_blocks(2)
    assert invoke(exp, "-o", tmp_path / "run.h5").exit_code == 130
    with h5py.File(tmp_path / "run.h5", "r+") as f:
        g = f["collisions"]
        n = g["step"].shape[0]
        for k in ("time", "position", "velocity", "angular_velocity", "orientation", "wall", "rank"):
            g[k].resize(n + 5, axis=1)
            g[k][:, n:] = 7          # garbage where the next records go
        g["step"].resize(n + 5, axis=0)
        g["count"][...] += 5
    tiny_blocks(None)
    assert invoke("--resume", tmp_path / "run.h5").exit_code == 0
    assert_same_records(read_run(tmp_path / "run.h5"), read_run(tmp_path / "ref.h5"))


@pytest.mark.parametrize("damage", ["state", "state-and-digest"])
def test_resume_refuses_a_state_that_does_not_match_its_records(damage, tmp_path, tiny_blocks):
    """A kill while final/ is rewritten can leave it half old, half new: resume must refuse it, not continue from
    a mixture (caught by the digest, or failing that by comparing the last records with the state)."""
    exp = write_config(tmp_path, scene("strip-random", 2000, 3, 3))
    tiny_blocks(2)
    assert invoke(exp, "-o", tmp_path / "run.h5").exit_code == 130
    with h5py.File(tmp_path / "run.h5", "r+") as f:
        for group in ("final", "final_previous"):     # both saved states (one alone is recovered from the other)
            if group not in f:
                continue
            f[f"{group}/time"][0] += 1.0
            if damage == "state-and-digest":
                f[group].attrs["digest"] = runfile.state_digest({k: f[group][k][...] for k in f[group]})
    res = invoke("--resume", tmp_path / "run.h5")
    assert res.exit_code == 2
    line, = res.stderr.strip().splitlines()
    assert "run.h5" in line and "killed" in line and "cannot be resumed" in line


def test_a_killed_run_resumes_exactly(tmp_path):
    """SIGKILL gives the process no chance to close the file. Resuming the .partial it leaves gives exactly the
    uninterrupted records: the file changes only at commits (rbx/journal.py), so no kill tears it (before the
    journal, a kill while HDF5 wrote its metadata could leave a file that did not open, refused in one line)."""
    cfg = strip_random(400_000, trajectories=3, every=7, record=("time", "position", "wall", "rank"))
    write_config(tmp_path, cfg)
    assert invoke(tmp_path / "exp.yaml", "-o", tmp_path / "ref.h5").exit_code == 0
    reference = read_run(tmp_path / "ref.h5")
    small_blocks = ("import sys, rbx.simulation as s; s.BLOCK_WORK = 3000; s.CHECKPOINT_SECONDS = 0; from rbx.cli.main import cli; "
                    "cli(sys.argv[1:], prog_name='rbx')")
    for delay in (0.05, 0.2, 0.35):
        for f in tmp_path.glob("run.h5*"):
            f.unlink()
        proc = subprocess.Popen([sys.executable, "-c", small_blocks, "simulate", "exp.yaml", "-o", "run.h5"],
                                cwd=tmp_path, stderr=subprocess.DEVNULL)
        while not (tmp_path / "run.h5.partial").exists():
            time.sleep(0.005)
        time.sleep(delay)
        assert proc.poll() is None, "the run ended before the kill: make it longer"
        proc.kill()
        proc.wait()
        assert not (tmp_path / "run.h5").exists()
        res = invoke("--resume", tmp_path / "run.h5.partial")          # writes run.h5
        assert res.exit_code == 0, res.stderr
        assert "failed their checksum" not in res.stderr             # no chunk torn, none read raw
        assert_same_records(read_run(tmp_path / "run.h5"), reference)
        assert not (tmp_path / "run.h5.lock").exists()          # the stale lock was taken over and removed


def test_resume_into_another_file_leaves_the_original(tmp_path, tiny_blocks):
    exp = write_config(tmp_path, scene("strip-random", 1500, 2, 3))
    tiny_blocks(2)
    assert invoke(exp, "-o", tmp_path / "run.h5").exit_code == 130
    before = (tmp_path / "run.h5").read_bytes()
    tiny_blocks(None)
    res = invoke("--resume", tmp_path / "run.h5", "-o", tmp_path / "done.h5")
    assert res.exit_code == 0, res.stderr
    assert (tmp_path / "run.h5").read_bytes() == before
    assert bool(read_run(tmp_path / "done.h5")["attrs"]["complete"])
    # a complete run: nothing to do, and that is not an error
    res = invoke("--resume", tmp_path / "done.h5")
    assert res.exit_code == 0 and "nothing to resume" in res.stderr
    # and -o to an existing file still needs --force
    res = invoke("--resume", tmp_path / "run.h5", "-o", tmp_path / "done.h5")
    assert res.exit_code == 2 and "exists; use --force" in res.stderr


def test_a_signal_during_the_last_block_still_completes_the_run(tmp_path, monkeypatch):
    """Work that was finished is reported finished: a stop requested during the last block is not an interrupt."""
    exp = write_config(tmp_path, scene("strip-random", 3000, 2, 1))
    monkeypatch.setattr(simulate, "BLOCK_WORK", 300)
    monkeypatch.setattr(simulate, "CHECKPOINT_SECONDS", 0)
    original = common.Progress.__call__

    def signal_at_the_end(self, done, total):
        if done == total:
            os.kill(os.getpid(), signal.SIGINT)
        return original(self, done, total)

    monkeypatch.setattr(common.Progress, "__call__", signal_at_the_end)
    res = invoke(exp, "-o", tmp_path / "run.h5")
    assert res.exit_code == 0, res.stderr
    assert bool(read_run(tmp_path / "run.h5")["attrs"]["complete"])


def wait_until_loaded(proc, library, timeout=300):
    """Wait until the process has mapped a shared library whose path holds ``library`` (numba: rbx is past its
    command line and its Ctrl-C handler, setting up). A fixed delay landed, on a loaded machine, in Python's own
    start-up, before any rbx code runs (docs/reliability.md, "Not handled yet")."""
    deadline = time.monotonic() + timeout
    while True:
        assert proc.poll() is None, proc.communicate()
        try:
            with open(f"/proc/{proc.pid}/maps") as fh:
                if library in fh.read():
                    return
        except FileNotFoundError:      # no /proc (not Linux): fall back to a delay
            time.sleep(1.0)
            return
        assert time.monotonic() < deadline, f"{library} never loaded"
        time.sleep(0.005)


@pytest.mark.long
@pytest.mark.parametrize("delay, sig", [(0.0, signal.SIGINT), (0.0, signal.SIGTERM), (1.5, signal.SIGINT),
                                        pytest.param(1.5, signal.SIGTERM, marks=pytest.mark.heavy)])
def test_ctrl_c_in_histogram_and_while_starting_is_one_line_and_130(tmp_path, delay, sig):
    # 10⁷ samples: a long experiment, so the signal lands while setting up (importing numba, loading kernels:
    # delay 0 after numba's first library is mapped) or running; click used to print 'Aborted!' and exit 1, and
    # the import phase a KeyboardInterrupt traceback
    cfg = {"table": {"kind": "rectangle", "width": 2, "height": 1}, "ball": {"radius": 0.1},
           "boundary": {"default": {"rule": "constant", "rank": 1}}, "initial": {"sample": "billiard", "wall": "bottom"},
           "run": {"trajectories": 10**7, "collisions": 1000}, "output": {"path": "ret.h5"}}
    (tmp_path / "h.yaml").write_text(yaml.safe_dump(cfg))
    # SIGINT at its default in the child, as from a shell: a test worker can have it ignored, the child inherits
    # that, and a signal sent while it still imports (delay 0) is then discarded by the kernel (it ran on for 120 s)
    proc = subprocess.Popen([RBX, "histogram", "h.yaml", "-o", "h.png", "--quiet"], cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONFAULTHANDLER": "1"},
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    wait_until_loaded(proc, "numba")
    time.sleep(delay)
    assert proc.poll() is None
    proc.send_signal(sig)
    try:
        _, err = proc.communicate(timeout=120)
    except subprocess.TimeoutExpired:   # once in a full suite: say where it hung (faulthandler dumps every thread)
        proc.send_signal(signal.SIGABRT)
        raise AssertionError("no exit 120 s after Ctrl-C; the stacks:\n" + proc.communicate(timeout=60)[1]) from None
    assert proc.returncode == 128 + sig and "Traceback" not in err and err.count("\n") == 1, err
    # importing, setting up or running (a loaded machine decides which): the same line, naming the signal
    assert err.startswith(f"rbx: interrupted by {sig.name}") and "nothing written" in err, err
    assert not (tmp_path / "h.png").exists()


@pytest.mark.parametrize("trajectories", [1, 2])
def test_ctrl_c_in_lyapunov_does_not_wait_for_the_running_segment(tmp_path, trajectories):
    """The kernels' threads cannot be interrupted: the command leaves them and ends the process (one line, 130).
    It used to wait for the running segment: here 10⁹ collisions, minutes of work. One trajectory ran on the
    calling thread itself, which a signal cannot reach in the kernel: SIGINT and SIGTERM waited for the segment
    (11 minutes, in one try); it runs on the pool as any other number does."""
    cfg = {"table": {"kind": "sinai", "size": [2.0, 1.5], "radius": 0.4}, "ball": {"radius": 0.1},
           "boundary": {"default": {"rule": "constant", "rank": 1}},
           "initial": {"position": [0.3, 0.3], "velocity": [0.83, 0.31], "angular_velocity": 0.7},
           "run": {"trajectories": trajectories, "collisions": 10**10}}
    (tmp_path / "l.yaml").write_text(yaml.safe_dump(cfg))
    proc = subprocess.Popen([RBX, "lyapunov", "l.yaml", "--quiet", "--warmup", "0"], cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    from rbx import _jit
    # the compile lock of the loop carrying tangent vectors, opened and closed: the kernel is there and the
    # segments start
    wait_until_open(proc, re.compile(re.escape(_jit.CACHE_DIR) + r"/\.advance-\d+\.lock$"), closed=True)
    time.sleep(0.5)
    assert proc.poll() is None
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)       # waiting for the segment would take minutes
    assert proc.returncode == 130 and err == "rbx: interrupted by SIGINT; nothing written\n", err


@pytest.mark.parametrize("kill", ["torn-newest-state", "between-the-renames"])
def test_a_kill_inside_the_checkpoint_leaves_a_state_to_resume_from(kill, tmp_path, tiny_blocks):
    """The checkpoint writes the new state beside the last one and swaps their names only once it verifies: a
    kill while it writes (the newest state torn) or between the two renames still resumes exactly (a kill inside
    the checkpoint used to lose the whole run: 'the last saved state is incomplete')."""
    exp = write_config(tmp_path, scene("strip-random", 2000, 3, 3))
    assert invoke(exp, "-o", tmp_path / "ref.h5").exit_code == 0
    tiny_blocks(3)
    assert invoke(exp, "-o", tmp_path / "run.h5").exit_code == 130
    with h5py.File(tmp_path / "run.h5", "r+") as f:
        assert "final" in f and "final_previous" in f
        if kill == "torn-newest-state":
            f["final/position"][0, 0] += 1.0                  # half written: no longer matches its digest
        else:
            f.move("final", "final_swap")                     # killed after the first rename
    tiny_blocks(None)
    res = invoke("--resume", tmp_path / "run.h5")
    assert res.exit_code == 0, res.stderr
    assert_same_records(read_run(tmp_path / "run.h5"), read_run(tmp_path / "ref.h5"))


def test_a_full_disk_stops_the_run_cleanly_and_it_resumes_exactly(tmp_path, monkeypatch):
    """Disk full in the middle of a run: HDF5 meeting ENOSPC left a half-written file and h5py crashed closing it
    (exit 139). rbx checks the room for each block before writing it and stops between blocks (DiskFull, an
    OSError; the CLI: one line, exit 1), its last checkpoint intact; resumed once there is space, the records are
    those of an uninterrupted run. (By hand on a 6 MB tmpfs filled by dd during the run: exit 1, one line.)"""
    import shutil

    import rbx
    exp = write_config(tmp_path, scene("strip-random", 3000, 2, 3))
    rbx.simulate(str(exp), output=tmp_path / "ref.h5")
    real = shutil.disk_usage
    calls = {"n": 0}

    def filling_up(path):
        calls["n"] += 1
        usage = real(path)
        return usage if calls["n"] < 5 else usage._replace(free=0)   # full after a few blocks

    monkeypatch.setattr(shutil, "disk_usage", filling_up)
    monkeypatch.setattr(simulate, "BLOCK_WORK", 300)
    monkeypatch.setattr(simulate, "CHECKPOINT_SECONDS", 0)
    with pytest.raises(runfile.DiskFull) as info:
        rbx.simulate(str(exp), output=tmp_path / "run.h5")
    assert "the disk is full" in str(info.value)
    monkeypatch.undo()
    partial = rbx.open(tmp_path / "run.h5")
    assert not partial.complete and 0 < partial.count.max() < 3001
    res = subprocess.run([RBX, "simulate", "--resume", "run.h5", "--quiet"], cwd=tmp_path, capture_output=True,
                         text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert_same_records(read_run(tmp_path / "run.h5"), read_run(tmp_path / "ref.h5"))


def _last_saved_chunk(f, field):
    """(chunk offset, byte offset, size, records the state accounts for) of the chunk holding trajectory 0's last
    saved record of ``field``."""
    length = int(f["collisions/count"][...].max())
    ds = f[f"collisions/{field}"]
    r0 = (length - 1) // ds.chunks[1] * ds.chunks[1]
    offset = (0, r0) + (0,) * (ds.ndim - 2)
    info = ds.id.get_chunk_info_by_coord(offset)
    return offset, info.byte_offset, info.size, length


@pytest.mark.parametrize("tear", ["checksum", "after-the-saved-records", "the-last-saved-record"])
def test_a_chunk_torn_by_a_kill_is_read_from_its_raw_bytes(tear, tmp_path, tiny_blocks):
    """A kill while HDF5 rewrote a partly filled chunk leaves it failing its Fletcher-32 checksum: its old
    sectors and its new ones mixed. The saved records are the same bytes in both, so resume reads the chunk raw,
    says so in a warning line, and the records equal the uninterrupted run's, every chunk checksummed again. A
    tear that reaches the last saved record is caught by its comparison with the saved state: refused."""
    cfg = scene("strip-random", 3000, 2, 1, record=["time", "position"])
    exp = write_config(tmp_path, cfg)
    assert invoke(exp, "-o", tmp_path / "ref.h5").exit_code == 0
    tiny_blocks(3)
    assert invoke(exp, "-o", tmp_path / "run.h5").exit_code == 130
    with h5py.File(tmp_path / "run.h5", "r") as f:
        offset, at, size, length = _last_saved_chunk(f, "time")
        rc = f["collisions/time"].chunks[1]
        assert f["collisions/time"].shape[1] == length and length % rc   # a partly filled chunk
    raw = bytearray((tmp_path / "run.h5").read_bytes())
    if tear == "checksum":
        where = at + size - 4                               # the checksum's sector not rewritten
    elif tear == "after-the-saved-records":
        where = at + 8 * (length - offset[1])               # trajectory 0's first record after the saved ones
    else:
        where = at + 8 * (length - 1 - offset[1])           # its last saved record
    raw[where:where + 4] = bytes(b ^ 0x5A for b in raw[where:where + 4])
    (tmp_path / "run.h5").write_bytes(bytes(raw))
    with h5py.File(tmp_path / "run.h5", "r") as f, pytest.raises(OSError):
        f["collisions/time"][...]                           # torn indeed: HDF5 refuses the chunk
    res = invoke("--resume", tmp_path / "run.h5")
    if tear == "the-last-saved-record":
        assert res.exit_code == 2
        line, = res.stderr.strip().splitlines()
        assert "collisions/time" in line and "not the saved state" in line
        return
    assert res.exit_code == 0, res.stderr
    line, = res.stderr.strip().splitlines()
    assert "warning" in line and "collisions/time" in line and "1 chunk(s)" in line and "checksum" in line
    assert_same_records(read_run(tmp_path / "run.h5"), read_run(tmp_path / "ref.h5"))
    with h5py.File(tmp_path / "run.h5", "r") as f:
        ds = f["collisions/time"]
        masks = [ds.id.get_chunk_info(i).filter_mask for i in range(ds.id.get_num_chunks())]
        assert masks and not any(masks)                     # every chunk has its checksum again


class _CountingSink(simulate.MemorySink):
    def __init__(self):
        super().__init__()
        self.checkpoints, self.saved_at = 0, []

    def checkpoint(self, sim):
        self.checkpoints += 1
        self.saved_at.append(int(sim.ncoll.min()))
        super().checkpoint(sim)


@pytest.mark.parametrize("seconds, stop_after", [(0, None), (1e9, None), (0, 3), (1e9, 3)])
def test_checkpoints_come_by_time_and_always_where_the_run_stops(seconds, stop_after, monkeypatch):
    """The state is saved after a block once CHECKPOINT_SECONDS have passed (0: after every block), and always where
    the run ends: finished, or stopped between blocks (here after 3 blocks). The records do not depend on when the
    state was saved."""
    from rbx import config
    monkeypatch.setattr(simulate, "BLOCK_WORK", 300)
    monkeypatch.setattr(simulate, "CHECKPOINT_SECONDS", seconds)
    cfg = config.from_dict(scene("strip-random", 3000, 2, 3), "<test>")
    sim = simulate.Simulation(cfg)
    step = sim.records_per_block() * 3                # collisions per block (every = 3)
    assert 3 * step < 3000                            # a stop after 3 blocks is before the end
    sink = _CountingSink()
    polls = {"n": 0}

    def should_stop():
        polls["n"] += 1
        return stop_after is not None and polls["n"] > stop_after
    complete = sim.run(sink, should_stop=should_stop)
    assert complete == (stop_after is None)
    blocks = len(sink.blocks) - 1                     # the first write is record 0
    assert blocks == (-(-3000 // step) if stop_after is None else stop_after)
    if seconds == 0:
        assert sink.checkpoints == blocks + (1 if stop_after is None else 0)   # each block, and the end
    else:
        assert sink.checkpoints == 1                  # only where the run ended
    assert sink.saved_at[-1] == (3000 if stop_after is None else 3 * step)
    assert sink.final["collisions"].min() == sink.saved_at[-1]
    monkeypatch.setattr(simulate, "CHECKPOINT_SECONDS", 0)
    reference = _CountingSink()
    simulate.Simulation(cfg).run(reference)
    got, ref = sink.records, reference.records
    for f in ref:
        np.testing.assert_array_equal(got[f], ref[f][:, :got[f].shape[1]])


# ---- the next block computed while this one is written (simulation.AHEAD) ----------------------------------------


def _run_in_memory(cfg, ahead, monkeypatch, sink=None):
    monkeypatch.setattr(simulate, "AHEAD", ahead)
    sim = simulate.Simulation(cfg)
    sink = sink or simulate.MemorySink()
    try:
        sim.run(sink)
    except RuntimeError:
        pass
    return sim, sink


class _SlowSink(_CountingSink):
    """A slow disk: each write takes 2 ms, long enough for the next block to be computed meanwhile."""

    def write(self, block, nrec):
        time.sleep(0.002)
        super().write(block, nrec)


@pytest.mark.parametrize("name", ["strip-escape-every4", "box-hemisphere-every5", "rectangle-sampled-every3"])
def test_computing_the_next_block_while_writing_changes_no_number(name, monkeypatch):
    """With the overlap the records, their counts and the final state are those of one block after the other
    (many small blocks; a trajectory that escapes at once; random draws; sampled starts)."""
    from rbx import config
    monkeypatch.setattr(simulate, "BLOCK_WORK", 300)
    monkeypatch.setattr(simulate, "CHECKPOINT_SECONDS", 0)
    cfg = config.from_dict(RESUME_SCENES[name], "<test>")
    (_, one), (sim, two) = (_run_in_memory(cfg, ahead, monkeypatch, _SlowSink()) for ahead in (False, True))
    assert len(two.blocks) > 4
    assert two.saved_at == one.saved_at          # each checkpoint saves the state at the end of its own block
    assert set(one.records) == set(two.records) and np.array_equal(one.count, two.count)
    for f in one.records:
        np.testing.assert_array_equal(one.records[f], two.records[f], err_msg=f)
    for f in one.final:
        np.testing.assert_array_equal(one.final[f], two.final[f], err_msg=f)
    assert not any(t.name.startswith("rbx-block") for t in __import__("threading").enumerate())


class _FailingSink(simulate.MemorySink):
    """Fails to write its k-th block (a full disk, say)."""

    def __init__(self, k):
        super().__init__()
        self.k, self.writes = k, 0

    def write(self, block, nrec):
        self.writes += 1
        if self.writes == self.k:
            raise RuntimeError("cannot write")
        super().write(block, nrec)


def test_an_error_while_writing_undoes_the_block_computed_ahead(monkeypatch):
    """A write that fails while the next block is being computed: that block is waited for and undone, so the
    simulation is where it would be without the overlap (at the end of the block that failed to be written),
    and no thread is left behind."""
    from rbx import config
    import threading
    monkeypatch.setattr(simulate, "BLOCK_WORK", 300)
    cfg = config.from_dict(RESUME_SCENES["strip-random-every3"], "<test>")
    states = []
    for ahead in (False, True):
        sim, sink = _run_in_memory(cfg, ahead, monkeypatch, _FailingSink(4))
        assert sink.writes == 4 and len(sink.blocks) == 3          # record 0, two blocks, then the failure
        states.append({k: np.array(v, copy=True) for k, v in sim.final_state().items()})
    for f in states[0]:
        np.testing.assert_array_equal(states[1][f], states[0][f], err_msg=f)
    assert not any(t.name.startswith("rbx-block") for t in threading.enumerate())


@pytest.mark.parametrize("command", ["histogram", "lyapunov", "simulate"])
def test_a_ctrl_c_whose_keyboardinterrupt_was_lost_still_stops_the_command(command, tmp_path):
    """A Ctrl-C early in a command can lose its KeyboardInterrupt (raised inside a callback, Python drops it as
    "Exception ignored"): the command must still see it and stop before its run, not run for hours. The lost
    exception is made here on purpose: the handler notes the signal and the exception is swallowed."""
    cfg = {"table": {"kind": "rectangle", "width": 2, "height": 1}, "ball": {"radius": 0.1},
           "boundary": {"default": {"rule": "constant", "rank": 1}}, "initial": {"sample": "billiard", "wall": "bottom"},
           "run": {"trajectories": 4, "collisions": 10**12}, "output": {"path": "ret.h5"}}
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(cfg))
    args = {"histogram": ["histogram", "c.yaml", "-o", "h.png"], "lyapunov": ["lyapunov", "c.yaml"],
            "simulate": ["simulate", "c.yaml", "-o", "run.h5"]}[command]
    code = ("import sys, rbx.cli.common as common\n"
            "try:\n    common.note_interrupt(2, None)\nexcept KeyboardInterrupt:\n    pass   # lost\n"
            "from rbx.cli.main import main\n"
            f"sys.argv = ['rbx'] + {args!r}\n"
            "main()\n")
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert done.returncode == 130, done.stderr
    line, = done.stderr.strip().splitlines()
    assert line.startswith("rbx: interrupted by SIGINT") and "Traceback" not in done.stderr, done.stderr
    assert not list(tmp_path.glob("*.h5*")) and not (tmp_path / "h.png").exists()


def test_the_terminal_closing_stops_a_run_and_leaves_a_file_to_resume(tmp_path):
    """The terminal a run was started in closes (a window closed, an ssh session lost): the kernel sends SIGHUP. The
    run stops between blocks as after Ctrl-C: its file saved (complete = false), its lock removed, exit 129. The
    child runs in a session of its own on a pseudo-terminal (pty.fork); closing the terminal's other end hangs it
    up, as a closed window does, and the line rbx then writes goes nowhere."""
    import pty
    cfg = strip_random(10**9, trajectories=2, every=1000, record=("time", "position", "wall"))
    write_config(tmp_path, cfg)
    out = tmp_path / "run.h5"
    pid, fd = pty.fork()
    if pid == 0:                                    # the child: rbx on the terminal
        try:
            os.chdir(tmp_path)
            os.execv(RBX, [RBX, "simulate", "exp.yaml", "-o", "run.h5"])
        finally:
            os._exit(127)
    said = b""
    deadline = time.monotonic() + 900       # a guard against a hang, not a bound: a first compile on a busy machine
    os.set_blocking(fd, False)
    while not Path(f"{out}.partial").exists():
        assert time.monotonic() < deadline, said
        assert os.waitpid(pid, os.WNOHANG) == (0, 0), said
        try:
            said += os.read(fd, 65536)          # the progress bar: read, or the terminal's buffer fills
        except (BlockingIOError, OSError):
            time.sleep(0.01)
    time.sleep(1.0)
    os.close(fd)                                # the terminal goes away
    for _ in range(6000):                       # a guard of 60 s: the run stops at its next block
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            break
        time.sleep(0.01)
    else:
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)
        pytest.fail("the run went on after its terminal closed")
    assert os.WIFEXITED(status), f"ended by signal {os.WTERMSIG(status)}: rbx did not handle SIGHUP"
    assert os.WEXITSTATUS(status) == 128 + signal.SIGHUP
    assert out.exists() and not Path(f"{out}.partial").exists()
    assert not Path(f"{out}.lock").exists()
    run = check_valid_partial(out, every=1000)
    assert 0 < run["final/collisions"].min() < 10**9


@pytest.mark.long
def test_under_nohup_the_hangup_is_ignored_and_the_run_goes_on(tmp_path):
    """Started with SIGHUP ignored (``nohup rbx simulate …``), rbx leaves it ignored: a hang-up stops nothing. Sent
    SIGHUP and then SIGTERM, the run is stopped by the SIGTERM and says so (handled, the SIGHUP, the lower number,
    would be acted on first)."""
    cfg = strip_random(10**9, trajectories=2, every=1000, record=("time", "position", "wall"))
    write_config(tmp_path, cfg)
    out = tmp_path / "run.h5"
    proc = subprocess.Popen(["nohup", RBX, "simulate", "exp.yaml", "-o", "run.h5"], cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 900
    while not Path(f"{out}.partial").exists():
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "the run never started writing"
        time.sleep(0.01)
    time.sleep(1.0)                         # past its first blocks
    proc.send_signal(signal.SIGHUP)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert "interrupted by SIGTERM" in err and "SIGHUP" not in err
    check_valid_partial(out, every=1000)
