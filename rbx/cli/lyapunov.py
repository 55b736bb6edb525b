"""``rbx lyapunov CONFIG``: the Lyapunov spectrum of the flow (docs/reference.md §10; docs/tangent-map.md)."""
import json
import math
import time

import click
import numpy as np

from .common import (Command, UserError, check_cluster_options, check_memory, connect, duration, ending_on_signals,
                     parse_sets, pending_signal, plural, quiet_option, report_and_exit, set_option, summary, user_errors,
                     warn_repeated)
from ..progress import compile_note, watch_compiles


@click.command(cls=Command)
@click.argument("config", type=click.Path(dir_okay=False))
@click.option("--collisions", type=int, help="Override run.collisions (per trajectory, the warm-up included).")
@click.option("--trajectories", type=int, help="Override run.trajectories.")
@click.option("--seed", type=int, help="Override run.seed.")
@set_option
@click.option("--segments", type=click.IntRange(1, 10000), default=10, show_default=True,
              help="Segments per trajectory for the error estimate.")
@click.option("--warmup", type=click.IntRange(0, None), help="Collisions not counted while the vectors align "
                                                              "(default: a tenth of the collisions).")
@click.option("--exponents", type=int, metavar="K",
              help="Follow K tangent vectors instead of all: the K leading exponents (K = 1: λ1 alone, the cheapest).")
@click.option("--threshold", type=float, metavar="RATE",
              help="An orbit whose own λ1 per unit time is below RATE counts as regular (default 0.02; in the "
                   "table's units: a table 100 times larger has exponents 100 times smaller).")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object (exponents, stderr, sum, time, …).")
@click.option("--scheduler", metavar="ADDRESS",
              help="Follow the trajectories on the workers of a Dask cluster: its scheduler's address "
                   "(tcp://HOST:PORT) or scheduler file (docs/cluster.md). Same results as a local run.")
@click.option("--slices", type=click.IntRange(min=1), metavar="N",
              help="With --scheduler: tasks, each a slice of the trajectories (default: 4 per worker thread).")
@quiet_option
@click.option("--debug", is_flag=True, help="Show a traceback with user errors.")
def lyapunov(config, collisions, trajectories, seed, sets, segments, warmup, exponents, threshold, as_json, scheduler,
             slices, quiet, debug):
    """The Lyapunov spectrum of the flow, per unit time, largest first, with standard errors.

    Benettin's method on the linearised dynamics (free flight, collision time, collision map with the wall's
    curvature and the spin), along each of run.trajectories trajectories of CONFIG for run.collisions collisions.
    Coordinates: position, R√κ·orientation, velocity, R√κ·spin (6 exponents in 2D, 12 in 3D)."""
    from ..api import StopFlag
    cluster = {"scheduler": scheduler, "slices": slices, "task_collisions": None}
    began = time.perf_counter()
    stop = StopFlag(pending=pending_signal)      # never running: every signal raises KeyboardInterrupt, and stop.signum says it came
    try:
        with ending_on_signals(stop):
            _lyapunov(config, collisions, trajectories, seed, sets, segments, warmup, as_json, cluster,
                      quiet or as_json, began, exponents, threshold)
    except UserError as exc:
        report_and_exit(exc, debug)


