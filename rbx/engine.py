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
import numba
import numpy as np
from numba import literally, prange

from ._jit import jit, jit_hot, jit_loop, jit_parallel, stack_array
from .geometry import contact_normal, next_collision, slab_collision, snap
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
def rescale_energy(v, W, R, kappa, e0, n):
    """Scale (v, W) so the kinetic energy is exactly the trajectory's initial energy ``e0`` again.

    The rough map conserves energy exactly in exact arithmetic, but its constants (α, 1/(κR)) are rounded the
    same way at every collision, which biases the energy by ~1e-17 per collision: 2e-12 after 10⁵ collisions in
    an L-shaped table. Projecting back onto the energy surface removes that drift (docs/accuracy.md)."""
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
                 o_rank, n):
    """Write the requested fields of one state into slot (j, r) of the block buffers."""
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


#: bits of ``spec``, the compile-time description of what a run needs (SPEC §7: skip what a scene does not need).
#: ``spec`` reaches the kernels as a literal, so Numba compiles one specialised loop per combination in use and the
#: branches a scene does not need disappear from its machine code (and the dimension becomes a constant).
S_DIM3 = 1          # 3D (else 2D)
S_ORIENT = 2        # follow the orientation (a hemisphere rule or the recorded field needs it)
S_SPIN = 4          # some rule is rough: spin arithmetic (else specular reflection only)
S_TREE = 8          # some wall's rule is a hemisphere or random tree (else the wall's constant rule directly)
S_RECORD = 16       # per-collision records are written
S_COMPENSATED = 64  # compensated (Kahan) summation of the time and the position
S_SNAP = 128        # put the centre exactly on the wall at contact
S_SLAB = 256        # two parallel walls (strip, plates): closed-form flight time and exact normal coordinate
S_STOP_WALL = 512   # end a trajectory when it hits ``stop_wall``
#: the bits compiled into the kernel; the others are tested at run time (a predictable branch). Each compiled
#: combination costs a compile of ~5 s the first time, so only the bits that pay for it are compiled: the
#: dimension (loops of constant length, state in registers), spin arithmetic and the slab's closed form.
COMPILED_BITS = S_DIM3 | S_SPIN | S_SLAB
RUNTIME_BITS = ~COMPILED_BITS


def make_spec(n, orient=False, spin=True, tree=False, record=False, compensated=False, snap=False,
              slab=False, stop_wall=False):
    """The ``spec`` bits from flags (:class:`rbx.simulate.Simulation` derives them from the config)."""
    flags = ((n == 3, S_DIM3), (orient, S_ORIENT), (spin, S_SPIN), (tree, S_TREE), (record, S_RECORD),
             (compensated, S_COMPENSATED), (snap, S_SNAP), (slab, S_SLAB),
             (stop_wall, S_STOP_WALL))
    return sum(bit for on, bit in flags if on)


@jit_hot
def kahan_add(s, comp, j, i, x):
    """s + x, compensated: the rounding error of each sum is carried in comp[j, i] and fed into the next one
    (Neumaier's two-sum), so s stays within half an ulp of the exact sum of every x -> new s."""
    y = x + comp[j, i]
    t = s + y
    if abs(s) >= abs(y):
        comp[j, i] = (s - t) + y
    else:
        comp[j, i] = (y - t) + s
    return t


