"""Seventh round: a reader finishes a journal only under the run's lock, a run that fits a small disk finishes there,
``rbx histogram`` keeps the size limits, and a run moved to its ``.partial`` is named where it is. Each test was
seen to fail on the code before its change."""
import os
import re
import subprocess
import sys
import threading

import numpy as np
import pytest

import rbx
from rbx import journal
from tests.test_interrupt import assert_same_records, read_run, strip_random, write_config
from tests.test_reliability5 import KILL_MID_APPLY

#: a guard against a hang, not a bound
HANG = 600


def _killed_inside_a_commit(folder, at=5):
    """A run of the strip SIGKILLed halfway through copying its ``at``-th checkpoint's journal into the file:
    ``o.h5.partial`` torn, its journal beside it; and the uninterrupted run's records."""
    write_config(folder, strip_random(30_000, trajectories=3, every=7, record=("time", "position", "wall")))
    rbx.simulate(str(folder / "exp.yaml"), output=str(folder / "ref.h5")).close()
    killed = subprocess.run([sys.executable, "-c", KILL_MID_APPLY.replace("{at}", str(at)), "simulate", "exp.yaml",
                             "-o", "o.h5", "--quiet"], cwd=folder, capture_output=True, text=True, timeout=900)
    assert killed.returncode == -9, killed.stderr
    assert journal.pending(folder / "o.h5.partial")
    return read_run(folder / "ref.h5")


@pytest.mark.long
def test_a_reader_finishing_a_journal_holds_the_run_lock_so_a_resume_cannot_finish_under_it(tmp_path, monkeypatch):
    """A reader (``rbx.open``, ``rbx plot``) finished a killed run's pending journal without the run's lock: a
    resume started while the reader copied the pages in (a reader stalled by Ctrl-Z or a loaded machine) applied
    the journal itself, finished the run, and the reader's late pages, of the older checkpoint, were written over
    the complete file. The reader is held inside its copying-in here (an event, no timing) while a resume starts:
    the resume is now refused naming the lock, and once the reader is done it resumes bit for bit."""
    reference = _killed_inside_a_commit(tmp_path)
    partial = tmp_path / "o.h5.partial"
    inside, go = threading.Event(), threading.Event()
    real = journal._apply
    reader_thread = []

    def held(fd, pages, overlay):
        if threading.current_thread() is reader_thread[0] and not inside.is_set():
            inside.set()
            assert go.wait(HANG)
        return real(fd, pages, overlay)
    monkeypatch.setattr(journal, "_apply", held)
    read = {}

    def reader():
        try:
            with rbx.open(partial) as run:
                read["complete"] = run.complete
        except Exception as exc:    # noqa: BLE001 - reported by the main thread
            read["error"] = exc
    thread = threading.Thread(target=reader)
    reader_thread.append(thread)
    thread.start()
    try:
        assert inside.wait(HANG)
        try:
            rbx.resume(tmp_path / "o.h5").close()
            resumed = True
        except rbx.FileError as exc:
            assert "another rbx run is writing it" in str(exc), exc
            resumed = False
    finally:
        go.set()
        thread.join(HANG)
    assert "error" not in read and read["complete"] is False, read
    if not resumed:
        rbx.resume(tmp_path / "o.h5").close()
    assert_same_records(read_run(tmp_path / "o.h5"), reference)
    assert not resumed, "the resume ran while the reader copied its journal in"


# ---- a run that fits a small disk finishes there -------------------------------------------------------------------

#: the command line with small blocks and a checkpoint after each, stopping itself by SIGTERM after its first commit
#: (the file's structure and first block: a run interrupted at its first checkpoint)
STOP_AT_FIRST_COMMIT = """
import os, signal, sys
import rbx.simulation as s, rbx.journal as j
s.BLOCK_WORK = 500
s.CHECKPOINT_SECONDS = 0
real = j.JournaledFile.commit
def commit(self):
    done = real(self)
    os.kill(os.getpid(), signal.SIGTERM)
    return done
j.JournaledFile.commit = commit
from rbx.cli.main import main
sys.argv[0] = "rbx"
main()
"""


def _small_disk_reference(tmp_path):
    cfg = strip_random(20_000, trajectories=3, every=3)          # its file takes 1.8 MB
    write_config(tmp_path, cfg)
    rbx.simulate(str(tmp_path / "exp.yaml"), output=str(tmp_path / "ref.h5")).close()
    return cfg, read_run(tmp_path / "ref.h5")


@pytest.mark.long
def test_a_run_interrupted_at_its_first_checkpoint_on_a_small_disk_is_finished_there(tmp_path):
    """On a 3 MB disk a run interrupted at its first checkpoint (1.23 MB): every resume in place failed with
    'writing failed: No space left on device', and left the file 1.46 MB longer. The resume cut the records back,
    HDF5 put the new chunks in the room that freed inside the file (so through the journal), while the room was
    reserved past the file's end: none was left for the journal. Now such chunks are counted as journal, and the
    room reserved and not used is given back; the resume finishes bit for bit."""
    from tests.test_reliability3 import tmpfs
    cfg, reference = _small_disk_reference(tmp_path)
    with tmpfs(tmp_path / "disk", "3m") as disk:
        write_config(disk, cfg)
        stopped = subprocess.run([sys.executable, "-c", STOP_AT_FIRST_COMMIT, "simulate", "exp.yaml", "-o", "o.h5",
                                  "--quiet"], cwd=disk, capture_output=True, text=True, timeout=900)
        assert stopped.returncode == 143 and "interrupted by SIGTERM after 0 of" in stopped.stderr, stopped.stderr
        rbx.resume(disk / "o.h5").close()
        assert_same_records(read_run(disk / "o.h5"), reference)
        assert sorted(p.name for p in disk.iterdir()) == ["exp.yaml", "o.h5"]


