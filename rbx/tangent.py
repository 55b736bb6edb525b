"""The linearised dynamics of the rough billiard flow and Benettin's method (docs/reference.md §10;
docs/tangent-map.md).

These are the tangent steps of the engine's own loop (:func:`rbx.engine.kernel` with the bit ``S_TANGENT``): the
orbit is the one ``rbx simulate`` records, by construction, and only the tangent part is added beside it.
Beside the state, tangent vectors (the columns of ``Y``) are carried through

- the free flight: δa += τ δv, δφ̂ ← e^{τW} δφ̂ + (∫₀^τ e^{uW} du) δω̂ (2D: δθ̂ += τ δω̂);
- each collision: δx⁺ = DM·(δx⁻ + f⁻ δt) − f⁺ δt with δt = −(ν·δa)/(ν·v⁻), where DM is the derivative of the
  collision map in (v, W) and, through ν(a), in the contact point (:func:`rbx.geometry.normal_jacobian`).

Tangent coordinates (d = 2(n + m), m = n(n−1)/2 spin components): ``[δa (n), δφ̂ (m), δv (n), δω̂ (m)]``, the
orientation and spin scaled by c = R√κ (2D: x₀ = R√κ θ, v₀ = R√κ ω of the paper §2.6; 3D: the space-frame rotation
vector δφ with δA = [δφ]×A, and ω) so that the kinetic energy is ½|(v, ω̂)|² and the collision map is orthogonal
on (v, ω̂). The tangent vectors are the rows of ``Y`` (each contiguous); :func:`step2`/:func:`step3` take them through
a flight and the collision at its end in one call. With ``orthonormalise2``/``3`` they are re-orthonormalised
(Gram–Schmidt, a second pass where the first cancelled much) every few collisions (the engine decides when:
``engine.Tangent.ortho``, ``grow``) and the logarithms of the stretches are added to ``sums`` (through the
products ``prod``, :func:`fold`): their growth per unit time is the Lyapunov spectrum.
"""
import numpy as np

from ._jit import jit_call, jit_hot, stack_array
from .physics import project_roughness
from .trig import sincos


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


@jit_hot
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
        cs, sn = sincos(phi)            # inline (rbx.trig): a libm call spills the step's registers
        s = sn / w
        c1 = (1.0 - cs) / w2
        k2 = (tau - s) / w2
    for i in range(3):
        for j in range(3):
            # (W²)_ij = Σ_k W_ik W_kj without the products by W's zero diagonal (the same bits but the sign of a zero)
            if i == j:
                ww = 0.0
                for k in range(3):
                    if k != i:
                        ww += W[i, k] * W[k, j]
            else:
                ww = W[i, 3 - i - j] * W[3 - i - j, j]
            e = 1.0 if i == j else 0.0
            Rot[i, j] = e + s * W[i, j] + c1 * ww
            K[i, j] = tau * e + c1 * W[i, j] + k2 * ww


