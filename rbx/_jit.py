"""The one place that decides how rbx compiles its kernels (tests/test_jit.py fails if any other module under rbx/
calls Numba's jit decorators or sets ``fastmath`` or ``parallel``). The private parts of Numba it uses are in
:mod:`rbx._numba_hooks`, each with a fallback.

- a disk cache: compiled kernels are stored so that a second run starts in well under a second. Numba checks only
  a kernel's *own* file, not the helpers inlined into it from other modules, so an edited helper could run stale.
  The cache therefore lives in a folder named by a hash of every kernel module's source, the Numba version and the
  hooks in use (``$NUMBA_CACHE_DIR`` or ``~/.cache/rbx``, then ``numba-<hash>``): any change compiles afresh. Only
  rbx's kernels go there: Numba's global cache setting is left alone, so a user's own cached functions stay where
  Numba puts them.
- ``error_model='numpy'``: a division by zero gives inf/nan instead of raising; ``inf`` means "no collision".
- no ``fastmath``: the engine relies on ``inf`` and exact comparisons (fast-math would assume no infs), and without
  it LLVM neither reorders nor contracts (into fused multiply-adds) floating-point operations, so a kernel's
  arithmetic is the same on every CPU it is compiled for.
"""
import contextlib
import hashlib
import os
import sys
import tempfile
import time

import numba

from . import _numba_hooks as hooks
from . import model
from .environment import disable_jit

if disable_jit():       # every kernel would be plain Python, and rbx reads compiled entry points (py_func)
    raise ImportError(f"NUMBA_DISABLE_JIT: {disable_jit()}")

#: every module that defines kernels (tests/test_jit.py checks that each module under rbx/ importing this one is
#: listed)
KERNEL_MODULES = ("_jit", "_numba_hooks", "engine", "geometry", "physics", "primitives", "rng", "rules", "tangent",
                  "trig")
#: modules whose values the kernels compile in as constants (the record bits of rbx.model.FIELDS): the cache key
#: covers those values (:func:`_compiled_constants`), not the modules' whole text, so that an edit elsewhere in
#: rbx/model.py (a config key, a docstring) does not compile every kernel again
KERNEL_CONSTANTS = ("model",)


def _compiled_constants():
    """What the kernels read from :data:`KERNEL_CONSTANTS` modules, as text: each record field's name (the order
    of ``engine.Records``) and its bit of the record mask."""
    return repr([(f.name, int(f.bit)) for f in model.FIELDS])


def kernel_source_hash():
    h = hashlib.sha256(numba.__version__.encode())
    here = os.path.dirname(os.path.abspath(__file__))
    for name in KERNEL_MODULES:
        with open(os.path.join(here, name + ".py"), "rb") as f:
            h.update(f.read())
    h.update(_compiled_constants().encode())
    h.update(repr(sorted(hooks.NO_RUNTIME.items())).encode())   # the code compiled differs without the hooks
    return h.hexdigest()[:16]


def _writable(folder):
    """Whether compiled kernels can be stored in ``folder`` (made if missing; a probe file written and removed)."""
    try:
        os.makedirs(folder, mode=0o700, exist_ok=True)
        fd, probe = tempfile.mkstemp(dir=folder, prefix=".probe-")
        os.close(fd)
        os.remove(probe)
        return True
    except OSError:
        return False


def _cache_dir():
    """The kernel cache folder, keyed by the kernels' source. If it cannot be written (a read-only or invalid
    ``NUMBA_CACHE_DIR``, a read-only home), a private folder in the temporary directory keyed the same way, with
    one warning line: Numba's own fallback, the package's ``__pycache__``, is keyed by file timestamps only and
    served stale kernels after an edit of an inlined helper."""
    name = "numba-" + kernel_source_hash()
    base = os.environ.get("NUMBA_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "rbx")
    folder = os.path.join(base, name)
    if _writable(folder):
        return folder
    private = os.path.join(tempfile.gettempdir(), f"rbx-{os.getuid() if hasattr(os, 'getuid') else 'user'}", name)
    if not (_writable(private) and (not hasattr(os, "getuid") or os.stat(private).st_uid == os.getuid())):
        private = tempfile.mkdtemp(prefix=f"rbx-{name}-")
    sys.stderr.write(f"rbx: warning: cannot write the kernel cache {folder}; compiled kernels go to {private}\n")
    return private


#: the folder of rbx's compiled kernels (only rbx's: see :func:`rbx._numba_hooks.enable_cache`)
CACHE_DIR = _cache_dir()


def compile_lock(name):
    """Hold an exclusive lock named ``name`` in the kernel cache folder while compiling a kernel: another process
    (a second test worker, a CLI run started meanwhile) that needs the same kernel waits, then loads it from the
    disk cache instead of compiling it a second time (each combination takes 10–60 s). The lock (``flock``) goes
    with the process that holds it, so a killed compile blocks nobody; where no lock can be taken (no ``fcntl``, a
    folder that refuses it), the kernel is compiled without one."""
    return compile_lock_at(os.path.join(CACHE_DIR, f".{name}.lock"))


@contextlib.contextmanager
def compile_lock_at(path):
    """:func:`compile_lock` on the lock file ``path``."""
    fd = None
    try:
        import fcntl
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o600)
        # asked again every 20 ms rather than waited for in one blocking call: Ctrl-C while another process
        # compiles must end this one now, and a blocking flock sees the signal only if the kernel delivers it to
        # this very thread (else Python runs its handler when the other compile is done, up to a minute later)
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                time.sleep(0.02)
    except (ImportError, OSError):
        if fd is not None:
            os.close(fd)
        fd = None
    try:
        yield
    finally:
        if fd is not None:
            os.close(fd)          # releases the lock


hooks.reuse_inlined_callees(__package__)
hooks.defer_blas_check()

_POLICY = dict(cache=False, error_model="numpy", fastmath=False, nogil=True)


def _cached(decorator):
    """``decorator`` (a ``numba.njit(...)``) with the compiled code cached in :data:`CACHE_DIR`."""
    def decorate(function):
        return hooks.enable_cache(decorator(function), CACHE_DIR)
    return decorate


jit = _cached(numba.njit(**_POLICY))

#: for the small functions called once per collision (collision time, normal, rule choice, collision map):
#: compiled without the Numba runtime (no reference counting: they allocate nothing), so that passing arrays to
#: them costs no atomic reference counting. Measured on the strip: 80 ns per call with it, 18 ns without
#: (Numba 0.68; ``inline="always"`` does not help, the inlined arguments are reference-counted too).
jit_hot = _cached(numba.njit(inline="always", **hooks.NO_RUNTIME, **_POLICY))

#: the serial loop of one trajectory: no runtime either (its scratch space is on its stack: ``stack_array``), so the
#: helpers inlined into it are free of reference counting
jit_loop = _cached(numba.njit(**hooks.NO_RUNTIME, **_POLICY))

#: a helper the kernels call rather than inline: compiled once (one type signature, the dimension an argument) and
#: shared by every kernel that calls it, on disk too. For the tangent loop's re-orthonormalisation (rbx.tangent),
#: taken every few collisions, and for the general loop's helpers (rbx.engine.CALLED_IN_GENERAL). No runtime, like
#: the loop that calls them.
jit_call = _cached(numba.njit(**hooks.NO_RUNTIME, **_POLICY))

#: a float64 array in the calling kernel's stack frame: ``stack_array(capacity, shape)`` (see
#: :func:`rbx._numba_hooks.make_stack_array`)
stack_array = hooks.make_stack_array(numba.njit(inline="always", **_POLICY))
