"""Studies: a parameter swept over a grid, an ensemble per point, an error bar per number (``rbx sweep``,
:func:`sweep`; docs/studies.md).

A study file::

    base: ../examples/sinai.yaml          # an experiment config (a path relative to the study file) or a mapping
    set: {initial: {sample: billiard}}    # optional: dotted overrides made at every point
    vary:                                  # dotted config keys; the product of all, or zip: true
      ball.inertia: [0.1, 0.25, 0.5, 1.0]
      table.radius: {from: 0.1, to: 0.4, num: 4, scale: linear}     # or scale: log
    zip: false
    measure: [lyapunov, regular_share, {mean_free_path: {segments: 10}}]   # rbx.observables.REGISTRY
    ensemble: {trajectories: 32, collisions: 100000, seed: 1}

Each point's experiment is ``rbx.load(base, set + point + ensemble)``, so checked as the YAML is. A point's seed is
derived from the study's seed and the point's own keys and values (:func:`point_seed`), so adding a point changes
no other point's numbers. Points run one after the other in this process, each on the engine's thread pool (or a
Dask cluster: ``scheduler=``). The results file (NetCDF, h5netcdf) is rewritten atomically as points finish
(spaced so that the writes take at most a twentieth of the run: :data:`WRITE_SPACING`) as ``OUT.partial`` and
renamed to ``OUT`` at the end; ``resume=True`` computes only the points it lacks, and refuses a
study whose canonical text changed (``study_digest``).
"""
import contextlib
import hashlib
import io
import itertools
import json
import math
import os
import shlex
import sys
import time
import warnings
from collections.abc import Mapping

import numpy as np
import yaml

from . import __version__, observables as obs
from .analysis import scene_title, unbounded_axes
from .api import _load as load, cluster_for, simulate
from .cluster import ClusterError, SchedulerUnreachable, connect
from .config import other_kind, parse_yaml, read_text, repeated_orbits, start_groups
from .dynamics import lyapunov
from .histogram import return_experiment
from .model import ConfigError
from .locks import LockNotWritable, acquire_lock, release_lock
from .paths import (DiskFull, check_own_kind, check_own_names, check_replaceable, config_file_problem, display_path,
                    other_commands_file)
from .runfile import FileError, provenance
from .simulation import STATE_BYTES, memory_refusal, records_bytes

__all__ = ["sweep", "load_study", "Study", "point_seed", "StudyInterrupted"]

STUDY_KEYS = ("base", "set", "vary", "zip", "measure", "ensemble")
ENSEMBLE_KEYS = ("trajectories", "collisions", "seed")
SCALES = ("linear", "log")


class Study:
    """A validated study: ``file`` (or None), ``folder``, ``base`` (a path or a mapping), ``fixed`` (the ``set``
    overrides), ``keys`` and ``values`` (one array per varied key), ``zip``, ``measure`` (list of (name,
    options)), ``ensemble`` (dict), ``text`` (canonical JSON) and ``digest``."""

    def __init__(self, **kw):
        self.__dict__.update(kw)

    @property
    def observables(self):
        return [obs.get(name) for name, _ in self.measure]

    def points(self):
        """The points in order -> list of (index tuple, {key: value})."""
        if self.zip:
            n = len(self.values[0])
            return [((i,), {k: v[i] for k, v in zip(self.keys, self.values)}) for i in range(n)]
        out = []
        for idx in itertools.product(*(range(len(v)) for v in self.values)):
            out.append((idx, {k: v[i] for k, v, i in zip(self.keys, self.values, idx)}))
        return out

    @property
    def shape(self):
        return (len(self.values[0]),) if self.zip else tuple(len(v) for v in self.values)

    @property
    def dims(self):
        return (self.keys[0],) if self.zip else tuple(self.keys)

    def seed(self, point):
        return point_seed(self.ensemble["seed"], point)

    def experiment(self, point, fields=(), every=1):
        """The experiment of one point: base + set + the point's values + the ensemble (+ what to record); made
        once per point and kept (the title and the run ask for the same one: ~10 ms each, a tenth of a point of
        10⁶ collisions)."""
        memo = self.__dict__.setdefault("_experiments", {})
        key = (tuple(sorted(point.items())), tuple(fields), int(every))
        if key not in memo and len(memo) >= CHECK_EVERY_POINT:
            memo.clear()         # a large study's points one after the other: not 10⁵ experiments in memory
        if key not in memo:
            memo[key] = self._experiment(point, fields, every)
        return memo[key]

    def _experiment(self, point, fields, every):
        changes = dict(self.fixed)
        changes.update(point)
        changes.update({"run.trajectories": self.ensemble["trajectories"],
                        "run.collisions": self.ensemble["collisions"], "run.seed": self.seed(point),
                        "output.record": list(fields), "output.every": int(every)})
        try:
            if isinstance(self.base, Mapping):
                return load(dict(self.base), changes, base=self.folder)
            return load(self.base, changes)
        except ConfigError as exc:
            raise self._blame(exc) from None

    def _blame(self, exc):
        """An error found while building a point, named in the study file: the varied or set key at fault."""
        key = exc.key or ""
        for k in self.keys:
            if key == k or key.startswith(k + "."):
                return ConfigError(self.file, f"vary.{k}", exc.problem)
        for k in self.fixed:
            if key == k or key.startswith(k + "."):
                if k in getattr(self, "given", ()):        # rbx sweep --set: named as rbx simulate names it
                    problem = exc.problem
                    if problem.endswith(f" (override {k})"):
                        problem = problem[:-len(f" (override {k})")]
                    return ConfigError(self.file, key, f"{problem} (--set {k})")
                return ConfigError(self.file, f"set.{k}", exc.problem)
        if exc.file and self.file and os.path.abspath(exc.file) == os.path.abspath(self.file):
            return exc
        return ConfigError(self.file, f"base: {exc.file}: {key}" if exc.file else f"base.{key}", exc.problem) \
            if key else ConfigError(self.file, "base", exc.problem)


def point_seed(study_seed, point):
    """The seed of one point: 63 bits of SHA-256 of the study seed and the point's canonical text (keys sorted,
    values as JSON numbers): the same in every process and on every machine, and independent of the other points."""
    text = json.dumps({"seed": int(study_seed), "point": {k: _plain(v) for k, v in sorted(point.items())}},
                      sort_keys=True, separators=(",", ":"))
    return int.from_bytes(hashlib.sha256(text.encode()).digest()[:8], "big") >> 1


def _plain(v):
    if isinstance(v, (np.integer, int)) and not isinstance(v, bool):
        return int(v)
    return float(v)


# ---- reading a study file ---------------------------------------------------------------------------------------

