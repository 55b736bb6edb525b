"""Experiment configs: YAML in, validated once into frozen dataclasses (docs/reference.md §3–4).

Every user mistake becomes a :class:`ConfigError` naming the file, the key (a dotted path such as
``boundary.walls.top.rank``) and the problem; the CLI prints it as one line and exits with code 2. A table or
boundary kept in its own file is checked against that file, so its errors name it. Command-line overrides
(``--collisions`` …) are checked here too and their errors name the option instead of a file.

What is checked: the YAML itself (syntax with line and column, duplicate keys, an empty file, a top level that is
not a mapping); unknown keys (with a did-you-mean hint) and missing required ones at every level; the type, range
and finiteness of every value; that the ball fits the table and starts inside the table shrunk by its radius with
a finite, non-zero velocity; wall names; ranks 0 … n−1 and a direction for 3D rank 1; probabilities that are
non-negative and sum to 1; positive integer counts. Relative paths are resolved from the config file's folder.

Changes to a config (``--set KEY=VALUE``, ``rbx.load(path, {KEY: VALUE})``, a changed part of an experiment) are
made to the config mapping before it is validated (:func:`apply_changes`), so they meet the same checks and the
same messages as the YAML. A key is dotted (``ball.inertia``, ``boundary.walls.top``, ``initial[0].position``); an
unknown one is refused with a did-you-mean hint (``colisions``: did you mean 'run.collisions'?).
"""
import copy
import dataclasses
import difflib
import math
import numbers
import os
import re
import types
from collections.abc import Mapping

import numpy as np

from . import rules, tables
from .analysis import table_measure
from .model import (COMPRESSIONS, DEFAULT_MAX_SIZE, RECORD_FIELDS, SERVICES, VALIDATED, Ball, ConfigError, Experiment,
                    INERTIA_NAMES, Numerics, Output, RunSettings, kappa_of, unknown_inertia)
from .paths import path_text_problem
from .primitives import P_POINT
from .yamlfile import check_size, copied, gc_paused, parse_yaml, read_yaml
from .rules import PROBABILITY_SUM_TOLERANCE, parse_rule  # noqa: F401 - the tolerance: read by the rules' checks

SECTIONS = ("table", "boundary", "ball", "initial", "run", "output", "numerics")
#: command-line options that override config keys, and the option each one's errors name
OVERRIDE_OPTIONS = {"collisions": "--collisions", "trajectories": "--trajectories", "seed": "--seed",
                    "max_size": "--max-size"}
#: the config key each of those options overrides
OVERRIDE_KEYS = {"collisions": "run.collisions", "trajectories": "run.trajectories", "seed": "run.seed",
                 "max_size": "output.max_size"}
#: the keys of the sections whose keys are fixed (those of table, boundary and initial depend on the table kind,
#: its walls and the kind of start)
SECTION_KEYS = {"ball": ("radius", "inertia"), "run": ("collisions", "trajectories", "seed"),
                "output": ("path", "record", "every", "max_size", "compression"),
                "numerics": ("renormalize", "compensated", "snap")}
#: units of a size (output.max_size, --max-size)
SIZE_UNITS = {"": 1, "b": 1, "kb": 1e3, "mb": 1e6, "gb": 1e9, "tb": 1e12, "pb": 1e15,
              "kib": 2**10, "mib": 2**20, "gib": 2**30, "tib": 2**40, "pib": 2**50}
#: counters are int64 in the kernels; anything near this is a typo, not a run anyone can wait for
MAX_COUNT = 2**62
MAX_SEED = 2**63 - 1


# ---- checks ---------------------------------------------------------------------------------------------------

_SCIENTIFIC = re.compile(r"^\s*[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+\s*$")


class _Checker:
    """Type and range checks that name the file and the dotted key."""

    #: added to 'file not found' of a table or boundary file (a mapping's paths are relative to the working folder)
    not_found_hint = ""

    def __init__(self, file):
        self.file = file
        self.included = []     # files the config names (table, boundary), in the order met

    def fail(self, key, problem):
        raise ConfigError(self.file, key, problem)

    @staticmethod
    def kind(value):
        """How a value is named in a message: 'a list', "the text 'abc'", …"""
        return _kind(value)

    def mapping(self, value, key, allowed, required=()):
        if not isinstance(value, dict):
            self.fail(key, f"expected a mapping, got {_kind(value)}")
        for k in value:
            if k not in allowed:
                self.fail(_join(key, k), "unknown key" + _hint(k, allowed, "allowed"))
        for k in required:
            if k not in value:
                self.fail(_join(key, k), "missing required key")
        return value

    def choice(self, value, key, allowed, what):
        """A name from ``allowed`` (table kinds, rule names, …) -> the name."""
        if not isinstance(value, str):
            self.fail(key, f"expected a {what} name ({', '.join(allowed)}), got {_kind(value)}")
        if value not in allowed:
            self.fail(key, f"unknown {what} '{value}'" + _hint(value, allowed, "known"))
        return value

    def number(self, value, key, positive=False, lo=None, hi=None, lo_open=False, hi_open=False):
        if isinstance(value, str) and _SCIENTIFIC.match(value):
            value = float(value)
        if isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_)):
            value = float(value) if not isinstance(value, numbers.Integral) else int(value)   # NumPy's too
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(key, f"expected a number, got {_kind(value)}")
        try:
            value = float(value)
        except OverflowError:
            self.fail(key, "is too large")
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
        if isinstance(value, numbers.Integral) and not isinstance(value, bool):
            value = int(value)          # NumPy's integers too (np.int64(100) from an array or a range)
        if isinstance(value, str) and _SCIENTIFIC.match(value):
            value = float(value)
        if isinstance(value, float) and math.isfinite(value) and value.is_integer():
            value = int(value)
        if isinstance(value, float):
            self.fail(key, f"expected an integer, got {value:g}")
        if isinstance(value, bool) or not isinstance(value, int):
            self.fail(key, f"expected an integer, got {_kind(value)}")
        if lo is not None and value < lo:
            self.fail(key, f"must be {'a positive integer' if lo == 1 else f'≥ {lo}'}, got {value}")
        if hi is not None and value > hi:
            self.fail(key, f"must be ≤ {hi:.3g}, got {value:.3g}")
        return value

    def vector(self, value, key, n):
        if not isinstance(value, (list, tuple)):
            self.fail(key, f"expected a list of {n} numbers, got {_kind(value)}")
        if len(value) != n:
            self.fail(key, f"expected {n} numbers, got {len(value)}")
        return tuple(self.number(x, f"{key}[{i}]") for i, x in enumerate(value))

    def nonzero_vector(self, value, key, n):
        vec = np.array(self.vector(value, key, n))
        if not np.any(vec):
            self.fail(key, "must be a non-zero vector")
        return vec