@jit_hot
def _step(Y, tau, collide_too, T, curved, R, kappa, rank, n):
    """Carry the tangent vectors (the rows of Y) through a free flight of duration τ and then, if
    ``collide_too``, through the collision at its end (docs/tangent-map.md):

        flight:     δa += τ δv, δφ̂ ← e^{τW} δφ̂ + (∫₀^τ e^{uW} du) δω̂ (2D: δθ̂ += τ δω̂)    (fixed τ: the change
                    of the flight time is the collision's δt)
        δt  = −(ν·δa)/(ν·v⁻)                               the change of the collision time
        z   = δx⁻ + f(x⁻) δt                                 the perturbation at the perturbed contact
        δx⁺ = DM·z − f(x⁺) δt,   DM = ∂M/∂(v, W) + ∂M/∂ν · ∂ν/∂a

    ``T`` (:data:`STATE_SHAPE`, filled by the caller, :func:`state_before` and :func:`state_after`): the state
    before the map (and during the flight) ``T[3, 0, 0]`` = v⁻, ``T[0, 0]`` = W⁻; after it ``T[3, 0, 1]``,
    ``T[1, 0]``; the normal ``T[3, 0, 2]`` and its derivative ∂ν_i/∂a_j at the contact ``T[2, 0]`` (``curved``
    False: a flat wall, J = 0 and not read); the rule's roughness basis ``T[4, 0]`` where its rank is below
    n − 1; the time unit u of the stored vectors and 1/u in ``T[5, 0, 0, :2]`` (:func:`set_unit`: the rows of Y
    hold u·δv and u·δω̂, converted on the way in and out; u = 1, a number no other unit takes, converts nothing) (the map projects onto it: :func:`rbx.physics.project_roughness` reads ``T`` as it reads
    ``rules.basis``, at node 4 and wall 0). One array, not seven: on an Intel Xeon the call with the seven (about
    ninety words of arguments, most on the stack) cost 23 ns a collision of the 3D box, half of the engine's own
    time there. ``rank``: the rule applied there (as in :func:`rbx.physics.collide`). ``n`` a literal
    (the 2D and 3D steps are compiled apart): every index into the step's own arrays is then a constant and they
    live in registers, each vector is loaded once, taken through the flight and the collision, and stored once.
    The arithmetic is the one of the per-coordinate formulas in docs/tangent-map.md, in the same order; what a
    flat wall's J = 0 multiplies is left out (adding ±0 changes no bit but the sign of a zero)."""
    vm = T[3, 0, 0]
    vp = T[3, 0, 1]
    nu = T[3, 0, 2]
    Wm = T[0, 0]
    Wp = T[1, 0]
    J = T[2, 0]
    m = n * (n - 1) // 2
    d = 2 * (n + m)
    K = Y.shape[0]
    grown = 0.0
    y = stack_array(12, (d,))           # one tangent vector
    z = stack_array(3, (n,))            # δa at the perturbed contact
    dnu = stack_array(3, (n,))          # δν
    dvp = stack_array(3, (n,))          # δv'
    w0 = stack_array(3, (3,))           # ω̂⁻, ω̂⁺, δω (scaled)
    w4 = stack_array(3, (3,))
    dw = stack_array(3, (3,))
    work = stack_array(9, (3, n))       # rows: 1 δu → δp, 2 scratch (physics.project_roughness)
    p = stack_array(3, (n,))            # P u⁻
    dW = stack_array(9, (n, n))
    dWp = stack_array(9, (n, n))
    Rot = stack_array(9, (3, 3))
    Kf = stack_array(9, (3, 3))
    tmp = stack_array(3, (3,))
    if n == 3:
        flight_rotation(Wm, tau, Rot, Kf)
    c = R * np.sqrt(kappa)
    alpha2 = 2.0 * kappa / (1.0 + kappa)
    sc = 2.0 / ((1.0 + kappa) * R)
    vn = 0.0
    if collide_too:
        for i in range(n):
            vn += vm[i] * nu[i]
        spin_components(Wm, w0, n)
        spin_components(Wp, w4, n)
        for i in range(m):
            w0[i] *= c
            w4[i] *= c
        if rank != 0:
            for i in range(n):
                s = 0.0
                for q in range(n):
                    s += Wm[i, q] * nu[q]
                work[1, i] = (vm[i] - vn * nu[i]) - R * s
            if rank < n - 1:
                project_roughness(work, rank, T, 4, 0, n)
            for i in range(n):
                p[i] = work[1, i]
    unit = T[5, 0, 0, 0]
    inv = T[5, 0, 0, 1]
    for k in range(K):
        for i in range(d):
            y[i] = Y[k, i]
        if unit != 1.0:                 # stored in units of the time unit: exact (a power of two)
            for i in range(n + m, d):
                y[i] *= inv
        # the flight
        for i in range(n):
            y[i] += tau * y[n + m + i]
        if n == 2:
            y[2] += tau * y[5]
        else:
            for i in range(3):
                s = 0.0
                for q in range(3):
                    s += Rot[i, q] * y[3 + q] + Kf[i, q] * y[9 + q]
                tmp[i] = s
            for i in range(3):
                y[3 + i] = tmp[i]
        if collide_too:
            na = 0.0
            for i in range(n):
                na += nu[i] * y[i]
            dt = -na / vn
            for i in range(n):
                z[i] = y[i] + vm[i] * dt
            for i in range(m):
                y[n + i] += w0[i] * dt
            # δν = J δa_z; δ(v·ν) = δv·ν + v·δν
            dvn = 0.0
            if curved:
                for i in range(n):
                    s = 0.0
                    for q in range(n):
                        s += J[i, q] * z[q]
                    dnu[i] = s
                for i in range(n):
                    dvn += y[n + m + i] * nu[i] + vm[i] * dnu[i]
                for i in range(n):
                    dvp[i] = y[n + m + i] - 2.0 * dvn * nu[i] - 2.0 * vn * dnu[i]
            else:
                for i in range(n):
                    dnu[i] = 0.0
                for i in range(n):
                    dvn += y[n + m + i] * nu[i]
                for i in range(n):
                    dvp[i] = y[n + m + i] - 2.0 * dvn * nu[i]
            for i in range(m):
                dw[i] = y[2 * n + m + i]
            spin_matrix_of(dw, 1.0 / c, dW, n)
            for i in range(n):
                for q in range(n):
                    dWp[i, q] = dW[i, q]
            if rank != 0:
                # δu_t = δv − δ(v·ν)ν − (v·ν)δν − R(δW ν + W δν), projected like u_t
                for i in range(n):
                    s = 0.0
                    if curved:
                        for q in range(n):
                            s += dW[i, q] * nu[q] + Wm[i, q] * dnu[q]
                        work[1, i] = y[n + m + i] - dvn * nu[i] - vn * dnu[i] - R * s
                    else:
                        for q in range(n):
                            s += dW[i, q] * nu[q]
                        work[1, i] = y[n + m + i] - dvn * nu[i] - R * s
                if rank < n - 1:
                    project_roughness(work, rank, T, 4, 0, n)
                for i in range(n):
                    dvp[i] -= alpha2 * work[1, i]
                # δW' = δW + s(δp νᵀ + p δνᵀ − δν pᵀ − ν δpᵀ)
                if curved:
                    for i in range(n):
                        for q in range(n):
                            dWp[i, q] += sc * (work[1, i] * nu[q] + p[i] * dnu[q] - dnu[i] * p[q]
                                               - nu[i] * work[1, q])
                else:
                    for i in range(n):
                        for q in range(n):
                            dWp[i, q] += sc * (work[1, i] * nu[q] - nu[i] * work[1, q])
            for i in range(n):
                y[i] = z[i] - vp[i] * dt
                y[n + m + i] = dvp[i]
            spin_components(dWp, dw, n)
            for i in range(m):
                y[n + i] -= w4[i] * dt
                y[2 * n + m + i] = c * dw[i]
        if unit != 1.0:
            for i in range(n + m, d):
                y[i] *= unit
        for i in range(d):
            Y[k, i] = y[i]
        if k == 0:
            for i in range(d):
                grown += y[i] * y[i]
    return grown


