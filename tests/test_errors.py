"""Bad input gets exit code 2 and one line ``rbx: <file>: <key>: <problem>``, never a traceback, and never touches
an existing output file (docs/reference.md §4).

Each case of the table mutates a valid experiment (a config with its table and boundary in their own files) and
states which file and key the message must name. The whole table runs in-process through click's CliRunner; a
sample of it also runs as real ``rbx`` processes, in parallel, to check what a shell sees.
"""
import copy
import math
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml
from click.testing import CliRunner
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from rbx.paths import FileError
from rbx.reader import Run
from rbx.cli.main import cli

RBX = str(Path(sys.executable).with_name("rbx"))
STRIP = Path(__file__).resolve().parents[1] / "configs" / "examples" / "strip.yaml"
SENTINEL = b"\x89HDF\r\n\x1a\n" + b"an existing result that must survive"     # what rbx writes: HDF5

TABLE = {"kind": "strip", "width": 1.0}
BOUNDARY = {"default": {"rule": "random", "choices": [{"rule": "constant", "rank": 0}, {"rule": "constant", "rank": 1}],
                        "probabilities": [0.5, 0.5]}}
BASE = {"table": "tables/strip.yaml", "boundary": "boundary/random.yaml", "ball": {"radius": 0.1, "inertia": "uniform"},
        "initial": {"position": [0.0, 0.5], "velocity": [0.6, 0.8], "angular_velocity": 0.0, "orientation": 0.0},
        "run": {"collisions": 50, "trajectories": 2, "seed": 0},
        "output": {"path": "out.h5", "record": ["time", "position", "wall"], "every": 1}}
PLATES = {"table": {"kind": "plates", "gap": 1.0}, "boundary": {"default": {"rule": "constant", "rank": 2}},
          "ball": {"radius": 0.1}, "initial": {"position": [0, 0, 0.5], "velocity": [0.2, 0.3, 0.9]},
          "run": {"collisions": 50}, "output": {"path": "out.h5"}}


def setp(path, value):
    """A mutation: set (or with value DELETE, remove) the key at a dotted path."""
    def mutate(cfg):
        keys = path.split(".")
        node = cfg
        for k in keys[:-1]:
            node = node[int(k)] if isinstance(node, list) else node[k]
        last = int(keys[-1]) if isinstance(node, list) else keys[-1]
        if value is DELETE:
            del node[last]
        else:
            node[last] = value
        return cfg
    return mutate


DELETE = object()


def based_on(base, *mutations):
    def mutate(_):
        cfg = copy.deepcopy(base)
        for m in mutations:
            cfg = m(cfg)
        return cfg
    return mutate


