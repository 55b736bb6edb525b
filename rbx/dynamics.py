"""Dynamics of rough billiards (docs/reference.md §10): the Lyapunov spectrum (:func:`lyapunov`), escape and return times
(:func:`escape_times`), and the flow's Jacobian (:func:`flow_jacobian`, for checking the tangent map).

The linearised dynamics and Benettin's method run in compiled code (:mod:`rbx.tangent`) along the engine's own
orbit; the derivation of the tangent map is in docs/tangent-map.md, the escape statistics in docs/dynamics.md.
"""
import contextlib
import os
from dataclasses import dataclass, field

import math

import numpy as np

from . import engine
from .analysis import scene_title, wilson
from .api import cluster_for, load
from .cluster import Cluster
from .ensembles import orbit_rows
from .engine import State
from .physics import spin_vector
from .reader import Run
from .model import ConfigError
from .simulation import STATE_BYTES, Simulation, memory_problem, record_buffers
from .tangent import coordinate_names, tangent_dimension

__all__ = ["lyapunov", "Lyapunov", "flow_jacobian", "escape_times", "Escape"]


# ---- the tangent dynamics ------------------------------------------------------------------------------------------

#: Benettin's re-orthonormalisation after at most this many collisions (and whenever a trajectory stops) …
ORTHO_EVERY = 16
#: … and as soon as the first tangent vector has grown by 16 since the last one (its squared length above 256): the
#: diagonal of a product of triangular factors is the product of their diagonals, so the sums of the stretches'
#: logarithms are the same in exact arithmetic as with a QR after every collision. The rows, never let grow apart by
#: much more than 16² before they are made orthonormal again, lose to rounding about 16² ulp of the smallest
#: stretch per QR: λ₁ and the spectrum's sum stay within 1e-12 of a QR per collision, the nearly neutral
#: exponents move by what any change of rounding moves them (docs/tangent-map.md: measured on every example)
ORTHO_GROWTH = 256.0
#: … with one vector there is nothing to keep apart: it is normalised every ORTHO_EVERY collisions, or sooner only
#: before its length could overflow (rough box, λ₁ alone: 120 → 110 ns per collision; λ₁ to 1e-12, tested)
ORTHO_GROWTH_ONE = 1e100
#: the tangent vectors' velocity-like coordinates are stored in a time unit of the orbit (:func:`time_unit`) only
#: when its flights last longer than 2^TIME_UNIT_BITS or shorter than its inverse; else in the config's own unit
TIME_UNIT_BITS = 10
#: … judged by the median flight of the first PROBE_TRAJECTORIES trajectories' first PROBE_COLLISIONS collisions
PROBE_TRAJECTORIES = 8
PROBE_COLLISIONS = 64
#: the whole spectrum of a volume-preserving flow sums to 0: a sum above this fraction of Σ|λ| is refused
SUM_TOLERANCE = 1e-6

def initial_basis(d):
    """The tangent vectors' start: a fixed orthonormal basis of R^d (rows) in general position, no row in a
    coordinate block. The coordinate axes were the start before: where a block of the tangent map never feeds back
    (the orientation and spin of a specular table, the orientation of a rough one), the axes inside it kept their
    vectors to themselves, so Benettin's first K vectors were not the K most expanding (the 3D box's first 8
    held its most contracting exponent) and the whole spectrum had to be sorted. From a basis in general position
    the k-th vector follows the k-th exponent and Benettin's order is the decreasing one (to the run's error
    among nearly equal exponents). Entries from an integer hash (splitmix64), orthonormalised by Gram–Schmidt twice in plain
    Python arithmetic: the same bits on every machine; row k depends only on rows ≤ k."""
    def entry(k):               # splitmix64's output of the counter k, in [−½, ½)
        z = (k * 0x9E3779B97F4A7C15) & 0xFFFFFFFFFFFFFFFF
        z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & 0xFFFFFFFFFFFFFFFF
        z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & 0xFFFFFFFFFFFFFFFF
        return ((z ^ (z >> 31)) >> 11) / 2.0 ** 53 - 0.5
    rows = []
    for i in range(d):
        y = [entry(i * d + j + 1) for j in range(d)]
        for _ in range(2):
            for q in rows:
                c = sum(a * b for a, b in zip(q, y))
                y = [b - c * a for a, b in zip(q, y)]
        norm = math.sqrt(sum(b * b for b in y))
        rows.append([b / norm for b in y])
    return np.array(rows)


class NothingMeasured(ValueError):
    """:func:`lyapunov` found nothing to measure: every trajectory left the table during its warm-up, or too few
    segments were measured for an error. A study stores no value (NaN) at such a point and goes on."""


