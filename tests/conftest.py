"""The tests run rbx's general loops (``rbx.engine.KERNELS``, ``RBX_KERNELS=general``): one compile per dimension
(the tangent vectors' bit read at run time as well) instead of one per combination of compiled bits a scene uses, so a
cold suite compiles 2 loops, not 45. They give the specialised loops' numbers bit for bit; tests/test_kernels.py compares the two on every
example. The variable is set before rbx is imported, so every process the tests start (the command line, Dask
workers) inherits it; ``RBX_KERNELS=specialised make test`` runs the whole suite on the specialised loops."""
import os

os.environ.setdefault("RBX_KERNELS", "general")


def pytest_sessionstart(session):
    """On a cold kernel cache, each of two test workers compiles one of the two general loops before its first test
    (gw0 the 2D one, gw1 the 3D one, 30 s each), both cores at once: the tests' order had the second worker wait
    idle on the compile lock (rbx._jit.compile_lock) for the loop the first was compiling. With a warm cache this
    loads the two loops in under a second; a run without workers compiles each loop when a test first needs it."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    if os.environ.get("RBX_KERNELS") != "general" or worker not in ("gw0", "gw1"):
        return
    import warnings

    import rbx
    examples = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "configs", "examples")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rbx.simulate(rbx.load(os.path.join(examples, "strip.yaml" if worker == "gw0" else "plates.yaml")),
                     collisions=1, trajectories=1)
