"""The linearised dynamics of the rough billiard flow and Benettin's method (docs/reference.md §10;
docs/tangent-map.md).

The orbit is the engine's: the same :func:`rbx.geometry.next_collision`, :func:`~rbx.geometry.contact_normal`,
:func:`rbx.rules.choose`, :func:`rbx.physics.collide` and energy projection (:func:`rbx.engine.energy_factor`) in
the same order, so a trajectory followed here is the trajectory ``rbx simulate`` records (tests/test_lyapunov.py).
Beside the state, ``d`` tangent vectors (the columns of ``Y``) are carried through

- the free flight: δa += τ δv, δφ̂ ← e^{τW} δφ̂ + (∫₀^τ e^{uW} du) δω̂ (2D: δθ̂ += τ δω̂);
- each collision: δx⁺ = DM·(δx⁻ + f⁻ δt) − f⁺ δt with δt = −(ν·δa)/(ν·v⁻), where DM is the derivative of the
  collision map in (v, W) and, through ν(a), in the contact point (:func:`rbx.geometry.normal_jacobian`).

Tangent coordinates (d = 2(n + m), m = n(n−1)/2 spin components): ``[δa (n), δφ̂ (m), δv (n), δω̂ (m)]``, the
orientation and spin scaled by c = R√κ (2D: x₀ = R√κ θ, v₀ = R√κ ω of the paper §2.6; 3D: the space-frame rotation
vector δφ with δA = [δφ]×A, and ω) so that the kinetic energy is ½|(v, ω̂)|² and the collision map is orthogonal
on (v, ω̂). With ``orthonormalise`` the columns are re-orthonormalised (Gram–Schmidt, twice) after every collision
and the logarithms of the stretches are added to ``sums``: their growth per unit time is the Lyapunov spectrum.
"""
import numpy as np

from ._jit import jit, jit_hot
from .engine import energy_factor, rotate, scale_state
from .geometry import contact_normal, next_collision, normal_jacobian, periodic_flight, slab_collision

from .physics import collide, collide_axis, project_roughness
from .rules import EXIT, choose


