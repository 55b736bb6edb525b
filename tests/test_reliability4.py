"""Faults of the run file found by a red-team after the third round (docs/reliability.md): a kill during a resume
into the run's own file, the room a block asks for on a small disk, run files holding values no run writes, and
the API's arguments. Real ``rbx`` processes on real files (a tmpfs where the test may mount one, skipped with the
reason otherwise)."""
import os
import signal
import subprocess
import sys

import h5py
import numpy as np
import pytest

import rbx
from tests.test_interrupt import assert_same_records, read_run, reference_run, strip_random, write_config
from tests.test_reliability import small_blocks
from tests.test_reliability3 import one_line, rbx_cli, tmpfs

ALL = ("time", "position", "velocity", "angular_velocity", "orientation", "wall", "rank")


# ---- the room a block asks for -------------------------------------------------------------------------------------

@pytest.mark.long
def test_runs_that_fit_a_small_disk_finish_and_resume_there(tmp_path):
    """On a 3 MB disk, runs of 6000–10 000 collisions passed the up-front size check, then every block asked
    3.3–4.3 MB (two chunks per dataset, doubled for the journal: the whole file's chunks, twice) and the run never
    finished, nor did its resume. A block now asks for the chunks it makes, the pages of committed chunks it
    changes (the journal keeps those alone) and the checkpoint's state: each run finishes, with the records of
    the same run written elsewhere; so does a run checkpointed after every block, killed, and resumed in place on
    that disk."""
    with tmpfs(tmp_path / "disk", "3m") as disk:
        for M, collisions, record in ((3, 10_000, ALL), (2, 10_000, ALL), (3, 6000, ("time", "position", "velocity"))):
            write_config(tmp_path, strip_random(collisions, trajectories=M, every=1, record=record))
            reference_run(tmp_path, force=True)
            res = rbx_cli("simulate", "exp.yaml", "-o", disk / "run.h5", "--quiet", cwd=tmp_path)
            assert res.returncode == 0, (M, collisions, res.stderr)
            assert_same_records(read_run(disk / "run.h5"), read_run(tmp_path / "ref.h5"))
            os.remove(disk / "run.h5")
        # checkpoints after every block of 3000 collisions' work: committed chunks rewritten through the journal
        write_config(tmp_path, strip_random(10_000, trajectories=3, every=1, record=ALL))
        reference_run(tmp_path, force=True)
        killed = subprocess.run(small_blocks(kill_at=4) + ["simulate", "exp.yaml", "-o", disk / "run.h5", "--quiet"],
                                cwd=tmp_path, capture_output=True, text=True, timeout=900)
        assert killed.returncode == -signal.SIGKILL, killed.stderr
        resumed = subprocess.run(small_blocks() + ["simulate", "--resume", disk / "run.h5", "--quiet"],
                                 cwd=tmp_path, capture_output=True, text=True, timeout=900)
        assert resumed.returncode == 0, resumed.stderr
        assert sorted(p.name for p in disk.iterdir()) == ["run.h5"]
        assert_same_records(read_run(disk / "run.h5"), read_run(tmp_path / "ref.h5"))


# ---- a kill during a resume into the run's own file ---------------------------------------------------------------

#: ``python -c`` running the CLI with small blocks, a checkpoint after each, sending itself SIG after checkpoint AT
SELF_SIGNAL = ("import os, sys, rbx.simulation as s, rbx.runfile as f; s.BLOCK_WORK = 3000; s.CHECKPOINT_SECONDS = 0; "
               "c = f.H5Sink.checkpoint; n = [0]\n"
               "def cp(self, sim):\n"
               "    c(self, sim); n[0] += 1\n"
               "    if n[0] == {at}: os.kill(os.getpid(), {sig})\n"
               "f.H5Sink.checkpoint = cp\n"
               "from rbx.cli.main import main; sys.argv[0] = 'rbx'; main()")


