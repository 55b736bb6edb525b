"""How fast rbx is, measured: collisions per second per scene and rule, against minimal hand-written njit loops,
the whole `rbx simulate` command against a minimal standalone njit program (scripts/minimal_loop.py), the cost of
each recorded field (in memory and to HDF5 through the CLI), ensembles on 1 and 2 threads, compile
time against the on-disk cache, the numerical variants, a public peer, and what each skip of docs/reference.md §7
saves. Writes docs/benchmarks.md and its plots docs/benchmarks-*.png (`make bench`).

    python scripts/bench.py [--quick] [--out docs/benchmarks.md] [--repeats K] [--seconds S] [--collisions N]
                            [--process-collisions N]

Every timing is ``time.perf_counter`` around the work alone (``Simulation.run``; the whole ``rbx simulate``
command for the CLI), after a warm-up run of the same configuration (compiled or loaded from the cache), with the
number of collisions grown until one run lasts at least ``--seconds``; the table shows the median of ``--repeats``
runs. ``--quick`` runs everything at tiny sizes (for tests/test_bench_smoke.py): its numbers mean nothing.
"""
import argparse
import dataclasses
import math
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass

import numba
import numpy as np
import yaml

from rbx import config
from rbx.model import RECORD_FIELDS, RENORMALIZE_EVERY
from rbx.rng import draw_bits, uniform
from rbx.simulation import MemorySink, Simulation

# the rough strip and plates (section 3's standalone program) and their pieces, shared with the loops below
from minimal_loop import A2, KAPPA, R, SC, plates_loop, plates_rough, slab_wall, strip_loop, strip_rough


# ---- minimal hand-written loops: our proxy for the speed limit of each scene ---------------------------------------
# The loops share the pieces that compile to the same code (the slab's wall and rough maps of minimal_loop.py,
# _map2, _map3, rbx.rng's draws); the Sinai and L loops write their wall and disc tests out: as shared helpers
# (a disc time returning inf, a side normal by kind) the hand loops ran slower (Sinai 19 -> 21 ns, L 9.9 -> 13.1
# ns per collision), which would flatter rbx's ratio.
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
def rectangle_loop(x, y, vx, vy, width, height, N):
    """Specular disc in a rectangle [0, width] × [0, height]: the nearer of the two walls ahead."""
    t = 0.0
    for _ in range(N):
        tx = (width - R - x) / vx if vx > 0 else (R - x) / vx
        ty = (height - R - y) / vy if vy > 0 else (R - y) / vy
        tau = min(tx, ty)
        x += tau * vx
        y += tau * vy
        t += tau
        if tau == ty:
            vy = -vy
        else:
            vx = -vx
    return x + y + vx + vy + t


@numba.njit(cache=True)
def box_loop(x, y, z, vx, vy, vz, lx, ly, lz, N):
    """Specular ball in a box [0, lx] × [0, ly] × [0, lz]: the nearest of the three walls ahead."""
    t = 0.0
    for _ in range(N):
        tx = (lx - R - x) / vx if vx > 0 else (R - x) / vx
        ty = (ly - R - y) / vy if vy > 0 else (R - y) / vy
        tz = (lz - R - z) / vz if vz > 0 else (R - z) / vz
        tau = min(tx, ty, tz)
        x += tau * vx
        y += tau * vy
        z += tau * vz
        t += tau
        if tau == tx:
            vx = -vx
        elif tau == ty:
            vy = -vy
        else:
            vz = -vz
    return x + y + z + vx + vy + vz + t


@numba.njit(cache=True, inline="always")
def _map2(vx, vy, w, nx, ny, rough):
    """The 2D collision map at a wall of inward normal (nx, ny): specular, or completely rough."""
    vn = vx * nx + vy * ny
    if not rough:
        return vx - 2 * vn * nx, vy - 2 * vn * ny, w
    a2, sc = 2 * KAPPA / (1 + KAPPA), 1 / (KAPPA * R)
    ux, uy = vx + R * w * ny, vy - R * w * nx     # u = v + W r, r = −Rν
    dvx, dvy = -a2 * (ux - vn * nx), -a2 * (uy - vn * ny)
    return vx + dvx - 2 * vn * nx, vy + dvy - 2 * vn * ny, w + sc * (ny * dvx - dvy * nx)


@numba.njit(cache=True)
def sinai_loop(x, y, vx, vy, w, width, height, cx, cy, rho, rough, N):
    """A disc in a Sinai billiard: the rectangle [0, width] × [0, height] and a scatterer of grown radius rho about
    (cx, cy); the nearer of the two walls ahead and the scatterer's smaller root."""
    t = 0.0
    for _ in range(N):
        tx = (width - R - x) / vx if vx > 0 else (R - x) / vx
        ty = (height - R - y) / vy if vy > 0 else (R - y) / vy
        dx, dy = x - cx, y - cy
        b = dx * vx + dy * vy
        tau, kind = (tx, 0) if tx < ty else (ty, 1)
        if b < 0.0:
            vv = vx * vx + vy * vy
            c = (np.sqrt(dx * dx + dy * dy) - rho) * (np.sqrt(dx * dx + dy * dy) + rho)
            disc = b * b - vv * c
            if disc > 0.0:
                td = c / (np.sqrt(disc) - b)
                if td < tau:
                    tau, kind = max(td, 0.0), 2
        x += tau * vx
        y += tau * vy
        t += tau
        if kind == 0:
            nx, ny = (-1.0, 0.0) if vx > 0 else (1.0, 0.0)
        elif kind == 1:
            nx, ny = (0.0, -1.0) if vy > 0 else (0.0, 1.0)
        else:
            m = 1.0 / np.sqrt((x - cx) ** 2 + (y - cy) ** 2)
            nx, ny = (x - cx) * m, (y - cy) * m
        vx, vy, w = _map2(vx, vy, w, nx, ny, rough)
    return x + y + vx + vy + (w if rough else 0.0) + t


@numba.njit(cache=True)
def sinai_tangent_loop(x, y, vx, vy, width, height, cx, cy, rho, N):
    """The yardstick of the tangent loop: the specular Sinai table (as :func:`sinai_loop`) with Benettin's method on
    its 4 × 4 reduced map (δa, δv): four tangent vectors (rows of Y) through each flight (δa += τδv) and collision
    (δt = −ν·δa/ν·v, z = δa + vδt, δν = z_⊥/ρ on the scatterer, δv' = δv − 2(δv·ν + v·δν)ν − 2(v·ν)δν,
    δa' = z − v'δt), Gram–Schmidt twice after every collision -> (sum of log-stretches of the first vector, time)."""
    Y = np.eye(4)
    y4 = np.zeros(4)
    tmp = np.zeros(4)
    lsum = 0.0
    t = 0.0
    for _ in range(N):
        tx = (width - R - x) / vx if vx > 0 else (R - x) / vx
        ty = (height - R - y) / vy if vy > 0 else (R - y) / vy
        dx, dy = x - cx, y - cy
        b = dx * vx + dy * vy
        tau, kind = (tx, 0) if tx < ty else (ty, 1)
        if b < 0.0:
            vv = vx * vx + vy * vy
            c = (np.sqrt(dx * dx + dy * dy) - rho) * (np.sqrt(dx * dx + dy * dy) + rho)
            disc = b * b - vv * c
            if disc > 0.0:
                td = c / (np.sqrt(disc) - b)
                if td < tau:
                    tau, kind = max(td, 0.0), 2
        x += tau * vx
        y += tau * vy
        t += tau
        if kind == 0:
            nx, ny = (-1.0, 0.0) if vx > 0 else (1.0, 0.0)
        elif kind == 1:
            nx, ny = (0.0, -1.0) if vy > 0 else (0.0, 1.0)
        else:
            m = 1.0 / np.sqrt((x - cx) ** 2 + (y - cy) ** 2)
            nx, ny = (x - cx) * m, (y - cy) * m
        vn = vx * nx + vy * ny
        ux, uy = vx - 2 * vn * nx, vy - 2 * vn * ny
        for k in range(4):
            ax, ay = Y[k, 0] + tau * Y[k, 2], Y[k, 1] + tau * Y[k, 3]
            dt = -(nx * ax + ny * ay) / vn
            zx, zy = ax + vx * dt, ay + vy * dt
            dnx, dny = 0.0, 0.0
            if kind == 2:                       # J = (I − ννᵀ)/ρ
                zn = zx * nx + zy * ny
                dnx, dny = (zx - zn * nx) / rho, (zy - zn * ny) / rho
            dvn = Y[k, 2] * nx + Y[k, 3] * ny + vx * dnx + vy * dny
            wx = Y[k, 2] - 2 * dvn * nx - 2 * vn * dnx
            wy = Y[k, 3] - 2 * dvn * ny - 2 * vn * dny
            Y[k, 0], Y[k, 1], Y[k, 2], Y[k, 3] = zx - ux * dt, zy - uy * dt, wx, wy
        vx, vy = ux, uy
        for k in range(4):
            for i in range(4):
                y4[i] = Y[k, i]
            for _p in range(2):
                for q in range(k):
                    tmp[q] = Y[q, 0] * y4[0] + Y[q, 1] * y4[1] + Y[q, 2] * y4[2] + Y[q, 3] * y4[3]
                for q in range(k):
                    for i in range(4):
                        y4[i] -= tmp[q] * Y[q, i]
            nrm = np.sqrt(y4[0] * y4[0] + y4[1] * y4[1] + y4[2] * y4[2] + y4[3] * y4[3])
            if k == 0:
                lsum += np.log(nrm)
            for i in range(4):
                Y[k, i] = y4[i] / nrm
    return lsum, t


@numba.njit(cache=True)
def stadium_loop(x, y, vx, vy, w, length, rho, rough, N):
    """A disc in a stadium (caps of shrunk radius rho about (0, 0) and (length, 0)): it is convex, so the line
    leaves it once: on a flat wall if it crosses y = ±rho over [0, length], else on the cap of that side."""
    t = 0.0
    for _ in range(N):
        tau = np.inf
        if vy != 0.0:
            tau = ((rho if vy > 0 else -rho) - y) / vy
        xh = x + tau * vx
        if 0.0 <= xh <= length:
            nx, ny = 0.0, (-1.0 if vy > 0 else 1.0)
            x, y = xh, (rho if vy > 0 else -rho)
        else:
            cx = 0.0 if (xh < 0.0 if vy != 0.0 else vx < 0) else length
            dx = x - cx
            b = dx * vx + y * vy
            vv = vx * vx + vy * vy
            c = (np.sqrt(dx * dx + y * y) - rho) * (np.sqrt(dx * dx + y * y) + rho)
            disc = max(b * b - vv * c, 0.0)      # the centre may be outside this cap's circle (between the caps)
            tau = -c / (b + np.sqrt(disc)) if b > 0.0 else (np.sqrt(disc) - b) / vv
            x += tau * vx
            y += tau * vy
            m = 1.0 / np.sqrt((x - cx) ** 2 + y * y)
            nx, ny = -(x - cx) * m, -y * m
        t += tau
        vx, vy, w = _map2(vx, vy, w, nx, ny, rough)
    return x + y + vx + vy + (w if rough else 0.0) + t


@numba.njit(cache=True)
def rectangle_rough_loop(x, y, vx, vy, w, width, height, N):
    """Rough disc in a rectangle [0, width] × [0, height]: :func:`rectangle_loop`'s wall, the rough 2D map."""
    t = 0.0
    for _ in range(N):
        tx = (width - R - x) / vx if vx > 0 else (R - x) / vx
        ty = (height - R - y) / vy if vy > 0 else (R - y) / vy
        tau = min(tx, ty)
        x += tau * vx
        y += tau * vy
        t += tau
        if tau == ty:
            nx, ny = 0.0, (-1.0 if vy > 0 else 1.0)
        else:
            nx, ny = (-1.0 if vx > 0 else 1.0), 0.0
        vx, vy, w = _map2(vx, vy, w, nx, ny, True)
    return x + y + vx + vy + w + t


@numba.njit(cache=True, inline="always")
def _map3(vx, vy, vz, wx, wy, wz, nx, ny, nz):
    """The completely rough 3D map (rank 2) at a wall of inward normal ν = (nx, ny, nz): u = v + ω × r with
    r = −Rν, Δv = −2α(u − (v·ν)ν), v' = v + Δv − 2(v·ν)ν, ω' = ω + r × Δv/(κR²)."""
    a2, sc = 2 * KAPPA / (1 + KAPPA), 1 / (KAPPA * R)
    vn = vx * nx + vy * ny + vz * nz
    ux = vx - R * (wy * nz - wz * ny) - vn * nx
    uy = vy - R * (wz * nx - wx * nz) - vn * ny
    uz = vz - R * (wx * ny - wy * nx) - vn * nz
    dvx, dvy, dvz = -a2 * ux, -a2 * uy, -a2 * uz
    return (vx + dvx - 2 * vn * nx, vy + dvy - 2 * vn * ny, vz + dvz - 2 * vn * nz,
            wx - sc * (ny * dvz - nz * dvy), wy - sc * (nz * dvx - nx * dvz), wz - sc * (nx * dvy - ny * dvx))


@numba.njit(cache=True)
def box_rough_loop(x, y, z, vx, vy, vz, wx, wy, wz, lx, ly, lz, N):
    """Rough ball (rank 2) in a box [0, lx] × [0, ly] × [0, lz]: :func:`box_loop`'s wall, the rough 3D map."""
    t = 0.0
    for _ in range(N):
        tx = (lx - R - x) / vx if vx > 0 else (R - x) / vx
        ty = (ly - R - y) / vy if vy > 0 else (R - y) / vy
        tz = (lz - R - z) / vz if vz > 0 else (R - z) / vz
        tau = min(tx, ty, tz)
        x += tau * vx
        y += tau * vy
        z += tau * vz
        t += tau
        nx = ny = nz = 0.0
        if tau == tx:
            nx = -1.0 if vx > 0 else 1.0
        elif tau == ty:
            ny = -1.0 if vy > 0 else 1.0
        else:
            nz = -1.0 if vz > 0 else 1.0
        vx, vy, vz, wx, wy, wz = _map3(vx, vy, vz, wx, wy, wz, nx, ny, nz)
    return x + y + z + vx + vy + vz + wx + wy + wz + t


