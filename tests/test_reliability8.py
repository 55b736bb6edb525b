"""Eighteenth round: a file that appears under an output's name while a command works is never replaced without
--force (return angles, a study's results, a histogram's figure), a figure never replaces a file that is not one
(put there while it was drawn), a signal that comes once a command's output is in place does not say 'nothing
written', a study's results file is checked for what it is (a FIFO, a dataset added by hand), and a study whose
folder is removed ends in one line. Each reproduction runs the real command line in a subprocess, with the racing file made from
inside the command (a function it calls wrapped, no timing); each test was seen to fail on the code before it."""
import os
import shutil
import subprocess
import sys

import h5py
import pytest
import yaml

from tests.test_histogram import write_config as histogram_config
from tests.test_sweep import specular_study

#: a guard against a hang, not a bound
HANG = 600
NOTES = b"my notes: not a figure\n"


def cli(prelude, *args, cwd):
    """``rbx ARGS`` in a subprocess after ``prelude`` (Python run first: the wrapping that makes the race)."""
    code = f"import sys\n{prelude}\nfrom rbx.cli.main import main\nsys.argv[0] = 'rbx'\nmain()\n"
    return subprocess.run([sys.executable, "-c", code, *args], cwd=cwd, capture_output=True, text=True,
                          timeout=HANG)


def wrapped(module, name, after):
    """A prelude that wraps ``module.name`` so that ``after`` (Python statements; ``result`` is the call's) runs
    once the call returns, on its first call only."""
    body = "\n".join(f"        {line}" for line in after.strip().splitlines())
    return (f"import {module} as _m\n_real = _m.{name}\n_done = []\n"
            f"def _raced(*a, **k):\n    result = _real(*a, **k)\n    if not _done:\n        _done.append(1)\n"
            f"{body}\n    return result\n_m.{name} = _raced\n")


def signal_at(path, after):
    """A prelude that sends this process SIGINT once, when ``os.replace`` or ``os.link`` puts a file at ``path``:
    just before the call (``after`` false) or just after it returned."""
    return (f"import os, signal\n_sent = []\n"
            f"def _hooked(real):\n    def call(a, b, *rest, **k):\n"
            f"        hit = not _sent and os.path.abspath(b) == {str(path)!r}\n"
            f"        if hit:\n            _sent.append(1)\n"
            f"        if hit and not {after!r}:\n            os.kill(os.getpid(), signal.SIGINT)\n"
            f"        result = real(a, b, *rest, **k)\n"
            f"        if hit and {after!r}:\n            os.kill(os.getpid(), signal.SIGINT)\n"
            f"        return result\n    return call\n"
            f"os.replace, os.link = _hooked(os.replace), _hooked(os.link)\n")


@pytest.fixture(scope="module")
def a_run(tmp_path_factory):
    """A complete run file of rbx simulate: what "another run" leaves under a name."""
    folder = tmp_path_factory.mktemp("run")
    conf = histogram_config(folder / "h.yaml", run="{collisions: 50, trajectories: 2, seed: 2}",
                            initial="{position: [1.0, 0.5], velocity: [0.6, 0.8]}")
    res = subprocess.run([sys.executable, "-c", "from rbx.cli.main import main; main()", "simulate", str(conf), "-o",
                          str(folder / "run.h5"), "--quiet"], capture_output=True, text=True, timeout=HANG)
    assert res.returncode == 0, res.stderr
    return folder / "run.h5"


@pytest.mark.long
def test_return_angles_never_replace_a_run_that_finished_while_they_were_drawn(tmp_path, a_run):
    """`rbx histogram --data r.h5` without --force, and a run of rbx simulate finished as r.h5 meanwhile: the run
    was replaced by the return angles, exit 0. Now one line, exit 2, the run as it was."""
    conf = histogram_config(tmp_path / "h.yaml", run="{collisions: 300, trajectories: 400, seed: 2}")
    target = tmp_path / "r.h5"
    prelude = wrapped("rbx.histogram", "return_experiment", f"import shutil; shutil.copyfile({str(a_run)!r}, "
                                                             f"{str(target)!r})")
    res = cli(prelude, "histogram", str(conf), "--data", str(target), "-o", str(tmp_path / "h.png"), cwd=tmp_path)
    assert res.returncode == 2, res.stderr
    assert len(res.stderr.splitlines()) == 1 and "Traceback" not in res.stderr, res.stderr
    assert "appeared while the samples were drawn" in res.stderr and "was not replaced" in res.stderr
    assert target.read_bytes() == a_run.read_bytes()
    assert not (tmp_path / "h.png").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["h.yaml", "r.h5"]     # no file of rbx's left behind
    # with --force, the return angles replace a file of return angles, not a run that appeared
    res = cli(prelude, "histogram", str(conf), "--data", str(target), "-o", str(tmp_path / "h.png"), "--force",
              cwd=tmp_path)
    assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr
    assert "a run file of rbx simulate" in res.stderr
    assert target.read_bytes() == a_run.read_bytes()


