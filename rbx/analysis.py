"""Analysis of runs: arrays in, numbers out. Nothing here simulates or draws.

- the billiard-measure laws (paper §2.7): the angle φ to the normal in the metric-orthonormal coordinates
  ``(v, R√κ·ω)``, its predicted density ∝ cos φ·sin^(d−2) φ with ``d = n + n(n−1)/2``, the Kolmogorov–Smirnov test
  against it, and Santaló's mean free path;
- positions on the boundary: which part of a wall a collision point lies on, its inward normal, and the Birkhoff
  coordinates of the boundary map (arc length s, sin of the angle to the normal);
- diffusion: mean-square displacement and the diffusion coefficient with a confidence interval, growth
  exponents of excursions, the exact expected MSD of the random-rank strip, and the velocity an orbit between
  parallel walls keeps forever (the part of its state that no collision map can change).

Units: lengths in the table's unit L, times in the unit T of the config's velocities; a "step" is one collision.
"""
import itertools
import math
from dataclasses import dataclass

import numpy as np

from . import rules, tables
from .model import roughness_direction, rule_leaves
from .pieces import Lattice, Sphere

# ---- the billiard measure (paper §2.7) -------------------------------------------------------------------------


def velocity_dimension(n):
    """d = n + n(n−1)/2: the dimension of the velocity space (v, R√κ·ω) of a ball in Rⁿ (3 for a disc, 6 for a
    ball), i.e. of the configuration space Q = table × SO(n)."""
    return n + n * (n - 1) // 2


def spin_free(experiment):
    """True when no orbit of the experiment ever spins: its starts carry no spin (point-particle starts, or explicit
    states without angular velocity) and every wall's rule is specular (rank 0) or an exit, so the spin stays 0.
    Its orbits then live in the point particle's phase space, velocity dimension n, not n + n(n−1)/2."""
    start = experiment.initial
    if start and isinstance(start[0], str):
        if start[0] != "point_particle":
            return False
    elif not all(np.all(np.asarray(s["angular_velocity"]) == 0) for s in start):
        return False
    return all(leaf.rank in (0, -1) for rule in experiment.wall_rules for leaf in rule_leaves(rule))


def spin_mixture(experiment):
    """True when every wall's rule is specular (rank 0) or an exit but the starts carry spin (a disc or ball started
    with the billiard measure): a specular wall keeps each orbit's spin, so each orbit moves in the plane at its own
    share c of its speed in (v, R√κ·ω), and leaves a hole at its own rate per unit path, c·|hole|/(C_n·|table|).
    Survival is then a mixture of exponentials whose slow part (orbits spinning fast, c near 0) has no rate: a
    power-law tail, not one escape rate. The mean rate at the start, over the billiard measure, is the small-hole
    rate of the whole velocity space, |hole|/(C_d·|table|)."""
    return (not spin_free(experiment)
            and all(leaf.rank in (0, -1) for rule in experiment.wall_rules for leaf in rule_leaves(rule)))


def orbit_velocity_dimension(experiment):
    """The dimension of the velocity space the experiment's orbits fill: n for a spin-free experiment
    (:func:`spin_free`), else :func:`velocity_dimension` (v and R√κ·ω). Santaló's constant and the small-hole escape
    rate take it: |hole|/(π·|table|) for a point particle in 2D, |hole|/(4·|table|) for a disc with spin."""
    n = experiment.dimension
    return n if spin_free(experiment) else velocity_dimension(n)


def normal_angle(velocity, angular_velocity, normal, R, kappa):
    """Angle φ ∈ [0, π] between the state's velocity in metric-orthonormal coordinates (v, R√κ·ω) and the inward
    normal (ν, 0) of the wall -> (M,).  cos φ = (v·ν)/sqrt(|v|² + κR²|ω|²); φ < π/2 for a post-collision state."""
    v = np.asarray(velocity, float)
    w = np.asarray(angular_velocity, float)
    w2 = w * w if w.ndim == 1 else np.sum(w * w, axis=-1)
    speed = np.sqrt(np.sum(v * v, axis=-1) + kappa * R * R * w2)
    c = np.sum(v * np.asarray(normal, float), axis=-1) / speed
    # math.acos (libm), not np.arccos, whose AVX-512 version gives other last bits than the one other CPUs run
    return np.array([math.acos(x) for x in np.clip(c, -1.0, 1.0).ravel().tolist()], float).reshape(np.shape(c))


def cos_law_pdf(phi, d):
    """Density of φ on [0, π/2] under the billiard measure in d velocity dimensions: (d−1)·cos φ·sin^(d−2) φ
    (sin 2φ for a disc, d = 3; 5·cos φ·sin⁴ φ for a ball, d = 6)."""
    phi = np.asarray(phi, float)
    return (d - 1) * np.cos(phi) * np.sin(phi) ** (d - 2)


def cos_law_cdf(phi, d):
    """Distribution function of φ under the billiard measure: sin^(d−1) φ on [0, π/2]."""
    return np.sin(np.clip(np.asarray(phi, float), 0.0, np.pi / 2)) ** (d - 1)


def ks_cos_law(phi, d):
    """Kolmogorov–Smirnov test of angles φ against the billiard-measure law -> (statistic, p-value)."""
    from scipy import stats
    res = stats.kstest(np.asarray(phi, float), lambda x: cos_law_cdf(x, d))
    return float(res.statistic), float(res.pvalue)


def santalo_constant(d):
    """|S^(d−1)| / |B^(d−1)| = 2√π·Γ((d+1)/2)/Γ(d/2): π for d = 2, 4 for d = 3, 15π/8 for d = 6.

    Santaló's formula: in a domain Q ⊂ R^d the mean free path of the billiard measure (uniform on ∂Q, ∝ cos φ on
    the inward hemisphere) is this constant times |Q|/|∂Q|."""
    return 2.0 * math.sqrt(math.pi) * math.gamma((d + 1) / 2) / math.gamma(d / 2)


