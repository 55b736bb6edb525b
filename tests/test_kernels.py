"""The general loop (``RBX_KERNELS=general``, which the test suite runs) against the specialised loops users run by
default: on every example, the final states, every recorded field and the Lyapunov spectrum are the same bit for bit
(both do the same floating-point operations in the same order; only when each branch is decided differs)."""
import glob
import os
import warnings

import numpy as np
import pytest

import rbx
from rbx import engine

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
EXAMPLES = sorted(glob.glob(os.path.join(ROOT, "configs", "examples", "*.yaml")))


def run(monkeypatch, mode, exp, collisions):
    monkeypatch.setattr(engine, "KERNELS", mode)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)     # a fixed start in an example: copies of one orbit
        r = rbx.simulate(exp, collisions=collisions, trajectories=min(exp.run.trajectories, 4))
    return r.final, {f: r.read(f) for f in r.fields}


def test_the_mode_picks_the_compiled_bits(monkeypatch):
    flags = engine.make_spec(3, spin=True, slab=True, tree=True, record=True, tangent=True)
    monkeypatch.setattr(engine, "KERNELS", "specialised")
    assert engine.compiled_spec(flags) == flags & engine.COMPILED_BITS
    assert engine.compiled_spec(flags) & engine.S_SLAB
    monkeypatch.setattr(engine, "KERNELS", "general")
    assert engine.compiled_spec(flags) == engine.S_DIM3 | engine.S_GENERAL       # the tangent vectors: run time too
    assert engine.compiled_spec(engine.make_spec(2, slab=True)) == engine.S_GENERAL


#: compared by make test (the strip's records, the Sinai table's exponents); the others (each a specialised
#: compile of 5–20 s) by make stress
QUICK = ("strip", "lyapunov-sinai")


def _examples(names, path=lambda name: name, quick=QUICK):
    return [pytest.param(path(n), id=n, marks=() if n in quick else pytest.mark.long) for n in names]


@pytest.mark.parametrize("example", _examples([os.path.basename(e)[:-5] for e in EXAMPLES],
                                              lambda n: os.path.join(ROOT, "configs", "examples", n + ".yaml"),
                                              quick=QUICK[:1]))
def test_the_general_loop_is_the_specialised_loop_bit_for_bit(example, monkeypatch):
    exp = rbx.load(example)
    final, fields = run(monkeypatch, "specialised", exp, 1500)
    final2, fields2 = run(monkeypatch, "general", exp, 1500)
    assert fields and sorted(fields) == sorted(fields2)
    for name in fields:
        np.testing.assert_array_equal(fields[name], fields2[name], err_msg=name)
    assert sorted(final) == sorted(final2)
    for name in final:
        np.testing.assert_array_equal(final[name], final2[name], err_msg=name)
    assert np.any(final["collisions"] > 0)


@pytest.mark.parametrize("example", _examples(["lyapunov-sinai", "sinai3d", "plates"]))
def test_the_general_tangent_loop_is_the_specialised_one_bit_for_bit(example, monkeypatch):
    exp = rbx.load(os.path.join(ROOT, "configs", "examples", example + ".yaml"))
    spectra = []
    for mode in ("specialised", "general"):
        monkeypatch.setattr(engine, "KERNELS", mode)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            result = rbx.lyapunov(exp, collisions=1500, trajectories=2, segments=3)
        spectra.append((np.asarray(result.exponents), np.asarray(result.segment_exponents)))
    assert np.all(np.isfinite(spectra[0][0])) and np.ptp(spectra[0][0]) > 0
    np.testing.assert_array_equal(spectra[0][0], spectra[1][0])
    np.testing.assert_array_equal(spectra[0][1], spectra[1][1])


def test_an_unknown_mode_in_the_environment_warns_and_runs_the_specialised_loops(monkeypatch):
    monkeypatch.setenv("RBX_KERNELS", "genral")
    with pytest.warns(UserWarning, match="RBX_KERNELS='genral' is not one of specialised, general"):
        assert engine._kernel_mode_from_environment() == "specialised"
    monkeypatch.setenv("RBX_KERNELS", "general")
    assert engine._kernel_mode_from_environment() == "general"
