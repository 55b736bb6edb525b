"""End to end: the real `rbx simulate` in a subprocess, the real HDF5 file read back (docs/reference.md §4–5)."""
import os
import re
import subprocess
import sys

import h5py
import numpy as np
import pytest
import yaml

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RBX = [sys.executable, "-c", "from rbx.cli.main import main; main()"]


def rbx(*args, cwd=None):
    return subprocess.run(RBX + list(args), capture_output=True, text=True, cwd=cwd, timeout=300)


# every example through the real command, its file checked and drawn: tests/test_gallery.py


def test_records_and_shapes_3d(tmp_path):
    cfg = {"table": {"kind": "box", "size": [1, 1, 1]}, "boundary": {"default": {"rule": "constant", "rank": 2}},
           "ball": {"radius": 0.1},
           "initial": {"position": [0.5, 0.5, 0.5], "velocity": [0.3, 0.2, 0.9], "angular_velocity": [1, 0, 0]},
           "run": {"collisions": 2000, "trajectories": 3},
           "output": {"path": "out.h5", "every": 7}}
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(cfg))
    res = rbx("simulate", "c.yaml", "--quiet", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    with h5py.File(tmp_path / "out.h5") as f:               # output.path is relative to the config's folder
        g = f["collisions"]
        T = 2000 // 7 + 1
        assert g["orientation"].shape == (3, T, 3, 3) and g["angular_velocity"].shape == (3, T, 3)
        assert list(g["count"][:]) == [T] * 3
        A = g["orientation"][0, -1]
        np.testing.assert_allclose(A @ A.T, np.eye(3), atol=1e-12)
        # every 7th record equals the state just after collision 7k: the times grow, the walls are real walls
        assert np.all(np.diff(g["time"][0]) > 0) and set(np.unique(g["wall"][0, 1:])) <= set(range(6))
        assert g.attrs.get("complete", f.attrs["complete"])


def test_record_nothing_keeps_only_the_final_state(tmp_path):
    cfg = {"table": {"kind": "strip", "width": 1}, "boundary": {"default": {"rule": "constant", "rank": 1}},
           "ball": {"radius": 0.1}, "initial": {"position": [0, 0.5], "velocity": [0.6, 0.8]},
           "run": {"collisions": 100000, "trajectories": 4}, "output": {"path": "o.h5", "record": []}}
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(cfg))
    assert rbx("simulate", "c.yaml", "--quiet", cwd=tmp_path).returncode == 0
    with h5py.File(tmp_path / "o.h5") as f:
        assert "position" not in f["collisions"] and list(f["collisions/count"][:]) == [0] * 4
        assert list(f["final/collisions"][:]) == [100000] * 4
        # the first flight crosses half the shrunk width (0.4 at vy = 0.8), every later one all of it (0.8)
        assert f["final/time"][0] == pytest.approx(0.5 + 99999 * 1.0, rel=1e-12)


def test_results_do_not_depend_on_the_number_of_threads(tmp_path):
    cfg = {"table": {"kind": "rectangle", "width": 2, "height": 1}, "ball": {"radius": 0.1},
           "boundary": {"default": {"rule": "random", "choices": [{"rule": "constant", "rank": 0},
                                                                  {"rule": "constant", "rank": 1}],
                                    "probabilities": [0.5, 0.5]}},
           "initial": {"sample": "billiard"}, "run": {"collisions": 3000, "trajectories": 16, "seed": 9},
           "output": {"record": ["position", "rank"], "every": 3}}
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(cfg))
    data = []
    for threads in ("1", "2"):
        env = dict(os.environ, NUMBA_NUM_THREADS=threads)
        res = subprocess.run(RBX + ["simulate", "c.yaml", "-o", f"t{threads}.h5", "--quiet"], cwd=tmp_path, env=env,
                             capture_output=True, text=True, timeout=300)
        assert res.returncode == 0, res.stderr
        with h5py.File(tmp_path / f"t{threads}.h5") as f:
            data.append((f["collisions/position"][:], f["collisions/rank"][:]))
    np.testing.assert_array_equal(data[0][0], data[1][0])
    np.testing.assert_array_equal(data[0][1], data[1][1])
    assert 0 < data[0][1][:, 1:].mean() < 1                  # both ranks were drawn


def test_wedge_escape_ends_the_trajectory_and_count_says_where(tmp_path):
    cfg = {"table": {"kind": "wedge", "angle_deg": 60}, "ball": {"radius": 0.1},
           "boundary": {"default": {"rule": "constant", "rank": 0}},
           "initial": {"position": [1.0, 0.3], "velocity": [-1.0, 0.2]}, "run": {"collisions": 50},
           "output": {"path": "w.h5"}}
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(cfg))
    assert rbx("simulate", "c.yaml", "--quiet", cwd=tmp_path).returncode == 0
    with h5py.File(tmp_path / "w.h5") as f:
        c = int(f["collisions/count"][0])
        assert 1 < c <= 4                      # specular in a 60° wedge: at most 3 collisions, then away
        assert f.attrs["complete"]
        assert not f["final/alive"][0]
        assert np.all(np.isnan(f["collisions/time"][0, c:]))


