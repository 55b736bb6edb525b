"""A run file describes itself (docs/runfile.md): netCDF readers see named dimensions and units, the root attributes say
where the file comes from, the stored config names the file written, compression changes no number, and a new
run's ``.partial`` is never a torn HDF5 file.

- ``xarray.open_dataset(path, engine="h5netcdf", group="collisions")`` names the dimensions ``trajectory``,
  ``record``, ``axis`` (``axis2``: the 3D orientation's columns) from HDF5 dimension scales, with each field's
  ``units``; also after a resume, and a file written without the scales (before them) still reads and resumes.
- Provenance root attributes (:data:`rbx.runfile.PROVENANCE_ATTRS`): creation time, versions, command line, host.
- The config stored names the ``-o`` / ``output=`` file (and the ``-o`` of a resume), not the config's own path.
- ``output.compression`` (none, gzip, gzip:LEVEL, lzf) round-trips the same numbers bit for bit; a bad value is
  one line and exit 2.
- A process killed while a new run's structure is written leaves no ``.partial`` (only a ``.partial.new``, which
  the next run removes); killed right after, the ``.partial`` opens, holds the structure and resumes.
"""
import datetime
import os
import shlex
import socket
import subprocess
import sys
import textwrap
from pathlib import Path

import h5py
import numba
import numpy as np
import pytest
import yaml

import rbx
import rbx.runfile as runfile
from rbx.model import FIELD
from tests.catalog import scene
from tests.test_interrupt import invoke, tiny_blocks, write_config  # noqa: F401 - tiny_blocks is a fixture

xr = pytest.importorskip("xarray")
pytest.importorskip("h5netcdf")

ROOT = Path(__file__).resolve().parents[1]
RBX = str(Path(sys.executable).with_name("rbx"))


def open_collisions(path):
    return xr.open_dataset(path, engine="h5netcdf", group="collisions")


def assert_self_describing(path, run):
    """xarray sees the run's records under named dimensions, with units, the same numbers as :class:`rbx.Run`."""
    with open_collisions(path) as ds:
        assert not [d for d in ds.dims if str(d).startswith("phony")], dict(ds.sizes)
        assert ds.sizes["trajectory"] == run.trajectories and ds.sizes["record"] == run.records
        tails = {0: (), 1: ("axis",), 2: ("axis", "axis2")}
        for name in run.fields:
            f = FIELD[name]
            assert ds[name].dims == ("trajectory", "record") + tails[len(f.shape(run.dimension))], name
            assert ds[name].attrs["units"] == f.units and ds[name].attrs["description"] == f.description
            values, expected = ds[name].values, getattr(run, name)
            if expected.dtype.kind == "i" and values.dtype.kind == "f":   # xarray reads the fill value −1 as NaN
                values = np.where(np.isnan(values), -1, values)
            assert np.array_equal(values, expected, equal_nan=expected.dtype.kind == "f"), name
        assert ds["count"].dims == ("trajectory",) and np.array_equal(ds["count"].values, run.count)
        assert ds["step"].dims == ("record",) and np.array_equal(ds["step"].values, run.step)
        assert list(ds["record"].values) == list(range(run.records))
        if "axis" in ds.dims:
            assert list(ds["axis"].values) == ["x", "y", "z"][:run.dimension]


@pytest.mark.parametrize("name", ["strip-random", "box-hemisphere"])
def test_xarray_opens_a_run_with_named_dimensions_and_units(name, tmp_path):
    """2D (orientation a scalar angle) and 3D (spin a vector, orientation a 3 × 3 matrix: axis, axis2)."""
    out = tmp_path / "run.h5"
    run = rbx.simulate(scene(name, collisions=120, trajectories=3), output=out)
    assert_self_describing(out, run)
    with open_collisions(out) as ds:
        assert set(ds.dims) == ({"trajectory", "record", "axis"} | ({"axis2"} if run.dimension == 3 else set()))


