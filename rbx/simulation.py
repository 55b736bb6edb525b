"""Python tier of the event loop: allocate the state, run :func:`rbx.engine.run_advance_all` block by block and hand
each block of records to a sink (the HDF5 writer, or memory for the API and tests).

Memory stays flat: a block holds at most a few million values whatever the run's length.
"""
import copy
import os
import time
from concurrent.futures import ThreadPoolExecutor, wait

import numpy as np

from . import engine, rules
from .geometry import END_TOLERANCE
from .model import FIELD, FIELDS
from .physics import energy, spin_matrix, spin_vector
from .rng import PURPOSE_RULES
from .rules import compile_rules
from .sampling import explicit_states, sample_billiard, sample_point_particle, stream_keys

#: collisions per block summed over trajectories: ~0.1 s of work, so progress and Ctrl-C stay responsive
BLOCK_WORK = 2_000_000
#: the state is saved (a checkpoint: the file flushed and committed, rbx.journal) after a block when this long has
#: passed since the last one, and when the run stops. A block of a fast scene takes ~10 ms: a checkpoint after
#: each rewrote the partly filled chunks and journalled them ~100 times a second (HDF5 recording the strip's time
#: at 5.8e7 collisions/s, 6.6e7 before the journal). A kill loses at most this much computing
CHECKPOINT_SECONDS = 1.0
#: values (float64) held in the record buffers of one block (two blocks' worth while one is written, AHEAD)
BLOCK_VALUES = 4_000_000
#: compute the next block while this one is written (a run that records): a run then takes the sum of the
#: engine's and the writer's times no longer, but the larger of them
AHEAD = True
#: the attributes of a Simulation that the kernels advance (engine.State, but for the keys, which stay)
STATE_ARRAYS = ("pos", "vel", "W", "theta", "A", "time", "ncoll", "draws", "alive", "last_wall", "last_rank",
                "energy0", "_comp")


def spin_matrices(angular_velocity, M, n):
    """The (M, n, n) spin matrices of M angular velocities (2D: M values; 3D: M vectors; or M matrices) — what
    :func:`rbx.physics.spin_matrix` gives row by row, built at once (the same numbers, tests/test_fastpaths.py):
    row by row took 4.5 µs a trajectory, half the set-up of 10⁵ short orbits."""
    w = np.asarray(angular_velocity, float)
    if n == 2 and w.size == M:
        w = w.reshape(M)
        W = np.zeros((M, 2, 2))
        W[:, 0, 1] = -w
        W[:, 1, 0] = w
        return W
    if n == 3 and w.shape == (M, 3):
        W = np.zeros((M, 3, 3))
        W[:, 0, 1], W[:, 0, 2] = -w[:, 2], w[:, 1]
        W[:, 1, 0], W[:, 1, 2] = w[:, 2], -w[:, 0]
        W[:, 2, 0], W[:, 2, 1] = -w[:, 1], w[:, 0]
        return W
    return np.array([spin_matrix(x, n) for x in w]).reshape(M, n, n)


def block_work(geom):
    """BLOCK_WORK for this table: each collision tests every primitive, so a table with many walls gets smaller
    blocks and Ctrl-C stays responsive (a 400-edge polygon: ~40 000 collisions per block, ~0.3 s)."""
    return max(1, int(BLOCK_WORK / (1 + len(geom.codes) / 8)))


class NonFiniteState(ArithmeticError):
    """A trajectory's state stopped being finite: the run stops (its file keeps the last checkpoint, incomplete)
    rather than end the trajectory as if it had escaped."""


#: bytes of one trajectory's state, generously (position, velocity, spin and orientation matrices, counters, key):
#: what :func:`memory_problem` counts for a run
STATE_BYTES = 400


