"""A twenty-second round: values edited by hand into files rbx wrote and kept as if rbx had written them (a return
path removed from a finished point of a study, a run's requested length changed). Each is refused now, in one line
naming the variable; each test was seen to fail on the code before it."""
import math
import os
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml

import rbx
from tests.test_reliability8 import cli
from tests.test_reliability9 import INTERRUPT
from tests.test_reliability10 import _config
from tests.test_sweep import as_unfinished, edit_point

EXAMPLES = Path(__file__).resolve().parents[1] / "configs" / "examples"

RETURNS = {"table": {"kind": "rectangle", "width": 2.0, "height": 1.0},
           "boundary": {"default": {"rule": "constant", "rank": 1}, "walls": {"left": {"rule": "exit"}}},
           "ball": {"radius": 0.1, "inertia": 0.5}, "initial": {"sample": "billiard", "wall": "left"},
           "run": {"collisions": 100, "trajectories": 10}, "output": {"record": []}}


def _return_study(folder, collisions, measure="return_path"):
    """A study of the rough rectangle's returns to its left wall (a hole for the return path; a wall for the return
    angles) at two inertias -> (study file, results file)."""
    table = dict(RETURNS) if measure == "return_path" else {**RETURNS, "boundary": {"default": RETURNS["boundary"][
        "default"]}}
    (folder / "table.yaml").write_text(yaml.safe_dump(table, sort_keys=False))
    (folder / "study.yaml").write_text(yaml.safe_dump(
        {"base": "table.yaml", "vary": {"ball.inertia": [0.2, 0.5]}, "measure": [measure],
         "ensemble": {"trajectories": 200, "collisions": collisions, "seed": 3}}, sort_keys=False))
    rbx.sweep(str(folder / "study.yaml"), str(folder / "r.nc"))
    return folder / "study.yaml", folder / "r.nc"


@pytest.mark.long
@pytest.mark.parametrize("variable", ["return_path", "return_path_stderr", "return_angle_ks"])
def test_a_return_value_removed_by_hand_where_every_orbit_returned_is_refused(tmp_path, variable):
    """A NaN written into a finished point's `return_path` (or its error) was kept by `rbx sweep --resume` and
    drawn as a point without a value, with a warning that blamed orbits that had not returned, where the file
    itself said every one had (`return_path_unreturned` 0). The figure and the resume refuse it now."""
    from rbx.cli.common import UserError
    from rbx.cli.sweep import open_results
    study, good = _return_study(tmp_path, 20_000, variable.removesuffix("_stderr"))
    with h5py.File(good, "r") as f:
        if variable == "return_angle_ks":
            assert f["return_angle_ks_returned"][()].tolist() == [1.0, 1.0]
        else:
            assert f["return_path_unreturned"][()].tolist() == [0.0, 0.0]
    open_results(str(good))                          # as written: read
    with h5py.File(good, "r+") as f:
        a = f[variable][()]
        a[1] = math.nan
        f[variable][...] = a
    said = "every sample returned" if variable == "return_angle_ks" else "every trajectory returned"
    words = f"{variable}: is NaN at 1 of the points marked done where the file says {said} (the first: " \
            "ball.inertia = 0.5)"
    with pytest.raises(UserError) as info:
        open_results(str(good))
    assert words in str(info.value)
    res = cli("", "plot", "r.nc", "--kind", "sweep", "-o", "f.png", cwd=tmp_path)
    assert res.returncode == 2 and res.stderr.count("\n") == 1 and words in res.stderr, res.stderr
    assert not (tmp_path / "f.png").exists()
    as_unfinished(good, tmp_path / "r.nc.partial")
    res = cli("", "sweep", "study.yaml", "-o", "r.nc", "--resume", "--quiet", cwd=tmp_path)
    assert res.returncode == 2 and res.stderr.count("\n") == 1 and words in res.stderr, res.stderr


@pytest.mark.long
def test_a_return_path_without_a_value_where_orbits_had_not_returned_is_read(tmp_path):
    """The legitimate NaN: a run too short for every orbit to return has no return path, and says why."""
    from rbx.cli.sweep import open_results
    _, path = _return_study(tmp_path, 2)
    ds = open_results(str(path))
    assert np.all(np.isnan(ds["return_path"].values)) and np.all(ds["return_path_unreturned"].values > 0)


