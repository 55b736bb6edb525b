"""Sixth round: a killed run's journal travels with its file (another disk, a read-only one), a small disk finishes
a run that fits it, a resume is checked against every key that makes its orbit, and a large study starts at once.
Each test was seen to fail on the code before its change."""
import os
import shutil
import subprocess
import sys

import pytest
import yaml

import rbx
from tests.test_interrupt import (assert_same_records, read_run, reference_run, strip_random, without_path,
                                  write_config)
from tests.test_reliability3 import one_line, rbx_cli, tmpfs
from tests.test_reliability5 import KILL_MID_APPLY, _refused

#: a guard against a hang, not a bound
HANG = 600


@pytest.mark.long
def test_a_pending_journal_on_a_read_only_disk_is_read_and_resumed_into_a_writable_folder(tmp_path):
    """A run killed while copying its checkpoint's journal in, on a file system then made read-only: ``rbx.open``,
    ``rbx plot`` and ``--resume … -o`` each said 'finishing that needs to write the file: Read-only file system'.
    The journal is now applied in memory to read the file, and to the copy a resume into -o writes."""
    with tmpfs(tmp_path / "disk", "64m") as disk:
        write_config(disk, strip_random(300_000, trajectories=3, every=3))
        killed = subprocess.run([sys.executable, "-c", KILL_MID_APPLY.replace("{at}", "5"), "simulate", "exp.yaml",
                                 "-o", "o.h5", "--quiet"], cwd=disk, capture_output=True, text=True, timeout=900)
        assert killed.returncode == -9, killed.stderr
        assert (disk / "o.h5.partial.journal").exists()
        res = rbx_cli("simulate", disk / "exp.yaml", "-o", tmp_path / "ref.h5", "--quiet", cwd=tmp_path)
        assert res.returncode == 0, res.stderr
        res = subprocess.run(["mount", "-o", "remount,ro", str(disk)], capture_output=True, text=True)
        if res.returncode != 0:
            pytest.skip(f"cannot make the tmpfs read-only: {res.stderr.strip()}")
        with rbx.open(disk / "o.h5.partial") as run:
            assert not run.complete and run.read("time").shape[0] == 3
        res = rbx_cli("plot", disk / "o.h5.partial", "--kind", "orbit", "-o", tmp_path / "x.png", cwd=tmp_path)
        assert res.returncode == 0 and (tmp_path / "x.png").stat().st_size > 0, res.stderr
        res = rbx_cli("simulate", "--resume", disk / "o.h5.partial", "-o", tmp_path / "out.h5", "--quiet",
                      cwd=tmp_path)
        assert res.returncode == 0, res.stderr
        assert_same_records(read_run(tmp_path / "out.h5"), read_run(tmp_path / "ref.h5"))
        assert (disk / "o.h5.partial.journal").exists()         # the read-only folder as it was
        # a file that is not there is not there, read-only folder or not (it was "cannot be resumed in place")
        res = rbx_cli("simulate", "--resume", disk / "none.h5.partial", cwd=tmp_path)
        assert res.returncode == 2 and res.stderr.endswith("none.h5.partial: file not found\n"), res.stderr


@pytest.mark.long
@pytest.mark.parametrize("name", ["o.h5.partial", "o.h5"])
def test_a_killed_run_that_fits_a_small_disk_is_finished_there(name, tmp_path):
    """On a 3 MB disk a run whose file takes 1.8 MB, killed at 1.5 MB: its resume in place stopped at once ('the
    disk is full … the checkpoint's journal 1.4 MB': the first block of a resume adds the rest of the run to
    chunks committed before, all through the journal) and renamed the .partial to o.h5, whose resume then asked
    room for a copy ('would write about 2.28 MB but the disk has 1.63 MB free'), for ever. Now a block whose
    journal does not fit is written in parts, each committed; and o.h5 is continued in place (renamed, not
    copied) where the copy does not fit."""
    from tests.test_reliability import small_blocks
    write_config(tmp_path, strip_random(20_000, trajectories=3, every=3))
    reference_run(tmp_path)
    with tmpfs(tmp_path / "disk", "3m") as disk:
        write_config(disk, strip_random(20_000, trajectories=3, every=3))
        killed = subprocess.run(small_blocks(work=1000, kill_at=12) + ["simulate", "exp.yaml", "-o", "o.h5",
                                                                       "--quiet"],
                                cwd=disk, capture_output=True, text=True, timeout=900)
        assert killed.returncode == -9, killed.stderr
        if name == "o.h5":         # as a run stopped for room leaves it: renamed, complete = false
            os.rename(disk / "o.h5.partial", disk / "o.h5")
            (disk / "filler").write_bytes(bytes(1_200_000))     # no room even in place: what to do, nothing moved
            res = rbx_cli("simulate", "--resume", name, "--quiet", cwd=disk)
            line = _refused(res, "o.h5", "written already, but the disk has",
                            "resume it into a file on another disk with -o")
            assert sorted(p.name for p in disk.iterdir()) == ["exp.yaml", "filler", "o.h5"], line
            os.remove(disk / "filler")
        res = rbx_cli("simulate", "--resume", name, "--quiet", cwd=disk)
        assert res.returncode == 0, res.stderr
        assert_same_records(read_run(disk / "o.h5"), read_run(tmp_path / "ref.h5"))
        assert sorted(p.name for p in disk.iterdir()) == ["exp.yaml", "o.h5"]


