"""The event loop (njit): free flight to the next wall, choose the rule, apply the collision map, record.

Three tiers (after stumpy): :mod:`rbx.simulation` validates and allocates → :func:`run_advance_all` runs
slices of the trajectories on a thread pool → :func:`kernel` ``(spec)``, the serial loop over a slice (``nogil``; each
trajectory writes only its own slots), one compiled closure per combination of compiled bits. Kernels take arrays and scalars only, in six
named groups (module-level named tuples, so that Numba types them and its disk cache finds them again):

- :class:`Table`: the shrunk table's primitives (codes, wall of each primitive, parameters) and the flight
  tolerance;
- :class:`Rules`: the rule trees flattened into arrays (:meth:`rbx.rules.CompiledRules.kernel_arrays`);
- :class:`Settings`: the run's scalars (all ``spec`` bits, stop wall, record stride and mask, renormalisation
  period, the ball's R and κ);
- :class:`State`: the state of the M trajectories, one row each, read and written in place;
- :class:`Records`: the block's record buffers, one per field of :data:`rbx.model.FIELDS`, named as the fields;
- :class:`Tangent`: tangent vectors carried along the orbit, for the Lyapunov spectrum and the flow's Jacobian
  (:mod:`rbx.dynamics`; empty, and compiled out, in every other run).

Beside them go only the per-call arguments (the trajectories' slice, their collision targets and the record
counts); the compiled bits (:data:`COMPILED_BITS`) are constants of the loop's closure. A named tuple of arrays
costs nothing in the loop: Numba passes its members as separate arguments, and the loop is compiled without the
runtime, so reading a member is no reference count.

Per collision (ARCHITECTURE.md, "The event loop"):
 1. ``box_collision``: the smallest flight time over the shrunk table's primitives, the sides of an axis-aligned
    box in closed form (inf: the trajectory escapes and ends); slabs and periodic cells have their own search;
 2. free flight: ``a += τv``, ``t += τ``; the orientation only if a rule or a recorded field needs it;
 3. the contact normal ν at the new position;
 4. the rule tree of the wall picks a constant rule (rank, roughness basis) — hemisphere by the body-frame
    contact point, random by the trajectory's counter-based stream;
 5. the strict collision map updates (v, W) in place;
 6. every ``every``-th collision, the requested fields go to the trajectory's row of the block buffers.

With the compiled bit ``S_TANGENT`` the same loop carries tangent vectors beside the state (the flight's and the
collision's linearisations, :mod:`rbx.tangent`, added after steps 2 and 5): the Lyapunov spectrum follows exactly
the orbit ``rbx simulate`` records, by construction — the same search, snapping, compensated sums and exit
bookkeeping.
"""
import os
import types
import warnings
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import numba
import numpy as np

from ._jit import compile_lock, hooks, jit_call, jit_hot, jit_loop, stack_array
from .environment import KERNEL_MODES as _MODES, kernel_mode
from .geometry import (HALFSPACE, SEGMENT, box_collision, contact_normal, normal_jacobian, periodic_flight,
                       periodic_images, slab_collision, snap)
from .model import FIELD, FIELDS
from .primitives import P_NORMAL, P_POINT
from .physics import collide, collide_axis
from .rng import draw53
# Rules: a group of the kernels, defined with the rules
from .rules import EXIT, HEMISPHERE, Rules, choose, hemisphere_step  # noqa: F401
from .tangent import (STATE_SHAPE, fold, last_flight, orthonormalise, set_unit, state_after, state_before, step,
                      step_inline)
from .trig import sincos

# bits of the record mask (rbx.model.FIELDS), as module constants so that Numba compiles them in
F_TIME, F_POSITION, F_VELOCITY, F_SPIN, F_ORIENTATION, F_WALL, F_RANK = (
    FIELD[f].bit for f in ("time", "position", "velocity", "angular_velocity", "orientation", "wall", "rank"))


class Table(NamedTuple):
    """The shrunk table (:class:`rbx.geometry.Geometry`) as the kernels read it."""
    codes: np.ndarray       # (P,) int64: the kind of each primitive (geometry's codes)
    prim_wall: np.ndarray   # (P,) int64: the wall each primitive belongs to
    params: np.ndarray      # (P, k) float64: each primitive's parameters
    tol: float              # flights shorter than this do not count (END_TOLERANCE × the table's size)
    lattice_lo: np.ndarray  # (n,) a periodic table's cell starts here (S_PERIODIC) …
    period: np.ndarray      # (n,) … and repeats with this period along each axis
    box: np.ndarray         # (2n,) int64: the sides of an axis-aligned box (Geometry.axis_box), else (0,) …
    others: np.ndarray      # (P′,) int64 … and the other primitives (all of them without a box)
    first_hit: bool         # a convex boundary of pieces (Geometry.convex_boundary): the first hit in ``others``
    axis: np.ndarray        # (P,) int64: i for a flat primitive of normal ±e_i (physics.collide_axis), else −1
    images: np.ndarray      # (Q,) int64: a periodic table's images tested in each cell: primitive images[q] …
    image_shift: np.ndarray  # (Q, n) float64 … shifted by this many cells (geometry.periodic_images)


def make_table(geom, tol):
    """The kernels' :class:`Table` of a :class:`rbx.geometry.Geometry` (the one place it is made)."""
    n = geom.dimension
    lo, period = geom.lattice if geom.lattice is not None else (np.zeros(n), np.ones(n))
    box = geom.axis_box
    box = np.zeros(0, dtype=np.int64) if box is None else box
    others = [k for k in range(len(geom.codes)) if k not in set(box.tolist())]
    first = geom.convex_boundary
    images, image_shift = periodic_images(geom)
    if first:       # the cheaper segments are asked first (box_collision stops at the first hit)
        others.sort(key=lambda k: geom.codes[k] != SEGMENT)
    return Table(codes=geom.codes, prim_wall=geom.walls, params=np.ascontiguousarray(geom.params), tol=float(tol),
                 lattice_lo=np.ascontiguousarray(lo, dtype=np.float64),
                 period=np.ascontiguousarray(period, dtype=np.float64), box=box,
                 others=np.array(others, dtype=np.int64), first_hit=bool(first), axis=flat_axes(geom),
                 images=images, image_shift=image_shift)


