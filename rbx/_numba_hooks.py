"""Every use rbx makes of Numba's private parts, each with a fallback onto public Numba.

rbx compiles its kernels with Numba's public decorators; a few private parts of Numba buy start-up time, compile
time and speed per collision. They are all here, each guarded: where a name is missing (another Numba release) or
``RBX_NUMBA_FALLBACK`` names the hook (a comma-separated list, or ``all``: the tests force each fallback this way),
rbx takes the public route, slower or caching less, never giving other numbers.

============  =========================================================  ======================================
hook          private part of Numba                                      fallback
============  =========================================================  ======================================
fingerprint   ``numba._dispatcher.compute_fingerprint``, a dispatcher's  the entry point found by typing the
              ``overloads`` and a compile result's ``entry_point``       arguments (0.2 ms a block instead of
                                                                         12 µs), or the dispatcher itself
nrt           the target option ``_nrt=False`` (no reference counting    the runtime on
              of arrays in the hot loop)
stack         ``numba.np.arrayobj.make_array``/``populate_array``,       ``np.empty`` (needs the runtime: nrt
              ``numba.core.cgutils`` (scratch arrays on the stack)       falls back with it)
inline        ``InlineWorker.run_untyped_passes`` (an inlined helper's    Numba's own (a longer compile)
              front end run once per process, not at every call site)
              and ``inline_ir``'s copies of it (one copy of its scope
              per call site, not one per block)
blas          ``numba.np.arraymath._HAVE_BLAS`` (asked when needed,       asked at import, as Numba does
              not at import: 0.4 s of start-up)
cache         ``numba.core.caching``'s locator and function cache: the   no disk cache: every process compiles
              kernels' cache in rbx's own folder, keyed by their source  its kernels, with one warning line
============  =========================================================  ======================================

Why the cache needs a hook: Numba keys a cached kernel by its own file only, not by the helpers inlined into it from
other modules, so an edited (or upgraded) helper could run stale. rbx keeps its kernels in a folder named by a hash
of every kernel module's source (:mod:`rbx._jit`). Setting ``numba.config.CACHE_DIR`` would do that too, but for
every Numba function of the process: a user's own cached functions would move with rbx's. The locator below serves
rbx's functions only; anyone else's cache stays where Numba puts it.

The versions of Numba rbx is tested with are declared in pyproject.toml; ``make test-numba`` runs the suite with
the oldest and the newest.
"""
import os
import sys

import numba

from .environment import NUMBA_HOOKS, fallback_hooks

#: the hooks, in the order of the table above
HOOKS = NUMBA_HOOKS


def _forced():
    """The hooks ``RBX_NUMBA_FALLBACK`` turns off (``all``, or names from :data:`HOOKS`); an unknown name is an
    error, not a silent no-op."""
    forced, problem = fallback_hooks()
    if problem:
        raise ImportError(f"RBX_NUMBA_FALLBACK: {problem}")
    return forced


FORCED = _forced()


# ---- fingerprint: the compiled entry point of a dispatcher ------------------------------------------------------

try:
    from numba._dispatcher import compute_fingerprint as _compute_fingerprint
except ImportError:  # pragma: no cover - another Numba
    _compute_fingerprint = None
if "fingerprint" in FORCED:
    _compute_fingerprint = None


def fingerprint(args):
    """Numba's fingerprint of the types of ``args`` (the key of a dispatcher's type cache; ~3 µs) -> a hashable
    value, or None where it cannot be had (no such function, or a value Numba cannot fingerprint)."""
    if _compute_fingerprint is None:
        return None
    try:
        return _compute_fingerprint(args)
    except (TypeError, ValueError, NotImplementedError):
        return None


def is_compiled(dispatcher):
    """Whether ``dispatcher`` holds a compiled (or loaded) specialisation."""
    return bool(getattr(dispatcher, "overloads", None))


def entry_point(dispatcher, args):
    """A callable that runs ``dispatcher``'s specialisation for the types of ``args``, compiled (or loaded) by
    calling the dispatcher once with ``args`` if needed (the caller makes that call a no-op). The compiled entry
    point skips the typing of the arguments at every call; without the private parts it is the dispatcher."""
    if "fingerprint" in FORCED:
        dispatcher(*args)
        return dispatcher
    try:
        sig = tuple(numba.typeof(a) for a in args)
        cres = dispatcher.overloads.get(sig)
        if cres is None:
            dispatcher(*args)
            cres = dispatcher.overloads[sig]
        return cres.entry_point
    except (AttributeError, KeyError, TypeError, ValueError):  # pragma: no cover - another Numba
        dispatcher(*args)
        return dispatcher


# ---- nrt and stack: the hot loop without the runtime, its scratch space on the stack ------------------------------

