"""What every ``scripts/fig_<label>.py`` shares: its command line, the checks of the paper's property, and the
record ``figures/<label>.json`` from which ``scripts/figures_readme.py`` writes ``figures/README.md``.

A figure script is called by the Makefile as

    python scripts/fig_<label>.py DATA.h5 [DATA.h5 ...] -o figures/<label>.png

It reads the runs (written by ``rbx simulate`` from ``configs/experiments/<label>.yaml``, or from every config in
``configs/experiments/<label>/`` for a figure with several scenes), measures the property the paper states, draws
the figure, and records everything in ``figures/<label>.json`` beside the picture. It exits 1 (after writing both)
when a check fails, so ``make reproduce-figures`` fails when the paper's property does not hold.

Use::

    fig = Figure(label, caption=__doc__)      # the module docstring: caption in our words + why the parameters
    fig.measure("spread of the vertex angle", 3e-13, "rad")
    fig.check("vertex angle constant along the orbit", spread, "<=", 1e-9)
    fig.save(matplotlib_figure, args)         # writes PNG and JSON, exits 1 if a check failed

The PNG and the JSON are committed, so they must come out byte for byte the same on every CPU (an Intel Xeon
rewrote them in the last digits). What differs between CPUs is not the arithmetic (+ − × ÷ √ are exactly rounded
everywhere) but the library kernels NumPy chooses at run time: BLAS dot products and LAPACK (``x @ y``,
``np.linalg.norm`` of a vector, ``pinv``, ``polyfit``), and the AVX-512 versions of ``log10``, ``power``,
``arccos``, ``arctan2``, ``exp`` and of the complex product, which round differently from the ones other CPUs
run. Hence, in the figure scripts and here:

- no ``@``/``np.dot``/``np.linalg`` on the numbers a figure reports: sums in a fixed order, ``math.hypot``;
- a record keeps :data:`RECORD_DIGITS` significant digits, and a quantity that measures rounding (a spread of
  1e-12, a gap of 1e-11) only ``digits=ROUNDING`` of them; ``-0`` is written as ``0`` (:func:`fixed`);
- log axes map their data with an exactly rounded log10 (:class:`PortableLogScale`, registered as ``"log"`` on
  import), so that the drawn lines, and the pixels, do not depend on NumPy's ``log10``; :func:`geomspace` for
  log-spaced samples.
"""
import argparse
import contextlib
import decimal
import json
import math
import operator
import os
import sys

import numpy as np
from matplotlib import scale as mscale
from matplotlib import ticker as mticker

from rbx.paths import FileError, create_new, display_path, written_whole
from rbx.plotting import letter_panels

OPS = {"<": operator.lt, "<=": operator.le, ">": operator.gt, ">=": operator.ge}
#: significant digits a record keeps: more than any figure's property needs, fewer than the 17 whose last ones are
#: the rounding of the machine that computed them
RECORD_DIGITS = 10
#: ... and for a quantity that measures rounding itself (a spread of 1e-12 over a run, a gap of 1e-11): its size
ROUNDING = 2


def arguments(description):
    p = argparse.ArgumentParser(description=description.strip().splitlines()[0])
    p.add_argument("data", nargs="+", help="HDF5 files written by rbx simulate (or rbx histogram)")
    p.add_argument("-o", "--output", required=True, help="figure to write (PNG); the JSON record goes beside it")
    args = p.parse_args()
    for path in args.data:
        problem = made_from_its_config(path)
        if problem:
            print(f"rbx: {problem}", file=sys.stderr)
            sys.exit(2)
    return args


ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
#: settings that change how a run is stored, not its numbers
STORAGE_KEYS = ("output.path", "output.max_size", "output.compression")
#: the keys named first when they differ: what a shortened or re-seeded run changes
RUN_KEYS = ("run.trajectories", "run.collisions", "run.seed")