def flat_axes(geom):
    """Per primitive, the axis i of a flat one (half-space or segment) whose normal is exactly ±e_i, else −1: the
    kernels give it the collision map with ν's zeros left out (:func:`rbx.physics.collide_axis`)."""
    n = geom.dimension
    out = np.full(len(geom.codes), -1, dtype=np.int64)
    for k, code in enumerate(geom.codes):
        if code in (HALFSPACE, SEGMENT):
            nu = geom.params[k, P_NORMAL:P_NORMAL + n]
            i = int(np.argmax(np.abs(nu)))
            if abs(nu[i]) == 1.0 and np.count_nonzero(nu) == 1:
                out[k] = i
    return out


class Settings(NamedTuple):
    """The run's scalars."""
    flags: int              # every bit S_* of the run; the kernel takes the run-time ones (RUNTIME_BITS) from here
    stop_wall: int          # with S_STOP_WALL, a trajectory ends right after hitting this wall
    every: int              # record every ``every``-th collision
    mask: int               # which fields are recorded: the bits of rbx.model.FIELDS
    renorm_every: int       # rescale onto the initial energy every so many collisions (0: never; the speed alone where all walls are specular)
    R: float                # the ball's radius
    kappa: float            # the ball's inertia coefficient κ


class State(NamedTuple):
    """The state of M trajectories, row j for trajectory j, advanced in place."""
    pos: np.ndarray         # (M, n) centre
    vel: np.ndarray         # (M, n) velocity
    W: np.ndarray           # (M, n, n) spin matrix (antisymmetric)
    theta: np.ndarray       # (M,) 2D orientation angle
    A: np.ndarray           # (M, 3, 3) 3D orientation (body to space)
    time: np.ndarray        # (M,)
    ncoll: np.ndarray       # (M,) int64 collisions made
    draws: np.ndarray       # (M,) int64 random draws used
    alive: np.ndarray       # (M,) bool: not escaped, not stopped
    keys: np.ndarray        # (M,) uint64 random stream keys
    last_wall: np.ndarray   # (M,) int64 wall of the last collision (−1: none yet)
    last_rank: np.ndarray   # (M,) int64 rank of the rule at the last collision
    energy0: np.ndarray     # (M,) initial energy (the renormalisation's target)
    comp: np.ndarray        # (M, n+1) rounding errors carried by compensated summation (position, time)


class Records(NamedTuple):
    """The record buffers of one block, one per field of :data:`rbx.model.FIELDS` (same names, same order): slot
    (j, r) is trajectory j's r-th record of the block. A field not recorded has a buffer of size 0."""
    time: np.ndarray              # (M, b)
    position: np.ndarray          # (M, b, n)
    velocity: np.ndarray          # (M, b, n)
    angular_velocity: np.ndarray  # (M, b, 1 or 3)
    orientation: np.ndarray       # (M, b, 1 or 9)
    wall: np.ndarray              # (M, b) int32
    rank: np.ndarray              # (M, b) int32


assert Records._fields == tuple(f.name for f in FIELDS)


class Tangent(NamedTuple):
    """Tangent vectors carried along the orbit (with ``S_TANGENT``; :mod:`rbx.tangent`, :mod:`rbx.dynamics`)."""
    Y: np.ndarray           # (M, K, d): trajectory j's K tangent vectors are the rows of Y[j] (each contiguous)
    sums: np.ndarray        # (M, K): with ``ortho``, the sums of the logarithms of the stretches
    t_end: np.ndarray       # (M,): a trajectory stops in flight when its time reaches t_end[j] (inf: never)
    ortho: int              # re-orthonormalise the rows every ``ortho`` collisions and when the trajectory stops
                            # (Benettin); 0: never, Y is then the transposed Jacobian
    grow: float             # … and as soon as the first vector's squared length exceeds this
    #: the time unit u (a power of two) of the rows' velocity-like coordinates: they hold u·δv and u·δω̂, so that
    #: re-orthonormalising weighs a length and a velocity times u alike (rbx.dynamics.time_unit); 1 converts nothing
    unit: float = 1.0


#: what the kernels get in every run without tangent vectors (the loop's tangent steps are compiled out)
NO_TANGENT = Tangent(Y=np.zeros((0, 0, 0)), sums=np.zeros((0, 0)), t_end=np.zeros(0), ortho=0, grow=np.inf)



@jit_hot
def rotate(A, W, tau):
    """A ← exp(τW)·A for 3D, column by column by Rodrigues' formula, with ω = (W₂₁, W₀₂, W₁₀) and φ = τ|ω|:
    a ← a + (sin φ/|ω|) ω × a + ((1 − cos φ)/|ω|²) ω × (ω × a): two cross products a column, where building
    exp(τW) and multiplying A by it took a 3 × 3 product besides (the cost measured: docs/speed-gaps.md)."""
    wx, wy, wz = W[2, 1], W[0, 2], W[1, 0]
    w = np.sqrt(wx * wx + wy * wy + wz * wz)
    phi = tau * w
    if phi == 0.0:
        return
    c, sn = sincos(phi)                  # inline: a libm call spills the loop's registers
    s = sn / w                           # the two divisions once, not once per entry (no fast-math to hoist them)
    c1 = (1.0 - c) / (w * w)
    for j in range(3):
        ax, ay, az = A[0, j], A[1, j], A[2, j]
        cx, cy, cz = wy * az - wz * ay, wz * ax - wx * az, wx * ay - wy * ax          # ω × a
        A[0, j] = ax + s * cx + c1 * (wy * cz - wz * cy)
        A[1, j] = ay + s * cy + c1 * (wz * cx - wx * cz)
        A[2, j] = az + s * cz + c1 * (wx * cy - wy * cx)


