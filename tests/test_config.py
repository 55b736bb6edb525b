"""rbx.config: a valid config loads once into frozen objects; paths, numbers, defaults and overrides behave as a
user expects; what is stored in a run file reads back to the same config (for --resume)."""
import dataclasses
import os

import numpy as np
import pytest
import yaml

from rbx import config, model, yamlfile
from rbx.config import ConfigError
from rbx.runfile import config_yaml
from tests.catalog import SCENES

STRIP = """\
table: tables/strip.yaml
boundary: boundary/rough.yaml
ball: {radius: 0.1, inertia: uniform}
initial: {position: [0.0, 0.5], velocity: [0.6, 0.8], angular_velocity: 1.5}
run: {collisions: 100, trajectories: 2, seed: 7}
output: {path: runs/strip.h5, record: [time, wall], every: 2}
"""


@pytest.fixture
def experiment(tmp_path):
    (tmp_path / "tables").mkdir()
    (tmp_path / "boundary").mkdir()
    (tmp_path / "tables" / "strip.yaml").write_text("kind: strip\nwidth: 1\n")
    (tmp_path / "boundary" / "rough.yaml").write_text("default: {rule: constant, rank: 1}\n")
    path = tmp_path / "exp.yaml"
    path.write_text(STRIP)
    return path


def error_of(path_or_data, overrides=None):
    with pytest.raises(ConfigError) as info:
        if isinstance(path_or_data, dict):
            config.from_dict(path_or_data, overrides=overrides)
        else:
            config.load(path_or_data, overrides)
    return info.value


def test_a_valid_config_is_frozen(experiment):
    cfg = config.load(experiment)
    assert cfg.table_kind == "strip" and cfg.dimension == 2 and cfg.wall_names == ("bottom", "top")
    assert cfg.run == model.RunSettings(100, 2, 7)
    assert cfg.output.record == ("time", "wall") and cfg.output.every == 2
    assert cfg.wall_rules == (model.Constant(1), model.Constant(1))
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.run = None
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.run.collisions = 5
    with pytest.raises(TypeError):
        cfg.table["width"] = 2.0
    with pytest.raises(ValueError):
        cfg.initial[0]["position"][0] = 1.0


def test_relative_paths_resolve_from_the_config_folder(experiment, tmp_path, monkeypatch):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    cfg = config.load(os.path.relpath(experiment))
    assert cfg.output.path == str(tmp_path / "runs" / "strip.h5")
    assert cfg.table["width"] == 1.0


def test_defaults(experiment):
    data = yaml.safe_load(STRIP)
    del data["run"], data["output"]
    data["table"] = {"kind": "strip", "width": 1}
    data["boundary"] = {"default": {"rule": "constant", "rank": 0}}
    cfg = config.from_dict(data)
    assert cfg.run == model.RunSettings(1000, 1, 0)
    assert cfg.output == model.Output(None, model.RECORD_FIELDS, 1)
    # an empty section means its defaults too
    cfg = config.from_dict({**data, "run": None, "output": None})
    assert cfg.run == model.RunSettings(1000, 1, 0)


def test_scientific_notation_is_a_number(experiment):
    experiment.write_text(STRIP.replace("collisions: 100", "collisions: 1e6").replace("radius: 0.1", "radius: 5e-2"))
    cfg = config.load(experiment)
    assert cfg.run.collisions == 1_000_000 and cfg.ball.radius == 0.05


def test_duplicate_keys_are_errors_but_merge_keys_work(experiment):
    experiment.write_text(STRIP + "run: {collisions: 5}\n")
    err = error_of(experiment)
    assert err.file == str(experiment) and "duplicate key 'run'" in err.problem and "line 7" in err.problem
    experiment.write_text(STRIP.replace("run: {collisions: 100, trajectories: 2, seed: 7}",
                                        "base: &base {collisions: 100, trajectories: 2, seed: 7}\n"
                                        "run: {<<: *base, seed: 9}").replace("base:", "x-base:"))
    err = error_of(experiment)   # the anchor's own key is unknown, but the merge itself parses
    assert err.key == "x-base"
    data = yaml.load(experiment.read_text(), Loader=yamlfile._Loader)
    assert data["run"] == {"collisions": 100, "trajectories": 2, "seed": 9}


