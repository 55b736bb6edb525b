"""The event loop (njit): free flight to the next wall, choose the rule, apply the collision map, record.

Three tiers (STYLE, after stumpy): :mod:`rbx.simulate` validates and allocates → :func:`advance_all`, a
``prange`` driver over trajectories (each writes only its own slots) → :func:`advance`, the serial loop of one
trajectory. Kernels take arrays and scalars only.

Per collision (ARCHITECTURE.md, "The event loop"):
 1. ``next_collision``: the smallest flight time over the shrunk table's primitives (inf: the trajectory escapes
    and ends);
 2. free flight: ``a += τv``, ``t += τ``; the orientation only if a rule or a recorded field needs it;
 3. the contact normal ν at the new position;
 4. the rule tree of the wall picks a constant rule (rank, roughness basis) — hemisphere by the body-frame
    contact point, random by the trajectory's counter-based stream;
 5. the strict collision map updates (v, W) in place;
 6. every ``every``-th collision, the requested fields go to the trajectory's row of the block buffers.
"""
import numpy as np
from numba import prange

from ._jit import jit, jit_hot, jit_loop, jit_parallel
from .geometry import contact_normal, next_collision
from .physics import collide
from .rules import choose

# bits of the record mask, in the order of SPEC §5
F_TIME, F_POSITION, F_VELOCITY, F_SPIN, F_ORIENTATION, F_WALL, F_RANK = (1 << i for i in range(7))
FIELD_BITS = {"time": F_TIME, "position": F_POSITION, "velocity": F_VELOCITY, "angular_velocity": F_SPIN,
              "orientation": F_ORIENTATION, "wall": F_WALL, "rank": F_RANK}


@jit_hot
def rotate(A, W, tau, E, tmp):
    """A ← exp(τW)·A for 3D (Rodrigues' formula with ω = (W₂₁, W₀₂, W₁₀))."""
    wx, wy, wz = W[2, 1], W[0, 2], W[1, 0]
    w = np.sqrt(wx * wx + wy * wy + wz * wz)
    phi = tau * w
    if phi == 0.0:
        return
    s = np.sin(phi)
    c1 = 1.0 - np.cos(phi)
    for i in range(3):
        for j in range(3):
            k2 = 0.0
            for k in range(3):
                k2 += W[i, k] * W[k, j]
            E[i, j] = (1.0 if i == j else 0.0) + s * W[i, j] / w + c1 * k2 / (w * w)
    for i in range(3):
        for j in range(3):
            s2 = 0.0
            for k in range(3):
                s2 += E[i, k] * A[k, j]
            tmp[i, j] = s2
    for i in range(3):
        for j in range(3):
            A[i, j] = tmp[i, j]


@jit_hot
def rescale_energy(v, W, R, kappa, e0):
    """Scale (v, W) so the kinetic energy is exactly the trajectory's initial energy ``e0`` again.

    The rough map conserves energy exactly in exact arithmetic, but its constants (α, 1/(κR)) are rounded the
    same way at every collision, which biases the energy by ~1e-17 per collision: 2e-12 after 10⁵ collisions in
    an L-shaped table. Projecting back onto the energy surface removes that drift (docs/accuracy.md)."""
    n = v.shape[0]
    e = 0.0
    for i in range(n):
        e += v[i] * v[i]
    rot = 0.0
    for i in range(n):
        for k in range(n):
            rot += W[i, k] * W[i, k]
    e = 0.5 * e + 0.25 * kappa * R * R * rot
    f = np.sqrt(e0 / e)
    for i in range(n):
        v[i] *= f
        for k in range(n):
            W[i, k] *= f


@jit_hot
def write_record(j, r, mask, t, a, v, W, theta, A, wall, rank, o_time, o_pos, o_vel, o_spin, o_orient, o_wall,
                 o_rank):
    """Write the requested fields of one state into slot (j, r) of the block buffers."""
    n = a.shape[0]
    if mask & F_TIME:
        o_time[j, r] = t
    if mask & F_POSITION:
        for i in range(n):
            o_pos[j, r, i] = a[i]
    if mask & F_VELOCITY:
        for i in range(n):
            o_vel[j, r, i] = v[i]
    if mask & F_SPIN:
        if n == 2:
            o_spin[j, r, 0] = W[1, 0]
        else:
            o_spin[j, r, 0] = W[2, 1]
            o_spin[j, r, 1] = W[0, 2]
            o_spin[j, r, 2] = W[1, 0]
    if mask & F_ORIENTATION:
        if n == 2:
            o_orient[j, r, 0] = theta
        else:
            for i in range(3):
                for k in range(3):
                    o_orient[j, r, 3 * i + k] = A[i, k]
    if mask & F_WALL:
        o_wall[j, r] = wall
    if mask & F_RANK:
        o_rank[j, r] = rank


