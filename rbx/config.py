"""Experiment configs: YAML in, validated once into frozen dataclasses (SPEC §3–4).

Every user mistake becomes a :class:`ConfigError` naming the file, the key (a dotted path such as
``boundary.walls.top.rank``) and the problem; the CLI prints it as one line and exits with code 2.
"""
import difflib
import math
import os
from dataclasses import dataclass, field

import numpy as np
import yaml

from . import geometry
from .physics import kappa_of

RECORD_FIELDS = ("time", "position", "velocity", "angular_velocity", "orientation", "wall", "rank")
TABLE_PARAMS = {"strip": ("width",), "circle": ("radius",), "wedge": ("angle_deg",), "rectangle": ("width", "height"),
                "polygon": ("vertices",), "plates": ("gap",), "box": ("size",)}
TABLE_DIM = {"strip": 2, "circle": 2, "wedge": 2, "rectangle": 2, "polygon": 2, "plates": 3, "box": 3}


class ConfigError(Exception):
    """A user mistake in a config: ``rbx: <file>: <key>: <problem>``."""

    def __init__(self, file, key, problem):
        self.file, self.key, self.problem = str(file), key, problem
        super().__init__(f"{self.file}: {key}: {problem}" if key else f"{self.file}: {problem}")


# ---- the validated config -------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Constant:
    rank: int
    direction: tuple | None = None      # ('deg', θ) or ('vector', (x, y, z)) for 3D rank 1


@dataclass(frozen=True)
class Hemisphere:
    axis: tuple
    rough: object
    smooth: object


@dataclass(frozen=True)
class Random:
    choices: tuple
    probabilities: tuple


@dataclass(frozen=True)
class Ball:
    radius: float
    inertia: object
    kappa: float


@dataclass(frozen=True)
class Run:
    collisions: int
    trajectories: int
    seed: int


@dataclass(frozen=True)
class Output:
    path: str | None
    record: tuple
    every: int


@dataclass(frozen=True)
class Config:
    """A validated experiment. ``initial`` is a tuple of explicit states (dicts of arrays) or ``('sample', wall)``."""
    source: str
    dimension: int
    table_kind: str
    table: dict = field(hash=False)
    wall_rules: tuple = ()               # one rule per wall, in wall order
    wall_names: tuple = ()
    ball: Ball = None
    initial: object = None
    run: Run = None
    output: Output = None
    resolved: dict = field(default=None, hash=False, compare=False)

    def geometry(self):
        return geometry.build(self.table_kind, self.table, self.ball.radius)

    def replace(self, **changes):
        import dataclasses
        return dataclasses.replace(self, **changes)


# ---- loading --------------------------------------------------------------------------------------------------

def load(path, overrides=None):
    """Read and validate an experiment config file -> :class:`Config`. Raises :class:`ConfigError`."""
    path = os.path.abspath(path)
    data = _read_yaml(path)
    return from_dict(data, path, overrides)


def _read_yaml(path, key=None):
    try:
        with open(path, encoding="utf-8") as fh:
            data = yaml.safe_load(fh)
    except FileNotFoundError:
        raise ConfigError(path, key, "file not found") from None
    except IsADirectoryError:
        raise ConfigError(path, key, "is a directory, not a YAML file") from None
    except UnicodeDecodeError:
        raise ConfigError(path, key, "not a text (UTF-8) file") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ConfigError(path, key, f"YAML syntax error: {where}{problem}") from None
    return data


