"""The run file's schema (docs/reference.md §5): what rbx writes inside an HDF5 file, and its writer.

Writing: the root attributes (:data:`ROOT_ATTRS`, one list for run files and return-angle files), the
``collisions/`` datasets made from :data:`rbx.model.FIELDS` (each with its ``units`` and ``description`` as dataset
attributes, compressed as ``output.compression`` says: :func:`compression_options`), the streaming writer
:class:`H5Sink` (with the room each block needs reserved first), the checkpoint digest (:func:`state_digest`), the
file opened through its write-ahead journal (:mod:`rbx.journal`: :func:`open_journaled`, :func:`commit`,
:func:`close_journal`) and the ``returns/`` group of ``rbx histogram`` (:func:`fill_returns`). Which file is written
and under which name (``OUT.h5.partial.new`` → ``OUT.h5.partial`` → ``OUT.h5``, the run lock, the resume) is
:mod:`rbx.driver`'s; reading a file back, :mod:`rbx.reader`'s (:class:`rbx.reader.Run`).

Layout (T trajectories, N records; trajectory axis first):

| path | shape (2D / 3D) | dtype | meaning |
|---|---|---|---|
| ``/`` attrs | | | :data:`ROOT_ATTRS`: ``rbx_version``, ``dimension``, ``config`` (resolved YAML), ``complete``, ``schema_version``, ``table_kind``, ``wall_names``, ``radius``, ``kappa``, ``collisions_requested``; and :data:`PROVENANCE_ATTRS`: ``created``, ``numba_version``, ``numpy_version``, ``h5py_version``, ``hdf5_version``, ``python_version``, ``command``, ``host``, ``resumed`` |
| ``collisions/time`` | (T, N) | f8 | time of the record |
| ``collisions/position``, ``velocity`` | (T, N, n) | f8 | centre and its velocity |
| ``collisions/angular_velocity`` | (T, N) / (T, N, 3) | f8 | space-frame ω |
| ``collisions/orientation`` | (T, N) / (T, N, 3, 3) | f8 | continuous angle θ / rotation matrix A |
| ``collisions/wall``, ``rank`` | (T, N) | i4 | wall index hit (−1 for record 0), roughness rank used |
| ``collisions/count`` | (T,) | i8 | records written for each trajectory (rows past it are NaN / −1) |
| ``collisions/step`` | (N,) | i8 | collision number of each record (0, every, 2·every, …) |
| ``collisions/trajectory``, ``record``, ``axis``, ``axis2`` | (T,), (N,), (n,), (3,) | i8 / text | HDF5 dimension scales (:data:`SCALES`) naming the datasets' axes for netCDF readers (xarray with h5netcdf); files written before them have none, and nothing here reads them |
| ``final/*`` | (T, …) | | the last state of every trajectory, its ``collisions`` and ``draws`` counts and ``alive`` flag (for ``--resume``); attributes ``sequence`` and ``digest`` (hash of the state, see :func:`state_digest`) |
| ``final_previous/*`` | (T, …) | | the state one block earlier: each checkpoint writes over the older of the two (digest last), so a process killed at any instant leaves one verified state (:func:`latest_state` takes the newest that verifies); the newest is named ``final`` when the run stops, and a complete run keeps ``final`` alone |
| ``returns/angle`` | (K,) | f8 | ``rbx histogram`` files only (no ``collisions/``): return angles φ; see :func:`write_returns` |

The ``config`` attribute names the file written as ``output.path``. Only the fields in ``output.record`` are
present. Every ``collisions/`` dataset carries the attributes ``units``
and ``description`` (from :data:`rbx.model.FIELDS`). Datasets grow along the record axis in chunks, so memory does
not grow with the run's length; ``count`` is rewritten with every block, and ``final/`` is saved and the file
flushed and committed once a second (:data:`rbx.simulation.CHECKPOINT_SECONDS`) and when the run stops,
so an interrupted run leaves a readable file with ``complete = False``.
"""
import contextlib
import datetime
import errno
import hashlib
import json
import os
import platform
import shlex
import shutil
import socket
import sys
from importlib import metadata

import h5py
import numpy as np
import yaml

from . import __version__
from . import journal
from .model import FIELD
from .paths import DiskFull, FileError, format_size, stored_text

SCHEMA_VERSION = 1
CHUNK_BYTES = 1 << 18

