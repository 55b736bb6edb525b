"""Boundary rules: the registry of rule kinds, and the rule trees flattened into arrays for the kernels
(docs/reference.md §3).

One :class:`RuleKind` record per kind (``constant``, ``hemisphere``, ``random``, ``exit``), registered by
:func:`register`, holds every facet of the kind: its config keys and their checks (``parse``, read by
:mod:`rbx.config`), its config mapping again (``plain``), its node in the kernels' arrays (``node``: rank, axis,
children and their cumulative probabilities), its step in the kernels' walk (``step``, called by :func:`choose`),
its form and step at any mpmath precision (``precise``, ``precise_step``: :mod:`rbx.precise`), its phrase for
titles (``phrase``: :func:`describe`, ``analysis.describe_rule``) and an example config. The rule's noun is its
frozen dataclass in :mod:`rbx.model` (``Constant``, ``Hemisphere``, ``Random``, ``Exit``). tests/test_rules.py
fails when a kind lacks a facet, when a dataclass of :mod:`rbx.model` has no record, and when :func:`choose` does
not call an inner kind's step.

Node kinds: ``CONSTANT`` (a roughness rank and, for 3D rank 1, a direction), ``HEMISPHERE`` (children: rough,
smooth; picked by the contact point in the ball's body frame), ``RANDOM`` (children with cumulative
probabilities; one draw per visit) and ``EXIT`` (the wall is a hole: the trajectory ends at the contact,
no map applied; its rank is −1). :func:`choose` walks a wall's tree at a collision and returns the leaf (constant
or exit node) that applies.

How to add a rule kind: its dataclass in :mod:`rbx.model`, then one :func:`register` call here with its facets
(an inner kind: its ``step``, a jitted function, and its branch in :func:`choose`), its case in
tests/reference.py (the independent loop) and a catalog scene that uses it.
"""
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ._jit import jit, jit_hot
from .model import Constant, Exit, Hemisphere, Random, roughness_direction
from .primitives import HALFSPACE, P_NORMAL, SEGMENT
from .rng import draw53

CONSTANT, HEMISPHERE, RANDOM, EXIT = 0, 1, 2, 3


class Rules(NamedTuple):
    """The rule trees of the walls as arrays, one of the kernels' argument groups (:mod:`rbx.engine`;
    :meth:`CompiledRules.kernel_arrays`, :func:`choose`). At module level: Numba's disk cache finds the type again."""
    root: np.ndarray        # (walls,) root node of each wall
    kind: np.ndarray        # (nodes,) node kind
    rank: np.ndarray        # (nodes,) roughness rank (constant nodes)
    first: np.ndarray       # (nodes,) first child in ``children``
    nchild: np.ndarray      # (nodes,) number of children
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

    @property
    def shared_pick(self):
        """Every wall's rule is one node that picks among constant rules by one test: a random choice of two or
        three (one draw, compared with each threshold), or a hemisphere rule (:func:`hemisphere_step`'s test). The
        kernel holds its leaves, their ranks and its thresholds in locals and picks without the walk (engine.S_SHARED):
        instructions a collision, the plates' hemisphere rule 411 -> 348, their random rule over three directions
        255 -> 166, the strip's hemisphere rule 145 -> 93 (docs/speed-gaps.md)."""
        r0 = self.root[0]
        if np.any(self.root != r0):
            return False
        kind, k, count = self.kind[r0], self.first[r0], self.nchild[r0]
        if not ((kind == RANDOM and count in (2, 3)) or kind == HEMISPHERE):
            return False
        return all(self.kind[self.children[k + c]] == CONSTANT for c in range(count))

    def kernel_arrays(self):
        """The arrays the kernels read, as the group :class:`Rules`."""
        return Rules(root=self.root, kind=self.kind, rank=self.rank, first=self.first, nchild=self.nchild,
                     children=self.children, threshold=self.threshold, axis=self.axis, phase=self.phase,
                     basis=self.basis)


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
        kind = kind_of(rule)
        rank, axis, direction, kids, probs = kind.node(rule, n)
        if kids:
            ids = [add(k) for k in kids]
            first = len(links)
            links.extend(zip(ids, probs))
        else:
            first = 0
        nodes[idx] = (kind.code, rank, first, len(kids), axis, direction)
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
        normals = geom.params[ks, P_NORMAL:P_NORMAL + n]
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
def choose(wall, nu, A, theta, key, draws, root, kind, first, nchild, children, threshold, axis, phase, n, rounded):
    """Walk the rule tree of ``wall`` -> (leaf node: a constant or an exit node, number of draws used so far).

    Each inner node takes its kind's step (its record's ``step``): hemisphere, :func:`hemisphere_step`; random,
    :func:`random_step` (one draw of the stream ``key``, number ``draws``). ``rounded`` (a constant of the kernel:
    :attr:`CompiledRules.round_hemisphere`) compiles the hemisphere test with cos θ and sin θ for walls without a
    phase: without it, the kernel holds no trace of it (the rough strip: 19.5 ns per collision with the
    trigonometry in a branch never taken, 10.6 without it).
    """
    node = root[wall]
    while kind[node] == HEMISPHERE or kind[node] == RANDOM:
        if kind[node] == HEMISPHERE:
            node = children[first[node] + hemisphere_step(node, wall, nu, A, theta, axis, phase, n, rounded, -1)]
        else:
            node = children[random_step(first[node], nchild[node], key, draws, threshold)]
            draws += 1
    return node, draws