def load_study(study, base=None, progress=None, sets=None, ensemble=None):
    """A study file (YAML) or mapping -> :class:`Study`; a mistake raises :class:`rbx.ConfigError` naming the
    file and the key (``vary.ball.inertia``, ``measure.diffusion``, …). ``progress(done, total)``: the configs of
    its points checked so far (:func:`_check_points`; a study at its grid bound takes minutes).

    ``sets``: ``{dotted config key: value}`` made to the base at every point after the study's own ``set`` (a key
    given in both: this value), named ``--set KEY`` in errors (``rbx sweep --set``); ``ensemble``: values that
    replace the study's ``ensemble`` entries (``{"trajectories": 4}``: ``rbx sweep --trajectories 4``). Both are
    in the study's digest, so a resume must give them again."""
    if isinstance(study, Study):
        return study
    if isinstance(study, Mapping):
        file, data = None, dict(study)
        folder = os.path.abspath(os.fspath(base)) if base is not None else os.getcwd()
        if os.path.isfile(folder):
            folder = os.path.dirname(folder)
    else:
        file = os.path.abspath(os.fspath(study))
        text = read_text(file)
        _duplicates(text, file)                 # names the dotted key given twice (the parser says only the line)
        data = parse_yaml(text, file)
        if not isinstance(data, Mapping):
            raise ConfigError(file, None, "a study file is a mapping with base, vary, measure, ensemble")
        problem = other_kind(data, "study")     # a config, a table or a boundary file: say so, and what to do
        if problem:
            raise ConfigError(file, None, problem)
        folder = os.path.dirname(file)

    def fail(key, problem):
        raise ConfigError(file, key, problem)

    for k in data:
        if k not in STUDY_KEYS:
            fail(str(k), f"unknown key (a study has {', '.join(STUDY_KEYS)})")
    for k in ("base", "vary", "measure", "ensemble"):
        if k not in data:
            fail(k, "missing")
    base_value = data["base"]
    if isinstance(base_value, str):
        base_path = os.path.normpath(os.path.join(folder, os.path.expanduser(base_value)))
        problem = _base_problem(base_path, base_value)
        if problem and file is None and base is None and not os.path.isabs(os.path.expanduser(base_value)):
            problem += (f" (a mapping's relative paths are resolved from the working folder, {folder}: give base=, "
                        "the study file or folder they are relative to, or an absolute path)")
        if problem:
            fail("base", problem)
        base_value = base_path
    elif not isinstance(base_value, Mapping):
        fail("base", "a config path or a mapping of config sections")
    fixed = data.get("set") or {}
    if not isinstance(fixed, Mapping):
        fail("set", "a mapping of dotted config keys to values")
    fixed = {str(k): v for k, v in fixed.items()}
    for key, value in fixed.items():
        _not_the_studys(key, value, f"set.{key}", fail)
    sets = dict(sets or {})
    for key, value in sets.items():
        for reserved in ("run.trajectories", "run.collisions"):
            if key == reserved or reserved.startswith(key + ".") and isinstance(value, Mapping) \
                    and _holds(value, reserved[len(key) + 1:]):
                what = reserved.split(".")[1]
                fail(f"--set {key}", f"set at every point by the study from ensemble.{what}: give --{what}")
        _not_the_studys(key, value, f"--set {key}", fail)
    fixed = {**{k: v for k, v in fixed.items() if k not in sets}, **sets}
    changed = {k: v for k, v in (ensemble or {}).items() if v is not None}
    zipped = data.get("zip", False)
    if not isinstance(zipped, bool):
        fail("zip", f"true or false, not {zipped!r}")
    vary = data["vary"]
    if not isinstance(vary, Mapping) or not vary:
        fail("vary", "a mapping of dotted config keys to lists of values or {from, to, num, scale}")
    own = {str(k): v for k, v in (data.get("set") or {}).items()}
    for key in vary:
        _not_the_studys(str(key), None, f"vary.{key}", fail)
        # a set: or --set of a varied key would be replaced at every point without a word
        for where, given, value in ([("set.", k, v) for k, v in own.items()]
                                    + [("--set ", k, v) for k, v in sets.items()]):
            if _sets_varied(given, value, str(key)):
                fail(f"{where}{given}", f"the study varies {key} (vary.{key}): a value set for it would not be used")
    _check_size(vary, zipped, fail)         # before any value is made: 10⁷ points took 4.3 GB to build
    keys, values = [], []
    for key, spec in vary.items():
        key = str(key)
        values.append(_values(spec, f"vary.{key}", fail))
        keys.append(key)
    if zipped and len({len(v) for v in values}) > 1:
        fail("vary", "with zip: true every key needs as many values (" +
             ", ".join(f"{k}: {len(v)}" for k, v in zip(keys, values)) + ")")
    measure = _measure(data["measure"], fail)
    ensemble = data["ensemble"]
    if not isinstance(ensemble, Mapping):
        fail("ensemble", "a mapping {trajectories: M, collisions: N, seed: S}")
    ensemble = {**ensemble, **changed}
    for k in ensemble:
        if k not in ENSEMBLE_KEYS:
            fail(f"ensemble.{k}", f"unknown key (ensemble has {', '.join(ENSEMBLE_KEYS)})")
    ens = {}
    for k, lo in (("trajectories", 1), ("collisions", 1), ("seed", 0)):
        v = ensemble.get(k, 0 if k == "seed" else None)
        if v is None:
            fail(f"ensemble.{k}", "missing")
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)) or v < lo:     # NumPy's too
            fail(f"ensemble.{k}", f"expected an integer ≥ {lo}, got {v!r}")
        ens[k] = int(v)
    first = {k: _plain(v[0]) for k, v in zip(keys, values)}
    canonical = {"base": _canonical_base(base_value, folder, fixed, first), "set": fixed,
                 "vary": {k: [_plain(x) for x in v] for k, v in zip(keys, values)}, "zip": zipped,
                 "measure": [[n, o] for n, o in measure], "ensemble": ens}
    text = json.dumps(canonical, sort_keys=True, separators=(",", ":"), default=str, ensure_ascii=False)
    source = text if file is None else open(file, encoding="utf-8").read()
    if file is not None and (sets or changed):
        # the results file's copy of the study says what the command line changed (its digest covers it)
        given = [f"--set {k}={json.dumps(v, ensure_ascii=False, default=str)}" for k, v in sets.items()]
        given += [f"--{k} {v}" for k, v in changed.items()]
        source = source.rstrip("\n") + "\n# changed by rbx sweep: " + " ".join(given) + "\n"
    study_obj = Study(file=file, folder=folder, base=base_value, fixed=fixed, keys=keys, values=values, zip=zipped,
                      measure=measure, ensemble=ens, text=text, digest=hashlib.sha256(text.encode()).hexdigest(),
                      source=source, given=tuple(sets))
    _check_points(study_obj, progress)
    return study_obj


