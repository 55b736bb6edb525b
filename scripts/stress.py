"""Stress cases (docs/reference.md §2, §7): grazing flights, exact corner hits, wedge escapes and bounces near the
vertex, tiny and huge scales, a ball that barely fits, κ → 0 and κ = 1, far positions in the strip, extreme speeds and a
10⁹-collision run. Writes docs/stress.md: for each case what it does to the error metrics, and what breaks.

    python scripts/stress.py [--quick] [--out docs/stress.md] [--long N]

Each case is one trajectory run by the engine with every field recorded, then checked:

* **table**: the smallest clearance of the recorded centres (and, in non-convex tables, of points along each
  flight) inside the shrunk table, over the table's size L: below −1e-12 the ball has left the table;
* **wall**: the largest distance of a collision point from the wall it names, over L: above 1e-12 a wall was
  missed or a collision invented;
* **energy**: the largest |E − E₀|/E₀ over the records: above 1e-12 the energy is not kept;
* **reversal**: N collisions forward, v and ω reversed, N back, carried on to the forward run's total time:
  distance from the start over max(L, |a|) (reported, not judged: chaotic orbits amplify any rounding);
* **precise**: walls and states of the first collisions against the same orbit at 50 digits (rbx/precise.py);
* **compare**: for cases that are an exact transformation of another (a scaled table, a scaled speed, a shift
  along the strip), the largest difference from the transformed reference run, relative;
* **escape**: whether the trajectory ended because no wall lies ahead (docs/conventions.md, "Escapes"), and
  what the case expects.

A case whose checks fail is reported as BROKEN with what was expected; nothing is fixed here.
"""
import argparse
import copy
import math
import os
import sys
import time
from dataclasses import dataclass, field

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from accuracy import apply_variant, fmt, machine, source_state  # noqa: E402

from rbx import config  # noqa: E402
from rbx.geometry import CONCAVE_ARC, CONVEX_ARC, HALFSPACE, SEGMENT  # noqa: E402
from rbx.model import RECORD_FIELDS  # noqa: E402
from rbx.simulation import MemorySink, Simulation  # noqa: E402

ALL = RECORD_FIELDS
TOL = 1e-12          # table and wall checks, relative to the table's size
ENERGY_TOL = 1e-12   # energy drift allowed over a case
ROUGH2 = {"default": {"rule": "constant", "rank": 1}}
ROUGH3 = {"default": {"rule": "constant", "rank": 2}}
SMOOTH = {"default": {"rule": "constant", "rank": 0}}
L_SHAPE = [[0, 0], [2, 0], [2, 2], [1, 2], [1, 1], [0, 1]]
COMPENSATED = {"compensated": True}       # variants on top of the engine's defaults (scripts/accuracy.py)
SNAP = {"snap": True}


def cfg(table, position, velocity, spin=None, boundary=None, radius=0.1, inertia="uniform"):
    n = len(position)
    if spin is None:
        spin = 0.0 if n == 2 else [0.0, 0.0, 0.0]
    return {"table": table, "boundary": boundary or (ROUGH2 if n == 2 else ROUGH3),
            "ball": {"radius": radius, "inertia": inertia},
            "initial": {"position": position, "velocity": velocity, "angular_velocity": spin},
            "run": {"collisions": 1, "seed": 1}}


@dataclass
class Case:
    group: str
    name: str
    config: dict
    N: int
    quick_N: int = None
    expect_escape: object = False      # True, False, or None (either is documented behaviour)
    max_collisions: int = None         # an escape must come within this many collisions
    walls: tuple = None                # expected walls of the first collisions (corners)
    same_time: int = 0                 # that many first collisions happen at the same time (a corner)
    precise: int = 30                  # compare this many first collisions with the 50-digit loop (0: no)
    precise_tol: float = 1e-9
    reverse: bool = True
    compare: tuple = None              # (reference config, position factor, velocity factor, time factor, shift)
    compare_tol: float = 1e-9
    compare_first: int = None          # compare only the first collisions (chaotic scenes)
    compare_absolute: bool = False     # position differences over L, not over max(L, |a|)
    corner_order_ok: bool = False      # a corner taken in another order than exactly is a remark, not a break
    variant: dict = field(default_factory=dict)
    note: str = ""

    def n(self, quick):
        return (self.quick_N or min(self.N, 200)) if quick else self.N


# -- the cases ----------------------------------------------------------------------------------------------------


def scaled(c, s, speed=1.0):
    """A copy of config c with every length × s and every speed × speed (spins × speed/s)."""
    c = copy.deepcopy(c)
    t = c["table"]
    for k in ("width", "height", "radius", "gap"):
        if k in t:
            t[k] = t[k] * s
    if "vertices" in t:
        t["vertices"] = [[x * s for x in p] for p in t["vertices"]]
    if "size" in t:
        t["size"] = [x * s for x in t["size"]]
    c["ball"]["radius"] *= s
    ini = c["initial"]
    ini["position"] = [x * s for x in ini["position"]]
    ini["velocity"] = [x * speed for x in ini["velocity"]]
    w = ini.get("angular_velocity", 0.0)
    ini["angular_velocity"] = [x * speed / s for x in w] if isinstance(w, list) else w * speed / s
    return c


BASE = {
    "strip": cfg({"kind": "strip", "width": 1.0}, [0, 0.5], [0.6, 0.8], 1.5),
    "circle": cfg({"kind": "circle", "radius": 1.0}, [0.1, -0.2], [-0.3, 0.9], -2.0),
    "L-polygon": cfg({"kind": "polygon", "vertices": L_SHAPE}, [0.5, 0.5], [0.83, 0.31], 0.7),
    "box": cfg({"kind": "box", "size": [1.0, 1.3, 0.8]}, [0.5, 0.5, 0.4], [0.3, -0.5, 0.6], [0.4, 0.1, -0.9]),
    "plates": cfg({"kind": "plates", "gap": 1.0}, [0, 0, 0.5], [0.2, -0.4, 0.7], [1.0, 0.5, -0.3]),
}


def wedge_start(phi_deg, R=0.1, dist=2.0, toward=0.3):
    """A start on the bisector at ``dist`` from the vertex, moving towards the vertex turned by ``toward`` rad."""
    b = math.radians(phi_deg) / 2
    pos = [dist * math.cos(b), dist * math.sin(b)]
    ang = b + math.pi + toward * b
    return pos, [math.cos(ang), math.sin(ang)]