@pytest.mark.long
def test_a_run_whose_checkpoints_span_many_blocks_finishes_on_a_small_disk(tmp_path, monkeypatch):
    """On a 3 MB disk a run of 1.8 MB with small blocks and a checkpoint only at its end stopped 'the disk is
    full … the checkpoint's journal 1.81 MB': the journal a block asks room for summed each block's pages, though
    the journal keeps a page once. Now it is counted over the records since the last commit; the run finishes."""
    import rbx.simulation as simulation
    from tests.test_reliability3 import tmpfs
    cfg, reference = _small_disk_reference(tmp_path)
    monkeypatch.setattr(simulation, "BLOCK_WORK", 500)
    monkeypatch.setattr(simulation, "CHECKPOINT_SECONDS", 1e9)     # no checkpoint before the end
    with tmpfs(tmp_path / "disk", "3m") as disk:
        write_config(disk, cfg)
        rbx.simulate(str(disk / "exp.yaml"), output=str(disk / "o.h5")).close()
        assert_same_records(read_run(disk / "o.h5"), reference)


# ---- rbx histogram keeps the limits every run keeps ------------------------------------------------------------------

@pytest.mark.long
def test_histogram_keeps_the_size_limit_and_a_write_that_finds_no_room_leaves_nothing(tmp_path):
    """`rbx histogram` wrote its return angles with neither output.max_size nor the free space checked (10 kB
    given, 9.6 MB written), and a write that met a full disk left its `.partial.new` filling the disk. The size is
    now checked before the samples are drawn, in one line, exit 2; a write that finds no room (a file size limit
    here, which no check sees) is one line, exit 1, nothing left behind."""
    import resource
    import signal
    from tests.test_first_contact import histogram_config
    from tests.test_reliability3 import one_line, rbx_cli
    conf = histogram_config(tmp_path)
    res = rbx_cli("histogram", conf, "-o", "h.png", "--set", "output.max_size=10kB", cwd=tmp_path)
    line = one_line(res)
    assert res.returncode == 2 and line.startswith("rbx: h.yaml: output.max_size: the run would write about"), line
    assert "more than the limit 10 kB" in line, line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["h.yaml"]

    def limited():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))
    res = rbx_cli("histogram", conf, "-o", "h.png", cwd=tmp_path, preexec_fn=limited)
    line = one_line(res)
    assert res.returncode == 1 and line.startswith("rbx: returns.h5: cannot write: File too large"), line
    assert "nothing was saved" in line, line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["h.yaml"]


def test_the_refusal_of_a_journal_left_without_its_file_names_the_callers_way_to_force(tmp_path):
    """A killed run's journal whose `.partial` was moved away: `rbx.simulate(…)` was told to 'use --force', an
    option it does not have; its refusals say `force=True`, the command line's `--force`."""
    from tests.test_reliability3 import one_line, rbx_cli
    write_config(tmp_path, strip_random(300, trajectories=2, every=1, record=("time",)))
    (tmp_path / "o.h5.partial.journal").write_bytes(b"rbx journal 3\n")
    with pytest.raises(rbx.FileError, match="is not here") as info:
        rbx.simulate(str(tmp_path / "exp.yaml"), output=str(tmp_path / "o.h5"))
    assert "force=True" in str(info.value) and "--force" not in str(info.value), info.value
    line = one_line(rbx_cli("simulate", "exp.yaml", "-o", "o.h5", cwd=tmp_path))
    assert "--force" in line and "force=True" not in line, line
    assert (tmp_path / "o.h5.partial.journal").exists() and not (tmp_path / "o.h5").exists()


def test_reading_an_output_whose_run_lies_in_its_partial_names_the_partial(tmp_path):
    """A resume in place renames OUT.h5 to OUT.h5.partial while it runs; killed, it leaves no OUT.h5, and every
    reader said only 'file not found'. The line now names the `.partial` and how to continue."""
    from tests.test_reliability3 import one_line, rbx_cli
    write_config(tmp_path, strip_random(300, trajectories=2, every=1, record=("time",)))
    rbx.simulate(str(tmp_path / "exp.yaml"), output=str(tmp_path / "o.h5")).close()
    os.rename(tmp_path / "o.h5", tmp_path / "o.h5.partial")
    with pytest.raises(rbx.FileError, match="o.h5.partial holds its run") as info:
        rbx.open(tmp_path / "o.h5")
    assert "rbx simulate --resume" in str(info.value), info.value
    line = one_line(rbx_cli("plot", "o.h5", "--kind", "orbit", "-o", "x.png", cwd=tmp_path))
    assert line.startswith("rbx: o.h5: file not found, but o.h5.partial holds its run"), line


# ---- an output is never named as a run's own files -------------------------------------------------------------------

from tests.test_interrupt import invoke, tiny_blocks  # noqa: E402,F401 - the fixture, used by the tests below


def _refusal(res):
    """The one line a refused CliRunner invocation printed (exit 2)."""
    assert res.exit_code == 2, (res.exit_code, res.stderr)
    lines = [x for x in res.stderr.strip().splitlines() if x.startswith("rbx:")]
    assert len(lines) == 1 and "Traceback" not in res.stderr, res.stderr
    return lines[0]