def test_provenance_in_the_root_attributes(tmp_path):
    """The real CLI: when (UTC, ISO 8601, a moment ago), which versions, which command line, which host."""
    cfg = write_config(tmp_path, scene("strip-random", collisions=50, trajectories=2))
    before = datetime.datetime.now(datetime.timezone.utc).replace(microsecond=0)
    args = [RBX, "simulate", str(cfg), "-o", str(tmp_path / "run.h5"), "--quiet"]
    res = subprocess.run(args, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    after = datetime.datetime.now(datetime.timezone.utc)
    run = rbx.open(tmp_path / "run.h5")
    assert set(runfile.PROVENANCE_ATTRS) <= set(run.attrs)
    created = datetime.datetime.fromisoformat(run.attrs["created"])
    assert created.utcoffset() == datetime.timedelta(0) and before <= created <= after
    assert run.attrs["rbx_version"] == rbx.__version__
    assert run.attrs["numba_version"] == numba.__version__ and run.attrs["numpy_version"] == np.__version__
    assert run.attrs["h5py_version"] == h5py.__version__
    assert run.attrs["hdf5_version"] == h5py.version.hdf5_version
    assert run.attrs["python_version"] == ".".join(map(str, sys.version_info[:3]))
    assert shlex.split(run.attrs["command"])[1:] == args[1:]
    assert run.attrs["host"] == socket.gethostname()


def test_the_stored_config_names_the_file_written(tmp_path):
    """`-o` (CLI), `output=` (API) and `--resume … -o` (another file): the stored output.path is that file, not
    the config's default, and it reads back as the experiment's output.path."""
    cfg = scene("strip-random", collisions=2000, trajectories=2)
    cfg["output"]["path"] = "default.h5"
    config = write_config(tmp_path, cfg)

    def stored(path):
        with h5py.File(path, "r") as f:
            return yaml.safe_load(f.attrs["config"])["output"]["path"]

    res = subprocess.run([RBX, "simulate", str(config), "-o", str(tmp_path / "cli.h5"), "--quiet"],
                         capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert stored(tmp_path / "cli.h5") == str(tmp_path / "cli.h5")
    assert rbx.open(tmp_path / "cli.h5").experiment.output.path == str(tmp_path / "cli.h5")
    rbx.simulate(config, output=tmp_path / "api.h5")
    assert stored(tmp_path / "api.h5") == str(tmp_path / "api.h5")
    assert not (tmp_path / "default.h5").exists()


@pytest.mark.long
def test_resume_keeps_the_scales_and_names_its_own_file(tmp_path, tiny_blocks):  # noqa: F811
    """An interrupted run resumed into another file (-o): xarray opens it with the same dimensions as an
    uninterrupted run, the same numbers, and its config names the new file."""
    config = write_config(tmp_path, scene("strip-random", collisions=3000, trajectories=3, every=3))
    tiny_blocks(None)
    assert invoke(config, "-o", tmp_path / "ref.h5").exit_code == 0
    tiny_blocks(3)
    assert invoke(config, "-o", tmp_path / "cut.h5").exit_code == 130
    tiny_blocks(None)
    assert invoke("--resume", tmp_path / "cut.h5", "-o", tmp_path / "resumed.h5").exit_code == 0
    resumed, ref = rbx.open(tmp_path / "resumed.h5"), rbx.open(tmp_path / "ref.h5")
    assert resumed.complete and resumed.records == ref.records
    assert_self_describing(tmp_path / "resumed.h5", ref)
    assert resumed.experiment.output.path == str(tmp_path / "resumed.h5")


def test_a_file_without_scales_still_reads_and_resumes(tmp_path, tiny_blocks, monkeypatch):  # noqa: F811
    """Files written before the dimension scales: the reader does not need them, and a resume writes on."""
    config = write_config(tmp_path, scene("strip-random", collisions=3000, trajectories=3, every=3))
    tiny_blocks(None)
    assert invoke(config, "-o", tmp_path / "ref.h5").exit_code == 0
    monkeypatch.setattr(runfile, "_make_scales", lambda g, M, n: None)       # the layout before them
    tiny_blocks(3)
    assert invoke(config, "-o", tmp_path / "old.h5").exit_code == 130
    with h5py.File(tmp_path / "old.h5", "r") as f:
        assert "record" not in f["collisions"] and "DIMENSION_LIST" not in f["collisions/time"].attrs
    monkeypatch.undo()
    tiny_blocks(None)
    assert invoke("--resume", tmp_path / "old.h5").exit_code == 0
    old, ref = rbx.open(tmp_path / "old.h5"), rbx.open(tmp_path / "ref.h5")
    assert old.complete and old.fields == ref.fields
    for name in ref.fields:
        assert np.array_equal(getattr(old, name), getattr(ref, name), equal_nan=True), name
    assert old.to_xarray().sizes == ref.to_xarray().sizes


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
    import rbx, rbx.driver as runfile
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


@pytest.mark.long
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


@pytest.mark.long
def test_a_partial_is_whole_from_the_instant_it_exists(tmp_path):
    """Killed right after the rename: the .partial opens, with its structure and dimension scales, no records
    yet, and resumes to the end."""
    out = tmp_path / "run.h5"
    kill_while_creating("published", out)
    partial = tmp_path / "run.h5.partial"
    assert partial.exists() and not (tmp_path / "run.h5.partial.new").exists()
    run = rbx.open(partial)
    assert not run.complete and run.records == 0 and set(run.fields) == set(FIELD)
    with open_collisions(partial) as ds:
        assert ds.sizes["record"] == 0 and ds.sizes["trajectory"] == 2
    res = subprocess.run([RBX, "simulate", "--resume", str(partial), "--quiet"], capture_output=True, text=True,
                         timeout=300)
    assert res.returncode == 0, res.stderr
    assert rbx.open(out).complete and rbx.open(out).records == 201 and not partial.exists()