def santalo_mean_free_path(geom):
    """Mean free path of the billiard measure on the whole boundary (Santaló) -> float.

    Q = shrunk table × SO(n) with the metric of (v, R√κ·ω); SO(n) is compact without boundary, so its volume
    cancels from |Q|/|∂Q| = V/S (area/perimeter of the shrunk disc table, volume/surface of the shrunk box):
    4·A/P for a disc, 15π/8·V/S for a ball. With unit speed it is also the mean first flight time."""
    volume, surface = table_measure(geom)
    return santalo_constant(velocity_dimension(geom.dimension)) * volume / surface


def table_measure(geom):
    """(volume, boundary measure) of the shrunk table -> (area, perimeter) in 2D, (volume, surface) in 3D.

    From the sampling patches of the walls and the divergence theorem, V = (1/n)∮ p·ν_out dS, so reflex-vertex
    arcs are exact. Raises ValueError for unbounded tables (strip, wedge, plates)."""
    n = geom.dimension
    volume, surface = 0.0, 0.0
    for wall in geom.wall_list:
        for patch in wall.patches:
            if patch[0] == "flat":
                _, origin, normal, axes = patch
                lengths = [length for _, length in axes]
                if not all(np.isfinite(lengths)):
                    raise ValueError(f"the {geom.kind} table is unbounded: it has no finite volume")
                m = float(np.prod(lengths))
                surface += m
                volume += -float(origin @ normal) * m          # p·ν_out = −p·ν is constant on a flat wall
            elif patch[0] == "arc":
                _, centre, rho, a0, a1, sign = patch
                surface += rho * (a1 - a0)
                radial_integral = np.array([np.sin(a1) - np.sin(a0), np.cos(a0) - np.cos(a1)])
                volume += -sign * rho * (float(centre @ radial_integral) + rho * (a1 - a0))
            elif patch[0] == "sphere":           # ∮ p·ν_out = ∓ρ·4πρ² (the centre's part integrates to 0)
                _, centre, rho, sign = patch
                surface += 4 * np.pi * rho ** 2
                volume += -sign * 4 * np.pi * rho ** 3
            elif patch[0] == "cylinder":         # ν_out = radial: p·ν_out = ρ + c·radial, which integrates to ρ
                _, centre, rho, z0, z1 = patch
                surface += 2 * np.pi * rho * (z1 - z0)
                volume += 2 * np.pi * rho * rho * (z1 - z0)
            else:                                # a cylinder's cap: p·ν_out = −p·ν, constant
                _, centre, normal, rho = patch
                surface += np.pi * rho ** 2
                volume += -float(centre @ normal) * np.pi * rho ** 2
    if geom.lattice is not None:                 # the periodic cell's sides: ∮ p·ν_out over the box = n·|box|
        volume += n * float(np.prod(geom.lattice[1]))
    return volume / n, surface


# ---- positions on the boundary ---------------------------------------------------------------------------------


def _ccw_tangent(nu):
    """The boundary tangent t = −Jν (2D, J the rotation by +90°): the direction in which the table's boundary is
    traversed counter-clockwise (interior on the left)."""
    return np.stack([nu[..., 1], -nu[..., 0]], axis=-1)


def _patch_offsets(geom):
    """[(wall, patch, s0)] in boundary order: walls in index order and, within an edge of a polygon, the arc at
    its start vertex before the segment (docs/conventions.md). s0 is 0 on every wall of an unbounded table."""
    patches = [(w, p) for w, wall in enumerate(geom.wall_list)
               for p in sorted(wall.patches, key=lambda p: p[0] != "arc")]
    if any(p[0] == "flat" and not all(np.isfinite(length) for _, length in p[3]) for _, p in patches):
        return [(w, p, 0.0) for w, p in patches]
    out, s = [], 0.0
    for w, p in patches:
        out.append((w, p, s))
        s += float(np.prod([length for _, length in p[3]])) if p[0] == "flat" else p[2] * (p[4] - p[3])
    return out


def boundary_length(geom):
    """Total arc length of the shrunk 2D table's boundary (inf for unbounded tables)."""
    try:
        return table_measure(geom)[1]
    except ValueError:
        return np.inf


def wall_joints(geom):
    """Arc lengths where one wall ends and the next begins (for marking them in phase portraits) -> list."""
    offsets = _patch_offsets(geom)
    if all(s0 == 0.0 for _, _, s0 in offsets):
        return []
    starts = {}
    for w, _, s0 in offsets:
        starts.setdefault(w, s0)
    return sorted(starts.values())[1:]


def locate(geom, walls, positions):
    """Where collision points lie on the boundary -> (s, normal).

    ``walls`` (M,) are wall indices (from the file's ``wall`` field), ``positions`` (M, n) the centre at the
    collision. ``normal`` (M, n) is the inward unit normal there (exact on arcs too). ``s`` (M,) is the Birkhoff
    arc length along the shrunk boundary, counter-clockwise, starting at the start of wall 0 (2D; on unbounded
    tables each wall's s is measured from its own origin along the counter-clockwise tangent — for the strip's
    top wall s = −x); NaN in 3D and where ``walls`` < 0. In a periodic table the positions are unfolded: each is
    taken back into the cell, and then to whichever neighbouring image of the wall it lies on (an obstacle may
    cross the cell's sides)."""
    walls = np.asarray(walls, np.int64).reshape(-1)
    p = np.asarray(positions, float)
    n = p.shape[-1]
    p = p.reshape(len(walls), n)
    s = np.full(len(walls), np.nan)
    normal = np.full((len(walls), n), np.nan)
    best = np.full(len(walls), np.inf)
    shifts = [np.zeros(n)]
    if geom.lattice is not None:
        lo, period = (np.asarray(x, float) for x in geom.lattice)
        p = p - np.floor((p - lo) / period) * period
        shifts = [np.array(o, float) * period for o in itertools.product((-1, 0, 1), repeat=n)]
    for w, patch, s0 in _patch_offsets(geom):
        sel = np.nonzero(walls == w)[0]
        if len(sel) == 0:
            continue
        for shift in shifts:
            residual, nus, local = _on_patch(patch, p[sel] + shift, n)
            take = residual < best[sel]
            idx = sel[take]
            best[idx] = residual[take]
            normal[idx] = nus[take]
            s[idx] = s0 + local[take]
    return s, normal


