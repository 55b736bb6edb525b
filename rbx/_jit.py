"""The one place that decides how rbx compiles its kernels (STYLE: one module owns the jit policy; tests/test_jit.py
fails if any other module under rbx/ calls Numba's jit decorators or sets ``fastmath`` or ``parallel``).

- ``cache=True``: compiled kernels are stored on disk so a second run starts in well under a second. Numba checks
  only the timestamp of a kernel's *own* file, not of the helpers inlined into it from other modules, so an edited
  helper could run stale. The cache therefore lives in a folder named by a hash of every kernel module's source
  and the Numba version (``$NUMBA_CACHE_DIR`` or ``~/.cache/rbx``, then ``numba-<hash>``): any change compiles
  afresh.
- ``error_model='numpy'``: a division by zero gives inf/nan instead of raising; ``inf`` means "no collision".
- no ``fastmath``: the engine relies on ``inf`` and exact comparisons (fast-math would assume no infs).
"""
import contextlib
import hashlib
import os
import sys
import tempfile
import time

import numba
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic
from numba.np.arrayobj import make_array, populate_array

#: every module that defines kernels (tests/test_jit.py checks that each module under rbx/ importing this one is
#: listed)
KERNEL_MODULES = ("_jit", "engine", "geometry", "physics", "rng", "rules", "tangent", "trig")
#: modules whose values the kernels compile in as constants (the record bits of rbx.model.FIELDS): the cache key
#: covers those values (:func:`_compiled_constants`), not the modules' whole text, so that an edit elsewhere in
#: rbx/model.py (a config key, a docstring) does not compile every kernel again
KERNEL_CONSTANTS = ("model",)


def _compiled_constants():
    """What the kernels read from :data:`KERNEL_CONSTANTS` modules, as text: each record field's name (the order
    of ``engine.Records``) and its bit of the record mask."""
    from .model import FIELDS
    return repr([(f.name, int(f.bit)) for f in FIELDS])


def kernel_source_hash():
    h = hashlib.sha256(numba.__version__.encode())
    here = os.path.dirname(os.path.abspath(__file__))
    for name in KERNEL_MODULES:
        with open(os.path.join(here, name + ".py"), "rb") as f:
            h.update(f.read())
    h.update(_compiled_constants().encode())
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


# read by Numba when a kernel is decorated below (its cache locator), so it must be set before any of them
numba.config.CACHE_DIR = _cache_dir()

@contextlib.contextmanager
def compile_lock(name):
    """Hold an exclusive lock named ``name`` in the kernel cache folder while compiling a kernel: another process
    (a second test worker, a CLI run started meanwhile) that needs the same kernel waits, then loads it from the
    disk cache instead of compiling it a second time (each combination takes 10–60 s). The lock (``flock``) goes
    with the process that holds it, so a killed compile blocks nobody; where no lock can be taken (no ``fcntl``, a
    folder that refuses it), the kernel is compiled without one."""
    fd = None
    try:
        import fcntl
        fd = os.open(os.path.join(numba.config.CACHE_DIR, f".{name}.lock"), os.O_RDWR | os.O_CREAT, 0o600)
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


def _reuse_inlined_callees():
    """Numba inlines a helper marked ``inline="always"`` by running its front end (bytecode to IR, and the inlining
    of its own helpers) afresh at every call site of every kernel it compiles; the rbx loop inlines the same dozen
    helpers into each combination of compiled bits, and the front end of ``box_collision`` alone took a third of a
    kernel's compile. Numba deep-copies the helper's IR before it changes it (``InlineWorker.inline_ir``: "Always
    copy the callee IR, it gets mutated"), so the IR made once for a helper of rbx is kept and handed out again.
    Only rbx's own helpers, for the same typing context and SSA setting, and no local type declarations (the front
    end reads no target: its context is made anew for each kernel, so it is not part of the key)."""
    try:
        from numba.core.inline_closurecall import InlineWorker
        original = InlineWorker.run_untyped_passes
    except (ImportError, AttributeError):       # another Numba: compile as it does
        return
    if getattr(original, "rbx_reuse", False):
        return
    made = {}

    def run_untyped_passes(self, func, enable_ssa=False):
        if not getattr(func, "__module__", "").startswith(__package__ + ".") or self.locals:
            return original(self, func, enable_ssa)
        key = (func, enable_ssa, id(self.typingctx))      # the target context is made anew for each kernel
        if key not in made:
            made[key] = original(self, func, enable_ssa)
        else:
            self.flags.enable_ssa = enable_ssa          # what the original does to the caller's flags
        return made[key]

    run_untyped_passes.rbx_reuse = True
    InlineWorker.run_untyped_passes = run_untyped_passes


