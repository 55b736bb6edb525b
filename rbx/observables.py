"""The observables a study measures (``measure:`` in a study file; :mod:`rbx.study`): one registry, one
:class:`Observable` record per name — its unit, what it means, what runs it needs (record fields, the tangent loop,
the return-angle experiment), what the table must have (an exit wall, an unbounded direction), its options, its
companion numbers, and the function from a point's runs to a value and a standard error. The sweep, the results
file and ``rbx plot --kind sweep`` read these records and name no observable.

How to add an observable: one ``register(Observable(...))`` call below, with its words and symbol for the axes
(``label``, ``symbol``; :func:`variable_label`), and a test against a closed form or an independent estimate in
tests/test_sweep.py.

Errors are standard errors (1σ) unless the record says otherwise: a share's is the half-width of its Wilson
interval at z = 1 (its bounds are the companions ``<name>_low``/``<name>_high``); a p-value has none (NaN).
"""
import math
from dataclasses import dataclass, field

import numpy as np

from .analysis import (free_corridors, orbit_velocity_dimension, santalo_constant, spin_free, spin_mixture,
                       table_measure, unbounded_axes, velocity_dimension, wall_measure, wilson)
from .dynamics import REGULAR_THRESHOLD, escape_times
from .escape import fit_escape, levels_off
from .histogram import exit_problem
from .model import Exit, rule_leaves

__all__ = ["Observable", "REGISTRY", "register", "get", "PointRuns", "Value", "PARAMETERS", "axis_label",
           "variable_label", "parameter_label", "error_bars"]


@dataclass(frozen=True)
class Companion:
    """A number reported beside an observable's value (``<observable>_<suffix>`` in the results file)."""
    suffix: str
    unit: str
    description: str
    dim: str | None = None          # an extra dimension (its coordinate from ``Observable.coords``)
    label: str = ""                 # what it is in a few words, for an axis ("Kac's mean return path")
    symbol: str = ""                # its symbol ("4A/ℓ")
    #: a value of the observable's own quantity to compare it with (Santaló's, Kac's): a study's figure draws it
    #: dashed on the observable's panel; other companions (a share, a flag, a statistic) have panels of their own
    reference: bool = False
    #: a 0/1 flag: where it is 0, the observable's value is not what its name promises; a study's figure says so,
    #: with this text, for the points where it is 0
    caveat: str = ""
    #: the value this companion takes where the observable's closed form holds (a ratio to Kac's value: 1): a
    #: study's figure of this companion draws it as a dashed line, with ``expected_label``
    expected: float | None = None
    expected_label: str = ""
    #: the least value it can take (a length, a rate, a width: 0): a results file holding less at a point marked
    #: done is refused (rbx.sweeping.value_problem)
    least: float | None = None


@dataclass
class Value:
    """What an observable gives at one point: the value, its error, and the companions by suffix."""
    value: object
    stderr: object
    companions: dict = field(default_factory=dict)


@dataclass
class PointRuns:
    """The runs of one point: ``experiment``; ``run`` (:class:`rbx.Run` in memory, with the records the observables
    asked for) or None; ``lyapunov`` (:class:`rbx.dynamics.Lyapunov`) or None; ``returns``
    (:class:`rbx.histogram.Returns`) or None."""
    experiment: object
    run: object = None
    lyapunov: object = None
    returns: object = None


