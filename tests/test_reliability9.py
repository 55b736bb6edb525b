"""Nineteenth round: a study's results file whose variable is a link or a virtual dataset (to a FIFO: a hang that
SIGTERM did not end), a resume that replaced a file put at its output while it ran, and inputs deep or large enough
to end in a traceback. Each reproduction runs the real command line (or the API) in a subprocess; each test was seen
to fail on the code before it."""
import json
import os
import shutil
import subprocess
import sys

import h5py
import pytest
import yaml

from tests.test_reliability8 import HANG, _results, cli, wrapped
from tests.test_sweep import specular_study


def _plant(out, variable, how, target):
    """Replace ``variable`` of the results file ``out`` by an external link to ``target`` (or a virtual dataset
    whose source is it)."""
    with h5py.File(out, "r+") as f:
        shape, dtype = f[variable].shape, f[variable].dtype
        del f[variable]
        if how == "external link":
            f[variable] = h5py.ExternalLink(str(target), "/x")
        else:
            layout = h5py.VirtualLayout(shape=shape, dtype=dtype)
            layout[...] = h5py.VirtualSource(str(target), "x", shape=shape)
            f.create_virtual_dataset(variable, layout)


@pytest.mark.long
@pytest.mark.parametrize("how", ["external link", "virtual dataset"])
def test_a_results_variable_that_lies_in_another_file_is_refused_not_followed(tmp_path, how):
    """A results variable made an external link (or a virtual dataset) to a FIFO: `rbx plot --kind sweep`, `rbx
    sweep --resume` and `rbx.sweep(resume=True)` waited in the FIFO's open for ever, and SIGTERM did not end them
    (only SIGKILL); to a regular file, its values were taken as the study's. Now one line naming the variable, exit
    2, nothing opened."""
    out = _results(tmp_path)
    os.mkfifo(tmp_path / "fifo.h5")
    _plant(out, "mean_free_path", how, tmp_path / "fifo.h5")
    shutil.copyfile(out, tmp_path / "copy.nc")
    words = "is a link, not a variable of this file" if how == "external link" else "is an HDF5 virtual dataset"
    for args in (["plot", "out.nc", "--kind", "sweep", "-o", "x.png"],
                 ["sweep", "study.yaml", "-o", "out.nc", "--resume"]):
        res = cli("", *args, cwd=tmp_path)
        assert res.returncode == 2, (args, res.returncode, res.stderr)
        assert res.stderr.splitlines() == [f"rbx: out.nc: mean_free_path: {words}: its values lie elsewhere; a study's "
                                           "results hold their own (the file was changed after rbx wrote it)"] \
            if how == "external link" else len(res.stderr.splitlines()) == 1 and words in res.stderr, res.stderr
    code = ("import rbx\ntry:\n    rbx.sweep('study.yaml', output='copy.nc', resume=True)\n"
            "except rbx.FileError as exc:\n    print('refused:', exc)\n")
    res = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=HANG)
    assert res.returncode == 0 and res.stdout.startswith("refused: ") and "mean_free_path" in res.stdout, \
        (res.stdout, res.stderr)
    assert not (tmp_path / "x.png").exists()


#: a prelude that makes blocks of a few hundred collisions, a checkpoint after each, and sends this process SIGINT
#: after the third block: an interrupted run file (complete = false) to resume
INTERRUPT = ("import os, signal\nimport rbx.simulation as _s\nimport rbx.cli.common as _c\n"
             "_s.BLOCK_WORK = 300\n_s.CHECKPOINT_SECONDS = 0\n_seen = [0]\n_call = _c.Progress.__call__\n"
             "def _p(self, done, total):\n    _seen[0] += 1\n    if _seen[0] == 3:\n"
             "        os.kill(os.getpid(), signal.SIGINT)\n    return _call(self, done, total)\n"
             "_c.Progress.__call__ = _p\n")


