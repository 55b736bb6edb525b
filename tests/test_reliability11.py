"""A twenty-first round: a resume's copy written into a file hard-linked at its `.partial` (another run's live
file), a resume in place of a file with a second name, and files at names rbx uses for a moment (a stale lock set
aside, a figure's record being written) replaced or removed. Each reproduction runs the real command line (or the
figure scripts' own function); each test was seen to fail on the code before it."""
import itertools
import os
import secrets
import shutil
import subprocess
import sys

import h5py
import pytest

from tests.test_reliability8 import HANG, _results, cli
from tests.test_reliability9 import INTERRUPT
from tests.test_reliability10 import _config

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _interrupted(tmp_path, conf, name):
    res = cli(INTERRUPT, "simulate", str(conf), "-o", name, "--quiet", cwd=tmp_path)
    assert res.returncode == 130, res.stderr
    with h5py.File(tmp_path / name, "r") as f:
        assert not f.attrs["complete"]


@pytest.mark.long
def test_a_resume_never_copies_into_a_file_hard_linked_at_its_partial(tmp_path):
    """`rbx simulate --resume s2.h5 --force` with `s2.h5.partial` a hard link to another run's file (a live run's
    `.partial` in the reproduction): the copy of s2.h5 the resume works on was written into that file (shutil's
    copy truncates the name it is given), and the other run's records were gone. Now the name is removed and the
    copy made under a new one: the other file keeps every byte, and s2.h5 is resumed to the end."""
    conf = _config(tmp_path)
    _interrupted(tmp_path, conf, "s2.h5")
    res = cli("", "simulate", str(conf), "-o", "other.h5", "--seed", "7", "--quiet", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    theirs = (tmp_path / "other.h5").read_bytes()
    os.link(tmp_path / "other.h5", tmp_path / "s2.h5.partial")
    res = cli("", "simulate", "--resume", "s2.h5", "--force", "--quiet", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert (tmp_path / "other.h5").read_bytes() == theirs
    with h5py.File(tmp_path / "s2.h5", "r") as f:
        assert f.attrs["complete"] and int(f["final/collisions"][0]) == 2000
    assert not os.path.lexists(tmp_path / "s2.h5.partial")


@pytest.mark.long
@pytest.mark.parametrize("given", ["b.h5.partial", "b.h5"])
def test_a_run_with_a_second_name_is_not_continued_in_place(tmp_path, given):
    """`rbx simulate --resume b.h5.partial` with b.h5.partial a hard link to another run's file (with HDF5's file
    locking off, as on NFS, to a live run's `.partial`: both wrote one file, which neither could read after): it
    was continued in place, so the other name's file changed with it. A file written in place must now have one
    name: one line, exit 2, the other file untouched. (`--resume b.h5`, a copy, never writes the linked file.)"""
    conf = _config(tmp_path)
    _interrupted(tmp_path, conf, "a.h5")
    theirs = (tmp_path / "a.h5").read_bytes()
    os.link(tmp_path / "a.h5", tmp_path / given)
    res = cli("", "simulate", "--resume", given, "--quiet", cwd=tmp_path)
    if given == "b.h5.partial":
        assert res.returncode == 2, (res.returncode, res.stderr)
        assert res.stderr.splitlines() == ["rbx: b.h5.partial: has another name (a hard link): rbx continues a run in "
                                           "place only in a file of one name, which no other run can be writing; "
                                           "resume a copy of it (cp), or remove the other name"], res.stderr
    else:
        assert res.returncode == 0, res.stderr
        with h5py.File(tmp_path / "b.h5", "r") as f:
            assert f.attrs["complete"]
    assert (tmp_path / "a.h5").read_bytes() == theirs


@pytest.mark.long
def test_taking_over_a_stale_lock_replaces_and_removes_nothing_but_the_lock(tmp_path):
    """The stale lock of a killed run was renamed to `OUT.h5.lock.stale.<pid>` (the pid known in advance: a shell
    that `exec`s rbx), replacing the file there, which was then removed; files named like the killed run's scratch
    lock (`OUT.h5.lock.new.<its pid>.*`) were removed too. Now the lock is set aside under a name with a random part
    that is not there, and only scratch names rbx makes are cleared: both files keep their notes."""
    conf = _config(tmp_path)
    killed = subprocess.run([sys.executable, "-c", "import os, rbx.locks\nrbx.locks.acquire_lock('st.h5')\n"
                                                   "print(os.getpid(), flush=True)\nos._exit(9)"],
                            cwd=tmp_path, capture_output=True, text=True, timeout=HANG)
    dead = killed.stdout.strip()
    assert dead.isdigit() and (tmp_path / "st.h5.lock").exists(), killed.stderr
    (tmp_path / f"st.h5.lock.new.{dead}.notes").write_text("mine\n")
    plant = "import os\nopen(f'st.h5.lock.stale.{os.getpid()}', 'w').write('notes\\n')\n"
    res = cli(plant, "simulate", str(conf), "-o", "st.h5", "--quiet", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert "a stale lock" in res.stderr and "was taken over" in res.stderr
    stale = [p for p in tmp_path.iterdir() if p.name.startswith("st.h5.lock.stale.")]
    assert len(stale) == 1 and stale[0].read_text() == "notes\n"
    assert (tmp_path / f"st.h5.lock.new.{dead}.notes").read_text() == "mine\n"
    assert not (tmp_path / "st.h5.lock").exists()


def test_a_figures_record_is_written_under_a_name_of_its_own(tmp_path, monkeypatch):
    """The paper figures' scripts wrote their JSON record to `<figure>.json.<pid>.new` opened exclusively; a file
    already there made the open fail, and the clean-up then removed that file (a traceback, exit 1, the notes gone).
    The scratch name now has a random part, and is removed on a failure only once it is the script's own: a file at
    the name drawn is passed over for the next, and a record that fails to write leaves nothing."""
    sys.path.insert(0, os.path.join(ROOT, "scripts"))
    try:
        import figlib
    finally:
        sys.path.pop(0)
    monkeypatch.chdir(tmp_path)
    record = tmp_path / "c.json"
    old_style = tmp_path / f"c.json.{os.getpid()}.new"
    drawn = tmp_path / "c.json.deadbeef.new"
    for planted in (old_style, drawn):
        planted.write_text("notes\n")
    tokens = itertools.chain(["deadbeef"], itertools.repeat("0badcafe"))
    monkeypatch.setattr(secrets, "token_hex", lambda n: next(tokens))
    figlib._write_record(str(record), {"label": "c", "checks": [], "value": 1.5})
    assert record.read_text().startswith("{") and '"value": 1.5' in record.read_text()
    assert old_style.read_text() == "notes\n" and drawn.read_text() == "notes\n"
    with pytest.raises(TypeError):
        figlib._write_record(str(record), {"label": "c", "checks": [object()]})     # not JSON: the write fails midway
    assert '"value": 1.5' in record.read_text()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["c.json", old_style.name, drawn.name])


def _edited(tmp_path, name, edit):
    """A copy of a finished study's results (tests/test_reliability8.py) as ``name``, edited with h5py."""
    out = _results(tmp_path)
    shutil.copyfile(out, tmp_path / name)
    with h5py.File(tmp_path / name, "r+") as f:
        edit(f)
    return tmp_path / name


@pytest.mark.long
def test_a_title_of_megabytes_in_study_results_is_drawn_cut(tmp_path):
    """A results file whose `title` attribute was set to 10 MB: `rbx plot --kind sweep` held matplotlib for minutes,
    5 GB resident, past SIGTERM (100 MB: 16 GB, SIGKILL). The plot draws the title rbx writes, two lines of a few
    dozen characters: each line is cut to 200 characters, and the figure is drawn."""
    from rbx.cli.sweep import TITLE_LINE, sweep_panel
    from rbx.sweeping import read_results

    def edit(f):
        f.attrs["title"] = "t" * 10**7
    path = _edited(tmp_path, "t.nc", edit)
    _, title = sweep_panel(read_results(str(path)))
    first = title.split("\n")[0]
    assert len(first) == TITLE_LINE and first.endswith("…") and len(title) < 3 * TITLE_LINE
    res = cli("", "plot", "t.nc", "--kind", "sweep", "-o", "t.png", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert (tmp_path / "t.png").stat().st_size > 0


@pytest.mark.long
@pytest.mark.parametrize("name, value, words", [
    ("mean_free_path_santalo", -1.0, "is below 0, the least its quantity can be at 1 of the points marked done"),
    ("lyapunov_per_collision_stderr", -1.0, "is not an error (a number ≥ 0, or none) at 1 of the points marked done"),
])
def test_an_impossible_companion_value_in_study_results_is_refused(tmp_path, name, value, words):
    """Santaló's mean free path of −1 at a finished point was drawn (exit 0) and kept by `--resume` ('nothing to
    do'); a per-collision standard error of −1 ended the figure in matplotlib's 'yerr must not contain negative
    values'. Every standard error, and every companion with a least value (a length, a rate), is checked as the
    observables' own values were: one line naming the variable, exit 2, from the plot and the resume."""
    def edit(f):
        f[name][0] = value
    _edited(tmp_path, "c.nc", edit)
    for args in (["plot", "c.nc", "--kind", "sweep", "-o", "c.png"], ["sweep", "study.yaml", "-o", "c.nc", "--resume"]):
        res = cli("", *args, cwd=tmp_path)
        assert res.returncode == 2, (args, res.returncode, res.stderr)
        lines = res.stderr.splitlines()
        assert len(lines) == 1 and lines[0].startswith(f"rbx: c.nc: {name}: {words}"), res.stderr
    assert not (tmp_path / "c.png").exists()


@pytest.mark.long
def test_two_attributes_that_differ_late_are_quoted_where_they_differ(tmp_path):
    """`measure` edited at its end ('energy_drifu'): the refusal quoted the first 40 characters of both values,
    the same in both. Each is now quoted from a little before the first difference."""
    def edit(f):
        f.attrs["measure"] = f.attrs["measure"].replace("energy_drift", "energy_drifu")
    _edited(tmp_path, "m.nc", edit)
    res = cli("", "sweep", "study.yaml", "-o", "m.nc", "--resume", cwd=tmp_path)
    assert res.returncode == 2, res.stderr
    line, = res.stderr.splitlines()
    assert line.startswith("rbx: m.nc: measure: is '…") and "energy_drifu" in line and "energy_drift" in line, line


def test_an_experiments_resolved_config_edited_in_place_is_refused(tmp_path):
    """`exp.resolved` is a dict: `exp.resolved['ball']['radius'] = 0.05` then `rbx.simulate(exp, output=…)` ran
    radius 0.1 and stored 0.05 (and `run.seed` 999) as the config that ran, which `rbx.open` and the plots read
    back. The API now refuses an experiment whose resolved config changed since it was made, naming the ways to
    change a key; `replace` and `rbx.load` with overrides still work."""
    import rbx
    from rbx.model import ConfigError
    exp = rbx.load(os.path.join(ROOT, "configs", "examples", "strip.yaml"))
    assert rbx.simulate(exp.replace(ball={"inertia": 0.3}), collisions=20).final["collisions"][0] == 20
    exp.resolved["ball"]["radius"] = 0.05
    for call in (lambda: rbx.simulate(exp, collisions=20, output=str(tmp_path / "r.h5")),
                 lambda: rbx.lyapunov(exp, collisions=20), lambda: rbx.load(exp, {"ball.inertia": 0.2})):
        with pytest.raises(ConfigError) as err:
            call()
        assert err.value.key == "resolved" and "was changed in place" in str(err.value)
    assert not os.path.exists(tmp_path / "r.h5")


def test_a_pipe_given_as_a_config_is_named_once():
    """`base: /dev/stdin` in a study said 'is not a regular file, not a regular file': the pipe behind it has no
    name to look at. Now 'is not a regular file: give a YAML file'."""
    from rbx.paths import config_file_problem
    r, w = os.pipe()
    try:
        assert config_file_problem(f"/dev/fd/{r}") == "is not a regular file: give a YAML file"
    finally:
        os.close(r)
        os.close(w)


def test_a_study_path_in_bytes_is_a_path(tmp_path):
    """`rbx.sweep(b"st.yaml")` ended in os.path's 'Can't mix strings and bytes in path components'; a path in bytes
    is a path, as rbx.open and rbx.simulate take one (here a study whose missing section is then named in its file)."""
    import rbx
    from rbx.model import ConfigError
    (tmp_path / "st.yaml").write_text("base: configs/examples/strip.yaml\nvary: {ball.inertia: [0.1, 0.2]}\n"
                                      "measure: [mean_free_path]\n")
    with pytest.raises(ConfigError) as err:
        rbx.sweep(os.fsencode(tmp_path / "st.yaml"))
    assert str(err.value.file).endswith("st.yaml") and err.value.key == "ensemble", err.value