@pytest.mark.long
def test_a_histograms_figure_never_replaces_a_file_that_appeared_without_force(tmp_path):
    conf = histogram_config(tmp_path / "h.yaml", run="{collisions: 300, trajectories: 400, seed: 2}")
    fig = tmp_path / "h.png"
    prelude = wrapped("rbx.histogram", "return_experiment", f"open({str(fig)!r}, 'wb').write({NOTES!r})")
    res = cli(prelude, "histogram", str(conf), "--data", str(tmp_path / "r.h5"), "-o", str(fig), cwd=tmp_path)
    assert res.returncode == 2 and len(res.stderr.splitlines()) == 1, res.stderr
    assert "appeared while the figure was made" in res.stderr and "samples are kept in" in res.stderr
    assert fig.read_bytes() == NOTES
    with h5py.File(tmp_path / "r.h5", "r") as f:          # the samples were written, and are said to be kept
        assert f["returns/angle"].size > 0


@pytest.mark.long
def test_a_studys_results_never_replace_a_file_that_appeared_while_it_ran(tmp_path, a_run):
    """`rbx sweep STUDY -o out.nc` without --force, and a file put at out.nc while the points ran: it was replaced
    by the results, exit 0. Now one line, exit 2, the file as it was, the results kept in out.nc.partial."""
    (tmp_path / "study.yaml").write_text(yaml.safe_dump(specular_study(trajectories=2, collisions=100)))
    out = tmp_path / "out.nc"
    prelude = wrapped("rbx.sweeping", "run_point", f"import shutil; shutil.copyfile({str(a_run)!r}, {str(out)!r})")
    res = cli(prelude, "sweep", "study.yaml", "-o", "out.nc", "--quiet", cwd=tmp_path)
    assert res.returncode == 2, res.stderr
    assert len(res.stderr.splitlines()) == 1 and "Traceback" not in res.stderr, res.stderr
    assert "appeared while the study ran" in res.stderr and "out.nc.partial" in res.stderr
    assert out.read_bytes() == a_run.read_bytes()
    import xarray as xr
    with xr.open_dataset(tmp_path / "out.nc.partial", engine="h5netcdf") as ds:
        assert int(ds["done"].values.min()) == 1 and ds.attrs["complete"] == 1
    # with --force, a file of another command that appeared is not replaced either
    res = cli(prelude, "sweep", "study.yaml", "-o", "out.nc", "--quiet", "--force", cwd=tmp_path)
    assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr
    assert "a run file of rbx simulate" in res.stderr
    assert out.read_bytes() == a_run.read_bytes()
    # nor a link put there (it did not say where the results were)
    out.unlink()
    link = f"import os; os.symlink({str(a_run)!r}, {str(out)!r})"
    res = cli(wrapped("rbx.sweeping", "run_point", link), "sweep", "study.yaml", "-o", "out.nc", "--quiet",
              "--force", cwd=tmp_path)
    assert res.returncode == 2 and len(res.stderr.splitlines()) == 1, res.stderr
    assert "is a symbolic link" in res.stderr and "the results are in out.nc.partial" in res.stderr, res.stderr
    assert os.readlink(out) == str(a_run)


@pytest.mark.long
@pytest.mark.parametrize("command", ["plot", "animate"])
def test_a_figure_never_replaces_a_file_that_is_not_one_put_there_while_it_was_drawn(tmp_path, a_run, command):
    """`rbx plot RUN -o f.png` (or animate -o f.gif) while notes were saved as f.png: the notes were replaced by
    the figure, exit 0. Now one line, exit 2, the notes as they were, no file of rbx's left."""
    run = tmp_path / "run.h5"
    shutil.copyfile(a_run, run)
    fig = tmp_path / ("f.png" if command == "plot" else "f.gif")
    module, name = ("rbx.cli.plot", "make_figure") if command == "plot" else ("rbx.cli.animate", "ball_frames")
    prelude = wrapped(module, name, f"open({str(fig)!r}, 'wb').write({NOTES!r})")
    extra = ["--kind", "orbit"] if command == "plot" else ["--frames", "5", "--dpi", "30"]
    res = cli(prelude, command, str(run), *extra, "-o", str(fig), cwd=tmp_path)
    assert res.returncode == 2, res.stderr
    assert len(res.stderr.splitlines()) == 1 and "Traceback" not in res.stderr, res.stderr
    assert "is not a figure" in res.stderr and "nothing was replaced" in res.stderr
    assert fig.read_bytes() == NOTES
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([run.name, fig.name])


