"""Continue an interrupted run from its HDF5 file (``rbx simulate --resume``).

Everything needed is in the file: the fully resolved config (root attribute ``config``) and, in ``final/``, the
last state of every trajectory with its collision and random-draw counters. Random streams are counter-based
(:mod:`rbx.rng`: draw k of trajectory j depends only on (seed, j, k)), and records fall on the collisions whose
number is a multiple of ``output.every`` whatever the block boundaries, so a resumed run writes exactly the
records an uninterrupted run would have written.

The records in the file are first cut back to what ``final/`` accounts for: an uninterrupted run writes a block's
records before its checkpoint, so after a hard kill between the two the file may hold a few records past the
saved state; those are dropped and recomputed. A file with no ``final/`` (stopped before its first block) starts
over from the config's initial state.

A ``.partial`` already marked complete (a run killed between marking it and renaming it) needs no simulation:
:func:`rbx.driver.finish_complete` renames it. The workflow around these (locks, copy, journal, rename) is
:mod:`rbx.driver`'s: :func:`rbx.driver.prepare_resume`, :func:`rbx.driver.resume_to_file`.
"""
import json
import weakref

import h5py
import numpy as np

from . import __version__, runfile
from .locks import acquire_lock, release_lock
from .model import ConfigError
from .runfile import STATE_GROUPS, latest_state
from .simulation import Simulation

#: what ``final/`` must hold to continue (Simulation takes the rest from the config)
STATE_KEYS = ("time", "position", "velocity", "angular_velocity", "orientation", "collisions", "draws", "alive",
              "last_wall", "last_rank")


def load(run, source, lock=True):
    """Read an incomplete run (a :class:`rbx.reader.Run` opened from its file; the file is only read) ->
    (Simulation, write_initial, done). ``lock``: take the file's run lock, held until the run's file is done
    (False: a file on a read-only file system, which nothing can write).

    ``done``: collisions already made by the trajectories still running; ``write_initial``: True when the file
    has no saved state yet and the run starts over. Raises :class:`rbx.config.ConfigError` (naming ``source``)
    if the file does not hold a run that can be continued. Then call :func:`make_consistent` on a writable copy."""
    # the run's lock first (OUT.h5.lock for OUT.h5 and OUT.h5.partial): two resumes of one file, or a resume of a
    # file a run still writes, would both write it. Held until rbx.driver.stream ends (sim.locks).
    if not lock:
        return _load(run, source)
    acquire_lock(run.path or source)
    try:
        sim, write_initial, done = _load(run, source)
    except BaseException:
        release_lock(run.path or source)
        raise
    # released by rbx.driver.stream when the run's file is done, or when the simulation is dropped without
    # running (a later check of --resume refused it)
    sim.locks.append(weakref.finalize(sim, release_lock, run.path or source))
    return sim, write_initial, done