# ---- a resume is checked against everything that makes its orbit ------------------------------------------------

def _edit_stored_config(path, edit):
    import h5py
    import yaml
    with h5py.File(path, "r+") as f:
        cfg = yaml.safe_load(f.attrs["config"])
        edit(cfg)
        f.attrs["config"] = yaml.safe_dump(cfg, sort_keys=False)


@pytest.mark.long
@pytest.mark.parametrize("key, edit", [("run.seed", lambda c: c["run"].update(seed=99)),
                                       ("boundary", lambda c: c["boundary"]["default"].update(probabilities=[0.4, 0.6]))])
def test_a_resume_of_a_file_whose_stored_config_was_changed_is_refused(key, edit, tmp_path):
    """A stored config whose ``run.seed`` was edited in the file resumed with exit 0: the records after the
    checkpoint came from another seed than those before. Every key that makes the orbit is compared with the
    digests the checkpoint stored with the state."""
    import h5py
    from tests.test_reliability3 import killed_run
    reference = killed_run(tmp_path)
    with h5py.File(tmp_path / "run.h5.partial", "r") as f:
        original = f.attrs["config"]
    _edit_stored_config(tmp_path / "run.h5.partial", edit)
    res = rbx_cli("simulate", "--resume", "run.h5", "--quiet", cwd=tmp_path, timeout=HANG)
    _refused(res, "run.h5.partial", f"config: {key}: differs from the value the run's records were computed with",
             "run the config again")
    assert not (tmp_path / "run.h5").exists()
    # what is recorded and where is not the orbit: the config put back with another max_size resumes exactly
    with h5py.File(tmp_path / "run.h5.partial", "r+") as f:
        f.attrs["config"] = original
    _edit_stored_config(tmp_path / "run.h5.partial", lambda c: c["output"].update(max_size="1 GB"))
    res = rbx_cli("simulate", "--resume", "run.h5", "--quiet", cwd=tmp_path, timeout=HANG)
    assert res.returncode == 0, res.stderr
    resumed = read_run(tmp_path / "run.h5")
    assert without_path(resumed["attrs"]["config"])["output"]["max_size"] == "1 GB"
    resumed["attrs"]["config"] = reference["attrs"]["config"]
    assert_same_records(resumed, reference)


@pytest.mark.long
def test_a_complete_attribute_that_is_not_a_boolean_is_refused(tmp_path):
    """``complete = "false"`` (text) was taken as complete: 'nothing to resume', and read as a finished run."""
    import h5py
    from tests.test_reliability3 import killed_run
    killed_run(tmp_path)
    with h5py.File(tmp_path / "run.h5.partial", "r+") as f:
        f.attrs["complete"] = "false"
    with pytest.raises(rbx.FileError, match="complete: is 'false', not true or false"):
        rbx.open(tmp_path / "run.h5.partial")
    res = rbx_cli("simulate", "--resume", "run.h5", "--quiet", cwd=tmp_path, timeout=HANG)
    _refused(res, "run.h5.partial", "complete: is 'false'")


def test_the_api_resume_names_its_own_keyword_for_a_bad_max_size(tmp_path):
    from tests.test_reliability3 import killed_run
    killed_run(tmp_path)
    for bad in (-1, "lots"):
        with pytest.raises(rbx.ConfigError) as info:
            rbx.resume(tmp_path / "run.h5", max_size=bad)
        assert info.value.key == "max_size" and "--max-size" not in str(info.value), info.value


@pytest.mark.long
def test_a_resume_never_writes_over_a_file_that_is_not_a_run_file(tmp_path):
    """``--resume r.h5 -o c.yaml --force`` (and ``rbx.resume(…, output="c.yaml", force=True)``) wrote HDF5 over
    the YAML config; ``rbx simulate`` refuses its own config even with --force, a resume now any ``-o`` that exists
    and is not an HDF5 file."""
    from tests.test_reliability3 import killed_run
    killed_run(tmp_path)
    text = (tmp_path / "exp.yaml").read_text()
    res = rbx_cli("simulate", "--resume", "run.h5", "-o", "exp.yaml", "--force", "--quiet", cwd=tmp_path,
                  timeout=HANG)
    line = _refused(res, "-o", "exp.yaml exists and is not an HDF5 file")
    with pytest.raises(rbx.FileError, match="exp.yaml exists and is not an HDF5 file"):
        rbx.resume(tmp_path / "run.h5", output=tmp_path / "exp.yaml", force=True)
    assert (tmp_path / "exp.yaml").read_text() == text, line
    assert not (tmp_path / "exp.yaml.partial").exists()