# ---- the registry of rule kinds ------------------------------------------------------------------------------------

@dataclass(frozen=True)
class RuleKind:
    """Every facet of one rule kind (see the module docstring)."""
    name: str               # the config's ``rule:`` value
    model: type             # its dataclass in rbx.model
    code: int               # its node kind in the kernels' arrays
    #: (mapping, key, n, checker, geom, wall_ids) -> the rule (checked; the children through :func:`parse_rule`).
    #: ``checker``: rbx.config's (fail, mapping, integer, number, nonzero_vector); ``wall_ids``: the walls it is
    #: on, for the checks of a 3D direction
    parse: object
    plain: object           # (rule, key) -> its config mapping (children through :func:`rule_config`)
    #: (rule, n) -> (rank, axis (n,), direction, children, cumulative probabilities of the children)
    node: object
    step: object            # an inner kind's jitted step in choose (None for a leaf)
    precise: object         # (rule, loop, convert) -> its form at the precise loop's precision (a tuple, kind first)
    precise_step: object    # (form, loop, nu) -> the child form taken (None for a leaf); loop: rbx.precise's
    phrase: object          # (rule, n, describe) -> a short text for titles
    example: dict           # a config mapping of this kind, valid in 2D and 3D

    @property
    def leaf(self):
        return self.step is None


#: name -> :class:`RuleKind`, in the order registered
RULE_KINDS = {}
_BY_MODEL = {}


def register(kind):
    """Add a rule kind to the registry -> the kind."""
    if kind.name in RULE_KINDS or kind.model in _BY_MODEL:
        raise ValueError(f"rule kind {kind.name!r} registered twice")
    RULE_KINDS[kind.name] = _BY_MODEL[kind.model] = kind
    return kind


class NotARule(TypeError):
    """Something that is not a rule where a rule was expected (``key``: where, ``got``: its type's name)."""

    def __init__(self, key, got):
        self.key, self.got = key, got
        super().__init__(f"{key}: expected a rule (rbx.model.Constant, Hemisphere, Random or Exit), got {got}")


def kind_of(rule, key="rule"):
    """The record of a rule (a dataclass of :mod:`rbx.model`) -> :class:`RuleKind`; :class:`NotARule` for
    anything else."""
    try:
        return _BY_MODEL[type(rule)]
    except KeyError:
        raise NotARule(key, type(rule).__name__) from None