@numba.njit(cache=True)
def lpolygon_loop(x, y, vx, vy, w, rough, N):
    """A disc in the L polygon of SCENES, (0,0) (2,0) (2,2) (1,2) (1,1) (0,1), shrunk by R (rbx.geometry.polygon):
    the four outer sides as lines (their extensions lie outside the table: a flight meets another wall first),
    the two inner sides as segments (x = 1 + R for y ≥ 1, y = 1 − R for x ≤ 1: their extensions cross the table)
    and the reflex corner (1, 1) as a disc of radius R hit from outside (its smaller root; only its quarter in
    x ≥ 1, y ≤ 1 can be reached)."""
    t = 0.0
    for _ in range(N):
        tx = (2.0 - R - x) / vx if vx > 0 else (R - x) / vx
        ty = (2.0 - R - y) / vy if vy > 0 else (R - y) / vy
        tau, kind = (tx, 0) if tx < ty else (ty, 1)
        if vx < 0.0 and x >= 1.0 + R:                   # the inner side x = 1 + R, normal +x, for y ≥ 1
            ti = (1.0 + R - x) / vx
            if ti < tau and y + ti * vy >= 1.0:
                tau, kind = ti, 2
        if vy > 0.0 and y <= 1.0 - R:                   # the inner side y = 1 − R, normal −y, for x ≤ 1
            ti = (1.0 - R - y) / vy
            if ti < tau and x + ti * vx <= 1.0:
                tau, kind = ti, 3
        dx, dy = x - 1.0, y - 1.0
        b = dx * vx + dy * vy
        if b < 0.0:                                     # the corner: approaching its centre
            vv = vx * vx + vy * vy
            c = (np.sqrt(dx * dx + dy * dy) - R) * (np.sqrt(dx * dx + dy * dy) + R)
            disc = b * b - vv * c
            if disc > 0.0:
                td = c / (np.sqrt(disc) - b)
                if td < tau:
                    tau, kind = max(td, 0.0), 4
        x += tau * vx
        y += tau * vy
        t += tau
        if kind == 0:
            nx, ny = (-1.0, 0.0) if vx > 0 else (1.0, 0.0)
        elif kind == 1:
            nx, ny = (0.0, -1.0) if vy > 0 else (0.0, 1.0)
        elif kind == 2:
            nx, ny = 1.0, 0.0
        elif kind == 3:
            nx, ny = 0.0, -1.0
        else:
            m = 1.0 / np.sqrt((x - 1.0) ** 2 + (y - 1.0) ** 2)
            nx, ny = (x - 1.0) * m, (y - 1.0) * m
        vx, vy, w = _map2(vx, vy, w, nx, ny, rough)
    return x + y + vx + vy + (w if rough else 0.0) + t


@numba.njit(cache=True)
def wedge_loop(x, y, vx, vy, w, n1x, n1y, N):
    """Rough disc in a wedge: the walls y = R (normal (0, 1)) and x·ν₁ = R (normal ν₁ = (n1x, n1y)), the nearer
    of those ahead; a division only for a wall ahead (a trajectory that escapes gets an infinite flight: the
    checksum is then not finite). From the scene's start the orbit settles on a 2-cycle between the two walls."""
    t = 0.0
    for _ in range(N):
        tau, nx, ny = np.inf, 0.0, 1.0
        if vy < 0:
            tau = (R - y) / vy
        vn1 = vx * n1x + vy * n1y
        if vn1 < 0:
            t1 = (R - (x * n1x + y * n1y)) / vn1
            if t1 < tau:
                tau, nx, ny = t1, n1x, n1y
        x += tau * vx
        y += tau * vy
        t += tau
        vx, vy, w = _map2(vx, vy, w, nx, ny, True)
    return x + y + vx + vy + w + t


@numba.njit(cache=True)
def strip_hemisphere_loop(x, y, vx, vy, w, width, N):
    """Disc in a strip under the hemisphere rule (axis y in the body frame): rough iff the contact point
    −ν rotated by −θ has a positive y component, i.e. iff ν_y cos θ < 0; θ += τω in flight. The sign of cos θ
    is read off the parity of ⌊θ/π + ½⌋ (a multiplication and a floor instead of a cosine)."""
    inv_pi = 1.0 / np.pi
    t = 0.0
    th = 0.0
    for _ in range(N):
        tau, y, s = slab_wall(y, vy, width)
        x += tau * vx
        t += tau
        th += tau * w
        cos_pos = (np.int64(np.floor(th * inv_pi + 0.5)) & 1) == 0
        vy = -vy
        if cos_pos == (s > 0):                  # ν_y = −s: rough iff s·cos θ > 0
            vx, w = strip_rough(vx, w, s)
    return x + y + vx + vy + w + t


@numba.njit(cache=True, inline="always")
def turn(ax, ay, az, wx, wy, wz, sn, c1):
    """The vector a turned by exp(τW), Rodrigues' formula with sn = sin φ/|ω|, c1 = (1 − cos φ)/|ω|², φ = τ|ω|:
    a + sn ω × a + c1 ω × (ω × a)."""
    cx, cy, cz = wy * az - wz * ay, wz * ax - wx * az, wx * ay - wy * ax       # ω × a
    return (ax + sn * cx + c1 * (wy * cz - wz * cy), ay + sn * cy + c1 * (wz * cx - wx * cz),
            az + sn * cz + c1 * (wx * cy - wy * cx))


@numba.njit(cache=True, inline="always")
def turn_coefficients(wx, wy, wz, tau):
    """(φ ≠ 0, sin φ/|ω|, (1 − cos φ)/|ω|²) of a flight of τ at spin ω, φ = τ|ω| (:func:`turn`)."""
    om = np.sqrt(wx * wx + wy * wy + wz * wz)
    phi = tau * om
    if phi == 0.0:
        return False, 0.0, 0.0
    return True, np.sin(phi) / om, (1.0 - np.cos(phi)) / (om * om)


@numba.njit(cache=True)
def plates_hemisphere_loop(x, y, z, vx, vy, vz, wx, wy, wz, gap, N):
    """Ball between plates under the hemisphere rule (axis z in the body frame): rough iff ν·(A e_z) < 0. Only
    the body axis b = A e_z is followed, b ← exp(τW) b by Rodrigues' formula (rbx turns the whole matrix A)."""
    t = 0.0
    bx, by, bz = 0.0, 0.0, 1.0
    for _ in range(N):
        tau, z, s = slab_wall(z, vz, gap)
        x += tau * vx
        y += tau * vy
        t += tau
        turning, sn, c1 = turn_coefficients(wx, wy, wz, tau)
        if turning:
            bx, by, bz = turn(bx, by, bz, wx, wy, wz, sn, c1)
        vz = -vz
        if s * bz > 0.0:                        # ν_z = −s: rough iff ν_z b_z < 0
            vx, vy, wx, wy = plates_rough(vx, vy, wx, wy, s)
    return x + y + z + vx + vy + vz + wx + wy + wz + t


@numba.njit(cache=True)
def plates_hemisphere_orientation_loop(x, y, z, vx, vy, vz, wx, wy, wz, gap, N):
    """The plates under the hemisphere rule as plates_hemisphere_loop, but keeping the whole orientation A (nine
    numbers, as a program that reports or saves the orientation must): each column of A turns by :func:`turn`,
    and the test reads A's third column. Returns the same sum as the other loops plus the sum of A's entries."""
    t = 0.0
    a00, a01, a02, a10, a11, a12, a20, a21, a22 = 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0
    for _ in range(N):
        tau, z, s = slab_wall(z, vz, gap)
        x += tau * vx
        y += tau * vy
        t += tau
        turning, sn, c1 = turn_coefficients(wx, wy, wz, tau)
        if turning:
            a00, a10, a20 = turn(a00, a10, a20, wx, wy, wz, sn, c1)
            a01, a11, a21 = turn(a01, a11, a21, wx, wy, wz, sn, c1)
            a02, a12, a22 = turn(a02, a12, a22, wx, wy, wz, sn, c1)
        vz = -vz
        if s * a22 > 0.0:                       # ν_z = −s: rough iff ν_z (A e_z)_z < 0
            vx, vy, wx, wy = plates_rough(vx, vy, wx, wy, s)
    return (x + y + z + vx + vy + vz + wx + wy + wz + t
            + (a00 + a01 + a02 + a10 + a11 + a12 + a20 + a21 + a22))


@numba.njit(cache=True)
def strip_random_loop(x, y, vx, vy, w, width, key, N):
    """Disc in a strip under the random rule: draw k of the trajectory's stream (rbx.rng) picks specular (u < ½)
    or rough. u = (bits >> 11)·2⁻⁵³ < ½ iff the top bit is 0: no conversion to a float."""
    t = 0.0
    k = np.uint64(0)
    for _ in range(N):
        tau, y, s = slab_wall(y, vy, width)
        x += tau * vx
        t += tau
        vy = -vy
        if draw_bits(key, k) >> np.uint64(63):
            vx, w = strip_rough(vx, w, s)
        k += np.uint64(1)
    return x + y + vx + vy + w + t


@numba.njit(cache=True)
def plates_random_loop(x, y, z, vx, vy, vz, wx, wy, wz, gap, key, p1, p2, dirs, N):
    """Ball between plates under the random rule: draw k (rbx.rng) picks one of three rank-1 directions dirs[i]
    (in the plates' tangent axes x, y) by the cumulative probabilities p1, p2; the slip velocity is projected on
    it (rbx.physics.collide_axis at rank 1)."""
    t = 0.0
    k = np.uint64(0)
    for _ in range(N):
        tau, z, s = slab_wall(z, vz, gap)
        x += tau * vx
        y += tau * vy
        t += tau
        vz = -vz
        u = uniform(key, k)
        k += np.uint64(1)
        i = 0 if u < p1 else (1 if u < p2 else 2)
        ex, ey = dirs[i, 0], dirs[i, 1]
        ux, uy = vx + wy * s * R, vy - wx * s * R
        p = ux * ex + uy * ey
        dvx, dvy = -A2 * p * ex, -A2 * p * ey
        vx += dvx
        vy += dvy
        wx += -s * dvy * SC
        wy += s * dvx * SC
    return x + y + z + vx + vy + vz + wx + wy + wz + t


@numba.njit(cache=True, inline="always")
def _bounce3(vx, vy, vz, wx, wy, wz, nx, ny, nz, rough):
    """The 3D collision map at a wall of inward normal ν: completely rough (:func:`_map3`), or specular."""
    if rough:
        return _map3(vx, vy, vz, wx, wy, wz, nx, ny, nz)
    vn = 2.0 * (vx * nx + vy * ny + vz * nz)
    return vx - vn * nx, vy - vn * ny, vz - vn * nz, wx, wy, wz


@numba.njit(cache=True)
def sphere_loop(x, y, z, vx, vy, vz, wx, wy, wz, rho, rough, N):
    """A ball (rough: rank 2) in a sphere of shrunk radius rho: :func:`circle_loop` in 3D."""
    t = 0.0
    for _ in range(N):
        b = x * vx + y * vy + z * vz
        vv = vx * vx + vy * vy + vz * vz
        c = x * x + y * y + z * z - rho * rho
        tau = (np.sqrt(b * b - vv * c) - b) / vv
        x += tau * vx
        y += tau * vy
        z += tau * vz
        t += tau
        m = -1.0 / np.sqrt(x * x + y * y + z * z)
        vx, vy, vz, wx, wy, wz = _bounce3(vx, vy, vz, wx, wy, wz, x * m, y * m, z * m, rough)
    return x + y + z + vx + vy + vz + ((wx + wy + wz) if rough else 0.0) + t


@numba.njit(cache=True)
def cylinder_loop(x, y, z, vx, vy, vz, wx, wy, wz, rho, height, rough, N):
    """A ball (rough: rank 2) in a cylinder of axis z: the side (shrunk radius rho, the larger root across the
    axis) and the caps z = R, z = height − R (the sign of vz)."""
    t = 0.0
    for _ in range(N):
        tz = (height - R - z) / vz if vz > 0 else (R - z) / vz
        b = x * vx + y * vy
        vv = vx * vx + vy * vy
        c = x * x + y * y - rho * rho
        ts = (np.sqrt(b * b - vv * c) - b) / vv
        if ts < tz:
            tau = ts
        else:
            tau = tz
        x += tau * vx
        y += tau * vy
        z += tau * vz
        t += tau
        if ts < tz:
            m = -1.0 / np.sqrt(x * x + y * y)
            vx, vy, vz, wx, wy, wz = _bounce3(vx, vy, vz, wx, wy, wz, x * m, y * m, 0.0, rough)
        else:
            vx, vy, vz, wx, wy, wz = _bounce3(vx, vy, vz, wx, wy, wz, 0.0, 0.0, -1.0 if vz > 0 else 1.0, rough)
    return x + y + z + vx + vy + vz + ((wx + wy + wz) if rough else 0.0) + t


