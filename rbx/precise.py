"""A high-precision event loop (mpmath, any number of digits) for every scene and rule: the yardstick of the
accuracy benchmark (``scripts/accuracy.py``) and of the stress tests.

It is the slow pure-Python reference loop of ``tests/reference.py`` written again over mpmath numbers, for exactly the
same formulation (docs/reference.md §1–3, docs/conventions.md), so that its only difference from float64 is the working
precision: ``digits=50`` follows an orbit to ~1e-50 per step, ``digits=15`` (53 bits) behaves like a float64 loop.
Nothing is clever:

* the state is the centre ``a``, velocity ``v`` (lists of mpf), the angular velocity as an n×n antisymmetric
  matrix ``W`` and the orientation (2D angle θ, 3D matrix A), all held at the working precision; the time is
  their exact-to-precision sum;
* the shrunk table is a list of primitives (offset lines or planes with an extent; the circle, sphere or
  cylinder of radius r − R of a round table, a focusing arc or a 3D sphere, and of radius r + R of a dispersing
  arc or a disc/sphere obstacle, an arc over its own angular extent; one arc of radius R per reflex joint of a
  polygon or boundary — where it turns clockwise, judged by the tangents of the pieces there — over the fan where
  the joint is the nearest point of both pieces, attributed to the piece that leaves it), built from the table's
  wall pieces (:mod:`rbx.tables`) at the working precision (the float64 inputs are taken as exact numbers; κ of a
  named mass distribution is the exact fraction, e.g. 2/5, and angles are ``deg·π/180``);
* a periodic table (a ``Lattice``): its obstacles repeat with the cell's period, positions stay unfolded; the
  flight is looked at in windows one cell's smallest side long, testing every image that comes within reach of
  the window (a flight that meets nothing in ``LATTICE_MAX_WINDOWS`` windows is an escape: a corridor);
* a line that only touches a focusing wall's circle from outside, ahead on its extent, is a contact there
  (v·ν = 0: past it the flight would leave the table; docs/conventions.md, Grazing);
* next collision: for each primitive the time the line ``a + t·v`` meets it while moving into it (``v·ν < 0``),
  kept if the hit point lies on the primitive's extent; the smallest wins, and times that agree to the working
  precision are a tie, which goes to the lower wall index (conventions, "Corners": the second wall of a corner
  is then hit at flight time ≈ 0). A point a hair (≤ ``scale·ε^0.6``, ε = 2^−precision) on the wrong side of a
  wall it moves into is hit at time 0; further behind, it is a wall of another part of a non-convex table;
* free flight ``a ← a + τv``, ``θ ← θ + τω`` or ``A ← exp(τW)·A`` (Rodrigues' formula at the working precision);
* the collision map, literally: ``r = −Rν, u = v + W r, u_t = u − (u·ν)ν, Δv = −2α P u_t,
  v' = v − 2(v·ν)ν + Δv, W' = W + (Δv rᵀ − r Δvᵀ)/(κR²)``, P the projector onto the roughness subspace;
* rules: constant; hemisphere (b = Aᵀ(−ν), rough iff b·axis > 0); random, driven by the engine's own draws
  (``rbx.rng``: draw k of the stream keyed by (seed, trajectory, PURPOSE_RULES)), each compared with the
  engine's float64 cumulative probabilities, so that both loops pick the same rule from the same draw; exit: the
  contact is recorded with no map (rank −1) and the trajectory ends there.

Nothing is projected back onto the energy: at 50 digits there is no drift to remove.

    loop = PreciseBilliard(cfg, digits=50)   # cfg: rbx.config.Config, or a config mapping (validated here)
    loop.step()                              # one collision -> False when no wall lies ahead (an escape)
    records, count = precise_run(cfg, collisions=100, digits=50)   # float64 arrays shaped like the engine's

mpmath is imported lazily (it is a dev dependency: only the benchmark and the tests need this module).
Speed: ~0.1 ms per collision in 2D at 50 digits, ~10⁴ times slower than the engine.
"""
import math
from fractions import Fraction

import numpy as np

from . import rules, tables
from .config import from_dict
from .model import RECORD_FIELDS as FIELDS  # the one table of record fields
from .model import roughness_direction
from .rng import PURPOSE_RULES, stream_key, uniform