def parse_rule(r, key, n, c, geom, wall_ids):
    """Validate a rule mapping of a config (recursively) -> the rule. ``c``: the config's checker (its messages
    name the file and the key); ``wall_ids``: the walls the rule applies to, for checking 3D directions."""
    if not isinstance(r, dict):
        c.fail(key, f"expected a rule mapping such as {{rule: constant, rank: 1}}, got {c.kind(r)}")
    names = tuple(RULE_KINDS)
    if "rule" not in r:
        c.fail(_join(key, "rule"), f"missing required key (one of: {', '.join(names)})")
    name = c.choice(r["rule"], _join(key, "rule"), names, "rule")
    return RULE_KINDS[name].parse(r, key, n, c, geom, wall_ids)


def rule_config(rule, key="rule"):
    """A rule (:class:`rbx.model.Constant`, …) as its config mapping. Raises TypeError for anything else."""
    return kind_of(rule, key).plain(rule, key)


def describe(rule, n):
    """A short name for a rule: 'specular', 'rough', 'rank 1 at 60°', 'hemisphere rough/specular',
    'random (specular 0.5, rough 0.5)'."""
    return kind_of(rule).phrase(rule, n, describe)


def _join(key, k):
    return f"{key}.{k}" if key else str(k)


def _plain(values):
    """A tuple of numbers (NumPy's too) as a list of plain numbers."""
    return [x.item() if isinstance(x, np.generic) else x for x in values]


def _num(x):
    """A number for a title: 0.5, 60, 1e-06."""
    return f"{float(x):g}"


def _dot(a, b):
    return sum(x * y for x, y in zip(a, b))


# ---- constant: a roughness rank (and for 3D rank 1 a direction) ---------------------------------------------------

def _constant_parse(r, key, n, c, geom, wall_ids):
    c.mapping(r, key, ("rule", "rank", "direction_deg", "direction"), ("rank",))
    rank = c.integer(r["rank"], _join(key, "rank"), lo=0, hi=n - 1)
    has_dir = "direction_deg" in r or "direction" in r
    if "direction_deg" in r and "direction" in r:
        c.fail(_join(key, "direction"), "give either direction or direction_deg, not both")
    if has_dir and not (n == 3 and rank == 1):
        c.fail(_join(key, "direction_deg" if "direction_deg" in r else "direction"),
               "a direction is used only for 3D rank 1")
    if n == 3 and rank == 1:
        if not has_dir:
            c.fail(_join(key, "direction_deg"), "3D rank 1 needs a roughness direction "
                                                "(direction_deg or direction)")
        curved = [geom.wall_names[w] for w in wall_ids or () if geom.wall_list[w].tangents is None]
        if curved:
            c.fail(_join(key, "direction_deg" if "direction_deg" in r else "direction"),
                   f"a rank-1 roughness direction is fixed in a flat wall's tangent axes; wall '{curved[0]}' is "
                   "curved (use rank 0 or 2 there)")
        if "direction_deg" in r:
            return Constant(1, ("deg", c.number(r["direction_deg"], _join(key, "direction_deg"))))
        vec = c.nonzero_vector(r["direction"], _join(key, "direction"), 3)
        unit = vec / np.max(np.abs(vec))        # scaled first: [1e200, 0, 0] and [1e-200, 0, 0] squared to inf and 0
        unit = unit / np.linalg.norm(unit)
        for w in wall_ids or ():
            t = geom.wall_list[w].tangents
            if np.linalg.norm(t @ unit) < 1e-9:
                c.fail(_join(key, "direction"), f"is normal to wall '{geom.wall_names[w]}': it has no "
                                                "tangential part")
        return Constant(1, ("vector", tuple(vec)))
    return Constant(rank)


def _constant_plain(rule, key):
    out = {"rule": "constant", "rank": rule.rank}
    if rule.direction is not None:
        kind, v = rule.direction
        out.update({"direction_deg": v} if kind == "deg" else {"direction": _plain(v)})
    return out


def _constant_phrase(rule, n, describe):
    if rule.rank == 0:
        return "specular"
    if rule.rank == n - 1:
        return "rough" if n == 2 else f"rough (rank {rule.rank})"
    if rule.direction is None:
        return f"rank {rule.rank}"
    kind, value = rule.direction
    if kind == "deg":
        return f"rank {rule.rank} at {_num(value)}°"
    return f"rank {rule.rank} along ({', '.join(_num(x) for x in value)})"