def test_yaml_errors_name_file_and_line(experiment):
    experiment.write_text("table: tables/strip.yaml\nball: {radius: 0.1\ninitial: x\n")
    err = error_of(experiment)
    assert err.file == str(experiment) and err.problem.startswith("YAML syntax error: line 3")


def test_an_alias_that_contains_itself_is_an_error(experiment):
    experiment.write_text(STRIP.replace("boundary: boundary/rough.yaml",
                                        "boundary: {default: &r {rule: random, choices: [*r], probabilities: [1]}}"))
    err = error_of(experiment)
    assert "nested too deeply" in err.problem


def test_errors_in_an_included_file_name_that_file(experiment, tmp_path):
    (tmp_path / "boundary" / "rough.yaml").write_text("default: {rule: constant, rank: 3}\n")
    err = error_of(experiment)
    assert err.file == str(tmp_path / "boundary" / "rough.yaml") and err.key == "default.rank"
    (tmp_path / "tables" / "strip.yaml").write_text("")
    err = error_of(experiment)
    assert err.file == str(tmp_path / "tables" / "strip.yaml") and "empty" in err.problem


def test_overrides_win_and_name_the_option(experiment):
    cfg = config.load(experiment, {"collisions": 5, "trajectories": None, "seed": 3})
    assert cfg.run == model.RunSettings(5, 2, 3)
    for name, value in (("collisions", 0), ("trajectories", -1), ("seed", -2), ("collisions", 2**70)):
        err = error_of(experiment, {name: value})
        assert err.file is None and err.key == f"--{name}" and str(err).startswith(f"--{name}: ")


@pytest.mark.parametrize("name", list(SCENES))
def test_stored_config_reads_back_the_same(name):
    """What a run file stores (``config`` attribute) validates again to the same experiment: --resume needs it."""
    cfg = config.from_dict(SCENES[name])
    again = config.loads(config_yaml(cfg), "run.h5")
    for f in ("dimension", "table_kind", "wall_rules", "wall_names", "ball", "run", "output"):
        assert getattr(again, f) == getattr(cfg, f), f
    assert dict(again.table) == dict(cfg.table)
    for a, b in zip(again.initial, cfg.initial):
        for k in a:
            np.testing.assert_array_equal(a[k], b[k])


@pytest.mark.parametrize("vertices, problem", [
    ([[0, 0], [2, 0], [2, 1], [1, 0], [0, 1]], "touches"),     # a vertex on another edge
    ([[0, 0], [1, 0], [1, 0], [0, 1]], "coincide"),
    ([[0, 0], [1, 0], [2, 0]], "counter-clockwise"),             # no area
])
def test_degenerate_polygons(vertices, problem):
    data = dict(SCENES["triangle-rough"], table={"kind": "polygon", "vertices": vertices})
    assert problem in error_of(data).problem


def test_hints():
    data = dict(SCENES["strip-rough"])
    assert "did you mean 'boundary'" in str(error_of({**data, "bondary": {}}))
    assert "did you mean 'circle'" in str(error_of({**data, "table": {"kind": "circel", "radius": 1}}))
    assert "did you mean 'hemisphere'" in str(error_of({**data, "boundary": {"default": {"rule": "hemispere"}}}))
    err = error_of({**data, "initial": {"sampel": "billiard"}})
    assert err.key == "initial.sampel" and "did you mean 'sample'" in err.problem


# ---- numerical options (config section `numerics`, rbx.model.Numerics) ---------------------------------------------

def test_numerics_default_and_given(experiment, tmp_path):
    assert config.load(experiment).numerics == model.Numerics(model.RENORMALIZE_EVERY, False, False)
    assert "numerics" not in config.load(experiment).resolved        # files of runs without it read as before
    path = tmp_path / "num.yaml"
    path.write_text(STRIP + "numerics: {renormalize: 0, compensated: true, snap: true}\n")
    cfg = config.load(path)
    assert cfg.numerics == model.Numerics(0, True, True)
    again = config.loads(config_yaml(cfg), "<stored>")                # what a run file stores reads back the same
    assert again.numerics == cfg.numerics