def _base_problem(path, given):
    """Why the base config at ``path`` cannot be read -> None or the problem (a device, a FIFO, a directory, a
    huge file are named as such, as ``rbx simulate`` names its config; only a missing file is 'no such config')."""
    try:
        problem = config_file_problem(path)
    except FileNotFoundError:
        return f"no such config: {given}"
    except IsADirectoryError:
        return f"{given} is a directory, not a YAML config file"
    except OSError as exc:
        return f"cannot read {given}: {exc.strerror or exc}"
    return f"{given} {problem}" if problem else None


#: the config keys a study sets at every point itself (so a value in ``vary`` or ``set`` would be overwritten without
#: a word: ``vary: {run.collisions: [...]}`` ran every point with ensemble.collisions) -> where they come from
STUDY_SETS = {"run.trajectories": "ensemble.trajectories", "run.collisions": "ensemble.collisions",
              "run.seed": "ensemble.seed (each point's seed derives from it)",
              "output.record": "the observables (what they need is recorded)",
              "output.every": "the observables (what they need is recorded)"}


def _not_the_studys(key, value, where, fail):
    """Refuse a ``vary`` or ``set`` key the study sets itself at every point (:data:`STUDY_SETS`): the key, a key
    inside it, or a mapping (``set: {run: {collisions: 5}}``) that holds one."""
    for reserved, source in STUDY_SETS.items():
        inside = reserved.startswith(key + ".")
        if key == reserved or key.startswith(reserved + ".") or (
                inside and isinstance(value, Mapping) and _holds(value, reserved[len(key) + 1:])):
            fail(where, f"set at every point by the study from {source}: change it there" if
                 reserved.startswith("run.") else f"set at every point by the study from {source}")
        if inside and value is None:        # a varied parent key (vary: {run: ...}) would replace it
            fail(where, f"holds {reserved}, which the study sets at every point from {source}")


def _sets_varied(given, value, key):
    """Whether setting ``given`` to ``value`` sets the varied ``key`` (or a part of it): the key itself, a key
    inside it, or a parent mapping that holds it (a parent mapping that does not is refused when a point is
    built: the overrides would name one key twice)."""
    if given == key or given.startswith(key + "."):
        return True
    return key.startswith(given + ".") and (not isinstance(value, Mapping) or _holds(value, key[len(given) + 1:]))


def _holds(mapping, dotted):
    head, _, rest = dotted.partition(".")
    if head not in mapping:
        return False
    return not rest or (isinstance(mapping[head], Mapping) and _holds(mapping[head], rest))


#: the most points a study may have: each point's experiment is built and checked before anything runs (~3 ms and
#: ~4 kB a point, so 100 000 points take about 5 minutes and 0.5 GB before the first run)
MAX_POINTS = 100_000


def _count(spec):
    """How many values a ``vary`` entry has, read without making them -> int, or None when the entry is malformed
    (:func:`_values` says how)."""
    if isinstance(spec, (list, tuple)):
        return len(spec)
    if isinstance(spec, Mapping):
        num = spec.get("num")
        return num if isinstance(num, int) and not isinstance(num, bool) and num >= 1 else None
    if isinstance(spec, (int, float)) and not isinstance(spec, bool):
        return 1
    return None


def _check_size(vary, zipped, fail):
    """Refuse a study of more than :data:`MAX_POINTS` points, counted from the entries (the product of their lengths,
    or the common length with zip) before any value or point is made."""
    counts = {}
    for key, spec in vary.items():
        n = _count(spec)
        if n is None:
            continue
        if n > MAX_POINTS:
            fail(f"vary.{key}.num" if isinstance(spec, Mapping) else f"vary.{key}",
                 f"{n} values; a study has at most {MAX_POINTS} points")
        counts[str(key)] = n
    if zipped or len(counts) < 2:
        return
    total = math.prod(counts.values())
    if total > MAX_POINTS:
        fail("vary", f"{' × '.join(str(n) for n in counts.values())} = {total} points; a study has at most "
                     f"{MAX_POINTS}: fewer values, or zip: true to vary the keys together")


def _duplicates(text, file):
    """Refuse a key given twice in one mapping, naming its dotted path (``vary.ball.inertia``)."""
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError:
        return                      # parse_yaml says where the syntax is wrong
    stack, visited = [(root, "")], set()
    while stack:
        node, path = stack.pop()
        if id(node) in visited:     # an alias: its node is checked once (walked each time, aliases multiply)
            continue
        visited.add(id(node))
        if isinstance(node, yaml.MappingNode):
            seen = set()
            for k, v in node.value:
                name = str(k.value)
                where = f"{path}.{name}" if path else name
                if name in seen:
                    raise ConfigError(file, where, f"given twice (line {k.start_mark.line + 1}): one entry per key")
                seen.add(name)
                stack.append((v, where))
        elif isinstance(node, yaml.SequenceNode):
            stack.extend((v, path) for v in node.value)


def _canonical_base(base, folder, fixed=None, first=None):
    """The base as it will be run: its resolved config (the files it includes inlined) with the study's ``set``
    applied — or, if it is valid only then, with the ``first`` point's values too — so that a changed base file,
    a table file an inline base names or one that ``set`` names, changes the study's digest too (a resume would
    otherwise mix points of two scenes)."""
    fixed = dict(fixed or {})
    for changes in (fixed, {**fixed, **(first or {})}):
        try:
            if isinstance(base, Mapping):
                return load(dict(base), changes, base=folder).resolved
            return load(base, changes).resolved
        except ConfigError:
            continue
    return dict(base) if isinstance(base, Mapping) else base


def _number(x, key, fail):
    if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
        fail(key, f"expected a finite number, got {x!r}")
    return x


def _values(spec, key, fail):
    if isinstance(spec, (list, tuple)):
        if not spec:
            fail(key, "an empty list: give at least one value")
        vals = [_number(x, key, fail) for x in spec]
        if len(set(vals)) != len(vals):
            fail(key, "a value is listed twice")
        if all(isinstance(x, int) for x in vals):
            return np.array(vals, dtype=np.int64)
        return np.array(vals, dtype=float)
    if isinstance(spec, Mapping):
        for k in spec:
            if k not in ("from", "to", "num", "scale"):
                fail(f"{key}.{k}", "unknown key (a range has from, to, num, scale)")
        for k in ("from", "to", "num"):
            if k not in spec:
                fail(f"{key}.{k}", "missing (a range is {from: A, to: B, num: N, scale: linear|log})")
        a, b = _number(spec["from"], f"{key}.from", fail), _number(spec["to"], f"{key}.to", fail)
        num = spec["num"]
        if isinstance(num, bool) or not isinstance(num, int) or num < 1:
            fail(f"{key}.num", f"expected an integer ≥ 1, got {num!r}")
        scale = spec.get("scale", "linear")
        if scale not in SCALES:
            fail(f"{key}.scale", f"linear or log, not {scale!r}")
        if scale == "log":
            if a <= 0 or b <= 0:
                fail(key, f"a log scale needs positive bounds, got from {a} to {b}")
            return np.geomspace(float(a), float(b), num)
        return np.linspace(float(a), float(b), num)
    if isinstance(spec, (int, float)) and not isinstance(spec, bool):
        return np.array([spec], dtype=float)
    fail(key, f"a list of numbers or {{from, to, num, scale}}, got {spec!r}")