@jit_hot
def energy_factor(v, W, R, kappa, e0, half_inv_e0, n):
    """The factor f that puts (v, W) back onto the trajectory's initial energy ``e0``: f²·energy = e0.

    The rough map conserves energy exactly in exact arithmetic, but its constants (α, 2/((1+κ)R)) are rounded the
    same way at every collision, which biases the energy by ~1e-17 per collision: 2e-12 after 10⁵ collisions in
    an L-shaped table. Projecting back onto the energy surface removes that drift (docs/accuracy.md)."""
    e = 0.0
    for i in range(n):
        e += v[i] * v[i]
    rot = 0.0                                   # ½ tr(WᵀW): W is antisymmetric, its upper triangle is enough
    for i in range(n):
        for k in range(i + 1, n):
            rot += W[i, k] * W[i, k]
    e = 0.5 * e + 0.5 * kappa * R * R * rot
    # f = √(e0/e). Between projections e drifts from e0 by a few ulp (δ = (e0 − e)/e0 ~ 1e-15), and for
    # |δ| < 1e-9, 1 + δ/2 is √(e0/e) to within δ²/8 < 1.3e-19, below an ulp: no division and no square root
    # (``half_inv_e0`` = 1/(2e0), once per trajectory)
    d = e0 - e
    if abs(d) < 1e-9 * e0:
        return 1.0 + d * half_inv_e0
    return np.sqrt(e0 / e)


@jit_hot
def speed_factor(v, W, R, kappa, e0, n):
    """The factor f that puts the speed back where the trajectory's initial energy ``e0`` puts it, the spin
    ``W`` left as it is: f²·½|v|² = e0 − ½κR²·½tr(WᵀW), for scenes whose walls are all specular (their maps never
    change the spin, and a projection must not either). The reflection v − 2(v·ν)ν off a curved wall, ν a unit
    vector to an ulp, raises |v|² by about 1e-16 per collision on average: 1.2e-10 after 10⁶ collisions of the
    specular Sinai table. 1 where the spin holds all the energy (nothing to put back)."""
    e = 0.0
    for i in range(n):
        e += v[i] * v[i]
    rot = 0.0
    for i in range(n):
        for k in range(i + 1, n):
            rot += W[i, k] * W[i, k]
    target = e0 - 0.5 * kappa * R * R * rot
    e = 0.5 * e
    if not (target > 0.0 and e > 0.0):
        return 1.0
    d = target - e
    if abs(d) < 1e-9 * target:          # as in energy_factor: 1 + δ/2 is √(target/e) to below an ulp
        return 1.0 + 0.5 * d / target
    return np.sqrt(target / e)


@jit_hot
def scale_state(v, W, f, n):
    """(v, W) ← f·(v, W), W kept exactly antisymmetric."""
    for i in range(n):
        v[i] *= f
        for k in range(i + 1, n):
            W[i, k] *= f
            W[k, i] = -W[i, k]


@jit_hot
def write_record(j, r, mask, t, a, v, W, theta, A, wall, rank, out, n):
    """Write the requested fields of one state into slot (j, r) of the block buffers ``out`` (:class:`Records`)."""
    if mask & F_TIME:
        out.time[j, r] = t
    if mask & F_POSITION:
        for i in range(n):
            out.position[j, r, i] = a[i]
    if mask & F_VELOCITY:
        for i in range(n):
            out.velocity[j, r, i] = v[i]
    if mask & F_SPIN:
        if n == 2:
            out.angular_velocity[j, r, 0] = W[1, 0]
        else:
            out.angular_velocity[j, r, 0] = W[2, 1]
            out.angular_velocity[j, r, 1] = W[0, 2]
            out.angular_velocity[j, r, 2] = W[1, 0]
    if mask & F_ORIENTATION:
        if n == 2:
            out.orientation[j, r, 0] = theta
        else:
            for i in range(3):
                for k in range(3):
                    out.orientation[j, r, 3 * i + k] = A[i, k]
    if mask & F_WALL:
        out.wall[j, r] = wall
    if mask & F_RANK:
        out.rank[j, r] = rank


