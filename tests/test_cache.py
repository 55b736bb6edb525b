"""The kernel cache (rbx/_jit.py): keyed by the kernels' source, and a folder that cannot be written falls back to
a private temporary folder keyed the same way, with one warning line — never to Numba's own fallback (the
package's __pycache__, keyed by file timestamps only, which served stale kernels after an edit)."""
import os
import signal
import subprocess
import sys

import h5py
import numpy as np
import pytest

from rbx import _jit
from tests.test_interrupt import wait_until_open

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CONFIG = os.path.join(ROOT, "configs", "examples", "strip.yaml")
RBX = os.path.join(os.path.dirname(sys.executable), "rbx")


def _run(tmp_path, out, env_changes):
    env = dict(os.environ, **env_changes)
    return subprocess.run([RBX, "simulate", CONFIG, "-o", str(out), "--force",
                           "--collisions", "200", "--quiet"], capture_output=True, text=True, env=env, timeout=300,
                          cwd=tmp_path)


def test_the_cache_key_covers_the_kernels_and_their_constants():
    assert set(_jit.KERNEL_MODULES) >= {"engine", "geometry", "physics", "rng", "rules", "_jit"}
    assert "model" in _jit.KERNEL_CONSTANTS       # engine compiles the record bits of rbx.model.FIELDS in
    assert _jit.kernel_source_hash() in _jit.CACHE_DIR


def test_the_cache_key_follows_the_record_bits_not_the_rest_of_the_model(monkeypatch):
    """The kernels compile in each record field's bit (engine's F_* constants) and the fields' order (Records):
    a change of either is a new key; an edit elsewhere in rbx/model.py is not (it would compile every kernel again)."""
    import dataclasses

    from rbx import model
    key = _jit.kernel_source_hash()
    fields = list(model.FIELDS)
    swapped = [dataclasses.replace(fields[0], bit=fields[1].bit), dataclasses.replace(fields[1], bit=fields[0].bit)]
    monkeypatch.setattr(model, "FIELDS", tuple(swapped + fields[2:]))
    assert _jit.kernel_source_hash() != key
    monkeypatch.setattr(model, "FIELDS", tuple([fields[1], fields[0]] + fields[2:]))
    assert _jit.kernel_source_hash() != key
    monkeypatch.setattr(model, "FIELDS", tuple(fields))
    assert _jit.kernel_source_hash() == key


@pytest.mark.long
def test_an_unwritable_cache_falls_back_to_a_private_folder(tmp_path):
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("a file where the cache folder should be")
    good = _run(tmp_path, tmp_path / "good.h5", {})
    bad = _run(tmp_path, tmp_path / "bad.h5", {"NUMBA_CACHE_DIR": str(blocker / "cache")})
    assert good.returncode == 0 and bad.returncode == 0, bad.stderr
    warnings = [line for line in bad.stderr.splitlines() if line.startswith("rbx: warning: cannot write the kernel")]
    assert len(warnings) == 1, bad.stderr
    assert "numba-" + _jit.kernel_source_hash() in warnings[0]    # the fallback is keyed like the normal folder
    with h5py.File(tmp_path / "good.h5") as a, h5py.File(tmp_path / "bad.h5") as b:
        for f in a["collisions"]:
            np.testing.assert_array_equal(a["collisions"][f][...], b["collisions"][f][...])


def test_a_second_process_waits_for_a_kernel_being_compiled():
    """_jit.compile_lock: while one process compiles a combination, another that needs it waits (then loads it from
    the disk cache instead of compiling it a second time, as two test workers or a CLI run beside a notebook did)."""
    code = ("import sys, rbx._jit as j\nprint('waiting', flush=True)\n"
            "with j.compile_lock('advance-probe'):\n    print('got it', flush=True)\n")
    with _jit.compile_lock("advance-probe"):
        child = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
        assert child.stdout.readline().strip() == "waiting"
        try:
            child.wait(timeout=3)
        except subprocess.TimeoutExpired:
            pass
        assert child.poll() is None, "the second process did not wait for the lock"
    out, _ = child.communicate(timeout=120)
    assert out.strip() == "got it" and child.returncode == 0


def test_ctrl_c_while_waiting_for_another_compile_ends_the_wait():
    """A process waiting for the compile lock is interrupted at once, even when the signal reaches another of its
    threads (the main thread has it blocked here: the kernel then delivers it elsewhere, and a blocking flock in the
    main thread never saw it, so Python's handler ran only once the other process had compiled)."""
    # the default Ctrl-C handler set explicitly: a child inherits an ignored SIGINT from its parent (a test worker
    # after an in-process CLI run), and Python then installs none
    code = ("import signal, threading, time, rbx._jit as j\n"
            "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
            "threading.Thread(target=time.sleep, args=(60,), daemon=True).start()\n"
            "signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})\n"
            "print('waiting', flush=True)\n"
            "try:\n    with j.compile_lock('interrupt-probe'):\n        print('got it', flush=True)\n"
            "except KeyboardInterrupt:\n    print('interrupted', flush=True)\n")
    with _jit.compile_lock("interrupt-probe"):
        child = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
        assert child.stdout.readline().strip() == "waiting"
        # waiting for the lock: its file is open in the child (no delay, which a loaded machine can outrun)
        wait_until_open(child, os.path.join(_jit.CACHE_DIR, ".interrupt-probe.lock"))
        child.send_signal(signal.SIGINT)
        out, _ = child.communicate(timeout=60)      # while this process still holds the lock
    assert out.strip() == "interrupted", out


def test_the_front_end_of_an_inlined_helper_is_made_once():
    """_numba_hooks.reuse_inlined_callees: the IR Numba makes for an inlined rbx helper is kept and handed out again (it is
    copied before Numba changes it), so the second kernel of a process does not run the helpers' front end again."""
    from numba.core.inline_closurecall import InlineWorker
    assert getattr(InlineWorker.run_untyped_passes, "rbx_reuse", False)


def test_the_blocks_of_an_inlined_helper_share_one_copy_of_its_scope(monkeypatch):
    """_numba_hooks (inline): Numba copies an inlined helper's IR block by block, each with a deep copy of the whole
    scope of its own; with the hook the blocks of one copy share one copy of the scope, as the blocks of a helper
    made afresh do, and the compiled function computes what Python does."""
    import numba
    from numba.core.inline_closurecall import InlineWorker
    copies = []
    inline_ir = InlineWorker.inline_ir

    def spy(self, *args, **kwargs):
        made = inline_ir(self, *args, **kwargs)
        copies.append(made[0])                  # the callee's IR as copied, before it was changed
        return made

    monkeypatch.setattr(InlineWorker, "inline_ir", spy)

    @numba.njit(inline="always")
    def helper(x):
        if x > 1.0:
            y = x * 2.0
        else:
            y = x - 3.0
        for _ in range(3):
            y = y + 0.5
        return y

    @numba.njit
    def caller(x):
        return helper(x) + helper(x + 1.0)

    assert [caller(x) for x in (0.5, 2.0)] == [caller.py_func(x) for x in (0.5, 2.0)]
    assert len(copies) == 2
    for ir in copies:
        assert len(ir.blocks) > 2
        assert len({id(block.scope) for block in ir.blocks.values()}) == 1
