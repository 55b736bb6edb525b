"""The strict collision map (docs/reference.md §1, paper eq. (update)) in n = 2, 3, 4: invariants and closed forms."""
import numpy as np
import pytest

from rbx.physics import collision_map, energy, kappa_of, spin_matrix

DIMS = (2, 3, 4)


def random_state(rng, n):
    v = rng.normal(size=n)
    A = rng.normal(size=(n, n))
    W = A - A.T
    nu = rng.normal(size=n)
    nu /= np.linalg.norm(nu)
    R = rng.uniform(0.05, 2.0)
    kappa = rng.uniform(0.01, 1.0)
    return v, W, nu, R, kappa


def roughness_basis(rng, nu, k):
    """An orthonormal basis (rows) of a random k-dimensional subspace of the tangent plane ν⊥, padded with zeros."""
    n = len(nu)
    X = rng.normal(size=(n, max(k, 1)))
    X -= np.outer(nu, nu @ X)
    Q, _ = np.linalg.qr(X)
    basis = np.zeros((max(n - 1, 1), n))
    basis[:k] = Q[:, :k].T
    return basis


def cases(n, count=40, seed=0):
    rng = np.random.default_rng(seed + 10 * n)
    for _ in range(count):
        v, W, nu, R, kappa = random_state(rng, n)
        k = int(rng.integers(0, n))
        yield v, W, nu, R, kappa, k, roughness_basis(rng, nu, k)


def literal_map(v, W, nu, R, kappa, k, basis):
    """docs/reference.md §1 written with matrices, as the paper states it: P = Σ dᵢdᵢᵀ (or the tangent projector if
    k = n−1)."""
    n = len(v)
    r = -R * nu
    u = v + W @ r
    ut = u - (u @ nu) * nu
    P = np.eye(n) - np.outer(nu, nu) if k == n - 1 else basis[:k].T @ basis[:k]
    alpha = kappa / (1 + kappa)
    dv = -2 * alpha * P @ ut
    lam2 = kappa * R * R
    return v - 2 * (v @ nu) * nu + dv, W + (np.outer(dv, r) - np.outer(r, dv)) / lam2


@pytest.mark.parametrize("n", DIMS)
def test_matches_the_literal_matrix_form(n):
    for v, W, nu, R, kappa, k, basis in cases(n):
        v1, W1 = collision_map(v, W, nu, R, kappa, k, basis)
        v2, W2 = literal_map(v, W, nu, R, kappa, k, basis)
        np.testing.assert_allclose(v1, v2, atol=1e-12)
        np.testing.assert_allclose(W1, W2, atol=1e-12 * max(1, np.abs(W2).max()))


@pytest.mark.parametrize("n", DIMS)
def test_energy_is_kept(n):
    for v, W, nu, R, kappa, k, basis in cases(n):
        v1, W1 = collision_map(v, W, nu, R, kappa, k, basis)
        e0, e1 = energy(v, W, R, kappa), energy(v1, W1, R, kappa)
        assert abs(e1 - e0) <= 1e-13 * e0


@pytest.mark.parametrize("n", DIMS)
def test_the_map_is_an_involution(n):
    for v, W, nu, R, kappa, k, basis in cases(n):
        v1, W1 = collision_map(v, W, nu, R, kappa, k, basis)
        v2, W2 = collision_map(v1, W1, nu, R, kappa, k, basis)
        np.testing.assert_allclose(v2, v, atol=1e-12)
        np.testing.assert_allclose(W2, W, atol=1e-11 * max(1, np.abs(W).max()))


@pytest.mark.parametrize("n", DIMS)
def test_angular_momentum_about_the_contact_point_is_kept(n):
    # 3D: −r×v + 2λω; in any n the matrix 2λW + r vᵀ − v rᵀ (r ∧ v as in docs/reference.md §1)
    for v, W, nu, R, kappa, k, basis in cases(n):
        v1, W1 = collision_map(v, W, nu, R, kappa, k, basis)
        r = -R * nu
        lam2 = kappa * R * R

        def L(v, W):
            return lam2 * W + np.outer(r, v) - np.outer(v, r)
        np.testing.assert_allclose(L(v1, W1), L(v, W), atol=1e-12 * max(1, np.abs(L(v, W)).max()))