@numba.njit(cache=True)
def sinai3_loop(x, y, z, vx, vy, vz, wx, wy, wz, lx, ly, lz, cx, cy, cz, rho, rough, N):
    """A ball in a Sinai box [0, lx] × [0, ly] × [0, lz] with a sphere of grown radius rho about (cx, cy, cz):
    :func:`sinai_loop` in 3D (the nearest of the three sides ahead, the sphere's smaller root)."""
    t = 0.0
    for _ in range(N):
        tx = (lx - R - x) / vx if vx > 0 else (R - x) / vx
        ty = (ly - R - y) / vy if vy > 0 else (R - y) / vy
        tz = (lz - R - z) / vz if vz > 0 else (R - z) / vz
        tau, kind = (tx, 0) if tx < ty else (ty, 1)
        if tz < tau:
            tau, kind = tz, 2
        dx, dy, dz = x - cx, y - cy, z - cz
        b = dx * vx + dy * vy + dz * vz
        if b < 0.0:
            vv = vx * vx + vy * vy + vz * vz
            d = np.sqrt(dx * dx + dy * dy + dz * dz)
            c = (d - rho) * (d + rho)
            disc = b * b - vv * c
            if disc > 0.0:
                ts = c / (np.sqrt(disc) - b)
                if ts < tau:
                    tau, kind = max(ts, 0.0), 3
        x += tau * vx
        y += tau * vy
        z += tau * vz
        t += tau
        nx = ny = nz = 0.0
        if kind == 0:
            nx = -1.0 if vx > 0 else 1.0
        elif kind == 1:
            ny = -1.0 if vy > 0 else 1.0
        elif kind == 2:
            nz = -1.0 if vz > 0 else 1.0
        else:
            m = 1.0 / np.sqrt((x - cx) ** 2 + (y - cy) ** 2 + (z - cz) ** 2)
            nx, ny, nz = (x - cx) * m, (y - cy) * m, (z - cz) * m
        vx, vy, vz, wx, wy, wz = _bounce3(vx, vy, vz, wx, wy, wz, nx, ny, nz, rough)
    return x + y + z + vx + vy + vz + ((wx + wy + wz) if rough else 0.0) + t


@numba.njit(cache=True)
def lorentz_loop(x, y, vx, vy, w, lx, ly, rho, rough, N):
    """A disc in the periodic Lorentz gas of cell [0, lx] × [0, ly] with a scatterer of grown radius rho at each
    cell's centre, the position unfolded: from the cell of the start, the cells the flight crosses in turn (the
    side reached first: one addition per crossing), each cell's scatterer tested by its smaller root until one is
    hit (it lies inside its cell, so the first hit is the collision)."""
    t = 0.0
    vv = vx * vx + vy * vy
    for _ in range(N):
        i = np.floor(x / lx)
        j = np.floor(y / ly)
        tx = ((i + 1.0) * lx - x) / vx if vx > 0 else (i * lx - x) / vx
        ty = ((j + 1.0) * ly - y) / vy if vy > 0 else (j * ly - y) / vy
        si = 1.0 if vx > 0 else -1.0
        sj = 1.0 if vy > 0 else -1.0
        while True:
            dx, dy = x - (i + 0.5) * lx, y - (j + 0.5) * ly
            b = dx * vx + dy * vy
            if b < 0.0:
                d = np.sqrt(dx * dx + dy * dy)
                c = (d - rho) * (d + rho)
                disc = b * b - vv * c
                if disc > 0.0:
                    tau = max(c / (np.sqrt(disc) - b), 0.0)
                    break
            if tx < ty:
                i += si
                tx += lx / abs(vx)
            else:
                j += sj
                ty += ly / abs(vy)
        x += tau * vx
        y += tau * vy
        t += tau
        dx, dy = x - (i + 0.5) * lx, y - (j + 0.5) * ly
        m = 1.0 / np.sqrt(dx * dx + dy * dy)
        vx, vy, w = _map2(vx, vy, w, dx * m, dy * m, rough)
        vv = vx * vx + vy * vy
    return x + y + vx + vy + (w if rough else 0.0) + t


@numba.njit(cache=True)
def mushroom_loop(x, y, vx, vy, w, rc, half, h, rough, N):
    """A disc in the mushroom of cap radius rc on a stem [−half, half] × [−h, 0] (rbx.tables), shrunk by R: the
    cap's arc (radius rc − R about the origin, the larger root, where it lies above the floor), the floor
    y = R where |x| ≥ half, the stem's sides x = ±(half − R) below y = 0 and its bottom y = R − h, and the two
    reflex corners (±half, 0) as discs of radius R hit from outside (the smaller root). It is not convex: the
    nearest of the walls whose test passes."""
    rho, xs, yb = rc - R, half - R, R - h
    t = 0.0
    for _ in range(N):
        vv = vx * vx + vy * vy
        b = x * vx + y * vy
        d = np.sqrt(x * x + y * y)
        c = (d - rho) * (d + rho)
        disc = b * b - vv * c
        tau, kind = np.inf, -1
        if disc >= 0.0:
            ta = -c / (b + np.sqrt(disc)) if b > 0.0 else (np.sqrt(disc) - b) / vv
            if ta >= 0.0 and y + ta * vy >= R:
                tau, kind = ta, 0                       # the cap
        if vy < 0.0:
            if y >= R:                                  # the floor, either side of the stem
                tf = (R - y) / vy
                if tf < tau and abs(x + tf * vx) >= half:
                    tau, kind = tf, 1
            tb = (yb - y) / vy                          # the stem's bottom
            if tb < tau and abs(x + tb * vx) <= xs:
                tau, kind = tb, 1
        if vx > 0.0 and x <= xs:                        # the stem's right side
            ts = (xs - x) / vx
            if ts < tau and y + ts * vy <= 0.0:
                tau, kind = ts, 2
        elif vx < 0.0 and x >= -xs:                     # the stem's left side
            ts = (-xs - x) / vx
            if ts < tau and y + ts * vy <= 0.0:
                tau, kind = ts, 2
        for s in (-1.0, 1.0):                           # the rounded reflex corners
            dx = x - s * half
            bc = dx * vx + y * vy
            if bc < 0.0:
                dc = np.sqrt(dx * dx + y * y)
                cc = (dc - R) * (dc + R)
                dd = bc * bc - vv * cc
                if dd > 0.0:
                    tc = max(cc / (np.sqrt(dd) - bc), 0.0)
                    if tc < tau:
                        tau, kind = tc, 3 if s < 0 else 4
        x += tau * vx
        y += tau * vy
        t += tau
        if kind == 0:
            m = -1.0 / np.sqrt(x * x + y * y)
            nx, ny = x * m, y * m
        elif kind == 1:
            nx, ny = 0.0, (1.0 if vy < 0 else -1.0)
        elif kind == 2:
            nx, ny = (-1.0 if vx > 0 else 1.0), 0.0
        else:
            cx = -half if kind == 3 else half
            m = 1.0 / np.sqrt((x - cx) ** 2 + y * y)
            nx, ny = (x - cx) * m, y * m
        vx, vy, w = _map2(vx, vy, w, nx, ny, rough)
    return x + y + vx + vy + (w if rough else 0.0) + t


# ---- the scenes, rules and configs ----------------------------------------------------------------------------------
#: name -> (table, position, velocity, angular velocity): one explicit start per scene, well inside the table
SCENES = {
    "strip": ({"kind": "strip", "width": 1.0}, [0.0, 0.5], [0.6, 0.8], 1.5),
    "circle": ({"kind": "circle", "radius": 1.0}, [0.1, -0.2], [-0.3, 0.9], -2.0),
    "wedge60": ({"kind": "wedge", "angle_deg": 60}, [1.5, 0.2], [-0.2, 0.05], -3.0),
    "rectangle": ({"kind": "rectangle", "width": 2.0, "height": 1.0}, [0.5, 0.5], [0.83, 0.31], 0.7),
    "L-polygon": ({"kind": "polygon", "vertices": [[0, 0], [2, 0], [2, 2], [1, 2], [1, 1], [0, 1]]},
                  [0.5, 0.5], [0.83, 0.31], 0.7),
    # 3D: the horizontal spin is not perpendicular to the horizontal velocity (else the plates orbit stays in a plane)
    "plates": ({"kind": "plates", "gap": 1.0}, [0, 0, 0.5], [0.2, -0.4, 0.7], [1.0, -2.0, -0.3]),
    "box": ({"kind": "box", "size": [1.0, 1.3, 0.8]}, [0.5, 0.6, 0.4], [0.3, -0.5, 0.7], [1.0, -2.0, -0.3]),
    # the zoo (docs/reference.md §8)
    "stadium": ({"kind": "stadium", "radius": 0.5, "length": 1.0}, [0.5, 0.1], [0.83, 0.31], 0.7),
    "sinai": ({"kind": "sinai", "size": [2.0, 1.5], "radius": 0.4}, [0.3, 0.3], [0.83, 0.31], 0.7),
    "lorentz": ({"kind": "lorentz", "cell": [1.0, 1.0], "radius": 0.3}, [0.1, 0.1], [0.83, 0.31], 0.7),
    "mushroom": ({"kind": "mushroom", "cap_radius": 1.0, "stem_width": 0.6, "stem_height": 1.0}, [0.2, 0.5],
                 [0.83, 0.31], 0.7),
    "sinai3": ({"kind": "sinai", "size": [1.0, 1.3, 0.8], "radius": 0.2}, [0.2, 0.2, 0.2], [0.3, -0.5, 0.7],
               [1.0, -2.0, -0.3]),
    "sphere": ({"kind": "sphere", "radius": 1.0}, [0.1, 0.2, 0.3], [0.3, -0.5, 0.7], [1.0, -2.0, -0.3]),
    "cylinder": ({"kind": "cylinder", "radius": 1.0, "height": 1.5}, [0.1, 0.2, 0.7], [0.3, -0.5, 0.7],
                 [1.0, -2.0, -0.3]),
}
RULE_NAMES = ("specular", "rough", "hemisphere", "random")
#: the 3D random rule draws a rank-1 direction, which is fixed in a flat wall's tangent axes: not on curved walls
NOT_EXPRESSIBLE = {("sinai3", "random"), ("sphere", "random"), ("cylinder", "random")}


def rule(name, n):
    """The boundary rule ``name`` in dimension n (the same on every wall)."""
    smooth, rough = {"rule": "constant", "rank": 0}, {"rule": "constant", "rank": n - 1}
    if name == "specular":
        return smooth
    if name == "rough":
        return rough
    if name == "hemisphere":
        return {"rule": "hemisphere", "axis": [0, 1] if n == 2 else [0, 0, 1], "rough": rough, "smooth": smooth}
    if n == 2:   # random rank 0 / 1 with p = ½ (figure graphRandom)
        return {"rule": "random", "choices": [smooth, rough], "probabilities": [0.5, 0.5]}
    # random rank-1 direction among 0°, 60°, 120° (figure roughrank)
    return {"rule": "random", "probabilities": [1 / 3, 1 / 3, 1 - 2 / 3],
            "choices": [{"rule": "constant", "rank": 1, "direction_deg": d} for d in (0, 60, 120)]}


RULE_TEXT = {"specular": "rank 0 everywhere", "rough": "constant, completely rough (2D rank 1, 3D rank 2)",
             "hemisphere": "hemisphere rule (axis y / z in the body frame; rough: completely rough, smooth: rank 0)",
             "random": "2D: rank 0 or 1 with p = ½; 3D: rank 1 along 0°, 60° or 120°, drawn at every collision"}


def scene_dict(scene, rule_name="rough", record=(), every=1, trajectories=1, sample=False):
    """A config mapping (for ``config.from_dict`` or a YAML file); run.collisions is set by the caller."""
    table, pos, vel, spin = SCENES[scene]
    n = len(pos)
    initial = {"sample": "billiard"} if sample else {"position": pos, "velocity": vel, "angular_velocity": spin}
    out = {"record": list(record)}
    if record:
        out["every"] = every
    return {"table": table, "boundary": {"default": rule(rule_name, n)}, "ball": {"radius": R, "inertia": KAPPA},
            "initial": initial, "run": {"collisions": 1, "trajectories": trajectories, "seed": 0}, "output": out}


def rbx_config(name, N, rule_name="rough"):
    """The validated config of scene ``name``, one trajectory of N collisions, nothing recorded."""
    d = scene_dict(name, rule_name)
    d["run"]["collisions"] = N
    return config.from_dict(d, "<bench>")


def rules_key(seed=0, trajectory=0):
    """The key of the stream that a trajectory's random rules draw from (``Simulation.keys``; scene_dict's seed 0,
    its one trajectory 0) -> numpy uint64."""
    from rbx.rng import PURPOSE_RULES, stream_key
    return np.uint64(stream_key(seed, trajectory, PURPOSE_RULES))


#: the 3D random rule of :func:`rule` as the hand loop takes it: cumulative probabilities of its first two choices
#: (the last takes the rest) and its rank-1 directions in the plates' tangent axes x, y (rbx.model.roughness_direction)
RANDOM3 = (tuple(np.cumsum([1 / 3, 1 / 3, 1 - 2 / 3])[:2]),
           np.array([[math.cos(math.radians(d)), math.sin(math.radians(d))] for d in (0, 60, 120)]))

