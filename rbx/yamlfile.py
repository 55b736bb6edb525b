"""Reading YAML safely: the text of a config, study, table or boundary file -> plain Python data, or a
:class:`rbx.model.ConfigError` naming the file (and the key, for text given as a key's value).

YAML 1.2 numbers (``010`` is ten, ``1e6`` a float, no sexagesimal ``1:30``), no duplicate keys, integers of at most
:data:`MAX_INT_DIGITS` digits, and at most :data:`MAX_CONFIG_VALUES` values added by aliases (or :data:`ALIAS_RATIO`
times those written out): a "billion laughs" text is refused before it is built. The text is read by libyaml when
present; a text it refuses is read again by the pure-Python loader for its message (line and column). A YAML file of
another kind than the one asked for (a study given as a config, …) is named as such by its top-level keys
(:data:`FILE_KINDS`, :func:`other_kind`), and a binary file by its first bytes (an HDF5 run or results file). The
cycle collector is held off while a config is read and validated (:func:`gc_paused`).
"""
import contextlib
import copy
import gc
import math
import re

import yaml

from .model import ConfigError
from .paths import config_file_problem, path_text_problem, rbx_kind

class _Loader(yaml.SafeLoader):
    """Safe YAML with numbers read by the rules of YAML 1.2 (its core schema), not PyYAML's YAML 1.1: ``1e6`` is
    a number (1.1: text), ``010`` is ten (1.1: octal 8), ``1:30`` is text (1.1: sexagesimal 90), ``0o17`` octal,
    ``0x1f`` hexadecimal (``1_000`` is still a thousand); and a key given twice in one mapping is an error (PyYAML keeps the last one silently)."""


_INT, _FLOAT = "tag:yaml.org,2002:int", "tag:yaml.org,2002:float"
_Loader.yaml_implicit_resolvers = {
    first: [(tag, rx) for tag, rx in resolvers if tag not in (_INT, _FLOAT)]
    for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()}
_Loader.add_implicit_resolver(_INT, re.compile(r"^(?:[-+]?[0-9][0-9_]*|0o[0-7]+|0x[0-9a-fA-F]+)$"),
                              list("-+0123456789"))
_Loader.add_implicit_resolver(
    _FLOAT, re.compile(r"^(?:[-+]?(?:\.[0-9]+|[0-9][0-9_]*(?:\.[0-9_]*)?)(?:[eE][-+]?[0-9]+)?|[-+]?\.(?:inf|Inf|INF)"
                       r"|\.(?:nan|NaN|NAN))$"), list("-+0123456789."))

#: the longest integer read (Python refuses to convert more than 4300 digits, with a traceback)
MAX_INT_DIGITS = 4000


def _construct_int(loader, node):
    text = loader.construct_scalar(node).replace("_", "")     # 1_000_000: digits grouped, as in Python
    digits = text.lstrip("+-")
    if len(digits) > MAX_INT_DIGITS:
        raise yaml.constructor.ConstructorError(None, None, f"an integer of {len(digits)} digits is too long",
                                                node.start_mark)
    if digits.startswith("0o"):
        return int(text.replace("0o", "", 1), 8)
    if digits.startswith("0x"):
        return int(text, 16)
    return int(text, 10)


_Loader.add_constructor(_INT, _construct_int)


def _construct_mapping(loader, node, deep=False):
    seen = set()
    for key_node, _ in node.value:
        if key_node.tag == "tag:yaml.org,2002:merge":
            continue   # `<<: *base` followed by overrides is legitimate YAML
        key = loader.construct_object(key_node, deep=True)
        try:
            duplicate = key in seen
            seen.add(key)
        except TypeError:
            continue   # an unhashable key: the constructor reports it
        if duplicate:
            raise yaml.constructor.ConstructorError(None, None, f"duplicate key '{key}'", key_node.start_mark)
    return loader.construct_mapping(node, deep=deep)


_Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


