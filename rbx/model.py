"""The nouns of rbx, each defined once: an experiment and its parts (ball, rules, run settings, output, numerical
options) as frozen dataclasses, and the table of record fields (docs/reference.md §5).

Everything else reads these: :mod:`rbx.config` validates YAML into them, the engine takes its record bits from
:data:`FIELDS`, the run file takes each field's dtype, shape, units and description from it, the precise loop
and the tests walk it. This is the lowest layer: it imports no other rbx module, at module level or inside a
function (tests/test_imports.py). What an experiment asks of the layers above it — its table's geometry
(:mod:`rbx.tables`) and a new validation when a part is changed by hand (:mod:`rbx.config`) — they register in
:data:`SERVICES` when they are imported; every experiment is made by :mod:`rbx.config`, which imports both.

No value is stored beside the values it is derived from: κ is computed from the ball's ``inertia`` (a property),
and an experiment changed by hand (``dataclasses.replace``, :meth:`Experiment.replace`) is validated again as a
config, so that its table, rules, ball, start and stored config (``resolved``) always agree.

How to add a record field: one :class:`Field` row in :data:`FIELDS` (its bit is its position), its write in
``engine.write_record`` and its value in ``simulation.Simulation.current_record``; config, HDF5 layout, API and
tests pick it up from the table.
"""
import copy
import dataclasses
import math
import numbers
from dataclasses import dataclass, field

import numpy as np


class ConfigError(Exception):
    """A user mistake in a config: ``rbx: <file>: <key>: <problem>`` (file None: a command-line option)."""

    def __init__(self, file, key, problem):
        self.file = None if file is None else str(file)
        self.key, self.problem = key, problem
        super().__init__(": ".join(x for x in (self.file, key, problem) if x))


# ---- boundary rules (docs/reference.md §3) --------------------------------------------------------------------------

@dataclass(frozen=True)
class Constant:
    """Roughness rank 0 … n−1; for 3D rank 1 a ``direction``: ('deg', θ from the wall's first tangent axis) or
    ('vector', (x, y, z), projected onto the wall)."""
    rank: int
    direction: tuple | None = None


@dataclass(frozen=True)
class Hemisphere:
    """``rough`` where the body-frame contact point lies in the hemisphere around ``axis`` (unit), else ``smooth``."""
    axis: tuple
    rough: object
    smooth: object


@dataclass(frozen=True)
class Random:
    """One of ``choices`` drawn with ``probabilities`` at every collision from the trajectory's stream."""
    choices: tuple
    probabilities: tuple


@dataclass(frozen=True)
class Exit:
    """The wall is a hole (docs/reference.md §3): a trajectory that reaches it records that contact (no collision
    map; its rank is recorded as −1) and ends there. Open billiards: escape and return times (docs/reference.md
    §10)."""
    rank = -1           # a class attribute, not a field: every exit is the same rule


def roughness_direction(direction, t1, t2, cos=math.cos, sin=math.sin, sqrt=math.sqrt, radians=math.radians):
    """The unit roughness direction of a 3D rank-1 rule on a flat wall with orthonormal tangent axes t1, t2 -> list.

    ``('deg', θ)``: cos θ·t1 + sin θ·t2; ``('vector', v)``: v projected onto the wall, normalised (a vector with no
    tangential part is refused by the config). Written once for every number type: the precise loop passes its
    own ``cos``, ``sin``, ``sqrt``, ``radians`` and tangents at its precision."""
    kind, value = direction
    if kind == "deg":
        th = radians(value)
        c, s = cos(th), sin(th)
        return [c * a + s * b for a, b in zip(t1, t2)]
    top = max(abs(x) for x in value)
    value = [x / top for x in value]        # scaled first: [1e200, 0, 0] squared to inf, and the wall was specular
    x1 = sum(x * a for x, a in zip(value, t1))
    x2 = sum(x * b for x, b in zip(value, t2))
    d = [x1 * a + x2 * b for a, b in zip(t1, t2)]
    norm = sqrt(sum(x * x for x in d))
    # a direction normal to this wall: refused by the config where the rule applies; elsewhere never used
    return [x / norm for x in d] if norm > 0 else d


