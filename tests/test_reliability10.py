"""Twentieth round: the lock's scratch name written through a link planted at it (or held open by a FIFO), a run
whose final rename failed reported as written with exit 0, and return angles whose datasets lie in other files or
are declared larger than memory. Each reproduction runs the real command line (or the API) in a subprocess; each
test was seen to fail on the code before it."""
import os
import subprocess
import sys

import h5py
import numpy as np
import pytest

from tests.test_histogram import write_config as histogram_config
from tests.test_reliability8 import HANG, cli, wrapped


def _config(tmp_path):
    return histogram_config(tmp_path / "h.yaml", run="{collisions: 2000, trajectories: 2, seed: 2}",
                            initial="{sample: billiard}")


@pytest.mark.parametrize("planted", ["link", "fifo", "link at the random name"])
def test_the_locks_scratch_name_is_never_written_through_what_is_planted_there(tmp_path, planted):
    """A link at OUT.h5.lock.new.<pid>.<thread> (a name known in advance from the process and its thread) had
    rbx.simulate write the lock into the file it pointed to, outside the run, and left OUT.h5.lock a link to it; a
    FIFO there held the run in open() past SIGTERM. The scratch name now has a random part and is created
    exclusively, never followed: the file pointed to is untouched, the run is written, exit 0. A link planted at
    the very name drawn is passed over for the next one."""
    conf = _config(tmp_path)
    victim = tmp_path / "victim.txt"
    victim.write_text("notes, not rbx's\n")
    make = "os.mkfifo(name)" if planted == "fifo" else f"os.symlink({str(victim)!r}, name)"
    if planted == "link at the random name":
        # the first random part drawn is known: the link is put at that very name
        plant = ("import os, threading, itertools, rbx.locks\n"
                 "_tokens = itertools.chain(['deadbeef'], itertools.repeat('0badcafe'))\n"
                 "rbx.locks.secrets.token_hex = lambda n: next(_tokens)\n"
                 f"name = f'ln.h5.lock.new.{{os.getpid()}}.{{threading.get_ident()}}.deadbeef'\n{make}\n")
    else:
        plant = (f"import os, threading\nname = f'ln.h5.lock.new.{{os.getpid()}}.{{threading.get_ident()}}'\n"
                 f"{make}\n")
    code = f"{plant}import rbx\nrun = rbx.simulate({str(conf)!r}, output='ln.h5')\nprint(run.complete)\n"
    res = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=HANG)
    assert res.returncode == 0 and res.stdout.strip() == "True", (res.stdout, res.stderr)
    assert victim.read_text() == "notes, not rbx's\n"
    assert not os.path.lexists(tmp_path / "ln.h5.lock")
    with h5py.File(tmp_path / "ln.h5", "r") as f:
        assert f.attrs["complete"]


def test_a_run_whose_final_rename_fails_is_not_reported_written(tmp_path):
    """`rbx simulate -o d1.h5 --force` with a folder made at d1.h5 while it ran: 'cannot rename d1.h5.partial to
    it: Is a directory; the records are in d1.h5.partial', then 'rbx: wrote d1.h5 …' and exit 0, though d1.h5 held
    no run (an immutable old run there was kept the same way: a script trusting exit 0 read the old numbers). Now
    the one line, exit 2, no 'wrote', and the records in d1.h5.partial."""
    conf = _config(tmp_path)
    out = tmp_path / "d1.h5"
    res = cli(wrapped("rbx.driver", "open_journaled", f"import os\nos.mkdir({str(out)!r})"),
              "simulate", str(conf), "-o", "d1.h5", "--force", cwd=tmp_path)
    assert res.returncode == 2, (res.returncode, res.stderr)
    assert res.stderr.splitlines() == ["rbx: d1.h5: cannot rename d1.h5.partial to it: Is a directory; the records "
                                       "are in d1.h5.partial"], res.stderr
    assert "wrote" not in res.stdout + res.stderr and out.is_dir()
    with h5py.File(tmp_path / "d1.h5.partial", "r") as f:
        assert f.attrs["complete"]


@pytest.fixture(scope="module")
def returns_file(tmp_path_factory):
    """A file of return angles written by `rbx histogram --data`."""
    folder = tmp_path_factory.mktemp("returns")
    conf = histogram_config(folder / "h.yaml", run="{collisions: 200, trajectories: 200, seed: 2}")
    res = cli("", "histogram", str(conf), "-o", "h.png", "--data", "a.h5", "--quiet", cwd=folder)
    assert res.returncode == 0, res.stderr
    return folder / "a.h5"


@pytest.mark.long
@pytest.mark.parametrize("how", ["external link", "virtual dataset", "external storage", "declared 1e11 long",
                                 "group link"])
