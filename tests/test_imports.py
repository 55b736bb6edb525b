"""rbx's import graph, read from the source with ``ast`` (every module under rbx/, imports at module level and
inside functions alike): it has no cycle, and the library never imports the command line (rbx.cli).

A cycle through a function-level import works at run time (the import happens after both modules are loaded),
which is how cycles crept in unnoticed: this test reads both levels, so that the layers of ARCHITECTURE.md's
module map hold for every import, not only the ones at the top of a file.
"""
import ast
import os

import pytest

import rbx

PACKAGE = os.path.dirname(os.path.abspath(rbx.__file__))


def modules():
    """Every module under rbx/ -> {dotted name: path}."""
    out = {}
    for folder, _, files in os.walk(PACKAGE):
        for f in files:
            if not f.endswith(".py"):
                continue
            rel = os.path.relpath(os.path.join(folder, f), os.path.dirname(PACKAGE))[:-3].replace(os.sep, ".")
            if rel.endswith(".__init__"):
                rel = rel[: -len(".__init__")]
            out[rel] = os.path.join(folder, f)
    return out


def imports_of(name, path, known):
    """The rbx modules that module ``name`` imports, at any level -> {module: [line, …]}."""
    tree = ast.parse(open(path, encoding="utf-8").read(), path)
    is_package = path.endswith("__init__.py")
    package = name if is_package else name.rpartition(".")[0]
    out = {}

    def add(target, line):
        if target != name and target in known:
            out.setdefault(target, []).append(line)

    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name == "rbx" or alias.name.startswith("rbx."):
                    add(alias.name, node.lineno)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            if not (module == "rbx" or module.startswith("rbx.")):
                continue
            for alias in node.names:
                sub = f"{module}.{alias.name}"
                add(sub if sub in known else module, node.lineno)
    return out


def graph():
    known = modules()
    return {name: imports_of(name, path, known) for name, path in known.items()}


def find_cycle(edges):
    """A cycle of the directed graph ``edges`` (node -> iterable of nodes) as a list of nodes, or None."""
    WHITE, GREY, BLACK = 0, 1, 2
    colour = {v: WHITE for v in edges}
    stack = []

    def visit(v):
        colour[v] = GREY
        stack.append(v)
        for w in sorted(edges.get(v, ())):
            if colour.get(w, BLACK) == GREY:
                return stack[stack.index(w):] + [w]
            if colour.get(w) == WHITE:
                found = visit(w)
                if found:
                    return found
        stack.pop()
        colour[v] = BLACK
        return None

    for v in sorted(edges):
        if colour[v] == WHITE:
            found = visit(v)
            if found:
                return found
    return None


def test_the_graph_is_read():
    g = graph()
    # spot checks that both levels are read: a module-level and a function-level import
    assert "rbx.model" in g["rbx.engine"]
    assert "rbx.config" in g["rbx.api"]          # rbx.api imports its loader inside load()
    assert g["rbx.cli.simulate"]


def test_find_cycle_finds_one():
    assert find_cycle({"a": ["b"], "b": ["c"], "c": ["a"]}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": ["b"], "b": ["c"], "c": []}) is None


def test_no_import_cycle():
    g = graph()
    cycle = find_cycle({k: list(v) for k, v in g.items()})
    if cycle:
        steps = [f"{a} -> {b} (line {g[a][b][0]})" for a, b in zip(cycle, cycle[1:])]
        pytest.fail("import cycle: " + "; ".join(steps))


def test_the_library_never_imports_the_command_line():
    g = graph()
    bad = [f"{name} imports {target} (line {lines[0]})" for name, targets in g.items()
           if not (name == "rbx.cli" or name.startswith("rbx.cli.") or name == "rbx.__main__")
           for target, lines in targets.items() if target == "rbx.cli" or target.startswith("rbx.cli.")]
    assert not bad, bad
