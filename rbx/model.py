"""The nouns of rbx, each defined once: an experiment and its parts (ball, rules, run settings, output, numerical
options) as frozen dataclasses, and the table of record fields (SPEC §5).

Everything else reads these: :mod:`rbx.config` validates YAML into them, the engine takes its record bits from
:data:`FIELDS`, the run file takes each field's dtype, shape, units and description from it, the precise loop
and the tests walk it. Nothing here imports a loader, h5py or numba.

How to add a record field: one :class:`Field` row in :data:`FIELDS` (its bit is its position), its write in
``engine.write_record`` and its value in ``simulation.Simulation.current_record``; config, HDF5 layout, API and
tests pick it up from the table.
"""
import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np


class ConfigError(Exception):
    """A user mistake in a config: ``rbx: <file>: <key>: <problem>`` (file None: a command-line option)."""

    def __init__(self, file, key, problem):
        self.file = None if file is None else str(file)
        self.key, self.problem = key, problem
        super().__init__(": ".join(x for x in (self.file, key, problem) if x))


# ---- boundary rules (SPEC §3) ----------------------------------------------------------------------------------

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
    """The wall is a hole (SPEC §3): a trajectory that reaches it records that contact (no collision map; its
    rank is recorded as −1) and ends there. Open billiards: escape and return times (SPEC §10)."""
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
    """Radius R, the mass distribution as given (a name or κ) and κ = 2λ/R²."""
    radius: float
    inertia: object
    kappa: float


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


#: default period (in collisions) of the projection onto the initial energy in rough scenes (docs/accuracy.md)
RENORMALIZE_EVERY = 16


@dataclass(frozen=True)
class Numerics:
    """Numerical options (docs/accuracy.md measures each): project back onto the initial energy every
    ``renormalize`` collisions of a rough scene (0: never; ``engine.energy_factor``), compensated summation of
    the time and the position, snapping the centre onto the wall at contact. Config section ``numerics``."""
    renormalize: int = RENORMALIZE_EVERY
    compensated: bool = False
    snap: bool = False


@dataclass(frozen=True)
class Experiment:
    """A validated experiment. ``initial`` is a tuple of explicit states (read-only arrays) or ``('sample', wall)``.

    ``table`` is a read-only mapping of the table's parameters; ``resolved`` is the plain-data form of the whole
    experiment (tables and boundaries inlined, paths absolute) that is stored in the HDF5 file and read back by
    ``--resume`` and :func:`rbx.open`."""
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

    def geometry(self):
        """The shrunk table the centre moves in (:class:`rbx.geometry.Geometry`)."""
        from .tables import build
        return build(self.table_kind, self.table, self.ball.radius)

    def replace(self, **changes):
        """A copy with some fields changed (``run=…``, ``numerics=…``); ``resolved`` follows ``run``, ``output``
        and ``numerics`` so that the file written records what was run."""
        new = dataclasses.replace(self, **changes)
        if self.resolved is not None:
            resolved = dict(self.resolved)
            if "run" in changes:
                resolved["run"] = dataclasses.asdict(new.run)
            if "output" in changes:
                resolved["output"] = new.output.resolved()
            if "numerics" in changes:
                resolved["numerics"] = dataclasses.asdict(new.numerics)
            object.__setattr__(new, "resolved", resolved)
        return new


# ---- record fields (SPEC §5) ---------------------------------------------------------------------------------------

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
