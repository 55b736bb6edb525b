"""Studies (``rbx sweep``, :func:`rbx.sweep`, :mod:`rbx.observables`): the observables against closed forms on the
specular Sinai table (Santaló's mean free path, the wavefront-curvature exponent, wall shares ∝ wall lengths,
Kac's mean return path), point seeds independent of the other points, a study killed with SIGKILL and resumed,
a Dask cluster giving the local numbers, the one-line refusals of bad study files, and the sweep plot.
Tiny ensembles: each number is compared with its own error bar."""
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

import rbx
from rbx import analysis
from rbx.model import ConfigError
from rbx.study import load_study
from rbx.sweeping import sweep

from reference import wavefront_sums

ROOT = Path(__file__).resolve().parents[1]
SINAI = str(ROOT / "configs" / "examples" / "sinai.yaml")
RBX = str(Path(sys.executable).with_name("rbx"))
SPECULAR = {"boundary.default": {"rule": "constant", "rank": 0}}
SKIP = {"wall_time"}        # the only number that differs between two runs of a point


def specular_study(**ensemble):
    return {"base": SINAI, "set": SPECULAR, "vary": {"table.radius": [0.2, 0.35]},
            "measure": ["mean_free_path", "lyapunov", "wall_share", "energy_drift"],
            "ensemble": {"trajectories": 4, "collisions": 3000, "seed": 3, **ensemble}}


@pytest.fixture(scope="module")
def specular(tmp_path_factory):
    out = tmp_path_factory.mktemp("specular") / "specular.nc"
    return sweep(specular_study(), out), out


def wavefront_exponent(run, centre, rho, first):
    """λ₁ of the classic billiard by the curvature of a divergent front (tests/reference.py), pooled over the
    trajectories: Σ log(1 + ℓB) over the flights after collision ``first`` / the time they take."""
    sums = [wavefront_sums(run.position[j], run.velocity[j], run.time[j], centre, rho, first)
            for j in range(run.trajectories)]
    return sum(S for S, _ in sums) / sum(T for _, T in sums)


