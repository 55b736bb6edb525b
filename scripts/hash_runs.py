"""Fingerprints of every example config's run: the records, the final state and the shrunk table's geometry, one
SHA-256 line per config and variant. A change that must leave every run bit for bit what it was is checked by
running this before and after it and comparing the outputs (``diff``).

    .venv/bin/python scripts/hash_runs.py > before.txt     # on the old code
    .venv/bin/python scripts/hash_runs.py > after.txt      # on the new code
    diff before.txt after.txt

Each config under configs/examples and configs/experiments runs short (``--collisions``, ``--trajectories``),
recording every field at every collision, in memory; and again with each ``numerics:`` option (compensated
sums, snapping, no renormalisation). The geometry's hash covers the primitive codes, walls, parameters, wall
names, sampling patches and the flags the kernels read (slab, axis box, convex boundary, lattice).
"""
import argparse
import glob
import hashlib
import os
import sys
import warnings

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

VARIANTS = {
    "default": {},
    "compensated": {"numerics.compensated": True},
    "snap": {"numerics.snap": True},
    "norenorm": {"numerics.renormalize": 0},
}


def _feed(h, value):
    if isinstance(value, dict):
        for k in sorted(value):
            h.update(repr(k).encode())
            _feed(h, value[k])
    elif isinstance(value, (list, tuple)):
        h.update(b"[")
        for x in value:
            _feed(h, x)
        h.update(b"]")
    elif isinstance(value, np.ndarray):
        a = np.ascontiguousarray(value)
        h.update(repr((a.dtype.str, a.shape)).encode())
        h.update(a.tobytes())
    elif value is None or isinstance(value, (bool, int, float, str, np.generic)):
        h.update(repr(value).encode())
    else:
        _feed(h, {k: getattr(value, k) for k in sorted(vars(value))} if hasattr(value, "__dict__") else repr(value))


def digest(value):
    h = hashlib.sha256()
    _feed(h, value)
    return h.hexdigest()[:20]


def geometry_facts(geom):
    walls = [(w.name, getattr(w, "patch", None), getattr(w, "tangents", None)) for w in geom.wall_list]
    return {"kind": geom.kind, "n": geom.dimension, "codes": geom.codes, "walls": geom.walls, "params": geom.params,
            "wall_list": walls, "size": geom.size, "slab": geom.slab, "axis_box": geom.axis_box,
            "convex": bool(geom.convex_boundary), "lattice": geom.lattice, "can_sample": geom.can_sample,
            "outline": geom.outline, "shrunk_outline": geom.shrunk_outline, "circle": geom.circle,
            "corners": geom.corners}


def configs():
    out = sorted(glob.glob(os.path.join(ROOT, "configs", "examples", "*.yaml")))
    out += sorted(glob.glob(os.path.join(ROOT, "configs", "experiments", "*.yaml")))
    out += sorted(glob.glob(os.path.join(ROOT, "configs", "experiments", "*", "*.yaml")))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--collisions", type=int, default=2000)
    ap.add_argument("--trajectories", type=int, default=3)
    ap.add_argument("--only", default=None, help="substring of the config paths to run")
    args = ap.parse_args()
    import rbx
    from rbx.model import RECORD_FIELDS
    from rbx.simulation import MemorySink, Simulation
    warnings.simplefilter("ignore")
    for path in configs():
        name = os.path.relpath(path, ROOT)
        if args.only and args.only not in name:
            continue
        for variant, extra in VARIANTS.items():
            changes = {"output.record": list(RECORD_FIELDS), "output.every": 1, "output.path": None, **extra}
            try:
                exp = rbx.load(path, {"collisions": args.collisions, "trajectories": args.trajectories, **changes})
            except Exception as e:      # noqa: BLE001 - a config that refuses the override: say so, go on
                print(f"{name} {variant} refused: {type(e).__name__}: {e}", flush=True)
                continue
            sim = Simulation(exp)
            sink = MemorySink()
            sim.run(sink)
            print(f"{name} {variant} geometry={digest(geometry_facts(sim.geom))} "
                  f"records={digest(sink.records)} count={digest(sink.count)} final={digest(sink.final)}",
                  flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