#: (scene, rule) -> hand-written loop of N collisions from the scene's start (returns a checksum of the final state)
HAND = {
    ("strip", "rough"): lambda N: strip_loop(0.0, 0.5, 0.6, 0.8, 1.5, 1.0, N),
    ("circle", "rough"): lambda N: circle_loop(0.1, -0.2, -0.3, 0.9, -2.0, 1.0 - R, N),
    ("plates", "rough"): lambda N: plates_loop(0, 0, 0.5, 0.2, -0.4, 0.7, 1.0, -2.0, -0.3, 1.0, N),
    ("rectangle", "specular"): lambda N: rectangle_loop(0.5, 0.5, 0.83, 0.31, 2.0, 1.0, N),
    ("box", "specular"): lambda N: box_loop(0.5, 0.6, 0.4, 0.3, -0.5, 0.7, 1.0, 1.3, 0.8, N),
    ("sinai", "specular"): lambda N: sinai_loop(0.3, 0.3, 0.83, 0.31, 0.7, 2.0, 1.5, 1.0, 0.75, 0.4 + R, False, N),
    ("sinai", "rough"): lambda N: sinai_loop(0.3, 0.3, 0.83, 0.31, 0.7, 2.0, 1.5, 1.0, 0.75, 0.4 + R, True, N),
    ("stadium", "specular"): lambda N: stadium_loop(0.5, 0.1, 0.83, 0.31, 0.7, 1.0, 0.5 - R, False, N),
    ("stadium", "rough"): lambda N: stadium_loop(0.5, 0.1, 0.83, 0.31, 0.7, 1.0, 0.5 - R, True, N),
    ("rectangle", "rough"): lambda N: rectangle_rough_loop(0.5, 0.5, 0.83, 0.31, 0.7, 2.0, 1.0, N),
    ("box", "rough"): lambda N: box_rough_loop(0.5, 0.6, 0.4, 0.3, -0.5, 0.7, 1.0, -2.0, -0.3, 1.0, 1.3, 0.8, N),
    ("L-polygon", "specular"): lambda N: lpolygon_loop(0.5, 0.5, 0.83, 0.31, 0.7, False, N),
    ("L-polygon", "rough"): lambda N: lpolygon_loop(0.5, 0.5, 0.83, 0.31, 0.7, True, N),
    ("wedge60", "rough"): lambda N: wedge_loop(1.5, 0.2, -0.2, 0.05, -3.0, np.sin(np.radians(60)),
                                               -np.cos(np.radians(60)), N),
    ("strip", "hemisphere"): lambda N: strip_hemisphere_loop(0.0, 0.5, 0.6, 0.8, 1.5, 1.0, N),
    ("plates", "hemisphere"): lambda N: plates_hemisphere_loop(0, 0, 0.5, 0.2, -0.4, 0.7, 1.0, -2.0, -0.3, 1.0, N),
    ("strip", "random"): lambda N: strip_random_loop(0.0, 0.5, 0.6, 0.8, 1.5, 1.0, rules_key(), N),
    ("plates", "random"): lambda N: plates_random_loop(0, 0, 0.5, 0.2, -0.4, 0.7, 1.0, -2.0, -0.3, 1.0, rules_key(),
                                                       *RANDOM3[0], RANDOM3[1], N),
    ("sphere", "specular"): lambda N: sphere_loop(0.1, 0.2, 0.3, 0.3, -0.5, 0.7, 1.0, -2.0, -0.3, 1.0 - R, False, N),
    ("sphere", "rough"): lambda N: sphere_loop(0.1, 0.2, 0.3, 0.3, -0.5, 0.7, 1.0, -2.0, -0.3, 1.0 - R, True, N),
    ("cylinder", "specular"): lambda N: cylinder_loop(0.1, 0.2, 0.7, 0.3, -0.5, 0.7, 1.0, -2.0, -0.3, 1.0 - R, 1.5,
                                                      False, N),
    ("cylinder", "rough"): lambda N: cylinder_loop(0.1, 0.2, 0.7, 0.3, -0.5, 0.7, 1.0, -2.0, -0.3, 1.0 - R, 1.5,
                                                   True, N),
    ("sinai3", "specular"): lambda N: sinai3_loop(0.2, 0.2, 0.2, 0.3, -0.5, 0.7, 1.0, -2.0, -0.3, 1.0, 1.3, 0.8,
                                                  0.5, 0.65, 0.4, 0.2 + R, False, N),
    ("sinai3", "rough"): lambda N: sinai3_loop(0.2, 0.2, 0.2, 0.3, -0.5, 0.7, 1.0, -2.0, -0.3, 1.0, 1.3, 0.8,
                                               0.5, 0.65, 0.4, 0.2 + R, True, N),
    ("lorentz", "specular"): lambda N: lorentz_loop(0.1, 0.1, 0.83, 0.31, 0.7, 1.0, 1.0, 0.3 + R, False, N),
    ("lorentz", "rough"): lambda N: lorentz_loop(0.1, 0.1, 0.83, 0.31, 0.7, 1.0, 1.0, 0.3 + R, True, N),
    ("mushroom", "specular"): lambda N: mushroom_loop(0.2, 0.5, 0.83, 0.31, 0.7, 1.0, 0.3, 1.0, False, N),
    ("mushroom", "rough"): lambda N: mushroom_loop(0.2, 0.5, 0.83, 0.31, 0.7, 1.0, 0.3, 1.0, True, N),
}
#: (scene, rule) -> a second hand-written loop of the row that keeps what rbx must keep and the first loop leaves
#: out: the plates' hemisphere loop follows one body axis, where rbx turns the whole orientation A (saved with the
#: state, recorded as a field): this one turns all of A
HAND_KEEPING_A = {
    ("plates", "hemisphere"): lambda N: plates_hemisphere_orientation_loop(0, 0, 0.5, 0.2, -0.4, 0.7, 1.0, -2.0,
                                                                           -0.3, 1.0, N),
}
#: collisions over which a hand loop's orbit is checked against rbx's (tests/test_bench_smoke.py): chaotic tables
#: separate nearby orbits exponentially, so rounding differences grow past 1e-9 after 15-20 collisions (the
#: L-polygon, dispersed by its rounded reflex corner, after ~300; the rough cylinder after ~500; the Lorentz gas
#: after ~15)
HAND_CHECK_COLLISIONS = {"sinai": 12, "stadium": 12, "L-polygon": 100, "cylinder": 200, "sinai3": 50, "lorentz": 12,
                         "mushroom": 40}

FIELDS = RECORD_FIELDS
FIELD_VALUES = {2: {"time": 1, "position": 2, "velocity": 2, "angular_velocity": 1, "orientation": 1, "wall": 0.5,
                    "rank": 0.5},
                3: {"time": 1, "position": 3, "velocity": 3, "angular_velocity": 3, "orientation": 9, "wall": 0.5,
                    "rank": 0.5}}   # in units of 8 bytes (wall and rank are int32)
FIELD_CASES = ([("nothing", (), 1)] + [(f, (f,), 1) for f in FIELDS]
               + [("all", FIELDS, 1), ("all, every 10", FIELDS, 10), ("all, every 100", FIELDS, 100)])
FIELD_SCENES = ("strip", "plates")           # rough
QUICK_H5_CASES = ("nothing", "time", "all", "all, every 100")   # --quick: the CLI's start-up dominates, run fewer
ENSEMBLE_SCENES = ("circle", "box")          # rough, starts drawn from the billiard measure
ENSEMBLE_SIZES = (1, 10, 100, 1000)
JIT_SCENES = ("circle", "box")               # rough, every field recorded
VARIANT_SCENES = ("strip", "circle")         # rough
VARIANTS = [("default (renormalize 16)", {}), ("renormalize 0 (off)", {"renormalize": 0}),
            ("renormalize 1", {"renormalize": 1}), ("renormalize 64", {"renormalize": 64}),
            ("compensated", {"compensated": True}), ("snap", {"snap": True}),
            ("compensated + snap", {"compensated": True, "snap": True})]
PEER_SCENES = ("rectangle", "strip")         # specular: what the peer simulates
PROCESS_SCENES = ("strip", "plates")         # rough: rbx simulate against scripts/minimal_loop.py, whole processes
MINIMAL_PROGRAM = os.path.join(os.path.dirname(os.path.abspath(__file__)), "minimal_loop.py")
#: what each skip saves (docs/reference.md §7): (scene, rule, what the kernel skips, Simulation attribute, engine
#: bit). The kernel is made to do the work anyway (force_bits) or to leave out a fast path (drop_bits); same orbit
#: either way. A 2D run follows the orientation always (one multiply-add per flight, and one compiled loop less per
#: scene that records it): its row drops the update instead, so that its cost shows as a negative saving
SKIPS = [("strip", "specular", "none: 2D always follows θ (θ += τω); this row drops it by hand to show its cost",
          "drop_bits", "S_ORIENT"),
         ("plates", "rough", "orientation update (A ← exp(τW)A)", "force_bits", "S_ORIENT"),
         ("rectangle", "specular", "spin arithmetic (the rough map at rank 0)", "force_bits", "S_SPIN"),
         ("box", "specular", "spin arithmetic (the rough map at rank 0)", "force_bits", "S_SPIN"),
         ("strip", "rough", "rule tree walk (a constant rule's node looked up directly)", "force_bits", "S_TREE"),
         ("strip", "rough", "per-collision record bookkeeping", "force_bits", "S_RECORD"),
         ("strip", "rough", "slab closed form (flight time, normal, slab map)", "drop_bits", "S_SLAB"),
         ("plates", "rough", "slab closed form (flight time, normal, slab map)", "drop_bits", "S_SLAB")]


# ---- timing ---------------------------------------------------------------------------------------------------------
@dataclass
class Timing:
    """``N`` collisions (work units) per run, ``times`` of the repeats; ``escaped``: collisions made before the
    trajectory left for infinity (then no rate)."""
    N: int
    times: list
    escaped: int = None
    extra: float = 0.0          # bytes written, for the HDF5 runs
    limit: tuple = None         # HDF5 runs: (seconds of rbx's writer alone, of a plain write, bytes): writer_limit

    @property
    def seconds(self):
        return statistics.median(self.times) if self.times else math.nan

    @property
    def rate(self):
        return self.N / self.seconds if self.times and self.escaped is None else math.nan


def measure(run, args, n0=1000, cap=10 ** 10):
    """``run(N) -> (seconds, collisions made)``: at least N collisions unless the trajectory escaped. Warm up,
    grow N until one run lasts ``args.seconds``, then time ``args.repeats`` runs -> Timing."""
    if args.collisions:
        N = args.collisions
        run(min(N, 10))
    else:
        run(10)
        N = min(n0, cap)
        while True:
            t, done = run(N)
            if done < N:
                return Timing(N, [], escaped=done)
            if t >= args.seconds or N >= cap:
                break
            N = int(min(cap, max(2 * N, N * min(1000.0, 1.25 * args.seconds / max(t, 1e-9)))))
    times = []
    for _ in range(args.repeats):
        t, done = run(N)
        if done < N:
            return Timing(N, [], escaped=done)
        times.append(t)
    return Timing(done, times)


