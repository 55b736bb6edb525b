"""The Python API (docs/reference.md §9): ``rbx.load``, ``rbx.simulate``, ``rbx.open``, ``rbx.Run``.

The acceptance test: the API and the real CLI (``rbx simulate`` in a subprocess) write the same records, bit for
bit, on scenes and rules of every kind (rough, hemisphere and random rules; strip, rectangle, circle, wedge,
plates, box; every record, a subset with ``every``, no records); an in-memory run equals the file-backed one;
``to_xarray`` names its dimensions; a bad config raises ``rbx.ConfigError`` naming the key (the message the CLI
prints); ``rbx.open`` of a file that is not a run says so. Also: the README's Python example and the example
notebook run.
"""
import json
import os
import re
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml

import rbx
from catalog import scene
from rbx.model import FIELD
from rbx.runfile import PROVENANCE_ATTRS, SCALES, STATE_GROUPS
from tests.test_interrupt import without_path

ROOT = Path(__file__).resolve().parents[1]
RBX = str(Path(sys.executable).with_name("rbx"))
EXAMPLES = ROOT / "configs" / "examples"

#: name -> (config: a path under configs/examples or a catalog scene (dict), CLI overrides)
CASES = {
    "strip-hemisphere": (EXAMPLES / "strip.yaml", {"collisions": 300}),
    "rectangle-random": (EXAMPLES / "rectangle.yaml", {"collisions": 200, "trajectories": 7, "seed": 5}),
    "circle-rough": (EXAMPLES / "circle.yaml", {"collisions": 300}),
    "wedge-rough": (EXAMPLES / "wedge.yaml", {"collisions": 100}),
    "plates-mixed": (EXAMPLES / "plates.yaml", {"collisions": 300}),
    "box-rough": (EXAMPLES / "box.yaml", {"collisions": 100, "trajectories": 3}),
    "strip-rough": (scene("strip-rough", collisions=300), {}),
    "strip-random-every": (scene("strip-random", collisions=400, trajectories=3, record=["position", "rank"],
                                 every=3), {}),
    "box-hemisphere-final-only": (scene("box-hemisphere", collisions=200, record=[]), {}),
}


def config_file(folder, name):
    """The case's config as a file the CLI can read -> path."""
    cfg, _ = CASES[name]
    if isinstance(cfg, Path):
        return cfg
    path = Path(folder) / f"{name}.yaml"
    path.write_text(yaml.safe_dump(cfg, sort_keys=False))
    return path


def cli_run(config, out, overrides):
    args = [RBX, "simulate", str(config), "-o", str(out), "--quiet"]
    for k, v in overrides.items():
        args += [f"--{k}", str(v)]
    return subprocess.run(args, capture_output=True, text=True, timeout=300)


def read_file(path):
    """Everything an HDF5 run holds: root attributes, every dataset (with its attributes) -> dict."""
    out = {}
    with h5py.File(path, "r") as f:
        out["attrs"] = {k: f.attrs[k] for k in f.attrs}

        def visit(name, obj):
            # dimension scales: the names attached to each axis (their attributes hold object references, which
            # are addresses in the file)
            out[name + "@attrs"] = {k: obj.attrs[k] for k in obj.attrs if k not in ("DIMENSION_LIST", "REFERENCE_LIST")}
            if isinstance(obj, h5py.Dataset):
                out[name] = obj[...]
                out[name + "@dims"] = str([list(d.keys()) for d in obj.dims])
        f.visititems(visit)
    return out


def comparable(content):
    """What two files of one run share: all but their provenance (when, where, by which command each was written),
    their config's output.path (each file names itself there) and the saved state's ``sequence`` (how many
    checkpoints were taken: one per CHECKPOINT_SECONDS of running, so a loaded machine takes more)."""
    content["attrs"] = {k: v for k, v in content["attrs"].items() if k not in PROVENANCE_ATTRS}
    for group in STATE_GROUPS:
        content.get(f"{group}@attrs", {}).pop("sequence", None)
    content["attrs"]["config"] = without_path(content["attrs"]["config"])
    return content