def test_a_short_wide_run_makes_a_file_the_size_of_its_records(tmp_path):
    # chunks are never longer along the records than the run: 20 000 trajectories × 3 collisions made a 577 MB
    # file for ~5 MB of records when every trajectory got a chunk of 256 records
    cfg = {"table": {"kind": "rectangle", "width": 2, "height": 1}, "ball": {"radius": 0.1},
           "boundary": {"default": {"rule": "constant", "rank": 1}}, "initial": {"sample": "billiard"},
           "run": {"collisions": 3, "trajectories": 20000}}
    (tmp_path / "e.yaml").write_text(yaml.safe_dump(cfg))
    out = tmp_path / "run.h5"
    res = rbx("simulate", str(tmp_path / "e.yaml"), "-o", str(out), "--quiet")
    assert res.returncode == 0, res.stderr
    with h5py.File(out) as f:
        stored = sum(f["collisions"][k].size * f["collisions"][k].dtype.itemsize for k in f["collisions"])
        stored += sum(f["final"][k].size * f["final"][k].dtype.itemsize for k in f["final"])
        assert f["collisions/position"].shape == (20000, 4, 2)
    assert os.path.getsize(out) < 2 * stored, (os.path.getsize(out), stored)


# ---- what is already on disk is kept (races, --force then Ctrl-C; docs/reliability.md) ---------------------------

def _tiny_run(tmp_path, name, complete=True):
    import rbx
    from rbx import driver as runfile     # the run's file lifecycle
    out = tmp_path / name
    rbx.simulate(os.path.join(ROOT, "configs", "examples", "strip.yaml"), collisions=50, output=out)
    if not complete:
        with h5py.File(out, "r+") as f:
            f.attrs["complete"] = False
    return out, runfile


def test_a_second_run_on_the_same_output_cannot_open_its_partial(tmp_path):
    from rbx import driver as runfile     # the run's file lifecycle
    first = runfile.create(str(tmp_path / "run.h5"))
    try:
        with pytest.raises(runfile.FileError) as info:
            runfile.create(str(tmp_path / "run.h5"))          # exclusive creation, whatever HDF5's locking
        assert "another run is writing it" in str(info.value)
    finally:
        first.close()


def test_an_unfinished_run_never_replaces_a_complete_result(tmp_path):
    old, runfile = _tiny_run(tmp_path, "run.h5")
    before = old.read_bytes()
    fragment, _ = _tiny_run(tmp_path, "fragment.h5", complete=False)
    tmp = runfile.temporary_path(str(old))
    os.replace(fragment, tmp)
    said = []
    runfile.publish(tmp, str(old), complete=False, replace=True, report=said.append)   # --force, then Ctrl-C
    assert old.read_bytes() == before and os.path.exists(tmp) and "kept" in said[0]


def test_a_file_that_appeared_meanwhile_is_not_replaced_without_force(tmp_path):
    other, runfile = _tiny_run(tmp_path, "run.h5")             # written by another run while ours ran
    before = other.read_bytes()
    ours, _ = _tiny_run(tmp_path, "ours.h5")
    tmp = runfile.temporary_path(str(other))
    os.replace(ours, tmp)
    with pytest.raises(runfile.FileError) as info:
        runfile.publish(tmp, str(other), complete=True, replace=False, report=None)
    assert "appeared while this run was writing" in str(info.value)
    assert other.read_bytes() == before and os.path.exists(tmp)
    ours_inode = os.stat(tmp).st_ino
    runfile.publish(tmp, str(other), complete=True, replace=True, report=None)     # with --force: replaced
    assert not os.path.exists(tmp) and os.stat(other).st_ino == ours_inode


@pytest.mark.long
def test_a_first_compile_is_announced_before_it_starts_and_a_warm_run_says_nothing(tmp_path):
    """A cold kernel cache: rbx simulate says on a terminal, before compiling, that it compiles (seconds of silence
    otherwise); the next run loads the kernels and says nothing of it; --quiet says nothing either. A stderr that
    is not a terminal (a program, a log) gets no notice: the summary line alone, which says a compile after the
    fact (a cold run without a terminal: every one-line refusal of the suite on a fresh clone)."""
    import os as _os
    import pty
    env = {**_os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    example = os.path.join(ROOT, "configs", "examples", "strip.yaml")

    def run(*extra, tty=True):
        args = RBX + ["simulate", example, "-o", str(tmp_path / "s.h5"), "--force", "--collisions", "100", *extra]
        if not tty:
            res = subprocess.run(args, capture_output=True, text=True, timeout=300, env=env)
            return res.returncode, res.stderr.splitlines()
        master, slave = pty.openpty()
        try:
            proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=slave, env=env)
            _os.close(slave)
            out = b""
            while True:
                try:
                    chunk = _os.read(master, 65536)
                except OSError:         # the terminal's other end closed: the process is gone
                    break
                if not chunk:
                    break
                out += chunk
            code = proc.wait(timeout=300)
        finally:
            _os.close(master)
        return code, [x for x in out.decode().replace("\r", "\n").split("\n") if x.strip()]
    code, lines = run()
    assert code == 0, lines
    assert lines[0] == "rbx: compiling kernels for this scene, once (3–15 s each; the next run loads them from the " \
                       "cache)…", lines
    assert re.search(r"\(compiling kernels for this scene, once: [0-9.]+ (s|min)", lines[-1]), lines
    code, lines = run()
    assert code == 0 and not any("compiling" in x for x in lines), lines
    assert re.search(r"\([0-9.]+ s setting up\)", lines[-1]), lines
    assert run("--quiet") == (0, [])
    code, lines = run(tty=False)
    assert code == 0 and len(lines) == 1 and "compiling" not in lines[0], lines


def test_the_readme_gives_the_default_size_limit_as_the_refusal_does(tmp_path):
    res = rbx("simulate", os.path.join(ROOT, "configs", "examples", "circle.yaml"), "--collisions", "1000000000",
              "-o", str(tmp_path / "big.h5"))
    assert res.returncode == 2, res.stderr
    import re
    limit = re.search(r"more than the limit ([0-9.]+ [kMGT]?B)", res.stderr).group(1)
    readme = " ".join(open(os.path.join(ROOT, "README.md"), encoding="utf-8").read().split())
    assert f"`output.max_size` (default {limit}" in readme, limit