def rbx_run(d, threads=1, **variants):
    """A runner for :func:`measure`: the config mapping ``d`` for N collisions in all (split over its
    trajectories), timed around ``Simulation.run`` with a MemorySink."""
    M = d["run"]["trajectories"]
    bits = {k: variants.pop(k) for k in ("force_bits", "drop_bits") if k in variants}

    def run(N):
        per = max(1, -(-N // M))
        cfg = config.from_dict({**d, "run": {**d["run"], "collisions": per}}, "<bench>")
        sim = Simulation(cfg.replace(numerics=dataclasses.replace(cfg.numerics, **variants)), **bits)
        numba.set_num_threads(threads)
        sink = MemorySink()
        t0 = time.perf_counter()
        sim.run(sink)
        dt = time.perf_counter() - t0
        return dt, int(sim.ncoll.sum())
    return run


def rbx_command():
    exe = os.path.join(os.path.dirname(sys.executable), "rbx")
    return [exe] if os.path.exists(exe) else [shutil.which("rbx") or "rbx"]


def cli_start(d, tmp, name, N, env=None):
    """Start ``rbx simulate`` of config ``d`` for N collisions in a subprocess -> handle for :func:`cli_finish`."""
    cfg_path = os.path.join(tmp, name + ".yaml")
    out = os.path.join(tmp, name + ".h5")
    with open(cfg_path, "w") as fh:
        yaml.safe_dump(d, fh)
    cmd = rbx_command() + ["simulate", cfg_path, "-o", out, "--force", "--quiet", "--collisions", str(N)]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env)
    return cmd, out, proc, t0


def cli_finish(handle):
    """Wait for it -> (wall seconds, bytes of the file written)."""
    cmd, out, proc, t0 = handle
    _, err = proc.communicate()
    dt = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{err[-2000:]}")
    size = os.path.getsize(out)
    os.remove(out)
    return dt, size


def cli_run(d, tmp, name, N, env=None):
    """``rbx simulate`` of config ``d`` for N collisions in a subprocess -> (wall seconds, bytes of the file)."""
    return cli_finish(cli_start(d, tmp, name, N, env))


# ---- the sections ---------------------------------------------------------------------------------------------------
def log(*a):
    print(*a, file=sys.stderr, flush=True)


def section_rates(args):
    """(scene, rule) -> Timing: one trajectory, nothing recorded, one thread."""
    res = {}
    for scene in SCENES:
        for r in RULE_NAMES:
            if (scene, r) in NOT_EXPRESSIBLE:
                res[scene, r] = Timing(0, [], escaped="not expressible")
                continue
            res[scene, r] = measure(rbx_run(scene_dict(scene, r)), args, n0=2000)
            tm = res[scene, r]
            log(f"rates    {scene:10s} {r:10s} " + (f"{tm.rate:10.3e}/s" if tm.escaped is None
                                                     else f"escapes after {tm.escaped}"))
    return res


def interleaved(runs, args, n0=2000):
    """Several runners timed in turn, repeat by repeat (so that a change of load on the machine hits them alike:
    their ratio is what is compared) -> list of Timing; N is found for each by :func:`measure` first."""
    one = argparse.Namespace(**{**vars(args), "repeats": 1})
    sizes = [measure(run, one, n0=n0).N for run in runs]
    times = [[] for _ in runs]
    for _ in range(args.repeats):
        for k, run in enumerate(runs):
            t, _ = run(sizes[k])
            times[k].append(t)
    return [Timing(N, t) for N, t in zip(sizes, times)]


def section_hand(args, rates):
    """(scene, rule) -> (rbx default Timing, rbx renormalize-off Timing or None, hand Timing), timed interleaved
    (section 1's rate of the same run is not reused: measured minutes apart, the ratio would carry the change of
    load in between)."""
    res = {}
    for (scene, r), fn in HAND.items():
        def hand(N, fn=fn):
            t0 = time.perf_counter()
            fn(N)
            return time.perf_counter() - t0, N
        runs = [rbx_run(scene_dict(scene, r)), hand, rbx_run(scene_dict(scene, r), renormalize=0)]
        if (scene, r) in HAND_KEEPING_A:
            def keeping_a(N, fn=HAND_KEEPING_A[scene, r]):
                t0 = time.perf_counter()
                fn(N)
                return time.perf_counter() - t0, N
            runs.append(keeping_a)
        got = interleaved(runs, args)
        dflt, h, off = got[0], got[1], got[2]
        res[scene, r] = (dflt, off, h, got[-1] if (scene, r) in HAND_KEEPING_A else None)
        log(f"hand     {scene:10s} {r:10s} hand {h.rate:10.3e}/s  rbx / hand {dflt.rate / h.rate:.2f}")
    return res


def minimal_run(scene, N, env=None):
    """The minimal njit program (scripts/minimal_loop.py) of ``scene`` for N collisions in a subprocess -> (wall
    seconds, the checksum it prints)."""
    cmd = [sys.executable, MINIMAL_PROGRAM, scene, str(N)]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    dt = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{proc.stderr[-2000:]}")
    return dt, float(proc.stdout)


def section_process(args, tmp):
    """scene -> (work Timing of rbx, of the minimal program; start-up Timing of rbx, of the minimal program).

    What a user gets from the command, not from the kernel alone: `rbx simulate CONFIG --force
    --quiet -o OUT.h5 --collisions N` (nothing recorded, one trajectory, rough) against
    `python scripts/minimal_loop.py SCENE N`, a plain @njit loop of the same scene and orbit that imports numpy and
    numba only — both whole processes, wall time from the start of the subprocess to its exit, so Python's start-up,
    the imports, loading the compiled code from the cache and (for rbx) the config, the file and the blocks are in.
    Each command is run once first (the caches filled or loaded: warm), then the two are run in turn, repeat by
    repeat (a change of load hits both), ``args.process_collisions`` collisions each; then the same for one collision
    (the start-up)."""
    N = args.process_collisions
    res = {}
    for scene in PROCESS_SCENES:
        d = scene_dict(scene, "rough")
        cli_run(d, tmp, "process", 1)               # warm-up: compiled or loaded from the caches
        minimal_run(scene, 1)
        work, start = ([], []), ([], [])
        for size, out in ((N, work), (1, start)):
            for _ in range(args.repeats):
                out[0].append(cli_run(d, tmp, "process", size)[0])
                out[1].append(minimal_run(scene, size)[0])
        res[scene] = (Timing(N, work[0]), Timing(N, work[1]), Timing(1, start[0]), Timing(1, start[1]))
        rbx, mini, rs, ms = res[scene]
        log(f"process  {scene:10s} N={N:.0e} rbx {rbx.seconds:.2f} s  minimal {mini.seconds:.2f} s  minimal / rbx "
            f"{mini.seconds / rbx.seconds:.2f}  start-up rbx {rs.seconds:.2f} s minimal {ms.seconds:.2f} s")
    return res


def field_bytes(n, fields, every):
    return 8 * sum(FIELD_VALUES[n][f] for f in fields) / every


def section_fields(args, tmp):
    """scene -> list of (label, memory Timing, HDF5 Timing) and the CLI start-up Timing per scene."""
    res, startup = {}, {}
    for scene in FIELD_SCENES:
        n = len(SCENES[scene][1])
        # start-up of `rbx simulate` (import, cache load, file set-up): one collision, nothing recorded
        base = Timing(1, [cli_run(scene_dict(scene), tmp, "startup", 1)[0] for _ in range(max(1, args.repeats))])
        startup[scene] = base
        rows = []
        for label, fields, every in FIELD_CASES:
            d = scene_dict(scene, "rough", fields, every)
            per_coll = field_bytes(n, fields, every)
            cap = int(args.memory_cap / per_coll) if per_coll else 10 ** 10
            mem = measure(rbx_run(d), args, n0=2000, cap=cap)
            h5 = None
            if not args.quick or label in QUICK_H5_CASES:
                # HDF5: enough collisions for ~h5_seconds of work (from the in-memory rate), capped by the file
                # size; the kernels are in the disk cache already (the in-memory runs put them there)
                N = int(max(1000, min(mem.rate * args.h5_seconds, args.file_cap / per_coll if per_coll else 1e12)))
                runs = [cli_run(d, tmp, "fields", N) for _ in range(args.repeats)]
                h5 = Timing(N, [t for t, _ in runs], extra=statistics.median(s for _, s in runs))
                if fields:
                    lim = [writer_limit(d, N, tmp) for _ in range(args.repeats)]
                    h5.limit = (statistics.median(x[0] for x in lim), statistics.median(x[1] for x in lim),
                                lim[0][2])
            rows.append((label, fields, mem, h5))
            log(f"fields   {scene:10s} {label:16s} memory {mem.rate:10.3e}/s"
                + (f"  HDF5 wall {h5.seconds:.2f} s" if h5 else ""))
        res[scene] = rows
    return res, startup


def writer_limit(d, N, tmp):
    """What writing the records of an N-collision run costs without the engine -> (seconds through rbx's own HDF5
    writer, seconds of a plain file write of the same bytes, bytes). The blocks are the ones the run hands its
    sink (captured from a one-block run: the same fields, shapes, block length and values), written N/block times
    over: to a fresh run file by :class:`rbx.runfile.H5Sink` (h5py with rbx's chunks, checksums and bookkeeping,
    through the journal, flushed and committed as often as a run checkpoints (``simulation.CHECKPOINT_SECONDS``): the
    limit of the recording path), and with ``file.write`` to a plain file (what the disk takes)."""
    from rbx import simulation
    from rbx.runfile import H5Sink, close_journal, commit, open_journaled
    cfg = config.from_dict({**d, "run": {**d["run"], "collisions": N}}, "<bench>")
    sim = Simulation(cfg)
    b = sim.records_per_block()
    one = config.from_dict({**d, "run": {**d["run"], "collisions": b * cfg.output.every}}, "<bench>")
    sink = MemorySink()
    Simulation(one).run(sink)
    block = max(sink.blocks, key=lambda x: next(iter(x.values())).shape[1])
    nrec = np.full(cfg.run.trajectories, next(iter(block.values())).shape[1], np.int64)
    reps = max(1, -(-(N // cfg.output.every) // int(nrec[0])))
    path = os.path.join(tmp, "limit.h5")
    t0 = time.perf_counter()
    h5 = open_journaled(path, create=True)
    with h5:
        out = H5Sink(h5, cfg, fresh=True, path=path)
        last = time.monotonic()
        for _ in range(reps):
            out.write(block, nrec)
            if time.monotonic() - last >= simulation.CHECKPOINT_SECONDS:
                h5.flush()
                commit(h5)
                last = time.monotonic()
        h5.flush()
        commit(h5)
    close_journal(h5)
    t_h5 = time.perf_counter() - t0
    raw = b"".join(np.ascontiguousarray(a).tobytes() for a in block.values())
    t0 = time.perf_counter()
    with open(os.path.join(tmp, "limit.bin"), "wb") as f:
        for _ in range(reps):
            f.write(raw)
    t_raw = time.perf_counter() - t0
    os.remove(path)
    os.remove(os.path.join(tmp, "limit.bin"))
    return t_h5, t_raw, reps * len(raw)


def section_ensembles(args):
    """(scene, M, threads) -> Timing of N collisions in all over M trajectories."""
    res = {}
    for scene in ENSEMBLE_SCENES:
        for threads in (1, 2):
            for M in ENSEMBLE_SIZES:
                d = scene_dict(scene, "rough", trajectories=M, sample=True)
                res[scene, M, threads] = measure(rbx_run(d, threads=threads), args, n0=max(2000, M))
                log(f"ensemble {scene:10s} M={M:5d} threads={threads} {res[scene, M, threads].rate:10.3e}/s")
    numba.set_num_threads(1)
    return res


def section_jit(args, tmp):
    """scene -> (cold seconds, warm Timing, cache bytes): `rbx simulate` of a tiny config with an empty
    NUMBA_CACHE_DIR, then the same command again."""
    colds = {scene: [] for scene in JIT_SCENES}
    warms = {scene: [] for scene in JIT_SCENES}
    sizes = {}
    for _ in range(args.repeats):
        caches = {scene: tempfile.mkdtemp(prefix="rbx-bench-cache-", dir=tmp) for scene in JIT_SCENES}
        envs = {scene: {**os.environ, "NUMBA_CACHE_DIR": caches[scene]} for scene in JIT_SCENES}
        cfgs = {scene: scene_dict(scene, "rough", FIELDS) for scene in JIT_SCENES}
        if args.quick:      # both at once: the timings mean nothing anyway, and the test stays short
            handles = [cli_start(cfgs[s], tmp, "jit-" + s, 1000, envs[s]) for s in JIT_SCENES]
            for s, h in zip(JIT_SCENES, handles):
                colds[s].append(cli_finish(h)[0])
        else:
            for s in JIT_SCENES:
                colds[s].append(cli_run(cfgs[s], tmp, "jit-" + s, 1000, envs[s])[0])
        for s in JIT_SCENES:
            sizes[s] = sum(os.path.getsize(os.path.join(dp, f)) for dp, _, fs in os.walk(caches[s]) for f in fs)
            warms[s] += [cli_run(cfgs[s], tmp, "jit-" + s, 1000, envs[s])[0] for _ in range(args.repeats)]
            shutil.rmtree(caches[s], ignore_errors=True)
    res = {s: (Timing(1000, colds[s]), Timing(1000, warms[s]), sizes[s]) for s in JIT_SCENES}
    for s, (cold, warm, _) in res.items():
        log(f"jit      {s:10s} cold {cold.seconds:.2f} s  warm {warm.seconds:.2f} s")
    return res


def section_variants(args):
    """(scene, variant label) -> Timing."""
    res = {}
    for scene in VARIANT_SCENES:
        for label, var in VARIANTS:
            res[scene, label] = measure(rbx_run(scene_dict(scene, "rough"), **var), args, n0=2000)
            log(f"variant  {scene:10s} {label:26s} {res[scene, label].rate:10.3e}/s")
    return res


def section_skips(args):
    """index in SKIPS -> (Timing as the engine runs it, Timing with the work forced in or the fast path left out)."""
    from rbx import engine
    res = {}
    for i, (scene, r, _, attr, bit) in enumerate(SKIPS):
        d = scene_dict(scene, r)
        base = measure(rbx_run(d), args, n0=2000)
        worse = measure(rbx_run(d, **{attr: getattr(engine, bit)}), args, n0=2000)
        res[i] = (base, worse)
        log(f"skip     {scene:10s} {bit:10s} {base.rate:10.3e}/s  without the skip {worse.rate:10.3e}/s")
    return res


def peer_table(scene):
    """The ``billiards`` obstacles for a specular scene: infinite walls (inside on the left)."""
    from billiards import InfiniteWall
    if scene == "rectangle":
        w, h = SCENES[scene][0]["width"], SCENES[scene][0]["height"]
        corners = [(0, 0), (w, 0), (w, h), (0, h)]
        return [InfiniteWall(corners[i], corners[(i + 1) % 4]) for i in range(4)]
    width = SCENES[scene][0]["width"]
    return [InfiniteWall((0, 0), (1, 0)), InfiniteWall((1, width), (0, width))]


def peer_run(scene, T):
    """``billiards`` from the scene's start up to time T -> (seconds, collisions, collision times)."""
    from billiards import Billiard
    _, pos, vel, _ = SCENES[scene]
    bil = Billiard(peer_table(scene))
    bil.add_ball(pos, vel, radius=R)
    t0 = time.perf_counter()
    colls = bil.evolve(T)
    return time.perf_counter() - t0, len(colls), np.array([c[0] for c in colls])


def peer_k(args):
    return 200 if args.quick else 1000


def section_peer(args, rates):
    """-> (version or None, reason, {scene: (peer Timing, rbx Timing, max |Δt| of the first collision times)})."""
    try:
        import billiards
        version = getattr(billiards, "__version__", None)
        if version is None:
            from importlib.metadata import version as _v
            version = _v("billiards")
    except ImportError:
        return None, "not installed (`pip install billiards`, or `pip install -e '.[bench]'`)", {}
    res = {}
    for scene in PEER_SCENES:
        # the same orbit? collision times of the first K collisions, against rbx's recorded times
        K = peer_k(args)
        d = scene_dict(scene, "specular", ("time",))
        d["run"]["collisions"] = K
        sink = MemorySink()
        Simulation(config.from_dict(d, "<bench>")).run(sink)
        t_rbx = sink.records["time"][0, 1:]
        _, m, t_peer = peer_run(scene, t_rbx[-1] * (1 + 1e-9))
        k = min(m, K)
        dev = float(np.max(np.abs(t_peer[:k] - t_rbx[:k]) / t_rbx[:k])) if m >= K - 1 else math.inf
        # its speed: grow the end time until a run lasts args.seconds
        mean_free = t_rbx[-1] / K
        def run(N):
            dt, done, _ = peer_run(scene, N * mean_free)
            return dt * N / max(done, 1), N     # the time of exactly N collisions at the measured pace
        peer = measure(run, args, n0=200)
        res[scene] = (peer, rates[scene, "specular"], dev)
        log(f"peer     {scene:10s} billiards {peer.rate:10.3e}/s  rbx {rates[scene, 'specular'].rate:10.3e}/s")
    return version, "", res


# ---- the document ---------------------------------------------------------------------------------------------------
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
    import h5py
    return (f"{cpu}, {os.cpu_count()} cores; {platform.system()} {platform.machine()}; "
            f"Python {platform.python_version()}, numba {numba.__version__}, numpy {np.__version__}, "
            f"h5py {h5py.__version__}")


def engine_version():
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    try:
        head = subprocess.run(["git", "-C", root, "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                              check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", root, "status", "--porcelain", "--", "rbx"], capture_output=True,
                               text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown (not a git checkout)"
    return f"commit {head}" + (" with uncommitted changes in rbx/" if dirty else "")


def rate_s(x):
    return "—" if x is None or not np.isfinite(x) else f"{x:.3g}"


def ns(tm):
    return f"{1e9 * tm.seconds / tm.N:.1f}"


def cell_rate(tm):
    if isinstance(tm.escaped, str):
        return tm.escaped
    if tm.escaped is not None:
        return f"escapes after {tm.escaped}"
    return f"{tm.rate:.3g} ({ns(tm)} ns)"


def heading(args, title, key):
    return [title, "", f"*Load average (1 min) when this section started: {args.loads[key]}.*", ""]


def table(header, rows):
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return out


def plot_rates(path, rates):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    scenes = list(SCENES)
    fig, ax = plt.subplots(figsize=(9, 4.2))
    width = 0.2
    for i, r in enumerate(RULE_NAMES):
        xs = np.arange(len(scenes)) + (i - 1.5) * width
        ys = [rates[s, r].rate if rates[s, r].escaped is None else np.nan for s in scenes]
        ax.bar(xs, ys, width, label=r)
    ax.set_yscale("log")
    lo = min(t.rate for t in rates.values() if t.escaped is None) / 3
    ax.set_ylim(bottom=lo)
    for i, r in enumerate(RULE_NAMES):
        for j, s in enumerate(scenes):
            if rates[s, r].escaped is not None:
                ax.text(j + (i - 1.5) * width, lo * 1.1, rates[s, r].escaped if isinstance(rates[s, r].escaped, str)
                        else "escapes", rotation=90, ha="center", va="bottom",
                        fontsize=7)
    # 14 scene names side by side ran into each other (wedge60, rectangle, L-polygon, plates): tilted
    ax.set_xticks(np.arange(len(scenes)), scenes, rotation=30, ha="right", rotation_mode="anchor")
    ax.set_ylabel("collisions / s (one core)")
    ax.set_title("rbx, one trajectory, nothing recorded", pad=24)
    # above the axes: inside, it covered the strip's and the plates' tallest bars
    ax.legend(ncol=4, fontsize=8, loc="lower center", bbox_to_anchor=(0.5, 1.0), frameon=False)
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_fields(path, fields, startup):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker
    fig, axes = plt.subplots(1, len(fields), figsize=(11, 4.5), sharey=True)
    for ax, (scene, rows) in zip(np.atleast_1d(axes), fields.items()):
        labels = [r[0] for r in rows]
        base_mem = rows[0][2].seconds / rows[0][2].N
        mem = [r[2].seconds / r[2].N / base_mem for r in rows]
        h5 = [h5_work(r[3], startup[scene]) / r[3].N / base_mem if h5_ok(r[3], startup[scene]) else np.nan
              for r in rows]
        y = np.arange(len(rows))
        ax.barh(y - 0.2, mem, 0.4, label="in memory (MemorySink)")
        ax.barh(y + 0.2, h5, 0.4, label="HDF5 (rbx simulate, start-up subtracted)")
        ax.set_xscale("log")
        # ticks at 1, 2, 5, 10, … written plainly (matplotlib labelled a short log range "2 × 10⁰")
        ax.xaxis.set_major_locator(matplotlib.ticker.LogLocator(subs=(1.0, 2.0, 5.0)))
        ax.xaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda x, _: f"{x:g}"))
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_yticks(y, labels)
        ax.invert_yaxis()
        ax.axvline(1, color="k", lw=0.8)
        ax.set_xlabel("time per collision / nothing recorded in memory")
        ax.set_title(f"{scene} (rough)")
        ax.grid(axis="x", alpha=0.3)
    np.atleast_1d(axes)[0].legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_scaling(path, ens):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 4))
    for k, scene in enumerate(ENSEMBLE_SCENES):      # a colour per scene, a line style per thread count
        for threads, style in ((1, "o-"), (2, "s--")):
            ax.plot(ENSEMBLE_SIZES, [ens[scene, M, threads].rate / 1e6 for M in ENSEMBLE_SIZES], style,
                    color=f"C{k}", label=f"{scene}, {threads} thread{'s' if threads > 1 else ''}")
    ax.set_xscale("log")
    ax.set_xlabel("trajectories M")
    ax.set_ylabel("million collisions / s in total")
    ax.set_ylim(bottom=0)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def h5_ok(h5, base):
    """Was there enough work in the HDF5 runs to tell it from the start-up's noise?"""
    return h5 is not None and h5_work(h5, base) > 0.05 * h5.seconds


def h5_work(h5, base):
    """Seconds of work in an `rbx simulate` run: wall time less the start-up (a one-collision run)."""
    return h5.seconds - base.seconds


def write_document(args, cmd, results, wall):
    out = args.out
    stem = os.path.splitext(os.path.basename(out))[0]
    folder = os.path.dirname(os.path.abspath(out))
    rates, hand, process, (fields, startup), ens, jit, variants, (peer_version, peer_reason, peer), skips = results
    pngs = {k: f"{stem}-{k}.png" for k in ("rates", "fields", "scaling")}
    plot_rates(os.path.join(folder, pngs["rates"]), rates)
    plot_fields(os.path.join(folder, pngs["fields"]), fields, startup)
    plot_scaling(os.path.join(folder, pngs["scaling"]), ens)

    L = ["# Benchmarks", "",
         f"Generated by `{cmd}` (`make bench`) in {wall / 60:.1f} min; do not edit by hand.", "",
         f"Machine: {machine()}. Load average at the start {args.load0}, at the end {fmt_load()} "
         "(other work on the machine shows up as noise).", "",
         f"Engine: {engine_version()}.", "",
         "How: `time.perf_counter` around the work alone (`Simulation.run` with a `MemorySink`, or the whole "
         "`rbx simulate` command), after a warm-up run of the same configuration (which compiles it or loads it "
         f"from the cache); the number of collisions N is grown until one run lasts ≥ {args.seconds:g} s, then "
         f"the median of {args.repeats} runs is shown. Ball: R = {R}, κ = {KAPPA}. Rates are collisions per "
         "second, with the time per collision in parentheses."
         + (" **Quick mode: tiny sizes, the numbers mean nothing.**" if args.quick else ""), ""]

    # 1
    L += heading(args, "## 1. Collisions per second per scene and rule", "rates") + [
          "One trajectory, one thread, nothing recorded (`record: []`), from one explicit start per scene. Rules "
          "(the same on every wall):", ""]
    L += [f"- **{r}**: {RULE_TEXT[r]}" for r in RULE_NAMES]
    L += [""]
    L += table(["scene", "dim", "walls"] + list(RULE_NAMES),
               [[s, len(SCENES[s][1]), len(config.from_dict(scene_dict(s), "<bench>").geometry().codes)]
                + [cell_rate(rates[s, r]) for r in RULE_NAMES] for s in SCENES])
    L += ["", "`walls` counts the primitives of the shrunk table that each collision tests (the L-polygon's "
          "reflex corner is an extra arc). “escapes after k”: the trajectory left for infinity after k "
          "collisions, so there is no rate (a specular disc makes at most 3 collisions in a 60° wedge, and any "
          "rule with specular bounces lets it out too).", "",
          f"![collisions per second per scene and rule]({pngs['rates']})", ""]

    # 2
    L += heading(args, "## 2. Against a minimal hand-written loop", "hand") + [
          "The hand-written loop (in `scripts/bench.py`) is a plain `@njit` loop for that scene and rule alone, "
          "with the wall known in closed form: our proxy for the speed limit. It computes the same orbit "
          "(tests/test_bench_smoke.py checks it against rbx), but it does not renormalize the energy, check "
          "for escapes, keep the state's bookkeeping or support any other table. Each follows only what its rule "
          "reads: a hemisphere loop the sign of cos θ (from ⌊θ/π + ½⌋, 2D) or the body axis A·e_z (3D, not the "
          "whole matrix A); a random loop draws from rbx's own stream (`rbx.rng`, the trajectory's key), the 2D "
          "choice read off the draw's top bit. `rbx` is the default engine (energy projected back "
          f"every {RENORMALIZE_EVERY} collisions; in a specular scene the speed alone, which a reflection off a "
          "flat wall of normal ±e_i keeps exactly); `rbx, renormalize 0` turns that off: the like-for-like "
          "comparison, and the hand loop's orbit. The three are timed in turn, run by run (median of "
          f"{args.repeats} each), so that a change of load on the machine hits them alike.", ""]
    rows = []
    for (s, r), (dflt, off, h, _) in hand.items():
        rows.append([s, r, rate_s(dflt.rate), rate_s(off.rate) if off else "—", rate_s(h.rate),
                     f"{dflt.rate / h.rate:.2f}", f"{off.rate / h.rate:.2f}" if off else "—"])
    L += table(["scene", "rule", "rbx collisions/s", "rbx, renormalize 0", "hand-written collisions/s",
                "rbx / hand", "rbx renormalize 0 / hand"], rows)
    L += ["", "Target: rbx / hand ≥ 0.9 for the rough strip, plates and circle with nothing recorded.", ""]
    keeping = [(s, r, t) for (s, r), t in hand.items() if t[3] is not None]
    if keeping:
        L += ["The plates' hemisphere loop above follows one body axis; rbx turns the whole orientation A, which it "
              "saves with the state and records as a field. A second hand loop keeps A too (nine numbers, each "
              "column turned by Rodrigues' formula: `plates_hemisphere_orientation_loop`), timed in the same "
              "interleaved runs as the row above:", ""]
        L += table(["keeping the orientation", "hand-written collisions/s", "rbx / hand"],
                   [[f"{s} {r}", rate_s(t[3].rate), f"{t[0].rate / t[3].rate:.2f}"] for s, r, t in keeping])
        L += [""]

    # 3
    L += heading(args, "## 3. Whole processes: `rbx simulate` against a minimal njit program", "process") + [
          "What a user waits for: the command `rbx simulate CONFIG --force --quiet -o OUT.h5 --collisions N` "
          "(rough rule, one trajectory, nothing recorded) against `python scripts/minimal_loop.py SCENE N`, a "
          "standalone program that imports numpy and numba only and runs the same loop as section 2's hand-written "
          "one (the same orbit; cached on disk with `cache=True`, as a user's would be). Wall time of each whole "
          "process, from its start to its exit: Python's start-up, the imports, loading the compiled code from the "
          "cache, and for rbx the config, the run file and the blocks. Each command is run once first (warm "
          f"caches), then the two in turn, run by run, median of {args.repeats} each; `start-up` is the same for "
          "one collision. `minimal / rbx` is the minimal program's wall time over rbx's: rbx's speed as a fraction "
          "of the minimal program's.", ""]
    rows = []
    for s, (rbx, mini, rs, ms) in process.items():
        rows.append([s, f"{rbx.N:,}", f"{rbx.seconds:.2f}", f"{mini.seconds:.2f}", f"{mini.seconds / rbx.seconds:.2f}",
                     f"{rs.seconds:.2f}", f"{ms.seconds:.2f}"])
    L += table(["scene", "collisions", "rbx simulate (s)", "minimal program (s)", "minimal / rbx",
                "rbx start-up, 1 collision (s)", "minimal start-up, 1 collision (s)"], rows)
    L += ["", "Targets: minimal / rbx ≥ 0.9 for 10⁹ collisions of the rough strip and plates; "
          "`rbx simulate`'s warm start-up ≤ 0.5 s.", ""]

    # 4
    L += heading(args, "## 4. The cost of recording", "fields") + [
          "One trajectory, rough rule, each field alone, all of them, and all of them every 10 and 100 "
          "collisions. **In memory**: `Simulation.run` into a `MemorySink` (the API; it keeps copies of every "
          f"block), N capped at {args.memory_cap / 1e6:.0f} MB of records. **HDF5**: the real command "
          "`rbx simulate CONFIG -o OUT.h5 --force --quiet --collisions N` in a subprocess, N chosen for about "
          f"{args.h5_seconds:g} s of work (at most {args.file_cap / 1e6:.0f} MB of file); its work is the wall "
          "time less the start-up (the same command for one collision, median of runs: import, loading the "
          "kernels from the cache, creating the file), and the rates and MB/s come from that work. `relative` is "
          "the time per collision over that of nothing recorded in memory. The limits, without the engine "
          "(`writer_limit`): **writer alone**, the same blocks (fields, length, values) written as often by rbx's "
          "HDF5 writer (`runfile.H5Sink`: h5py, rbx's chunks and checksums, through the journal, committed once a "
          "second as a run's checkpoints are); **plain write**, the same bytes by "
          "`file.write` to a plain file (page cache, no fsync: what the disk side takes); both as collisions per "
          "second of the same run, to set beside `HDF5 collisions/s`. `HDF5 MB/s` counts the whole file: the "
          "records and, per record, its `step` (8 bytes: a run recording `time` alone writes twice its records' "
          "bytes; before commit 079f207 the `record` scale stored its values too, 8 bytes more per record).", ""]
    for scene, rows in fields.items():
        base_mem = rows[0][2].seconds / rows[0][2].N
        n = len(SCENES[scene][1])
        trs = []
        for label, fs, mem, h5 in rows:
            if h5 is None:
                trs.append([label, f"{field_bytes(n, fs, 1):g}", rate_s(mem.rate),
                            f"{mem.seconds / mem.N / base_mem:.2f}"] + ["not run (--quick)"] * 8)
                continue
            work = h5_work(h5, startup[scene])
            ok = h5_ok(h5, startup[scene])
            trs.append([label, f"{field_bytes(n, fs, 1):g}",
                        rate_s(mem.rate), f"{mem.seconds / mem.N / base_mem:.2f}",
                        f"{h5.N:,}", f"{h5.seconds:.2f}", f"{h5.extra / 1e6:.1f}",
                        rate_s(h5.N / work) if ok else "within start-up noise",
                        f"{work / h5.N / base_mem:.2f}" if ok else "—",
                        f"{h5.extra / 1e6 / work:.0f}" if ok and h5.extra > 1e5 else "—"]
                       + ([rate_s(h5.N / h5.limit[0]), rate_s(h5.N / h5.limit[1])]
                          if h5.limit else ["—", "—"]))
        L += [f"### {scene} ({n}D, rough); `rbx simulate` start-up {startup[scene].seconds:.2f} s", ""]
        L += table(["recorded", "bytes/record", "memory collisions/s", "memory relative", "HDF5 N", "HDF5 wall s",
                    "file MB", "HDF5 collisions/s", "HDF5 relative", "HDF5 MB/s", "writer alone collisions/s",
                    "plain write collisions/s"], trs)
        L += [""]
    L += [f"![cost of each recorded field]({pngs['fields']})", ""]

    # 5
    L += heading(args, "## 5. Ensembles and threads", "ensembles") + [
          "`run.trajectories: M`, starts drawn from the billiard measure, rough rule, nothing recorded, N "
          "collisions in all (N/M each), `numba.set_num_threads(k)`. Collisions per second in total.", ""]
    rows = []
    for scene in ENSEMBLE_SCENES:
        for M in ENSEMBLE_SIZES:
            one, two = ens[scene, M, 1], ens[scene, M, 2]
            rows.append([scene, M, f"{one.N // M:,}", rate_s(one.rate), rate_s(two.rate),
                         f"{two.rate / one.rate:.2f}"])
    L += table(["scene", "M", "collisions per trajectory (1 thread)", "1 thread", "2 threads", "speed-up"], rows)
    L += ["", f"![ensembles and threads]({pngs['scaling']})", ""]

    # 6
    L += heading(args, "## 6. Compilation and the on-disk cache", "jit") + [
          "`rbx simulate` of a 1000-collision config recording every field, rough rule, one trajectory, in a "
          "subprocess: first with an empty `NUMBA_CACHE_DIR` (every kernel that run needs is compiled), then the "
          "same command again with the cache it left. Wall time of the whole command, median over "
          f"{args.repeats} fresh caches (and {args.repeats} cached runs on each).", ""]
    L += table(["scene", "first run, empty cache (s)", "cached start-up (s)", "compile cost (s)", "cache size (MB)"],
               [[s, f"{c.seconds:.2f}", f"{w.seconds:.2f}", f"{c.seconds - w.seconds:.2f}", f"{size / 1e6:.1f}"]
                for s, (c, w, size) in jit.items()])
    L += ["", "Each further combination of compile-time bits (dimension, rule kinds, recording, variants: "
          "`Simulation.spec()`) compiles once more on first use, then loads from the same cache.", ""]

    # 7
    L += heading(args, "## 7. Numerical variants", "variants") + [
          "Speed only (their accuracy is in docs/accuracy.md): rough rule, one trajectory, nothing recorded; "
          "`numerics.renormalize` (period of the projection onto the initial energy, 0 = off), "
          "`numerics.compensated` (compensated summation of time and position), `numerics.snap` (centre put on the wall at "
          "contact). `relative` is the time per collision over the default's.", ""]
    rows = []
    for scene in VARIANT_SCENES:
        base = variants[scene, VARIANTS[0][0]]
        for label, _ in VARIANTS:
            tm = variants[scene, label]
            rows.append([scene, label, cell_rate(tm), f"{base.rate / tm.rate:.2f}"])
    L += table(["scene", "variant", "collisions/s", "relative"], rows)
    L += [""]

    # 8
    L += heading(args, "## 8. A public peer: `billiards` (PyPI)", "peer") + [
          "[`billiards`](https://pypi.org/project/billiards/) simulates 2D billiards event by event: balls (with "
          "a radius) against each other and against obstacles (infinite walls, discs), specular only and in pure "
          "Python with NumPy. It fits the specular rectangle (four infinite walls) and the specular strip (two); "
          "it cannot express a circular table (its disc obstacles are hit from outside), 3D, or any rough rule. "
          "Timed: `Billiard.evolve(T)` from the same start as rbx, with the end time grown until one run lasts "
          f"≥ {args.seconds:g} s; `Δt` is the largest relative difference between its collision times and rbx's "
          f"over the first {peer_k(args)} collisions (is it the same orbit?). It is an optional dependency: "
          "`pip install -e '.[bench]'`. We found no other package on PyPI for these tables: `pooltool-billiards` "
          "simulates the game of pool (cloth friction, cushions), and physics engines such as pymunk step time "
          "with contact forces instead of going from collision to collision.", ""]
    if peer_version is None:
        L += table(["scene", "billiards collisions/s", "rbx collisions/s", "rbx / billiards", "Δt"],
                   [[s, peer_reason, rate_s(rates[s, "specular"].rate), "—", "—"] for s in PEER_SCENES])
    else:
        L += [f"`billiards` {peer_version}.", ""]
        L += table(["scene", "billiards collisions/s", "rbx collisions/s", "rbx / billiards", "Δt"],
                   [[s, rate_s(p.rate), rate_s(r.rate), f"{r.rate / p.rate:.0f}", f"{dev:.1e}"]
                    for s, (p, r, dev) in peer.items()])
    L += [""]

    # 9
    L += heading(args, "## 9. What each skip saves", "skips") + [
          "The kernel leaves out what a scene does not need ([reference.md §7](reference.md#7-speed-and-accuracy)), "
          "by compiling it out (`engine.COMPILED_BITS`) or behind a predictable run-time branch (per-collision "
          "records, the variants). "
          "Here each skip is undone on one scene — the work forced in (`Simulation.force_bits`) or the fast path "
          "left out (`Simulation.drop_bits`), the orbit the same — one trajectory, nothing recorded, one thread.",
          ""]
    L += table(["scene", "rule", "skipped", "collisions/s as run", "without the skip", "saved per collision (ns)",
                "time without / with"],
               [[SKIPS[i][0], SKIPS[i][1], SKIPS[i][2], cell_rate(a), cell_rate(b),
                 f"{1e9 * (b.seconds / b.N - a.seconds / a.N):.1f}", f"{(b.seconds / b.N) / (a.seconds / a.N):.2f}"]
                for i, (a, b) in skips.items()])
    L += ["", "Random draws are skipped by the same bit as the tree walk: a constant rule draws nothing; the "
          "`random` column of section 1 against `rough` shows what drawing costs.", ""]
    spread = {}
    for i, (a, _) in skips.items():
        spread.setdefault(f"{SKIPS[i][0]} {SKIPS[i][1]}", []).append(1e9 * a.seconds / a.N)
    noisy = {sc: (min(v), max(v)) for sc, v in spread.items() if len(v) > 1}
    if noisy:
        L += ["The same run measured in several rows (“as run”) gives the spread of one measurement on this "
              "machine: " + "; ".join(f"{sc} {lo:.1f}–{hi:.1f} ns" for sc, (lo, hi) in noisy.items()) + ". A "
              "saving smaller than that spread is not resolved by this measurement; the 2D orientation row "
              "measures a cost, not a skip, and is negative by design.", ""]
    L += notes(rates, hand, process, fields, ens, variants)
    with open(out, "w") as fh:
        fh.write("\n".join(L) + "\n")


def notes(rates, hand, process, fields, ens, variants):
    """Facts read off the numbers (no judgement beyond them)."""
    L = ["## What stands out", ""]
    ok = [(k, t) for k, t in rates.items() if t.escaped is None]
    fast = max(ok, key=lambda kt: kt[1].rate)
    slow = min(ok, key=lambda kt: kt[1].rate)
    L.append(f"- Fastest: {fast[0][0]} / {fast[0][1]} at {fast[1].rate:.3g} collisions/s; slowest: {slow[0][0]} / "
             f"{slow[0][1]} at {slow[1].rate:.3g} ({fast[1].rate / slow[1].rate:.1f}× slower).")
    for r in RULE_NAMES:
        col = [(s, rates[s, r]) for s in SCENES if rates[s, r].escaped is None]
        if len(col) < 3:
            continue
        med = statistics.median(t.rate for _, t in col)
        for s, t in col:
            if t.rate < med / 3:
                L.append(f"- {s} / {r} runs at {t.rate:.3g} collisions/s, {med / t.rate:.1f}× below the median of "
                         f"the {r} column ({med:.3g}).")
    for (s, r), (dflt, off, h, _) in hand.items():
        if r == "rough":
            L.append(f"- {s} (rough) against its hand-written loop: {dflt.rate / h.rate:.2f} with the default "
                     f"renormalization, {off.rate / h.rate:.2f} without (target 0.9).")
    for s, (rbx, mini, rs, ms) in process.items():
        L.append(f"- {s} (rough) as whole processes, {rbx.N:,} collisions: `rbx simulate` {rbx.seconds:.2f} s, the "
                 f"minimal program {mini.seconds:.2f} s (minimal / rbx {mini.seconds / rbx.seconds:.2f}, target 0.9); "
                 f"start-up {rs.seconds:.2f} s against {ms.seconds:.2f} s (target ≤ 0.5 s).")
    for scene, rows in fields.items():
        base = rows[0][2].seconds / rows[0][2].N
        single = [r for r in rows if len(r[1]) == 1]
        worst = max(single, key=lambda r: r[2].seconds / r[2].N)
        L.append(f"- {scene}: the dearest single field in memory is `{worst[0]}` "
                 f"({worst[2].seconds / worst[2].N / base:.2f}× the time per collision of nothing recorded).")
    for scene in ENSEMBLE_SCENES:
        sp = ens[scene, ENSEMBLE_SIZES[-1], 2].rate / ens[scene, ENSEMBLE_SIZES[-1], 1].rate
        L.append(f"- {scene}: {ENSEMBLE_SIZES[-1]} trajectories on 2 threads run {sp:.2f}× as fast as on 1.")
    return L + [""]


def load1():
    try:
        return f"{os.getloadavg()[0]:.1f}"
    except OSError:
        return "unknown"


def fmt_load():
    try:
        return "/".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        return "unknown"


SECTIONS = ("rates", "hand", "process", "fields", "ensembles", "jit", "variants", "peer", "skips")


def _positive(text):
    """argparse type: a whole number ≥ 1."""
    if not text.isdigit() or int(text) < 1:
        raise argparse.ArgumentTypeError(f"a whole number ≥ 1, got {text!r}")
    return int(text)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="tiny sizes (for the smoke test): numbers mean nothing")
    ap.add_argument("--repeats", type=int, help="timed runs per measurement (median); default 3, quick 1")
    ap.add_argument("--seconds", type=float, help="least duration of one timed run; default 0.4, quick 0.002")
    ap.add_argument("--collisions", type=int, help="a fixed number of collisions instead of --seconds")
    ap.add_argument("--process-collisions", type=_positive,
                    help="collisions of each whole-process run (section 3); default 10⁹, quick 10⁵")
    ap.add_argument("--tangent-only", action="store_true",
                    help="run only the tangent-loop and short-orbit rows and put them in --out (in place of "
                         "the ones there)")
    ap.add_argument("--studies-only", action="store_true",
                    help="run only the studies and explicit-states rows and put them in --out (in place of the "
                         "ones there)")
    ap.add_argument("--out", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "docs",
                                                  "benchmarks.md"))
    args = ap.parse_args(argv)
    args.repeats = args.repeats or (1 if args.quick else 3)
    args.seconds = args.seconds or (0.002 if args.quick else 0.4)
    args.h5_seconds = 0.01 if args.quick else 1.0          # work per `rbx simulate` run of section 4
    args.memory_cap = 2e6 if args.quick else 256e6         # bytes of records kept by a MemorySink run
    args.file_cap = 2e6 if args.quick else 400e6           # bytes of an HDF5 file
    args.process_collisions = args.process_collisions or (10 ** 5 if args.quick else 10 ** 9)   # section 3
    args.load0 = fmt_load()
    argv = sys.argv[1:] if argv is None else argv
    cmd = " ".join(["python scripts/bench.py"] + [a if a != args.out else os.path.relpath(a) for a in argv])
    t0 = time.perf_counter()
    numba.set_num_threads(1)
    args.loads = {}
    if args.tangent_only or args.studies_only:
        if args.studies_only:
            section_studies(args)
        if args.tangent_only:
            section_tangent(args)
        return None

    def section(name, fn, *a):
        args.loads[name] = load1()
        t = time.perf_counter()
        res = fn(args, *a)
        log(f"section {name}: {time.perf_counter() - t:.1f} s")
        return res
    with tempfile.TemporaryDirectory(prefix="rbx-bench-") as tmp:
        rates = section("rates", section_rates)
        hand = section("hand", section_hand, rates)
        process = section("process", section_process, tmp)
        fields = section("fields", section_fields, tmp)
        ens = section("ensembles", section_ensembles)
        jit = section("jit", section_jit, tmp)
        variants = section("variants", section_variants)
        peer = section("peer", section_peer, rates)
        skips = section("skips", section_skips)
    results = (rates, hand, process, fields, ens, jit, variants, peer, skips)
    write_document(args, cmd, results, time.perf_counter() - t0)
    section_studies(args)    # appends its own table to the document
    section_tangent(args)    # so does this one
    log(f"wrote {args.out} in {time.perf_counter() - t0:.0f} s")
    return results