def _hint(name, allowed, label):
    close = difflib.get_close_matches(str(name), [str(a) for a in allowed], n=1)
    return f" (did you mean '{close[0]}'?)" if close else f" ({label}: {', '.join(str(a) for a in allowed)})"


def _kind(value):
    if value is None:
        return "nothing (null)"
    if isinstance(value, str):
        return f"the text '{value}'" if len(value) <= 40 else f"the text '{value[:37]}...'"
    return {bool: "a boolean", list: "a list", dict: "a mapping", int: "an integer",
            float: "a number"}.get(type(value), type(value).__name__)


def _join(key, k):
    return f"{key}.{k}" if key else str(k)


# ---- loading --------------------------------------------------------------------------------------------------

def load(path, overrides=None, changes=None, label="override"):
    """Read and validate an experiment config file -> :class:`rbx.model.Experiment`. Raises :class:`ConfigError`.

    ``overrides``: ``{'collisions': N, 'trajectories': M, 'seed': S, 'max_size': X}`` from the command line's
    options (None: not given; their errors name the option); ``changes``: ``{dotted key: value}`` made to the
    config before it is validated (:func:`apply_changes`; ``label`` names where they came from in messages)."""
    path = os.path.abspath(path)
    with gc_paused():                   # one pause over reading and validating (one deferred collection)
        return from_dict(read_yaml(path), path, overrides, changes=changes, label=label, copy_data=False)


def loads(text, source, overrides=None):
    """Validate config YAML text (e.g. the ``config`` attribute of a run's HDF5 file) -> :class:`rbx.model.Experiment`."""
    data = parse_yaml(text, source)
    if data is None:
        raise ConfigError(source, None, "the config is empty")
    return from_dict(data, source, overrides, copy_data=False)


def from_dict(data, source="<config>", overrides=None, changes=None, base=None, label="override", includes=(),
              copy_data=True):
    """Validate a config mapping -> :class:`rbx.model.Experiment` (the mapping itself is left as it is).

    Relative paths are resolved from ``base`` (a folder), else from ``source``'s folder (a ``source`` such as
    ``<config>``, not a file: the working folder). ``overrides`` and ``changes`` as for :func:`load`;
    ``includes``: files named by the config this mapping was made from (kept in the experiment's ``includes``)."""
    with gc_paused():
        return _validated(data, source, overrides, changes, base, label, includes, copy_data)


def _validated(data, source, overrides, changes, base, label, includes, copy_data):
    try:
        check_size(data, source)
        if copy_data:          # the experiment must not share the caller's lists and mappings (its stored config)
            data = copied(data, {})
        inlined = ()
        folder = _base(source, base)
        if changes:
            data, inlined = apply_changes(data, changes, str(source), folder, label)
        overrides = overrides or {}
        for name, option in OVERRIDE_OPTIONS.items():
            clash = [k for k in changes or () if overrides.get(name) is not None
                     and (OVERRIDE_KEYS[name] + ".").startswith(k + ".")]
            if clash:
                raise ConfigError(None, option, f"and {label} {clash[0]} both set {OVERRIDE_KEYS[name]}: give one")
        try:
            exp = _from_dict(data, str(source), overrides, folder, base is None and str(source).startswith("<"),
                             tuple(includes) + tuple(inlined))
        except ConfigError as exc:
            raise _blame(exc, changes, label) from None
        return exp
    except RecursionError:
        # a YAML alias that contains itself (`&a [*a]`) would otherwise recurse without end
        raise ConfigError(source, None, "the config is nested too deeply (an alias that refers to itself?)") \
            from None


def _base(source, base):
    """The folder relative paths are resolved from."""
    if base is not None:
        return os.path.abspath(os.fspath(base))
    source = str(source)
    return os.path.dirname(os.path.abspath(source)) if not source.startswith("<") else os.getcwd()


def _blame(exc, changes, label):
    """A validation error of a key that a change set: the message says so (the file does not hold that value)."""
    for key in changes or ():
        k = str(key)
        if exc.key and (exc.key == k or exc.key.startswith((k + ".", k + "["))):
            return ConfigError(exc.file, exc.key, f"{exc.problem} ({label} {k})")
    return exc


def _from_dict(data, source, overrides, base, cwd_hint=False, includes=()):
    c = _Checker(source)
    if cwd_hint:
        c.not_found_hint = (" (a mapping's relative paths are resolved from the working folder: give base=, the file "
                            "or folder the config came from, or load exp.to_dict() of a loaded experiment)")
    c.included.extend(includes)
    if not isinstance(data, dict):
        c.fail(None, f"expected a mapping with the sections {', '.join(SECTIONS)}; got {_kind(data)}")
    c.mapping(data, "", SECTIONS, required=("table", "boundary", "ball", "initial"))
    resolved = {}

    kind, tparams, tc, tkey = _table(data["table"], base, c)
    n = tables.dimension(kind, tparams)
    resolved["table"] = {"kind": kind, **tparams}
    frozen_table = types.MappingProxyType({k: _frozen(v) for k, v in tparams.items()})

    radius, inertia, kappa = _ball(data["ball"], n, c)
    resolved["ball"] = {"radius": radius, "inertia": inertia}

    try:
        # a degenerate table (edges nearly parallel, numbers near the limit) may overflow while it is built: that
        # is refused below in one line, not shown as NumPy warnings on stderr
        with np.errstate(all="ignore"):
            geom = tables.build(kind, tparams, radius)
            if not np.all(np.isfinite(geom.params)):
                try:        # a rule of the kind's own keys says more (a mushroom's stem as wide as its cap)
                    _check_fits(kind, tparams, radius, geom, c, tc, tkey)
                except ConfigError:
                    raise
                except Exception:   # noqa: BLE001 - the check itself cannot read such a table: the overflow says it
                    pass
                tc.fail(tkey or None, "the table's numbers overflow once it is built (coordinates too large, or "
                                      "walls too nearly parallel)")
            _check_fits(kind, tparams, radius, geom, c, tc, tkey)
        _check_span(geom, n, tc, tkey)
    except ConfigError:
        raise
    except Exception as exc:   # a degenerate table the checks above let through: still the user's input
        tc.fail(tkey or None, f"cannot build the table: {exc}")
    names = geom.wall_names

    per_wall, resolved["boundary"] = _boundary(data["boundary"], base, c, n, geom, kind)

    run = c.mapping(_section(data, "run"), "run", SECTION_KEYS["run"])
    collisions = _count(run, overrides, "collisions", 1000, c, lo=1, hi=MAX_COUNT)
    seed = _count(run, overrides, "seed", 0, c, lo=0, hi=MAX_SEED)

    initial, traj_default = _initial(data["initial"], n, c, geom, kind, radius, kappa, names)
    trajectories = _count(run, overrides, "trajectories", traj_default, c, lo=1, hi=MAX_COUNT)
    if not isinstance(initial[0], str) and len(initial) > 1 and trajectories != len(initial):
        key, file = ("run.trajectories", source) if overrides.get("trajectories") is None else ("--trajectories", None)
        raise ConfigError(file, key, f"is {trajectories} but initial lists {len(initial)} states")
    resolved["initial"] = data["initial"]
    resolved["run"] = {"collisions": collisions, "trajectories": trajectories, "seed": seed}

    output = _output(_section(data, "output"), base, c, overrides)
    resolved["output"] = output.resolved()

    numerics = _numerics(_section(data, "numerics"), c)
    if "numerics" in data:   # stored only when given, so that files of runs without it read the same as before
        resolved["numerics"] = {"renormalize": numerics.renormalize, "compensated": numerics.compensated,
                                "snap": numerics.snap}

    return Experiment(source=source, dimension=n, table_kind=kind, table=frozen_table,
                      wall_rules=tuple(per_wall), wall_names=tuple(names), ball=Ball(radius, inertia, n),
                      initial=initial, run=RunSettings(collisions, trajectories, seed), output=output,
                      numerics=numerics, resolved=resolved, includes=tuple(c.included), checked=VALIDATED)