def _kinds_in(rule, n):
    """The names of the rule kinds in a rule tree -> set."""
    kind = rules.kind_of(rule)
    return {kind.name}.union(*(_kinds_in(c, n) for c in kind.node(rule, n)[3]))


def _mpmath():
    import mpmath
    return mpmath


# -- primitives of the shrunk table ----------------------------------------------------------------------------


class _Flat:
    """Offset of a flat wall: {x : ν·x = c}, c = ν·base + R, hit points restricted to the extent: 2D
    s = (x − base)·direction in [s_min, s_max]; 3D lo ≤ x ≤ hi coordinatewise (None: unbounded)."""
    kind = "flat"

    def __init__(self, wall, c, normal, base=None, direction=None, s_min=None, s_max=None, lo=None, hi=None):
        self.wall, self.c, self.normal = wall, c, normal
        self.base, self.direction, self.s_min, self.s_max = base, direction, s_min, s_max
        self.lo, self.hi = lo, hi


class _Rim:
    """The circle |x| = ρ (already shrunk) around the origin; the centre stays inside, ν = −x/|x|."""
    kind = "rim"

    def __init__(self, wall, rho):
        self.wall, self.rho = wall, rho


class _Reflex:
    """Arc of radius R around a reflex vertex V; the centre stays outside, ν = (x − V)/R; extent: the fan
    (x − V)·e_in ≥ 0 and (x − V)·e_out ≤ 0 (unit directions of the edges arriving at and leaving V)."""
    kind = "reflex"

    def __init__(self, wall, vertex, radius, e_in, e_out):
        self.wall, self.vertex, self.radius, self.e_in, self.e_out = wall, vertex, radius, e_in, e_out


class _Round:
    """A circle (2D), sphere (3D) or, with ``axes = 2``, a cylinder with axis ∥ z: |x − centre| = ρ over the first
    ``axes`` coordinates (ρ already shrunk or grown). ``inside``: the free region is inside (ν = (centre − x)/|…|,
    hit where the line leaves it), else outside (ν = (x − centre)/|…|, hit where it enters). ``arc``: None, or
    (first angle, span) of a 2D arc going counter-clockwise."""
    kind = "round"

    def __init__(self, wall, centre, rho, inside, axes, arc=None):
        self.wall, self.centre, self.rho, self.inside, self.axes, self.arc = wall, centre, rho, inside, axes, arc

    def shifted(self, offset):
        return _Round(self.wall, [c + o for c, o in zip(self.centre, offset)], self.rho, self.inside, self.axes,
                      self.arc)


#: a joint whose unit tangents have a cross product above −this is not reflex (a tangent joint is not): a property
#: of the table's data, the same at every precision
TANGENT_TOLERANCE = 1e-12
#: a periodic flight that meets no obstacle within this many windows (one cell's smallest side each) escapes
LATTICE_MAX_WINDOWS = 10_000


def _dot(x, y):
    s = 0
    for p, q in zip(x, y):
        s += p * q
    return s


def _axpy(t, x, y):
    """y + t·x."""
    return [q + t * p for p, q in zip(x, y)]


def _sub(x, y):
    return [p - q for p, q in zip(x, y)]


def _norm(ctx, x):
    return ctx.sqrt(_dot(x, x))


# -- the loop ---------------------------------------------------------------------------------------------------