def _on_patch(patch, q, n):
    """How far the points ``q`` (k, n) lie from a wall's patch (:func:`_patch_offsets`) -> (distance (k,), inward
    normal (k, n), arc length from the patch's start (k,))."""
    if patch[0] == "flat":
        _, origin, nu, axes = patch
        d = q - origin
        residual = np.abs(d @ nu)
        for axis, length in axes:
            c = d @ np.asarray(axis, float)
            if np.isfinite(length):
                residual = residual + np.maximum(0.0, np.maximum(-c, c - length))
        nus = np.broadcast_to(nu, q.shape)
        local = d @ _ccw_tangent(nu) if n == 2 else np.full(len(q), np.nan)
        return residual, nus, local
    _, centre, rho, a0, a1, sign = patch
    d = q - centre
    r = np.linalg.norm(d, axis=1)
    ang = a0 + np.mod(np.arctan2(d[:, 1], d[:, 0]) - a0, 2 * np.pi)
    over = np.where(ang > a1, np.minimum(ang - a1, a0 + 2 * np.pi - ang), 0.0)
    residual = np.abs(r - rho) + rho * over
    nus = sign * d / np.where(r > 0, r, 1.0)[:, None]
    local = rho * (ang - a0) if sign < 0 else rho * (a1 - ang)
    return residual, nus, local


def birkhoff_coordinates(geom, walls, positions, velocities):
    """Birkhoff coordinates of collisions of a 2D table -> (s, sin ψ).

    s: arc length along the shrunk boundary (see :func:`locate`); ψ: the angle between the centre's outgoing
    velocity v and the inward normal ν, signed so that sin ψ = v·t/|v| with t the counter-clockwise tangent."""
    s, nu = locate(geom, walls, positions)
    v = np.asarray(velocities, float).reshape(nu.shape)
    sin_psi = np.sum(v * _ccw_tangent(nu), axis=1) / np.linalg.norm(v, axis=1)
    return s, sin_psi


def spin_planes(walls, normals, velocities, angular_velocity, R, kappa, tangents=None):
    """Tangential velocity against scaled spin at collisions (angle–position coordinates, v₀ = R√κ·ω) -> list of
    (x, y, x name, y name): one plane in 2D, two in 3D.

    2D: x = v·t (t the counter-clockwise tangent), y = v₀ = R√κ·ω; the contact point's slip is v·t + Rω, so the
    no-slip line is y = −√κ·x and the completely rough map acts on the plane as a reflection.
    3D: with e₁ the wall's first tangent axis (``tangents[wall][0]``) and e₂ = ν×e₁ the slip is
    (v·e₁ − Rω·e₂, v·e₂ + Rω·e₁): planes (v·e₁, R√κ ω·e₂) and (v·e₂, −R√κ ω·e₁)."""
    nu = np.asarray(normals, float)
    v = np.asarray(velocities, float)
    w = np.asarray(angular_velocity, float)
    scale = R * math.sqrt(kappa)
    if nu.shape[1] == 2:
        return [(np.sum(v * _ccw_tangent(nu), axis=1), scale * w.reshape(-1), "v·t", "v₀ = R√κ·ω")]
    e1 = np.array([tangents[k][0] if k >= 0 else np.full(3, np.nan) for k in np.asarray(walls, np.int64)])
    e1 = e1 - np.sum(e1 * nu, axis=1, keepdims=True) * nu
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(nu, e1)
    return [(np.sum(v * e1, axis=1), scale * np.sum(w * e2, axis=1), "v·e₁", "R√κ ω·e₂"),
            (np.sum(v * e2, axis=1), -scale * np.sum(w * e1, axis=1), "v·e₂", "−R√κ ω·e₁")]


# ---- diffusion -------------------------------------------------------------------------------------------------


def mean_square_displacement(x):
    """x (M, T): one coordinate of M trajectories at T records -> (T,) ⟨(x(t) − x(0))²⟩ over the trajectories
    that have a record there (NaN rows, from trajectories that ended early, are skipped)."""
    x = np.asarray(x, float)
    dx = x - x[:, :1]
    with np.errstate(invalid="ignore"):
        return np.nanmean(dx * dx, axis=0)


@dataclass(frozen=True)
class DiffusionFit:
    """MSD(t) ≈ 2·D·t + c over the fit window, D in L² per unit of t, with a confidence interval."""
    coefficient: float
    low: float
    high: float
    confidence: float
    intercept: float
    start: float
    stop: float
    trajectories: int
    intercept_half_width: float = math.nan   # of the same confidence as D's interval

    def msd(self, t):
        return 2.0 * self.coefficient * np.asarray(t, float) + self.intercept

    @property
    def half_width(self):
        return 0.5 * (self.high - self.low)


