"""Which trajectories of an experiment follow the same orbit: an ensemble of copies of one orbit (a fixed start run
several times, no random numbers drawn) adds no sample. Where it matters: the warnings of settings that change
nothing (:func:`repeated_orbits`: copies; :func:`unused_seed`: a seed given to a run that draws no random numbers),
said by the CLI (``cli.common.warn_repeated``) and as RuntimeWarnings by the API; the errors of ``rbx lyapunov``
and of a study, taken from the distinct orbits alone (:func:`start_groups`, :func:`distinct_orbits`)."""
from collections.abc import Mapping

import numpy as np

from .config import STATE_KEYS
from .model import Hemisphere, Random


def draws_random_numbers(experiment):
    """True if a trajectory draws from its random stream: a sampled start (the billiard measure, a point particle's),
    or a random rule on some wall."""
    def random(rule):
        if isinstance(rule, Random):
            return True
        return isinstance(rule, Hemisphere) and (random(rule.rough) or random(rule.smooth))
    return isinstance(experiment.initial[0], str) or any(random(r) for r in experiment.wall_rules)


def start_groups(experiment):
    """Which trajectories follow the same orbit -> an int array, one entry per trajectory, equal for trajectories
    that start from the same state (and so, with no random numbers drawn, are the same orbit); None when every
    trajectory draws its own random numbers (a sampled start, a random rule)."""
    if draws_random_numbers(experiment):
        return None
    M = experiment.run.trajectories
    states = experiment.initial
    rows = np.concatenate([np.array([s[k] for s in states], float).reshape(len(states), -1) for k in STATE_KEYS],
                          axis=1)
    _, group = np.unique(rows, axis=0, return_inverse=True)
    group = np.ravel(group)
    return np.resize(group, M) if len(states) == 1 else group[:M]


def orbit_rows(experiment, selected=None):
    """The first trajectory of each distinct orbit among ``selected`` (all by default; copies of one orbit:
    :func:`start_groups`) -> sorted index array; every selected one where the trajectories draw random numbers."""
    rows = np.arange(experiment.run.trajectories) if selected is None else np.asarray(selected, np.int64)
    group = start_groups(experiment)
    if group is None:
        return np.sort(rows)
    return np.sort(rows[np.unique(group[rows], return_index=True)[1]])


def distinct_orbits(experiment):
    """The experiment with one trajectory per distinct orbit (:func:`start_groups`), or the experiment itself when
    its trajectories are all different: copies of an orbit add no sample, and counted as samples they shrank a
    standard error by the square root of their number."""
    first = orbit_rows(experiment)
    if len(first) == experiment.run.trajectories:
        return experiment
    states = experiment.initial
    return experiment.replace(initial=[dict(states[i % len(states)]) for i in first],
                              run={"collisions": experiment.run.collisions, "trajectories": len(first),
                                   "seed": experiment.run.seed})


def repeated_orbits(experiment):
    """A warning for an ensemble whose trajectories repeat each other (a fixed start, trajectories > 1, and no
    random numbers drawn: each copy follows the same orbit) -> text, or None."""
    group = start_groups(experiment)
    M = experiment.run.trajectories
    if group is None or M < 2:
        return None
    distinct = len(np.unique(group))
    if distinct == M:
        return None
    fix = "for an ensemble: initial: {sample: billiard}, a list of different states, or a random rule"
    if distinct == 1:
        return (f"the {M} trajectories all start from the same state and no rule draws random numbers: they are {M} "
                f"copies of one orbit ({fix})")
    return (f"only {distinct} of the {M} trajectories start from different states and no rule draws random numbers: "
            f"the others repeat their orbits ({fix})")


def unused_seed(experiment):
    """A warning for a seed given to a run that draws no random numbers (fixed starts, no random rule): the seed
    changes nothing -> text, or None. Said where a seed is given (``--seed``, ``--set run.seed=``, ``seed=``), as
    :func:`repeated_orbits` is."""
    if draws_random_numbers(experiment):
        return None
    return "nothing in this run draws random numbers (a fixed start, no random rule): the seed changes nothing"


def seed_change(changes):
    """The dotted key of ``changes`` that sets run.seed (``run.seed``, or ``run`` with a seed), or None."""
    for key, value in (changes or {}).items():
        if str(key) == "run.seed" or (str(key) == "run" and isinstance(value, Mapping) and "seed" in value):
            return str(key)
    return None