@jit_call
def step2(Y, tau, collide_too, T, curved, R, kappa, rank):
    """:func:`_step` in 2D (6 tangent coordinates), compiled once and called by the general loop."""
    return _step(Y, tau, collide_too, T, curved, R, kappa, rank, 2)


@jit_call
def step3(Y, tau, collide_too, T, curved, R, kappa, rank):
    """:func:`_step` in 3D (12 tangent coordinates), compiled once and called by the general loop."""
    return _step(Y, tau, collide_too, T, curved, R, kappa, rank, 3)


@jit_hot
def _orthonormalise(Y, sums, prod, j, d):
    """Gram–Schmidt on the rows of Y (K vectors of ``d`` coordinates, ``d`` a literal); row k's stretch (QR of Yᵀ:
    Yᵀ = QR, Yᵀ ← Q, the stretch R_kk) is multiplied into ``prod[k]``, whose logarithm is added to sums[j, k] only
    when it leaves [1e-150, 1e150] and by :func:`fold` (a call of libm's ``log`` per vector per QR was an eighth of
    the loop). Each row is projected off the ones before it, and a second time only if the first pass cancelled
    more than half of its squared length (the criterion of Daniel, Gragg, Kaufman and Stewart, η = 1/√2: "twice is
    enough", and once is enough when little cancels)."""
    K = Y.shape[0]
    y = stack_array(12, (d,))
    tmp = stack_array(12, (12,))
    for k in range(K):
        for i in range(d):
            y[i] = Y[k, i]
        before = 0.0
        if k > 0:
            for i in range(d):
                before += y[i] * y[i]
        for _ in range(2):
            for q in range(k):
                s = 0.0
                for i in range(d):
                    s += Y[q, i] * y[i]
                tmp[q] = s
            for q in range(k):
                for i in range(d):
                    y[i] -= tmp[q] * Y[q, i]
            s = 0.0
            for i in range(d):
                s += y[i] * y[i]
            if s >= 0.5 * before:
                break
            before = s
        s = np.sqrt(s)
        g = prod[k] * s
        if g > 1e150 or g < 1e-150:
            sums[j, k] += np.log(g)
            g = 1.0
        prod[k] = g
        for i in range(d):
            Y[k, i] = y[i] / s