class _Tangent:
    """M trajectories of an experiment as ``rbx simulate`` runs them (:class:`rbx.simulation.Simulation`: the same
    initial states, random streams, rules and numerical options) with tangent vectors beside them: the engine's
    own loop with the bit ``S_TANGENT`` (:mod:`rbx.engine`, :mod:`rbx.tangent`), nothing recorded. The state's
    orientation is followed in 2D (one multiply-add; the loop is then the one :func:`flow_jacobian` compiles) and,
    in 3D, only with ``orientation`` (:func:`flow_jacobian`'s final state) or when a rule reads it — not for a
    recorded field, since nothing is recorded: the tangent step turns the orientation's tangent coordinates
    itself, and the 3D update of the state's orientation cost the rough box 36 ns per collision (λ₁ alone 113 →
    80 ns). It never changes the orbit, so the orbit is the simulation's, bit for bit.
    ``vectors``: follow the first K tangent vectors only (default all d)."""

    def __init__(self, exp, state=None, vectors=None, orientation=False):
        orient = engine.S_ORIENT if (exp.dimension == 2 or orientation) else 0
        sim = self.sim = Simulation(exp, state=state, force_bits=engine.S_TANGENT | orient,
                                    drop_bits=engine.S_RECORD | engine.S_STOP_WALL)
        if not orient and not sim.rules.uses_orientation:
            sim.drop_bits |= engine.S_ORIENT      # followed for a recorded field only: nothing is recorded here
        self.n, self.M = sim.n, sim.M
        self.d = tangent_dimension(self.n)
        self.groups = sim.kernel_groups()
        self.state = sim.state_group()
        K = self.d if vectors is None else int(vectors)
        # the K tangent vectors are the rows of Y[j], at the start the first K rows of one fixed generic basis
        # (initial_basis): the first K vectors of Benettin's method do not depend on the others, so K of them
        # give the K leading exponents of the whole basis, bit for bit
        self.Y = np.repeat(initial_basis(self.d)[None, :K], self.M, axis=0)
        self.sums = np.zeros((self.M, K))

    def probe(self):
        """Copies of the first initial states, from which :func:`time_unit` judges the orbit's time scale."""
        return State(*(np.array(x[:PROBE_TRAJECTORIES]) for x in self.state))

    def kernel(self):
        """What the kernel needs besides the trajectories' rows: the groups (Table, Rules, Settings) — the same for
        every trajectory, so a worker of a cluster gets them with each slice (:func:`_measure_slice`)."""
        return self.groups

    def advance(self, stop, t_end=np.inf, ortho=None, grow=None):
        """Advance every live trajectory to ``stop`` collisions in all or to time ``t_end`` (``ortho``, ``grow``:
        :class:`rbx.engine.Tangent`'s, default :data:`ORTHO_EVERY`, :data:`ORTHO_GROWTH`)."""
        _advance(self.kernel(), self.state, self.Y, self.sums, stop, t_end, ortho, grow)


def time_unit(kernel, probe):
    """The time unit u of the tangent vectors' velocity-like coordinates (:class:`rbx.engine.Tangent`): the power
    of two nearest the median flight time of the trajectories ``probe`` (copies of the first
    :data:`PROBE_TRAJECTORIES` initial states) over their first :data:`PROBE_COLLISIONS` collisions, or 1 when
    that lies within 2^±:data:`TIME_UNIT_BITS` (every table and speed of order one: the config's own units).

    Why: Benettin's Gram–Schmidt measures a tangent vector's length as √(|δa|² + |δv|²), a length and a velocity
    added as numbers. In a table of size 1e20, or at speeds of 1e-30, a flight turns δv into a δa 1e20 or 1e30
    times larger, the velocity part of every re-orthonormalised vector falls below the rounding of the position
    part, and the contracting exponents came out large and positive (the sum of the spectrum, 0 for these maps,
    was 20 times λ₁). Measured as √(|δa|² + u²|δv|²) with u a flight time, both parts are of one size. A power of
    two changes no bit of the arithmetic but the scale; the exponents do not depend on the metric. The median,
    not the mean: one flight of 1e149 before flights of 1 (a slow start that a spin turns into a fast orbit)
    would set the unit by the one."""
    M, d = probe.pos.shape[0], tangent_dimension(probe.pos.shape[1])
    if M == 0:
        return 1.0
    state = State(*(np.array(x) for x in probe))
    Y, sums = np.zeros((M, 0, d)), np.zeros((M, 0))
    times = [state.time.copy()]
    for _ in range(PROBE_COLLISIONS):
        _advance(kernel, state, Y, sums, state.ncoll + 1, ortho=0, grow=np.inf)
        times.append(state.time.copy())
    with np.errstate(invalid="ignore"):
        flights = np.diff(np.array(times), axis=0).ravel()
    flights = flights[np.isfinite(flights) & (flights > 0)]
    if len(flights) == 0:
        return 1.0
    bits = int(np.round(np.log2(np.median(flights))))
    if abs(bits) <= TIME_UNIT_BITS:
        return 1.0
    return math.ldexp(1.0, max(-900, min(900, bits)))


