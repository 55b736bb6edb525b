"""Ensembles on a Dask cluster (docs/reference.md §11): a real ``dask scheduler`` and real ``dask worker`` processes on
127.0.0.1, the real ``rbx`` command in subprocesses, real HDF5 files.

A run on the cluster must write the local run's file — every dataset, bit for bit — whatever the number of
workers and of slices; a worker killed mid-run must cost only its task; Ctrl-C on the client must leave a valid
``.partial`` that ``--resume`` continues (here or on the cluster) to the uninterrupted result; an unreachable
scheduler is one line and exit 2. The workers run in a folder without any config: what they need travels with
the tasks.
"""
import copy
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml

from rbx import runfile
from rbx.cluster import CONNECT_TIMEOUT
from rbx.runfile import PROVENANCE_ATTRS
from tests.catalog import SCENES
from tests.test_interrupt import without_path

pytest.importorskip("distributed")

RBX = str(Path(sys.executable).with_name("rbx"))
ALL = ["time", "position", "velocity", "angular_velocity", "orientation", "wall", "rank"]
#: one kernel thread per process: two workers and a client share this machine's cores
ENV = dict(os.environ, NUMBA_NUM_THREADS="1")


# ---- a cluster on this machine --------------------------------------------------------------------------------

class LocalDask:
    """``dask scheduler`` and ``workers`` × ``dask worker`` (each with its nanny) as subprocesses, bound to
    127.0.0.1 only, started in a folder of their own; :meth:`stop` ends every process it started."""

    def __init__(self, folder, workers):
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.file = self.folder / "scheduler.json"
        self.procs = []
        loopback = ["--host", "127.0.0.1", "--no-dashboard", "--dashboard-address", "127.0.0.1:0"]
        self._start([sys.executable, "-m", "distributed.cli.dask_scheduler", "--port", "0",
                     "--scheduler-file", str(self.file)] + loopback, "scheduler")
        deadline = time.monotonic() + 60
        while not (self.file.exists() and self.file.stat().st_size):
            assert self.procs[0].poll() is None, self.log("scheduler")
            assert time.monotonic() < deadline, "the scheduler did not start"
            time.sleep(0.1)
        time.sleep(0.2)                      # the file is written in one go, but let it be complete
        self.address = json.loads(self.file.read_text())["address"]
        for k in range(workers):
            self._start([sys.executable, "-m", "distributed.cli.dask_worker", self.address, "--nthreads", "1",
                         "--name", f"w{k}", "--local-directory", str(self.folder / f"w{k}")] + loopback, f"w{k}")
        self.wait_for_workers(workers)

    def _start(self, args, name):
        log = open(self.folder / f"{name}.log", "w")
        self.procs.append(subprocess.Popen(args, cwd=self.folder, env=ENV, stdout=log, stderr=subprocess.STDOUT,
                                           start_new_session=True))

    def log(self, name):
        return (self.folder / f"{name}.log").read_text()

    def client(self):
        from distributed import Client
        return Client(self.address, timeout=30, set_as_default=False)

    def wait_for_workers(self, n):
        with self.client() as c:
            c.wait_for_workers(n, timeout=120)

    def worker_pids(self):
        with self.client() as c:
            return c.run(os.getpid)

    def stop(self):
        for p in reversed(self.procs):
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGTERM)
        for p in reversed(self.procs):
            try:
                p.wait(timeout=15)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()


@pytest.fixture(scope="module")
def two(tmp_path_factory):
    """A scheduler with two workers."""
    cluster = LocalDask(tmp_path_factory.mktemp("dask2"), 2)
    yield cluster
    cluster.stop()


@pytest.fixture(scope="module")
def one(tmp_path_factory):
    """A scheduler with one worker."""
    cluster = LocalDask(tmp_path_factory.mktemp("dask1"), 1)
    yield cluster
    cluster.stop()


# ---- runs ---------------------------------------------------------------------------------------------------

def scene(name, collisions, trajectories, every=1, record=ALL, seed=7, **extra):
    cfg = copy.deepcopy(SCENES[name])
    cfg["run"] = {"collisions": collisions, "trajectories": trajectories, "seed": seed}
    cfg["output"] = {"record": list(record), "every": every}
    cfg.update(extra)
    return cfg


def rbx(*args, cwd):
    return subprocess.run([RBX, *map(str, args)], cwd=cwd, env=ENV, capture_output=True, text=True, timeout=600)