@jit_loop
def advance(j, stop, stop_wall, every, mask, follow_orientation, renormalize, codes, prim_wall, params, tol, R, kappa,
            root, kind, rank, first, children, cumprob, axis, basis,
            pos, vel, W, theta, A, time, ncoll, draws, alive, keys, last_wall, last_rank, energy0,
            o_time, o_pos, o_vel, o_spin, o_orient, o_wall, o_rank, scratch_n, scratch_3n, scratch_33):
    """Run trajectory j until it has made ``stop`` collisions in all -> records written to row j.

    It ends early (``alive[j] = False``) when no wall lies ahead (an escape) or, if ``stop_wall ≥ 0``, right
    after a collision with that wall (the return loop of the invariant-measure experiment)."""
    a = pos[j]
    v = vel[j]
    Wj = W[j]
    Aj = A[j]
    n = a.shape[0]
    nu = scratch_n[j]
    work = scratch_3n[j]
    E = scratch_33[j, 0]
    tmp = scratch_33[j, 1]
    th = theta[j]
    t = time[j]
    c = ncoll[j]
    d = draws[j]
    key = keys[j]
    w = last_wall[j]
    rk = last_rank[j]
    nrec = 0
    while c < stop:
        tau, p = next_collision(codes, params, a, v, tol)
        if p < 0:
            alive[j] = False
            break
        for i in range(n):
            a[i] += tau * v[i]
        t += tau
        if follow_orientation:
            if n == 2:
                th += tau * Wj[1, 0]
            else:
                rotate(Aj, Wj, tau, E, tmp)
        contact_normal(codes[p], params, p, a, nu)
        w = prim_wall[p]
        node, d = choose(w, nu, Aj, th, key, d, root, kind, first, children, cumprob, axis)
        rk = rank[node]
        collide(v, Wj, nu, R, kappa, rk, basis, node, w, work)
        if renormalize and rk > 0:
            rescale_energy(v, Wj, R, kappa, energy0[j])
        c += 1
        if mask != 0 and c % every == 0:
            write_record(j, nrec, mask, t, a, v, Wj, th, Aj, w, rk, o_time, o_pos, o_vel, o_spin, o_orient, o_wall,
                         o_rank)
            nrec += 1
        if w == stop_wall:
            alive[j] = False
            break
    theta[j] = th
    time[j] = t
    ncoll[j] = c
    draws[j] = d
    last_wall[j] = w
    last_rank[j] = rk
    return nrec


@jit_parallel
def advance_all(stop, stop_wall, every, mask, follow_orientation, renormalize, codes, prim_wall, params, tol, R, kappa,
                root, kind, rank, first, children, cumprob, axis, basis,
                pos, vel, W, theta, A, time, ncoll, draws, alive, keys, last_wall, last_rank, energy0,
                o_time, o_pos, o_vel, o_spin, o_orient, o_wall, o_rank, scratch_n, scratch_3n, scratch_33):
    """Advance every live trajectory to ``stop[j]`` collisions, in parallel -> records written per trajectory."""
    N = pos.shape[0]
    nrec = np.zeros(N, np.int64)
    for j in prange(N):
        if alive[j]:
            nrec[j] = advance(j, stop[j], stop_wall, every, mask, follow_orientation, renormalize, codes, prim_wall, params, tol, R, kappa,
                              root, kind, rank, first, children, cumprob, axis, basis,
                              pos, vel, W, theta, A, time, ncoll, draws, alive, keys, last_wall, last_rank, energy0,
                              o_time, o_pos, o_vel, o_spin, o_orient, o_wall, o_rank, scratch_n, scratch_3n,
                              scratch_33)
    return nrec