if getattr(yaml, "__with_libyaml__", False):
    class _CLoader(yaml.cyaml.CParser, yaml.constructor.SafeConstructor, yaml.resolver.Resolver):
        """:class:`_Loader` on libyaml's parser (C): the same resolvers and constructors, so the same data, in a
        third of the time (a list of 10 000 states: 2.4 s → 0.8 s). A text it refuses is parsed again by
        :class:`_Loader`, whose messages the errors quote."""

        def __init__(self, stream):
            yaml.cyaml.CParser.__init__(self, stream)
            yaml.constructor.SafeConstructor.__init__(self)
            yaml.resolver.Resolver.__init__(self)

        def get_single_data(self):
            node = self.get_single_node()
            if node is None:
                return None
            try:
                return _build(self, node, {})
            except (_Slow, RecursionError):       # a merge key, a tag, a duplicate key: the constructor's own way
                return self.construct_document(node)

    _CLoader.yaml_implicit_resolvers = _Loader.yaml_implicit_resolvers
    _CLoader.yaml_constructors = _Loader.yaml_constructors
else:   # pragma: no cover - PyYAML built without libyaml
    _CLoader = None


class _Slow(Exception):
    """A node :func:`_build` leaves to PyYAML's constructor."""


_SEQ, _MAP, _STR = "tag:yaml.org,2002:seq", "tag:yaml.org,2002:map", "tag:yaml.org,2002:str"


def _build(loader, node, memo):
    """The data of a composed YAML node, as :class:`_Loader`'s constructors make it, for the plain case (mappings,
    sequences and scalars of the known tags; an alias is the node it names, so it is shared as there) ->
    data; raises :class:`_Slow` for anything else (a merge key, another tag, a duplicate or unhashable key), which
    the constructor then builds and reports. A third of the time of PyYAML's generic constructor, whose
    bookkeeping (a generator per collection, a state per node) cost 0.35 s on 10 000 states."""
    key = id(node)
    if key in memo:
        return memo[key]
    tag = node.tag
    if type(node) is yaml.ScalarNode:
        if tag == _FLOAT and "_" not in node.value:
            try:
                value = float(node.value)           # what construct_yaml_float gives for these forms
            except ValueError:                      # .inf, .nan
                value = loader.yaml_constructors[tag](loader, node)
        elif tag == _STR:
            value = node.value
        else:
            make = loader.yaml_constructors.get(tag)
            if make is None:
                raise _Slow
            value = make(loader, node)
        memo[key] = value
        return value
    if type(node) is yaml.SequenceNode and tag == _SEQ:
        out = memo[key] = []
        out.extend([_build(loader, item, memo) for item in node.value])
        return out
    if type(node) is yaml.MappingNode and tag == _MAP:
        out = memo[key] = {}
        for key_node, value_node in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                raise _Slow
            k = _build(loader, key_node, memo)
            if isinstance(k, (list, dict)) or k in out:
                raise _Slow
            out[k] = _build(loader, value_node, memo)
        return out
    raise _Slow


#: the most values YAML aliases may add to a config (each use of an anchored part after its first counts that part's
#: values again; the values written out count nothing): a real experiment adds a few hundred at most, and aliases
#: nested 20 deep (each naming the one before twice) add a million, which took minutes to validate. A list of any
#: number of explicit states written out is not limited
MAX_CONFIG_VALUES = 100_000
#: ... or this many times the values written out, if that is more (a list of many states that all name one anchored
#: state: ``[*s, *s, …]``, or ``[s] * N`` from Python): the expanded config stays within a constant factor of the
#: text, so validating it stays linear in the length of the file, as go-yaml bounds its alias expansion
ALIAS_RATIO = 32


def expanded_size(data, limit=MAX_CONFIG_VALUES):
    """How many values ``data`` holds with every shared (aliased) part counted each time it is used -> int
    (``limit`` is kept for callers; the count is exact), ``inf`` for a part that contains itself (`&a [*a]`).
    Linear in the number of distinct objects (shared parts are counted once each)."""
    return alias_count(data)[0]


