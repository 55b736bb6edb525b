"""Studies: a parameter swept over a grid, an ensemble per point, an error bar per number (docs/studies.md). This
module reads and checks a study; :mod:`rbx.sweeping` runs it (``rbx sweep``, :func:`rbx.sweep`) into its results
file.

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
no other point's numbers. :func:`needs` says what the measured observables need of each point's runs.
"""
import hashlib
import itertools
import json
import math
import os
import re
import warnings
from collections.abc import Mapping

import numpy as np
import yaml

from . import observables as obs
from .analysis import unbounded_axes
from .api import _load as load
from .config import MAX_SEED
from .ensembles import orbit_rows, repeated_orbits
from .yamlfile import copied, other_kind, parse_yaml, read_text
from .model import ConfigError
from .paths import config_file_problem, display_path

__all__ = ["load_study", "Study", "point_seed", "needs"]

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
            blamed = self._blame(exc)
            if len(self.keys) > 1 or blamed.key != f"vary.{self.keys[0]}":
                # the other keys' values may be the cause (2R > h: radius and height), or the varied key made an
                # untouched one fail (a height of 0.15 named ball.radius of the base file)
                where = ", ".join(f"{k} = {_plain(point[k])}" for k in self.keys)
                blamed = ConfigError(blamed.file, blamed.key, f"{blamed.problem} (at the point {where})")
            raise blamed from None

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
        if not problem:             # a study, a table or a boundary file named as the base: say it of base:
            try:
                other = other_kind(parse_yaml(read_text(base_path), base_path), "config")
            except ConfigError:     # not YAML, or too large: said where the base is read, with its own key
                other = None
            if other:
                problem = f"{base_value} {other.split(':')[0]}: base names the experiment config each point runs"
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
    fixed = _after(fixed, sets)
    changed = {k: v for k, v in (ensemble or {}).items() if v is not None}
    zipped = data.get("zip", False)
    if not isinstance(zipped, bool):
        fail("zip", f"true or false, not {zipped!r}")
    vary = data["vary"]
    if not isinstance(vary, Mapping) or not vary:
        fail("vary", "a mapping of dotted config keys to lists of values or {from, to, num, scale}")
    own = {str(k): v for k, v in (data.get("set") or {}).items()}
    for key in vary:
        try:
            str(key).encode("utf-8")
        except UnicodeEncodeError:      # a lone surrogate ('\udc80'): the study's digest cannot be taken
            fail(f"vary.{ascii(str(key))[1:-1]}", "is not a config key (it holds a character that is not text: a "
                                                  "lone surrogate)")
        _not_the_studys(str(key), None, f"vary.{key}", fail)
        # a set: or --set of a varied key would be replaced at every point without a word
        for where, given, value in ([("set.", k, v) for k, v in own.items()]
                                    + [("--set ", k, v) for k, v in sets.items()]):
            if _sets_varied(given, value, str(key)):
                fail(f"{where}{given}", f"the study varies {key} (vary.{key}): a value set for it would not be used")
            if str(key).startswith(f"{given}.") and isinstance(value, Mapping):
                # a mapping for a section that holds the varied key (and not the key itself): each point would name
                # the key twice, which was said as 'vary.ball.inertia: set twice, as ball and ball.inertia'
                inner = str(key)[len(given) + 1:].partition(".")[0]
                other = next((str(k) for k in value if str(k) != inner), "NAME")
                fail(f"{where}{given}", f"gives the section {given} whole, and the study varies {key} inside it "
                                        f"(vary.{key}): give its keys one by one ({given}.{other}=…)")
    _check_size(vary, zipped, fail)         # before any value is made: 10⁷ points took 4.3 GB to build
    keys, values = [], []
    for key, spec in vary.items():
        key = str(key)
        values.append(_values(spec, f"vary.{key}", fail))
        keys.append(key)
    if zipped and len({len(v) for v in values}) > 1:
        fail("vary", "with zip: true every key needs as many values (" +
             ", ".join(f"{k}: {len(v)}" for k, v in zip(keys, values)) + ")")
    _check_distinct(keys, values, zipped, fail)
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
        if k == "seed" and v > MAX_SEED:    # as run.seed: a seed of 2**64 ran every point, then failed to be stored
            fail("ensemble.seed", f"at most {MAX_SEED} (2⁶³ − 1), as run.seed; got {v}")
        ens[k] = int(v)
    for name, options in measure:       # a mean over segments of the run: at least two collisions in each
        if name != "lyapunov" and "segments" in options and ens["collisions"] < 2 * int(options["segments"]):
            fail(f"measure.{name}.segments", f"{options['segments']} segments of the ensemble's {ens['collisions']} "
                                             "collisions leave fewer than 2 in each (a study of 1 collision stored "
                                             "NaN): fewer segments, or more collisions")
    if any(obs.get(name).tangent for name, _ in measure):   # the tangent loop's warm-up and segments, checked now
        options = dict(measure).get("lyapunov", {})
        own = "lyapunov" in dict(measure)       # else regular_share alone runs it with lyapunov's defaults
        N, segments = ens["collisions"], int(options.get("segments", 10))
        warmup = N // 10 if options.get("warmup") is None else int(options["warmup"])
        if warmup >= N:
            fail("measure.lyapunov.warmup" if own else "ensemble.collisions",
                 f"{warmup} collisions of warm-up leave none of the ensemble's {N} to measure")
        if N - warmup < segments:
            fail("measure.lyapunov.segments" if own else "ensemble.collisions",
                 f"{segments} segments in the {N - warmup} collisions measured after the warm-up of {warmup}: "
                 + ("fewer segments, or more collisions" if own else "more collisions"))
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