# id: (files to write {relative path: dict or raw text}, mutation of BASE, extra args, file named, key named, problem)
# "file named" is the basename the message must contain (None: a command-line option, no file).
CASES = {
    # the YAML itself
    "yaml-syntax": ({"exp.yaml": "table: tables/strip.yaml\nball: {radius: 0.1\ninitial: x\n"}, None, [],
                    "exp.yaml", None, "line 3"),
    "yaml-tab-indent": ({"exp.yaml": "run:\n\tcollisions: 5\n"}, None, [], "exp.yaml", None, "YAML syntax error"),
    "yaml-empty": ({"exp.yaml": "# nothing here\n"}, None, [], "exp.yaml", None, "empty"),
    "yaml-top-list": ({"exp.yaml": "- table\n- ball\n"}, None, [], "exp.yaml", None, "expected a mapping"),
    "yaml-top-text": ({"exp.yaml": "just words\n"}, None, [], "exp.yaml", None, "expected a mapping"),
    "yaml-duplicate-key": ({"exp.yaml": yaml.safe_dump(BASE) + "run: {collisions: 5}\n"}, None, [], "exp.yaml",
                           None, "duplicate key 'run'"),
    # YAML 1.1 number forms are not numbers here (1:30 was read as 90, 010 as 8): YAML 1.2 rules
    "yaml-sexagesimal": ({"exp.yaml": yaml.safe_dump({k: v for k, v in BASE.items() if k != "run"})
                                      + "run: {collisions: 1:30}\n"}, None, [], "exp.yaml", "run.collisions",
                         "expected an integer, got the text '1:30'"),
    "yaml-long-integer": ({"exp.yaml": yaml.safe_dump({k: v for k, v in BASE.items() if k != "run"})
                                       + "run: {collisions: " + "9" * 5000 + "}\n"}, None, [], "exp.yaml", None,
                          "5000 digits is too long"),
    # an alias bomb: 20 rules each naming the one before twice expand to a million values (took minutes)
    "yaml-alias-bomb": ({"exp.yaml": yaml.safe_dump(BASE) + "defs:\n  - &a0 {rule: constant, rank: 1}\n" + "".join(
        f"  - &a{i} {{rule: hemisphere, axis: [0, 1], rough: *a{i - 1}, smooth: *a{i - 1}}}\n" for i in range(1, 21))},
        None, [], "exp.yaml", None, "aliases are expanded"),
    "not-utf8": ({"exp.yaml": b"table: \xff\xfe\n"}, None, [], "exp.yaml", None, "UTF-8"),
    "config-missing": ({}, None, ["nope.yaml"], "nope.yaml", None, "file not found"),
    "config-is-dir": ({"adir/x.yaml": "a: 1"}, None, ["adir"], "adir", None, "directory"),
    # keys
    "unknown-top-key": ({}, setp("ouptut", {}), [], "exp.yaml", "ouptut", "did you mean 'output'"),
    "unknown-ball-key": ({}, setp("ball.raduis", 0.1), [], "exp.yaml", "ball.raduis", "did you mean 'radius'"),
    "unknown-initial-key": ({}, setp("initial.spin", 1.0), [], "exp.yaml", "initial.spin", "unknown key"),
    "missing-ball": ({}, setp("ball", DELETE), [], "exp.yaml", "ball", "missing required key"),
    "missing-radius": ({}, setp("ball.radius", DELETE), [], "exp.yaml", "ball.radius", "missing"),
    "missing-velocity": ({}, setp("initial.velocity", DELETE), [], "exp.yaml", "initial.velocity", "missing"),
    "ball-not-mapping": ({}, setp("ball", 0.1), [], "exp.yaml", "ball", "expected a mapping"),
    "run-not-mapping": ({}, setp("run", [1, 2]), [], "exp.yaml", "run", "expected a mapping"),
    # the table (inline, and in its own file: then that file is named)
    "table-kind-typo": ({}, setp("table", {"kind": "strp", "width": 1}), [], "exp.yaml", "table.kind",
                        "did you mean 'strip'"),
    "table-kind-list": ({}, setp("table", {"kind": ["strip"], "width": 1}), [], "exp.yaml", "table.kind",
                        "expected a table kind"),
    "table-param-missing": ({}, setp("table", {"kind": "rectangle", "width": 1}), [], "exp.yaml", "table.height",
                            "missing"),
    "table-param-of-other-kind": ({}, setp("table", {"kind": "strip", "width": 1, "radius": 2}), [], "exp.yaml",
                                  "table.radius", "unknown key"),
    "table-not-mapping": ({}, setp("table", 3), [], "exp.yaml", "table", "expected a file name or a mapping"),
    "table-file-missing": ({}, setp("table", "tables/nope.yaml"), [], "exp.yaml", "table", "file not found"),
    "table-file-syntax": ({"tables/strip.yaml": "kind: strip\nwidth: [1\n"}, None, [], "strip.yaml", None, "line"),
    "table-file-empty": ({"tables/strip.yaml": ""}, None, [], "strip.yaml", None, "empty"),
    "table-file-negative": ({"tables/strip.yaml": {"kind": "strip", "width": -1}}, None, [], "strip.yaml", "width",
                            "must be positive"),
    "table-file-unknown-key": ({"tables/strip.yaml": {"kind": "strip", "widht": 1}}, None, [], "strip.yaml", "widht",
                               "did you mean 'width'"),
    "width-nan": ({}, setp("table", {"kind": "strip", "width": math.nan}), [], "exp.yaml", "table.width", "finite"),
    "width-inf": ({}, setp("table", {"kind": "strip", "width": math.inf}), [], "exp.yaml", "table.width", "finite"),
    "width-text": ({}, setp("table", {"kind": "strip", "width": "one"}), [], "exp.yaml", "table.width",
                   "expected a number"),
    "width-bool": ({}, setp("table", {"kind": "strip", "width": True}), [], "exp.yaml", "table.width",
                   "expected a number"),
    "width-huge-int": ({}, setp("table", {"kind": "strip", "width": 10**400}), [], "exp.yaml", "table.width",
                       "too large"),
    "wedge-180": ({}, setp("table", {"kind": "wedge", "angle_deg": 180}), [], "exp.yaml", "table.angle_deg", "< 180"),
    "polygon-clockwise": ({}, setp("table", {"kind": "polygon", "vertices": [[0, 0], [0, 1], [1, 1], [1, 0]]}), [],
                          "exp.yaml", "table.vertices", "counter-clockwise"),
    "polygon-crossing": ({}, setp("table", {"kind": "polygon", "vertices": [[0, 0], [2, 0], [0, 1], [2, 1.2]]}), [],
                         "exp.yaml", "table.vertices", "crosses"),
    "polygon-two-points": ({}, setp("table", {"kind": "polygon", "vertices": [[0, 0], [1, 0]]}), [], "exp.yaml",
                           "table.vertices", "at least 3"),
    "polygon-bad-point": ({}, setp("table", {"kind": "polygon", "vertices": [[0, 0], [1, 0], [1]]}), [], "exp.yaml",
                          "table.vertices[2]", "expected 2 numbers"),
    "box-negative": ({}, based_on(PLATES, setp("table", {"kind": "box", "size": [1, -1, 1]})), [], "exp.yaml",
                     "table.size[1]", "positive"),
    # the ball
    "radius-negative": ({}, setp("ball.radius", -0.1), [], "exp.yaml", "ball.radius", "positive"),
    "radius-zero": ({}, setp("ball.radius", 0), [], "exp.yaml", "ball.radius", "positive"),
    "ball-does-not-fit": ({}, setp("ball.radius", 0.6), [], "exp.yaml", "ball.radius", "does not fit"),
    "ball-does-not-fit-rectangle": ({}, setp("table", {"kind": "rectangle", "width": 3, "height": 0.15}), [],
                                    "exp.yaml", "ball.radius", "does not fit"),
    "inertia-unknown": ({}, setp("ball.inertia", "solid"), [], "exp.yaml", "ball.inertia", "unknown mass"),
    "inertia-ring-3d": ({}, based_on(PLATES, setp("ball.inertia", "ring")), [], "exp.yaml", "ball.inertia",
                        "unknown mass"),
    "inertia-too-big": ({}, setp("ball.inertia", 1.5), [], "exp.yaml", "ball.inertia", "≤ 1"),
    # the initial state
    "position-outside": ({}, setp("initial.position", [0.0, 0.05]), [], "exp.yaml", "initial.position",
                         "outside the table shrunk"),
    "position-nan": ({}, setp("initial.position", [0.0, math.nan]), [], "exp.yaml", "initial.position[1]", "finite"),
    # along the strip, x = 1e17 never moved (its last digit is longer than a flight), and the run ended complete
    "position-too-far": ({}, setp("initial.position", [1e17, 0.5]), [], "exp.yaml", "initial.position",
                         "too far out: a coordinate of 1e+17"),
    "position-3-numbers": ({}, setp("initial.position", [0, 0.5, 0]), [], "exp.yaml", "initial.position",
                           "expected 2 numbers"),
    # the output-size guard: refused before anything is written, with the estimate
    "output-too-large": ({}, setp("run.collisions", 10**15), [], "exp.yaml", "output.max_size",
                         "more than the limit"),
    "max-size-too-small": ({}, None, ["--max-size", "1 kB"], None, "--max-size", "more than the limit 1 kB"),
    "max-size-compressed": ({}, setp("output.compression", "gzip:4"), ["--max-size", "1 kB"], None, "--max-size",
                            "kB before compression (2 trajectories"),
    "max-size-option-bad": ({}, None, ["--max-size", "lots"], None, "--max-size", "expected a size"),
    "max-size-key-bad": ({}, setp("output.max_size", -3), [], "exp.yaml", "output.max_size", "positive"),
    "velocity-zero": ({}, setp("initial.velocity", [0, 0]), [], "exp.yaml", "initial.velocity", "non-zero"),
    # values so small or large that the state would become NaN (they used to run to NaN and exit 0)
    "velocity-underflows": ({}, setp("initial.velocity", [1e-300, 0]), [], "exp.yaml", "initial.velocity",
                            "too small"),
    "velocity-subnormal": ({}, setp("initial.velocity", [5e-324, 5e-324]), [], "exp.yaml", "initial.velocity",
                           "too small"),
    "radius-spin-overflows": ({}, setp("ball.radius", 1e-200), [], "exp.yaml", "ball.radius", "too small"),
    "spin-overflows": ({}, setp("initial.angular_velocity", 1e154), [], "exp.yaml", "initial.angular_velocity",
                       "too large"),
    "velocity-inf": ({}, setp("initial.velocity", [math.inf, 0]), [], "exp.yaml", "initial.velocity[0]", "finite"),
    "velocity-overflows": ({}, setp("initial.velocity", [1e300, 1e300]), [], "exp.yaml", "initial.velocity",
                           "overflows"),
    "spin-text": ({}, setp("initial.angular_velocity", "fast"), [], "exp.yaml", "initial.angular_velocity",
                  "expected a number"),
    "sample-unknown": ({}, setp("initial", {"sample": "uniform"}), [], "exp.yaml", "initial.sample",
                       "unknown sampler"),
    "sample-wall-typo": ({}, setp("initial", {"sample": "billiard", "wall": "topp"}), [], "exp.yaml", "initial.wall",
                         "did you mean 'top'"),
    "states-vs-trajectories": ({}, setp("initial", [BASE["initial"]] * 3), [], "exp.yaml",
                               "run.trajectories", "lists 3 states"),
    # boundary rules (in their own file)
    "rank-too-high": ({"boundary/random.yaml": {"default": {"rule": "constant", "rank": 2}}}, None, [], "random.yaml",
                      "default.rank", "≤ 1"),
    "rank-negative": ({"boundary/random.yaml": {"default": {"rule": "constant", "rank": -1}}}, None, [],
                      "random.yaml", "default.rank", "≥ 0"),
    "rank-fraction": ({"boundary/random.yaml": {"default": {"rule": "constant", "rank": 0.5}}}, None, [],
                      "random.yaml", "default.rank", "expected an integer"),
    "rank-missing": ({"boundary/random.yaml": {"default": {"rule": "constant"}}}, None, [], "random.yaml",
                     "default.rank", "missing"),
    "rule-unknown": ({"boundary/random.yaml": {"default": {"rule": "constnat", "rank": 1}}}, None, [], "random.yaml",
                     "default.rule", "did you mean 'constant'"),
    "rule-not-mapping": ({"boundary/random.yaml": {"default": "rough"}}, None, [], "random.yaml", "default",
                         "expected a rule mapping"),
    "wall-unknown": ({"boundary/random.yaml": {"default": {"rule": "constant", "rank": 0},
                                               "walls": {"topp": {"rule": "constant", "rank": 1}}}}, None, [],
                     "random.yaml", "walls.topp", "did you mean 'top'"),
    "walls-list": ({"boundary/random.yaml": {"default": {"rule": "constant", "rank": 0}, "walls": [{"a": 1}]}}, None,
                   [], "random.yaml", "walls", "expected a mapping"),
    "no-rule-for-a-wall": ({"boundary/random.yaml": {"walls": {"top": {"rule": "constant", "rank": 1}}}}, None, [],
                           "random.yaml", "default", "give a default rule"),
    "direction-2d": ({"boundary/random.yaml": {"default": {"rule": "constant", "rank": 1, "direction_deg": 30}}},
                     None, [], "random.yaml", "default.direction_deg", "only for 3D rank 1"),
    "rank1-3d-no-direction": ({}, based_on(PLATES, setp("boundary", {"default": {"rule": "constant", "rank": 1}})),
                              [], "exp.yaml", "boundary.default.direction_deg", "needs a roughness direction"),
    "direction-normal-to-wall": ({}, based_on(PLATES, setp("boundary", {"default": {"rule": "constant", "rank": 1,
                                                                                    "direction": [0, 0, 1]}})),
                                 [], "exp.yaml", "boundary.default.direction", "normal to wall 'bottom'"),
    "direction-zero": ({}, based_on(PLATES, setp("boundary", {"walls": {"top": {"rule": "constant", "rank": 2}},
                                                              "default": {"rule": "constant", "rank": 1,
                                                                          "direction": [0, 0, 0]}})),
                       [], "exp.yaml", "boundary.default.direction", "non-zero"),
    "direction-deg-nan": ({}, based_on(PLATES, setp("boundary", {"default": {"rule": "constant", "rank": 1,
                                                                             "direction_deg": math.nan}})),
                          [], "exp.yaml", "boundary.default.direction_deg", "finite"),
    "probabilities-sum": ({"boundary/random.yaml": {"default": {**BOUNDARY["default"], "probabilities": [0.5, 0.4]}}},
                          None, [], "random.yaml", "default.probabilities", "sum to 1"),
    "probabilities-negative": ({"boundary/random.yaml": {"default": {**BOUNDARY["default"],
                                                                    "probabilities": [-0.5, 1.5]}}},
                               None, [], "random.yaml", "default.probabilities[0]", "≥ 0"),
    "probabilities-count": ({"boundary/random.yaml": {"default": {**BOUNDARY["default"], "probabilities": [1.0]}}},
                            None, [], "random.yaml", "default.probabilities", "one per choice"),
    "random-nested-rank": ({"boundary/random.yaml": {"default": {**BOUNDARY["default"], "choices": [
        {"rule": "constant", "rank": 0}, {"rule": "constant", "rank": 7}]}}}, None, [], "random.yaml",
        "default.choices[1].rank", "≤ 1"),
    "hemisphere-zero-axis": ({"boundary/random.yaml": {"default": {"rule": "hemisphere", "axis": [0, 0],
                                                                   "rough": {"rule": "constant", "rank": 1},
                                                                   "smooth": {"rule": "constant", "rank": 0}}}},
                             None, [], "random.yaml", "default.axis", "non-zero"),
    "hemisphere-missing-smooth": ({"boundary/random.yaml": {"default": {"rule": "hemisphere", "axis": [0, 1],
                                                                        "rough": {"rule": "constant", "rank": 1}}}},
                                  None, [], "random.yaml", "default.smooth", "missing"),
    "boundary-file-syntax": ({"boundary/random.yaml": "default: {rule: constant, rank: 1\n"}, None, [],
                             "random.yaml", None, "YAML syntax error"),
    # run and output
    "collisions-zero": ({}, setp("run.collisions", 0), [], "exp.yaml", "run.collisions", "positive integer"),
    "collisions-negative": ({}, setp("run.collisions", -5), [], "exp.yaml", "run.collisions", "positive integer"),
    "collisions-fraction": ({}, setp("run.collisions", 2.5), [], "exp.yaml", "run.collisions", "expected an integer"),
    "collisions-text": ({}, setp("run.collisions", "many"), [], "exp.yaml", "run.collisions", "expected an integer"),
    "collisions-huge": ({}, setp("run.collisions", 10**30), [], "exp.yaml", "run.collisions", "≤"),
    "trajectories-zero": ({}, setp("run.trajectories", 0), [], "exp.yaml", "run.trajectories", "positive integer"),
    "seed-negative": ({}, setp("run.seed", -1), [], "exp.yaml", "run.seed", "≥ 0"),
    "every-zero": ({}, setp("output.every", 0), [], "exp.yaml", "output.every", "positive integer"),
    "record-typo": ({}, setp("output.record", ["time", "positon"]), [], "exp.yaml", "output.record[1]",
                    "did you mean 'position'"),
    "record-not-list": ({}, setp("output.record", "time"), [], "exp.yaml", "output.record", "expected a list"),
    "output-path-number": ({}, setp("output.path", 5), [], "exp.yaml", "output.path", "expected a file name"),
    "no-output-path": ({}, setp("output", {"record": []}), ["<no -o>"], "exp.yaml", "output.path", "no output file"),
    # command-line options
    "option-collisions-zero": ({}, None, ["--collisions", "0"], None, "--collisions", "positive integer"),
    "option-trajectories-negative": ({}, None, ["--trajectories", "-1"], None, "--trajectories", "positive integer"),
    "option-seed-negative": ({}, None, ["--seed", "-3"], None, "--seed", "≥ 0"),
    "option-collisions-text": ({}, None, ["--collisions", "abc"], None, "rbx: --collisions:", "not a valid integer"),
    "option-unknown": ({}, None, ["--colisions", "5"], None, "--colisions", "No such option"),
    "option-trajectories-vs-states": ({}, setp("initial", [BASE["initial"], BASE["initial"]]),
                                      ["--trajectories", "3"], None, "--trajectories", "lists 2 states"),
    "option-trajectories-memory": ({}, None, ["--trajectories", str(10**14)], None, "--trajectories", "memory"),
    "output-is-directory": ({"adir/x": "x"}, None, ["-o", "adir"], None, "-o", "is a directory"),
    "output-is-config": ({}, None, ["-o", "exp.yaml"], None, "-o", "is the config file itself"),
    # with --force it used to overwrite the table's YAML with HDF5
    "output-is-included-table": ({}, None, ["-o", "tables/strip.yaml"], None, "-o", "a file the config includes"),
    # existing files
    "output-exists": ({}, None, ["<no --force>"], "out.h5", None, "exists; use --force"),
    "partial-exists": ({"fresh.h5.partial": "a run in progress"}, None, ["<no --force>", "-o", "fresh.h5"],
                       "fresh.h5.partial", None, "exists"),
}