_reuse_inlined_callees()


class _BlasAvailable:
    """Whether SciPy's BLAS is there, asked when Numba first needs to know (its truth value), not when
    ``numba.np.arraymath`` is imported."""
    def __init__(self, check):
        self.check, self.known = check, None

    def __bool__(self):
        if self.known is None:
            try:
                self.check()
                self.known = True
            except ImportError:
                self.known = False
        return self.known


def _defer_blas_check():
    """Numba loads its array implementations (``numba.np.arraymath``) when a process first compiles or loads a
    kernel, and that module asks at import whether a BLAS is there by importing ``scipy.linalg``: 0.38 s of the
    1.5 s a warm ``rbx simulate`` took to start, for ``np.correlate`` and ``np.convolve`` alone (its one reader,
    ``_HAVE_BLAS``), which no rbx kernel calls. The module is imported here with that question deferred: its answer
    is the same, found the first time something compiles one of those two (:class:`_BlasAvailable`). Any other
    Numba: left as it is."""
    if "numba.np.arraymath" in sys.modules:
        return
    try:
        from numba.np import linalg
        ensure_blas = linalg.ensure_blas
    except (ImportError, AttributeError):
        return

    def later():
        raise ImportError("asked later")

    linalg.ensure_blas = later
    try:
        from numba.np import arraymath
    finally:
        linalg.ensure_blas = ensure_blas
    if getattr(arraymath, "ensure_blas", None) is later and arraymath._HAVE_BLAS is False:
        arraymath.ensure_blas = ensure_blas
        arraymath._HAVE_BLAS = _BlasAvailable(ensure_blas)


_defer_blas_check()

_POLICY = dict(cache=True, error_model="numpy", fastmath=False, nogil=True)

jit = numba.njit(**_POLICY)

#: for the small functions called once per collision (collision time, normal, rule choice, collision map):
#: compiled without the Numba runtime (``_nrt=False``: they allocate nothing), so that passing arrays to them
#: costs no atomic reference counting. Measured on the strip: 80 ns per call with it, 18 ns without
#: (Numba 0.68; ``inline="always"`` does not help, the inlined arguments are reference-counted too).
jit_hot = numba.njit(_nrt=False, inline="always", **_POLICY)

#: the serial loop of one trajectory: no runtime either (its scratch space is on its stack: ``stack_array``), so the
#: helpers inlined into it are free of reference counting
jit_loop = numba.njit(_nrt=False, **_POLICY)


@intrinsic
def stack_array(typingctx, capacity, shape):
    """A float64 C-contiguous array of ``shape`` (a tuple) in the calling kernel's stack frame, with room for
    ``capacity`` (a literal int) values; uninitialised, never freed, never to be returned.

    Why: the state of a trajectory held in arrays of the caller (``pos[j]``…) lives in memory, and every collision
    then goes through store-to-load round trips (the compiler cannot prove the arrays do not alias). A stack array
    whose every index is a constant once the dimension is (``spec``) is promoted to registers by LLVM: the rough
    strip went from 15–21 to 11–16 ns per collision (same loaded machine, interleaved runs)."""
    if not isinstance(capacity, types.IntegerLiteral) or not isinstance(shape, types.BaseTuple) or \
            not all(isinstance(t, types.Integer) for t in shape):
        return None
    ndim = len(shape)
    arrty = types.Array(types.float64, ndim, "C")

    def codegen(context, builder, signature, args):
        data = cgutils.alloca_once(builder, context.get_value_type(types.float64), size=capacity.literal_value)
        shapes = [context.cast(builder, x, t, types.intp)
                  for x, t in zip(cgutils.unpack_tuple(builder, args[1], ndim), shape)]
        itemsize = context.get_constant(types.intp, 8)
        strides = [itemsize] * ndim
        for k in range(ndim - 2, -1, -1):
            strides[k] = builder.mul(strides[k + 1], shapes[k + 1])
        ary = make_array(arrty)(context, builder)
        populate_array(ary, data=data, shape=shapes, strides=strides, itemsize=itemsize, meminfo=None)
        return ary._getvalue()

    return arrty(capacity, shape), codegen