class _Checker:
    """Type and range checks that name the file and the dotted key."""

    def __init__(self, file):
        self.file = file

    def fail(self, key, problem):
        raise ConfigError(self.file, key, problem)

    def mapping(self, value, key, allowed, required=()):
        if not isinstance(value, dict):
            self.fail(key, f"expected a mapping, got {_kind(value)}")
        for k in value:
            if k not in allowed:
                hint = difflib.get_close_matches(str(k), allowed, n=1)
                extra = f" (did you mean '{hint[0]}'?)" if hint else f" (allowed: {', '.join(allowed)})"
                self.fail(_join(key, k), f"unknown key{extra}")
        for k in required:
            if k not in value:
                self.fail(_join(key, k), "missing required key")
        return value

    def number(self, value, key, positive=False, lo=None, hi=None, lo_open=False, hi_open=False):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(key, f"expected a number, got {_kind(value)}")
        value = float(value)
        if not math.isfinite(value):
            self.fail(key, f"must be finite, got {value}")
        if positive and value <= 0:
            self.fail(key, f"must be positive, got {value:g}")
        if lo is not None and (value < lo or (lo_open and value == lo)):
            self.fail(key, f"must be {'>' if lo_open else '≥'} {lo:g}, got {value:g}")
        if hi is not None and (value > hi or (hi_open and value == hi)):
            self.fail(key, f"must be {'<' if hi_open else '≤'} {hi:g}, got {value:g}")
        return value

    def integer(self, value, key, lo=None, hi=None):
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        if isinstance(value, bool) or not isinstance(value, int):
            self.fail(key, f"expected an integer, got {_kind(value)}")
        if lo is not None and value < lo:
            self.fail(key, f"must be ≥ {lo}, got {value}")
        if hi is not None and value > hi:
            self.fail(key, f"must be ≤ {hi}, got {value}")
        return value

    def vector(self, value, key, n):
        if not isinstance(value, (list, tuple)):
            self.fail(key, f"expected a list of {n} numbers, got {_kind(value)}")
        if len(value) != n:
            self.fail(key, f"expected {n} numbers, got {len(value)}")
        return tuple(self.number(x, f"{key}[{i}]") for i, x in enumerate(value))


def _kind(value):
    if value is None:
        return "nothing (null)"
    return {bool: "a boolean", str: f"the text '{value}'", list: "a list", dict: "a mapping",
            int: "an integer", float: "a number"}.get(type(value), type(value).__name__)


def _join(key, k):
    return f"{key}.{k}" if key else str(k)


