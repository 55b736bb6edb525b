"""The invariant-measure experiment (paper §2.7; ``rbx histogram``, docs/reference.md §4) and Santaló's mean free
path.

Sample M states from the billiard measure on one wall (:func:`rbx.sampling.sample_billiard`), follow each until
it returns to that wall — keeping only the return state, no trajectory is stored — and compare the return angles
φ (to the wall's normal, in the metric-orthonormal coordinates (v, R√κ·ω)) with the law the invariance of the
billiard measure predicts: density ∝ cos φ·sin^(d−2) φ, distribution function sin^(d−1) φ, d = n + n(n−1)/2.

The return map of a wall is the first-return map of the boundary map to that wall, so it preserves the billiard
measure restricted to the wall whenever the boundary map preserves it (Theorem `invariance`). The post-collision
state is the one compared: it is the state the boundary map acts on. The file of ``rbx histogram`` (group
``returns/``) is written by :mod:`rbx.driver` (``write_returns``, with :func:`rbx.runfile.fill_returns`) and read by :func:`rbx.reader.read_returns`.
"""
import dataclasses
import time
from dataclasses import dataclass

import numpy as np

from . import analysis
from .model import Exit, rule_leaves
from .sampling import sample_billiard
from .simulation import Simulation


class _NullSink:
    """Records nothing: the experiment reads the final state only."""

    def write(self, block, nrec):  # pragma: no cover - never called with record = ()
        pass

    def checkpoint(self, sim):
        pass


@dataclass
class Returns:
    """Outcome of the experiment. Arrays over the M sampled trajectories unless said otherwise."""
    wall: int | None               # the wall sampled and returned to (None: the whole boundary, one collision)
    d: int                         # velocity dimension n + n(n−1)/2
    initial_angle: np.ndarray      # (M,) φ of the sampled state
    returned: np.ndarray           # (M,) bool: came back within run.collisions
    collisions: np.ndarray         # (M,) collisions made (up to and including the return)
    angle: np.ndarray              # (K,) return angles of the K returned trajectories, in trajectory order
    ks_statistic: float            # of the returned angles
    ks_pvalue: float               # NaN when some sample did not return (a test of the truncation, not the law)
    seconds: float

    @property
    def samples(self):
        return len(self.returned)

    @property
    def not_returned(self):
        return int(np.count_nonzero(~self.returned))


def _sample(cfg, geom, _spin_scale):
    state = sample_billiard(geom, cfg.ball.kappa, cfg.ball.radius, cfg.run.seed, cfg.initial[1], 0,
                            cfg.run.trajectories)
    # test hook: a sampler with the wrong spin scaling must make the experiment fail
    state["angular_velocity"] = state["angular_velocity"] * _spin_scale
    return state


def _quiet(cfg):
    return cfg.replace(output=dataclasses.replace(cfg.output, record=(), every=1))


def exit_problem(cfg):
    """Why the return experiment cannot be run on ``cfg`` because of its exits -> text, or None. A contact with a
    wall whose rule is (or may resolve to) an exit is the arriving state, no collision map applied: its angle to
    the inward normal is above 90°, and the Kolmogorov–Smirnov test against the billiard measure's law would
    reject it with D = 1 whatever the dynamics."""
    exits = [w for w, rule in enumerate(cfg.wall_rules) if any(isinstance(x, Exit) for x in rule_leaves(rule))]
    wall = cfg.initial[1] if cfg.initial and cfg.initial[0] == "sample" else None
    if wall is not None and wall in exits:
        return (f"the sampled wall '{cfg.wall_names[wall]}' has the rule exit: a return there is no collision "
                "(no state after a collision map to compare); sample on a wall without exit")
    if wall is None and exits:
        return (f"wall '{cfg.wall_names[exits[0]]}' has the rule exit, and without initial.wall the return is the "
                "next contact on any wall: at an exit it is no collision (no state after a collision map to "
                "compare); sample on one wall without exit (initial: {sample: billiard, wall: NAME})")
    if exits:
        # orbits leave through it before they return, and were reported as not returned ('raise run.collisions');
        # the returns of the others are no sample of the billiard measure's law
        return (f"wall '{cfg.wall_names[exits[0]]}' has the rule exit: orbits leave through it before they return, "
                "and the returns of the others are no sample of the law; give that wall a rule without exit")
    return None


