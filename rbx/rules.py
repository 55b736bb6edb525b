"""Boundary rules as data: a rule tree per wall, flattened into arrays for the kernels (SPEC §3).

Node kinds: ``CONSTANT`` (a roughness rank and, for 3D rank 1, a direction), ``HEMISPHERE`` (children: rough,
smooth; picked by the contact point in the ball's body frame), ``RANDOM`` (children with cumulative
probabilities; one uniform draw per visit) and ``EXIT`` (the wall is a hole: the trajectory ends at the contact,
no map applied; its rank is −1). :func:`choose` walks a wall's tree at a collision and returns the leaf (constant
or exit node) that applies. Adding a rule kind = a code, a branch in :func:`choose`, a case in
:func:`compile_rules` and in the config validation.
"""
from dataclasses import dataclass

import numpy as np

from ._jit import jit, jit_hot
from .model import Constant, Exit, Hemisphere, Random, roughness_direction
from .rng import uniform

CONSTANT, HEMISPHERE, RANDOM, EXIT = 0, 1, 2, 3


@dataclass
class CompiledRules:
    root: np.ndarray        # (walls,) root node of each wall
    kind: np.ndarray        # (nodes,) node kind
    rank: np.ndarray        # (nodes,) roughness rank (CONSTANT nodes; −1 for EXIT nodes)
    first: np.ndarray       # (nodes,) index of the first child in ``children``
    nchild: np.ndarray      # (nodes,)
    children: np.ndarray    # (links,) child node indices
    cumprob: np.ndarray     # (links,) cumulative probabilities (RANDOM children)
    axis: np.ndarray        # (nodes, n) body-frame axis (HEMISPHERE nodes)
    basis: np.ndarray       # (nodes, walls, n-1, n) roughness basis per wall (CONSTANT nodes, 0 < rank < n-1)
    uses_orientation: bool  # some hemisphere rule: the orientation must be followed
    uses_random: bool
    max_rank: int
    uses_exit: bool = False  # some wall can be an exit

    def kernel_arrays(self):
        """The arrays the kernels read, as the group :class:`rbx.engine.Rules`."""
        from .engine import Rules       # here: rbx.engine imports this module
        return Rules(root=self.root, kind=self.kind, rank=self.rank, first=self.first, children=self.children,
                     cumprob=self.cumprob, axis=self.axis, basis=self.basis)


def compile_rules(wall_rules, geom):
    """Flatten one rule per wall (config objects) into :class:`CompiledRules`; equal rules share nodes."""
    n = geom.dimension
    nw = len(wall_rules)
    nodes, links = [], []   # node: [kind, rank, first, nchild, axis, direction]
    memo = {}

    def add(rule):
        if rule in memo:
            return memo[rule]
        idx = len(nodes)
        nodes.append(None)
        if isinstance(rule, Constant):
            nodes[idx] = (CONSTANT, rule.rank, 0, 0, np.zeros(n), rule.direction)
        elif isinstance(rule, Exit):
            nodes[idx] = (EXIT, -1, 0, 0, np.zeros(n), None)
        else:
            kids = (rule.rough, rule.smooth) if isinstance(rule, Hemisphere) else rule.choices
            probs = (0.0, 0.0) if isinstance(rule, Hemisphere) else np.cumsum(rule.probabilities)
            ids = [add(k) for k in kids]
            first = len(links)
            links.extend(zip(ids, probs))
            if isinstance(rule, Random):
                links[-1] = (links[-1][0], np.inf)   # rounding in the sum never leaves a draw unassigned
            axis = np.asarray(rule.axis, float) if isinstance(rule, Hemisphere) else np.zeros(n)
            nodes[idx] = (HEMISPHERE if isinstance(rule, Hemisphere) else RANDOM, 0, first, len(ids), axis, None)
        memo[rule] = idx
        return idx

    root = np.array([add(r) for r in wall_rules], np.int64)
    m = len(nodes)
    basis = np.zeros((m, nw, max(n - 1, 1), n))
    for i, (kind, rank, _, _, _, direction) in enumerate(nodes):
        if kind == CONSTANT and direction is not None:
            for w in range(nw):
                t1, t2 = geom.wall_list[w].tangents
                basis[i, w, 0] = roughness_direction(direction, t1, t2)
    kinds = np.array([x[0] for x in nodes], np.int64)
    reach = _reachable(root, nodes, links)
    return CompiledRules(
        root=root, kind=kinds, rank=np.array([x[1] for x in nodes], np.int64),
        first=np.array([x[2] for x in nodes], np.int64), nchild=np.array([x[3] for x in nodes], np.int64),
        children=np.array([l[0] for l in links] or [0], np.int64),
        cumprob=np.array([l[1] for l in links] or [0.0], float),
        axis=np.array([x[4] for x in nodes]).reshape(m, n), basis=basis,
        uses_orientation=bool(np.any(kinds[reach] == HEMISPHERE)), uses_random=bool(np.any(kinds[reach] == RANDOM)),
        max_rank=int(max(nodes[i][1] for i in reach)), uses_exit=bool(np.any(kinds[reach] == EXIT)))


def _reachable(root, nodes, links):
    seen, stack = set(), list(root)
    while stack:
        i = stack.pop()
        if i in seen:
            continue
        seen.add(i)
        kind, _, first, nchild, _, _ = nodes[i]
        stack.extend(links[first + c][0] for c in range(nchild))
    return sorted(seen)


@jit_hot
def choose(wall, nu, A, theta, key, draws, root, kind, first, children, cumprob, axis, n):
    """Walk the rule tree of ``wall`` -> (leaf node: a constant or an exit node, number of draws used so far).

    Hemisphere: the contact point in the body frame is b = Aᵀ(−ν) (2D: −ν rotated by −θ); rough iff b·axis > 0,
    i.e. iff ν·(A·axis) < 0. Random: draw number ``draws`` of the stream ``key`` picks the first child whose
    cumulative probability exceeds it.
    """
    node = root[wall]
    while kind[node] == HEMISPHERE or kind[node] == RANDOM:
        if kind[node] == HEMISPHERE:
            s = 0.0
            if n == 2:
                c, sn = np.cos(theta), np.sin(theta)
                s = nu[0] * (c * axis[node, 0] - sn * axis[node, 1]) + nu[1] * (sn * axis[node, 0] + c * axis[node, 1])
            else:
                for i in range(n):
                    for j in range(n):
                        s += nu[i] * A[i, j] * axis[node, j]
            node = children[first[node] + (0 if s < 0.0 else 1)]
        else:
            u = uniform(key, draws)
            draws += 1
            k = first[node]
            while u >= cumprob[k]:
                k += 1
            node = children[k]
    return node, draws