def simulate(folder, cfg, out, *options):
    folder = Path(folder)
    (folder / "exp.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False))
    res = rbx("simulate", "exp.yaml", "-o", out, "--quiet", "--force", *options, cwd=folder)
    assert res.returncode == 0, res.stderr
    assert not res.stderr, res.stderr                 # quiet: nothing from Dask either
    return read_run(folder / out)


def read_run(path):
    """Everything a run file holds: root attributes, every dataset of collisions/ and final/ -> dict."""
    with h5py.File(path, "r") as f:
        out = {"attrs": {k: f.attrs[k] for k in f.attrs}}
        for group in ("collisions", "final"):
            for k in f.get(group, {}):
                ds = f[group][k]
                out[f"{group}/{k}"] = ds.asstr()[...].astype(str) if ds.dtype.kind == "O" else ds[...]   # axis names
                # dimension scales by the names attached to each axis (their attributes hold object references:
                # addresses in the file)
                out.update({f"{group}/{k}@{a}": v for a, v in ds.attrs.items()
                            if a not in ("DIMENSION_LIST", "REFERENCE_LIST")})
                out[f"{group}/{k}@dims"] = np.array(str([list(d.keys()) for d in ds.dims]))
    return out


def assert_same(a, b):
    """Bit for bit: every dataset (NaN rows past a trajectory's end included) and every root attribute."""
    assert sorted(a) == sorted(b)
    for k in a:
        if k == "attrs":
            continue
        x, y = np.asarray(a[k]), np.asarray(b[k])
        assert x.shape == y.shape and x.dtype == y.dtype, k
        assert x.tobytes() == y.tobytes(), k          # the same bits, the NaN past a trajectory's end included
    assert sorted(a["attrs"]) == sorted(b["attrs"])
    for k in a["attrs"]:
        x, y = a["attrs"][k], b["attrs"][k]
        if k in PROVENANCE_ATTRS:            # when, where and by which command each file was written
            continue
        if k == "config":                    # each file names itself as output.path
            assert without_path(x) == without_path(y)
            continue
        assert np.array_equal(np.asarray(x), np.asarray(y)), k


#: scenes: a random rule in 2D, a random rule in 3D (orientation matrices, random roughness directions), a
#: trajectory that escapes (a wedge: count and the NaN tails), and an ensemble that records nothing
SCENE_RUNS = {
    "strip-random": scene("strip-random", 3000, 7, every=3),
    "plates-random-3d": scene("plates-random-direction", 2000, 5, every=2),
    # six different starts (six copies of one would be warned about as no ensemble)
    "wedge-escape": scene("wedge-rough", 60, 6, every=1,
                          initial=[{"position": [1.0, 0.3], "velocity": [-1.0, 0.2 + 0.01 * k], "angular_velocity": 0.0}
                                   for k in range(6)]),
    "rectangle-random-final-only": scene("rectangle-random", 5000, 40, record=[]),
}
#: (cluster, options): the default cut; few slices of many rounds (the scheduler named by its file); as many slices
#: as trajectories; one worker
CUTS = {
    "two-workers-default": ("two", ()),
    "two-workers-3-slices-many-rounds": ("two", ("--slices", 3, "--task-collisions", 1500)),
    "two-workers-one-slice-per-trajectory": ("two", ("--slices", 1000, "--task-collisions", 800)),
    "one-worker-2-slices": ("one", ("--slices", 2, "--task-collisions", 4000)),
}


@pytest.fixture(scope="module")
def local_runs(tmp_path_factory):
    """The local run of each scene, once."""
    runs = {}

    def get(name):
        if name not in runs:
            runs[name] = simulate(tmp_path_factory.mktemp(f"local-{name}"), SCENE_RUNS[name], "local.h5")
        return runs[name]
    return get


#: every cut on the 2D random scene, two on the 3D one, one on each of the others (the test's time)
PAIRS = [("strip-random", cut) for cut in CUTS] + [
    ("plates-random-3d", "two-workers-3-slices-many-rounds"), ("plates-random-3d", "one-worker-2-slices"),
    ("wedge-escape", "two-workers-3-slices-many-rounds"), ("rectangle-random-final-only", "one-worker-2-slices")]


@pytest.mark.long
@pytest.mark.parametrize("name, cut", PAIRS, ids=[f"{n}-{c}" for n, c in PAIRS])
def test_a_cluster_run_is_the_local_run_bit_for_bit(name, cut, local_runs, request, tmp_path):
    which, options = CUTS[cut]
    cluster = request.getfixturevalue(which)
    local = local_runs(name)          # first: its kernel goes to the disk cache, where the workers find it
    address = cluster.file if cut == "two-workers-3-slices-many-rounds" else cluster.address
    run = simulate(tmp_path, SCENE_RUNS[name], "cluster.h5", "--scheduler", address, *options)
    assert run["attrs"]["complete"]
    assert_same(run, local)
    if name == "wedge-escape":                    # the scene does what it is here for: trajectories end early
        assert run["collisions/count"].min() < run["collisions/count"].max() or not run["final/alive"].any()
        assert not run["final/alive"].any()


@pytest.mark.long
def test_workers_load_the_kernels_from_the_disk_cache(two, tmp_path):
    """A local run compiles the scene's kernel into the disk cache; the workers load it from there (a Numba
    cache hit) and compile nothing."""
    simulate(tmp_path, SCENE_RUNS["strip-random"], "local.h5")       # now: the kernel sources of this moment
    simulate(tmp_path, SCENE_RUNS["strip-random"], "cluster.h5", "--scheduler", two.address, "--slices", 4)

    def kernel_cache():
        import sys

        engine = sys.modules.get("rbx.engine")
        if engine is None:                   # a worker that ran no task yet
            return None
        kernels = list(engine._KERNELS.values())
        hits = sum(sum(k.stats.cache_hits.values()) for k in kernels)
        return hits, sum(len(k.stats.cache_misses) for k in kernels)

    with two.client() as c:
        seen = [v for v in c.run(kernel_cache).values() if v is not None]
    assert seen and all(hits >= 1 and compiled == 0 for hits, compiled in seen), seen


@pytest.mark.long
def test_the_api_on_a_local_cluster_and_on_an_address(two, tmp_path):
    """rbx.simulate(..., scheduler=): a distributed.Client of a LocalCluster (worker processes), in memory; an
    address, into a file. Both are the local run, bit for bit."""
    import rbx
    from distributed import Client, LocalCluster

    cfg = SCENE_RUNS["plates-random-3d"]
    local = rbx.simulate(cfg)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None) as lc, Client(lc, set_as_default=False) as client:
        in_memory = rbx.simulate(cfg, scheduler=client, slices=3, task_collisions=2000)
        assert client.status == "running"                  # a client given is the caller's: left open
    on_file = rbx.simulate(cfg, scheduler=two.address, output=tmp_path / "api.h5", slices=2)
    for run in (in_memory, on_file):
        assert run.complete
        for f in local.fields + ("count", "step"):
            assert getattr(run, f).tobytes() == getattr(local, f).tobytes(), f
        assert sorted(run.final) == sorted(local.final)
        for k in local.final:
            assert run.final[k].tobytes() == local.final[k].tobytes(), k