def cases():
    out = []
    add = out.append
    # ---- grazing flights
    for e in (1e-3, 1e-6, 1e-9, 1e-12, 1e-15):
        add(Case("grazing", f"strip v·ν = {e:g}|v|", cfg({"kind": "strip", "width": 1.0}, [0, 0.5], [1.0, e], 0.5),
                 10_000, 200, note="|v_y| never changes in the strip: flights of length ~1/ε, x grows to ~N/ε"))
    for e in (1e-6, 1e-12, 1e-15):
        add(Case("grazing", f"plates v·ν = {e:g}|v|", cfg({"kind": "plates", "gap": 1.0}, [0, 0, 0.5],
                                                         [0.6, 0.8, e], [0.3, -0.2, 0.1]), 10_000, 200))
    for e in (1e-4, 1e-6, 1e-8):
        rho = 0.9
        h = rho * math.sqrt(1 - e * e)
        add(Case("grazing", f"circle v·ν = {e:g}|v| (whispering gallery)",
                 cfg({"kind": "circle", "radius": 1.0}, [0.0, -h], [1.0, 0.0], 0.0, boundary=SMOOTH),
                 10_000, 200, precise_tol=1e-14 / e,
                 note="specular: the chord turns by 2ε per collision. The chord's distance from the centre is "
                      "known to an ulp, so the angle only to ~1e-16/ε: the precise check allows 1e-14/ε"))
        add(Case("grazing", f"circle v·ν = {e:g}|v|, rough",
                 cfg({"kind": "circle", "radius": 1.0}, [0.0, -h], [1.0, 0.0], 1.0 / 0.1), 10_000, 200,
                 precise_tol=1e-14 / e, note="rolling without slip at the start (ω = |v|/R): the first collisions change nothing"))
    h = 0.9 * math.sqrt(1 - 1e-16)
    for vname, variant in (("snap", SNAP), ("compensated", COMPENSATED)):
        add(Case("grazing", f"circle v·ν = 1e-08|v| (whispering gallery), {vname}",
                 cfg({"kind": "circle", "radius": 1.0}, [0.0, -h], [1.0, 0.0], 0.0, boundary=SMOOTH), 10_000, 200,
                 precise_tol=1e-6, variant=variant, note=f"the case above with the `{vname}` variant"))
    add(Case("grazing", "rectangle: flight along the bottom wall (v·ν = 0), into the corners",
             cfg({"kind": "rectangle", "width": 2.0, "height": 1.0}, [0.5, 0.125], [1.0, 0.0], 0.0, radius=0.125),
             1000, 50, walls=(1, 3, 1, 3), note="never touches the bottom (grazing rule); each end is a corner"))
    for e in (1e-9, 1e-15):
        add(Case("grazing", f"rectangle v·ν = {e:g}|v| along the bottom",
                 cfg({"kind": "rectangle", "width": 2.0, "height": 1.0}, [0.5, 0.125 + 1e-6], [1.0, -e], 0.0,
                     radius=0.125), 10_000, 200))
    add(Case("grazing", "box v·ν = 1e-15|v|", cfg({"kind": "box", "size": [1.0, 1.3, 0.8]}, [0.5, 0.5, 0.4],
                                                  [0.6, 0.8, 1e-15], [0.2, 0.1, 0.0]), 10_000, 200))
    # ---- exact corner hits (dyadic data: every number below is exact in binary)
    rect = {"kind": "rectangle", "width": 2.0, "height": 1.0}
    add(Case("corner", "rectangle corner (1.875, 0.875), rough",
             cfg(rect, [0.5, 0.5], [1.375, 0.375], 0.0, radius=0.125), 1000, 100, walls=(1, 2), same_time=2,
             note="ties go to the lower wall index: right, then top at flight time 0"))
    add(Case("corner", "rectangle corner (1.875, 0.875), specular",
             cfg(rect, [0.5, 0.5], [1.375, 0.375], 0.0, boundary=SMOOTH, radius=0.125), 1000, 100, walls=(1, 2),
             same_time=2, note="the velocity is reversed: the ball flies back along its path"))
    add(Case("corner", "rectangle: start in the corner (0.125, 0.125) moving into both walls",
             cfg(rect, [0.125, 0.125], [-1.0, -0.5], 2.0, radius=0.125), 1000, 100, walls=(0, 3), same_time=2))
    box = {"kind": "box", "size": [1.0, 1.5, 0.75]}
    add(Case("corner", "box corner (0.875, 1.375, 0.625), three walls at once",
             cfg(box, [0.5, 0.5, 0.375], [0.375, 0.875, 0.25], [0.5, -1.0, 2.0], radius=0.125), 1000, 100,
             walls=(1, 3), same_time=2, note="rough: after the right and back walls v_z may point away from the "
                                             "top wall (then it is not hit)"))
    add(Case("corner", "box corner, specular", cfg(box, [0.5, 0.5, 0.375], [0.375, 0.875, 0.25], [0.5, -1.0, 2.0],
                                                   boundary=SMOOTH, radius=0.125), 1000, 100, walls=(1, 3, 5),
             same_time=3, corner_order_ok=True,
             note="the reversed flight reaches a second corner that float64 sees as two nearly equal times"))
    add(Case("corner", "box edge x = 0.875, y = 1.375",
             cfg(box, [0.5, 0.5, 0.375], [0.375, 0.875, 0.0625], [0.5, -1.0, 2.0], radius=0.125), 1000, 100,
             walls=(1, 3), same_time=2))
    L = {"kind": "polygon", "vertices": L_SHAPE}
    add(Case("corner", "L-polygon convex corner (1.875, 0.125)",
             cfg(L, [0.5, 0.5], [1.375, -0.375], 0.5, radius=0.125), 1000, 100, walls=(0, 1), same_time=2))
    add(Case("corner", "L-polygon: junction of edge 4 and the reflex arc at (1, 0.875)",
             cfg(L, [0.5, 0.5], [0.5, 0.375], 0.5, radius=0.125), 1000, 100, walls=(4,)))
    add(Case("corner", "L-polygon: flight tangent to the reflex arc (along edge 4's offset line)",
             cfg(L, [0.5, 0.875], [1.0, 0.0], 0.0, radius=0.125), 1000, 100, walls=(1, 5),
             note="parallel to edge 4 and tangent to the arc around (1, 1): touches neither (grazing rule)"))
    add(Case("corner", "L-polygon: aimed at the reflex vertex (1, 1)",
             cfg(L, [0.5, 0.5], [0.5, 0.5], 0.5, radius=0.125), 1000, 100, walls=(4,),
             note="the arc's normal at the hit point is (−1, −1)/√2: wall edge4 (it owns the arc)"))
    # ---- wedges
    for phi in (10, 45, 60, 90, 135, 170):
        pos, vel = wedge_start(phi)
        add(Case("wedge", f"wedge {phi}°, specular", cfg({"kind": "wedge", "angle_deg": phi}, pos, vel, 0.0,
                                                        boundary=SMOOTH), 1000, 100, expect_escape=True,
                 max_collisions=math.ceil(180 / phi), note=f"a point billiard escapes after ≤ ⌈180/φ⌉ = "
                                                           f"{math.ceil(180 / phi)} collisions"))
        add(Case("wedge", f"wedge {phi}°, rough", cfg({"kind": "wedge", "angle_deg": phi}, pos, vel, 0.0),
                 10_000, 200, expect_escape=None))
    for phi in (60, 90):
        b = math.radians(phi) / 2
        apex = 0.125 / math.sin(b)
        pos = [(apex + 1.0) * math.cos(b), (apex + 1.0) * math.sin(b)]
        add(Case("wedge", f"wedge {phi}°: aimed at the vertex, rough",
                 cfg({"kind": "wedge", "angle_deg": phi}, pos, [-math.cos(b), -math.sin(b)], 0.0, radius=0.125),
                 1000, 100, expect_escape=None, same_time=2, corner_order_ok=True,
                 note="the aim and the wall directions are rounded: which wall comes first is decided by rounding, "
                      "and for a rough ball the order matters"))
    # the bounded orbits of the paper's figure `periodic` (configs/experiments/periodic/), then the same orbits
    # shrunk towards the vertex of the shrunk wedge: flights are straight and the collision map does not depend on
    # the position, so the orbit scaled by s about that vertex is an orbit, with times × s
    for phi, pos, vel, w in ((60, [1.2, 0.5], [-0.5, 0.866], -3.0), (90, [1.0, 0.3], [-0.866, 0.5], -6.0)):
        base = cfg({"kind": "wedge", "angle_deg": phi}, pos, vel, w)
        add(Case("wedge", f"wedge {phi}°: bounded orbit of the paper, rough", base, 100_000, 200,
                 note="bounded: never escapes"))
        b = math.radians(phi) / 2
        apex = np.array([math.cos(b), math.sin(b)]) * 0.1 / math.sin(b)
        for s in (1e-6, 1e-12):
            c = copy.deepcopy(base)
            c["initial"]["position"] = list(apex + s * (np.array(pos) - apex))
            add(Case("wedge", f"wedge {phi}°: that orbit shrunk by {s:g} towards the vertex", c, 100_000, 200,
                     compare=(base, s, 1.0, s, list(apex * (1 - s))), compare_absolute=True, compare_first=1000,
                     compare_tol=1e3 * 2.2e-16 * float(np.linalg.norm(apex)) / s,
                     note=f"bounces within ~{s:g} of the vertex; compare: against the unshrunk orbit over its first "
                          f"1000 collisions, positions over s (rounding of the positions alone is ~ulp(|apex|)/s = "
                          f"{2.2e-16 * float(np.linalg.norm(apex)) / s:.1g}; allowed 1000 times that)"))
    # ---- tiny and huge scales
    for name in ("strip", "circle", "L-polygon", "box"):
        for s in (1e-9, 1e6):
            add(Case("scale", f"{name} × {s:g}", scaled(BASE[name], s), 10_000, 200,
                     compare=(BASE[name], s, 1.0, s, [0.0] * len(BASE[name]["initial"]["position"])), compare_first=40 if name in ("L-polygon", "box") else None,
                     note="lengths × s, spins × 1/s: the same orbit, lengths and times × s"))
    # ---- a ball that barely fits
    for d in (1e-6, 1e-9, 1e-12):
        R = 0.1
        add(Case("fits", f"strip width 2R(1 + {d:g})",
                 cfg({"kind": "strip", "width": 2 * R * (1 + d)}, [0.0, R * (1 + d)], [0.6, 0.8], 1.5), 10_000, 200))
        add(Case("fits", f"circle radius R(1 + {d:g})",
                 cfg({"kind": "circle", "radius": R * (1 + d)}, [0.0, 0.0], [0.6, 0.8], 1.5), 10_000, 200))
        add(Case("fits", f"rectangle height 2R(1 + {d:g}) (a corridor)",
                 cfg({"kind": "rectangle", "width": 2.0, "height": 2 * R * (1 + d)}, [1.0, R * (1 + d)],
                     [0.6, 0.8], 1.5), 10_000, 200))
        add(Case("fits", f"L-polygon, R = ½(1 − {d:g}) in arms of width 1",
                 cfg({"kind": "polygon", "vertices": L_SHAPE}, [1.5, 1.0], [0.6, 0.8], 1.5, radius=0.5 * (1 - d)),
                 10_000, 200))
        add(Case("fits", f"box height 2R(1 + {d:g})",
                 cfg({"kind": "box", "size": [1.0, 1.3, 2 * R * (1 + d)]}, [0.5, 0.5, R * (1 + d)],
                     [0.3, -0.5, 0.6], [0.4, 0.1, -0.9]), 10_000, 200))
    # ---- κ → 0 and κ = 1
    for k in (1e-3, 1e-8, 1e-16, 1e-300, 1e-320, 1.0):
        for name in ("strip", "circle", "box"):
            c = copy.deepcopy(BASE[name])
            c["ball"]["inertia"] = k
            add(Case("kappa", f"{name}, κ = {k:.0e}" if k < 1 else f"{name}, κ = 1", c, 10_000, 200,
                     note="subnormal κ" if k < 2.3e-308 else ""))
    # ---- far along the strip, extreme speeds
    for x0 in (1e6, 1e12):
        c = copy.deepcopy(BASE["strip"])
        c["initial"]["position"] = [x0, 0.5]
        ulp = float(np.spacing(x0))
        for N, quick_N in ((10_000, 200),):
            add(Case("far", f"strip from x = {x0:g}", c, N, quick_N, compare=(BASE["strip"], 1.0, 1.0, 1.0, [x0, 0.0]),
                     compare_absolute=True, compare_tol=N * ulp, precise=0,
                     note=f"translation invariant: compare = max |x − x₀ − x_ref| (the run from x = 0), in units "
                          f"of the width; ulp(x₀) = {ulp:.2g}, allowed N·ulp(x₀)"))
        add(Case("far", f"strip from x = {x0:g}, compensated", c, 10_000, 200,
                 compare=(BASE["strip"], 1.0, 1.0, 1.0, [x0, 0.0]), compare_absolute=True, compare_tol=10_000 * ulp,
                 precise=0, variant=COMPENSATED, note="compensated summation of the position and the time"))
        c = copy.deepcopy(BASE["plates"])
        c["initial"]["position"] = [x0, x0, 0.5]
        add(Case("far", f"plates from x = y = {x0:g}", c, 10_000, 200,
                 compare=(BASE["plates"], 1.0, 1.0, 1.0, [x0, x0, 0.0]), compare_absolute=True,
                 compare_tol=10_000 * ulp, precise=0, note="as the strip, in x and y"))
    for name in ("strip", "circle", "L-polygon", "box"):
        for s in (1e-100, 1e100, 1e-150, 1e150):
            add(Case("speed", f"{name}, speed × {s:g}", scaled(BASE[name], 1.0, s), 10_000, 200,
                     compare=(BASE[name], 1.0, s, 1.0 / s, [0.0] * len(BASE[name]["initial"]["position"])),
                     compare_first=40 if name in ("L-polygon", "box") else None,
                     note="the same orbit, times × 1/s"))
    return out