register(RuleKind(
    "constant", Constant, CONSTANT, parse=_constant_parse, plain=_constant_plain,
    node=lambda rule, n: (rule.rank, np.zeros(n), rule.direction, (), ()),
    step=None, precise=lambda rule, loop, convert: ("constant", rule.rank, rule.direction), precise_step=None,
    phrase=_constant_phrase, example={"rule": "constant", "rank": 1}))


# ---- hemisphere: rough where the body-frame contact point lies around an axis, else smooth ------------------------

def _hemisphere_parse(r, key, n, c, geom, wall_ids):
    c.mapping(r, key, ("rule", "axis", "rough", "smooth"), ("axis", "rough", "smooth"))
    axis = c.nonzero_vector(r["axis"], _join(key, "axis"), n)
    norm = np.linalg.norm(axis)
    if not np.isfinite(norm) or norm < 1e-150:
        # huge or tiny components: normalise in two steps so that the norm neither overflows nor underflows
        axis = axis / np.max(np.abs(axis))
        norm = np.linalg.norm(axis)
    return Hemisphere(tuple(axis / norm), parse_rule(r["rough"], _join(key, "rough"), n, c, geom, wall_ids),
                      parse_rule(r["smooth"], _join(key, "smooth"), n, c, geom, wall_ids))


@jit_hot
def hemisphere_step(node, wall, nu, A, theta, axis, phase, n, rounded, m):
    """The child a hemisphere node takes -> 0 (rough) or 1 (smooth). The contact point in the body frame is
    b = Aᵀ(−ν) (2D: −ν rotated by −θ); rough iff b·axis > 0, i.e. iff ν·(A·axis) < 0 (2D on a flat wall: read
    off θ and the node's ``phase``, :func:`phases`; ``rounded``: see :func:`choose`).

    ``m`` ≥ 0 (3D; a constant where the kernel passes it: a slab's walls): ν is ±e_m, and the sum reads row m of A
    alone, ν_m·(A_m·axis). Its sign is the full sum's: the terms with ν's zeros add zeros of either sign, and ν_m = ±1
    is exact; NaN (an orientation gone non-finite) is smooth either way."""
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
    elif m >= 0:
        for j in range(n):
            s += A[m, j] * axis[node, j]
        s *= nu[m]
    else:
        for i in range(n):
            for j in range(n):
                s += nu[i] * A[i, j] * axis[node, j]
    return 0 if s < 0.0 else 1


def _hemisphere_precise_step(form, loop, nu):
    if loop.n == 2:   # b = −ν rotated by −θ
        c, s = loop.ctx.cos(loop.theta), loop.ctx.sin(loop.theta)
        b = [-(c * nu[0] + s * nu[1]), -(-s * nu[0] + c * nu[1])]
    else:             # b = Aᵀ(−ν)
        b = [-sum(loop.A[i][j] * nu[i] for i in range(3)) for j in range(3)]
    return form[2] if _dot(b, form[1]) > 0 else form[3]


register(RuleKind(
    "hemisphere", Hemisphere, HEMISPHERE, parse=_hemisphere_parse,
    plain=lambda rule, key: {"rule": "hemisphere", "axis": _plain(rule.axis),
                             "rough": rule_config(rule.rough, f"{key}.rough"),
                             "smooth": rule_config(rule.smooth, f"{key}.smooth")},
    node=lambda rule, n: (0, np.asarray(rule.axis, float), None, (rule.rough, rule.smooth), (0.0, 0.0)),
    step=hemisphere_step,
    precise=lambda rule, loop, convert: ("hemisphere", loop.vec(rule.axis), convert(rule.rough),
                                         convert(rule.smooth)),
    precise_step=_hemisphere_precise_step,
    phrase=lambda rule, n, describe: f"hemisphere {describe(rule.rough, n)}/{describe(rule.smooth, n)}",
    example={"rule": "hemisphere", "axis": [0.0, 1.0], "rough": {"rule": "constant", "rank": 1},
             "smooth": {"rule": "constant", "rank": 0}}))


