"""rbx: simulate non-standard (rough) billiards with the strict collision maps of Cox, Feres and Ward.

The Python API (SPEC §9; :mod:`rbx.api`): ``rbx.load(path_or_dict)`` -> Experiment, ``rbx.simulate(experiment,
…)`` -> Run, ``rbx.open(path)`` -> Run, ``rbx.Run``, ``rbx.ConfigError``, ``rbx.FileError``. ``python -m rbx`` is
the command line. Importing rbx is light: the engine (numba) loads when first used.

``rbx.simulate`` is both the API function and the module ``rbx/simulate.py`` (the Python tier of the event loop):
a package attribute and a submodule of the same name cannot be told apart, so that module is made callable —
calling it calls :func:`rbx.api.simulate`, and its contents (``Simulation``, ``MemorySink``, …) are there as
before.
"""
import importlib.abc
import importlib.machinery
import sys
import types

__version__ = "0.1.0"

_LAZY = {"load": "api", "open": "api", "Run": "runfile", "FileError": "runfile", "ConfigError": "model"}


class _CallableModule(types.ModuleType):
    """The module rbx.simulate, which is also the API function rbx.simulate(...)."""

    def __call__(self, experiment, **options):
        from .api import simulate
        return simulate(experiment, **options)


class _MakeCallable(importlib.abc.Loader):
    def __init__(self, loader):
        self.loader = loader

    def create_module(self, spec):
        return None

    def exec_module(self, module):
        module.__class__ = _CallableModule
        self.loader.exec_module(module)

    def __getattr__(self, name):   # get_source, get_code, …: the file loader's
        return getattr(self.loader, name)


class _Finder(importlib.abc.MetaPathFinder):
    """Loads rbx/simulate.py as a :class:`_CallableModule`, however it is first imported."""

    def find_spec(self, name, path, target=None):
        if name != __name__ + ".simulate":
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        if spec is not None and spec.loader is not None:
            spec.loader = _MakeCallable(spec.loader)
        return spec


if not any(isinstance(f, _Finder) for f in sys.meta_path):
    sys.meta_path.insert(0, _Finder())
if __name__ + ".simulate" in sys.modules:   # imported before this package (a reload): make it callable now
    sys.modules[__name__ + ".simulate"].__class__ = _CallableModule


def __getattr__(name):
    if name == "simulate":
        return importlib.import_module(__name__ + ".simulate")
    if name in _LAZY:
        return getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
    raise AttributeError(f"module 'rbx' has no attribute '{name}'")


def __dir__():
    return sorted(set(globals()) | set(_LAZY) | {"simulate"})


__all__ = ["load", "simulate", "open", "Run", "ConfigError", "FileError", "__version__"]