def unbounded_axes(geom):
    """The coordinate axes along which the table extends without end -> set of axis indices: every axis of a
    periodic table (positions are unfolded), the directions of a 2D wall that is an infinite line (strip: x;
    wedge: both), the tangent axes of an unbounded plane (plates: x and y); none for a closed table."""
    n = geom.dimension
    if geom.lattice is not None:
        return set(range(n))
    try:
        table_measure(geom)
        return set()                  # a finite volume: closed (the caps of a cylinder are unbounded planes)
    except ValueError:
        pass
    out = set()
    for piece in tables.walls(geom.kind, geom.table):
        if isinstance(piece, tables.Line) and not (math.isfinite(piece.s_min) and math.isfinite(piece.s_max)):
            d = piece.direction
            if d and d[0] == "deg":
                d = (math.cos(math.radians(d[1])), math.sin(math.radians(d[1])))
            out |= {k for k in range(2) if abs(float(d[k])) > 1e-12}
        elif isinstance(piece, tables.Plane):
            for t in piece.tangents:
                for k in range(3):
                    if abs(float(t[k])) > 1e-12 and not (math.isfinite(piece.lo[k]) and math.isfinite(piece.hi[k])):
                        out.add(k)
    return out


#: coordinates whose mean-square displacement can grow without bound: the position (along an axis the table does
#: not bound) and the 2D orientation angle; velocities and spins are bounded by the energy, time is not random
DIFFUSING = {"x": 0, "y": 1, "z": 2, "theta": None}


def diffusion_problem(geom, coordinate):
    """Why a diffusion coefficient of ``coordinate`` means nothing in this table -> a phrase, or None if it may."""
    if coordinate not in DIFFUSING:
        what = "the time is not a random coordinate" if coordinate == "time" else \
            f"{coordinate} is bounded by the energy"
        return f"{what}: diffusion is measured along a position (x, y, z) or the orientation theta"
    axis = DIFFUSING[coordinate]
    if axis is not None and axis >= geom.dimension:
        return f"a {geom.dimension}D run has no coordinate {coordinate}"
    if axis is not None and axis not in unbounded_axes(geom):
        return (f"the {geom.kind} table is bounded along {coordinate}: the mean-square displacement saturates, "
                "there is no diffusion coefficient")
    return None


#: the lattice planes (2D: lines) whose free corridors are looked for: Miller indices up to this size. A corridor of
#: higher index is narrower than the spacing of its planes, 1/|(h/a, k/b, l/c)|, which falls below any scatterer's
#: diameter first
CORRIDOR_INDEX = 6


@dataclass(frozen=True)
class Corridor:
    """A free corridor of a periodic table: a slab between lattice planes (2D: a strip between lattice lines) that
    no grown scatterer meets, so that a flight along it never ends."""
    index: tuple        # Miller indices of the planes (h, k[, l]) of the rectangular cell
    normal: tuple       # the unit normal of the planes
    width: float        # the free width the centre can fly in [L]

    def along(self, axis):
        """Whether a flight inside the corridor can move along the coordinate axis (not only across it)."""
        return abs(self.normal[axis]) < 1.0 - 1e-12


def free_corridors(geom):
    """The free corridors of a periodic table of round scatterers (a Lorentz gas) -> list of :class:`Corridor`
    (empty: a finite horizon, every flight ends), or None where it is not worked out (a periodic table with other
    obstacles) or does not apply (a table that is not periodic).

    For each family of lattice planes (Miller indices (h, k[, l]) up to :data:`CORRIDOR_INDEX`, normal
    g = (h/a, k/b, l/c), spacing d = 1/|g|) every scatterer image projects onto g/|g| at its centre's projection
    modulo d; the planes leave a free slab when the grown scatterers' intervals [p − ρ, p + ρ] (ρ = radius + R)
    do not cover the circle of length d. In 2D a free strip carries flights of unbounded length with a density
    that makes the mean-square displacement grow as t·log t (Bleher 1992); in 3D so does a free slab (a planar
    horizon, Dettmann 2012), while a corridor of lower dimension does not, so only planes are looked at."""
    if geom.lattice is None or geom.pieces is None:
        return None
    period = np.asarray(geom.lattice[1], float)
    n = len(period)
    balls = []
    for piece in geom.pieces:
        if isinstance(piece, Lattice):
            continue
        if not isinstance(piece, Sphere) or piece.inside:
            return None
        balls.append((np.asarray(piece.center, float), float(piece.radius) + float(geom.shrunk_radius)))
    out = []
    for index in itertools.product(range(-CORRIDOR_INDEX, CORRIDOR_INDEX + 1), repeat=n):
        first = next((i for i in index if i != 0), 0)
        if first <= 0 or math.gcd(*index) != 1:         # one of ±index, primitive
            continue
        g = np.array(index, float) / period
        d = 1.0 / float(np.linalg.norm(g))
        unit = g * d
        width = _free_gap([(float(c @ unit) % d, rho) for c, rho in balls], d)
        if width > 0:
            out.append(Corridor(tuple(index), tuple(float(x) for x in unit), width))
    return out


def _free_gap(intervals, d):
    """The longest stretch of a circle of length d that no interval (centre, half-width) covers -> float (0 if
    covered)."""
    if any(2 * rho >= d for _, rho in intervals):
        return 0.0
    spans = sorted(((p - rho) % d, 2 * rho) for p, rho in intervals)
    best, start0 = 0.0, spans[0][0]
    reach = start0 + spans[0][1]
    for lo, length in spans[1:] + [(start0 + d, 0.0)]:
        best = max(best, lo - reach)
        reach = max(reach, lo + length)
    return best