def _advance(kernel, state, Y, sums, stop, t_end=np.inf, ortho=None, grow=None, unit=1.0):
    """Advance the live trajectories of ``state`` (and their tangent vectors ``Y``, log-stretch sums ``sums``) to
    ``stop`` collisions in all or to time ``t_end``, on the engine's pool of threads
    (:func:`rbx.engine.run_advance_all`). Each trajectory's numbers depend only on its own rows (its random
    stream is keyed by its global index, in ``state.keys``): not on the thread count, nor on which other
    trajectories share the arrays."""
    table, rules, settings = kernel
    M, n = state.pos.shape
    stop = np.broadcast_to(np.asarray(stop, np.int64), (M,)).copy()
    t_end = np.broadcast_to(np.asarray(t_end, float), (M,)).copy()
    ortho = ORTHO_EVERY if ortho is None else int(ortho)
    if grow is None:
        grow = ORTHO_GROWTH if Y.shape[1] > 1 else ORTHO_GROWTH_ONE
    grow = float(grow)
    tangent = engine.Tangent(Y=Y, sums=sums, t_end=t_end, ortho=ortho, grow=grow, unit=float(unit))
    out = engine.Records(**record_buffers((), n, M, 0))
    engine.run_advance_all(stop, table, rules, settings, state, out, tangent)


def _measure(kernel, state, Y, sums, cuts, probe):
    """Benettin's method on the trajectories of ``state``: a warm-up to ``cuts[0]`` collisions, then one segment
    to each of ``cuts[1:]`` -> dict of per-trajectory arrays (``seg_sums`` (M, S, d), ``seg_time`` (M, S),
    ``total_sums`` (M, d), ``total_time``, ``collisions``, ``ended`` (M,)). Row by row, so that a slice of the
    trajectories gives the same rows as the whole ensemble (how :func:`lyapunov` runs on a cluster); ``probe``, the
    ensemble's first initial states (:func:`time_unit`), is the same for every slice."""
    M, d = Y.shape[:2]
    segments = len(cuts) - 1
    unit = time_unit(kernel, probe)
    if cuts[0] > 0:
        _advance(kernel, state, Y, sums, cuts[0], unit=unit)
    sums0, t0, c0, alive0 = sums.copy(), state.time.copy(), state.ncoll.copy(), state.alive.copy()
    seg_sums = np.zeros((M, segments, d))
    seg_time = np.zeros((M, segments))
    for s in range(segments):
        before, tb = sums.copy(), state.time.copy()
        _advance(kernel, state, Y, sums, cuts[s + 1], unit=unit)
        seg_sums[:, s] = sums - before
        seg_time[:, s] = state.time - tb
    return {"seg_sums": seg_sums, "seg_time": seg_time, "total_sums": sums - sums0, "total_time": state.time - t0,
            "collisions": state.ncoll - c0, "ended": ~state.alive,
            # an exit's contact counts as a collision (as in rbx simulate) but maps nothing
            "exits": alive0 & ~state.alive & (state.last_rank == -1)}


class _SliceTask:
    """One slice of a Lyapunov ensemble for a worker of a Dask cluster: the kernel's data and the slice's rows
    (state, stream keys of the global trajectory indices included; tangent vectors; sums), and the collision
    cuts. A plain object, so that Dask sends it as it is."""

    def __init__(self, kernel, state, Y, sums, cuts, probe):
        self.kernel, self.state, self.Y, self.sums, self.cuts, self.probe = kernel, state, Y, sums, cuts, probe


def _measure_slice(task):
    """Runs on a worker: :func:`_measure` on one slice -> its per-trajectory arrays. A pure function of the task
    (a worker lost mid-task: Dask runs it again elsewhere, with the same result)."""

    def own(x):       # writable copies: Dask may hand read-only arrays, another type to Numba (a new compile)
        return np.array(x) if isinstance(x, np.ndarray) else x

    table, rules, settings = task.kernel
    kernel = (type(table)(*map(own, table)), type(rules)(*map(own, rules)), settings)
    state = State(*map(own, task.state))
    return _measure(kernel, state, own(task.Y), own(task.sums), own(task.cuts), State(*map(own, task.probe)))


#: bytes per trajectory, generously, beyond its state (rbx.simulation.STATE_BYTES): its tangent vectors (at most
#: 12 × 12 numbers) and their sums per segment
TANGENT_BYTES = 2000


def _load(experiment, collisions=None, trajectories=None, seed=None):
    overrides = {k: v for k, v in (("collisions", collisions), ("trajectories", trajectories), ("seed", seed))
                 if v is not None}
    return load(experiment, overrides or None)