# -- running and checking -----------------------------------------------------------------------------------------


def make(c, N, record=ALL):
    c = copy.deepcopy(c)
    c["run"]["collisions"] = int(N)
    c["output"] = {"record": list(record)}
    return config.from_dict(c)


def variant_available(variant):
    if not variant:
        return True
    numerics = make(BASE["strip"], 1, record=()).numerics
    return all(hasattr(numerics, a) for a in variant)


def run_records(c, N, variant=None):
    """-> (Config, records of trajectory 0 trimmed to its count, final state, alive)."""
    cf = make(c, N)
    sim = Simulation(apply_variant(cf, variant or {}))
    sink = MemorySink()
    sim.run(sink)
    k = int(sink.count[0])
    rec = {f: v[0, :k] for f, v in sink.records.items()}
    return cf, rec, {f: np.asarray(v)[0] for f, v in sink.final.items()}, bool(sim.alive[0])


def wall_distance(geom, wall, pts):
    """Distance of centre positions from the primitives of one wall of the shrunk table (the nearest)."""
    best = np.full(len(pts), np.inf)
    n = geom.dimension
    for code, w, row in zip(geom.codes, geom.walls, geom.params):
        if w != wall:
            continue
        if code in (HALFSPACE, SEGMENT):
            d = np.abs((pts - row[:n]) @ row[4:4 + n])
            if code == SEGMENT:
                s = (pts - row[:2]) @ row[8:10]
                d = np.hypot(d, np.maximum(0, np.maximum(-s, s - row[12])))
        else:
            d = np.abs(np.linalg.norm(pts - row[:n], axis=1) - row[12])
            if code == CONVEX_ARC:
                m = pts - row[:2]
                fan = (row[4] * m[:, 1] - row[5] * m[:, 0] >= -1e-9 * row[12]) & \
                      (m[:, 0] * row[9] - m[:, 1] * row[8] >= -1e-9 * row[12])
                d = np.where(fan, d, np.inf)
        best = np.minimum(best, d)
    return best