def from_dict(data, source="<config>", overrides=None):
    """Validate a config mapping (paths relative to ``source``'s folder) -> :class:`Config`."""
    c = _Checker(source)
    base = os.path.dirname(os.path.abspath(source)) if not source.startswith("<") else os.getcwd()
    c.mapping(data, "", ("table", "boundary", "ball", "initial", "run", "output"),
              required=("table", "boundary", "ball", "initial"))
    resolved = {}

    table, table_file = _include(data["table"], "table", base, c)
    tc = _Checker(table_file or source)
    tc.mapping(table, "table" if table_file is None else "", ("kind",) + tuple(sorted({p for ps in TABLE_PARAMS.values() for p in ps})), ("kind",))
    tkey = (lambda k: _join("table", k)) if table_file is None else (lambda k: k)
    kind = table["kind"]
    if kind not in TABLE_PARAMS:
        hint = difflib.get_close_matches(str(kind), TABLE_PARAMS, n=1)
        tc.fail(tkey("kind"), f"unknown table kind '{kind}'" + (f" (did you mean '{hint[0]}'?)" if hint else
                                                                f" (known: {', '.join(TABLE_PARAMS)})"))
    tc.mapping(table, "table" if table_file is None else "", ("kind",) + TABLE_PARAMS[kind], ("kind",) + TABLE_PARAMS[kind])
    n = TABLE_DIM[kind]
    tparams = _table_params(kind, table, tc, tkey)
    resolved["table"] = {"kind": kind, **{k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in tparams.items()}}

    ball = c.mapping(data["ball"], "ball", ("radius", "inertia"), ("radius",))
    radius = c.number(ball["radius"], "ball.radius", positive=True)
    inertia = ball.get("inertia", "uniform")
    if isinstance(inertia, str):
        names = ("uniform", "shell", "ring") if n == 2 else ("uniform", "shell")
        if inertia not in names:
            c.fail("ball.inertia", f"unknown mass distribution '{inertia}' for a {n}D ball (use {', '.join(names)} "
                                   f"or a number κ in (0, 1])")
    else:
        inertia = c.number(inertia, "ball.inertia", lo=0.0, hi=1.0, lo_open=True)
    kappa = kappa_of(inertia, n)
    resolved["ball"] = {"radius": radius, "inertia": inertia}

    try:
        geom = geometry.build(kind, tparams, radius)
    except (ValueError, np.linalg.LinAlgError) as exc:  # pragma: no cover - defensive
        c.fail("table", f"cannot build the table: {exc}")
    _check_fits(kind, tparams, radius, geom, c)
    names = geom.wall_names

    bdata, bfile = _include(data["boundary"], "boundary", base, c)
    bc = _Checker(bfile or source)
    bkey = "boundary" if bfile is None else ""
    bc.mapping(bdata, bkey, ("default", "walls"))
    if "default" not in bdata and set((bdata.get("walls") or {})) != set(names):
        bc.fail(_join(bkey, "default"), "missing: give a default rule or a rule for every wall "
                                        f"({', '.join(names)})")
    default = _rule(bdata["default"], _join(bkey, "default"), n, bc, geom, None) if "default" in bdata else None
    walls_cfg = bdata.get("walls") or {}
    if not isinstance(walls_cfg, dict):
        bc.fail(_join(bkey, "walls"), f"expected a mapping from wall name to rule, got {_kind(walls_cfg)}")
    per_wall = []
    for w in walls_cfg:
        if w not in names:
            hint = difflib.get_close_matches(str(w), names, n=1)
            bc.fail(_join(bkey, f"walls.{w}"), f"no wall named '{w}' in a {kind} table" +
                    (f" (did you mean '{hint[0]}'?)" if hint else f" (walls: {', '.join(names)})"))
    for i, w in enumerate(names):
        if w in walls_cfg:
            per_wall.append(_rule(walls_cfg[w], _join(bkey, f"walls.{w}"), n, bc, geom, [i]))
        else:
            per_wall.append(default)
    if default is not None:
        _rule(bdata["default"], _join(bkey, "default"), n, bc, geom,
              [i for i, w in enumerate(names) if w not in walls_cfg])
    resolved["boundary"] = {"default": bdata["default"]} if "default" in bdata else {}
    if walls_cfg:
        resolved["boundary"]["walls"] = walls_cfg

    run = c.mapping(data.get("run") or {}, "run", ("collisions", "trajectories", "seed"))
    ov = overrides or {}
    collisions = c.integer(ov.get("collisions", run.get("collisions", 1000)), "run.collisions", lo=1)
    seed = c.integer(ov.get("seed", run.get("seed", 0)), "run.seed", lo=0, hi=2**63 - 1)

    initial, traj_default = _initial(data["initial"], n, c, geom, kind, radius, names)
    trajectories = c.integer(ov.get("trajectories", run.get("trajectories", traj_default)), "run.trajectories", lo=1)
    if isinstance(initial, tuple) and initial and initial[0] != "sample" and len(initial) > 1 \
            and trajectories != len(initial):
        c.fail("run.trajectories", f"is {trajectories} but initial lists {len(initial)} states")
    resolved["initial"] = data["initial"]
    resolved["run"] = {"collisions": collisions, "trajectories": trajectories, "seed": seed}

    out = c.mapping(data.get("output") or {}, "output", ("path", "record", "every"))
    opath = out.get("path")
    if opath is not None:
        if not isinstance(opath, str) or not opath:
            c.fail("output.path", f"expected a file name, got {_kind(opath)}")
        opath = os.path.normpath(os.path.join(base, opath))
    record = out.get("record", list(RECORD_FIELDS))
    if not isinstance(record, list):
        c.fail("output.record", f"expected a list of fields, got {_kind(record)}")
    for i, f in enumerate(record):
        if f not in RECORD_FIELDS:
            hint = difflib.get_close_matches(str(f), RECORD_FIELDS, n=1)
            c.fail(f"output.record[{i}]", f"unknown field '{f}'" + (f" (did you mean '{hint[0]}'?)" if hint else
                                                                  f" (fields: {', '.join(RECORD_FIELDS)})"))
    record = tuple(f for f in RECORD_FIELDS if f in record)
    every = c.integer(out.get("every", 1), "output.every", lo=1)
    resolved["output"] = {"path": opath, "record": list(record), "every": every}

    return Config(source=source, dimension=n, table_kind=kind, table=tparams, wall_rules=tuple(per_wall),
                  wall_names=tuple(names), ball=Ball(radius, inertia, kappa), initial=initial,
                  run=Run(collisions, trajectories, seed), output=Output(opath, record, every), resolved=resolved)


def _include(value, key, base, c):
    """A table or boundary given inline (mapping) or as a path relative to the config's folder."""
    if isinstance(value, str):
        path = os.path.normpath(os.path.join(base, value))
        if not os.path.exists(path):
            c.fail(key, f"file not found: {path}")
        return _read_yaml(path), path
    if not isinstance(value, dict):
        c.fail(key, f"expected a file name or a mapping, got {_kind(value)}")
    return value, None


