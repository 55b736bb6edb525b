"""A twenty-ninth round: results files of a study edited into another layout (a variable moved onto another
dimension, a dimension emptied, ``done`` made one value, numbers stored as text) ended ``rbx plot --kind sweep`` in
a traceback, or named another variable, where ``rbx sweep --resume`` refused them. Each is refused now by both, in
one line naming the variable; the test was seen to fail on the code before it."""
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
import yaml

import rbx
from tests.test_reliability8 import cli

RECTANGLE = {"table": {"kind": "rectangle", "width": 2.0, "height": 1.0},
             "boundary": {"default": {"rule": "constant", "rank": 1}}, "ball": {"radius": 0.1, "inertia": 0.5},
             "initial": {"sample": "billiard"}, "run": {"collisions": 100, "trajectories": 4},
             "output": {"record": []}}


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    """A finished study of the rough rectangle at three inertias, its energy drift measured."""
    folder = tmp_path_factory.mktemp("layout")
    (folder / "table.yaml").write_text(yaml.safe_dump(RECTANGLE, sort_keys=False))
    (folder / "study.yaml").write_text(yaml.safe_dump(
        {"base": "table.yaml", "vary": {"ball.inertia": [0.2, 0.5, 1.0]}, "measure": ["energy_drift"],
         "ensemble": {"trajectories": 4, "collisions": 100, "seed": 3}}, sort_keys=False))
    rbx.sweep(str(folder / "study.yaml"), str(folder / "r.nc"))
    return folder / "r.nc"


def _edits():
    def moved(ds, name):            # the variable's values on a dimension of its own, of another length
        ds[name] = ("other", np.arange(6.0))
        return ds
    return {
        "energy_drift": lambda ds: moved(ds, "energy_drift"),
        "wall_time": lambda ds: moved(ds, "wall_time"),
        "collisions": lambda ds: moved(ds, "collisions"),
        "emptied": lambda ds: ds.isel({"ball.inertia": slice(0, 0)}),
        "done": lambda ds: ds.assign(done=((), np.int8(1))),
        "text": lambda ds: ds.assign(energy_drift=(ds["energy_drift"].dims,
                                                   ds["energy_drift"].values.astype(str))),
    }


WORDS = {"energy_drift": "energy_drift: has dimensions {'other': 6}, where each variable has the points' "
                         "{'ball.inertia': 3} first",
         "wall_time": "wall_time: has dimensions {'other': 6}",
         "collisions": "collisions: has dimensions {'other': 6}",
         "emptied": "done: holds no point (dimensions {'ball.inertia': 0})",
         "done": "done: holds no value per point (dimensions {})",
         "text": "energy_drift: holds <U"}


@pytest.mark.parametrize("edit", list(_edits()))
def test_a_results_file_of_another_layout_is_refused_by_the_figure(results, tmp_path, edit):
    from rbx.cli.common import UserError
    from rbx.cli.sweep import open_results
    with xr.open_dataset(results, engine="h5netcdf") as ds:
        edited = _edits()[edit](ds.load().copy())
    path = tmp_path / f"{edit}.nc"
    edited.to_netcdf(path, engine="h5netcdf")
    with pytest.raises(UserError) as info:
        open_results(str(path))
    assert WORDS[edit] in str(info.value), str(info.value)
    if edit == "energy_drift":          # the command, as a user runs it
        res = cli("", "plot", path.name, "--kind", "sweep", "-o", "f.png", cwd=tmp_path)
        assert res.returncode == 2 and res.stderr.count("\n") == 1 and WORDS[edit] in res.stderr, res.stderr
        assert not (tmp_path / "f.png").exists()


def test_the_results_file_as_written_is_drawn(results, tmp_path):
    res = cli("", "plot", str(results), "--kind", "sweep", "-o", str(tmp_path / "f.png"), cwd=tmp_path)
    assert res.returncode == 0 and (tmp_path / "f.png").stat().st_size > 0, res.stderr


def _read_only_midway(folder, args, written):
    """``rbx ARGS`` in ``folder``, the folder made read-only once the file ``written`` is there -> (the finished
    process, its stderr). As root the command runs without the capability that ignores file modes (setpriv), so
    that the mode binds it too."""
    import os
    import shutil
    import subprocess
    import sys
    import time
    prefix = []
    if os.geteuid() == 0:
        if shutil.which("setpriv") is None:
            pytest.skip("root, and no setpriv to run rbx without CAP_DAC_OVERRIDE")
        drop = "-dac_override,-dac_read_search"
        prefix = ["setpriv", f"--bounding-set={drop}", f"--inh-caps={drop}"]
    code = "import sys\nfrom rbx.cli.main import main\nsys.argv[0] = 'rbx'\nmain()\n"
    run = subprocess.Popen(prefix + [sys.executable, "-c", code, *args], cwd=folder, stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True)
    try:
        waited = time.monotonic()
        while not (folder / written).exists() and run.poll() is None and time.monotonic() - waited < 300:
            time.sleep(0.05)
        assert run.poll() is None, run.communicate()
        os.chmod(folder, 0o555)
        _, err = run.communicate(timeout=300)
    finally:
        os.chmod(folder, 0o755)
        if run.poll() is None:
            run.kill()
    return run, err


def test_a_folder_made_read_only_while_a_run_writes_is_one_line_naming_the_cause(tmp_path):
    """The folder of a running `rbx simulate` made read-only: its next checkpoint failed (right: the records up to
    the last one are kept, resumable), but two lines were said, the first the consequence (the rename of the
    unfinished file, refused too) and neither the cause. One line now, naming the folder, exit 1."""
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(
        {**RECTANGLE, "initial": {"position": [0.5, 0.5], "velocity": [0.6, 0.8]},
         "run": {"collisions": 10**11, "trajectories": 1}, "output": {"record": ["time"], "every": 100_000}}))
    run, err = _read_only_midway(tmp_path, ("simulate", "s.yaml", "-o", "r.h5"), "r.h5.partial")
    lines = err.strip().splitlines()
    assert run.returncode == 1 and len(lines) == 1, err
    assert lines[0].startswith("rbx: r.h5.partial: writing failed: Permission denied (its folder can no longer be "
                               "written?); the file holds every record up to its last checkpoint"), err
    assert lines[0].endswith("continue with: rbx simulate --resume r.h5.partial"), err
    assert rbx.open(str(tmp_path / "r.h5.partial")).complete is False


def test_a_folder_made_read_only_while_a_study_writes_is_not_called_a_full_disk(tmp_path):
    """The same for `rbx sweep`: the line said to free some room; it names the folder now, and the points written
    before are kept for --resume."""
    (tmp_path / "table.yaml").write_text(yaml.safe_dump(RECTANGLE, sort_keys=False))
    (tmp_path / "study.yaml").write_text(yaml.safe_dump(
        {"base": "table.yaml", "vary": {"ball.inertia": {"from": 0.1, "to": 1.0, "num": 400}},
         "measure": ["energy_drift"], "ensemble": {"trajectories": 4, "collisions": 20_000, "seed": 3}},
        sort_keys=False))
    run, err = _read_only_midway(tmp_path, ("sweep", "study.yaml", "-o", "r.nc", "--quiet"), "r.nc.partial")
    lines = err.strip().splitlines()
    assert run.returncode == 1 and len(lines) == 1, err
    assert "r.nc.partial: cannot write the study's results (Permission denied); its folder . cannot be written; " \
           "r.nc.partial is as it was: once the folder can be written, continue with --resume" in lines[0], err
    assert "room" not in lines[0]
