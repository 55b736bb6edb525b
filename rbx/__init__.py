"""rbx: simulate non-standard (rough) billiards with the strict collision maps of Cox, Feres and Ward.

The Python API (docs/reference.md §9; :mod:`rbx.api`): ``rbx.load(config, overrides)`` -> Experiment,
``rbx.simulate(experiment, …)`` -> Run, ``rbx.resume(path, …)`` -> Run, ``rbx.open(path)`` -> Run, ``rbx.Run``,
``rbx.ConfigError``, ``rbx.FileError``; and (docs/reference.md §10, :mod:`rbx.dynamics`) ``rbx.lyapunov(experiment, …)`` -> the
Lyapunov spectrum, ``rbx.escape_times(run)`` -> escape or return times; (docs/studies.md, :mod:`rbx.study`, :mod:`rbx.sweeping`)
``rbx.sweep(study, output=None, …)`` -> a parameter study as an xarray.Dataset. ``python -m rbx`` is the command line.
Importing rbx is light: the engine (numba) loads when first used.
"""
import importlib

__version__ = "0.1.0"

_LAZY = {"load": "api", "simulate": "api", "resume": "api", "open": "api", "Run": "reader", "FileError": "paths",
         "ConfigError": "model", "lyapunov": "dynamics", "escape_times": "dynamics", "sweep": "sweeping"}


def __getattr__(name):
    if name in _LAZY:
        return getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
    raise AttributeError(f"module 'rbx' has no attribute '{name}'")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))


__all__ = ["load", "simulate", "resume", "open", "lyapunov", "escape_times", "sweep", "Run", "ConfigError", "FileError", "__version__"]