#: the root attributes of every rbx file (run or return angles) -> meaning. The first four are the ones
#: docs/reference.md §5 lists first; a file without them is not an rbx file. ``schema_version`` is read as 1 when
#: absent.
ROOT_ATTRS = {
    "rbx_version": "version of rbx that wrote the file",
    "dimension": "n: 2 (disc in a planar table) or 3 (ball)",
    "config": "the fully resolved experiment (tables and boundaries inlined, paths absolute) as YAML text",
    "complete": "False while the run is written and when it was interrupted",
    "schema_version": f"version of this layout ({SCHEMA_VERSION})",
    "table_kind": "the table kind (a record of the registry rbx.tables)",
    "wall_names": "the table's walls, in wall order (the index in collisions/wall)",
    "radius": "ball radius R [L]",
    "kappa": "κ = 2λ/R² of the ball's mass distribution",
    "collisions_requested": "run.collisions: the length the run was asked for",
}
REQUIRED_ATTRS = ("rbx_version", "dimension", "config", "complete")
#: where a file comes from: root attributes written with :data:`ROOT_ATTRS` -> meaning (:func:`provenance`). Not
#: required when reading (files written before them lack them); a resumed run keeps those of its first start and
#: adds a line to ``resumed`` (:func:`note_resume`).
PROVENANCE_ATTRS = {
    "created": "when the file was created (UTC, ISO 8601)",
    "numba_version": "version of Numba that compiled the kernels",
    "numpy_version": "version of NumPy", "h5py_version": "version of h5py",
    "hdf5_version": "version of the HDF5 library h5py wrote the file with",
    "python_version": "version of Python",
    "command": "the command line of the process that wrote the file (sys.argv, shell-quoted)",
    "host": "name of the machine that wrote the file",
    "resumed": "one line per resume of the run: when, where, from which collision, the command and the versions "
               "(empty if never resumed)",
}
#: the datasets of collisions/ besides the record fields -> (units, description)
INDEX_DATASETS = {"count": ("1", "records written for each trajectory (rows past it are NaN / −1)"),
                  "step": ("1", "collision number of each record (0, every, 2·every, …)")}
#: the dimension scales of collisions/ (HDF5 dimension scales: netCDF readers such as
#: ``xarray.open_dataset(path, engine="h5netcdf", group="collisions")`` name the datasets' dimensions by them)
#: -> (units, description). ``axis`` only when a field has a vector part, ``axis2`` for the 3D orientation matrix.
SCALES = {"trajectory": ("1", "trajectory index"),
          "record": ("1", "record index (record i is the state after collision step[i])"),
          "axis": ("1", "space axis (x, y[, z]): row of the 3D orientation matrix (space frame)"),
          "axis2": ("1", "column of the 3D orientation matrix (body frame axis)")}
#: the NAME of a dimension scale that holds no values: netCDF-4's "dimension without a variable" (its readers
#: number such a dimension 0, 1, …). The ``record`` scale is one: its values 0 … N−1 took 8 bytes per record, a
#: third of a file recording ``time`` alone
DIMENSION_ONLY = "This is a netCDF dimension but not a netCDF variable."


#: room kept free on the disk beyond a block's records, its new chunks and the state, for HDF5's metadata
DISK_MARGIN = 256 << 10


# ---- writing ---------------------------------------------------------------------------------------------------

def config_yaml(cfg, path=None):
    """The experiment's resolved config as the YAML text stored in the root attribute ``config``; ``path``: the
    file actually written (``-o``, ``output=``), stored as ``output.path`` in place of the config's own."""
    resolved = cfg.resolved
    if path is not None:
        resolved = dict(resolved, output=dict(resolved.get("output") or {}, path=os.path.abspath(os.fspath(path))))
    return yaml.dump(_plain(resolved), Dumper=_DUMPER, sort_keys=False)


#: libyaml's emitter when there is one: the same text as yaml.safe_dump, in a third of the time (a config of
#: 10 000 explicit states: 0.9 s -> 0.3 s)
_DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)
_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def _plain(x):
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, str):
        return stored_text(x)
    return x


def root_attrs(cfg, complete, path=None):
    """The values of :data:`ROOT_ATTRS` for an experiment -> dict (written to files, held by in-memory runs);
    ``path``: the file written (see :func:`config_yaml`)."""
    values = {"rbx_version": __version__, "dimension": cfg.dimension, "config": config_yaml(cfg, path),
              "complete": bool(complete), "schema_version": SCHEMA_VERSION, "table_kind": cfg.table_kind,
              "wall_names": list(cfg.wall_names), "radius": cfg.ball.radius, "kappa": cfg.ball.kappa,
              "collisions_requested": cfg.run.collisions}
    assert tuple(values) == tuple(ROOT_ATTRS)
    return values


def orbit_digests(config):
    """What makes a run's orbit, key by key -> JSON text {key: digest}: every section of ``config`` (the stored
    config, as read from the file's ``config`` attribute: the same text gives the same digests) but ``output``
    (where and what is recorded) and ``run.collisions`` (how far). A checkpoint stores it with the state (the
    ``orbit`` attribute of ``final/``); a resume compares it with its stored config's, so that a config changed
    in the file since (``run.seed`` edited) is refused rather than continued with records of two orbits
    (:func:`rbx.continuation.load`)."""
    parts = {}
    for key, value in (config if isinstance(config, dict) else {}).items():
        if key == "output":
            continue
        if key == "run" and isinstance(value, dict):
            parts.update({f"run.{k}": v for k, v in value.items() if k != "collisions"})
        else:
            parts[key] = value
    return json.dumps({k: hashlib.blake2b(json.dumps(_plain(v), sort_keys=True, default=repr).encode(),
                                          digest_size=8).hexdigest() for k, v in parts.items()}, sort_keys=True)


