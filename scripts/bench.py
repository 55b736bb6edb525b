"""Collisions per second with nothing recorded, rbx against a minimal hand-written njit loop for the same scene
(our proxy for the speed limit). Writes docs/benchmarks.md.

    python scripts/bench.py [--collisions N] [--repeats K] [--out docs/benchmarks.md]
"""
import argparse
import os
import platform
import statistics
import sys
import time

import numba
import numpy as np

from rbx import config
from rbx.simulate import MemorySink, Simulation

KAPPA, R = 0.5, 0.1


@numba.njit(cache=True)
def strip_loop(x, y, vx, vy, w, width, N):
    """Rough disc in a strip: the walls are known from the sign of vy."""
    a2, sc = 2 * KAPPA / (1 + KAPPA), 1 / (KAPPA * R)
    t = 0.0
    for _ in range(N):
        if vy > 0:
            tau, y, s = (width - R - y) / vy, width - R, 1.0
        else:
            tau, y, s = (R - y) / vy, R, -1.0
        x += tau * vx
        t += tau
        dv = -a2 * (vx - w * s * R)        # slip velocity along x; ν = (0, −s), r = (0, sR)
        vx += dv
        vy = -vy
        w -= sc * s * dv
    return x + y + vx + vy + w + t


@numba.njit(cache=True)
def circle_loop(x, y, vx, vy, w, rho, N):
    """Rough disc in a circle of radius rho (shrunk): larger root of |a + τv|² = ρ²."""
    a2, sc = 2 * KAPPA / (1 + KAPPA), 1 / (KAPPA * R)
    t = 0.0
    for _ in range(N):
        b = x * vx + y * vy
        vv = vx * vx + vy * vy
        c = x * x + y * y - rho * rho
        tau = (np.sqrt(b * b - vv * c) - b) / vv
        x += tau * vx
        y += tau * vy
        t += tau
        m = 1.0 / np.sqrt(x * x + y * y)
        nx, ny = -x * m, -y * m
        vn = vx * nx + vy * ny
        ux, uy = vx + R * w * ny, vy - R * w * nx     # u = v + W r, W r = w J (−Rν)
        utx, uty = ux - vn * nx, uy - vn * ny
        dvx, dvy = -a2 * utx, -a2 * uty
        vx += dvx - 2 * vn * nx
        vy += dvy - 2 * vn * ny
        w += sc * (ny * dvx - dvy * nx)               # W₁₀ += (ν₁Δv₀ − Δv₁ν₀)/(κR)
    return x + y + vx + vy + w + t


@numba.njit(cache=True)
def plates_loop(x, y, z, vx, vy, vz, wx, wy, wz, gap, N):
    """Rough ball (rank 2) between plates."""
    a2, sc = 2 * KAPPA / (1 + KAPPA), 1 / (KAPPA * R)
    t = 0.0
    for _ in range(N):
        if vz > 0:
            tau, z, s = (gap - R - z) / vz, gap - R, 1.0
        else:
            tau, z, s = (R - z) / vz, R, -1.0
        x += tau * vx
        y += tau * vy
        t += tau
        # ν = (0, 0, −s), r = (0, 0, sR); u = v + ω × r
        ux, uy = vx + wy * s * R, vy - wx * s * R
        dvx, dvy = -a2 * ux, -a2 * uy
        vx += dvx
        vy += dvy
        vz = -vz
        # ω += r × Δv / (2λ) = sR (−Δv_y, Δv_x, 0) / (κR²)
        wx += -s * dvy * sc
        wy += s * dvx * sc
    return x + y + z + vx + vy + vz + wx + wy + wz + t


SCENES = {
    "strip": ({"kind": "strip", "width": 1.0}, [0.0, 0.5], [0.6, 0.8], 1.5,
              lambda N: strip_loop(0.0, 0.5, 0.6, 0.8, 1.5, 1.0, N)),
    "circle": ({"kind": "circle", "radius": 1.0}, [0.1, -0.2], [-0.3, 0.9], -2.0,
               lambda N: circle_loop(0.1, -0.2, -0.3, 0.9, -2.0, 1.0 - R, N)),
    "plates": ({"kind": "plates", "gap": 1.0}, [0, 0, 0.5], [0.2, -0.4, 0.7], [1.0, 0.5, -0.3],
               lambda N: plates_loop(0, 0, 0.5, 0.2, -0.4, 0.7, 1.0, 0.5, -0.3, 1.0, N)),
}


def rbx_config(name, N):
    table, pos, vel, spin, _ = SCENES[name]
    rank = 2 if len(pos) == 3 else 1
    return config.from_dict({"table": table, "boundary": {"default": {"rule": "constant", "rank": rank}},
                             "ball": {"radius": R, "inertia": KAPPA},
                             "initial": {"position": pos, "velocity": vel, "angular_velocity": spin},
                             "run": {"collisions": N}, "output": {"record": []}})


def time_rbx(cfg):
    sim = Simulation(cfg)
    t0 = time.perf_counter()
    sim.run(MemorySink())
    return time.perf_counter() - t0


def time_hand(fn, N):
    t0 = time.perf_counter()
    fn(N)
    return time.perf_counter() - t0


def machine():
    cpu = platform.processor() or "unknown CPU"
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return (f"{cpu}, {os.cpu_count()} cores; Python {platform.python_version()}, numba {numba.__version__}, "
            f"numpy {np.__version__}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--collisions", type=int, default=2_000_000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "..", "docs", "benchmarks.md"))
    args = ap.parse_args(argv)
    N = args.collisions
    rows = []
    for name, (*_, hand) in SCENES.items():
        cfg = rbx_config(name, N)
        time_rbx(rbx_config(name, 10))   # compile (or load from the cache) first
        hand(10)
        t_rbx = statistics.median(time_rbx(cfg) for _ in range(args.repeats))
        t_hand = statistics.median(time_hand(hand, N) for _ in range(args.repeats))
        rows.append((name, N / t_rbx, N / t_hand, t_hand / t_rbx))
        print(f"{name:8s} rbx {N / t_rbx:12.3e}/s  hand {N / t_hand:12.3e}/s  ratio {t_hand / t_rbx:.2f}",
              file=sys.stderr)
    cmd = "python scripts/bench.py " + " ".join(argv if argv is not None else sys.argv[1:])
    lines = ["# Benchmarks", "", "Generated by `" + cmd.strip() + "` (`make bench`); do not edit by hand.", "",
             f"Machine: {machine()}.", "",
             f"One trajectory, {N:,} collisions, nothing recorded (`record: []`), completely rough ball "
             f"(R = {R}, κ = {KAPPA}); median of {args.repeats} runs after compilation. The hand-written loop is a minimal "
             "njit loop for that scene alone (in this script): our proxy for the speed limit.", "",
             "| scene | rbx collisions/s | hand-written collisions/s | rbx / hand |", "|---|---|---|---|"]
    lines += [f"| {n} | {a:.3g} | {b:.3g} | {c:.2f} |" for n, a, b, c in rows]
    with open(args.out, "w") as fh:
        fh.write("\n".join(lines) + "\n")
    return rows


if __name__ == "__main__":
    main()