def horizon_problem(geom, coordinate):
    """Why the mean-square displacement of ``coordinate`` has no diffusion coefficient in this table although it
    grows without bound (an infinite horizon: a free corridor along it) -> (a short phrase for a figure, a
    sentence), or None."""
    axis = DIFFUSING.get(coordinate)
    corridors = free_corridors(geom) if axis is not None else None
    along = [c for c in corridors or () if c.along(axis)]
    if not along:
        return None
    widest = max(along, key=lambda c: c.width)

    def named(c):         # 2D: the corridor's direction in cell vectors (k, −h); 3D: the slab's Miller indices
        if geom.dimension == 2:
            h, k = c.index
            u = (k, -h) if (k, -h) > (0, 0) else (-k, h)
            return f"({u[0]},\u00a0{u[1]})"          # a no-break space: "(1," and "0)" on two lines of a title
        return "(" + " ".join(str(i) for i in c.index) + ")"
    shown = ", ".join(named(c) for c in along[:4]) + (" …" if len(along) > 4 else "")
    where = "corridors along the cell vectors" if geom.dimension == 2 else "slabs between the lattice planes"
    short = f"infinite horizon (free {where} {shown}, {widest.width:.3g} L wide): MSD ∝ t·log t"
    return short, (f"infinite horizon: free {where} {shown} (the widest {widest.width:.3g} L across) carry flights "
                   f"of any length, so the MSD along {coordinate} grows as t·log t and no diffusion coefficient "
                   "exists; the slope shown depends on the window")


def fit_diffusion(t, x, fit_from=0.1, confidence=0.95):
    """Diffusion coefficient of one coordinate -> :class:`DiffusionFit`.

    ``t`` (T,): steps (or times) of the records, ``x`` (M, T): the coordinate of M independent trajectories.
    Each complete trajectory j gets the least-squares line through its own squared displacement over the window
    t ≥ fit_from·max(t) (skipping the ballistic start); D_j = slope_j/2. The slope of the ensemble MSD is the mean
    of the D_j (least squares is linear in the data), and because trajectories are independent — unlike the
    points of one MSD curve — their spread gives an honest Student-t confidence interval (for the intercept c
    too: it is poorly determined, ±D·(window length) per trajectory, so a fitted c of either sign and of order
    100 L² over a few thousand steps is noise, not curvature)."""
    from scipy import stats
    t = np.asarray(t, float)
    x = np.asarray(x, float)
    full = np.all(np.isfinite(x), axis=1)
    M = int(full.sum())
    if M < 2:
        raise ValueError("a diffusion fit needs at least 2 complete trajectories")
    window = t >= fit_from * t.max()
    window &= t > t.min()
    if window.sum() < 2:
        raise ValueError("the fit window holds fewer than 2 records")
    tw = t[window]
    y = (x[full] - x[full, :1])[:, window] ** 2
    tc = tw - tw.mean()
    slopes = (y - y.mean(axis=1, keepdims=True)) @ tc / (tc @ tc)
    intercepts = y.mean(axis=1) - slopes * tw.mean()
    D = 0.5 * slopes
    mean = float(D.mean())
    tq = stats.t.ppf(0.5 + confidence / 2, M - 1)
    half = float(tq * D.std(ddof=1) / math.sqrt(M))
    c_half = float(tq * intercepts.std(ddof=1) / math.sqrt(M))
    return DiffusionFit(mean, mean - half, mean + half, confidence, float(intercepts.mean()), float(tw.min()),
                        float(tw.max()), M, c_half)


def growth_exponent(n, values, lo, hi):
    """Least-squares slope of log(values) against log(n) over lo ≤ n ≤ hi -> float (the exponent a of values ∝ nᵃ):
    0 for a bounded excursion, ½ for a diffusive one, 1 for a ballistic one (1 and 2 for a mean-square
    displacement). Points with values ≤ 0 are skipped."""
    n = np.asarray(n, float)
    values = np.asarray(values, float)
    sel = (n >= lo) & (n <= hi) & (values > 0) & np.isfinite(values)
    if sel.sum() < 2:
        raise ValueError("a growth exponent needs at least 2 points with positive values in the window")
    # the slope in closed form with exactly rounded sums and libm's log: np.polyfit goes through LAPACK and BLAS
    # and np.log has an AVX-512 version, both of which give other last bits on other CPUs
    x = [math.log(a) for a in n[sel].tolist()]
    y = [math.log(b) for b in values[sel].tolist()]
    xm, ym = math.fsum(x) / len(x), math.fsum(y) / len(y)
    dx = [a - xm for a in x]
    return math.fsum(a * (b - ym) for a, b in zip(dx, y)) / math.fsum(a * a for a in dx)


def running_excursion(points):
    """points (T, k): the largest distance from the first point reached up to each record -> (T,)."""
    p = np.asarray(points, float)
    return np.maximum.accumulate(np.linalg.norm(p - p[:1], axis=1))


def time_averaged_msd(points, lags):
    """Time-averaged mean-square displacement of one long orbit -> (len(lags),): the mean of |p(i+L) − p(i)|²
    over every start i, for each lag L (in records). ~L for a diffusive orbit, ~L² for a ballistic one,
    bounded for a bounded one."""
    p = np.asarray(points, float).reshape(len(points), -1)
    return np.array([np.mean(np.sum((p[L:] - p[:-L]) ** 2, axis=1)) for L in np.asarray(lags, int)])