def _load(run, source):
    cfg = run.experiment

    def damaged(key, problem):
        return ConfigError(source, key, f"{problem}; the file cannot be resumed")

    if run.dimension != cfg.dimension:
        raise damaged("dimension", f"is {run.dimension} but the stored config is {cfg.dimension}D")
    recorded = run.fields
    if recorded != cfg.output.record:
        raise damaged("collisions", f"holds {', '.join(recorded) or 'no fields'} but the config records "
                                    f"{', '.join(cfg.output.record) or 'no fields'}")
    M = cfg.run.trajectories
    g = run.h5["collisions"]
    for f in recorded + ("count",):
        if g[f].shape[0] != M:
            raise damaged(f"collisions/{f}", f"has {g[f].shape[0]} trajectories, the config {M}")
    _check_growable(g, recorded, cfg, damaged)

    state, slot, verified = latest_state(run.h5)
    if any(k not in state for k in STATE_KEYS):
        return Simulation(cfg), True, 0
    state = {k: np.array(v) for k, v in state.items()}
    for k in STATE_KEYS:
        if state[k].shape[:1] != (M,):
            raise damaged(f"{slot}/{k}", f"has shape {state[k].shape}, expected {M} trajectories first")
    if not verified:
        raise damaged(slot, "the last saved state is incomplete (the process was killed while writing it)")
    if cfg.numerics.compensated and "compensation" not in state:
        # the compensated sums' error terms were not saved (rbx before they were): continuing them from zero
        # would not give the uninterrupted run's numbers
        raise ConfigError(source, f"{slot}/compensation",
                          "missing: the run uses numerics.compensated and its saved state lacks the sums' error "
                          "terms (written by an older rbx), so a resumed run would not equal an uninterrupted one; "
                          "run it again from its config")
    _check_state_fits(run, cfg, state, slot, damaged)
    _check_orbit(run, slot, source)
    collisions = state["collisions"].astype(np.int64)
    alive = state["alive"].astype(bool)
    running = np.unique(collisions[alive])
    if running.size > 1:
        raise damaged("final/collisions", "the running trajectories are at different collisions")
    if np.any(collisions < 0) or np.any(collisions > cfg.run.collisions):
        raise damaged("final/collisions", "out of range")
    if cfg.output.record:
        expected = 1 + collisions // cfg.output.every   # record 0 and one per ``every`` collisions
        if g["step"].shape[0] < expected.max() or np.any(g["count"][...] < expected):
            raise damaged("collisions/count", "fewer records than the saved state accounts for")
        torn = _torn_chunks(g, cfg, int(expected.max()), damaged)
        _check_last_records(g, cfg, state, expected, damaged, torn)
    else:
        torn = {}
    sim = Simulation(cfg, state)
    sim.torn_chunks = torn
    done = int(running[0]) if running.size else cfg.run.collisions
    return sim, False, done


def _check_growable(g, recorded, cfg, damaged):
    """The datasets a resume cuts back and extends along the records (the recorded fields, ``step``, the ``record``
    scale) must be able to: chunked, with room for the run's records. A file rewritten with them contiguous (as
    ``h5repack -l CONTI`` does) or chunked with a fixed maximum shape reads as any other, but its resume failed
    in HDF5 with a traceback after the copy of the file was made."""
    needed = cfg.run.collisions // cfg.output.every + 1 if recorded else 0
    for name in recorded + ("step",) + (("record",) if "record" in g else ()):
        ds = g[name]
        axis = 0 if ds.ndim == 1 else 1
        if ds.chunks is None:
            raise damaged(f"collisions/{name}", "is stored contiguous, not in chunks, so it cannot be extended (a "
                                                "copy rewritten by h5repack or another tool?)")
        most = ds.maxshape[axis]
        if most is not None and most < needed:
            raise damaged(f"collisions/{name}", f"has a fixed maximum of {most} records, fewer than the run's "
                                                f"{needed}, so it cannot be extended (a copy rewritten by another "
                                                "tool?)")


def _check_orbit(run, slot, source):
    """The stored config must make the orbit the saved state was computed on: every key of it that does (the
    seed, the table, the rules, the ball, the initial states, the numerics: :func:`rbx.runfile.orbit_digests`)
    as it was at the checkpoint. A state saved by an older rbx carries no such digests: not checked."""
    stored = run.h5[slot].attrs.get("orbit") if slot in run.h5 else None
    if stored is None:
        return
    try:
        was = json.loads(runfile._text(stored))
        if not isinstance(was, dict):
            raise ValueError(was)
    except (ValueError, RecursionError):       # RecursionError: '{"a":' nested 100 000 deep
        raise ConfigError(source, f"{slot}.orbit", "damaged (not the digests rbx writes); the file cannot be "
                                                   "resumed") from None
    now = json.loads(runfile.orbit_digests(run.config))
    changed = [k for k in sorted(set(was) | set(now)) if was.get(k) != now.get(k)]
    if changed:
        more = f"; so do {', '.join(changed[1:])}" if changed[1:] else ""
        raise ConfigError(source, f"config: {changed[0]}",
                          "differs from the value the run's records were computed with (the stored config was "
                          f"changed in the file since{more}): a resume would mix two orbits in one file; run the "
                          "config again instead")


#: how far (in units of the table's size) a saved centre may lie outside the shrunk table: rounding on a wall
FIT_TOLERANCE = 1e-9