def _numerics(section, c):
    """The optional section ``numerics: {renormalize: N, compensated: bool, snap: bool}`` -> :class:`Numerics`."""
    c.mapping(section, "numerics", SECTION_KEYS["numerics"])
    default = Numerics()
    flags = {}
    for name in ("compensated", "snap"):
        value = section.get(name, getattr(default, name))
        if not isinstance(value, bool):
            c.fail(f"numerics.{name}", f"expected true or false, got {_kind(value)}")
        flags[name] = value
    renormalize = c.integer(section.get("renormalize", default.renormalize), "numerics.renormalize", lo=0,
                            hi=MAX_COUNT)
    return Numerics(renormalize, **flags)


def _frozen(x):
    return tuple(_frozen(v) for v in x) if isinstance(x, list) else x


def _section(data, name):
    """An optional section: absent or empty (``run:`` with nothing after it) means all defaults."""
    value = data.get(name)
    return {} if value is None else value


def _count(section, overrides, name, default, c, lo, hi):
    """run.<name>, or its command-line override (whose errors name the option, not the file)."""
    if overrides.get(name) is not None:
        return _Checker(None).integer(overrides[name], OVERRIDE_OPTIONS[name], lo=lo, hi=hi)
    return c.integer(section.get(name, default), f"run.{name}", lo=lo, hi=hi)


def _include(value, key, base, c):
    """A table or boundary given inline (mapping) or as a path relative to the config's folder -> (data, file)."""
    if isinstance(value, str):
        if not value.strip():
            c.fail(key, "expected a file name or a mapping, got an empty text")
        if path_text_problem(value):
            c.fail(key, path_text_problem(value))
        path = os.path.normpath(os.path.join(base, os.path.expanduser(value)))
        if not os.path.exists(path):
            c.fail(key, f"file not found: {path}{c.not_found_hint}")
        c.included.append(path)
        return read_yaml(path, expected=key), path
    if not isinstance(value, dict):
        c.fail(key, f"expected a file name or a mapping, got {_kind(value)}")
    return value, None


def _table(value, base, c):
    """-> (kind, validated parameters as plain data, the checker of the file the table is written in, the key of
    the table in it: ``table`` inline, '' in a table file of its own)."""
    table, table_file = _include(value, "table", base, c)
    tc = _Checker(table_file or c.file)
    prefix = "table" if table_file is None else ""
    all_params = tuple(sorted({p for k in tables.KINDS.values() for p in list(k.params) + list(k.optional or ())}
                              | {tables.OBSTACLES}))
    tc.mapping(table, prefix, ("kind",) + all_params, ("kind",))
    kind = tc.choice(table["kind"], _join(prefix, "kind"), tuple(tables.KINDS), "table kind")
    k = tables.kind(kind)
    params, optional = tuple(k.params), tuple(k.optional or ())
    tc.mapping(table, prefix, ("kind",) + params + optional + (tables.OBSTACLES,), ("kind",) + params)
    out = {name: check(table[name], tc, _join(prefix, name)) for name, check in k.params.items()}
    out.update({name: check(table[name], tc, _join(prefix, name))
                for name, check in (k.optional or {}).items() if name in table})
    if tables.OBSTACLES in table:
        out[tables.OBSTACLES] = tables.obstacles(table[tables.OBSTACLES], tc, _join(prefix, tables.OBSTACLES),
                                                 tables.dimension(kind, out))
    _check_magnitudes(out, prefix, tc)
    return kind, out, tc, prefix


#: the largest length or coordinate of a table: squares of lengths (distances, quadratics) must stay finite, with
#: room to spare. A Lorentz cell of 1e307 overflowed (inf, then NaN) and its run never ended
MAX_TABLE_NUMBER = 1e100


def _check_magnitudes(value, key, c):
    """Every number of a validated table (nested lists and mappings) is at most MAX_TABLE_NUMBER in size."""
    if isinstance(value, dict):
        for k, v in value.items():
            _check_magnitudes(v, _join(key, str(k)), c)
    elif isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            _check_magnitudes(v, f"{key}[{i}]", c)
    elif isinstance(value, float) and abs(value) > MAX_TABLE_NUMBER:
        c.fail(key, f"{value:g} is too large: a table's lengths and coordinates are at most {MAX_TABLE_NUMBER:g}")


def _ball(ball, n, c):
    """-> (radius, inertia as given, kappa)."""
    c.mapping(ball, "ball", SECTION_KEYS["ball"], ("radius",))
    radius = c.number(ball["radius"], "ball.radius", positive=True)
    inertia = ball.get("inertia", "uniform")
    if isinstance(inertia, str):
        if inertia not in INERTIA_NAMES[n]:
            c.fail("ball.inertia", unknown_inertia(inertia, n))
    else:
        inertia = c.number(inertia, "ball.inertia", lo=0.0, hi=1.0, lo_open=True)
    return radius, inertia, kappa_of(inertia, n)