def write_experiment(folder, files, mutation):
    """The experiment of a case in ``folder``: exp.yaml, tables/strip.yaml, boundary/random.yaml, out.h5."""
    folder = Path(folder)
    defaults = {"tables/strip.yaml": TABLE, "boundary/random.yaml": BOUNDARY,
                "exp.yaml": (mutation or (lambda c: c))(copy.deepcopy(BASE))}
    for rel, content in {**defaults, **files}.items():
        p = folder / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(content, bytes):
            p.write_bytes(content)
        elif isinstance(content, str):
            p.write_text(content)
        else:
            p.write_text(yaml.safe_dump(content, sort_keys=False))
    (folder / "out.h5").write_bytes(SENTINEL)
    return folder / "exp.yaml"


def case_args(folder, extra):
    """rbx arguments of a case: by default `simulate exp.yaml -o out.h5 --force` (so errors must come first)."""
    extra = list(extra)
    force = "<no --force>" not in extra
    with_o = "<no -o>" not in extra
    extra = [a for a in extra if a not in ("<no --force>", "<no -o>")]
    target = [] if extra and not extra[0].startswith("-") else [str(folder / "exp.yaml")]
    args = ["simulate"] + target + extra
    if with_o and "-o" not in extra:
        args += ["-o", str(folder / "out.h5")]
    elif "-o" in extra:
        i = args.index("-o") + 1
        args[i] = str(folder / args[i])
    if extra and not extra[0].startswith("-"):
        args[1] = str(folder / extra[0])
    return args + (["--force"] if force else []) + ["--quiet"]


