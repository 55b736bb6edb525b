"""The private parts of Numba rbx uses (rbx/_numba_hooks.py): each has a fallback onto public Numba that gives the
same numbers, forced here with ``RBX_NUMBA_FALLBACK``; and rbx keeps its kernel cache to itself, leaving Numba's
global configuration, and so the cache of anyone else's functions, alone."""
import os
import subprocess
import sys
import textwrap

import h5py
import numpy as np
import pytest

from rbx import _jit, _numba_hooks

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CONFIG = os.path.join(ROOT, "configs", "examples", "strip.yaml")
RBX = os.path.join(os.path.dirname(sys.executable), "rbx")

USER_MODULE = textwrap.dedent("""
    import numba

    @numba.njit(cache=True)
    def twice(x):
        return 2.0 * x
""")

PROBE = textwrap.dedent("""
    import json, sys
    sys.path.insert(0, {folder!r})
    rbx_cache = None
    if {with_rbx!r}:
        from rbx import _jit, config, engine
        from rbx.simulation import run_in_memory
        if {run!r}:
            run_in_memory(config.load({config!r}, overrides={{"collisions": 20}}))   # rbx's kernels, loaded or made
        rbx_cache = _jit.CACHE_DIR
    import numba, usermod
    assert usermod.twice(1.5) == 3.0
    print(json.dumps({{"numba_cache_dir": numba.config.CACHE_DIR, "path": usermod.twice._cache.cache_path,
                      "rbx": rbx_cache}}))
""")


def _probe(tmp_path, with_rbx, env, run=False):
    folder = tmp_path / ("with" if with_rbx else "without")
    folder.mkdir()
    (folder / "usermod.py").write_text(USER_MODULE)
    code = PROBE.format(folder=str(folder), with_rbx=with_rbx, run=run, config=CONFIG)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=600)
    assert done.returncode == 0, done.stderr
    import json
    return folder, json.loads(done.stdout.strip().splitlines()[-1])


def _has_index(folder, prefix):
    return any(f.startswith(prefix) and f.endswith(".nbi") for _, _, files in os.walk(folder) for f in files)


def test_a_users_cached_function_is_cached_where_numba_puts_it_without_rbx(tmp_path):
    """Beside rbx (its kernels run, from rbx's cache), a user's ``cache=True`` function goes to Numba's own place
    for it, the __pycache__ beside its module, as without rbx; Numba's global cache setting is untouched."""
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    alone_folder, alone = _probe(tmp_path, False, env)
    beside_folder, beside = _probe(tmp_path, True, env, run=True)
    assert beside["numba_cache_dir"] == alone["numba_cache_dir"]
    assert alone["path"] == str(alone_folder / "__pycache__")
    assert beside["path"] == str(beside_folder / "__pycache__")
    assert _has_index(beside["path"], "usermod.twice")
    assert _has_index(beside["rbx"], "engine.") and not _has_index(beside["rbx"], "usermod")
    assert os.path.basename(beside["rbx"]).startswith("numba-")


def test_a_users_numba_cache_dir_is_honoured_for_their_functions(tmp_path):
    """With ``NUMBA_CACHE_DIR`` set, the user's function is cached there, where Numba puts it without rbx (and
    rbx's kernels go to a folder of their own beneath it)."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "users-cache"))
    _, alone = _probe(tmp_path, False, env)
    _, beside = _probe(tmp_path, True, env)
    assert beside["numba_cache_dir"] == alone["numba_cache_dir"] == str(tmp_path / "users-cache")
    # Numba's folder for a module is named after the module's folder ("with" or "without" here)
    assert os.path.dirname(beside["path"]) == os.path.dirname(alone["path"]) == str(tmp_path / "users-cache")
    assert _has_index(beside["path"], "usermod.twice")
    assert os.path.dirname(beside["rbx"]) == str(tmp_path / "users-cache")


def test_rbx_kernels_are_cached_in_the_keyed_folder():
    from rbx import engine
    assert engine.kernel(0)._cache.cache_path.startswith(_jit.CACHE_DIR)
    assert os.path.basename(_jit.CACHE_DIR) == "numba-" + _jit.kernel_source_hash()


def _simulate(tmp_path, name, env_changes):
    # the strip's specialised loop: a compile of a few seconds without the hooks, where the general loop takes ~30 s
    env = dict(os.environ, RBX_KERNELS="specialised", **env_changes)
    out = tmp_path / f"{name}.h5"
    done = subprocess.run([RBX, "simulate", CONFIG, "-o", str(out), "--force", "--collisions", "300", "--quiet"],
                          capture_output=True, text=True, env=env, timeout=900, cwd=tmp_path)
    return out, done


@pytest.mark.slow
def test_every_fallback_forced_gives_the_same_numbers(tmp_path):
    """All hooks off at once: the dispatcher instead of the entry point, the runtime on and np.empty for the stack
    arrays, Numba's own inlining and BLAS question, no disk cache (so the kernel compiles in the process, once)."""
    normal, a = _simulate(tmp_path, "normal", {})
    forced, b = _simulate(tmp_path, "forced", {"RBX_NUMBA_FALLBACK": "all"})
    assert a.returncode == 0, a.stderr
    assert b.returncode == 0, b.stderr
    warnings = [line for line in b.stderr.splitlines() if line.startswith("rbx: warning:")]
    assert len(warnings) == 1 and "compiled afresh in every process" in warnings[0], b.stderr
    with h5py.File(normal) as x, h5py.File(forced) as y:
        assert sorted(x["collisions"]) == sorted(y["collisions"])
        for f in x["collisions"]:
            np.testing.assert_array_equal(x["collisions"][f][...], y["collisions"][f][...])
        for f in x["final"]:
            np.testing.assert_array_equal(x["final"][f][...], y["final"][f][...])


def test_the_forced_fallbacks_are_what_the_module_reports():
    code = ("from rbx import _jit, _numba_hooks as h, engine\n"
            "print(h.describe(), h.NO_RUNTIME, h.fingerprint((1.0,)), h.reuse_inlined_callees('rbx'),"
            " engine.kernel(0).targetoptions.get('_nrt'))\n")
    env = dict(os.environ, RBX_NUMBA_FALLBACK="nrt,fingerprint,inline")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    assert out.stdout.split() == ["stack,blas,cache", "{}", "None", "False", "None"], out.stdout
    # normal: every hook in place
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env={k: v for k, v in os.environ.items() if k != "RBX_NUMBA_FALLBACK"})
    words = out.stdout.split()
    assert words[0] == ",".join(_numba_hooks.HOOKS) and words[1:3] == ["{'_nrt':", "False}"], out.stdout
    assert words[-2:] == ["True", "False"], out.stdout


def test_an_unknown_fallback_name_is_refused():
    env = dict(os.environ, RBX_NUMBA_FALLBACK="fingerprnt")
    out = subprocess.run([sys.executable, "-c", "import rbx._jit"], capture_output=True, text=True, env=env)
    assert out.returncode != 0 and "RBX_NUMBA_FALLBACK: unknown hook(s) ['fingerprnt']" in out.stderr