@pytest.mark.parametrize("text, key, problem", [
    ("numerics: {renormalise: 3}", "numerics.renormalise", "did you mean 'renormalize'"),
    ("numerics: {renormalize: -1}", "numerics.renormalize", "≥ 0"),
    ("numerics: {renormalize: 1.5}", "numerics.renormalize", "integer"),
    ("numerics: {snap: 1}", "numerics.snap", "true or false"),
    ("numerics: [1]", "numerics", "mapping"),
])
def test_numerics_errors_name_the_key(tmp_path, experiment, text, key, problem):
    path = tmp_path / "bad.yaml"
    path.write_text(experiment.read_text() + text + "\n")
    err = error_of(path)
    assert err.key == key and problem in err.problem, str(err)


def test_numerics_reach_the_engine(experiment):
    # the options change what the kernel does: the energy projection off, the energy drifts by rounding; the
    # replaced experiment records the options it ran with
    from rbx.simulation import MemorySink, Simulation
    cfg = config.load(experiment, {"collisions": 20000, "trajectories": 1}).replace(
        output=model.Output(None, (), 1))
    finals = {}
    for period in (16, 0):
        run = cfg.replace(numerics=model.Numerics(renormalize=period))
        assert run.resolved["numerics"]["renormalize"] == period
        sim = Simulation(run)
        assert sim.numerics.renormalize == period
        sink = MemorySink()
        sim.run(sink)
        finals[period] = sink.final
    assert not np.array_equal(finals[16]["velocity"], finals[0]["velocity"])
    np.testing.assert_allclose(finals[16]["velocity"], finals[0]["velocity"], rtol=1e-9)


def test_a_tiny_hemisphere_axis_is_normalised_not_nan():
    # [1e-320, 0] has a norm that underflows to 0: normalised in two steps it is the unit vector (1, 0)
    c = {"table": {"kind": "strip", "width": 1}, "ball": {"radius": 0.1},
         "boundary": {"default": {"rule": "hemisphere", "axis": [1e-320, 0], "rough": {"rule": "constant", "rank": 1},
                                  "smooth": {"rule": "constant", "rank": 0}}},
         "initial": {"position": [0, 0.5], "velocity": [0.6, 0.8]}}
    assert config.from_dict(c).wall_rules[0].axis == (1.0, 0.0)


@pytest.mark.parametrize("scale", [1e-150, 1e150])
def test_extreme_speeds_inside_the_limits_run_without_nan(scale):
    from rbx.simulation import run_in_memory
    c = {"table": {"kind": "rectangle", "width": 1, "height": 1}, "ball": {"radius": 0.1},
         "boundary": {"default": {"rule": "constant", "rank": 1}},
         "initial": {"position": [0.5, 0.5], "velocity": [0.6 * scale, 0.8 * scale], "angular_velocity": scale},
         "run": {"collisions": 2000}, "output": {"record": ["time", "velocity", "angular_velocity"]}}
    rec, count, final = run_in_memory(config.from_dict(c))
    assert count[0] == 2001 and final["alive"][0]
    assert all(np.all(np.isfinite(v)) for v in rec.values())


def test_numbers_follow_yaml_1_2():
    # a leading zero is decimal (YAML 1.1: octal), 0o/0x prefixes as in YAML 1.2, digits may be grouped with _
    data = yamlfile.parse_yaml("a: 010\nb: 0o17\nc: 0x1f\nd: 1_000_000\ne: 1e6\nf: 1:30\ng: .5\n", "f")
    assert data == {"a": 10, "b": 15, "c": 31, "d": 1000000, "e": 1e6, "f": "1:30", "g": 0.5}
    assert isinstance(data["e"], float) and isinstance(data["d"], int)


def test_expanded_size_counts_shared_parts_each_time():
    leaf = [1, 2]
    assert yamlfile.expanded_size({"a": leaf, "b": leaf}) == 1 + 2 * (1 + 2) + 2     # the dict, two lists, two keys
    loop = []
    loop.append(loop)                                                             # `&a [*a]`
    assert yamlfile.expanded_size(loop) == float("inf")
    with pytest.raises(ConfigError) as info:
        config.from_dict({"table": loop})
    assert "refers to itself" in info.value.problem


def test_paths_expand_the_home_folder_and_refuse_folders(experiment, monkeypatch, tmp_path):
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    text = experiment.read_text()
    experiment.write_text(text.replace("path: runs/strip.h5", "path: ~/runs/x.h5"))
    assert config.load(experiment).output.path == str(tmp_path / "home" / "runs" / "x.h5")
    experiment.write_text(text.replace("path: runs/strip.h5", "path: runs/"))
    err = error_of(experiment)
    assert err.key == "output.path" and "names a folder" in err.problem


