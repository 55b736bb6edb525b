"""Compile ahead the kernels of every example (``make warm-up``, which ``make reproduce-figures`` runs): each config
of ``configs/examples/`` is loaded and run for one collision in memory, which compiles the kernel variants its
first real run needs (``rbx simulate`` of it; ``rbx lyapunov`` too for the examples made for it) into the kernel
cache (``~/.cache/rbx`` or ``$NUMBA_CACHE_DIR``). The first run of an example then loads them from the cache
instead of compiling for several seconds (3–7 s a kernel variant on this project's 2-core machines).

    python scripts/warm_up.py [CONFIG.yaml ...] [--jobs N]      # default: every configs/examples/*.yaml
"""
import glob
import os
import sys
import time
import warnings

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import rbx  # noqa: E402
from rbx.progress import duration, plural, watch_compiles  # noqa: E402

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


def _warm(config):
    watch_compiles()
    return config, warm(config)


def main(argv=None):
    import argparse
    import concurrent.futures
    import multiprocessing
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("configs", nargs="*", help="example configs (default: every configs/examples/*.yaml)")
    p.add_argument("--jobs", type=int, default=os.cpu_count() or 1,
                   help="processes compiling at once (default: one per CPU; a compile uses one core)")
    args = p.parse_args(argv)
    configs = args.configs or sorted(glob.glob(os.path.join(ROOT, "configs", "examples", "*.yaml")))
    began = time.perf_counter()
    jobs = max(1, min(args.jobs, len(configs)))
    if jobs == 1:
        done = map(_warm, configs)
    else:   # processes of their own (spawned: Numba and forks do not mix); a kernel two of them need is compiled
        # once, the other waits on its lock in the cache and loads it (rbx._jit.compile_lock)
        pool = concurrent.futures.ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn"))
        done = (f.result() for f in concurrent.futures.as_completed([pool.submit(_warm, c) for c in configs]))
    for config, seconds in done:
        print(f"warm-up: {os.path.relpath(config)}: {duration(seconds)}", flush=True)
    print(f"warm-up: the kernels of {plural(len(configs), 'example')} are in the cache "
          f"({duration(time.perf_counter() - began)}, {jobs} at once)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
