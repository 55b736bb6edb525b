"""How fast rbx runs on a Dask cluster (docs/cluster.md): a scheduler and 1 or 2 workers started here on
127.0.0.1, an ensemble of the random strip run on them and on the local thread pool, and the overhead of a task.

    python scripts/bench_cluster.py [--trajectories M] [--collisions N] [--repeats K] [--output FILE]

Prints a markdown table (and writes it, with the machine and the command, to ``--output``: `make bench` writes
docs/benchmarks-cluster.md). Each timing is ``time.perf_counter`` around ``Simulation.run`` alone (connected, the
kernels compiled and loaded on the workers by a warm-up run), the median of ``--repeats`` runs; every cluster run
is checked to end in the local run's final state, bit for bit. The workers get one kernel thread each
(``NUMBA_NUM_THREADS=1``), the local pool ``numba.get_num_threads()`` threads.

The overhead of a task: many tasks of one collision per trajectory (``task_collisions`` tiny) on 8 trajectories in
8 slices: the run's wall time over the number of tasks. Where the machine is shared, these numbers carry its load:
``uptime`` is printed beside them.
"""
import argparse
import copy
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import rbx
from rbx import cluster as rbx_cluster
from rbx.simulation import MemorySink, Simulation

STRIP_RANDOM = {"table": {"kind": "strip", "width": 1.0}, "ball": {"radius": 0.1, "inertia": "uniform"},
                "boundary": {"default": {"rule": "random", "probabilities": [0.5, 0.5],
                                         "choices": [{"rule": "constant", "rank": 0},
                                                     {"rule": "constant", "rank": 1}]}},
                "initial": {"position": [0, 0.5], "velocity": [0.6, 0.8], "angular_velocity": 1.5}}


class Dask:
    """A scheduler and ``workers`` workers on 127.0.0.1 (subprocesses, ended by :meth:`stop`)."""

    def __init__(self, folder, workers):
        Path(folder).mkdir(parents=True, exist_ok=True)
        self.file = Path(folder) / "scheduler.json"
        env = dict(os.environ, NUMBA_NUM_THREADS="1")
        common = ["--host", "127.0.0.1", "--no-dashboard"]
        self.procs = [subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_scheduler", "--port", "0",
                                        "--scheduler-file", str(self.file)] + common, cwd=folder, env=env,
                                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)]
        while not (self.file.exists() and self.file.stat().st_size):
            time.sleep(0.1)
        time.sleep(0.2)
        self.address = json.loads(self.file.read_text())["address"]
        for _ in range(workers):
            self.procs.append(subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_worker", self.address,
                                                "--nthreads", "1"] + common, cwd=folder, env=env,
                                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                               start_new_session=True))
        from distributed import Client
        with Client(self.address, set_as_default=False) as c:
            c.wait_for_workers(workers, timeout=120)

    def stop(self):
        for p in reversed(self.procs):
            os.killpg(p.pid, signal.SIGTERM)
        for p in self.procs:
            p.wait()


def experiment(trajectories, collisions):
    d = copy.deepcopy(STRIP_RANDOM)
    d["run"] = {"collisions": collisions, "trajectories": trajectories, "seed": 1}
    d["output"] = {"record": []}
    return rbx.load(d)


def timed(exp, on=None):
    sim = Simulation(exp)
    sim.cluster = on
    sink = MemorySink()
    start = time.perf_counter()
    sim.run(sink)
    return time.perf_counter() - start, sink.final


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trajectories", type=int, default=16)
    ap.add_argument("--collisions", type=int, default=4_000_000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--output", metavar="FILE", help="also write the table, the machine and the command here")
    args = ap.parse_args()
    exp = experiment(args.trajectories, args.collisions)
    total = args.trajectories * args.collisions
    timed(experiment(args.trajectories, 100))                        # compile or load the kernel here
    rows = []
    local = [timed(exp) for _ in range(args.repeats)]
    reference = local[0][1]
    rows.append(("local thread pool", statistics.median(t for t, _ in local), None))
    with tempfile.TemporaryDirectory() as folder:
        for workers in (1, 2):
            dask = Dask(Path(folder) / f"w{workers}", workers)
            try:
                with rbx_cluster.connect(dask.address) as on:
                    timed(experiment(args.trajectories, 100), on)    # the workers import rbx, load the kernel
                    runs = [timed(exp, on) for _ in range(args.repeats)]
                    same = all(np.array_equal(final[k], reference[k]) for _, final in runs for k in reference)
                    rows.append((f"{workers} worker{'s' * (workers > 1)}", statistics.median(t for t, _ in runs),
                                 same))
                    if workers == 2:
                        tiny = experiment(8, 200)
                        with rbx_cluster.connect(dask.address, slices=8, task_collisions=1) as each:
                            seconds, _ = timed(tiny, each)
                            overhead = seconds / each.tasks_run, each.tasks_run
            finally:
                dask.stop()
    one, two = rows[1][1], rows[2][1]
    lines = [f"{args.trajectories} trajectories × {args.collisions} collisions of the random strip, record: [] "
             f"({os.cpu_count()} cores; {os.getloadavg()[0]:.1f} load average at the end)", "",
             "| where | seconds (median of %d) | M collisions/s | final state = local, bit for bit |" % args.repeats,
             "|---|---|---|---|"]
    for label, seconds, same in rows:
        lines.append(f"| {label} | {seconds:.2f} | {total / seconds / 1e6:.1f} | {'—' if same is None else same} |")
    lines += ["", f"2 workers / 1 worker: {one / two:.2f}×",
              f"task overhead: {1e3 * overhead[0]:.1f} ms of wall time per task ({overhead[1]} tasks of 1 collision "
              "per trajectory, 8 slices, 2 workers)"]
    print("\n".join(lines))
    if args.output:
        import platform
        head = ["# rbx on a Dask cluster: measured", "",
                f"Written by `{' '.join(['python'] + sys.argv)}` on {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; "
                f"machine: {platform.node()}, {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
                f"Python {platform.python_version()}. A scheduler and 1, then 2 workers (one kernel thread each) "
                "started on 127.0.0.1; each timing is the median of the repeats, `Simulation.run` alone, kernels "
                "loaded. docs/cluster.md explains the numbers.", ""]
        Path(args.output).write_text("\n".join(head + lines) + "\n")


if __name__ == "__main__":
    main()