def test_changes_are_made_to_the_config_before_it_is_validated(experiment):
    """Dotted changes (--set, rbx.load overrides) reach into included files, index lists, merge mappings, and
    replace a rule, a table or a start given with its kind."""
    cfg = config.load(experiment, changes={"table.width": 2, "boundary.walls.top": {"rule": "exit"}})
    assert cfg.table["width"] == 2.0 and cfg.resolved["table"] == {"kind": "strip", "width": 2.0}
    assert isinstance(cfg.wall_rules[1], model.Exit) and cfg.wall_rules[0] == model.Constant(1)
    # the table file a change reached into is still one the output must never overwrite
    assert str(experiment.parent / "tables" / "strip.yaml") in cfg.includes
    # a rule given with its kind replaces the rule there (a hemisphere's axis is no key of a constant rule)
    cfg = config.load(experiment, changes={"boundary": {"default": {"rule": "hemisphere", "axis": [0, 1],
                                                                     "rough": {"rule": "constant", "rank": 1},
                                                                     "smooth": {"rule": "constant", "rank": 0}}}})
    assert isinstance(cfg.wall_rules[0], model.Hemisphere)
    cfg = config.load(experiment, changes={"boundary.default": {"rule": "constant", "rank": 0}})
    assert cfg.wall_rules == (model.Constant(0), model.Constant(0))
    # a list item by its index; a section that was not there
    two = {"initial": [{"position": [0, 0.5], "velocity": [1, 0]}, {"position": [0, 0.5], "velocity": [0, 1]}]}
    cfg = config.load(experiment, changes=two)
    cfg = config.from_dict(cfg.resolved, cfg.source, changes={"initial[1].position": [0, 0.3], "numerics.snap": True})
    assert cfg.initial[1]["position"].tolist() == [0, 0.3] and cfg.initial[0]["position"].tolist() == [0, 0.5]
    assert cfg.numerics.snap and cfg.resolved["numerics"]["snap"]
    assert config.load(experiment).numerics == model.Numerics()      # the file itself is untouched


@pytest.mark.parametrize("changes, key, problem", [
    ({"colisions": 7}, "colisions", "unknown key (did you mean 'run.collisions'?)"),
    ({"ball.inertai": 0.2}, "ball.inertai", "unknown key (did you mean 'ball.inertia'?)"),
    ({"ball.radius": -1}, "ball.radius", "must be positive, got -1 (override ball.radius)"),
    ({"table.width.x": 1}, "table.width.x", "table.width is an integer, not a mapping: it has no key 'x'"),
    ({"initial[0]": {}}, "initial[0]", "initial is a mapping, not a list: [0] names nothing"),
    ({"ball..radius": 1}, "ball..radius", "not a config key"),
    ({"ball": {"radius": 0.1}, "ball.inertia": 1}, "ball.inertia", "set twice, as ball and ball.inertia"),
    ({"boundary.walls.middle": {"rule": "exit"}}, "boundary.walls.middle", "no wall named 'middle'"),
])
def test_a_bad_change_names_its_key(experiment, changes, key, problem):
    with pytest.raises(ConfigError) as info:
        config.load(experiment, changes=changes)
    exc = info.value
    assert exc.file == str(experiment) and exc.key == key and exc.problem.startswith(problem), str(exc)


def test_a_ball_computes_kappa_from_its_inertia():
    """κ is never stored beside the inertia it comes from; a ball that cannot exist is refused when made."""
    ball = model.Ball(0.1, "uniform", 3)
    assert ball.kappa == 0.4 and dataclasses.replace(ball, inertia="shell").kappa == pytest.approx(2 / 3)
    assert dataclasses.replace(ball, dimension=2).kappa == 0.5 and dataclasses.replace(ball, inertia=0.1).kappa == 0.1
    for bad, key in (({"inertia": "ring"}, "ball.inertia"), ({"inertia": 0}, "ball.inertia"),
                     ({"radius": -0.1}, "ball.radius"), ({"dimension": 4}, "ball.dimension")):
        with pytest.raises(ConfigError) as info:
            dataclasses.replace(ball, **bad)
        assert info.value.key == key and info.value.file is None


# ---- explicit states of any number; aliases counted, not values written out -------------------------------------