#: bits of ``spec``, the compile-time description of what a run needs (docs/reference.md §7: skip what a scene does not need).
#: The compiled ones are constants of the loop (:func:`kernel`): Numba compiles one specialised loop per combination
#: in use and the branches a scene does not need are not in it (and the dimension becomes a constant).
S_DIM3 = 1          # 3D (else 2D)
S_ORIENT = 2        # follow the orientation (a hemisphere rule or the recorded field needs it)
S_SPIN = 4          # some rule is rough: spin arithmetic (else specular reflection only)
S_TREE = 8          # some wall's rule is a hemisphere or random tree (else the wall's constant rule directly)
S_RECORD = 16       # per-collision records are written
S_COMPENSATED = 64  # compensated (Kahan) summation of the time and the position
S_SNAP = 128        # put the centre exactly on the wall at contact
S_SLAB = 256        # two parallel walls (strip, plates): closed-form flight time and exact normal coordinate
S_STOP_WALL = 512   # end a trajectory when it hits ``stop_wall``
S_PERIODIC = 1024   # a periodic cell (Table.lattice_lo, period): the images of the primitives around the centre
S_EXIT = 2048       # some wall's rule is (or may resolve to) ``exit``: the trajectory ends at its contact
S_AXES = 4096       # bounded by an axis-aligned box (Table.box): a division per axis, then the other primitives
S_ROUND_HEMI = 8192  # 2D: a hemisphere rule on a wall without one normal: cos θ, sin θ (rbx.rules.choose)
S_TANGENT = 16384   # carry tangent vectors (Tangent) along the orbit: the Lyapunov spectrum, the flow's Jacobian
S_BLEND = 32768     # the rank is drawn at random: the map computed without a branch on it (rbx.physics.rough_factor)
S_SHARED = 65536    # every wall's rule is one node picking among constant rules by one test: picked without the walk
S_GENERAL = 131072  # the general loop (compiled_spec): every bit but the dimension read at run time
#: the bits compiled into the kernel; the others are tested at run time (a predictable branch). Each compiled
#: combination in use costs a compile of 5–15 s the first time (then it is on disk), so the bits compiled are the
#: ones that pay: the dimension (loops of constant length, state in registers), spin arithmetic, the slab's closed
#: form, and what docs/reference.md §7 says is skipped (the orientation, rule trees and random draws). Compiling these took the
#: rough strip from 6.7 to 5.0 ns per collision and the rough plates from 8.5 to 6.2 (the run-time tests keep
#: registers busy); as a run-time bit the orientation costs the rough plates 0.99 -> 0.86 of their hand loop. An
#: axis-aligned box (S_AXES) is compiled too: rbx/hand of the rectangle 0.53 -> 0.80, box 0.39 -> 0.72, Sinai
#: 0.69 -> 0.76 (specular, CPU time interleaved, load ~6), and 0.50, 0.64, 0.69 with the box a run-time branch.
#: Periodic cells and exits are compiled because a scene without them then never compiles their code (the
#: periodic search was 4.4 s of the 29 s a kernel took to compile while it was a run-time branch). Per-collision
#: records are a run-time bit: compiled, they doubled the combinations in use (the test suite compiled 71 loops,
#: 50 without it) for 1.14 -> 1.08 of the strip's hand loop and 0.99 -> 0.96 of the plates' (interleaved, load
#: ~2; the record branch is never taken when nothing is recorded). The variants and the stop wall are run-time
#: bits too.
COMPILED_BITS = (S_DIM3 | S_SPIN | S_SLAB | S_TREE | S_ORIENT | S_AXES | S_PERIODIC | S_EXIT | S_ROUND_HEMI
                 | S_TANGENT)
RUNTIME_BITS = ~COMPILED_BITS

#: which loops are compiled. ``"specialised"`` (the default): one per combination of :data:`COMPILED_BITS` in use,
#: each with the code its scene needs and nothing else (the fastest per collision, 5–15 s to compile each).
#: ``"general"`` (the environment variable ``RBX_KERNELS=general``): one per dimension, every other bit (the
#: tangent vectors' too) read at run time like the run-time bits. Its numbers are the specialised loop's bit
#: for bit: both do the same floating-point operations in the same order (no fast-math, so no contraction or
#: reassociation); only whether a branch is decided when compiling or when running differs. It is slower per
#: collision and compiles once for every scene: the test suite uses it (tests/conftest.py), and the tests compare
#: both on every example (tests/test_kernels.py). Read from the environment by :mod:`rbx.environment`.
KERNEL_MODES = _MODES


def _kernel_mode_from_environment():
    mode, problem = kernel_mode()
    if problem:
        warnings.warn(f"RBX_KERNELS={problem}: the specialised loops are used", stacklevel=2)
    return mode


KERNELS = _kernel_mode_from_environment()


def compiled_spec(flags):
    """The bits of ``flags`` compiled into the loop that runs them (:data:`KERNELS`): ``flags & COMPILED_BITS``, or
    for the general loop the dimension and :data:`S_GENERAL`."""
    if KERNELS == "general":
        return (int(flags) & S_DIM3) | S_GENERAL
    return int(flags) & COMPILED_BITS


def make_spec(n, orient=False, spin=True, tree=False, record=False, compensated=False, snap=False,
              slab=False, stop_wall=False, periodic=False, exit=False, axes=False, round_hemisphere=False,
              tangent=False, blend=False, shared=False):
    """The ``spec`` bits from flags (:class:`rbx.simulation.Simulation` derives them from the config)."""
    flags = ((n == 3, S_DIM3), (orient, S_ORIENT), (spin, S_SPIN), (tree, S_TREE), (record, S_RECORD),
             (compensated, S_COMPENSATED), (snap, S_SNAP), (slab, S_SLAB),
             (stop_wall, S_STOP_WALL), (periodic, S_PERIODIC), (exit, S_EXIT), (axes, S_AXES),
             (round_hemisphere, S_ROUND_HEMI), (tangent, S_TANGENT), (blend, S_BLEND),
             (shared, S_SHARED))
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


#: a random node's threshold that no draw reaches (a draw has 53 bits): the third leaf of a choice of two
NEVER = np.uint64(2**64 - 1)

#: the compiled loops, one per combination of compiled bits in use (:func:`kernel`)
_KERNELS = {}


def kernel(spec):
    """The compiled loop over trajectories for the compiled bits ``spec`` (:func:`compiled_spec`): made on first
    use by :func:`_make_kernel`, compiled (or loaded from the disk cache) on its first call."""
    k = _KERNELS.get(spec)
    if k is None:
        k = _KERNELS[spec] = _make_kernel(spec)
    return k


