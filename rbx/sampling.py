"""Initial states drawn from the billiard measure (paper §2.7; docs/reference.md §4).

On a wall: position uniform on the wall as seen by the centre (the shrunk wall), orientation uniform, and the
velocity in the metric-orthonormal coordinates ``(v, R√κ·ω)`` (dimension ``d = n + n(n−1)/2``) with density
∝ cos φ on the unit hemisphere around the inward normal. Projected on the plane orthogonal to the normal that
density is uniform on the unit (d−1)-ball, which is how it is drawn. Along an infinite direction (strip, plates)
the position is 0: the dynamics are invariant under that translation. Without a wall, the wall (and the patch
of a wall: a polygon edge and its reflex-vertex arc) is drawn with probability proportional to its measure.

Each trajectory j uses its own stream (seed, j, PURPOSE_INITIAL), so the draw does not depend on how many
trajectories are run or in which order.
"""
import numpy as np

from .physics import rotation_from_vector
from .rng import PURPOSE_INITIAL, _GOLDEN, _M1, _M2, _mix, uniform_table

NDRAWS = 32


def _patch_measure(patch):
    """The measure (length or area) of a sampling patch of a wall (rbx.geometry.Wall.patches):
    ``('flat', origin, normal, [(axis, length)…])``, ``('arc', centre, ρ, θ0, θ1, sign)`` (2D, normal sign·radial),
    ``('sphere', centre, ρ, sign)``, ``('cylinder', axis point (x, y), ρ, z0, z1)`` (normal −radial),
    ``('disc', centre, normal, ρ)`` (a cylinder's cap)."""
    kind = patch[0]
    if kind == "flat":
        return float(np.prod([length for _, length in patch[3] if np.isfinite(length)]))
    if kind == "arc":
        _, _, rho, a0, a1, _ = patch
        return rho * (a1 - a0)
    if kind == "sphere":
        return 4.0 * np.pi * patch[2] ** 2
    if kind == "cylinder":
        _, _, rho, z0, z1 = patch
        return 2.0 * np.pi * rho * (z1 - z0)
    if kind == "disc":
        return np.pi * patch[3] ** 2
    raise ValueError(kind)


def wall_patches(geom, wall):
    """[(patch, weight)] for one wall index or all walls (None), weights normalised."""
    walls = range(len(geom.wall_list)) if wall is None else [wall]
    items = [(p, _patch_measure(p)) for w in walls for p in geom.wall_list[w].patches]
    items = [(p, m) for p, m in items if m > 0]
    total = sum(m for _, m in items)
    return [(p, m / total) for p, m in items]


