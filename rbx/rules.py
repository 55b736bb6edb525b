"""Boundary rules as data: a rule tree per wall, flattened into arrays for the kernels (docs/reference.md §3).

Node kinds: ``CONSTANT`` (a roughness rank and, for 3D rank 1, a direction), ``HEMISPHERE`` (children: rough,
smooth; picked by the contact point in the ball's body frame), ``RANDOM`` (children with cumulative
probabilities; one draw per visit) and ``EXIT`` (the wall is a hole: the trajectory ends at the contact,
no map applied; its rank is −1). :func:`choose` walks a wall's tree at a collision and returns the leaf (constant
or exit node) that applies. Adding a rule kind = a code, a branch in :func:`choose`, a case in
:func:`compile_rules` and in the config validation.
"""
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ._jit import jit, jit_hot
from .model import Constant, Exit, Hemisphere, Random, roughness_direction
from .geometry import HALFSPACE, SEGMENT
from .rng import draw_bits

CONSTANT, HEMISPHERE, RANDOM, EXIT = 0, 1, 2, 3


class Rules(NamedTuple):
    """The rule trees of the walls as arrays, one of the kernels' argument groups (:mod:`rbx.engine`;
    :meth:`CompiledRules.kernel_arrays`, :func:`choose`). At module level: Numba's disk cache finds the type again."""
    root: np.ndarray        # (walls,) root node of each wall
    kind: np.ndarray        # (nodes,) node kind
    rank: np.ndarray        # (nodes,) roughness rank (constant nodes)
    first: np.ndarray       # (nodes,) first child in ``children``
    children: np.ndarray    # (links,) child nodes
    threshold: np.ndarray   # (links,) uint64 thresholds on a draw's 53 bits (random nodes)
    axis: np.ndarray        # (nodes, n) body-frame axis (hemisphere nodes)
    phase: np.ndarray       # (nodes, walls) 2D hemisphere nodes on flat walls, else NaN (rbx.rules.phases)
    basis: np.ndarray       # (nodes, walls, n-1, n) roughness basis (constant nodes)


@dataclass
class CompiledRules:
    root: np.ndarray        # (walls,) root node of each wall
    kind: np.ndarray        # (nodes,) node kind
    rank: np.ndarray        # (nodes,) roughness rank (CONSTANT nodes; −1 for EXIT nodes)
    first: np.ndarray       # (nodes,) index of the first child in ``children``
    nchild: np.ndarray      # (nodes,)
    children: np.ndarray    # (links,) child node indices
    cumprob: np.ndarray     # (links,) cumulative probabilities (RANDOM children)
    threshold: np.ndarray   # (links,) uint64: the same as thresholds on a draw's 53 bits (:func:`thresholds`)
    axis: np.ndarray        # (nodes, n) body-frame axis (HEMISPHERE nodes)
    phase: np.ndarray       # (nodes, walls) 2D hemisphere nodes on flat walls: ½ − φ/π (:func:`phases`), else NaN
    basis: np.ndarray       # (nodes, walls, n-1, n) roughness basis per wall (CONSTANT nodes, 0 < rank < n-1)
    uses_orientation: bool  # some hemisphere rule: the orientation must be followed
    uses_random: bool
    max_rank: int
    uses_exit: bool = False  # some wall can be an exit
    round_hemisphere: bool = False  # 2D: a hemisphere rule on a wall without one normal (no ``phase``)

    def kernel_arrays(self):
        """The arrays the kernels read, as the group :class:`Rules`."""
        return Rules(root=self.root, kind=self.kind, rank=self.rank, first=self.first, children=self.children,
                     threshold=self.threshold, axis=self.axis, phase=self.phase, basis=self.basis)


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
                # a curved wall has no tangent axes, and the config refuses a direction on one (rbx.config._rule):
                # the node is never reached there. (Unpacking None crashed any 3D table with a curved wall.)
                if geom.wall_list[w].tangents is None:
                    continue
                t1, t2 = geom.wall_list[w].tangents
                basis[i, w, 0] = roughness_direction(direction, t1, t2)
    kinds = np.array([x[0] for x in nodes], np.int64)
    reach = _reachable(root, nodes, links)
    cumprob = np.array([l[1] for l in links] or [0.0], float)
    normals = flat_normals(geom)
    axis = np.array([x[4] for x in nodes]).reshape(m, n)
    return CompiledRules(
        root=root, kind=kinds, rank=np.array([x[1] for x in nodes], np.int64),
        first=np.array([x[2] for x in nodes], np.int64), nchild=np.array([x[3] for x in nodes], np.int64),
        children=np.array([l[0] for l in links] or [0], np.int64), cumprob=cumprob, threshold=thresholds(cumprob),
        axis=axis, phase=phases(kinds, axis, normals), basis=basis,
        uses_orientation=bool(np.any(kinds[reach] == HEMISPHERE)), uses_random=bool(np.any(kinds[reach] == RANDOM)),
        max_rank=int(max(nodes[i][1] for i in reach)), uses_exit=bool(np.any(kinds[reach] == EXIT)),
        round_hemisphere=n == 2 and any(np.any(kinds[_reachable([root[w]], nodes, links)] == HEMISPHERE)
                                        for w in range(nw) if np.isnan(normals[w, 0])))


