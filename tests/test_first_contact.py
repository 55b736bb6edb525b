"""What a new user met first, through the real API and the real ``rbx`` (subprocesses):

1. changing an experiment: overrides by dotted key (``rbx.load(path, {"ball.inertia": 0.2})``, ``--set
   ball.inertia=0.2``) are validated as the YAML is, an unknown key is refused with a did-you-mean hint, a nested
   mapping is merged, never ignored; κ follows the ball's inertia (``dataclasses.replace(exp.ball, inertia=0.1)``);
   a part changed by hand is validated again (a mapping for the ball is merged or refused, never kept unchecked);
   a config's includes are found from its own folder after it was edited as a mapping;
2. an ensemble of copies of one orbit (one fixed start, several trajectories, no random numbers) is warned about,
   and the diffusion plot of such a run is refused in one line;
3. ``rbx histogram`` never replaces the run ``rbx simulate`` wrote to the same ``output.path`` by default, and
   ``--data`` names its HDF5 file.
"""
import dataclasses
import json
import subprocess
import warnings
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml

import rbx
from tests.test_interrupt import RBX

ROOT = Path(__file__).resolve().parents[1]
STRIP = ROOT / "configs" / "examples" / "strip.yaml"       # the README's first example: a fixed start
#: a random rule for the strip (each trajectory draws from its own stream)
RANDOM = "{default: {rule: random, choices: [{rule: constant, rank: 0}, {rule: constant, rank: 1}], " \
         "probabilities: [0.5, 0.5]}}"


def cli(*args, cwd):
    return subprocess.run([RBX, *map(str, args)], capture_output=True, text=True, cwd=cwd, timeout=600)


def one_line(res):
    """The single line of a refused command (exit 2, nothing else said)."""
    assert res.returncode == 2, (res.returncode, res.stderr)
    assert "Traceback" not in res.stderr and res.stderr.count("\n") == 1, res.stderr
    return res.stderr.rstrip("\n")


def records(run):
    return {f: np.asarray(getattr(run, f)) for f in ("time", "position", "velocity", "angular_velocity")}


def assert_same_records(a, b):
    for f in a:
        np.testing.assert_array_equal(a[f], b[f], err_msg=f)


@pytest.fixture
def strip_inertia(tmp_path):
    """The strip example with inertia 0.2 written in its YAML (its includes beside it): the reference for the
    overrides."""
    for sub in ("tables", "boundary"):
        (tmp_path / sub).mkdir()
    (tmp_path / "tables" / "strip.yaml").write_text((ROOT / "configs/tables/strip.yaml").read_text())
    (tmp_path / "boundary" / "hemisphere.yaml").write_text((ROOT / "configs/boundary/hemisphere.yaml").read_text())
    (tmp_path / "configs").mkdir()
    path = tmp_path / "configs" / "strip.yaml"
    path.write_text(STRIP.read_text().replace("inertia: uniform", "inertia: 0.2"))
    return path


# ---- 1. changing an experiment ------------------------------------------------------------------------------------

def test_a_dotted_override_runs_the_physics_the_yaml_would(strip_inertia):
    reference = rbx.simulate(rbx.load(strip_inertia), collisions=200)
    assert reference.kappa == 0.2
    for exp in (rbx.load(STRIP, {"ball.inertia": 0.2}), rbx.load(STRIP, overrides={"ball.inertia": 0.2}),
                rbx.load(rbx.load(STRIP), {"ball.inertia": 0.2}),
                rbx.load(STRIP, {"ball": {"inertia": 0.2}})):          # a nested mapping: merged, not ignored
        assert exp.ball.kappa == 0.2 and exp.ball.radius == 0.1 and exp.resolved["ball"]["inertia"] == 0.2
        run = rbx.simulate(exp, collisions=200)
        assert run.kappa == 0.2
        assert_same_records(records(run), records(reference))
    # the short names of the run settings still work, as do simulate's keywords
    with pytest.warns(RuntimeWarning, match="the seed changes nothing"):        # the strip draws no numbers
        assert rbx.load(STRIP, {"collisions": 7, "run.seed": 3}).run == rbx.model.RunSettings(7, 1, 3)
    assert rbx.simulate(STRIP, collisions=20).records == 21