def _states_yaml(n, anchored=False):
    head = ("table: {kind: rectangle, width: 2.0, height: 1.0}\nboundary: {default: {rule: constant, rank: 0}}\n"
            "ball: {radius: 0.1}\n")
    if anchored:
        return head + "initial:\n- &s {position: [1.0, 0.5], velocity: [0.6, 0.8]}\n" + "- *s\n" * (n - 1)
    rng = np.random.default_rng(0)
    xs, ys, a = rng.uniform(0.2, 1.8, n), rng.uniform(0.2, 0.8, n), rng.uniform(0, 2 * np.pi, n)
    rows = (f"- {{position: [{float(x)!r}, {float(y)!r}], velocity: [{float(np.cos(t))!r}, {float(np.sin(t))!r}]}}\n"
            for x, y, t in zip(xs, ys, a))
    return head + "initial:\n" + "".join(rows)


@pytest.mark.long
def test_a_list_of_40000_states_written_out_loads(tmp_path):
    # 40 000 states hold ~440 000 values: refused before as "a bomb of nested aliases?" though no alias was used
    path = tmp_path / "many.yaml"
    path.write_text(_states_yaml(40_000))
    exp = config.load(str(path))
    assert len(exp.initial) == 40_000 and exp.run.trajectories == 40_000
    assert exp.initial[39_999]["position"].flags.writeable is False


def test_a_list_of_states_that_all_name_one_anchor_loads(tmp_path):
    # one anchored state named 40 000 times: the aliases add ~400 000 values, ten times what is written out
    path = tmp_path / "same.yaml"
    path.write_text(_states_yaml(40_000, anchored=True))
    exp = config.load(str(path))
    assert len(exp.initial) == 40_000
    assert config.from_dict({**yaml.safe_load(path.read_text())}).run.trajectories == 40_000


def test_an_alias_bomb_is_still_refused_in_one_line(tmp_path):
    # "billion laughs": 30 levels, each a list naming the one before 10 times: 10³⁰ values from 30 lines
    text = "a0: &a0 [lol]\n" + "".join(f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 10)}]\n" for i in range(1, 31))
    with pytest.raises(ConfigError) as info:
        yamlfile.parse_yaml(text, "bomb.yaml")
    assert "aliases are expanded" in info.value.problem and "bomb" in info.value.problem
    expanded, written = yamlfile.alias_count(yamlfile._load_yaml(text))
    assert expanded > 10 ** 30 and written < 400


def test_alias_count_counts_uses_of_shared_parts_only():
    leaf = [1, 2]
    assert yamlfile.alias_count({"a": leaf, "b": leaf}) == (1 + 2 * (1 + 2) + 2, 1 + (1 + 2) + 1 + 2)
    honest = [[float(i), 0.0] for i in range(1000)]
    expanded, written = yamlfile.alias_count(honest)
    assert expanded == written == 1 + 3 * 1000


@pytest.mark.long
def test_states_checked_in_bulk_read_as_one_by_one():
    # the bulk path (plain numbers, checked as arrays) and the one-by-one path give the same experiment, and the
    # first bad state is named as before, wherever it is in the list
    base = yaml.safe_load(_states_yaml(300))
    bulk = config.from_dict(base)
    mixed = copy_of(base)
    mixed["initial"][0]["position"] = [np.float64(x) for x in mixed["initial"][0]["position"]]   # not plain
    slow = config.from_dict(mixed)
    for a, b in zip(bulk.initial, slow.initial):
        assert set(a) == set(b)
        for k in a:
            assert np.array_equal(a[k], b[k]) and type(a[k]) is type(b[k])
    for i, (key, value, problem) in enumerate([("position", [5.0, 0.5], "outside the table"),
                                                ("velocity", [0, 0], "must be non-zero"),
                                                ("velocity", [1e200, 1e200], "overflows"),
                                                ("angular_velocity", float("nan"), "finite"),
                                                ("position", [0.5], "expected 2 numbers")]):
        bad = copy_of(base)
        bad["initial"][250][key] = value
        bad["initial"][270]["position"] = [9.0, 9.0]
        with pytest.raises(ConfigError) as info:
            config.from_dict(bad)
        assert info.value.key.startswith("initial[250]") and problem in info.value.problem, (i, info.value)


def copy_of(data):
    return yaml.safe_load(yaml.safe_dump(data))