def strip_random_rank_msd(steps, position, velocity, angular_velocity, width, R, kappa, p):
    """The exact expected mean-square displacement along a strip when each collision is rough (rank 1) with
    probability p and specular otherwise, for trajectories that all start from one state -> (msd at ``steps``,
    D, c) with MSD(k) = 2·D·k + c + (terms that decay geometrically in k).

    In the metric-orthonormal coordinates u = (R√κ·ω, v_x) the rough map of a wall is a reflection S_w
    (docs/reference.md §1; bottom: v·Jν = −v_x, top: v·Jν = v_x), v_y only changes sign, so every flight after the
    first takes τ = (width − 2R)/|v_y|. Exactly, with X_k = x_k − x_0 and B_k = S_w with probability p, else I:
    X_{k+1} = X_k + τ_k·u_x,  u_{k+1} = B_{k+1}·u_k, so the moments q = E[X²], g = E[X·u], m = E[u uᵀ] obey
    q' = q + 2τ g_x + τ² m_xx,  g' = Ā(g + τ m e_x),  m' = (1 − p)·m + p·S m S  with Ā = (1 − p)I + pS.
    For p = ½ the limit is D = τ²|u|²(1 + 1/κ)/4 (the velocity correlation decays by (1 − κ)/(1 + κ) per
    collision). ``steps``: collision counts (the records); the first flight starts at ``position``."""
    steps = np.asarray(steps, np.int64)
    kappa, R = float(kappa), float(R)
    vx, vy = float(velocity[0]), float(velocity[1])
    if vy == 0.0:
        raise ValueError("v_y = 0: the disc never reaches a wall")
    c0 = R * math.sqrt(kappa)
    u = np.array([c0 * float(angular_velocity), vx])
    k1, k2 = (kappa - 1) / (1 + kappa), 2 * math.sqrt(kappa) / (1 + kappa)
    M = np.array([[k1, k2], [k2, -k1]])                # on (v0, v·Jν)
    flip = np.diag([1.0, -1.0])
    S = {"top": M, "bottom": flip @ M @ flip}          # on (v0, v_x)
    A = {w: (1 - p) * np.eye(2) + p * S[w] for w in S}
    tau = (width - 2 * R) / abs(vy)
    y0 = float(position[1])
    wall = "top" if vy > 0 else "bottom"
    tau_k = ((width - R) - y0) / vy if vy > 0 else (y0 - R) / -vy
    q, g, m = 0.0, np.zeros(2), np.outer(u, u)
    last = int(steps.max()) if len(steps) else 0
    horizon = max(last, 2000)                          # long after the transient has decayed
    msd = np.zeros(horizon + 1)
    for k in range(horizon):
        q = q + 2 * tau_k * g[1] + tau_k * tau_k * m[1, 1]
        g = A[wall] @ (g + tau_k * m[:, 1])
        m = (1 - p) * m + p * S[wall] @ m @ S[wall].T
        msd[k + 1] = q
        tau_k = tau
        wall = "bottom" if wall == "top" else "top"
    D = (msd[horizon] - msd[horizon - 2]) / 4.0        # two flights: one past each wall
    c = float(msd[horizon] - 2 * D * horizon)
    return msd[steps], float(D), c


def slip_constraints(rough, R, kappa):
    """Rows of the linear map whose null space is the set of states that do not slip in any of the rough
    directions ``rough`` = [(ν, d), …] (wall normal into the free region, unit rough direction d ⊥ ν), in the
    metric-orthonormal coordinates z = (v, R√κ·ω) (2D: ω scalar; 3D: ω a vector) -> (len(rough), dim).

    The contact point slips at u = v + ω×r with r = −Rν, so d·u = d·v − (1/√κ)·(R√κ ω)·(ν×d) in 3D and
    d·v − (1/√κ)·(R√κ ω)·(d·Jν) in 2D."""
    rows = []
    for nu, d in rough:
        nu, d = np.asarray(nu, float), np.asarray(d, float)
        if len(nu) == 2:
            rows.append(np.concatenate([d, [-(d @ np.array([-nu[1], nu[0]])) / math.sqrt(kappa)]]))
        else:
            rows.append(np.concatenate([d, -np.cross(nu, d) / math.sqrt(kappa)]))
    return np.array(rows)


def conserved_drift(velocity, angular_velocity, rough, R, kappa):
    """Between two parallel walls (strip, plates): the velocity along the walls that the orbit keeps on average
    forever -> (n,) vector (its normal component is 0).

    Every rough collision acts on z = (v, R√κ·ω) (normal velocity left out: it only changes sign) as an
    orthogonal reflection whose fixed space is the states that do not slip in that wall's rough directions
    (docs/reference.md §1: the map is an energy-preserving involution, the identity on non-slipping states). The
    part of z in the intersection F of the fixed spaces of every map that can occur — ``rough`` lists each (ν, d)
    pair that any rule can use — is therefore never changed, and the rest averages to zero unless more is conserved. A
    non-zero velocity part of P_F z makes the orbit drift ballistically; none (F ∩ velocities = 0) leaves it
    bounded or diffusive."""
    v = np.asarray(velocity, float).copy()
    n = len(v)
    normal = np.asarray(rough[0][0], float) if rough else np.eye(n)[-1]
    v = v - _fdot(v, normal) * normal
    w = np.atleast_1d(np.asarray(angular_velocity, float)) * R * math.sqrt(kappa)
    z = np.concatenate([v, w])
    if not rough:
        return v
    # z minus its projection on the row space of K, from an orthonormal basis of the rows (modified Gram–Schmidt,
    # exactly rounded sums): not np.linalg.pinv and @, whose LAPACK and BLAS kernels give other last bits (and signs
    # of the zeros) on other CPUs
    basis = []
    for row in slip_constraints(rough, R, kappa):
        q = np.asarray(row, float)
        scale = _fnorm(q)
        for b in basis:
            q = q - _fdot(b, q) * b
        size = _fnorm(q)
        if size > 1e-9 * scale:
            basis.append(q / size)
    zF = z
    for b in basis:
        zF = zF - _fdot(b, zF) * b
    drift = zF[:n]
    return drift - _fdot(drift, normal) * normal