def test_an_output_named_as_a_runs_partial_is_refused_on_every_path(tmp_path, tiny_blocks):
    """`-o r.h5.partial` was accepted by a new run and by a resume: the finished run, under the name rbx gives r.h5's
    unfinished file, was later called 'left by a run that was killed', deleted by `--force` to r.h5 without a word
    and renamed by `--resume r.h5.partial`. Such an output is now refused in one line, exit 2, before anything is
    written; a killed run's `.partial` given to `--resume` (its input) still continues."""
    exp = write_config(tmp_path, strip_random(1500, trajectories=2, every=3, record=("time",)))
    tiny_blocks(None)
    line = _refusal(invoke(exp, "-o", tmp_path / "r.h5.partial"))
    assert "r.h5.partial is the name rbx gives" in line and "r.h5's" in line, line
    with pytest.raises(rbx.FileError, match="is the name rbx gives"):
        rbx.simulate(str(exp), output=str(tmp_path / "r.h5.partial"))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["exp.yaml"]

    tiny_blocks(2)                    # an interrupted run.h5
    assert invoke(exp, "-o", tmp_path / "run.h5").exit_code == 130
    before = (tmp_path / "run.h5").read_bytes()
    tiny_blocks(None)
    for force in ((), ("--force",)):
        line = _refusal(invoke("--resume", tmp_path / "run.h5", "-o", tmp_path / "x.h5.partial", *force))
        assert "x.h5.partial is the name rbx gives" in line, line
    with pytest.raises(rbx.FileError, match="is the name rbx gives"):
        rbx.resume(tmp_path / "run.h5", output=tmp_path / "x.h5.partial", force=True)
    with pytest.raises(rbx.FileError, match="is the name rbx gives"):
        rbx.resume(tmp_path / "run.h5", output=tmp_path / "run.h5.partial", force=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["exp.yaml", "run.h5"]
    assert (tmp_path / "run.h5").read_bytes() == before

    # a killed run's .partial is the input of --resume: it continues, in place and into -o
    os.rename(tmp_path / "run.h5", tmp_path / "k.h5.partial")
    res = invoke("--resume", tmp_path / "k.h5.partial", "-o", tmp_path / "other.h5")
    assert res.exit_code == 0, res.stderr
    res = invoke("--resume", tmp_path / "k.h5.partial")
    assert res.exit_code == 0, res.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["exp.yaml", "k.h5", "other.h5"]
    assert bool(read_run(tmp_path / "k.h5")["attrs"]["complete"])
    assert_same_records(read_run(tmp_path / "k.h5"), read_run(tmp_path / "other.h5"))


# ---- a file whose datasets cannot grow is refused before a resume writes anything ------------------------------------

def _rewrite_records(path, how):
    """Rewrite the record datasets and ``step`` of the run file ``path`` as they cannot grow: ``contiguous`` (as
    ``h5repack -l CONTI`` writes them) or chunked with a fixed maximum shape, their values and attributes kept."""
    import h5py
    with h5py.File(path, "r+") as f:
        g = f["collisions"]
        for name in [n for n in g if n not in ("count", "trajectory", "record", "axis", "axis2")]:
            ds = g[name]
            data, attrs = ds[...], {k: v for k, v in ds.attrs.items() if k != "DIMENSION_LIST"}
            del g[name]
            if how == "contiguous":
                new = g.create_dataset(name, data=data)
            else:
                new = g.create_dataset(name, data=data, chunks=True, maxshape=data.shape)
            assert (new.chunks is None) == (how == "contiguous")
            for k, v in attrs.items():
                new.attrs[k] = v


@pytest.mark.parametrize("how", ["contiguous", "fixed maximum"])
def test_a_run_file_whose_datasets_cannot_grow_is_refused_before_a_resume_writes(how, tmp_path, tiny_blocks):
    """An interrupted run file rewritten with its datasets contiguous (as a repack does) or chunked with a fixed
    maximum shape: `rbx.open` and `rbx plot` read it, but `--resume` failed with a traceback ('Only chunked datasets
    can be resized', 'dimension cannot exceed the existing maximal size'), exit 1, and left a copy under the -o
    name. It is now refused in one line naming the dataset, exit 2, with nothing written, in place or into -o."""
    exp = write_config(tmp_path, strip_random(1500, trajectories=2, every=3, record=("time", "position")))
    tiny_blocks(2)
    assert invoke(exp, "-o", tmp_path / "run.h5").exit_code == 130
    tiny_blocks(None)
    _rewrite_records(tmp_path / "run.h5", how)
    with rbx.open(tmp_path / "run.h5") as run:
        assert not run.complete and run.read("time").shape[1] > 1
    before = (tmp_path / "run.h5").read_bytes()
    for args in (("-o", tmp_path / "out.h5"), ()):
        line = _refusal(invoke("--resume", tmp_path / "run.h5", *args))
        assert "run.h5: collisions/" in line and "cannot be extended" in line, line
        assert "cannot be resumed" in line, line
        assert sorted(p.name for p in tmp_path.iterdir()) == ["exp.yaml", "run.h5"]
        assert (tmp_path / "run.h5").read_bytes() == before
    with pytest.raises(rbx.ConfigError, match="cannot be extended"):
        rbx.resume(tmp_path / "run.h5", output=tmp_path / "out.h5")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["exp.yaml", "run.h5"]


# ---- a resume in place in a read-only folder says so ---------------------------------------------------------------

def test_a_resume_into_itself_in_a_read_only_folder_says_the_folder_cannot_be_written(tmp_path, tiny_blocks):
    """`--resume OUT.h5` of an interrupted run on a read-only file system said 'OUT.h5.partial: cannot write:
    Read-only file system', naming a file that does not exist and giving no way on. It now says the run cannot be
    resumed there, its folder cannot be written, and to resume it into a writable folder with -o, which works."""
    from tests.test_reliability3 import tmpfs
    exp = write_config(tmp_path, strip_random(1500, trajectories=2, every=3, record=("time",)))
    with tmpfs(tmp_path / "disk", "16m") as disk:
        tiny_blocks(2)
        assert invoke(exp, "-o", disk / "i.h5").exit_code == 130
        tiny_blocks(None)
        res = subprocess.run(["mount", "-o", "remount,ro", str(disk)], capture_output=True, text=True)
        if res.returncode != 0:
            pytest.skip(f"cannot make the tmpfs read-only: {res.stderr.strip()}")
        line = _refusal(invoke("--resume", disk / "i.h5"))
        assert "i.h5.partial" not in line and "i.h5: cannot be resumed in place" in line, line
        assert "its folder cannot be written" in line and "into a writable folder with -o" in line, line
        with pytest.raises(rbx.FileError, match="its folder cannot be written"):
            rbx.resume(disk / "i.h5")
        res = invoke("--resume", disk / "i.h5", "-o", tmp_path / "out.h5")
        assert res.exit_code == 0, res.stderr
        assert sorted(p.name for p in disk.iterdir()) == ["i.h5"]
    assert bool(read_run(tmp_path / "out.h5")["attrs"]["complete"])


@pytest.mark.long
def test_a_figure_writers_remains_after_sigkill_are_removed_by_the_next_write_of_that_figure(tmp_path):
    """A writer killed mid-write (SIGKILL runs no clean-up) left its hidden new name (.rbx-XXXX.png) beside the
    figure for ever. The next write of the same figure removes such remains that no live writer holds; those of
    another figure, of a writer still holding its lock, and anything else stay."""
    import hashlib
    exp = rbx.load(os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "configs", "examples",
                                "strip.yaml"), {"run.collisions": 50})
    rbx.simulate(exp, output=str(tmp_path / "s.h5"))
    h = hashlib.sha1(b"orbit.png").hexdigest()[:8]
    dead = tmp_path / f".rbx-{h}-0badf00d.png"          # as a killed writer leaves it: no process holds it
    dead.write_bytes(b"\x89PNG half")
    held = tmp_path / f".rbx-{h}-1234abcd.png"          # a writer still at work holds its lock
    held.write_bytes(b"")
    other = tmp_path / f".rbx-{hashlib.sha1(b'phase.png').hexdigest()[:8]}-0badf00d.png"     # another figure's
    other.write_bytes(b"")
    holder = subprocess.Popen([sys.executable, "-c", "import fcntl, os, sys, time\n"
                               f"fd = os.open({str(held)!r}, os.O_RDONLY); fcntl.flock(fd, fcntl.LOCK_EX)\n"
                               "print('held', flush=True); time.sleep(60)"], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        res = subprocess.run([os.path.join(os.path.dirname(sys.executable), "rbx"), "plot", "s.h5", "--kind",
                              "orbit", "-o", "orbit.png"], cwd=tmp_path, capture_output=True, text=True, timeout=HANG)
        assert res.returncode == 0, res.stderr
    finally:
        holder.kill()
        holder.wait()
    assert not dead.exists() and held.exists() and other.exists()
    assert (tmp_path / "orbit.png").read_bytes()[:4] == b"\x89PNG"
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".rbx-")) == sorted([held.name, other.name])