def test_libyaml_reads_what_the_python_loader_reads():
    # the config is read through libyaml when there is one: the same data, and a refused text is read again by
    # the pure-Python loader, so that its message (line, column, problem) is the one users always saw
    text = ("a: 010\nb: 0o17\nc: 0x1f\nd: 1_000_000\ne: 1e6\nf: 1:30\ng: .5\nh: [.inf, -.Inf, .nan]\ni: yes\n"
            "j: 2001-12-14\nk: ~\nl: &x {m: [1, 2]}\nn: *x\no: {<<: *x, q: 3}\n")
    text += ("p: !!binary aGVsbG8=\nq: !!set {a, b}\nr: !!omap [{x: 1}, {y: 2}]\ns: !!str 12\nt: '1e3'\nu: 1e3\n"
             "v: -0.0\nw: 1_000.5\nx: &r [*r]\n")
    fast, slow = yamlfile._load_yaml(text), yaml.load(text, Loader=yamlfile._Loader)
    assert repr(fast) == repr(slow)
    plain = yaml.safe_dump({"initial": [{"position": [0.1 * i, -0.0], "velocity": [1e-300, 2.5e10]}
                                        for i in range(50)], "n": [None, True, "yes", 3]})
    assert repr(yamlfile._load_yaml(plain)) == repr(yaml.load(plain, Loader=yamlfile._Loader))
    for bad in ("a: 1\na: 2\n", "a: [1, 2\n", "a: b: c\n", "x: " + "9" * 5000 + "\n"):
        with pytest.raises(ConfigError) as fast_error:
            yamlfile.parse_yaml(bad, "f.yaml")
        try:
            yaml.load(bad, Loader=yamlfile._Loader)
        except yaml.YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            assert f"line {mark.line + 1}, column {mark.column + 1}" in fast_error.value.problem
            assert (getattr(exc, "problem", None) or str(exc).splitlines()[0]) in fast_error.value.problem
        else:
            pytest.fail(bad)


@pytest.mark.long
def test_reading_many_explicit_states_sets_off_no_garbage_collection(tmp_path):
    """A list of 10 000 states is ~90 000 YAML values and none of them garbage, yet each few hundred set off a
    collection of the cycle collector (0.62 of the 0.65 s CPU of rbx.load): it is held off while a config is read
    and validated, and is back as it was after (what it held off done in one collection), also after an error."""
    import gc

    import rbx
    rng = np.random.default_rng(0)
    states = [{"position": [float(x), float(y)], "velocity": [1.0, float(v)]}
              for x, y, v in rng.uniform(0.2, 0.8, (10_000, 3))]
    data = {"table": {"kind": "rectangle", "width": 2.0, "height": 1.0},
            "boundary": {"default": {"rule": "constant", "rank": 0}}, "ball": {"radius": 0.1},
            "initial": states, "run": {"collisions": 1}, "output": {"record": []}}
    path = tmp_path / "states.yaml"
    path.write_text(yaml.safe_dump(data, default_flow_style=None))
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({**data, "ball": {"radius": -1}}, default_flow_style=None))
    collections = []

    def count(phase, info):
        if phase == "start":
            collections.append(info["generation"])
    rbx.load(path)                      # the first load imports what it needs (imports collect)
    gc.collect()
    gc.callbacks.append(count)
    try:
        exp = rbx.load(path)
        assert exp.run.trajectories == 10_000 and gc.isenabled()
        assert rbx.load(data).run.trajectories == 10_000 and gc.isenabled()
        with pytest.raises(ConfigError, match="ball.radius"):
            rbx.load(bad)
        assert gc.isenabled()
        assert len(collections) <= 3    # one each at most, when the collector comes back (it was 1 100 in all)
        gc.disable()                    # a caller that holds the collector off keeps it off
        try:
            rbx.load(path)
            assert not gc.isenabled()
        finally:
            gc.enable()
    finally:
        gc.callbacks.remove(count)


