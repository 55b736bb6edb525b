"""The environment variables rbx reads, each checked in one place.

rbx's own: ``RBX_KERNELS`` (which compiled loops run: :data:`KERNEL_MODES`, :mod:`rbx.engine`) and
``RBX_NUMBA_FALLBACK`` (the uses of Numba's private parts to leave out: :data:`NUMBA_HOOKS`,
:mod:`rbx._numba_hooks`). Numba's, that stop rbx before it runs: ``NUMBA_NUM_THREADS`` (a count Numba cannot read
is a traceback at its import), ``NUMBA_DISABLE_JIT`` (rbx's loops exist only compiled) and
``NUMBA_THREADING_LAYER`` (a layer that cannot be loaded fails the first run), and any ``NUMBA_*`` whose value
Numba cannot parse (it warns with a traceback, then ignores it).

The command line calls :func:`problem` before any command and refuses in one line, exit 2; the library reads the
same functions where it uses each variable (an unknown ``RBX_KERNELS`` warns, an unknown hook is an ImportError).
Imports nothing of rbx, and Numba only when one of its variables is set.
"""
import os

#: the values of ``RBX_KERNELS`` (the first is the default): see :data:`rbx.engine.KERNELS`
KERNEL_MODES = ("specialised", "general")
#: the names ``RBX_NUMBA_FALLBACK`` takes (besides ``all``): the hooks of :mod:`rbx._numba_hooks`, in its order
NUMBA_HOOKS = ("fingerprint", "nrt", "stack", "inline", "blas", "cache")


def kernel_mode():
    """``RBX_KERNELS`` -> (mode, problem): problem None, or what is wrong (the mode is then the default)."""
    mode = os.environ.get("RBX_KERNELS", "").strip() or KERNEL_MODES[0]
    if mode not in KERNEL_MODES:
        return KERNEL_MODES[0], f"{mode!r} is not one of {', '.join(KERNEL_MODES)}"
    return mode, None


def fallback_hooks():
    """``RBX_NUMBA_FALLBACK`` -> (the hooks it turns off, a frozenset; problem: None or what is wrong)."""
    text = os.environ.get("RBX_NUMBA_FALLBACK", "").strip()
    names = {w.strip() for w in text.split(",") if w.strip()}
    if "all" in names:
        return frozenset(NUMBA_HOOKS), None
    unknown = names - set(NUMBA_HOOKS)
    if unknown:
        return frozenset(names - unknown), (f"unknown hook(s) {sorted(unknown)}; known: all, "
                                            f"{', '.join(NUMBA_HOOKS)}")
    return frozenset(names), None


def _num_threads():
    threads = os.environ.get("NUMBA_NUM_THREADS")
    if threads is not None and not (threads.strip().isdigit() and int(threads) >= 1):
        return f"must be a positive integer, got '{threads}'"
    return None


def disable_jit():
    """``NUMBA_DISABLE_JIT`` -> None, or why rbx cannot run with it (Numba's compiler turned off)."""
    value = os.environ.get("NUMBA_DISABLE_JIT", "").strip()
    try:
        on = int(value) != 0 if value else False
    except ValueError:          # Numba itself ignores a value that is not an integer
        on = False
    return f"is {value!r}: rbx's loops run only as Numba compiles them; unset it" if on else None


def _threading_layer():
    layer = os.environ.get("NUMBA_THREADING_LAYER", "").strip()
    if not layer or layer == "default":
        return None
    import numba
    try:
        numba.get_num_threads()         # loads the layer, as the first run would
    except ValueError as exc:           # an unknown name, a layer whose library is not installed
        lines = [line.strip().split(", try")[0].rstrip(".:") for line in str(exc).splitlines() if line.strip()]
        said = ": ".join(lines[:1] + [line for line in lines[1:] if "required" in line])  # TBB's hint, not pip's
        return f"Numba cannot load the threading layer {layer!r} ({said}); unset it or install the layer"
    return None


def problem():
    """The first environment variable that stops rbx -> (name, what is wrong), or None."""
    checks = (("NUMBA_NUM_THREADS", _num_threads), ("NUMBA_DISABLE_JIT", disable_jit),
              ("RBX_KERNELS", lambda: kernel_mode()[1]), ("RBX_NUMBA_FALLBACK", lambda: fallback_hooks()[1]),
              ("NUMBA_THREADING_LAYER", _threading_layer))
    for name, check in checks:
        said = check()
        if said:
            return name, said
    return _unread_numba_setting()


def _unread_numba_setting():
    """A ``NUMBA_*`` variable whose value Numba cannot read -> (name, what is wrong), or None. Numba reads its
    variables when it is imported and warns about one it cannot parse with its parser's whole traceback (twelve
    lines for ``NUMBA_OPT=abc``), then goes on without it. Numba is imported here only if such a variable is set."""
    if not any(key.startswith("NUMBA_") for key in os.environ):
        return None
    import re
    import warnings
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        import numba.core.config  # noqa: F401 - its import reads the variables
    for w in caught:
        found = re.match(r"Environment variable '(\w+)' is defined but its associated value '(.*)' could not be "
                         r"parsed", str(w.message))
        if found:
            lines = [line.strip() for line in str(w.message).splitlines() if line.strip()]
            why = lines[-1].split(": ", 1)[-1] if len(lines) > 1 else "not a value it takes"
            return found.group(1), f"Numba cannot read the value {found.group(2)!r} ({why}); unset it or fix it"
    return None