def _lyapunov(config, collisions, trajectories, seed, sets, segments, warmup, as_json, cluster, quiet, began,
              exponents=None, threshold=None):
    """``quiet``: no summary line (nor with --json: its output is the JSON object alone, for programs that read
    both streams)."""
    from ..cluster import ClusterError
    from ..config import load as config_load
    from ..dynamics import REGULAR_THRESHOLD
    from ..dynamics import lyapunov as spectrum

    check_cluster_options(cluster)
    if threshold is None:
        threshold = REGULAR_THRESHOLD
    elif not (math.isfinite(threshold) and threshold > 0):
        raise UserError(None, "--threshold", f"must be a positive rate (per unit time), not {threshold}")

    overrides = {k: v for k, v in (("collisions", collisions), ("trajectories", trajectories), ("seed", seed))
                 if v is not None}
    changes = parse_sets(sets)
    with user_errors():
        exp = config_load(config, overrides, changes=changes, label="--set")
    N = exp.run.collisions
    if warmup is not None and warmup >= N:
        raise UserError(None, "--warmup", f"{warmup} leaves no collisions of the {N} to measure")
    if N - (N // 10 if warmup is None else warmup) < segments:
        raise UserError(None, "--segments", f"more segments ({segments}) than measured collisions")
    from ..tangent import tangent_dimension
    d = tangent_dimension(exp.dimension)
    if exponents is not None and not 1 <= exponents <= d:
        raise UserError(None, "--exponents", f"must be from 1 to {d} (the dimension of the phase space), "
                                             f"not {exponents}")
    from ..dynamics import TANGENT_BYTES
    check_memory(exp, overrides, extra=TANGENT_BYTES)
    with connect(cluster) as on:     # an unreachable scheduler is a user error, said before any work
        watch_compiles()
        try:
            result = spectrum(exp, segments=segments, warmup=warmup, scheduler=on, exponents=exponents)
        except ValueError as exc:   # every trajectory left the table (exits, a wedge's escapes) before measuring
            raise UserError(config, None, str(exc)) from None
        except ClusterError as exc:     # the cluster failed mid-run: not the user's input, exit 1
            click.echo(f"rbx: {exc}; nothing computed", err=True)
            raise SystemExit(1) from None
    warn_repeated(exp, overrides, changes)        # after every refusal: a user error stays one line
    said = (f"lyapunov: {plural(len(result.time), 'trajectory')} × {plural(exp.run.collisions, 'collision')} in "
            f"{duration(time.perf_counter() - began)}" + (f" ({compile_note()})" if compile_note() else ""))
    from ..ensembles import start_groups
    group = start_groups(exp)
    copies = len(result.time) > 1 and group is not None and len(set(group.tolist())) == 1
    if as_json:
        out = result.to_dict(threshold)
        if copies:      # copies of one orbit (warned about above): no share, no interval
            out["regular_share"].update(share=None, low=None, high=None, copies_of_one_orbit=True)
        click.echo(json.dumps(out))
        return
    click.echo(f"Lyapunov spectrum (per unit time): {result.title}")
    M, measured = len(result.time), result.measured()
    unmeasured = (f" ({M - measured} of them left the table during their warm-up and measured nothing)"
                  if measured < M else "")
    click.echo(f"{plural(M, 'trajectory')}{unmeasured}, {plural(int(result.collisions.sum()), 'collision')} "
               f"measured over time "
               f"{result.time.sum():.6g} (after {result.warmup} warm-up collisions each, which are not counted)")
    click.echo(f"  (±: one {_get('lyapunov').error}, {_get('lyapunov').level})")
    for k, (lam, err) in enumerate(zip(result.exponents, result.stderr), 1):
        click.echo(f"  λ{k:<2} = {_six(lam, True)} ± {_six(err)}")
    if len(result.exponents) == d:
        click.echo(f"  sum = {result.exponents.sum(): .3e}")
    else:
        click.echo(f"  (the {len(result.exponents)} leading of {d})")
    tau = float(np.sum(result.time)) / max(1, int(np.sum(result.collisions)))
    click.echo(f"per collision (× the mean time between collisions, {tau:.6g}):")
    for k, (lam, err) in enumerate(zip(result.per_collision(), result.per_collision(result.stderr)), 1):
        click.echo(f"  λ{k:<2} = {_six(lam, True)} ± {_six(err)}")
    share, low, high = result.regular_share(threshold)
    if copies:
        # copies of one orbit (warned about above): one orbit, regular or not; no share, no interval
        lam1 = result.per_trajectory[:, 0]
        lam1 = lam1[np.isfinite(lam1)]
        if len(lam1):
            # as the share counts it: an orbit that left through an exit is not a regular one
            kind = "regular" if result.regular(threshold)[0] else "not regular"
            click.echo(f"regular orbits (own λ1 < {threshold:g} per unit time): one orbit, run as {M} copies: {kind} (own "
                       f"λ1 = {lam1[0]:.6f}); copies give no share and no interval")
    elif len(result.time) > 1:
        regular, counted = result.regular(threshold)
        of = (f"{regular} of the {measured} measured (the other {M - measured} left the table during their "
              "warm-up)" if measured < M else f"{regular} of {measured}")
        if counted < measured:      # copies of one orbit count once in the share
            of = f"{regular} of the {counted} distinct orbits among the {measured} measured"
            measured = counted
        click.echo(f"regular orbits (own λ1 < {threshold:g} per unit time): {of}, share {share:.3f} "
                   f"(Wilson interval, z = 1, {_get('regular_share').level}: {low:.3f} … {high:.3f})")
        if 0 < regular < measured:
            click.echo("the exponents above pool the regular and the chaotic orbits; each orbit's own exponents: "
                       "--json (per_trajectory)")
        elif regular == measured > 0:
            per = float(result.per_collision()[0])
            if per < REGULAR_THRESHOLD:
                # an integrable table's λ1 was read as a positive exponent, its bar 7 standard errors above 0
                click.echo("every orbit is regular: their λ1 falls as log t / t, so the values above are finite-time "
                           "ones (they shrink with longer runs) and the ± is their spread, not that bias")
            else:       # a chaotic table of another scale (100 times larger): the threshold is in the table's units
                click.echo(f"every orbit is below the threshold, but λ1 per collision is {per:.3g}: the threshold is "
                           "a rate per unit time in this table's units; give --threshold in them")
    if result.ended is not None and result.ended.any():
        click.echo(f"{plural(int(result.ended.sum()), 'trajectory')} left the table (an exit or an escape) before "
                   "the end")
    summary(quiet, said)



def _six(x, signed=False):
    """A number with 6 decimals, or 6 digits after a power of ten from 1e6 up (speeds near 1e150 printed exponents
    of 150 digits)."""
    x = float(x)
    if abs(x) >= 1e6:
        return f"{x: .6e}" if signed else f"{x:.6e}"
    return f"{x: .6f}" if signed else f"{x:.6f}"


def _get(name):
    """The observable ``name``'s record (what its error is and the level it covers, as a study's figure says)."""
    from ..observables import get
    return get(name)