def made_from_its_config(path):
    """Whether the data file ``path`` at the Makefile's place (``data/<x>.h5`` or ``data/<label>/<x>.h5``) is the
    run of the config the Makefile makes it from (``configs/experiments/<x>.yaml``) as that config stands: the
    config stored in the file (its root attribute ``config``) against the config read now, every key but where the
    file was written (:data:`STORAGE_KEYS`), and the run complete -> None, or the problem in one line
    ``<file>: <key>: <problem>``. (``rbx histogram … --trajectories 300`` writes data/histogram.h5 by default, and
    the paper's figure was then drawn from 300 samples with its checks passing.) A file elsewhere (a test's
    shortened run) is not checked."""
    import h5py
    import yaml

    import rbx
    data = os.path.join(ROOT, "data")
    full = os.path.abspath(path)
    if os.path.commonpath([full, data]) != data:
        return None
    rel = os.path.relpath(full, data)
    config = os.path.join(ROOT, "configs", "experiments", os.path.splitext(rel)[0] + ".yaml")
    if not os.path.exists(config):
        return None
    shown = os.path.relpath(full, ROOT)
    again = f"make it again: rm {shown} && make reproduce-figures"
    if not os.path.exists(full):
        return f"{shown}: no such file: make it with make reproduce-figures"
    try:
        with h5py.File(full, "r") as f:
            stored = f.attrs.get("config")
            complete = f.attrs.get("complete")
        stored = yaml.safe_load(stored.decode() if isinstance(stored, bytes) else stored)
        if not isinstance(stored, dict):
            raise ValueError("no config")
    except Exception:
        return None         # not a run file: the script's reader says what it is
    if complete is not None and not bool(complete):
        return (f"{shown}: complete: the run was interrupted (complete = false): continue it with rbx simulate "
                f"--resume {shown}, or {again}")
    wanted = rbx.load(config).to_dict()
    got, want = _flat(stored), _flat(wanted)
    keys = [k for k in RUN_KEYS if got.get(k) != want.get(k)]
    keys += sorted(k for k in set(got) | set(want) if k not in STORAGE_KEYS and k not in RUN_KEYS
                   and got.get(k) != want.get(k))
    if not keys:
        return None
    k = keys[0]
    more = f" (and {len(keys) - 1} other key{'s' if len(keys) > 2 else ''})" if len(keys) > 1 else ""
    return (f"{shown}: {k}: {_short(got.get(k))} in this file, {_short(want.get(k))} in "
            f"{os.path.relpath(config, ROOT)}, which the figure is made from{more}: {again}")


def _flat(mapping, prefix=""):
    out = {}
    for k, v in mapping.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict) and v:
            out.update(_flat(v, key + "."))
        else:
            out[key] = v
    return out


def _short(value, width=40):
    text = "(none)" if value is None else json.dumps(value, ensure_ascii=False, default=str)
    return text if len(text) <= width else text[:width - 1] + "…"


class Figure:
    def __init__(self, label, caption):
        self.label = label
        self.caption = " ".join(caption.strip().split())
        self.measured = []
        self.checks = []

    def measure(self, name, value, unit="", digits=RECORD_DIGITS):
        """A measured quantity, reported in figures/README.md, recorded to ``digits`` significant digits."""
        self.measured.append({"name": name, "value": _plain(value, digits), "unit": unit})
        return value

    def check(self, claim, value, op, bound, digits=RECORD_DIGITS):
        """The paper's property as an inequality on a measured value; a failed check fails the figure. The check
        is made on the value itself, the record keeps ``digits`` of it."""
        ok = bool(OPS[op](value, bound))
        self.checks.append({"claim": claim, "value": _plain(value, digits), "op": op, "bound": _plain(bound),
                            "ok": ok})
        return ok

    def save(self, mpl_figure, args, dpi=150):
        out = args.output
        os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
        letter_panels(mpl_figure)          # (a), (b), … as rbx plot letters its panels
        record_path = os.path.splitext(out)[0] + ".json"
        _check_record(record_path)          # before anything is written: a figure without its record is none
        # no timestamps in the PNG: the same data gives the same bytes. Written beside its name and renamed over
        # it (only over a figure: a link or another file there is refused, not written through)
        try:
            with written_whole(out) as scratch:
                mpl_figure.savefig(scratch, dpi=dpi, metadata={"Software": None})
        except FileError as exc:
            _refuse(str(exc))
        # nothing that depends on the run (no timings): re-plotting the same data writes the same JSON
        record = {
            "label": self.label,
            "caption": self.caption,
            "data": [os.path.relpath(d) for d in args.data],
            "configs": [_config_of(d) for d in args.data],
            "measured": self.measured,
            "checks": self.checks,
        }
        _write_record(record_path, record)
        failed = [c for c in self.checks if not c["ok"]]
        for c in self.checks:
            print(f"{self.label}: {'ok  ' if c['ok'] else 'FAIL'} {c['claim']}: {c['value']:.6g} {c['op']} "
                  f"{c['bound']:.6g}")
        if failed:
            sys.exit(1)


def _refuse(message):
    print(f"rbx: {message}", file=sys.stderr)
    sys.exit(2)


def _is_record(path):
    """Whether ``path`` is a regular file (not a link) holding a figure's JSON record, as :func:`_write_record`
    writes it."""
    if os.path.islink(path) or not os.path.isfile(path) or os.path.getsize(path) > 2 ** 20:
        return False
    try:
        with open(path, encoding="utf-8") as f:
            old = json.load(f)
    except (OSError, ValueError):
        return False
    return isinstance(old, dict) and {"label", "checks"} <= set(old)


def _check_record(path):
    if os.path.lexists(path) and not _is_record(path):
        _refuse(f"{display_path(path)}: is not the JSON record of a figure (a link, or another file): not "
                "replaced; move it, or draw the figure under another name")


