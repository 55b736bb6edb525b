"""Ensembles on a Dask cluster (docs/reference.md §11): ``rbx simulate CONFIG --scheduler ADDRESS`` (and ``rbx histogram``,
through the same blocks; ``rbx lyapunov`` sends one task per slice of trajectories through :meth:`Cluster.map`).

The client keeps the run: its :class:`rbx.simulation.Simulation` (the state of every trajectory), its sink (the
one HDF5 file, or memory), its checkpoints and progress. The workers only advance slices of trajectories:

1. The trajectories are cut into ``slices`` contiguous slices, and the run's collisions into *rounds*: every
   trajectory still running is at the same collision when a round begins, as at a block of a local run.
2. A task is one slice for one round. It carries everything the worker needs — the kernel groups
   ``(Table, Rules, Settings)`` exactly as :meth:`Simulation.kernel_groups` builds them, the slice's rows of the
   state (:class:`rbx.engine.State`, stream keys included), the round's last collision and the record layout —
   and runs :func:`rbx.simulation.advance_state`, the code of a local run, on it. No config file, no table file
   is read on a worker. It returns the slice's records of the round (one block) and its new state.
3. The client gathers the tasks as they finish. A slice may start its next round as soon as its last one is back
   (up to :data:`AHEAD` rounds before the slowest slice), so workers do not wait for each other; when every slice
   has finished a round, its blocks are put side by side into the round's block (M trajectories), the slices'
   states into the simulation, and :meth:`Simulation.run` writes the block and checkpoints, as for a local block.

Bit for bit: a trajectory's numbers depend only on its own row — its state, its counter-based stream keyed by its
*global* index (``state.keys``, made by the client's Simulation) and its draw counter — never on the slice, the
worker or the order in which tasks finish. Records fall on the collisions that are multiples of ``output.every``,
so the file is the local run's file whatever the rounds (only the number of checkpoints differs).

Faults: a worker lost mid-task costs that task, which the scheduler runs again elsewhere (a task is a pure
function of its inputs, so the result is the same). ``should_stop()`` (Ctrl-C, SIGTERM) is polled while waiting:
the tasks still running are cancelled and the file keeps the last checkpointed round, which ``--resume``
continues here or locally. A failed task, or a lost scheduler, raises :class:`ClusterError` (the file again holds
every checkpointed round).
"""
import asyncio
import json
import logging
import os
import platform
import queue
import socket
import sys
import threading
import time

import llvmlite
import numba
import numpy as np

from . import __version__, _jit
from .engine import State
from .model import FIELD
from .paths import what_it_is
from .simulation import advance_state, record_buffers, records_block

#: seconds to reach the scheduler before giving up (an unreachable address is an error, not a wait)
CONNECT_TIMEOUT = 5.0
#: collisions one task should make (a slice times its round), for a table of a few walls: several seconds of
#: work, against a task overhead of a few milliseconds (docs/cluster.md); tables with many walls get fewer, as
#: blocks do (:func:`rbx.simulation.block_work`)
TASK_COLLISIONS = 200_000_000
#: record values (float64) one round may hold on the client, summed over its slices
ROUND_VALUES = 8_000_000
#: how many rounds a slice may run ahead of the slowest one (its records wait on the client meanwhile)
AHEAD = 2
#: bytes of state one task carries at most, by default (~15 000 trajectories)
SLICE_BYTES = 4_000_000
#: slices per worker thread by default: enough to even out slices that finish at different times
SLICES_PER_THREAD = 4
#: seconds between two looks at ``should_stop`` while waiting for a task (one that finishes is seen at once)
POLL = 0.1
#: while no task finishes, the scheduler is asked every HEARTBEAT seconds whether it still answers; a run stops when
#: it has not answered for SILENCE seconds. A frozen scheduler (SIGSTOP, a hung host) keeps its connections open and
#: sends nothing: the run waited for ever, without a line. Long tasks are fine: the scheduler answers meanwhile.
#: Its answer also says when it last heard from each worker (a worker's heartbeat, every second or so, goes on while
#: it runs a task): a run stops too when no worker has been heard from for SILENCE seconds (every worker frozen, or
#: none left), where it waited for ever
HEARTBEAT = 30.0
SILENCE = 60.0
class _AbandonedGather(logging.Filter):
    """Drops asyncio's report of the gather task that a fetch cut short by its timeout leaves behind in Dask's
    client ('Task exception was never retrieved … AllExit'): a result given up on, not an error of the run."""

    def filter(self, record):
        return "AllExit" not in record.getMessage() and "AllExit" not in str(record.exc_info or "")