def flow_jacobian(experiment, t_end, *, collisions=None, trajectories=None, seed=None, state=None):
    """The Jacobian of the time-``t_end`` map of the flow at each trajectory's initial state -> (J (M, d, d),
    final state dict). A trajectory stops at time ``t_end`` or after ``run.collisions`` collisions, whichever
    comes first (then J is the Jacobian of the flow up to just after that collision).

    Tangent coordinates (:func:`rbx.tangent.coordinate_names`): ``[a, R√κ·orientation, v, R√κ·ω]``; the 3D
    orientation's coordinate is the space-frame rotation vector δφ of δA = [δφ]×A. Collisions on the way are
    linearised with the rule drawn at each (docs/tangent-map.md). For checking the tangent map against finite
    differences of the engine. The final state's keys are those of a run's ``final`` (and ``W``, ``theta``, ``A``).
    ``state``: initial states as :class:`rbx.simulation.Simulation` takes them (a dict
    of arrays: position, velocity, angular_velocity, orientation — 3D as matrices) instead of the experiment's."""
    exp = _load(experiment, collisions, trajectories, seed)
    if state is not None:
        state = {k: np.array(v, copy=True) for k, v in state.items()}   # the kernels write into them
    tan = _Tangent(exp, state, orientation=True)
    tan.Y[:] = np.eye(tan.d)                  # the Jacobian: from the identity
    tan.advance(exp.run.collisions, t_end, ortho=0)
    st = tan.state
    final = {"time": st.time.copy(), "position": st.pos.copy(), "velocity": st.vel.copy(), "W": st.W.copy(),
             "angular_velocity": spin_vector(st.W), "theta": st.theta.copy(), "A": st.A.copy(),
             "collisions": st.ncoll.copy(), "alive": st.alive.copy(), "draws": st.draws.copy(),
             "last_wall": st.last_wall.copy(), "last_rank": st.last_rank.copy(), "compensation": st.comp.copy()}
    return np.ascontiguousarray(tan.Y.transpose(0, 2, 1)), final    # rows of Y: the columns of J


#: what the result's time and collisions include (to_dict, rbx lyapunov's text)
COUNTED = ("time and collisions of every trajectory after its warm-up (the warm-up excluded); an exit's contact "
           "counts as a collision, as in rbx simulate, and the flight to it as time")

#: a trajectory whose own λ₁ per unit time is below this is counted regular (:meth:`Lyapunov.regular_share`; the
#: studies' ``regular_share`` observable takes the same default)
REGULAR_THRESHOLD = 0.02