@pytest.mark.long
def test_histogram_on_the_cluster_is_the_local_histogram(two, tmp_path):
    cfg = {"table": {"kind": "rectangle", "width": 2.0, "height": 1.0}, "ball": {"radius": 0.1},
           "boundary": {"default": {"rule": "random", "choices": [{"rule": "constant", "rank": 0},
                                                                   {"rule": "constant", "rank": 1}],
                                    "probabilities": [0.5, 0.5]}},
           "initial": {"sample": "billiard", "wall": "bottom"},
           "run": {"collisions": 500, "trajectories": 1000, "seed": 3}, "output": {"path": "h.h5"}}
    (tmp_path / "h.yaml").write_text(yaml.safe_dump(cfg))
    angles = {}
    for label, options in (("local", ()), ("cluster", ("--scheduler", two.address, "--slices", 5))):
        res = rbx("histogram", "h.yaml", "-o", f"{label}.png", "--force", "--quiet", *options, cwd=tmp_path)
        assert res.returncode == 0, res.stderr
        with h5py.File(tmp_path / "h.h5") as f:
            angles[label] = {k: f["returns"][k][...] for k in f["returns"]}
    assert len(angles["local"]["angle"]) > 600
    for k, v in angles["local"].items():
        assert np.array_equal(v, angles["cluster"][k]), k


# ---- faults ---------------------------------------------------------------------------------------------------

#: long enough to be interrupted: 4 trajectories × 4·10⁶ collisions in rounds of 2·10⁵ (tasks of ~10 ms)
#: long enough that a signal or a kill 1 s after the run starts writing lands in the middle of it (4·10⁶ collisions
#: each ended within 0.9 s once the start-up got faster, and a Ctrl-C came during the exit)
LONG_EVERY = 40_000
LONG = scene("strip-random", 16_000_000, 4, every=LONG_EVERY)
LONG_CUT = ("--slices", 4, "--task-collisions", 200_000)


@pytest.fixture(scope="module")
def long_local(tmp_path_factory):
    return simulate(tmp_path_factory.mktemp("long-local"), LONG, "local.h5")