def _hide_abandoned_gathers():
    log = logging.getLogger("asyncio")
    if not any(isinstance(f, _AbandonedGather) for f in log.filters):
        log.addFilter(_AbandonedGather())


#: what :meth:`Cluster._outcome` gives when the run was told to stop while a result was being fetched
STOPPED = object()
#: seconds a finished task's result may take to arrive before the future is looked at again (its worker lost)
FETCH_TIMEOUT = 5.0


#: times the workers are asked for their rbx before the run (a worker lost meanwhile is left out)
IDENTITY_TRIES = 3


def _missing_install(exc):
    """True if ``exc``, raised on a worker, says rbx (or a module it needs) cannot be imported or run there; not a
    lost connection (a worker killed while it answered)."""
    return isinstance(exc, (ImportError, AttributeError, SyntaxError, NameError))


class ClusterError(RuntimeError):
    """The cluster failed during a run (a task failed, the scheduler went away): ``<key>: <problem>``."""

    def __init__(self, key, problem):
        self.key, self.problem = key, problem
        super().__init__(f"{key}: {problem}" if key else problem)


class SchedulerUnreachable(ClusterError):
    """The scheduler cannot be used: not reachable, not a Dask scheduler, workers without (this) rbx, or
    ``distributed`` not installed. A user error (the CLI exits 2)."""


def _worker_identity():
    """Runs on each worker: what must match the client for the results to be the client's, bit for bit.

    ``rbx`` and ``kernels`` (rbx's version and the hash of the kernel sources *as imported*, which covers Numba's
    version, see :mod:`rbx._jit`; the files on disk may have changed since) must match: the client refuses workers
    that differ. ``platform`` (the processor architecture, the CPU Numba compiles for, the C library, NumPy and
    llvmlite) should: the kernels' arithmetic is the same on any CPU (no fast-math, no contraction), but the maths
    library's ``sin``/``cos`` and NumPy's vectorised functions may differ in the last bit between builds and
    processors, so the client warns on a mismatch."""
    try:
        from llvmlite import binding
        cpu = os.environ.get("NUMBA_CPU_NAME") or binding.get_host_cpu_name()
    except Exception:   # noqa: BLE001 - only a description
        cpu = "?"
    return {"rbx": __version__, "kernels": os.path.basename(_jit.CACHE_DIR).removeprefix("numba-"),
            "platform": {"machine": platform.machine(), "cpu": cpu, "libc": " ".join(platform.libc_ver()),
                         "numba": numba.__version__, "llvmlite": llvmlite.__version__,
                         "numpy": np.__version__}}


def _address(address):
    """``host:port`` -> ``tcp://host:port`` (Dask's default protocol), other addresses as given."""
    address = str(address).strip()
    return address if "://" in address else f"tcp://{address}"


def _in_background(call, name):
    """``call()`` on a daemon thread of its own, started -> (the thread, a list that receives ``(True, result)`` or
    ``(False, exception)`` when it ends). For requests to the scheduler that Dask would wait for without end: the
    caller waits as long as it chooses, and a thread still waiting holds nothing of the run's."""
    outcome = []

    def run():
        try:
            outcome.append((True, call()))
        except BaseException as exc:   # noqa: BLE001 - handed to the caller
            outcome.append((False, exc))
    thread = threading.Thread(target=run, daemon=True, name=name)
    thread.start()
    return thread, outcome


def _probe(address, timeout):
    """Ask the scheduler at ``address`` who it is -> its identity dict; raises OSError if it cannot be reached.

    A Dask Client that cannot connect waits its whole timeout and then, collected, waits again to close; this
    one connection says at once whether anything answers, and whether it is a scheduler."""
    from distributed.comm import connect

    scheme, _, where = address.partition("://")
    if scheme == "tcp":
        # Dask retries a refused connection until its timeout: a plain socket says at once that nothing listens
        host, _, port = where.rpartition(":")
        if not port.isdigit():
            raise ValueError("no port in the address (give tcp://HOST:PORT, e.g. tcp://127.0.0.1:8786)")
        if not 0 < int(port) < 65536:       # the system wraps it, and said "Connection refused"
            raise ValueError(f"port {port} does not exist (ports are 1 … 65535)")
        with socket.create_connection((host.strip("[]"), int(port)), timeout=timeout):
            pass

    async def ask():
        comm = await connect(address, timeout=timeout)
        try:
            await comm.write({"op": "identity", "reply": True})
            return await comm.read()
        finally:
            comm.abort()            # closed without waiting: a peer that never answers never acknowledges either

    async def asked():
        # the whole exchange in one bound: a port that accepts a connection and never answers held Dask's
        # handshake (and a polite close) for ever, and rbx simulate --scheduler with it
        return await asyncio.wait_for(ask(), timeout)

    return asyncio.run(asked())


