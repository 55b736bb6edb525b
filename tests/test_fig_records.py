"""What the figure scripts commit (figures/<label>.png and .json, docs/reference.md §6): re-plotting the same data
writes the same bytes, and the periodic figure draws a negative gap instead of clipping it."""
import json
import os
import sys
import types

import numpy as np
import pytest
from matplotlib.figure import Figure as MplFigure

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "scripts"))

from figlib import Figure  # noqa: E402
from fig_periodic import draw_gap  # noqa: E402


def save_once(tmp_path, name):
    fig = Figure("demo", caption="a caption")
    fig.measure("a quantity", 1.5, "L")
    fig.check("a property", 1.0, "<=", 2.0)
    out = MplFigure(figsize=(2, 2))
    out.add_subplot().plot([0, 1], [1, 0])
    png = tmp_path / f"{name}.png"
    fig.save(out, types.SimpleNamespace(output=str(png), data=[]))
    return png.read_bytes(), (tmp_path / f"{name}.json").read_text()


def test_replotting_writes_the_same_png_and_json_with_no_timing(tmp_path):
    png1, json1 = save_once(tmp_path, "a")
    png2, json2 = save_once(tmp_path, "b")
    assert png1 == png2 and json1 == json2
    record = json.loads(json1)
    assert set(record) == {"label", "caption", "data", "configs", "measured", "checks"}    # nothing run-dependent


def test_periodic_gap_panel_draws_a_negative_gap_with_its_sign():
    supremum = 2.0
    s_run = np.maximum.accumulate(np.concatenate([np.linspace(1.0, supremum * (1 - 1e-12), 500),
                                                  np.full(500, supremum * (1 + 3e-11))]))
    ax = MplFigure().add_subplot()
    draw_gap(ax, s_run, supremum)
    lines = {ln.get_label(): ln.get_ydata() for ln in ax.get_lines()}
    negative = [y for label, y in lines.items() if label.startswith("gap < 0")]
    assert len(negative) == 1
    drawn = np.asarray(negative[0], float)
    assert abs(np.nanmax(drawn) - 3e-11) < 1e-15                            # its size
    assert np.nanmin(drawn) > 1e-12                                          # not clipped to a floor
    assert "-3e-11" in ax.get_title() and "never crossed" not in ax.get_title()
    assert "from collision 501" in [t.get_text() for t in ax.get_legend().get_texts()][1]


def _tree(tmp_path):
    """A copy of the repository's configs and figure scripts, so that the data/ they check is the copy's."""
    import shutil
    for folder in ("configs", "scripts"):
        shutil.copytree(os.path.join(ROOT, folder), tmp_path / folder)
    (tmp_path / "data").mkdir()
    return tmp_path


def _run(args, cwd):
    import subprocess
    return subprocess.run(args, cwd=cwd, capture_output=True, text=True, timeout=600,
                          env={**os.environ, "MPLBACKEND": "Agg"})


@pytest.mark.long
def test_a_figure_refuses_data_not_made_with_its_configs_own_run_settings(tmp_path):
    tree = _tree(tmp_path)
    rbx = os.path.join(os.path.dirname(sys.executable), "rbx")
    config = "configs/experiments/histogram.yaml"
    script = [sys.executable, "scripts/fig_histogram.py", "data/histogram.h5", "-o", "figures/histogram.png"]
    # rbx histogram's --data defaults to the config's output.path: data/histogram.h5, of 300 samples
    res = _run([rbx, "histogram", config, "-o", "h.png", "--trajectories", "300", "--quiet"], tree)
    assert res.returncode == 0 and (tree / "data" / "histogram.h5").exists(), res.stderr
    res = _run(script, tree)
    assert res.returncode == 2 and not (tree / "figures" / "histogram.png").exists(), res.stdout + res.stderr
    assert res.stderr.splitlines() == [
        "rbx: data/histogram.h5: run.trajectories: 300 in this file, 100000 in configs/experiments/histogram.yaml, "
        "which the figure is made from: make it again: rm data/histogram.h5 && make reproduce-figures"], res.stderr
    # another seed, or another key, is named too
    res = _run([rbx, "histogram", config, "-o", "h.png", "--force", "--quiet", "--set", "run.trajectories=300",
                "--set", "run.seed=7", "--set", "ball.inertia=0.3"], tree)
    assert res.returncode == 0, res.stderr
    res = _run(script, tree)
    assert res.returncode == 2 and "data/histogram.h5: run.trajectories: 300 in this file" in res.stderr
    assert "(and 2 other keys)" in res.stderr and len(res.stderr.splitlines()) == 1, res.stderr
    # the config as it stands: the figure is drawn (here of 300 samples, the config's own number)
    text = (tree / config).read_text()
    (tree / config).write_text(text.replace("trajectories: 100000", "trajectories: 300"))
    res = _run([rbx, "histogram", config, "-o", "h.png", "--force", "--quiet"], tree)
    assert res.returncode == 0, res.stderr
    res = _run(script, tree)
    assert res.returncode in (0, 1) and "rbx:" not in res.stderr, res.stdout + res.stderr
    assert (tree / "figures" / "histogram.png").exists()


def test_a_figure_and_its_record_never_write_through_a_link_or_replace_another_file(tmp_path):
    """figs/circ.json a link to notes.txt: the figure script wrote its JSON record into notes.txt, exit 0; an
    unrelated c2.json beside c2.png was replaced the same way. Now each is refused in one line, exit 2, and left as
    it was; the figure's own earlier record and PNG are replaced as before."""
    import pytest
    notes = tmp_path / "notes.txt"
    notes.write_text("notes\n")
    (tmp_path / "a.json").symlink_to(notes)
    (tmp_path / "b.json").write_text('{"mine": 1}\n')
    for name in ("a", "b"):
        with pytest.raises(SystemExit) as exit_:
            save_once(tmp_path, name)
        assert exit_.value.code == 2
    assert notes.read_text() == "notes\n" and (tmp_path / "b.json").read_text() == '{"mine": 1}\n'
    assert os.path.islink(tmp_path / "a.json")
    (tmp_path / "c.png").symlink_to(notes)       # a link at the figure's own name: not written through either
    with pytest.raises(SystemExit) as exit_:
        save_once(tmp_path, "c")
    assert exit_.value.code == 2 and notes.read_text() == "notes\n"
    first = save_once(tmp_path, "d")
    assert save_once(tmp_path, "d") == first      # its own record and figure: replaced, the same bytes
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json", "b.json", "c.png", "d.json", "d.png", "notes.txt"]