# ---- a file of another kind where a config is expected ------------------------------------------------------------

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.mark.parametrize("path,problem", [
    ("configs/studies/lyapunov-sinai.yaml", "is a study (base, vary, measure), not an experiment config: run it "
                                            "with rbx sweep"),
    ("configs/tables/circle.yaml", "is a table file (kind), not an experiment config: name it in a config's table:"),
    ("configs/boundary/rough2d.yaml", "is a boundary file (default, walls), not an experiment config: name it in a "
                                      "config's boundary:"),
])
def test_a_file_of_another_kind_given_as_a_config_says_what_it_is(path, problem):
    """A study, a table file or a boundary file given where an experiment config is expected: the message names the
    kind of file and what to do with it (it named the first key as unknown)."""
    with pytest.raises(ConfigError) as info:
        config.load(os.path.join(ROOT, path))
    assert info.value.key is None and info.value.problem == problem


def test_a_config_named_as_a_table_or_given_as_a_study_says_what_it_is(tmp_path):
    from rbx.study import load_study
    example = os.path.join(ROOT, "configs", "examples", "sinai.yaml")
    with pytest.raises(ConfigError) as info:
        load_study(example)
    assert info.value.file == example and info.value.problem == (
        "is an experiment config (table, boundary, ball, initial), not a study: run it with rbx simulate, or name it "
        "in a study's base:")
    (tmp_path / "exp.yaml").write_text(f"table: {example}\nboundary: {{default: {{rule: constant, rank: 1}}}}\n"
                                       "ball: {radius: 0.1}\ninitial: {position: [0.5, 0.5], velocity: [1, 0]}\n")
    with pytest.raises(ConfigError) as info:
        config.load(tmp_path / "exp.yaml")
    assert info.value.file == example and info.value.problem.startswith(
        "is an experiment config (table, boundary, ball, initial), not a table file")


def test_an_hdf5_file_given_as_a_config_is_named_a_run(tmp_path):
    """A run file (HDF5) where a YAML config is expected: what it is and what to do with it (it said only that it
    is not a text file)."""
    import rbx
    run = tmp_path / "run.h5"
    rbx.simulate(os.path.join(ROOT, "configs", "examples", "circle.yaml"), collisions=5, output=str(run))
    with pytest.raises(ConfigError) as info:
        config.load(run)
    assert info.value.problem == ("is a run file (HDF5), not a YAML file: draw it with rbx plot, continue it with "
                                  "rbx simulate --resume")
    (tmp_path / "binary.yaml").write_bytes(b"\xff\xfe\x00 not text")
    with pytest.raises(ConfigError) as info:
        config.load(tmp_path / "binary.yaml")
    assert info.value.problem == "not a text (UTF-8) file"


def test_a_speed_whose_square_underflows_is_refused_and_a_corridor_flight_is_named():
    """|v| = 1.4e-170 with spin passed the energy check (the spin carries it), then 'ended earlier (no wall ahead)'
    with exit 0: |v|² is 0 in floats. And rbx lyapunov said of a flight along a free corridor that it 'left the
    table'."""
    import warnings

    import rbx
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    circle = os.path.join(root, "configs", "examples", "circle.yaml")
    with pytest.raises(ConfigError, match=r"initial.velocity: too small: \|v\|² = 0 is below 1e-304") as info:
        rbx.load(circle, {"initial.velocity": [1e-170, 1e-170]})
    assert info.value.key == "initial.velocity"
    assert rbx.load(circle, {"initial.velocity": [1e-140, 1e-140]}).initial[0]["velocity"][0] == 1e-140
    # an overflow is named by its part: a spin of 1e200 was refused as initial.velocity
    with pytest.raises(ConfigError, match="initial.angular_velocity: too large: the kinetic energy") as info:
        rbx.load(circle, {"initial.angular_velocity": 1e200})
    assert info.value.key == "initial.angular_velocity"
    with pytest.raises(ConfigError, match="initial.velocity: too large: the kinetic energy"):
        rbx.load(circle, {"initial.velocity": [1e200, 0]})
    with pytest.raises(ConfigError, match=r"initial\[1\].velocity: too small"):
        rbx.load(circle, {"initial": [{"position": [0, 0], "velocity": [1, 0]},
                                      {"position": [0, 0], "velocity": [1e-170, 0]}], "run.trajectories": 2})
    lorentz = os.path.join(root, "configs", "examples", "lorentz.yaml")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        with pytest.raises(ValueError, match="each ended during it .* along a free corridor"):
            rbx.lyapunov(rbx.load(lorentz, {"initial": {"position": [0.5, 0.0], "velocity": [1, 0]},
                                            "run.trajectories": 1}), collisions=100)