def _after(fixed, sets):
    """The study's ``set`` with ``--set`` made after it -> dict: a key given again replaces it, a key inside one of
    its mappings changes that mapping (``--set initial.sample=billiard`` beside ``set: {initial: {sample:
    point_particle}}`` was refused as 'set twice, as initial and initial.sample'), and a key holding some of its
    keys replaces them."""
    out = {k: v for k, v in fixed.items() if not any(k == s or k.startswith(s + ".") for s in sets)}
    for key, value in sets.items():
        parent = next((p for p in out if key.startswith(p + ".") and isinstance(out[p], Mapping)), None)
        if parent is None or "[" in key:
            out[key] = value
            continue
        tree = out[parent] = copied(dict(out[parent]), {})
        *path, last = key[len(parent) + 1:].split(".")
        for part in path:
            if not isinstance(tree.get(part), Mapping):
                tree[part] = {}
            tree = tree[part]
        tree[last] = value
    return out


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
    except (yaml.YAMLError, RecursionError):
        return                      # parse_yaml says where the syntax is wrong, or that it is nested too deeply
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
    if isinstance(x, (list, tuple)):
        named = re.sub(r"\.(\d+)(?=\.|$)", r"[\1]", key.removeprefix("vary."))    # table.boundary.3 -> [3]
        fail(key, f"expected a number, got the list {list(x)!r}: a study varies one number per key; name one item of "
                  f"a list by its index in brackets ({named}[1]), and vary several with zip: true")
    if isinstance(x, (np.integer, np.floating)) and not isinstance(x, np.bool_):
        x = x.item()            # NumPy's numbers as ensemble, sets= and rbx.load take them
    if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
        fail(key, f"expected a finite number, got {x!r}")
    return x


def _check_distinct(keys, values, zipped, fail):
    """Two points of a study are never the same point: with zip, no two columns of values alike (a value repeated
    in one key is fine: (0.4, 0.05) and (0.2, 0.05) are two points; it was refused); else no value twice in one
    key, whether listed or made by a range ({from: 0.2, to: 0.2, num: 3} gave three identical points with one
    seed)."""
    if zipped:
        seen = {}
        for i, point in enumerate(zip(*(v.tolist() for v in values))):
            if point in seen:
                fail("vary", f"with zip: true, points {seen[point] + 1} and {i + 1} are the same ("
                             + ", ".join(f"{k} = {_plain(x)}" for k, x in zip(keys, point)) + ")")
            seen[point] = i
        return
    for key, v in zip(keys, values):
        if len(np.unique(v)) != len(v):
            ordered = np.sort(v)
            twice = _plain(ordered[np.flatnonzero(np.diff(ordered) == 0)[0]])
            fail(f"vary.{key}", f"the value {twice} comes twice (listed twice, or a range whose from and to are "
                                "equal or too close for its num)")


def _values(spec, key, fail):
    if isinstance(spec, (list, tuple)):
        if not spec:
            fail(key, "an empty list: give at least one value")
        vals = [_number(x, key, fail) for x in spec]
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
    need = needs(study)
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
        if need["tangent"] and need["segments"] < 2 and len(orbit_rows(exp)) < 2:
            # one orbit (copies of it count once) in one segment: no error estimate (the tangent loop refuses it)
            fail_at = "measure.lyapunov.segments" if "lyapunov" in dict(study.measure) else "ensemble.trajectories"
            raise ConfigError(study.file, fail_at, f"one segment of one orbit gives no error estimate (the "
                                                   f"{exp.run.trajectories} trajectories are copies of one orbit "
                                                   "or one trajectory): segments ≥ 2, or distinct orbits")
        repeated = repeated or repeated_orbits(exp)
    if repeated:
        # each point's error bar would be the spread of copies of one orbit (a regular share of 1.0 ± 0.1 from 4
        # copies): said as rbx simulate and rbx lyapunov say it
        warnings.warn(f"{display_path(study.file) if study.file else 'the study'}: ensemble.trajectories: "
                      f"{repeated}", RuntimeWarning, stacklevel=3)
    if progress is not None:
        progress(total, total)


def needs(study):
    """What a study's observables need of each point's runs -> dict: the recorded ``fields`` and ``every``, whether
    it simulates, follows tangent vectors or samples returns, and the Lyapunov ``segments`` and ``warmup``."""
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