def signalled(folder, sig, at, *args):
    res = subprocess.run([sys.executable, "-c", SELF_SIGNAL.format(at=at, sig=int(sig)), *map(str, args)],
                         cwd=folder, capture_output=True, text=True, timeout=900)
    return res.returncode


def interrupted_then_killed_resume(folder):
    """``k.h5`` interrupted (Ctrl-C: complete = false), then ``rbx simulate --resume k.h5`` SIGKILLed after it
    checkpointed further: k.h5, k.h5.partial (the resume's copy, further along) and a stale lock -> the bytes of
    k.h5."""
    for f in folder.glob("k.h5*"):
        f.unlink()
    assert signalled(folder, signal.SIGINT, 3, "simulate", "exp.yaml", "-o", "k.h5", "--quiet") == 130
    assert signalled(folder, signal.SIGKILL, 3, "simulate", "--resume", "k.h5", "--quiet") == -signal.SIGKILL
    assert sorted(p.name for p in folder.glob("k.h5*")) == ["k.h5", "k.h5.lock", "k.h5.partial"]
    return (folder / "k.h5").read_bytes()


@pytest.mark.long
def test_a_resume_killed_while_continuing_the_run_in_its_own_file_is_resumed(tmp_path):
    """SIGKILL during ``rbx simulate --resume k.h5`` (k.h5 interrupted: the resume works on a copy, k.h5.partial)
    left k.h5 and k.h5.partial; the next ``--resume k.h5`` said "exists: another run may be writing it" though no
    run held the lock, and asked for --force (which copied k.h5 over the further .partial); ``--resume
    k.h5.partial`` said "k.h5: exists; use --force". Either resume now goes on from the further file, the records
    those of the uninterrupted run; a copy cut short by the kill is removed (its records are all in k.h5), and a
    .partial of another run is left alone, in one line saying how to continue either. Killed while it continued
    k.h5 into ``-o o.h5``, the same resume said "another run may be writing" o.h5.partial: it says it was
    killed and how to continue it."""
    write_config(tmp_path, strip_random(30_000, trajectories=3, every=7, record=("time", "position", "wall")))
    reference_run(tmp_path)
    reference = read_run(tmp_path / "ref.h5")
    for resumed in ("k.h5", "k.h5.partial"):
        interrupted_then_killed_resume(tmp_path)
        res = rbx_cli("simulate", "--resume", resumed, "--quiet", cwd=tmp_path)
        assert res.returncode == 0, (resumed, res.stderr)
        if resumed == "k.h5":
            assert "k.h5.partial: warning: resumed in place of k.h5: the copy a killed resume of k.h5 left, " \
                   "further along" in one_line(res), res.stderr
        assert sorted(p.name for p in tmp_path.glob("k.h5*")) == ["k.h5"], resumed
        assert_same_records(read_run(tmp_path / "k.h5"), reference)
    # the API: the same code
    interrupted_then_killed_resume(tmp_path)
    with pytest.warns(RuntimeWarning, match="resumed in place of"):
        assert rbx.resume(tmp_path / "k.h5").complete
    assert_same_records(read_run(tmp_path / "k.h5"), reference)
    # killed while it copied k.h5: the .partial is the first bytes of k.h5
    original = interrupted_then_killed_resume(tmp_path)
    (tmp_path / "k.h5.partial").write_bytes(original[:len(original) // 2])
    res = rbx_cli("simulate", "--resume", "k.h5", "--quiet", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert "warning: removed k.h5.partial, a copy of it cut short by a killed resume" in one_line(res)
    assert_same_records(read_run(tmp_path / "k.h5"), reference)
    # killed while it continued k.h5 into -o o.h5: the same resume says how to go on, and that does
    interrupted_then_killed_resume(tmp_path)
    (tmp_path / "k.h5.partial").unlink()
    assert signalled(tmp_path, signal.SIGKILL, 3, "simulate", "--resume", "k.h5", "-o", "o.h5", "--quiet") == -9
    res = rbx_cli("simulate", "--resume", "k.h5", "-o", "o.h5", cwd=tmp_path)
    assert res.returncode == 2, res.stderr
    assert one_line(res) == ("rbx: o.h5.partial: exists, left by a run that was killed (no run holds its lock): "
                             "continue that run with rbx simulate --resume o.h5.partial; or remove it, or use "
                             "--force to write this one over it")
    res = rbx_cli("simulate", "--resume", "o.h5.partial", "--quiet", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert_same_records(read_run(tmp_path / "o.h5"), reference)
    # the .partial of another run (a new run of another seed with --force, killed): nothing is touched
    interrupted_then_killed_resume(tmp_path)
    (tmp_path / "k.h5.partial").unlink()
    assert signalled(tmp_path, signal.SIGKILL, 3, "simulate", "exp.yaml", "-o", "k.h5", "--seed", 5, "--force",
                     "--quiet") == -signal.SIGKILL
    before = {p.name: p.read_bytes() for p in tmp_path.glob("k.h5*") if p.name != "k.h5.lock"}
    res = rbx_cli("simulate", "--resume", "k.h5", cwd=tmp_path)
    assert res.returncode == 2, res.stderr
    assert one_line(res) == ("rbx: k.h5.partial: holds another run than k.h5 (its run was killed: no run holds the "
                             "lock); to continue that run, replacing k.h5 when it ends: rbx simulate --resume "
                             "k.h5.partial --force; to continue k.h5: remove k.h5.partial")
    assert {p.name: p.read_bytes() for p in tmp_path.glob("k.h5*") if p.name != "k.h5.lock"} == before


# ---- the API's arguments -------------------------------------------------------------------------------------------

@pytest.mark.long
def test_the_api_says_what_a_path_argument_must_be_and_names_its_own_keywords(tmp_path):
    """``rbx.resume(None)``, ``rbx.resume(5)`` gave os.fspath's TypeError from deep inside, ``rbx.resume(b"…")``
    'endswith first arg must be bytes'; a size limit met through the API was to be raised with ``--max-size``.
    The API now names its argument and what it takes (a TypeError, as rbx.load's), reads a bytes path as the path
    it is, and a limit met through it names ``max_size=``; the command line names ``--max-size``."""
    from tests.test_reliability3 import killed_run
    reference = killed_run(tmp_path)
    for args, kw, said in (((None,), {}, "path is the path of a run file (a str or os.PathLike), not NoneType"),
                           ((5,), {}, "path is the path of a run file (a str or os.PathLike), not int"),
                           (("run.h5",), {"output": 5}, "output is the path of a run file (a str or os.PathLike), "
                                                        "not int")):
        with pytest.raises(TypeError) as info:
            rbx.resume(*args, **kw)
        assert str(info.value) == f"rbx.resume: {said}"
    with pytest.raises(rbx.FileError) as info:
        rbx.resume(os.fsencode(tmp_path / "run.h5.partial"), max_size="1KB")
    assert "give a larger max_size= if that is meant" in str(info.value) and "--max-size" not in str(info.value)
    run = rbx.resume(os.fsencode(tmp_path / "run.h5.partial"))
    assert run.complete and run.path == str(tmp_path / "run.h5")
    assert_same_records(read_run(tmp_path / "run.h5"), reference)
    cfg = strip_random(10**9, trajectories=3, every=1, record=("time",))
    for kw, said in (({}, "exp.yaml: output.max_size: the run would write about 32 GB"),
                     ({"max_size": "1KB"}, "max_size: the run would write about 32 GB")):
        with pytest.raises(rbx.FileError) as info:
            rbx.simulate(write_config(tmp_path, cfg), output=tmp_path / "big.h5", **kw)
        assert said in str(info.value) and "max_size= if that is meant" in str(info.value), str(info.value)
        assert "--max-size" not in str(info.value)
    for option, said in (((), "raise output.max_size or give --max-size if that is meant"),
                         (("--max-size", "1KB"), "give a larger --max-size if that is meant")):
        res = rbx_cli("simulate", "exp.yaml", "-o", "big.h5", *option, cwd=tmp_path)
        assert res.returncode == 2 and said in one_line(res), res.stderr
    assert not list(tmp_path.glob("big.h5*"))


# ---- run files holding values no run writes --------------------------------------------------------------------------

def _virtual(g):
    """``collisions/time`` made an HDF5 virtual dataset whose values lie in another file."""
    other = os.path.join(os.path.dirname(g.file.filename), "other.h5")
    shape = g["time"].shape
    with h5py.File(other, "w") as f:
        f["x"] = g["time"][...]              # the run's own values: only where they lie is wrong
    layout = h5py.VirtualLayout(shape=shape, dtype="f8")
    layout[...] = h5py.VirtualSource(other, "x", shape=shape)
    del g["time"]
    g.create_virtual_dataset("time", layout, fillvalue=np.nan)


def _external(g):
    """``collisions/time`` made an HDF5 dataset whose raw values lie in another file."""
    raw = os.path.join(os.path.dirname(g.file.filename), "raw.bin")
    shape = g["time"].shape
    g["time"][...].tofile(raw)
    del g["time"]
    g.create_dataset("time", shape=shape, dtype="f8", external=[(raw, 0, h5py.h5f.UNLIMITED)])


def _external_link(g):
    """``collisions/time`` made an HDF5 external link to a dataset of another file (the run's own values)."""
    other = os.path.join(os.path.dirname(g.file.filename), "linked.h5")
    with h5py.File(other, "w") as f:
        f["time"] = g["time"][...]
    del g["time"]
    g["time"] = h5py.ExternalLink("linked.h5", "time")


def _set(name, at, value):
    return lambda g: g[name].__setitem__(at, value)


#: case -> (the change to collisions/, a plot kind that reads it, what the one line says)
BAD_VALUES = {
    "a position at inf": (_set("position", (0, 7, 0), np.inf), "orbit",
                          "collisions/position: holds [inf, 0.9] at trajectory 0, record 7: a number that is not "
                          "finite"),
    "a wall index 99": (_set("wall", (1, 9), 99), "phase",
                        "collisions/wall: holds 99 at trajectory 1, record 9: a wall index the table does not have "
                        "(its 2 walls are 0 … 1; −1 before the first collision)"),
    "a NaN time": (_set("time", (0, 3), np.nan), "diffusion",
                   "collisions/time: holds nan at trajectory 0, record 3: a number that is not finite"),
    "a virtual dataset": (_virtual, "orbit", "collisions/time: is an HDF5 virtual dataset: its values lie in other "
                                             "files"),
    "an external dataset": (_external, "orbit", "collisions/time: is an HDF5 external dataset: its values lie in "
                                                "other files"),
    "an external link": (_external_link, "orbit", "collisions/time: is a link, not a dataset of this file: its "
                                                  "values lie elsewhere"),
    "a step out of line": (_set("step", 5, 77), "orbit",
                           "collisions/step: holds 77 at record 5; the layout says record × output.every (5)"),
}


@pytest.mark.long
@pytest.mark.parametrize("case", list(BAD_VALUES))
def test_a_run_file_holding_values_no_run_writes_is_refused_in_one_line(case, tmp_path):
    """Run files with positions at inf, a wall index 99 (the table has 2 walls), a NaN time, or records held in
    other files (an HDF5 virtual or external dataset) opened without complaint, and were drawn. What is read is
    checked as it is read (numbers finite within the records a trajectory wrote, wall indices among the table's
    walls; the datasets' storage and ``step`` when the file opens): rbx.FileError from the API, one line and exit
    2 from ``rbx plot``."""
    change, kind, said = BAD_VALUES[case]
    path = tmp_path / "bad.h5"
    rbx.simulate(strip_random(500, trajectories=2, every=1, record=ALL), output=path)
    with h5py.File(path, "r+") as f:
        change(f["collisions"])
    with pytest.raises(rbx.FileError) as info:
        run = rbx.open(path)
        [getattr(run, field) for field in run.fields]
    assert str(info.value).startswith(f"{path}: {said}"), str(info.value)
    res = rbx_cli("plot", path, "--kind", kind, "-o", tmp_path / "x.png", cwd=tmp_path)
    assert res.returncode == 2, res.stderr
    assert one_line(res).startswith(f"rbx: bad.h5: {said}"), res.stderr
    assert not (tmp_path / "x.png").exists()


@pytest.mark.long
def test_a_resume_refuses_records_held_elsewhere_and_a_state_naming_a_wall_the_table_lacks(tmp_path):
    """A killed run's file whose ``collisions/time`` is an HDF5 virtual or external dataset (its values, the run's
    own, lying in another file) gave a TypeError traceback from the resume ('Only chunked datasets can be
    resized'); a saved state whose last wall is 99 (the strip has 2 walls), its digest made to match, was refused
    as 'the last records are not the saved state (the process was killed while writing)'. Each is one line
    naming the dataset, exit 2, the file left as it was."""
    from rbx.runfile import state_digest
    from tests.test_reliability3 import killed_run
    killed_run(tmp_path)
    rbx.open(tmp_path / "run.h5.partial")        # applies a journal a kill may have left, before h5py edits it

    def last_wall(f):
        for group in ("final", "final_previous"):
            if group in f:
                f[group]["last_wall"][1] = 99
                state = {k: f[group][k][...] for k in f[group]}     # crafted whole: its digest made to match
                f[group].attrs["digest"] = state_digest(state)

    for change, said in ((lambda f: _virtual(f["collisions"]), "collisions/time: is an HDF5 virtual dataset"),
                         (lambda f: _external(f["collisions"]), "collisions/time: is an HDF5 external dataset"),
                         (last_wall, "final/last_wall: names no wall of the table (0 … 1, or −1): trajectory 1")):
        bad = tmp_path / "bad.h5.partial"
        bad.write_bytes((tmp_path / "run.h5.partial").read_bytes())
        with h5py.File(bad, "r+") as f:
            change(f)
        before = bad.read_bytes()
        res = rbx_cli("simulate", "--resume", bad, cwd=tmp_path)
        assert res.returncode == 2, res.stderr
        assert one_line(res).startswith(f"rbx: bad.h5.partial: {said}"), res.stderr
        assert bad.read_bytes() == before and not (tmp_path / "bad.h5").exists()


@pytest.mark.long
def test_a_run_file_whose_wall_names_disagree_with_its_config_is_refused_in_one_line(tmp_path):
    """A run file whose root attribute ``wall_names`` lists 3 walls for the strip's 2: ``rbx plot --kind phase``
    gave an IndexError traceback (the records' wall index read against the config's table). Reading the file's
    experiment compares the two: rbx.FileError naming ``wall_names``, one line and exit 2 from the plot."""
    path = tmp_path / "walls.h5"
    rbx.simulate(strip_random(200, trajectories=2, every=1, record=ALL), output=path)
    with h5py.File(path, "r+") as f:
        f.attrs["wall_names"] = np.array(["bottom", "top", "left"], dtype=h5py.string_dtype())
    with pytest.raises(rbx.FileError) as info:
        rbx.open(path).experiment
    assert str(info.value).startswith(f"{path}: wall_names: the root attribute names 3 walls"), str(info.value)
    for kind in ("phase", "orbit"):
        res = rbx_cli("plot", path, "--kind", kind, "-o", tmp_path / "x.png", cwd=tmp_path)
        assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr
        assert one_line(res).startswith("rbx: walls.h5: wall_names:"), res.stderr
    assert not (tmp_path / "x.png").exists()