def test_return_angles_that_lie_elsewhere_or_exceed_memory_are_refused(tmp_path, returns_file, how):
    """returns/extra made an external link, a virtual dataset or an external-storage dataset to a FIFO:
    `rbx.reader.read_returns` and scripts/fig_histogram.py waited for ever; a dataset declared 10¹¹ samples long
    (its chunks never written) ended in a MemoryError traceback. Now one FileError naming it, nothing opened."""
    data = tmp_path / "a.h5"
    data.write_bytes(returns_file.read_bytes())
    os.mkfifo(tmp_path / "fifo")
    with h5py.File(data, "r+") as f:
        g = f["returns"]
        if how == "external link":
            g["extra"] = h5py.ExternalLink(str(tmp_path / "fifo"), "/x")
        elif how == "virtual dataset":
            layout = h5py.VirtualLayout(shape=(10,), dtype="f8")
            layout[...] = h5py.VirtualSource(str(tmp_path / "fifo"), "x", shape=(10,))
            g.create_virtual_dataset("extra", layout)
        elif how == "external storage":
            g.create_dataset("extra", shape=(10,), dtype="f8", external=[(str(tmp_path / "fifo"), 0, 80)])
        elif how == "declared 1e11 long":
            g.create_dataset("extra", shape=(10 ** 11,), dtype="f8", chunks=(1000,))
        else:
            f.move("returns", "real")
            f["returns"] = h5py.ExternalLink(str(tmp_path / "fifo"), "/returns")
    code = (f"import rbx.reader\ntry:\n    rbx.reader.read_returns({str(data)!r})\n"
            "except rbx.reader.FileError as exc:\n    print('refused:', exc)\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=HANG)
    assert res.returncode == 0 and res.stdout.startswith("refused: "), (res.stdout, res.stderr)
    where = "returns:" if how in ("group link", "declared 1e11 long") else "returns/extra:"
    assert where in res.stdout and "Traceback" not in res.stderr, res.stdout
    # the figure script reads them through the same reader
    script = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "scripts", "fig_histogram.py")
    res = subprocess.run([sys.executable, script, str(data), "-o", str(tmp_path / "f.png")], capture_output=True,
                         text=True, timeout=HANG, env={**os.environ, "MPLBACKEND": "Agg"})
    assert res.returncode == 2 and "Traceback" not in res.stderr and len(res.stderr.splitlines()) == 1, res.stderr
    assert not (tmp_path / "f.png").exists()


def test_a_run_read_after_another_file_took_its_path_is_refused(tmp_path):
    """r = rbx.open('sw.h5'), then another run moved to sw.h5: r.time held the other run's 8 trajectories beside
    this run's 64 counts and its config, without a word. Now each read that opens the file again checks that the
    path still names the file read, and refuses in one FileError naming it; a file changed in place (the same
    file) is read as before."""
    import rbx
    conf = _config(tmp_path)
    rbx.simulate(conf, output=tmp_path / "sw.h5", trajectories=4, collisions=300)
    rbx.simulate(conf, output=tmp_path / "other.h5", trajectories=2, collisions=300)
    run = rbx.open(tmp_path / "sw.h5")
    assert run.trajectories == 4
    os.replace(tmp_path / "other.h5", tmp_path / "sw.h5")
    for read in (lambda: run.time, lambda: run.read("time", trajectories=[0])):
        with pytest.raises(rbx.FileError, match="is another file than the one opened: it was replaced since"):
            read()
    with pytest.raises(rbx.FileError, match="replaced since"):
        with run:
            pass
    again = rbx.open(tmp_path / "sw.h5")
    assert again.time.shape[0] == 2


def test_a_journal_larger_than_memory_is_refused_not_read(tmp_path):
    """A file of 4 GB (sparse) put at j.h5.journal beside a run, under a memory limit of 2.5 GB: `rbx plot j.h5`
    read it whole and ended in a MemoryError traceback, exit 1. Now one line naming the journal, exit 2, the run
    and the journal left as they are."""
    import rbx
    rbx.simulate(_config(tmp_path), output=tmp_path / "j.h5", trajectories=2, collisions=300)
    before = (tmp_path / "j.h5").read_bytes()
    with open(tmp_path / "j.h5.journal", "wb") as f:
        f.truncate(4 * 2 ** 30)
    limit = "import resource\nresource.setrlimit(resource.RLIMIT_AS, (2_500_000_000, 2_500_000_000))\n"
    res = cli(limit, "plot", "j.h5", "--kind", "series", "-o", "j.png", cwd=tmp_path)
    assert res.returncode == 2, (res.returncode, res.stderr)
    lines = res.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("rbx: j.h5.journal: is larger than this process may hold"), lines
    assert (tmp_path / "j.h5").read_bytes() == before and os.path.getsize(tmp_path / "j.h5.journal") == 4 * 2 ** 30
    assert not (tmp_path / "j.png").exists()


@pytest.mark.long
def test_a_committed_datatype_in_a_results_file_is_named(tmp_path):
    """A committed HDF5 datatype added to a study's results: `rbx plot --kind sweep` and `rbx sweep --resume` quoted
    Python's "'Datatype' object has no attribute 'is_virtual'". Now a line naming it, exit 2."""
    from tests.test_reliability8 import _results
    out = _results(tmp_path)
    with h5py.File(out, "r+") as f:
        f["odd"] = np.dtype("f8")
    for args in (["plot", "out.nc", "--kind", "sweep", "-o", "x.png"],
                 ["sweep", "study.yaml", "-o", "out.nc", "--resume"]):
        res = cli("", *args, cwd=tmp_path)
        assert res.returncode == 2, (args, res.stderr)
        assert res.stderr.splitlines() == ["rbx: out.nc: odd: is an HDF5 committed datatype, not a variable; a "
                                           "study's results hold their own (the file was changed after rbx wrote "
                                           "it)"], res.stderr