def _make_kernel(spec):
    """The serial loop of :func:`kernel` for ``spec``, with each compiled bit a constant of the closure.

    Why a closure and not a literal argument: Numba prunes a branch on a constant (a closure variable) before it
    inlines the helpers (its untyped passes: dead-branch pruning, then inlining), so a branch the scene does not
    need is never copied, typed or lowered; a branch on a literal argument is pruned only by LLVM, after all of
    that work. The Sinai rough kernel compiled in 29 s that way, most of it inlining and typing the periodic
    search and rule trees it does not use. The closure's constants are part of Numba's cache key (its index keys
    closures by their cell contents), so each combination has its own entry on disk."""
    N = 3 if spec & S_DIM3 else 2
    ORIENT, SPIN, TREE = bool(spec & S_ORIENT), bool(spec & S_SPIN), bool(spec & S_TREE)
    SLAB, PERIODIC = bool(spec & S_SLAB), bool(spec & S_PERIODIC)
    EXIT_, AXES, ROUND_HEMI = bool(spec & S_EXIT), bool(spec & S_AXES), bool(spec & S_ROUND_HEMI)
    TANGENT = bool(spec & S_TANGENT)
    GENERAL = bool(spec & S_GENERAL)
    BLEND = SPIN and TREE   # a rank chosen per collision: S_BLEND can apply

    def advance_all(j0, j1, stop, table, rules, settings, state, out, tangent, nrec):
        """Run each live trajectory j0 ≤ j < j1 until it has made ``stop[j]`` collisions in all -> records written
        to row j of ``out``, their number in ``nrec[j]``.

        ``table``, ``rules``, ``settings``, ``state``, ``out``: the groups :class:`Table`, :class:`Rules`,
        :class:`Settings`, :class:`State`, :class:`Records`. A trajectory ends early (``state.alive[j] = False``)
        when no wall lies ahead (an escape), at an exit, or, with ``S_STOP_WALL``, right after a collision with
        ``settings.stop_wall`` (the return loop of the invariant-measure experiment). With ``S_COMPENSATED``,
        ``state.comp[j]`` carries the rounding errors of the position (0…n−1) and time (n) sums. With
        ``S_TANGENT``, the columns of ``tangent.Y[j]`` follow the orbit's linearisation (:mod:`rbx.tangent`), and
        the trajectory stops in flight when its time reaches ``tangent.t_end[j]``.

        Compiled without the Numba runtime (:data:`rbx._jit.jit_loop`): reading a member of a group is no reference
        count, and the members used per collision are taken into locals once, here; ``nogil``:
        :func:`run_advance_all` runs slices of the trajectories on several threads at once (each writes only its
        own rows)."""
        n = N
        on = settings.flags                        # the run-time bits are read from here (the compiled ones: constants)
        blend = (BLEND or (GENERAL and (on & S_SPIN) != 0 and (on & S_TREE) != 0)) and (on & S_BLEND) != 0
        codes, prim_wall, params, tol = table.codes, table.prim_wall, table.params, table.tol
        first_hit = table.first_hit
        R, kappa, every, renorm_every = settings.R, settings.kappa, settings.every, settings.renorm_every
        comp = state.comp
        # the trajectory's state in the kernel's own stack frame (registers, once n is a constant): see stack_array
        a = stack_array(3, (n,))
        v = stack_array(3, (n,))
        Wj = stack_array(9, (n, n))
        Aj = stack_array(9, (3, 3))
        nu = stack_array(3, (n,))
        work = stack_array(9, (3, n))
        prod = stack_array(12, (12,))          # the tangent vectors' stretches since their logs were last added
        base = stack_array(3, (n,))            # periodic tables: the centre's cell, …
        loc = stack_array(3, (n,))             # … its position relative to the image of the cell hit, …
        off = stack_array(3, (n,))             # … and that image's shift (loc = a − off); …
        ahead = stack_array(3, (n,))           # … and where the flight is looked at from
        if TANGENT or (GENERAL and (on & S_TANGENT) != 0):
            # what the tangent step reads besides the state
            Ts = stack_array(54, STATE_SHAPE)  # the state around the collision, as the step reads it (tangent._step)
            set_unit(Ts, tangent.unit)
            Jn = Ts[2, 0]                      # the normal's derivative along the wall
            period = tangent.ortho             # re-orthonormalise every so many collisions (0: never)
        # every wall the same choice among constant rules (rules.CompiledRules.shared_pick): a random one of two or
        # three, or the side of a hemisphere rule. Its leaves, their ranks and its thresholds are held in locals, so
        # that the pick walks no tree (tests/test_rules.py: the same orbit as the walk)
        shared = (TREE or GENERAL) and (on & S_SHARED) != 0
        r0 = np.int64(0)
        hemi = False
        pick_c0, pick_c1, pick_c2 = np.int64(0), np.int64(0), np.int64(0)
        pick_r0, pick_r1, pick_r2 = np.int64(0), np.int64(0), np.int64(0)
        pick_t0, pick_t1 = np.uint64(0), NEVER
        if shared:
            r0 = rules.root[0]
            f0, k0 = rules.first[r0], rules.nchild[r0]
            hemi = rules.kind[r0] == HEMISPHERE
            pick_c0, pick_c1 = rules.children[f0], rules.children[f0 + 1]
            pick_c2 = rules.children[f0 + 2] if k0 == 3 else pick_c1
            pick_r0, pick_r1, pick_r2 = rules.rank[pick_c0], rules.rank[pick_c1], rules.rank[pick_c2]
            pick_t0 = rules.threshold[f0]
            if k0 == 3:
                pick_t1 = rules.threshold[f0 + 1]
        # the stop wall as a number no wall has when there is none: one comparison per collision
        stop_at = np.int64(settings.stop_wall) if on & S_STOP_WALL else np.int64(-2)
        alive = state.alive
        for j in range(j0, j1):
            if not alive[j]:
                continue
            c_stop = stop[j]
            count = 0
            for i in range(n):
                a[i] = state.pos[j, i]
                v[i] = state.vel[j, i]
                for k in range(n):
                    Wj[i, k] = state.W[j, i, k]
            if ORIENT or (GENERAL and (on & S_ORIENT) != 0):
                for i in range(3):
                    for k in range(3):
                        Aj[i, k] = state.A[j, i, k]
            th = state.theta[j]
            t = state.time[j]
            c = state.ncoll[j]
            d = state.draws[j]
            key = state.keys[j]
            w = state.last_wall[j]
            rk = state.last_rank[j]
            e0 = state.energy0[j]
            half_inv_e0 = 0.5 / e0
            count = 0
            until_record = every - c % every           # collisions to the next record
            until_renorm = renorm_every - c % renorm_every if renorm_every > 0 else 0
            if TANGENT or (GENERAL and (on & S_TANGENT) != 0):
                Yj = tangent.Y[j]
                t_end = tangent.t_end[j]
                since = 0                       # collisions since the vectors were last re-orthonormalised
                for k in range(Yj.shape[0]):
                    prod[k] = 1.0
            while c < c_stop:
                # 1. next collision: the flight time and the primitive hit
                if SLAB or (GENERAL and (on & S_SLAB) != 0):
                    tau, p = slab_collision(params, a, v, n)
                elif PERIODIC or (GENERAL and (on & S_PERIODIC) != 0):
                    tau, p = periodic_flight(codes, params, a, v, tol, n, table.lattice_lo, table.period, table.images,
                                             table.image_shift, base, loc, off, ahead)
                else:
                    tau, p = box_collision(codes, params, a, v, tol, n, table.box, table.others,
                                           AXES or (GENERAL and (on & S_AXES) != 0), first_hit)
                in_flight = False               # the tangent loop's stop at t_end, in flight
                if TANGENT or (GENERAL and (on & S_TANGENT) != 0):
                    if t + tau > t_end:
                        tau = t_end - t
                        in_flight = True
                if p == -1 and not in_flight:
                    state.alive[j] = False
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
                if ORIENT or (GENERAL and (on & S_ORIENT) != 0):
                    if n == 2:
                        th += tau * Wj[1, 0]
                    else:
                        rotate(Aj, Wj, tau)
                if TANGENT or (GENERAL and (on & S_TANGENT) != 0):
                    # the flight's tangent step is taken with the collision's (one call); a flight that ends
                    # without one (stopped at t_end, or at an exit below) takes it alone, after the vectors'
                    # stretches up to the last collision are added
                    if in_flight:
                        since = last_flight(Yj, tangent.sums, prod, j, since, tau, Ts, Wj, R, kappa, n)
                        t = t_end
                        if on & S_COMPENSATED:
                            comp[j, n] = 0.0
                        break
                if SLAB or (GENERAL and (on & S_SLAB) != 0):
                    a[n - 1] = params[p, P_POINT + n - 1]  # exactly on the wall: the normal coordinate is known
                    if on & S_COMPENSATED:
                        comp[j, n - 1] = 0.0
                # 3. contact normal (a slab's is ±e_{n−1}, known from the wall: no lookup; the rule tree and snapping
                #    read it, and the slab map takes only its sign); in a periodic table, on the image hit
                if SLAB or (GENERAL and (on & S_SLAB) != 0):
                    for i in range(n - 1):
                        nu[i] = 0.0
                    nu[n - 1] = 1.0 if p == 0 else -1.0
                elif PERIODIC or (GENERAL and (on & S_PERIODIC) != 0):
                    for i in range(n):
                        loc[i] = a[i] - off[i]
                    contact_normal(codes[p], params, p, loc, nu, n)
                    if on & S_SNAP:
                        snap(codes[p], params, p, loc, nu, n)
                        for i in range(n):
                            a[i] = loc[i] + off[i]
                else:
                    contact_normal(codes[p], params, p, a, nu, n)
                    if on & S_SNAP:
                        snap(codes[p], params, p, a, nu, n)
                # 4. rule
                w = prim_wall[p]
                if (TREE or (GENERAL and (on & S_TREE) != 0)) and shared:
                    second, third = False, False    # two selects each, not a branch on a coin
                    if hemi:                    # the second leaf: smooth (on a 3D slab, ν = ±e_z: one row of A)
                        second = hemisphere_step(r0, w, nu, Aj, th, rules.axis, rules.phase, n,
                                                 ROUND_HEMI or (GENERAL and (on & S_ROUND_HEMI) != 0),
                                                 2 if N == 3 and (SLAB or (GENERAL and (on & S_SLAB) != 0)) else -1) == 1
                    else:                       # rules.random_step: the thresholds the draw reaches
                        m53 = draw53(key, d)
                        second = m53 >= pick_t0
                        if pick_t1 != NEVER:    # a choice of three
                            third = m53 >= pick_t1
                        d += 1
                    node = pick_c1 if second else pick_c0
                    rk = pick_r1 if second else pick_r0
                    node = pick_c2 if third else node
                    rk = pick_r2 if third else rk
                else:
                    if TREE or (GENERAL and (on & S_TREE) != 0):
                        node, d = choose(w, nu, Aj, th, key, d, rules.root, rules.kind, rules.first, rules.nchild,
                                         rules.children, rules.threshold, rules.axis, rules.phase, n,
                                         ROUND_HEMI or (GENERAL and (on & S_ROUND_HEMI) != 0))
                    else:
                        node = rules.root[w]
                    rk = rules.rank[node]
                if EXIT_ or (GENERAL and (on & S_EXIT) != 0):
                    if rules.kind[node] == EXIT:          # a hole: the contact is the trajectory's last record
                        if TANGENT or (GENERAL and (on & S_TANGENT) != 0):
                            since = last_flight(Yj, tangent.sums, prod, j, since, tau, Ts, Wj, R, kappa, n)
                        c += 1
                        if on & S_RECORD:
                            until_record -= 1
                            if until_record == 0:
                                write_record(j, count, settings.mask, t, a, v, Wj, th, Aj, w, rk, out, n)
                                count += 1
                        state.alive[j] = False
                        break
                if TANGENT or (GENERAL and (on & S_TANGENT) != 0):
                    # the state before the map, and the normal's derivative at the contact
                    state_before(Ts, v, Wj, n)
                    curved = False              # a flat wall: J = 0, not read
                    if not (SLAB or (GENERAL and (on & S_SLAB) != 0)):
                        code = codes[p]
                        if code != HALFSPACE and code != SEGMENT:
                            curved = True
                            if PERIODIC or (GENERAL and (on & S_PERIODIC) != 0):
                                normal_jacobian(code, params, p, loc, Jn, n)
                            else:
                                normal_jacobian(code, params, p, a, Jn, n)
                # 5. collision map
                # Without spin arithmetic (a specular-only scene) the map is called with rank 0, a constant: only its
                # reflection is compiled. Every renorm_every-th rough collision, the factor onto the initial energy is
                # taken from the state before the map and applied after it: the map keeps the energy to an ulp, and
                # computing the factor beside the map keeps it off the chain of operations that sets the speed.
                f = 0.0
                map_rank = 0
                if SPIN or (GENERAL and (on & S_SPIN) != 0):
                    map_rank = rk
                    if renorm_every > 0:
                        until_renorm -= 1
                        if until_renorm == 0:
                            until_renorm = renorm_every
                            f = energy_factor(v, Wj, R, kappa, e0, half_inv_e0, n)
                elif renorm_every > 0 and not (SLAB or (GENERAL and (on & S_SLAB) != 0)):
                    # every wall specular: the speed alone is put back, the spin kept. A reflection off a wall of
                    # normal ±e_i negates one component and keeps |v| exactly (a slab's: not projected); off a
                    # curved or slanted wall it does not. The factor is the state's before the map, applied after
                    # it, as above
                    until_renorm -= 1
                    if until_renorm == 0:
                        until_renorm = renorm_every
                        f = speed_factor(v, Wj, R, kappa, e0, n)
                # a flat wall of normal ±e_i (a slab's, a box's side, an axis-aligned segment) takes the map with ν's
                # zeros left out, one call per axis so that i is a constant in each; the same numbers as collide
                # (tests/test_physics.py)
                if SLAB or (GENERAL and (on & S_SLAB) != 0):
                    collide_axis(v, Wj, n - 1, nu[n - 1], R, kappa, map_rank, rules.basis, node, w, work, n, blend)
                else:
                    ax = table.axis[p]
                    if ax == 0:
                        collide_axis(v, Wj, 0, nu[0], R, kappa, map_rank, rules.basis, node, w, work, n, blend)
                    elif ax == 1:
                        collide_axis(v, Wj, 1, nu[1], R, kappa, map_rank, rules.basis, node, w, work, n, blend)
                    elif N == 3 and ax == 2:
                        collide_axis(v, Wj, 2, nu[2], R, kappa, map_rank, rules.basis, node, w, work, n, blend)
                    else:
                        collide(v, Wj, nu, R, kappa, map_rank, rules.basis, node, w, work, n, blend)
                if f != 0.0:
                    if SPIN or (GENERAL and (on & S_SPIN) != 0):
                        scale_state(v, Wj, f, n)
                    else:
                        for i in range(n):
                            v[i] *= f
                if TANGENT or (GENERAL and (on & S_TANGENT) != 0):
                    state_after(Ts, v, Wj, nu, map_rank, rules.basis, node, w, n)
                    if GENERAL:
                        g = step(Yj, tau, True, Ts, curved, R, kappa, map_rank, n)
                    else:
                        g = step_inline(Yj, tau, True, Ts, curved, R, kappa, map_rank, n)
                    if period > 0:
                        since += 1
                        if since == period or g > tangent.grow:
                            since = 0
                            orthonormalise(Yj, tangent.sums, prod, j, n)
                c += 1
                # 6. record
                if on & S_RECORD:
                    until_record -= 1
                    if until_record == 0:
                        until_record = every
                        write_record(j, count, settings.mask, t, a, v, Wj, th, Aj, w, rk, out, n)
                        count += 1
                if w == stop_at:
                    state.alive[j] = False
                    break
            if TANGENT or (GENERAL and (on & S_TANGENT) != 0):
                if since > 0:                  # the stretches up to the last collision, before the next call
                    orthonormalise(Yj, tangent.sums, prod, j, n)
                fold(tangent.sums, prod, j, Yj.shape[0])
            for i in range(n):
                state.pos[j, i] = a[i]
                state.vel[j, i] = v[i]
                for k in range(n):
                    state.W[j, i, k] = Wj[i, k]
            if ORIENT or (GENERAL and (on & S_ORIENT) != 0):
                for i in range(3):
                    for k in range(3):
                        state.A[j, i, k] = Aj[i, k]
            state.theta[j] = th
            state.time[j] = t
            state.ncoll[j] = c
            state.draws[j] = d
            state.last_wall[j] = w
            state.last_rank[j] = rk
            nrec[j] = count

    return jit_loop(_calling(advance_all) if GENERAL else advance_all)


