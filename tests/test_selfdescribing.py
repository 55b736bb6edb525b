"""A run file describes itself (issue 18): compression changes no number, and a new run's ``.partial`` is never a
torn HDF5 file.

- ``output.compression`` (none, gzip, gzip:LEVEL, lzf) round-trips the same numbers bit for bit; a bad value is
  one line and exit 2.
- A process killed while a new run's structure is written leaves no ``.partial`` (only a ``.partial.new``, which
  the next run removes); killed right after, the ``.partial`` opens, holds the structure and resumes.
"""
import subprocess
import sys
import textwrap
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml

import rbx
from rbx.model import FIELD
from tests.catalog import scene
from tests.test_interrupt import write_config

ROOT = Path(__file__).resolve().parents[1]
RBX = str(Path(sys.executable).with_name("rbx"))


COMPRESSIONS = {"gzip": ("gzip", 4), "gzip:1": ("gzip", 1), "gzip:9": ("gzip", 9), "lzf": ("lzf", None)}


@pytest.mark.parametrize("name", ["strip-random", "box-hemisphere"])
def test_each_compression_round_trips_the_same_numbers(name, tmp_path):
    """Every record field, bit for bit the uncompressed run's, and the datasets really are compressed."""
    def with_compression(value):
        cfg = scene(name, collisions=400, trajectories=3)
        cfg["output"]["compression"] = value
        return cfg

    plain = rbx.simulate(with_compression("none"), output=tmp_path / "none.h5")
    with h5py.File(tmp_path / "none.h5", "r") as f:
        assert all(f["collisions"][k].compression is None for k in plain.fields)
    for value, (filter_name, level) in COMPRESSIONS.items():
        out = tmp_path / f"{value.replace(':', '-')}.h5"
        run = rbx.simulate(with_compression(value), output=out)
        with h5py.File(out, "r") as f:
            for k in run.fields:
                ds = f["collisions"][k]
                assert ds.compression == filter_name and ds.compression_opts == level and ds.fletcher32, (value, k)
        assert run.fields == plain.fields
        for k in plain.fields:
            a, b = getattr(run, k), getattr(plain, k)
            assert a.dtype == b.dtype and a.tobytes() == b.tobytes(), (value, k)
        assert np.array_equal(run.count, plain.count) and np.array_equal(run.step, plain.step)
        assert yaml.safe_load(run.attrs["config"])["output"]["compression"] == ("gzip:4" if value == "gzip"
                                                                                 else value)


@pytest.mark.parametrize("value, problem", [("zstd", "unknown compression 'zstd'"), ("gzip:11", "gzip level"),
                                            ("lzf:2", "lzf takes no level"), (5, "expected one of")])
def test_a_bad_compression_is_one_line_exit_2(value, problem, tmp_path):
    cfg = scene("strip-random", collisions=10)
    cfg["output"]["compression"] = value
    config = write_config(tmp_path, cfg)
    res = subprocess.run([RBX, "simulate", str(config), "-o", str(tmp_path / "run.h5"), "--quiet"],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"rbx: {config}: output.compression: "), res.stderr
    assert problem in lines[0]
    assert not list(tmp_path.glob("run.h5*"))


KILLED = textwrap.dedent("""
    import os, sys
    import h5py
    import rbx, rbx.runfile as runfile
    from tests.catalog import scene
    where, out = sys.argv[1], sys.argv[2]
    if where == "structure":        # killed while HDF5 writes the new file's structure: the third dataset
        made = [0]
        create = h5py.Group.create_dataset
        def create_then_die(self, *args, **kwargs):
            made[0] += 1
            if made[0] == 3:
                os._exit(9)
            return create(self, *args, **kwargs)
        h5py.Group.create_dataset = create_then_die
    else:                           # killed the instant the .partial exists
        publish = runfile.publish_new
        def publish_then_die(h5, tmp):
            publish(h5, tmp)
            if os.path.exists(tmp):
                os._exit(9)
        runfile.publish_new = publish_then_die
    rbx.simulate(scene("strip-random", collisions=200, trajectories=2), output=out)
""")


def kill_while_creating(where, out):
    res = subprocess.run([sys.executable, "-c", KILLED, where, str(out)], capture_output=True, text=True,
                         timeout=300, cwd=ROOT)
    assert res.returncode == 9, res.stderr


def test_a_kill_while_the_structure_is_written_leaves_no_partial(tmp_path):
    """The old way (the .partial created first, its structure written into it) left a .partial that a new run
    refuses and whose structure may be torn; now only a .partial.new is left, and the next run (no --force)
    removes it and writes its file."""
    out = tmp_path / "run.h5"
    kill_while_creating("structure", out)
    assert not (tmp_path / "run.h5.partial").exists() and not out.exists()
    assert (tmp_path / "run.h5.partial.new").exists()
    res = subprocess.run([RBX, "simulate", str(write_config(tmp_path, scene("strip-random", collisions=200,
                                                                             trajectories=2))),
                          "-o", str(out), "--quiet"], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["exp.yaml", "run.h5"]
    assert rbx.open(out).complete


def test_a_partial_is_whole_from_the_instant_it_exists(tmp_path):
    """Killed right after the rename: the .partial opens, with its structure, no records yet, and resumes to the
    end."""
    out = tmp_path / "run.h5"
    kill_while_creating("published", out)
    partial = tmp_path / "run.h5.partial"
    assert partial.exists() and not (tmp_path / "run.h5.partial.new").exists()
    run = rbx.open(partial)
    assert not run.complete and run.records == 0 and set(run.fields) == set(FIELD)
    res = subprocess.run([RBX, "simulate", "--resume", str(partial), "--quiet"], capture_output=True, text=True,
                         timeout=300)
    assert res.returncode == 0, res.stderr
    assert rbx.open(out).complete and rbx.open(out).records == 201 and not partial.exists()