EXAMPLES = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "configs", "examples")


def _cpu_per(run, N):
    """CPU seconds per unit of ``run(N)`` (one thread: the kernels run in this one)."""
    t0 = time.process_time()
    run(N)
    return (time.process_time() - t0) / N


def tangent_rows(args, tables=("sinai", "lorentz", "box", "sinai3d")):
    """Per collision, one trajectory of each example config, one thread, CPU time: the engine as ``rbx simulate``
    runs it with nothing recorded (``engine.run_advance_all``), the tangent loop with the whole spectrum and with
    λ₁ alone (``dynamics._Tangent``: what ``rbx lyapunov`` runs), on the same orbit; interleaved rounds, median ->
    rows (table, d, engine s, full s, K=1 s)."""
    from rbx import engine
    from rbx.dynamics import _Tangent
    from rbx.simulation import record_buffers
    N = 2_000 if args.quick else 40_000
    rows = []
    for name in tables:
        exp = config.load(os.path.join(EXAMPLES, name + ".yaml"), {"trajectories": 1, "collisions": 10 ** 12})

        def eng():          # made before it is timed: the set-up is not per collision
            sim = Simulation(exp, drop_bits=engine.S_RECORD | engine.S_STOP_WALL | engine.S_ORIENT)
            out = engine.Records(**record_buffers((), sim.n, 1, 0))
            groups, state = sim.kernel_groups(), sim.state_group()
            return lambda n: engine.run_advance_all(np.full(1, n, np.int64), *groups, state, out)

        def tan(K):
            def make():
                t = _Tangent(exp, vectors=K)
                return t.advance
            return make
        runs = ((eng, 20 * N), (tan(None), N), (tan(1), N))
        for make, n in runs:
            make()(min(n, 100))
        times = [[] for _ in runs]
        for _ in range(max(3, args.repeats)):
            for k, (make, n) in enumerate(runs):
                times[k].append(_cpu_per(make(), n))
        d = _Tangent(exp).d
        rows.append((name, d) + tuple(statistics.median(t) for t in times))
    return rows