def _table_params(kind, t, c, key):
    if kind in ("strip",):
        return {"width": c.number(t["width"], key("width"), positive=True)}
    if kind == "circle":
        return {"radius": c.number(t["radius"], key("radius"), positive=True)}
    if kind == "wedge":
        return {"angle_deg": c.number(t["angle_deg"], key("angle_deg"), lo=0, hi=180, lo_open=True, hi_open=True)}
    if kind == "rectangle":
        return {"width": c.number(t["width"], key("width"), positive=True),
                "height": c.number(t["height"], key("height"), positive=True)}
    if kind == "plates":
        return {"gap": c.number(t["gap"], key("gap"), positive=True)}
    if kind == "box":
        size = c.vector(t["size"], key("size"), 3)
        for i, s in enumerate(size):
            if s <= 0:
                c.fail(f"{key('size')}[{i}]", f"must be positive, got {s:g}")
        return {"size": list(size)}
    V = t["vertices"]
    if not isinstance(V, list) or len(V) < 3:
        c.fail(key("vertices"), "expected a list of at least 3 points [x, y]")
    V = np.array([c.vector(p, f"{key('vertices')}[{i}]", 2) for i, p in enumerate(V)])
    area = 0.5 * np.sum(V[:, 0] * np.roll(V[:, 1], -1) - np.roll(V[:, 0], -1) * V[:, 1])
    if area <= 0:
        c.fail(key("vertices"), "must be listed counter-clockwise (the signed area is not positive)")
    if np.any(np.linalg.norm(np.roll(V, -1, axis=0) - V, axis=1) == 0):
        c.fail(key("vertices"), "two consecutive vertices coincide")
    if _self_intersecting(V):
        c.fail(key("vertices"), "the polygon crosses itself")
    return {"vertices": V.tolist()}


def _self_intersecting(V):
    m = len(V)
    for i in range(m):
        a, b = V[i], V[(i + 1) % m]
        for j in range(i + 2, m):
            if i == 0 and j == m - 1:
                continue
            p, q = V[j], V[(j + 1) % m]
            d1, d2 = np.cross(b - a, p - a), np.cross(b - a, q - a)
            d3, d4 = np.cross(q - p, a - p), np.cross(q - p, b - p)
            if d1 * d2 < 0 and d3 * d4 < 0:
                return True
    return False


def _check_fits(kind, p, R, geom, c):
    where = "ball.radius"
    if kind == "strip" and 2 * R >= p["width"]:
        c.fail(where, f"a ball of radius {R:g} does not fit in a strip of width {p['width']:g}")
    if kind == "plates" and 2 * R >= p["gap"]:
        c.fail(where, f"a ball of radius {R:g} does not fit between plates {p['gap']:g} apart")
    if kind == "circle" and R >= p["radius"]:
        c.fail(where, f"a ball of radius {R:g} does not fit in a circle of radius {p['radius']:g}")
    if kind == "box" and 2 * R >= min(p["size"]):
        c.fail(where, f"a ball of radius {R:g} does not fit in a box of size {p['size']}")
    if kind in ("rectangle", "polygon") and np.any(geom.lengths <= 0):
        bad = int(np.argmin(geom.lengths))
        c.fail(where, f"a ball of radius {R:g} does not fit in the {kind} (near wall '{geom.wall_names[bad]}')")