def energies(cf, rec):
    kap, R = cf.ball.kappa, cf.ball.radius
    v = rec["velocity"]
    w = rec["angular_velocity"]
    with np.errstate(all="ignore"):
        rot = w * w if w.ndim == 1 else np.sum(w * w, axis=1)
        return 0.5 * np.sum(v * v, axis=1) + 0.5 * kap * R * R * rot


def reversal(c, N, final, variant=None):
    """Distance from the start after N forward, reverse, N back (relative to max(L, |a|)), or NaN."""
    cf = make(c, N, record=())
    if int(final["collisions"]) < N:
        return math.nan
    state = {"position": np.array(final["position"])[None], "velocity": -np.array(final["velocity"])[None],
             "angular_velocity": -np.array(final["angular_velocity"])[None],
             "orientation": np.array(final["orientation"])[None]}
    sim = Simulation(apply_variant(cf, variant or {}), state=state)
    sink = MemorySink()
    sim.run(sink)
    back = {f: np.asarray(v)[0] for f, v in sink.final.items()}
    if int(back["collisions"]) < N:
        return math.inf
    a0 = np.asarray(cf.initial[0]["position"], float)
    with np.errstate(all="ignore"):
        a = back["position"] + (float(final["time"]) - float(back["time"])) * back["velocity"]
        scale = max(cf.geometry().size, float(np.max(np.abs(a0))), float(np.max(np.abs(final["position"]))))
        return float(np.max(np.abs(a - a0))) / scale


def precise_check(c, rec, k, tol):
    """The first k collisions against the 50-digit loop -> (first collision where the states differ by more than
    ``tol`` (relative) or None, largest relative difference, remarks).

    Collisions at the same time (a corner) are compared as a group: the same walls, and the state after the
    group. When float64 and the exact orbit take a corner's walls in a different order (rounding decides which
    of two nearly equal flight times is smaller) that is a remark, and so is a collision at the joint of two
    primitives of different walls named after the other one; the states still have to agree."""
    from rbx.precise import PreciseBilliard
    cf = config.from_dict(c)
    loop = PreciseBilliard(cf, digits=50, orientation=False)
    L = cf.geometry().size
    n_rec = len(rec["wall"])
    states = []
    for _ in range(min(k, n_rec - 1) + 3):
        if not loop.step():
            break
        states.append((loop.wall, float(loop.time), list(loop.a), list(loop.v), loop.ctx.sqrt(2 * loop.energy())))
    remarks, worst, first_bad = [], 0.0, None
    i = 1
    m = min(k, n_rec - 1, len(states))
    if len(states) < min(k, n_rec - 1):
        first_bad = len(states) + 1
        remarks.append(f"the exact orbit escapes after {len(states)} collisions")
    while i <= m:
        t = states[i - 1][1]
        j = i
        while j < len(states) and abs(states[j][1] - t) <= 1e-12 * max(1.0, abs(t)):
            j += 1                                  # collisions i … j at the same time (1-based)
        j = min(j, n_rec - 1)
        w_exact = [states[q - 1][0] for q in range(i, j + 1)]
        w_float = [int(rec["wall"][q]) for q in range(i, j + 1)]
        if w_exact != w_float:
            if sorted(w_exact) == sorted(w_float):
                remarks.append(f"collisions {i}–{j} at one corner in the order {w_float}, exactly {w_exact}")
            else:
                remarks.append(f"collision {i}: wall {w_float} where the exact orbit names {w_exact}")
        _, _, a, v, speed = states[j - 1]
        scale_a = max(L, float(max(abs(x) for x in a)))
        da = float(max(abs(loop.num(float(x)) - q) for x, q in zip(rec["position"][j], a))) / scale_a
        dv = float(max(abs(loop.num(float(x)) - q) for x, q in zip(rec["velocity"][j], v))) / float(speed)
        worst = max(worst, da, dv)
        if not max(da, dv) <= tol:
            first_bad = j
            break
        i = j + 1
    return first_bad, worst, remarks