@dataclass
class Lyapunov:
    """The Lyapunov spectrum of the flow (per unit time, largest first: Benettin's order) and its standard error.

    ``exponents`` (d,): Σ log-stretches / Σ time over the measured segments of every trajectory (copies of one orbit
    counted once: :func:`rbx.ensembles.start_groups`), in Benettin's order (from a start in general position:
    decreasing where the run resolves the gaps, nearly equal exponents possibly out of order within their errors);
    ``stderr`` (d,): the standard error from the spread of the segment estimates (batch means: ``segments``
    per trajectory × ``trajectories``, each weighted by its duration), or from the spread of the trajectories'
    own estimates if that is larger (a table that is not ergodic); ``per_trajectory`` (M, d);
    ``segment_exponents`` (M, S, d) and ``segment_times`` (M, S); ``time`` (M,) and ``collisions`` (M,) measured
    (after ``warmup`` collisions; counted as ``rbx simulate`` counts them: an exit's contact is a collision); ``coordinates``: the tangent coordinates' names."""
    exponents: np.ndarray
    stderr: np.ndarray
    per_trajectory: np.ndarray
    segment_exponents: np.ndarray
    segment_times: np.ndarray
    time: np.ndarray
    collisions: np.ndarray
    warmup: int
    coordinates: tuple
    title: str = ""
    ended: np.ndarray = field(default=None)
    #: the first trajectory of each distinct orbit (copies of one orbit count once: :func:`rbx.ensembles.start_groups`);
    #: None: every trajectory
    orbits: np.ndarray = field(default=None)

    def __repr__(self):
        """A summary (the arrays of every segment made the repr of a short run 7.7 kB long): the exponents per unit
        time with their errors, per collision, what was measured, the regular share."""
        def numbers(x):
            return "[" + ", ".join(f"{v:.4g}" for v in np.asarray(x, float)) + "]"
        regular, measured = self.regular()
        return (f"Lyapunov({self.title + ': ' if self.title else ''}exponents per unit time {numbers(self.exponents)} "
                f"± {numbers(self.stderr)}, per collision {numbers(self.per_collision())}; "
                f"{len(self.time)} trajectories, {int(np.sum(self.collisions))} collisions over time "
                f"{float(np.sum(self.time)):.6g} after a warm-up of {self.warmup} each; regular {regular} of "
                f"{measured} (own λ1 < {REGULAR_THRESHOLD:g} per unit time))")

    def per_collision(self, values=None):
        """The exponents per collision: per unit time × the measured time / the measured collisions (``values``:
        other numbers per unit time to convert, such as :attr:`stderr`)."""
        values = self.exponents if values is None else np.asarray(values, float)
        collisions = float(np.sum(self.collisions))
        return values * (float(np.sum(self.time)) / collisions) if collisions > 0 else values * np.nan

    def measured(self):
        """The trajectories that have their own exponents: a trajectory that left the table (an exit, an escape)
        during its warm-up measured nothing (its row of ``per_trajectory`` is NaN) -> int."""
        return int(np.sum(np.isfinite(self.per_trajectory[:, 0])))

    def regular(self, threshold=REGULAR_THRESHOLD):
        """The regular orbits among the measured ones (:meth:`measured`): those whose own λ₁ (per unit time) is
        below ``threshold`` and that stayed in the table to the end -> (regular, measured)."""
        lam1 = self.per_trajectory[:, 0]
        measured = np.isfinite(lam1)
        if self.orbits is not None:         # copies of one orbit are one orbit (a Wilson interval 4 times too narrow)
            measured &= np.isin(np.arange(len(lam1)), self.orbits)
        # an orbit that left the table (an exit) is not a trapped one, however little it measured (those leaving
        # just after their warm-up have λ₁ = 0: a specular Sinai table with a hole was 2.2 % "regular")
        stayed = ~np.asarray(self.ended, bool) if self.ended is not None else np.ones(len(lam1), bool)
        return int(np.sum(measured & stayed & (lam1 < threshold))), int(measured.sum())

    def regular_share(self, threshold=REGULAR_THRESHOLD):
        """The share of trajectories whose own λ₁ (per unit time) is below ``threshold`` — regular orbits, which a
        rough table can trap beside chaotic ones — with its Wilson interval (z = 1) -> (share, low, high)."""
        return wilson(*self.regular(threshold))

    def to_dict(self, threshold=REGULAR_THRESHOLD):
        """Plain data for JSON: exponents and stderr (per unit time), per collision, their sum, each trajectory's
        own exponents (null where it measured no time), the regular share (below ``threshold`` per unit time), the
        time and collisions measured (the warm-up excluded; an exit's contact is a collision, as in rbx simulate)."""
        def finite(x):
            return float(x) if np.isfinite(x) else None
        share, low, high = self.regular_share(threshold)
        return {"exponents": [float(x) for x in self.exponents], "stderr": [float(x) for x in self.stderr],
                "per_collision": [finite(x) for x in self.per_collision()],
                "per_collision_stderr": [finite(x) for x in self.per_collision(self.stderr)],
                "sum": float(np.sum(self.exponents)), "time": float(np.sum(self.time)),
                "collisions": int(np.sum(self.collisions)), "trajectories": int(len(self.time)),
                "measured": self.measured(),
                "segments": int(self.segment_times.shape[1]), "warmup": int(self.warmup),
                "counted": COUNTED, "mean_over": MEAN_OVER,
                "coordinates": list(self.coordinates), "title": self.title,
                "ended_early": int(np.sum(self.ended)) if self.ended is not None else 0,
                "per_trajectory": [[finite(x) for x in row] for row in self.per_trajectory],
                "regular_share": {"threshold": float(threshold), "share": finite(share), "low": finite(low),
                                  "high": finite(high)}}


#: what the pooled exponents and their errors average over (the JSON output says it beside them)
MEAN_OVER = ("every trajectory, regular and chaotic alike, weighted by its measured time; each trajectory's own "
             "exponents are in per_trajectory, and the share of regular ones in regular_share")