def test_an_override_is_checked_as_the_yaml_is(strip_inertia):
    with pytest.raises(rbx.ConfigError) as info:
        rbx.load(STRIP, {"colisions": 7})
    assert info.value.key == "colisions" and "did you mean 'run.collisions'?" in str(info.value)
    with pytest.raises(rbx.ConfigError, match="run.colisions: unknown key .did you mean 'run.collisions'"):
        rbx.load(STRIP, {"run.colisions": 7})
    with pytest.raises(rbx.ConfigError, match="did you mean 'ball.inertia'"):
        rbx.load(STRIP, {"inertia": 0.2})
    # the value: the message of the same value in the YAML, and which override set it
    bad = strip_inertia.with_name("bad.yaml")
    bad.write_text(strip_inertia.read_text().replace("inertia: 0.2", "inertia: 2"))
    with pytest.raises(rbx.ConfigError) as in_yaml:
        rbx.load(bad)
    with pytest.raises(rbx.ConfigError) as as_override:
        rbx.load(STRIP, {"ball.inertia": 2})
    assert as_override.value.key == in_yaml.value.key == "ball.inertia"
    assert as_override.value.problem.startswith(in_yaml.value.problem)
    with pytest.raises(rbx.ConfigError, match="ball: expected a mapping"):
        rbx.load(STRIP, {"ball": 3})
    with pytest.raises(rbx.ConfigError, match="set twice"):
        rbx.load(STRIP, {"ball": {"radius": 0.1}, "ball.inertia": 0.3})


def test_a_fixed_start_given_whole_replaces_a_sampled_one():
    """``initial`` given as a mapping with a fixed start's keys, for a config whose start is sampled, replaces
    the sampled start (its keys mean nothing to a sampler); the reverse keeps working. A single key of a fixed start
    given for a sampled one is refused with how to give the start whole."""
    lorentz = ROOT / "configs" / "examples" / "lorentz.yaml"         # initial: {sample: billiard}
    start = {"position": [0.5, 0.0], "velocity": [0.6, 0.8], "angular_velocity": 0.3}
    exp = rbx.load(lorentz, {"initial": start, "run.trajectories": 1})
    assert len(exp.initial) == 1 and exp.initial[0]["position"].tolist() == [0.5, 0.0]
    assert exp.initial[0]["angular_velocity"] == 0.3
    assert rbx.load(STRIP, {"initial": {"sample": "billiard"}}).to_dict()["initial"] == {"sample": "billiard"}
    with pytest.raises(rbx.ConfigError) as info:
        rbx.load(lorentz, {"initial.position": [0.5, 0.0]})
    assert info.value.key == "initial.position"
    assert "a sampled start (initial: {sample: …}) has no position; a fixed start replaces it when given whole" \
        in info.value.problem, info.value.problem


def test_kappa_follows_the_inertia_and_a_changed_part_is_validated(strip_inertia):
    exp = rbx.load(STRIP)
    ball = dataclasses.replace(exp.ball, inertia=0.1)
    assert ball.kappa == 0.1
    reference = records(rbx.simulate(rbx.load(STRIP, {"ball.inertia": 0.1}), collisions=200))
    for changed in (exp.replace(ball=ball), dataclasses.replace(exp, ball=ball), exp.replace(ball={"inertia": 0.1})):
        assert changed.ball.kappa == 0.1 and changed.resolved["ball"] == {"radius": 0.1, "inertia": 0.1}
        run = rbx.simulate(changed, collisions=200)
        assert run.kappa == 0.1
        assert_same_records(records(run), reference)
    assert exp.ball.kappa == 0.5 and exp.resolved["ball"]["inertia"] == "uniform"     # the original: unchanged
    # what the validator refuses in a YAML it refuses in a changed part, naming the key; never an AttributeError
    with pytest.raises(rbx.ConfigError, match="ball.inertia: must be ≤ 1, got 7"):
        exp.replace(ball={"inertia": 7})
    with pytest.raises(rbx.ConfigError, match="^ball: expected an rbx.model.Ball"):
        dataclasses.replace(exp, ball=[0.1, 0.2])
    with pytest.raises(rbx.ConfigError, match="ball.inertia"):
        dataclasses.replace(exp.ball, inertia=-1)
    with pytest.raises(rbx.ConfigError, match="^dimension: is derived"):
        exp.replace(dimension=3)
    with pytest.raises(rbx.ConfigError, match="initial.position"):       # a start outside the shrunk strip
        exp.replace(initial={"position": [0.0, 2.0]})
    with pytest.raises(rbx.ConfigError, match="ball.radius"):             # the ball must still fit the strip
        exp.replace(ball=dataclasses.replace(exp.ball, radius=0.6))