#: the helpers the general loop calls where a specialised loop inlines them (:func:`_calling`)
CALLED_IN_GENERAL = ("slab_collision", "periodic_flight", "box_collision", "rotate", "contact_normal", "snap",
                     "choose", "normal_jacobian", "energy_factor", "speed_factor", "collide_axis", "collide",
                     "scale_state", "write_record")
_TWINS = {}


def _calling(loop):
    """``loop`` (the Python function of the general loop) with each helper of :data:`CALLED_IN_GENERAL` called, not
    inlined: a function of the same code whose globals name, for each of them, a twin compiled on its own
    (:data:`rbx._jit.jit_call`, no runtime, on disk too).

    Why: Numba inlines a ``jit_hot`` helper into its caller's intermediate code at each call site, and the general
    loop, which keeps every branch, holds a dozen of them, some several times (the collision map once per axis):
    its compile grew with that code in Numba's own passes, not LLVM's: 50 s in 2D, 62 s in 3D (measured side by side
    on a cold cache), 28 s and 32 s with them called. Called, each helper is compiled once. The arithmetic is the
    same: the same operations in the same order, without fast-math (LLVM may still inline a twin, which changes no
    result); tests/test_kernels.py compares the general loop with the
    specialised ones bit for bit. The specialised loops keep the helpers inlined: there a constant argument (the
    axis, the dimension) prunes their branches before Numba types them, and the call would cost per collision."""
    names = dict(loop.__globals__)
    for name in CALLED_IN_GENERAL:
        helper = names[name]
        if helper not in _TWINS:
            _TWINS[helper] = jit_call(helper.py_func)
        names[name] = _TWINS[helper]
    return types.FunctionType(loop.__code__, names, loop.__name__, loop.__defaults__, loop.__closure__)