def test_angular_momentum_in_3d_is_the_cross_product_form():
    rng = np.random.default_rng(5)
    for _ in range(20):
        v, _, nu, R, kappa = random_state(rng, 3)
        w = rng.normal(size=3)
        v1, W1 = collision_map(v, w, nu, R, kappa, 2)
        w1 = np.array([W1[2, 1], W1[0, 2], W1[1, 0]])
        r = -R * nu
        lam2 = kappa * R * R
        np.testing.assert_allclose(-np.cross(r, v1) + lam2 * w1, -np.cross(r, v) + lam2 * w, atol=1e-12)


@pytest.mark.parametrize("n", DIMS)
def test_normal_velocity_is_reversed_and_tangential_unslipping_part_untouched(n):
    for v, W, nu, R, kappa, k, basis in cases(n):
        v1, _ = collision_map(v, W, nu, R, kappa, k, basis)
        assert v1 @ nu == pytest.approx(-(v @ nu), abs=1e-13)
        if k == 0:
            np.testing.assert_allclose(v1, v - 2 * (v @ nu) * nu, atol=1e-14)


@pytest.mark.parametrize("n", DIMS)
def test_identity_on_states_whose_contact_point_does_not_slip(n):
    for _, W, nu, R, kappa, k, basis in cases(n):
        v = -W @ (-R * nu)                      # u = v + W r = 0: the touching point is at rest
        assert abs(v @ nu) < 1e-12
        v1, W1 = collision_map(v, W, nu, R, kappa, k, basis)
        np.testing.assert_allclose(v1, v, atol=1e-12)
        np.testing.assert_allclose(W1, W, atol=1e-12)


@pytest.mark.parametrize("kappa", [0.5, 0.1, 0.4, 2 / 3, 1.0])
def test_2d_completely_rough_matrix_in_angle_position_coordinates(kappa):
    # docs/reference.md §1: on (v0, v·Jν), v0 = R√κ·ω, the map is
    # [[(κ−1)/(1+κ), 2√κ/(1+κ)], [2√κ/(1+κ), (1−κ)/(1+κ)]]
    M = np.array([[kappa - 1, 2 * np.sqrt(kappa)], [2 * np.sqrt(kappa), 1 - kappa]]) / (1 + kappa)
    rng = np.random.default_rng(7)
    for _ in range(30):
        th = rng.uniform(0, 2 * np.pi)
        nu = np.array([np.cos(th), np.sin(th)])
        Jnu = np.array([-nu[1], nu[0]])
        v, w, R = rng.normal(size=2), rng.normal(), rng.uniform(0.1, 3)
        v1, W1 = collision_map(v, w, nu, R, kappa, 1)
        s = R * np.sqrt(kappa)
        np.testing.assert_allclose([s * W1[1, 0], v1 @ Jnu], M @ [s * w, v @ Jnu], atol=1e-12)
        assert v1 @ nu == pytest.approx(-(v @ nu))


def test_paper_eq_update2_for_the_uniform_disc():
    # paper eq. (update2): v0⁺ = −v0/3 + (2√2/3) v·Jν;  v⁺ = [(2√2/3) v0 + (1/3) v·Jν] Jν − (v·ν) ν,  x0 = Rθ/√2
    rng = np.random.default_rng(11)
    kappa = kappa_of("uniform", 2)
    assert kappa == 0.5
    for _ in range(30):
        th = rng.uniform(0, 2 * np.pi)
        nu = np.array([np.cos(th), np.sin(th)])
        Jnu = np.array([-nu[1], nu[0]])
        v, w, R = rng.normal(size=2), rng.normal(), rng.uniform(0.1, 3)
        v0 = R * w / np.sqrt(2)
        v1, W1 = collision_map(v, w, nu, R, kappa, 1)
        c = 2 * np.sqrt(2) / 3
        assert R * W1[1, 0] / np.sqrt(2) == pytest.approx(-v0 / 3 + c * (v @ Jnu), abs=1e-12)
        np.testing.assert_allclose(v1, (c * v0 + (v @ Jnu) / 3) * Jnu - (v @ nu) * nu, atol=1e-12)


