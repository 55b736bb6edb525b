"""Nineteenth round: a study's results file whose variable is a link or a virtual dataset (to a FIFO: a hang that
SIGTERM did not end), a resume that replaced a file put at its output while it ran, and inputs deep or large enough
to end in a traceback. Each reproduction runs the real command line (or the API) in a subprocess; each test was seen
to fail on the code before it."""
import json
import os
import shutil
import subprocess
import sys

import h5py
import pytest
import yaml

from tests.test_reliability8 import HANG, _results, cli, wrapped
from tests.test_sweep import specular_study


def _plant(out, variable, how, target):
    """Replace ``variable`` of the results file ``out`` by an external link to ``target`` (or a virtual dataset
    whose source is it)."""
    with h5py.File(out, "r+") as f:
        shape, dtype = f[variable].shape, f[variable].dtype
        del f[variable]
        if how == "external link":
            f[variable] = h5py.ExternalLink(str(target), "/x")
        else:
            layout = h5py.VirtualLayout(shape=shape, dtype=dtype)
            layout[...] = h5py.VirtualSource(str(target), "x", shape=shape)
            f.create_virtual_dataset(variable, layout)


@pytest.mark.long
@pytest.mark.parametrize("how", ["external link", "virtual dataset"])
def test_a_results_variable_that_lies_in_another_file_is_refused_not_followed(tmp_path, how):
    """A results variable made an external link (or a virtual dataset) to a FIFO: `rbx plot --kind sweep`, `rbx
    sweep --resume` and `rbx.sweep(resume=True)` waited in the FIFO's open for ever, and SIGTERM did not end them
    (only SIGKILL); to a regular file, its values were taken as the study's. Now one line naming the variable, exit
    2, nothing opened."""
    out = _results(tmp_path)
    os.mkfifo(tmp_path / "fifo.h5")
    _plant(out, "mean_free_path", how, tmp_path / "fifo.h5")
    shutil.copyfile(out, tmp_path / "copy.nc")
    words = "is a link, not a variable of this file" if how == "external link" else "is an HDF5 virtual dataset"
    for args in (["plot", "out.nc", "--kind", "sweep", "-o", "x.png"],
                 ["sweep", "study.yaml", "-o", "out.nc", "--resume"]):
        res = cli("", *args, cwd=tmp_path)
        assert res.returncode == 2, (args, res.returncode, res.stderr)
        assert res.stderr.splitlines() == [f"rbx: out.nc: mean_free_path: {words}: its values lie elsewhere; a study's "
                                           "results hold their own (the file was changed after rbx wrote it)"] \
            if how == "external link" else len(res.stderr.splitlines()) == 1 and words in res.stderr, res.stderr
    code = ("import rbx\ntry:\n    rbx.sweep('study.yaml', output='copy.nc', resume=True)\n"
            "except rbx.FileError as exc:\n    print('refused:', exc)\n")
    res = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=HANG)
    assert res.returncode == 0 and res.stdout.startswith("refused: ") and "mean_free_path" in res.stdout, \
        (res.stdout, res.stderr)
    assert not (tmp_path / "x.png").exists()