def _boundary(value, base, c, n, geom, kind):
    """-> (one rule per wall in wall order, plain-data form)."""
    names = geom.wall_names
    bdata, bfile = _include(value, "boundary", base, c)
    bc = _Checker(bfile or c.file)
    bkey = "boundary" if bfile is None else ""
    bc.mapping(bdata, bkey, ("default", "walls"))
    walls_cfg = bdata.get("walls")
    walls_cfg = {} if walls_cfg is None else walls_cfg
    if not isinstance(walls_cfg, dict):
        bc.fail(_join(bkey, "walls"), f"expected a mapping from wall name to rule, got {_kind(walls_cfg)}")
    for w in walls_cfg:
        if w not in names:
            bc.fail(_join(bkey, f"walls.{w}"), f"no wall named '{w}' in a {kind} table" + _hint(w, names, "walls"))
    uncovered = [i for i, w in enumerate(names) if w not in walls_cfg]
    if "default" not in bdata and uncovered:
        bc.fail(_join(bkey, "default"), "missing: give a default rule or a rule for every wall "
                                        f"({', '.join(names)})")
    default = None
    if "default" in bdata:
        # checked against the walls it applies to (a 3D direction must not be normal to any of them)
        default = _rule(bdata["default"], _join(bkey, "default"), n, bc, geom, uncovered)
    per_wall = [_rule(walls_cfg[w], _join(bkey, f"walls.{w}"), n, bc, geom, [i]) if w in walls_cfg else default
                for i, w in enumerate(names)]
    plain = {"default": bdata["default"]} if "default" in bdata else {}
    if walls_cfg:
        plain["walls"] = walls_cfg
    return per_wall, plain


def _output(out, base, c, overrides):
    c.mapping(out, "output", SECTION_KEYS["output"])
    opath = out.get("path")
    if opath is not None:
        if not isinstance(opath, str) or not opath.strip():
            c.fail("output.path", f"expected a file name, got {_kind(opath)}")
        if path_text_problem(opath):
            c.fail("output.path", path_text_problem(opath))
        if opath.endswith(("/", os.sep)):
            c.fail("output.path", f"'{opath}' names a folder; give a file name such as {opath.rstrip('/')}/run.h5")
        # ~ is the home folder, as in a shell (it used to create a folder named '~')
        opath = os.path.normpath(os.path.join(base, os.path.expanduser(opath)))
    record = out.get("record", list(RECORD_FIELDS))
    if record is None:
        record = []
    if not isinstance(record, list):
        c.fail("output.record", f"expected a list of fields ({', '.join(RECORD_FIELDS)}), got {_kind(record)}")
    for i, f in enumerate(record):
        if not isinstance(f, str) or f not in RECORD_FIELDS:
            c.fail(f"output.record[{i}]", f"unknown field {_kind(f) if not isinstance(f, str) else repr(f)}"
                   + _hint(f, RECORD_FIELDS, "fields"))
    record = tuple(f for f in RECORD_FIELDS if f in record)
    every = c.integer(out.get("every", 1), "output.every", lo=1, hi=MAX_COUNT)
    if overrides.get("max_size") is not None:
        max_size = parse_size(overrides["max_size"], _Checker(None), OVERRIDE_OPTIONS["max_size"])
    else:
        max_size = parse_size(out.get("max_size", DEFAULT_MAX_SIZE), c, "output.max_size")
    return Output(opath, record, every, max_size, _compression(out.get("compression", "none"), c))


def _compression(value, c):
    """``output.compression``: ``none``, ``lzf``, ``gzip`` or ``gzip:LEVEL`` (0-9) -> its normal form (``none``,
    ``lzf``, ``gzip:LEVEL``; plain ``gzip`` is level 4, h5py's default)."""
    key = "output.compression"
    if not isinstance(value, str):
        c.fail(key, f"expected one of {', '.join(COMPRESSIONS)} (gzip with a level: gzip:0 … gzip:9), got "
                    f"{_kind(value)}")
    name, colon, level = value.strip().lower().partition(":")
    if name not in COMPRESSIONS:
        c.fail(key, f"unknown compression {value!r}" + _hint(name, COMPRESSIONS, "one of")
               + "; gzip takes a level: gzip:0 … gzip:9")
    if name != "gzip":
        if colon:
            c.fail(key, f"{name} takes no level, got {value!r}")
        return name
    if not colon:
        return "gzip:4"
    if not re.fullmatch(r"[0-9]", level.strip()):
        c.fail(key, f"the gzip level must be a whole number from 0 to 9, got {level.strip()!r}")
    return f"gzip:{int(level)}"


def parse_size(value, c, key):
    """A size in bytes: a number, or a text such as '20 GB', '1.5 TiB', '500MB' -> float (positive)."""
    if isinstance(value, str):
        m = re.fullmatch(r"\s*([0-9.eE+-]+)\s*([A-Za-z]*)\s*", value)
        unit = m.group(2).lower() if m else None
        if not m or unit not in SIZE_UNITS:
            c.fail(key, f"expected a size such as 20 GB, 500 MiB or a number of bytes, got {_kind(value)}")
        try:
            number = float(m.group(1))
        except ValueError:
            c.fail(key, f"expected a size such as 20 GB, 500 MiB or a number of bytes, got {_kind(value)}")
        return c.number(number, key, positive=True) * SIZE_UNITS[unit]
    return c.number(value, key, positive=True)


def _check_fits(kind, p, R, geom, c, tc, tkey):
    """The built table against the ball: a problem of the table's own keys is reported in the file the table is
    written in (``tc``, the table at key ``tkey`` there), one of the ball in the config's."""
    names = list(geom.wall_names)
    for i, ob in enumerate(p.get(tables.OBSTACLES) or ()):
        if names.count(ob["name"]) > 1:
            tc.fail(_join(tkey, f"{tables.OBSTACLES}[{i}].name"), f"'{ob['name']}' names two walls (walls: "
                                                                  f"{', '.join(names)})")
    problem = tables.fits(kind, p, R, geom)
    if isinstance(problem, tuple):     # (the table's key, problem): obstacles, periodic cells
        tc.fail(_join(tkey, problem[0]), problem[1])
    if problem:
        c.fail("ball.radius", f"a ball of radius {R:g} {problem}")


def _rule(r, key, n, c, geom, wall_ids):
    """Validate a rule (recursively) by its kind's record (:func:`rbx.rules.parse_rule`); ``wall_ids``: the walls
    it applies to, for checking 3D directions."""
    return parse_rule(r, key, n, c, geom, wall_ids)


STATE_KEYS = ("position", "velocity", "angular_velocity", "orientation")
#: the smallest initial kinetic energy accepted (10⁴ × the smallest normal float, 2.2e-308): below it the energy
#: and the squares of speeds are subnormal or zero, and the energy projection divides by them
MIN_ENERGY = 1e-304
#: the largest square of a spin the kernels may meet (ω² in the energy; well below overflow)
MAX_SPIN_SQUARE = 1e306
#: the largest initial orientation [rad]: the 2D angle θ, or the length of the 3D rotation vector. At 1e17 the
#: angle's last digit is 16 rad, so θ + ωt never moved and a hemisphere rule read the same side at every
#: collision; a rotation vector of 1e155 squared to infinity and every orientation was NaN. At 1e8 the last digit
#: is 1.5e-8 rad.
MAX_ORIENTATION = 1e8
#: the largest initial position coordinate, in units of the table's size (``geom.size``): in an unbounded table (the
#: strip, the plates, a periodic gas) a start at x = 1e17 was taken, and x never moved (its last digit, 16, is
#: longer than a flight), in a run that ended complete. At 1e14 sizes the last digit is 1/64 of a size (the stress
#: suite runs the strip and the plates from 1e12).
MAX_POSITION = 1e14