def rule_leaves(rule):
    """Every leaf rule (constant or exit) a rule can reach (hemisphere: both sides; random: every choice), in order
    -> list."""
    if isinstance(rule, (Constant, Exit)):
        return [rule]
    kids = (rule.rough, rule.smooth) if isinstance(rule, Hemisphere) else rule.choices
    return [leaf for k in kids for leaf in rule_leaves(k)]


# ---- the experiment ------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Ball:
    """Radius R, the mass distribution as given (``uniform``, ``shell``, ``ring`` or κ itself) and the dimension of
    the ball (2: a disc, 3: a ball). κ = 2λ/R² is computed from them (:attr:`kappa`), so that
    ``dataclasses.replace(ball, inertia=0.1)`` is a ball of κ = 0.1. Checked when made (:class:`ConfigError`)."""
    radius: float
    inertia: object
    dimension: int

    def __post_init__(self):
        check_ball(self)

    @property
    def kappa(self):
        """κ = 2λ/R² of the mass distribution in this dimension (a number ``inertia`` is κ itself)."""
        return kappa_of(self.inertia, self.dimension)


#: κ = 2λ/R² of named mass distributions; 'uniform' depends on the dimension: 2/(n+2)
INERTIA_KAPPA = {"shell": {2: 1.0, 3: 2.0 / 3.0}, "ring": {2: 1.0}}
#: the named mass distributions of a ball in each dimension
INERTIA_NAMES = {2: ("uniform", "shell", "ring"), 3: ("uniform", "shell")}


def kappa_of(inertia, n):
    """κ of a named mass distribution in dimension n, or the number itself (validated by :func:`check_ball` and
    the config loader)."""
    if isinstance(inertia, str):
        if inertia == "uniform":
            return 2.0 / (n + 2)
        return INERTIA_KAPPA[inertia][n]
    return float(inertia)


def unknown_inertia(inertia, n):
    """Why the text ``inertia`` names no mass distribution of an ``n``D ball -> the problem's words."""
    names = INERTIA_NAMES[n]
    try:
        float(inertia)
    except ValueError:
        return f"unknown mass distribution '{inertia}' for a {n}D ball (use {', '.join(names)} or a number κ in (0, 1])"
    return (f"is the text '{inertia}', not a number: give κ as a number (inertia: {inertia.strip()}, no quotes) or "
            f"a mass distribution ({', '.join(names)})")


def check_ball(ball):
    """A :class:`Ball` as made (by the config or by hand): dimension 2 or 3, a finite positive radius, a mass
    distribution that exists in its dimension (a name of :data:`INERTIA_NAMES` or κ in (0, 1]). Raises
    :class:`ConfigError` naming ``ball.…`` (no file), with the config's words."""
    n = ball.dimension
    if isinstance(n, bool) or n not in (2, 3):
        raise ConfigError(None, "ball.dimension", f"must be 2 (a disc) or 3 (a ball), got {n!r}")
    radius = _number(ball.radius, "ball.radius")
    if radius <= 0:
        raise ConfigError(None, "ball.radius", f"must be positive, got {radius:g}")
    inertia = ball.inertia
    if isinstance(inertia, str):
        if inertia not in INERTIA_NAMES[n]:
            raise ConfigError(None, "ball.inertia", unknown_inertia(inertia, n))
    else:
        kappa = _number(inertia, "ball.inertia")
        if not 0.0 < kappa <= 1.0:
            raise ConfigError(None, "ball.inertia", f"must be {'> 0' if kappa <= 0 else '≤ 1'}, got {kappa:g}")


def _number(value, key):
    """A finite real number (not a bool) -> float, else :class:`ConfigError` naming ``key``."""
    # NumPy's numbers too (a float32 as rbx.load takes it), never a bool
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise ConfigError(None, key, f"expected a number, got {type(value).__name__}")
    try:
        value = float(value)
    except OverflowError:
        raise ConfigError(None, key, "is too large") from None
    if not math.isfinite(value):
        raise ConfigError(None, key, f"must be finite, got {value}")
    return value