def _measure(spec, fail):
    items = spec if isinstance(spec, (list, tuple)) else [spec]
    if not items:
        fail("measure", "an empty list: name at least one observable")
    out, seen = [], set()
    for item in items:
        if isinstance(item, Mapping) and len(item) == 1:
            name, options = next(iter(item.items()))
            options = options or {}
            if not isinstance(options, Mapping):
                fail(f"measure.{name}", "its options are a mapping")
        elif isinstance(item, str):
            name, options = item, {}
        else:
            fail("measure", f"an observable's name or {{name: {{options}}}}, got {item!r}")
        name = str(name)
        if name not in obs.REGISTRY:
            fail(f"measure.{name}", f"unknown observable (known: {', '.join(sorted(obs.REGISTRY))})")
        if name in seen:
            fail(f"measure.{name}", "measured twice")
        seen.add(name)
        rec = obs.get(name)
        for k in options:
            if k not in rec.options:
                fail(f"measure.{name}.{k}", "unknown option" + (f" (options: {', '.join(rec.options)})"
                                                                if rec.options else " (it takes none)"))
            ok, what = OPTION_VALUES.get(k, (lambda v: True, ""))
            if not ok(options[k]):
                fail(f"measure.{name}.{k}", f"must be {what}, got {options[k]!r}")
        opts = dict(rec.options)
        opts.update(options)
        out.append((name, opts))
    return out


def _whole(v, low):
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= low


#: what each option of an observable takes -> (test, words): checked where the study is read, with the key
OPTION_VALUES = {
    "segments": (lambda v: _whole(v, 1), "an integer ≥ 1"),
    "warmup": (lambda v: v is None or _whole(v, 0), "an integer ≥ 0 (collisions; null: a tenth of the run)"),
    "spectrum": (lambda v: isinstance(v, bool), "true or false"),
    "fit_from": (lambda v: isinstance(v, (int, float)) and not isinstance(v, bool) and 0 <= v < 1,
                 "a number from 0 up to 1 (a quantile of the exit paths)"),
    "threshold": (lambda v: isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0,
                  "a number > 0 (an orbit's own λ₁ below it is regular)"),
}


#: a study of at most this many points has every point's config built and checked before any point runs; a larger
#: product grid has every value of each key checked once (the other keys at their first values), and a combination
#: of values that is refused only together is refused when its point runs (the points finished before are kept)
CHECK_EVERY_POINT = 2000


def _representatives(study):
    """The points that stand for the whole study -> (points, whether they are all of them): every point of a study
    of up to :data:`CHECK_EVERY_POINT` points (or of one key, or zipped keys), else each value of each key once
    with the other keys at their first values (a grid of 1000 × 100 points: 1099)."""
    points = study.points()
    if len(points) <= CHECK_EVERY_POINT or study.zip or len(study.keys) == 1:
        return [point for _, point in points], len(points) <= CHECK_EVERY_POINT
    first = {k: v[0] for k, v in zip(study.keys, study.values)}
    return [first] + [dict(first, **{k: x}) for k, v in zip(study.keys, study.values) for x in v[1:]], False


def _check_points(study, progress=None):
    """Every point's experiment is built now (a bad value is refused before anything runs) and every observable
    is asked whether this table can give it: every point of a study of up to :data:`CHECK_EVERY_POINT` points,
    else every value of each key once (a grid of 1000 × 100 points: 1099 configs, not 100 000; at ~1 ms a
    config, the grid bound's study sat silent for 2 minutes). ``progress(done, total)``: configs checked so far,
    every few hundred."""
    need = _needs(study)
    checked, small = _representatives(study)
    total = len(checked)
    repeated = None
    for i, point in enumerate(checked):
        if progress is not None and i % 200 == 0:
            progress(i, total)
        # the one the run takes, kept for a small study (a large one's would fill the memory: 613 MB for 10⁵)
        exp = study.experiment(point, need["fields"], need["every"]) if small else \
            study._experiment(point, need["fields"], need["every"])
        for name, options in study.measure:
            rec = obs.get(name)
            problem = None
            if rec.exit and not obs.exit_walls(exp):
                problem = "needs a wall with the rule exit (boundary.walls.NAME: {rule: exit}); this table has none"
            elif rec.unbounded and not unbounded_axes(exp.geometry()):
                problem = f"the {exp.table_kind} table is bounded: no diffusion (it needs a periodic or open table)"
            elif rec.problem is not None:
                problem = rec.problem(exp, options)
            if problem:
                raise ConfigError(study.file, f"measure.{name}", problem)
        repeated = repeated or repeated_orbits(exp)
    if repeated:
        # each point's error bar would be the spread of copies of one orbit (a regular share of 1.0 ± 0.1 from 4
        # copies): said as rbx simulate and rbx lyapunov say it
        warnings.warn(f"{display_path(study.file) if study.file else 'the study'}: ensemble.trajectories: "
                      f"{repeated}", RuntimeWarning, stacklevel=3)
    if progress is not None:
        progress(total, total)


# ---- running ------------------------------------------------------------------------------------------------------

def _needs(study):
    recs = study.observables
    fields = sorted({f for r in recs for f in r.fields})
    each = any(r.every_collision for r in recs)
    N = study.ensemble["collisions"]
    if each or not fields:
        every = 1
    else:
        segs = [int(o.get("segments", 20)) for n, o in study.measure if obs.get(n).fields]
        every = max(1, N // max(segs))
    opts = dict(study.measure).get("lyapunov", {"segments": 10, "warmup": None})
    return dict(fields=fields, every=every, simulate=any(r.simulate for r in recs),
                tangent=any(r.tangent for r in recs), returns=any(r.returns for r in recs),
                segments=int(opts.get("segments", 10)), warmup=opts.get("warmup"))


def run_point(study, point, scheduler=None):
    """Run one point and measure every observable -> ({name: Value}, collisions, seconds)."""

    need = _needs(study)
    began = time.perf_counter()
    exp = study.experiment(point, need["fields"], need["every"])
    runs = obs.PointRuns(exp)
    collisions = 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)     # repeated orbits: the study's numbers say it
        if need["simulate"]:
            runs.run = simulate(exp, scheduler=scheduler)
            collisions += int(np.sum(runs.run.final["collisions"]))
        if need["tangent"]:
            runs.lyapunov = lyapunov(exp, segments=need["segments"], warmup=need["warmup"], scheduler=scheduler)
            collisions += int(np.sum(runs.lyapunov.collisions))
        if need["returns"]:
            with cluster_for(scheduler, "scheduler") as on:
                runs.returns = return_experiment(exp, cluster=on)
            collisions += int(np.sum(runs.returns.collisions))
    values = {name: obs.get(name).compute(runs, options) for name, options in study.measure}
    if need["tangent"]:
        values["lyapunov_regular"], values["lyapunov_orbits"] = runs.lyapunov.regular(_threshold(study))
    return values, collisions, time.perf_counter() - began


