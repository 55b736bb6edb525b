"""The progress bar of long runs, and durations and rates for people: shared by the library
(``rbx.simulate(progress=True)``) and the commands."""
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


def per_second(rate):
    """A rate for people: ``870``, ``12.3 k``, ``4.56 M``."""
    for factor, prefix in ((1e9, " G"), (1e6, " M"), (1e3, " k")):
        if rate >= factor:
            return f"{rate / factor:.3g}{prefix}"
    return f"{rate:.3g}"


class Progress:
    """A one-line progress bar on stderr, on a terminal only: a redirected or captured stderr (a log file, a
    batch job) gets nothing from it, so no lines of ``\r`` updates. It appears once a run has taken more than
    ``delay`` seconds and shows the fraction done, the rate (collisions per second over all ``trajectories``) and
    the time left.

    ``done``/``total`` (the calls) count collisions per trajectory; ``start``: work already done before this
    process began (a resumed run), left out of the rate and the time estimate."""

    def __init__(self, label, delay=2.0, quiet=False, start=0, trajectories=1, stream=None):
        self.stream = sys.stderr if stream is None else stream
        self.label, self.delay, self.first, self.trajectories = label, delay, start, trajectories
        self.quiet = quiet or not is_terminal(self.stream)
        self.start = time.perf_counter()
        self.last = 0.0
        self.shown = False

    def __call__(self, done, total):
        now = time.perf_counter() - self.start
        if self.quiet or now < self.delay or (now - self.last < 0.5 and done < total):
            return
        self.last = now
        frac = done / total if total else 1.0
        rate = (done - self.first) / now if now > 0 else 0.0
        eta = (total - done) / rate if rate > 0 else float("inf")
        bar = "#" * int(30 * frac)
        line = (f"{self.label} [{bar:<30}] {100 * frac:5.1f}%  {per_second(rate * self.trajectories)} collisions/s  "
                f"{duration(now)}  eta {duration(eta)}")
        self.stream.write(f"\r{line:<100}")
        self.stream.flush()
        self.shown = True

    def close(self):
        if self.shown:
            self.stream.write("\n")
            self.stream.flush()