#: what the model asks of the layers above it, each registered by its module when imported (the model imports
#: none of them): ``build(kind, table, R)`` -> the shrunk table's geometry (:func:`rbx.tables.build`), and
#: ``revalidate(experiment, changed)`` -> the experiment validated again as a config (:func:`rbx.config.revalidate`).
#: Both are there whenever an experiment asks: every experiment with a table is made by :mod:`rbx.config`, which
#: imports :mod:`rbx.tables`.
SERVICES = {}


def _service(name):
    try:
        return SERVICES[name]
    except KeyError:
        raise RuntimeError(f"rbx.model: '{name}' is registered by rbx.config and rbx.tables when they are imported; "
                           "make experiments with rbx.load") from None


@dataclass(frozen=True)
class RunSettings:
    """How long and how many: collisions per trajectory, trajectories, the seed of the random streams."""
    collisions: int
    trajectories: int
    seed: int


#: the largest run file written unless asked for more (``output.max_size``, ``--max-size``): 10 GiB
DEFAULT_MAX_SIZE = 10 * 2**30


#: the values of ``output.compression`` (``gzip`` takes a level: ``gzip:0`` … ``gzip:9``, ``gzip`` is ``gzip:4``)
COMPRESSIONS = ("none", "gzip", "lzf")


@dataclass(frozen=True)
class Output:
    """Where the run goes (None: nowhere given), which fields are recorded (in :data:`FIELDS` order), every k-th,
    the largest file (bytes) the run may write (a larger estimate is refused before anything is written), and
    the compression of the record datasets (``none``, ``lzf``, ``gzip:LEVEL``; docs/runfile.md measures them)."""
    path: str | None
    record: tuple
    every: int
    max_size: float = DEFAULT_MAX_SIZE
    compression: str = "none"

    def resolved(self):
        """The ``output`` section as stored in a run file's config (``max_size`` and ``compression`` only when
        not the default, so that files of runs without them read the same as before) -> dict."""
        out = {"path": self.path, "record": list(self.record), "every": self.every}
        if self.max_size != DEFAULT_MAX_SIZE:
            out["max_size"] = self.max_size
        if self.compression != "none":
            out["compression"] = self.compression
        return out


#: default period (in collisions) of the projection onto the initial energy (docs/accuracy.md)
RENORMALIZE_EVERY = 16


@dataclass(frozen=True)
class Numerics:
    """Numerical options (docs/accuracy.md measures each): project back onto the initial energy every
    ``renormalize`` collisions (0: never; ``engine.energy_factor``, ``engine.speed_factor``), compensated summation of
    the time and the position, snapping the centre onto the wall at contact. Config section ``numerics``."""
    renormalize: int = RENORMALIZE_EVERY
    compensated: bool = False
    snap: bool = False


#: the parts of an experiment that its config gives (``wall_rules``: the ``boundary`` section): a part changed by
#: hand is validated again, with the rest of the experiment, as a config
PARTS = ("table", "wall_rules", "ball", "initial", "run", "output", "numerics")


def _digest(resolved):
    """A digest of an experiment's ``resolved`` config (plain data) -> str."""
    import hashlib
    import json
    return hashlib.sha256(json.dumps(resolved, sort_keys=True, default=repr).encode()).hexdigest()


#: the parts derived from the others (the table's dimension, kind and walls; the stored config): never set by hand
DERIVED = ("dimension", "table_kind", "wall_names", "resolved")
#: what :func:`rbx.config.from_dict` passes as ``checked``: the experiment it makes is validated
VALIDATED = "validated"