def _threshold(study):
    """The own λ₁ below which an orbit counts as regular: regular_share's threshold when measured, else its
    default."""
    return float(dict(study.measure).get("regular_share", {}).get("threshold", obs.REGULAR_THRESHOLD))


# ---- the results file -----------------------------------------------------------------------------------------------

def _empty(study, exp0):
    """The results dataset with every number NaN and ``done`` False."""
    import xarray as xr
    dims, shape = study.dims, study.shape
    coords = {}
    for i, (k, v) in enumerate(zip(study.keys, study.values)):
        dim = dims[0] if study.zip else dims[i]
        coords[k] = xr.Variable((dim,), v, {"units": _key_unit(k), "long_name": k})
    data = {}
    extra = {}
    for name, options in study.measure:
        rec = obs.get(name)
        if rec.coords is not None:
            extra.update(rec.coords(exp0))
        vdims = dims + ((rec.dim,) if rec.dim else ())
        vshape = shape + ((len(extra[rec.dim]),) if rec.dim else ())
        data[name] = xr.Variable(vdims, np.full(vshape, np.nan), {"units": rec.unit, "description": rec.description,
                                                                  "options": json.dumps(options)})
        data[f"{name}_stderr"] = xr.Variable(vdims, np.full(vshape, np.nan),
                                             {"units": rec.unit, "description": f"{rec.error} of {name}"})
        for c in rec.companions:
            if c.dim and not (name == "lyapunov" and options.get("spectrum")):
                continue
            cdims = dims + ((c.dim,) if c.dim else ())
            cshape = shape + ((len(extra[c.dim]),) if c.dim else ())
            data[f"{name}_{c.suffix}"] = xr.Variable(cdims, np.full(cshape, np.nan),
                                                     {"units": c.unit, "description": c.description})
    for dim, vals in extra.items():
        coords[dim] = xr.Variable((dim,), np.asarray(vals, dtype=str) if np.asarray(vals).dtype == object
                                  else np.asarray(vals))
    if _needs(study)["tangent"]:
        thr = _threshold(study)
        data["lyapunov_orbits"] = xr.Variable(dims, np.zeros(shape, np.int64), {
            "units": "trajectory", "description": "trajectories whose own λ₁ was measured (those that left the "
                                                  "table before any collision was counted have none)"})
        data["lyapunov_regular"] = xr.Variable(dims, np.zeros(shape, np.int64), {
            "units": "trajectory", "threshold": thr,
            "description": f"of those, the regular ones: own λ₁ below {thr:g} per unit time (the point's λ₁ "
                           "pools them with the chaotic ones)"})
    data["collisions"] = xr.Variable(dims, np.zeros(shape, np.int64),
                                     {"units": "collision", "description": "collisions run at the point (all runs)"})
    data["wall_time"] = xr.Variable(dims, np.full(shape, np.nan), {"units": "s", "description":
                                                                    "wall-clock time of the point"})
    data["seed"] = xr.Variable(dims, np.zeros(shape, np.int64), {"description": "run.seed of the point"})
    data["done"] = xr.Variable(dims, np.zeros(shape, np.int8), {"description": "1: the point is computed"})
    ds = xr.Dataset(data, coords=coords)
    ds.attrs.update(_attrs(study, exp0))
    return ds


def _key_unit(key):
    if key in obs.PARAMETERS:
        return obs.PARAMETERS[key][2]
    return "L" if key.startswith("table.") else "1"


_PUNCT = "(),;:"


def study_title(study, exp0=None):
    """What the whole study shows: the scene's title (:func:`rbx.analysis.scene_title`) with each word that
    changes from point to point given as its range over the points ('κ = 0.05–1'), then the varied keys and their
    ranges ('ball.inertia: 8 values, 0.05–1') -> str. (The first point's title alone named its κ as the study's.)"""
    need = _needs(study)
    # the words that change from point to point, read off the points that stand for the study (each value of each
    # key of a large grid once: building all 10⁵ configs of one took 67 s before its first point)
    titles = [scene_title(study.experiment(p, need["fields"], need["every"])) for p in _representatives(study)[0]]
    words = [t.split(" ") for t in titles]
    if len({len(w) for w in words}) == 1:
        merged = []
        for column in zip(*words):
            if len(set(column)) == 1:
                merged.append(column[0])
                continue
            core = [w.strip(_PUNCT) for w in column]
            head = column[0][:len(column[0]) - len(column[0].lstrip(_PUNCT))]
            tail = column[0][len(column[0].rstrip(_PUNCT)):]
            try:
                nums = [float(w) for w in core]
                span = f"{min(nums):g}–{max(nums):g}"
            except ValueError:
                span = "/".join(dict.fromkeys(core))
            merged.append(head + span + tail)
        scene = " ".join(merged)
    else:                 # the description changes shape from point to point: name the first and say so
        scene = f"{titles[0]} (at the first point)"
    varied = []
    for key, values in zip(study.keys, study.values):
        nums = [float(v) for v in values if isinstance(v, (int, float)) and not isinstance(v, bool)]
        span = f"{min(nums):g}–{max(nums):g}" if len(nums) == len(values) and len(values) > 1 else \
            ", ".join(str(v) for v in values)
        varied.append(f"{key}: {len(values)} value{'s' if len(values) != 1 else ''}, {span}")
    return f"{scene}\nvaried{' together' if study.zip and len(study.keys) > 1 else ''}: " + "; ".join(varied)


def _attrs(study, exp0):
    """The results file's attributes. ``ensemble_orbits``: how many distinct orbits each point's ensemble holds (its
    trajectories, unless fixed starts with no random numbers repeat each other: a study's figure says so)."""
    p = provenance()
    groups = start_groups(exp0)
    orbits = study.ensemble["trajectories"] if groups is None else int(len(np.unique(groups)))
    return {"rbx_study": 1, "study": study.source, "study_canonical": study.text, "study_digest": study.digest,
            "study_file": study.file or "", "title": study_title(study, exp0), "varied": json.dumps(study.keys),
            "zip": int(study.zip), "measure": json.dumps([n for n, _ in study.measure]),
            "ensemble_trajectories": study.ensemble["trajectories"], "ensemble_orbits": orbits,
            "ensemble_collisions": study.ensemble["collisions"], "ensemble_seed": study.ensemble["seed"],
            "rbx_version": __version__, "numba_version": p["numba_version"], "numpy_version": p["numpy_version"],
            "python_version": p["python_version"], "created": p["created"], "host": p["host"],
            "command": shlex.join(sys.argv), "complete": 0}