@dataclass(frozen=True)
class Observable:
    """One observable. ``compute(runs, options) -> Value``; ``problem(experiment, options) -> str | None`` says why
    this table cannot give it (after the generic needs ``exit`` and ``unbounded`` are checked)."""
    name: str
    unit: str
    description: str
    compute: object
    fields: tuple = ()              # record fields of the simulate run
    every_collision: bool = False   # the fields at every collision (else a record every collisions/segments)
    tangent: bool = False           # needs rbx.lyapunov's run (the tangent loop)
    returns: bool = False           # needs the return-angle experiment (rbx.histogram)
    final: bool = False             # needs the simulate run for its final state only
    exit: bool = False              # needs a wall with the rule exit
    unbounded: bool = False         # needs a table unbounded along some axis (periodic, strip)
    options: dict = field(default_factory=dict)     # name -> default
    companions: tuple = ()
    dim: str | None = None          # the value's extra dimension
    coords: object = None           # experiment -> coordinate values of ``dim`` (and of companions' dims)
    problem: object = None
    error: str = "standard error"  # what its error is: a standard error, "half-width of <an interval>" or "none (…)"
    level: str = "about 68 %"      # the share of repeated measurements the error bar's interval would cover
    label: str = ""                 # what it is in a few words, for an axis ("Lyapunov exponent"); default: the name
    symbol: str = ""                # its symbol ("λ₁"), beside the words on an axis
    #: where a point has no value (NaN) though it ran: why, for a study's figure ("" where it always has one)
    missing: str = ""
    #: where a results file's own numbers say a point has a value: ``(where, said, unsaid[, error_too])``,
    #: ``where(get)`` -> True where the point has one, False where it has none (``get(key)``: the companion
    #: ``<name>_<key>``'s values, else the variable ``key``'s, else the study's attribute ``key``); ``said`` and
    #: ``unsaid``: what the file says in each case; ``error_too`` (default: it has an error): its standard error
    #: follows the value. A NaN where it says there is a value, or a number where it says there is none (a hand
    #: edit), is refused when a study is resumed or drawn (rbx.sweeping.value_problem)
    has_value: tuple = ()
    #: a number at every computed point (no NaN whatever the run): a NaN there at a point marked done is not a
    #: result, and is refused when a study is resumed or drawn (rbx.sweeping.value_problem)
    never_nan: bool = False

    @property
    def simulate(self):
        return bool(self.fields) or self.final

    @property
    def bars(self):
        """What an error bar of this observable spans, from ``error`` and ``level``, for a figure's note
        ('±1 standard error (about 68 %)', 'the Wilson interval (z = 1, about 68 %)'), or '' (no error)."""
        if self.error.startswith("none"):
            return ""
        if self.error.startswith("half-width of "):
            interval = self.error[len("half-width of "):]
            if interval.endswith(")"):
                return f"{interval[:-1]}, {self.level})"
            return f"{interval} ({self.level})"
        return f"±1 {self.error} ({self.level})"


REGISTRY = {}


def register(observable):
    REGISTRY[observable.name] = observable
    return observable


def get(name):
    return REGISTRY[name]


# ---- how numbers are named on a figure --------------------------------------------------------------------------

#: the config keys a study varies most, as a physicist writes them: key -> (words, symbol, unit). R is the ball's
#: radius everywhere in rbx (docs/reference.md §1), so a table's radius is r. A key not listed is shown as itself.
PARAMETERS = {
    "ball.inertia": ("moment of inertia", "κ", "1"),
    "ball.radius": ("ball radius", "R", "L"),
    "table.radius": ("table radius", "r", "L"),
    "table.width": ("table width", "w", "L"),
    "table.height": ("table height", "h", "L"),
    "table.length": ("table length", "a", "L"),
    "table.cap_radius": ("cap radius", "r", "L"),
    "table.stem_width": ("stem width", "w", "L"),
    "table.stem_height": ("stem height", "h", "L"),
    "boundary.default.rank": ("roughness", "rank", "1"),      # axis "roughness rank", legend "rank = 1"
}


def axis_label(words, symbol, unit):
    """An axis label as a physicist writes it: 'Lyapunov exponent λ₁ [1/T]'; no unit for a pure number."""
    text = " ".join(t for t in (words, symbol) if t)
    return f"{text} [{unit}]" if unit and unit != "1" else text


def parameter_label(key, unit=None):
    """The axis label of a varied config key ('moment of inertia κ'), or the key itself with ``unit`` when the key
    is not in :data:`PARAMETERS` -> (label, symbol: 'κ' or the key)."""
    if key in PARAMETERS:
        words, symbol, known = PARAMETERS[key]
        return axis_label(words, symbol, known), symbol
    return axis_label(key, "", unit), key