def _nrt_option():
    if "nrt" in FORCED or "stack" in FORCED or _stack_parts() is None:
        return {}
    try:
        from numba.core.cpu import CPUTargetOptions
    except ImportError:  # pragma: no cover
        return {}
    return {"_nrt": False} if hasattr(CPUTargetOptions, "_nrt") else {}


def _stack_parts():
    if "stack" in FORCED:
        return None
    try:
        from numba.core import cgutils
        from numba.extending import intrinsic
        from numba.np.arrayobj import make_array, populate_array
    except ImportError:  # pragma: no cover - another Numba
        return None
    if not all(hasattr(cgutils, f) for f in ("alloca_once", "unpack_tuple")):  # pragma: no cover
        return None
    return cgutils, intrinsic, make_array, populate_array


#: the option that compiles a function without Numba's runtime (no reference counting), or nothing
NO_RUNTIME = _nrt_option()


def make_stack_array(jit_inline):
    """``stack_array(capacity, shape)``: a float64 C-contiguous array of ``shape`` (a tuple) in the calling
    kernel's stack frame with room for ``capacity`` (a literal int) values; uninitialised, never freed, never to be
    returned. ``jit_inline`` compiles the fallback (``np.empty(shape)``, which needs the runtime).

    Why: the state of a trajectory held in arrays of the caller (``pos[j]``…) lives in memory, and every collision
    then goes through store-to-load round trips (the compiler cannot prove the arrays do not alias). A stack array
    whose every index is a constant once the dimension is (``spec``) is promoted to registers by LLVM: the rough
    strip went from 15–21 to 11–16 ns per collision (same loaded machine, interleaved runs)."""
    parts = _stack_parts() if NO_RUNTIME else None
    if parts is None:
        import numpy as np

        def stack_array(capacity, shape):
            return np.empty(shape)
        return jit_inline(stack_array)
    cgutils, intrinsic, make_array, populate_array = parts
    from numba import types

    @intrinsic
    def stack_array(typingctx, capacity, shape):
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

    return stack_array


# ---- inline: an inlined helper's front end made once per process -------------------------------------------------

def reuse_inlined_callees(package):
    """Numba inlines a helper marked ``inline="always"`` by running its front end (bytecode to IR, and the inlining
    of its own helpers) afresh at every call site of every kernel it compiles; the rbx loop inlines the same dozen
    helpers into each combination of compiled bits, and the front end of ``box_collision`` alone took a third of a
    kernel's compile. Numba deep-copies the helper's IR before it changes it (``InlineWorker.inline_ir``: "Always
    copy the callee IR, it gets mutated"), so the IR made once for a helper of ``package`` is kept and handed out
    again. Only that package's helpers, for the same typing context and SSA setting, and no local type
    declarations. -> whether the hook is in place."""
    if "inline" in FORCED:
        return False
    try:
        from numba.core.inline_closurecall import InlineWorker
        original = InlineWorker.run_untyped_passes
    except (ImportError, AttributeError):  # pragma: no cover - another Numba: compile as it does
        return False
    if getattr(original, "rbx_reuse", False):
        return True
    made = {}

    def run_untyped_passes(self, func, enable_ssa=False):
        if not getattr(func, "__module__", "").startswith(package + ".") or self.locals:
            return original(self, func, enable_ssa)
        key = (func, enable_ssa, id(self.typingctx))      # the target context is made anew for each kernel
        if key not in made:
            made[key] = original(self, func, enable_ssa)
        else:
            self.flags.enable_ssa = enable_ssa          # what the original does to the caller's flags
        return made[key]

    run_untyped_passes.rbx_reuse = True
    InlineWorker.run_untyped_passes = run_untyped_passes
    _copy_blocks_with_one_scope()
    return True


class _BlockCopier:
    """Stands in for the ``copy`` module in :mod:`numba.core.inline_closurecall`. ``InlineWorker.inline_ir`` copies
    the inlined helper's IR block by block, each block with ``copy.deepcopy`` and a memo of its own, so each block
    gets its own deep copy of the helper's whole variable scope, which all its blocks share: a fifth of a kernel's
    compile went into these copies (the rough Sinai: 4.5 s -> 3.6 s without them). Here the blocks copied from one
    scope share one copy of it, as the blocks of a helper made afresh do. The copies are forgotten when
    ``inline_ir`` returns (:func:`_copy_blocks_with_one_scope`)."""
    def __init__(self, copy_module, block_class):
        self._copy, self._block, self.scopes = copy_module, block_class, None

    def __getattr__(self, name):
        return getattr(self._copy, name)

    def deepcopy(self, x, memo=None):
        if memo is None and self.scopes is not None and isinstance(x, self._block):
            made = self.scopes.get(id(x.scope))
            if made is None or made[0] is not x.scope:
                made = self.scopes[id(x.scope)] = (x.scope, self._copy.deepcopy(x.scope))
            memo = {id(x.scope): made[1]}
        return self._copy.deepcopy(x, memo)