_POOL = [None, 0]           # a thread pool and its size, made on first use


def _pool(threads):
    if _POOL[1] != threads:
        if _POOL[0] is not None:
            _POOL[0].shutdown()
        _POOL[0], _POOL[1] = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="rbx"), threads
    return _POOL[0]


#: (spec, fingerprint of the arguments' types) -> the compiled entry point of the spec's kernel for them
_ENTRY = {}


def _entry_point(stop, spec, groups, nrec):
    """The compiled entry point of :func:`kernel` ``(spec)`` for these arguments (compiled or loaded on first use).

    ``numba.typeof`` of the groups' 34 arrays takes ~0.2 ms, 2–3 % of a block of the rough strip, so the entry
    point is remembered under Numba's own fingerprint of the arguments' types (the key of its dispatcher's type
    cache: class and field names, dtypes, dimensions, layouts, writability; ~3 µs). Both are private parts of
    Numba (:mod:`rbx._numba_hooks`); without them, the dispatcher is called (the same numbers)."""
    found = hooks.fingerprint((stop, groups, nrec))
    key = None if found is None else (spec, found)
    entry = _ENTRY.get(key)
    if entry is None:
        loop = kernel(spec)
        args = (0, 0, stop) + tuple(groups) + (nrec,)     # j0 = j1 = 0: a call that runs nothing
        with compile_lock(f"advance-{spec}"):
            entry = hooks.entry_point(loop, args)
        if key is not None:
            _ENTRY[key] = entry
    return entry