def alias_count(data):
    """(expanded, written): the values ``data`` holds with every shared part counted each time it is used, and
    with each shared part counted once (the values written out in the YAML text; a use of an alias counts 1 there,
    as its ``*name``) -> (int, int), ``(inf, written)`` for a part that contains itself. Linear in the number of
    distinct objects."""
    memo = {}
    written = 0

    def size(x):
        nonlocal written
        key = id(x)
        if key in memo:
            if memo[key] is None:
                raise _Cycle
            written += 1                 # the alias itself
            return memo[key]
        memo[key] = None             # being counted: meeting it again inside itself is a cycle
        items = list(x.keys()) + list(x.values()) if isinstance(x, dict) else x
        total = 1
        written += 1
        for item in items:
            if type(item) in _ATOMS or not isinstance(item, (dict, list, tuple)):
                total += 1
                written += 1
            else:
                total += size(item)
        memo[key] = total
        return total

    if not isinstance(data, (dict, list, tuple)):
        return 1, 1
    try:
        return size(data), written
    except _Cycle:
        return math.inf, written


class _Cycle(Exception):
    pass


_ATOMS = frozenset((str, int, float, bool, type(None)))


def copied(x, memo):
    """A deep copy of a config's plain data (mappings, lists, scalars) keeping its shared parts shared, as
    ``copy.deepcopy`` does (anything else is copied by it), in a third of its time."""
    t = type(x)
    if t in _ATOMS:
        return x
    key = id(x)
    if key in memo:
        return memo[key]
    if t is dict:
        out = memo[key] = {}
        for k, v in x.items():
            out[k] = v if type(v) in _ATOMS else copied(v, memo)
        return out
    if t is list:
        out = memo[key] = []
        out.extend(v if type(v) in _ATOMS else copied(v, memo) for v in x)
        return out
    return copy.deepcopy(x, memo)


def check_size(data, file, key=None):
    expanded, written = alias_count(data)
    if expanded == math.inf:
        raise ConfigError(file, key, "the config is nested too deeply (an alias that refers to itself?)")
    added = expanded - written
    if added > max(MAX_CONFIG_VALUES, ALIAS_RATIO * written):
        raise ConfigError(file, key, f"the config holds {added:,} more values once its YAML aliases are expanded "
                                     f"than the {written:,} written out (at most {MAX_CONFIG_VALUES:,}, or "
                                     f"{ALIAS_RATIO} times those written out: a bomb of nested aliases?)")