def compare_transformed(case, rec, N):
    """Largest relative difference from the reference run transformed (positions × f + shift (a vector),
    velocities × g, times × h) over the first collisions; inf if the walls hit differ."""
    ref_c, f, g, h, shift = case.compare
    _, ref, _, _ = run_records(ref_c, N, case.variant)
    k = min(len(ref["time"]), len(rec["time"]))
    if case.compare_first:
        k = min(k, case.compare_first + 1)
    if len(ref["time"]) != len(rec["time"]) and not case.compare_first:
        return math.inf
    with np.errstate(all="ignore"):
        pos = ref["position"][:k] * f + np.asarray(shift, float)
        L = make(ref_c, 1).geometry().size * f
        dp = np.max(np.abs(rec["position"][:k] - pos)) / (L if case.compare_absolute else max(L, np.max(np.abs(pos))))
        dv = np.max(np.abs(rec["velocity"][:k] - ref["velocity"][:k] * g)) / (np.max(np.abs(ref["velocity"])) * g)
        dt = np.max(np.abs(rec["time"][:k] - ref["time"][:k] * h)) / max(float(np.max(ref["time"][:k] * h)), 1e-300)
        walls = np.array_equal(rec["wall"][:k], ref["wall"][:k])
    return float(max(dp, dv, dt)) if walls else math.inf


def check_case(case, quick=False):
    """Run a case -> dict of metrics and ``problems`` (what broke, against what was expected)."""
    N = case.n(quick)
    res = {"group": case.group, "name": case.name, "N": N, "problems": [], "remarks": [], "note": case.note,
           "config": case.config, "variant": case.variant}
    if not variant_available(case.variant):
        res["remarks"].append("variant not available in this engine: not run")
        res["skipped"] = True
        return res
    t0 = time.perf_counter()
    try:
        cf, rec, final, alive = run_records(case.config, N, case.variant)
    except Exception as exc:   # noqa: BLE001 - a stress case reports whatever breaks
        res["problems"].append(f"raised {type(exc).__name__}: {exc}")
        res["seconds"] = time.perf_counter() - t0
        return res
    res["seconds"] = time.perf_counter() - t0
    geom = cf.geometry()
    L = geom.size
    pos, wall = rec["position"], rec["wall"]
    made = len(wall) - 1
    res["collisions"] = made
    res["escaped"] = not alive
    finite = all(np.all(np.isfinite(rec[f])) for f in ("time", "position", "velocity", "angular_velocity"))
    if not finite:
        bad = min(int(np.argmax(~np.isfinite(rec[f]).reshape(len(wall), -1).any(axis=1)))
                  for f in ("time", "position", "velocity", "angular_velocity")
                  if not np.all(np.isfinite(rec[f])))
        res["problems"].append(f"non-finite state from record {bad}")
    with np.errstate(all="ignore"):
        clear = geom.clearance(pos)
        if np.any((geom.codes == SEGMENT) | (geom.codes == CONVEX_ARC)) and made > 0:
            s = np.linspace(0, 1, 9)[1:-1]
            mids = pos[:-1, None, :] + s[None, :, None] * (pos[1:] - pos[:-1])[:, None, :]
            clear = np.concatenate([clear, geom.clearance(mids).ravel()])
        res["table"] = float(np.nanmin(clear)) / L if len(clear) else 0.0
        wd = 0.0
        for w in range(len(geom.wall_list)):
            sel = np.nonzero(wall == w)[0]
            if len(sel):
                wd = max(wd, float(np.nanmax(wall_distance(geom, w, pos[sel]))))
        res["wall"] = wd / L
        e = energies(cf, rec)
        res["energy"] = float(np.nanmax(np.abs(e - e[0]))) / e[0] if e[0] > 0 else math.nan
    if not res["table"] >= -TOL:
        res["problems"].append(f"left the shrunk table by {-res['table']:.2g}·L")
    if not res["wall"] <= TOL:
        at = "?"
        for w in range(len(geom.wall_list)):
            sel = np.nonzero(wall == w)[0]
            if len(sel):
                d = wall_distance(geom, w, pos[sel])
                if np.nanmax(d) / L > TOL:
                    at = int(sel[int(np.nanargmax(d))])
                    break
        res["problems"].append(f"collision {at} is {res['wall']:.2g}·L off the wall it names")
    if not res["energy"] <= ENERGY_TOL:
        res["problems"].append(f"energy drift {res['energy']:.2g}")
    if case.expect_escape is True and alive:
        res["problems"].append(f"expected an escape, still bouncing after {made} collisions")
    if case.expect_escape is False and not alive:
        res["problems"].append(f"ended (no wall ahead) after {made} collisions; expected to keep bouncing")
    if case.max_collisions is not None and made > case.max_collisions:
        res["problems"].append(f"{made} collisions before escaping; at most {case.max_collisions} expected")
    if case.walls is not None:
        got = tuple(int(w) for w in wall[1:1 + len(case.walls)])
        res["first_walls"] = got
        if got != tuple(case.walls):
            res["problems"].append(f"first walls {got}, expected {tuple(case.walls)}")
    if case.same_time and made >= case.same_time:
        t = rec["time"][1:1 + case.same_time]
        res["corner_dt"] = float(np.max(t) - np.min(t))
        if res["corner_dt"] > 1e-15 * max(1.0, float(t[0])):
            res["problems"].append(f"the corner's collisions are {res['corner_dt']:.2g} apart in time")
    if case.reverse and alive and made == N:
        try:
            res["reversal"] = reversal(case.config, N, final, case.variant)
        except Exception as exc:   # noqa: BLE001
            res["problems"].append(f"reversal raised {type(exc).__name__}: {exc}")
    if case.precise:
        try:
            bad, worst, remarks = precise_check(case.config, rec, case.precise, case.precise_tol)
            res["precise"] = worst
            res["remarks"] += remarks
            if bad is not None and case.corner_order_ok and remarks:
                res["remarks"].append(f"so the orbits part at collision {bad} (relative difference {worst:.2g})")
            elif bad is not None:
                res["problems"].append(f"differs from the 50-digit orbit at collision {bad} (largest relative "
                                       f"difference {worst:.2g})")
        except Exception as exc:   # noqa: BLE001
            res["problems"].append(f"precise loop raised {type(exc).__name__}: {exc}")
    if case.compare is not None:
        res["compare"] = compare_transformed(case, rec, N)
        if not res["compare"] <= case.compare_tol:
            res["problems"].append(f"differs from the transformed reference run by {res['compare']:.2g} "
                                   f"(expected ≤ {case.compare_tol:g})")
    return res