def test_3d_rank_one_acts_only_along_its_direction():
    rng = np.random.default_rng(3)
    nu = np.array([0.0, 0.0, 1.0])
    d = np.array([np.cos(0.3), np.sin(0.3), 0.0])
    across = np.cross(nu, d)
    basis = np.array([d, [0, 0, 0]])
    for _ in range(20):
        v, w = rng.normal(size=3), rng.normal(size=3)
        v1, W1 = collision_map(v, w, nu, 0.2, 0.4, 1, basis)
        assert v1 @ across == pytest.approx(v @ across, abs=1e-13)   # smooth across d
        dw = np.array([W1[2, 1], W1[0, 2], W1[1, 0]]) - w
        assert dw @ d == pytest.approx(0.0, abs=1e-12)                # the spin changes only about ν×d


def test_spin_matrix_conventions():
    # 2D: W = ωJ (counter-clockwise); 3D: W x = ω × x
    assert np.allclose(spin_matrix(2.0, 2) @ [1, 0], [0, 2])
    w, x = np.array([0.3, -1.2, 0.7]), np.array([1.0, 2.0, -0.5])
    assert np.allclose(spin_matrix(w, 3) @ x, np.cross(w, x))


def test_named_mass_distributions():
    assert kappa_of("uniform", 2) == 0.5 and kappa_of("uniform", 3) == 0.4
    assert kappa_of("ring", 2) == 1.0 and kappa_of("shell", 3) == pytest.approx(2 / 3)
    assert kappa_of(0.25, 3) == 0.25


@pytest.mark.parametrize("n", DIMS)
def test_the_axis_map_is_the_general_map_bit_for_bit(n):
    # physics.collide_axis (ν = ±e_m: the walls of a strip or between plates, m = n−1, and the sides of an axis box,
    # any m) leaves out the products with ν's zeros: the same numbers must come out, not merely close ones (zeros
    # may differ in sign)
    from rbx.physics import collide, collide_axis
    rng = np.random.default_rng(7 + n)
    for trial in range(600):
        v, W, _, R, kappa = random_state(rng, n)
        sigma = 1.0 if trial % 2 else -1.0
        m = (trial // 2) % n
        nu = np.zeros(n)
        nu[m] = sigma
        k = int(rng.integers(0, n))
        basis = roughness_basis(rng, nu, k)
        basis[:, m] = 0.0                       # tangent to the wall exactly, as the rule compiler gives it
        b = basis[None, None]
        v1, W1, v2, W2 = v.copy(), W.copy(), v.copy(), W.copy()
        collide(v1, W1, nu, R, kappa, k, b, 0, 0, np.empty((3, n)), n, False)
        collide_axis(v2, W2, m, sigma, R, kappa, k, b, 0, 0, np.empty((3, n)), n, False)
        np.testing.assert_array_equal(v1, v2)
        np.testing.assert_array_equal(W1, W2)
        assert np.all(W2 == -W2.T)              # still exactly antisymmetric


@pytest.mark.parametrize("n", DIMS)
def test_the_map_without_a_branch_on_the_rank_is_the_map(n):
    # under a random rule the kernel computes the rough change at every rank and multiplies it by
    # physics.rough_factor (0 at rank 0): the state must be the map's own, general and axis form, at every rank
    # (assert_array_equal counts −0 and +0 equal: only the sign of a zero may differ)
    from rbx.physics import collide, collide_axis, rough_factor
    assert rough_factor(0, True) == 0.0 and rough_factor(1, True) == 1.0 and rough_factor(0, False) == 1.0
    rng = np.random.default_rng(11 + n)
    for trial in range(300):
        v, W, nu, R, kappa = random_state(rng, n)
        for k in range(n):
            basis = roughness_basis(rng, nu, k)[None, None]
            out = []
            for blend in (False, True):
                v1, W1 = v.copy(), W.copy()
                collide(v1, W1, nu, R, kappa, k, basis, 0, 0, np.empty((3, n)), n, blend)
                out.append((v1, W1))
            np.testing.assert_array_equal(out[0][0], out[1][0])
            np.testing.assert_array_equal(out[0][1], out[1][1])
            m, sigma = trial % n, (1.0 if trial % 2 else -1.0)
            e = np.zeros(n)
            e[m] = sigma
            b = roughness_basis(rng, e, k)
            b[:, m] = 0.0
            out = []
            for blend in (False, True):
                v1, W1 = v.copy(), W.copy()
                collide_axis(v1, W1, m, sigma, R, kappa, k, b[None, None], 0, 0, np.empty((3, n)), n, blend)
                out.append((v1, W1))
            np.testing.assert_array_equal(out[0][0], out[1][0])
            np.testing.assert_array_equal(out[0][1], out[1][1])
