"""The one place that decides how rbx compiles its kernels (STYLE: one module owns the jit policy).

- ``cache=True``: compiled kernels are stored in ``__pycache__`` so a second run starts in well under a second.
- ``error_model='numpy'``: a division by zero gives inf/nan instead of raising; ``inf`` means "no collision".
- no ``fastmath``: the engine relies on ``inf`` and exact comparisons (fast-math would assume no infs).
"""
import numba

_POLICY = dict(cache=True, error_model="numpy", fastmath=False, nogil=True)

jit = numba.njit(**_POLICY)


def jit_parallel(func):
    """Compile a driver that loops over trajectories with ``prange`` (never inside one trajectory)."""
    return numba.njit(parallel=True, **_POLICY)(func)
