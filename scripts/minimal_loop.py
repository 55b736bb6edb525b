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


def run(scene, N):
    """N collisions of ``scene`` ('strip' or 'plates') from bench.SCENES' start -> checksum."""
    if scene == "strip":
        return strip_loop(0.0, 0.5, 0.6, 0.8, 1.5, 1.0, N)
    if scene == "plates":
        return plates_loop(0.0, 0.0, 0.5, 0.2, -0.4, 0.7, 1.0, -2.0, -0.3, 1.0, N)
    raise SystemExit(f"minimal_loop.py: unknown scene {scene!r} (strip or plates)")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        raise SystemExit("usage: python scripts/minimal_loop.py strip|plates N")
    print(repr(run(sys.argv[1], int(sys.argv[2]))))
