"""An infinite horizon is found from the table's geometry, and the diffusion plot says that its slope is no
diffusion coefficient there (the MSD grows as t·log t); a table of finite horizon is plotted as before.

The corridors of a square Lorentz gas are known in closed form: with ρ = scatterer radius + R, a free strip along
the cell's sides exists iff 2ρ < 1 (width 1 − 2ρ), one along its diagonals iff 2ρ < √2/2 (width √2/2 − 2ρ).
"""
import math
import os

import pytest

import rbx
from rbx import analysis
from rbx.cli.plot import make_figure

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
EXAMPLES = os.path.join(ROOT, "configs", "examples")


def gas(cell, radius, lattice="simple", R=0.1):
    return rbx.load({"table": {"kind": "lorentz", "cell": cell, "radius": radius, "lattice": lattice},
                     "boundary": {"default": {"rule": "constant", "rank": 0}}, "ball": {"radius": R},
                     "initial": {"sample": "billiard"}}).geometry()


@pytest.mark.parametrize("radius", [0.05, 0.15, 0.2, 0.3, 0.395])
def test_the_corridors_of_a_square_lattice(radius):
    rho = radius + 0.1
    found = {c.index: c.width for c in analysis.free_corridors(gas([1.0, 1.0], radius))}
    expected = {}
    if 2 * rho < 1:
        expected.update({(1, 0): 1 - 2 * rho, (0, 1): 1 - 2 * rho})
    if 2 * rho < math.sqrt(2) / 2:
        expected.update({(1, 1): math.sqrt(2) / 2 - 2 * rho, (1, -1): math.sqrt(2) / 2 - 2 * rho})
    for index, width in expected.items():
        assert found.pop(index) == pytest.approx(width, abs=1e-12)
    # the others are of higher index, narrower than the diagonal ones (spacing 1/√(h² + k²))
    assert all(w < math.sqrt(2) / 2 - 2 * rho + 1e-12 for w in found.values()), found


def test_finite_and_infinite_horizons_of_the_examples():
    def corridors(name):
        return analysis.free_corridors(rbx.load(os.path.join(EXAMPLES, name)).geometry())
    assert corridors("lorentz-triangular.yaml") == []            # its own comment: every corridor blocked
    assert {c.index for c in corridors("lorentz.yaml")} == {(1, 0), (0, 1)}
    assert {c.index for c in corridors("lorentz3d.yaml")} == {(1, 0, 0), (0, 1, 0), (0, 0, 1)}
    assert corridors("strip.yaml") is None                      # not periodic: not a question of corridors
    # a triangular lattice (centred, cell 1 × √3) with thin scatterers: the rows along (1, 0), (1, ±1) are free
    thin = {c.index for c in analysis.free_corridors(gas([1.0, math.sqrt(3)], 0.1, "centred"))}
    assert {(0, 1), (1, 1), (1, -1)} <= thin


def short_run(tmp_path, name):
    exp = rbx.load(os.path.join(EXAMPLES, name), {"run.collisions": 2000, "run.trajectories": 16})
    rbx.simulate(exp, output=str(tmp_path / "gas.h5"))


def test_the_diffusion_plot_says_an_infinite_horizon_has_no_coefficient(tmp_path):
    short_run(tmp_path, "lorentz.yaml")
    fig = make_figure(str(tmp_path / "gas.h5"), "diffusion")
    said = fig.rbx_result                      # what rbx plot prints (tests/test_new_user.py: through the CLI)
    assert said.startswith("slope of the MSD along x, fitted as 2bt + c: b = "), said
    assert "not a diffusion coefficient: infinite horizon" in said and "t·log t" in said
    assert "no diffusion coefficient: infinite horizon" in fig.axes[0].get_title()
    labels = [t.get_text() for leg in fig.legends for t in leg.get_texts()]
    assert any(t.startswith("fit 2bt + c, over the fit window only") for t in labels), labels


def test_a_finite_horizon_keeps_its_diffusion_coefficient(tmp_path):
    short_run(tmp_path, "lorentz-triangular.yaml")
    fig = make_figure(str(tmp_path / "gas.h5"), "diffusion")
    said = fig.rbx_result                      # what rbx plot prints
    assert said.startswith("diffusion coefficient along x: D = ") and "horizon" not in said, said
    assert "horizon" not in fig.axes[0].get_title() and "coefficient" not in fig.axes[0].get_title()
    labels = [t.get_text() for leg in fig.legends for t in leg.get_texts()]
    assert any(t.startswith("fit 2Dt + c: D = ") for t in labels), labels
