"""A run file describes itself (issue 18): compression changes no number.

- ``output.compression`` (none, gzip, gzip:LEVEL, lzf) round-trips the same numbers bit for bit; a bad value is
  one line and exit 2.
"""
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml

import rbx
from tests.catalog import scene
from tests.test_interrupt import write_config

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