def test_a_file_of_a_changed_experiment_records_what_ran(tmp_path):
    exp = rbx.load(STRIP).replace(ball=dataclasses.replace(rbx.load(STRIP).ball, inertia=0.3))
    run = rbx.simulate(exp, collisions=50, output=tmp_path / "r.h5")
    assert run.kappa == 0.3 and run.config["ball"]["inertia"] == 0.3
    assert run.experiment.ball.kappa == 0.3


def test_a_loaded_experiments_starts_cannot_be_edited_in_place():
    """``exp.initial[0]["angular_velocity"] = 5.0`` was kept and shown while the run used the start it was loaded
    with (−2). The states are read-only now, like the rest of the experiment; ``replace`` is the way to change one,
    and is checked and run."""
    exp = rbx.load(str(ROOT / "configs" / "examples" / "circle.yaml"))
    with pytest.raises(TypeError):
        exp.initial[0]["angular_velocity"] = 5.0
    with pytest.raises(ValueError):
        exp.initial[0]["position"][0] = 5.0
    assert rbx.simulate(exp, collisions=5).angular_velocity[0][0] == exp.initial[0]["angular_velocity"]
    spun = exp.replace(initial=[{**exp.initial[0], "angular_velocity": 5.0}])
    assert rbx.simulate(spun, collisions=5).angular_velocity[0][0] == 5.0
    with pytest.raises(rbx.ConfigError, match="initial"):
        exp.replace(initial=[{**exp.initial[0], "position": [5.0, 5.0]}])


def test_an_edited_config_mapping_finds_its_includes(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)                  # another folder than the config's
    data = yaml.safe_load(STRIP.read_text())     # table: ../tables/strip.yaml, relative to the config's folder
    data["ball"]["inertia"] = 0.2
    with pytest.raises(rbx.ConfigError, match="file not found.*base="):
        rbx.load(data)
    for exp in (rbx.load(data, base=STRIP), rbx.load(data, base=STRIP.parent)):
        assert exp.table_kind == "strip" and exp.ball.kappa == 0.2
        assert exp.output.path == str((ROOT / "runs" / "strip.h5").resolve())
    # a loaded experiment's own mapping: includes inlined, paths absolute, loads from anywhere
    edited = rbx.load(STRIP).to_dict()
    edited["ball"]["inertia"] = 0.2
    assert rbx.load(edited).ball.kappa == 0.2
    assert rbx.load(STRIP).resolved["ball"]["inertia"] == "uniform"      # the copy was edited, not the experiment


@pytest.mark.long
def test_set_on_the_command_line(strip_inertia, tmp_path):
    reference = records(rbx.simulate(rbx.load(strip_inertia), collisions=100))
    res = cli("simulate", STRIP, "-o", "a.h5", "--collisions", 100, "--set", "ball.inertia=0.2",
              "--set", "initial.position=[0, 0.5]", "--quiet", cwd=tmp_path)
    assert res.returncode == 0 and res.stderr == "", res.stderr
    run = rbx.open(tmp_path / "a.h5")
    assert run.kappa == 0.2 and run.config["ball"]["inertia"] == 0.2
    assert_same_records(records(run), reference)
    # an unknown key, a value the YAML would refuse: one line naming the config, the key and the problem
    line = one_line(cli("simulate", STRIP, "-o", "b.h5", "--set", "run.colisions=7", cwd=tmp_path))
    assert line.startswith("rbx: ") and line.endswith(
        "strip.yaml: run.colisions: unknown key (did you mean 'run.collisions'?)"), line
    line = one_line(cli("simulate", STRIP, "-o", "b.h5", "--set", "ball.inertia=2", cwd=tmp_path))
    assert "strip.yaml: ball.inertia: must be ≤ 1, got 2" in line, line
    assert not (tmp_path / "b.h5").exists()
    # the other commands that read a config take it too
    res = cli("lyapunov", STRIP, "--collisions", 300, "--set", "ball.inertia=0.3", "--json", cwd=tmp_path)
    assert res.returncode == 0 and "κ = 0.3" in json.loads(res.stdout)["title"], res.stderr
    line = one_line(cli("lyapunov", STRIP, "--set", "ball.inertai=0.3", cwd=tmp_path))
    assert "ball.inertai: unknown key (did you mean 'ball.inertia'?)" in line, line
    conf = histogram_config(tmp_path)
    res = cli("histogram", conf, "-o", "h.png", "--set", "run.trajectories=200", "--set", "ball.inertia=shell",
              cwd=tmp_path)
    assert res.returncode == 0 and "200 samples" in res.stdout, res.stderr
    with h5py.File(tmp_path / "returns.h5") as f:
        assert f.attrs["kappa"] == 1.0 and len(f["returns/initial_angle"]) == 200


