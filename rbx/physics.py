"""The strict collision map in the space frame (docs/reference.md §1; paper eq. (update)), written once for any
dimension n.

State at contact: centre velocity ``v`` (n), angular velocity ``W`` (n×n antisymmetric, space frame; 2D ``W = ωJ``,
3D ``Wx = ω×x``), unit wall normal ``nu`` pointing into the free region, ball radius ``R``, ``kappa = 2λ/R²``.

    r    = −R ν                         contact point seen from the centre
    u    = v + W r                      velocity of the touching material point
    u_t  = u − (u·ν) ν                  its tangential part (the slip velocity)
    Δv_t = −2α P u_t,  α = κ/(1+κ)      P: projector onto the roughness subspace (rank k)
    v'   = v − 2(v·ν)ν + Δv_t
    W'   = W + (r ∧ Δv_t)/(2λ),         (a ∧ b) = b aᵀ − a bᵀ   (3D: ω' = ω + r×Δv_t/(2λ))

The roughness subspace is given by ``rank`` and, when ``0 < rank < n−1``, an orthonormal ``basis`` whose first
``rank`` rows span it; rank 0 is specular reflection and rank n−1 the completely rough (no-slip) map, for which
no basis is needed (P is the tangent projector at whatever point of the wall was hit).
"""
import numpy as np

from ._jit import jit, jit_hot
from .model import INERTIA_KAPPA, kappa_of  # noqa: F401 - κ of the mass distributions: the ball's, in rbx.model


@jit_hot
def project_roughness(work, rank, basis, node, wall, n):
    """work[1] ← P·work[1], P the projector onto the span of the first ``rank`` rows of ``basis[node, wall]`` (an
    orthonormal basis of the roughness subspace); work[2] is scratch."""
    for i in range(n):
        work[2, i] = 0.0
    for q in range(rank):
        c = 0.0
        for i in range(n):
            c += work[1, i] * basis[node, wall, q, i]
        for i in range(n):
            work[2, i] += c * basis[node, wall, q, i]
    for i in range(n):
        work[1, i] = work[2, i]


@jit_hot
def rough_factor(rank, blend):
    """1.0, or with ``blend`` 0.0 at rank 0 and 1.0 above: the map's rough change is multiplied by it. Where a
    wall's rank is drawn at random (engine.S_BLEND), a branch on it is mispredicted about every other time (about
    13 ns on the strip); computing the rough change always and multiplying it by 0 costs a few operations.
    x − 0·y is x, so the state is the specular map's to the sign of a zero. (A hemisphere rule keeps the branch:
    its rank follows the orbit, which the branch predicts ahead.)"""
    if blend:
        return np.float64(rank > 0)
    return 1.0


@jit_hot
def collide(v, W, nu, R, kappa, rank, basis, node, wall, work, n, blend):
    """Apply the strict collision map in place: (v, W) <- (v', W'); returns nothing.  docs/reference.md §1, paper
    eq. (update).

    The normal velocity is reversed exactly (``v·ν`` changes sign), so the next flight leaves the wall.
    ``basis[node, wall]`` holds the roughness basis (rows) and ``work`` is scratch space of shape (3, n): the
    kernel passes whole arrays and indices, since every array view costs reference counting in the hot loop.
    ``n`` is the dimension, passed in so that the kernels compile it as a constant. ``blend`` (the kernel's
    run-time bit engine.S_BLEND) computes the rough change at rank 0 too and multiplies it by 0
    (:func:`rough_factor`).
    """
    vn = 0.0
    for i in range(n):
        vn += v[i] * nu[i]
    if not blend and rank == 0:     # blend first: with it, no branch on the rank
        for i in range(n):
            v[i] -= 2.0 * vn * nu[i]
        return
    g = rough_factor(rank, blend)
    # slip velocity u_t = (v − (v·ν)ν) + W r with r = −Rν (W r is tangent: W is antisymmetric), written so that
    # the chain of operations from (v, W) to (v', W') is short: it is what bounds a trajectory's speed
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += W[i, j] * nu[j]
        work[1, i] = (v[i] - vn * nu[i]) - R * s
    # its projection P u_t onto the roughness subspace (the whole tangent plane for the completely rough map)
    if rank > 0 and rank < n - 1:
        project_roughness(work, rank, basis, node, wall, n)
    # Δv = −2α P u_t, and W += (Δv rᵀ − r Δvᵀ)/(2λ) with r = −Rν, 2λ = κR²: since α/κ = 1/(1+κ) the spin
    # change is (2/((1+κ)R))·(P u_t νᵀ − ν (P u_t)ᵀ), computed without dividing by κ (finite as κ → 0)
    alpha2 = g * (2.0 * kappa / (1.0 + kappa))
    scale = g * (2.0 / ((1.0 + kappa) * R))
    for i in range(n):
        v[i] = (v[i] - 2.0 * vn * nu[i]) - alpha2 * work[1, i]
        work[2, i] = scale * nu[i]
    # W is antisymmetric: the upper triangle is updated and mirrored (the lower one's increments are the exact
    # negatives of the upper one's, the diagonal's exactly 0: the same matrix, in n(n−1)/2 updates instead of n²)
    for i in range(n):
        for j in range(i + 1, n):
            W[i, j] += work[1, i] * work[2, j] - work[2, i] * work[1, j]
            W[j, i] = -W[i, j]