def same(a, b):
    """Equal bit for bit (NaN where the other has NaN; the same dtype and shape)."""
    a, b = np.asarray(a), np.asarray(b)
    if a.dtype != b.dtype or a.shape != b.shape:
        return False
    if a.dtype.kind == "f":
        return np.array_equal(a.view(np.int64 if a.itemsize == 8 else np.int32),
                              b.view(np.int64 if b.itemsize == 8 else np.int32))
    return np.array_equal(a, b)


def assert_same_run(a, b):
    """Two Run objects hold the same records, count, step, final state and root attributes, bit for bit."""
    assert a.fields == b.fields
    for f in a.fields:
        assert same(getattr(a, f), getattr(b, f)), f
    assert same(a.count, b.count) and same(a.step, b.step)
    assert sorted(a.final) == sorted(b.final)
    for k in a.final:
        assert same(a.final[k], b.final[k]), f"final/{k}"
    assert comparable({"attrs": dict(a.attrs)}) == comparable({"attrs": dict(b.attrs)})


@pytest.fixture(scope="module")
def cli_files(tmp_path_factory):
    """name -> the file `rbx simulate` wrote for each case (the CLI runs in parallel subprocesses)."""
    folder = tmp_path_factory.mktemp("cli")
    jobs = {name: (config_file(folder, name), folder / f"{name}.h5", CASES[name][1]) for name in CASES}
    with ThreadPoolExecutor(4) as pool:
        results = dict(zip(jobs, pool.map(lambda job: cli_run(*job), jobs.values())))
    for name, res in results.items():
        assert res.returncode == 0, (name, res.stderr)
    return {name: job[1] for name, job in jobs.items()}


@pytest.mark.parametrize("name", list(CASES))
def test_api_writes_what_the_cli_writes(name, cli_files, tmp_path):
    """rbx.simulate(config, output=…) writes the same file as `rbx simulate -o`: every dataset, its attributes and
    the root attributes, bit for bit; reading either back gives the same Run, and the in-memory run is the same
    Run too."""
    cfg, overrides = CASES[name]
    source = config_file(tmp_path, name)
    out = tmp_path / "api.h5"
    run = rbx.simulate(source, output=out, **overrides)
    assert isinstance(run, rbx.Run) and run.path == str(out) and run.complete
    ours, theirs = comparable(read_file(out)), comparable(read_file(cli_files[name]))
    assert sorted(ours) == sorted(theirs)
    for k in theirs:
        if k.endswith("attrs"):
            assert ours[k].keys() == theirs[k].keys(), k
            for a in theirs[k]:
                assert same(ours[k][a], theirs[k][a]) if isinstance(theirs[k][a], np.ndarray) \
                    else ours[k][a] == theirs[k][a], (k, a)
        else:
            assert same(ours[k], theirs[k]), k
    from_cli = rbx.open(cli_files[name])
    assert_same_run(run, from_cli)
    # in memory: from the path, from a dict, from an Experiment with the overrides given to simulate
    exp = rbx.load(source)
    in_memory = rbx.simulate(exp, **overrides)
    assert in_memory.path is None
    assert_same_run(in_memory, from_cli)
    if isinstance(cfg, dict):
        assert_same_run(rbx.simulate(cfg, **overrides), from_cli)


