"""Compile ahead the kernels of every example (``make warm-up``, which ``make reproduce-figures`` runs): each config
of ``configs/examples/`` is loaded and run for one collision in memory, which compiles the kernel variants its
first real run needs (``rbx simulate`` of it; ``rbx lyapunov`` too for the examples made for it) into the kernel
cache (``~/.cache/rbx`` or ``$NUMBA_CACHE_DIR``). The first run of an example then loads them from the cache
instead of compiling for 10–40 s.

    python scripts/warm_up.py [CONFIG.yaml ...]       # default: every configs/examples/*.yaml
"""
import glob
import os
import sys
import time
import warnings

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import rbx  # noqa: E402
from rbx.progress import duration, watch_compiles  # noqa: E402

#: the examples whose first run is ``rbx lyapunov`` (the tangent loop: a kernel of its own)
LYAPUNOV = ("lyapunov-sinai.yaml",)


def warm(config):
    """Compile the kernels of one example config -> seconds spent."""
    began = time.perf_counter()
    exp = rbx.load(config)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)     # copies of one orbit: one collision says nothing anyway
        rbx.simulate(exp, collisions=1)
        if os.path.basename(config) in LYAPUNOV:
            rbx.lyapunov(exp, collisions=40, segments=2)
    return time.perf_counter() - began


def main(argv=None):
    configs = (argv if argv is not None else sys.argv[1:]) or \
        sorted(glob.glob(os.path.join(ROOT, "configs", "examples", "*.yaml")))
    watch_compiles()
    began = time.perf_counter()
    for config in configs:
        seconds = warm(config)
        print(f"warm-up: {os.path.relpath(config, ROOT)}: {duration(seconds)}", flush=True)
    print(f"warm-up: the kernels of {len(configs)} examples are in the cache ({duration(time.perf_counter() - began)})",
          flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