def _rule(r, key, n, c, geom, wall_ids):
    """Validate a rule (recursively); ``wall_ids``: the walls it applies to, for checking 3D directions."""
    if not isinstance(r, dict):
        c.fail(key, f"expected a rule mapping such as {{rule: constant, rank: 1}}, got {_kind(r)}")
    kinds = ("constant", "hemisphere", "random")
    if "rule" not in r:
        c.fail(_join(key, "rule"), f"missing required key (one of: {', '.join(kinds)})")
    kind = r["rule"]
    if kind not in kinds:
        hint = difflib.get_close_matches(str(kind), kinds, n=1)
        c.fail(_join(key, "rule"), f"unknown rule '{kind}'" + (f" (did you mean '{hint[0]}'?)" if hint else
                                                             f" (rules: {', '.join(kinds)})"))
    if kind == "constant":
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
            if "direction_deg" in r:
                return Constant(1, ("deg", c.number(r["direction_deg"], _join(key, "direction_deg"))))
            vec = np.array(c.vector(r["direction"], _join(key, "direction"), 3))
            for w in wall_ids or ():
                t = geom.wall_list[w].tangents
                if np.linalg.norm(t @ vec) < 1e-9 * max(np.linalg.norm(vec), 1e-300):
                    c.fail(_join(key, "direction"), f"is normal to wall '{geom.wall_names[w]}': it has no "
                                                    "tangential part")
            return Constant(1, ("vector", tuple(vec)))
        return Constant(rank)
    if kind == "hemisphere":
        c.mapping(r, key, ("rule", "axis", "rough", "smooth"), ("axis", "rough", "smooth"))
        axis = np.array(c.vector(r["axis"], _join(key, "axis"), n))
        norm = np.linalg.norm(axis)
        if norm == 0:
            c.fail(_join(key, "axis"), "must be a non-zero vector")
        return Hemisphere(tuple(axis / norm), _rule(r["rough"], _join(key, "rough"), n, c, geom, wall_ids),
                          _rule(r["smooth"], _join(key, "smooth"), n, c, geom, wall_ids))
    c.mapping(r, key, ("rule", "choices", "probabilities"), ("choices", "probabilities"))
    ch, pr = r["choices"], r["probabilities"]
    if not isinstance(ch, list) or not ch:
        c.fail(_join(key, "choices"), "expected a non-empty list of rules")
    if not isinstance(pr, list) or len(pr) != len(ch):
        c.fail(_join(key, "probabilities"), f"expected a list of {len(ch)} numbers, one per choice")
    probs = tuple(c.number(p, f"{_join(key, 'probabilities')}[{i}]", lo=0.0) for i, p in enumerate(pr))
    if abs(sum(probs) - 1.0) > 1e-9:
        c.fail(_join(key, "probabilities"), f"must sum to 1, they sum to {sum(probs):.12g}")
    return Random(tuple(_rule(x, f"{_join(key, 'choices')}[{i}]", n, c, geom, wall_ids) for i, x in enumerate(ch)),
                  probs)


STATE_KEYS = ("position", "velocity", "angular_velocity", "orientation")


def _initial(init, n, c, geom, kind, R, names):
    """-> (tuple of explicit states, or ('sample', wall index or None)), default number of trajectories."""
    if isinstance(init, dict) and "sample" in init:
        c.mapping(init, "initial", ("sample", "wall"))
        if init["sample"] != "billiard":
            c.fail("initial.sample", f"unknown sampler '{init['sample']}' (use: billiard)")
        wall = init.get("wall")
        if wall is not None and wall not in names:
            hint = difflib.get_close_matches(str(wall), names, n=1)
            c.fail("initial.wall", f"no wall named '{wall}'" + (f" (did you mean '{hint[0]}'?)" if hint else
                                                              f" (walls: {', '.join(names)})"))
        idx = None if wall is None else names.index(wall)
        walls = range(len(names)) if idx is None else [idx]
        if kind == "wedge":
            c.fail("initial.wall" if wall else "initial.sample", "the wedge's walls are infinite: the billiard "
                                                                 "measure on them cannot be normalised")
        return ("sample", idx), 1
    states = init if isinstance(init, list) else [init]
    if not states:
        c.fail("initial", "expected a state or a non-empty list of states")
    out = []
    for i, s in enumerate(states):
        key = "initial" if not isinstance(init, list) else f"initial[{i}]"
        c.mapping(s, key, STATE_KEYS, ("position", "velocity"))
        pos = np.array(c.vector(s["position"], _join(key, "position"), n))
        vel = np.array(c.vector(s["velocity"], _join(key, "velocity"), n))
        if not np.any(vel):
            c.fail(_join(key, "velocity"), "must be non-zero")
        spin = s.get("angular_velocity", 0.0 if n == 2 else [0.0, 0.0, 0.0])
        spin = c.number(spin, _join(key, "angular_velocity")) if n == 2 else \
            np.array(c.vector(spin, _join(key, "angular_velocity"), 3))
        orient = s.get("orientation", 0.0 if n == 2 else [0.0, 0.0, 0.0])
        orient = c.number(orient, _join(key, "orientation")) if n == 2 else \
            np.array(c.vector(orient, _join(key, "orientation"), 3))
        clearance = float(geom.clearance(pos))
        if clearance < -1e-12 * geom.size:
            c.fail(_join(key, "position"), f"{pos.tolist()} is outside the table shrunk by the ball's radius "
                                           f"{R:g} (by {-clearance:.3g})")
        out.append({"position": pos, "velocity": vel, "angular_velocity": spin, "orientation": orient})
    return tuple(out), len(out)