@dataclass(frozen=True)
class Experiment:
    """A validated experiment. ``initial`` is a tuple of explicit states (read-only arrays) or ``('sample', wall)``.

    ``table`` is a read-only mapping of the table's parameters; ``resolved`` is the plain-data form of the whole
    experiment (tables and boundaries inlined, paths absolute) that is stored in the HDF5 file and read back by
    ``--resume`` and :func:`rbx.open` (:meth:`to_dict` gives a copy to edit and load again).

    Every copy is checked: a part changed by :meth:`replace` or ``dataclasses.replace`` (``ball``, ``run``,
    ``initial``, …, given as its dataclass or as a mapping of its config keys) is validated again with the rest
    of the experiment exactly as a config is, and ``resolved`` follows it; a mistake raises :class:`ConfigError`
    naming the key. The derived parts (``dimension``, ``table_kind``, ``wall_names``, ``resolved``) cannot be set.
    (An experiment made by calling ``Experiment(...)`` directly, without ``resolved``, is only type-checked.)"""
    source: str
    dimension: int
    table_kind: str
    table: dict = field(hash=False)
    wall_rules: tuple = ()               # one rule per wall, in wall order
    wall_names: tuple = ()
    ball: Ball = None
    initial: object = None
    run: RunSettings = None
    output: Output = None
    numerics: Numerics = Numerics()
    resolved: dict = field(default=None, hash=False, compare=False)
    #: the files the config names (its table and boundary files): a run's output must never overwrite them
    includes: tuple = field(default=(), compare=False)
    #: the parts as validated (:data:`PARTS` + :data:`DERIVED`, compared by identity): tells a copy whose parts
    #: were changed by hand, which is validated again, from one that was not
    checked: tuple = field(default=None, repr=False, compare=False, hash=False)

    def __post_init__(self):
        if isinstance(self.checked, str) and self.checked == VALIDATED:    # made by rbx.config
            # the parts, and a digest of ``resolved``: a dict, which can be edited in place (check_unchanged)
            object.__setattr__(self, "checked", self._parts() + (_digest(self.resolved),))
            return
        if self.checked is None:
            self._check_types()
            return
        old = dict(zip(PARTS + DERIVED, self.checked))
        changed = [name for name in PARTS if getattr(self, name) is not old[name]]
        for name in DERIVED:
            now = getattr(self, name)
            if now is not old[name] and (name == "resolved" or now != old[name]):
                raise ConfigError(None, name, _derived(name))
        if not changed:
            return
        new = _service("revalidate")(self, changed)
        for f in dataclasses.fields(self):
            if f.name not in ("source", "includes"):
                object.__setattr__(self, f.name, getattr(new, f.name))

    def _parts(self):
        return tuple(getattr(self, name) for name in PARTS + DERIVED)

    def check_unchanged(self):
        """Raise :class:`ConfigError` if ``resolved`` was edited in place since the experiment was made: a run's file
        stores it as the config that ran (``exp.resolved['ball']['radius'] = 0.05`` ran radius 0.1 and recorded
        0.05, which ``rbx.open`` and the plots then read)."""
        made = self.checked
        if isinstance(made, tuple) and len(made) > len(PARTS + DERIVED) and _digest(self.resolved) != made[-1]:
            raise ConfigError(self.source, "resolved", "was changed in place after the experiment was made, so it no "
                                                       "longer says what would run (a run's file stores it as the "
                                                       "config that ran): edit a copy, exp.to_dict(), and rbx.load "
                                                       "it; or change a key of an experiment left as made with "
                                                       "rbx.load(exp, {'ball.radius': 0.05}) or exp.replace(...)")

    def _check_types(self):
        """An experiment made by hand: each part of its type, the ball of the table's dimension."""
        for name, kind in (("ball", Ball), ("run", RunSettings), ("output", Output), ("numerics", Numerics)):
            value = getattr(self, name)
            if value is not None and not isinstance(value, kind):
                raise ConfigError(None, name, f"expected an rbx.model.{kind.__name__}, got {type(value).__name__}")
        if self.ball is not None and self.ball.dimension != self.dimension:
            raise ConfigError(None, "ball.dimension", f"is {self.ball.dimension}, but the table is "
                                                      f"{self.dimension}D")

    def geometry(self):
        """The shrunk table the centre moves in (:class:`rbx.geometry.Geometry`)."""
        return _service("build")(self.table_kind, self.table, self.ball.radius)

    def replace(self, **changes):
        """A copy with some parts changed, validated with the rest as a config is (raises :class:`ConfigError`).

        A part is given as its dataclass (``run=RunSettings(…)``, ``ball=dataclasses.replace(exp.ball,
        inertia=0.2)``), as a tuple (``initial``, ``wall_rules``), or as a mapping of its config keys, merged into
        the section as an override is (``ball={'inertia': 0.2}`` is ``rbx.load(exp, {'ball.inertia': 0.2})``).
        ``resolved`` follows, so that the file written records what was run."""
        unknown = [k for k in changes if k not in PARTS + ("source", "includes")]
        if unknown:
            key = unknown[0]
            raise ConfigError(None, key, _derived(key) if key in DERIVED + ("checked",) else
                              f"not a part of an experiment (parts: {', '.join(PARTS)})")
        return dataclasses.replace(self, **changes)

    def to_dict(self):
        """The experiment as a config mapping (a deep copy of ``resolved``: tables and boundaries inlined, paths
        absolute), to edit and load again from any folder: ``rbx.load(d)``."""
        return copy.deepcopy(self.resolved)