@pytest.mark.long
def test_a_resume_never_replaces_another_file_moved_to_its_output_while_it_ran(tmp_path):
    """`rbx simulate --resume rr.h5` and a complete run moved to rr.h5 while it ran: replaced by the resumed run,
    exit 0, nothing said (the resume was allowed to replace rr.h5, its own earlier file, and replaced whatever was
    there). Now the file moved there is kept, one line, exit 2, the records in rr.h5.partial; and a resume that
    nothing disturbs still replaces its own file."""
    from tests.test_histogram import write_config as histogram_config
    conf = histogram_config(tmp_path / "h.yaml", run="{collisions: 3000, trajectories: 1, seed: 2}",
                            initial="{position: [1.0, 0.5], velocity: [0.6, 0.8]}")
    other = histogram_config(tmp_path / "o.yaml", run="{collisions: 50, trajectories: 1, seed: 3}",
                             initial="{position: [1.0, 0.5], velocity: [0.6, 0.8]}")
    res = cli("", "simulate", str(other), "-o", "other.h5", "--quiet", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    theirs = (tmp_path / "other.h5").read_bytes()
    for name in ("rr.h5", "ok.h5"):
        res = cli(INTERRUPT, "simulate", str(conf), "-o", name, "--quiet", cwd=tmp_path)
        assert res.returncode == 130, res.stderr
        with h5py.File(tmp_path / name, "r") as f:
            assert not f.attrs["complete"]
    move = (f"import shutil, os\nshutil.copyfile({str(tmp_path / 'other.h5')!r}, {str(tmp_path / 'moving')!r})\n"
            f"os.replace({str(tmp_path / 'moving')!r}, {str(tmp_path / 'rr.h5')!r})")
    res = cli(wrapped("rbx.driver", "open_journaled", move), "simulate", "--resume", "rr.h5", "--quiet",
              cwd=tmp_path)
    assert res.returncode == 2, (res.returncode, res.stderr)
    assert res.stderr.splitlines() == ["rbx: rr.h5: appeared while this run was writing (another run?) and was not "
                                       "replaced; the records are in rr.h5.partial"], res.stderr
    assert (tmp_path / "rr.h5").read_bytes() == theirs
    with h5py.File(tmp_path / "rr.h5.partial", "r") as f:
        assert f.attrs["complete"]
    res = cli("", "simulate", "--resume", "ok.h5", "--quiet", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    with h5py.File(tmp_path / "ok.h5", "r") as f:
        assert f.attrs["complete"]
    assert not (tmp_path / "ok.h5.partial").exists()


@pytest.mark.long
def test_a_study_resume_never_replaces_other_results_moved_to_its_output_while_it_ran(tmp_path):
    """`rbx sweep STUDY -o C.nc --resume` and another study's results moved to C.nc while the points ran: replaced,
    exit 0. Now they are kept, one line, exit 2, the resumed results in C.nc.partial."""
    out = _results(tmp_path)
    shutil.copyfile(out, tmp_path / "other.nc")
    with h5py.File(tmp_path / "other.nc", "r+") as f:
        f.attrs["title"] = "another study"
    theirs = (tmp_path / "other.nc").read_bytes()
    with h5py.File(out, "r+") as f:
        f["done"][1:] = 0
        f.attrs["complete"] = 0
    move = (f"import shutil, os\nshutil.copyfile({str(tmp_path / 'other.nc')!r}, {str(tmp_path / 'moving')!r})\n"
            f"os.replace({str(tmp_path / 'moving')!r}, {str(out)!r})")
    res = cli(wrapped("rbx.sweeping", "run_point", move), "sweep", "study.yaml", "-o", "out.nc", "--resume",
              "--quiet", cwd=tmp_path)
    assert res.returncode == 2, (res.returncode, res.stderr)
    assert res.stderr.splitlines() == ["rbx: out.nc: appeared while the study ran (another program?) and was not "
                                       "replaced; the results are in out.nc.partial"], res.stderr
    assert out.read_bytes() == theirs
    import xarray as xr
    with xr.open_dataset(tmp_path / "out.nc.partial", engine="h5netcdf") as ds:
        assert int(ds["done"].values.min()) == 1 and ds.attrs["complete"] == 1


@pytest.mark.long
@pytest.mark.parametrize("given", ["hl.h5", "hl.h5.partial"])
def test_a_partial_that_is_the_run_under_a_second_name_resumes(tmp_path, given):
    """hl.h5.partial a hard link to an interrupted hl.h5 (what a kill between the final link and the remove
    leaves): `rbx simulate --resume hl.h5` took the .partial as the further file, then removed it as a second name:
    a FileNotFoundError traceback, exit 1. Now the second name is removed first and the run resumes to the end."""
    from tests.test_histogram import write_config as histogram_config
    conf = histogram_config(tmp_path / "h.yaml", run="{collisions: 3000, trajectories: 1, seed: 2}",
                            initial="{position: [1.0, 0.5], velocity: [0.6, 0.8]}")
    res = cli(INTERRUPT, "simulate", str(conf), "-o", "hl.h5", "--quiet", cwd=tmp_path)
    assert res.returncode == 130, res.stderr
    os.link(tmp_path / "hl.h5", tmp_path / "hl.h5.partial")
    res = cli("", "simulate", "--resume", given, "--quiet", cwd=tmp_path)
    assert res.returncode == 0 and "Traceback" not in res.stderr, res.stderr
    with h5py.File(tmp_path / "hl.h5", "r") as f:
        assert f.attrs["complete"] and int(f["final/collisions"][0]) == 3000
    assert sorted(p.name for p in tmp_path.iterdir()) == ["h.yaml", "hl.h5"]


@pytest.mark.long
def test_inputs_nested_too_deeply_are_one_line(tmp_path):
    """A study file nested 5000 deep, a results file whose `measure` is '[' 100 000 times, an interrupted run whose
    saved state's `orbit` digests are '{"a":' 100 000 times: each a RecursionError traceback, exit 1. Now one line
    each, exit 2."""
    from tests.test_histogram import write_config as histogram_config
    study = specular_study(trajectories=2, collisions=100)
    (tmp_path / "deep.yaml").write_text(yaml.safe_dump(study) + "notes: " + "{a: " * 5000 + "1" + "}" * 5000 + "\n")
    res = cli("", "sweep", "deep.yaml", "-o", "d.nc", cwd=tmp_path)
    assert res.returncode == 2 and res.stderr.splitlines() == ["rbx: deep.yaml: the YAML is nested too deeply"], \
        res.stderr
    out = _results(tmp_path)
    with h5py.File(out, "r+") as f:
        f.attrs["measure"] = "[" * 100_000
    res = cli("", "plot", "out.nc", "--kind", "sweep", "-o", "x.png", cwd=tmp_path)
    assert res.returncode == 2 and len(res.stderr.splitlines()) == 1, res.stderr
    assert res.stderr.startswith("rbx: out.nc: measure: is not a JSON list"), res.stderr
    conf = histogram_config(tmp_path / "h.yaml", run="{collisions: 3000, trajectories: 1, seed: 2}",
                            initial="{position: [1.0, 0.5], velocity: [0.6, 0.8]}")
    res = cli(INTERRUPT, "simulate", str(conf), "-o", "r.h5", "--quiet", cwd=tmp_path)
    assert res.returncode == 130, res.stderr
    with h5py.File(tmp_path / "r.h5", "r+") as f:
        f["final"].attrs["orbit"] = '{"a":' * 100_000
    res = cli("", "simulate", "--resume", "r.h5", "--quiet", cwd=tmp_path)
    assert res.returncode == 2 and len(res.stderr.splitlines()) == 1, res.stderr
    assert "final.orbit: damaged" in res.stderr and "Traceback" not in res.stderr, res.stderr


@pytest.mark.long
def test_a_resume_beside_another_studys_partial_says_the_results_are_there(tmp_path):
    """`rbx sweep A -o r.nc --resume`, r.nc holding every point of A and r.nc.partial another study's (a killed
    --force run of it): the line said only that the study changed, as if A's results were lost. Now it also says
    that r.nc holds them and how to go on."""
    out = _results(tmp_path)
    shutil.copyfile(out, tmp_path / "out.nc.partial")
    with h5py.File(tmp_path / "out.nc.partial", "r+") as f:
        f.attrs["study_digest"] = "0" * 64
    before = out.read_bytes()
    res = cli("", "sweep", "study.yaml", "-o", "out.nc", "--resume", cwd=tmp_path)
    assert res.returncode == 2 and len(res.stderr.splitlines()) == 1, res.stderr
    assert "the study changed since this file was started" in res.stderr
    assert res.stderr.rstrip().endswith("; out.nc holds this study's results (2 of 2 points): to go on with them, "
                                        "remove out.nc.partial (another study's, left by a killed run)"), res.stderr
    assert out.read_bytes() == before


@pytest.mark.long
def test_a_crafted_attribute_is_quoted_short(tmp_path):
    """An interrupted run whose root attribute wall_names was made '[' 100 000 times: the resume's refusal quoted it
    whole, a 'line' of 300 kB. Now the line is short and says what changed."""
    from tests.test_histogram import write_config as histogram_config
    conf = histogram_config(tmp_path / "h.yaml", run="{collisions: 3000, trajectories: 1, seed: 2}",
                            initial="{position: [1.0, 0.5], velocity: [0.6, 0.8]}")
    res = cli(INTERRUPT, "simulate", str(conf), "-o", "r.h5", "--quiet", cwd=tmp_path)
    assert res.returncode == 130, res.stderr
    with h5py.File(tmp_path / "r.h5", "r+") as f:
        f.attrs["wall_names"] = "[" * 100_000
    res = cli("", "simulate", "--resume", "r.h5", "--quiet", cwd=tmp_path)
    assert res.returncode == 2 and len(res.stderr.splitlines()) == 1 and len(res.stderr) < 600, res.stderr[:600]
    assert "wall_names: the root attribute names 100000 walls ([, [, [" in res.stderr and "…" in res.stderr, \
        res.stderr


@pytest.mark.long
def test_a_results_file_declaring_more_points_than_a_study_has_is_refused_before_it_is_read(tmp_path):
    """A 7 kB results file declaring 2·10⁹ points (chunks never written): `rbx plot --kind sweep` allocated 14.9 GiB
    for its coordinate (a MemoryError under a memory limit, the machine's memory without one). Now one line, exit 2,
    before anything is read; run here under a 4 GB limit so that the old code fails without taking the machine."""
    import h5netcdf
    with h5netcdf.File(tmp_path / "big.nc", "w") as f:
        f.dimensions = {"table.radius": 2_000_000_000}
        f.attrs.update(rbx_study="1", varied='["table.radius"]', measure='["mean_free_path"]')
        for name, dtype in (("table.radius", "f8"), ("done", "i1"), ("mean_free_path", "f8"), ("wall_time", "f8")):
            f.create_variable(name, ("table.radius",), dtype, chunks=(1_000_000,))
    assert (tmp_path / "big.nc").stat().st_size < 100_000
    prelude = "import resource\nresource.setrlimit(resource.RLIMIT_AS, (4 << 30, 4 << 30))"
    res = cli(prelude, "plot", "big.nc", "--kind", "sweep", "-o", "b.png", cwd=tmp_path)
    assert res.returncode == 2 and res.stderr.splitlines() == [
        "rbx: big.nc: table.radius: has a dimension of 2000000000; a study has at most 100000 points: the file was "
        "changed after rbx wrote it"], res.stderr