def test_a_saved_state_of_the_wrong_kind_and_an_impossible_ball_are_a_damaged_file(tmp_path):
    """final/alive stored as bytes read as all False (0 exits of 2000 reported, the plot saying none reached the
    exit); a root attribute kappa of NaN drew an empty Birkhoff map with exit 0."""
    import shutil

    import h5py
    import numpy as np
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    good = tmp_path / "good.h5"
    rbx.simulate(rbx.load(os.path.join(root, "configs", "examples", "escape-sinai.yaml"),
                          {"run.trajectories": 50, "run.collisions": 200}), output=str(good))
    cases = {"alive.h5": (lambda f: (f.__delitem__("final/alive"), f.create_dataset("final/alive", data=np.array([b"x"] * 50))),
                          "final/alive: has dtype |S1; the layout says booleans"),
             "count.h5": (lambda f: (f.__delitem__("final/collisions"),
                                     f.create_dataset("final/collisions", data=np.zeros(50))),
                          "final/collisions: has dtype float64; the layout says integers"),
             "kappa.h5": (lambda f: f.attrs.__setitem__("kappa", np.nan), "kappa: is nan; the layout says a positive"),
             "radius.h5": (lambda f: f.attrs.__setitem__("radius", -1.0), "radius: is -1.0; the layout says a positive")}
    for name, (change, words) in cases.items():
        shutil.copy(good, tmp_path / name)
        with h5py.File(tmp_path / name, "r+") as f:
            change(f)
        with pytest.raises(rbx.FileError, match=words.replace("|", r"\|")):
            rbx.open(str(tmp_path / name))
    res = subprocess.run([os.path.join(os.path.dirname(sys.executable), "rbx"), "plot", "alive.h5", "--kind",
                          "escape", "-o", "e.png"], cwd=tmp_path, capture_output=True, text=True, timeout=HANG)
    assert res.returncode == 2 and res.stderr == ("rbx: alive.h5: final/alive: has dtype |S1; the layout says "
                                                  "booleans (a damaged or crafted file)\n"), res.stderr