def test_run_exposes_the_file_layout(cli_files):
    """run.<field> has the shape and values of collisions/<field>; count, step, final, experiment, complete."""
    path = cli_files["rectangle-random"]
    run = rbx.open(path)
    with h5py.File(path, "r") as f:
        g = f["collisions"]
        assert set(run.fields) == set(g) - {"count", "step"} - set(SCALES)
        for name in run.fields:
            assert same(getattr(run, name), g[name][...])
            assert g[name].attrs["units"] == FIELD[name].units
            assert g[name].attrs["description"] == FIELD[name].description
        assert same(run.count, g["count"][...]) and same(run.step, g["step"][...])
        assert set(run.final) == set(f["final"])
    assert run.position.shape == (7, 21, 2) and run.wall.dtype == np.int32
    assert run.experiment.run.trajectories == 7 and run.experiment.run.seed == 5
    assert run.experiment.output.every == 10 and list(run.step[:3]) == [0, 10, 20]
    assert run.complete and run.trajectories == 7 and run.records == 21
    assert run.read("position", [2, 4], slice(0, 5)).shape == (2, 5, 2)
    with pytest.raises(AttributeError, match="did not record 'orientation'"):
        run.orientation
    with pytest.raises(ValueError):
        run.position[0, 0, 0] = 1.0          # read-only: the file is the record


def test_to_xarray_has_named_dimensions(cli_files):
    pytest.importorskip("xarray")
    ds = rbx.open(cli_files["box-rough"]).to_xarray()
    assert ds["position"].dims == ("trajectory", "record", "axis")
    assert ds["angular_velocity"].dims == ("trajectory", "record", "axis")
    assert ds["orientation"].dims == ("trajectory", "record", "axis", "axis2")
    assert ds["time"].dims == ("trajectory", "record") and ds["count"].dims == ("trajectory",)
    assert list(ds["axis"].values) == ["x", "y", "z"] and ds.sizes["trajectory"] == 3
    assert ds["velocity"].attrs["units"] == "L/T" and "centre" in ds["position"].attrs["description"]
    assert list(ds["step"].values[:3]) == [0, 1, 2]
    ds2 = rbx.simulate(scene("circle-rough", collisions=50)).to_xarray()
    assert ds2["angular_velocity"].dims == ("trajectory", "record") and list(ds2["axis"].values) == ["x", "y"]
    assert ds2["orientation"].attrs["units"].startswith("rad")


def test_a_bad_config_raises_config_error_naming_the_key(tmp_path):
    bad = scene("strip-rough", collisions=10)
    bad["ball"]["radius"] = -0.1
    with pytest.raises(rbx.ConfigError) as info:
        rbx.load(bad)
    assert info.value.key == "ball.radius" and "ball.radius" in str(info.value)
    with pytest.raises(rbx.ConfigError, match="ball.radius"):
        rbx.simulate(bad)
    # the CLI prints the same message for the same config in a file
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(bad))
    with pytest.raises(rbx.ConfigError) as from_file:
        rbx.load(path)
    res = subprocess.run([RBX, "simulate", str(path), "-o", str(tmp_path / "x.h5")], capture_output=True,
                         text=True)
    assert res.returncode == 2 and res.stderr.strip() == f"rbx: {from_file.value}"
    # overrides are checked as in the CLI, and name the keyword
    with pytest.raises(rbx.ConfigError, match="^collisions: "):
        rbx.simulate(scene("strip-rough"), collisions=0)
    with pytest.raises(rbx.ConfigError, match="trajectories"):
        rbx.simulate(rbx.load(scene("strip-rough")), trajectories=-2)
    with pytest.raises(TypeError):
        rbx.load(42)


def test_experiment_overrides_keep_the_stored_config_in_step(tmp_path):
    exp = rbx.load(scene("strip-random", collisions=1000))
    run = rbx.simulate(exp, collisions=30, seed=4, output=tmp_path / "r.h5")
    assert run.experiment.run.collisions == 30 and run.experiment.run.seed == 4 and run.records == 31
    assert exp.run.collisions == 1000          # the experiment itself is immutable


def test_open_of_a_file_that_is_not_a_run(tmp_path, cli_files):
    text = tmp_path / "notes.h5"
    text.write_text("not hdf5")
    with pytest.raises(rbx.FileError, match="notes.h5: not an HDF5 file"):
        rbx.open(text)
    # a config given for a run: said what it is and what to do with it, as the CLI says
    config = os.path.join(ROOT, "configs", "examples", "strip.yaml")
    with pytest.raises(rbx.FileError, match=r"strip.yaml: is an experiment config \(table, boundary, ball, initial\), "
                                            "not a run file: run it with rbx simulate"):
        rbx.open(config)
    with pytest.raises(rbx.FileError, match="file not found"):
        rbx.open(tmp_path / "missing.h5")
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f["x"] = np.arange(3)
    with pytest.raises(rbx.FileError, match="other.h5: not an rbx run file"):
        rbx.open(other)