def tangent_dimension(n):
    """d = 2(n + n(n−1)/2): position and orientation, their velocities (6 in 2D, 12 in 3D)."""
    return 2 * (n + n * (n - 1) // 2)


def coordinate_names(n):
    """The names of the tangent coordinates, in order."""
    if n == 2:
        return ("a_x", "a_y", "x0 = R√κ·θ", "v_x", "v_y", "v0 = R√κ·ω")
    return ("a_x", "a_y", "a_z", "R√κ·φ_x", "R√κ·φ_y", "R√κ·φ_z", "v_x", "v_y", "v_z", "R√κ·ω_x", "R√κ·ω_y",
            "R√κ·ω_z")


@jit_hot
def spin_components(W, out, n):
    """out[:m] ← ω of the antisymmetric W (2D: W₁₀; 3D: (W₂₁, W₀₂, W₁₀))."""
    if n == 2:
        out[0] = W[1, 0]
    else:
        out[0] = W[2, 1]
        out[1] = W[0, 2]
        out[2] = W[1, 0]


@jit_hot
def spin_matrix_of(w, scale, W, n):
    """W ← the antisymmetric matrix of the spin ``scale``·w (2D: ωJ; 3D: Wx = ω×x)."""
    if n == 2:
        W[0, 0] = 0.0
        W[1, 1] = 0.0
        W[1, 0] = scale * w[0]
        W[0, 1] = -scale * w[0]
    else:
        x, y, z = scale * w[0], scale * w[1], scale * w[2]
        W[0, 0] = 0.0
        W[1, 1] = 0.0
        W[2, 2] = 0.0
        W[2, 1] = x
        W[1, 2] = -x
        W[0, 2] = y
        W[2, 0] = -y
        W[1, 0] = z
        W[0, 1] = -z


@jit
def flight_rotation(W, tau, Rot, K):
    """3D: Rot ← e^{τW} and K ← ∫₀^τ e^{uW} du (Rodrigues; a series for small angles)."""
    wx, wy, wz = W[2, 1], W[0, 2], W[1, 0]
    w2 = wx * wx + wy * wy + wz * wz
    w = np.sqrt(w2)
    phi = tau * w
    if phi < 1e-4:
        # sin φ/w = τ(1 − φ²/6), (1 − cos φ)/w² = τ²(1/2 − φ²/24), (τ − sin φ/w)/w² = τ³(1/6 − φ²/120)
        s = tau * (1.0 - phi * phi / 6.0)
        c1 = tau * tau * (0.5 - phi * phi / 24.0)
        k2 = tau * tau * tau * (1.0 / 6.0 - phi * phi / 120.0)
    else:
        s = np.sin(phi) / w
        c1 = (1.0 - np.cos(phi)) / w2
        k2 = (tau - s) / w2
    for i in range(3):
        for j in range(3):
            ww = 0.0
            for k in range(3):
                ww += W[i, k] * W[k, j]
            e = 1.0 if i == j else 0.0
            Rot[i, j] = e + s * W[i, j] + c1 * ww
            K[i, j] = tau * e + c1 * W[i, j] + k2 * ww


@jit
def flight_tangent(Y, tau, W, Rot, K, tmp, n):
    """Carry the tangent vectors (columns of Y) through a free flight of duration τ (fixed τ: the change of the
    flight time is the collision's δt)."""
    m = n * (n - 1) // 2
    d = Y.shape[1]
    if n == 3:
        flight_rotation(W, tau, Rot, K)
    for k in range(d):
        for i in range(n):
            Y[i, k] += tau * Y[n + m + i, k]
        if n == 2:
            Y[2, k] += tau * Y[5, k]
        else:
            for i in range(3):
                s = 0.0
                for q in range(3):
                    s += Rot[i, q] * Y[3 + q, k] + K[i, q] * Y[9 + q, k]
                tmp[i] = s
            for i in range(3):
                Y[3 + i, k] = tmp[i]


@jit
def collision_tangent(Y, vm, Wm, vp, Wp, nu, J, R, kappa, rank, basis, node, wall, work, n):
    """Carry the tangent vectors (columns of Y) through a collision (docs/tangent-map.md):

        δt  = −(ν·δa)/(ν·v⁻)                               the change of the collision time
        z   = δx⁻ + f(x⁻) δt                                 the perturbation at the perturbed contact
        δx⁺ = DM·z − f(x⁺) δt,   DM = ∂M/∂(v, W) + ∂M/∂ν · ∂ν/∂a

    ``vm``, ``Wm``: the state before the map; ``vp``, ``Wp``: after it; ``nu``, ``J``: the normal and its derivative
    ∂ν_i/∂a_j at the contact; ``rank``, ``basis[node, wall]``: the rule applied there (as in
    :func:`rbx.physics.collide`). ``work``: scratch (12, n)."""
    m = n * (n - 1) // 2
    d = Y.shape[1]
    c = R * np.sqrt(kappa)
    alpha2 = 2.0 * kappa / (1.0 + kappa)
    sc = 2.0 / ((1.0 + kappa) * R)
    vn = 0.0
    for i in range(n):
        vn += vm[i] * nu[i]
    # rows of work: 0 ω̂⁻, 1 δu → δp, 2 scratch, 3 p = P u⁻, 4 ω̂⁺, 5 δa_z, 6 δν, 7 δv', 8 δω
    spin_components(Wm, work[0], n)
    spin_components(Wp, work[4], n)
    for i in range(m):
        work[0, i] *= c
        work[4, i] *= c
    if rank != 0:
        for i in range(n):
            s = 0.0
            for q in range(n):
                s += Wm[i, q] * nu[q]
            work[1, i] = (vm[i] - vn * nu[i]) - R * s
        if rank < n - 1:
            project_roughness(work, rank, basis, node, wall, n)
        for i in range(n):
            work[3, i] = work[1, i]
    dW = np.empty((n, n))
    dWp = np.empty((n, n))
    for k in range(d):
        na = 0.0
        for i in range(n):
            na += nu[i] * Y[i, k]
        dt = -na / vn
        for i in range(n):
            work[5, i] = Y[i, k] + vm[i] * dt
        for i in range(m):
            Y[n + i, k] += work[0, i] * dt
        # δν = J δa_z; δ(v·ν) = δv·ν + v·δν
        dvn = 0.0
        for i in range(n):
            s = 0.0
            for q in range(n):
                s += J[i, q] * work[5, q]
            work[6, i] = s
        for i in range(n):
            dvn += Y[n + m + i, k] * nu[i] + vm[i] * work[6, i]
        for i in range(m):
            work[8, i] = Y[2 * n + m + i, k]
        spin_matrix_of(work[8], 1.0 / c, dW, n)
        for i in range(n):
            work[7, i] = Y[n + m + i, k] - 2.0 * dvn * nu[i] - 2.0 * vn * work[6, i]
        for i in range(n):
            for q in range(n):
                dWp[i, q] = dW[i, q]
        if rank != 0:
            # δu_t = δv − δ(v·ν)ν − (v·ν)δν − R(δW ν + W δν), projected like u_t
            for i in range(n):
                s = 0.0
                for q in range(n):
                    s += dW[i, q] * nu[q] + Wm[i, q] * work[6, q]
                work[1, i] = Y[n + m + i, k] - dvn * nu[i] - vn * work[6, i] - R * s
            if rank < n - 1:
                project_roughness(work, rank, basis, node, wall, n)
            for i in range(n):
                work[7, i] -= alpha2 * work[1, i]
            # δW' = δW + s(δp νᵀ + p δνᵀ − δν pᵀ − ν δpᵀ)
            for i in range(n):
                for q in range(n):
                    dWp[i, q] += sc * (work[1, i] * nu[q] + work[3, i] * work[6, q]
                                       - work[6, i] * work[3, q] - nu[i] * work[1, q])
        for i in range(n):
            Y[i, k] = work[5, i] - vp[i] * dt
            Y[n + m + i, k] = work[7, i]
        spin_components(dWp, work[8], n)
        for i in range(m):
            Y[n + i, k] -= work[4, i] * dt
            Y[2 * n + m + i, k] = c * work[8, i]


@jit
def orthonormalise(Y, sums, j, tmp):
    """Gram–Schmidt twice on the columns of Y (QR: Y = QR, Y ← Q) and sums[j, k] += log R_kk."""
    d = Y.shape[1]
    for k in range(d):
        for _ in range(2):                              # "twice is enough" (Giraud et al.)
            for q in range(k):
                s = 0.0
                for i in range(Y.shape[0]):
                    s += Y[i, q] * Y[i, k]
                tmp[q] = s
            for q in range(k):
                for i in range(Y.shape[0]):
                    Y[i, k] -= tmp[q] * Y[i, q]
        s = 0.0
        for i in range(Y.shape[0]):
            s += Y[i, k] * Y[i, k]
        s = np.sqrt(s)
        sums[j, k] += np.log(s)
        for i in range(Y.shape[0]):
            Y[i, k] /= s


@jit
def tangent_advance(j, stop, t_end, ortho, slab, periodic, spin, tree, renorm_every, R, kappa, table, rules, state, Y,
                    sums):
    """Advance trajectory j and its tangent vectors Y[j] (columns) until it has made ``stop`` collisions or its time
    reaches ``t_end`` (then it stops in flight) -> collisions made in this call.

    The orbit as in :func:`rbx.engine.advance` (default numerics: no snapping, no compensated sums), orientation
    always followed. ``ortho``: re-orthonormalise after each collision, adding log-stretches to ``sums[j]``; else Y
    is the flow's Jacobian applied to the initial Y. ``slab``, ``periodic``, ``spin``, ``tree``: as the engine's bits
    S_SLAB, S_PERIODIC, S_SPIN, S_TREE. The trajectory ends (``alive`` False) on an exit wall (no map; the contact is its last state)
    or when no wall lies ahead."""
    n = state.pos.shape[1]
    codes, prim_wall, params, tol = table.codes, table.prim_wall, table.params, table.tol
    a = state.pos[j]
    v = state.vel[j]
    W = state.W[j]
    A = state.A[j]
    Yj = Y[j]
    nu = np.zeros(n)
    J = np.zeros((n, n))
    vm = np.zeros(n)
    Wm = np.zeros((n, n))
    work = np.zeros((12, n))
    E = np.zeros((3, 3))
    tmp = np.zeros((3, 3))
    Rot = np.zeros((3, 3))
    K = np.zeros((3, 3))
    tv = np.zeros(max(Yj.shape[1], 3))
    base = np.zeros(n)          # periodic tables: the centre's cell, its position relative to the image hit, and
    loc = np.zeros(n)           # that image's shift (loc = a − off)
    off = np.zeros(n)
    ahead = np.zeros(n)         # where a periodic table's flight is looked at from
    th = state.theta[j]
    t = state.time[j]
    c = state.ncoll[j]
    d = state.draws[j]
    key = state.keys[j]
    e0 = state.energy0[j]
    half_inv_e0 = 0.5 / e0
    until_renorm = renorm_every - c % renorm_every if renorm_every > 0 else 0
    made = 0
    while c < stop:
        if slab:
            tau, p = slab_collision(params, a, v, n)
        elif periodic:
            tau, p = periodic_flight(codes, params, a, v, tol, n, table.lattice_lo, table.period, table.images,
                                     table.image_shift, base, loc, off, ahead)
        else:
            tau, p = next_collision(codes, params, a, v, tol, n)
        if t + tau > t_end:                       # stop in flight at t_end (also when no wall lies ahead)
            tau = t_end - t
            p = -3
        if p == -1:
            state.alive[j] = False
            break
        for i in range(n):
            a[i] += tau * v[i]
        t += tau
        if n == 2:
            th += tau * W[1, 0]
        else:
            rotate(A, W, tau, E, tmp)
        flight_tangent(Yj, tau, W, Rot, K, tv, n)
        if p == -3:
            t = t_end
            break
        if not periodic:
            for i in range(n):
                loc[i] = a[i]
        else:
            for i in range(n):
                loc[i] = a[i] - off[i]
        if slab:
            a[n - 1] = params[p, n - 1]
            for i in range(n - 1):
                nu[i] = 0.0
            nu[n - 1] = 1.0 if p == 0 else -1.0
        else:
            contact_normal(codes[p], params, p, loc, nu, n)
        w = prim_wall[p]
        if tree:
            node, d = choose(w, nu, A, th, key, d, rules.root, rules.kind, rules.first, rules.children,
                             rules.threshold, rules.axis, rules.phase, n, True)
        else:
            node = rules.root[w]
        state.last_wall[j] = w
        if rules.kind[node] == EXIT:
            state.last_rank[j] = -1
            state.alive[j] = False
            break
        rk = rules.rank[node]
        state.last_rank[j] = rk
        f = 0.0
        map_rank = 0
        if spin:
            map_rank = rk
            if renorm_every > 0:
                until_renorm -= 1
                if until_renorm == 0:
                    until_renorm = renorm_every
                    f = energy_factor(v, W, R, kappa, e0, half_inv_e0, n)
        for i in range(n):
            vm[i] = v[i]
            for q in range(n):
                Wm[i, q] = W[i, q]
        if slab:
            collide_axis(v, W, n - 1, nu[n - 1], R, kappa, map_rank, rules.basis, node, w, work, n)
            for i in range(n):
                for q in range(n):
                    J[i, q] = 0.0
        else:
            collide(v, W, nu, R, kappa, map_rank, rules.basis, node, w, work, n)
            normal_jacobian(codes[p], params, p, loc, J, n)
        if f != 0.0:
            scale_state(v, W, f, n)
        collision_tangent(Yj, vm, Wm, v, W, nu, J, R, kappa, map_rank, rules.basis, node, w, work, n)
        if ortho:
            orthonormalise(Yj, sums, j, tv)
        c += 1
        made += 1
    state.theta[j] = th
    state.time[j] = t
    state.ncoll[j] = c
    state.draws[j] = d
    return made


@jit
def tangent_advance_all(j0, j1, stop, t_end, ortho, slab, periodic, spin, tree, renorm_every, R, kappa, table, rules,
                        state, Y, sums):
    """:func:`tangent_advance` for the live trajectories j0 ≤ j < j1 (``nogil``: slices run on threads)."""
    for j in range(j0, j1):
        if state.alive[j]:
            tangent_advance(j, stop[j], t_end[j], ortho, slab, periodic, spin, tree, renorm_every, R, kappa, table,
                            rules, state, Y, sums)