@pytest.mark.long
@pytest.mark.parametrize("value", [10**12, -1, 2.5])
def test_a_requested_length_edited_by_hand_is_refused(tmp_path, value):
    """A run file's `collisions_requested` was never checked: edited, it was shown as the run's, and a resume left
    it as it was. It is the stored config's `run.collisions` (a resume never changes it): a file where it is not is
    refused by the reader, the plots and the resume in one line."""
    conf = _config(tmp_path)
    res = cli(INTERRUPT, "simulate", str(conf), "-o", "s.h5", "--quiet", cwd=tmp_path)
    assert res.returncode == 130, res.stderr
    shutil.copy(tmp_path / "s.h5", tmp_path / "kept.h5")
    rbx.open(str(tmp_path / "s.h5"))                 # as written: read
    with h5py.File(tmp_path / "s.h5", "r+") as f:
        requested = int(f.attrs["collisions_requested"])
        f.attrs["collisions_requested"] = value
    assert requested != value
    words = f"s.h5: collisions_requested: is {value!r}, where the stored config's run.collisions is {requested}"
    with pytest.raises(rbx.FileError, match="collisions_requested: is "):
        rbx.open(str(tmp_path / "s.h5"))
    for args in (("plot", "s.h5", "--kind", "orbit", "-o", "o.png"), ("simulate", "--resume", "s.h5", "--quiet")):
        res = cli("", *args, cwd=tmp_path)
        assert res.returncode == 2 and res.stderr.count("\n") == 1 and words in res.stderr, (args, res.stderr)
    res = cli("", "simulate", "--resume", "kept.h5", "--quiet", cwd=tmp_path)     # the file as rbx wrote it
    assert res.returncode == 0, res.stderr
    with h5py.File(tmp_path / "kept.h5", "r") as f:
        assert f.attrs["complete"] and int(f.attrs["collisions_requested"]) == requested