def _copy_blocks_with_one_scope():
    """Put :class:`_BlockCopier` in place for the duration of each ``InlineWorker.inline_ir`` (part of the
    ``inline`` hook) -> whether it is in place."""
    try:
        import copy
        from numba.core import inline_closurecall, ir
        original = inline_closurecall.InlineWorker.inline_ir
        assert inline_closurecall.copy is copy
    except (ImportError, AttributeError, AssertionError):  # pragma: no cover - another Numba: its own copies
        return False
    copier = _BlockCopier(copy, ir.Block)

    def inline_ir(self, *args, **kwargs):
        outer = copier.scopes
        copier.scopes = {}
        try:
            return original(self, *args, **kwargs)
        finally:
            copier.scopes = outer

    inline_closurecall.copy = copier
    inline_closurecall.InlineWorker.inline_ir = inline_ir
    return True


# ---- blas: Numba's BLAS question asked when needed ----------------------------------------------------------------

class BlasAvailable:
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


def defer_blas_check():
    """Numba loads its array implementations (``numba.np.arraymath``) when a process first compiles or loads a
    kernel, and that module asks at import whether a BLAS is there by importing ``scipy.linalg``: 0.38 s of the
    1.5 s a warm ``rbx simulate`` took to start, for ``np.correlate`` and ``np.convolve`` alone (its one reader,
    ``_HAVE_BLAS``), which no rbx kernel calls. The module is imported here with that question deferred: its answer
    is the same, found the first time something compiles one of those two (:class:`BlasAvailable`). -> whether
    the hook is in place."""
    if "blas" in FORCED or "numba.np.arraymath" in sys.modules:
        return False
    try:
        from numba.np import linalg
        ensure_blas = linalg.ensure_blas
    except (ImportError, AttributeError):  # pragma: no cover
        return False

    def later():
        raise ImportError("asked later")

    linalg.ensure_blas = later
    try:
        from numba.np import arraymath
    finally:
        linalg.ensure_blas = ensure_blas
    if getattr(arraymath, "ensure_blas", None) is later and arraymath._HAVE_BLAS is False:
        arraymath.ensure_blas = ensure_blas
        arraymath._HAVE_BLAS = BlasAvailable(ensure_blas)
        return True
    return False   # pragma: no cover - another Numba


# ---- cache: rbx's kernels cached in rbx's folder, nobody else's ---------------------------------------------------

def _cache_class(folder):
    """A Numba function-cache class whose files go to ``folder`` (Numba's sub-folder per source file beneath it),
    or None without the private parts."""
    if "cache" in FORCED:
        return None
    try:
        from numba.core import caching
        base = getattr(caching, "UserProvidedCacheLocator", None) or caching._UserProvidedCacheLocator
        impl, function_cache = caching.CompileResultCacheImpl, caching.FunctionCache
    except (ImportError, AttributeError):  # pragma: no cover - another Numba
        return None

    class Locator(base):
        def __init__(self, py_func, py_file):
            self._py_file = py_file
            self._lineno = py_func.__code__.co_firstlineno
            self._cache_path = os.path.join(folder, self.get_suitable_cache_subpath(py_file))

        @classmethod
        def from_function(cls, py_func, py_file):
            if not os.path.exists(py_file):
                return None
            self = cls(py_func, py_file)
            try:
                self.ensure_cache_path()
            except OSError:
                return None
            return self

    class Impl(impl):
        _locator_classes = [Locator]

    class Cache(function_cache):
        _impl_class = Impl

    return Cache


_CACHE = {}
_WARNED = []


def enable_cache(dispatcher, folder):
    """Cache ``dispatcher``'s compiled code on disk in ``folder`` (as ``cache=True`` would, in Numba's folder).
    Without the private parts it is not cached on disk (one warning line per process): a cache keyed by the
    kernel's own file alone could serve stale code."""
    if folder not in _CACHE:
        _CACHE[folder] = _cache_class(folder)
    cls = _CACHE[folder]
    if cls is not None:
        try:
            dispatcher._cache = cls(dispatcher.py_func)
            return dispatcher
        except (AttributeError, RuntimeError, OSError):  # pragma: no cover
            pass
    if not _WARNED:
        _WARNED.append(True)
        sys.stderr.write(f"rbx: warning: this Numba ({numba.__version__}) cannot keep rbx's kernels in "
                         f"{folder}; they are compiled afresh in every process\n")
    return dispatcher


def describe():
    """The hooks in use, as text (run files and the cluster's check record it)."""
    return ",".join(h for h in HOOKS if h not in FORCED) or "none"