def sample_billiard(geom, kappa, R, seed, wall, first, count):
    """Draw ``count`` states for trajectories first … -> dict of arrays position (M, n), velocity (M, n),
    angular_velocity (M,) or (M, 3), orientation (M,) angle or (M, 3, 3) matrix, and the wall normal (M, n)."""
    n = geom.dimension
    d = n + n * (n - 1) // 2
    U = uniform_table(seed, first, count, PURPOSE_INITIAL, NDRAWS)
    patches = wall_patches(geom, wall)
    cum = np.cumsum([w for _, w in patches])
    cum[-1] = np.inf
    which = np.searchsorted(cum, U[:, 0], side="right")
    pos = np.zeros((count, n))
    nu = np.zeros((count, n))
    for k, (patch, _) in enumerate(patches):
        sel = which == k
        if patch[0] == "flat":
            _, origin, normal, axes = patch
            pos[sel] = origin
            for i, (axis, length) in enumerate(axes):
                if np.isfinite(length):
                    pos[sel] += np.outer(U[sel, 1 + i] * length, axis)
            nu[sel] = normal
        elif patch[0] == "arc":
            _, centre, rho, a0, a1, sign = patch
            ang = a0 + (a1 - a0) * U[sel, 1]
            radial = np.stack([np.cos(ang), np.sin(ang)], axis=1)
            pos[sel] = centre + rho * radial
            nu[sel] = sign * radial
        elif patch[0] == "sphere":        # uniform on the sphere: z uniform in [−1, 1] (Archimedes), then the angle
            _, centre, rho, sign = patch
            z = 1.0 - 2.0 * U[sel, 1]
            ang = 2.0 * np.pi * U[sel, 2]
            s = np.sqrt(np.maximum(0.0, 1.0 - z * z))
            radial = np.stack([s * np.cos(ang), s * np.sin(ang), z], axis=1)
            pos[sel] = centre + rho * radial
            nu[sel] = sign * radial
        elif patch[0] == "cylinder":
            _, centre, rho, z0, z1 = patch
            ang = 2.0 * np.pi * U[sel, 1]
            radial = np.stack([np.cos(ang), np.sin(ang), np.zeros_like(ang)], axis=1)
            pos[sel] = np.array([centre[0], centre[1], 0.0]) + rho * radial
            pos[sel, 2] = z0 + (z1 - z0) * U[sel, 2]
            nu[sel] = -radial
        else:                              # a disc across z (a cylinder's cap): uniform in area
            _, centre, normal, rho = patch
            r = rho * np.sqrt(U[sel, 1])
            ang = 2.0 * np.pi * U[sel, 2]
            pos[sel] = centre + np.stack([r * np.cos(ang), r * np.sin(ang), np.zeros_like(r)], axis=1)
            nu[sel] = normal
    # velocity: uniform in the unit (d−1)-ball of the tangent space, normal part sqrt(1 − |x|²)
    g = _normals(U[:, 4:4 + 2 * ((d - 1 + 1) // 2)])[:, :d - 1]
    radius = U[:, 3] ** (1.0 / (d - 1))
    x = g / np.linalg.norm(g, axis=1, keepdims=True) * radius[:, None]
    normal_part = np.sqrt(np.maximum(0.0, 1.0 - np.sum(x * x, axis=1)))
    tang = _tangent_basis(nu)                                   # (M, n−1, n)
    vel = normal_part[:, None] * nu + np.einsum("mk,mkn->mn", x[:, :n - 1], tang)
    spin_scaled = x[:, n - 1:]                                  # R√κ·ω
    spin = spin_scaled / (R * np.sqrt(kappa))
    o = U[:, 16:]
    if n == 2:
        orient = 2 * np.pi * o[:, 0]
        spin = spin[:, 0]
    else:
        orient = np.array([_uniform_rotation(o[m, :3]) for m in range(count)])
    return {"position": pos, "velocity": vel, "angular_velocity": spin, "orientation": orient, "normal": nu}


def _normals(U):
    """Standard normal pairs from uniform pairs (Box–Muller)."""
    u1, u2 = U[:, 0::2], U[:, 1::2]
    r = np.sqrt(-2.0 * np.log1p(-u1))
    return np.concatenate([r * np.cos(2 * np.pi * u2), r * np.sin(2 * np.pi * u2)], axis=1)


def _tangent_basis(nu):
    """An orthonormal basis of ν⊥ for each row -> (M, n−1, n)."""
    M, n = nu.shape
    if n == 2:
        return np.stack([-nu[:, 1], nu[:, 0]], axis=1)[:, None, :]
    helper = np.where(np.abs(nu[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    t1 = helper - np.sum(helper * nu, axis=1, keepdims=True) * nu
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(nu, t1)
    return np.stack([t1, t2], axis=1)


def _uniform_rotation(u):
    """A uniformly distributed rotation matrix from three uniforms (Shoemake's quaternion method)."""
    a, b, c = u
    q = np.array([np.sqrt(1 - a) * np.sin(2 * np.pi * b), np.sqrt(1 - a) * np.cos(2 * np.pi * b),
                  np.sqrt(a) * np.sin(2 * np.pi * c), np.sqrt(a) * np.cos(2 * np.pi * c)])
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def explicit_states(states, dimension, count):
    """Explicit initial states from the config (one state repeated, or one per trajectory) -> dict of arrays."""
    reps = [states[j % len(states)] for j in range(count)]
    out = {k: np.array([s[k] for s in reps], dtype=float) for k in ("position", "velocity", "angular_velocity")}
    if dimension == 2:
        out["orientation"] = np.array([s["orientation"] for s in reps], dtype=float)
    else:
        out["orientation"] = np.array([rotation_from_vector(s["orientation"]) for s in reps])
    return out


# ---- a point particle's start: uniform in the table's area and in direction, unit speed, no spin ------------------

#: uniforms per trajectory and round of :func:`sample_point_particle` (position n, direction n − 1, orientation
#: 1 or 3)
POINT_DRAWS = 8
#: the most rounds of rejection: a table whose area is so small a part of its bounding box that a start is still
#: missing after them is refused (a Sinai table takes 1–2 rounds on average)
POINT_ROUNDS = 10_000


def stream_keys(seed, trajectories, purpose):
    """:func:`rbx.rng.stream_key` of each trajectory index in ``trajectories`` at once -> uint64 array, the same bits
    (tests/test_fastpaths.py): one call per trajectory took 1.5 µs, 0.27 s of setting up 10⁵ short orbits."""
    mix = _mix.py_func                  # the same operations on uint64 arrays (wrapping, as the kernel's)
    j = np.asarray(trajectories, dtype=np.uint64)
    with np.errstate(over="ignore"):
        k = mix(np.uint64(seed) + _GOLDEN)
        k = mix(k ^ (j * _M1 + _GOLDEN))
        return mix(k ^ (np.uint64(purpose) * _M2 + _GOLDEN))


def _draws(seed, first, count, start, k, rows=None):
    """Draws ``start … start+k−1`` of the initial-state streams of trajectories ``first + rows`` (all ``count``
    of them when ``rows`` is None) -> (len(rows), k) array, the same numbers as :func:`rbx.rng.uniforms`."""
    rows = np.arange(count) if rows is None else np.asarray(rows)
    keys = stream_keys(seed, first + rows.astype(np.int64), PURPOSE_INITIAL)
    counter = np.arange(start, start + k, dtype=np.uint64) + np.uint64(1)
    with np.errstate(over="ignore"):
        z = keys[:, None] + counter[None, :] * np.uint64(0x9E3779B97F4A7C15)
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        z = z ^ (z >> np.uint64(31))
    return (z >> np.uint64(11)).astype(np.float64) * (1.0 / 9007199254740992.0)


def area_box(geom):
    """An axis-aligned box holding the shrunk table -> (lo, hi) arrays; along an infinite direction of the table
    (a strip's x, the plates' x and y) both are 0. A periodic table: its cell. From the walls' sampling patches,
    which bound the region the centre can reach."""
    n = geom.dimension
    if geom.lattice is not None:
        lo, period = (np.asarray(a, float) for a in geom.lattice)
        return lo, lo + period
    pts, infinite = [], np.zeros(n, bool)
    for wall in geom.wall_list:
        for patch in wall.patches:
            kind = patch[0]
            if kind == "flat":
                _, origin, _, axes = patch
                corners = [np.asarray(origin, float)]
                for axis, length in axes:
                    axis = np.asarray(axis, float)
                    if np.isfinite(length):
                        corners += [c + length * axis for c in corners]
                    else:
                        infinite |= axis != 0
                pts += corners
            elif kind in ("arc", "sphere"):
                centre, rho = np.asarray(patch[1], float), patch[2]
                pts += [centre - rho, centre + rho]
            elif kind == "cylinder":
                _, centre, rho, z0, z1 = patch
                pts += [np.array([centre[0] - rho, centre[1] - rho, z0]), np.array([centre[0] + rho, centre[1] + rho, z1])]
            else:                                        # a disc across z
                _, centre, _, rho = patch
                centre = np.asarray(centre, float)
                pts += [centre - [rho, rho, 0.0], centre + [rho, rho, 0.0]]
    pts = np.array(pts)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    lo[infinite], hi[infinite] = 0.0, 0.0
    return lo, hi


def sample_point_particle(geom, seed, first, count):
    """A point particle's starts (``initial: {sample: point_particle}``) for trajectories first … -> dict of arrays
    as :func:`sample_billiard` (no ``normal``): the centre uniform in the area (3D: volume) of the shrunk table,
    the direction of the velocity uniform on the unit circle (sphere), ``|v| = 1``, no spin, orientation uniform.
    This is the invariant measure of the billiard flow of a point particle (Liouville: area × direction).

    Along an infinite direction (strip, plates) the position is 0, as for :func:`sample_billiard`. The position
    is drawn by rejection from :func:`area_box`: trajectory j takes the first round r whose point lies in the
    shrunk table (:meth:`rbx.geometry.Geometry.clearance` ≥ 0), round r being the draws r·8 … r·8+7 of its own
    stream; the direction and orientation come from the same round. So a trajectory's start depends only on the
    seed and its index."""
    n = geom.dimension
    lo, hi = area_box(geom)
    U = np.empty((count, POINT_DRAWS))
    left = np.arange(count)
    for r in range(POINT_ROUNDS):
        if not len(left):
            break
        u = _draws(seed, first, count, r * POINT_DRAWS, POINT_DRAWS, left)
        pos = lo + (hi - lo) * u[:, :n]
        with np.errstate(all="ignore"):
            inside = geom.clearance(pos) >= 0.0
        U[left[inside]] = u[inside]
        left = left[~inside]
    else:
        if len(left):
            raise ValueError(f"no start inside the {geom.kind} table after {POINT_ROUNDS} rounds of rejection")
    pos = lo + (hi - lo) * U[:, :n]
    if n == 2:
        phi = 2.0 * np.pi * U[:, n]
        vel = np.stack([np.cos(phi), np.sin(phi)], axis=1)
        spin = np.zeros(count)
        orient = 2.0 * np.pi * U[:, n + 1]
    else:                              # uniform on the sphere: z uniform in [−1, 1] (Archimedes), then the angle
        z = 1.0 - 2.0 * U[:, n]
        phi = 2.0 * np.pi * U[:, n + 1]
        s = np.sqrt(np.maximum(0.0, 1.0 - z * z))
        vel = np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)
        spin = np.zeros((count, 3))
        orient = np.array([_uniform_rotation(U[m, n + 2:n + 5]) for m in range(count)]).reshape(count, 3, 3)
    return {"position": pos, "velocity": vel, "angular_velocity": spin, "orientation": orient}