# ---- random: one of the choices, drawn with its probability at every collision -------------------------------------

#: tolerance on the sum of the probabilities of a random rule (1/3 written as 0.3333333333 is accepted)
PROBABILITY_SUM_TOLERANCE = 1e-9


def _random_parse(r, key, n, c, geom, wall_ids):
    c.mapping(r, key, ("rule", "choices", "probabilities"), ("choices", "probabilities"))
    ch, pr = r["choices"], r["probabilities"]
    if not isinstance(ch, list) or not ch:
        c.fail(_join(key, "choices"), "expected a non-empty list of rules")
    if not isinstance(pr, list) or len(pr) != len(ch):
        c.fail(_join(key, "probabilities"), f"expected a list of {len(ch)} numbers, one per choice")
    probs = tuple(c.number(p, f"{_join(key, 'probabilities')}[{i}]", lo=0.0) for i, p in enumerate(pr))
    if abs(sum(probs) - 1.0) > PROBABILITY_SUM_TOLERANCE:
        c.fail(_join(key, "probabilities"), f"must sum to 1, they sum to {sum(probs):.12g}")
    return Random(tuple(parse_rule(x, f"{_join(key, 'choices')}[{i}]", n, c, geom, wall_ids)
                        for i, x in enumerate(ch)), probs)


def _random_node(rule, n):
    cum = list(np.cumsum(rule.probabilities))
    cum[-1] = np.inf            # rounding in the sum never leaves a draw unassigned
    return 0, np.zeros(n), None, tuple(rule.choices), cum


@jit_hot
def random_step(k, count, key, draws, threshold):
    """The link a random node takes, its ``count`` links starting at ``k`` -> the first link whose integer
    threshold exceeds draw number ``draws`` of the stream ``key`` (its 53 bits m: :func:`thresholds`). The
    thresholds do not decrease and the last is never reached, so that link is ``k`` plus the number of the others
    that m reaches: counted without a branch on the draw, which a loop searching for the link would mispredict
    about every other time (with probability ½ for each of two children)."""
    m = draw53(key, draws)
    j = k
    for c in range(count - 1):
        j += np.int64(m >= threshold[k + c])
    return j


def _random_precise(rule, loop, convert):
    cum = np.cumsum(np.asarray(rule.probabilities, float))   # the engine's float64 cumulative probabilities
    cum[-1] = np.inf
    return ("random", [float(c) for c in cum], [convert(c) for c in rule.choices])


def _random_precise_step(form, loop, nu):
    u = loop.draw()
    k = 0
    while not u < form[1][k]:
        k += 1
    return form[2][k]


register(RuleKind(
    "random", Random, RANDOM, parse=_random_parse,
    plain=lambda rule, key: {"rule": "random",
                             "choices": [rule_config(r, f"{key}.choices[{i}]") for i, r in enumerate(rule.choices)],
                             "probabilities": _plain(rule.probabilities)},
    node=_random_node, step=random_step, precise=_random_precise, precise_step=_random_precise_step,
    phrase=lambda rule, n, describe: "random (" + ", ".join(f"{describe(c, n)} {_num(p)}" for c, p in
                                                            zip(rule.choices, rule.probabilities)) + ")",
    example={"rule": "random", "choices": [{"rule": "constant", "rank": 0}, {"rule": "constant", "rank": 1}],
             "probabilities": [0.5, 0.5]}))


# ---- exit: the wall is a hole ---------------------------------------------------------------------------------------

def _exit_parse(r, key, n, c, geom, wall_ids):
    c.mapping(r, key, ("rule",))
    return Exit()


register(RuleKind(
    "exit", Exit, EXIT, parse=_exit_parse, plain=lambda rule, key: {"rule": "exit"},
    node=lambda rule, n: (-1, np.zeros(n), None, (), ()), step=None,
    precise=lambda rule, loop, convert: ("exit", -1, None), precise_step=None,
    phrase=lambda rule, n, describe: "exit", example={"rule": "exit"}))