def test_output_is_refused_without_force(tmp_path):
    out = tmp_path / "r.h5"
    out.write_bytes(b"\x89HDF\r\n\x1a\n precious")            # an HDF5 file, as rbx writes
    with pytest.raises(rbx.FileError, match="exists; use force=True"):
        rbx.simulate(scene("strip-rough", collisions=10), output=out)
    assert out.read_bytes() == b"\x89HDF\r\n\x1a\n precious"
    notes = tmp_path / "notes.h5"                           # not one: kept even with force=True
    notes.write_bytes(b"precious")
    with pytest.raises(rbx.FileError, match="is not an HDF5 file"):
        rbx.simulate(scene("strip-rough", collisions=10), output=notes, force=True)
    assert notes.read_bytes() == b"precious"
    run = rbx.simulate(scene("strip-rough", collisions=10), output=out, force=True)
    assert run.records == 11 and not Path(f"{out}.partial").exists()


def test_progress_callable_sees_the_run_finish():
    seen = []
    rbx.simulate(scene("strip-rough", collisions=2000), progress=lambda done, total: seen.append((done, total)))
    assert seen and seen[-1] == (2000, 2000)


def test_python_m_rbx_is_the_cli():
    res = subprocess.run([sys.executable, "-m", "rbx", "--version"], capture_output=True, text=True)
    assert res.returncode == 0 and rbx.__version__ in res.stdout
    res = subprocess.run([sys.executable, "-m", "rbx", "--help"], capture_output=True, text=True)
    assert res.returncode == 0 and "simulate" in res.stdout


def test_rbx_simulate_is_the_api_function_however_rbx_is_imported():
    """The engine's Python tier is the module rbx.simulation; importing it first must not change rbx.simulate."""
    code = ("import rbx.simulation\nimport rbx\nfrom rbx import api\n"
            "assert rbx.simulate is api.simulate and callable(rbx.simulate)\n"
            "r = rbx.simulate({'table': {'kind': 'strip', 'width': 1}, 'boundary': {'default': {'rule': 'constant', "
            "'rank': 1}}, 'ball': {'radius': 0.1}, 'initial': {'position': [0, 0.5], 'velocity': [0.6, 0.8]}, "
            "'run': {'collisions': 5}})\nassert r.records == 6\nprint('ok')")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert res.returncode == 0 and res.stdout.strip() == "ok", res.stderr


# ---- the README's example and the notebook --------------------------------------------------------------------

def python_blocks(markdown):
    return re.findall(r"```python\n(.*?)```", markdown, flags=re.S)


def test_readme_python_example_runs(tmp_path, monkeypatch):
    blocks = python_blocks((ROOT / "README.md").read_text())
    assert blocks, "README.md has no ```python block"
    monkeypatch.chdir(ROOT)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    namespace = {"__name__": "__readme__"}
    for block in blocks:
        exec(compile(block.replace("runs/api-example.h5", str(tmp_path / "api-example.h5")), "README.md", "exec"),
             namespace)


