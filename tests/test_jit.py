"""The jit policy and the kernels' interface (rbx/_jit.py, rbx/engine.py).

- rbx/_jit.py alone decides how kernels are compiled: no other module under rbx/ calls Numba's jit decorators or
  sets compile options (fast-math, parallel) of its own, and every module that defines kernels is in
  ``_jit.KERNEL_MODULES`` (the kernel cache is keyed by their source).
- The event loop takes its arrays and scalars in a few named groups (engine.Table, Rules, Settings, State,
  Records), not 40-odd positional arguments: the signatures are pinned here so that the grouping cannot
  silently regress.
"""
import inspect
import os
import re

import numpy as np

from rbx import _jit, config, engine
from rbx.model import RECORD_FIELDS
from rbx.simulation import Simulation, run_in_memory

PACKAGE = os.path.dirname(os.path.abspath(_jit.__file__))
STRIP = os.path.join(os.path.dirname(PACKAGE), "configs", "examples", "strip.yaml")
#: text that only rbx/_jit.py may contain: a jit decorator or a compile option set elsewhere escapes the policy
FORBIDDEN = ("njit(", "numba.njit", "@njit", "@numba.jit", "numba.jit(", "fastmath=", "parallel=True")


def _modules():
    """(module name relative to rbx, source text) for every .py file under rbx/."""
    for folder, _, files in os.walk(PACKAGE):
        for name in sorted(files):
            if name.endswith(".py"):
                path = os.path.join(folder, name)
                rel = os.path.relpath(path, PACKAGE)[:-3].replace(os.sep, ".")
                with open(path, encoding="utf-8") as f:
                    yield rel, f.read()


def test_only_jit_module_sets_the_jit_policy():
    found = [(mod, pattern) for mod, text in _modules() if mod != "_jit"
             for pattern in FORBIDDEN if pattern in text]
    assert not found, f"jit decorators or options outside rbx/_jit.py: {found}"


def test_the_forbidden_patterns_are_found():
    # the scan above reads the files as text; make sure it does read them and would catch the policy's own lines
    sources = dict(_modules())
    assert "engine" in sources and "cli.main" in sources
    assert any(p in sources["_jit"] for p in FORBIDDEN)


def test_every_kernel_module_is_in_the_cache_key():
    # a module that compiles kernels (imports the decorators); rbx.cluster imports _jit only for its cache folder
    uses_jit = {mod for mod, text in _modules() if re.search(r"from \.+_jit import [^\n]*\bjit", text)}
    assert uses_jit <= set(_jit.KERNEL_MODULES), uses_jit - set(_jit.KERNEL_MODULES)
    assert "engine" in uses_jit


def test_the_loop_is_compiled_without_the_runtime():
    assert engine.kernel(0).targetoptions.get("_nrt") is False      # jit_loop
    assert engine.kernel(0).targetoptions.get("nogil") is True      # run on several threads at once
    assert engine.write_record.targetoptions.get("_nrt") is False  # jit_hot, inlined into the loop


def _params(f):
    return list(inspect.signature(getattr(f, "py_func", f)).parameters)


def test_the_kernels_take_named_groups():
    groups = ["table", "rules", "settings", "state", "out", "tangent"]
    assert _params(engine.kernel(0)) == ["j0", "j1", "stop"] + groups + ["nrec"]
    assert _params(engine.run_advance_all) == ["stop"] + groups
    assert len(_params(engine.kernel(0))) <= 10


def test_one_kernel_per_combination_of_compiled_bits():
    """kernel(spec) is made once per combination, its compiled bits constants of the closure (pruned before Numba
    inlines the helpers): the specular rectangle's loop holds no periodic search, rule tree or record writer."""
    assert engine.kernel(engine.S_AXES) is engine.kernel(engine.S_AXES)
    assert engine.kernel(engine.S_AXES) is not engine.kernel(engine.S_AXES | engine.S_SPIN)
    closure = dict(zip(engine.kernel(engine.S_AXES).py_func.__code__.co_freevars,
                       (c.cell_contents for c in engine.kernel(engine.S_AXES).py_func.__closure__)))
    assert closure["AXES"] is True and closure["N"] == 2
    assert not any(closure[k] for k in ("ORIENT", "SPIN", "TREE", "SLAB", "PERIODIC", "EXIT_", "ROUND_HEMI",
                                        "TANGENT"))