def test_reading_a_run_still_being_written_says_so(tmp_path):
    """Opening OUT.h5 while its run was still writing OUT.h5.partial said the run was 'stopped or killed before it
    was renamed: read OUT.h5.partial', advice that reading the .partial then refused (a run is writing it)."""
    import time
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    proc = subprocess.Popen([os.path.join(os.path.dirname(sys.executable), "rbx"), "simulate",
                             os.path.join(root, "configs", "examples", "strip.yaml"), "-o", "k.h5", "--collisions",
                             "10000000000", "--quiet", "--set", "output.record=[]"], cwd=tmp_path,
                            stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + HANG
        while not (tmp_path / "k.h5.partial").exists() or not (tmp_path / "k.h5.lock").exists():
            assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read()
            time.sleep(0.05)
        with pytest.raises(rbx.FileError, match=r"k.h5: another rbx run is writing it \(pid "):
            rbx.open(str(tmp_path / "k.h5"))
    finally:
        proc.kill()
        proc.wait()
    with pytest.raises(rbx.FileError, match="stopped or killed before it was renamed"):      # once it is dead
        rbx.open(str(tmp_path / "k.h5"))


@pytest.mark.long
def test_a_file_name_holding_a_newline_is_said_on_one_line(tmp_path):
    """A file name holding a newline (or a tab, a carriage return) split the one line of an error or of the
    summary in two: each is now written with its control characters as escapes."""
    rbx_exe = os.path.join(os.path.dirname(sys.executable), "rbx")
    write_config(tmp_path, strip_random(10, trajectories=1, record=("time",)))
    missing = subprocess.run([rbx_exe, "simulate", "no\nsuch.yaml"], cwd=tmp_path, capture_output=True, text=True,
                             timeout=HANG)
    assert missing.returncode == 2 and missing.stderr == "rbx: no\\nsuch.yaml: file not found\n", missing.stderr
    wrote = subprocess.run([rbx_exe, "simulate", "exp.yaml", "-o", "a\nb\r.h5"], cwd=tmp_path, capture_output=True,
                           text=True, timeout=HANG)
    assert wrote.returncode == 0 and (tmp_path / "a\nb\r.h5").is_file(), wrote.stderr
    assert len(wrote.stderr.splitlines()) == 1 and wrote.stderr.startswith("rbx: wrote a\\nb\\r.h5"), wrote.stderr
    again = subprocess.run([rbx_exe, "simulate", "exp.yaml", "-o", "a\nb\r.h5"], cwd=tmp_path, capture_output=True,
                           text=True, timeout=HANG)
    assert again.returncode == 2 and len(again.stderr.splitlines()) == 1, again.stderr
    assert again.stderr.startswith("rbx: a\\nb\\r.h5: exists"), again.stderr


@pytest.mark.long
def test_records_past_a_trajectorys_count_in_a_finished_run_are_a_damaged_file(tmp_path):
    """``collisions/count`` set to 0 in a finished run: every plot kind drew all its rows as records. The slots
    past a trajectory's count hold the fill (NaN, −1) in every file rbx finishes: a value there is refused as
    read, naming the dataset, the trajectory and the record."""
    import h5py

    from rbx.paths import FileError
    write_config(tmp_path, strip_random(60, trajectories=2, every=1, record=("time", "position", "wall")))
    good = tmp_path / "good.h5"
    rbx.simulate(str(tmp_path / "exp.yaml"), output=str(good)).close()
    run = rbx.open(good)
    assert run.complete and (run.count == 61).all() and np.isfinite(run.position).all()
    for count, first in ((0, 0), (60, 60)):
        bad = tmp_path / f"count{count}.h5"
        bad.write_bytes(good.read_bytes())
        with h5py.File(bad, "r+") as f:
            f["collisions/count"][1] = count
        run = rbx.open(bad)
        assert np.isfinite(run.read("time", [0])).all()            # the trajectory that is whole reads
        with pytest.raises(FileError, match=rf"collisions/time: holds a value at trajectory 1, record {first}, past "
                                            rf"the {count} records collisions/count says it wrote"):
            run.time
        res = subprocess.run([os.path.join(os.path.dirname(sys.executable), "rbx"), "plot", str(bad), "--kind",
                              "orbit", "-o", str(tmp_path / "o.png")], capture_output=True, text=True, timeout=HANG)
        assert res.returncode == 2 and "past the" in res.stderr and len(res.stderr.splitlines()) == 1, res.stderr
        assert not (tmp_path / "o.png").exists()


@pytest.mark.long
def test_numpys_floating_point_warnings_on_crafted_values_do_not_reach_stderr(tmp_path):
    """Positions multiplied by 1e300 in a finished run: ``rbx plot`` printed NumPy's overflow warnings, seven lines
    with the source lines that raised them, before its own. Its stderr is its one line now."""
    import h5py
    huge = tmp_path / "huge.h5"
    example = os.path.join(os.path.dirname(rbx.__file__), "..", "configs", "examples", "rectangle.yaml")
    rbx.simulate(rbx.load(example, {"run.collisions": 2000}), output=str(huge)).close()     # drawn as a density
    with h5py.File(huge, "r+") as f:
        f["collisions/position"][...] = f["collisions/position"][...] * 1e300
    lines = []
    for kind in ("orbit", "phase", "series"):
        res = subprocess.run([os.path.join(os.path.dirname(sys.executable), "rbx"), "plot", str(huge), "--kind",
                              kind, "-o", str(tmp_path / f"{kind}.png")], capture_output=True, text=True, timeout=HANG)
        lines.append(res.stderr.splitlines())
        assert len(lines[-1]) == 1 and lines[-1][0].startswith("rbx: "), res.stderr
    assert any("wrote" in line[0] for line in lines)


@pytest.mark.long
def test_a_signal_after_the_figure_is_written_leaves_exit_0(tmp_path):
    """A Ctrl-C (or SIGTERM) that came just after ``rbx plot`` printed 'wrote fig.png' ended it with 'interrupted by
    SIGINT; nothing written' and exit 130, the figure replaced (4 of 30 tries). The signal is sent here from inside
    the summary line, once it is printed: no timing."""
    write_config(tmp_path, strip_random(30, trajectories=1, every=1, record=("time", "position")))
    rbx.simulate(str(tmp_path / "exp.yaml"), output=str(tmp_path / "o.h5")).close()
    code = ("import os, signal, sys\n"
            "from rbx.cli import main, plot\n"
            "said = plot.summary\n"
            "def summary(quiet, message):\n"
            "    said(quiet, message)\n"
            "    os.kill(os.getpid(), signal.SIG)\n"
            "    for _ in range(10 ** 5): pass\n"         # the handler runs between bytecodes
            "plot.summary = summary\n"
            "sys.argv = ['rbx', 'plot', 'o.h5', '--kind', 'orbit', '-o', 'o.png']\n"
            "main.main()\n")
    for sig in ("SIGINT", "SIGTERM"):
        res = subprocess.run([sys.executable, "-c", code.replace("signal.SIG)", f"signal.{sig})")], cwd=tmp_path,
                             capture_output=True, text=True, timeout=HANG)
        assert res.returncode == 0, (sig, res.returncode, res.stderr)
        assert res.stderr.startswith("rbx: wrote o.png") and len(res.stderr.splitlines()) == 1, res.stderr


@pytest.mark.parametrize("example, orientation, size", [("circle.yaml", 1e17, "1e+17"),
                                                        ("box.yaml", [1e155, 0.0, 0.0], "1e+155"),
                                                        ("box.yaml", [1e300, 1e300, 0.0], "1.41e+300")])
def test_an_orientation_too_large_to_hold_a_turn_is_refused(example, orientation, size, tmp_path):
    """A 3D ``initial.orientation`` of [1e155, 0, 0] squared to infinity: every recorded orientation was NaN in a
    run that ended complete, exit 0. A 2D one of 1e17 never moved (its last digit is 16 rad), so a hemisphere rule
    read the same side at every collision (1000 of 1000 smooth where the angle reduced gives 487 rough). Both are
    refused in one line, at load and from the command line; a large angle within the bound runs."""
    path = os.path.join(os.path.dirname(rbx.__file__), "..", "configs", "examples", example)
    n = 2 if example == "circle.yaml" else 3
    state = {"position": [0.0] * n if n == 2 else [0.5] * n, "velocity": [1.0, 0.3, 0.2][:n], "orientation": orientation}
    with pytest.raises(rbx.ConfigError, match=rf"initial.orientation: too large: {re.escape(size)} rad \(at most 1e\+08"):
        rbx.load(path, {"initial": state, "run.trajectories": 1})
    with pytest.raises(rbx.ConfigError, match=r"initial\[1\].orientation: too large"):
        rbx.load(path, {"initial": [{**state, "orientation": 0.5 if n == 2 else [0.5] * 3}, state],
                        "run.trajectories": 2})
    res = subprocess.run([os.path.join(os.path.dirname(sys.executable), "rbx"), "simulate", path, "-o", "o.h5",
                          "--trajectories", "1", "--set", f"initial={state}".replace("'", "")],
                         cwd=tmp_path, capture_output=True, text=True, timeout=HANG)
    assert res.returncode == 2 and len(res.stderr.splitlines()) == 1 and "too large" in res.stderr, res.stderr
    within = {**state, "orientation": 9e7 if n == 2 else [5e7, 5e7, 0.0]}
    run = rbx.simulate(rbx.load(path, {"initial": within, "run.trajectories": 1, "run.collisions": 50,
                                       "output.record": ["orientation"]}))
    assert np.isfinite(run.orientation).all() and run.complete


@pytest.mark.long
def test_an_animation_whose_frames_do_not_fit_in_memory_is_refused_before_it_is_drawn(tmp_path):
    """``rbx animate --frames 400 --dpi 600`` (both within their ranges) under ``ulimit -v`` 3 GB ended in a
    MemoryError traceback after drawing for a while: a GIF keeps every frame, about 24 MB each at dpi 600. The
    frames' memory is estimated first and refused in one line naming --frames; a GIF that fits is written."""
    import resource
    write_config(tmp_path, strip_random(40, trajectories=1, every=1,
                                        record=("time", "position", "velocity", "orientation")))
    rbx.simulate(str(tmp_path / "exp.yaml"), output=str(tmp_path / "o.h5")).close()

    def limited():
        resource.setrlimit(resource.RLIMIT_AS, (3 * 10 ** 9, resource.RLIM_INFINITY))
    exe = os.path.join(os.path.dirname(sys.executable), "rbx")
    res = subprocess.run([exe, "animate", "o.h5", "-o", "big.gif", "--frames", "400", "--dpi", "600"], cwd=tmp_path,
                         capture_output=True, text=True, timeout=HANG, preexec_fn=limited)
    assert res.returncode == 2 and res.stderr.startswith("rbx: --frames: 400 frames of 3600 × 3240 pixels (--dpi "
                                                         "600) need about ") and len(res.stderr.splitlines()) == 1, \
        res.stderr
    assert not list(tmp_path.glob("*.gif")) and not list(tmp_path.glob(".rbx-*"))
    res = subprocess.run([exe, "animate", "o.h5", "-o", "small.gif", "--frames", "10"], cwd=tmp_path,
                         capture_output=True, text=True, timeout=HANG, preexec_fn=limited)
    assert res.returncode == 0 and (tmp_path / "small.gif").is_file(), res.stderr


@pytest.mark.long
def test_a_stored_config_larger_than_a_config_may_be_is_refused_before_it_is_parsed(tmp_path):
    """A run file whose root ``config`` attribute held 80 MB of text (a comment) took 44 s to open or plot, exit 0:
    a config file is bounded (64 MiB), the stored one was not."""
    import h5py

    from rbx.paths import MAX_CONFIG_BYTES, FileError
    write_config(tmp_path, strip_random(20, trajectories=1, record=("time",)))
    big = tmp_path / "big.h5"
    rbx.simulate(str(tmp_path / "exp.yaml"), output=str(big)).close()
    with h5py.File(big, "r+") as f:
        f.attrs["config"] = f.attrs["config"] + "\n#" + "x" * MAX_CONFIG_BYTES
    with pytest.raises(FileError, match=r"config: the root attribute holds 64 MiB of text, more than the 64 MiB a "
                                        r"config may have"):
        rbx.open(big)


def test_a_time_that_runs_back_is_a_damaged_file(tmp_path):
    """A run file edited so that a trajectory's times run backwards opened, plotted and animated with exit 0; no
    run writes that. Refused as the field is read, naming the trajectory and the record."""
    import h5py

    from rbx.paths import FileError
    write_config(tmp_path, strip_random(30, trajectories=2, every=1, record=("time", "position")))
    path = tmp_path / "o.h5"
    rbx.simulate(str(tmp_path / "exp.yaml"), output=str(path)).close()
    assert np.all(np.diff(rbx.open(path).time, axis=1) >= 0)
    with h5py.File(path, "r+") as f:
        t = f["collisions/time"][...]
        t[1, 10:] = t[1, 10:][::-1].copy()
        f["collisions/time"][...] = t
    run = rbx.open(path)
    assert np.all(np.diff(run.read("time", [0]), axis=1) >= 0)
    with pytest.raises(FileError, match=r"collisions/time: runs back at trajectory 1, from record 10 "):
        run.time


def test_a_rank_1_direction_of_any_size_is_the_direction_it_names(tmp_path):
    """A 3D rank-1 ``direction: [1e200, 0, 0]`` squared to infinity: the wall then reflected specularly (the run bit
    for bit the rank-0 one, the file recording rank 1), with NumPy's overflow warnings; [1e-200, 0, 0] was refused
    as 'normal to wall top'. A direction is scaled before it is normalised: each runs as [1, 0, 0]."""
    path = os.path.join(os.path.dirname(rbx.__file__), "..", "configs", "examples", "plates.yaml")
    finals = []
    for direction in ([1.0, 0.0, 0.0], [1e200, 0.0, 0.0], [1e-200, 0.0, 0.0], [3e-320, 0.0, 0.0]):
        exp = rbx.load(path, {"boundary": {"default": {"rule": "constant", "rank": 1, "direction": direction}},
                              "run.collisions": 300, "run.trajectories": 1, "output.record": ["velocity"]})
        finals.append(rbx.simulate(exp).velocity[0, -1])
    specular = rbx.load(path, {"boundary": {"default": {"rule": "constant", "rank": 0}}, "run.collisions": 300,
                               "run.trajectories": 1, "output.record": ["velocity"]})
    assert all(np.array_equal(f, finals[0]) for f in finals)
    assert not np.array_equal(rbx.simulate(specular).velocity[0, -1], finals[0])
    with pytest.raises(rbx.ConfigError, match="is normal to wall 'top'"):
        rbx.load(path, {"boundary": {"default": {"rule": "constant", "rank": 1, "direction": [0.0, 0.0, 1e200]}}})


@pytest.mark.long
def test_an_output_name_too_long_for_the_files_beside_it_is_refused_as_such(tmp_path):
    """An output of 249 characters (a legal name) was refused with 'OUT.partial: is unreadable, not a regular file:
    remove it', of a file that was not there (the names rbx makes beside it are longer than the file system
    takes), or at 228–235 characters with 'cannot create the run's lock file: File name too long'. The line now
    says what is wrong, before any work; a name within the room runs."""
    from rbx.paths import OWN_NAME_ROOM
    write_config(tmp_path, strip_random(20, trajectories=1, record=("time",)))
    exe = os.path.join(os.path.dirname(sys.executable), "rbx")
    most = os.pathconf(tmp_path, "PC_NAME_MAX")
    for length in (most - 6, most - OWN_NAME_ROOM + 1):
        name = "b" * (length - 3) + ".h5"
        res = subprocess.run([exe, "simulate", "exp.yaml", "-o", name], cwd=tmp_path, capture_output=True, text=True,
                             timeout=HANG)
        assert res.returncode == 2 and res.stderr == (
            f"rbx: {name}: its name is {length} bytes long; rbx keeps its own files beside it under names up to "
            f"{OWN_NAME_ROOM} bytes longer, and this file system takes names of at most {most} bytes: give a name "
            f"of at most {most - OWN_NAME_ROOM} bytes\n"), res.stderr
    assert os.listdir(tmp_path) == ["exp.yaml"]
    name = "b" * (most - OWN_NAME_ROOM - 3) + ".h5"
    res = subprocess.run([exe, "simulate", "exp.yaml", "-o", name, "--quiet"], cwd=tmp_path, capture_output=True,
                         text=True, timeout=HANG)
    assert res.returncode == 0 and rbx.open(tmp_path / name).complete, res.stderr


@pytest.mark.long
def test_a_link_or_fifo_at_a_scratch_name_is_never_written_through(tmp_path):
    """A symbolic link named ``RESULTS.nc.partial.tmp`` (a study's results before they replace its ``.partial``)
    was written through: the file it named, in any folder, overwritten with netCDF, exit 0. A FIFO there held the
    study for ever after all its points ran; a journal's ``.journal.tmp`` was the same. Each scratch name is
    checked with the run's own names before any work, and created exclusively when written."""
    from rbx import journal
    (tmp_path / "study.yaml").write_text(
        "base: " + os.path.join(os.path.dirname(rbx.__file__), "..", "configs", "examples", "sinai.yaml") + "\n"
        "vary: {ball.inertia: [0.2, 0.4]}\nmeasure: [mean_free_path]\nensemble: {trajectories: 2, collisions: 200}\n")
    victim = tmp_path / "victim.txt"
    victim.write_text("mine\n")
    exe = os.path.join(os.path.dirname(sys.executable), "rbx")
    scratch = tmp_path / "r.nc.partial.tmp"
    for make in (lambda: scratch.symlink_to(victim), lambda: os.mkfifo(scratch), lambda: scratch.mkdir()):
        make()
        res = subprocess.run([exe, "sweep", "study.yaml", "-o", "r.nc"], cwd=tmp_path, capture_output=True, text=True,
                             timeout=HANG)
        assert res.returncode == 2 and res.stderr.startswith("rbx: r.nc.partial.tmp: is ") and \
            "rbx keeps its own files under this name" in res.stderr and len(res.stderr.splitlines()) == 1, res.stderr
        assert victim.read_text() == "mine\n" and not (tmp_path / "r.nc").exists()
        (scratch.rmdir if scratch.is_dir() and not scratch.is_symlink() else scratch.unlink)()
    # a journal's scratch name that appears while a run writes: the commit fails as an I/O error does (the run
    # stops at its last checkpoint), and nothing is written through it
    link = tmp_path / "o.h5.partial.journal.tmp"
    link.symlink_to(victim)
    with pytest.raises(OSError, match="is a symbolic link"):
        journal._write_journal(str(link), [b"journal"])
    assert victim.read_text() == "mine\n"


@pytest.mark.long
@pytest.mark.parametrize("when", ["sampling", "drawing"])
def test_a_signal_late_in_rbx_histogram_says_what_was_written(when, tmp_path):
    """A SIGINT in the last block of the sampling was noted and not acted on: both files written, exit 0. One that
    came after the samples' file was replaced said 'nothing written'. The signal is sent here from inside the
    sampling (its last call) or the drawing (before either file is put in place): no timing."""
    path = os.path.join(os.path.dirname(rbx.__file__), "..", "configs", "experiments", "histogram.yaml")
    code = ("import os, signal, sys\n"
            "from rbx.cli import main\n"
            "import rbx.histogram, rbx.plotting\n"
            "def late(f):\n"
            "    def g(*a, **k):\n"
            "        out = f(*a, **k)\n"
            "        os.kill(os.getpid(), signal.SIGINT)\n"
            "        for _ in range(10 ** 5): pass\n"
            "        return out\n"
            "    return g\n"
            + ("rbx.histogram.return_experiment = late(rbx.histogram.return_experiment)\n" if when == "sampling" else
               "rbx.plotting.histogram_figure = late(rbx.plotting.histogram_figure)\n") +
            f"sys.argv = ['rbx', 'histogram', {path!r}, '-o', 'h.png', '--data', 'h.h5', '--trajectories', '200']\n"
            "main.main()\n")
    res = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=HANG)
    assert res.returncode == 130, (res.returncode, res.stderr)
    if when == "sampling":
        assert res.stderr.strip().splitlines()[-1] == "rbx: interrupted by SIGINT; nothing written", res.stderr
        assert not (tmp_path / "h.h5").exists() and not (tmp_path / "h.png").exists()
    else:   # the samples are put in place once the figure is drawn, just before it: neither is
        assert res.stderr.strip().splitlines()[-1] == "rbx: interrupted by SIGINT; nothing written", res.stderr
        assert not (tmp_path / "h.h5").exists() and not (tmp_path / "h.png").exists()