def test_readme_names_the_error_of_a_script_beside_the_clone(tmp_path):
    """A script in the folder that holds the clone (a folder named rbx) imports that folder, not the package: the
    README says so, with the error it gives, as it is."""
    import subprocess
    import sys
    (tmp_path / "rbx").symlink_to(ROOT, target_is_directory=True)        # the clone, as git clone … rbx names it
    (tmp_path / "script.py").write_text('import rbx\nrbx.load("configs/examples/strip.yaml")\n')
    res = subprocess.run([sys.executable, "script.py"], capture_output=True, text=True, cwd=tmp_path, timeout=120)
    error = res.stderr.strip().splitlines()[-1]
    assert res.returncode == 1 and error == "AttributeError: module 'rbx' has no attribute 'load'", res.stderr
    readme = " ".join((ROOT / "README.md").read_text().split())
    assert error in readme and "keep scripts and notebooks out of the folder that holds the clone" in readme
    # what matters is the script's own folder, not where Python is started: the same script run from inside the
    # clone fails alike (the README said "run Python from the clone's folder")
    res = subprocess.run([sys.executable, str(tmp_path / "script.py")], capture_output=True, text=True, cwd=ROOT,
                         timeout=120)
    assert res.returncode == 1 and res.stderr.strip().splitlines()[-1] == error, res.stderr


@pytest.mark.long
def test_example_notebook_runs(tmp_path, monkeypatch):
    """examples/api.ipynb, every code cell in order in one namespace (what 'Run all' does)."""
    import matplotlib
    matplotlib.use("Agg")
    nb = json.loads((ROOT / "examples" / "api.ipynb").read_text())
    cells = ["".join(c["source"]) for c in nb["cells"] if c["cell_type"] == "code"]
    assert cells
    monkeypatch.chdir(ROOT / "examples")
    namespace = {"__name__": "__notebook__"}
    for i, code in enumerate(cells):
        code = "\n".join(line for line in code.splitlines() if not line.lstrip().startswith(("%", "!")))
        exec(compile(code, f"api.ipynb cell {i}", "exec"), namespace)
    import matplotlib.pyplot as plt
    plt.close("all")


def test_a_run_larger_than_the_free_space_is_refused_before_writing(tmp_path, monkeypatch):
    import shutil
    from collections import namedtuple
    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda path: usage(10**9, 10**9 - 10**6, 10**6))   # 1 MB free
    out = tmp_path / "run.h5"
    with pytest.raises(rbx.FileError) as info:
        rbx.simulate(scene("strip-rough", collisions=100_000), output=out)
    assert "the disk has 1 MB free" in str(info.value)
    assert not out.exists() and not (tmp_path / "run.h5.partial").exists()
    # within the limit and the space: written, and the estimate was not below what was written
    monkeypatch.undo()
    run = rbx.simulate(scene("strip-rough", collisions=20_000), output=out, max_size="10 MB")
    from rbx.driver import estimated_size
    assert run.complete and out.stat().st_size <= estimated_size(run.experiment)