def test_specular_sinai_against_closed_forms(specular):
    ds, _ = specular
    st = load_study(specular_study())
    assert list(ds["table.radius"].values) == [0.2, 0.35] and ds["table.radius"].attrs["units"] == "L"
    for i, (_, point) in enumerate(st.points()):
        exp = st.experiment(point)
        geom = exp.geometry()
        area, perimeter = analysis.table_measure(geom)
        # Santaló: the mean free path of the classic (ergodic) Sinai billiard is πA/P of the table the centre sees
        mfp, err = float(ds["mean_free_path"][i]), float(ds["mean_free_path_stderr"][i])
        assert float(ds["mean_free_path_santalo"][i]) == pytest.approx(math.pi * area / perimeter, rel=1e-12)
        assert 0 < err < 0.05 * mfp
        assert abs(mfp - math.pi * area / perimeter) < 3 * err
        # λ₁ by Benettin on the tangent loop = the wavefront-curvature recursion on the same orbits
        run = rbx.simulate(st.experiment(point, ("time", "position", "velocity"), 1))
        expected = wavefront_exponent(run, np.array([1.0, 0.75]), point["table.radius"] + exp.ball.radius,
                                      exp.run.collisions // 10)
        lam, lam_err = float(ds["lyapunov"][i]), float(ds["lyapunov_stderr"][i])
        assert expected > 0.3 and 0 < lam_err < 0.3 * lam
        assert abs(lam - expected) < lam_err
        assert abs(lam - expected) < 5e-3 * expected        # the same orbits: much closer than the error
        per_collision = lam * float(np.sum(run.time[:, -1] - run.time[:, exp.run.collisions // 10])) / (
            run.trajectories * (exp.run.collisions - exp.run.collisions // 10))
        assert float(ds["lyapunov_per_collision"][i]) == pytest.approx(per_collision, rel=1e-6)
        # the boundary map's invariant measure ∝ ds·cos φ dφ: a wall's share of the collisions is its length's
        lengths = np.array([analysis.wall_span(geom, w)[1] for w in range(len(exp.wall_names))])
        share, share_err = ds["wall_share"][i].values, ds["wall_share_stderr"][i].values
        assert list(ds["wall"].values) == list(exp.wall_names)
        assert share.sum() == pytest.approx(1.0)
        np.testing.assert_array_less(np.abs(share - lengths / lengths.sum()), 4 * share_err)
        assert float(ds["energy_drift"][i]) < 1e-11
    assert ds["done"].values.all() and (ds["collisions"].values > 0).all()
    assert ds.attrs["rbx_version"] == rbx.__version__ and ds.attrs["numba_version"]
    assert "table.radius" in ds.attrs["study"] and len(ds.attrs["study_digest"]) == 64


def test_results_file_reads_back_with_xarray(specular):
    import xarray as xr
    ds, path = specular
    assert path.exists() and not Path(f"{path}.partial").exists()
    with xr.open_dataset(path) as back:
        for name in ds.data_vars:
            np.testing.assert_array_equal(back[name].values, ds[name].values)
        assert back["lyapunov"].attrs["units"] == "1/T" and back["mean_free_path"].dims == ("table.radius",)


def test_kac_return_path_and_return_angles():
    """Started with the billiard measure on the left wall of the specular Sinai table (a hole: rule exit), the mean
    return path is Kac's 4A/ℓ (docs/dynamics.md); without the hole, the return angles to the wall follow the
    billiard measure (KS), and with a wrong spin in the samples they would not (tests/test_histogram.py)."""
    study = {"base": SINAI, "set": {**SPECULAR, "boundary.walls.left": {"rule": "exit"},
                                    "initial": {"sample": "billiard", "wall": "left"}},
             "vary": {"ball.inertia": [0.5]}, "measure": ["return_path", "trapped_share"],
             "ensemble": {"trajectories": 2500, "collisions": 3000, "seed": 5}}
    ds = sweep(study)
    area, _ = analysis.table_measure(rbx.load(SINAI).geometry())
    assert float(ds["return_path_kac"][0]) == pytest.approx(4 * area / 1.3, rel=1e-12)
    ratio, err = float(ds["return_path_ratio"][0]), float(ds["return_path_ratio_stderr"][0])
    assert 0 < err < 0.05 and abs(ratio - 1) < 3 * err
    assert float(ds["trapped_share"][0]) < 0.01 and float(ds["return_path_unreturned"][0]) < 0.01
    assert float(ds["trapped_share_levelled"][0]) == 1      # every orbit returned: levelled at 0, a share of 0
    from rbx.cli.sweep import sweep_panel
    # dashed beside the points: Kac's value, not a share or a flag of the same unit
    assert [r["label"] for r in sweep_panel(ds, "return_path")[0]["references"]] == [
        "Kac's lemma: C·|table| / |hole| (every state returns)"]
    panel = sweep_panel(ds, "trapped_share")[0]
    assert panel["references"] == [] and "survival still falling" not in panel.get("note", "")
    # too short for every orbit to return: the mean of the quick returns would be biased low (Kac's ratio far
    # below 1 with a small error), so there is no value, and the figure says why
    cut = sweep({**study, "ensemble": {**study["ensemble"], "collisions": 30}})
    assert np.isnan(float(cut["return_path"][0])) and np.isnan(float(cut["return_path_ratio"][0]))
    assert float(cut["return_path_unreturned"][0]) > 0.01
    panel, _ = sweep_panel(cut, "return_path")
    note = " ".join(panel["note"].split())          # wrapped to the panel's width (it ran off both edges)
    assert max(len(line) for line in panel["note"].splitlines()) <= 72, panel["note"]
    assert note.endswith("1 of 1 points: no value where some trajectory had not returned by the end of the run "
                         "(raise collisions), or with one trajectory (no mean with an error)"), panel["note"]
    # the same short run's trapped share counts orbits not out yet: the figure says so at that point
    assert float(cut["trapped_share_levelled"][0]) == 0
    assert "1 of 1 points: survival still falling at the end of the run: a share of orbits not out yet, not a " \
           "trapped share (run longer)" in " ".join(sweep_panel(cut, "trapped_share")[0]["note"].split())
    rough = {"base": SINAI, "set": {"initial": {"sample": "billiard", "wall": "left"}},
             "vary": {"ball.inertia": [0.2, 1.0]}, "measure": ["return_angle_ks"],
             "ensemble": {"trajectories": 3000, "collisions": 3000, "seed": 6}}
    ks = sweep(rough)
    assert (ks["return_angle_ks"].values > 1e-3).all() and (ks["return_angle_ks_statistic"].values < 0.05).all()
    assert (ks["return_angle_ks_returned"].values == 1).all()
    # runs too short for every sample to return: the p-value would test the truncation, so it is NaN
    short = sweep({**rough, "vary": {"ball.inertia": [0.5]},
                   "ensemble": {"trajectories": 300, "collisions": 3, "seed": 6}})
    assert 0 < float(short["return_angle_ks_returned"][0]) < 1 and np.isnan(float(short["return_angle_ks"][0]))
    panel, _ = sweep_panel(short, "return_angle_ks")
    assert panel["references"] == [] and "no p-value where some sample had not returned" in panel["note"]


def test_adding_a_point_changes_no_other_point():
    rough = {"base": SINAI, "vary": {"ball.inertia": [0.3, 0.6]}, "measure": ["mean_free_path", "wall_share"],
             "ensemble": {"trajectories": 2, "collisions": 400, "seed": 9}}
    a = sweep(rough)
    b = sweep({**rough, "vary": {"ball.inertia": [0.3, 0.45, 0.6]}})
    for name in a.data_vars:
        if name not in SKIP:
            np.testing.assert_array_equal(a[name].values, b[name].sel({"ball.inertia": [0.3, 0.6]}).values)
    assert len(set(b["seed"].values.tolist())) == 3
    c = sweep({**rough, "ensemble": {**rough["ensemble"], "seed": 10}})
    assert not np.array_equal(a["mean_free_path"].values, c["mean_free_path"].values)


def rbx_cli(*args, cwd):
    return subprocess.run([RBX, *map(str, args)], cwd=cwd, capture_output=True, text=True, timeout=600)


def same(a, b):
    assert set(a.data_vars) == set(b.data_vars)
    for name in a.data_vars:
        if name not in SKIP:
            np.testing.assert_array_equal(a[name].values, b[name].values, err_msg=name)


@pytest.mark.long
def test_a_killed_study_resumes_to_the_uninterrupted_result(tmp_path):
    import xarray as xr
    study = {"base": SINAI, "vary": {"ball.inertia": {"from": 0.1, "to": 1.0, "num": 10}},
             "measure": ["lyapunov", "regular_share"], "ensemble": {"trajectories": 4, "collisions": 400000,
                                                                    "seed": 4}}
    # points of 0.3 s or more: the results file is first written once the points took 20 writes' time (about a
    # second), then spaced as much again, so the run (3 s) lasts long enough after that first write for the kill to
    # come mid-way
    text = yaml.safe_dump(study, sort_keys=False)
    (tmp_path / "study.yaml").write_text(text)
    whole = sweep(tmp_path / "study.yaml")          # also puts the kernels in the disk cache
    partial = tmp_path / "out.nc.partial"
    proc = subprocess.Popen([RBX, "sweep", "study.yaml", "-o", "out.nc", "--quiet"], cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    done = 0
    while done < 1:
        assert proc.poll() is None, proc.communicate()
        if partial.exists():
            with xr.open_dataset(partial) as ds:
                done = int(ds["done"].sum())
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not (tmp_path / "out.nc").exists()
    with xr.open_dataset(partial) as ds:
        before = ds.load()
    assert 1 <= int(before["done"].sum()) < 10
    # a changed study is refused, in one line
    (tmp_path / "study.yaml").write_text(text.replace("400000", "390000"))
    res = rbx_cli("sweep", "study.yaml", "-o", "out.nc", "--resume", cwd=tmp_path)
    # the killed sweep's lock is stale: taken over with a warning (as rbx simulate does), then the one-line refusal
    warning, error = res.stderr.splitlines()
    assert "warning: a stale lock" in warning and "was taken over" in warning, res.stderr
    assert res.returncode == 2 and "--resume" in error and "changed" in error, res.stderr
    (tmp_path / "study.yaml").write_text(text)
    res = rbx_cli("sweep", "study.yaml", "-o", "out.nc", "--resume", "--quiet", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert not partial.exists()
    with xr.open_dataset(tmp_path / "out.nc") as ds:
        resumed = ds.load()
    same(resumed, whole)
    kept = before["done"].values.astype(bool)      # the points done before the kill were not run again
    np.testing.assert_array_equal(resumed["wall_time"].values[kept], before["wall_time"].values[kept])
    # an existing results file without --resume or --force
    res = rbx_cli("sweep", "study.yaml", "-o", "out.nc", cwd=tmp_path)
    assert res.returncode == 2 and len(res.stderr.splitlines()) == 1 and "--force" in res.stderr


@pytest.mark.long
def test_a_study_stopped_by_ctrl_c_says_what_it_kept_and_how_to_continue(tmp_path):
    import xarray as xr
    study = {"base": SINAI, "vary": {"ball.inertia": {"from": 0.1, "to": 1.0, "num": 10}},
             "measure": ["lyapunov"], "ensemble": {"trajectories": 4, "collisions": 400000, "seed": 4}}
    (tmp_path / "study.yaml").write_text(yaml.safe_dump(study, sort_keys=False))
    partial = tmp_path / "out.nc.partial"
    proc = subprocess.Popen([RBX, "sweep", "study.yaml", "-o", "out.nc", "--trajectories", "4"], cwd=tmp_path,
                            stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    while not partial.exists():
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.01)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=600)
    assert proc.returncode == 130, err
    with xr.open_dataset(partial) as ds:
        kept = int(ds["done"].sum())
    assert 1 <= kept < 10
    assert err.splitlines() == [
        f"rbx: out.nc.partial: interrupted by SIGINT after {kept} of 10 points; the file holds those {kept}. "
        "Continue with: rbx sweep study.yaml -o out.nc --trajectories 4 --resume"], err
    res = rbx_cli("sweep", "study.yaml", "-o", "out.nc", "--trajectories", "4", "--resume", cwd=tmp_path)
    assert res.returncode == 0 and f"({10 - kept} run now, {kept} before)" in res.stderr, res.stderr
    # a finished study resumed has nothing to do, and says so
    res = rbx_cli("sweep", "study.yaml", "-o", "out.nc", "--trajectories", "4", "--resume", cwd=tmp_path)
    assert res.returncode == 0 and res.stderr == "rbx: nothing to do: out.nc holds all 10 points of the study\n"


@pytest.mark.long
def test_a_dask_cluster_gives_the_local_numbers(tmp_path):
    pytest.importorskip("distributed")
    from tests.test_cluster import LocalDask
    study = {"base": SINAI, "vary": {"ball.inertia": [0.3, 0.6]}, "measure": ["lyapunov", "mean_free_path"],
             "ensemble": {"trajectories": 6, "collisions": 1500, "seed": 2}}
    local = sweep(study)
    cluster = LocalDask(tmp_path / "dask", 2)
    try:
        on = sweep(study, scheduler=cluster.address)
        workers = cluster.worker_pids()
    finally:
        cluster.stop()
    assert len(workers) == 2
    same(on, local)


BASE = f"base: {SINAI}\n"
ENSEMBLE = "ensemble: {trajectories: 2, collisions: 100, seed: 1}\n"
BAD = {
    "unknown-key": ("vary: {ball.inertai: [0.1]}\nmeasure: [lyapunov]\n", "vary.ball.inertai", "did you mean"),
    # a lone surrogate in a key: "'utf-8' codec can't encode character '\udc80'", naming no key
    "surrogate-key": ('vary: {"ball.\\udc80": [0.1]}\nmeasure: [lyapunov]\n', "vary.ball.\\udc80", "lone surrogate"),
    "empty-list": ("vary: {ball.inertia: []}\nmeasure: [lyapunov]\n", "vary.ball.inertia", "empty"),
    "not-a-number": ("vary: {ball.inertia: [0.1, x]}\nmeasure: [lyapunov]\n", "vary.ball.inertia", "number"),
    "twice": ("vary:\n  ball.inertia: [0.1]\n  ball.inertia: [0.2]\nmeasure: [lyapunov]\n", "vary.ball.inertia",
              "twice"),
    "no-to": ("vary: {ball.inertia: {from: 0.1, num: 3}}\nmeasure: [lyapunov]\n", "vary.ball.inertia.to",
              "missing"),
    "num-zero": ("vary: {ball.inertia: {from: 0.1, to: 1, num: 0}}\nmeasure: [lyapunov]\n", "vary.ball.inertia.num",
                 "≥ 1"),
    "log-zero": ("vary: {ball.inertia: {from: 0, to: 1, num: 3, scale: log}}\nmeasure: [lyapunov]\n",
                 "vary.ball.inertia", "positive"),
    "unknown-observable": ("vary: {ball.inertia: [0.1]}\nmeasure: [lyapunv]\n", "measure.lyapunv", "unknown"),
    "diffusion-bounded": ("vary: {ball.inertia: [0.1]}\nmeasure: [diffusion]\n", "measure.diffusion", "bounded"),
    "escape-no-exit": ("vary: {ball.inertia: [0.1]}\nmeasure: [escape_rate]\n", "measure.escape_rate", "exit"),
    "value-refused": ("vary: {table.radius: [0.4, 0.9]}\nmeasure: [lyapunov]\n", "vary.table.radius", "overlaps"),
    # keys the study sets at every point itself: the study overwrote them without a word (every point ran the
    # ensemble's collisions, whatever run.collisions was varied over)
    "vary-collisions": ("vary: {run.collisions: [100, 200]}\nmeasure: [mean_free_path]\n", "vary.run.collisions",
                        "ensemble.collisions"),
    "set-seed": ("set: {run: {seed: 3}}\nvary: {ball.inertia: [0.1]}\nmeasure: [mean_free_path]\n", "set.run",
                 "ensemble.seed"),
    "set-record": ("set: {output.record: [time]}\nvary: {ball.inertia: [0.1]}\nmeasure: [mean_free_path]\n",
                   "set.output.record", "observables"),
}


@pytest.mark.parametrize("option, value, words", [
    ("warmup", -5, "an integer ≥ 0"), ("warmup", 0.5, "an integer ≥ 0"), ("segments", 0, "an integer ≥ 1"),
    ("spectrum", "yes", "true or false"), ("threshold", -1, "a number > 0"), ("threshold", float("nan"), "a number"),
    ("threshold", "abc", "a number > 0")])
def test_an_observables_option_is_checked_where_the_study_is_read(option, value, words):
    """A negative warm-up reached rbx.lyapunov, which measured over more collisions than the run made; now the
    study's key is named before anything runs."""
    name = "regular_share" if option == "threshold" else "lyapunov"
    study = {"base": SINAI, "vary": {"ball.inertia": [0.5]}, "measure": [{name: {option: value}}],
             "ensemble": {"trajectories": 2, "collisions": 200, "seed": 1}}
    with pytest.raises(ConfigError, match=f"measure.{name}.{option}: must be {words}"):
        load_study(study)


@pytest.mark.parametrize("name", list(BAD))
def test_a_bad_study_is_one_line_naming_the_key(name, tmp_path):
    body, key, words = BAD[name]
    (tmp_path / "bad.yaml").write_text(BASE + body + ENSEMBLE)
    res = rbx_cli("sweep", "bad.yaml", "-o", "out.nc", cwd=tmp_path)
    assert res.returncode == 2, res.stderr
    lines = res.stderr.splitlines()
    assert len(lines) == 1 and "Traceback" not in res.stderr, res.stderr
    assert lines[0].startswith(f"rbx: bad.yaml: {key}: ") and words in lines[0], lines[0]
    assert not (tmp_path / "out.nc").exists() and not (tmp_path / "out.nc.partial").exists()


@pytest.mark.long
def test_plot_sweep_writes_a_figure(specular, tmp_path):
    _, path = specular
    res = rbx_cli("plot", path, "--kind", "sweep", "--y", "mean_free_path", "-o", "mfp.png", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    from PIL import Image
    image = Image.open(tmp_path / "mfp.png")
    assert image.size[0] > 600 and len(np.unique(np.asarray(image.convert("L")))) > 20    # drawn, not blank
    res = rbx_cli("plot", path, "--kind", "sweep", "--y", "nothing", cwd=tmp_path)
    assert res.returncode == 2 and "--y" in res.stderr and len(res.stderr.splitlines()) == 1


def test_the_title_says_what_the_whole_study_varies(specular):
    # the first point's scene named its radius (0.2) as the study's; the title gives the range over the points
    ds, _ = specular
    title = ds.attrs["title"]
    assert "scatterer of radius 0.2–0.35" in title and "radius 0.2 " not in title
    assert "varied: table.radius: 2 values, 0.2–0.35" in title
    two = load_study({"base": SINAI, "vary": {"ball.inertia": [0.1, 1.0], "table.radius": [0.2, 0.3, 0.4]},
                      "measure": ["mean_free_path"], "ensemble": {"trajectories": 1, "collisions": 20}})
    from rbx.sweeping import study_title
    text = study_title(two)
    assert "κ = 0.1–1" in text and "radius 0.2–0.4" in text
    assert text.endswith("· billiard-measure starts\nvaried: ball.inertia: 2 values, 0.1–1; table.radius: 3 values, "
                         "0.2–0.4")


@pytest.mark.long
def test_a_study_file_is_checked_for_what_it_is_and_its_output_replaces_only_regular_files(tmp_path):
    """A study file that is a device or a FIFO was read without bound (22 GB of /dev/zero) or waited on for ever, a
    bomb of aliases hung the duplicate-key walk, and ``-o X --force`` replaced a device or a link by a file."""
    os.mkfifo(tmp_path / "fifo.yaml")
    laughs = "a: &a [1, 1, 1, 1, 1, 1, 1, 1, 1]\n" + "".join(
        f"{c}: &{c} [{', '.join(['*' + p] * 9)}]\n" for p, c in zip("abcdefgh", "bcdefghi"))
    (tmp_path / "laughs.yaml").write_text(laughs)
    for study, words in (("/dev/zero", "not a regular file"), ("fifo.yaml", "not a regular file"),
                         ("laughs.yaml", "alias")):
        res = rbx_cli("sweep", study, "-o", "out.nc", cwd=tmp_path)
        assert res.returncode == 2 and res.stderr.count("\n") == 1 and words in res.stderr, res.stderr
    (tmp_path / "study.yaml").write_text(yaml.safe_dump(specular_study(trajectories=2, collisions=50)))
    os.symlink(tmp_path / "nowhere" / "x.nc", tmp_path / "dangling.nc")
    res = rbx_cli("sweep", "study.yaml", "-o", "dangling.nc", "--force", cwd=tmp_path)
    assert res.returncode == 2 and "symbolic link" in res.stderr and res.stderr.count("\n") == 1, res.stderr
    assert os.path.islink(tmp_path / "dangling.nc")


@pytest.mark.long
def test_an_ensemble_too_large_for_memory_is_one_line(tmp_path):
    study = specular_study(trajectories=10**12, collisions=100)
    study["vary"] = {"table.radius": [0.3]}
    (tmp_path / "study.yaml").write_text(yaml.safe_dump(study))
    res = rbx_cli("sweep", "study.yaml", "-o", "out.nc", cwd=tmp_path)
    assert res.returncode == 2 and res.stderr.count("\n") == 1, res.stderr
    assert "ensemble.trajectories" in res.stderr and "memory" in res.stderr and "Traceback" not in res.stderr
    # a few trajectories, but records of 10¹⁸ collisions each kept in memory for the mean free path: the process
    # grew by 0.5 GB/s until the system's out-of-memory killer ended it (exit 137, no line)
    study = specular_study(trajectories=4, collisions=100)
    (tmp_path / "long.yaml").write_text(yaml.safe_dump(study))
    res = rbx_cli("sweep", "long.yaml", "-o", "out.nc", "--collisions", "1000000000000000000", cwd=tmp_path)
    assert res.returncode == 2 and res.stderr.count("\n") == 1, res.stderr
    assert "long.yaml: ensemble.collisions: the records kept in memory need about" in res.stderr, res.stderr
    with pytest.raises(ConfigError, match="ensemble.collisions: the records kept in memory"):
        rbx.sweep(study, collisions=10**18)
    # under a limit on the process's memory (ulimit -v), the limit is what counts (the machine's 24 GB were, and a
    # MemoryError named the trajectories)
    res = subprocess.run(["bash", "-c", f"ulimit -v 4000000; exec {RBX} sweep long.yaml -o out.nc --collisions "
                          "100000000"], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert res.returncode == 2 and "long.yaml: ensemble.collisions: the records kept in memory need about" \
        in res.stderr and "more than this process may have" in res.stderr, res.stderr
    # a run in memory: the same check, naming the key given
    with pytest.raises(ConfigError, match="^collisions: the records kept in memory need about"):
        rbx.simulate(rbx.load(SINAI), collisions=10**15)
    assert not list(tmp_path.glob("out.nc*"))


@pytest.mark.parametrize("vary, key, words", [
    # one range of 10¹² values: np.linspace asked for 8 TB before anything was checked
    ("{ball.inertia: {from: 0.1, to: 1, num: 1000000000000}}", "vary.ball.inertia.num", "1000000000000 values"),
    # 1000 × 1000 points, every one refused: the grid was built (10⁶ points) before its first point was checked
    ("{ball.inertia: {from: 0.1, to: 1, num: 1000}, table.radius: {from: 0.8, to: 0.9, num: 1000}}", "vary",
     "1000 × 1000 = 1000000 points"),
])
def test_a_huge_grid_is_refused_before_it_is_built(vary, key, words, tmp_path):
    from rbx.study import MAX_POINTS
    (tmp_path / "big.yaml").write_text(f"{BASE}vary: {vary}\nmeasure: [mean_free_path]\n{ENSEMBLE}")
    res = rbx_cli("sweep", "big.yaml", "-o", "out.nc", cwd=tmp_path)
    assert res.returncode == 2 and res.stderr.count("\n") == 1, res.stderr
    assert res.stderr.startswith(f"rbx: big.yaml: {key}: ") and words in res.stderr, res.stderr
    assert f"at most {MAX_POINTS}" in res.stderr
    with pytest.raises(rbx.ConfigError) as err:         # the API's error, the same words
        sweep(tmp_path / "big.yaml")
    assert err.value.key == key and words in str(err.value)
    # zip: true varies the keys together: 1000 points, under the bound (then the radius is refused, point 1)
    (tmp_path / "zip.yaml").write_text(f"{BASE}vary: {vary}\nzip: true\nmeasure: [mean_free_path]\n{ENSEMBLE}")
    if key == "vary":
        with pytest.raises(rbx.ConfigError, match="overlaps") as err:
            load_study(tmp_path / "zip.yaml")
        assert err.value.key == "vary.table.radius"


@pytest.mark.long
def test_a_base_that_is_not_a_regular_file_is_named_as_such(tmp_path):
    # base: /dev/zero was "no such config"; a device, a FIFO, a directory are said as rbx simulate says them
    os.mkfifo(tmp_path / "fifo.yaml")
    (tmp_path / "folder").mkdir()
    for base, words in (("/dev/zero", "/dev/zero is a character device, not a regular file"),
                        ("fifo.yaml", "fifo.yaml is a FIFO (named pipe), not a regular file"),
                        ("folder", "folder is a directory"), ("nowhere.yaml", "no such config: nowhere.yaml")):
        (tmp_path / "s.yaml").write_text(f"base: {base}\nvary: {{ball.inertia: [0.1]}}\nmeasure: [lyapunov]\n"
                                         f"{ENSEMBLE}")
        res = rbx_cli("sweep", "s.yaml", "-o", "out.nc", cwd=tmp_path)
        assert res.returncode == 2 and res.stderr.count("\n") == 1, res.stderr
        assert res.stderr.startswith("rbx: s.yaml: base: ") and words in res.stderr, res.stderr


@pytest.mark.long
def test_the_sweep_plot_names_its_axes_as_a_physicist_would(specular, tmp_path):
    # the axes said "table.radius [L]" and "lyapunov [1/T]": config keys and registry names, not symbols
    from rbx import observables
    from rbx.cli.sweep import open_results, sweep_panel
    from rbx.plotting import sweep_figure
    _, path = specular
    ds = open_results(str(path))
    panel, title = sweep_panel(ds, "lyapunov")
    fig = sweep_figure([panel], title)
    ax = fig.axes[0]
    assert ax.get_xlabel() == "table radius r [L]" and ax.get_ylabel() == "Lyapunov exponent λ₁ [1/T]"
    # the axes say what is drawn against what; the title says what was run
    assert "\n4 trajectories × " in title and " against " not in title, title
    panel, _ = sweep_panel(ds, "mean_free_path")
    assert panel["ylabel"] == "mean free path ⟨ℓ⟩ [L]"
    assert [r["label"] for r in panel["references"]] == ["Santaló's mean free path πA/P"]
    assert sweep_panel(ds, "energy_drift")[0]["ylabel"] == "energy drift |ΔE|/E"        # a pure number: no unit
    assert sweep_panel(ds, "lyapunov_per_collision")[0]["ylabel"] == \
        "Lyapunov exponent per collision λ₁⟨τ⟩ [1/collision]"
    # one line per value of a second key, named by its symbol; the rank in words
    two = sweep({"base": SINAI, "vary": {"ball.inertia": [0.2, 0.6], "boundary.default.rank": [0, 1]},
                 "measure": ["mean_free_path"], "ensemble": {"trajectories": 1, "collisions": 50}})
    panel, title = sweep_panel(two, x="boundary.default.rank")
    assert panel["xlabel"] == "roughness rank"
    assert [s["label"] for s in panel["series"]] == ["κ = 0.2", "κ = 0.6"]
    assert " against " not in title, title
    assert sweep_panel(two)[0]["series"][0]["label"] == "rank = 0"
    # every observable of the registry, and each companion, is named in words (never by its registry name)
    for name, rec in observables.REGISTRY.items():
        assert observables.variable_label(name)[0].split(" [")[0] != name
        for c in rec.companions:
            assert observables.variable_label(f"{name}_{c.suffix}")[0] != f"{name}_{c.suffix}"
    res = rbx_cli("plot", path, "--kind", "sweep", "-o", "l.png", cwd=tmp_path)      # the CLI draws the same
    assert res.returncode == 0 and (tmp_path / "l.png").stat().st_size > 10_000, res.stderr


def test_a_short_study_writes_its_results_once_and_they_read_back_identical(tmp_path, monkeypatch):
    """The results file was written after the first point whatever it cost (a point of 10⁶ collisions took about as
    long as the write): a write now waits until the points since the start took WRITE_SPACING writes' time."""
    import xarray as xr

    from rbx import study as study_module
    monkeypatch.setattr(study_module, "FIRST_WRITE_COST", 1e6, raising=False)   # no write earned before the end
    monkeypatch.setattr(study_module, "_write_cost", None, raising=False)
    out = tmp_path / "out.nc"
    seen = []
    ds = sweep({**specular_study(trajectories=2, collisions=200), "vary": {"table.radius": [0.2, 0.25, 0.3]}}, out,
               progress=lambda done, total: seen.append((done, os.path.exists(f"{out}.partial"))))
    assert seen == [(0, False), (1, False), (2, False), (3, False)]
    assert out.exists() and not os.path.exists(f"{out}.partial")
    with xr.open_dataset(out, engine="h5netcdf") as back:
        assert back.load().identical(ds)        # values, dtypes, coordinates, units and the study's attributes
        assert back["wall"].values.tolist() == list(ds["wall"].values) and back["wall_share"].dims[-1] == "wall"


@pytest.mark.long
def test_the_lyapunov_sweep_plot_says_it_pools_regular_and_chaotic_orbits(specular, tmp_path):
    # rbx lyapunov says that its λ₁ pools the regular orbits with the chaotic ones; the sweep plot said nothing
    import xarray as xr

    from rbx.cli.sweep import open_results, sweep_panel
    study = {"base": SINAI, "vary": {"ball.inertia": {"from": 0.1, "to": 1.0, "num": 6}}, "measure": ["lyapunov"],
             "ensemble": {"trajectories": 8, "collisions": 20000, "seed": 4}}
    (tmp_path / "study.yaml").write_text(yaml.safe_dump(study, sort_keys=False))
    res = rbx_cli("sweep", "study.yaml", "-o", "out.nc", "--quiet", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    with xr.open_dataset(tmp_path / "out.nc") as ds:
        measured, regular = ds["lyapunov_orbits"].values, ds["lyapunov_regular"].values
    assert (measured == 8).all() and 0 < (regular > 0).sum() < 6      # some points have regular orbits, not all
    panel, _ = sweep_panel(open_results(str(tmp_path / "out.nc")), "lyapunov")
    share = round(100 * regular.max() / 8)
    assert (f"λ₁ pools each point's 8 orbits, regular and chaotic alike: {(regular > 0).sum()} of 6 points have "
            f"regular ones (own λ₁ < 0.02), up to {share}% of their orbits") in " ".join(panel["note"].split())
    res = rbx_cli("plot", "out.nc", "--kind", "sweep", "--y", "lyapunov", "-o", "l.png", cwd=tmp_path)
    assert res.returncode == 0 and (tmp_path / "l.png").exists(), res.stderr
    # the specular table's orbits are all chaotic, and the legend says so
    panel, _ = sweep_panel(open_results(str(specular[1])), "lyapunov")
    assert "λ₁ pools each point's 4 orbits; none is regular (own λ₁ < 0.02)" in " ".join(panel["note"].split())


def test_the_sweep_plot_says_what_its_error_bars_are(specular, tmp_path):
    """A bar is ±1 standard error for most observables and a Wilson interval at z = 1 for a share: the figure says
    which, and at what level, from the observable's record (the bars said nothing)."""
    from rbx import plotting
    from rbx.cli.sweep import open_results, sweep_panel
    ds = open_results(str(specular[1]))
    panel, _ = sweep_panel(ds, "mean_free_path")
    assert panel["note"] == "bars: ±1 standard error (about 68 %)"
    panel, _ = sweep_panel(ds, "lyapunov_per_collision")          # a companion with its own standard error
    assert panel["note"].splitlines()[0] == "bars: ±1 standard error (about 68 %)"
    ds["regular_share"] = ds["lyapunov"] * 0 + [0.0, 0.5]
    ds["regular_share_low"] = ds["lyapunov"] * 0 + [0.0, 0.276]
    ds["regular_share_high"] = ds["lyapunov"] * 0 + [0.2, 0.724]
    panel, _ = sweep_panel(ds, "regular_share")
    assert panel["note"] == "bars: the Wilson interval (z = 1, about 68 %)"
    panel, _ = sweep_panel(ds, "mean_free_path_santalo")          # no bars: nothing said
    assert panel.get("note") is None
    fig = plotting.sweep_figure([sweep_panel(ds, "regular_share")[0]], "t")
    assert "bars: the Wilson interval (z = 1, about 68 %)" in fig.axes[0].get_legend_handles_labels()[1]


def test_a_results_file_without_the_orbit_counts_says_only_what_it_can(specular, tmp_path):
    # a file written before the counts were kept: the regular share measured beside λ₁, or nothing about it
    from rbx.cli.sweep import open_results, pooled_note
    ds = open_results(str(specular[1])).drop_vars(["lyapunov_orbits", "lyapunov_regular"])
    assert pooled_note(ds, "λ₁", 4) == ("λ₁ pools each point's 4 orbits, regular and chaotic alike (how many were "
                                        "regular: measure regular_share)")
    ds["regular_share"] = ds["lyapunov"] * 0 + [0.0, 0.25]
    assert pooled_note(ds, "λ₁", 4) == ("λ₁ pools each point's 4 orbits, regular and chaotic alike: 1 of 2 points "
                                        "have regular ones, up to 25% of their orbits")


@pytest.mark.parametrize("form", ["inline base", "set names the table", "base valid only with set"])
def test_a_table_file_the_study_names_anywhere_is_in_its_digest(tmp_path, form):
    """A --resume refuses a study whose scene changed: the digest covers the table file an inline base names, one
    that `set:` names and a base file that is complete only with `set:`, not only the study's own text (a resume
    mixed points of two radii, exit 0)."""
    from rbx.study import load_study
    (tmp_path / "tab.yaml").write_text("{kind: sinai, size: [2.0, 1.5], radius: 0.4}\n")
    scene = {"boundary": {"default": {"rule": "constant", "rank": 0}}, "ball": {"radius": 0.1},
             "initial": {"sample": "billiard"}}
    head = {"vary": {"ball.inertia": [0.2, 0.5]}, "measure": ["mean_free_path"],
            "ensemble": {"trajectories": 4, "collisions": 100, "seed": 1}}
    if form == "inline base":
        study = {"base": {"table": "tab.yaml", **scene}, **head}
    else:
        base = dict(scene, table={"kind": "rectangle", "width": 2.0, "height": 1.0})
        if form == "base valid only with set":
            del base["initial"]
        (tmp_path / "base.yaml").write_text(yaml.safe_dump(base))
        fixed = {"table": "tab.yaml"} if form == "set names the table" else {"initial": {"sample": "billiard"},
                                                                           "table": "tab.yaml"}
        study = {"base": "base.yaml", "set": fixed, **head}
    (tmp_path / "study.yaml").write_text(yaml.safe_dump(study))
    before = load_study(str(tmp_path / "study.yaml")).digest
    assert load_study(str(tmp_path / "study.yaml")).digest == before
    (tmp_path / "tab.yaml").write_text("{kind: sinai, size: [2.0, 1.5], radius: 0.3}\n")
    assert load_study(str(tmp_path / "study.yaml")).digest != before


@pytest.mark.long
def test_the_results_never_replace_the_study_or_a_file_it_reads(tmp_path):
    """`-o` naming the study file, or a table file its base includes, is refused even with --force, in one line,
    and the file is left as it was (it was overwritten with NetCDF)."""
    (tmp_path / "tab.yaml").write_text("{kind: sinai, size: [2.0, 1.5], radius: 0.4}\n")
    study = {"base": {"table": "tab.yaml", "boundary": {"default": {"rule": "constant", "rank": 0}},
                      "ball": {"radius": 0.1}, "initial": {"sample": "billiard"}},
             "vary": {"ball.radius": [0.05, 0.1]}, "measure": ["mean_free_path"],
             "ensemble": {"trajectories": 2, "collisions": 50, "seed": 1}}
    (tmp_path / "study.yaml").write_text(yaml.safe_dump(study))
    for target, what in (("study.yaml", "the study file"), ("tab.yaml", "a file the study's base includes")):
        before = (tmp_path / target).read_bytes()
        res = rbx_cli("sweep", "study.yaml", "-o", target, "--force", cwd=tmp_path)
        assert res.returncode == 2 and len(res.stderr.splitlines()) == 1 and what in res.stderr, res.stderr
        assert (tmp_path / target).read_bytes() == before


@pytest.mark.long
def test_a_results_file_another_run_is_writing_is_refused(tmp_path):
    """A sweep takes the run lock of its results file, as `rbx simulate` does: with another process holding it
    (a second sweep, or a run writing that name), `rbx sweep --force` is refused in one line naming the holder
    and writes nothing; once the holder is gone it runs (two sweeps at once both said 'wrote', or one gave a
    BlockingIOError traceback)."""
    (tmp_path / "study.yaml").write_text(yaml.safe_dump(specular_study(trajectories=2, collisions=100)))
    holder = subprocess.Popen([sys.executable, "-c", "import sys; from rbx.locks import acquire_lock; "
                               "acquire_lock(sys.argv[1]); print('held', flush=True); sys.stdin.read()",
                               str(tmp_path / "out.nc")], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        res = rbx_cli("sweep", "study.yaml", "-o", "out.nc", "--force", cwd=tmp_path)
        assert res.returncode == 2 and len(res.stderr.splitlines()) == 1, res.stderr
        assert f"pid {holder.pid}" in res.stderr, res.stderr
        assert not (tmp_path / "out.nc").exists() and not (tmp_path / "out.nc.partial").exists()
    finally:
        holder.stdin.close()
        holder.wait(timeout=60)
    res = rbx_cli("sweep", "study.yaml", "-o", "out.nc", "--quiet", cwd=tmp_path)
    assert res.returncode == 0 and (tmp_path / "out.nc").exists(), res.stderr
    assert not (tmp_path / "out.nc.lock").exists()


@pytest.mark.long
def test_a_study_that_cannot_write_its_results_stops_in_one_line(tmp_path):
    """A full disk or a file-size limit (ulimit -f) when the results are written: one line, exit 1, no traceback
    and no half-written file (it was an h5py traceback, then a segmentation fault); with room again, --resume
    finishes the study."""
    (tmp_path / "study.yaml").write_text(yaml.safe_dump(specular_study(trajectories=2, collisions=100)))
    limited = subprocess.run(["bash", "-c", f"trap '' XFSZ; ulimit -f 8; exec {RBX} sweep study.yaml -o out.nc "
                              "--quiet"], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert limited.returncode == 1, limited.stderr
    assert "Traceback" not in limited.stderr and len(limited.stderr.splitlines()) == 1, limited.stderr
    assert "cannot write the study's results" in limited.stderr
    # its first write failed: nothing was kept, and the line does not say that something was
    assert "nothing of the study was on disk yet, so no point is kept (its results need " in limited.stderr
    assert "is as it was" not in limited.stderr and "continue with --resume" not in limited.stderr, limited.stderr
    assert not (tmp_path / "out.nc").exists() and not (tmp_path / "out.nc.partial.tmp").exists()
    res = rbx_cli("sweep", "study.yaml", "-o", "out.nc", "--resume", "--quiet", cwd=tmp_path)
    assert res.returncode == 0 and (tmp_path / "out.nc").exists(), res.stderr


def test_a_large_grid_checks_each_value_of_each_key_once(monkeypatch):
    """A study at its grid bound built and kept every point's config before the first point ran: 109 s and 613 MB,
    silently, for 100 000 points. A product grid past CHECK_EVERY_POINT points checks every value of each key
    once (the other keys at their first values) and reports the checks as they go."""
    import rbx.study as study_module
    built = []
    real = study_module.Study._experiment

    def counted(self, point, fields, every):
        built.append(dict(point))
        return real(self, point, fields, every)
    monkeypatch.setattr(study_module.Study, "_experiment", counted)
    radii = [round(0.1 + 0.004 * i, 4) for i in range(60)]
    inertia = [round(0.2 + 0.01 * i, 3) for i in range(60)]
    study = {"base": SINAI, "set": SPECULAR, "vary": {"table.radius": radii, "ball.inertia": inertia},
             "measure": ["mean_free_path"], "ensemble": {"trajectories": 1, "collisions": 20, "seed": 1}}
    reports = []
    st = load_study(study, progress=lambda done, total: reports.append((done, total)))
    assert len(st.points()) == 3600 > study_module.CHECK_EVERY_POINT
    assert len(built) == 60 + 60 - 1
    assert {p["table.radius"] for p in built} == set(radii) and {p["ball.inertia"] for p in built} == set(inertia)
    assert reports[0] == (0, 119) and reports[-1] == (119, 119)
    assert not st.__dict__.get("_experiments")          # none kept: a large study's would fill the memory
    # the results' title reads its ranges off the same points: it built all 3600 configs (the 1000 × 100 grid sat
    # silent for 67 s before its first point)
    from rbx.sweeping import study_title
    built.clear()
    title = study_title(st)
    assert len(built) <= 60 + 60 - 1
    assert "κ = 0.2–0.79" in title and "radius 0.1–0.336" in title, title


@pytest.mark.long
def test_a_study_of_copies_of_one_orbit_is_warned_about(tmp_path):
    """``rbx sweep`` ran ensembles of identical starts without a word (the circle example's fixed start, 4
    trajectories: a regular share of 1.0 ± 0.1 from 4 copies), where rbx simulate and rbx lyapunov warn. It says so
    now, once, in one line; a study whose starts differ says nothing."""
    study = {"base": str(ROOT / "configs" / "examples" / "circle.yaml"), "vary": {"ball.inertia": [0.2, 0.5]},
             "measure": ["regular_share"], "ensemble": {"trajectories": 4, "collisions": 300, "seed": 1}}
    (tmp_path / "copies.yaml").write_text(yaml.safe_dump(study))
    res = rbx_cli("sweep", "copies.yaml", "-o", "copies.nc", "--quiet", cwd=tmp_path)
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 0 and len(lines) == 1, res.stderr
    assert lines[0].startswith("rbx: warning: copies.yaml: ensemble.trajectories: the 4 trajectories all start "
                               "from the same state"), lines[0]
    with pytest.warns(RuntimeWarning, match="copies of one orbit"):
        load_study(study)
    # the results file and its figure say it too: the ensemble of each point is 4 copies of one orbit
    from rbx.cli.sweep import open_results, sweep_panel
    ds = open_results(str(tmp_path / "copies.nc"))
    assert ds.attrs["ensemble_orbits"] == 1
    assert "4 trajectories (copies of 1 orbit) × 300 collisions" in sweep_panel(ds)[1]
    study["set"] = {"initial": {"sample": "billiard"}}
    (tmp_path / "sampled.yaml").write_text(yaml.safe_dump(study))
    res = rbx_cli("sweep", "sampled.yaml", "-o", "sampled.nc", "--quiet", cwd=tmp_path)
    assert res.returncode == 0 and res.stderr == "", res.stderr
    ds = open_results(str(tmp_path / "sampled.nc"))
    assert ds.attrs["ensemble_orbits"] == 4 and "4 trajectories × 300 collisions" in sweep_panel(ds)[1]


def test_a_studys_set_can_give_a_fixed_start_for_a_sampled_one():
    """A study's ``set: {initial: {position: …, velocity: …}}`` on a base whose start is sampled replaces that
    start (it was merged into {sample: billiard} and refused as an unknown key)."""
    study = {"base": str(ROOT / "configs" / "examples" / "lorentz.yaml"),
             "set": {"initial": {"position": [0.5, 0.0], "velocity": [0.6, 0.8], "angular_velocity": 0.3}},
             "vary": {"ball.inertia": [0.2, 0.5]}, "measure": ["mean_free_path"],
             "ensemble": {"trajectories": 1, "collisions": 20, "seed": 1}}
    st = load_study(study)
    assert st.fixed["initial"]["position"] == [0.5, 0.0]


@pytest.mark.long
def test_sweep_set_and_ensemble_options_change_every_point(tmp_path):
    """``rbx sweep --set KEY=VALUE --trajectories M --collisions N`` shrinks or changes a shipped study without
    copying it: the same numbers as the study with those values written in it. A --set is checked as rbx
    simulate's is (an unknown key refused with a suggestion, in one line), and may not name a key the study sets
    or varies itself."""
    import xarray as xr
    study = {"base": SINAI, "vary": {"ball.inertia": [0.3, 0.6]}, "measure": ["mean_free_path"],
             "ensemble": {"trajectories": 500, "collisions": 100000, "seed": 2}}
    (tmp_path / "study.yaml").write_text(yaml.safe_dump(study))
    res = rbx_cli("sweep", "study.yaml", "-o", "out.nc", "--set", "ball.radius=0.05", "--trajectories", "3",
                  "--collisions", "200", "--quiet", cwd=tmp_path)
    assert res.returncode == 0 and res.stderr == "", res.stderr
    written = dict(study, set={"ball.radius": 0.05}, ensemble={"trajectories": 3, "collisions": 200, "seed": 2})
    with xr.open_dataset(tmp_path / "out.nc") as got:
        assert got.attrs["ensemble_trajectories"] == 3 and got.attrs["ensemble_collisions"] == 200
        assert "# changed by rbx sweep: --set ball.radius=0.05 --trajectories 3 --collisions 200" in got.attrs["study"]
        same(got.load(), sweep(written))
    for args, words in ((["--set", "ball.inertai=0.2"], "study.yaml: ball.inertai: unknown key (did you mean "
                                                         "'ball.inertia'?) (--set ball.inertai)"),
                        (["--set", "run.collisions=5"], "study.yaml: --set run.collisions: set at every point by the "
                                                        "study from ensemble.collisions: give --collisions"),
                        (["--set", "ball.inertia=0.2"], "study.yaml: --set ball.inertia: the study varies "
                                                        "ball.inertia"),
                        (["--trajectories", "0"], "--trajectories: 0 is not in the range x>=1")):
        res = rbx_cli("sweep", "study.yaml", "-o", "bad.nc", *args, cwd=tmp_path)
        assert res.returncode == 2 and res.stderr.count("\n") == 1 and words in res.stderr, (args, res.stderr)
        assert not (tmp_path / "bad.nc").exists()
    # a resume with another --collisions names it, and says what --force would discard (it said only "the study
    # changed … run it afresh with --force")
    res = rbx_cli("sweep", "study.yaml", "-o", "out.nc", "--resume", "--set", "ball.radius=0.05", "--trajectories",
                  "3", "--collisions", "300", cwd=tmp_path)
    assert res.returncode == 2 and res.stderr.count("\n") == 1, res.stderr
    assert "(ensemble_collisions 200 in the file, 300 now (--collisions or the study's ensemble))" in res.stderr \
        and "--force, which discards its 2 finished points" in res.stderr, res.stderr


def test_the_api_sweep_shortens_a_study_as_the_command_line_does(tmp_path):
    """``rbx.sweep(path, trajectories=, collisions=, sets=)`` is ``rbx sweep --trajectories --collisions --set``:
    the same numbers as the study with those values written in it, and the same refusals."""
    study = {"base": SINAI, "vary": {"ball.inertia": [0.3, 0.6]}, "measure": ["mean_free_path"],
             "ensemble": {"trajectories": 500, "collisions": 100000, "seed": 2}}
    (tmp_path / "study.yaml").write_text(yaml.safe_dump(study))
    got = rbx.sweep(tmp_path / "study.yaml", trajectories=3, collisions=200, sets={"ball.radius": 0.05})
    assert got.attrs["ensemble_trajectories"] == 3 and got.attrs["ensemble_collisions"] == 200
    written = dict(study, set={"ball.radius": 0.05}, ensemble={"trajectories": 3, "collisions": 200, "seed": 2})
    same(got, sweep(written))
    with pytest.raises(rbx.ConfigError, match="the study varies ball.inertia"):
        rbx.sweep(tmp_path / "study.yaml", sets={"ball.inertia": 0.2})
    # a key that is not text: it was "unsupported operand type(s) for +: 'int' and 'str'"
    with pytest.raises(TypeError, match="the keys of sets are dotted config keys such as 'ball.inertia', not 1"):
        rbx.sweep(tmp_path / "study.yaml", sets={1: 2})


def test_a_studys_own_set_of_a_varied_key_is_refused():
    # vary replaces the key at every point: a set: of it (or of a mapping holding it) was overridden without a word
    study = {"base": SINAI, "vary": {"ball.inertia": [0.3, 0.6]}, "measure": ["mean_free_path"],
             "ensemble": {"trajectories": 2, "collisions": 50}}
    for fixed, key in (({"ball.inertia": 0.2}, "set.ball.inertia"), ({"ball": {"inertia": 0.2}}, "set.ball")):
        with pytest.raises(rbx.ConfigError) as info:
            load_study(dict(study, set=fixed))
        assert info.value.key == key and "the study varies ball.inertia" in str(info.value), str(info.value)


def test_a_mapping_study_says_where_its_relative_base_is_resolved_from(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    study = {"base": "../examples/circle.yaml", "vary": {"ball.inertia": [0.2]}, "measure": ["mean_free_path"],
             "ensemble": {"trajectories": 2, "collisions": 10}}
    with pytest.raises(rbx.ConfigError) as info:
        rbx.sweep(study)
    assert info.value.key == "base"
    assert "a mapping's relative paths are resolved from the working folder" in str(info.value), str(info.value)


@pytest.mark.long
def test_a_results_file_to_resume_without_the_studys_variables_is_one_line(tmp_path):
    """A results file with the study's digest but its ``done`` deleted, of another shape or of text (damaged, or
    made by hand): --resume gave a traceback (KeyError, IndexError), or took text for finished points."""
    import h5py
    study = {"base": SINAI, "vary": {"ball.inertia": [0.3, 0.6]}, "measure": ["mean_free_path"],
             "ensemble": {"trajectories": 2, "collisions": 50, "seed": 2}}
    (tmp_path / "study.yaml").write_text(yaml.safe_dump(study))
    sweep(str(tmp_path / "study.yaml"), str(tmp_path / "r.nc"))
    for damage in ("no done", "done of 3", "done as text"):
        partial = tmp_path / "c.nc.partial"
        partial.write_bytes((tmp_path / "r.nc").read_bytes())
        with h5py.File(partial, "a") as f:
            del f["done"]
            if damage == "done of 3":
                f["done"] = np.zeros(3, np.int8)
            elif damage == "done as text":
                f["done"] = np.array([b"x", b"x"])
        res = rbx_cli("sweep", "study.yaml", "-o", "c.nc", "--resume", cwd=tmp_path)
        assert res.returncode == 2 and res.stderr.count("\n") == 1 and "Traceback" not in res.stderr, res.stderr
        assert res.stderr.startswith("rbx: c.nc.partial: done: "), res.stderr
        assert "not the results of this study as rbx sweep writes them: run it afresh with --force" in res.stderr
        assert not (tmp_path / "c.nc").exists()


@pytest.mark.long
def test_a_results_file_to_resume_with_other_coordinates_or_impossible_done_values_is_one_line(tmp_path):
    """A results file with the study's digest whose coordinates are not the study's values, or whose points marked
    done hold a NaN mean free path or another seed (made by hand): --resume continued it, the points computed now
    stored under the file's labels and the done ones kept as results, exit 0."""
    import h5py
    study = {"base": SINAI, "vary": {"ball.inertia": [0.3, 0.6]}, "measure": ["mean_free_path"],
             "ensemble": {"trajectories": 2, "collisions": 50, "seed": 2}}
    (tmp_path / "study.yaml").write_text(yaml.safe_dump(study))
    sweep(str(tmp_path / "study.yaml"), str(tmp_path / "r.nc"))
    damages = {"ball.inertia": lambda f: f["ball.inertia"].write_direct(np.array([3.0, 6.0])),
               "mean_free_path": lambda f: f["mean_free_path"].write_direct(np.array([np.nan, np.nan])),
               "seed": lambda f: f["seed"].write_direct(np.array([12345, 0], np.int64)),
               "mean_free_path_stderr": lambda f: f["mean_free_path_stderr"].write_direct(np.array([np.inf, 0.0])),
               "collisions": lambda f: f["collisions"].write_direct(np.array([-5, 0], f["collisions"].dtype)),
               # attributes its figure reads: carried into the finished file, which then plotted with a traceback
               "varied": lambda f: f.attrs.modify("varied", "[]"),
               "measure": lambda f: f.attrs.__delitem__("measure")}
    for key, damage in damages.items():
        partial = tmp_path / "c.nc.partial"
        partial.write_bytes((tmp_path / "r.nc").read_bytes())
        with h5py.File(partial, "a") as f:
            f["done"].write_direct(np.array([1, 0], np.int8))       # the first point done, the second to run
            damage(f)
        res = rbx_cli("sweep", "study.yaml", "-o", "c.nc", "--resume", cwd=tmp_path)
        assert res.returncode == 2 and res.stderr.count("\n") == 1 and "Traceback" not in res.stderr, res.stderr
        assert res.stderr.startswith(f"rbx: c.nc.partial: {key}: "), res.stderr
        assert "run it afresh with --force" in res.stderr, res.stderr
        assert not (tmp_path / "c.nc").exists()
    # the figure of a finished file edited so: one line naming the attribute, not a traceback
    from rbx.cli.common import UserError
    from rbx.cli.sweep import open_results
    for key, edit, words in (("measure", lambda f: f.attrs.__delitem__("measure"), "missing"),
                             ("varied", lambda f: f.attrs.modify("varied", "table.width"), "is not a JSON list"),
                             ("varied", lambda f: f.attrs.modify("varied", '["table.width"]'), "names 'table.width'"),
                             ("measure", lambda f: f.attrs.modify("measure", '{"a": 1}'), "is not a list of names"),
                             ("ensemble_orbits", lambda f: f.attrs.__setitem__("ensemble_orbits", "abc"),
                              "is not a whole number ≥ 1"),
                             ("varied", lambda f: (f.create_dataset("sc", data=1.0),
                                                   f.attrs.modify("varied", '["sc"]')), "names 'sc', which is not a coordinate")):
        edited = tmp_path / "edited.nc"
        edited.write_bytes((tmp_path / "r.nc").read_bytes())
        with h5py.File(edited, "a") as f:
            edit(f)
        with pytest.raises(UserError, match=f"{key}: {words}"):
            open_results(str(edited))
    # the same file as it was written, with the second point to run: continued to the whole results
    partial.write_bytes((tmp_path / "r.nc").read_bytes())
    with h5py.File(partial, "a") as f:
        f["done"].write_direct(np.array([1, 0], np.int8))
    res = rbx_cli("sweep", "study.yaml", "-o", "c.nc", "--resume", "--quiet", cwd=tmp_path)
    assert res.returncode == 0, res.stderr


@pytest.mark.parametrize("suffix", [".partial", ".lock"])
def test_results_named_as_rbxs_own_file_beside_another_are_refused(suffix, tmp_path):
    """`-o X.nc.partial` (or `X.nc.lock`) is the name rbx gives the unfinished results of `-o X.nc` (or its run
    lock): a sweep wrote its results there, exit 0, where a later `--resume -o X.nc` or `--force` takes it for its
    own. Refused in one line, as rbx simulate refuses such an output, nothing written."""
    study = {"base": SINAI, "vary": {"ball.inertia": [0.3, 0.6]}, "measure": ["mean_free_path"],
             "ensemble": {"trajectories": 2, "collisions": 50, "seed": 2}}
    (tmp_path / "study.yaml").write_text(yaml.safe_dump(study))
    res = rbx_cli("sweep", "study.yaml", "-o", f"x.nc{suffix}", "--quiet", cwd=tmp_path)
    assert res.returncode == 2 and res.stderr.count("\n") == 1, res.stderr
    assert res.stderr.startswith(f"rbx: -o: x.nc{suffix} is the name rbx gives x.nc's "), res.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["study.yaml"]


def test_a_failed_write_over_kept_points_says_how_much_room_a_write_needs(tmp_path):
    """The results are replaced whole: a new copy is written beside the old one, then renamed over it, so a disk
    that holds the results once cannot take the next write. The line says so, with the size (it said only 'free
    some room', and the same line came back at every --resume)."""
    from rbx.paths import DiskFull
    from rbx.sweeping import _write
    study = {"base": SINAI, "vary": {"ball.inertia": [0.3, 0.6]}, "measure": ["mean_free_path"],
             "ensemble": {"trajectories": 2, "collisions": 50, "seed": 2}}
    ds = sweep(study)
    path = tmp_path / "r.nc.partial"
    _write(ds, str(path))
    before = path.read_bytes()
    # a file-size limit below the new copy (ENOSPC and EFBIG are said alike), with its signal ignored for the write
    import resource
    import signal
    xfsz = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    limits = resource.getrlimit(resource.RLIMIT_FSIZE)
    resource.setrlimit(resource.RLIMIT_FSIZE, (len(before) // 2, limits[1]))
    try:
        with pytest.raises(DiskFull) as info:
            _write(ds, str(path))
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, limits)
        signal.signal(signal.SIGXFSZ, xfsz)
    said = str(info.value)
    assert "r.nc.partial is as it was (a write makes a whole new copy, " in said, said
    # a size limit is not a full disk: no 'free some room'
    assert " kB, beside it): raise the limit and continue with --resume" in said and "room" not in said, said
    assert "(File too large: a file-size limit (ulimit -f?))" in said, said
    assert path.read_bytes() == before and not (tmp_path / "r.nc.partial.tmp").exists()
    # a full disk (ENOSPC, from the flush of the new copy)
    import errno
    from unittest import mock

    def full(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    with mock.patch("rbx.sweeping.os.fsync", full), pytest.raises(DiskFull) as info:
        _write(ds, str(path))
    said = str(info.value)
    assert " kB, beside it before replacing it, so it needs that much free): free some room and continue with " \
           "--resume" in said, said
    assert path.read_bytes() == before and not (tmp_path / "r.nc.partial.tmp").exists()
    # a folder where the new copy goes is not a full disk (it said 'free some room' with 16 GB free)
    from rbx.paths import FileError
    (tmp_path / "r.nc.partial.tmp").mkdir()
    with pytest.raises(FileError, match=r"r.nc.partial.tmp: is a directory, not a regular file"):
        _write(ds, str(path))
    assert path.read_bytes() == before


def test_a_file_of_the_other_command_under_the_outputs_name_is_refused_whatever_the_options(tmp_path):
    """A killed rbx simulate's k.h5.partial beside rbx sweep -o k.h5: the sweep called it the study's file, and
    --force deleted the resumable run; a study's v.h5.partial beside rbx simulate -o v.h5 was called a killed run
    to resume with rbx simulate (which then failed), and --force deleted the finished points. Each command now says
    what the file is, and touches it with no option."""
    from rbx.paths import FileError
    study = {"base": SINAI, "vary": {"ball.inertia": [0.3]}, "measure": ["mean_free_path"],
             "ensemble": {"trajectories": 2, "collisions": 50, "seed": 2}}
    rbx.simulate(rbx.load(SINAI), collisions=20, output=str(tmp_path / "run.h5"))
    run_bytes = (tmp_path / "run.h5").read_bytes()
    (tmp_path / "k.h5.partial").write_bytes(run_bytes)
    for options in ({"force": True}, {"resume": True}, {}):
        with pytest.raises(FileError, match="k.h5.partial: is the unfinished run file of rbx simulate: continue it "
                                            "with rbx simulate --resume"):
            sweep(study, str(tmp_path / "k.h5"), **options)
    assert (tmp_path / "k.h5.partial").read_bytes() == run_bytes and not (tmp_path / "k.h5").exists()
    # a run killed while its checkpoint was copied in: HDF5 cannot open the file until its journal is applied, and
    # --force removed it (the journal left with nothing to apply to)
    (tmp_path / "t.h5.partial").write_bytes(run_bytes[:len(run_bytes) // 2])
    (tmp_path / "t.h5.partial.journal").write_bytes(b"a journal")
    with pytest.raises(FileError, match="t.h5.partial: is the unfinished run file of rbx simulate"):
        sweep(study, str(tmp_path / "t.h5"), force=True)
    assert (tmp_path / "t.h5.partial").exists()
    sweep(study, str(tmp_path / "r.nc"))
    results = (tmp_path / "r.nc").read_bytes()
    (tmp_path / "v.h5.partial").write_bytes(results)
    for force in (True, False):
        with pytest.raises(FileError, match=r"v.h5.partial: is the unfinished results of a study \(rbx sweep\)"):
            rbx.simulate(rbx.load(SINAI), collisions=20, output=str(tmp_path / "v.h5"), force=force)
    assert (tmp_path / "v.h5.partial").read_bytes() == results and not (tmp_path / "v.h5").exists()
    # resumed as a run, or given as a config: what it is, and how to continue it ("not an rbx run file (no root
    # attribute 'dimension')", "continue it with rbx simulate --resume")
    with pytest.raises(FileError, match=r"v.h5.partial: is the unfinished results of a study \(rbx sweep\): "
                                        "continue them with rbx sweep STUDY"):
        rbx.resume(str(tmp_path / "v.h5.partial"))
    with pytest.raises(ConfigError, match="v.h5.partial: is a study's results file .*continue it with rbx sweep"):
        rbx.load(str(tmp_path / "v.h5.partial"))


def test_a_reference_is_one_grey_line_where_it_is_the_same_beside_every_line_else_one_per_line():
    """Santaló's mean free path does not depend on κ: drawn once per κ in the first line's colour, the legend's
    entry matched a line hidden under the others; the largest energy drift differs per κ: in one grey it could not
    be told apart."""
    from rbx.cli.sweep import sweep_panel
    ds = sweep({"base": SINAI, "set": SPECULAR, "vary": {"ball.radius": [0.05, 0.1], "ball.inertia": [0.3, 0.6]},
                "measure": ["mean_free_path", "energy_drift"],
                "ensemble": {"trajectories": 4, "collisions": 1000, "seed": 1}})
    refs = sweep_panel(ds, "mean_free_path")[0]["references"]
    assert [(r["label"], r["color"]) for r in refs] == [("Santaló's mean free path πA/P", "0.3")]
    refs = sweep_panel(ds, "energy_drift")[0]["references"]
    assert [r["color"] for r in refs] == ["C0", "C1"] and refs[0]["label"] and refs[1]["label"] is None


def test_the_api_takes_numpys_numbers_and_bytes_paths_as_the_rest_of_it_does(tmp_path):
    """rbx.sweep refused np.int64 trajectories ("expected an integer ≥ 1, got np.int64(2)") where rbx.simulate takes
    them, and a bytes output gave a raw TypeError; rbx.open(b"run.h5") said "file not found" for a file there."""
    study = {"base": SINAI, "vary": {"ball.inertia": [0.3]}, "measure": ["mean_free_path"],
             "ensemble": {"trajectories": 2, "collisions": 50, "seed": 2}}
    out = os.fsencode(str(tmp_path / "r.nc"))
    ds = rbx.sweep(study, out, trajectories=np.int64(2), collisions=np.int64(60))
    assert ds.attrs["ensemble_collisions"] == 60 and (tmp_path / "r.nc").exists()
    run = rbx.simulate(rbx.load(SINAI), collisions=20, output=str(tmp_path / "run.h5"), max_size=np.int64(10**9))
    assert run.complete and rbx.open(os.fsencode(str(tmp_path / "run.h5"))).complete
    with pytest.raises(TypeError, match="rbx.open: path is the path of a run file"):
        rbx.open(5)


def test_a_ratio_to_a_closed_form_is_drawn_with_its_expected_value_and_a_rank_axis_has_whole_ticks(specular):
    """The ratio of the mean return path to Kac's value is drawn with a dashed line at 1 (it had none); a rank varied
    on the x axis has ticks at whole numbers only (it had 0.2, 0.4, …) and is named in words, and a rank beside it
    is 'rank = 1' in the legend, not 'boundary.default.rank = 1'."""
    from rbx import plotting
    from rbx.cli.sweep import open_results, sweep_panel
    from rbx.observables import parameter_label
    ds = open_results(str(specular[1]))
    ds["return_path_ratio"] = ds["mean_free_path"] * 0 + [0.97, 1.02]
    panel, _ = sweep_panel(ds, "return_path_ratio")
    assert {"x": None, "y": 1.0, "label": "1: Kac's lemma (every state returns)", "color": "0.3"} in \
        panel["references"]
    fig = plotting.sweep_figure([panel], "t")
    assert "1: Kac's lemma (every state returns)" in fig.axes[0].get_legend_handles_labels()[1]
    assert parameter_label("boundary.default.rank") == ("roughness rank", "rank")
    assert parameter_label("table.cell") == ("table.cell", "table.cell")       # a key without words: itself
    ranks = {"series": [{"x": [0, 1], "y": [1.0, 2.0], "err": None, "label": "rank = 0"}], "xlabel": "roughness rank",
             "ylabel": "y"}
    fig = plotting.sweep_figure([ranks], "t")
    fig.canvas.draw()
    ticks = [t for t in fig.axes[0].get_xticks() if -0.05 <= t <= 1.05]
    assert ticks and all(float(t).is_integer() for t in ticks), ticks


@pytest.mark.long
def test_a_point_with_too_few_exits_is_nan_and_a_refused_point_is_named_with_what_is_kept(tmp_path):
    """escape_rate where too few orbits exit to fit a rate is NaN, as documented (it stopped the study: 'fewer
    than 20 exits in any window', and every --resume stopped there again); a point whose values the config
    refuses, met only when it runs, is named with its values and with the finished points kept (the line named
    neither)."""
    rect = str(ROOT / "configs" / "examples" / "rectangle.yaml")
    study = {"base": rect, "set": {"boundary": {"default": {"rule": "constant", "rank": 1},
                                                "walls": {"left": {"rule": "exit"}}},
                                   "initial": {"sample": "billiard"}},
             "vary": {"table.width": [1, 300]}, "measure": ["escape_rate", "trapped_share"],
             "ensemble": {"trajectories": 300, "collisions": 100, "seed": 1}}
    ds = sweep(study)
    assert np.isfinite(float(ds["escape_rate"][0])) and np.isnan(float(ds["escape_rate"][1]))
    assert np.isfinite(float(ds["trapped_share"][1]))
    grid = {"base": rect, "set": {"initial": {"sample": "billiard"}},
            "vary": {"table.height": [1.0, 0.3], "ball.radius": [0.1, 0.2]},
            "measure": ["energy_drift"], "ensemble": {"trajectories": 1, "collisions": 2, "seed": 1}}
    (tmp_path / "grid.yaml").write_text(yaml.safe_dump(grid))
    res = rbx_cli("sweep", "grid.yaml", "-o", "g.nc", cwd=tmp_path)     # checked before any point runs
    assert res.returncode == 2 and res.stderr.count("\n") == 1, res.stderr
    assert "does not fit in a 2 × 0.3 rectangle: its height 0.3 is not more than the ball's diameter 0.4" in \
        res.stderr and res.stderr.endswith(
        "(at the point ball.radius = 0.2, table.height = 0.3)\n"), res.stderr
    import rbx.study
    with pytest.MonkeyPatch.context() as mp:        # a grid too large to check every point: met when it runs
        mp.chdir(tmp_path)
        mp.setattr(rbx.study, "CHECK_EVERY_POINT", 1)
        with pytest.raises(ConfigError) as info:
            sweep(str(tmp_path / "grid.yaml"), str(tmp_path / "h.nc"))
    assert info.value.key == "vary.ball.radius" and str(info.value).endswith(
        "(at the point ball.radius = 0.2, table.height = 0.3); the 3 of 4 points finished before it are kept in "
        "h.nc.partial (--resume stops here again: change the study, which then starts afresh with --force)"), \
        str(info.value)
    assert (tmp_path / "h.nc.partial").exists()


def test_a_studys_copies_of_one_orbit_do_not_shrink_its_error_bars():
    """A fixed start run 8 times with no random rule is one orbit 8 times: each point's errors were the orbit's over
    √8 (mean free path 0.000110 against 0.000326). Now they are the one orbit's, and the title says copies."""
    import warnings
    circle = str(ROOT / "configs" / "examples" / "circle.yaml")
    study = {"base": circle, "vary": {"ball.inertia": [0.3, 0.6]}, "measure": ["mean_free_path", "lyapunov"],
             "ensemble": {"trajectories": 1, "collisions": 300, "seed": 1}}
    one = sweep(study)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)      # copies of one orbit: warned about
        eight = sweep({**study, "ensemble": {**study["ensemble"], "trajectories": 8}})
    for name in ("mean_free_path", "mean_free_path_stderr", "lyapunov", "lyapunov_stderr"):
        assert np.array_equal(one[name].values, eight[name].values), name
    assert eight.attrs["ensemble_orbits"] == 1 and eight.attrs["ensemble_trajectories"] == 8


@pytest.mark.long
def test_points_without_an_error_bar_are_said_once_per_observable(tmp_path):
    """One trajectory in one segment gives no standard error: the study stored NaN and drew the points without a bar
    and without a word (rbx lyapunov refuses the same case). rbx sweep warns once per observable, naming it."""
    rect = str(ROOT / "configs" / "examples" / "rectangle.yaml")
    study = {"base": rect, "vary": {"ball.inertia": [0.5]},
             "measure": [{"mean_free_path": {"segments": 1}}, {"wall_share": {"segments": 1}}, "energy_drift"],
             "ensemble": {"trajectories": 1, "collisions": 50}}
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(study))
    res = rbx_cli("sweep", "s.yaml", "-o", "s.nc", "--quiet", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    lines = res.stderr.splitlines()
    for name in ("mean_free_path", "wall_share", "energy_drift"):
        assert f"rbx: warning: s.yaml: measure.{name}: 1 of 1 finished points hold no standard error: one orbit " \
               "per point gives no spread to take it from (more trajectories, of distinct orbits, or more segments " \
               "where the observable takes that option)" in lines
    assert len(lines) == 3, res.stderr
    from rbx.sweeping import NoErrorBars
    with pytest.warns(NoErrorBars, match="measure.energy_drift"):
        sweep({**study, "measure": ["energy_drift"]})


def test_two_points_of_a_study_are_never_the_same_point():
    """A value twice in one key is refused whether listed or made by a range ({from: 0.2, to: 0.2, num: 3} gave
    three identical points with one seed); with zip: true a value repeated in one key is fine as long as the points
    differ (it was refused), and two equal points are refused."""
    base = {"base": SINAI, "measure": ["mean_free_path"], "ensemble": {"trajectories": 2, "collisions": 50}}
    for vary, words in (({"ball.inertia": [0.3, 0.1, 0.3]}, "the value 0.3 comes twice"),
                        ({"ball.inertia": {"from": 0.2, "to": 0.2, "num": 3}}, "the value 0.2 comes twice"),
                        ({"ball.inertia": [1, 2, 1]}, "the value 1 comes twice")):
        with pytest.raises(ConfigError, match=words) as info:
            load_study({**base, "vary": vary})
        assert info.value.key == "vary.ball.inertia"
    st = load_study({**base, "zip": True, "vary": {"ball.inertia": [0.5, 0.4, 0.2], "ball.radius": [0.1, 0.05, 0.05]}})
    assert len(st.points()) == 3
    with pytest.raises(ConfigError, match=r"points 1 and 3 are the same \(ball.inertia = 0.5, ball.radius = 0.1\)"):
        load_study({**base, "zip": True, "vary": {"ball.inertia": [0.5, 0.4, 0.5], "ball.radius": [0.1, 0.05, 0.1]}})


def test_a_studys_own_mistakes_are_named_by_their_key(tmp_path):
    """A warm-up longer than the ensemble's collisions said '200 collisions leave -100 after the warm-up' with no
    key, once its first point ran; a study named as its own base said to run it with rbx sweep, while it was."""
    lyap = str(ROOT / "configs" / "examples" / "lyapunov-sinai.yaml")
    study = {"base": lyap, "vary": {"ball.inertia": [0.5]}, "measure": [{"lyapunov": {"segments": 5, "warmup": 300}}],
             "ensemble": {"trajectories": 2, "collisions": 200, "seed": 1}}
    with pytest.raises(ConfigError, match="300 collisions of warm-up leave none of the ensemble's 200 to measure") as info:
        load_study(study)
    assert info.value.key == "measure.lyapunov.warmup"
    study["measure"] = [{"lyapunov": {"segments": 50, "warmup": 190}}]
    with pytest.raises(ConfigError, match="50 segments in the 10 collisions measured") as info:
        load_study(study)
    assert info.value.key == "measure.lyapunov.segments"
    (tmp_path / "self.yaml").write_text(yaml.safe_dump({**study, "base": "self.yaml", "measure": ["mean_free_path"]}))
    with pytest.raises(ConfigError, match="self.yaml is a study .* base names the experiment config each point "
                                          "runs") as info:
        load_study(str(tmp_path / "self.yaml"))
    assert info.value.key == "base"


def test_a_mushroom_stem_as_wide_as_its_cap_is_named_not_an_overflow():
    with pytest.raises(ConfigError, match="must be less than the cap's diameter") as info:
        rbx.load(str(ROOT / "configs" / "examples" / "mushroom.yaml"), {"table.stem_width": 2.0})
    assert info.value.key == "table.stem_width"


def test_many_lines_are_coloured_along_a_colour_bar_not_each_in_the_legend():
    """A second key of 41 values drew 41 legend entries, and matplotlib warned that the layout collapsed."""
    import warnings

    from rbx import plotting
    from rbx.cli.sweep import MAX_LEGEND_LINES, sweep_panel
    rect = str(ROOT / "configs" / "examples" / "rectangle.yaml")
    ds = sweep({"base": rect, "vary": {"ball.inertia": [0.3, 0.6], "ball.radius": {"from": 0.05, "to": 0.15,
                                                                                     "num": MAX_LEGEND_LINES + 1}},
                "set": {"initial": {"sample": "billiard"}}, "measure": ["energy_drift"],
                "ensemble": {"trajectories": 2, "collisions": 2, "seed": 1}})
    panel, _ = sweep_panel(ds, "energy_drift", x="ball.inertia")
    assert all(s["label"] is None and "shade" in s for s in panel["series"]) and len(panel["series"]) == 11
    assert panel["shade_label"] == "ball radius R [L]"
    # each line's own reference (its largest drift) in that line's colour along the bar, one grey legend entry
    shaded = [r for r in panel["references"] if "shade" in r]
    assert len(shaded) == 11 and all(r["label"] is None for r in shaded)
    assert [r["label"] for r in panel["references"] if "shade" not in r] == \
        ["largest energy drift max |ΔE|/E (each in its line's colour)"]
    with warnings.catch_warnings():
        warnings.simplefilter("error")          # no layout warning
        fig = plotting.sweep_figure([panel], "t")
        fig.canvas.draw()
    assert any(ax.get_ylabel() == "ball radius R [L]" for ax in fig.axes)      # the colour bar
    few, _ = sweep_panel(ds, "energy_drift", x="ball.radius")                # two lines: a legend entry each
    assert [s["label"] for s in few["series"]] == ["κ = 0.3", "κ = 0.6"]


@pytest.mark.long
def test_a_hole_is_swept_by_naming_its_corners_list_items():
    """Varying the escape example's gate: `table.boundary.3.to: [[0, 0.8], …]` said only 'expected a finite number',
    and `table.boundary.3.to.1` that table.boundary has no key '3'. A list's items are named in brackets, and zip
    moves both ends of the gate together."""
    gate = str(ROOT / "configs" / "examples" / "escape-sinai.yaml")
    base = {"base": gate, "measure": ["escape_rate"], "ensemble": {"trajectories": 10, "collisions": 100}}
    with pytest.raises(ConfigError, match=r"got the list \[0, 0.8\]: a study varies one number per key; name one item "
                                          r"of a list by its index in brackets \(table.boundary\[3\].to\[1\]\)"):
        load_study({**base, "vary": {"table.boundary.3.to": [[0, 0.8], [0, 0.85]]}})
    with pytest.raises(ConfigError, match=r"a list's items are named by their index in brackets: table.boundary\[3\]"):
        load_study({**base, "vary": {"table.boundary.3.to.1": [0.8, 0.85]}})
    st = load_study({**base, "zip": True, "vary": {"table.boundary[3].to[1]": [0.8, 0.85],
                                                   "table.boundary[4].from[1]": [0.8, 0.85]}})
    from rbx.analysis import wall_measure
    gates = [wall_measure(st.experiment(p).geometry(), 4) for _, p in st.points()]
    assert gates == pytest.approx([0.8 - 0.675, 0.85 - 0.675], rel=1e-12)          # the gate's length, point by point


def test_a_studys_tangent_loop_is_checked_where_it_is_read_whichever_observable_needs_it():
    """regular_share alone runs the tangent loop with lyapunov's defaults: too few collisions were found only when a
    point ran, blamed on measure.lyapunov, which the study did not measure; copies of one orbit in one segment were
    told to use more trajectories (they had 8)."""
    circle = str(ROOT / "configs" / "examples" / "circle.yaml")
    base = {"base": circle, "vary": {"ball.inertia": [0.3, 0.6]}}
    with pytest.raises(ConfigError, match="10 segments in the 5 collisions measured") as info:
        load_study({**base, "measure": ["regular_share"], "ensemble": {"trajectories": 2, "collisions": 5}})
    assert info.value.key == "ensemble.collisions"
    with pytest.raises(ConfigError, match="one segment of one orbit gives no error estimate .the 8 trajectories") \
            as info:
        load_study({**base, "measure": [{"lyapunov": {"segments": 1}}],
                    "ensemble": {"trajectories": 8, "collisions": 300}})
    assert info.value.key == "measure.lyapunov.segments"


def test_a_command_line_set_changes_a_mapping_the_study_sets():
    """`rbx sweep --set initial.sample=billiard` on a study whose set holds `initial: {sample: point_particle}` was
    refused as 'set twice, as initial and initial.sample', though --set is made after the study's own set."""
    circle = str(ROOT / "configs" / "examples" / "circle.yaml")
    study = {"base": circle, "set": {"initial": {"sample": "point_particle"}, "boundary.default": {"rule": "constant",
                                                                                                  "rank": 0}},
             "vary": {"ball.inertia": [0.3, 0.6]}, "measure": ["mean_free_path"],
             "ensemble": {"trajectories": 2, "collisions": 50}}
    st = load_study(study, sets={"initial.sample": "billiard"})
    assert st.fixed["initial"] == {"sample": "billiard"}
    assert st.experiment(st.points()[0][1]).initial == ("sample", None)
    st = load_study(study, sets={"boundary": {"default": {"rule": "constant", "rank": 1}}})   # replaces set's part
    assert "boundary.default" not in st.fixed and st.fixed["boundary"]["default"]["rank"] == 1


def test_a_mean_over_segments_needs_two_collisions_in_each():
    """collisions: 1 with mean_free_path stored NaN with exit 0 (a NumPy warning per point) and --resume then refused
    the file rbx wrote; diffusion over 20 segments of fewer than 40 collisions measured single flights (0.073 ± 0.003
    against 0.056 ± 0.002)."""
    for measure, collisions, words in (("mean_free_path", 1, "10 segments of the ensemble's 1 collisions"),
                                       ("diffusion", 30, "20 segments of the ensemble's 30 collisions")):
        base = str(ROOT / "configs" / "examples" / ("lorentz.yaml" if measure == "diffusion" else "sinai.yaml"))
        with pytest.raises(ConfigError, match=words) as info:
            load_study({"base": base, "vary": {"ball.inertia": [0.3, 0.6]}, "measure": [measure],
                        "ensemble": {"trajectories": 2, "collisions": collisions}})
        assert info.value.key == f"measure.{measure}.segments"


def test_a_refused_point_is_named_and_numpy_values_are_taken_in_vary():
    """A height of 0.15 was refused as 'base: rectangle.yaml: ball.radius: … near wall right', naming neither the
    varied key's point nor the height; NumPy numbers in vary were refused ('expected an integer ≥ 1, got
    np.int64(2)') where ensemble, sets= and rbx.load take them; progress='x' and base=5 were bare TypeErrors."""
    rect = str(ROOT / "configs" / "examples" / "rectangle.yaml")
    base = {"base": rect, "measure": ["energy_drift"], "ensemble": {"trajectories": 2, "collisions": 5}}
    with pytest.raises(ConfigError, match=r"its height 0.15 is not more than the ball's diameter 0.2 "
                                          r"\(at the point table.height = 0.15\)"):
        load_study({**base, "vary": {"table.height": [1.0, 0.15]}})
    with pytest.raises(ConfigError, match=r"a 0.15 × 1 rectangle: its width 0.15 is not more"):
        load_study({**base, "vary": {"table.width": [0.15]}})
    st = load_study({**base, "vary": {"ball.inertia": [np.float64(0.3), np.float32(0.5)]}})
    assert [type(v) for v in st.values[0].tolist()] == [float, float]
    with pytest.raises(TypeError, match="progress is a callable"):
        sweep({**base, "vary": {"ball.inertia": [0.3]}}, progress="x")
    with pytest.raises(TypeError, match="base is the file or folder"):
        sweep({**base, "vary": {"ball.inertia": [0.3]}}, base=5)


def test_a_colour_bar_of_a_log_scaled_key_is_logarithmic():
    """12 lines of a key from 0.001 to 1 on a linear bar: 9 of them the same colour."""
    from matplotlib.colors import LogNorm

    from rbx import plotting
    series = [{"x": [0, 1], "y": [v, v], "err": None, "label": None, "shade": v} for v in np.geomspace(1e-3, 1, 12)]
    fig = plotting.sweep_figure([{"series": series, "xlabel": "x", "ylabel": "y", "shade_label": "k"}], "t")
    bar = [ax for ax in fig.axes if ax.get_ylabel() == "k"]
    assert bar and any(isinstance(getattr(c, "norm", None), LogNorm) for c in bar[0].get_children())


@pytest.mark.long
def test_a_point_whose_orbits_all_leave_during_the_warm_up_is_nan_and_said(tmp_path):
    """A λ₁ point where every orbit left through the exit during the warm-up stopped the whole study; it holds no
    value now (NaN, no orbit measured), the others are computed, a warning names the first such point, and the
    file resumes (a NaN λ₁ at a finished point is a result, not damage)."""
    study = {"base": str(ROOT / "configs" / "examples" / "escape-sinai.yaml"), "zip": True,
             # the gate from 0.825 down to 0.82 (narrow), then down to 0.001 (most of the left wall)
             "vary": {"table.boundary[4].to[1]": [0.82, 0.001], "table.boundary[5].from[1]": [0.82, 0.001]},
             "measure": [{"lyapunov": {"segments": 5, "warmup": 100}}, "regular_share"],
             "ensemble": {"trajectories": 6, "collisions": 400, "seed": 3}}
    from rbx.sweeping import NoValue
    out = tmp_path / "s.nc"
    with pytest.warns(NoValue, match=r"measure.lyapunov: 1 of 2 finished points are NaN \(the first: "
                                     r"table.boundary\[4\].to\[1\] = 0.001, table.boundary\[5\].from\[1\] = 0.001\): "
                                     "no value where every orbit left the table during its warm-up"):
        ds = sweep(study, str(out))
    lam = ds["lyapunov"].values
    assert np.isfinite(lam[0]) and lam[0] > 0.5 and np.isnan(lam[1]), lam
    assert ds["lyapunov_orbits"].values[0] >= 1 and ds["lyapunov_orbits"].values[1] == 0
    assert list(ds["done"].values) == [1, 1]
    assert np.isnan(ds["regular_share"].values[1]) and ds["regular_share"].values[0] == 0.0
    # resumed from its partial file: both points are kept as they are, nothing is run again
    os.replace(out, str(out) + ".partial")
    with pytest.warns(NoValue):
        again = sweep(study, str(out), resume=True)
    np.testing.assert_array_equal(again["lyapunov"].values, lam)
    assert list(again["collisions"].values) == list(ds["collisions"].values)


@pytest.mark.long
def test_an_escape_rate_study_draws_the_small_hole_rate_where_the_hole_is_small():
    """A hole-size sweep had no small-hole line to compare with (the single-run escape plot has one): the
    companion small_hole is |hole|/(π·|table|) for a point particle, worked out here by hand for the escape
    example (the centre's table: the 1.8 × 1.3 box less the disc of radius 0.4 + R), and NaN for a hole that is
    most of a wall."""
    study = {"base": str(ROOT / "configs" / "examples" / "escape-sinai.yaml"), "vary": {"ball.inertia": [0.5]},
             "set": {"initial": {"sample": "point_particle"}},
             "measure": ["escape_rate"], "ensemble": {"trajectories": 20, "collisions": 200, "seed": 1}}
    ds = sweep(study)
    area = 1.8 * 1.3 - math.pi * 0.5 ** 2
    # a point particle under specular walls: the classic billiard's |hole|/(π·|table|)
    assert float(ds["escape_rate_small_hole"][0]) == pytest.approx(0.15 / (math.pi * area), rel=1e-9)
    # the floor an exit too: 1.95 of the boundary's 9.3, no small hole
    large = sweep({**study, "set": {**study["set"], "boundary.walls.floor": {"rule": "exit"}}})
    assert np.isnan(float(large["escape_rate_small_hole"][0]))
    # a disc started with spin under these specular walls: each orbit its own rate, no value and no line
    spun = sweep({**study, "set": {"initial": {"sample": "billiard"}}})
    assert np.isnan(float(spun["escape_rate"][0])) and np.isnan(float(spun["escape_rate_small_hole"][0]))
    from rbx.cli.sweep import sweep_panel
    panel = sweep_panel(ds, "escape_rate")[0]
    assert [r["label"] for r in panel["references"]] == ["small-hole rate |hole| / (C·|table|)"]
    assert panel["ylabel"].startswith("escape rate per unit path in (x, R√κθ)")


@pytest.fixture(scope="module")
def lyapunov_results(tmp_path_factory):
    """A small λ₁ study and its results file -> (folder, study file, results file)."""
    folder = tmp_path_factory.mktemp("lyapunov-results")
    study = {"base": str(ROOT / "configs" / "examples" / "lyapunov-sinai.yaml"), "vary": {"ball.inertia": [0.3, 0.5]},
             "measure": [{"lyapunov": {"segments": 4}}, "regular_share"],
             "ensemble": {"trajectories": 2, "collisions": 200, "seed": 1}}
    (folder / "s.yaml").write_text(yaml.safe_dump(study))
    sweep(str(folder / "s.yaml"), str(folder / "r.nc"))
    return folder, folder / "s.yaml", folder / "r.nc"


def edit_point(path, variable, value, index=1):
    """Write ``value`` by hand into point ``index`` of ``variable`` in the study results file ``path``."""
    import h5py
    with h5py.File(path, "r+") as f:
        a = f[variable][()]
        a[index] = value
        f[variable][...] = a


def as_unfinished(results, partial):
    """Make the study results file ``results`` one with its first point still to run, at ``partial`` (what a
    resume continues)."""
    import h5py
    with h5py.File(results, "r+") as f:
        f.attrs["complete"] = 0
        d = f["done"][()]
        d[0] = 0
        f["done"][...] = d
    os.replace(results, partial)


@pytest.mark.parametrize("variable,value,words", [
    ("regular_share", 5.0, "regular_share: is not a share (a number in [0, 1])"),
    ("regular_share_low", 0.99, "regular_share_low: is above regular_share"),
    ("lyapunov_stderr", -3.0, "lyapunov_stderr: is not an error (a number ≥ 0, or none)"),
    ("lyapunov", np.inf, "lyapunov: is infinite"),
    ("lyapunov_regular", 99, "lyapunov_regular: is above lyapunov_orbits"),
    ("lyapunov_orbits", -2, "lyapunov_orbits: is not a count of orbits"),
    ("wall_time", -5.0, "wall_time: is not a time (a number ≥ 0)")])
def test_impossible_numbers_in_a_results_file_are_refused_by_resume_and_plot(lyapunov_results, tmp_path, variable,
                                                                            value, words):
    """A share of 5, a negative error bar, λ₁ = inf, more regular orbits than orbits at a finished point: a resume
    kept them in the finished file with exit 0, and the plot drew them or ended in a traceback ('yerr must not
    contain negative values'). Both refuse in one line naming the variable now (the plot in a real process for
    the first case; the others through the function it reads the file with)."""
    import shutil

    import h5py

    from rbx.cli.common import UserError
    from rbx.cli.sweep import open_results
    _, study, good = lyapunov_results
    bad = tmp_path / "bad.nc"
    shutil.copy(good, bad)
    with h5py.File(bad, "r+") as f:
        a = f[variable][()]
        a[1] = value
        f[variable][...] = a
    if variable == "regular_share":
        res = rbx_cli("plot", "bad.nc", "--kind", "sweep", "-o", "f.png", cwd=tmp_path)
        assert res.returncode == 2 and res.stderr.count("\n") == 1 and res.stderr.startswith(
            f"rbx: bad.nc: {words} at 1 of the points marked done"), res.stderr
        assert "(the first: ball.inertia = 0.5)" in res.stderr and not (tmp_path / "f.png").exists()
    with pytest.raises(UserError) as info:
        open_results(str(bad))
    assert f"{words} at 1 of the points marked done (the first: ball.inertia = 0.5)" in str(info.value)
    as_unfinished(bad, tmp_path / "r2.nc.partial")
    with pytest.raises(rbx.FileError, match=words.replace("[", r"\[").replace("]", r"\]").replace("(", r"\(")
                       .replace(")", r"\)")):
        sweep(str(study), str(tmp_path / "r2.nc"), resume=True)


@pytest.mark.long
def test_a_results_file_with_a_point_no_study_makes_is_refused_by_its_figure(specular, tmp_path):
    """Edited by hand, a study's varied values NaN or twice, and more orbits at a point than its trajectories, were
    drawn with exit 0 (the resume refused the first two already). Each is one line naming the variable."""
    import xarray as xr
    _, path = specular
    with xr.open_dataset(path) as ds:
        good = ds.load()
    cases = {"nan.nc": ("table.radius", good.assign_coords({"table.radius": [0.2, np.nan]}), "a value that is not "
                                                                                           "a number"),
             "twice.nc": ("table.radius", good.assign_coords({"table.radius": [0.2, 0.2]}), "a value twice"),
             "orbits.nc": ("lyapunov_orbits", good.assign(lyapunov_orbits=good["lyapunov_orbits"] * 0 + 9),
                           "is more than the 4 trajectories of a point")}
    for name, (key, ds, words) in cases.items():
        ds.to_netcdf(tmp_path / name, engine="h5netcdf")
        res = rbx_cli("plot", name, "--kind", "sweep", "--y", "mean_free_path", "-o", f"{name}.png", cwd=tmp_path)
        assert res.returncode == 2 and res.stderr.startswith(f"rbx: {name}: {key}: ") and words in res.stderr, \
            res.stderr
        assert len(res.stderr.splitlines()) == 1 and not (tmp_path / f"{name}.png").exists()
    # what `collisions` counts is said: a Lyapunov run's warm-up is not in it
    assert "warm-up is not counted" in good["collisions"].attrs["description"]


def test_a_study_whose_orbits_all_left_says_it_measured_nothing(specular):
    """Every orbit of every point left during its warm-up: the figure's note read "only 0–0: the others left the
    table first; none is regular", of no orbit at all."""
    from rbx.cli.sweep import pooled_note
    _, path = specular
    import xarray as xr
    with xr.open_dataset(path) as ds:
        ds = ds.load()
    ds["lyapunov_orbits"][:] = 0
    ds["lyapunov_regular"][:] = 0
    assert pooled_note(ds, "λ₁", 4) == "no point has an orbit that stayed past its warm-up: λ₁ is measured nowhere"
    ds["lyapunov_orbits"][:] = [3, 3]
    assert "(at 2 of 2 points only 3: the others left the table first)" in pooled_note(ds, "λ₁", 4)


@pytest.mark.long
def test_a_results_file_with_no_point_done_or_rounded_values_is_refused(specular, tmp_path):
    """No point marked done: `rbx plot --kind sweep` drew empty axes, exit 0. An observable stored as float32
    (its values rounded) was kept by `--resume` as 'nothing to do'."""
    import xarray as xr
    _, path = specular
    with xr.open_dataset(path) as ds:
        good = ds.load()
    good.assign(done=good["done"] * 0).to_netcdf(tmp_path / "none.nc", engine="h5netcdf")
    res = rbx_cli("plot", "none.nc", "--kind", "sweep", "--y", "mean_free_path", "-o", "n.png", cwd=tmp_path)
    assert res.returncode == 2 and res.stderr == ("rbx: none.nc: done: no point of the study is done: nothing to draw "
                                                  "(continue it with rbx sweep --resume)\n"), res.stderr
    good.assign(mean_free_path=good["mean_free_path"].astype(np.float32)).to_netcdf(tmp_path / "r.nc",
                                                                                    engine="h5netcdf")
    (tmp_path / "study.yaml").write_text(yaml.safe_dump(specular_study()))
    res = rbx_cli("sweep", "study.yaml", "-o", "r.nc", "--resume", cwd=tmp_path)
    assert res.returncode == 2 and "mean_free_path: holds float32 values where this study writes float64" in \
        res.stderr and len(res.stderr.splitlines()) == 1, res.stderr


def test_a_study_seed_beyond_a_runs_seed_is_refused_before_any_point_runs():
    """``ensemble.seed: 2**64`` ran every point, then the first write of the results failed in a 63-line TypeError
    traceback and the points were lost; ``rbx simulate --seed`` refuses such a seed. The study takes the same
    range as run.seed."""
    base = {"base": SINAI, "vary": {"ball.inertia": [0.3]}, "measure": ["mean_free_path"],
            "ensemble": {"trajectories": 2, "collisions": 50}}
    with pytest.raises(ConfigError, match=r"ensemble.seed: at most 9223372036854775807 \(2⁶³ − 1\), as run.seed; "
                                          r"got 18446744073709551616"):
        load_study({**base, "ensemble": {**base["ensemble"], "seed": 2 ** 64}})
    assert load_study({**base, "ensemble": {**base["ensemble"], "seed": 2 ** 63 - 1}}).ensemble["seed"] == 2 ** 63 - 1


@pytest.mark.long
def test_a_results_file_with_a_zip_flag_or_values_no_study_writes_is_one_line(specular, tmp_path):
    """Edited by hand: `zip` as 'maybe' ended `rbx plot --kind sweep` in a ValueError traceback, and `--resume` kept
    it (and a zip changed from 0 to 1); a numeric varied key holding text ended the figure in a traceback too."""
    import xarray as xr
    _, path = specular
    with xr.open_dataset(path) as ds:
        good = ds.load()
    maybe = good.copy()
    maybe.attrs["zip"] = "maybe"
    maybe.to_netcdf(tmp_path / "maybe.nc", engine="h5netcdf")
    res = rbx_cli("plot", "maybe.nc", "--kind", "sweep", "--y", "mean_free_path", "-o", "m.png", cwd=tmp_path)
    assert res.returncode == 2 and res.stderr == ("rbx: maybe.nc: zip: is 'maybe', not 0 or 1: the file was not "
                                                  "written as rbx sweep writes it; run the study again\n"), res.stderr
    zipped = good.copy()
    zipped.attrs["zip"] = 1
    zipped.to_netcdf(tmp_path / "r.nc", engine="h5netcdf")
    (tmp_path / "study.yaml").write_text(yaml.safe_dump(specular_study()))
    res = rbx_cli("sweep", "study.yaml", "-o", "r.nc", "--resume", cwd=tmp_path)
    assert res.returncode == 2 and "r.nc: zip: is '1' where this study's is '0'" in res.stderr, res.stderr
    text = good.assign_coords({"table.radius": ["a", "b"]})
    text.to_netcdf(tmp_path / "text.nc", engine="h5netcdf")
    res = rbx_cli("plot", "text.nc", "--kind", "sweep", "--y", "mean_free_path", "-o", "t.png", cwd=tmp_path)
    assert res.returncode == 2 and len(res.stderr.splitlines()) == 1 and res.stderr.startswith("rbx: text.nc: ") \
        and "the file was not written as rbx sweep writes it" in res.stderr, res.stderr


@pytest.mark.parametrize("output", ["", "sub", "sub/", "/"])
def test_results_named_as_a_folder_are_refused_before_any_point(tmp_path, monkeypatch, output):
    """rbx.sweep(study, output='' or a folder, force=True) ran every point, then put the results and the lock
    beside the folder, in the one above (output='/': '/.partial'), and said the disk was full. Now refused before
    any point, nothing written."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "sub").mkdir()
    with pytest.raises(rbx.FileError, match="an empty file name" if not output else "is a folder: give the results"):
        rbx.sweep(specular_study(trajectories=2, collisions=100), output=output, force=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sub"] and not list((tmp_path / "sub").iterdir())
    assert not os.path.exists("/.partial") and not os.path.exists("/.lock")


@pytest.mark.parametrize("variable,words", [
    ("lyapunov", "lyapunov: is NaN at 1 of the points marked done where the file says its orbits were measured"),
    ("mean_free_path", "mean_free_path: is not a number at 1 of the points marked done"),
    ("energy_drift", "energy_drift: is not a number at 1 of the points marked done")])
def test_a_value_removed_where_the_file_says_there_is_one_is_refused_by_the_figure_too(specular, tmp_path, variable,
                                                                                      words):
    """A NaN written into a finished point's λ₁ (its orbits measured: `lyapunov_orbits` 4), mean free path or
    energy drift (numbers every run gives): the figure drew the point as one without a value, its legend blaming
    orbits that left the table, exit 0; for the last two only the resume refused it. The figure and the resume
    both refuse it now, one line naming the variable (the figure in a real process for λ₁)."""
    import shutil

    import h5py

    from rbx.cli.common import UserError
    from rbx.cli.sweep import open_results
    _, good = specular
    with h5py.File(good, "r") as f:
        assert f["lyapunov_orbits"][()].tolist() == [4, 4]
    bad = tmp_path / "bad.nc"
    shutil.copy(good, bad)
    edit_point(bad, variable, np.nan)
    if variable == "lyapunov":
        res = rbx_cli("plot", "bad.nc", "--kind", "sweep", "-o", "f.png", cwd=tmp_path)
        assert res.returncode == 2 and res.stderr.count("\n") == 1 and words in res.stderr, res.stderr
        assert not (tmp_path / "f.png").exists()
    with pytest.raises(UserError) as info:
        open_results(str(bad))
    assert words in str(info.value) and "(the first: table.radius = 0.35)" in str(info.value)
    as_unfinished(bad, tmp_path / "r.nc.partial")
    with pytest.raises(rbx.FileError) as info:
        sweep(specular_study(), str(tmp_path / "r.nc"), resume=True)
    assert words in str(info.value)


def test_the_error_of_a_lyapunov_exponent_may_be_missing_where_its_value_is_not(specular, tmp_path):
    # λ₁'s error needs several segments or orbits; a point without one is read (and one with λ₁ and no orbit is not)
    import shutil

    from rbx.cli.common import UserError
    from rbx.cli.sweep import open_results
    _, good = specular
    bad = tmp_path / "bad.nc"
    shutil.copy(good, bad)
    edit_point(bad, "lyapunov_stderr", np.nan)
    open_results(str(bad))
    edit_point(bad, "lyapunov_orbits", 0)
    with pytest.raises(UserError) as info:
        open_results(str(bad))
    assert "lyapunov: is a number at 1 of the points marked done where the file says no orbit was measured" in \
        str(info.value)