@pytest.mark.long
@pytest.mark.parametrize("command", ["plot", "sweep", "histogram"])
def test_a_signal_once_the_output_is_in_place_does_not_say_nothing_written(tmp_path, a_run, command):
    """SIGINT sent by the command to itself right after its last output was put in place (the rename returned),
    before its summary: 'interrupted by SIGINT; nothing written' and exit 130 with the figure or the results in
    place (and rbx histogram said 'wrote only the samples, not the figure' with both written). Now the signal comes
    too late to stop anything: the summary, exit 0."""
    if command == "plot":
        run = tmp_path / "run.h5"
        shutil.copyfile(a_run, run)
        out = tmp_path / "f.png"
        args = ["plot", str(run), "--kind", "orbit", "-o", str(out)]
    elif command == "sweep":
        (tmp_path / "study.yaml").write_text(yaml.safe_dump(specular_study(trajectories=2, collisions=100)))
        out = tmp_path / "out.nc"
        args = ["sweep", "study.yaml", "-o", str(out)]
    else:
        conf = histogram_config(tmp_path / "h.yaml", run="{collisions: 300, trajectories: 400, seed: 2}")
        out = tmp_path / "h.png"
        args = ["histogram", str(conf), "--data", str(tmp_path / "r.h5"), "-o", str(out)]
    # the signal is sent just after the rename (or link) that put the command's last output in place returned
    res = cli(signal_at(out, after=True), *args, cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert "interrupted" not in res.stderr and "nothing written" not in res.stderr, res.stderr
    assert res.stderr.startswith("rbx: wrote ") and out.name in res.stderr, res.stderr
    assert out.exists() and "Traceback" not in res.stderr


@pytest.mark.long
def test_a_signal_while_the_samples_are_put_in_place_says_they_were_written(tmp_path):
    """A signal while rbx histogram's samples were renamed into place: acted on once they are there, and the
    line says so (not 'nothing written'); exit 130, no figure."""
    conf = histogram_config(tmp_path / "h.yaml", run="{collisions: 300, trajectories: 400, seed: 2}")
    data = tmp_path / "r.h5"
    # the signal arrives as the samples are renamed into place (just before the rename)
    res = cli(signal_at(data, after=False), "histogram", str(conf), "--data", str(data), "-o",
              str(tmp_path / "h.png"), cwd=tmp_path)
    assert res.returncode == 130, res.stderr
    assert "interrupted by SIGINT; wrote only" in res.stderr and "r.h5 (the samples)" in res.stderr, res.stderr
    assert data.exists() and not (tmp_path / "h.png").exists()
    assert "Traceback" not in res.stderr and len(res.stderr.splitlines()) == 1, res.stderr


def _results(tmp_path):
    """A finished study's results file, out.nc, and its study file."""
    (tmp_path / "study.yaml").write_text(yaml.safe_dump(specular_study(trajectories=2, collisions=100)))
    res = cli("", "sweep", "study.yaml", "-o", "out.nc", "--quiet", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    return tmp_path / "out.nc"


@pytest.mark.long
def test_a_fifo_named_as_a_studys_results_is_refused_not_opened(tmp_path):
    """`rbx sweep --resume` and `rbx plot --kind sweep` of a FIFO named out.nc waited in open() for ever (the first
    SIGTERM did not end the sweep). Now one line, exit 2, at once."""
    os.mkfifo(tmp_path / "o.nc")
    (tmp_path / "study.yaml").write_text(yaml.safe_dump(specular_study(trajectories=2, collisions=100)))
    for args in (["sweep", "study.yaml", "-o", "o.nc", "--resume"], ["plot", "o.nc", "--kind", "sweep", "-o", "x.png"]):
        res = cli("", *args, cwd=tmp_path)
        assert res.returncode == 2, res.stderr
        assert len(res.stderr.splitlines()) == 1 and "is a FIFO (named pipe), not a regular file" in res.stderr, \
            res.stderr


@pytest.mark.long
def test_a_dataset_added_to_a_results_file_is_named_not_a_traceback(tmp_path):
    """A results file with one more dataset, without dimension scales: `rbx plot --kind sweep` printed xarray's
    warning and an IndexError traceback (or, here, drew it, the reader taking it along the walls' dimension);
    `--resume` named the wrong variable. Now one line naming it, exit 2."""
    out = _results(tmp_path)
    with h5py.File(out, "a") as f:
        f.create_dataset("junk", shape=(5,), dtype="f8")
    shutil.copyfile(out, tmp_path / "out.nc.partial")
    out.unlink()
    for args in (["plot", "out.nc.partial", "--kind", "sweep", "-o", "x.png"],
                 ["sweep", "study.yaml", "-o", "out.nc", "--resume"]):
        res = cli("", *args, cwd=tmp_path)
        assert res.returncode == 2, res.stderr
        assert len(res.stderr.splitlines()) == 1 and "Traceback" not in res.stderr, res.stderr
        assert "junk: is a variable rbx sweep does not write" in res.stderr, res.stderr


@pytest.mark.long
def test_a_study_whose_folder_is_removed_while_it_runs_ends_in_one_line(tmp_path):
    """The output folder removed while the points ran: a 40-line FileNotFoundError traceback, exit 1. Now one line,
    exit 1, saying that nothing is kept."""
    (tmp_path / "study.yaml").write_text(yaml.safe_dump(specular_study(trajectories=2, collisions=100)))
    (tmp_path / "d").mkdir()
    prelude = wrapped("rbx.sweeping", "run_point", f"import shutil; shutil.rmtree({str(tmp_path / 'd')!r})")
    res = cli(prelude, "sweep", "study.yaml", "-o", "d/r.nc", "--quiet", cwd=tmp_path)
    assert res.returncode == 1, res.stderr
    assert len(res.stderr.splitlines()) == 1 and "Traceback" not in res.stderr, res.stderr
    assert "cannot write the study's results" in res.stderr and "is gone" in res.stderr, res.stderr


@pytest.mark.long
def test_a_signal_while_python_exits_after_the_summary_does_not_kill_the_command(tmp_path, a_run):
    """SIGINT late in Python's exit, after its signal handlers are gone (here sent from a finaliser): a finished
    command was killed by SIGINT just after 'rbx: wrote …'. Now exit 0."""
    run = tmp_path / "run.h5"
    shutil.copyfile(a_run, run)
    prelude = ("import builtins, os, signal\nclass _Late:\n    def __del__(self):\n"
               "        os.kill(os.getpid(), signal.SIGINT)\nbuiltins._late = _Late()\n")
    res = cli(prelude, "plot", str(run), "--kind", "orbit", "-o", str(tmp_path / "f.png"), cwd=tmp_path)
    assert res.returncode == 0, (res.returncode, res.stderr)
    assert res.stderr.startswith("rbx: wrote ") and (tmp_path / "f.png").exists()


@pytest.mark.parametrize("appears", ["results", "notes"])
def test_a_run_with_force_never_replaces_another_kind_of_file_that_appeared_while_it_ran(tmp_path, appears):
    """`rbx simulate -o r.h5 --force`, and a study's results (or notes) put at r.h5 while it ran: the study's
    results were replaced by the run, exit 0; notes were kept, but with exit 0 and a line without the file's name.
    Now one line naming r.h5 and what it is, exit 2, the file as it was, the records kept in r.h5.partial."""
    conf = histogram_config(tmp_path / "h.yaml", run="{collisions: 100, trajectories: 1, seed: 2}",
                            initial="{position: [1.0, 0.5], velocity: [0.6, 0.8]}")
    target = tmp_path / "r.h5"
    make = (f"import h5py\nwith h5py.File({str(target)!r}, 'w') as f:\n    f.attrs['rbx_study'] = 'x'"
            if appears == "results" else f"open({str(target)!r}, 'wb').write({NOTES!r})")
    res = cli(wrapped("rbx.driver", "check_target", make), "simulate", str(conf), "-o", str(target), "--force",
              "--quiet", cwd=tmp_path)
    assert res.returncode == 2, (res.returncode, res.stderr)
    assert len(res.stderr.splitlines()) == 1 and "Traceback" not in res.stderr, res.stderr
    assert res.stderr.startswith("rbx: r.h5"), res.stderr
    assert ("a study's results" if appears == "results" else "is not an HDF5 file") in res.stderr
    assert "the records are in" in res.stderr and "r.h5.partial" in res.stderr
    if appears == "results":
        with h5py.File(target, "r") as f:
            assert dict(f.attrs) == {"rbx_study": "x"} and not list(f)
    else:
        assert target.read_bytes() == NOTES
    with h5py.File(tmp_path / "r.h5.partial", "r") as f:
        assert bool(f.attrs["complete"]) and f["collisions/time"].shape[-1] > 1


@pytest.mark.long
def test_a_run_whose_folder_is_removed_while_it_runs_ends_in_one_line(tmp_path):
    """`rbx simulate -o out/r.h5` and the folder out removed while the run wrote: two lines that contradicted each
    other ('the records are in out/r.h5.partial', then 'nothing was saved (the run stopped before its file was
    made)'). Now one line saying the folder is gone, exit 1; the API raises the same as a FileNotFoundError."""
    conf = histogram_config(tmp_path / "h.yaml", run="{collisions: 200, trajectories: 1, seed: 2}",
                            initial="{position: [1.0, 0.5], velocity: [0.6, 0.8]}")
    (tmp_path / "out").mkdir()
    prelude = wrapped("rbx.driver", "publish_new", f"import shutil; shutil.rmtree({str(tmp_path / 'out')!r})")
    res = cli(prelude, "simulate", str(conf), "-o", "out/r.h5", "--quiet", cwd=tmp_path)
    assert res.returncode == 1, (res.returncode, res.stderr)
    assert res.stderr.splitlines() == ["rbx: out/r.h5: its folder out is gone (removed while the run wrote?): "
                                       "nothing was saved"], res.stderr
    (tmp_path / "out").mkdir()
    code = (f"{prelude}\nimport rbx\ntry:\n    rbx.simulate({str(conf)!r}, output='out/r.h5')\n"
            f"except FileNotFoundError as exc:\n    print('raised:', exc)\n")
    res = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=HANG)
    assert res.returncode == 0 and "Traceback" not in res.stderr, res.stderr
    assert res.stdout.startswith("raised: [Errno 2] the folder out is gone (removed while the run wrote?)"), \
        res.stdout
    assert not (tmp_path / "out").exists()


@pytest.mark.long
def test_a_read_only_disk_is_called_read_only_not_full(tmp_path):
    """`rbx simulate -o ro/r.h5` (and `rbx histogram --data ro/r.h5`) on a read-only disk with less free space than
    the run needs: 'the disk has 1.05 MB free', as if freeing space would help. Now one line saying the disk is
    read-only, exit 2, before any work."""
    from tests.test_reliability3 import tmpfs
    conf = histogram_config(tmp_path / "h.yaml", run="{collisions: 500, trajectories: 200000, seed: 2}")
    with tmpfs(tmp_path / "ro", "1m") as ro:
        res = subprocess.run(["mount", "-o", "remount,ro", str(ro)], capture_output=True, text=True)
        if res.returncode != 0:
            pytest.skip(f"cannot make the tmpfs read-only: {res.stderr.strip()}")
        for args in (["simulate", str(conf), "-o", "ro/r.h5"],
                     ["histogram", str(conf), "--data", "ro/r.h5", "-o", "h.png"]):
            res = cli("", *args, cwd=tmp_path)
            assert res.returncode == 2, (args, res.stderr)
            assert res.stderr.splitlines() == ["rbx: ro/r.h5: its folder ro is on a read-only file system: give an "
                                               "output on a writable disk"], res.stderr
        assert not list(ro.iterdir())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["h.yaml", "ro"]


@pytest.mark.long
def test_return_angles_never_remake_a_folder_removed_while_they_were_drawn(tmp_path):
    """`rbx histogram --data out/r.h5` (rbx makes no folders for it) and out removed while the samples were drawn:
    the folder was made again and the files written into it. Now one line saying it is gone, exit 1."""
    conf = histogram_config(tmp_path / "h.yaml", run="{collisions: 300, trajectories: 400, seed: 2}")
    (tmp_path / "out").mkdir()
    prelude = wrapped("rbx.histogram", "return_experiment", f"import shutil; shutil.rmtree({str(tmp_path / 'out')!r})")
    res = cli(prelude, "histogram", str(conf), "--data", "out/r.h5", "-o", "h.png", cwd=tmp_path)
    assert res.returncode == 1, (res.returncode, res.stderr)
    assert res.stderr.splitlines()[-1] == ("rbx: out/r.h5: its folder out is gone (removed while the samples were "
                                           "drawn?): nothing was saved"), res.stderr
    assert "Traceback" not in res.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["h.yaml"]