def _fdot(x, y):
    """x·y of two short vectors, exactly rounded (math.fsum) -> float: the same bits on every CPU."""
    return math.fsum(a * b for a, b in zip(np.asarray(x, float).tolist(), np.asarray(y, float).tolist()))


def _fnorm(x):
    return math.sqrt(_fdot(x, x))


def rough_directions(wall_rules, geom):
    """Every (ν, d) pair the rules of a table's walls (``Experiment.wall_rules``, one per wall) can use on its flat
    walls -> list: constant rank n−1 gives the wall's tangent axes, rank 1 its roughness direction, random and
    hemisphere rules every choice. For 2D walls the one tangent direction is Jν."""
    n = geom.dimension
    out = []
    for wall, rule in zip(geom.wall_list, wall_rules):
        for patch in wall.patches:
            if patch[0] != "flat":
                raise ValueError("rough_directions handles flat walls only")
            nu = np.asarray(patch[2], float)
            for leaf in rule_leaves(rule):
                out.extend((nu, d) for d in _leaf_directions(leaf, nu, wall, n))
    return out


def _leaf_directions(leaf, nu, wall, n):
    if leaf.rank <= 0:          # specular, or an exit (rank −1): no roughness direction
        return []
    if n == 2:
        return [np.array([-nu[1], nu[0]])]
    t1, t2 = (np.asarray(t, float) for t in wall.tangents)
    if leaf.rank == 2:
        return [t1, t2]
    return [np.array(roughness_direction(leaf.direction, t1, t2))]


# ---- describing scenes -----------------------------------------------------------------------------------------


def _num(x):
    return f"{float(x):g}"


def describe_table(kind, t):
    """'in a 2 × 1 rectangle', 'between plates 1 apart', … (the ``phrase`` facet of the kind's record)."""
    try:
        return tables.kind(kind).phrase(t)
    except (KeyError, TypeError, ValueError):
        return f"in a {kind}"


def describe_rule(rule, n):
    """A short name for a rule (``rbx.model`` Constant / Hemisphere / Random / Exit): 'specular', 'rough',
    'rank 1 at 60°', 'hemisphere rough/specular', 'random (specular 0.5, rough 0.5)' — the ``phrase`` of its
    kind's record (:mod:`rbx.rules`); :class:`rbx.rules.NotARule` for anything else."""
    return rules.describe(rule, n)


def describe_boundary(wall_rules, wall_names, n):
    """The rules of the walls: one name when all walls share it; else each wall's, or — when most walls share one
    rule — the walls whose rule differs, then 'others: …'."""
    names = [describe_rule(r, n) for r in wall_rules]
    common = max(names, key=names.count)
    if names.count(common) == len(names):
        return common
    if 2 * names.count(common) <= len(names):
        return ", ".join(f"{w}: {d}" for w, d in zip(wall_names, names))
    parts = [f"{w}: {d}" for w, d in zip(wall_names, names) if d != common]
    return ", ".join(parts + [f"others: {common}"])


def starts_phrase(experiment):
    """How the trajectories start, in a few words: 'point-particle starts', 'billiard-measure starts' (on a wall:
    'billiard-measure starts on gate') or 'fixed starts'. The small-hole escape rate and the mean free path of a
    point particle's starts differ from a disc's with spin (4/π, 14 %): a figure of either says which it is."""
    start = experiment.initial
    if start and isinstance(start[0], str):
        if start[0] == "point_particle":
            return "point-particle starts"
        wall = start[1]
        return "billiard-measure starts" + ("" if wall is None else f" on {experiment.wall_names[wall]}")
    return "fixed starts"


def scene_title(experiment):
    """'disc (R = 0.1, κ = 0.5) in a 2 × 1 rectangle · rough' for an :class:`rbx.model.Experiment`."""
    n = experiment.dimension
    ball = "disc" if n == 2 else "ball"
    return (f"{ball} (R = {_num(experiment.ball.radius)}, κ = {experiment.ball.kappa:.3g}) "
            f"{describe_table(experiment.table_kind, experiment.table)} · "
            f"{describe_boundary(experiment.wall_rules, experiment.wall_names, n)}")


# ---- sections (docs/reference.md §10) -------------------------------------------------------------------------


def wall_span(geom, wall):
    """(s at the start of ``wall``, its length) along the shrunk boundary (2D) -> (float, float)."""
    offsets = [(p, s0) for w, p, s0 in _patch_offsets(geom) if w == wall]
    if not offsets:
        raise ValueError(f"wall {wall} has no part the centre can touch")
    length = sum(float(np.prod([x for _, x in p[3]])) if p[0] == "flat" else p[2] * (p[4] - p[3]) for p, _ in offsets)
    return min(s0 for _, s0 in offsets), length


def ccw_direction(geom, wall):
    """Which way the arc length s of a flat 2D wall grows (counter-clockwise: the table on the left) -> words:
    'towards −x' on the strip's top wall, 'towards +x' on its floor, or 'along (−0.5, −0.866)'."""
    patch = geom.wall_list[wall].patches[0]
    if patch[0] != "flat":
        return "counter-clockwise"
    t = _ccw_tangent(np.asarray(patch[2], float))
    for k, name in enumerate("xy"):
        if abs(abs(t[k]) - 1.0) < 1e-12:
            return f"towards {'+' if t[k] > 0 else '−'}{name}"
    return f"along ({t[0]:.3g}, {t[1]:.3g})"