def test_the_groups():
    assert engine.Records._fields == RECORD_FIELDS             # one buffer per record field, in FIELDS order
    assert engine.Table._fields == ("codes", "prim_wall", "params", "tol", "lattice_lo", "period", "box", "others",
                                    "first_hit", "axis", "images", "image_shift")
    assert engine.Rules._fields == ("root", "kind", "rank", "first", "nchild", "children", "threshold", "axis",
                                    "phase", "basis")
    assert set(engine.Settings._fields) == {"flags", "stop_wall", "every", "mask", "renorm_every", "R", "kappa"}
    assert "pos" in engine.State._fields and len(engine.State._fields) == 14
    for group in (engine.Table, engine.Settings, engine.State, engine.Records, engine.Tangent):
        assert group.__module__ == "rbx.engine"    # module level: Numba's disk cache finds the types again
    assert engine.Rules.__module__ == "rbx.rules"  # beside the rules it flattens (rbx.engine imports it)


def test_the_entry_point_is_found_by_the_fingerprint_of_the_types(monkeypatch):
    """run_advance_all finds the compiled entry point by Numba's fingerprint of the arguments' types (a few µs)
    instead of typing them (~0.2 ms a block); without the fingerprint it types them, with the same results."""
    cfg = config.load(STRIP, {"collisions": 300})
    spec = engine.compiled_spec(Simulation(cfg).spec())
    records, count, final = run_in_memory(cfg)
    assert any(key is not None and key[0] == spec for key in engine._ENTRY)
    monkeypatch.setattr(engine.hooks, "_compute_fingerprint", None)
    monkeypatch.setattr(engine, "_ENTRY", {})
    records2, count2, final2 = run_in_memory(cfg)
    assert engine._ENTRY == {}                    # nothing remembered without a fingerprint
    np.testing.assert_array_equal(count, count2)
    for f in records:
        np.testing.assert_array_equal(records[f], records2[f])
    for k in final:
        np.testing.assert_array_equal(final[k], final2[k])


def test_a_value_numba_cannot_fingerprint_falls_back_to_typing(monkeypatch):
    """Numba's fingerprint raises NotImplementedError (or TypeError, ValueError) for a value whose type it cannot
    fingerprint: the entry point is then found by typing the arguments, with the same results, and nothing is
    remembered under a key."""
    cfg = config.load(STRIP, {"collisions": 300})
    records, count, final = run_in_memory(cfg)

    def cannot(args):
        raise NotImplementedError("no fingerprint for this type")
    monkeypatch.setattr(engine.hooks, "_compute_fingerprint", cannot)
    monkeypatch.setattr(engine, "_ENTRY", {})
    records2, count2, final2 = run_in_memory(cfg)
    assert engine._ENTRY == {}
    np.testing.assert_array_equal(count, count2)
    for f in records:
        np.testing.assert_array_equal(records[f], records2[f])
    for k in final:
        np.testing.assert_array_equal(final[k], final2[k])


def test_the_blas_question_is_asked_later_with_the_same_answer():
    """Numba asks whether SciPy's BLAS is there when it loads its array implementations, by importing
    scipy.linalg (0.13 s of a warm 0.57 s `rbx simulate`); rbx/_numba_hooks.py defers the question. A run must not import
    scipy.linalg, and the deferred answer must be Numba's own (true here: SciPy is installed, so np.convolve
    compiles)."""
    import subprocess
    import sys
    probe = ("import sys\n"
             "from rbx.simulation import run_in_memory\n"
             "from rbx import config\n"
             f"run_in_memory(config.load({STRIP!r}, overrides={{'collisions': 10}}))\n"
             "print('scipy.linalg' in sys.modules)\n"
             "from numba.np import arraymath\n"
             "print(type(arraymath._HAVE_BLAS).__name__)\n"
             "import numpy as np, numba\n"
             "print(numba.njit(lambda a, b: np.convolve(a, b))(np.ones(3), np.ones(2)).tolist())\n"
             "print(bool(arraymath._HAVE_BLAS), 'scipy.linalg' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout.split("\n")
    assert out[:4] == ["False", "BlasAvailable", "[1.0, 2.0, 2.0, 1.0]", "True True"], out
    from scipy.linalg import cython_blas  # noqa: F401  (what Numba's own check imports)
    assert _jit.hooks.BlasAvailable(lambda: None)
    assert not _jit.hooks.BlasAvailable(lambda: (_ for _ in ()).throw(ImportError()))