def test_changed_bytes_on_disk_are_a_clear_error_not_other_numbers(tmp_path):
    # every record dataset carries a Fletcher-32 checksum per chunk: bytes zeroed inside a complete file (a bad
    # disk, a truncated copy) make the read fail with one clear error instead of returning zeros
    out = tmp_path / "run.h5"
    rbx.simulate(scene("strip-rough", collisions=20_000), output=out)
    with h5py.File(out) as f:
        ds = f["collisions/velocity"]
        assert ds.fletcher32
        chunk = ds.id.get_chunk_info(0)
    with open(out, "r+b") as fh:
        fh.seek(chunk.byte_offset + chunk.size // 2)
        fh.write(b"\0" * 64)
    run = rbx.open(out)
    np.testing.assert_array_equal(run.position.shape, (1, 20_001, 2))       # the other fields still read
    with pytest.raises(rbx.FileError) as info:
        run.velocity
    assert "damaged" in str(info.value) and str(out) in str(info.value)


def test_the_2d_orientation_is_followed_whether_or_not_it_is_recorded():
    """The final θ of a rough 2D run is the orbit's, recorded or not (it was left at its initial value when
    nothing asked for it), and it is θ₀ + Σ ω τ over the flights: each record's θ is the last one's plus the
    spin after that collision times the flight time to this one."""
    exp = rbx.load(os.path.join(ROOT, "configs", "examples", "sinai.yaml"))
    kept = rbx.simulate(rbx.load(exp, {"output.record": ["time", "angular_velocity", "orientation"]}),
                        collisions=300, trajectories=2, seed=4)
    plain = rbx.simulate(rbx.load(exp, {"output.record": ["time"]}), collisions=300, trajectories=2, seed=4)
    np.testing.assert_array_equal(plain.final["orientation"], kept.final["orientation"])
    np.testing.assert_array_equal(kept.final["orientation"], kept.orientation[:, -1])
    theta, omega, t = kept.orientation[...], kept.angular_velocity[...], kept.time[...]
    assert np.ptp(omega) > 0.1                       # the spin changes at collisions: a rough table
    step = theta[:, 1:] - (theta[:, :-1] + omega[:, :-1] * np.diff(t, axis=1))
    assert np.all(np.abs(step) <= 1e-12 * (1 + np.abs(theta[:, 1:]))), np.abs(step).max()


def test_the_api_refuses_an_ensemble_beyond_memory_an_output_of_another_type_and_takes_numpy_integers():
    # 10¹⁰ trajectories in memory raised NumPy's raw MemoryError (rbx simulate refuses them with an estimate);
    # output=5 an internal TypeError; collisions=np.int64(100) (from an array) was refused as no integer
    import warnings
    strip = EXAMPLES / "strip.yaml"
    with pytest.raises(rbx.ConfigError) as info:
        rbx.simulate(strip, trajectories=10 ** 10, collisions=10)
    assert info.value.key == "trajectories" and "GiB of memory" in str(info.value), str(info.value)
    with pytest.raises(TypeError, match=r"output: a file path \(str, bytes or os.PathLike\), got int"):
        rbx.simulate(strip, collisions=10, output=5)      # a path in bytes is taken (as rbx.open takes it)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        run = rbx.simulate(strip, collisions=np.int64(100), trajectories=np.int32(2))
    assert run.experiment.run.collisions == 100 and type(run.experiment.run.collisions) is int


def test_hurried_arguments_get_one_clear_refusal(tmp_path):
    """force="no" is truthy and replaced a run; segments=None was a bare TypeError from int(); rbx.sweep(None) an
    os TypeError; a float32 was taken by rbx.load's overrides but refused by dataclasses.replace."""
    import dataclasses
    circle = str(EXAMPLES / "circle.yaml")
    out = tmp_path / "x.h5"
    out.write_bytes(b"not rbx's")
    with pytest.raises(TypeError, match="force: True or False, not 'no'"):
        rbx.simulate(circle, output=str(out), force="no")
    assert out.read_bytes() == b"not rbx's"
    with pytest.raises(TypeError, match="force: True or False"):
        rbx.resume(str(out), force=1)
    with pytest.raises(ValueError, match="segments must be an integer ≥ 1, not None"):
        rbx.lyapunov(circle, segments=None)
    with pytest.raises(TypeError, match="study is a study file's path, a mapping or a loaded Study, not NoneType"):
        rbx.sweep(None)
    with pytest.raises(TypeError, match="resume: True or False"):
        rbx.sweep({"base": circle}, resume="yes")
    exp = rbx.load(circle)
    by_replace = exp.replace(ball=dataclasses.replace(exp.ball, radius=np.float32(0.1))).ball
    assert by_replace == rbx.load(circle, {"ball.radius": np.float32(0.1)}).ball
    with pytest.raises(rbx.ConfigError, match="expected a number, got bool"):
        dataclasses.replace(exp.ball, radius=np.True_)


def test_a_path_in_bytes_is_taken_and_a_number_is_no_scheduler(tmp_path):
    """rbx.open took a path in bytes while rbx.simulate refused one; scheduler=42 was tried as the address
    tcp://42 and reported unreachable."""
    out = os.fsencode(str(tmp_path / "b.h5"))
    run = rbx.simulate(scene("strip-rough", collisions=50), output=out)
    assert run.complete and (tmp_path / "b.h5").exists() and rbx.open(out).complete
    with pytest.raises(TypeError, match="scheduler: a scheduler's address, its scheduler file or a "
                                        "distributed.Client, got int"):
        rbx.simulate(scene("strip-rough", collisions=50), scheduler=42)