def connect(scheduler, key="--scheduler", slices=None, task_collisions=None):
    """Connect to the Dask scheduler ``scheduler`` (an address such as ``tcp://host:8786`` or ``host:8786``, the
    JSON file a scheduler wrote with ``--scheduler-file``, or a ``distributed.Client``) -> :class:`Cluster`.

    Checks that the workers run this rbx with the same kernels (else their numbers could differ). Raises
    :class:`SchedulerUnreachable` naming ``key`` within :data:`CONNECT_TIMEOUT` seconds or so."""
    for name, value in (("slices", slices), ("task_collisions", task_collisions)):
        if value is not None and int(value) < 1:
            raise ValueError(f"{name}: must be at least 1, not {value}")
    try:
        import distributed
    except ImportError:
        raise SchedulerUnreachable(key, "running on a Dask cluster needs the package 'distributed': pip install "
                                        "'rbx[cluster]'") from None
    if isinstance(scheduler, distributed.Client):
        client, own = scheduler, False
    else:
        if not isinstance(scheduler, (str, os.PathLike)):     # scheduler=42 was tried as the address tcp://42
            raise TypeError(f"{key}: a scheduler's address, its scheduler file or a distributed.Client, got "
                            f"{type(scheduler).__name__}")
        text = os.fspath(scheduler) if isinstance(scheduler, os.PathLike) else str(scheduler)
        if not text.strip():
            raise SchedulerUnreachable(key, "an empty address (give tcp://HOST:PORT, or a scheduler file)")
        try:
            if os.path.isfile(text):     # a scheduler file: its address, tried like one given (a dead scheduler's
                address = _scheduler_file(text, key)      # file must not make Dask's Client wait and retry)
            elif os.path.lexists(text):      # a FIFO, a folder, a dangling link: no address and no file to read
                raise SchedulerUnreachable(key, f"{text} is {what_it_is(text)}, not a scheduler file (give "
                                                "tcp://HOST:PORT, or the file dask scheduler --scheduler-file "
                                                "wrote)")
            else:
                address = _address(text)
            scheme = address.partition("://")[0]
            if scheme != "tcp":
                # tls:// needs certificates, inproc:// a scheduler in this very process, ucx:// and ws:// their own
                # settings: none of which a command line passes (Dask took tls://… for a scheduler that answered
                # wrongly, inproc://x for a broken address)
                raise SchedulerUnreachable(key, f"{text}: rbx connects to a scheduler over tcp:// (give "
                                                f"tcp://HOST:PORT or a scheduler file); for {scheme}://, pass a "
                                                "distributed.Client set up for it from Python (scheduler=client)")
            try:
                identity = _probe(address, CONNECT_TIMEOUT)
            except ValueError as exc:          # no port, an unknown protocol
                raise SchedulerUnreachable(key, f"{text}: {_first_line(exc)}") from None
            except OSError as exc:             # refused, timed out (TimeoutError is an OSError), no route
                why = exc.strerror if isinstance(exc, OSError) and exc.strerror else _first_line(exc)
                if isinstance(exc, TimeoutError) and not exc.strerror:
                    why = f"no answer within {CONNECT_TIMEOUT:g} s"
                raise SchedulerUnreachable(key, f"cannot reach a Dask scheduler at {address}: {why} (is "
                                                "'dask scheduler' running there?)") from None
            except Exception:   # noqa: BLE001 - something answered, in another protocol (Dask read garbage)
                identity = None
            if not isinstance(identity, dict) or identity.get("type") != "Scheduler":
                raise SchedulerUnreachable(key, f"{address} answered, but not as a Dask scheduler")
            client = distributed.Client(address, timeout=CONNECT_TIMEOUT, set_as_default=False)
        except SchedulerUnreachable:
            raise
        except Exception as exc:   # noqa: BLE001 - a bad address, a refused handshake: all one line for the user
            raise SchedulerUnreachable(key, f"cannot connect to the Dask scheduler {text}: {_first_line(exc)}") \
                from None
        own = True
    cluster = Cluster(client, own, key=key, slices=slices, task_collisions=task_collisions)
    try:
        cluster.check_workers()
    except SchedulerUnreachable:
        cluster.close()
        raise
    except ClusterError as exc:     # it stopped answering, or its workers did, while asked: it cannot be used
        cluster.close()
        raise SchedulerUnreachable(key, exc.problem) from None
    except BaseException:
        cluster.close()
        raise
    return cluster