def test_a_tiny_kappa_and_huge_exponents_are_said_as_what_they_are():
    """``ball.inertia: 1e-320`` was refused as 'too large: 1e+161 overflows when squared' (the sampled spin
    1/(R√κ)), naming no κ; exponents of runs at speeds near 1e150 printed as 150-digit numbers."""
    from rbx.analysis import plus_minus
    from rbx.cli.lyapunov import _six
    path = os.path.join(os.path.dirname(rbx.__file__), "..", "configs", "examples", "sinai.yaml")
    with pytest.raises(rbx.ConfigError, match=r"ball.inertia: κ = 1e-320 is too small: sampled spins reach "
                                              r"1/\(R√κ\) = 1e\+161, which overflows when squared"):
        rbx.load(path, {"ball.inertia": 1e-320})
    assert _six(1.2e150, True) == " 1.200000e+150" and _six(0.572837, True) == " 0.572837"
    assert plus_minus(1.2345e150, 3.4e148) == "1.234e150 ± 0.034e150" and plus_minus(123456.0, 234.0) == "123460 ± 230"


def test_a_rank_the_ball_cannot_have_is_a_damaged_file():
    """A 3D run file with `collisions/rank = 7` was read and drawn with exit 0 (ranks run −1 … 2 in 3D; below −1
    was refused already). Refused as read, with the range of the ball's dimension."""
    import shutil
    import tempfile

    import h5py

    from rbx.paths import FileError
    folder = tempfile.mkdtemp()
    try:
        path = os.path.join(os.path.dirname(rbx.__file__), "..", "configs", "examples", "box.yaml")
        out = os.path.join(folder, "b.h5")
        rbx.simulate(rbx.load(path, {"run.collisions": 30, "run.trajectories": 1, "output.record": ["rank"]}),
                     output=out).close()
        assert set(np.unique(rbx.open(out).rank)) <= {-1, 0, 1, 2}
        with h5py.File(out, "r+") as f:
            f["collisions/rank"][0, 5] = 7
        with pytest.raises(FileError, match=r"collisions/rank: holds 7 at trajectory 0, record 5: a roughness rank "
                                            r"outside −1 … 2 \(a 3D ball\)"):
            rbx.open(out).rank
    finally:
        shutil.rmtree(folder)
