"""The figure pipeline of the Makefile (docs/reference.md §6, as showyourwork does it): data depends on its config,
a picture on its script and its data, so re-plotting never re-simulates and nothing stale is left. Checked with
`make -n` (what make would run) on a copy of the real Makefile over a tree of empty files with chosen ages: no
simulation or plot runs."""
import os
import re
import shutil
import subprocess
import time

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

pytestmark = pytest.mark.skipif(shutil.which("make") is None, reason="make is not installed")


def figures_and_configs():
    text = open(os.path.join(ROOT, "Makefile")).read()
    labels = re.search(r"^FIGURES := (.*)$", text, re.M).group(1).split()
    configs = []
    for label in labels:
        folder = os.path.join(ROOT, "configs", "experiments", label)
        if os.path.isdir(folder):
            configs += [os.path.join("configs", "experiments", label, f) for f in sorted(os.listdir(folder))
                        if f.endswith(".yaml")]
        else:
            configs.append(os.path.join("configs", "experiments", label + ".yaml"))
    return labels, configs


@pytest.fixture
def tree(tmp_path):
    """A built tree: every file the pipeline knows, each older than what is made from it."""
    labels, configs = figures_and_configs()
    shutil.copy(os.path.join(ROOT, "Makefile"), tmp_path / "Makefile")
    examples = [os.path.join("configs", "examples", f) for f in sorted(os.listdir(os.path.join(ROOT, "configs",
                                                                                               "examples")))]
    sources = ["pyproject.toml", "scripts/figlib.py", "scripts/figures_readme.py", "scripts/warm_up.py",
               "rbx/engine.py"] + configs + examples + [f"scripts/fig_{x}.py" for x in labels]
    data = [c.replace("configs/experiments/", "data/").replace(".yaml", ".h5") for c in configs]
    made = [".venv/.installed", ".venv/.bytecode"] + data + [f"figures/{x}.png" for x in labels] + ["figures/README.md",
                                                                                 ".venv/.warmed-up"]
    t = time.time() - 1000
    for i, rel in enumerate(sources + made):
        path = tmp_path / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("")
        os.utime(path, (t + i, t + i))       # in this order: everything is newer than what it is made from
    return tmp_path


def dry_run(path):
    res = subprocess.run(["make", "-n", "reproduce-figures"], cwd=path, capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    return [line for line in res.stdout.splitlines() if line.strip() and not line.startswith("make")]


def test_an_up_to_date_tree_runs_nothing(tree):
    assert dry_run(tree) == []


def test_a_deleted_picture_is_drawn_again_from_its_data_without_simulating(tree):
    os.remove(tree / "figures" / "caustics.png")
    cmds = dry_run(tree)
    assert any("fig_caustics.py data/caustics.h5" in c for c in cmds), cmds
    assert any("figures_readme.py" in c for c in cmds)
    assert not any("simulate" in c for c in cmds), cmds


def test_a_changed_config_re_simulates_that_run_only(tree):
    os.utime(tree / "configs" / "experiments" / "circle.yaml")
    cmds = dry_run(tree)
    sims = [c for c in cmds if "simulate" in c]
    assert len(sims) == 1 and "configs/experiments/circle.yaml" in sims[0], cmds
    assert any("fig_circle.py" in c for c in cmds)
    assert not any(c.startswith("rm ") for c in cmds), cmds          # runs in data/ are never deleted


def test_reproduce_figures_compiles_every_example_ahead(tree):
    """The first run of an example after `make reproduce-figures` loads its kernels from the cache: the warm-up
    (scripts/warm_up.py) is part of it, and runs again when an example or rbx's source changes, and only then."""
    os.remove(tree / ".venv" / ".warmed-up")
    cmds = dry_run(tree)
    assert cmds == [".venv/bin/python scripts/warm_up.py", "touch .venv/.warmed-up"], cmds
    subprocess.run(["touch", ".venv/.warmed-up"], cwd=tree, check=True)
    assert dry_run(tree) == []
    later = time.time()
    bytecode = [".venv/bin/python -m compileall -q rbx", "touch .venv/.bytecode"]
    for changed, first in (("configs/examples/strip.yaml", []), ("rbx/engine.py", bytecode)):
        later += 100
        os.utime(tree / changed, (later, later))
        cmds = dry_run(tree)
        assert cmds == first + [".venv/bin/python scripts/warm_up.py", "touch .venv/.warmed-up"], (changed, cmds)
        assert not any("simulate" in c or "fig_" in c for c in cmds)
        later += 100
        for made in (".venv/.bytecode", ".venv/.warmed-up"):
            os.utime(tree / made, (later, later))
