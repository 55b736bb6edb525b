"""What the figure scripts commit (figures/<label>.png and .json, docs/reference.md §6): re-plotting the same data
writes the same bytes, and the periodic figure draws a negative gap instead of clipping it."""
import json
import os
import sys
import types

import numpy as np
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