def _check_state_fits(run, cfg, state, slot, damaged):
    """The saved state must be a state of the stored config before the run goes on: every running trajectory's
    state finite and its centre inside the table shrunk by the ball's radius (the root attributes written with the
    run, radius, κ, table kind and walls, were checked against the config when the file was opened:
    :attr:`rbx.reader.Run.experiment`). A config changed in the file (the radius 0.1 made 0.2) had continued the
    old orbits outside the new table and marked the file complete."""
    alive = np.asarray(state["alive"]).astype(bool)
    for k in ("time", "position", "velocity", "angular_velocity", "orientation"):
        values = np.asarray(state[k])[alive]
        if values.dtype.kind != "f" or not np.all(np.isfinite(values)):
            raise damaged(f"{slot}/{k}", "not finite for a running trajectory")
    geom = cfg.geometry()
    if geom.lattice is not None or not alive.any():
        return          # a periodic table's centres are unfolded: any cell is the table
    pos = np.asarray(state["position"])[alive]
    if pos.shape[1:] != (cfg.dimension,):
        raise damaged(f"{slot}/position", f"has shape {pos.shape[1:]} per trajectory, the config "
                                          f"({cfg.dimension},)")
    with np.errstate(all="ignore"):
        clearance = np.asarray(geom.clearance(pos), dtype=float)
    bad = np.nonzero(~(clearance >= -FIT_TOLERANCE * geom.size))[0]
    if bad.size:
        j = int(np.nonzero(alive)[0][bad[0]])
        raise damaged(f"{slot}/position", f"trajectory {j} is at {pos[bad[0]].tolist()}, outside the table of the "
                                          "stored config shrunk by the ball's radius: the config does not fit the "
                                          "saved state (was it changed?)")