#: the largest speed times the table's size (and the smallest, its inverse): the collision test with a round wall
#: squares v·(a − c), of that size, so (speed × size)² must stay a normal double (1e±302). Lengths and speeds each
#: within their own limits but scaled together (a Sinai table of size 2e-100 at speeds of 1e-100) missed every
#: round wall, flew through the scatterer and out of a closed circle, in runs that ended complete with exit 0
MAX_SPEED_SIZE = 1e151


#: the farthest a bounded table's walls may reach from the origin, in units of its mean width (volume over boundary
#: measure, of the table the ball's centre moves in): the last digit of a coordinate is then at most 1/45 of a mean
#: width, as MAX_POSITION allows in sizes (the stress suite's corridor 2R(1 + 1e-12) high and 2 long is 2e13 mean
#: widths). A Sinai table 1e16 long and 1 wide (or a 100 × 1 table placed at x = 1e16) moved its ball by whole
#: units: a centre inside the scatterer, an x that never changed, a chaotic table measured as regular, exit 0
MAX_SPAN = 1e14


def _check_span(geom, n, c, key):
    """Refuse a bounded table whose walls reach further from the origin than :data:`MAX_SPAN` mean widths (an
    unbounded one has no mean width: its starts are bounded by :data:`MAX_POSITION` instead)."""
    try:
        volume, surface = table_measure(geom)
    except ValueError:                  # unbounded
        return
    with np.errstate(all="ignore"):
        width = volume / surface
        far = float(np.max(np.abs(geom.params[:, P_POINT:P_POINT + n])))
    if np.isfinite(width) and width > 0 and far > MAX_SPAN * width:
        c.fail(key or None, f"its walls reach {far:.3g} from the origin, {far / width:.2g} times its mean width "
                            f"{width:.3g} (its volume over its boundary): a coordinate's last digit is then more than "
                            f"2 % of a mean flight, and the orbit is lost; place the table near the origin, or make it "
                            f"less elongated (at most {MAX_SPAN:g} mean widths)")


def _speed_size_ok(speed, size):
    """Whether speeds (|v|² + κR²|ω|²)^½ (a number or an array) times the table's size stay within
    :data:`MAX_SPEED_SIZE` and its inverse (NaN does not)."""
    with np.errstate(all="ignore"):
        product = np.asarray(speed) * size
    return (product >= 1.0 / MAX_SPEED_SIZE) & (product <= MAX_SPEED_SIZE)


def _check_speed_size(speed, geom, c, key):
    """Refuse a speed whose product with the table's size over- or underflows when squared (:func:`_speed_size_ok`)."""
    if not _speed_size_ok(speed, geom.size):
        product = speed * geom.size
        c.fail(key, f"the speed {speed:.3g} times the table's size {geom.size:.3g} is {product:.3g}: the collision "
                    f"test squares it, and beyond 1e±{round(math.log10(MAX_SPEED_SIZE))} that leaves double "
                    "precision (round walls are missed); take units of length and time nearer the table's and the "
                    "orbit's")


def _check_spin_range(speed, spin, R, c, key):
    """The kernels square spin components (the energy): a collision gives the ball spins of order |v|/R, so
    (|v|/R)² and the initial ω² must stay finite — else the state becomes NaN, not just inexact. A radius so
    small (or a spin so large) that they do not is refused. (The stress cases at speeds ×1e±150 stay inside.)"""
    with np.errstate(all="ignore"):
        reach = speed / R
    if not reach * reach < MAX_SPIN_SQUARE:
        c.fail("ball.radius", f"{R:g} is too small for speeds of {speed:.3g}: the spin of order |v|/R a collision "
                              "gives the ball overflows when squared")
    if not spin * spin < MAX_SPIN_SQUARE:
        c.fail(key, f"too large: {spin:.3g} overflows when squared")


#: the samplers of ``initial: {sample: NAME}`` (docs/reference.md §4): ``billiard``, the billiard measure on the
#: walls; ``point_particle``, a point particle's start: uniform in the shrunk table's area (volume) and in direction,
#: unit speed, no spin (rbx.sampling.sample_point_particle)
SAMPLERS = ("billiard", "point_particle")


def _initial(init, n, c, geom, kind, R, kappa, names):
    """-> (tuple of explicit states, or ('sample', wall index or None), or ('point_particle', None)), default
    number of trajectories."""
    if isinstance(init, dict) and "sample" in init:
        given = [k for k in STATE_KEYS if k in init]
        if given:
            c.fail(f"initial.{given[0]}", "a sampled start (initial: {sample: …}) has no " + given[0] + "; a fixed "
                   "start replaces it when given whole: initial: {position: …, velocity: …} (--set "
                   "'initial={position: […], velocity: […]}')")
        c.mapping(init, "initial", ("sample", "wall"))
        sampler = c.choice(init["sample"], "initial.sample", SAMPLERS, "sampler")
        _check_speed_size(1.0, geom, c, "table")          # sampled states have unit speed
        wall = init.get("wall")
        if sampler == "point_particle":
            if wall is not None:
                c.fail("initial.wall", "point_particle starts are drawn in the table's area, not on a wall (for "
                                       "starts on a wall: sample: billiard)")
            if not geom.can_sample or geom.lattice is None and _infinite_area(geom):
                c.fail("initial.sample", f"the {kind} has no finite area: a uniform start in it cannot be drawn")
            return ("point_particle", None), 1
        if wall is not None:
            c.choice(wall, "initial.wall", names, "wall")
        idx = None if wall is None else names.index(wall)
        if not geom.can_sample:
            c.fail("initial.wall" if wall else "initial.sample", f"the {kind}'s walls are infinite: the billiard "
                                                                 "measure on them cannot be normalised")
        if idx is not None and not any(p for p in geom.wall_list[idx].patches):
            c.fail("initial.wall", f"a ball of radius {R:g} never touches wall '{wall}': there is no room for its "
                                   "centre along it (the wall is shorter than the ball, or behind a narrower part)")
        # sampled states have unit speed in (v, R√κ·ω): |v| ≤ 1, |ω| ≤ 1/(R√κ), which a tiny κ makes huge: said
        # as κ's problem (κ = 1e-320 was 'too large: 1e+161 overflows when squared')
        with np.errstate(all="ignore"):
            top = 1.0 / (R * math.sqrt(kappa))
        if not top * top < MAX_SPIN_SQUARE:
            c.fail("ball.inertia", f"κ = {kappa:.3g} is too small: sampled spins reach 1/(R√κ) = {top:.3g}, which "
                                   "overflows when squared")
        _check_spin_range(1.0, top, R, c, "ball.inertia")
        return ("sample", idx), 1
    states = init if isinstance(init, list) else [init]
    if not states:
        c.fail("initial", "expected a state or a non-empty list of states")
    # Most states pass: they are read in bulk (plain numbers, checked as arrays: a list of 10 000 took 1.6 s one
    # by one, most of it in the clearance of each position), from the first one that does not on one by one, so
    # that the first bad state is named with the same message as before.
    out = list(_plain_states(states, n, geom, R, kappa))
    for i in range(len(out), len(states)):
        key = "initial" if not isinstance(init, list) else f"initial[{i}]"
        out.append(_one_state(states[i], init, key, n, c, geom, R, kappa))
    speeds = np.sqrt([float(np.sum(np.square(s["velocity"])) + kappa * R * R * np.sum(np.square(s["angular_velocity"])))
                      for s in out])
    bad = np.flatnonzero(~_speed_size_ok(speeds, geom.size))
    if len(bad):
        key = "initial" if not isinstance(init, list) else f"initial[{int(bad[0])}]"
        _check_speed_size(float(speeds[bad[0]]), geom, c, _join(key, "velocity"))
    # read-only mappings of read-only arrays: an edit of a loaded experiment's start (exp.initial[0][...] = …) was
    # kept and shown, and the run used the start it was loaded with
    return tuple(types.MappingProxyType(state) for state in out), len(out)