def _store(ds, index, study, values, collisions, seconds, seed):
    # into the variables' arrays by position (xarray's labelled assignment took 13 ms a point)
    at = tuple(int(i) for i in index)

    def put(name, x):
        ds[name].values[at] = x
    for name, _ in study.measure:
        v = values[name]
        put(name, v.value)
        put(f"{name}_stderr", v.stderr)
        for suffix, x in v.companions.items():
            key = f"{name}_{suffix}"
            if key in ds:
                put(key, x)
    for name in ("lyapunov_orbits", "lyapunov_regular"):
        if name in values and name in ds:
            put(name, values[name])
    put("collisions", collisions)
    put("wall_time", seconds)
    put("seed", seed)
    put("done", 1)


#: the results file is rewritten after a finished point once the points since the last write (or since the start)
#: took this many times as long as a write (and at the end): writing it after every point cost 0.2 s a
#: point, more than a point of 10⁶ collisions (0.14 s); so the writes cost at most 1/20 of the run, and a kill
#: loses at most the points of the last ~20 writes' time, which --resume runs again (the same numbers)
WRITE_SPACING = 20
#: what a write is taken to cost before this process has timed one (8 points of one observable: 16 ms CPU, 40 ms
#: wall here); so the first write comes after a second of points, not after the first point: written after the
#: first point of 10⁶ collisions, it made a study 1.11 times as long as one run of the same collisions (CPU)
FIRST_WRITE_COST = 0.05
_write_cost = None          # the last write's time in this process


def _write(ds, path):
    """Write ``ds`` to ``path`` atomically: made in memory, written to a temporary file in the same folder,
    flushed to disk, renamed. A write that fails (a full disk, a file-size limit) leaves ``path`` as it was and
    raises :class:`rbx.paths.DiskFull` (HDF5 itself never meets the failure: made on the disk, a full disk gave an
    h5py traceback, then a segmentation fault as the half-written file was closed)."""
    global _write_cost
    began = time.perf_counter()
    tmp = f"{path}.tmp"
    image = io.BytesIO()
    _to_netcdf(ds, image)
    try:
        with open(tmp, "wb") as fh:
            fh.write(image.getbuffer())
            fh.flush()
            os.fsync(fh.fileno())
    except OSError as exc:
        with contextlib.suppress(OSError):
            os.remove(tmp)
        size = _bytes_text(len(image.getbuffer()))
        if os.path.exists(path):
            kept = (f"{display_path(path)} is as it was (a write makes a whole new copy, {size}, beside it before "
                    "replacing it, so it needs that much free): free some room and continue with --resume")
        else:
            kept = (f"nothing of the study was on disk yet, so no point is kept (its results need {size} free): "
                    "free some room and run the study again")
        raise DiskFull(f"{display_path(path)}: cannot write the study's results ({exc.strerror or exc}); "
                       + kept) from None
    os.replace(tmp, path)
    _write_cost = time.perf_counter() - began


def _bytes_text(n):
    """A size for people: ``14.5 kB``, ``3.2 MB``."""
    for factor, unit in ((1e9, "GB"), (1e6, "MB"), (1e3, "kB")):
        if n >= factor:
            return f"{n / factor:.3g} {unit}"
    return f"{n} bytes"


def _to_netcdf(ds, path):
    """``ds`` into a new NetCDF-4 file at ``path`` through h5netcdf, each variable as it is (xarray reads it back
    identical, tested): a third cheaper than ``Dataset.to_netcdf``, whose encoding pass (fill values, chunks,
    CF conventions) the results' plain arrays do not need (8 points: 15 → 10 ms CPU, the study's last write)."""
    import h5netcdf
    import h5py
    with warnings.catch_warnings(), h5netcdf.File(path, "w", invalid_netcdf=True) as f:
        warnings.simplefilter("ignore", UserWarning)        # "invalid netcdf features": a dotted name, a flag
        f.attrs.update(ds.attrs)
        for dim, size in ds.sizes.items():
            f.dimensions[dim] = size
        for name, var in ds.variables.items():
            data = np.asarray(var.values)
            if data.dtype.kind in "OU":                     # text (wall names): HDF5 variable-length strings
                out = f.create_variable(name, var.dims, dtype=h5py.string_dtype(), data=data.astype(object))
            else:
                out = f.create_variable(name, var.dims, data=data)
            out.attrs.update(var.attrs)


def _read(path):
    import xarray as xr
    # phony_dims: a variable without dimension scales (a file damaged or made by hand) is read, not warned about
    with xr.open_dataset(path, engine="h5netcdf", phony_dims="access") as ds:
        return ds.load()


def partial_path(output):
    return f"{output}.partial"


def sweep(study, output=None, *, scheduler=None, resume=False, force=False, progress=None, base=None,
          trajectories=None, collisions=None, sets=None):
    """Run a study -> :class:`xarray.Dataset` (docs/studies.md).

    ``study``: a study file or mapping (``base=``: the file or folder a mapping's relative paths start from);
    ``trajectories``, ``collisions`` replace its ``ensemble`` entries and ``sets`` (``{dotted config key: value}``)
    changes the base at every point after the study's own ``set``, as ``rbx sweep --trajectories M --collisions N
    --set KEY=VALUE`` do (a shipped study shortened without copying it; checked as they are, an error naming such
    a key ``--set KEY``; part of the study's digest, so a resume gives them again);
    ``output``: the results file (NetCDF via h5netcdf), committed after every point as ``output.partial`` and
    renamed at the end; an existing one is refused unless ``force`` (start again) or ``resume`` (compute only
    the points it lacks; a study whose canonical text changed is refused). ``scheduler``: a Dask scheduler
    address, scheduler file or ``distributed.Client`` that every point's runs use (the same numbers as a local
    run). ``progress(done, total)``: called after each point. A bad study raises :class:`rbx.ConfigError`.

    The results file is written under the run lock ``output.lock`` that ``rbx simulate`` takes too: a second
    sweep, or a run, writing the same file is refused, naming the one that holds it."""
    changes = {"sets": sets, "ensemble": {"trajectories": trajectories, "collisions": collisions}}
    if isinstance(study, Study) and (sets or trajectories is not None or collisions is not None):
        raise TypeError("rbx.sweep: trajectories, collisions and sets change a study file or mapping, not a loaded "
                        "Study (give them to load_study)")
    if sets is not None and not isinstance(sets, Mapping):
        raise TypeError(f"rbx.sweep: sets is a mapping {{'ball.inertia': 0.2, …}}, not {type(sets).__name__}")
    if output is None:
        return _sweep(study, None, scheduler, resume, force, progress, base, changes)
    if not isinstance(output, (str, bytes, os.PathLike)):
        raise TypeError(f"rbx.sweep: output is a file path (a str or os.PathLike), not {type(output).__name__}")
    output = os.path.abspath(os.fsdecode(os.fspath(output)))        # a bytes path is the path it names
    _check_not_own_name(output)
    check_own_names(output)        # a FIFO named as the lock would block its read
    try:
        acquire_lock(output)
    except LockNotWritable as exc:
        partial = partial_path(output)
        if resume and os.path.exists(partial):
            # the finished points are in the .partial; a sweep resumes only beside its output: say how to go on
            raise FileError(partial, None, f"cannot be resumed in place: its folder cannot be written ({exc.problem})"
                                           f"; copy it to a writable folder and resume there: rbx sweep STUDY -o "
                                           f"FOLDER/{os.path.basename(output)} --resume") from None
        raise
    try:
        return _sweep(study, output, scheduler, resume, force, progress, base, changes)
    finally:
        release_lock(output)