def lyapunov(experiment, *, collisions=None, trajectories=None, seed=None, segments=10, warmup=None,
             scheduler=None, slices=None, exponents=None):
    """The Lyapunov spectrum of the flow, per unit time, largest first (Benettin's order) -> :class:`Lyapunov`
    (docs/reference.md §10).

    Benettin's method: d = 2(n + n(n−1)/2) tangent vectors (6 in 2D, 12 in 3D: position, orientation and their
    velocities) follow each trajectory of the experiment (its initial states, ``run.trajectories`` of them, its
    rules and random streams), re-orthonormalised every few collisions (:data:`ORTHO_EVERY`, :data:`ORTHO_GROWTH`).
    The first ``warmup`` collisions (default a tenth of ``run.collisions``) align the vectors and are not counted;
    the rest are cut into ``segments`` segments per trajectory whose spread gives ``stderr``. A trajectory that
    leaves by an exit wall or escapes to infinity contributes the time it had.

    ``exponents``: K, follow K tangent vectors instead of d (1 ≤ K ≤ d): the K leading exponents; for K ≥ 2 the same bits as
    the first K of the whole spectrum (Benettin's k-th vector depends only on the ones before it); λ₁ alone
    (K = 1), normalised less often, within 1e-12 of it, at a fraction of the cost. The whole spectrum sums to 0
    (the flow keeps volume): a sum far from it is refused (:class:`NothingMeasured`), not reported.

    ``experiment``: an :class:`~rbx.model.Experiment`, a config path or a dict; ``collisions``, ``trajectories``,
    ``seed`` override ``run.*``.

    ``scheduler``: follow the trajectories on the workers of a Dask cluster (docs/reference.md §11, docs/cluster.md): its
    scheduler's address (``tcp://host:8786``), the file it wrote (``--scheduler-file``) or a
    ``distributed.Client``; ``slices``: tasks (slices of trajectories; default 4 per worker thread). The result
    is the local one, bit for bit. An unreachable scheduler raises :class:`rbx.cluster.SchedulerUnreachable`, a
    task that fails :class:`rbx.cluster.ClusterError`."""
    exp = _load(experiment, collisions, trajectories, seed)
    for name, value, low in (("segments", segments, 1), ("warmup", warmup, 0)):
        # a whole number in range, as the CLI's --segments and --warmup take: warmup=-1000 ran (and measured over
        # more collisions than the run made), 0.5 became 0, True 1
        if (value is not None or name == "segments") and (
                isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low):
            raise ValueError(f"{name} must be an integer ≥ {low}, not {value!r}"
                             + (" (None: a tenth of the run)" if name == "warmup" else ""))
    segments = int(segments)
    if scheduler is None and slices is not None:
        raise TypeError("slices cuts the ensemble for a cluster: give scheduler too")
    N = exp.run.collisions
    warmup = N // 10 if warmup is None else int(warmup)
    measured = N - warmup
    if measured <= 0:
        raise ValueError(f"a warm-up of {warmup} collisions leaves none of the {N} to measure")
    if measured < segments:
        raise ValueError(f"{N} collisions leave {measured} after the warm-up: fewer than {segments} segments")
    cuts = warmup + np.round(np.linspace(0, measured, segments + 1)).astype(np.int64)
    d = tangent_dimension(exp.dimension)
    if exponents is not None:
        if isinstance(exponents, bool) or not isinstance(exponents, (int, np.integer)) or not 1 <= exponents <= d:
            raise ValueError(f"exponents must be an integer from 1 to {d} (the dimension of the phase space), "
                             f"not {exponents!r}")
    # refused as rbx simulate refuses it, not a MemoryError (7 TiB asked) after setting up
    problem = memory_problem(exp.run.trajectories, STATE_BYTES + TANGENT_BYTES)
    if problem:
        given = trajectories is not None
        raise ConfigError(None if given else exp.source, "trajectories" if given else "run.trajectories", problem)
    tan = _Tangent(exp, vectors=exponents)
    # copies of one orbit are one sample: the exponents and their errors come from the distinct orbits alone
    # (counted as samples, 8 copies gave an error 2.96 times smaller than one orbit's)
    rows = orbit_rows(exp)
    copies = len(rows) < tan.M
    if segments * len(rows) < 2:
        # the error comes from the spread of the segments' estimates: one gives none (it was NaN, and --json wrote
        # NaN, which is not JSON)
        raise ValueError("one trajectory in one segment gives no error estimate: use segments ≥ 2 or more "
                         "trajectories" if tan.M == 1 else
                         f"the {tan.M} trajectories are copies of one orbit, and one orbit in one segment gives no "
                         "error estimate: use segments ≥ 2")
    d = tan.Y.shape[1]          # the vectors followed
    with _cluster(scheduler, slices) as cluster:
        if cluster is None:
            m = _measure(tan.kernel(), tan.state, tan.Y, tan.sums, cuts, tan.probe())
        else:
            m = _on_cluster(cluster, tan, cuts)
    total_time, total_sums, seg_time = m["total_time"], m["total_sums"], m["seg_time"]
    with np.errstate(invalid="ignore", divide="ignore"):
        per_traj = total_sums / total_time[:, None]
        seg_exp = m["seg_sums"] / seg_time[..., None]
    # copies of one orbit count once (``rows``, above), in the value as in its error: a study runs each distinct
    # orbit once, and the two gave different values for the starts [A, A, A, B]
    T = float(np.sum(total_time[rows]))
    moved = int(np.sum(m["collisions"][rows]) - np.sum(m["exits"][rows]))
    if T == 0 and moved > 0:
        # the collisions happened, but their flights vanished in the sum: a velocity of 1e-150 with a spin of 3
        # takes ~1e149 for the first flight, and the spin then turns into a speed of order one
        raise NothingMeasured(f"the time did not advance over the {moved} collisions after the warm-up: each flight "
                              "is below the rounding of the time already reached (a start far slower than the "
                              "orbit it leads to, such as a tiny velocity with spin)")
    if not T > 0 or moved == 0:
        # with no collision measured, the exponents were reported as 0 ± 0 (free flight alone stretches nothing)
        raise NothingMeasured("no trajectory moved after the warm-up: each ended during it (through an exit, or in "
                              "a flight with no wall ahead, such as along a free corridor)" if not T > 0 else
                              "no collision after the warm-up: every trajectory left the table at its first "
                              "contact")
    exponents = np.sum(total_sums[rows], axis=0) / T
    total = float(np.sum(exponents))
    if d == tangent_dimension(tan.n) and not abs(total) <= SUM_TOLERANCE * float(np.sum(np.abs(exponents))):
        # the flow keeps phase-space volume: the whole spectrum sums to 0 (to 1e-11 of Σ|λ| on every example, with
        # rounding). Far from 0, the vectors have lost the directions they stand for (a metric or an orbit the
        # double precision cannot resolve): no value is better than a wrong one said with exit 0
        raise NothingMeasured(f"the spectrum sums to {total:.3g}, not 0 (λ₁ = {exponents[0]:.3g}): the flow keeps "
                              "volume, so the exponents were not resolved in double precision (speeds, lengths or "
                              "times of very different sizes?)")
    stderr = _batch_stderr(seg_time[rows].reshape(-1), seg_exp[rows].reshape(-1, d), exponents)
    if not np.all(np.isfinite(stderr)):
        raise NothingMeasured("fewer than two segments were measured (the others' trajectories left the table): "
                              "no error estimate; run more collisions or trajectories")
    if len(rows) > 1:
        # trajectories of a table that is not ergodic (rough tables trap: docs/dynamics.md) can have different
        # exponents; their spread is then larger than the segments' and is the honest error
        stderr = np.fmax(stderr, _batch_stderr(total_time[rows], per_traj[rows], exponents))
    return Lyapunov(exponents=exponents, stderr=stderr, per_trajectory=per_traj, segment_exponents=seg_exp,
                    segment_times=seg_time, time=total_time, collisions=m["collisions"], warmup=warmup,
                    coordinates=coordinate_names(tan.n), title=scene_title(exp), ended=m["ended"],
                    orbits=rows if copies else None)