def _infinite_area(geom):
    """True if a table (not a periodic cell) has a wall patch infinite along a direction that is not a coordinate
    axis (a strip's and the plates' infinite axes are x and y, set to 0 by the sampler as by the billiard one)."""
    for wall in geom.wall_list:
        for patch in wall.patches:
            if patch[0] == "flat":
                for axis, length in patch[3]:
                    if not np.isfinite(length) and np.count_nonzero(axis) != 1:
                        return True
    return False


def _plain_states(states, n, geom, R, kappa):
    """The leading states that are plain (a mapping of the state keys whose values are int or float, of the right
    lengths) and pass every check of :func:`_one_state` -> list of states, stopping before the first that does
    not (checked then one by one)."""
    rows = []
    default_spin = 0.0 if n == 2 else (0.0, 0.0, 0.0)
    for s in states:
        if type(s) is not dict or "position" not in s or "velocity" not in s or not s.keys() <= _STATE_SET:
            break
        row = [s["position"], s["velocity"], s.get("angular_velocity", default_spin),
               s.get("orientation", default_spin)]
        if not all(_plain_vector(v, n if k < 2 else (1 if n == 2 else 3)) for k, v in enumerate(row)):
            break
        rows.append(row)
    if not rows:
        return []
    m = len(rows)
    with np.errstate(all="ignore"):
        pos = np.array([r[0] for r in rows], dtype=float).reshape(m, n)
        vel = np.array([r[1] for r in rows], dtype=float).reshape(m, n)
        spin = np.array([r[2] for r in rows], dtype=float).reshape(m, -1)
        orient = np.array([r[3] for r in rows], dtype=float).reshape(m, -1)
        finite = np.all(np.isfinite(pos), 1) & np.all(np.isfinite(vel), 1) & np.all(np.isfinite(spin), 1) & \
            np.all(np.isfinite(orient), 1)
        energy = 0.5 * (np.sum(vel * vel, 1) + kappa * R * R * np.sum(spin * spin, 1))
        reach = np.sqrt(np.sum(vel * vel, 1)) / R
        spin_norm = np.sqrt(np.sum(spin * spin, 1))
        ok = finite & (np.sum(vel * vel, 1) >= MIN_ENERGY) & np.isfinite(energy) & (energy >= MIN_ENERGY) & \
            (reach * reach < MAX_SPIN_SQUARE) & (spin_norm * spin_norm < MAX_SPIN_SQUARE) & \
            (_angle_size(orient) <= MAX_ORIENTATION) & (np.max(np.abs(pos), 1) <= MAX_POSITION * geom.size)
        ok &= geom.clearance(pos) >= -1e-12 * geom.size
    good = m if ok.all() else int(np.argmin(ok))
    for a in (pos, vel, spin, orient):
        a.setflags(write=False)
    if n == 2:
        return [{"position": pos[i], "velocity": vel[i], "angular_velocity": float(spin[i, 0]),
                 "orientation": float(orient[i, 0])} for i in range(good)]
    return [{"position": pos[i], "velocity": vel[i], "angular_velocity": spin[i], "orientation": orient[i]}
            for i in range(good)]


_STATE_SET = frozenset(STATE_KEYS)


def _angle_size(orient):
    """(m, k) orientations -> (m,) their sizes in rad: |θ| in 2D (k = 1), the rotation vector's length in 3D,
    computed without overflow (NaN stays NaN)."""
    with np.errstate(all="ignore"):
        top = np.max(np.abs(orient), 1)
        scale = np.where(top > 0, top, 1.0)
        return top * np.sqrt(np.sum((orient / scale[:, None]) ** 2, 1))


def _plain_vector(v, n):
    """A plain number (n = 1) or a list of n plain numbers (int or float, not bool)."""
    if n == 1:
        return type(v) is float or type(v) is int
    return type(v) is list and len(v) == n and all(type(x) is float or type(x) is int for x in v)