def variable_label(name, unit=None, units=True):
    """The axis label of a results file's variable: an observable ('Lyapunov exponent λ₁ [1/T]') or one of its
    companions ('<name>_<suffix>'), else the name itself with ``unit`` -> (label, short: the symbol 'λ₁', else the
    words, else the name); ``units=False``: the label without its unit (a legend entry)."""
    if name in REGISTRY:
        rec = REGISTRY[name]
        words = rec.label or name.replace("_", " ")
        return axis_label(words, rec.symbol, rec.unit if units else None), rec.symbol or words
    for rec in REGISTRY.values():
        for c in rec.companions:
            if name == f"{rec.name}_{c.suffix}":
                words = c.label or c.description.split(":")[0]
                return axis_label(words, c.symbol, c.unit if units else None), c.symbol or words
    return axis_label(name, "", unit if units else None), name


def references(name):
    """The results file's variables a study's figure draws dashed beside variable ``name``: the companions of the
    observable ``name`` marked :attr:`Companion.reference` -> list of names (none for any other variable)."""
    rec = REGISTRY.get(name)
    return [] if rec is None else [f"{name}_{c.suffix}" for c in rec.companions if c.reference]


def expected_line(name):
    """The constant a companion ``name`` takes where its observable's closed form holds, and its legend text ->
    (value, label), or None (:attr:`Companion.expected`)."""
    for rec in REGISTRY.values():
        for c in rec.companions:
            if name == f"{rec.name}_{c.suffix}" and c.expected is not None:
                return c.expected, c.expected_label
    return None


def caveats(name):
    """The 0/1 companions of observable ``name`` whose 0 says its value is not what its name promises -> list of
    (variable name, text) (:attr:`Companion.caveat`)."""
    rec = REGISTRY.get(name)
    return [] if rec is None else [(f"{name}_{c.suffix}", c.caveat) for c in rec.companions if c.caveat]


def missing_reason(name):
    """Why a point of observable ``name`` (or of one of its companions) may hold no value -> text, or ''."""
    for rec in REGISTRY.values():
        if name == rec.name or any(name == f"{rec.name}_{c.suffix}" for c in rec.companions):
            return rec.missing
    return ""


def error_bars(name):
    """What the error bars of a results file's variable are (an observable's, or a companion's with the error of
    its observable) -> 'bars: …' for a figure, or '' (no error, or not a registered name)."""
    for rec in REGISTRY.values():
        if name == rec.name or any(name == f"{rec.name}_{c.suffix}" for c in rec.companions):
            return f"bars: {rec.bars}" if rec.bars else ""
    return ""


# ---- statistics ------------------------------------------------------------------------------------------------

def _share(k, n):
    p, lo, hi = wilson(k, n)
    return Value(p, 0.5 * (hi - lo), {"low": lo, "high": hi})


def ratio_batches(num, den):
    """A ratio Σnum/Σden over batches (M trajectories × S segments; ``num`` may carry a trailing axis) and its
    standard error -> (value, stderr): the ratio estimator's error from the spread of the segments, or of the
    trajectories' own ratios if that is larger (a table that is not ergodic: trajectories differ)."""
    num = np.asarray(num, float)
    den = np.asarray(den, float)
    value = num.sum(axis=(0, 1)) / den.sum()

    def spread(a, b):
        ok = b > 0
        a, b = a[ok], b[ok]
        B = len(b)
        if B < 2:
            return np.full(np.shape(value), np.nan)
        resid = a - (value * b[:, None] if a.ndim == 2 else value * b)
        return np.sqrt(np.sum(resid ** 2, axis=0) / (B * (B - 1))) / np.mean(b)

    tail = num.shape[2:]
    err = spread(num.reshape((-1,) + tail), den.reshape(-1))
    if num.shape[0] > 1:
        err = np.fmax(err, spread(num.sum(axis=1), den.sum(axis=1)))
    return value, err


def _segment_sums(values, counts, segments):
    """Cut each row's series (M, K) into ``segments`` consecutive parts -> (sums (M, S), counts (M, S))."""
    M, K = values.shape
    edges = np.linspace(0, K, segments + 1).round().astype(int)
    s = np.stack([values[:, a:b].sum(axis=1) for a, b in zip(edges[:-1], edges[1:])], axis=1)
    c = np.stack([counts[:, a:b].sum(axis=1) for a, b in zip(edges[:-1], edges[1:])], axis=1)
    return s, c