def run_advance_all(stop, table, rules, settings, state, out, tangent=NO_TANGENT):
    """Advance every live trajectory j to ``stop[j]`` collisions on ``numba.get_num_threads()`` threads -> records
    written per trajectory (M,).

    ``table``, ``rules``, ``settings``, ``state``, ``out``: :class:`Table`, :class:`Rules`, :class:`Settings`,
    :class:`State` (M trajectories), :class:`Records`. The compiled bits ``compiled_spec(settings.flags)``
    select the specialisation.

    The trajectories are cut into slices (8 per thread, so that slices of short trajectories even out), each run
    by the compiled entry point of the specialisation on a thread of a pool; the kernel releases the GIL. Why not
    ``prange``: a parallel kernel takes ~15 s to compile against ~5 s for a serial one, for every combination of
    compiled bits in use. Why the entry point (:func:`_entry_point`): a call through the dispatcher types the 34
    arrays of the groups (~0.2 ms); a call through the entry point, groups built, costs ~12 µs in all
    (``Simulation.advance`` with nothing to do). The first call of a specialisation goes through the dispatcher
    (which compiles it or loads it from the cache). Each trajectory's numbers depend only on its own state and
    stream, never on the slicing or the thread count."""
    M = state.pos.shape[0]
    spec = compiled_spec(settings.flags)
    nrec = np.zeros(M, np.int64)
    groups = (table, rules, settings, state, out, tangent)
    entry = _entry_point(stop, spec, groups, nrec)
    # on the pool even for one slice: the calling thread waits for it, and so a signal reaches that thread (run on
    # it, a kernel of one trajectory kept SIGINT and SIGTERM off until its segment ended: minutes in rbx lyapunov)
    threads = max(1, numba.get_num_threads())
    cuts = np.linspace(0, M, max(1, min(M, 8 * threads)) + 1).astype(np.int64)
    run_slices(threads, entry, cuts, stop, *groups, nrec)
    return nrec


def run_slices(threads, function, cuts, *args):
    """``function(a, b, *args)`` for each slice a:b of ``cuts`` on the shared pool of ``threads`` threads; returns
    when all are done (the engine's blocks, :mod:`rbx.dynamics`'s tangent segments). Interrupted while waiting
    (Ctrl-C in a notebook, an error in one slice): the slices not started are cancelled and the exception passes
    on at once; those running finish on their own (a kernel cannot be stopped), so nobody waits for them."""
    jobs = [_pool(threads).submit(function, int(a), int(b), *args) for a, b in zip(cuts[:-1], cuts[1:]) if b > a]
    try:
        for job in jobs:
            job.result()
    except BaseException:
        for job in jobs:
            job.cancel()
        raise