def _derived(name):
    """Why a derived part of an experiment cannot be set."""
    if name in ("dimension", "table_kind", "wall_names"):
        return ("is derived from the table, it cannot be set: change the table (experiment.replace(table={...}) or "
                "rbx.load(experiment, {'table.KEY': VALUE}))")
    return ("is derived from the experiment's parts, it cannot be set: change a part (experiment.replace(ball=…)) "
            "or load an edited experiment.to_dict()")


# ---- record fields (docs/reference.md §5) ---------------------------------------------------------------------------

_SHAPES = {"scalar": lambda n: (), "vector": lambda n: (n,), "spin": lambda n: () if n == 2 else (3,),
           "orientation": lambda n: () if n == 2 else (3, 3)}


@dataclass(frozen=True)
class Field:
    """One recorded per-collision field: its dtype, trailing shape in dimension n (``shape(n)``), the bit of the
    engine's record mask, units and meaning. Lengths are in the table's unit L, times in T = L/(unit speed)."""
    name: str
    dtype: type
    kind: str            # key of the trailing shape: scalar | vector | spin | orientation
    bit: int
    units: str
    description: str

    def shape(self, n):
        return _SHAPES[self.kind](n)

    def size(self, n):
        """Values per record in dimension n (the flat width of the kernel's buffer)."""
        return int(np.prod(self.shape(n), dtype=np.int64))

    @property
    def fill(self):
        """Value of a slot past a trajectory's end: −1 for indices, NaN for numbers."""
        return -1 if np.dtype(self.dtype).kind == "i" else np.nan


FIELDS = tuple(Field(name, dtype, kind, 1 << i, units, text) for i, (name, dtype, kind, units, text) in enumerate((
    ("time", np.float64, "scalar", "T", "time of the record"),
    ("position", np.float64, "vector", "L", "centre of the ball"),
    ("velocity", np.float64, "vector", "L/T", "velocity of the centre"),
    ("angular_velocity", np.float64, "spin", "rad/T", "space-frame angular velocity ω (2D: counter-clockwise)"),
    ("orientation", np.float64, "orientation", "rad (2D) / 1 (3D)",
     "2D: continuous angle θ, never wrapped (x₀ = R√κ·θ); 3D: rotation matrix A (body to space)"),
    ("wall", np.int32, "scalar", "1", "index of the wall hit (−1 for record 0), in the table's wall order"),
    ("rank", np.int32, "scalar", "1", "roughness rank of the rule used at that collision"),
)))
#: field name -> :class:`Field`
FIELD = {f.name: f for f in FIELDS}
RECORD_FIELDS = tuple(FIELD)