def _torn_chunks(g, cfg, length, damaged):
    """The chunks the resumed file keeps and rewrites (those holding the last records the state accounts for) must
    read. A kill while HDF5 rewrote one can leave it failing its Fletcher-32 checksum: HDF5 writes a partly filled
    chunk whole, in place, and the kill lands between its sectors. The records the saved state accounts for are
    the same bytes in the old and the new version of the chunk (only records after them and the checksum
    differ), so such a chunk is read from its raw bytes and rewritten by :func:`make_consistent`, and the check of
    the last records against the saved state reads it so. A chunk that cannot be read so (compressed, or of the
    wrong size) refuses the resume in one line -> {field: {chunk offset: chunk array}}."""
    torn = {}
    for f in cfg.output.record:
        ds = g[f]
        if not ds.chunks:
            continue
        tc, rc = ds.chunks[:2]
        M = ds.shape[0]
        for r0 in range(max(0, (length - 1) // rc * rc), length, rc):
            for t0 in range(0, M, tc):
                try:
                    ds[t0:min(t0 + tc, M), r0:min(r0 + rc, length)]
                except OSError:
                    chunk = _raw_chunk(ds, _offset(ds, t0, r0))
                    if chunk is None:
                        raise damaged(f"collisions/{f}", "a chunk of the last saved records fails its checksum (the "
                                                         "process was killed while HDF5 rewrote it: run the config "
                                                         "again)") from None
                    torn.setdefault(f, {})[_offset(ds, t0, r0)] = chunk
    return torn


def _offset(ds, t0, r0):
    """The offset of the chunk of ``ds`` that starts at trajectory t0, record r0 (HDF5's key of a chunk)."""
    return (t0, r0) + (0,) * (ds.ndim - 2)


def _raw_chunk(ds, offset):
    """The chunk at ``offset`` decoded from its raw bytes without its checksum, or None where that cannot be done:
    a pipeline other than Fletcher-32 alone (a compressed chunk's bytes are not its values), or a size other than
    the chunk's values and the 4 bytes of the checksum."""
    if ds.compression is not None or ds.shuffle or not ds.fletcher32:
        return None
    try:
        mask, raw = ds.id.read_direct_chunk(offset)
    except (OSError, ValueError, KeyError):
        return None
    nbytes = int(np.prod(ds.chunks)) * ds.dtype.itemsize
    if mask != 0 or len(raw) != nbytes + 4:
        return None
    return np.frombuffer(raw[:nbytes], dtype=ds.dtype).reshape(ds.chunks).copy()


def _column(ds, column, torn):
    """Record ``column`` of every trajectory, the chunks in ``torn`` taken from there."""
    out = np.empty((ds.shape[0],) + ds.shape[2:], ds.dtype)
    tc, rc = (ds.chunks or ds.shape)[:2]
    r0 = column // rc * rc
    for t0 in range(0, ds.shape[0], tc):
        t1 = min(t0 + tc, ds.shape[0])
        chunk = torn.get(_offset(ds, t0, r0))
        out[t0:t1] = chunk[:t1 - t0, column - r0] if chunk is not None else ds[t0:t1, column]
    return out


def _rewrite_torn(g, torn):
    """Write the chunks :func:`_torn_chunks` read back, each with a checksum of its values: HDF5 makes the checksum
    (the chunk written to a dataset of the same shape and filter in a file in memory, whose raw chunk is then
    copied), so the chunk reads and keeps being checked like every other."""
    for f, chunks in torn.items():
        ds = g[f]
        with h5py.File("torn-chunk", "w", driver="core", backing_store=False) as mem:
            scratch = mem.create_dataset("x", shape=ds.chunks, dtype=ds.dtype, chunks=ds.chunks, fletcher32=True)
            for offset, chunk in chunks.items():
                scratch[...] = chunk
                mask, raw = scratch.id.read_direct_chunk((0,) * ds.ndim)
                ds.id.write_direct_chunk(offset, raw, filter_mask=mask)


def _check_last_records(g, cfg, state, expected, damaged, torn):
    """The last record of each running trajectory must be its saved state when it stopped on a recorded
    collision: records and state from different blocks (a hard kill) would otherwise continue silently from the
    wrong point. (Ended trajectories do not continue, so they need no check.)"""
    alive = state["alive"].astype(bool)
    rows = np.nonzero(alive & (state["collisions"] % cfg.output.every == 0))[0]
    if rows.size == 0:
        return
    column = int(expected[rows[0]]) - 1          # the running trajectories share it
    saved_as = {"wall": "last_wall", "rank": "last_rank"}
    for f in cfg.output.record:
        last = _column(g[f], column, torn.get(f, {}))[rows]
        saved = np.asarray(state[saved_as.get(f, f)])[rows].reshape(last.shape).astype(last.dtype)
        if not np.array_equal(last, saved):
            raise damaged(f"collisions/{f}", "the last records are not the saved state (the process was killed "
                                             "while writing)")


def make_consistent(h5, sim, write_initial):
    """Bring the records of a writable copy in line with the state :func:`load` read: cut records past it (or,
    with ``write_initial``, all of them) and set ``count``."""
    g = h5["collisions"]
    runfile.note_resume(h5, 0 if write_initial else int(sim.ncoll.max(initial=0)))
    if write_initial:
        _reset(h5, g, sim.cfg)
    else:
        _rewrite_torn(g, sim.torn_chunks)
        _cut_back(g, sim.cfg, sim.ncoll)
        # keep only the state slot it continues from: a slot a kill left unverified must be the next one written,
        # never the one this run's records now rest on
        _, used, _ = latest_state(h5)
        for name in STATE_GROUPS:
            if name != used and name in h5:
                del h5[name]
        if used is not None and used != "final":
            h5.move(used, "final")


def _cut_back(g, cfg, collisions):
    """Drop records past the saved state; set ``count`` to what the state accounts for."""
    if not cfg.output.record:
        g["count"][...] = 0
        return
    expected = 1 + collisions // cfg.output.every
    length = int(expected.max())
    for f in cfg.output.record:
        g[f].resize(length, axis=1)
    g["step"].resize(length, axis=0)
    g["count"][...] = expected


def _reset(h5, g, cfg):
    """A run stopped before its first checkpoint: empty the record datasets, to be written from record 0."""
    for f in cfg.output.record:
        g[f].resize(0, axis=1)
    g["step"].resize(0, axis=0)
    g["count"][...] = 0
    for name in STATE_GROUPS:
        if name in h5:
            del h5[name]


def version_note(run):
    """A warning if the file was written by another rbx version (its records may then differ in the last bits)."""
    written = run.attrs.get("rbx_version")
    if written != __version__:
        return f"written by rbx {written}, continued with rbx {__version__}"
    return None
