"""The run file's schema (docs/reference.md §5): what rbx writes inside an HDF5 file and how it reads it back.

Writing: the root attributes (:data:`ROOT_ATTRS`, one list for run files and return-angle files), the
``collisions/`` datasets made from :data:`rbx.model.FIELDS` (each with its ``units`` and ``description`` as dataset
attributes, compressed as ``output.compression`` says: :func:`compression_options`), the streaming writer
:class:`H5Sink` (with the room each block needs reserved first), the checkpoint digest (:func:`state_digest`), the
file opened through its write-ahead journal (:mod:`rbx.journal`: :func:`open_journaled`, :func:`commit`,
:func:`close_journal`) and the ``returns/`` group of ``rbx histogram`` (:func:`fill_returns`). Which file is written
and under which name (``OUT.h5.partial.new`` → ``OUT.h5.partial`` → ``OUT.h5``, the run lock, the resume) is
:mod:`rbx.driver`'s. Reading: one class, :class:`Run`, for ``rbx plot``, ``rbx simulate --resume``, the figure
scripts and the Python API (:func:`rbx.open`), and the same class holds a run made in memory (:func:`rbx.simulate`
without ``output``); every dataset is checked against the layout before it is read (:func:`check_layout`);
:func:`read_returns` reads ``returns/``. A file that is not what the caller needs raises :class:`FileError`
(``<file>: <key>: <problem>``; the CLI prints it as one line and exits 2).

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
from .analysis import scene_title
from .config import loads
from .locks import busy as _busy
from .locks import lock_holder
from .model import FIELD, FIELDS, RECORD_FIELDS, ConfigError
from .paths import DiskFull, FileError, format_size, what_it_is
from .progress import plural
# names that lived here before the locks and the driver had modules of their own, for code that reads them here
from .locks import _process_start, acquire_lock, lock_path, release_held_locks, release_lock  # noqa: F401, E402
from .paths import creation_path, display_path, temporary_path  # noqa: F401, E402

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
    import json
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
              "command": shlex.join(sys.argv), "host": socket.gethostname(), "resumed": ""}
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


# ---- opening a file for reading ----------------------------------------------------------------------------------

def _open_h5(path, mode="r"):
    """Open an existing HDF5 file -> ``h5py.File``, or raise :class:`FileError` saying why not."""
    path = str(path)
    if not os.path.exists(path):
        partial = f"{path}.partial"
        if not path.endswith(".partial") and os.path.isfile(partial):
            # a run stopped or killed before it was renamed to its output (a resume in place renames OUT.h5 to its
            # .partial while it runs): the records are there
            show = display_path(partial)
            raise FileError(path, None, f"file not found, but {show} holds its run, stopped or killed before it was "
                                        f"renamed: read {show}, or continue it with rbx simulate --resume "
                                        f"{display_path(path)}")
        raise FileError(path, None, "file not found")
    if os.path.isdir(path):
        raise FileError(path, None, "is a directory, not an HDF5 file")
    what = what_it_is(os.path.realpath(path))
    if what != "a regular file":       # a FIFO would block the read for ever; a device is no run
        raise FileError(path, None, f"is {what}, not a regular file: not an HDF5 file")
    if journal.pending(path):
        view = _finish_journal(path, mode)
        if view is not None:
            return view
    if journal.torn(path):
        holder = lock_holder(path)
        if holder is not None:      # a live run copying a checkpoint in: its file is locked meanwhile
            raise _busy(path, holder)
        raise FileError(path, None, "is torn: its run was killed while a checkpoint was being copied into it, and "
                                    f"the journal that finishes it ({os.path.basename(journal.journal_path(path))}) "
                                    "is gone; put that journal back beside the file, else run the config again")
    try:
        is_hdf5 = h5py.is_hdf5(path)
    except OSError as exc:
        raise FileError(path, None, f"cannot read: {exc.strerror or exc}") from None
    if not is_hdf5:
        raise FileError(path, None, _not_hdf5(path))
    try:
        return h5py.File(path, mode)
    except OSError as exc:
        holder = lock_holder(path)
        if holder is not None:      # HDF5's own lock on a file another run writes: say whose
            raise _busy(path, holder) from None
        if "unable to lock file" in str(exc):
            raise FileError(path, None, "is open in another program, which holds HDF5's lock on it (a run writing "
                                        "it?); try again when it has closed the file") from None
        if path.endswith(".partial"):
            raise FileError(path, None, f"cannot open the HDF5 file: its structure is damaged ({_first_line(exc)}), "
                                        "most likely by a kill while HDF5 was writing it; its records cannot be "
                                        "recovered: remove it and run the config again") from None
        raise FileError(path, None, f"cannot open the HDF5 file (damaged or locked by another program?): "
                                    f"{_first_line(exc)}") from None


def _not_hdf5(path):
    """What a file that is not HDF5 is, where its text says (a config, a study, a table or a boundary file, by
    their keys: :data:`rbx.config.FILE_KINDS`), and what to do with it -> the problem of a :class:`FileError`."""
    from .config import FILE_KINDS
    try:
        with open(path, "rb") as f:
            data = yaml.safe_load(f.read(1 << 16).decode("utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        data = None
    if isinstance(data, dict):
        keys = {str(k) for k in data}
        for name, marks, todo in FILE_KINDS.values():
            if keys & set(marks):
                return f"is {name} ({', '.join(marks)}), not a run file: {todo.rstrip(':')}"
    return "not an HDF5 file (or unreadable)"


def _finish_journal(path, mode):
    """Apply the pending journal of ``path`` (its run was killed inside a commit, after the commit point) under the
    run's lock, so that no resume writes the file meanwhile: a reader that copied the journal's pages in without it
    wrote an older checkpoint's pages over the file a resume had finished in the meantime -> None, or the file
    opened for reading with its journal applied in memory (:func:`_open_view`) where the lock cannot be taken (a
    live run holds it, a read-only folder) or the file cannot be written."""
    try:
        acquire_lock(path, warn=lambda message: None)    # a killed run's stale lock: taken over without a word
    except (FileError, OSError) as exc:      # a live run holds it, a read-only folder, no room for the lock
        if mode != "r":
            raise
        holder = lock_holder(path)
        try:
            return _open_view(path, shared=True)
        except FileError:
            if holder is not None:      # a live run: it finishes the journal itself, and names itself
                raise _busy(path, holder) from None
            raise exc from None
    try:
        if journal.pending(path):       # looked at again under the lock: a resume may have applied it meanwhile
            journal.recover(path)
    except journal.JournalError as exc:
        raise FileError(journal.journal_path(path), None, str(exc)) from None
    except OSError as exc:
        if mode == "r":       # the file cannot be written (a read-only file system): read it as finished
            return _open_view(path)
        raise FileError(path, None, "its run was killed while saving a checkpoint, and finishing that needs "
                                    f"to write the file: {exc.strerror or exc}") from None
    finally:
        release_lock(path)
    return None


def _open_view(path, shared=False):
    """Open for reading a file whose pending journal cannot be copied into it: applied in memory
    (:class:`rbx.journal.JournalView`) -> ``h5py.File``."""
    try:
        view = journal.JournalView(path, shared=shared)
    except journal.JournalError as exc:
        raise FileError(journal.journal_path(path), None, str(exc)) from None
    except OSError as exc:
        raise FileError(path, None, f"cannot read: {exc.strerror or exc}") from None
    try:
        f = h5py.File(view, "r")
    except Exception as exc:   # noqa: BLE001 - HDF5's own words on a damaged file
        view.close()
        raise FileError(path, None, f"cannot open the HDF5 file (damaged?): {_first_line(exc)}") from None
    f._rbx_journal_view = view
    return f


def _check_rbx_file(f, path, group):
    """An rbx file of a schema this rbx reads, holding ``group`` (``collisions`` or ``returns``)."""
    if group == "collisions" and "collisions" not in f and "returns" in f:
        raise FileError(path, None, "not an rbx run: it holds return angles from rbx histogram (returns/), no "
                                    "collisions/")
    missing = [a for a in REQUIRED_ATTRS if a not in f.attrs]
    if missing and not len(f.attrs) and not len(f) and path.endswith(".partial"):
        raise FileError(path, None, "holds nothing yet: its run was stopped before writing anything; remove it and "
                                    "run the config again")
    if missing:
        raise FileError(path, None, f"not an rbx run file (no root attribute '{missing[0]}')")
    if is_true(f.attrs["complete"]) is None:
        raise FileError(path, "complete", f"is {_attr(f.attrs['complete'])!r}, not true or false (a boolean): the "
                                          "attribute was changed since rbx wrote it")
    schema = int(f.attrs.get("schema_version", 1))
    if schema > SCHEMA_VERSION:
        raise FileError(path, "schema_version", f"is {schema}: written by a newer rbx (this one reads up to "
                                                f"{SCHEMA_VERSION}); upgrade rbx")
    missing = [a for a in ROOT_ATTRS if a not in f.attrs and a != "schema_version"]
    if missing:
        raise FileError(path, None, f"not an rbx run file (no root attribute '{missing[0]}')")
    if group not in f:
        raise FileError(path, None, f"not an rbx {'run' if group == 'collisions' else 'return-angle'} file "
                                    f"(no group '{group}/')")
    if group == "collisions":
        for k in INDEX_DATASETS:
            if k not in f["collisions"]:
                raise FileError(path, f"collisions/{k}", "not in this file (a damaged run?)")


def check_layout(f, path):
    """Every dataset of ``collisions/`` as the layout says (module docstring) before anything reads it: the record
    fields (T, N) + their tail in dimension n with their dtype, ``count`` (T,) integers within 0 … N, ``step``
    (N,) integers, T the config's trajectories. Raises :class:`FileError` naming the dataset. A crafted file
    (``step`` shorter than the records, ``time`` declared (1, 10¹²), ``position`` of shape (1, 5001, 7)) gave an
    IndexError, a MemoryError or a wrong picture."""
    g = f["collisions"]
    n = int(f.attrs["dimension"]) if np.ndim(f.attrs["dimension"]) == 0 else 0
    if n not in (2, 3):
        raise FileError(path, "dimension", f"is {f.attrs['dimension']!r}; the layout has 2 or 3")

    def fail(name, problem):
        raise FileError(path, f"collisions/{name}", f"{problem} (a damaged or crafted file)")

    for group in ("collisions",) + STATE_GROUPS:
        for name, ds in (f[group].items() if isinstance(f.get(group), h5py.Group) else ()):
            where = f"{group}/{name}"
            if not isinstance(ds, h5py.Dataset):
                raise FileError(path, where, "is not a dataset (a damaged or crafted file)")
            if ds.is_virtual or ds.external:
                # its values would be read from other files, which rbx never wrote (and a reader trusts)
                raise FileError(path, where, f"is an HDF5 {'virtual' if ds.is_virtual else 'external'} dataset: "
                                             "its values lie in other files; a run file holds its own (a crafted "
                                             "file)")
    count, step = g["count"], g["step"]
    if count.ndim != 1 or count.dtype.kind not in "iu":
        fail("count", f"has shape {count.shape} and dtype {count.dtype}; the layout says (T,) integers")
    if step.ndim != 1 or step.dtype.kind not in "iu":
        fail("step", f"has shape {step.shape} and dtype {step.dtype}; the layout says (N,) integers")
    T, N = count.shape[0], step.shape[0]
    try:
        wanted = int((yaml.safe_load(_text(f.attrs["config"])) or {}).get("run", {}).get("trajectories", T))
    except Exception:   # noqa: BLE001 - an unreadable config is said by the reader, with its own key
        wanted = T
    if T != wanted:
        fail("count", f"has {T} trajectories, the stored config {wanted}")
    for name in RECORD_FIELDS:
        if name not in g:
            continue
        ds, field = g[name], FIELD[name]
        shape = (T, N) + tuple(field.shape(n))
        if not isinstance(ds, _h5_dataset()) or ds.shape != shape:
            fail(name, f"has shape {getattr(ds, 'shape', None)}; the layout says {shape} ({T} trajectories × {N} "
                       "records, as count and step)")
        want = np.dtype(field.dtype)
        if ds.dtype.kind != want.kind or ds.dtype.itemsize != want.itemsize:
            fail(name, f"has dtype {ds.dtype}; the layout says {want}")
    c = count[...]
    if c.size and (c.min() < 0 or c.max() > N):
        fail("count", f"holds {int(c.min())} … {int(c.max())}; the layout says 0 … {N} (the records)")


def _check_step(step, every, path):
    """``collisions/step`` (read) is record × ``output.every``, as every run writes it: checked a million records
    at a time (no array as long as the file's made)."""
    for at in range(0, len(step), 1 << 20):
        part = step[at:at + (1 << 20)]
        wrong = np.flatnonzero(part != np.arange(at, at + len(part), dtype=np.int64) * every)
        if wrong.size:
            r = at + int(wrong[0])
            raise FileError(path, "collisions/step", f"holds {int(step[r])} at record {r}; the layout says record × "
                                                     f"output.every ({r * every}) (a damaged or crafted file)")


def _check_final(final, T, path, walls=None):
    """The saved state read from ``final/``: one row per trajectory in every array; the state of every running
    trajectory finite, its counters not negative, its last wall one of the table's ``walls`` (or −1)."""
    for k, v in final.items():
        if np.ndim(v) == 0 or np.shape(v)[0] != T:
            raise FileError(path, f"final/{k}", f"has shape {np.shape(v)}; the layout says {T} trajectories first "
                                                "(a damaged or crafted file)")
    alive = np.asarray(final.get("alive", np.ones(T, bool))).astype(bool)
    for k, v in final.items():
        v = np.asarray(v)
        if v.dtype.kind == "f":
            ok = np.isfinite(v[alive]).reshape(int(alive.sum()), int(np.prod(v.shape[1:]))).all(axis=1)
            problem = "is not finite for a running trajectory"
        elif k in ("collisions", "draws"):
            ok, problem = v >= 0, "is negative"
        elif k == "last_wall" and walls is not None:
            ok, problem = (v >= -1) & (v < walls), f"names no wall of the table (0 … {walls - 1}, or −1)"
        else:
            continue
        if not np.all(ok):
            j = int(np.nonzero(alive)[0][np.argmin(ok)]) if v.dtype.kind == "f" else int(np.argmin(ok))
            raise FileError(path, f"final/{k}", f"{problem}: trajectory {j} (a damaged or crafted file)")


def _h5_dataset():
    return h5py.Dataset


def _first_line(exc):
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def _text(x):
    return x.decode("utf-8", "replace") if isinstance(x, bytes) else str(x)


def _attr(v):
    """An HDF5 attribute as plain Python (text, list of text, number, bool)."""
    if isinstance(v, bytes):
        return v.decode("utf-8", "replace")
    if isinstance(v, np.ndarray):
        return [_attr(x) for x in v.tolist()]
    if isinstance(v, np.generic):
        return v.item()
    return v


def read_experiment(config_text, source):
    """The validated experiment of a stored ``config`` attribute -> :class:`rbx.model.Experiment`; a config that
    does not validate raises :class:`rbx.model.ConfigError` naming ``source`` and ``config: <key>``."""
    if not isinstance(config_text, str):
        raise ConfigError(source, "config", "the root attribute is not YAML text")
    try:
        return loads(config_text, source)
    except ConfigError as exc:
        raise ConfigError(source, f"config: {exc.key}" if exc.key else "config", exc.problem) from None


# ---- the one reader ---------------------------------------------------------------------------------------------

class Run:
    """A run: its records (the ``collisions/`` datasets of docs/reference.md §5 by name), final state and experiment.

    File-backed (:meth:`open`, :func:`rbx.open`) or in memory (:meth:`from_memory`, :func:`rbx.simulate` without
    ``output``); both behave the same. ``run.position``, ``run.time``, … are read-only numpy arrays shaped as in
    the file (trajectory axis first; rows past ``count[j]`` are NaN / −1); ``run.read(field, trajectories,
    records)`` reads a part of one. Metadata: ``count``, ``step``, ``final`` (dict of arrays), ``complete``,
    ``experiment`` (validated from the stored config), ``config`` (the stored config as a dict), ``attrs`` (the
    root attributes), ``fields`` (what was recorded), ``dimension``, ``table_kind``, ``wall_names``, ``radius``,
    ``kappa``, ``every``, ``trajectories``, ``records``, ``path`` (None in memory).

    A file-backed run opens its file for each read; ``with run: …`` keeps it open for many reads (and gives
    ``run.h5``, the open ``h5py.File``)."""

    def __init__(self, attrs, count, step, final, fields, path=None, arrays=None, experiment=None, config=None):
        self.attrs = attrs
        self.path = path
        self.count, self.step = _frozen(count), _frozen(step)
        self.final = {k: _frozen(v) for k, v in final.items()}
        self.fields = tuple(fields)
        self._arrays = {} if arrays is None else {k: _frozen(v) for k, v in arrays.items()}
        self._experiment = experiment
        self._h5, self._depth = None, 0
        self.dimension = int(attrs["dimension"])
        self.table_kind = str(attrs["table_kind"])
        self.wall_names = list(attrs["wall_names"])
        self.radius, self.kappa = float(attrs["radius"]), float(attrs["kappa"])
        self.complete = bool(attrs["complete"])
        source = path or "<run>"
        try:
            # an in-memory run is given its config already parsed (parsing it again took 2 s for 10 000 states)
            self.config = yaml.safe_load(attrs["config"]) if config is None else config
        except yaml.YAMLError:
            raise FileError(source, "config", "the root attribute is not valid YAML") from None
        if not isinstance(self.config, dict) or not isinstance(self.config.get("table"), dict):
            raise FileError(source, "config", "the root attribute has no resolved 'table' mapping")
        out = self.config.get("output")
        self.every = int((out.get("every", 1) if isinstance(out, dict) else 1) or 1)
        self.trajectories, self.records = len(self.count), len(self.step)

    # -- making one --------------------------------------------------------------------------------------------
    @classmethod
    def open(cls, path):
        """Read the run file at ``path`` (checked: an rbx run of a schema this rbx reads) -> :class:`Run`.
        Raises :class:`FileError`."""
        path = str(path)
        with _open_h5(path) as f:
            try:
                _check_rbx_file(f, path, "collisions")
                g = f["collisions"]
                attrs = {k: _attr(f.attrs[k]) for k in f.attrs}
                fields = [k for k in RECORD_FIELDS if k in g]
                check_layout(f, path)
                final, _, _ = latest_state(f)
                _check_final(final, len(g["count"]), path, len(attrs["wall_names"]))
                run = cls(attrs, g["count"][...], g["step"][...], final, fields, path=path)
                # an unfinished run's records past its saved state may be a block a kill cut short (written before
                # the journal): a resume drops them, a reader is not refused for them
                upto = run.records if run.complete else \
                    min(run.records, 1 + int(np.max(final["collisions"], initial=-1)) // run.every) \
                    if "collisions" in final else 0
                _check_step(run.step[:upto], run.every, path)
                return run
            except FileError:
                raise
            except Exception as exc:   # a damaged file can fail on the first read rather than on opening
                raise FileError(path, None, f"cannot read the HDF5 file (damaged?): {_first_line(exc)}") from None

    @classmethod
    def from_memory(cls, experiment, sink, complete):
        """The run of ``experiment`` collected by a :class:`rbx.simulation.MemorySink` -> :class:`Run`."""
        M = experiment.run.trajectories
        arrays = sink.records
        count = np.zeros(M, np.int64) if sink.count is None else np.asarray(sink.count, np.int64)
        nrec = next(iter(arrays.values())).shape[1] if arrays else 0
        step = np.arange(nrec, dtype=np.int64) * experiment.output.every
        attrs = root_attrs(experiment, complete)
        return cls(attrs, count, step, sink.final or {}, [f for f in RECORD_FIELDS if f in arrays], arrays=arrays,
                   experiment=experiment, config=_plain(experiment.resolved))

    # -- reading -----------------------------------------------------------------------------------------------
    def __enter__(self):
        if self.path is not None:
            if self._h5 is None:
                self._h5 = _open_h5(self.path)
            self._depth += 1
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        if self._h5 is not None:
            self._depth -= 1
            if self._depth <= 0:
                self._h5.close()
                self._h5, self._depth = None, 0

    @property
    def h5(self):
        """The open ``h5py.File`` inside ``with run:`` (file-backed runs)."""
        if self._h5 is None:
            raise RuntimeError("run.h5 exists only inside 'with run:' for a run read from a file")
        return self._h5

    @contextlib.contextmanager
    def _reading(self):
        try:
            if self._h5 is not None:
                yield self._h5["collisions"]
            else:
                with _open_h5(self.path) as f:
                    yield f["collisions"]
        except (OSError, KeyError, ValueError) as exc:
            # a chunk whose Fletcher-32 checksum does not match (its bytes changed on disk), or a damaged header
            raise FileError(self.path, "collisions", f"damaged: cannot read the records ({_first_line(exc)})") \
                from None

    def require(self, fields, why):
        """Raise :class:`FileError` unless every field in ``fields`` was recorded (``why``: what needs them)."""
        missing = [f for f in fields if f not in self.fields]
        if missing:
            f = missing[0]
            raise FileError(self.path or "<run>", f"collisions/{f}",
                            f"not in this file: {why} needs {', '.join(fields)} (the run did not record it: add "
                            f"'{f}' to output.record)")

    def read(self, field, trajectories=None, records=slice(None)):
        """One recorded field for some trajectories (None: all; else a sorted list) and a record slice ->
        (len(trajectories), records, …) array."""
        self.require([field], f"reading '{field}'")
        idx = slice(None) if trajectories is None else sorted(trajectories)
        if isinstance(idx, list) and idx == list(range(idx[0], idx[-1] + 1)):
            idx = slice(idx[0], idx[-1] + 1)       # a contiguous block reads much faster than a point selection
        if self.path is None or field in self._arrays:
            data = self._arrays[field]
            return data[idx][:, records]
        with self._reading() as g:
            ds = g[field]
            start, stop, stride = records.indices(ds.shape[1])
            data = ds[idx, start:stop]
            if stride != 1:
                data = data[:, ::stride]
        self._check_values(field, data, np.arange(self.trajectories)[idx],
                           np.arange(start, stop, stride)[:data.shape[1]])
        return data

    def _check_values(self, name, data, rows, records):
        """Refuse values no run writes in what was just read (``data``: trajectories ``rows`` × ``records``): a
        number that is not finite within the records a trajectory wrote (``count``), a wall index that names no
        wall of the table, a rank below −1. Only what is read is checked, as it is read: a file is never read
        whole for it. Raises :class:`FileError` naming the dataset, the trajectory and the record."""
        if data.size == 0:
            return
        walls = len(self.wall_names)
        if data.dtype.kind == "f":
            with np.errstate(all="ignore"):
                if np.isfinite(np.add.reduce(data, axis=None)):
                    return        # a NaN or an infinity anywhere makes the sum one: one pass, no array made
            bad = ~np.isfinite(data)
            if bad.ndim > 2:
                bad = bad.any(axis=tuple(range(2, bad.ndim)))
            bad &= records[None, :] < self.count[rows][:, None]     # past count: NaN, as written
            what = "a number that is not finite"
        elif name == "wall":
            if data.min() >= -1 and data.max() < walls:
                return
            bad = (data < -1) | (data >= walls)
            what = f"a wall index the table does not have (its {walls} walls are 0 … {walls - 1}; −1 before the " \
                   "first collision)"
        elif name == "rank":
            if data.min() >= -1:
                return
            bad = data < -1
            what = "a roughness rank below −1"
        else:
            return
        if bad.any():
            j, r = (int(x) for x in np.argwhere(bad)[0])
            value = data[j, r]
            shown = value.tolist() if np.ndim(value) else value.item()
            raise FileError(self.path, f"collisions/{name}", f"holds {shown} at trajectory {int(rows[j])}, record "
                                                             f"{int(records[r])}: {what}; no run writes that (a "
                                                             "damaged or crafted file)")

    def __getattr__(self, name):
        if name in FIELD and not name.startswith("_"):
            if name not in self.fields:
                raise AttributeError(f"{self.path or 'this run'}: the run did not record '{name}' (recorded: "
                                     f"{', '.join(self.fields) or 'nothing'}; add it to output.record)")
            if name not in self._arrays:
                with self._reading() as g:
                    try:
                        data = g[name][...]
                    except MemoryError:
                        raise FileError(self.path, f"collisions/{name}",
                                        f"{g[name].nbytes / 1e9:.3g} GB do not fit in the free memory: read a part "
                                        f"with run.read('{name}', trajectories, records)") from None
                self._check_values(name, data, np.arange(self.trajectories), np.arange(self.records))
                self._arrays[name] = _frozen(data)
            return self._arrays[name]
        raise AttributeError(f"'Run' object has no attribute '{name}'")

    def __dir__(self):
        return sorted(set(super().__dir__()) | set(self.fields))

    def __repr__(self):
        where = self.path or "in memory"
        return (f"<rbx.Run {where}: {self.table_kind}, {plural(self.trajectories, 'trajectory')} × "
                f"{plural(self.records, 'record')} "
                f"of {', '.join(self.fields) or 'nothing'}{'' if self.complete else ', INCOMPLETE'}>")

    @property
    def experiment(self):
        """The validated :class:`rbx.model.Experiment` of the stored config (raises ConfigError if it does not
        validate with this rbx)."""
        if self._experiment is None:
            exp = read_experiment(self.attrs["config"], self.path or "<run>")
            if list(exp.wall_names) != list(self.wall_names):   # what collisions/wall indexes: the plots read both
                raise FileError(self.path or "<run>", "wall_names",
                                f"the root attribute names {len(self.wall_names)} walls "
                                f"({', '.join(map(str, self.wall_names))}), the stored config's table "
                                f"{len(exp.wall_names)} ({', '.join(exp.wall_names)}): a damaged or crafted file")
            self._experiment = exp
        return self._experiment

    def geometry(self):
        """The shrunk table the centre moved in (:class:`rbx.geometry.Geometry`)."""
        return self.experiment.geometry()

    def scene(self):
        """A title naming the scene and rule: 'disc (R = 0.1, κ = 0.5) in a 2 × 1 rectangle · rough'."""
        return scene_title(self.experiment)

    def to_xarray(self):
        """The records as an ``xarray.Dataset`` (needs the optional extra ``rbx[xarray]``).

        One variable per recorded field with dimensions ``trajectory``, ``record`` and, for vectors and the 3D
        spin, ``axis`` (x, y[, z]); the 3D orientation matrix has ``axis`` (row: space frame) and ``axis2``
        (column: body frame). Variable ``count`` (trajectory); coordinates ``trajectory``, ``record``, ``step``
        (the collision number of each record, along ``record``), ``axis``, ``axis2``. Each variable carries
        ``units`` and ``description`` (:data:`rbx.model.FIELDS`); the dataset's attributes are the root
        attributes of the file (``config``, ``complete``, …)."""
        try:
            import xarray as xr
        except ImportError:
            raise ImportError("Run.to_xarray needs xarray: pip install 'rbx[xarray]'") from None
        n = self.dimension
        names = ["x", "y", "z"][:n]
        tails = {0: (), 1: ("axis",), 2: ("axis", "axis2")}
        data = {}
        for name in self.fields:
            f = FIELD[name]
            values = getattr(self, name)
            data[name] = xr.Variable(("trajectory", "record") + tails[len(f.shape(n))], values,
                                     attrs={"units": f.units, "description": f.description})
        units, text = INDEX_DATASETS["count"]
        data["count"] = xr.Variable(("trajectory",), self.count, attrs={"units": units, "description": text})
        coords = {"trajectory": np.arange(self.trajectories), "record": np.arange(self.records),
                  "step": ("record", self.step, {"units": "1", "description": INDEX_DATASETS["step"][1]}),
                  "axis": names}
        if n == 3 and "orientation" in self.fields:
            coords["axis2"] = names
        attrs = {k: int(v) if isinstance(v, bool) else v for k, v in self.attrs.items()}   # netCDF has no bool
        return xr.Dataset(data, coords=coords, attrs=attrs)


def _frozen(a):
    a = np.asarray(a)
    if a.flags.writeable:
        a = a.view()
        a.flags.writeable = False
    return a


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


def read_returns(path):
    """Read a file written by ``rbx histogram`` -> dict: the ``returns/`` datasets (``angle``, ``trajectory``,
    ``collisions``, ``initial_angle``), its attributes (:data:`RETURNS_ATTRS`) and ``attrs`` (the root
    attributes). Raises :class:`FileError`."""
    path = str(path)
    with _open_h5(path) as f:
        _check_rbx_file(f, path, "returns")
        g = f["returns"]
        out = {k: g[k][...] for k in g}
        out.update({k: _attr(v) for k, v in g.attrs.items()})
        out["attrs"] = {k: _attr(f.attrs[k]) for k in f.attrs}
    return out