def _one_state(s, init, key, n, c, geom, R, kappa):
    """One explicit state checked -> its dict of read-only arrays (2D spin and orientation: floats)."""
    # 'sample' is allowed only for the hint: a mapping holding it took the sampler's branch
    c.mapping(s, key, STATE_KEYS + (("sample",) if s is init else ()), ("position", "velocity"))
    pos = np.array(c.vector(s["position"], _join(key, "position"), n))
    vel = np.array(c.vector(s["velocity"], _join(key, "velocity"), n))
    if not np.any(vel):
        c.fail(_join(key, "velocity"), "must be non-zero (a ball at rest never reaches a wall)")
    with np.errstate(all="ignore"):     # an overflow is said below, with the energy
        speed2 = float(np.sum(vel * vel))
    if not speed2 >= MIN_ENERGY:
        # a spinning ball with |v| = 1.4e-170 'ended earlier (no wall ahead)', exit 0: |v|² is 0 in floats
        c.fail(_join(key, "velocity"), f"too small: |v|² = {speed2:.3g} is below {MIN_ENERGY:g}, and the flight to "
                                       "a wall would never end (scale the velocities up, or the unit of time down)")
    spin = s.get("angular_velocity", 0.0 if n == 2 else [0.0, 0.0, 0.0])
    spin = c.number(spin, _join(key, "angular_velocity")) if n == 2 else \
        np.array(c.vector(spin, _join(key, "angular_velocity"), 3))
    orient = s.get("orientation", 0.0 if n == 2 else [0.0, 0.0, 0.0])
    orient = c.number(orient, _join(key, "orientation")) if n == 2 else \
        np.array(c.vector(orient, _join(key, "orientation"), 3))
    size = float(_angle_size(np.reshape(orient, (1, -1)))[0])
    if not size <= MAX_ORIENTATION:
        c.fail(_join(key, "orientation"),
               f"too large: {size:.3g} rad (at most {MAX_ORIENTATION:g}{'' if n == 2 else ' in length'}); so large an "
               "angle keeps no fraction of a turn in double precision: give it reduced to one turn, within ±π")
    with np.errstate(over="ignore", invalid="ignore"):
        energy = 0.5 * (np.sum(vel * vel) + kappa * R * R * np.sum(np.square(spin)))
    if not np.isfinite(energy):
        # named by the part that overflows: a spin of 1e200 was refused as initial.velocity
        with np.errstate(over="ignore", invalid="ignore"):
            spins = not np.isfinite(kappa * R * R * np.sum(np.square(spin)))
        c.fail(_join(key, "angular_velocity" if spins else "velocity"),
               "too large: the kinetic energy ½(|v|² + 2λ|ω|²) overflows")
    if not energy >= MIN_ENERGY:
        c.fail(_join(key, "velocity"), f"too small: the kinetic energy ½(|v|² + 2λ|ω|²) is {energy:.3g}, below "
                                       f"{MIN_ENERGY:g}; flight times and energies would underflow (scale the "
                                       "velocities up, or the unit of time down)")
    _check_spin_range(float(np.linalg.norm(vel)), float(np.linalg.norm(spin)), R, c,
                      _join(key, "angular_velocity"))
    far = float(np.max(np.abs(pos)))
    if far > MAX_POSITION * geom.size:
        c.fail(_join(key, "position"), f"too far out: a coordinate of {far:.3g} is over {MAX_POSITION:g} times the "
                                       f"table's size ({geom.size:.3g}); so far out a coordinate keeps almost no "
                                       "digit of a flight (at 1e17 it never moved): start nearer the table's origin")
    with np.errstate(all="ignore"):
        clearance = float(geom.clearance(pos))
    if not clearance >= -1e-12 * geom.size:   # written so that a NaN fails too
        c.fail(_join(key, "position"), f"{pos.tolist()} is outside the table shrunk by the ball's radius "
                                       f"{R:g}" + (f" (by {-clearance:.3g})" if np.isfinite(clearance) else ""))
    for a in (pos, vel) + ((spin, orient) if n == 3 else ()):
        a.setflags(write=False)
    return {"position": pos, "velocity": vel, "angular_velocity": spin, "orientation": orient}


# ---- changes: --set KEY=VALUE, rbx.load(path, {KEY: VALUE}), a changed part of an experiment ----------------------

#: keys whose presence says what kind of mapping it is (a rule, a table, a sampled start): such a mapping replaces
#: the one it is given for instead of being merged into it (the keys of one kind of rule mean nothing to another)
KIND_KEYS = ("rule", "kind", "sample")
_KEY = re.compile(r"[^.\[\]\s]+(?:\[[0-9]+\])*(?:\.[^.\[\]\s]+(?:\[[0-9]+\])*)*")


def known_keys():
    """The dotted keys a change may name, for did-you-mean hints (the walls and the rule keys depend on the
    table, so a wall is named by the validator) -> list."""
    keys = [f"{section}.{k}" for section, ks in SECTION_KEYS.items() for k in ks]
    keys += [f"initial.{k}" for k in STATE_KEYS + ("sample", "wall")]
    params = sorted({p for k in tables.KINDS.values() for p in list(k.params) + list(k.optional or ())}
                    | {tables.OBSTACLES, "kind"})
    keys += [f"table.{p}" for p in params] + ["boundary.default", "boundary.walls"]
    return list(SECTIONS) + keys


def key_path(key, file=None):
    """A dotted key (``ball.inertia``, ``initial[0].position``) -> its parts (names, and list indices as int)."""
    if not isinstance(key, str) or not _KEY.fullmatch(key):
        raise ConfigError(file, str(key), "not a config key: give a dotted name such as ball.inertia or "
                                          "initial[0].position")
    return [int(i) if i else name for name, i in re.findall(r"([^.\[\]]+)|\[([0-9]+)\]", key)]


def _unknown(file, key, wrong):
    """An unknown key: did you mean …? among the dotted keys that exist."""
    close = difflib.get_close_matches(wrong, known_keys(), n=1)
    if not close and "." in wrong:     # 'colisions' in a wrong section: by its last part
        tail = wrong.rsplit(".", 1)[1]
        close = [k for k in known_keys() if k.endswith("." + tail)][:1]
    hint = f"did you mean '{close[0]}'?" if close else f"the sections are {', '.join(SECTIONS)}"
    raise ConfigError(file, key, f"unknown key ({hint})")