def start(args, cwd, partial):
    """Start ``args`` and wait until it writes ``partial`` -> the process."""
    proc = subprocess.Popen([RBX, *map(str, args)], cwd=cwd, env=ENV, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not os.path.exists(partial):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "the run never started writing"
        time.sleep(0.01)
    return proc


@pytest.mark.long
def test_sigint_leaves_a_partial_that_resumes_locally_and_on_the_cluster(two, long_local, tmp_path):
    (tmp_path / "exp.yaml").write_text(yaml.safe_dump(LONG, sort_keys=False))
    proc = start(["simulate", "exp.yaml", "-o", "run.h5", "--scheduler", two.address, *LONG_CUT], tmp_path,
                 tmp_path / "run.h5.partial")
    time.sleep(1.0)
    assert proc.poll() is None, "the run ended before the signal: make it longer"
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("rbx: run.h5: interrupted by SIGINT"), err
    assert "--resume run.h5" in lines[0]

    cut = read_run(tmp_path / "run.h5")
    assert not cut["attrs"]["complete"]
    made = cut["final/collisions"]
    assert 0 < made.min() and made.max() < LONG["run"]["collisions"]
    assert len(set(made.tolist())) == 1                     # a checkpoint: every trajectory at the same collision
    np.testing.assert_array_equal(cut["collisions/count"], 1 + made // LONG_EVERY)
    assert len(cut["collisions/step"]) == cut["collisions/count"].max()
    length = len(cut["collisions/step"])
    for f in LONG["output"]["record"]:                      # the records so far are the local run's
        assert cut[f"collisions/{f}"].tobytes() == long_local[f"collisions/{f}"][:, :length].tobytes(), f

    for label, options in (("here", ()), ("cluster", ("--scheduler", two.address, "--slices", 3))):
        res = rbx("simulate", "--resume", "run.h5", "-o", f"{label}.h5", "--quiet", *options, cwd=tmp_path)
        assert res.returncode == 0, res.stderr
        assert_same(read_run(tmp_path / f"{label}.h5"), long_local)


@pytest.mark.long
def test_a_worker_killed_mid_run_costs_only_its_task(two, long_local, tmp_path):
    two.wait_for_workers(2)
    (tmp_path / "exp.yaml").write_text(yaml.safe_dump(LONG, sort_keys=False))
    address, victim = sorted(two.worker_pids().items())[0]
    proc = start(["simulate", "exp.yaml", "-o", "run.h5", "--scheduler", two.address, *LONG_CUT], tmp_path,
                 tmp_path / "run.h5.partial")
    time.sleep(0.5)
    assert proc.poll() is None, "the run ended before the kill: make it longer"
    os.kill(victim, signal.SIGKILL)
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    assert_same(read_run(tmp_path / "run.h5"), long_local)
    assert f"Remove worker addr: {address}" in two.log("scheduler")   # the scheduler did lose it mid-run
    two.wait_for_workers(2)                                 # its nanny starts it again, for the next tests


@pytest.mark.long
def test_ctrl_c_stops_a_run_whose_cluster_lost_every_worker(tmp_path):
    """With its only worker killed mid-run, a result the run was fetching waited for a worker to come back and
    SIGINT or SIGTERM went unheard (45 s and more); the fetch is asked in turns now, and Ctrl-C stops the run with
    its one line, the records so far kept."""
    dask = LocalDask(tmp_path / "dask", 1)
    try:
        # rounds of records large enough that the worker is often killed while a finished result is fetched; the
        # run far longer than the test waits, and its estimate (3.7 GB) well within a CI disk's free room (at 2·10⁸
        # collisions it was 12.3 GB, refused where less was free)
        cfg = scene("strip-random", 6 * 10**7, 4, every=3, record=["time", "position", "velocity", "wall"])
        (tmp_path / "exp.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False))
        proc = start(["simulate", "exp.yaml", "-o", "run.h5", "--quiet", "--max-size", "20GB", "--scheduler",
                      dask.address], tmp_path, tmp_path / "run.h5.partial")
        time.sleep(4.0)
        assert proc.poll() is None, "the run ended before its worker was killed"
        os.killpg(dask.procs[1].pid, signal.SIGKILL)          # the worker and its nanny: no worker is left
        deadline = time.monotonic() + 60
        while "Lost all workers" not in dask.log("scheduler") and time.monotonic() < deadline:
            time.sleep(0.1)
        time.sleep(1.0)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
        dask.stop()
    assert proc.returncode == 130, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("rbx: run.h5: interrupted by SIGINT after ") and "rbx simulate --resume run.h5" in err
    assert not read_run(tmp_path / "run.h5")["attrs"]["complete"]


@pytest.mark.long
def test_a_scheduler_lost_mid_run_is_one_line_exit_1_and_a_resumable_file(tmp_path):
    dask = LocalDask(tmp_path / "dask", 1)
    try:
        cfg = scene("strip-random", 10**9, 2, every=10**6, record=["time", "position"])
        (tmp_path / "exp.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False))
        proc = start(["simulate", "exp.yaml", "-o", "run.h5", "--quiet", "--scheduler", dask.address,
                      "--task-collisions", 4_000_000], tmp_path, tmp_path / "run.h5.partial")
        time.sleep(3.0)
        assert proc.poll() is None, "the run ended before the scheduler was killed"
        os.killpg(dask.procs[0].pid, signal.SIGKILL)
        out, err = proc.communicate(timeout=120)
    finally:
        dask.stop()
    assert proc.returncode == 1, err
    line, = err.strip().splitlines()
    assert line.startswith("rbx: run.h5: --scheduler: the run's tasks were cancelled: the scheduler is gone")
    assert "rbx simulate --resume run.h5" in line
    run = read_run(tmp_path / "run.h5")
    assert not run["attrs"]["complete"]
    # consistent, so resumable: the records that the newest verified saved state accounts for (it may be in any
    # slot: a run stopped by a lost scheduler is not settled; rbx.runfile.latest_state), or, before the first
    # checkpoint (the scheduler killed early on a loaded machine), at most the initial records, which a resume writes
    with h5py.File(tmp_path / "run.h5", "r") as f:
        state, _, verified = runfile.latest_state(f)
    assert verified
    if state:
        np.testing.assert_array_equal(run["collisions/count"], 1 + state["collisions"] // 10**6)
    else:
        count = run["collisions/count"]
        assert set(count.tolist()) in ({0}, {1}), count
    assert len(run["collisions/step"]) == run["collisions/count"].max()


@pytest.mark.long
@pytest.mark.parametrize("command", ["simulate", "lyapunov"])
@pytest.mark.parametrize("frozen", ["scheduler", "worker"])
def test_a_scheduler_or_worker_that_stops_answering_mid_run_is_one_line_exit_1(command, frozen, tmp_path):
    """A scheduler frozen mid-run (SIGSTOP: its connections stay open, nothing comes back) held `rbx simulate
    --scheduler` and `rbx lyapunov --scheduler` for ever, without a line; so did a frozen worker, the scheduler
    answering. While no task finishes, the run now asks the scheduler every HEARTBEAT seconds whether it answers,
    and stops once it has not for SILENCE seconds (here made 1 and 3 s), or once its answers have said for that
    long that no worker sent it a heartbeat: one line, exit 1, and `simulate` leaves a file that resumes."""
    dask = LocalDask(tmp_path / "dask", 1)
    target = dask.procs[0 if frozen == "scheduler" else 1]
    prelude = "import rbx.cluster as _c\n_c.HEARTBEAT = 1.0\n_c.SILENCE = 3.0\n"
    if command == "simulate":
        cfg = scene("strip-random", 10**9, 2, every=10**6, record=["time", "position"])
        args = ["simulate", "exp.yaml", "-o", "run.h5", "--quiet", "--task-collisions", "4000000"]
    else:
        cfg = dict(LYAPUNOV, run={"collisions": 10**9, "trajectories": 2, "seed": 1})
        args = ["lyapunov", "exp.yaml", "--quiet", "--slices", "2"]
    (tmp_path / "exp.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False))
    code = f"import sys\n{prelude}from rbx.cli.main import main\nsys.argv[0] = 'rbx'\nmain()\n"
    try:
        proc = subprocess.Popen([sys.executable, "-c", code, *args, "--scheduler", dask.address], cwd=tmp_path,
                                env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        with dask.client() as c:           # the run's tasks are on the worker: the run is under way
            deadline = time.monotonic() + 300
            while not any(c.processing().values()):
                assert proc.poll() is None, proc.communicate()
                assert time.monotonic() < deadline, "no task ever ran"
                time.sleep(0.05)
        os.killpg(target.pid, signal.SIGSTOP)
        out, err = proc.communicate(timeout=300)
    finally:
        os.killpg(target.pid, signal.SIGCONT)
        dask.stop()
    assert proc.returncode == 1, err
    line, = err.strip().splitlines()
    said = ("--scheduler: the scheduler stopped answering (no reply for " if frozen == "scheduler" else
            "--scheduler: none of its 1 worker(s) has sent the scheduler a heartbeat for ")
    assert said in line, line
    if command == "simulate":
        assert line.startswith("rbx: run.h5: ") and "rbx simulate --resume run.h5" in line, line
        with h5py.File(tmp_path / "run.h5", "r") as f:
            assert not f.attrs["complete"]


@pytest.mark.long
def test_a_scheduler_frozen_while_a_study_measures_return_paths_is_one_line_exit_1(tmp_path):
    """`rbx sweep --scheduler` of a study measuring return paths waited without a line when the scheduler froze:
    each point's connection asks the workers who they are, a request Dask waits for without end. It is now waited
    for as a task is (HEARTBEAT, SILENCE: here 1 and 3 s): one line, exit 1, and the finished points are kept."""
    dask = LocalDask(tmp_path / "dask", 1)
    (tmp_path / "table.yaml").write_text(yaml.safe_dump(
        {"table": {"kind": "rectangle", "width": 2.0, "height": 1.0},
         "boundary": {"default": {"rule": "constant", "rank": 1}, "walls": {"left": {"rule": "exit"}}},
         "ball": {"radius": 0.1, "inertia": 0.5}, "initial": {"sample": "billiard", "wall": "left"},
         "run": {"collisions": 100, "trajectories": 10}, "output": {"record": []}}, sort_keys=False))
    (tmp_path / "study.yaml").write_text(yaml.safe_dump(
        {"base": "table.yaml", "vary": {"ball.inertia": [0.1, 0.2, 0.3, 0.4, 0.5, 0.6]},
         "measure": ["return_path"], "ensemble": {"trajectories": 4000, "collisions": 10_000, "seed": 3}},
        sort_keys=False))
    prelude = "import rbx.cluster as _c\n_c.HEARTBEAT = 1.0\n_c.SILENCE = 3.0\n"
    code = f"import sys\n{prelude}from rbx.cli.main import main\nsys.argv[0] = 'rbx'\nmain()\n"
    try:
        proc = subprocess.Popen([sys.executable, "-c", code, "sweep", "study.yaml", "-o", "study.nc", "--quiet",
                                 "--scheduler", dask.address], cwd=tmp_path, env=ENV, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
        with dask.client() as c:           # the study's first task has reached the scheduler
            deadline = time.monotonic() + 300
            while c.run_on_scheduler(lambda dask_scheduler: dask_scheduler.transition_counter) == 0:
                assert proc.poll() is None, proc.communicate()
                assert time.monotonic() < deadline, "no task ever ran"
                time.sleep(0.05)
        os.killpg(dask.procs[0].pid, signal.SIGSTOP)
        out, err = proc.communicate(timeout=120)
    finally:
        os.killpg(dask.procs[0].pid, signal.SIGCONT)
        dask.stop()
    assert proc.returncode == 1, err
    line, = err.strip().splitlines()
    assert "scheduler: the scheduler stopped answering (no reply for " in line, line


@pytest.mark.long
@pytest.mark.parametrize("frozen", ["scheduler", "worker"])
def test_asking_a_frozen_cluster_who_the_workers_are_is_bounded(tmp_path, monkeypatch, frozen):
    """Each point of a study connects again (`connect(client)`), which asks the workers who they are, and a run
    asks how many threads they have: requests that Dask waits for without end, which held `rbx sweep --scheduler`
    silent when the scheduler froze between two points, and `rbx histogram --scheduler` (and every command) when a
    worker was frozen before the run began. They are waited for as a task is now; connecting says it in the line of
    a scheduler that cannot be used (`rbx histogram` printed a traceback)."""
    import rbx.cluster as cluster
    monkeypatch.setattr(cluster, "HEARTBEAT", 1.0)
    monkeypatch.setattr(cluster, "SILENCE", 3.0)
    dask = LocalDask(tmp_path / "dask", 1)
    target = dask.procs[0 if frozen == "scheduler" else 1]
    said = "the scheduler stopped answering" if frozen == "scheduler" else \
        "none of its 1 worker.s. has sent the scheduler a heartbeat"
    try:
        with dask.client() as client:
            on = cluster.connect(client)           # answered: the scheduler runs
            assert on.threads() == 1
            os.killpg(target.pid, signal.SIGSTOP)
            began = time.monotonic()
            with pytest.raises(cluster.ClusterError, match=said):
                on.check_workers()
            with pytest.raises(cluster.SchedulerUnreachable, match=said):
                cluster.connect(client)
            if frozen == "scheduler":
                with pytest.raises(cluster.ClusterError, match=said):
                    on.threads()
            assert time.monotonic() - began < 60
            os.killpg(target.pid, signal.SIGCONT)
    finally:
        os.killpg(target.pid, signal.SIGCONT)
        dask.stop()


# ---- errors ---------------------------------------------------------------------------------------------------

def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.long
@pytest.mark.parametrize("address", ["tcp://127.0.0.1:{port}", "127.0.0.1:{port}", "nonsense://where",
                                     "scheduler.json", "tls://127.0.0.1:{port}", "inproc://x", "fifo", "folder",
                                     "number.json", "name.json"])
def test_an_unreachable_scheduler_is_one_line_and_exit_2(address, tmp_path):
    """Each a line saying what is wrong; a FIFO or a folder named as the scheduler file was said to have 'no port
    in the address'."""
    port = free_port()
    address = address.format(port=port)
    if address == "scheduler.json":     # the file of a scheduler that is gone
        (tmp_path / address).write_text(json.dumps({"type": "Scheduler", "address": f"tcp://127.0.0.1:{port}"}))
    if address in ("number.json", "name.json"):   # said as "no 'address'", and as the protocol "s1.json://"
        (tmp_path / address).write_text(json.dumps({"address": 12345 if address == "number.json" else "s1.json"}))
    if address == "fifo":
        os.mkfifo(tmp_path / address)
    if address == "folder":
        (tmp_path / address).mkdir()
    (tmp_path / "exp.yaml").write_text(yaml.safe_dump(SCENE_RUNS["strip-random"]))
    res = rbx("simulate", "exp.yaml", "-o", "run.h5", "--scheduler", address, cwd=tmp_path)
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("rbx: --scheduler: "), res.stderr
    if address.startswith(("nonsense", "tls", "inproc")):
        # tls:// was said to have "answered, but not as a Dask scheduler", inproc://x "not enough values to unpack"
        assert "rbx connects to a scheduler over tcp://" in lines[0], lines[0]
    elif address in ("fifo", "folder"):
        what = "a FIFO (named pipe)" if address == "fifo" else "a directory"
        assert lines[0] == f"rbx: --scheduler: {address} is {what}, not a scheduler file (give tcp://HOST:PORT, or " \
                           "the file dask scheduler --scheduler-file wrote)", lines[0]
    elif address in ("number.json", "name.json"):
        value = "'12345'" if address == "number.json" else "'s1.json'"
        assert lines[0] == f"rbx: --scheduler: {address}: not a Dask scheduler file (its 'address' is {value}, not " \
                           "an address such as tcp://HOST:PORT)", lines[0]
    else:
        assert "cannot reach a Dask scheduler" in lines[0] and "Connection refused" in lines[0]
    assert not list(tmp_path.glob("run.h5*"))                # nothing written


@pytest.mark.long
def test_a_port_that_accepts_and_never_answers_or_does_not_exist_is_one_line(tmp_path):
    """``--scheduler`` naming a port where something accepts connections and never answers held ``rbx simulate``
    for over ten minutes with no line (Dask's handshake waited for ever); a port of 99999 was 'Connection
    refused'. Both are one line and exit 2, the first within the connection timeout."""
    import threading
    silent = socket.socket()
    silent.bind(("127.0.0.1", 0))
    silent.listen(8)
    held = []
    taking = threading.Thread(target=lambda: [held.append(silent.accept()) for _ in range(8)], daemon=True)
    taking.start()
    (tmp_path / "exp.yaml").write_text(yaml.safe_dump(SCENE_RUNS["strip-random"]))
    try:
        for command in (("simulate", "exp.yaml", "-o", "run.h5"), ("sweep", "study.yaml", "-o", "s.nc")):
            if command[0] == "sweep":
                (tmp_path / "study.yaml").write_text(yaml.safe_dump(
                    {"base": "exp.yaml", "vary": {"ball.inertia": [0.2, 0.4]}, "measure": ["mean_free_path"],
                     "ensemble": {"trajectories": 2, "collisions": 100}}))
            res = rbx(*command, "--scheduler", f"tcp://127.0.0.1:{silent.getsockname()[1]}", cwd=tmp_path)
            lines = res.stderr.strip().splitlines()
            assert res.returncode == 2 and len(lines) == 1, res.stderr
            assert lines[0].startswith("rbx: --scheduler: cannot reach a Dask scheduler") and \
                f"no answer within {CONNECT_TIMEOUT:g} s" in lines[0], lines[0]
    finally:
        silent.close()
    res = rbx("simulate", "exp.yaml", "-o", "run.h5", "--scheduler", "tcp://127.0.0.1:99999", cwd=tmp_path)
    assert res.returncode == 2 and res.stderr == ("rbx: --scheduler: tcp://127.0.0.1:99999: port 99999 does not exist "
                                                  "(ports are 1 … 65535)\n"), res.stderr
    assert not list(tmp_path.glob("run.h5*")) and not list(tmp_path.glob("s.nc*"))


def test_cluster_options_need_a_scheduler(tmp_path):
    (tmp_path / "exp.yaml").write_text(yaml.safe_dump(SCENE_RUNS["strip-random"]))
    res = rbx("simulate", "exp.yaml", "-o", "run.h5", "--slices", "3", cwd=tmp_path)
    assert res.returncode == 2
    assert res.stderr.strip() == "rbx: --slices: only with --scheduler (it cuts a run into tasks for a Dask cluster)"


# ---- rbx lyapunov on the cluster ---------------------------------------------------------------------------------

#: a chaotic scene (λ₁ > 0): the rough Sinai table, 4 trajectories × 2000 collisions from the billiard measure
LYAPUNOV = {"table": {"kind": "sinai", "size": [2.0, 1.5], "radius": 0.4},
            "boundary": {"default": {"rule": "constant", "rank": 1}}, "ball": {"radius": 0.1, "inertia": "uniform"},
            "initial": {"sample": "billiard"}, "run": {"collisions": 2000, "trajectories": 4, "seed": 1}}


def lyapunov_json(folder, *options, cfg=LYAPUNOV):
    (Path(folder) / "lyap.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False))
    res = rbx("lyapunov", "lyap.yaml", "--json", "--segments", 5, *options, cwd=folder)
    assert res.returncode == 0, res.stderr
    assert not res.stderr, res.stderr                 # nothing from Dask either
    return json.loads(res.stdout)


@pytest.fixture(scope="module")
def local_lyapunov(tmp_path_factory):
    return lyapunov_json(tmp_path_factory.mktemp("lyap-local"))


def tasks_seen(cluster):
    """Workers of ``cluster`` that ran a Lyapunov task (imported rbx.dynamics, which nothing else imports there)."""
    with cluster.client() as c:
        return sum(c.run(lambda: "rbx.dynamics" in sys.modules).values())


@pytest.mark.long
@pytest.mark.parametrize("which, slices", [("one", None), ("two", 2), ("two", 3)])
def test_lyapunov_on_the_cluster_is_the_local_spectrum_bit_for_bit(which, slices, local_lyapunov, request, tmp_path):
    cluster = request.getfixturevalue(which)
    options = ("--scheduler", cluster.address) + (("--slices", slices) if slices else ())
    on = lyapunov_json(tmp_path, *options)
    assert local_lyapunov["exponents"][0] > 0.05 and local_lyapunov["trajectories"] == 4   # a chaotic ensemble
    assert on["exponents"] == local_lyapunov["exponents"]          # JSON floats round-trip: the same bits
    assert on["stderr"] == local_lyapunov["stderr"]
    assert on == local_lyapunov
    assert tasks_seen(cluster) >= 1                                # the workers did run it


@pytest.mark.heavy
def test_lyapunov_survives_a_worker_killed_mid_run(two, tmp_path):
    """4 slices of 1 trajectory × 5·10⁶ collisions (~1 s each: 2·10⁵ took ~0.03 s once the tangent loop ran at
    ~0.13 µs a collision, and could end before the kill): a worker SIGKILLed while it runs one; Dask runs that
    slice again and the spectrum is still the local one, bit for bit."""
    cfg = dict(LYAPUNOV, run={"collisions": 5_000_000, "trajectories": 4, "seed": 2})
    local = lyapunov_json(tmp_path, cfg=cfg)
    two.wait_for_workers(2)
    pids = two.worker_pids()
    removed = two.log("scheduler").count("Remove worker addr: ")
    (tmp_path / "lyap.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False))
    proc = subprocess.Popen([RBX, "lyapunov", "lyap.yaml", "--json", "--segments", "5", "--scheduler", two.address,
                             "--slices", "4"], cwd=tmp_path, env=ENV, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    victim = None
    deadline = time.monotonic() + 120

    def busy(c):
        return [w for w, keys in c.processing().items() if any(str(k).startswith("rbx-lyapunov") for k in keys)]
    with two.client() as c:
        while victim is None:
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "no Lyapunov task ever ran"
            found = busy(c)
            if found:
                time.sleep(0.3)                            # into the task's work, and still at it
                victim = found[0] if found[0] in busy(c) else None
            else:
                time.sleep(0.05)
        os.kill(pids[victim], signal.SIGKILL)
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    assert json.loads(out) == local
    # lost mid-run: the scheduler says so in its log, which it may write after the client has its answer
    def lost(log):
        return f"Remove worker addr: {victim}" in log and log.count("Remove worker addr: ") > removed
    deadline = time.monotonic() + 60
    while not lost(two.log("scheduler")) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert lost(two.log("scheduler")), two.log("scheduler")[-2000:]
    two.wait_for_workers(2)                                 # its nanny starts it again, for the next tests


def test_lyapunov_unreachable_scheduler_is_one_line_and_exit_2(tmp_path):
    (tmp_path / "lyap.yaml").write_text(yaml.safe_dump(LYAPUNOV))
    res = rbx("lyapunov", "lyap.yaml", "--json", "--scheduler", f"tcp://127.0.0.1:{free_port()}", cwd=tmp_path)
    assert res.returncode == 2, res.stderr
    assert not res.stdout
    line, = res.stderr.strip().splitlines()
    assert line.startswith("rbx: --scheduler: cannot reach a Dask scheduler") and "Connection refused" in line


def test_lyapunov_slices_need_a_scheduler(tmp_path):
    (tmp_path / "lyap.yaml").write_text(yaml.safe_dump(LYAPUNOV))
    res = rbx("lyapunov", "lyap.yaml", "--json", "--slices", "2", cwd=tmp_path)
    assert res.returncode == 2 and not res.stdout
    assert res.stderr.strip() == "rbx: --slices: only with --scheduler (it cuts a run into tasks for a Dask cluster)"


DIES_WHEN_ASKED = """
import os
import rbx.cluster


def _die():
    os.kill(os.getpid(), 9)      # SIGKILLed while it answers the client's question


rbx.cluster._worker_identity = _die
"""


@pytest.mark.heavy
def test_a_worker_killed_while_the_client_checks_the_workers_is_left_out_not_taken_for_a_missing_install(tmp_path):
    """A worker SIGKILLed about 3 s after the client started gave 'the workers cannot run rbx (… Stream is
    closed); install this rbx (0.1.0) where they run', exit 2 (1 of 11 tries): the client asks every worker for
    its rbx and kernels before the run, and one lost meanwhile failed the question. Here a worker (without a
    nanny: it stays dead) is killed exactly when asked; the run goes on with the other worker, and its file is
    the local run's, bit for bit, in the local run's layout (final/ alone, however many checkpoints)."""
    cfg = scene("strip-random", 3000, 3, every=3)
    local = simulate(tmp_path, cfg, "local.h5")
    cluster = LocalDask(tmp_path / "dask", 1)
    try:
        (tmp_path / "dies.py").write_text(DIES_WHEN_ASKED)
        cluster._start([sys.executable, "-m", "distributed.cli.dask_worker", cluster.address, "--nthreads", "1",
                        "--name", "dies", "--no-nanny", "--preload", str(tmp_path / "dies.py"),
                        "--local-directory", str(cluster.folder / "dies"), "--host", "127.0.0.1",
                        "--no-dashboard", "--dashboard-address", "127.0.0.1:0"], "dies")
        cluster.wait_for_workers(2)
        doomed = cluster.procs[-1]
        remote = simulate(tmp_path, cfg, "remote.h5", "--scheduler", cluster.address)
        assert doomed.wait(timeout=60) == -signal.SIGKILL      # it was asked, and died
    finally:
        cluster.stop()
    assert_same(remote, local)
    with h5py.File(tmp_path / "remote.h5") as f:
        assert sorted(f) == ["collisions", "final"]


@pytest.mark.long
def test_a_scheduler_lost_mid_study_is_one_line_exit_1_and_how_to_continue(tmp_path):
    """rbx sweep --scheduler with the scheduler killed after the first point was written: it said "no worker
    answered … the workers were lost; start them again" (exit 2, a user error), after Dask's own ERROR line; as
    rbx simulate says it: one line naming the lost scheduler, what the results file keeps and the --resume line,
    exit 1."""
    sinai = str(Path(__file__).resolve().parents[1] / "configs" / "examples" / "sinai.yaml")
    study = {"base": sinai, "vary": {"ball.inertia": [0.3, 0.6, 0.9]}, "measure": ["lyapunov"],
             "ensemble": {"trajectories": 2, "collisions": 3_000_000, "seed": 2}}
    (tmp_path / "study.yaml").write_text(yaml.safe_dump(study, sort_keys=False))
    dask = LocalDask(tmp_path / "dask", 1)
    try:
        # the first write comes once the points took about a second, and leaves a point to run
        proc = start(["sweep", "study.yaml", "-o", "out.nc", "--quiet", "--trajectories", 2, "--scheduler",
                      dask.address], tmp_path, tmp_path / "out.nc.partial")
        assert proc.poll() is None, "the study ended before the scheduler was killed"
        os.killpg(dask.procs[0].pid, signal.SIGKILL)
        dask.procs[0].wait()
        _, err = proc.communicate(timeout=300)
    finally:
        dask.stop()
    assert proc.returncode == 1, err
    line, = err.strip().splitlines()
    assert line.startswith("rbx: out.nc.partial: --scheduler: ") and "the scheduler is gone" in line, line
    assert line.endswith("Continue with: rbx sweep study.yaml -o out.nc --trajectories 2 --resume (with "
                         "--scheduler, or locally)"), line
    import xarray as xr
    with xr.open_dataset(tmp_path / "out.nc.partial") as ds:
        kept = int(ds["done"].sum())
    assert 1 <= kept < 3 and f"the file holds the {kept} of 3 points finished before" in line, line


def test_a_task_submitted_to_a_client_its_scheduler_closed_is_a_lost_cluster_not_a_traceback():
    """The scheduler killed while rbx histogram --scheduler ran: Dask closed the client, and the next task's submit
    raised ClosedClientError, a traceback (2 of 3 tries). Now the ClusterError of a lost scheduler (one line, exit
    1). A real client on a real (in-process) scheduler, closed."""
    from distributed import Client, LocalCluster

    from rbx.cluster import Cluster, ClusterError
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as local:
        client = Client(local, set_as_default=False)
        cluster = Cluster(client)
        assert cluster._submit(abs, -2, pure=False).result(timeout=60) == 2
        client.close()
        with pytest.raises(ClusterError, match=r"^--scheduler: the scheduler is gone \(shut down, or the network"):
            cluster._submit(abs, -3, pure=False)


def test_a_frozen_worker_is_said_silence_after_the_last_answer_that_had_news(monkeypatch):
    """The scheduler is asked every HEARTBEAT (30 s) who its workers are; a worker frozen just after an answer was
    counted quiet only from the first answer without news, so the run stopped SILENCE + 2 HEARTBEAT after the
    freeze (124 s measured, where docs/cluster.md says at most 90 s). Quiet is now counted from the last answer
    that had news: no heartbeat came after it. A clock of the test's, answers made by hand."""
    import types
    from rbx import cluster
    clock = [0.0]
    monkeypatch.setattr(cluster, "time", types.SimpleNamespace(monotonic=lambda: clock[0]))
    c = cluster.Cluster(None)

    def answer(at, last_seen):
        clock[0] = at
        c._check_worker_news({"workers": {"tcp://w:1": {"last_seen": last_seen}}}, at)
    answer(30.0, 1000.0)                # the worker beat at 1000 (the scheduler's clock), then froze
    answer(60.0, 1000.0)                # quiet for 30 s at least
    with pytest.raises(cluster.ClusterError, match=r"none of its 1 worker\(s\) has sent the scheduler a heartbeat "
                                                   r"for 60 s"):
        answer(90.0, 1000.0)            # 60 s after the last answer with news: SILENCE, said now (not at 120 s)
    c = cluster.Cluster(None)
    answer(30.0, 1000.0)
    answer(60.0, 1030.0)                # news: the worker is alive
    answer(90.0, 1030.0)
    c._heard_from()                     # a task finished: alive after that answer too
    answer(120.0, 1030.0)               # quiet counted from this answer, not the one at 60 s
    answer(150.0, 1030.0)
    with pytest.raises(cluster.ClusterError):
        answer(180.0, 1030.0)


def test_a_result_whose_fetch_times_out_watches_the_scheduler(monkeypatch):
    """A task finished, its result fetched while the scheduler was frozen: each fetch timed out and was tried again
    without asking whether the scheduler still answers, and `rbx histogram --scheduler` gave no line for 150–200 s
    (then SIGTERM). The retry now watches the scheduler as a wait for a task does: silence for SILENCE seconds,
    counted from its last answer, is one ClusterError. A clock of the test's; no Dask."""
    import types
    from rbx import cluster
    clock = [0.0]
    monkeypatch.setattr(cluster, "time", types.SimpleNamespace(monotonic=lambda: clock[0], sleep=lambda s: None))
    monkeypatch.setattr(cluster, "_probe", lambda address, timeout: (_ for _ in ()).throw(OSError("frozen")))
    monkeypatch.setattr(cluster, "_in_background", lambda call, name: (types.SimpleNamespace(
        join=lambda timeout: None), [(False, None)]))
    client = types.SimpleNamespace(scheduler=types.SimpleNamespace(address="tcp://127.0.0.1:1"))
    c = cluster.Cluster(client)
    fetches = []

    class Finished:
        def done(self):
            return True

        def result(self, timeout):
            fetches.append(clock[0])
            clock[0] += timeout             # each fetch waits its timeout out
            if len(fetches) > 1000:
                return "the result"         # the old loop: it would have gone on for ever
            raise TimeoutError
    with pytest.raises(cluster.ClusterError, match=r"the scheduler stopped answering \(no reply for 6\d s"):
        c._outcome(Finished(), "a task")
    assert clock[0] <= cluster.SILENCE + cluster.HEARTBEAT + cluster.FETCH_TIMEOUT, clock[0]