def is_true(value):
    """A file's ``complete`` attribute -> bool; None when it is not a boolean (text such as 'false', an array: a
    crafted or changed file, which must not be taken as complete because a non-empty text is true)."""
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)) and value in (0, 1):
        return bool(value)
    return None


def provenance():
    """The values of :data:`PROVENANCE_ATTRS` for this process, now -> dict."""

    values = {"created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
              "numba_version": _version("numba"), "numpy_version": np.__version__, "h5py_version": h5py.__version__,
              "hdf5_version": h5py.version.hdf5_version, "python_version": platform.python_version(),
              "command": shlex.join(map(stored_text, sys.argv)), "host": socket.gethostname(), "resumed": ""}
    assert tuple(values) == tuple(PROVENANCE_ATTRS)
    return values


def note_resume(h5, collisions):
    """Add a line to the ``resumed`` attribute of a file a run continues (from ``collisions``): the records after
    it were computed then, there, by that software, which the provenance of the first start does not say."""
    p = provenance()
    line = (f"{p['created']} on {p['host']}, from collision {collisions}: {p['command']} (rbx {__version__}, "
            f"numba {p['numba_version']}, numpy {p['numpy_version']}, h5py {p['h5py_version']}, "
            f"HDF5 {p['hdf5_version']}, Python {p['python_version']})")
    before = _text(h5.attrs["resumed"]) if "resumed" in h5.attrs else ""
    h5.attrs["resumed"] = f"{before}\n{line}" if before else line


def _version(package):
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return "not installed"


def write_root_attrs(h5, cfg, complete, path=None):
    """Write :data:`ROOT_ATTRS` (``path``: the file written, see :func:`config_yaml`) and
    :data:`PROVENANCE_ATTRS`."""
    for k, v in root_attrs(cfg, complete, path).items():
        h5.attrs[k] = np.array(v, dtype=h5py.string_dtype()) if k == "wall_names" else v
    h5.attrs.update(provenance())


def compression_options(compression):
    """``output.compression`` (``none``, ``lzf``, ``gzip:LEVEL``) -> keyword arguments of h5py's
    ``create_dataset``. Compressed datasets are byte-shuffled first (the bytes of a float by significance:
    the exponents and high bytes of neighbouring records compress, the low bytes do not)."""
    name, _, level = compression.partition(":")
    if name == "none":
        return {}
    if name == "gzip":
        return {"compression": "gzip", "compression_opts": int(level or 4), "shuffle": True}
    return {"compression": name, "shuffle": True}