def _check_not_own_name(output):
    """Refuse results named as rbx names the files beside another output (``X.nc.partial``, ``X.nc.lock``, …): a
    sweep wrote its results there, which ``--resume -o X.nc`` then took for its own unfinished results (and
    ``--force`` removed), or over a live run's lock. As ``rbx simulate`` refuses such an output."""
    from .driver import OWN_SUFFIXES
    for suffix, what in OWN_SUFFIXES:
        if output.endswith(suffix) and len(os.path.basename(output)) > len(suffix):
            raise FileError(None, "-o", f"{display_path(output)} is the name rbx gives "
                                        f"{display_path(output[:-len(suffix)])}'s {what}; give another name, such "
                                        "as results.nc")


def _sweep(study, output, scheduler, resume, force, progress, base, changes):
    st = load_study(study, base, **changes)      # the path of rbx sweep --set, --trajectories, --collisions
    points = st.points()
    need = _needs(st)
    exp0 = st.experiment(points[0][1], need["fields"], need["every"])
    kept = records_bytes(exp0)          # a point keeps the records its observables read in memory
    refusal = memory_refusal(st.ensemble["trajectories"], records=kept)
    if refusal:         # before anything is written, and named by the study's own key
        key, problem = refusal
        raise ConfigError(st.file, f"ensemble.{key}", f"{problem}: fewer {'collisions ' if key == 'collisions' else ''}"
                                                      "per point")
    ds = None
    if output is not None:
        partial = partial_path(output)
        for p in (output, partial):      # never over the study, its base or a file they include
            for f, what in ((st.file, "the study file"), (exp0.source, "the study's base config"),
                            *((f, "a file the study's base includes") for f in exp0.includes)):
                if f and os.path.isfile(f) and os.path.exists(p) and os.path.samefile(p, f):
                    raise FileError(p, "-o", f"is {what}: give the results a file of their own, such as "
                                             "results.nc")
        for p in (output, partial):      # a run of rbx simulate under these names: never taken for the study's
            problem = other_commands_file(p, "study")
            if problem is not None:
                raise problem
        if resume:
            source = partial if os.path.exists(partial) else output if os.path.exists(output) else None
            if source is not None:
                try:
                    ds = _read(source)
                except Exception as exc:     # not a results file
                    raise FileError(source, None, f"cannot read as a study's results: {exc}") from None
                if ds.attrs.get("study_digest") != st.digest:
                    # what changed, where the file says it: an option given now (--collisions) reads as "the study
                    # changed", and --force would throw the finished points away
                    now = {"ensemble_trajectories": (st.ensemble["trajectories"], "--trajectories"),
                           "ensemble_collisions": (st.ensemble["collisions"], "--collisions"),
                           "ensemble_seed": (st.ensemble["seed"], "ensemble.seed")}
                    changed = [f"{key} {ds.attrs.get(key)} in the file, {value} now ({option} or the study's "
                               f"ensemble)" for key, (value, option) in now.items()
                               if key in ds.attrs and str(ds.attrs[key]) != str(value)]
                    what = changed[0] if changed else "its text, its base or a file it includes"
                    raise FileError(source, "--resume", f"the study changed since this file was started ({what}): "
                                                        "resume with the study and options it was started with, or "
                                                        "run it afresh with --force, which discards its "
                                                        f"{int(np.sum(ds['done'].values)) if 'done' in ds else 0} "
                                                        "finished points")
                _check_resumable(ds, _empty(st, exp0), source, st, points)
                if source == output and int(ds["done"].values.min()) == 1:
                    return ds
        elif not force:
            for p in (output, partial):
                if os.path.lexists(p):
                    raise FileError(p, None, "exists: --force starts the study again, --resume continues it")
        for p in (output, partial):       # replaced only if a regular file rbx wrote: never a device, a FIFO, a
            check_replaceable(p, "-o", None)  # link, a study file or notes
            check_own_kind(p, "-o", None)
        os.makedirs(os.path.dirname(output), exist_ok=True)
    if ds is None:
        ds = _empty(st, exp0)
    done = ds["done"].values
    todo = [(i, p) for i, p in points if not done[i]]
    total, finished = len(points), len(points) - len(todo)
    stored = finished       # the finished points the results file on disk holds
    client = _client(scheduler)
    try:
        if progress is not None:
            progress(finished, total)
        written = time.perf_counter()   # when the file was last written (the start counts as one)
        for index, point in todo:
            try:
                values, collisions, seconds = run_point(st, point, scheduler=client)
            except SchedulerUnreachable as exc:
                if client is None:
                    raise
                # the cluster the study started on is lost (its scheduler killed, its workers gone): a run that
                # stopped, not a bad address
                raise ClusterError(exc.key, exc.problem) from None
            except MemoryError:
                if kept > st.ensemble["trajectories"] * STATE_BYTES:      # the records, more than the state
                    raise ConfigError(st.file, "ensemble.collisions", "the records a point keeps do not fit in this "
                                                                      "process's memory: fewer collisions per point") \
                        from None
                raise ConfigError(st.file, "ensemble.trajectories",
                                  f"{st.ensemble['trajectories']} trajectories of a point do not fit in this "
                                  "process's memory: fewer per point") from None
            _store(ds, index, st, values, collisions, seconds, st.seed(point))
            finished += 1
            if output is not None and finished < total and (
                    time.perf_counter() - written >= WRITE_SPACING * (_write_cost or FIRST_WRITE_COST)):
                _write(ds, partial)
                written, stored = time.perf_counter(), finished
            if progress is not None:
                progress(finished, total)
    except BaseException as exc:
        # the points finished since the last write are kept too (a Ctrl-C, a lost cluster, a point that failed):
        # --resume then runs only the others
        if output is not None and finished > stored:
            _write_held(ds, partial)
        if isinstance(exc, KeyboardInterrupt) and output is not None:
            raise StudyInterrupted(*kept_points(partial, st.digest)[:2], total) from None
        raise
    finally:
        if client is not None and client is not scheduler:
            client.close()
    ds.attrs["complete"] = 1
    if output is not None:
        _write(ds, partial)
        os.replace(partial, output)
    return ds