@jit_call
def orthonormalise2(Y, sums, prod, j):
    """:func:`_orthonormalise` of 2D tangent vectors."""
    _orthonormalise(Y, sums, prod, j, 6)


@jit_call
def orthonormalise3(Y, sums, prod, j):
    """:func:`_orthonormalise` of 3D tangent vectors."""
    _orthonormalise(Y, sums, prod, j, 12)


@jit_hot
def fold(sums, prod, j, K):
    """sums[j, k] += log prod[k], prod[k] ← 1 (k < K): the stretches multiplied since the last fold, added to the
    sums before a trajectory leaves the loop (the sums are complete at every stop)."""
    for k in range(K):
        sums[j, k] += np.log(prod[k])
        prod[k] = 1.0


@jit_hot
def step(Y, tau, collide_too, T, curved, R, kappa, rank, n):
    """:func:`step2` or :func:`step3`, for the dimension ``n`` (a constant of the calling loop): called, for the
    general loop (the test suite's one loop per dimension); the specialised loops take :func:`step_inline`."""
    if n == 2:
        return step2(Y, tau, collide_too, T, curved, R, kappa, rank)
    return step3(Y, tau, collide_too, T, curved, R, kappa, rank)


@jit_hot
def step_inline(Y, tau, collide_too, T, curved, R, kappa, rank, n):
    """:func:`_step` inlined into the calling loop: the specialised loops users run. Called, the step cost 16–20 ns
    a collision of the 3D box's λ₁ loop (10 % on an Intel Xeon: the call's arguments, and the loop's registers
    saved around it); inlined into the general loop, it made that loop's compile longer by 9 s in each
    dimension, which the test suite pays on a cold cache. The same operations in the same order either way
    (tests/test_kernels.py compares the two loops bit for bit)."""
    return _step(Y, tau, collide_too, T, curved, R, kappa, rank, n)


@jit_hot
def orthonormalise(Y, sums, prod, j, n):
    """:func:`orthonormalise2` or :func:`orthonormalise3`, for the dimension ``n``."""
    if n == 2:
        orthonormalise2(Y, sums, prod, j)
    else:
        orthonormalise3(Y, sums, prod, j)


@jit_hot
def last_flight(Y, sums, prod, j, since, tau, T, W, R, kappa, n):
    """The tangent step of a flight that ends without a collision map (the stop at the end time, or an exit): the
    stretches of the ``since`` collisions taken since the last re-orthonormalisation are added first (so that
    they are not mixed with the flight's), then the flight alone (``W`` the spin during it) -> 0, the collisions
    since."""
    if since > 0:
        orthonormalise(Y, sums, prod, j, n)
    for i in range(n):
        for q in range(n):
            T[0, 0, i, q] = W[i, q]
    step(Y, tau, False, T, False, R, kappa, 0, n)
    return 0


#: the shape of the array ``T`` that hands the step the state around a collision (:func:`_step`): six 3 × 3
#: blocks, each shaped as one (node, wall) of ``rules.basis``; the last holds the time unit of the stored
#: velocity-like coordinates and its inverse (:func:`set_unit`)
STATE_SHAPE = (6, 1, 3, 3)


@jit_hot
def set_unit(T, unit):
    """T ← the time unit of the stored tangent vectors' velocity-like coordinates (:class:`rbx.engine.Tangent`)."""
    T[5, 0, 0, 0] = unit
    T[5, 0, 0, 1] = 1.0 / unit


@jit_hot
def state_before(T, v, W, n):
    """T ← the state before the collision map: v⁻ and W⁻ (the spin during the flight)."""
    for i in range(n):
        T[3, 0, 0, i] = v[i]
        for q in range(n):
            T[0, 0, i, q] = W[i, q]


@jit_hot
def state_after(T, v, W, nu, rank, basis, node, wall, n):
    """T ← the state after the map, the normal, and where the rule's rank is below n − 1 its roughness basis
    (the normal's derivative is written into ``T[2, 0]`` by the caller, on a curved wall)."""
    for i in range(n):
        T[3, 0, 1, i] = v[i]
        T[3, 0, 2, i] = nu[i]
        for q in range(n):
            T[1, 0, i, q] = W[i, q]
    if rank != 0 and rank < n - 1:
        for q in range(rank):
            for i in range(n):
                T[4, 0, q, i] = basis[node, wall, q, i]