@pytest.mark.long
def test_force_never_writes_a_new_run_over_a_file_rbx_did_not_write(tmp_path):
    """A new run with --force (``rbx simulate``, ``rbx.simulate(force=True)``, ``rbx histogram --data``, ``rbx
    sweep -o``) wrote HDF5 over any regular file: notes, another experiment's config, another study. It replaces
    only what rbx writes (HDF5, a torn run file) and an empty file; the rest is refused in one line, --force or not."""
    from rbx import journal, paths
    assert journal.TORN in paths.OWN_SIGNATURES
    write_config(tmp_path, strip_random(200))
    notes = tmp_path / "notes.txt"
    notes.write_text("my notes\n")
    other = tmp_path / "other.yaml"
    other.write_text((tmp_path / "exp.yaml").read_text())
    study = tmp_path / "study.yaml"
    study.write_text("base: exp.yaml\nvary: {ball.inertia: [0.2, 0.4]}\nensemble: {trajectories: 2, collisions: 100}\n"
                     "measure: [energy_drift]\n")
    for args, name in ((["simulate", "exp.yaml", "-o", "notes.txt"], "notes.txt"),
                       (["simulate", "exp.yaml", "-o", "other.yaml"], "other.yaml"),
                       (["sweep", "study.yaml", "-o", "other.yaml"], "other.yaml")):
        res = rbx_cli(*args, "--force", "--quiet", cwd=tmp_path, timeout=HANG)
        _refused(res, "-o", f"{name} exists and is not an HDF5 file")
    with pytest.raises(rbx.FileError, match="notes.txt exists and is not an HDF5 file"):
        rbx.simulate(tmp_path / "exp.yaml", output=notes, force=True)
    assert notes.read_text() == "my notes\n" and other.read_text() == (tmp_path / "exp.yaml").read_text()
    # what rbx wrote, and an empty file, are replaced
    (tmp_path / "empty.h5").write_bytes(b"")
    for out in ("run.h5", "run.h5", "empty.h5"):
        res = rbx_cli("simulate", "exp.yaml", "-o", out, "--force", "--quiet", cwd=tmp_path, timeout=HANG)
        assert res.returncode == 0, res.stderr


@pytest.mark.long
def test_a_complete_output_beside_a_killed_newer_partial_says_how_to_continue_it(tmp_path):
    """``rbx simulate c.yaml -o o.h5 --force`` over a complete o.h5, SIGKILLed: ``--resume o.h5`` said only that
    o.h5 is complete, not that o.h5.partial holds a killed run and how to continue it."""
    from tests.test_reliability3 import killed_run
    killed_run(tmp_path)
    os.rename(tmp_path / "ref.h5", tmp_path / "run.h5")        # complete, beside the killed run's .partial
    res = rbx_cli("simulate", "--resume", "run.h5", "--quiet", cwd=tmp_path, timeout=HANG)
    assert res.returncode == 0, res.stderr
    assert "the run is complete; nothing to resume" in res.stderr
    assert "run.h5.partial" in res.stderr and "rbx simulate --resume run.h5.partial" in res.stderr, res.stderr
    assert (tmp_path / "run.h5.partial").exists()


@pytest.mark.long
def test_a_size_limit_met_by_a_resumes_copy_is_named_as_such(tmp_path):
    """``ulimit -f`` below the size of an interrupted OUT.h5: the resume's copy failed with 'the disk is full'
    though the disk had room; it is the file size limit, and the line says so."""
    from tests.test_reliability3 import RBX, killed_run
    killed_run(tmp_path)
    os.rename(tmp_path / "run.h5.partial", tmp_path / "run.h5")
    before = (tmp_path / "run.h5").read_bytes()
    limit = len(before) // 2048                      # KiB: half the file
    res = subprocess.run(["bash", "-c", f"trap '' XFSZ; ulimit -f {limit}; exec {RBX} simulate --resume run.h5 "
                                        "--quiet"], cwd=tmp_path, capture_output=True, text=True, timeout=HANG)
    assert res.returncode == 1, res.stderr
    line = one_line(res)
    assert "not allowed to grow (a file size limit" in line and "disk is full" not in line, line
    assert (tmp_path / "run.h5").read_bytes() == before and not (tmp_path / "run.h5.partial").exists()