def return_experiment(cfg, progress=None, _spin_scale=1.0, cluster=None, should_stop=None, on_run=None):
    """Run the return-angle experiment of a validated config with ``initial: {sample: billiard, wall: W}`` ->
    :class:`Returns`.

    Each of ``run.trajectories`` sampled states is followed until it hits wall W again (at most
    ``run.collisions`` collisions; the others are counted in ``returned``). Without a wall the states are drawn
    on the whole boundary and the return is the next collision, on any wall (the boundary map itself).
    ``_spin_scale`` multiplies the sampled spins: a deliberately wrong sampler, for testing that the test can
    fail. ``cluster``: a :class:`rbx.cluster.Cluster` to follow the trajectories on (the same result).
    ``should_stop()`` is polled between blocks: if it says stop, KeyboardInterrupt (the experiment is not whole).
    ``on_run()`` is called once the states are drawn and the kernels compiled, just before the trajectories run
    (the command line switches there from aborting at a signal to flagging it: the set-up of 10⁷ states takes
    seconds, and a Ctrl-C in it used to wait for the first block); if it returns True, KeyboardInterrupt."""
    if cfg.initial[0] != "sample":
        raise ValueError("the return experiment needs initial: {sample: billiard, wall: NAME}")
    problem = exit_problem(cfg)
    if problem:
        raise ValueError(problem)
    start = time.perf_counter()
    wall = cfg.initial[1]
    if wall is None:
        cfg = cfg.replace(run=dataclasses.replace(cfg.run, collisions=1))
    cfg = _quiet(cfg)
    n, R, kappa = cfg.dimension, cfg.ball.radius, cfg.ball.kappa
    d = analysis.velocity_dimension(n)
    geom = cfg.geometry()
    state = _sample(cfg, geom, _spin_scale)
    initial = analysis.normal_angle(state["velocity"], state["angular_velocity"], state["normal"], R, kappa)
    sim = Simulation(cfg, state=state, stop_wall=-1 if wall is None else wall)
    sim.cluster = cluster
    sim.compile_kernels()
    if on_run is not None and on_run():
        raise KeyboardInterrupt
    sim.run(_NullSink(), progress=progress, should_stop=should_stop)
    if should_stop is not None and should_stop():
        raise KeyboardInterrupt
    fin = sim.final_state()
    hit = fin["last_wall"]
    returned = (fin["collisions"] > 0) & (hit >= 0)
    if wall is not None:
        returned &= (hit == wall) & ~fin["alive"]
    _, nu = analysis.locate(geom, hit[returned], fin["position"][returned])
    angle = analysis.normal_angle(fin["velocity"][returned], fin["angular_velocity"][returned], nu, R, kappa)
    stat, p = analysis.ks_cos_law(angle, d) if len(angle) else (np.nan, np.nan)
    if not returned.all():
        # the slow returns are missing, and they are not a random share: a p-value would test the truncation,
        # so there is none (NaN); D is kept as a description of the returned angles
        p = np.nan
    return Returns(wall, d, initial, returned, np.asarray(fin["collisions"]), angle, stat, p,
                   time.perf_counter() - start)


def first_flight_times(cfg, _spin_scale=1.0):
    """Flight time from a billiard-measure sample on the boundary (``initial.wall`` or, without it, the whole
    boundary) to the next collision -> (M,) times. With unit speed in (v, R√κ·ω) — the sampler's — these are
    free path lengths in Q; on the whole boundary their mean is Santaló's :func:`rbx.analysis.santalo_mean_free_path`.
    Trajectories that escape (no wall ahead) give inf."""
    cfg = _quiet(cfg.replace(run=dataclasses.replace(cfg.run, collisions=1)))
    geom = cfg.geometry()
    sim = Simulation(cfg, state=_sample(cfg, geom, _spin_scale))
    sim.run(_NullSink())
    fin = sim.final_state()
    return np.where(fin["collisions"] > 0, fin["time"], np.inf)