# -- the long run -------------------------------------------------------------------------------------------------


#: the long run: the rough strip, with a flight time (w − 2R)/|v_y| = 0.8/0.7 that binary cannot hold exactly
LONG = cfg({"kind": "strip", "width": 1.0}, [0.0, 0.5], [0.6, 0.7], 1.5)
LONG_VARIANTS = (("plain", {"renormalize": 0}), ("default", {}), ("renormalize/1", {"renormalize": 1}),
                 ("compensated", COMPENSATED), ("compensated, no projection", {"renormalize": 0, "compensated": True}))


def exact_strip(c, N, digits=60):
    """The exact state of a rough-strip orbit after N collisions, in closed form -> (t, x, v_x, ω) (mpf).

    In the strip the rough map reverses v_y exactly and acts on s = (v_x, ω) linearly: at the bottom wall
    (ν = (0, 1), r = (0, −R)) the slip is u = v_x + Rω and s ← (v_x − 2αu, ω − 2αu/(κR)); at the top wall
    (r = (0, R)) u = v_x − Rω and s ← (v_x − 2αu, ω + 2αu/(κR)). Every flight after the first lasts
    τ = (w − 2R)/|v_y|, so x_N = x₀ + τ₀v_x,0 + τ·Σ_{k=1}^{N−1} v_x,k, and with P the map of two collisions
    (top then bottom, or the reverse) the sum is a geometric series of 2×2 matrices: Σ P^m = (I − P)⁻¹(I − P^K)."""
    import mpmath
    mp = mpmath.mp.clone() if hasattr(mpmath.mp, "clone") else mpmath.MPContext()
    mp.dps = digits
    F = lambda x: mp.mpf(float(x))  # noqa: E731
    w, R = F(c["table"]["width"]), F(c["ball"]["radius"])
    inertia = c["ball"].get("inertia", "uniform")
    kappa = mp.mpf(1) / 2 if inertia == "uniform" else (mp.mpf(1) if inertia in ("ring", "shell") else F(inertia))
    alpha = kappa / (1 + kappa)
    x0, y0 = (F(x) for x in c["initial"]["position"])
    vx0, vy = (F(x) for x in c["initial"]["velocity"])
    s0 = mp.matrix([[vx0], [F(c["initial"].get("angular_velocity", 0.0))]])

    def wall_map(sign):   # sign −1: bottom (u = v_x + Rω), +1: top (u = v_x − Rω)
        a = 2 * alpha
        return mp.matrix([[1 - a, a * R * sign], [sign * a / (kappa * R), 1 - a * sign * sign * R / (kappa * R)]])

    bottom, top = wall_map(-1), wall_map(+1)
    first, second = (top, bottom) if vy > 0 else (bottom, top)
    tau0 = ((w - R) - y0) / vy if vy > 0 else (y0 - R) / -vy
    tau = (w - 2 * R) / abs(vy)
    P = second * first                                  # two collisions, starting with the first wall
    I = mp.eye(2)
    # s_k after k collisions: s_{2m} = P^m s0, s_{2m+1} = first·P^m s0
    K_even = (N - 1) // 2 + 1                           # k = 0, 2, …, ≤ N−1 (k = 0 removed below)
    K_odd = N // 2                                      # k = 1, 3, …, ≤ N−1
    geo = lambda K: (I - P) ** -1 * (I - P ** K)  # noqa: E731
    sum_vx = (geo(K_even) * s0)[0] - s0[0] + (first * geo(K_odd) * s0)[0]
    sN = (P ** (N // 2)) * s0 if N % 2 == 0 else first * (P ** (N // 2)) * s0
    t = tau0 + (N - 1) * tau
    x = x0 + tau0 * vx0 + tau * sum_vx
    return t, x, sN[0], sN[1]


def long_run(N, probe, log=print):
    """The rough strip (LONG) for ``N`` collisions with nothing recorded, after measuring the rate on ``probe``,
    for each variant: energy drift, the error of the time, of x and of (v_x, ω) against the exact orbit
    (:func:`exact_strip`), and the time-reversal error."""
    c = LONG
    t_ex, x_ex, vx_ex, w_ex = exact_strip(c, N)
    cf0 = make(c, 1, record=())
    s = cf0.initial[0]
    e0 = 0.5 * float(np.sum(np.square(s["velocity"]))) + 0.5 * cf0.ball.kappa * cf0.ball.radius ** 2 * float(
        s["angular_velocity"]) ** 2
    out = []
    for vname, variant in LONG_VARIANTS:
        if not variant_available(variant):
            continue
        row = {"variant": vname}
        cf = make(c, probe, record=())
        for attempt in range(2):                   # the first run compiles (or loads from the cache)
            sim = Simulation(apply_variant(cf, variant))
            t0 = time.perf_counter()
            sim.run(MemorySink())
            row["rate"] = probe / (time.perf_counter() - t0)
        log(f"  long run {vname}: {row['rate']:.3g} collisions/s on {probe:,}; {N:,} will take "
            f"~{N / row['rate']:.0f} s")
        cf = make(c, N, record=())
        sim = Simulation(apply_variant(cf, variant))
        sink = MemorySink()
        t0 = time.perf_counter()
        sim.run(sink)
        row["seconds"] = time.perf_counter() - t0
        final = {f: np.asarray(v)[0] for f, v in sink.final.items()}
        row["collisions"] = int(final["collisions"])
        e = energies(cf, {"velocity": final["velocity"][None],
                          "angular_velocity": np.atleast_1d(final["angular_velocity"])})[0]
        row["energy"] = abs(e - e0) / e0
        row["time_error"] = float(abs(t_ex.__class__(float(final["time"])) - t_ex) / t_ex)
        row["x_error"] = float(abs(x_ex.__class__(float(final["position"][0])) - x_ex))
        row["x"] = float(x_ex)
        speed = math.sqrt(2 * e0)
        row["v_error"] = max(float(abs(vx_ex.__class__(float(final["velocity"][0])) - vx_ex)),
                             cf.ball.radius * math.sqrt(cf.ball.kappa)
                             * float(abs(w_ex.__class__(float(final["angular_velocity"])) - w_ex))) / speed
        t0 = time.perf_counter()
        row["reversal"] = reversal(c, N, final, variant)
        row["reversal_seconds"] = time.perf_counter() - t0
        log(f"  long run {vname}: {N:,} collisions in {row['seconds']:.1f} s; energy {row['energy']:.2g}, time "
            f"error {row['time_error']:.2g}, x error {row['x_error']:.2g}, (v, ω) error {row['v_error']:.2g}, "
            f"reversal {row['reversal']:.2g}")
        out.append(row)
    return out


# -- the document -------------------------------------------------------------------------------------------------


GROUP_TITLES = {"grazing": "Grazing flights", "corner": "Exact corner hits", "wedge": "Wedges: escapes and the vertex",
                "scale": "Tiny and huge tables", "fits": "A ball that barely fits", "kappa": "κ → 0 and κ = 1",
                "far": "Far along the strip", "speed": "Extreme speeds"}


def _checks_text():
    doc = __doc__
    return doc[doc.index("Each case is"):doc.index("A case whose")].strip()


def write(path, results, long_rows, cmd, seconds, quick):
    lines = ["# Stress tests", "", f"Generated by `{cmd}` (`make stress`) in {seconds:.0f} s; do not edit by hand.",
             "", f"Machine: {machine()}. Code: {source_state()}.", "", _checks_text(), "",
             "Columns: N collisions asked (made, if fewer); **table** = smallest clearance/L (≥ −1e-12 passes); "
             "**wall** = largest distance of a collision from its wall/L (≤ 1e-12 passes); **energy** = largest "
             "relative drift; **reversal** = relative distance from the start after N forward and N back; "
             "**precise** = largest relative difference from the 50-digit orbit over its first collisions; "
             "**compare** = largest relative difference from the transformed reference run.", ""]
    broken = [r for r in results if r["problems"]]
    lines += ["## Summary", "", f"{len(results)} cases, {len(broken)} broken." if broken else
              f"{len(results)} cases, none broken.", ""]
    for r in broken:
        lines.append(f"- BROKEN **{r['name']}** ({r['group']}): " + "; ".join(r["problems"]) + ".")
    if broken:
        import yaml
        lines += ["", "Reproducers (run with `rbx simulate`, or `rbx.simulation.run_in_memory(rbx.config.from_dict(…))`"
                      "; a variant is set on the Simulation before `run`):", ""]
        seen = set()
        for r in broken:
            c = copy.deepcopy(r["config"])
            c["run"]["collisions"] = r["N"]
            c["output"] = {"record": ["time", "position", "velocity", "angular_velocity", "wall"]}
            text = yaml.safe_dump(c, default_flow_style=None, sort_keys=False, width=110).strip()
            if text in seen:
                continue
            seen.add(text)
            lines += [f"{r['name']}" + (f" (variant {r['variant']})" if r["variant"] else "") + ":", "", "```yaml",
                      text, "```", ""]
    if long_rows:
        lines += ["", "## A long run", "",
                  f"The rough strip (width 1, R = 0.1, κ = ½, start (0, 0.5), v = (0.6, 0.7), ω = 1.5), "
                  f"{long_rows[0]['collisions']:,} collisions, nothing recorded; the rate is measured first on a "
                  "shorter run. In the strip the exact orbit has a closed form (`exact_strip` in scripts/stress.py: "
                  "the rough map reverses v_y exactly and acts linearly on (v_x, ω), so x is a geometric series of "
                  "2×2 matrices), so the errors after all these collisions are known: **time** relative, **x** "
                  f"absolute (the exact x is {long_rows[0]['x']:.6g}), **(v_x, ω)** over the speed, **reversal** "
                  "as above.", "",
                  "| variant | rate (collisions/s) | run time (s) | energy drift | time error | x error | "
                  "(v_x, ω) error | reversal | reversal run time (s) |", "|---|---|---|---|---|---|---|---|---|"]
        for r in long_rows:
            lines.append(f"| {r['variant']} | {r['rate']:.3g} | {r['seconds']:.1f} | {fmt(r['energy'])} | "
                         f"{fmt(r['time_error'])} | {fmt(r['x_error'])} | {fmt(r['v_error'])} | "
                         f"{fmt(r['reversal'])} | {r['reversal_seconds']:.1f} |")
    for group, title in GROUP_TITLES.items():
        rows = [r for r in results if r["group"] == group]
        if not rows:
            continue
        lines += ["", f"## {title}", "", "| case | N | escaped | table | wall | energy | reversal | precise | compare "
                                         "| outcome |", "|---|---|---|---|---|---|---|---|---|---|"]
        for r in rows:
            made = r.get("collisions")
            n = f"{r['N']:,}" if made is None or made == r["N"] else f"{r['N']:,} ({made:,})"
            outcome = "BROKEN: " + "; ".join(r["problems"]) if r["problems"] else "ok"
            if r["remarks"]:
                outcome += " (" + "; ".join(r["remarks"]) + ")"
            if r["note"]:
                outcome += f" — {r['note']}"
            cell = lambda x: str(x).replace("|", "\\|")  # noqa: E731
            outcome = cell(outcome)
            lines.append(f"| {cell(r['name'])} | {n} | {'yes' if r.get('escaped') else 'no'} | "
                         f"{fmt(r.get('table'))} | {fmt(r.get('wall'))} | {fmt(r.get('energy'))} | "
                         f"{fmt(r.get('reversal'))} | {fmt(r.get('precise'))} | {fmt(r.get('compare'))} | "
                         f"{outcome} |")
    with open(path, "w") as fh:
        fh.write("\n".join(lines) + "\n")


# ---- kills at random instants (docs/reliability.md) ------------------------------------------------------------

KILL_CONFIG = {"table": {"kind": "strip", "width": 1.0},
               "boundary": {"default": {"rule": "random", "choices": [{"rule": "constant", "rank": 0},
                                                                     {"rule": "constant", "rank": 1}],
                                        "probabilities": [0.5, 0.5]}},
               "ball": {"radius": 0.1, "inertia": "uniform"},
               "initial": {"position": [0, 0.5], "velocity": [0.6, 0.8], "angular_velocity": 1.5, "orientation": 0.3},
               "run": {"collisions": 400_000, "trajectories": 3, "seed": 11},
               "output": {"record": ["time", "position", "wall", "rank"], "every": 7}}


def kill_survey(kills, seed=1, block_work=3000, src=None, log=print, extra_env=None):
    """SIGKILL a real ``rbx simulate`` (tiny blocks, so most of its time is spent writing HDF5) ``kills`` times at
    uniformly random instants of its writing, resume each file with a real ``rbx simulate --resume`` and compare
    with an uninterrupted run -> dict outcome -> count: ``exact`` (resumed, records bit for bit the
    uninterrupted run's), ``refused`` (one line, exit 2), ``other:<what>`` (anything else: a crash, a traceback,
    different records). ``src``: a source tree to run instead of the installed rbx (to measure an older commit)."""
    import random
    import shutil
    import signal
    import subprocess
    import tempfile

    import h5py
    import yaml

    rng = random.Random(seed)
    root = os.path.abspath(src) if src else None
    prelude = (f"import sys; sys.path.insert(0, {root!r}); " if root else "import sys; ")

    def cmd(block, *args):
        code = prelude + (f"import rbx.simulation as s; s.BLOCK_WORK = {block}; s.CHECKPOINT_SECONDS = 0; " if block else "") + \
            "from rbx.cli.main import main; sys.argv[0] = 'rbx'; main()"
        return [sys.executable, "-c", code, *args]

    def read(path):
        with h5py.File(path, "r") as f:
            out = {"complete": bool(f.attrs["complete"])}
            out.update({k: f["collisions"][k][...] for k in f["collisions"]})
        return out

    def same(a, b):
        return a.keys() == b.keys() and all(np.array_equal(a[k], b[k], equal_nan=getattr(a[k], "dtype", None) is not
                                                           None and a[k].dtype.kind == "f") for k in a)

    env = dict(os.environ, **(extra_env or {}))
    folder = tempfile.mkdtemp(prefix="rbx-kills-")

    def outcome_done(where):
        return (os.path.exists(os.path.join(where, "run.h5"))
                and not os.path.exists(os.path.join(where, "run.h5.partial")))

    outcomes = {}
    try:
        with open(os.path.join(folder, "exp.yaml"), "w") as fh:
            yaml.safe_dump(KILL_CONFIG, fh)
        res = subprocess.run(cmd(None, "simulate", "exp.yaml", "-o", "ref.h5", "--quiet"), cwd=folder, env=env,
                             capture_output=True, text=True)
        assert res.returncode == 0, res.stderr
        reference = read(os.path.join(folder, "ref.h5"))
        partial = os.path.join(folder, "run.h5.partial")
        t0 = time.monotonic()          # the length of the writing phase, to draw the kill instants from
        res = subprocess.run(cmd(block_work, "simulate", "exp.yaml", "-o", "timed.h5", "--quiet"), cwd=folder,
                             env=env, capture_output=True, text=True)
        assert res.returncode == 0, res.stderr
        writing = time.monotonic() - t0 - 1.0      # start-up (imports, cached kernels) is ~1 s of it
        log(f"kill survey: the run writes for about {writing:.1f} s; {kills} kills")
        for i in range(kills):
            for name in os.listdir(folder):
                if name.startswith("run.h5"):
                    os.remove(os.path.join(folder, name))
            proc = subprocess.Popen(cmd(block_work, "simulate", "exp.yaml", "-o", "run.h5", "--quiet"), cwd=folder,
                                    env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            while not os.path.exists(partial) and proc.poll() is None:
                time.sleep(0.001)
            time.sleep(rng.uniform(0, 0.9 * max(writing, 0.1)))
            if proc.poll() is not None:
                outcome = "finished-before-the-kill"
            else:
                proc.send_signal(signal.SIGKILL)
                proc.wait()
            if outcome_done(folder):        # killed while exiting, its file already renamed: nothing to resume
                outcome = "finished-before-the-kill"
            else:
                # killed inside a commit, after its commit point: the journal is applied when the file is opened
                journal = os.path.exists(partial + ".journal")
                res = subprocess.run(cmd(None, "simulate", "--resume", "run.h5.partial", "--quiet"), cwd=folder,
                                     env=env, capture_output=True, text=True)
                lines = res.stderr.strip().splitlines()
                if res.returncode == 0 and "nothing to resume" in res.stderr:
                    outcome = "finished-before-the-kill"    # killed between marking it complete and the rename
                elif res.returncode == 0:
                    try:
                        same_records = same(read(os.path.join(folder, "run.h5")), reference)
                        outcome = "exact" if same_records else "other:different"
                        if same_records and "failed their checksum" in res.stderr:
                            outcome = "exact, a torn chunk read raw"   # rbx.resume: the chunk the kill tore
                        if same_records and journal:
                            outcome += ", a journal applied"
                    except Exception as exc:   # noqa: BLE001 - counted, not raised
                        outcome = f"other:unreadable ({type(exc).__name__})"
                elif res.returncode == 2 and len([x for x in lines if "warning" not in x]) == 1:
                    outcome = "refused"
                    log(f"  kill {i}: refused: {lines[-1]}")
                else:
                    outcome = f"other:exit {res.returncode}"
                    log(f"  kill {i}: exit {res.returncode}: {lines[-1] if lines else ''}")
            outcomes[outcome] = outcomes.get(outcome, 0) + 1
            if (i + 1) % 10 == 0:
                log(f"  {i + 1} kills: {outcomes}")
        return outcomes
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="tiny sizes (for the smoke test)")
    ap.add_argument("--long", type=int, default=None, help="collisions of the long run (default 10⁹; quick 10⁵)")
    ap.add_argument("--groups", default=",".join(GROUP_TITLES), help="comma-separated subset of the groups")
    ap.add_argument("--out", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "docs",
                                                  "stress.md"))
    ap.add_argument("--kills", type=int, default=0,
                    help="only the kill survey: SIGKILL a real run this many times at random instants, resume each, "
                         "count the outcomes (docs/reliability.md)")
    ap.add_argument("--kill-src", default=None, help="with --kills: a source tree to run instead of the installed rbx")
    ap.add_argument("--kill-seed", type=int, default=1, help="with --kills: the seed of the kill instants")
    args = ap.parse_args(argv)
    if args.kills:
        print(kill_survey(args.kills, seed=args.kill_seed, src=args.kill_src,
                          log=lambda m: print(m, file=sys.stderr, flush=True)))
        return None
    groups = set(args.groups.split(","))
    t_start = time.perf_counter()

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    results = []
    for case in cases():
        if case.group not in groups:
            continue
        r = check_case(case, quick=args.quick)
        results.append(r)
        log(f"{case.group:8s} {case.name:60s} {'ok' if not r['problems'] else 'BROKEN: ' + '; '.join(r['problems'])}")
    N_long = args.long if args.long is not None else (100_000 if args.quick else 1_000_000_000)
    long_rows = long_run(N_long, min(N_long, 10_000_000), log) if N_long > 0 else []
    cmd = ("python scripts/stress.py " + " ".join(argv if argv is not None else sys.argv[1:])).strip()
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    write(args.out, results, long_rows, cmd, time.perf_counter() - t_start, args.quick)
    return results, long_rows


if __name__ == "__main__":
    main()