def apply_changes(data, changes, file, base, label="override"):
    """``data`` (a config mapping, changed in place) with ``changes`` ``{dotted key: value}`` made, in order ->
    (data, the table or boundary files read to make them).

    A value replaces what the key holds, except a mapping given for a mapping, which is merged into it key by key
    (``{'ball': {'inertia': 0.2}}`` is ``{'ball.inertia': 0.2}``), unless it names its kind (``rule:``,
    ``kind:``, ``sample:``; for ``initial``, a fixed start's key such as ``position:`` given for a sampled start):
    then it replaces. A table or boundary kept in its own file is read (from ``base``)
    when a change reaches into it. Unknown keys (did you mean …?), keys given twice and keys through a value that
    is not a mapping or a list raise :class:`ConfigError` (``file`` names the config, ``label`` the changes)."""
    if not isinstance(changes, Mapping):
        raise ConfigError(None, label, "expected a mapping from config key to value (such as {'ball.inertia': 0.2}), "
                                       f"got {type(changes).__name__}")
    if not isinstance(data, dict):
        return data, ()       # validation says what is wrong with it
    paths = {key: key_path(key, file) for key in changes}
    seen = {}
    for key, path in paths.items():
        for other, before in seen.items():
            n = min(len(path), len(before))
            if path[:n] == before[:n]:
                raise ConfigError(file, key, f"set twice, as {other} and {key}" if other != key else "set twice")
        seen[key] = path
    inlined = []
    for key, value in changes.items():
        path = paths[key]
        head = path[0]
        if head not in SECTIONS:
            _unknown(file, key, key)
        if head in SECTION_KEYS and len(path) > 1 and path[1] not in SECTION_KEYS[head]:
            _unknown(file, key, f"{head}.{path[1]}")
        parent, name = data, head
        for depth, part in enumerate(path[1:], 1):
            where = _path_text(path[:depth])
            child = parent[name] if isinstance(name, int) else parent.get(name)
            if child is None:
                child = {}
                parent[name] = child
            elif depth == 1 and name in ("table", "boundary") and isinstance(child, str):
                child = _inline(parent, name, base, file, inlined)
            if isinstance(part, int):
                if not isinstance(child, list):
                    raise ConfigError(file, key, f"{where} is {_kind(child)}, not a list: [{part}] names nothing")
                if part >= len(child):
                    raise ConfigError(file, key, f"{where} has {len(child)} items (0–{len(child) - 1})")
            elif not isinstance(child, dict):
                hint = (f"; a list's items are named by their index in brackets: {where}[{part}]"
                        if isinstance(child, list) and str(part).isdigit() else "")
                raise ConfigError(file, key, f"{where} is {_kind(child)}, not a mapping: it has no key '{part}'{hint}")
            parent, name = child, part
        old = parent[name] if isinstance(name, int) else parent.get(name)
        if len(path) == 1 and head in ("table", "boundary") and isinstance(old, str) and isinstance(value, Mapping) \
                and not any(k in value for k in KIND_KEYS):
            old = _inline(parent, name, base, file, inlined)
        if path == ["initial"] and isinstance(old, dict) and "sample" in old and isinstance(value, Mapping) \
                and any(k in value for k in STATE_KEYS):
            old = None             # a fixed start given for a sampled one replaces it (its keys mean nothing there)
        parent[name] = _merged(old, value)
    return data, tuple(inlined)


def _path_text(parts):
    return "".join(f"[{p}]" if isinstance(p, int) else (f".{p}" if i else p) for i, p in enumerate(parts))


def _inline(parent, name, base, file, inlined):
    """The table or boundary file that ``parent[name]`` names, read into the config in its place."""
    c = _Checker(file)
    value, path = _include(parent[name], name, base, c)
    inlined.append(path)
    parent[name] = value
    return value


def _merged(old, new):
    """``new`` given for ``old``: a mapping is merged into a mapping key by key (unless it names its kind)."""
    if isinstance(new, Mapping) and isinstance(old, dict) and not any(k in new for k in KIND_KEYS):
        out = dict(old)
        for k, v in new.items():
            out[k] = _merged(old.get(k), v)
        return out
    return _plain(new)


def _plain(x):
    """Plain data (dicts, lists, numbers, text) from mappings, tuples and NumPy values, copied."""
    if isinstance(x, Mapping):
        return {k: _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return _plain(x.tolist())
    if isinstance(x, np.generic):
        return x.item()
    return copy.deepcopy(x)


def revalidate(exp, changed):
    """``exp`` whose parts ``changed`` were changed by hand (:meth:`rbx.model.Experiment.replace`,
    ``dataclasses.replace``), validated again as a config: the changed parts in the plain form of a config, the
    rest as stored in ``exp.resolved`` -> a new validated :class:`rbx.model.Experiment`. Raises
    :class:`ConfigError`."""
    data = _plain(exp.resolved)
    merges, wholes = {}, []
    for name in changed:
        value = getattr(exp, name)
        section = "boundary" if name == "wall_rules" else name
        if isinstance(value, Mapping):
            merges[section] = value
        else:
            data[section] = _plain_part(name, value, exp)
            wholes.append(section)
    try:
        return from_dict(data, exp.source, changes=merges, label="changed", includes=exp.includes,
                         copy_data=False)
    except ConfigError as exc:
        raise _blame(exc, wholes, "changed") from None


_PART_TYPES = {"ball": Ball, "run": RunSettings, "output": Output, "numerics": Numerics}


def _plain_part(name, value, exp):
    """A part of an experiment (a dataclass or a tuple) as its config section."""
    if name in _PART_TYPES:
        if not isinstance(value, _PART_TYPES[name]):
            raise ConfigError(None, name, f"expected an rbx.model.{_PART_TYPES[name].__name__} or a mapping of its "
                                          f"config keys, got {type(value).__name__}")
        if name == "ball":
            if value.dimension != exp.dimension:
                raise ConfigError(None, "ball.dimension", f"is {value.dimension}, but the table is {exp.dimension}D")
            return _plain({"radius": value.radius, "inertia": value.inertia})      # NumPy numbers as rbx.load's
        if name == "output":
            return value.resolved()
        return _plain(dataclasses.asdict(value))
    if name == "initial":
        if isinstance(value, tuple) and len(value) == 2 and value[0] == "sample":
            wall = value[1]
            if wall is not None and not (isinstance(wall, int) and 0 <= wall < len(exp.wall_names)):
                raise ConfigError(None, "initial", "('sample', wall): the wall is an index "
                                                   f"0–{len(exp.wall_names) - 1} or None, got {wall!r}")
            return {"sample": "billiard", **({} if wall is None else {"wall": exp.wall_names[wall]})}
        if isinstance(value, tuple) and len(value) == 2 and value[0] == "point_particle" and value[1] is None:
            return {"sample": "point_particle"}
        if isinstance(value, (tuple, list)) and value and all(isinstance(s, Mapping) for s in value):
            return [_plain(s) for s in value]
        raise ConfigError(None, "initial", "expected a tuple of states (mappings of position, velocity, …), "
                                           f"('sample', wall) or a mapping of config keys, got {type(value).__name__}")
    if name == "wall_rules":
        if not isinstance(value, (tuple, list)) or len(value) != len(exp.wall_names):
            raise ConfigError(None, "wall_rules", f"expected one rule per wall ({', '.join(exp.wall_names)})")
        return {"walls": {w: rule_config(r, f"wall_rules[{i}]") for i, (w, r) in enumerate(zip(exp.wall_names,
                                                                                                  value))}}
    raise ConfigError(None, name, f"expected a mapping of the {name}'s parameters, got {type(value).__name__}")


def rule_config(rule, key="rule"):
    """A rule (:class:`rbx.model.Constant`, …) as its config mapping (its kind's record: :mod:`rbx.rules`)."""
    try:
        return rules.rule_config(rule, key)
    except rules.NotARule as exc:
        raise ConfigError(None, exc.key, f"expected a rule (rbx.model.Constant, Hemisphere, Random or Exit), got "
                                         f"{exc.got}") from None


# an experiment changed by hand is validated again here (rbx.model asks through SERVICES: it imports no loader)
SERVICES["revalidate"] = revalidate