def _scheduler_file(path, key):
    """The address in a scheduler file (``dask scheduler --scheduler-file``) -> str."""
    try:
        with open(path) as f:
            address = json.load(f).get("address")
    except (OSError, ValueError, AttributeError) as exc:
        raise SchedulerUnreachable(key, f"{path}: not a Dask scheduler file ({_first_line(exc)})") from None
    if address is None:
        raise SchedulerUnreachable(key, f"{path}: not a Dask scheduler file (no 'address')")
    if not isinstance(address, str) or "://" not in address:
        # a number, or a name without a protocol, was said as 'no address' or as the protocol 's1.json://'
        raise SchedulerUnreachable(key, f"{path}: not a Dask scheduler file (its 'address' is {str(address)[:60]!r}, "
                                        "not an address such as tcp://HOST:PORT)")
    return address


def _first_line(exc):
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


class _Task:
    """One slice for one round: what a worker needs, all of it (a plain object, so that Dask sends it as it is
    and does not look inside for futures)."""

    def __init__(self, groups, state, stop, record, n, records):
        self.groups, self.state, self.stop = groups, state, stop
        self.record, self.n, self.records = record, n, records


def run_task(task):
    """Runs on a worker: advance one slice to ``task.stop`` collisions -> (block or None, nrec, state).

    The kernels are the client's (same source, checked at connect); a worker compiles a specialisation once, or
    loads it from the disk cache of :mod:`rbx._jit`, then keeps it for its next tasks."""
    # writable copies: a worker in the client's process would share the client's arrays, and an array Dask hands
    # over read-only would be another type to Numba (another signature to compile, not the cached one)
    groups = tuple(type(g)(*(np.array(x) if isinstance(x, np.ndarray) else x for x in g)) for g in task.groups)
    state = State(*(np.array(a) for a in task.state))
    bufs = record_buffers(task.record, task.n, state.pos.shape[0], task.records)
    nrec = advance_state(groups, state, task.stop, bufs)
    block = records_block(bufs, nrec, task.record, task.n) if task.record else None
    if block is not None:       # the views would pickle their whole buffers
        block = {f: np.ascontiguousarray(a) for f, a in block.items()}
    return block, nrec, state