def spin_fraction(velocity, angular_velocity, R, kappa):
    """The spin's share of the speed in the metric coordinates: v₀/|(v, v₀)| with v₀ = R√κ·ω (2D), or R√κ·ω·e/…
    for 3D components -> values in [−1, 1] (M,) for 2D, (M, 3) for 3D."""
    v = np.asarray(velocity, float)
    w = np.asarray(angular_velocity, float)
    c = R * math.sqrt(kappa)
    w2 = w * w if w.ndim == v.ndim - 1 else np.sum(w * w, axis=-1)
    speed = np.sqrt(np.sum(v * v, axis=-1) + c * c * w2)
    return c * w / (speed if w.ndim == v.ndim - 1 else speed[..., None])


def parse_plane(text):
    """A plane for a Poincaré section: 'z=0.5' (also x=, y=) or 'n=1,0,1;c=0.3' (the plane n·x = c, n normalised)
    -> (unit normal (3,), offset c). Raises ValueError."""
    t = text.replace(" ", "")

    def number(x, what):
        try:
            value = float(x)
        except ValueError:
            raise ValueError(f"{what} must be a number, got '{x}'") from None
        if not math.isfinite(value):
            raise ValueError(f"{what} must be finite, got '{x}'")
        return value
    if len(t) > 2 and t[0] in "xyz" and t[1] == "=":
        n = np.zeros(3)
        n["xyz".index(t[0])] = 1.0
        return n, number(t[2:], f"the offset of {t[0]}=")
    pairs = [p.split("=", 1) for p in t.split(";")]
    parts = dict(p for p in pairs if len(p) == 2)
    if len(pairs) != 2 or set(parts) != {"n", "c"}:
        raise ValueError(f"expected a plane such as z=0.5 or n=1,0,1;c=0.3 (n and c once each), got '{text}'")
    n = np.array([number(x, "the normal's components") for x in parts["n"].split(",")])
    if n.shape != (3,) or not np.any(n):
        raise ValueError(f"the plane's normal must be 3 numbers, not all 0: '{parts['n']}'")
    big = float(np.max(np.abs(n)))           # scaled first: |n| of components of 1e300 overflowed, of 1e-300 was 0
    n = n / big
    norm = float(np.linalg.norm(n))
    return n / norm, number(parts["c"], "the offset c") / big / norm


def plane_crossings(position, velocity, angular_velocity, time, normal, offset):
    """Poincaré section of 3D orbits by the plane normal·x = offset, crossed in the direction of the normal ->
    dict of arrays over the crossings: ``position`` (k, 3), ``velocity``, ``angular_velocity``, ``time``,
    ``trajectory``, ``record`` (the record the flight started from).

    Between records k and k+1 (both recorded: output.every must be 1) the centre flies freely with the velocity of
    record k, so the crossing point is the exact linear interpolation; velocity and spin are those of record k."""
    p, v, w, t = (np.asarray(x, float) for x in (position, velocity, angular_velocity, time))
    h = p @ normal - offset                     # (M, T) signed height above the plane
    a, b = h[:, :-1], h[:, 1:]
    vn = v[:, :-1] @ normal
    hit = (a < 0) & (b >= 0) & (vn > 0) & np.isfinite(b)
    j, k = np.nonzero(hit)
    dt = -a[j, k] / vn[j, k]
    return {"position": p[j, k] + dt[:, None] * v[j, k], "velocity": v[j, k], "angular_velocity": w[j, k],
            "time": t[j, k] + dt, "trajectory": j, "record": k}


def plane_axes(normal):
    """Two unit axes (e₁, e₂) spanning a plane with this unit normal, e₁ along x (or y) projected on it."""
    normal = np.asarray(normal, float)
    base = np.eye(3)[int(np.argmin(np.abs(normal)))] if abs(normal[0]) > 0.9 else np.eye(3)[0]
    e1 = base - (base @ normal) * normal
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(normal, e1)


def wall_measure(geom, w):
    """The length (2D) or area (flat 3D) of wall ``w`` of the shrunk table, from its sampling patches."""
    total = 0.0
    for patch in geom.wall_list[w].patches:
        if patch[0] == "flat":
            total += float(np.prod([x for _, x in patch[3]]))
        elif patch[0] == "arc":
            total += patch[2] * (patch[4] - patch[3])
        elif patch[0] == "sphere":
            total += 4 * np.pi * patch[2] ** 2
        else:
            raise ValueError("the measure of a curved 3D wall other than a sphere is not computed")
    return total


def plus_minus(value, error, digits=2):
    """'value ± error' with the error to ``digits`` significant digits and the value to the same decimal place
    ('0.0084 ± 0.0098', not '0.008357 ± 0.01'); very small and very large numbers (1e6 and more: speeds near
    1e150 printed 150 digits) share one power of ten ('1.234e-12 ± 0.056e-12'). A NaN, infinite or zero error: the value to 4 significant digits and the error as it is."""
    value, error = float(value), float(error)
    if not (math.isfinite(value) and math.isfinite(error) and error > 0):
        return f"{value:.4g} ± {error:.2g}"
    place = digits - 1 - math.floor(math.log10(error))        # decimals that keep ``digits`` of the error
    if place < 0 and max(abs(value), error) < 1e6:   # an error of 100 or more: whole numbers, to its last digit
        return f"{round(value, place):.0f} ± {round(error, place):.0f}"
    if 0 <= place <= 8:
        return f"{value:.{place}f} ± {error:.{place}f}"
    power = math.floor(math.log10(max(abs(value), error)))
    places = max(0, place + power)
    return f"{value / 10 ** power:.{places}f}e{power} ± {error / 10 ** power:.{places}f}e{power}"


def wilson(k, n, z=1.0):
    """The Wilson score interval of a binomial share k/n at z standard deviations -> (share, low, high)."""
    if n == 0:
        return math.nan, math.nan, math.nan
    p = k / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return p, max(0.0, centre - half), min(1.0, centre + half)