def chunk_shape(M, records, per):
    """The chunks of a record dataset of ``M`` trajectories × ``records`` records of ``per`` bytes each ->
    (trajectories, records) per chunk: ~:data:`CHUNK_BYTES`, never longer along the records than the run, so a
    short run's chunks span more trajectories instead (64 × 256 records allocated per trajectory made 20 000
    trajectories × 3 collisions a 577 MB file for 5.3 MB of records)."""
    rchunk = min(records, max(1, CHUNK_BYTES // (min(M, 64) * per)))
    tchunk = min(M, max(1, CHUNK_BYTES // (rchunk * per)))
    return tchunk, rchunk


#: the chunk length of ``collisions/step`` (and of the ``record`` scale)
STEP_CHUNK = 4096


def data_bytes(cfg):
    """Bytes the chunks of a run's file take once it is complete (every chunk allocated whole, with its checksum),
    its ``count`` and its two saved states: the file but for HDF5's metadata and the attributes -> int."""
    M, n = cfg.run.trajectories, cfg.dimension
    records = cfg.run.collisions // cfg.output.every + 1
    total = 0
    for name in cfg.output.record:
        f = FIELD[name]
        per = f.size(n) * np.dtype(f.dtype).itemsize
        tc, rc = chunk_shape(M, records, per)
        total += -(-M // tc) * -(-records // rc) * (tc * rc * per + 4)
    if cfg.output.record:
        total += -(-records // STEP_CHUNK) * (STEP_CHUNK * 8 + 4)       # collisions/step
    return total + M * 8 * 2 + 2 * state_bytes(M, n)                      # count, the trajectory scale


def state_bytes(M, n):
    """Bytes of one saved state of ``M`` trajectories in dimension ``n`` (``final/``), generously."""
    return M * (4 * n + n * n + 9 + 8) * 8


class H5Sink:
    """Streams the records of a :class:`rbx.simulation.Simulation` into an open HDF5 file (``fresh``: a new file,
    whose attributes and datasets are created here; else a file being resumed). ``path``: the file the run
    is written to in the end (stored as ``output.path`` in the config attribute)."""

    def __init__(self, h5, cfg, fresh=True, path=None):
        self.h5 = h5
        M, n = cfg.run.trajectories, cfg.dimension
        self.every = cfg.output.every
        records = cfg.run.collisions // cfg.output.every + 1       # the most records a trajectory can have
        if fresh:
            write_root_attrs(h5, cfg, complete=False, path=path)
            g = h5.create_group("collisions")
            filters = compression_options(cfg.output.compression)
            for name in cfg.output.record:
                f = FIELD[name]
                tail = f.shape(n)
                tchunk, rchunk = chunk_shape(M, records, f.size(n) * np.dtype(f.dtype).itemsize)
                # fletcher32: a checksum per chunk, checked on every read, so that changed bytes on disk are an
                # error rather than silently different numbers
                ds = g.create_dataset(name, shape=(M, 0) + tail, maxshape=(M, None) + tail, dtype=f.dtype,
                                      chunks=(tchunk, rchunk) + tail, fillvalue=f.fill, fletcher32=True, **filters)
                ds.attrs["units"], ds.attrs["description"] = f.units, f.description
            g.create_dataset("count", data=np.zeros(M, np.int64))
            g.create_dataset("step", shape=(0,), maxshape=(None,), dtype=np.int64, chunks=(STEP_CHUNK,))
            for name, (units, text) in INDEX_DATASETS.items():
                g[name].attrs["units"], g[name].attrs["description"] = units, text
            _make_scales(g, M, n)
            h5.flush()    # the skeleton on disk at once: a kill from here on leaves a file that opens
        self.g = h5["collisions"]
        #: datasets a write can add a chunk of CHUNK_BYTES to (the scales' are small, or never grow)
        self.chunked = sum(1 for name in self.g if name not in SCALES)
        self._growing = None     # the growing datasets' chunks (:meth:`_block_room`), read once
        if not fresh:
            _extend_record_scale(self.g)      # resume cut the records back (or emptied them)
        #: bytes of one saved state (a checkpoint writes one, over the older of the two slots or as a new one)
        self.state_bytes = state_bytes(M, n)
        self.orbit = None        # the stored config's orbit_digests, made at the first checkpoint
        #: records in the file at its last commit: a chunk holding one of them lies below the commit, and a block
        #: that adds records to it goes through the journal (rbx.journal); chunks made since are written in place
        self._committed_records = 0 if fresh else int(self.g["step"].shape[0])
        #: bytes of new chunks the blocks since the last commit may have put in room freed inside the file (a
        #: resume cuts records back): written through the journal, not past the file's end (:meth:`_inside`)
        self._inside_due = 0
        self._slot = self._count_pages = None      # read once: :meth:`_next_slot`, :meth:`_count_bytes`
        #: room was reserved in the file beyond HDF5's end (:meth:`_reserve`): :func:`trim` the file once closed
        self.reserved = False
        #: the last check found no room: nothing more is written (not even the final renames, see :meth:`settle`)
        self.full = False

    def write(self, block, nrec):
        g = self.g
        b = next(iter(block.values())).shape[1]
        start = g["step"].shape[0]
        new = self._block_room(start, b)[0]
        inside = self._inside(new)
        due = self._journal_due(start + b) + self._inside_due + inside
        free = self._free()
        if b > 1 and not self._fits(new - inside, due, self._next_slot()[1], free):
            # its records would go into chunks committed before (the first block of a resume adds the rest of the
            # run to them), and the journal of that is more than the disk has room for: in halves, each committed
            # before the next, so that one journal at a time takes room. A commit without a checkpoint leaves
            # records past the saved state, which a resume cuts back, as after a kill between a block and its
            # checkpoint
            h = b // 2
            self.write({f: a[:, :h] for f, a in block.items()}, np.minimum(nrec, h))
            self.h5.flush()
            commit(self.h5)
            self._committed_records, self._inside_due = int(g["step"].shape[0]), 0
            self.write({f: a[:, h:] for f, a in block.items()}, np.maximum(np.asarray(nrec) - h, 0))
            return
        self._check_space(new - inside, due, self._next_slot()[1], free)
        self._inside_due += inside
        for f, arr in block.items():
            ds = g[f]
            ds.resize(start + b, axis=1)
            ds[:, start:start + b] = arr
        g["step"].resize(start + b, axis=0)
        g["step"][start:] = np.arange(start, start + b) * self.every
        _extend_record_scale(g)
        g["count"][...] = g["count"][...] + nrec

    def _journal_due(self, end):
        """Bytes the next commit's journal holds once the records up to ``end`` are written, about: the pages of
        the committed chunks that the records since the last commit change (each page once, however many blocks
        change it: summed per block, a checkpoint of several small blocks asked for the whole file) and ``count``'s
        pages."""
        since = self._committed_records
        return (self._block_room(since, end - since)[1] if end > since else 0) + self._count_bytes()

    def _inside(self, new):
        """Of ``new`` bytes of new chunks, those HDF5 may put in room freed inside the file (the records a resume
        cut back): written below the last commit, so through the journal, and not past the file's end. A resume
        of a run interrupted at its first checkpoint reserved 1.2 MB past the end for chunks that went inside, and
        found no room for their journal."""
        if not new:
            return 0
        try:
            return min(new, int(self.h5.id.get_freespace()))
        except Exception:    # noqa: BLE001 - another file driver: none known
            return 0

    def _count_bytes(self):
        """Bytes of ``count`` (rewritten with each block, in place) in whole pages."""
        if self._count_pages is None:
            self._count_pages = (-(-self.g["count"].nbytes // journal.PAGE) + 1) * journal.PAGE
        return self._count_pages

    def _block_room(self, start, b):
        """What writing records ``start`` … ``start + b − 1`` adds -> (bytes of new chunks, bytes journalled).

        A chunk none of whose records is written yet is new: HDF5 allocates it whole (checksum included) past the
        file's end, written in place, never journalled. A chunk holding records written before the last commit is
        rewritten whole by HDF5, in place, through the journal, which keeps only the pages that changed
        (:func:`rbx.journal._changed`): per trajectory row of the chunk, the pages the block's records in it
        span (and one for the checksum). So a block asks for its records (× the chunk rounding), not for two
        whole chunks per dataset doubled (3.4 MB for a run of 10 collisions; a 10 000-collision run on a 3 MB
        disk never finished)."""
        if self._growing is None:      # (chunk bytes, chunk length along the records, chunks across,
            self._growing = []         #  rows per chunk, bytes of one record of one row) per dataset
            for name in self.g:
                ds = self.g[name]
                if not ds.chunks or ds.maxshape[0 if ds.ndim == 1 else 1] is not None:
                    continue      # a dataset that never grows (count, the fixed scales)
                if name == "record" and DIMENSION_ONLY in _text(ds.attrs.get("NAME", b"")):
                    continue      # a scale without values: nothing is written
                one_d = ds.ndim == 1
                across = 1 if one_d else -(-ds.shape[0] // ds.chunks[0])
                rows = 1 if one_d else ds.chunks[0]
                per_record = ds.dtype.itemsize * int(np.prod(ds.chunks[1 if one_d else 2:]))
                self._growing.append((int(np.prod(ds.chunks)) * ds.dtype.itemsize + 4,
                                      ds.chunks[0 if one_d else 1], across, rows, per_record))
        page = journal.PAGE
        new = rewritten = 0
        for per, rc, across, rows, per_record in self._growing:
            first_new, end = -(-start // rc), -(-(start + b) // rc)
            new += max(0, end - first_new) * across * per
            if start % rc and start // rc * rc < self._committed_records:
                k = min(b, rc - start % rc)              # the block's records in the committed chunk
                pages = min(-(-per // page) + 1, rows * (-(-(k * per_record) // page) + 1) + 1)
                rewritten += across * pages * page
        return new, rewritten

    def _next_slot(self):
        """The group the next checkpoint writes its state into -> (name, whether it exists: rewritten in place);
        read from the file once per checkpoint (reading the groups' attributes for each block cost ~0.8 ms)."""
        if self._slot is None:
            slots = {name: _slot_sequence(self.h5, name) for name in STATE_GROUPS}
            newest = max(slots, key=slots.get) if max(slots.values()) >= 0 else None
            target = next(name for name in ("final_previous", "final", "final_swap") if name != newest)
            self._slot = target, target in self.h5
        return self._slot

    def _free(self):
        """Bytes free on the file's disk -> int, or None if the system does not say."""
        try:
            return shutil.disk_usage(os.path.dirname(os.path.abspath(file_path(self.h5))) or ".").free
        except OSError:
            return None

    def _fits(self, new_bytes, journal_bytes, in_place, free):
        """Whether :meth:`_check_space` would find room for these writes with ``free`` bytes free (it says
        nothing)."""
        if free is None:
            return True
        file_bytes = new_bytes + (0 if in_place else self.state_bytes) + DISK_MARGIN
        journal_bytes = journal_bytes + (self.state_bytes if in_place else 0) + DISK_MARGIN
        return free + self._spare() >= file_bytes + journal_bytes

    def _spare(self):
        """Room reserved in the file by the last block's check and not used by HDF5 yet."""
        jf = journal_of(self.h5)
        with contextlib.suppress(OSError):
            if jf is not None:
                return max(0, os.fstat(jf.fd).st_blocks * 512 - jf.size)
        return 0

    def _check_space(self, new_bytes, journal_bytes, in_place, free=False):
        """Stop with :class:`DiskFull` before a write the disk has no room for: HDF5 meeting ENOSPC mid-write left
        the file half-updated and h5py crashed (a segmentation fault) closing it. The room is what the write
        really takes: ``new_bytes`` of new chunks in the file, the next checkpoint's state (a new slot in the
        file, or rewritten in place through the journal: ``in_place``), the next commit's journal
        (``journal_bytes``, another file) and a margin for HDF5's metadata in each; room the file reserved
        already and did not use counts as free. Checked, the run stops between blocks like an interrupted one:
        the last checkpoint is intact and the file can be resumed once there is space."""
        file_bytes = new_bytes + (0 if in_place else self.state_bytes) + DISK_MARGIN
        journal_bytes = journal_bytes + (self.state_bytes if in_place else 0) + DISK_MARGIN
        if free is False:      # not measured by the caller
            free = self._free()
        spare = self._spare()  # room reserved by the last block's check and not used by HDF5 yet
        if free is not None and free + spare < file_bytes + journal_bytes:
            self.full = True
            raise DiskFull(f"the disk is full: {format_size(free)} free, the next block needs about "
                           f"{format_size(file_bytes + journal_bytes - spare)} (its records "
                           f"{format_size(new_bytes)}, the checkpoint's journal {format_size(journal_bytes)})")
        self._reserve(file_bytes)

    def _reserve(self, need):
        """Allocate the room for the next writes in the file itself, past what HDF5 uses (``posix_fallocate``):
        another program filling the disk after the check above cannot take it, so HDF5's writes do not meet
        ENOSPC (or EFBIG under a file size limit), which HDF5 does not survive (h5py then crashed closing the
        file). HDF5 writes its new chunks and metadata into this room; :func:`trim` gives back what is left."""
        jf = journal_of(self.h5)
        if jf is None:      # another file driver: the check above is all there is
            return
        fd, used = jf.fd, jf.size                   # HDF5's end of file, not counting an earlier reservation
        try:
            try:
                os.posix_fallocate(fd, 0, used + need)
            except OSError as exc:
                if exc.errno not in (errno.EFBIG, errno.ENOSPC, errno.EDQUOT) or need <= DISK_MARGIN:
                    raise
                # the margin for HDF5's metadata does not fit (a file size limit just above the run's file: its
                # last blocks stopped for room they would not use): the room the block writes without it. A write
                # of HDF5's that then meets the limit is the file's failure, and it stays at its last commit
                os.posix_fallocate(fd, 0, used + need - DISK_MARGIN)
        except OSError as exc:
            self.full = exc.errno in (errno.EFBIG, errno.ENOSPC, errno.EDQUOT)
            if exc.errno == errno.EFBIG:
                raise DiskFull(f"the file is not allowed to grow by {format_size(need)} for the next block (a file "
                               f"size limit, ulimit -f?; it holds {format_size(used)})") from None
            if exc.errno in (errno.ENOSPC, errno.EDQUOT):
                raise DiskFull(f"the disk is full (or the quota reached): cannot reserve {format_size(need)} for "
                               "the next block") from None
            # EOPNOTSUPP, EINVAL: the file system cannot reserve room; the check above is all there is
        self.reserved = True

    def checkpoint(self, sim):
        """Save the state that accounts for the records written so far. It is written over the older of the two
        saved states (``final``, ``final_previous``), its digest last, so a process killed at any point leaves at
        least one state that verifies (see :func:`latest_state`, which takes the newest that does). The groups
        are not renamed here: a rename rewrites the root group's link storage, HDF5 metadata that a kill while it
        is written can leave unreadable (docs/reliability.md); :meth:`settle` names the newest ``final`` once, at
        the end."""
        # flush first: the block's records reach the file before the state that accounts for them
        self.h5.flush()
        slots = {name: _slot_sequence(self.h5, name) for name in STATE_GROUPS}
        sequence = max(slots.values()) + 1
        newest = max(slots, key=slots.get) if max(slots.values()) >= 0 else None
        target = next(name for name in ("final_previous", "final", "final_swap") if name != newest)
        self._slot = None             # the next checkpoint writes the other slot
        self._check_space(0, self._journal_due(int(self.g["step"].shape[0])) + self._inside_due, target in self.h5)
        fin = self.h5.require_group(target)
        state = sim.final_state()
        for k, v in state.items():
            v = np.asarray(v)
            ds = fin.get(k)               # one lookup: group access is most of a checkpoint's Python time
            if ds is not None and ds.shape == v.shape and ds.dtype == v.dtype:
                ds[...] = v
            else:
                if ds is not None:
                    del fin[k]
                fin.create_dataset(k, data=v)
        fin.attrs["sequence"] = sequence
        if self.orbit is None:   # the config as stored (a resume into -o stores it again before running)
            self.orbit = orbit_digests(yaml.load(_text(self.h5.attrs["config"]), Loader=_LOADER))
        fin.attrs["orbit"] = self.orbit
        fin.attrs["digest"] = state_digest(state)     # last: until it is written the group does not verify
        self.h5.flush()
        commit(self.h5)      # the file changes here, all at once: a kill before leaves the last checkpoint's
        self._committed_records, self._inside_due = int(self.g["step"].shape[0]), 0

    def settle(self, complete=False):
        """Name the newest saved state ``final`` (and the other ``final_previous``), once the run stops writing
        blocks: readers of ``final/`` then find the newest state there. A ``complete`` run keeps ``final`` alone:
        whether ``final_previous`` was there depended on how many checkpoints the run took (time, the machine, a
        cluster's rounds), so two runs of one config differed in layout; an unfinished one keeps both, for a
        resume."""
        if self.full:     # no room was reserved: leave HDF5's metadata alone (the readers find the newest anyway)
            return
        slots = {name: _slot_sequence(self.h5, name) for name in STATE_GROUPS}
        if max(slots.values()) < 0:
            return
        if slots["final"] != max(slots.values()):
            newest = max(slots, key=slots.get)
            if "final" in self.h5:
                self.h5.move("final", "final_swap" if newest != "final_swap" else "final_old")
            self.h5.move(newest, "final")
            for name in ("final_swap", "final_old"):
                if name in self.h5 and "final_previous" not in self.h5:
                    self.h5.move(name, "final_previous")
        if complete:
            for name in STATE_GROUPS + ("final_old",):
                if name != "final" and name in self.h5:
                    del self.h5[name]
        self.h5.flush()


def _make_scales(g, M, n):
    """The dimension scales :data:`SCALES` of ``collisions/``, attached to every dataset's axes (``trajectory``
    first, ``record`` second, then ``axis`` and ``axis2`` for a field's vector or matrix part)."""
    tails = {len(g[name].shape) - 2 for name in g if name in FIELD}
    made = {"trajectory": g.create_dataset("trajectory", data=np.arange(M, dtype=np.int64)),
            "record": g.create_dataset("record", shape=(0,), maxshape=(None,), dtype=np.float32, chunks=(4096,))}
    names = np.array(["x", "y", "z"][:n], dtype=h5py.string_dtype())
    if tails & {1, 2}:
        made["axis"] = g.create_dataset("axis", data=names)
    if 2 in tails:
        made["axis2"] = g.create_dataset("axis2", data=names)
    for name, ds in made.items():
        ds.make_scale(f"{DIMENSION_ONLY}{0:10}" if name == "record" else name)   # record: no values written
        ds.attrs["units"], ds.attrs["description"] = SCALES[name]
    for name in g:
        if name in made:
            continue
        ds = g[name]
        dims = ("trajectory",) if name == "count" else ("record",) if name == "step" else \
            ("trajectory", "record", "axis", "axis2")[:ds.ndim]
        for i, dim in enumerate(dims):
            ds.dims[i].attach_scale(made[dim])


def _extend_record_scale(g):
    """The ``record`` scale as long as ``step`` (files written before the scales have none). Its values are written
    only in files written before it became a dimension without values (:data:`DIMENSION_ONLY`)."""
    if "record" not in g:
        return
    scale, length = g["record"], g["step"].shape[0]
    old = scale.shape[0]
    if old != length:
        scale.resize(length, axis=0)
        if length > old and DIMENSION_ONLY not in _text(scale.attrs.get("NAME", b"")):
            scale[old:] = np.arange(old, length)


#: the groups that may hold a saved state: ``final`` (the newest), ``final_previous`` (the one before), and
#: ``final_swap`` (only while their names are swapped); :func:`latest_state` takes the newest that verifies
STATE_GROUPS = ("final", "final_previous", "final_swap")


def _slot_sequence(h5, name):
    try:
        return int(h5[name].attrs.get("sequence", 0)) if name in h5 else -1
    except Exception:   # noqa: BLE001 - a slot damaged by a kill: the one to overwrite
        return -1


def latest_state(h5):
    """The run's saved state -> (dict of arrays, group name, verified): the newest group of :data:`STATE_GROUPS`
    whose digest matches its arrays; if none does, the newest readable one with ``verified`` False; ({}, None,
    True) when nothing was saved yet. A slot without a digest (older files) counts as verified."""
    found = []
    for name in STATE_GROUPS:
        try:
            g = h5[name] if name in h5 else None
            if g is None:
                continue
            state = {k: g[k][...] for k in g}
            digest = g.attrs.get("digest")
            ok = digest is None or digest == state_digest(state)
            found.append((ok, int(g.attrs.get("sequence", 0)), name, state))
        except Exception:   # noqa: BLE001 - unreadable after a kill: not a candidate
            continue
    if not found:
        return {}, None, True
    found.sort(key=lambda x: (x[0], x[1]), reverse=True)
    ok, _, name, state = found[0]
    return state, name, ok


def state_digest(state):
    """A hash of a final state (dict of arrays). A process killed outright (SIGKILL, power loss) can leave
    ``final/`` half rewritten; ``--resume`` recomputes this hash and refuses such a state instead of continuing
    from a mixture of two blocks."""
    h = hashlib.blake2b(digest_size=16)
    for k in sorted(state):
        a = np.ascontiguousarray(state[k])
        h.update(f"{k}:{a.dtype.str}:{a.shape}:".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def open_journaled(path, create=False):
    """Open a run's file for writing through its journal (:mod:`rbx.journal`) -> ``h5py.File`` (``create``: a new
    file, exclusively; else an existing one, its pending journal applied first). Commit with :func:`commit`;
    :func:`close_journal` after closing the ``h5py.File``. OSError if it cannot; :class:`FileError` if its journal
    cannot be applied."""
    try:
        jf = journal.JournaledFile(path, create=create)
    except journal.JournalError as exc:
        raise FileError(journal.journal_path(path), None, str(exc)) from None
    try:
        h5 = h5py.File(jf, "w" if create else "r+")
    except BaseException:
        jf.close(commit=False)
        raise
    h5._rbx_journal = jf
    return h5


def journal_of(h5):
    """The :class:`rbx.journal.JournaledFile` an ``h5py.File`` writes through, or None."""
    return getattr(h5, "_rbx_journal", None)


def file_path(h5):
    """The path of an open run file (h5py names a file-object file by the object's ``repr``: the path)."""
    jf = journal_of(h5)
    return jf.path if jf is not None else h5.filename


def commit(h5):
    """Make what HDF5 wrote so far (flush it first) the file on disk, at once (:meth:`JournaledFile.commit`)."""
    jf = journal_of(h5)
    if jf is not None:
        jf.commit()


def close_journal(h5, commit=True):
    """After the ``h5py.File`` is closed: the last commit (unless ``commit`` is False), and the file closed -> None,
    or the OSError that kept it from committing (a write or read that failed, or the commit itself): the file is
    then left at its last commit, still whole."""
    jf = journal_of(h5)
    if jf is None:
        return None
    try:
        jf.close(commit=commit)
    except OSError as exc:
        jf.close(commit=False)
        failure = exc
    else:
        failure = jf.failure          # a failure keeps close from committing
    if failure is not None and journal.pending(jf.path):
        # committed but not applied (the error came while copying it in): try once more, else the journal stays
        with contextlib.suppress(Exception):
            journal.recover(jf.path)
    return failure


def _text(x):
    return x.decode("utf-8", "replace") if isinstance(x, bytes) else str(x)


# ---- returns/ (rbx histogram) -----------------------------------------------------------------------------------

#: attributes of returns/ -> meaning
RETURNS_ATTRS = {
    "wall": "the wall sampled and returned to ('': the whole boundary, next collision)",
    "samples": "states sampled (M)", "returned": "of them, returned within run.collisions",
    "not_returned": "the others", "velocity_dimension": "d = n + n(n−1)/2",
    "predicted_density": "density of φ the invariance of the billiard measure predicts",
    "predicted_cdf": "its distribution function", "ks_statistic": "Kolmogorov–Smirnov D against it",
    "ks_pvalue": "its p-value (NaN when some sample did not return)", "seconds": "time the experiment took",
}


def fill_returns(h5, cfg, result, path):
    """Write the root attributes and ``returns/`` of a return-angle experiment (:class:`rbx.histogram.Returns`)
    into the new file ``h5`` (``path``: the file it becomes), by the layout :func:`rbx.driver.write_returns`
    documents."""
    names = cfg.wall_names
    write_root_attrs(h5, cfg, complete=True, path=path)
    g = h5.create_group("returns")
    g.create_dataset("angle", data=result.angle)
    g.create_dataset("trajectory", data=np.nonzero(result.returned)[0].astype(np.int64))
    g.create_dataset("collisions", data=result.collisions[result.returned].astype(np.int64))
    g.create_dataset("initial_angle", data=result.initial_angle)
    values = {"wall": "" if result.wall is None else names[result.wall], "samples": result.samples,
              "returned": result.samples - result.not_returned, "not_returned": result.not_returned,
              "velocity_dimension": result.d,
              "predicted_density": f"{result.d - 1}·cos φ·sin^{result.d - 2} φ",
              "predicted_cdf": f"sin^{result.d - 1} φ", "ks_statistic": result.ks_statistic,
              "ks_pvalue": result.ks_pvalue, "seconds": result.seconds}
    assert set(values) == set(RETURNS_ATTRS)
    g.attrs.update(values)