class PreciseBilliard:
    """One trajectory of a config, followed at ``digits`` significant decimal digits (see the module docstring).

    ``initial``: a state mapping (position, velocity, angular_velocity, orientation; 3D orientation as a
    rotation vector or a 3×3 matrix; numbers may be floats, ints, Fractions or decimal strings) instead of the
    config's; ``uniforms``: an iterable of draws in [0, 1) for random rules instead of the engine's stream;
    ``orientation``: follow the orientation even when no rule needs it (needed for ``record``)."""

    def __init__(self, cfg, digits=50, trajectory=0, initial=None, uniforms=None, orientation=True):
        mp = _mpmath()
        if not hasattr(cfg, "resolved"):
            cfg = from_dict(cfg)
        self.cfg = cfg
        data = cfg.resolved
        ctx = self.ctx = mp.MPContext()
        ctx.dps = int(digits)
        self.digits = int(digits)
        eps = ctx.mpf(2) ** (-ctx.prec)
        self._dist_rel = eps ** ctx.mpf(0.6)
        self._ext_rel = eps ** ctx.mpf(0.75)
        self._tie_rel = eps ** ctx.mpf(0.9)
        n = self.n = cfg.dimension
        self.R = self.num(data["ball"]["radius"])
        self.kappa = self._kappa(data["ball"].get("inertia", "uniform"))
        self._build_table(data["table"])
        self.rules = [self._rule(r) for r in cfg.wall_rules]
        self.uses_orientation = orientation or any("hemisphere" in _kinds_in(r, n) for r in cfg.wall_rules)
        if uniforms is None:
            key = stream_key(cfg.run.seed, trajectory, PURPOSE_RULES)
            self._draw = lambda k: float(uniform(key, k))
        else:
            it = iter(uniforms)
            self._draw = lambda k: float(next(it))
        self.draws = 0
        self._set_initial(initial if initial is not None else self._config_initial(data, trajectory))
        self.time = ctx.mpf(0)
        self.collisions = 0
        self.wall = -1
        self.rank = 0
        self.alive = True

    # -- numbers --------------------------------------------------------------------------------------------------
    def num(self, x):
        """An exact conversion of a float / int / Fraction (or a decimal string, rounded) to the working precision."""
        if isinstance(x, Fraction):
            return self.ctx.mpf(x.numerator) / x.denominator
        if isinstance(x, str):
            return self.ctx.mpf(x)
        return self.ctx.mpf(float(x)) if not isinstance(x, int) else self.ctx.mpf(x)

    def vec(self, xs):
        return [self.num(x) for x in xs]

    def _kappa(self, inertia):
        n, one = self.n, self.ctx.mpf(1)
        if isinstance(inertia, str):
            return {"uniform": 2 * one / (n + 2), "shell": one if n == 2 else 2 * one / 3, "ring": one}[inertia]
        return self.num(inertia)

    def deg(self, x):
        return self.num(x) * self.ctx.pi / 180

    # -- the table --------------------------------------------------------------------------------------------------
    def _build_table(self, t):
        """The shrunk table at this precision from the table's wall pieces (:mod:`rbx.tables`): no kind is named."""
        ctx, R = self.ctx, self.R
        params = {k: v for k, v in t.items() if k != "kind"}
        self.tangent_axes = {}
        self.prims = []
        wall = 0

        def unit(d):
            return self.vec(tables.unit(d, cos=ctx.cos, sin=ctx.sin, radians=self.deg) if d[0] == "deg" else d)

        self.lattice = None
        self.periodic = []
        for piece in tables.walls(t["kind"], params):
            if isinstance(piece, tables.Lattice):
                lo = self.vec(piece.lo)
                self.lattice = (lo, _sub(self.vec(piece.hi), lo))
                continue
            if isinstance(piece, tables.Polygon):
                V = [self.vec(p) for p in piece.vertices]
                self.prims += self._polygon(V, first_wall=wall)
                wall += len(piece.names)
                continue
            if isinstance(piece, tables.Boundary):
                self.prims += self._boundary(piece.pieces, first_wall=wall)
                wall += len(piece.pieces)
                continue
            if isinstance(piece, tables.Sphere):
                rho = self.num(piece.radius) - R if piece.inside else self.num(piece.radius) + R
                self.prims.append(_Round(wall, self.vec(piece.center), rho, piece.inside, len(piece.center)))
            elif isinstance(piece, tables.Cylinder):
                self.prims.append(_Round(wall, self.vec(piece.center), self.num(piece.radius) - R, True, 2))
            elif isinstance(piece, tables.Circle):
                assert tuple(piece.center) == (0.0, 0.0), "the precise loop's rim is centred at the origin"
                self.prims.append(_Rim(wall, self.num(piece.radius) - R))       # centred at the origin
            elif isinstance(piece, tables.Line):
                p, e, nu = self.vec(piece.point), unit(piece.direction), unit(piece.normal)
                bounded = math.isfinite(piece.s_min) or math.isfinite(piece.s_max)
                self.prims.append(_Flat(wall, _dot(nu, p) + R, nu, p if bounded else None, e if bounded else None,
                                        self.num(piece.s_min) if math.isfinite(piece.s_min) else None,
                                        self.num(piece.s_max) if math.isfinite(piece.s_max) else None))
            else:   # a plane: contact points within the table's box shrunk by R (the normal axis unbounded)
                p, nu = self.vec(piece.point), self.vec(piece.normal)
                lo = [self.num(x) + R if math.isfinite(x) else None for x in piece.lo]
                hi = [self.num(x) - R if math.isfinite(x) else None for x in piece.hi]
                bounded = any(x is not None for x in lo + hi)
                self.prims.append(_Flat(wall, _dot(nu, p) + R, nu, lo=lo if bounded else None,
                                        hi=hi if bounded else None))
                self.tangent_axes[wall] = tuple(self.vec(x) for x in piece.tangents)
            wall += 1
        if self.lattice is not None:     # every wall of a periodic table repeats: only obstacles do here
            if not all(p.kind == "round" and not p.inside for p in self.prims):
                raise TypeError("a lattice holds only obstacles here")
            self.periodic, self.prims = self.prims, []
        self.scale = self.num(tables.kind(t["kind"]).scale(params))

    def _boundary(self, pieces, first_wall=0):
        """A closed counter-clockwise boundary of segments and arcs: each piece's offset towards the table over
        its extent, and an arc of radius R about every reflex joint (the tangents turn clockwise there),
        attributed to the piece leaving it, over the fan (x − joint)·t_in ≥ 0, (x − joint)·t_out ≤ 0."""
        ctx, R = self.ctx, self.R
        prims, starts, ends = [], [], []
        for i, piece in enumerate(pieces):
            wall = first_wall + i
            p0, p1 = self.vec(piece.start), self.vec(piece.end)
            if isinstance(piece, tables.Segment):
                length = _norm(ctx, _sub(p1, p0))
                e = [x / length for x in _sub(p1, p0)]
                nu = [-e[1], e[0]]
                prims.append(_Flat(wall, _dot(nu, p0) + R, nu, p0, e, ctx.mpf(0), length))
                starts.append(e)
                ends.append(e)
                continue
            c = self.vec(piece.center)
            rs, re = _sub(p0, c), _sub(p1, c)
            rho = _norm(ctx, rs)
            a_s, a_e = ctx.atan2(rs[1], rs[0]), ctx.atan2(re[1], re[0])
            ccw = piece.turn == "ccw"
            two_pi = 2 * ctx.pi
            arc = (a_s, (a_e - a_s) % two_pi) if ccw else (a_e, (a_s - a_e) % two_pi)

            def tangent(r):
                u = [x / _norm(ctx, r) for x in r]
                return [-u[1], u[0]] if ccw else [u[1], -u[0]]
            if ccw:
                if rho > R:
                    prims.append(_Round(wall, c, rho - R, True, 2, arc))
            else:
                prims.append(_Round(wall, c, rho + R, False, 2, arc))
            starts.append(tangent(rs))
            ends.append(tangent(re))
        for i in range(len(pieces)):
            t_in, t_out = ends[i - 1], starts[i]
            if t_in[0] * t_out[1] - t_in[1] * t_out[0] < -TANGENT_TOLERANCE:
                prims.append(_Reflex(first_wall + i, self.vec(pieces[i].start), R, t_in, t_out))
        return prims

    def _polygon(self, V, first_wall=0):
        """Offset segments of every edge (full length: at a convex corner the other offset line is reached
        first) and an arc of radius R per reflex vertex, attributed to the edge leaving it (walls from
        ``first_wall`` on)."""
        ctx, R = self.ctx, self.R
        m = len(V)
        prims = []
        for i in range(m):
            edge = _sub(V[(i + 1) % m], V[i])
            length = _norm(ctx, edge)
            e = [x / length for x in edge]
            nu = [-e[1], e[0]]
            prims.append(_Flat(first_wall + i, _dot(nu, V[i]) + R, nu, V[i], e, ctx.mpf(0), length))
        for i in range(m):
            e_in, e_out = _sub(V[i], V[i - 1]), _sub(V[(i + 1) % m], V[i])
            if e_in[0] * e_out[1] - e_in[1] * e_out[0] < 0:   # a clockwise turn of a CCW boundary: reflex
                prims.append(_Reflex(first_wall + i, V[i], R, [x / _norm(ctx, e_in) for x in e_in],
                                     [x / _norm(ctx, e_out) for x in e_out]))
        return prims

    # -- rules ------------------------------------------------------------------------------------------------------
    def _rule(self, rule):
        """A rule (rbx.model Constant / Hemisphere / Random / Exit) -> its form at this precision: a tuple whose
        first entry is its kind's name (the ``precise`` facet of its record in :mod:`rbx.rules`)."""
        return rules.kind_of(rule).precise(rule, self, self._rule)

    def draw(self):
        """The next draw of the trajectory's stream of rule draws (a random rule's step)."""
        u = self._draw(self.draws)
        self.draws += 1
        return u

    def _choose(self, wall, nu):
        rule = self.rules[wall]
        while not rules.RULE_KINDS[rule[0]].leaf:
            rule = rules.RULE_KINDS[rule[0]].precise_step(rule, self, nu)
        return rule

    def _rough_direction(self, rule, wall, nu):
        """The unit roughness direction d of a 3D rank-1 rule at this wall."""
        kind, value = rule[2]
        t1, t2 = self.tangent_axes[wall]
        ctx = self.ctx
        return roughness_direction((kind, value if kind == "deg" else self.vec(value)), t1, t2,
                                   cos=ctx.cos, sin=ctx.sin, sqrt=ctx.sqrt, radians=self.deg)

    # -- state ------------------------------------------------------------------------------------------------------
    @staticmethod
    def _config_initial(data, trajectory):
        init = data["initial"]
        if isinstance(init, dict) and "sample" in init:
            raise ValueError("a sampled initial state: pass initial= (e.g. a state from rbx.simulation.Simulation)")
        states = init if isinstance(init, list) else [init]
        return states[trajectory % len(states)]

    def _set_initial(self, s):
        ctx, n = self.ctx, self.n
        zero = ctx.mpf(0)
        self.a = self.vec(s["position"])
        self.v = self.vec(s["velocity"])
        w = s.get("angular_velocity", 0.0 if n == 2 else [0.0, 0.0, 0.0])
        if n == 2:
            w = self.num(w)
            self.W = [[zero, -w], [w, zero]]
            self.theta = self.num(s.get("orientation", 0.0))
            self.A = None
        else:
            wx, wy, wz = self.vec(w)
            self.W = [[zero, -wz, wy], [wz, zero, -wx], [-wy, wx, zero]]
            o = s.get("orientation", [0.0, 0.0, 0.0])
            if np.ndim(o) == 2:
                self.A = [self.vec(row) for row in o]
            else:
                self.A = self._rodrigues(self.vec(o), 1)
            self.theta = None
        self.energy0 = self.energy()

    def _rodrigues(self, w, tau):
        """exp(τ[w]×) for a 3-vector w, at the working precision."""
        ctx = self.ctx
        norm = _norm(ctx, w)
        one, zero = ctx.mpf(1), ctx.mpf(0)
        if norm == 0:
            return [[one if i == j else zero for j in range(3)] for i in range(3)]
        k = [x / norm for x in w]
        K = [[zero, -k[2], k[1]], [k[2], zero, -k[0]], [-k[1], k[0], zero]]
        s, c1 = ctx.sin(tau * norm), 1 - ctx.cos(tau * norm)
        return [[(one if i == j else zero) + s * K[i][j] + c1 * sum(K[i][m] * K[m][j] for m in range(3))
                 for j in range(3)] for i in range(3)]

    def omega(self):
        """Angular velocity: 2D scalar ω = W₁₀, 3D vector (W₂₁, W₀₂, W₁₀) (mpf)."""
        W = self.W
        return W[1][0] if self.n == 2 else [W[2][1], W[0][2], W[1][0]]

    def energy(self):
        """½(|v|² + 2λ|ω|²) = ½|v|² + ¼κR²·Σ W_ij² (mpf)."""
        rot = sum(x * x for row in self.W for x in row)
        return _dot(self.v, self.v) / 2 + self.kappa * self.R ** 2 * rot / 4

    def record(self):
        """The present state as float64 values, fields as in the engine's records (docs/reference.md §5)."""
        w = self.omega()
        return {"time": float(self.time), "position": [float(x) for x in self.a],
                "velocity": [float(x) for x in self.v],
                "angular_velocity": float(w) if self.n == 2 else [float(x) for x in w],
                "orientation": (float(self.theta) if self.n == 2 else [[float(x) for x in row] for row in self.A])
                if self.uses_orientation or self.n == 2 else np.eye(3).tolist(),
                "wall": self.wall, "rank": self.rank}

    def reverse(self):
        """Time reversal: v ← −v, W ← −W (the orientation stays)."""
        self.v = [-x for x in self.v]
        self.W = [[-x for x in row] for row in self.W]

    # -- one collision ----------------------------------------------------------------------------------------------
    def _scale(self):
        return max(self.scale, self.R, max(abs(x) for x in self.a))

    def _collision_time(self, prim, scale):
        """(t, hit point) of the flight a + t v into the primitive while moving into it, or None."""
        a, v, ctx = self.a, self.v, self.ctx
        dist_tol = self._dist_rel * scale
        ext_tol = self._ext_rel * scale
        if prim.kind == "flat":
            nu = prim.normal
            vn = _dot(nu, v)
            if not vn < 0:                      # parallel or moving away: never touches (grazing rule)
                return None
            d = _dot(nu, a) - prim.c           # signed distance to the offset wall, > 0 inside
            if d < -dist_tol:                  # well behind it: a wall of another part of a non-convex table
                return None
            t = max(d, 0) / -vn
            q = _axpy(t, v, a)
            if prim.direction is not None:
                s = _dot(_sub(q, prim.base), prim.direction)
                if s < prim.s_min - ext_tol or (prim.s_max is not None and s > prim.s_max + ext_tol):
                    return None
            elif prim.lo is not None:
                for i in range(self.n):
                    if prim.lo[i] is not None and not (prim.lo[i] - ext_tol <= q[i] <= prim.hi[i] + ext_tol):
                        return None
            return t, q
        if prim.kind == "round":
            return self._round_time(prim, dist_tol, ext_tol)
        vv = _dot(v, v)
        if vv == 0:
            return None
        if prim.kind == "rim":
            b = _dot(a, v)
            r2 = _dot(a, a)
            dist = prim.rho - ctx.sqrt(r2)     # > 0 inside
            if dist < 0:
                if dist < -dist_tol:
                    return None
                if b > 0:                      # a hair outside and moving out: hit now
                    return ctx.mpf(0), list(a)
            C = r2 - prim.rho ** 2
            disc = b * b - vv * C
            if disc <= 0:
                return None
            s = ctx.sqrt(disc)
            t = (-b + s) / vv if b <= 0 else -C / (b + s)   # the larger root, without cancellation
            t = max(t, 0)
            q = _axpy(t, v, a)
            if not _dot(q, v) > 0:
                return None
            return t, q
        # reflex arc
        p = _sub(a, prim.vertex)
        b = _dot(p, v)
        if not b < 0:                          # moving away from the vertex: never reaches its arc
            return None
        C = _dot(p, p) - prim.radius ** 2
        dist = ctx.sqrt(_dot(p, p)) - prim.radius   # > 0 on the free side
        if dist < 0:
            if dist < -dist_tol:
                return None
            t = ctx.mpf(0)
        else:
            disc = b * b - vv * C
            if disc <= 0:
                return None
            t = C / (-b + ctx.sqrt(disc))      # the smaller root, without cancellation (b < 0)
        q = _axpy(t, v, a)
        rel = _sub(q, prim.vertex)
        if not _dot(rel, v) < 0:
            return None
        if _dot(rel, prim.e_in) < -ext_tol or _dot(rel, prim.e_out) > ext_tol:
            return None
        return t, q

    def _round_time(self, prim, dist_tol, ext_tol):
        """(t, hit point) of the flight into a round primitive (see :class:`_Round`), or None."""
        ctx, a, v, m = self.ctx, self.a, self.v, prim.axes
        p = _sub(a[:m], prim.centre)
        w = v[:m]
        vv = _dot(w, w)
        if vv == 0:
            return None
        b = _dot(p, w)                                  # > 0: moving away from the centre
        r = ctx.sqrt(_dot(p, p))
        C = (r - prim.rho) * (r + prim.rho)
        disc = b * b - vv * C
        if prim.inside:
            d = prim.rho - r                            # > 0 on the free side
            clamped = False
            if d < -dist_tol and disc <= 0:
                # outside the circle (a stadium's straight part), the line touching it ahead on the wall's extent:
                # a contact at the touching point (past it the flight would leave the table; conventions, Grazing)
                t_near = -b / vv
                h = ctx.sqrt(max(_dot(p, p) - b * b / vv, 0))
                q = _axpy(t_near, v, a)
                if t_near > 0 and h - prim.rho <= dist_tol and self._on_arc(prim, q, ext_tol):
                    return t_near, q
                return None
            if disc < 0:                                # the line misses the circle
                if d < -dist_tol:
                    return None
                disc, clamped = ctx.mpf(0), True        # a hair outside counts as on it
            root = ctx.sqrt(disc)
            t = (-b + root) / vv if b <= 0 else -C / (b + root)     # the larger root, cancellation-free
            if t < 0:                                   # behind: only a point a hair outside moving out
                if d < -dist_tol:
                    return None
                t = ctx.mpf(0)
            q = _axpy(t, v, a)
            if not clamped and t > 0 and not _dot(_sub(q[:m], prim.centre), w) > 0:
                return None                             # tangent: a grazing flight does not touch it
        else:
            d = r - prim.rho
            if not b < 0:                               # moving away: never enters
                return None
            if d < 0:
                if d < -dist_tol:
                    return None
                t = ctx.mpf(0)
            else:
                if disc <= 0:                           # misses, or grazes: no contact
                    return None
                t = C / (-b + ctx.sqrt(disc))           # the smaller root, cancellation-free (b < 0)
            q = _axpy(t, v, a)
        if not self._on_arc(prim, q, ext_tol):
            return None
        return t, q

    def _on_arc(self, prim, q, ext_tol):
        """Whether q's direction from the centre lies on the primitive's arc (within the length ``ext_tol``)."""
        if prim.arc is None:
            return True
        ctx = self.ctx
        first, span = prim.arc
        rel = _sub(q[:2], prim.centre)
        two_pi = 2 * ctx.pi
        delta = (ctx.atan2(rel[1], rel[0]) - first) % two_pi
        slack = ext_tol / prim.rho
        return delta <= span + slack or delta >= two_pi - slack

    def _images(self, p0, p1):
        """The periodic images of the lattice's obstacles whose grown sphere meets the box spanned by p0, p1."""
        ctx = self.ctx
        period = self.lattice[1]
        lo = [min(x, y) for x, y in zip(p0, p1)]
        hi = [max(x, y) for x, y in zip(p0, p1)]
        out = []
        for prim in self.periodic:
            ranges = [range(int(ctx.ceil((lo[j] - prim.rho - prim.centre[j]) / period[j])),
                            int(ctx.floor((hi[j] + prim.rho - prim.centre[j]) / period[j])) + 1)
                      for j in range(self.n)]
            shifts = [[]]
            for rg in ranges:
                shifts = [k + [x] for k in shifts for x in rg]
            out += [prim.shifted([x * P for x, P in zip(k, period)]) for k in shifts]
        return out

    def next_collision(self):
        """(t, primitive, hit point) of the next collision, or None if no wall lies ahead."""
        scale = self._scale()
        hits = []
        for prim in self.prims:
            hit = self._collision_time(prim, scale)
            if hit is not None:
                hits.append((hit[0], prim.wall, prim, hit[1]))
        if self.lattice is not None and self.periodic and _dot(self.v, self.v) > 0:
            window = min(self.lattice[1]) / _norm(self.ctx, self.v)
            for k in range(LATTICE_MAX_WINDOWS):
                t0, t1 = k * window, (k + 1) * window
                if hits and min(h[0] for h in hits) <= t0:
                    break
                for prim in self._images(_axpy(t0, self.v, self.a), _axpy(t1, self.v, self.a)):
                    hit = self._collision_time(prim, scale)
                    if hit is not None:
                        hits.append((hit[0], prim.wall, prim, hit[1]))
                if hits and min(h[0] for h in hits) <= t1:
                    break
        if not hits:
            return None
        t_min = min(h[0] for h in hits)
        speed = _norm(self.ctx, self.v)
        # times equal to the working precision are a tie (an exact corner), which the lower wall index wins
        tied = [h for h in hits if (h[0] - t_min) * speed <= self._tie_rel * scale]
        best = min(tied, key=lambda h: (h[1], h[0]))
        return best[0], best[2], best[3]

    def _normal(self, prim, q):
        if prim.kind == "flat":
            return list(prim.normal)
        if prim.kind == "rim":
            x = [-c for c in q]
        elif prim.kind == "round":
            x = _sub(q[:prim.axes], prim.centre) + [0 * c for c in q[prim.axes:]]
            if prim.inside:
                x = [-c for c in x]
        else:
            x = _sub(q, prim.vertex)
        norm = _norm(self.ctx, x)
        return [c / norm for c in x]

    def step(self):
        """One flight and collision -> True, or False (and ``alive`` False) if no wall lies ahead. At an exit the
        contact is the last step: True, and ``alive`` False."""
        if not self.alive:
            return False
        hit = self.next_collision()
        if hit is None:
            self.alive = False
            return False
        tau, prim, q = hit
        self.time += tau
        self.a = q
        if self.uses_orientation:
            if self.n == 2:
                self.theta += tau * self.W[1][0]
            else:
                E = self._rodrigues(self.omega(), tau)
                self.A = [[sum(E[i][m] * self.A[m][j] for m in range(3)) for j in range(3)] for i in range(3)]
        nu = self._normal(prim, q)
        leaf = self._choose(prim.wall, nu)
        if leaf[0] == "exit":           # a hole: the contact is recorded as it is, and the trajectory ends
            self.wall, self.rank = prim.wall, -1
            self.collisions += 1
            self.alive = False
            return True
        self._collide(nu, leaf, prim.wall)
        self.wall, self.rank = prim.wall, leaf[1]
        self.collisions += 1
        return True

    def _collide(self, nu, leaf, wall):
        """docs/reference.md §1, literally (see the module docstring)."""
        n, R, kappa = self.n, self.R, self.kappa
        v, W = self.v, self.W
        vn = _dot(v, nu)
        rank = leaf[1]
        if rank == 0:
            self.v = _axpy(-2 * vn, nu, v)
            return
        r = [-R * x for x in nu]
        u = [v[i] + _dot(W[i], r) for i in range(n)]
        un = _dot(u, nu)
        ut = _axpy(-un, nu, u)
        if rank == n - 1:
            pu = ut                            # P = I − ννᵀ and u_t is tangential already
        elif n == 3 and rank == 1:
            d = self._rough_direction(leaf, wall, nu)
            pu = [_dot(d, ut) * x for x in d]
        else:
            raise ValueError(f"rank {rank} in dimension {n}")
        alpha = kappa / (1 + kappa)
        dv = [-2 * alpha * x for x in pu]
        self.v = [v[i] - 2 * vn * nu[i] + dv[i] for i in range(n)]
        two_lambda = kappa * R * R
        self.W = [[W[i][j] + (dv[i] * r[j] - r[i] * dv[j]) / two_lambda for j in range(n)] for i in range(n)]

    def run(self, collisions, every=1):
        """Follow ``collisions`` more collisions -> records (list of float dicts: the present state first, then
        every ``every``-th collision); stops early at an escape."""
        out = [self.record()]
        for _ in range(int(collisions)):
            if not self.step():
                break
            if self.collisions % every == 0:
                out.append(self.record())
        return out