def yardstick():
    """The specular Sinai table from one start, as rbx's experiment and as :func:`sinai_tangent_loop` -> (experiment,
    hand(N) -> (sum of the first vector's log-stretches, time)). The same orbit (tests/test_bench_smoke.py)."""
    v = np.array([0.83, 0.31]) / np.hypot(0.83, 0.31)
    d = {"table": {"kind": "sinai", "size": [2.0, 1.5], "radius": 0.4},
         "boundary": {"default": {"rule": "constant", "rank": 0}}, "ball": {"radius": R, "inertia": KAPPA},
         "initial": {"position": [0.3, 0.3], "velocity": [float(v[0]), float(v[1])]},
         "run": {"collisions": 10 ** 12, "trajectories": 1, "seed": 1}, "output": {"record": []},
         "numerics": {"renormalize": 0}}      # the hand loop's orbit: no speed put back every 16 collisions
    return (config.from_dict(d, "<bench>"),
            lambda n: sinai_tangent_loop(0.3, 0.3, v[0], v[1], 2.0, 1.5, 1.0, 0.75, 0.4 + R, n))


def yardstick_rows(args):
    """:func:`yardstick`: rbx's tangent loop (the whole spectrum, 6 vectors, and λ₁ alone) against the hand loop
    (the 4 × 4 reduced map, QR after every collision), CPU time, interleaved, median; λ₁ of both on the same orbit
    -> (hand s, rbx whole s, rbx K=1 s, λ₁ hand, λ₁ rbx)."""
    from rbx.dynamics import _Tangent
    N = 2_000 if args.quick else 100_000
    exp, loop = yardstick()

    def hand():
        return loop

    def rbx(K):
        return lambda: _Tangent(exp, vectors=K).advance
    runs = (hand, rbx(None), rbx(1))
    for make in runs:
        make()(100)
    times = [[] for _ in runs]
    for _ in range(max(3, args.repeats)):
        for k, make in enumerate(runs):
            times[k].append(_cpu_per(make(), N))
    ls, T = loop(N)
    tan = _Tangent(exp)
    tan.Y[:] = np.eye(tan.d)        # the hand loop's start (rbx's own is a basis in general position)
    tan.advance(N, ortho=1)
    lam = tan.sums[0, 0] / tan.state.time[0]
    return tuple(statistics.median(t) for t in times) + (ls / T, lam)


