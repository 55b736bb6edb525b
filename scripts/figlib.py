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
"""
import argparse
import json
import operator
import os
import sys

from rbx.plotting import letter_panels

OPS = {"<": operator.lt, "<=": operator.le, ">": operator.gt, ">=": operator.ge}


def arguments(description):
    p = argparse.ArgumentParser(description=description.strip().splitlines()[0])
    p.add_argument("data", nargs="+", help="HDF5 files written by rbx simulate (or rbx histogram)")
    p.add_argument("-o", "--output", required=True, help="figure to write (PNG); the JSON record goes beside it")
    return p.parse_args()


class Figure:
    def __init__(self, label, caption):
        self.label = label
        self.caption = " ".join(caption.strip().split())
        self.measured = []
        self.checks = []

    def measure(self, name, value, unit=""):
        """A measured quantity, reported in figures/README.md."""
        self.measured.append({"name": name, "value": _plain(value), "unit": unit})
        return value

    def check(self, claim, value, op, bound):
        """The paper's property as an inequality on a measured value; a failed check fails the figure."""
        ok = bool(OPS[op](value, bound))
        self.checks.append({"claim": claim, "value": _plain(value), "op": op, "bound": _plain(bound), "ok": ok})
        return ok

    def save(self, mpl_figure, args, dpi=150):
        out = args.output
        os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
        letter_panels(mpl_figure)          # (a), (b), … as rbx plot letters its panels
        # no timestamps in the PNG: the same data gives the same bytes
        mpl_figure.savefig(out, dpi=dpi, metadata={"Software": None})
        # nothing that depends on the run (no timings): re-plotting the same data writes the same JSON
        record = {
            "label": self.label,
            "caption": self.caption,
            "data": [os.path.relpath(d) for d in args.data],
            "configs": [_config_of(d) for d in args.data],
            "measured": self.measured,
            "checks": self.checks,
        }
        with open(os.path.splitext(out)[0] + ".json", "w") as f:
            json.dump(record, f, indent=1)
        failed = [c for c in self.checks if not c["ok"]]
        for c in self.checks:
            print(f"{self.label}: {'ok  ' if c['ok'] else 'FAIL'} {c['claim']}: {c['value']:.6g} {c['op']} "
                  f"{c['bound']:.6g}")
        if failed:
            sys.exit(1)


def _config_of(data_path):
    """configs/experiments/<x>.yaml for data/<x>.h5 (the Makefile's pattern), if it exists."""
    rel = os.path.relpath(os.path.abspath(data_path), os.path.abspath("data"))
    cfg = os.path.join("configs", "experiments", os.path.splitext(rel)[0] + ".yaml")
    return cfg if os.path.exists(cfg) else None


def _plain(x):
    try:
        return float(x)
    except (TypeError, ValueError):
        return str(x)
