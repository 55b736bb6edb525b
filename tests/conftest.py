"""The tests run rbx's general loops (``rbx.engine.KERNELS``, ``RBX_KERNELS=general``): one compile per dimension
(the tangent vectors' bit read at run time as well) instead of one per combination of compiled bits a scene uses, so a
cold suite compiles 2 loops, not 45. They give the specialised loops' numbers bit for bit; tests/test_kernels.py compares the two on every
example. The variable is set before rbx is imported, so every process the tests start (the command line, Dask
workers) inherits it; ``RBX_KERNELS=specialised make test`` runs the whole suite on the specialised loops."""
import os

os.environ.setdefault("RBX_KERNELS", "general")