@pytest.mark.long
@pytest.mark.parametrize("key,value", [("kappa", 9.0), ("radius", 0.3), ("table_kind", "stadium")])
def test_an_attribute_written_with_the_run_that_its_config_contradicts_is_refused(tmp_path, key, value):
    """`kappa` set to 9 in a run file whose stored config gives 0.5: `rbx plot --kind birkhoff` coloured the spin
    share with κ = 9 under a title saying κ = 0.5 (exit 0), and `rbx.open` returned 9. The reader checks the
    radius, κ and table kind written with the run against its stored config, as the resume did."""
    conf = _config(tmp_path)
    res = cli("", "simulate", str(conf), "-o", "s.h5", "--quiet", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    with h5py.File(tmp_path / "s.h5", "r+") as f:
        f.attrs[key] = value
    with pytest.raises(rbx.FileError, match=f"config: {key}: is .* but the run was made with {value!r}"):
        rbx.open(str(tmp_path / "s.h5"))
    res = cli("", "plot", "s.h5", "--kind", "birkhoff", "-o", "b.png", cwd=tmp_path)
    assert res.returncode == 2 and res.stderr.count("\n") == 1, res.stderr
    assert f"s.h5: config: {key}: is " in res.stderr and not (tmp_path / "b.png").exists(), res.stderr


@pytest.fixture(scope="module")
def returns_file(tmp_path_factory):
    """A return-angle file as `rbx histogram --data` writes it."""
    folder = tmp_path_factory.mktemp("returns")
    conf = _config(folder)
    res = cli("", "histogram", str(conf), "-o", "h.png", "--data", "h.h5", "--quiet", cwd=folder)
    assert res.returncode == 0, res.stderr
    return folder / "h.h5"


@pytest.mark.long
@pytest.mark.parametrize("where,value,words", [
    ("returns@samples", 10**6, "returns@samples: is 1000000, not returned + not_returned"),
    ("returns@velocity_dimension", 2, "returns@velocity_dimension: is 2; in 2D it is 3"),
    ("returns@wall", "top", "returns@wall: is 'top', where the stored config samples on "),
    ("returns/angle", 3.0, "returns/angle: holds angles outside [0, π/2]"),
    ("returns/collisions", 10**9, "returns/collisions: holds counts outside 1 … "),
    ("@kappa", 0.9, "config: kappa: is 0.5 but the run was made with 0.9")])
def test_a_return_angle_file_whose_numbers_contradict_each_other_is_refused(returns_file, tmp_path, where, value,
                                                                            words):
    """Return-angle files edited by hand were read whole: 5000 samples of which 2000 had angles passed the figure's
    'every sample returned', angles of 3 rad were drawn, and a velocity dimension of 2 failed the KS test against
    the wrong law. Each number is now checked against the others and the stored config when the file is read."""
    from rbx.reader import read_returns
    read_returns(returns_file)                      # as written: read
    bad = tmp_path / "bad.h5"
    shutil.copy(returns_file, bad)
    group, _, name = where.rpartition("@") if "@" in where else (where.rpartition("/")[0], "", where)
    with h5py.File(bad, "r+") as f:
        if "@" in where:
            (f[group] if group else f).attrs[name] = value
        else:
            a = f[where][()]
            a[0] = value
            f[where][...] = a
    with pytest.raises(rbx.FileError) as info:
        read_returns(bad)
    assert words in str(info.value), str(info.value)


@pytest.mark.long
def test_a_return_path_where_the_file_says_orbits_had_not_returned_is_refused(tmp_path):
    """The converse hand edit: `return_path_unreturned` set to 0.5 at a point with a value (every orbit had
    returned) was kept by the resume and drawn."""
    from rbx.cli.common import UserError
    from rbx.cli.sweep import open_results
    _, path = _return_study(tmp_path, 20_000)
    edit_point(path, "return_path_unreturned", 0.5)
    with pytest.raises(UserError) as info:
        open_results(str(path))
    assert "return_path: is a number at 1 of the points marked done where the file says some trajectory had not " \
           "returned or the ensemble has one trajectory (the first: ball.inertia = 0.5)" in str(info.value)


def test_a_return_path_study_of_one_trajectory_a_point_is_read(tmp_path):
    """One trajectory a point that returned: no mean with an error, so no value, though every trajectory returned.
    The check that a value is where the file says there is one took that NaN for a value removed by hand and
    refused the study's own results: the file says one trajectory a point, and the NaN is read."""
    from rbx.cli.sweep import open_results
    (tmp_path / "table.yaml").write_text(yaml.safe_dump(RETURNS, sort_keys=False))
    (tmp_path / "study.yaml").write_text(yaml.safe_dump(
        {"base": "table.yaml", "vary": {"ball.inertia": [0.2, 0.5]}, "measure": ["return_path"],
         "ensemble": {"trajectories": 1, "collisions": 20_000, "seed": 3}}, sort_keys=False))
    with pytest.warns(Warning):
        rbx.sweep(str(tmp_path / "study.yaml"), str(tmp_path / "r.nc"))
    with h5py.File(tmp_path / "r.nc", "r") as f:
        assert f["return_path_unreturned"][()].tolist() == [0.0, 0.0]
        assert np.isnan(f["return_path"][()]).all()
    open_results(str(tmp_path / "r.nc"))
    res = cli("", "plot", "r.nc", "--kind", "sweep", "-o", "f.png", cwd=tmp_path)
    assert res.returncode == 0, res.stderr


def test_a_path_with_a_nul_character_is_one_line_not_a_traceback(tmp_path):
    """A NUL character in an output path (YAML, ``--set``) ended `rbx simulate` and `rbx histogram` in a traceback
    from the first system call (``ValueError: embedded null byte``), exit 1, and the API's calls raised that bare
    ValueError: no file name can hold one. One line naming the key, exit 2; rbx's own errors from the API."""
    from rbx.model import ConfigError
    from rbx.paths import FileError
    strip = str(EXAMPLES / "strip.yaml")
    for command in (["simulate", strip], ["histogram", strip, "-o", "h.png"]):
        res = cli("", *command, "--set", 'output.path="a\\0b.h5"', cwd=tmp_path)
        assert res.returncode == 2 and res.stderr.count("\n") == 1 and "Traceback" not in res.stderr, res.stderr
        assert "output.path: holds a NUL character" in res.stderr, res.stderr
    exp = rbx.load(strip)
    study = tmp_path / "s.yaml"
    study.write_text(yaml.safe_dump({"base": strip, "vary": {"ball.inertia": [0.2, 0.5]},
                                     "measure": ["mean_free_path"], "ensemble": {"trajectories": 2, "collisions": 10}}))
    for key, call in (("output", lambda: rbx.simulate(exp, output=str(tmp_path / "a\0b.h5"))),
                      ("output", lambda: rbx.simulate(exp, output=b"a\0b.h5")),
                      ("path", lambda: rbx.open("a\0b.h5")),
                      ("path", lambda: rbx.resume("a\0b.h5")),
                      ("output", lambda: rbx.sweep(str(study), output=str(tmp_path / "r\0.nc")))):
        with pytest.raises(FileError, match=f"{key}: .* holds a NUL character"):
            call()
    for key, call in (("output.path", lambda: rbx.load({**exp.to_dict(), "output": {"path": "a\0b.h5"}})),
                      ("table", lambda: rbx.load({**exp.to_dict(), "table": "t\0.yaml"})),
                      (None, lambda: rbx.load("a\0b.yaml"))):
        with pytest.raises(ConfigError, match="holds a NUL character"):
            call()
    assert not list(tmp_path.glob("*.h5*")) and not list(tmp_path.glob("*.nc*"))


def test_names_that_are_not_utf8_are_written_and_read(tmp_path):
    """A byte such as 0xff in a file name (Latin-1 names, where the system takes any bytes): Python reads it as a
    lone surrogate, which no HDF5 or YAML text holds, so `-o`, a config's name, `--set output.path`, `rbx histogram
    --data`/`-o` and `rbx sweep -o` ended in a UnicodeEncodeError traceback, exit 1, with nothing written. The
    files are now written under their real names, the names stored in them as ``\\xff`` escapes, and every
    message shows them so."""
    strip = EXAMPLES / "strip.yaml"
    odd = tmp_path / "c\udcf3.yaml"                 # the bytes b"c\xf3.yaml"
    odd.write_text(strip.read_text().replace("../", f"{EXAMPLES.parent}/"))
    for args, written in (([str(strip), "-o", "\udcff.h5"], b"\xff.h5"),
                          ([str(odd), "-o", "a.h5"], b"a.h5"),
                          ([str(strip), "--set", f"output.path={tmp_path}/\udcfe.h5"], b"\xfe.h5")):
        res = cli("", "simulate", *args, "--collisions", "50", cwd=tmp_path)
        assert res.returncode == 0, res.stderr
        assert "Traceback" not in res.stderr and "\\udc" not in res.stderr, res.stderr
        with h5py.File(os.path.join(os.fsencode(tmp_path), written), "r") as f:
            assert "\\x" in f.attrs["command"], f.attrs["command"]
            stored = yaml.safe_load(f.attrs["config"])["output"]["path"]
            assert stored.endswith(os.fsdecode(written).encode("utf-8", "surrogateescape")
                                   .decode("utf-8", "backslashreplace")), stored
            assert f["collisions/time"].shape == (1, 51)
    res = cli("", "plot", "\udcff.h5", "--kind", "orbit", "-o", "\udcfd.png", cwd=tmp_path)
    assert res.returncode == 0 and "wrote \\xfd.png" in res.stderr, res.stderr
    res = cli("", "histogram", str(EXAMPLES / "rectangle.yaml"), "--data", "\udcfc.h5", "-o", "\udcfb.png",
              "--set", "run.trajectories=20", "--set", "initial={sample: billiard, wall: left}", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    study = tmp_path / "s.yaml"
    study.write_text(yaml.safe_dump({"base": str(strip), "vary": {"ball.inertia": [0.2, 0.5]},
                                     "measure": ["mean_free_path"], "ensemble": {"trajectories": 2, "collisions": 100}}))
    res = cli("", "sweep", "s.yaml", "-o", "\udcfa.nc", cwd=tmp_path)
    assert res.returncode == 0 and "wrote \\xfa.nc" in res.stderr, res.stderr
    res = cli("", "sweep", "s.yaml", "-o", "\udcfa.nc", "--resume", cwd=tmp_path)
    assert res.returncode == 0 and "nothing to do" in res.stderr, res.stderr
    assert {b"\xff.h5", b"a.h5", b"\xfe.h5", b"\xfd.png", b"\xfc.h5", b"\xfb.png", b"\xfa.nc"} <= set(
        os.listdir(os.fsencode(tmp_path)))
    run = rbx.simulate(rbx.load(str(strip)), collisions=10, output=os.fsencode(tmp_path) + b"/\xf9.h5")
    run.close()
    assert rbx.open(os.fsencode(tmp_path) + b"/\xf9.h5").time.shape == (1, 11)
    with pytest.raises(rbx.FileError, match=r"output: .*'\\ud800', a character that no file name can"):
        rbx.simulate(rbx.load(str(strip)), collisions=10, output=str(tmp_path / "\ud800.h5"))


def test_a_group_linked_into_itself_is_refused_not_walked_for_ever(tmp_path):
    """A crafted run file whose `collisions` group holds a hard link to itself (`f['collisions/loop'] =
    f['collisions']`, 19 kB): `rbx plot` and `rbx.open` walked it for ever at full CPU, and a study's results file so
    edited held `rbx sweep --resume` past SIGTERM. rbx gives each group and dataset one name: a second name is
    refused in one line, exit 2. A dataset under two names (a diamond, not a loop) too."""
    from rbx.cli.common import UserError
    from rbx.cli.sweep import open_results
    run = tmp_path / "q.h5"
    rbx.simulate(rbx.load(str(EXAMPLES / "circle.yaml")), output=str(run)).close()
    for what, edit in (("collisions/loop", lambda f: f.__setitem__("collisions/loop", f["collisions"])),
                       ("collisions/again", lambda f: f.__setitem__("collisions/again", f["collisions/time"]))):
        bad = tmp_path / "bad.h5"
        shutil.copy(run, bad)
        with h5py.File(bad, "r+") as f:
            edit(f)
        with pytest.raises(rbx.FileError, match=r"collisions/\w+: is a second name") as info:
            rbx.open(str(bad))
        assert what in str(info.value) or what == "collisions/again"    # the walk may meet either name first
    res = cli("", "plot", "bad.h5", "--kind", "orbit", "-o", "o.png", cwd=tmp_path)
    assert res.returncode == 2 and res.stderr.count("\n") == 1 and "is a second name" in res.stderr, res.stderr
    _, results = _return_study(tmp_path, 2_000)
    with h5py.File(results, "r+") as f:
        f["g"] = f["/"]
    with pytest.raises(UserError, match="is a second name"):
        open_results(str(results))


def test_a_stopped_resume_does_not_walk_its_results_file_again(tmp_path):
    """SIGTERM while `rbx sweep --resume` checked a results file holding 200 000 groups (edited in): the walk
    stopped, then the line saying what the file keeps read the whole file again (33 s; a hang for ever while a group
    linked into itself was walked). That line now reads only the `done` variable: no second walk after the signal."""
    _, results = _return_study(tmp_path, 2_000)
    prelude = ("import os, signal, rbx.paths as _p\n_real = _p.foreign_object\n"
               "def _walk(*a, **k):\n    import sys\n    sys.stderr.write('WALK\\n')\n"
               "    os.kill(os.getpid(), signal.SIGTERM)\n    return _real(*a, **k)\n_p.foreign_object = _walk\n")
    res = cli(prelude, "sweep", "study.yaml", "-o", results.name, "--resume", cwd=tmp_path)
    assert res.returncode == 143, res.stderr
    assert res.stderr.count("WALK") == 1 and "interrupted by SIGTERM; the file holds all" in res.stderr, res.stderr


def test_a_histogram_killed_while_its_figure_is_drawn_leaves_both_files_as_they_were(tmp_path):
    """`rbx histogram --force` put the new samples in place, then drew the figure (seconds): a SIGKILL meanwhile
    left the new samples beside the previous run's figure, and nothing said so. The figure is now drawn first,
    beside its name; the samples are put in place once it is drawn, then the figure, one rename after the other."""
    import hashlib
    from tests.test_first_contact import histogram_config
    conf = histogram_config(tmp_path)
    args = ["histogram", str(conf), "--data", "r.h5", "-o", "h.png"]
    res = cli("", *args, cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    digest = {name: hashlib.sha256((tmp_path / name).read_bytes()).hexdigest() for name in ("r.h5", "h.png")}
    killer = ("import os, signal, matplotlib.figure as _f\n"
              "def _killed(*a, **k):\n    os.kill(os.getpid(), signal.SIGKILL)\n_f.Figure.savefig = _killed\n")
    res = cli(killer, *args, "--force", "--seed", "7", cwd=tmp_path)
    assert res.returncode == -9, res.stderr
    assert {name: hashlib.sha256((tmp_path / name).read_bytes()).hexdigest() for name in digest} == digest
    res = cli("", *args, "--force", "--seed", "7", cwd=tmp_path)     # and the next run replaces both
    assert res.returncode == 0, res.stderr
    assert all(hashlib.sha256((tmp_path / name).read_bytes()).hexdigest() != digest[name] for name in digest)


@pytest.mark.parametrize("key, value, said", [
    ("config", 5, "config: is int64 5, not YAML text (UTF-8)"),
    ("config", ["a", "b"], "config: is ndarray ['a', 'b'], not YAML text (UTF-8)"),
    ("config", b"\xff\xfe", "config: is str '\\xff\\xfe', not YAML text (UTF-8)"),
    ("schema_version", "one", "schema_version: is str 'one', not a whole number"),
    ("wall_names", [], "wall_names: is ndarray [], not the list of the table's wall names"),
])
def test_a_root_attribute_of_another_kind_is_named_not_called_damage(tmp_path, key, value, said):
    """A root attribute edited to another kind was 'cannot read the HDF5 file (damaged?)' in Python's words
    ("object of type 'numpy.int64' has no len()", "invalid literal for int()"), or blamed on another part of the
    file (an empty `wall_names`: "final/last_wall: names no wall of the table (0 … -1…)"). Each is now named."""
    run = tmp_path / "a.h5"
    rbx.simulate(rbx.load(str(EXAMPLES / "circle.yaml")), collisions=20, output=str(run)).close()
    with h5py.File(run, "r+") as f:
        del f.attrs[key]
        if isinstance(value, bytes):
            f.attrs.create(key, value)          # fixed-length bytes, not UTF-8: h5py hands back lone surrogates
        elif isinstance(value, list) and not value:
            f.attrs[key] = np.array([], dtype=h5py.string_dtype())
        else:
            f.attrs[key] = value
    with pytest.raises(rbx.FileError) as info:
        rbx.open(str(run))
    assert said in str(info.value), str(info.value)
    for args in (["plot", "a.h5", "--kind", "orbit", "-o", "o.png"], ["simulate", "--resume", "a.h5", "-o", "b.h5"]):
        res = cli("", *args, cwd=tmp_path)
        assert res.returncode == 2 and res.stderr == f"rbx: a.h5: {said}: the attribute was changed since rbx " \
                                                     "wrote it\n", res.stderr


def test_a_resume_refuses_a_run_file_with_thousands_of_root_attributes_added(tmp_path):
    """5 000 root attributes added to an interrupted run file (a 0.4 MB edit): `rbx simulate --resume` ran for
    minutes inside HDF5 (each root attribute it changes rewrote a header of them all), deaf to SIGTERM and SIGINT,
    and a SIGKILL left its locks. A resume now takes at most MAX_EXTRA_ATTRS attributes of the user's beside rbx's
    own, and refuses more in one line before anything is written; 64 notes resume as before, and are kept."""
    from rbx.driver import MAX_EXTRA_ATTRS
    conf = _config(tmp_path)
    res = cli(INTERRUPT, "simulate", str(conf), "-o", "s.h5", "--quiet", cwd=tmp_path)
    assert res.returncode == 130, res.stderr
    shutil.copy(tmp_path / "s.h5", tmp_path / "t.h5")
    with h5py.File(tmp_path / "s.h5", "r+") as f:
        for i in range(MAX_EXTRA_ATTRS + 1):
            f.attrs[f"note{i}"] = i
    before = (tmp_path / "s.h5").read_bytes()
    res = cli("", "simulate", "--resume", "s.h5", "-o", "r.h5", cwd=tmp_path)
    assert res.returncode == 2 and res.stderr == (
        f"rbx: s.h5: holds {MAX_EXTRA_ATTRS + 1} root attributes that rbx does not write (the first: note0), more "
        f"than the {MAX_EXTRA_ATTRS} a resume takes: remove them (h5py: del f.attrs[name]) and resume again\n"), \
        res.stderr
    assert (tmp_path / "s.h5").read_bytes() == before and not list(tmp_path.glob("r.h5*"))
    assert not list(tmp_path.glob("*.lock"))
    with h5py.File(tmp_path / "t.h5", "r+") as f:
        for i in range(MAX_EXTRA_ATTRS):
            f.attrs[f"note{i}"] = i
    res = cli("", "simulate", "--resume", "t.h5", "-o", "u.h5", "--quiet", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    with h5py.File(tmp_path / "u.h5", "r") as f:
        assert f.attrs["complete"] and f.attrs[f"note{MAX_EXTRA_ATTRS - 1}"] == MAX_EXTRA_ATTRS - 1


def test_a_signal_whose_keyboardinterrupt_was_lost_still_stops_a_study(tmp_path):
    """Ctrl-C during `rbx sweep --resume` of a results file with 20 000 attributes added: its KeyboardInterrupt was
    raised inside a finaliser (xarray and h5netcdf reading the attributes), where Python drops it, and the study
    ran to the end, exit 0, 4 of 4 times. The signal is on the command's flag: it is now acted on after the next
    point. Here the handler is made to lose every KeyboardInterrupt, and SIGINT sent as the first point is stored."""
    study = tmp_path / "s.yaml"
    study.write_text(yaml.safe_dump({"base": str(EXAMPLES / "strip.yaml"), "vary": {"ball.inertia": [0.2, 0.3, 0.5]},
                                     "measure": ["mean_free_path"], "ensemble": {"trajectories": 2, "collisions": 100}}))
    prelude = ("import os, signal, rbx.api as _a, rbx.sweeping as _s\n"
               "def _lost(self, signum, frame):\n    self.signum = self.signum or signum\n"
               "_a.StopFlag._handler = _lost\n_real = _s._store\n_sent = []\n"
               "def _store(*a, **k):\n    _real(*a, **k)\n    if not _sent:\n        _sent.append(1)\n"
               "        os.kill(os.getpid(), signal.SIGINT)\n_s._store = _store\n")
    res = cli(prelude, "sweep", "s.yaml", "-o", "r.nc", cwd=tmp_path)
    assert res.returncode == 130, res.stderr
    assert "interrupted by SIGINT after 1 of 3 points" in res.stderr, res.stderr
    assert (tmp_path / "r.nc.partial").exists() and not (tmp_path / "r.nc").exists()


def test_a_section_set_whole_around_a_varied_key_is_named(tmp_path):
    """`rbx.sweep(study, sets={"ball": {"radius": 0.05}})` of a study varying ball.inertia was refused as
    "vary.ball.inertia: set twice, as ball and ball.inertia": the line named the study's key, not the one given.
    It now names the --set and says how to give it."""
    study = tmp_path / "s.yaml"
    study.write_text(yaml.safe_dump({"base": str(EXAMPLES / "strip.yaml"), "vary": {"ball.inertia": [0.2, 0.5]},
                                     "measure": ["mean_free_path"], "ensemble": {"trajectories": 2, "collisions": 100}}))
    from rbx.model import ConfigError
    with pytest.raises(ConfigError, match=r"--set ball: gives the section ball whole, and the study varies "
                                          r"ball\.inertia inside it \(vary\.ball\.inertia\): give its keys one by one "
                                          r"\(ball\.radius=…\)"):
        rbx.sweep(str(study), sets={"ball": {"radius": 0.05}})
    res = cli("", "sweep", "s.yaml", "-o", "r.nc", "--set", "ball={radius: 0.05}", cwd=tmp_path)
    assert res.returncode == 2 and res.stderr.count("\n") == 1 and "--set ball: gives the section" in res.stderr
    assert rbx.sweep(str(study), sets={"ball.radius": 0.05})["mean_free_path"].size == 2