def _cluster(scheduler, slices):
    """The cluster of ``scheduler`` as a context manager (:func:`rbx.api.cluster_for`: connected now, closed at the
    end; None for a local run); a :class:`rbx.cluster.Cluster` already connected (the CLI's) is used as it is."""
    if scheduler is not None:
        if isinstance(scheduler, Cluster):
            return contextlib.nullcontext(scheduler)
    return cluster_for(scheduler, "scheduler", slices)


def _on_cluster(cluster, tan, cuts):
    """:func:`_measure` of ``tan``'s ensemble on a cluster: one task per slice of trajectories, the slices' rows
    joined in order -> the arrays of the whole ensemble, the same bits as a local run (each row depends only on
    its trajectory)."""
    state_bytes = sum(a.nbytes for a in tan.state) + tan.Y.nbytes + tan.sums.nbytes
    bounds = cluster.slice_cuts(tan.M, state_bytes)
    kernel = tan.kernel()
    probe = tan.probe()
    tasks = [_SliceTask(kernel, type(tan.state)(*(x[a:b] for x in tan.state)), tan.Y[a:b], tan.sums[a:b], cuts,
                        probe)
             for a, b in zip(bounds[:-1].tolist(), bounds[1:].tolist())]
    parts = cluster.map(_measure_slice, tasks, what="lyapunov")
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def _batch_stderr(w, e, mean):
    """Standard error of a time-weighted mean of batch estimates e (B, d) with durations w (B,)."""
    ok = w > 0
    w, e = w[ok], e[ok]
    B = len(w)
    if B < 2:
        return np.full(e.shape[1] if e.ndim == 2 else len(mean), np.nan)
    wn = w / np.mean(w)
    return np.sqrt(np.sum((wn[:, None] * (e - mean)) ** 2, axis=0) / (B * (B - 1)))


# ---- escape and return times (open billiards: walls with the rule ``exit``) -----------------------------------------