def short_orbit_rows(args, table="sinai"):
    """Many short orbits against one long one, the same number of collisions (M × N = 10⁷): the set-up (config,
    sampling or explicit states, allocation: ``Simulation``) and the run with its final state (``Simulation.run``
    into a MemorySink), CPU time, interleaved, median -> rows (start, M, N, setup s, run s)."""
    M, N = (1_000, 100) if args.quick else (100_000, 100)
    long_n = M * N
    base = config.load(os.path.join(EXAMPLES, table + ".yaml"), {"trajectories": M, "collisions": N})
    base = base.replace(output=dataclasses.replace(base.output, record=()))
    from rbx.physics import spin_vector
    sim0 = Simulation(base)             # the sampler's starts, handed back as explicit states
    explicit = {"position": sim0.pos.copy(), "velocity": sim0.vel.copy(),
                "angular_velocity": np.array([spin_vector(W) for W in sim0.W]),
                "orientation": sim0.theta.copy() if sim0.n == 2 else sim0.A.copy()}

    def case(cfg, state=None):
        def run():
            t0 = time.process_time()
            sim = Simulation(cfg, state=state)
            t1 = time.process_time()
            sim.run(MemorySink())
            return t1 - t0, time.process_time() - t1
        return run
    long_cfg = base.replace(run=dataclasses.replace(base.run, trajectories=1, collisions=long_n))
    cases = (("one long trajectory", 1, long_n, case(long_cfg)), ("sampled starts", M, N, case(base)),
             ("explicit states", M, N, case(base, explicit)))
    for c in cases:
        c[3]()
    times = {c[0]: [] for c in cases}
    for _ in range(max(3, args.repeats)):
        for c in cases:
            times[c[0]].append(c[3]())
    return [(c[0], c[1], c[2], statistics.median(t[0] for t in times[c[0]]),
             statistics.median(t[1] for t in times[c[0]])) for c in cases]


def section_tangent(args):
    """The tangent loop against the engine per table and many short orbits against one long one (docs/speed-gaps.md
    §the tangent loop). Ratios measured in one process, interleaved, CPU time: fair on a loaded machine. Appends
    its tables to ``args.out``."""
    t0 = time.perf_counter()
    load = fmt_load()
    # quick (the smoke test): one table, whose loops make test compiles anyway
    tan = tangent_rows(args, ("sinai",)) if args.quick else tangent_rows(args)
    short = short_orbit_rows(args)
    y_hand, y_whole, y_one, lam_hand, lam_rbx = yardstick_rows(args)
    out = ["", "## The tangent loop against the engine, and many short orbits", "",
           f"*{machine()}; engine {engine_version()}. Load average at the start {load} (this run counts for 1: above "
           f"it, other work shared the machine). Interleaved, CPU time of this one thread, ratios in one process. "
           f"{time.perf_counter() - t0:.0f} s.*",
           "",
           "Per collision, one trajectory of each example config, the same orbit: the engine as `rbx simulate` runs "
           "it with nothing recorded, against `rbx lyapunov`'s loop with the whole spectrum (d tangent vectors) and "
           "with λ₁ alone (`--exponents 1`). Targets: the whole spectrum ≤ 10× the engine in 2D, ≤ 30× in 3D; λ₁ "
           "alone ≤ 5×.", "",
           "| table | d | engine | whole spectrum | ratio | λ₁ alone | ratio |", "|---|---|---|---|---|---|---|"]
    for name, d, e, full, one in tan:
        out.append(f"| {name} | {d} | {e * 1e9:.1f} ns | {full * 1e9:.0f} ns | {full / e:.1f} | {one * 1e9:.0f} ns "
                   f"| {one / e:.1f} |")
    out += ["", "The yardstick: a hand-written tangent loop of the specular Sinai table (`sinai_tangent_loop`: the "
            "4 × 4 reduced map (δa, δv), four vectors, Gram–Schmidt twice after every collision) against rbx's "
            f"loop on the same orbit (λ₁ {lam_hand:.9f} by hand, {lam_rbx:.9f} by rbx with QR after every "
            "collision). rbx follows 6 vectors (the orientation and the spin too) and re-orthonormalises every few "
            "collisions. Target: hand / rbx ≥ 0.8.", "",
            "| loop | per collision | hand / rbx |", "|---|---|---|",
            f"| hand-written, 4 × 4 | {y_hand * 1e9:.0f} ns | 1 |",
            f"| rbx, the whole spectrum (6) | {y_whole * 1e9:.0f} ns | {y_hand / y_whole:.2f} |",
            f"| rbx, λ₁ alone | {y_one * 1e9:.0f} ns | {y_hand / y_one:.2f} |"]
    out += ["", "Many short orbits of the Sinai example (nothing recorded): set-up (sampling or the explicit "
            "states, allocation) and the run (with its final state), against one trajectory of as many "
            "collisions. Target: at most 2× in all.", "",
            "| start | trajectories × collisions | set-up | run | all / one long |", "|---|---|---|---|---|"]
    whole = short[0][3] + short[0][4]
    for name, M, N, setup, run in short:
        out.append(f"| {name} | {M:,} × {N:,} | {setup:.3f} s | {run:.3f} s | {(setup + run) / whole:.2f} |")
    out.append("")
    append_section(args.out, out)
    log("\n".join(out))
    return tan, short


def section_studies(args):
    """Studies and explicit states (docs/studies.md): ``rbx.load`` of 10 000 explicit states (a mapping and a YAML
    file), ``rbx.simulate`` of them for 1 collision each, and a sweep of 8 points of 10⁶ collisions against one
    ``rbx.simulate`` of the same 8·10⁶ collisions (both written to their files). Each pair is timed in turn in
    this process (interleaved), so a ratio is fair on a loaded machine; the wall times are not, and the CPU times
    (``time.process_time``) are given beside them. Appends its table to ``args.out`` (after the document)."""
    import warnings

    import rbx
    states = 1_000 if args.quick else 10_000
    K, M, N = (2, 4, 100) if args.quick else (8, 100, 10_000)
    repeats = max(3, args.repeats)
    rng = np.random.default_rng(0)
    xs, ys, a = rng.uniform(0.2, 1.8, states), rng.uniform(0.2, 0.8, states), rng.uniform(0, 2 * np.pi, states)
    data = {"table": {"kind": "rectangle", "width": 2.0, "height": 1.0},
            "boundary": {"default": {"rule": "constant", "rank": 0}}, "ball": {"radius": 0.1},
            "initial": [{"position": [float(x), float(y)], "velocity": [float(np.cos(t)), float(np.sin(t))]}
                        for x, y, t in zip(xs, ys, a)],
            "run": {"collisions": 1, "trajectories": states}, "output": {"record": []}}
    base = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "configs", "examples", "sinai.yaml")
    study = {"base": os.path.abspath(base), "set": {"initial": {"sample": "billiard"}},
             "vary": {"ball.inertia": [round(0.1 * (i + 1), 2) for i in range(K)]}, "measure": ["energy_drift"],
             "ensemble": {"trajectories": M, "collisions": N, "seed": 1}}
    whole = rbx.load(os.path.abspath(base), {"initial": {"sample": "billiard"}, "run.trajectories": K * M,
                                             "run.collisions": N, "output.record": ["velocity", "angular_velocity"],
                                             "output.every": max(1, N // 20), "ball.inertia": 0.5})

    def timed(fn):
        w, c = time.perf_counter(), time.process_time()
        out = fn()
        return out, time.perf_counter() - w, time.process_time() - c
    with tempfile.TemporaryDirectory(prefix="rbx-bench-studies-") as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        path = os.path.join(tmp, "states.yaml")
        with open(path, "w") as fh:
            yaml.safe_dump(data, fh, default_flow_style=None)
        exp = rbx.load(data)
        rbx.simulate(exp)                                        # warm-up: the kernels from the cache
        rbx.sweep(study, os.path.join(tmp, "s.nc"), force=True)
        rbx.simulate(whole, output=os.path.join(tmp, "w.h5"), force=True)
        rows = {k: [] for k in ("mapping", "file", "simulate", "sweep", "whole")}
        for _ in range(repeats):
            load0 = load1()
            rows["mapping"].append(timed(lambda: rbx.load(data))[1:])
            rows["file"].append(timed(lambda: rbx.load(path))[1:])
            rows["simulate"].append(timed(lambda: rbx.simulate(exp))[1:])
            rows["sweep"].append(timed(lambda: rbx.sweep(study, os.path.join(tmp, "s.nc"), force=True))[1:])
            rows["whole"].append(timed(lambda: rbx.simulate(whole, output=os.path.join(tmp, "w.h5"),
                                                            force=True))[1:])
            log(f"studies  load {rows['mapping'][-1][0]:.3f}/{rows['file'][-1][0]:.3f} s, simulate "
                f"{rows['simulate'][-1][0]:.3f} s, sweep/simulate {rows['sweep'][-1][0] / rows['whole'][-1][0]:.3f} "
                f"(load {load0})")
    med = {k: (statistics.median(w for w, _ in v), statistics.median(c for _, c in v)) for k, v in rows.items()}
    pairs = [s[0] / w[0] for s, w in zip(rows["sweep"], rows["whole"])]
    coll = f"{M * N:,}".replace(",", " ")
    lines = [
        "", "## Studies and explicit states", "",
        f"`section_studies` of scripts/bench.py, {repeats} interleaved repeats (median), load average {load1()} "
        "(2 cores): the wall times grow with the load, the CPU times (`time.process_time`) and the ratio of the "
        "interleaved pair much less." + (" `--quick`: tiny sizes, the numbers mean nothing." if args.quick else ""),
        "",
        "| what | wall [s] | CPU [s] | target |", "|---|---|---|---|",
        f"| `rbx.load` of {states:,} explicit states, a mapping | {med['mapping'][0]:.3f} | {med['mapping'][1]:.3f} "
        "| ≤ 0.5 s |",
        f"| `rbx.load` of {states:,} explicit states, a YAML file | {med['file'][0]:.3f} | {med['file'][1]:.3f} | "
        "≤ 0.5 s |",
        f"| `rbx.simulate` of them, 1 collision each | {med['simulate'][0]:.3f} | {med['simulate'][1]:.3f} | ≤ 1 s |",
        f"| `rbx.sweep` of {K} points × {M} trajectories × {N} collisions ({coll} a point) into .nc | "
        f"{med['sweep'][0]:.3f} | {med['sweep'][1]:.3f} | – |",
        f"| one `rbx.simulate` of the same {K * M} × {N} collisions into .h5 | {med['whole'][0]:.3f} | "
        f"{med['whole'][1]:.3f} | – |",
        f"| sweep / simulate, interleaved (each pair: {', '.join(f'{p:.3f}' for p in pairs)}) | "
        f"{statistics.median(pairs):.3f} | {med['sweep'][1] / med['whole'][1]:.3f} | ≤ 1.05 |", ""]
    append_section(args.out, lines)
    return med, pairs


def append_section(path, lines):
    """Append a section (``lines``, its title the first that starts with '## ') to the document ``path``, in place
    of a section of that title already there (a re-run of one section replaces its table, not adds a second)."""
    title = next(line for line in lines if line.startswith("## "))
    with open(path, encoding="utf-8") as fh:
        kept = fh.read().split("\n")
    if title in kept:
        start = kept.index(title)
        end = next((i for i in range(start + 1, len(kept)) if kept[i].startswith("## ")), len(kept))
        while start > 0 and not kept[start - 1].strip():
            start -= 1
        kept = kept[:start] + kept[end:]
    while kept and not kept[-1].strip():
        kept.pop()
    with open(path, "w", encoding="utf-8") as fh:
        fh.write("\n".join(kept + lines) + "\n")

if __name__ == "__main__":
    main()