# ---- 2. an ensemble of one orbit ---------------------------------------------------------------------------------

@pytest.mark.long
def test_copies_of_one_orbit_are_warned_about_and_their_diffusion_refused(tmp_path):
    res = cli("simulate", STRIP, "-o", "same.h5", "--collisions", 2000, "--trajectories", 4, "--quiet", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert res.stderr.startswith("rbx: warning: --trajectories: the 4 trajectories all start from the same state")
    assert "copies of one orbit" in res.stderr and res.stderr.count("\n") == 1, res.stderr
    line = one_line(cli("plot", "same.h5", "--kind", "diffusion", cwd=tmp_path))
    assert line.startswith("rbx: same.h5: --kind diffusion: the 4 trajectories are copies of one orbit"), line
    assert not (tmp_path / "same_diffusion.png").exists()
    # a random rule: the same start is a real ensemble (each trajectory draws its own numbers): nothing to say
    res = cli("simulate", STRIP, "-o", "random.h5", "--collisions", 2000, "--trajectories", 4,
              "--set", f"boundary={RANDOM}", "--quiet", cwd=tmp_path)
    assert res.returncode == 0 and res.stderr == "", res.stderr
    res = cli("plot", "random.h5", "--kind", "diffusion", "--quiet", cwd=tmp_path)
    assert res.returncode == 0 and res.stderr == "", res.stderr
    assert (tmp_path / "random_diffusion.png").stat().st_size > 10_000


@pytest.mark.long
def test_the_api_warns_of_copies_of_one_orbit(tmp_path):
    with pytest.warns(RuntimeWarning, match="the 3 trajectories all start from the same state"):
        rbx.simulate(STRIP, collisions=20, trajectories=3)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rbx.simulate(STRIP, collisions=20)                                               # one trajectory
        rbx.simulate(rbx.load(STRIP, {"boundary": yaml.safe_load(RANDOM)}), collisions=20, trajectories=3)
    from rbx.ensembles import repeated_orbits
    assert repeated_orbits(rbx.load(STRIP, {"initial": [
        {"position": [0, 0.5], "velocity": [0.6, 0.8]}, {"position": [0, 0.5], "velocity": [0.6, 0.8]},
        {"position": [0, 0.4], "velocity": [0.6, 0.8]}]})).startswith("only 2 of the 3 trajectories")
    # the CLI names the key to change: the list of starts, not run.trajectories (which the user never set)
    res = cli("simulate", STRIP, "-o", "twice.h5", "--collisions", 50, "--quiet", "--set",
              "initial=[{position: [0, 0.5], velocity: [0.6, 0.8]}, {position: [0, 0.5], velocity: [0.6, 0.8]}]",
              cwd=tmp_path)
    assert res.returncode == 0 and res.stderr.startswith("rbx: warning: ") and ": initial: " in res.stderr and \
        "run.trajectories" not in res.stderr, res.stderr


@pytest.mark.long
def test_a_seed_that_nothing_uses_is_warned_about(tmp_path):
    """--seed (or --set run.seed) on a run that draws no random numbers (a fixed start, no random rule) changes
    nothing: one warning line, as for copies of one orbit; a run that draws numbers says nothing."""
    circle = ROOT / "configs" / "examples" / "circle.yaml"
    res = cli("simulate", circle, "-o", "t.h5", "--seed", 5, "--collisions", 100, "--quiet", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert res.stderr == ("rbx: warning: --seed: nothing in this run draws random numbers (a fixed start, no random "
                          "rule): the seed changes nothing\n"), res.stderr
    res = cli("lyapunov", circle, "--set", "run.seed=5", "--collisions", 200, "--quiet", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert res.stderr.startswith("rbx: warning: --set run.seed: nothing in this run draws random numbers"), res.stderr
    res = cli("simulate", STRIP, "-o", "random.h5", "--collisions", 100, "--seed", 5,
              "--set", f"boundary={RANDOM}", "--quiet", cwd=tmp_path)
    assert res.returncode == 0 and res.stderr == "", res.stderr


def test_the_api_warns_of_a_seed_that_nothing_uses():
    with pytest.warns(RuntimeWarning, match="strip.yaml: seed: nothing in this run draws random numbers"):
        rbx.simulate(STRIP, collisions=20, seed=5)
    with pytest.warns(RuntimeWarning, match="strip.yaml: run.seed: .*the seed changes nothing"):
        rbx.load(STRIP, {"run.seed": 5})             # named as the key was given
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rbx.simulate(STRIP, collisions=20)                                        # no seed given
        rbx.simulate(rbx.load(STRIP, {"boundary": yaml.safe_load(RANDOM)}), collisions=20, seed=5)


# ---- 3. rbx histogram and rbx simulate share output.path --------------------------------------------------------

def histogram_config(folder):
    path = Path(folder) / "h.yaml"
    path.write_text("table: {kind: rectangle, width: 2.0, height: 1.0}\n"
                    "boundary: {default: {rule: constant, rank: 1}}\n"
                    "ball: {radius: 0.1}\n"
                    "initial: {sample: billiard, wall: bottom}\n"
                    "run: {collisions: 300, trajectories: 400, seed: 2}\n"
                    "output: {path: returns.h5}\n")
    return path


@pytest.mark.long
def test_histogram_never_replaces_the_simulation_by_default_and_data_names_its_file(tmp_path):
    conf = histogram_config(tmp_path)
    assert cli("simulate", conf, "--collisions", 30, "--quiet", cwd=tmp_path).returncode == 0
    before = (tmp_path / "returns.h5").read_bytes()
    refusal = ("rbx: returns.h5: is a run file of rbx simulate: remove it if it is not needed; give the return "
               "angles another name (--data)")
    assert one_line(cli("histogram", conf, "-o", "fig.png", "--force", cwd=tmp_path)) == refusal
    # named with --data too (it was replaced then, as rbx sweep never replaces a run)
    assert one_line(cli("histogram", conf, "-o", "fig.png", "--data", "returns.h5", "--force", cwd=tmp_path)) == \
        refusal
    assert (tmp_path / "returns.h5").read_bytes() == before and not (tmp_path / "fig.png").exists()
    res = cli("histogram", conf, "-o", "fig.png", "--data", "angles.h5", "--quiet", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert (tmp_path / "returns.h5").read_bytes() == before
    assert rbx.open(tmp_path / "returns.h5").records == 31          # the simulation, intact
    with h5py.File(tmp_path / "angles.h5") as f:
        assert len(f["returns/initial_angle"]) == 400 and "collisions" not in f
    # --data names an existing file: replaced only with --force, as every output
    line = one_line(cli("histogram", conf, "-o", "fig.png", "--data", "angles.h5", cwd=tmp_path))
    assert line == "rbx: angles.h5: exists; use --force to overwrite it", line
    # never the config itself
    line = one_line(cli("histogram", conf, "--data", "h.yaml", "--force", cwd=tmp_path))
    assert "h.yaml is the config file itself" in line, line
    # nor, the other way round, the return angles replaced by a run
    line = one_line(cli("simulate", conf, "-o", "angles.h5", "--force", cwd=tmp_path))
    assert line == ("rbx: angles.h5: is the return angles of rbx histogram: remove it if it is not needed; give this "
                    "run's output another name"), line


@pytest.mark.long
def test_lyapunov_of_copies_of_one_orbit_gives_one_orbit_and_no_interval(tmp_path):
    """rbx lyapunov on the circle example's fixed start (a deterministic rule) with 5 trajectories: after the
    warning, the regular share is one orbit's verdict, with no Wilson interval computed from 5 copies of it."""
    res = cli("lyapunov", ROOT / "configs" / "examples" / "circle.yaml", "--trajectories", "5", "--collisions",
              "2000", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert "5 copies of one orbit" in res.stderr
    line = [x for x in res.stdout.splitlines() if x.startswith("regular orbits")]
    assert len(line) == 1 and "one orbit, run as 5 copies: regular (own λ1 = " in line[0], res.stdout
    assert "Wilson" not in res.stdout and "share 1.000" not in res.stdout, res.stdout
    # and the JSON object gives no share either, saying why
    res = cli("lyapunov", ROOT / "configs" / "examples" / "circle.yaml", "--trajectories", "5", "--collisions",
              "2000", "--json", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    share = json.loads(res.stdout)["regular_share"]
    assert share["share"] is None and share["low"] is None and share["copies_of_one_orbit"] is True, share


def test_the_readmes_override_example_changes_one_orbit_without_copying_it():
    """The README's override example was 10 copies of the strip's one orbit (a fixed start, no random rule)."""
    import ast
    import re
    from rbx.ensembles import repeated_orbits
    text = " ".join((ROOT / "README.md").read_text().split())
    found = re.search(r'give overrides by dotted key: `rbx\.load\("([^"]+)", (\{[^`]*\})\)`', text)
    exp = rbx.load(ROOT / found.group(1), ast.literal_eval(found.group(2)))
    assert repeated_orbits(exp) is None
    assert exp.ball.inertia == 0.2