#: 2⁵³: a draw keeps 53 random bits (:func:`rbx.rng.uniform` is m·2⁻⁵³ with m = bits >> 11)
_TWO53 = 9007199254740992.0
_INV_PI = 1.0 / np.pi


def thresholds(cumprob):
    """The cumulative probabilities as integer thresholds on a draw's 53 bits m: u = m·2⁻⁵³ ≥ c exactly when
    m ≥ ⌈c·2⁵³⌉ (c·2⁵³ is exact: a power of two), so the kernel compares integers and makes no float of the
    draw; the same children as comparing u with c. c = inf (the last child) becomes 2⁵³, which no m reaches."""
    t = np.ceil(np.minimum(np.asarray(cumprob, float), 1.0) * _TWO53)
    return np.maximum(t, 0.0).astype(np.uint64)


def flat_normals(geom):
    """(walls, n) the normal of each wall made only of flat primitives that share one normal; NaN for the
    others (curved walls, or flat pieces facing different ways)."""
    n = geom.dimension
    out = np.full((len(geom.wall_list), n), np.nan)
    for w in range(len(geom.wall_list)):
        ks = np.flatnonzero(geom.walls == w)
        if len(ks) == 0 or not all(geom.codes[k] in (HALFSPACE, SEGMENT) for k in ks):
            continue
        normals = geom.params[ks, 4:4 + n]
        if np.all(normals == normals[0]):
            out[w] = normals[0]
    return out


def phases(kinds, axis, normals):
    """(nodes, walls): for a 2D hemisphere node on a flat wall of normal ν, ½ − φ/π, where φ is the angle of
    (P, Q) = (ν·axis, ν₁axis₀ − ν₀axis₁); else NaN.

    The rule's test is the sign of s = ν·R(θ)·axis = P cos θ + Q sin θ = |(P, Q)|·cos(θ − φ): rough iff
    cos(θ − φ) < 0, i.e. iff ⌊θ/π + ½ − φ/π⌋ is odd. So on a flat wall the kernel reads the rule off a
    multiplication, an addition and a floor, where cos θ and sin θ of the accumulated angle θ cost a call into
    libm per collision (the rough strip under the hemisphere rule: 27.9 -> 10.6 ns per collision). The two tests
    differ only where |cos(θ − φ)| is within a few ulp of θ of zero, the rounding θ carries anyway."""
    m, nw = len(kinds), normals.shape[0]
    out = np.full((m, nw), np.nan)
    if axis.shape[1] != 2:
        return out
    for i in np.flatnonzero(kinds == HEMISPHERE):
        for w in range(nw):
            nu = normals[w]
            if np.all(np.isfinite(nu)):
                P = nu[0] * axis[i, 0] + nu[1] * axis[i, 1]
                Q = nu[1] * axis[i, 0] - nu[0] * axis[i, 1]
                out[i, w] = 0.5 - np.arctan2(Q, P) * _INV_PI
    return out


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
def choose(wall, nu, A, theta, key, draws, root, kind, first, children, threshold, axis, phase, n, rounded):
    """Walk the rule tree of ``wall`` -> (leaf node: a constant or an exit node, number of draws used so far).

    Hemisphere: the contact point in the body frame is b = Aᵀ(−ν) (2D: −ν rotated by −θ); rough iff b·axis > 0,
    i.e. iff ν·(A·axis) < 0 (2D on a flat wall: read off θ and the node's ``phase``, :func:`phases`). Random:
    draw number ``draws`` of the stream ``key`` picks the first child whose cumulative probability exceeds it
    (:func:`thresholds`: as integers). ``rounded`` (a constant of the kernel: :attr:`CompiledRules.round_hemisphere`)
    compiles the test with cos θ and sin θ for walls without a phase: without it, the kernel holds no trace of it
    (the rough strip: 19.5 ns per collision with the trigonometry in a branch never taken, 10.6 without it).
    """
    node = root[wall]
    while kind[node] == HEMISPHERE or kind[node] == RANDOM:
        if kind[node] == HEMISPHERE:
            s = 0.0
            if n == 2:
                ph = phase[node, wall]
                if not rounded or ph == ph:                 # a flat wall (its phase is not NaN)
                    f = np.floor(theta * _INV_PI + ph)
                    s = -1.0 if f - 2.0 * np.floor(0.5 * f) == 1.0 else 1.0   # ⌊θ/π + ph⌋ odd (θ NaN: smooth)
                else:
                    c, sn = np.cos(theta), np.sin(theta)   # libm: rbx.trig.sincos inline was slower here (circle 46 -> 50 ns)
                    s = (nu[0] * (c * axis[node, 0] - sn * axis[node, 1])
                         + nu[1] * (sn * axis[node, 0] + c * axis[node, 1]))
            else:
                for i in range(n):
                    for j in range(n):
                        s += nu[i] * A[i, j] * axis[node, j]
            node = children[first[node] + (0 if s < 0.0 else 1)]
        else:
            m = draw_bits(key, draws) >> np.uint64(11)
            draws += 1
            k = first[node]
            while m >= threshold[k]:
                k += 1
            node = children[k]
    return node, draws
