"""The committed figures (figures/<label>.png, .json, README.md) come out the same on every CPU: no minus sign on a
zero, records to the digits that mean something, log axes and the autocorrelation of Figure graph independent of
the SIMD kernels NumPy picks for the CPU (scripts/figlib.py explains why)."""
import decimal
import json
import os
import platform
import subprocess
import sys
import types

import numpy as np
import pytest
from matplotlib.figure import Figure as MplFigure

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "scripts"))

import figlib  # noqa: E402
from fig_graph import autocorrelation  # noqa: E402
from fig_plate import record_plates  # noqa: E402
from figlib import ROUNDING, Figure, fixed  # noqa: E402


def _dispatch_targets():
    """NumPy's run-time SIMD targets of this build (AVX2, AVX-512 … on x86-64), to be switched off."""
    try:
        from numpy._core._multiarray_umath import __cpu_dispatch__
    except ImportError:                                     # NumPy 1.x
        from numpy.core._multiarray_umath import __cpu_dispatch__
    return list(__cpu_dispatch__)


def _in_subprocess(code, **env):
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=ROOT,
                         env={**os.environ, "MPLBACKEND": "Agg", **env})
    assert out.returncode == 0, out.stderr
    return out.stdout.strip()


def test_fixed_writes_no_minus_zero():
    assert fixed(-3e-17, 6) == "0.000000"
    assert fixed(-0.0, 4) == "0.0000"
    assert fixed(4e-17, 6) == "0.000000"
    assert fixed(-0.3142857142857143, 6) == "-0.314286"
    assert fixed(-0.00042, 4) == "-0.0004"


def test_plate_record_writes_a_zero_drift_without_sign():
    # the projection of conserved_drift is 0 in exact arithmetic and ±1e-17 in floating point, its sign the CPU's:
    # figures/plate.json read "(0.000000, -0.000000)" on an Intel Xeon
    fig = Figure("demo", caption="a caption")
    m = dict(N=1000, n1=100, e1=0.5, eN=0.5, exponent=3.9e-9, lags=[10, 100], tamsd_exponent=0.0039,
             drift=np.array([2.1e-17, -3.5e-17]), measured_drift=np.array([-4.2e-10, 1e-9]), drifts=False)
    record_plates(fig, m)
    values = {r["name"]: r["value"] for r in fig.measured}
    assert values["conserved (slip-free) horizontal velocity, predicted"] == "(0.000000, 0.000000)"
    assert values["mean horizontal velocity over the run, measured"] == "(0.000000, 0.000000)"


def test_record_keeps_its_digits_and_checks_the_value_itself(tmp_path):
    fig = Figure("demo", caption="a caption")
    fig.measure("supremum", 6.834284309081306)
    fig.measure("gap", -8.261756041420001e-11, digits=ROUNDING)
    fig.measure("zero", -0.0)
    fig.measure("count", 1000000)
    held = fig.check("just above the bound", 1.0000000000004, "<=", 1.0)
    out = MplFigure(figsize=(1, 1))
    out.add_subplot().plot([0, 1])
    with pytest.raises(SystemExit):                         # the failed check fails the figure
        fig.save(out, types.SimpleNamespace(output=str(tmp_path / "demo.png"), data=[]))
    text = (tmp_path / "demo.json").read_text()
    record = json.loads(text)
    values = [m["value"] for m in record["measured"]]
    assert values == [6.834284309, -8.3e-11, 0.0, 1000000.0]
    assert "-0.0" not in text
    assert not held and record["checks"][0]["ok"] is False and record["checks"][0]["value"] == 1.0


def test_log_axis_maps_data_by_the_exactly_rounded_log10():
    x = np.concatenate([np.geomspace(1e-17, 1e7, 3001), 10.0 ** np.arange(-17, 8), [0.7, 3.0, 2.0 ** -60]])
    ax = MplFigure().add_subplot()
    ax.set_yscale("log")
    got = ax.yaxis.get_transform().transform(x)
    exact = decimal.Context(prec=40)
    want = np.array([float(exact.log10(decimal.Decimal(v))) for v in x])
    assert np.array_equal(got, want)
    back = ax.yaxis.get_transform().inverted().transform(got)
    assert np.array_equal(back, [float(exact.power(10, decimal.Decimal(v))) for v in got])
    assert np.array_equal(figlib.geomspace(1.0, 1e6, 7), 10.0 ** np.arange(7))


@pytest.mark.skipif(platform.machine().lower() not in ("x86_64", "amd64"), reason="x86-64 SIMD dispatch")
def test_figure_numbers_and_log_axes_do_not_depend_on_numpys_simd_kernels():
    # the same computations with every run-time SIMD target of NumPy switched off (the kernels of a CPU without
    # AVX2 or AVX-512): the bits must not change. On a CPU with AVX-512, np.log10 and the complex product of the
    # old code differ here
    code = ("import sys, hashlib, numpy as np; sys.path.insert(0, 'scripts'); import figlib;"
            "from fig_graph import autocorrelation;"
            "from matplotlib.figure import Figure;"
            "x = np.random.default_rng(7).standard_normal(20000).cumsum();"
            "ax = Figure().add_subplot(); ax.set_xscale('log'); ax.set_yscale('log');"
            "ax.set_xlim(1, 1e6); ax.set_ylim(1e-17, 1e3);"
            "p = np.abs(x[1:]) * 1e-16 + np.arange(1, 20000) * 1e-20;"
            "d = ax.transData.transform(np.column_stack([np.arange(1.0, 20000.0), p]));"
            "v = np.diff(x) * np.abs(np.diff(x));"
            "print(*(hashlib.sha256(a.tobytes()).hexdigest() for a in"
            " (autocorrelation(v, 2000), d, figlib.geomspace(3, 7e5, 2000))))")
    here = _in_subprocess(code)
    assert here == _in_subprocess(code, NPY_DISABLE_CPU_FEATURES=" ".join(_dispatch_targets()))


def test_autocorrelation_of_a_known_series():
    rho = autocorrelation(np.array([1.0, -1.0] * 50), 3)
    assert rho[0] == 1.0
    assert np.allclose(rho, [1.0, -1.0, 1.0, -1.0], atol=1e-12)