@pytest.mark.long
def test_a_run_under_a_size_limit_just_above_its_file_finishes(tmp_path):
    """``ulimit -f`` a little above the size of a run's finished file (1759 KiB for a 1753 KiB file): the run
    stopped, 'not allowed to grow by 820 kB for the next block', and so did its resumes up to 2000 KiB. The room
    reserved for a block keeps a margin for HDF5's metadata; where only the margin does not fit, the block's own
    room is reserved (a write of HDF5's that meets the limit is the file's failure: it stays at its last commit)."""
    from tests.test_reliability3 import RBX
    write_config(tmp_path, strip_random(20_000, trajectories=3, every=3))
    res = rbx_cli("simulate", "exp.yaml", "-o", "ref.h5", "--quiet", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    limit = -(-(tmp_path / "ref.h5").stat().st_size // 1024) + 64          # KiB
    res = subprocess.run(["bash", "-c", f"trap '' XFSZ; ulimit -f {limit}; exec {RBX} simulate exp.yaml -o o.h5 "
                                        "--quiet"], cwd=tmp_path, capture_output=True, text=True, timeout=HANG)
    assert res.returncode == 0, res.stderr
    assert_same_records(read_run(tmp_path / "o.h5"), read_run(tmp_path / "ref.h5"))


@pytest.mark.long
def test_a_new_run_keeps_the_journal_of_a_partial_that_was_moved_away(tmp_path):
    """A killed run's ``.partial`` moved away (to keep it, inspect it, free the name) left its journal, the only
    thing that can finish it if the kill tore it; a new run on that output deleted the journal without a word. It
    is kept and named now; ``--force`` (or removing it) starts the run."""
    write_config(tmp_path, strip_random(200))
    orphan = tmp_path / "o.h5.partial.journal"
    orphan.write_bytes(b"a journal whose file was moved away")
    res = rbx_cli("simulate", "exp.yaml", "-o", "o.h5", "--quiet", cwd=tmp_path, timeout=HANG)
    _refused(res, "o.h5.partial.journal", "which is not here", "put it back beside the file")
    with pytest.raises(rbx.FileError, match="put it back beside the file"):
        rbx.simulate(tmp_path / "exp.yaml", output=tmp_path / "o.h5")
    assert orphan.read_bytes() == b"a journal whose file was moved away"
    assert not (tmp_path / "o.h5").exists() and not (tmp_path / "o.h5.lock").exists()
    res = rbx_cli("simulate", "exp.yaml", "-o", "o.h5", "--quiet", "--force", cwd=tmp_path, timeout=HANG)
    assert res.returncode == 0 and (tmp_path / "o.h5").exists() and not orphan.exists(), res.stderr


@pytest.mark.long
def test_a_studys_unfinished_results_in_a_read_only_folder_say_how_to_go_on(tmp_path):
    """rbx sweep --resume of a study whose .partial lies in a read-only folder said only "cannot create the run's
    lock file: Read-only file system"; it says to copy the file to a writable folder, which resumes there."""
    sinai = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "configs", "examples",
                         "sinai.yaml")
    study = {"base": sinai, "vary": {"ball.inertia": [0.3, 0.6]}, "measure": ["mean_free_path"],
             "ensemble": {"trajectories": 2, "collisions": 50, "seed": 2}}
    with tmpfs(tmp_path / "disk", "8m") as disk:
        (disk / "study.yaml").write_text(yaml.safe_dump(study))
        assert rbx_cli("sweep", "study.yaml", "-o", "r.nc", "--quiet", cwd=disk).returncode == 0
        os.replace(disk / "r.nc", disk / "r.nc.partial")
        res = subprocess.run(["mount", "-o", "remount,ro", str(disk)], capture_output=True, text=True)
        if res.returncode != 0:
            pytest.skip(f"cannot make the tmpfs read-only: {res.stderr.strip()}")
        res = rbx_cli("sweep", "study.yaml", "-o", "r.nc", "--resume", cwd=disk)
        assert res.returncode == 2 and res.stderr.count("\n") == 1, res.stderr
        assert res.stderr.startswith("rbx: r.nc.partial: cannot be resumed in place: its folder cannot be written") \
            and "copy it to a writable folder and resume there: rbx sweep STUDY -o FOLDER/r.nc --resume" \
            in res.stderr, res.stderr
        shutil.copy(disk / "r.nc.partial", tmp_path / "r.nc.partial")
    (tmp_path / "study.yaml").write_text(yaml.safe_dump(study))
    res = rbx_cli("sweep", "study.yaml", "-o", "r.nc", "--resume", "--quiet", cwd=tmp_path)
    assert res.returncode == 0 and (tmp_path / "r.nc").exists(), res.stderr
