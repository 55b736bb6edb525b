"""The HDF5 file of a run (SPEC §5), written as the run streams.

Layout (trajectory axis first; T trajectories, N records):

| path | shape (2D / 3D) | dtype | meaning |
|---|---|---|---|
| ``/`` attrs | | | ``rbx_version``, ``schema_version``, ``dimension``, ``config`` (resolved YAML), ``complete``, ``table_kind``, ``wall_names``, ``radius``, ``kappa``, ``collisions_requested`` |
| ``collisions/time`` | (T, N) | f8 | time of the record |
| ``collisions/position``, ``velocity`` | (T, N, n) | f8 | centre and its velocity |
| ``collisions/angular_velocity`` | (T, N) / (T, N, 3) | f8 | space-frame ω |
| ``collisions/orientation`` | (T, N) / (T, N, 3, 3) | f8 | continuous angle θ / rotation matrix A |
| ``collisions/wall``, ``rank`` | (T, N) | i4 | wall index hit (−1 for record 0), roughness rank used |
| ``collisions/count`` | (T,) | i8 | records written for each trajectory (rows past it are NaN / −1) |
| ``collisions/step`` | (N,) | i8 | collision number of each record (0, every, 2·every, …) |
| ``final/*`` | (T, …) | | last state of every trajectory, its ``collisions`` and ``draws`` counts and ``alive`` flag (for ``--resume``); attribute ``digest``: hash of the state, see :func:`state_digest` |

Datasets grow along the record axis in chunks, so memory does not grow with the run's length; ``count`` and
``final/`` are rewritten after every block and the file is flushed, so an interrupted run leaves a readable file
with ``complete = False``.
"""
import os

import h5py
import numpy as np
import yaml

from . import __version__
from .model import FIELD

SCHEMA_VERSION = 1
CHUNK_BYTES = 1 << 18


def config_yaml(cfg):
    return yaml.safe_dump(_plain(cfg.resolved), sort_keys=False)


def _plain(x):
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    return x


def write_root_attrs(h5, cfg, geom, complete):
    """The root attributes every rbx file carries (SPEC §5), for run files and return-angle files alike."""
    a = h5.attrs
    a["rbx_version"] = __version__
    a["schema_version"] = SCHEMA_VERSION
    a["dimension"] = cfg.dimension
    a["config"] = config_yaml(cfg)
    a["complete"] = bool(complete)
    a["table_kind"] = cfg.table_kind
    a["wall_names"] = np.array(geom.wall_names, dtype=h5py.string_dtype())
    a["radius"] = cfg.ball.radius
    a["kappa"] = cfg.ball.kappa
    a["collisions_requested"] = cfg.run.collisions


class H5Sink:
    """Streams the records of a :class:`rbx.simulate.Simulation` into an open HDF5 file."""

    def __init__(self, h5, cfg, geom, fresh=True):
        self.h5 = h5
        M, n = cfg.run.trajectories, cfg.dimension
        self.every = cfg.output.every
        if fresh:
            write_root_attrs(h5, cfg, geom, complete=False)
            g = h5.create_group("collisions")
            for f in cfg.output.record:
                tail = FIELD[f].shape(n)
                dtype = FIELD[f].dtype
                per = int(np.prod(tail or (1,))) * np.dtype(dtype).itemsize
                tchunk = min(M, 64)
                rchunk = max(1, CHUNK_BYTES // (tchunk * per))
                g.create_dataset(f, shape=(M, 0) + tail, maxshape=(M, None) + tail, dtype=dtype,
                                 chunks=(tchunk, rchunk) + tail, fillvalue=FIELD[f].fill)
            g.create_dataset("count", data=np.zeros(M, np.int64))
            g.create_dataset("step", shape=(0,), maxshape=(None,), dtype=np.int64, chunks=(4096,))
        self.g = h5["collisions"]

    def write(self, block, nrec):
        g = self.g
        b = next(iter(block.values())).shape[1]
        start = g["step"].shape[0]
        for f, arr in block.items():
            ds = g[f]
            ds.resize(start + b, axis=1)
            ds[:, start:start + b] = arr
        g["step"].resize(start + b, axis=0)
        g["step"][start:] = np.arange(start, start + b) * self.every
        g["count"][...] = g["count"][...] + nrec

    def checkpoint(self, sim):
        # flush first: the block's records reach the file before the state that accounts for them
        self.h5.flush()
        fin = self.h5.require_group("final")
        state = sim.final_state()
        for k, v in state.items():
            v = np.asarray(v)
            if k in fin and fin[k].shape == v.shape:
                fin[k][...] = v
            else:
                if k in fin:
                    del fin[k]
                fin.create_dataset(k, data=v)
        fin.attrs["digest"] = state_digest(state)
        self.h5.flush()


def state_digest(state):
    """A hash of a final state (dict of arrays). A process killed outright (SIGKILL, power loss) can leave
    ``final/`` half rewritten; ``--resume`` recomputes this hash and refuses such a state instead of continuing
    from a mixture of two blocks."""
    import hashlib
    h = hashlib.blake2b(digest_size=16)
    for k in sorted(state):
        a = np.ascontiguousarray(state[k])
        h.update(f"{k}:{a.dtype.str}:{a.shape}:".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def temporary_path(path):
    """Where a run writes until it stops: beside the target, renamed over it at the end."""
    return f"{path}.partial"


def open_for_writing(path):
    os.makedirs(os.path.dirname(os.path.abspath(path)) or ".", exist_ok=True)
    return h5py.File(temporary_path(path), "w")