@contextlib.contextmanager
def gc_paused():
    """Python's cycle collector held off while a config is read and validated: reading makes ~10 objects per value
    and none is garbage, yet each few hundred of them set off a collection that walks the young objects, and the
    older generations ever more often: 10 000 explicit states took 0.62 s to load with it and 0.22 s without (CPU,
    best of 5). The collector is switched back on (if it was on) at the end; what it would have freed meanwhile
    (no cycles are made) waits for its next run. The text is at most 64 MiB (:func:`read_text`), so is the pause."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def _load_yaml(text):
    """YAML text -> data, through libyaml when there is one; a text it refuses (or that a constructor refuses) is
    read again by the pure-Python loader, so that an error says what it always said."""
    if _CLoader is not None:
        try:
            return yaml.load(text, Loader=_CLoader)
        except (yaml.YAMLError, RecursionError):
            pass
    return yaml.load(text, Loader=_Loader)


def parse_yaml(text, file, key=None):
    """YAML text -> data, or :class:`ConfigError` naming ``file`` and the line of a syntax error (or a config
    whose aliases expand beyond :data:`MAX_CONFIG_VALUES`)."""
    try:
        with gc_paused():
            data = _load_yaml(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ConfigError(file, key, f"YAML syntax error: {where}{problem}") from None
    except RecursionError:
        raise ConfigError(file, key, "the YAML is nested too deeply") from None
    check_size(data, file, key)
    return data


#: the kinds of YAML file rbx reads, told apart by their top-level keys: kind -> (what it is called, the keys that
#: mark it, what to do with it). A file given where another kind is expected is named by the kind its keys say.
FILE_KINDS = {
    "config": ("an experiment config", ("table", "boundary", "ball", "initial"),
               "run it with rbx simulate, or name it in a study's base:"),
    "study": ("a study", ("base", "vary", "measure"), "run it with rbx sweep"),
    "table": ("a table file", ("kind",), "name it in a config's table:"),
    "boundary": ("a boundary file", ("default", "walls"), "name it in a config's boundary:"),
}

#: the first bytes of an HDF5 file (a run of rbx simulate, rbx histogram's return angles, a study's NetCDF results)
HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


def other_kind(data, expected):
    """Why the mapping read from a file is not of the ``expected`` kind (a key of :data:`FILE_KINDS`), when its
    top-level keys say it is a file of another kind and none marks the expected one -> a problem for
    :class:`ConfigError` ('is a study (base, vary, measure), not an experiment config: run it with rbx sweep'), or
    None: the file's own keys are then checked one by one."""
    if not isinstance(data, dict):
        return None
    keys = {str(k) for k in data}
    if keys & set(FILE_KINDS[expected][1]):
        return None
    for kind, (name, marks, todo) in FILE_KINDS.items():
        if kind != expected and keys & set(marks):
            return f"is {name} ({', '.join(marks)}), not {FILE_KINDS[expected][0]}: {todo}"
    return None


def _binary_problem(path):
    """What a file that is not UTF-8 text is, where a YAML file was expected."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(len(HDF5_SIGNATURE))
    except OSError:
        head = b""
    if head != HDF5_SIGNATURE:
        return "not a text (UTF-8) file"
    kind = rbx_kind(path)            # by what the file holds, not its name (a study's .partial ends in .partial)
    if kind == "study" or (kind is None and str(path).endswith(".nc")):
        return ("is a study's results file (NetCDF), not a YAML file: draw it with rbx plot --kind sweep"
                + (", continue it with rbx sweep STUDY --resume" if str(path).endswith(".partial") else ""))
    if kind == "returns":
        return "is the return angles of rbx histogram (HDF5), not a YAML file"
    return "is a run file (HDF5), not a YAML file: draw it with rbx plot, continue it with rbx simulate --resume"


def read_text(path, key=None):
    """The text of the YAML file at ``path`` (a config or a study), or :class:`ConfigError`: a device, a FIFO or a
    huge file is refused before it is read (:func:`rbx.paths.config_file_problem`), and every failure to read is
    one line naming the file."""
    if path_text_problem(path):
        raise ConfigError(repr(path), key, path_text_problem(path))
    try:
        problem = config_file_problem(path)     # a device, a FIFO, a huge file: refused before it is read
        if problem:
            raise ConfigError(path, key, problem)
        with open(path, encoding="utf-8") as fh:
            return fh.read()
    except FileNotFoundError:
        raise ConfigError(path, key, "file not found") from None
    except IsADirectoryError:
        raise ConfigError(path, key, "is a directory, not a YAML file") from None
    except PermissionError:
        raise ConfigError(path, key, "cannot read the file: permission denied") from None
    except UnicodeDecodeError:
        raise ConfigError(path, key, _binary_problem(path)) from None
    except OSError as exc:
        raise ConfigError(path, key, f"cannot read the file: {exc.strerror or exc}") from None


def read_yaml(path, key=None, expected="config"):
    """The mapping of a YAML file of the ``expected`` kind (:data:`FILE_KINDS`: a config, a study, a table or a
    boundary file), or :class:`ConfigError`; a file whose keys say it is of another kind is named as such."""
    text = read_text(path, key)
    data = parse_yaml(text, path)
    if data is None:
        raise ConfigError(path, None, "the file is empty (expected a YAML mapping)")
    problem = other_kind(data, expected)
    if problem:
        raise ConfigError(path, None, problem)
    return data