class Cluster:
    """A connection to a Dask cluster that runs the blocks of a :class:`rbx.simulation.Simulation`
    (``sim.cluster = cluster``).

    ``slices``: tasks per round (default :data:`SLICES_PER_THREAD` per worker thread, at most one per
    trajectory); ``task_collisions``: collisions one task makes (default :data:`TASK_COLLISIONS`, fewer for
    tables with many walls). Use as a context manager, or :meth:`close` it."""

    def __init__(self, client, own=False, key="--scheduler", slices=None, task_collisions=None):
        self.client, self.own, self.key = client, own, key
        self._heard = time.monotonic()      # when the scheduler last answered, or a task finished
        self._answered_at = self._heard     # when it last answered, or a task finished (not a failed question)
        self._silent_since = None           # the first unanswered heartbeat since then
        self._workers_seen = {}             # each worker's last heartbeat, as the scheduler last told it
        self._workers_quiet_since = None    # since when no worker had news, by the scheduler's answers
        self._workers_answered_at = None    # when the scheduler last answered (no task finished since)
        self.slices = None if slices is None else int(slices)
        self.task_collisions = None if task_collisions is None else int(task_collisions)
        self.tasks_run = 0

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        if self.own and self.client is not None:
            try:
                self.client.close(timeout=CONNECT_TIMEOUT)
            except Exception:   # noqa: BLE001 - a scheduler already gone: nothing left to close
                pass
        self.client = None

    # -- the workers ---------------------------------------------------------------------------------------------
    def threads(self):
        """Worker threads in the cluster now (0 when it has no workers)."""
        try:
            info = self._bounded(lambda: self.client.scheduler_info(n_workers=-1))   # recent Dask lists only 5
        except TypeError:
            info = self._bounded(self.client.scheduler_info)
        workers = info.get("workers", {})
        return sum(int(w.get("nthreads", 1)) for w in workers.values())

    def check_workers(self):
        """Every worker runs rbx with the client's kernels; raises :class:`SchedulerUnreachable` otherwise."""
        mine = _worker_identity()
        theirs = self._identities()
        for worker, ident in sorted(theirs.items()):
            if (ident.get("rbx"), ident.get("kernels")) != (mine["rbx"], mine["kernels"]):
                what = (f"rbx {ident.get('rbx')}, this client rbx {mine['rbx']}" if ident.get("rbx") != mine["rbx"]
                        else "other kernel sources (or another Numba)")
                raise SchedulerUnreachable(self.key, f"worker {worker} runs {what}: its numbers could differ; "
                                                     "install the same rbx on the workers and the client")
        differ = {}
        for worker, ident in sorted(theirs.items()):
            for name, value in (ident.get("platform") or {}).items():
                if value != mine["platform"].get(name):
                    differ.setdefault(name, (value, worker))
        if differ:
            said = "; ".join(f"{name} {value} on {worker}, {mine['platform'][name]} here"
                             for name, (value, worker) in sorted(differ.items()))
            sys.stderr.write(f"rbx: warning: {self.key}: the workers' platform differs from this client's ({said}):"
                             " the results are expected to be the local run's but are not guaranteed bit for bit\n")

    def _identities(self, tries=IDENTITY_TRIES):
        """Each worker's :func:`_worker_identity` -> {worker: identity}, from the workers that answer. A worker
        lost meanwhile (killed, its connection closed: "Stream is closed") is left out, as Dask leaves it out
        of the run; asked again if no worker answered. Only a worker that answered with an error of its own (rbx
        or one of its modules not importable there) means rbx is missing: :class:`SchedulerUnreachable`."""
        lost = None
        for _ in range(tries):
            try:
                answers = self._bounded(lambda: self.client.run(_worker_identity, on_error="return"))
            except TypeError:          # a Dask without on_error: all or nothing
                try:
                    answers = self._bounded(lambda: self.client.run(_worker_identity))
                except ClusterError:
                    raise
                except Exception as exc:   # noqa: BLE001 - sorted below
                    answers = {"?": exc}
            except ClusterError:
                raise
            except Exception as exc:   # noqa: BLE001 - the scheduler's own connection to a worker, lost
                lost = exc
                continue
            found = {}
            for worker, answer in answers.items():
                if not isinstance(answer, BaseException):
                    found[worker] = answer
                elif _missing_install(answer):
                    raise SchedulerUnreachable(self.key, f"the workers cannot run rbx ({_first_line(answer)}); "
                                                         f"install this rbx ({__version__}) where they run")
                else:
                    lost = answer
            if found or not answers:        # no worker at all: the run waits for them (said by the caller)
                return found
        if getattr(self.client, "status", "running") not in ("running", "newly-created"):
            # the client lost its scheduler (killed, shut down): not the workers
            raise SchedulerUnreachable(self.key, "the scheduler is gone (shut down, or the network to it lost): "
                                                 f"the client's connection is {self.client.status}")
        why = f" ({_first_line(lost)})" if lost is not None else ""
        raise SchedulerUnreachable(self.key, f"no worker answered{why}: the workers were lost (killed, or the "
                                             "network to them); start them again")

    # -- running -------------------------------------------------------------------------------------------------
    def slice_cuts(self, M, state_bytes):
        """Slice boundaries (S+1,) of M trajectories whose state takes ``state_bytes``: ``slices`` slices, or by
        default enough to keep each task's state small (Dask warns about large tasks, and a task lost costs less)
        and :data:`SLICES_PER_THREAD` per worker thread; at most one per trajectory."""
        S = self.slices or max(SLICES_PER_THREAD * self.threads(), -(-int(state_bytes) // SLICE_BYTES), 1)
        S = max(1, min(S, M))
        return np.linspace(0, M, S + 1).astype(np.int64)

    def _outcome(self, future, what, should_stop=None):
        """The result of a finished task, or :data:`STOPPED` if ``should_stop()`` became true while it was fetched;
        a cancelled one (the scheduler gone) or a failed one raises :class:`ClusterError` (``what``: which task, for
        the message). A finished task whose worker was lost before its result was fetched is run again by Dask, and
        fetching it waits for a worker: asked in turns of :data:`POLL` seconds, so that Ctrl-C still stops the run
        when the cluster has lost its workers (one blocking wait never returned)."""
        from distributed import CancelledError
        from distributed.comm.core import CommClosedError
        try:
            while True:
                # a result lost with its worker makes the future pending again ("lost"): wait for it by looking,
                # not in a blocking fetch (a fetch cut short by a timeout leaves Dask's gather task behind, which
                # asyncio then reports on stderr)
                if not future.done():
                    if should_stop is not None and should_stop():
                        return STOPPED
                    self._watch()
                    time.sleep(POLL)
                    continue
                try:
                    return future.result(timeout=FETCH_TIMEOUT)
                except TimeoutError:        # its worker lost, the future not told yet: look again
                    _hide_abandoned_gathers()
                    if should_stop is not None and should_stop():
                        return STOPPED
                    # or the scheduler frozen: the fetch asks it where the result is. Not watched here, a frozen
                    # scheduler held rbx histogram --scheduler for ever, without a line
                    self._watch()
                    continue
        except ClusterError:
            raise
        except (CancelledError, CommClosedError):
            # the scheduler killed: the futures are cancelled, or (1 in ~10 runs of the test) the client's gather
            # from it finds its connection closed first
            raise ClusterError(self.key, "the run's tasks were cancelled: the scheduler is gone "
                                         "(shut down, or the network to it lost)") from None
        except Exception as exc:   # noqa: BLE001 - a task that failed, a worker lost too often
            raise ClusterError(self.key, f"a task failed ({what}): {type(exc).__name__}: {_first_line(exc)}") \
                from None

    def _bounded(self, call):
        """``call()`` (a request to the scheduler, which Dask would wait for without end) on a thread of its own,
        waited for as a task is (:meth:`_watch`): its result, its exception, or :class:`ClusterError` once the
        scheduler has not answered for :data:`SILENCE` seconds (the thread is left to its wait; it holds nothing of
        the run's). Asking the workers who they are waits for each of them: a frozen one is noticed as in a run,
        by its heartbeats."""
        self._heard, self._silent_since = time.monotonic(), None
        asking, outcome = _in_background(call, "rbx-scheduler-call")
        while True:
            asking.join(POLL)
            if outcome:
                ok, value = outcome[0]
                if ok:
                    return value
                raise value
            self._watch()

    def _watch(self, workers=True):
        """Called while waiting for a task: every :data:`HEARTBEAT` seconds without news, ask the scheduler who it
        is (:func:`_probe`); raise :class:`ClusterError` once it has not answered for :data:`SILENCE` seconds, or
        (``workers``) once its answers have said for that long that no worker sent it a heartbeat. Only a
        scheduler reached over TCP is asked (another kind of address, an in-process one, cannot freeze alone)."""
        now = time.monotonic()
        if now - self._heard < HEARTBEAT:
            return
        address = getattr(getattr(self.client, "scheduler", None), "address", None) or ""
        if not address.startswith("tcp://"):
            self._heard = now
            return
        # on a thread of its own: the probe runs an event loop, which a thread that has one running (a notebook's)
        # cannot; whatever goes wrong (no answer in time, refused, reset) is silence all the same
        asking, outcome = _in_background(lambda: _probe(address, CONNECT_TIMEOUT), "rbx-scheduler-probe")
        asking.join(CONNECT_TIMEOUT + 1.0)
        answered = [value for ok, value in list(outcome) if ok]
        if answered:
            self._silent_since = None
            self._answered_at = now
            if workers:
                self._check_worker_news(answered[0], now)
        else:
            if self._silent_since is None:
                # silent since its last answer (or the last task that finished), not since this first unanswered
                # question: counted from here, a freeze was said up to SILENCE + HEARTBEAT after it, and as 30 s shorter
                self._silent_since = self._answered_at
            if time.monotonic() - self._silent_since >= SILENCE:
                raise ClusterError(self.key, f"the scheduler stopped answering (no reply for "
                                             f"{time.monotonic() - self._silent_since:.0f} s: frozen, overloaded, or "
                                             f"the network to it lost)") from None
        self._heard = time.monotonic()

    def _check_worker_news(self, identity, now):
        """Raise :class:`ClusterError` when the scheduler's answers (its ``identity``, at ``now``) have said for
        :data:`SILENCE` seconds that no worker has sent it a heartbeat: each worker's ``last_seen`` is compared with
        the previous answer's, not with a clock (the scheduler's host keeps its own time)."""
        listed = (identity.get("workers") or {}) if isinstance(identity, dict) else {}
        seen = {worker: (info or {}).get("last_seen") for worker, info in listed.items()}
        news = any(when is not None and when != self._workers_seen.get(worker) for worker, when in seen.items())
        self._workers_seen = seen
        previous, self._workers_answered_at = self._workers_answered_at, now
        if news:
            self._workers_quiet_since = None
            return
        if self._workers_quiet_since is None:
            # no heartbeat since the previous answer: quiet since then at least. Counted from this answer, a worker
            # frozen just after one was said about SILENCE + 2 HEARTBEAT later (124 s, where 90 was written)
            self._workers_quiet_since = previous if previous is not None else now
        if time.monotonic() - self._workers_quiet_since >= SILENCE:
            quiet = time.monotonic() - self._workers_quiet_since
            what = (f"none of its {len(seen)} worker(s) has sent the scheduler a heartbeat for {quiet:.0f} s "
                    "(frozen, or their host hung)" if seen else
                    f"the scheduler has had no worker for {quiet:.0f} s (start them again)")
            raise ClusterError(self.key, what) from None

    def _heard_from(self):
        """A task finished: the scheduler and a worker are alive."""
        self._heard, self._silent_since = time.monotonic(), None
        self._answered_at = self._heard
        self._workers_quiet_since = self._workers_answered_at = None

    def _submit(self, function, *args, **options):
        """``client.submit``; a client closed meanwhile (its scheduler killed: Dask closes the client, and the next
        submit raised ClosedClientError, a traceback) raises :class:`ClusterError` as a lost scheduler does."""
        from distributed.client import ClosedClientError
        from distributed.comm.core import CommClosedError
        try:
            return self.client.submit(function, *args, **options)
        except (ClosedClientError, CommClosedError, OSError) as exc:
            raise ClusterError(self.key, f"the scheduler is gone (shut down, or the network to it lost): "
                                         f"{_first_line(exc)}") from None

    def map(self, function, tasks, what="task", should_stop=None):
        """``function(task)`` for each of ``tasks`` on the workers -> the results, in the order of ``tasks`` (None
        if ``should_stop()`` became true first). Every task is submitted at once (for work that is not cut into
        rounds: ``rbx lyapunov``'s slices). A lost worker's task is run again by Dask. Polls ``should_stop`` and
        lets KeyboardInterrupt through while waiting; cancels the tasks still running however it ends. Raises
        :class:`ClusterError` if a task fails or the scheduler goes away."""
        run_id = f"rbx-{what}-{os.getpid()}-{time.monotonic_ns():x}"
        finished = queue.Queue()
        running = {}
        results = [None] * len(tasks)
        try:
            for i, task in enumerate(tasks):
                future = self._submit(function, task, key=f"{run_id}-{i}", pure=False)
                running[future] = i
                future.add_done_callback(finished.put)   # called in the client's thread: the queue hands over
            while running:
                if should_stop is not None and should_stop():
                    return None
                try:
                    future = finished.get(timeout=POLL)
                except queue.Empty:
                    self._watch()
                    continue
                self._heard_from()
                result = self._outcome(future, f"{what} slice {running[future]}", should_stop)
                if result is STOPPED:
                    return None
                i = running.pop(future)
                results[i] = result
                future.release()
                self.tasks_run += 1
            return results
        finally:
            if running and self.client is not None:
                try:
                    self.client.cancel(list(running))
                except Exception:   # noqa: BLE001 - a scheduler already gone: nothing left to cancel
                    pass

    def plan(self, sim):
        """How ``sim`` is cut -> (slice boundaries (S+1,), collisions per round)."""
        M = sim.M
        cuts = self.slice_cuts(M, sum(a.nbytes for a in sim.state_group()))
        S = len(cuts) - 1
        work = self.task_collisions or max(1, int(TASK_COLLISIONS / (1 + len(sim.geom.codes) / 8)))
        per_trajectory = max(1, work * S // M)               # a task's work over its slice's trajectories
        every = sim.cfg.output.every
        if sim.record:
            per_record = 1 + sum(FIELD[f].size(sim.n) for f in sim.record)
            by_memory = max(1, ROUND_VALUES // (M * per_record))             # records per trajectory per round
            length = every * max(1, min(per_trajectory // every, by_memory))
        else:
            length = per_trajectory
        return cuts, length

    def blocks(self, sim, should_stop=None, progress=None):
        """Run ``sim`` round by round on the cluster -> yields (block or None, nrec, sim) per round, as
        :meth:`Simulation._blocks` does for a local run, ``sim``'s state advanced to the round's end (the state
        that the round's check and checkpoint read).

        Stops early (yielding nothing more) when ``should_stop()``; cancels the tasks still running however it
        ends. Raises :class:`ClusterError` if a task fails."""
        total = sim.cfg.run.collisions
        cuts, length = self.plan(sim)
        slices = list(zip(cuts[:-1].tolist(), cuts[1:].tolist()))
        S = len(slices)
        groups = sim.kernel_groups()
        every = sim.cfg.output.every
        full = sim.state_group()
        done = int(sim.ncoll[sim.alive].min()) if sim.alive.any() else total
        # the rounds' last collisions: aligned on multiples of the round length, as local blocks are on theirs
        ends = []
        c = done
        while c < total:
            c = min(total, (c // length + 1) * length)
            ends.append(c)
        starts = [done] + ends[:-1]
        if not ends or not sim.alive.any():
            return
        run_id = f"rbx-{os.getpid()}-{id(sim):x}-{time.monotonic_ns():x}"
        # per slice: its state after its last finished round and that round's index (−1: none yet)
        states = [State(*(np.array(field[a:b]) for field in full)) for a, b in slices]
        reached = [-1] * S
        results = [dict() for _ in range(S)]     # slice -> {round: (block, nrec)} not yet written
        running = {}                             # future -> (slice, round)
        finished = queue.Queue()                 # futures done, in the order they finished
        frontier = 0                             # the first round not yet finished by every slice

        def submit(s):
            r = reached[s] + 1
            if r >= len(ends) or r > frontier + AHEAD or any(v == (s, r) for v in running.values()):
                return
            state = states[s]
            if not state.alive.any():            # nothing left to do in this slice: no task
                m = state.pos.shape[0]
                block = ({f: np.empty((m, 0) + FIELD[f].shape(sim.n), FIELD[f].dtype) for f in sim.record}
                         if sim.record else None)
                finish(s, r, block, np.zeros(m, np.int64), state)
                return
            records = ends[r] // every - starts[r] // every if sim.record else 0
            task = _Task(groups, state, ends[r], sim.record, sim.n, records)
            future = self._submit(run_task, task, key=f"{run_id}-s{s}-r{r}", pure=False, priority=-r)
            running[future] = (s, r)
            future.add_done_callback(finished.put)     # called in the client's thread: the queue is the hand-over

        def finish(s, r, block, nrec, state):
            states[s] = state
            reached[s] = r
            results[s][r] = (block, nrec, state)
            submit(s)

        try:
            for s in range(S):
                submit(s)
            while frontier < len(ends):
                if should_stop is not None and should_stop():
                    return
                try:
                    ready = [finished.get(timeout=POLL)]
                except queue.Empty:
                    self._watch()
                    continue
                self._heard_from()
                for future in ready:
                    s, r = running[future]
                    result = self._outcome(future, f"slice {s}, round {r}", should_stop)
                    if result is STOPPED:
                        return
                    running.pop(future)
                    block, nrec, state = result
                    future.release()
                    self.tasks_run += 1
                    finish(s, r, block, nrec, state)
                if progress is not None:
                    made = sum((b - a) * (ends[reached[s]] if reached[s] >= 0 else done)
                               for s, (a, b) in enumerate(slices))
                    progress(min(total, made // sim.M), total)
                while frontier < len(ends) and all(reached[s] >= frontier for s in range(S)):
                    yield self._gather(sim, slices, results, frontier, full) + (sim,)
                    frontier += 1
                    if not sim.alive.any():      # every trajectory has ended: the run is over, as a local one
                        return
                    for s in range(S):
                        submit(s)
        finally:
            if running:
                self.client.cancel(list(running))

    @staticmethod
    def _gather(sim, slices, results, r, full):
        """Round ``r`` of every slice -> (block of the M trajectories or None, nrec); the state of the round's end
        is put into ``sim`` (its arrays, through ``full``)."""
        parts = [results[s].pop(r) for s in range(len(slices))]
        nrec = np.concatenate([nrec for _, nrec, _ in parts])
        for (a, b), (_, _, state) in zip(slices, parts):
            for mine, theirs in zip(full, state):
                mine[a:b] = theirs
        if not sim.record:
            return None, nrec
        width = int(nrec.max()) if len(nrec) else 0
        block = {}
        for f in sim.record:
            spec = FIELD[f]
            arr = np.full((sim.M, width) + spec.shape(sim.n), spec.fill, dtype=spec.dtype)
            for (a, b), (part, _, _) in zip(slices, parts):
                piece = part[f]
                arr[a:b, :piece.shape[1]] = piece
            block[f] = arr
        return block, nrec