@dataclass
class Escape:
    """Per trajectory: how long it stayed in the table, and whether it left by an exit wall.

    ``time`` (M,): the time of the exit contact, or the time reached (``exited`` False: censored — the trajectory
    was still in the table when the run ended, or left for infinity where no wall is ahead); ``path`` (M,): the
    same as a path length in the angle–position metric, ``time·|(v, R√κ·ω)|`` (the speed of the flow on the
    configuration space; constant: it is the energy); ``exited`` (M,) bool; ``wall`` (M,): the exit wall's index
    (−1 if none); ``escaped`` (M,): left for infinity (no wall ahead; also censored)."""
    time: np.ndarray
    path: np.ndarray
    exited: np.ndarray
    wall: np.ndarray
    escaped: np.ndarray
    wall_names: tuple = ()

    @property
    def censored(self):
        return ~self.exited

    def survival(self, path=True):
        """The Kaplan–Meier survival function: (s, S(s)) at the exit times, S the fraction still inside after s
        (right-censored trajectories leave the risk set at their last time without counting as exits) -> two
        arrays, starting with (0, 1)."""
        return survival(self.path if path else self.time, self.exited)

    def rate(self, start=0.0, stop=np.inf, path=True):
        """The exponential escape rate fitted to the window start ≤ s < stop -> (rate, standard error, exits
        used): :func:`exponential_rate`. The whole run by default; ``rbx plot --kind escape`` and the study's
        ``escape_rate`` fit from a quantile of the exits on, and say where no exponential law follows
        (:func:`rbx.escape.fit_escape`, which takes ``self.path`` and ``self.exited``)."""
        return exponential_rate(self.path if path else self.time, self.exited, start, stop)


def escape_times(run):
    """Escape (or return) times of a run whose table has exit walls -> :class:`Escape`.

    ``run``: a :class:`rbx.Run` (from :func:`rbx.simulate` or :func:`rbx.open`). Read from the run's final state,
    so no per-collision records are needed: a trajectory that ended on an exit wall (its last rule had rank −1)
    exited at its final time; one still alive is censored at the time it reached. Started with the billiard
    measure on an exit wall (``initial: {sample: billiard, wall: NAME}``), the times are return times to that wall:
    Kac's lemma gives their mean (docs/dynamics.md)."""
    if isinstance(run, (str, os.PathLike)):      # a run file's path, as rbx.open takes it
        with Run.open(os.fspath(run)) as opened:
            return escape_times(opened)
    if not hasattr(run, "final"):
        raise TypeError(f"escape_times takes a run (rbx.open, rbx.simulate) or a run file's path, not "
                        f"{type(run).__name__}")
    final = run.final
    if not final or "alive" not in final:
        raise ValueError("the run has no final state (it never ran a block)")
    exp = run.experiment
    alive = np.asarray(final["alive"], bool)
    last_rank = np.asarray(final["last_rank"])
    exited = ~alive & (last_rank == -1)
    t = np.asarray(final["time"], float)
    speed = np.sqrt(2.0 * np.asarray(final["energy"], float))
    wall = np.where(exited, np.asarray(final["last_wall"]), -1)
    return Escape(time=t, path=t * speed, exited=exited, wall=wall, escaped=~alive & ~exited,
                  wall_names=tuple(exp.wall_names) if exp is not None else ())


def survival(times, exited):
    """Kaplan–Meier estimate of the survival function from right-censored times -> (s, S): S[i] is the fraction
    still inside just after s[i]; s[0] = 0, S[0] = 1."""
    times = np.asarray(times, float)
    exited = np.asarray(exited, bool)
    order = np.argsort(times, kind="stable")
    t, e = times[order], exited[order]
    at_risk = len(t) - np.arange(len(t))
    factors = np.where(e, 1.0 - 1.0 / at_risk, 1.0)
    S = np.cumprod(factors)
    keep = e
    return np.concatenate([[0.0], t[keep]]), np.concatenate([[1.0], S[keep]])


def exponential_rate(times, exited, start=0.0, stop=np.inf):
    """Maximum-likelihood rate γ of an exponential law fitted to the window ``start`` ≤ s < ``stop`` of
    right-censored times -> (γ, standard error, exits used).

    For exponential times, censored or not, the likelihood of the tail (each time counted from ``start``) is
    γ^k·exp(−γ·Σ(s_i − start)), k the exits after ``start``: γ = k/Σ(s_i − start) over every trajectory that reached
    ``start``; its standard error (the inverse Fisher information) is γ/√k. ``start`` > 0 leaves out the
    transient before the law is exponential; a finite ``stop`` censors every time at ``stop`` (the early decay)."""
    times = np.asarray(times, float)
    exited = np.asarray(exited, bool)
    exited = exited & (times < stop)
    times = np.minimum(times, stop)
    tail = times >= start
    k = int(np.sum(exited & tail))
    exposure = float(np.sum(times[tail] - start))
    if k == 0 or exposure <= 0:
        return 0.0, np.inf, k
    rate = k / exposure
    return rate, rate / np.sqrt(k), k