def memory_problem(trajectories, per_trajectory=STATE_BYTES, records=0):
    """Why an ensemble's state (``per_trajectory`` bytes each), and the ``records`` bytes a run in memory keeps
    (:func:`records_bytes`), would not fit in this machine's memory -> the problem as text, or None: refused before
    minutes of setting up, rather than a MemoryError (or the system's out-of-memory killer) after them."""
    try:
        available = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):   # not a POSIX system: let the allocation decide
        return None
    try:        # a limit on the process's memory (ulimit -v), less what it holds already (the interpreter, NumPy)
        import resource         # POSIX only: where it is missing, no limit is read
        limit = resource.getrlimit(resource.RLIMIT_AS)[0]
        if limit != resource.RLIM_INFINITY:
            with open("/proc/self/statm") as f:
                used = int(f.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
            available = min(available, max(limit - used, 0))
    except (ImportError, OSError, ValueError):
        pass
    state = trajectories * per_trajectory
    if state + records <= available:
        return None
    if state <= available:
        return (f"the records kept in memory need about {records / 2**30:.3g} GiB, more than this process may have "
                f"({available / 2**30:.3g} GiB)")
    return (f"{trajectories} trajectories need about {state / 2**30:.3g} GiB of memory, more than this process may "
            f"have ({available / 2**30:.3g} GiB)")


def memory_refusal(trajectories, records=0):
    """:func:`memory_problem` with what to lower -> None, or ("trajectories" where the state alone does not fit,
    else "collisions": the records are too many, problem)."""
    problem = memory_problem(trajectories, records=records)
    if problem is None:
        return None
    return ("collisions" if memory_problem(trajectories) is None else "trajectories"), problem


def records_bytes(cfg):
    """Bytes of the records a run kept in memory holds (:class:`MemorySink`: every recorded field of every record
    of every trajectory) -> int (a Python int: 10¹⁸ collisions do not overflow)."""
    n = cfg.dimension
    per = sum(FIELD[name].size(n) * np.dtype(FIELD[name].dtype).itemsize for name in cfg.output.record)
    return int(cfg.run.trajectories) * (int(cfg.run.collisions) // int(cfg.output.every) + 1) * int(per)


class Simulation:
    """The state of M trajectories of one validated experiment, advanced block by block.

    ``state``: the state to start from (a resumed run, sampled states) instead of the experiment's initial one;
    ``stop_wall``: end a trajectory right after it hits this wall (−1: never; the return-angle experiment);
    ``force_bits`` / ``drop_bits``: bits engine.S_* to add to / take from what this run needs — scripts/bench.py
    measures what each skip saves by making the kernel do the work anyway (the results stay the same). The
    numerical options come from ``cfg.numerics`` (:class:`rbx.model.Numerics`)."""

    def __init__(self, cfg, state=None, stop_wall=-1, force_bits=0, drop_bits=0):
        self.cfg = cfg
        self.geom = cfg.geometry()
        self.rules = compile_rules(cfg.wall_rules, self.geom)
        n = self.n = cfg.dimension
        M = self.M = cfg.run.trajectories
        self.record = cfg.output.record
        self.mask = sum(FIELD[f].bit for f in self.record)
        # the orientation is followed in 2D (θ += τ·ω, one multiply-add a flight: a kernel of its own without it
        # would be one more compile for every 2D scene that records it; ns per collision without → with it, CPU time,
        # 3·10⁶ collisions, 3 interleaved runs each, loaded machine: strip 11.1–11.4 → 10.7–11.2, rectangle
        # 19.5–20.4 → 20.0–20.8, Sinai 25.4–26.6 → 25.3–26.1, circle 31.4–31.8 → 31.4–31.7) and in 3D only when a
        # hemisphere rule or the recorded field needs it (the rotation turns A's three columns a flight)
        # (docs/reference.md §7)
        self.follow_orientation = n == 2 or self.rules.uses_orientation or "orientation" in self.record
        self.keys = stream_keys(cfg.run.seed, np.arange(M), PURPOSE_RULES)
        if state is None:
            state = self._initial_state()
        self.pos = np.ascontiguousarray(state["position"], dtype=float).reshape(M, n)
        self.vel = np.ascontiguousarray(state["velocity"], dtype=float).reshape(M, n)
        self.W = spin_matrices(state["angular_velocity"], M, n)
        orient = np.asarray(state["orientation"], float)
        self.theta = orient.reshape(M).copy() if n == 2 else np.zeros(M)
        self.A = orient.reshape(M, 3, 3).copy() if n == 3 else np.zeros((M, 3, 3))
        self.time = np.asarray(state.get("time", np.zeros(M)), float).copy()
        self.ncoll = np.asarray(state.get("collisions", np.zeros(M)), np.int64).copy()
        self.draws = np.asarray(state.get("draws", np.zeros(M)), np.int64).copy()
        self.alive = np.asarray(state.get("alive", np.ones(M)), np.bool_).copy()
        self.last_wall = np.asarray(state.get("last_wall", -np.ones(M)), np.int64).copy()
        self.last_rank = np.asarray(state.get("last_rank", np.zeros(M)), np.int64).copy()
        self.tol = END_TOLERANCE * self.geom.size
        kap, R = cfg.ball.kappa, cfg.ball.radius
        self.energy0 = np.asarray(state["energy"] if "energy" in state else energy(self.vel, self.W, R, kap),
                                  float).copy()
        self.numerics = cfg.numerics
        # the compensated sums' running error terms (numerics.compensated): part of the state, saved with it, so
        # that a resumed run continues the sums exactly as an uninterrupted one
        self._comp = (np.asarray(state["compensation"], float).reshape(M, n + 1).copy() if "compensation" in state
                      else np.zeros((M, n + 1)))
        self.stop_wall = int(stop_wall)
        self.force_bits = int(force_bits)
        self.drop_bits = int(drop_bits)
        #: a :class:`rbx.cluster.Cluster` to run the blocks on (None: this machine's threads)
        self.cluster = None
        #: callables giving back the run locks (:func:`rbx.locks.acquire_lock`) this run holds, called by
        #: :func:`rbx.driver.stream` when its file is done
        self.locks = []
        #: a resumed run: the record chunks its kill tore, read from their raw bytes ({field: {offset: chunk}},
        #: :func:`rbx.resume.load`), written back by :func:`rbx.resume.make_consistent`
        self.torn_chunks = {}

    def _initial_state(self):
        cfg = self.cfg
        if cfg.initial[0] == "point_particle":
            return sample_point_particle(self.geom, cfg.run.seed, 0, self.M)
        if cfg.initial[0] == "sample":
            return sample_billiard(self.geom, cfg.ball.kappa, cfg.ball.radius, cfg.run.seed, cfg.initial[1], 0,
                                   self.M)
        return explicit_states(cfg.initial, self.n, self.M)

    # -- records ------------------------------------------------------------------------------------------------
    def current_record(self):
        """The present state of every trajectory as one record: dict field -> (M, 1, …)."""
        M = self.M
        values = {"time": self.time, "position": self.pos, "velocity": self.vel,
                  "angular_velocity": spin_vector(self.W), "orientation": self.theta if self.n == 2 else self.A,
                  "wall": self.last_wall, "rank": self.last_rank}
        return {f: np.asarray(values[f]).reshape((M, 1) + FIELD[f].shape(self.n)).astype(FIELD[f].dtype)
                for f in self.record}

    def final_state(self):
        return {"time": self.time, "position": self.pos, "velocity": self.vel, "angular_velocity": spin_vector(self.W),
                "orientation": self.theta if self.n == 2 else self.A, "collisions": self.ncoll,
                "draws": self.draws, "alive": self.alive, "last_wall": self.last_wall, "last_rank": self.last_rank,
                "energy": self.energy0, **({"compensation": self._comp} if self.numerics.compensated else {})}

    def block_buffers(self, records):
        """Record buffers for a block of ``records`` records per trajectory (zero-size for fields not recorded)."""
        return record_buffers(self.record, self.n, self.M, records)

    def records_per_block(self):
        every = self.cfg.output.every
        per_record = 1 + sum(FIELD[f].size(self.n) for f in self.record)
        by_memory = max(1, BLOCK_VALUES // (self.M * per_record))
        by_work = max(1, block_work(self.geom) // (self.M * every))
        return min(by_memory, by_work)

    # -- running ------------------------------------------------------------------------------------------------
    def spec(self):
        """What the kernel must do for this run, as bits engine.S_*; those in engine.COMPILED_BITS are compiled in
        (what is not needed is not in the machine code), the others are tested at run time."""
        r = self.rules
        rough = r.max_rank > 0
        bits = engine.make_spec(
            self.n, orient=self.follow_orientation, spin=rough, tree=r.uses_orientation or r.uses_random,
            record=bool(self.record), compensated=self.numerics.compensated,
            snap=self.numerics.snap, slab=self.geom.slab, stop_wall=self.stop_wall >= 0,
            periodic=self.geom.lattice is not None, exit=bool(np.any(r.kind == rules.EXIT)),
            axes=self.geom.axis_box is not None, round_hemisphere=r.round_hemisphere, blend=r.uses_random,
            shared=r.shared_pick)
        return (bits | self.force_bits) & ~self.drop_bits

    def kernel_groups(self):
        """What every trajectory of the run shares, as the kernels take it -> (engine.Table, engine.Rules,
        engine.Settings). Plain arrays and scalars: :mod:`rbx.cluster` sends them to the workers as they are."""
        geom, ball = self.geom, self.cfg.ball
        table = engine.make_table(geom, self.tol)
        settings = engine.Settings(flags=int(self.spec()), stop_wall=self.stop_wall, every=int(self.cfg.output.every),
                                   mask=int(self.mask), renorm_every=int(self.numerics.renormalize),
                                   R=float(ball.radius), kappa=float(ball.kappa))
        return table, self.rules.kernel_arrays(), settings

    def state_group(self):
        """The M trajectories' state as the kernels take it -> engine.State of this simulation's own arrays
        (writing into a row writes into the simulation)."""
        return engine.State(pos=self.pos, vel=self.vel, W=self.W, theta=self.theta, A=self.A, time=self.time,
                            ncoll=self.ncoll, draws=self.draws, alive=self.alive, keys=self.keys,
                            last_wall=self.last_wall, last_rank=self.last_rank, energy0=self.energy0,
                            comp=self._comp)

    def advance(self, stop, bufs):
        """Advance every live trajectory to ``stop`` collisions in all -> records written per trajectory (M,)."""
        return advance_state(self.kernel_groups(), self.state_group(), stop, bufs)

    def finished(self):
        """Whether the run is done: every trajectory still running has made ``run.collisions`` collisions."""
        return not self.alive.any() or int(self.ncoll[self.alive].min()) >= self.cfg.run.collisions

    def compile_kernels(self):
        """Compile (or load from the cache) this run's kernels now, while Ctrl-C can still abort at once: a first
        compile takes several seconds, and once the run has started a signal is only seen between blocks. (Not for
        a run on a cluster: its workers compile, the client never runs a kernel.)"""
        if self.cluster is None:
            self.advance(0, self.block_buffers(0))   # no trajectory is below collision 0: nothing moves

    def run(self, sink, progress=None, should_stop=None, write_initial=None):
        """Run to ``run.collisions`` collisions, streaming records to ``sink`` -> True if complete.

        ``sink.write(block, nrec)`` gets dicts field -> (M, b, …) with rows past ``nrec[j]`` filled with NaN / −1;
        ``sink.checkpoint(sim)`` follows a block once :data:`CHECKPOINT_SECONDS` have passed since the last one, and
        the last block. ``should_stop()`` is polled before each block.
        ``write_initial``: write record 0 first (default: when no trajectory has collided yet; a resumed run
        whose file holds record 0 already passes False).

        The blocks come from this machine's thread pool, or, with ``self.cluster`` set (a
        :class:`rbx.cluster.Cluster`), from the workers of a Dask cluster: the same blocks, the same sink."""
        self.check_finite()
        moving = self.alive.copy()      # the trajectories a block can change: only theirs are checked after it
        if write_initial is None:
            write_initial = bool(np.all(self.ncoll == 0))
        if self.record and write_initial:
            sink.write(self.current_record(), np.ones(self.M, np.int64))
        blocks = (self._blocks(should_stop, progress) if self.cluster is None
                  else self.cluster.blocks(self, should_stop, progress))
        last, unsaved = time.monotonic(), False
        try:
            for block, nrec, at_end in blocks:          # at_end: the state at the block's end
                # before anything of the block is written: the file stays valid. Only the trajectories alive when
                # the block began (a NaN ends one as an escape would): checking all M after every block made a
                # return loop of 2·10⁶ samples, whose blocks are short while a few trajectories are still out, take
                # time that grew as M × blocks
                at_end.check_finite(np.flatnonzero(moving))
                moving = at_end.alive.copy()
                if block is not None:
                    sink.write(block, nrec)
                unsaved = True
                if time.monotonic() - last >= CHECKPOINT_SECONDS:
                    sink.checkpoint(at_end)
                    last, unsaved = time.monotonic(), False
        finally:
            blocks.close()        # a cluster's tasks still running are cancelled; a block computed ahead is undone
        if not self.finished():
            if unsaved:                       # stopped (Ctrl-C, a trajectory escaped…): save where it stopped
                sink.checkpoint(self)
            return False
        sink.checkpoint(self)
        return True

    def check_finite(self, rows=None):
        """Raise :class:`NonFiniteState` if a trajectory's state is no longer finite (in the kernel, a NaN
        position finds no wall ahead and would end like an escape: a shortened trajectory, silently). ``rows``:
        the trajectories to check (default: all)."""
        # the orientation too: a NaN there (a 3D start whose rotation vector overflowed) was recorded at every
        # collision of a run that ended complete, exit 0
        rows = np.arange(self.M) if rows is None else np.asarray(rows)
        bad = ~(np.isfinite(self.pos[rows]).all(axis=1) & np.isfinite(self.vel[rows]).all(axis=1)
                & np.isfinite(self.W[rows]).all(axis=(1, 2)) & np.isfinite(self.time[rows])
                & np.isfinite(self.theta[rows]) & np.isfinite(self.A[rows]).all(axis=(1, 2)))
        if bad.any():
            j = int(rows[np.argmax(bad)])
            orientation = (f", orientation {self.theta[j]}" if self.n == 2 else
                           f", orientation {self.A[j].tolist()}") if not (np.isfinite(self.theta[j])
                                                                       and np.isfinite(self.A[j]).all()) else ""
            raise NonFiniteState(f"trajectory {j} (and {int(bad.sum()) - 1} more) reached a non-finite state by "
                                 f"collision {int(self.ncoll[j])}: position {self.pos[j].tolist()}, velocity "
                                 f"{self.vel[j].tolist()}{orientation}")

    def _blocks(self, should_stop=None, progress=None):
        """The local blocks of a run: advance on this machine's threads -> yields (block or None, nrec, at_end) per
        block, ``at_end`` the state at its end (the simulation itself when one block follows the other);
        ``progress(done, total)`` once each is checkpointed.

        A run that records computes the next block while the caller writes this one (:data:`AHEAD`; the kernels
        release the GIL, so the two overlap): the blocks take two record buffers in turn, and ``at_end`` is a copy
        of the state at the block's end, which the caller checks and checkpoints, since the simulation's own state
        is then already moving on. ``should_stop`` is polled once per block, before the
        next one starts. When the caller stops taking blocks (an error, a closed generator) while one is computed
        ahead, that block is waited for and undone: the simulation is put back to the end of the last block
        handed out."""
        total = self.cfg.run.collisions
        every = self.cfg.output.every
        if self.record:
            per = self.records_per_block()
            step = per * every
        else:
            work = block_work(self.geom)
        done = int(self.ncoll[self.alive].min()) if self.alive.any() else total

        def stop_of(done):
            if self.record:
                return min(total, (done // step + 1) * step)
            # nothing recorded: the block's work shared among the trajectories still running, so that a return
            # loop whose last few trajectories are still out takes long blocks, not one collision a block each
            # (every block costs a pass over all M: 2·10⁶ samples took minutes)
            return min(total, done + max(1, work // max(1, int(np.count_nonzero(self.alive)))))

        if not (self.record and AHEAD and self._state_bytes() * 4 <= per * self.M * 8 *
                (1 + sum(FIELD[f].size(self.n) for f in self.record))):
            # records not written, or a state so large (many trajectories, few records per block) that copying
            # it for each block would cost more than the overlap saves: one block after the other
            bufs = self.block_buffers(per if self.record else 0)
            while done < total and self.alive.any():
                if should_stop is not None and should_stop():
                    return
                stop = stop_of(done)
                nrec = self.advance(stop, bufs)
                yield (records_block(bufs, nrec, self.record, self.n) if self.record else None), nrec, self
                done = stop
                if progress is not None:
                    progress(done, total)
            return

        bufs = [self.block_buffers(per), self.block_buffers(per)]
        pool = ThreadPoolExecutor(1, thread_name_prefix="rbx-block")
        previous = self.frozen()          # the state the file accounts for once the last block handed out is written
        ahead = None                      # the block being computed
        try:
            if done >= total or not self.alive.any() or (should_stop is not None and should_stop()):
                return
            stop, k = stop_of(done), 0
            ahead = pool.submit(self.advance, stop, bufs[k])
            while True:
                nrec = ahead.result()
                ahead = None
                at_end = self.frozen()
                block = records_block(bufs[k], nrec, self.record, self.n)
                done = stop
                # polled once per block, as without the overlap: here before the next block starts
                more = (done < total and bool(self.alive.any())
                        and not (should_stop is not None and should_stop()))
                if more:
                    stop, k = stop_of(done), 1 - k
                    ahead = pool.submit(self.advance, stop, bufs[k])
                previous = at_end
                yield block, nrec, at_end
                if progress is not None:
                    progress(done, total)
                if not more:
                    return
        finally:
            if ahead is not None:         # stopped by an error or a closed generator with a block being computed:
                wait([ahead])             # a kernel cannot be interrupted; let it end, then undo its block
                self.restore(previous)
            pool.shutdown(wait=True)

    def frozen(self):
        """A copy of this simulation whose state arrays are copies (the rest shared): the state as it is now, for
        checks and checkpoints while the simulation itself moves on (:meth:`_blocks`)."""
        twin = copy.copy(self)
        for name in STATE_ARRAYS:
            setattr(twin, name, getattr(self, name).copy())
        return twin

    def _state_bytes(self):
        return sum(getattr(self, name).nbytes for name in STATE_ARRAYS)

    def restore(self, frozen):
        """Put this simulation's state back to that of :meth:`frozen`'s copy (in place: the arrays stay the ones the
        kernels were given)."""
        for name in STATE_ARRAYS:
            np.copyto(getattr(self, name), getattr(frozen, name))


def record_buffers(record, n, M, records):
    """Record buffers (engine.Records fields) for M trajectories and ``records`` records each, zero-size for the
    fields not in ``record``."""
    bufs = {}
    for f in FIELDS:
        size = records if f.name in record else 0
        # scalar fields are (M, records); the others (M, records, values per record), flat
        bufs[f.name] = np.empty((M, size) if f.kind == "scalar" else (M, size, f.size(n)), dtype=f.dtype)
    return bufs


def advance_state(groups, state, stop, bufs):
    """Advance the live trajectories of ``state`` (engine.State) to ``stop`` collisions with the kernel groups
    ``(table, rules, settings)`` of :meth:`Simulation.kernel_groups` -> records written per trajectory.

    A row's numbers depend only on the row (its stream key is in ``state.keys``): the same code advances a whole
    run here and a slice of it on a cluster's worker (:mod:`rbx.cluster`)."""
    table, rules, settings = groups
    M = state.pos.shape[0]
    return engine.run_advance_all(np.full(M, stop, np.int64), table, rules, settings, state, engine.Records(**bufs))


def records_block(bufs, nrec, record, n):
    """The records of a block: dict field -> (M, b, …) views of the buffers, b = nrec.max(), rows past
    ``nrec[j]`` filled with NaN / −1."""
    b = int(nrec.max()) if len(nrec) else 0
    block = {f: bufs[f][:, :b].reshape((len(nrec), b) + FIELD[f].shape(n)) for f in record}
    _blank_tails(block, nrec, b)
    return block


def _blank_tails(block, nrec, b):
    short = np.nonzero(nrec < b)[0]
    for j in short:
        for f, arr in block.items():
            arr[j, nrec[j]:] = FIELD[f].fill


class MemorySink:
    """Collects the records of a run in memory: ``records[field]`` (M, T, …), ``count`` (M,)."""

    def __init__(self):
        self.blocks, self.count, self.final = [], None, None

    def write(self, block, nrec):
        self.blocks.append({f: a.copy() for f, a in block.items()})
        self.count = nrec.copy() if self.count is None else self.count + nrec

    def checkpoint(self, sim):
        self.final = {k: np.array(v, copy=True) for k, v in sim.final_state().items()}

    @property
    def records(self):
        if not self.blocks:
            return {}
        return {f: np.concatenate([b[f] for b in self.blocks], axis=1) for f in self.blocks[0]}


def run_in_memory(cfg):
    """Run a validated config without writing files -> (records dict, count, final state). For the API and tests."""
    sim = Simulation(cfg)
    sink = MemorySink()
    sim.run(sink)
    return sink.records, sink.count, sink.final