#: the observables whose value is a number at every computed point (rbx.lyapunov raises rather than give none; the
#: energy of a run that went non-finite stops it; a mean free path counts at least the flight to the first
#: collision): a NaN there in a point marked done is not a result
NEVER_NAN = frozenset({"lyapunov", "energy_drift", "mean_free_path"})


def _check_resumable(ds, template, path, study=None, points=()):
    """Refuse (:class:`FileError` naming the variable) a results file to resume whose variables are not those this
    study writes, of their shapes: a file with the study's digest but ``done`` missing, of another shape or not
    0/1 (damaged, or made by hand) gave a traceback, or was taken as finished. Refused too: coordinates other than
    the study's values (compared exactly: the points computed now would be stored under the file's labels), and
    points marked done that hold a non-finite value where their observable always gives a number, a seed other
    than the study's for the point, or a non-finite wall time (their values would be kept as results)."""
    fix = "not the results of this study as rbx sweep writes them: run it afresh with --force"
    for name, var in template.variables.items():
        if name not in ds.variables:
            raise FileError(path, name, f"missing; {fix}")
        got = ds.variables[name]
        if got.dims != var.dims or got.shape != var.shape:
            raise FileError(path, name, f"has dimensions {dict(zip(got.dims, got.shape))}, where this study's "
                                        f"are {dict(zip(var.dims, var.shape))}; {fix}")
        if var.dtype.kind in "iufb" and got.dtype.kind not in "iufb":
            raise FileError(path, name, f"holds {got.dtype} values, not numbers; {fix}")
    done = ds["done"].values
    if not np.all((done == 0) | (done == 1)):
        raise FileError(path, "done", f"holds values other than 0 and 1; {fix}")
    for key in ("measure", "varied", "ensemble_trajectories", "ensemble_collisions", "ensemble_seed",
                "ensemble_orbits"):
        # the attributes a figure of the finished file reads: carried into it by the resume (a file edited by
        # hand then gave tracebacks when plotted)
        if key in template.attrs and str(ds.attrs.get(key)) != str(template.attrs[key]):
            raise FileError(path, key, f"is {str(ds.attrs.get(key))[:40]!r} where this study's is "
                                       f"{str(template.attrs[key])[:40]!r}; {fix}")
    for name, var in template.coords.items():
        mine, theirs = np.asarray(var.values), np.asarray(ds[name].values)
        if mine.dtype.kind in "OUS":
            mine, theirs = mine.astype(str), theirs.astype(str)
        if theirs.dtype.kind in "iufb" and mine.dtype.kind in "iufb" or mine.dtype.kind == theirs.dtype.kind:
            equal = theirs.shape == mine.shape and bool(np.all(theirs == mine))
        else:
            equal = False
        if not equal:
            raise FileError(path, name, f"holds the values {_shown(theirs)} where this study's are {_shown(mine)}; "
                                        f"{fix}")
    if study is None:
        return
    finished = done.astype(bool)
    for name in [n for n, _ in study.measure if n in NEVER_NAN] + ["wall_time"]:
        values = np.asarray(ds[name].values, float)
        bad = finished & ~np.all(np.isfinite(values.reshape(done.shape + (-1,))), axis=-1)
        if bad.any():
            raise FileError(path, name, f"is not a number at {int(bad.sum())} of the points marked done (the "
                                        f"first: {_point_label(study, np.argwhere(bad)[0])}); {fix}")
    # an error bar is a non-negative number or none (NaN), and a count of collisions a whole number ≥ 0: an inf
    # error or −5 collisions of a point marked done were kept as results
    checks = [(f"{name}_stderr", lambda v: np.isnan(v) | (np.isfinite(v) & (v >= 0)),
               "is not an error (a number ≥ 0, or none)") for name, _ in study.measure if f"{name}_stderr" in ds]
    checks.append(("collisions", lambda v: np.isfinite(v) & (v >= 0) & (v == np.floor(v)),
                   "is not a count of collisions"))
    for name, ok, what in checks:
        values = np.asarray(ds[name].values, float).reshape(done.shape + (-1,))
        bad = finished & ~np.all(ok(values), axis=-1)
        if bad.any():
            raise FileError(path, name, f"{what} at {int(bad.sum())} of the points marked done (the first: "
                                        f"{_point_label(study, np.argwhere(bad)[0])}); {fix}")
    seeds = np.asarray(ds["seed"].values)
    for index, point in points:
        if finished[index] and int(seeds[index]) != study.seed(point):
            raise FileError(path, "seed", f"holds {int(seeds[index])} at the point "
                                          f"{_point_label(study, index)}, where this study's seed is "
                                          f"{study.seed(point)}; {fix}")


def _shown(values, most=4):
    shown = ", ".join(str(v) if not isinstance(v, float) else f"{v:g}" for v in values.ravel()[:most].tolist())
    return f"[{shown}{', …' if values.size > most else ''}]"


def _point_label(study, index):
    index = tuple(int(i) for i in np.atleast_1d(index))
    if study.zip:
        return ", ".join(f"{k} = {v[index[0]]}" for k, v in zip(study.keys, study.values))
    return ", ".join(f"{k} = {v[i]}" for k, v, i in zip(study.keys, study.values, index))


class StudyInterrupted(KeyboardInterrupt):
    """A study stopped by a signal: ``path`` (None: nothing of the study written) holds ``kept`` of its ``total``
    points, which ``resume=True`` (``rbx sweep --resume``) continues."""

    def __init__(self, path, kept, total):
        super().__init__(path, kept, total)
        self.path, self.kept, self.total = path, kept, total


def kept_points(path, digest=None):
    """The finished points a results file holds -> (path, number, points of its study), or (None, 0, 0) when
    there is no such file (or it is another study's, or unreadable)."""
    if not os.path.exists(path):
        return None, 0, 0
    try:
        ds = _read(path)
        if digest is not None and ds.attrs.get("study_digest") != digest:
            return None, 0, 0
        done = np.asarray(ds["done"].values)
        return path, int(np.sum(done == 1)), int(done.size)
    except Exception:         # not a results file, or one without a readable 'done'
        return None, 0, 0


def _write_held(ds, path):
    """:func:`_write`, with SIGINT and SIGTERM held off meanwhile (a second Ctrl-C would cut the write short) and a
    failure let pass: the file on disk then stays as it was (the write replaces it whole or not at all)."""
    import signal
    import threading
    main = threading.current_thread() is threading.main_thread()
    old = {s: signal.signal(s, signal.SIG_IGN) for s in (signal.SIGINT, signal.SIGTERM)} if main else {}
    try:
        _write(ds, path)
    except Exception:
        pass
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def _client(scheduler):
    """One Dask client for the whole study (each point's runs would otherwise connect anew)."""
    if scheduler is None or not isinstance(scheduler, (str, os.PathLike)):
        return scheduler
    cluster = connect(scheduler, key="scheduler")
    return cluster.client