def to_arrays(records):
    """A list of record dicts -> dict field -> float64 array (T, …) (wall and rank int), like one trajectory of
    the engine's records."""
    out = {}
    for f in FIELDS:
        dtype = np.int32 if f in ("wall", "rank") else float
        out[f] = np.array([r[f] for r in records], dtype=dtype)
    return out


def precise_run(cfg, collisions=None, digits=50, every=1, **kw):
    """Run one trajectory at ``digits`` digits -> (dict field -> float64 array (T, …), T). ``collisions``
    defaults to the config's ``run.collisions``; keywords go to :class:`PreciseBilliard`."""
    loop = PreciseBilliard(cfg, digits=digits, **kw)
    if collisions is None:
        collisions = loop.cfg.run.collisions
    recs = loop.run(collisions, every=every)
    return to_arrays(recs), len(recs)


def deviation(loop, position, velocity, angular_velocity=None):
    """How far a float64 state is from the loop's present state, differences taken at the loop's precision ->
    {'position': max |Δa_i|, 'velocity': max |Δv_i|, 'angular_velocity': max |Δω_i|} (floats)."""
    def dist(x, y):
        return float(max(abs(loop.num(float(p)) - q) for p, q in zip(np.ravel(x), y)))

    out = {"position": dist(position, loop.a), "velocity": dist(velocity, loop.v)}
    if angular_velocity is not None:
        w = loop.omega()
        out["angular_velocity"] = dist(angular_velocity, [w] if loop.n == 2 else w)
    return out
