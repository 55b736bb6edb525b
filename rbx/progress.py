"""The progress bar of long runs, and durations and rates for people: shared by the library
(``rbx.simulate(progress=True)``) and the commands."""
import os
import sys
import time


def is_terminal(stream):
    """True if ``stream`` is a terminal (a redirected or captured stream is not), or a Jupyter notebook's stderr
    (``rbx.simulate(progress=True)`` there: it draws ``\r`` updates in place, as a terminal does)."""
    if type(stream).__module__.startswith("ipykernel."):
        return True
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError, OSError):   # no isatty, or closed
        return False


def duration(seconds):
    """A duration for people: ``0.84 s``, ``12.3 s``, ``4 min 05 s``, ``2 h 03 min``."""
    if seconds != seconds or seconds == float("inf"):
        return "?"
    if seconds < 10:
        return f"{seconds:.2g} s" if seconds < 1 else f"{seconds:.1f} s"
    if seconds < 60:
        return f"{seconds:.0f} s"
    minutes, secs = divmod(int(round(seconds)), 60)
    if minutes < 60:
        return f"{minutes} min {secs:02d} s"
    hours, minutes = divmod(minutes, 60)
    return f"{hours} h {minutes:02d} min"


def plural(count, word, many=None):
    """``1 trajectory``, ``3 trajectories``, ``0 points``: a count and its noun in the right number (``many``: the
    plural where it is not the noun plus s, or y to ies)."""
    if count == 1:
        return f"{count} {word}"
    if many is None:
        many = word[:-1] + "ies" if word.endswith("y") and word[-2:-1] not in "aeiou" else word + "s"
    return f"{count} {many}"


_COMPILES = {"seconds": 0.0, "count": 0, "watching": False}


def watch_compiles():
    """Count from now on the time Numba spends compiling in this process (its ``numba:compile`` events, which a
    kernel loaded from the disk cache does not raise): :func:`setup_note` then says whether the set-up was a
    one-time compile. Cheap after the first call; Numba is imported here, not at the command line's start."""
    if _COMPILES["watching"]:
        return
    try:
        from numba.core import event
    except ImportError:         # pragma: no cover - a Numba without the event API: the plain note
        return

    class Listener(event.Listener):
        depth, began = 0, 0.0

        def on_start(self, ev):
            if self.depth == 0:
                self.began = time.perf_counter()
            self.depth += 1

        def on_end(self, ev):
            self.depth -= 1
            if self.depth == 0:          # a kernel and the helpers compiled inside it: one compile
                _COMPILES["seconds"] += time.perf_counter() - self.began
                _COMPILES["count"] += 1

    event.register("numba:compile", Listener())
    _COMPILES["watching"] = True


def setup_note(seconds):
    """What the set-up of a command was, for its summary line: ``0.4 s setting up`` when the kernels came from the
    cache, ``compiling kernels for this scene, once: 12 s`` when this process compiled them (the next run of the
    same table loads them from the cache in well under a second). Needs :func:`watch_compiles` before the
    compile."""
    if _COMPILES["count"]:
        return f"compiling kernels for this scene, once: {duration(max(seconds, _COMPILES['seconds']))}"
    return f"{duration(seconds)} setting up"


def compile_note():
    """``compiling kernels for this scene, once: 39 s`` if this process compiled kernels (:func:`watch_compiles`),
    else the empty string."""
    if _COMPILES["count"]:
        return f"compiling kernels for this scene, once: {duration(_COMPILES['seconds'])}"
    return ""


def per_second(rate):
    """A rate for people: ``870``, ``12.3 k``, ``4.56 M``."""
    for factor, prefix in ((1e9, " G"), (1e6, " M"), (1e3, " k")):
        if rate >= factor:
            return f"{rate / factor:.3g}{prefix}"
    return f"{rate:.3g}"


def _size(stream, fallback=(100, 24)):
    """(columns, rows) of the terminal behind ``stream``, ``fallback`` for a size it does not report: tqdm asks the
    terminal itself and, from one that reports 0 × 0 (a pseudo-terminal whose size was never set: ``script``, some
    CI runners, the tests' pty), made −1 × −1 and drew nothing at all."""
    try:
        columns, rows = os.get_terminal_size(stream.fileno())
    except (AttributeError, ValueError, OSError):     # no file descriptor (a notebook's stream), or not a terminal
        return fallback
    return (columns if columns > 0 else fallback[0]), (rows if rows > 0 else fallback[1])


class Progress:
    """The progress bar of a long run: tqdm's (``tqdm.auto``: a bar on a terminal, a widget in a Jupyter notebook),
    on stderr, on a terminal or in a notebook only: a redirected or captured stderr (a log file, a batch job) gets
    nothing from it, so no lines of ``\r`` updates. It appears once a run has taken more than ``delay`` seconds and
    shows the fraction done, the rate (collisions per second over all ``trajectories``) and the time left.

    ``done``/``total`` (the calls) count collisions per trajectory; ``start``: work already done before this
    process began (a resumed run), left out of the rate and the time estimate. tqdm is imported when the bar is
    first drawn (0.1–0.3 s), so short and redirected runs never pay for it."""

    #: the bar's layout: ``simulate [#####     ]  42.0%  1.23M collisions/s  00:05  eta 00:07``
    FORMAT = "{desc} [{bar:30}] {percentage:5.1f}%  {rate_fmt}  {elapsed}  eta {remaining}"

    def __init__(self, label, delay=2.0, quiet=False, start=0, trajectories=1, stream=None, unit="collisions"):
        self.stream = sys.stderr if stream is None else stream
        self.label, self.delay, self.first, self.trajectories, self.unit = label, delay, start, trajectories, unit
        self.quiet = quiet or not is_terminal(self.stream)
        self.start = time.perf_counter()
        self.bar = None

    def __call__(self, done, total):
        if self.quiet:
            return
        M = self.trajectories
        if self.bar is None:
            if time.perf_counter() - self.start < self.delay:       # a run shorter than that never shows one
                return
            from tqdm.auto import tqdm
            columns, rows = _size(self.stream)
            # opened at the work done so far (a resumed run's too); the rate is tqdm's moving average of the
            # updates, so the work done before the bar appeared never counts in it
            self.bar = tqdm(total=total * M, initial=done * M, desc=self.label, unit=" " + self.unit, unit_scale=True,
                            file=self.stream, bar_format=self.FORMAT, ascii=" #", mininterval=0.5, smoothing=0.1,
                            ncols=columns, nrows=rows, leave=True)
            self.bar.start_t -= time.perf_counter() - self.start     # the elapsed time is the run's, not the bar's
            return
        self.bar.update(done * M - self.bar.n)

    @property
    def shown(self):
        return self.bar is not None

    def close(self):
        if self.bar is not None:
            self.bar.close()