# ---- what a table has ------------------------------------------------------------------------------------------

def exit_walls(experiment):
    return [w for w, r in enumerate(experiment.wall_rules) if any(isinstance(x, Exit) for x in rule_leaves(r))]


def _flow_starts(experiment):
    """Starts drawn with the billiard flow's measure (uniform in the table and in direction): point-particle
    starts. Under specular walls (:func:`rbx.analysis.spin_free`) that measure is the flow's invariant one; under
    rough walls the orbits gain spin, and it is not."""
    init = experiment.initial
    return isinstance(init, tuple) and bool(init) and init[0] == "point_particle"


def _sampled_wall(experiment):
    init = experiment.initial
    return init[1] if isinstance(init, tuple) and init and init[0] == "sample" else None


# ---- the observables -------------------------------------------------------------------------------------------

#: why a tangent observable's point may hold no value (rbx.sweeping.run_point)
NOTHING_MEASURED = ("no value where every orbit left the table during its warm-up, or too few segments were "
                    "measured for an error (a shorter warm-up, more trajectories or collisions)")


def _lyapunov(runs, options):
    ly = runs.lyapunov
    per_collision = float(np.sum(ly.time) / max(1, int(np.sum(ly.collisions))))
    out = {"per_collision": ly.exponents[0] * per_collision, "per_collision_stderr": ly.stderr[0] * per_collision}
    if options.get("spectrum"):
        out["spectrum"] = np.asarray(ly.exponents, float)
        out["spectrum_stderr"] = np.asarray(ly.stderr, float)
    return Value(float(ly.exponents[0]), float(ly.stderr[0]), out)


def _exponent_coords(experiment):
    return np.arange(1, 2 * velocity_dimension(experiment.dimension) + 1)


register(Observable(
    "lyapunov", "1/T", "largest Lyapunov exponent λ₁ of the flow per unit time (rbx.lyapunov: Benettin's method, "
    "the error from segments and trajectories)", _lyapunov, tangent=True,
    options={"spectrum": False, "segments": 10, "warmup": None}, label="Lyapunov exponent", symbol="λ₁",
    companions=(Companion("per_collision", "1/collision", "λ₁ per collision (λ₁ · mean time between collisions)",
                          label="Lyapunov exponent per collision", symbol="λ₁⟨τ⟩"),
                Companion("per_collision_stderr", "1/collision", "standard error of λ₁ per collision",
                          label="standard error of", symbol="λ₁⟨τ⟩"),
                Companion("spectrum", "1/T", "the Lyapunov spectrum per unit time, largest first "
                                             "(with spectrum: true)", dim="exponent",
                          label="Lyapunov exponents", symbol="λᵢ"),
                Companion("spectrum_stderr", "1/T", "standard errors of the spectrum", dim="exponent",
                          label="standard error of", symbol="λᵢ")),
    coords=lambda exp: {"exponent": _exponent_coords(exp)}, missing=NOTHING_MEASURED,
    # λ₁ is measured wherever one orbit was (its error needs more segments or orbits: it may be missing)
    has_value=(lambda get: get("lyapunov_orbits") >= 1, "its orbits were measured", "no orbit was measured", False)))


def _regular_share(runs, options):
    return _share(*runs.lyapunov.regular(float(options["threshold"])))


register(Observable(
    "regular_share", "1", "share of trajectories whose own λ₁ is below the threshold (per unit time): regular "
    "(trapped) orbits", _regular_share, tangent=True, options={"threshold": REGULAR_THRESHOLD},
    label="share of regular orbits",
    companions=(Companion("low", "1", "Wilson interval, lower bound (z = 1)"),
                Companion("high", "1", "Wilson interval, upper bound (z = 1)")),
    error="half-width of the Wilson interval (z = 1)", missing=NOTHING_MEASURED,
    has_value=(lambda get: get("lyapunov_orbits") >= 1, "its orbits were measured", "no orbit was measured")))