def check_user_error(code, stderr, file, key, problem, folder):
    assert code == 2, stderr
    assert "Traceback" not in stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    line = lines[0]
    assert line.startswith("rbx: "), line
    if file is not None:
        assert file in line, line
    if key is not None:
        assert key in line, line
    assert problem in line, line
    assert (folder / "out.h5").read_bytes() == SENTINEL, "an existing output file was touched"
    assert not (folder / "out.h5.partial").exists() or (folder / "out.h5.partial").read_text() == "a run in progress"


@pytest.mark.parametrize("case", list(CASES))
def test_user_error(case, tmp_path):
    files, mutation, extra, file, key, problem = CASES[case]
    write_experiment(tmp_path, files, mutation)
    result = CliRunner().invoke(cli, case_args(tmp_path, extra), catch_exceptions=False)
    check_user_error(result.exit_code, result.stderr, file, key, problem, tmp_path)


#: a sample of the table run as real processes: what a shell sees (exit status, stderr), including --debug
SUBPROCESS_CASES = ["yaml-syntax", "unknown-top-key", "table-file-negative", "width-nan", "position-outside",
                    "probabilities-sum", "option-collisions-zero", "option-trajectories-negative", "output-exists",
                    "rank1-3d-no-direction"]


@pytest.mark.long
def test_user_errors_in_real_processes(tmp_path):
    jobs = []
    for case in SUBPROCESS_CASES:
        files, mutation, extra, file, key, problem = CASES[case]
        folder = tmp_path / case
        folder.mkdir()
        write_experiment(folder, files, mutation)
        jobs.append((case, folder, [RBX] + case_args(folder, extra)))

    def run(job):
        return subprocess.run(job[2], capture_output=True, text=True, timeout=120)

    with ThreadPoolExecutor(4) as pool:
        results = list(pool.map(run, jobs))
    for (case, folder, _), res in zip(jobs, results):
        _, _, _, file, key, problem = CASES[case]
        assert res.stdout == ""
        check_user_error(res.returncode, res.stderr, file, key, problem, folder)