def _write_record(path, record):
    """The JSON record beside a figure, written whole: to a new name beside it, then renamed over it. Only a
    figure's earlier record is replaced: a link there (it was written through, into the file it pointed to) or a
    file of another kind is refused in one line, exit 2."""
    _check_record(path)
    # a name nobody knows in advance, created exclusively; removed on failure only once it is this script's own (a
    # file put at ``<figure>.json.<pid>.new`` was removed when the exclusive open failed on it)
    scratch, fd = create_new(lambda token: f"{path}.{token}.new")
    try:
        with open(fd, "w", encoding="utf-8") as f:
            json.dump(record, f, indent=1)
        os.replace(scratch, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.remove(scratch)
        raise


def _config_of(data_path):
    """configs/experiments/<x>.yaml for data/<x>.h5 (the Makefile's pattern), if it exists."""
    rel = os.path.relpath(os.path.abspath(data_path), os.path.abspath("data"))
    cfg = os.path.join("configs", "experiments", os.path.splitext(rel)[0] + ".yaml")
    return cfg if os.path.exists(cfg) else None


def _plain(x, digits=RECORD_DIGITS):
    """A number as a float rounded to ``digits`` significant digits (−0 as 0), anything else as text."""
    try:
        x = float(x)
    except (TypeError, ValueError):
        return str(x)
    if math.isfinite(x):
        x = float(f"{x:.{digits}g}") + 0.0          # + 0.0: −0.0 becomes 0.0
    return x


def fixed(x, places):
    """``x`` with ``places`` decimals, and no minus sign on a value that rounds to zero: ``fixed(-3e-17, 6)`` is
    '0.000000' (a projection that is 0 in exact arithmetic comes out ±1e-17, its sign the CPU's)."""
    return f"{round(float(x), places) + 0.0:.{places}f}"


# ---- log axes that draw the same pixels on every CPU ------------------------------------------------------------

_DECIMAL = decimal.Context(prec=25)


def log10(values):
    """log10 of each value, computed to 25 digits in decimal and rounded to the nearest double (−inf at 0, NaN
    below) -> array of the shape of ``values`` (masked where it is): the same bits on every machine. ``np.log10``
    is not: its AVX-512 version and the C library's differ in the last bit, which moves a line on a log axis by
    1e-13 pixels and, through matplotlib's path simplification, changes pixels."""
    a = np.asarray(values, float)
    out = [float(_DECIMAL.log10(decimal.Decimal(x))) if 0.0 < x < math.inf else
           (-math.inf if x == 0.0 else math.inf if x == math.inf else math.nan) for x in a.ravel().tolist()]
    return _like(values, np.array(out, float).reshape(a.shape))


def exp10(values):
    """10**value for each value, computed to 25 digits in decimal and rounded to the nearest double -> array of
    the shape of ``values`` (masked where it is)."""
    a = np.asarray(values, float)
    out = [float(_DECIMAL.power(10, decimal.Decimal(x))) if math.isfinite(x) else
           (math.inf if x == math.inf else 0.0 if x == -math.inf else math.nan) for x in a.ravel().tolist()]
    return _like(values, np.array(out, float).reshape(a.shape))


def _like(values, out):
    return np.ma.masked_array(out, mask=np.ma.getmaskarray(values)) if np.ma.isMaskedArray(values) else out


def geomspace(start, stop, num):
    """``num`` numbers from ``start`` to ``stop`` (both > 0) evenly spaced on a log scale, as ``np.geomspace`` but
    the same bits on every CPU (np.geomspace goes through np.log10 and np.power)."""
    out = exp10(np.linspace(log10(float(start)), log10(float(stop)), int(num)))
    if len(out):
        out[0], out[-1] = start, stop
    return out


class _PortableLogTransform(mscale.LogTransform):
    def transform_non_affine(self, values):
        if self.base != 10:
            return super().transform_non_affine(values)
        out = log10(values)
        if self._clip:
            out[np.asarray(values, float) <= 0] = -1000        # as matplotlib's LogTransform
        return out

    def inverted(self):
        return _PortableInvertedLogTransform(self.base)


class _PortableInvertedLogTransform(mscale.InvertedLogTransform):
    def transform_non_affine(self, values):
        return exp10(values) if self.base == 10 else super().transform_non_affine(values)

    def inverted(self):
        return _PortableLogTransform(self.base)


class _PortableLogLocator(mticker.LogLocator):
    """matplotlib's LogLocator with the decades found by :func:`log10` and the ticks m·10^k rounded to the
    nearest double (it computes them with ``np.power``, whose last bit is the CPU's)."""

    def _log_b(self, x):
        return log10(x) if self._base == 10 else super()._log_b(x)

    def tick_values(self, vmin, vmax):
        return np.array([float(f"{t:.12g}") for t in np.asarray(super().tick_values(vmin, vmax), float)])


class PortableLogScale(mscale.LogScale):
    """The "log" axis scale, base 10, drawn the same on every CPU (:func:`log10`)."""

    def __init__(self, *args, **kwargs):          # (axis, …) before matplotlib 3.11, without axis since
        super().__init__(*args, **kwargs)
        t = self._transform
        self._transform = _PortableLogTransform(t.base, "clip" if t._clip else "mask")

    def set_default_locators_and_formatters(self, axis):
        super().set_default_locators_and_formatters(axis)
        axis.set_major_locator(_PortableLogLocator(self.base))
        axis.set_minor_locator(_PortableLogLocator(self.base, self.subs))


mscale.register_scale(PortableLogScale)            # ax.loglog, semilogy, set_yscale("log") in every figure