def _diffusion(runs, options):
    run, exp = runs.run, runs.experiment
    axes = sorted(unbounded_axes(exp.geometry()))
    seg = max(1, exp.run.collisions // int(options["segments"]))
    at = np.nonzero(run.step % seg == 0)[0]
    pos = np.asarray(run.position)[:, at][..., axes]
    t = np.asarray(run.time)[:, at]
    dr2 = np.sum(np.diff(pos, axis=1) ** 2, axis=-1) / (2 * len(axes))
    dt = np.diff(t, axis=1)
    ok = np.isfinite(dr2) & np.isfinite(dt)
    value, err = ratio_batches(np.where(ok, dr2, 0.0), np.where(ok, dt, 0.0))
    return Value(float(value), float(err), {"horizon": _widest_corridor(exp.geometry(), axes)})


def _widest_corridor(geom, axes):
    """The width of the widest free corridor along one of ``axes`` (an infinite horizon: the MSD grows as t·log t
    and the value depends on the segments' length), 0 for a finite horizon, NaN where it is not worked out."""
    corridors = free_corridors(geom)
    if corridors is None:
        return math.nan
    return max((c.width for c in corridors if any(c.along(a) for a in axes)), default=0.0)


def _bounded(exp, options):
    if not unbounded_axes(exp.geometry()):
        return f"the {exp.table_kind} table is bounded: no diffusion (it needs a periodic or open table)"
    return None


register(Observable(
    "diffusion", "L²/T", "diffusion coefficient per unit time, ⟨|Δx|²⟩ = 2k·D·t over the k unbounded axes, from "
    "the displacements over segments of each trajectory (run.collisions/segments collisions each)", _diffusion,
    fields=("time", "position"), unbounded=True, options={"segments": 20}, problem=_bounded,
    companions=(Companion("horizon", "L", "the widest free corridor along the axes measured: above 0 an infinite "
                          "horizon, where the mean-square displacement grows as t·log t and no diffusion coefficient "
                          "exists (the value then depends on the segments' length); 0 a finite horizon; NaN not "
                          "worked out (a table that is not a periodic gas of round scatterers)", least=0.0,
                          label="widest free corridor", symbol="w"),),
    label="diffusion coefficient", symbol="D"))


#: the small-hole escape rate |hole|/(C_d·|table|) applies to holes at most this share of the boundary: for a
#: larger one (a whole wall of a rectangle) an orbit's next exit is not a rare event and the formula means nothing
SMALL_HOLE = 0.1


def hole_rate(experiment, d=None):
    """|hole|/(C_d·|table|): the flux through the walls whose rule is an exit over the phase volume, per unit path,
    C_d Santaló's constant of a velocity space of dimension ``d`` (default: the one the orbits fill, π for a point
    particle in 2D, 4 for a disc with spin) -> (rate, the hole's share of the boundary, C_d as written), or None
    (no such wall, or a table whose measure is not computed)."""
    geom = experiment.geometry()
    try:
        volume, _ = table_measure(geom)
        # walls whose rule is an exit (one that is an exit at random is a hole only part of the time)
        hole = sum(wall_measure(geom, w) for w, r in enumerate(experiment.wall_rules) if isinstance(r, Exit))
        boundary = sum(wall_measure(geom, w) for w in range(len(geom.wall_list)))
    except (ValueError, ZeroDivisionError):
        return None
    if not (np.isfinite(boundary) and hole > 0):
        return None
    d = orbit_velocity_dimension(experiment) if d is None else d
    written = {2: "π", 3: "4"}.get(d, f"{santalo_constant(d):.3g}")
    return hole / (santalo_constant(d) * volume), hole / boundary, written


def small_hole_rate(experiment):
    """The small-hole escape rate per unit path, |hole|/(C_d·|table|) (:func:`hole_rate`) -> (rate, hole's share of
    the boundary, C_d as written), or None where it does not apply: a hole larger than :data:`SMALL_HOLE` of the
    boundary, no wall whose rule is an exit, a table whose measure is not computed, spinning starts under specular
    walls (each orbit then has a rate of its own, :func:`rbx.analysis.spin_mixture`)."""
    if spin_mixture(experiment):
        return None
    found = hole_rate(experiment)
    return found if found is not None and found[1] <= SMALL_HOLE else None


def _escape_rate(runs, options):
    """The rate of rbx plot --kind escape's fit (:func:`rbx.escape.fit_escape`, with the level where survival levels
    off): the same number as the figure, and none where no exponential law follows the survival (a rate fitted
    anyway was 0.260 ± 0.006 for a specular rectangle, whose decay is not exponential)."""
    esc = escape_times(runs.run)
    if spin_mixture(runs.experiment):         # each orbit its own rate: no one rate to give
        return Value(math.nan, math.nan, {"small_hole": math.nan})
    small = small_hole_rate(runs.experiment)
    trapped = levels_off(esc.path, esc.exited)
    # the small-hole law is for orbits that all leave in the end: none where survival levels off (a trap)
    expected = {"small_hole": small[0] if small is not None and not trapped else math.nan}
    if not esc.exited.any():
        return Value(math.nan, math.nan, expected)
    try:
        fit = fit_escape(esc.path, esc.exited, fit_from=float(options["fit_from"]), trapped=trapped)
    except ValueError:          # too few exits in any window to fit a rate (the figure says so too)
        return Value(math.nan, math.nan, expected)
    if not (fit.follows and fit.rate > 0 and np.isfinite(fit.rate_err)):
        return Value(math.nan, math.nan, expected)
    return Value(fit.rate, fit.rate_err, expected)


register(Observable(
    "escape_rate", "1/L", "exponential escape rate through the exit walls per unit path in (x, R√κ·θ): the fit of "
    "rbx plot --kind escape (from the fit_from quantile of the exits on, with the level survival tends to where it "
    "levels off); NaN where no exponential law follows the survival", _escape_rate,
    final=True, exit=True, options={"fit_from": 0.1}, label="escape rate per unit path in (x, R√κθ)", symbol="γ",
    companions=(Companion("small_hole", "1/L", "the small-hole rate |hole|/(C_d·|table|) (C_d = π for a point "
                          "particle in 2D, 4 for a disc with spin); NaN for a hole larger than a tenth of the "
                          "boundary, or where survival levels off", reference=True, least=0.0,
                          label="small-hole rate |hole| / (C·|table|)"),),
    missing="no value where no exponential law follows the survival, or too few orbits exited to fit one (rbx "
            "plot --kind escape of a point's run shows it), or where spinning starts meet only specular walls "
            "(each orbit keeps its spin and leaves at its own rate: point-particle starts give the classic one)"))


def _trapped_share(runs, options):
    esc = escape_times(runs.run)
    value = _share(int(np.sum(~esc.exited)), len(esc.exited))
    # every orbit out is survival levelled at 0: a trapped share of 0, read as such
    value.companions["levelled"] = float(bool(esc.exited.all()) or levels_off(esc.path, esc.exited))
    return value


register(Observable(
    "trapped_share", "1", "share of trajectories that never reach an exit wall within the run; a trapped share "
    "only where survival has levelled off by the end of the run (the companion levelled)", _trapped_share,
    final=True, exit=True, label="share never reaching the exit",
    companions=(Companion("low", "1", "Wilson interval, lower bound (z = 1)"),
                Companion("high", "1", "Wilson interval, upper bound (z = 1)"),
                Companion("levelled", "1", "1 where survival has levelled off by the end of the run, or every "
                                          "orbit left (the share is then the trapped share), 0 where it still "
                                          "falls (the share then "
                                          "counts the orbits not out yet, and shrinks with longer runs)",
                          label="survival levelled off",
                          caveat="survival still falling at the end of the run: a share of orbits not out yet, "
                                 "not a trapped share (run longer)")),
    error="half-width of the Wilson interval (z = 1)"))


def kac_return_path(experiment):
    """Kac's lemma with Santaló's formula: the mean return path to the exit walls, C_d·|table|/|holes| (4A/ℓ for a
    disc), for billiard-measure starts on the holes when almost every state returns (docs/dynamics.md)."""
    geom = experiment.geometry()
    volume, _ = table_measure(geom)
    hole = sum(wall_measure(geom, w) for w in exit_walls(experiment))
    return santalo_constant(velocity_dimension(experiment.dimension)) * volume / hole


def _return_path(runs, options):
    esc = escape_times(runs.run)
    p = esc.path[esc.exited]
    kac = kac_return_path(runs.experiment)
    unreturned = float(np.mean(~esc.exited))
    if len(p) < 2 or unreturned > 0:
        # a trajectory still out at the end of the run is one of the longest returns: the mean of the others is
        # biased low, far beyond its standard error (a Sinai table with a hole, 30 collisions per trajectory:
        # Kac's ratio 0.58 ± 0.04; every orbit returned: 1.03 ± 0.10): no value
        return Value(math.nan, math.nan, {"kac": kac, "ratio": math.nan, "ratio_stderr": math.nan,
                                          "unreturned": unreturned})
    mean, err = float(p.mean()), float(p.std(ddof=1) / math.sqrt(len(p)))
    return Value(mean, err, {"kac": kac, "ratio": mean / kac, "ratio_stderr": err / kac, "unreturned": unreturned})


def _on_exit_wall(exp, options):
    wall = _sampled_wall(exp)
    if wall is None or wall not in exit_walls(exp):
        return "needs starts on an exit wall (initial: {sample: billiard, wall: W}, W with the rule exit)"
    return None


register(Observable(
    "return_path", "L", "mean path in (x, R√κ·θ) of the trajectories started with the billiard measure on the exit "
    "wall until they return to it; NaN when some did not return within the run (the longest returns missing, the "
    "mean of the others is biased low)", _return_path, final=True, exit=True,
    problem=_on_exit_wall, label="mean return path in (x, R√κθ)", symbol="⟨ℓ⟩",
    missing="no value where some trajectory had not returned by the end of the run (raise collisions), or with "
            "one trajectory (no mean with an error)",
    has_value=(lambda get: (get("unreturned") == 0) & (get("ensemble_trajectories") >= 2),
               "every trajectory returned", "some trajectory had not returned or the ensemble has one trajectory"),
    companions=(Companion("kac", "L", "Kac/Santaló: C_d·|table|/|hole| (4A/ℓ for a disc)", reference=True, least=0.0,
                          label="Kac's lemma: C·|table| / |hole| (every state returns)"),
                Companion("ratio", "1", "mean return path / Kac's value",
                          label="mean return path / Kac's", expected=1.0, least=0.0,
                          expected_label="1: Kac's lemma (every state returns)"),
                Companion("ratio_stderr", "1", "standard error of the ratio",
                          label="standard error of the mean return path / Kac's"),
                Companion("unreturned", "1", "share of trajectories that did not return within the run",
                          label="share not returned within the run"))))


def _mean_free_path(runs, options):
    run, exp = runs.run, runs.experiment
    pos = np.asarray(run.position)[:, 1:]           # from the first collision (a start may be inside the table)
    d = np.linalg.norm(np.diff(pos, axis=1), axis=-1)
    ok = np.isfinite(d)
    s, c = _segment_sums(np.where(ok, d, 0.0), ok.astype(float), int(options["segments"]))
    if _flow_starts(exp) and spin_free(exp):
        # starts drawn with the flow's measure weight each orbit by its mean free path (an orbit of long chords is
        # met more often in the area): every trajectory runs the same collisions, so in a table that is not
        # ergodic (a circle, a rectangle) the pooled mean was the flow's mean chord (16r/3π in a circle, 8 % above
        # πA/P). Weighted by its collisions per unit path, each counts as if all had run the same path — the
        # flow's time average, which is the billiard map's mean, Santaló's, in any table.
        path, hits = s.sum(axis=1), c.sum(axis=1)
        w = np.divide(hits, path, out=np.zeros_like(path), where=path > 0)
        s, c = s * w[:, None], c * w[:, None]
    value, err = ratio_batches(s[..., None], c)
    try:
        volume, surface = table_measure(exp.geometry())
        santalo = santalo_constant(exp.dimension) * volume / surface
    except ValueError:          # unbounded
        santalo = math.nan
    return Value(float(value[0]), float(err[0]), {"santalo": santalo})


register(Observable(
    "mean_free_path", "L", "the centre's mean distance between consecutive collisions", _mean_free_path,
    fields=("position",), every_collision=True, options={"segments": 10}, label="mean free path", symbol="⟨ℓ⟩",
    never_nan=True,     # it counts at least the flight to the first collision
    companions=(Companion("santalo", "L", "Santaló's mean free path of a point in the shrunk table: "
                                          "πA/P in 2D (4V/S in 3D)",
                          label="Santaló's mean free path", symbol="πA/P", reference=True, least=0.0),)))


def _wall_share(runs, options):
    run = runs.run
    wall = np.asarray(run.wall)[:, 1:]
    names = runs.experiment.wall_names
    onehot = (wall[..., None] == np.arange(len(names))).astype(float)
    counted = (wall >= 0).astype(float)
    S = int(options["segments"])
    M, K = wall.shape
    edges = np.linspace(0, K, S + 1).round().astype(int)
    num = np.stack([onehot[:, a:b].sum(axis=1) for a, b in zip(edges[:-1], edges[1:])], axis=1)
    den = np.stack([counted[:, a:b].sum(axis=1) for a, b in zip(edges[:-1], edges[1:])], axis=1)
    value, err = ratio_batches(num, den)
    return Value(value, err)


register(Observable(
    "wall_share", "1", "share of the collisions made on each wall", _wall_share, fields=("wall",),
    every_collision=True, options={"segments": 10}, dim="wall", label="share of the collisions on the wall",
    coords=lambda exp: {"wall": np.array(exp.wall_names, dtype=object)}))


def _return_angle_ks(runs, options):
    r = runs.returns
    return Value(float(r.ks_pvalue), math.nan, {"statistic": float(r.ks_statistic),
                                                "returned": float(np.mean(r.returned))})


def _on_a_wall(exp, options):
    wall = _sampled_wall(exp)
    if wall is None:
        return "needs starts on one wall (initial: {sample: billiard, wall: W})"
    return exit_problem(exp)


register(Observable(
    "return_angle_ks", "1", "Kolmogorov–Smirnov p-value of the return angles to the sampled wall against the "
    "billiard measure's law sin^(d−1) φ (rbx histogram); NaN when some sample did not return within the run (the "
    "slow returns missing, the test would test the truncation)", _return_angle_ks, returns=True, problem=_on_a_wall,
    label="KS p-value of the return angles", symbol="p",
    missing="no p-value where some sample had not returned by the end of the run (raise collisions)",
    has_value=(lambda get: get("returned") == 1, "every sample returned", "some sample had not returned"),
    companions=(Companion("statistic", "1", "the KS statistic", label="KS statistic of the return angles"),
                Companion("returned", "1", "share of the samples that returned within the run",
                          label="share returned within the run")),
    error="none (a p-value)"))


def _energy(velocity, spin, R, kappa):
    v = np.asarray(velocity, float)
    w = np.asarray(spin, float)
    w2 = w * w if w.ndim == v.ndim - 1 else np.sum(w * w, axis=-1)
    return 0.5 * (np.sum(v * v, axis=-1) + kappa * R * R * w2)


def _energy_drift(runs, options):
    run, exp = runs.run, runs.experiment
    R, kappa = exp.ball.radius, exp.ball.kappa
    e0 = _energy(np.asarray(run.velocity)[:, 0], np.asarray(run.angular_velocity)[:, 0], R, kappa)
    e1 = _energy(run.final["velocity"], run.final["angular_velocity"], R, kappa)
    drift = np.abs(e1 / e0 - 1.0)
    M = len(drift)
    return Value(float(drift.mean()), float(drift.std(ddof=1) / math.sqrt(M)) if M > 1 else math.nan,
                 {"max": float(drift.max())})


register(Observable(
    "energy_drift", "1", "health check: mean relative change of the kinetic energy over the run", _energy_drift,
    fields=("velocity", "angular_velocity"), label="energy drift", symbol="|ΔE|/E",
    never_nan=True,     # a run whose energy went non-finite stops
    companions=(Companion("max", "1", "largest relative change", label="largest energy drift",
                          symbol="max |ΔE|/E", reference=True),)))