def test_debug_shows_the_traceback_too(tmp_path):
    write_experiment(tmp_path, {}, setp("ball.radius", -1))
    res = subprocess.run([RBX, "simulate", str(tmp_path / "exp.yaml"), "--debug"], capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 2
    assert "Traceback" in res.stderr
    assert res.stderr.strip().splitlines()[-1].startswith("rbx: ")


def test_relative_table_and_output_paths_resolve_from_the_config_folder(tmp_path, monkeypatch):
    write_experiment(tmp_path / "exp", {}, None)
    (tmp_path / "exp" / "out.h5").unlink()
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(cli, ["simulate", "exp/exp.yaml", "--quiet"], catch_exceptions=False)
    assert result.exit_code == 0, result.stderr
    assert (tmp_path / "exp" / "out.h5").exists() and not (tmp_path / "out.h5").exists()
    # and an existing result is then kept without --force
    result = CliRunner().invoke(cli, ["simulate", "exp/exp.yaml", "--quiet"], catch_exceptions=False)
    assert result.exit_code == 2 and result.stderr.strip() == "rbx: exp/out.h5: exists; use --force to overwrite it"


# ---- --resume of files that cannot be resumed, and the reader of plot, resume and the API (rbx.reader.Run) -------

def make_files(folder):
    """Files that are not rbx runs: missing, text, an HDF5 file of something else, a run without positions."""
    folder = Path(folder)
    (folder / "text.h5").write_text("not hdf5")
    with h5py.File(folder / "other.h5", "w") as f:
        f["x"] = np.arange(3)
    write_experiment(folder, {}, setp("output.record", ["time"]))
    (folder / "out.h5").unlink()
    res = CliRunner().invoke(cli, ["simulate", str(folder / "exp.yaml"), "--quiet"], catch_exceptions=False)
    assert res.exit_code == 0
    with h5py.File(folder / "newer.h5", "w") as f:
        for k in ("rbx_version", "dimension", "config", "complete"):
            f.attrs[k] = 0
        f.attrs["schema_version"] = 99
    return folder


OPEN_RUN_CASES = {"missing.h5": "file not found", "text.h5": "not an HDF5 file", "other.h5": "not an rbx run file",
                  "newer.h5": "newer rbx", ".": "is a directory"}


@pytest.mark.parametrize("name", list(OPEN_RUN_CASES))
def test_reading_a_run_names_the_file(name, tmp_path):
    make_files(tmp_path)
    path = tmp_path / name
    with pytest.raises(FileError) as info:
        Run.open(str(path))
    assert os.path.basename(str(path)) in str(info.value) or name == "."
    assert OPEN_RUN_CASES[name] in str(info.value)


def test_reading_a_run_names_a_missing_dataset(tmp_path):
    make_files(tmp_path)
    run = Run.open(str(tmp_path / "out.h5"))
    with pytest.raises(FileError) as info:
        run.require(("time", "position"), "this test")
    msg = str(info.value)
    assert "out.h5" in msg and "collisions/position" in msg and "add 'position' to output.record" in msg
    run.require(("time",), "this test")
    assert run.time.shape[0] == 2 and run.read("time").shape[0] == 2


@pytest.mark.parametrize("name, args, problem", [
    ("missing.h5", [], "file not found"), ("text.h5", [], "not an HDF5 file"), ("other.h5", [], "not an rbx run"),
    ("out.h5", ["--collisions", "5"], "cannot be changed when resuming"),
    ("out.h5", ["exp.yaml"], "not both")])
def test_resume_errors(name, args, problem, tmp_path):
    make_files(tmp_path)
    extra = [str(tmp_path / a) if a.endswith(".yaml") else a for a in args]
    result = CliRunner().invoke(cli, ["simulate", "--resume", str(tmp_path / name)] + extra, catch_exceptions=False)
    assert result.exit_code == 2
    line, = result.stderr.strip().splitlines()
    assert problem in line and "Traceback" not in line


# ---- random, mostly wrong configs: a valid run or exit 2, never a traceback ---------------------------------------

JUNK = [None, True, False, -1, 0, 1, 2, 3, 0.5, -0.5, 1e-300, 1e308, math.nan, math.inf, -math.inf, 10**30, "", "x",
        "strip", "top", "1e3", "constant", "random", "billiard", [], [0.5], [0.5, 0.5], [0.0, 0.0, 0.5],
        [[0, 0], [1, 0], [0, 1]], {}, {"rule": "constant", "rank": 1}, {"kind": "circle", "radius": 1}, {"x": 1}]
KEYS = ["kind", "width", "radius", "rule", "rank", "choices", "probabilities", "position", "velocity", "wall", "sample",
        "collisions", "trajectories", "every", "record", "direction", "direction_deg", "axis", "walls", "default"]
BASES = [
    {**BASE, "table": TABLE, "boundary": BOUNDARY},
    {**PLATES, "boundary": {"default": {"rule": "random", "probabilities": [0.5, 0.5], "choices": [
        {"rule": "constant", "rank": 1, "direction_deg": 30}, {"rule": "constant", "rank": 2}]}},
     "run": {"collisions": 30, "trajectories": 2}},
    # (a convex quadrilateral: the loop of a hemisphere rule on flat walls, which other tests compile too)
    {"table": {"kind": "polygon", "vertices": [[0, 0], [2, 0], [1.5, 2], [0.3, 1.2]]},
     "boundary": {"default": {"rule": "hemisphere", "axis": [0, 1], "rough": {"rule": "constant", "rank": 1},
                              "smooth": {"rule": "constant", "rank": 0}}},
     "ball": {"radius": 0.1, "inertia": 0.3}, "initial": {"sample": "billiard", "wall": "edge0"},
     "run": {"collisions": 30, "trajectories": 3, "seed": 4}, "output": {"every": 2}},
    {"table": {"kind": "wedge", "angle_deg": 40}, "boundary": {"default": {"rule": "constant", "rank": 1}},
     "ball": {"radius": 0.05}, "initial": {"position": [1.0, 0.2], "velocity": [-1, 0.1], "angular_velocity": 2},
     "run": {"collisions": 30}, "output": {"record": []}},
]


@st.composite
def mostly_wrong_configs(draw):
    cfg = copy.deepcopy(draw(st.sampled_from(BASES)))
    for _ in range(draw(st.integers(1, 3))):
        # walk down to a random node, then break it
        parent, key = None, None
        node = cfg
        while isinstance(node, (dict, list)) and node and draw(st.booleans()):
            keys = list(node) if isinstance(node, dict) else list(range(len(node)))
            parent, key = node, draw(st.sampled_from(keys))
            node = node[key]
        action = draw(st.sampled_from(["replace", "replace", "delete", "add", "wrap"]))
        if parent is None:
            if action == "add":
                cfg[draw(st.sampled_from(KEYS))] = copy.deepcopy(draw(st.sampled_from(JUNK)))
            continue
        if action == "replace":
            parent[key] = copy.deepcopy(draw(st.sampled_from(JUNK)))
        elif action == "delete":
            del parent[key]
        elif action == "add" and isinstance(node, dict):
            node[draw(st.sampled_from(KEYS))] = copy.deepcopy(draw(st.sampled_from(JUNK)))
        else:
            parent[key] = [node]
    text = yaml.safe_dump(cfg, sort_keys=False)
    if draw(st.integers(0, 9)) == 0:   # now and then a broken file: cut it anywhere
        text = text[:draw(st.integers(0, len(text)))]
    return text


#: examples per run; RBX_FUZZ_EXAMPLES=6000 for a longer hunt (6000 passed when this was written)
FUZZ_EXAMPLES = int(os.environ.get("RBX_FUZZ_EXAMPLES", 300))


@pytest.mark.long
@settings(max_examples=FUZZ_EXAMPLES, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(text=mostly_wrong_configs())
def test_random_configs_never_give_a_traceback(text, tmp_path_factory):
    folder = tmp_path_factory.mktemp("random")
    (folder / "exp.yaml").write_text(text)
    out = folder / "run.h5"
    # catch_exceptions=False: any exception other than SystemExit reaches pytest instead of becoming exit code 1
    result = CliRunner().invoke(cli, ["simulate", str(folder / "exp.yaml"), "-o", str(out), "--quiet"],
                                catch_exceptions=False)
    assert result.exception is None or isinstance(result.exception, SystemExit)
    assert "Traceback" not in result.output
    event(f"exit {result.exit_code}")
    assert result.exit_code in (0, 2), (result.exit_code, result.output, text)
    if result.exit_code == 2:
        line, = result.stderr.strip().splitlines()
        assert line.startswith("rbx: ")
        assert not out.exists() and not Path(f"{out}.partial").exists()
    else:
        with h5py.File(out) as f:
            assert bool(f.attrs["complete"])


def test_a_deleted_working_directory_is_one_line(tmp_path):
    gone = tmp_path / "gone"
    gone.mkdir()
    script = f"import os, subprocess, sys; os.chdir({str(gone)!r}); os.rmdir({str(gone)!r}); " \
             f"r = subprocess.run([{RBX!r}, 'simulate', 'x.yaml'], capture_output=True, text=True); " \
             "sys.stdout.write(str(r.returncode) + '\\n' + r.stderr)"
    res = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    code, *err = res.stdout.splitlines()
    assert code == "2" and err == ["rbx: the working directory no longer exists; change to an existing folder"]



@pytest.mark.parametrize("args, key, problem", [
    (["plot", "x.h5", "--kind", "orbit", "--dpi", "100000"], "--dpi", "not in the range"),
    (["plot", "x.h5", "--kind", "orbt"], "--kind", "is not one of"),
    (["histogram"], "CONFIG", "Missing argument"),
    # memory: the histogram's sample count and a plot's trajectory range are checked before anything is allocated
    (["histogram", "{config}", "--trajectories", "1000000000"], "--trajectories", "GiB of memory"),
    # and rbx lyapunov's (a MemoryError traceback, 7 TiB asked)
    (["lyapunov", "{config}", "--trajectories", "1000000000000"], "--trajectories", "GiB of memory"),
    (["plot", "{run}", "--kind", "orbit", "--trajectories", "0-100000000000"], "--trajectories", "does not exist"),
    # -o '' used output.path silently; -o newdir/ wrote a file named newdir
    (["simulate", "{config}", "-o", ""], "-o", "an empty file name"),
    (["simulate", "{config}", "-o", "newdir/"], "-o", "names a folder"),
])
def test_usage_mistakes_of_every_command_are_one_line(tmp_path, args, key, problem):
    config = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "configs", "examples",
                          "strip.yaml")
    if "{run}" in args:
        run = tmp_path / "run.h5"
        assert subprocess.run([RBX, "simulate", config, "-o", str(run), "--collisions", "20", "--quiet"],
                              timeout=120).returncode == 0
    hist = os.path.join(os.path.dirname(config), "..", "experiments", "histogram.yaml")
    res = subprocess.run([RBX] + [a.format(config=hist if args[0] == "histogram" else config, run=tmp_path / "run.h5")
                                  for a in args], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert res.returncode == 2 and res.stderr.count("\n") == 1, res.stderr
    assert not (tmp_path / "newdir").exists()
    assert (res.stderr.startswith(f"rbx: {key}: ") or f": {key}: " in res.stderr) and problem in res.stderr


@pytest.mark.parametrize("variable, value, said", [
    ("RBX_KERNELS", "Generalx", "'Generalx' is not one of specialised, general"),
    ("RBX_NUMBA_FALLBACK", "bogus", "unknown hook(s) ['bogus']; known: all, fingerprint"),
    ("NUMBA_DISABLE_JIT", "1", "is '1': rbx's loops run only as Numba compiles them; unset it"),
    ("NUMBA_THREADING_LAYER", "bogus", "Numba cannot load the threading layer 'bogus' (The threading layer"),
    ("NUMBA_OPT", "abc", "Numba cannot read the value 'abc' (Environment variable `NUMBA_OPT` is set to an "
                         "unsupported value 'abc', supported values are 0, 1, 2, 3, and 'max'); unset it or fix it"),
])
def test_an_environment_variable_that_stops_rbx_is_one_line(tmp_path, variable, value, said):
    """An unknown hook in RBX_NUMBA_FALLBACK, Numba's compiler turned off, a threading layer Numba cannot load
    ended a command in a traceback, and an unknown RBX_KERNELS warned in Python's two lines and ran on, as did
    a value of NUMBA_OPT that Numba cannot read (its parser's traceback in a warning): each is now one line
    naming the variable, exit 2, before any work."""
    res = subprocess.run([RBX, "simulate", str(STRIP), "-o", "a.h5"], capture_output=True, text=True, timeout=120,
                         cwd=tmp_path, env=dict(os.environ, **{variable: value}))
    assert res.returncode == 2 and res.stderr.count("\n") == 1, res.stderr
    assert res.stderr.startswith(f"rbx: {variable}: {said}"), res.stderr
    assert os.listdir(tmp_path) == []


def test_the_library_refuses_to_run_with_numbas_compiler_turned_off():
    res = subprocess.run([sys.executable, "-c", "import rbx; rbx.simulate(rbx.load(%r), collisions=5)"
                          % str(STRIP)], capture_output=True, text=True, timeout=120,
                         env=dict(os.environ, NUMBA_DISABLE_JIT="1"))
    assert res.returncode == 1 and res.stderr.splitlines()[-1] == (
        "ImportError: NUMBA_DISABLE_JIT: is '1': rbx's loops run only as Numba compiles them; unset it"), res.stderr


def test_a_bad_numba_num_threads_is_one_line(tmp_path):
    env = dict(os.environ, NUMBA_NUM_THREADS="0")
    res = subprocess.run([RBX, "simulate", "x.yaml"], capture_output=True, text=True, timeout=120, cwd=tmp_path,
                         env=env)
    assert res.returncode == 2 and res.stderr == "rbx: NUMBA_NUM_THREADS: must be a positive integer, got '0'\n"