@jit_loop
def advance(j, stop, spec, flags, stop_wall, every, mask, renorm_every, codes, prim_wall, params, tol, R, kappa,
            root, kind, rank, first, children, cumprob, axis, basis,
            pos, vel, W, theta, A, time, ncoll, draws, alive, keys, last_wall, last_rank, energy0, comp,
            o_time, o_pos, o_vel, o_spin, o_orient, o_wall, o_rank):
    """Run trajectory j until it has made ``stop`` collisions in all -> records written to row j.

    It ends early (``alive[j] = False``) when no wall lies ahead (an escape) or, if ``stop_wall ≥ 0``, right
    after a collision with that wall (the return loop of the invariant-measure experiment). With
    ``S_COMPENSATED``, ``comp[j]`` carries the rounding errors of the position (0…n−1) and time (n) sums."""
    literally(spec)
    n = 3 if spec & S_DIM3 else 2
    # ``spec``: the compiled bits (a literal); ``flags``: all bits, of which the run-time ones are taken. For a
    # compiled bit, ``flags & RUNTIME_BITS & bit`` folds to 0, so ``on & bit`` is a constant and its branch goes.
    on = spec | (flags & RUNTIME_BITS)
    # the trajectory's state in the kernel's own stack frame (registers, once n is a constant): see stack_array
    a = stack_array(3, (n,))
    v = stack_array(3, (n,))
    Wj = stack_array(9, (n, n))
    Aj = stack_array(9, (3, 3))
    nu = stack_array(3, (n,))
    work = stack_array(9, (3, n))
    E = stack_array(9, (3, 3))
    tmp = stack_array(9, (3, 3))
    for i in range(n):
        a[i] = pos[j, i]
        v[i] = vel[j, i]
        for k in range(n):
            Wj[i, k] = W[j, i, k]
    if on & S_ORIENT:
        for i in range(3):
            for k in range(3):
                Aj[i, k] = A[j, i, k]
    th = theta[j]
    t = time[j]
    c = ncoll[j]
    d = draws[j]
    key = keys[j]
    w = last_wall[j]
    rk = last_rank[j]
    e0 = energy0[j]
    nrec = 0
    until_record = every - c % every           # collisions to the next record
    until_renorm = renorm_every - c % renorm_every if renorm_every > 0 else 0
    while c < stop:
        # 1. next collision: the flight time and the primitive hit
        if on & S_SLAB:
            tau, p = slab_collision(params, a, v, n)
        else:
            tau, p = next_collision(codes, params, a, v, tol, n)
        if p < 0:
            alive[j] = False
            break
        # 2. free flight
        if on & S_COMPENSATED:
            for i in range(n):
                a[i] = kahan_add(a[i], comp, j, i, tau * v[i])
            t = kahan_add(t, comp, j, n, tau)
        else:
            for i in range(n):
                a[i] += tau * v[i]
            t += tau
        if on & S_SLAB:
            a[n - 1] = params[p, n - 1]            # exactly on the wall: the normal coordinate is known
            if on & S_COMPENSATED:
                comp[j, n - 1] = 0.0
        if on & S_ORIENT:
            if n == 2:
                th += tau * Wj[1, 0]
            else:
                rotate(Aj, Wj, tau, E, tmp)
        # 3. contact normal
        contact_normal(codes[p], params, p, a, nu, n)
        if on & S_SNAP:
            snap(codes[p], params, p, a, nu, n)
        # 4. rule
        w = prim_wall[p]
        if on & S_TREE:
            node, d = choose(w, nu, Aj, th, key, d, root, kind, first, children, cumprob, axis, n)
        else:
            node = root[w]
        rk = rank[node]
        # 5. collision map
        if on & S_SPIN:
            collide(v, Wj, nu, R, kappa, rk, basis, node, w, work, n)
            if renorm_every > 0:
                until_renorm -= 1
                if until_renorm == 0:
                    until_renorm = renorm_every
                    rescale_energy(v, Wj, R, kappa, e0, n)
        else:
            vn = 0.0
            for i in range(n):
                vn += v[i] * nu[i]
            for i in range(n):
                v[i] -= 2.0 * vn * nu[i]
        c += 1
        # 6. record
        if on & S_RECORD:
            until_record -= 1
            if until_record == 0:
                until_record = every
                write_record(j, nrec, mask, t, a, v, Wj, th, Aj, w, rk, o_time, o_pos, o_vel, o_spin, o_orient,
                             o_wall, o_rank, n)
                nrec += 1
        if on & S_STOP_WALL:
            if w == stop_wall:
                alive[j] = False
                break
    for i in range(n):
        pos[j, i] = a[i]
        vel[j, i] = v[i]
        for k in range(n):
            W[j, i, k] = Wj[i, k]
    if on & S_ORIENT:
        for i in range(3):
            for k in range(3):
                A[j, i, k] = Aj[i, k]
    theta[j] = th
    time[j] = t
    ncoll[j] = c
    draws[j] = d
    last_wall[j] = w
    last_rank[j] = rk
    return nrec


@jit_parallel
def advance_all(stop, spec, flags, stop_wall, every, mask, renorm_every, codes, prim_wall, params, tol, R, kappa,
                root, kind, rank, first, children, cumprob, axis, basis,
                pos, vel, W, theta, A, time, ncoll, draws, alive, keys, last_wall, last_rank, energy0, comp,
                o_time, o_pos, o_vel, o_spin, o_orient, o_wall, o_rank):
    """Advance every live trajectory to ``stop[j]`` collisions, in parallel -> records written per trajectory."""
    literally(spec)
    N = pos.shape[0]
    nrec = np.zeros(N, np.int64)
    for j in prange(N):
        if alive[j]:
            nrec[j] = advance(j, stop[j], spec, flags, stop_wall, every, mask, renorm_every, codes, prim_wall, params, tol,
                              R, kappa, root, kind, rank, first, children, cumprob, axis, basis,
                              pos, vel, W, theta, A, time, ncoll, draws, alive, keys, last_wall, last_rank, energy0,
                              comp, o_time, o_pos, o_vel, o_spin, o_orient, o_wall, o_rank)
    return nrec


def run_advance_all(*args):
    """Call :func:`advance_all` (arguments in its order) without Numba's dispatch on literal arguments.

    ``spec`` is a literal, and resolving a literal argument through the dispatcher costs ~10 ms per call (it
    re-types the call every time); the compiled entry point of the specialisation costs ~5 µs. The first call of a
    specialisation goes through the dispatcher (which compiles it or loads it from the cache)."""
    sig = tuple(numba.types.literal(x) if i == 1 else numba.typeof(x) for i, x in enumerate(args))
    cres = advance_all.overloads.get(sig)
    if cres is None:
        return advance_all(*args)
    return cres.entry_point(*args)
