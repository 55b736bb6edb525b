"""A minimal standalone njit program of the rough strip or the rough plates: what a user could write in place of
`rbx simulate` for these two scenes. scripts/bench.py times it as a whole process against `rbx simulate` of the
same scene (its section "Whole processes"); it imports numpy and numba only.

    python scripts/minimal_loop.py strip|plates N

Runs N collisions from the scene's start in scripts/bench.py (SCENES; R = 0.1, κ = 0.5; the same orbit as rbx)
and prints a checksum of the final state (time + position + velocity + angular velocity). The loops are cached on
disk (``cache=True``) as a user's would be. They are also section 2's hand-written loops of these two scenes
(bench.py imports them from here: one definition).
"""
import sys

import numba

KAPPA, R = 0.5, 0.1


#: the rough map's constants: 2κ/(1+κ) and 1/(κR)
A2, SC = 2 * KAPPA / (1 + KAPPA), 1 / (KAPPA * R)


@numba.njit(cache=True, inline="always")
def slab_wall(q, vq, gap):
    """The plate ahead in a slab [0, gap] (strip or plates), for the coordinate q across it moving at vq ->
    (flight time, q at the contact, s): s = +1 for the upper plate (ν = −e), −1 for the lower one."""
    if vq > 0:
        return (gap - R - q) / vq, gap - R, 1.0
    return (R - q) / vq, R, -1.0


@numba.njit(cache=True, inline="always")
def strip_rough(vx, w, s):
    """The completely rough map on a strip's plate s -> (vx, ω); vy is reversed by the caller. The slip velocity
    is along x: ν = (0, −s), r = (0, sR)."""
    dv = -A2 * (vx - w * s * R)
    return vx + dv, w - SC * s * dv


@numba.njit(cache=True, inline="always")
def plates_rough(vx, vy, wx, wy, s):
    """The completely rough map (rank 2) on plate s -> (vx, vy, ωx, ωy); vz is reversed by the caller.
    ν = (0, 0, −s), r = (0, 0, sR); u = v + ω × r; ω += r × Δv / (2λ) = sR (−Δv_y, Δv_x, 0) / (κR²)."""
    ux, uy = vx + wy * s * R, vy - wx * s * R
    dvx, dvy = -A2 * ux, -A2 * uy
    return vx + dvx, vy + dvy, wx + -s * dvy * SC, wy + s * dvx * SC


@numba.njit(cache=True)
def strip_loop(x, y, vx, vy, w, width, N):
    """Rough disc in a strip: the walls are known from the sign of vy."""
    t = 0.0
    for _ in range(N):
        tau, y, s = slab_wall(y, vy, width)
        x += tau * vx
        t += tau
        vx, w = strip_rough(vx, w, s)
        vy = -vy
    return x + y + vx + vy + w + t


@numba.njit(cache=True)
def plates_loop(x, y, z, vx, vy, vz, wx, wy, wz, gap, N):
    """Rough ball (rank 2) between plates."""
    t = 0.0
    for _ in range(N):
        tau, z, s = slab_wall(z, vz, gap)
        x += tau * vx
        y += tau * vy
        t += tau
        vx, vy, wx, wy = plates_rough(vx, vy, wx, wy, s)
        vz = -vz
    return x + y + z + vx + vy + vz + wx + wy + wz + t


def run(scene, N):
    """N collisions of ``scene`` ('strip' or 'plates') from bench.SCENES' start -> checksum."""
    if scene == "strip":
        return strip_loop(0.0, 0.5, 0.6, 0.8, 1.5, 1.0, N)
    if scene == "plates":
        return plates_loop(0.0, 0.0, 0.5, 0.2, -0.4, 0.7, 1.0, -2.0, -0.3, 1.0, N)
    fail(f"scene: unknown {scene!r} (strip or plates)")


def fail(problem):
    """A usage error: one line, exit 2 (as rbx's commands)."""
    sys.stderr.write(f"minimal_loop.py: {problem}\n")
    sys.exit(2)


if __name__ == "__main__":
    if len(sys.argv) != 3:
        fail("usage: python scripts/minimal_loop.py strip|plates N")
    if not sys.argv[2].isdigit():
        fail(f"N: a whole number of collisions ≥ 0, got {sys.argv[2]!r}")
    print(repr(run(sys.argv[1], int(sys.argv[2]))))