@jit_hot
def collide_axis(v, W, m, sigma, R, kappa, rank, basis, node, wall, work, n, blend):
    """:func:`collide` for a wall normal ν = σ·e_m (σ = ±1: the walls of a strip or between plates, the sides of an
    axis-aligned box), with the products by the zero components of ν left out -> the same (v', W') as
    :func:`collide`, bit for bit up to the sign of zeros (tests/test_physics.py). Only v_m (reversed) and the
    column and row m of W change, and the chain of operations from (v, W) to (v', W') is about half as long.
    ``m`` is a constant where the kernels call it (each axis its own call), so that every index stays a constant."""
    v[m] = -v[m]
    if not blend and rank == 0:     # blend first: with it, no branch on the rank
        return
    g = rough_factor(rank, blend)
    # u_t,i = v_i + (W r)_i with r = −Rσ e_m, for i ≠ m; u_t,m = 0
    rs = R * sigma
    for i in range(n):
        if i != m:
            work[1, i] = v[i] - rs * W[i, m]
    work[1, m] = 0.0
    if rank > 0 and rank < n - 1:
        project_roughness(work, rank, basis, node, wall, n)
    alpha2 = g * (2.0 * kappa / (1.0 + kappa))
    c = g * ((2.0 / ((1.0 + kappa) * R)) * sigma)
    for i in range(n):
        if i != m:
            v[i] -= alpha2 * work[1, i]
            W[i, m] += c * work[1, i]
            W[m, i] -= c * work[1, i]


def collision_map(v, W, nu, R, kappa, rank, basis=None):
    """Pure form of :func:`collide` -> (v', W') as new arrays; ``W`` may also be a 2D scalar ω or a 3D vector ω."""
    v = np.array(v, dtype=float)
    n = v.shape[0]
    Wm = spin_matrix(W, n)
    b = np.zeros((max(n - 1, 1), n)) if basis is None else np.asarray(basis, dtype=float)
    collide(v, Wm, np.asarray(nu, dtype=float), float(R), float(kappa), int(rank), b[None, None], 0, 0,
            np.empty((3, n)), n, False)
    return v, Wm


def spin_matrix(w, n):
    """Angular velocity as the antisymmetric n×n matrix W (2D: ω J; 3D: W x = ω × x; else already a matrix)."""
    w = np.asarray(w, dtype=float)
    if w.ndim == 2:
        return w.copy()
    if n == 2:
        return np.array([[0.0, -float(w)], [float(w), 0.0]])
    if n == 3:
        return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    raise ValueError("give the angular velocity as an n×n antisymmetric matrix for n > 3")


def spin_vector(W):
    """Inverse of :func:`spin_matrix`: 2D scalar ω, 3D vector ω."""
    W = np.asarray(W)
    if W.shape[-1] == 2:
        return W[..., 1, 0]
    return np.stack([W[..., 2, 1], W[..., 0, 2], W[..., 1, 0]], axis=-1)


def energy(v, W, R, kappa):
    """Kinetic energy per unit mass ½(|v|² + 2λ|ω|²) = ½|v|² + ¼κR²·tr(WᵀW)."""
    v = np.asarray(v, dtype=float)
    W = np.asarray(W, dtype=float)
    return 0.5 * np.sum(v * v, axis=-1) + 0.25 * kappa * R * R * np.sum(W * W, axis=(-2, -1))


def rotation_from_vector(rv):
    """Rotation matrix exp([rv]×) of a 3D rotation vector (Rodrigues)."""
    rv = np.asarray(rv, dtype=float)
    th = float(np.linalg.norm(rv))
    K = spin_matrix(rv, 3)
    if th < 1e-12:
        return np.eye(3) + K
    return np.eye(3) + np.sin(th) / th * K + (1.0 - np.cos(th)) / th**2 * K @ K
