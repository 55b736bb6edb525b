"""The one place that decides how rbx compiles its kernels (STYLE: one module owns the jit policy).

- ``cache=True``: compiled kernels are stored in ``__pycache__`` so a second run starts in well under a second.
- ``error_model='numpy'``: a division by zero gives inf/nan instead of raising; ``inf`` means "no collision".
- no ``fastmath``: the engine relies on ``inf`` and exact comparisons (fast-math would assume no infs).
"""
import numba

_POLICY = dict(cache=True, error_model="numpy", fastmath=False, nogil=True)

jit = numba.njit(**_POLICY)

#: for the small functions called once per collision (collision time, normal, rule choice, collision map):
#: compiled without the Numba runtime (``_nrt=False``: they allocate nothing), so that passing arrays to them
#: costs no atomic reference counting. Measured on the strip: 80 ns per call with it, 18 ns without
#: (Numba 0.68; ``inline="always"`` does not help, the inlined arguments are reference-counted too).
jit_hot = numba.njit(_nrt=False, inline="always", **_POLICY)

#: the serial loop of one trajectory: no runtime either (its scratch space is allocated by the caller), so the
#: helpers inlined into it are free of reference counting
jit_loop = numba.njit(_nrt=False, **_POLICY)


def jit_parallel(func):
    """Compile a driver that loops over trajectories with ``prange`` (never inside one trajectory)."""
    return numba.njit(parallel=True, **_POLICY)(func)
