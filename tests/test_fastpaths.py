"""The engine's closed forms are the general loop's numbers, bit for bit: the axis-aligned box
(geometry.box_collision, Geometry.axis_box) and the antisymmetric spin update of the collision map."""
import numpy as np
import pytest

from rbx import config, engine
from rbx.geometry import FOCUS_ARC, SEGMENT, box_collision, collision_time, next_collision
from rbx.physics import collide

R = 0.05


def geometry(table, n):
    d = {"table": table, "ball": {"radius": R},
         "initial": {"position": [0.1] * n, "velocity": [1.0] + [0.5] * (n - 1)},
         "boundary": {"default": {"rule": "constant", "rank": 0}}, "run": {"collisions": 1}}
    return config.from_dict(d, "<test>").geometry()


BOXED = {
    "rectangle": ({"kind": "rectangle", "width": 2.0, "height": 1.0}, 2),
    "box": ({"kind": "box", "size": [1.0, 1.3, 0.8]}, 3),
    "sinai": ({"kind": "sinai", "size": [2.0, 1.5], "radius": 0.4}, 2),
    "sinai3": ({"kind": "sinai", "size": [1.0, 1.3, 0.8], "radius": 0.2}, 3),
    # its four outer sides have the whole polygon on one side: half-spaces, an axis box; the two inner sides and
    # the rounded reflex corner are the other primitives
    "L-polygon": ({"kind": "polygon", "vertices": [[0, 0], [2, 0], [2, 2], [1, 2], [1, 1], [0, 1]]}, 2),
    "box-obstacles": ({"kind": "box", "size": [2.0, 2.0, 2.0],
                       "obstacles": [{"name": "s1", "sphere": {"center": [0.6, 0.6, 0.6], "radius": 0.2}},
                                     {"name": "s2", "sphere": {"center": [1.4, 1.3, 1.2], "radius": 0.3}}]}, 3),
}
NOT_BOXED = {
    "strip": ({"kind": "strip", "width": 1.0}, 2),             # a slab: its own closed form
    "plates": ({"kind": "plates", "gap": 1.0}, 3),
    "stadium": ({"kind": "stadium", "radius": 0.5, "length": 1.0}, 2),
    "circle": ({"kind": "circle", "radius": 1.0}, 2),
    "lorentz": ({"kind": "lorentz", "cell": [1.0, 1.0], "radius": 0.3}, 2),    # periodic: the images
    "periodic-box": ({"kind": "box", "size": [1.0, 1.0, 1.0], "periodic": True,
                      "obstacles": [{"name": "s1", "sphere": {"center": [0.5, 0.5, 0.5], "radius": 0.2}}]}, 3),
}


@pytest.mark.parametrize("name", sorted(BOXED))
def test_a_box_is_found_and_its_closed_form_is_the_general_loop(name):
    table, n = BOXED[name]
    geom = geometry(table, n)
    box = geom.axis_box
    assert box is not None and sorted(box.tolist()) == sorted(set(box.tolist()))
    for i in range(n):                     # side 2i has normal +e_i, side 2i+1 normal −e_i
        assert geom.params[box[2 * i], 4 + i] == 1.0 and geom.params[box[2 * i + 1], 4 + i] == -1.0
    t = engine.make_table(geom, 1e-12)
    assert sorted(t.box.tolist() + t.others.tolist()) == list(range(len(geom.codes)))
    rng = np.random.default_rng(7)
    lo = np.array([geom.params[box[2 * i], i] for i in range(n)])
    hi = np.array([geom.params[box[2 * i + 1], i] for i in range(n)])
    starts = [lo + (hi - lo) * rng.uniform(size=n) for _ in range(3000)]
    dirs = [rng.normal(size=n) for _ in range(3000)]
    # ties: from the centre of the box straight at a corner, and along an axis (zero components)
    mid = (lo + hi) / 2
    for corner in range(2 ** n):
        s = np.array([1.0 if corner >> i & 1 else -1.0 for i in range(n)])
        starts.append(mid.copy())
        dirs.append(s * (hi - lo) / 2)
        starts.append(mid.copy())
        dirs.append(np.where(np.arange(n) == corner % n, s, 0.0))
    # on a wall (t = 0 when moving out, the flight after a collision when moving in)
    for i in range(n):
        a = mid.copy()
        a[i] = hi[i]
        starts += [a, a]
        dirs += [np.eye(n)[i], -np.eye(n)[i] + 0.3]
    ties = 0
    for a, v in zip(starts, dirs):
        want = next_collision(geom.codes, geom.params, a, v, 1e-12, n)
        got = box_collision(geom.codes, geom.params, a, v, 1e-12, n, t.box, t.others, True, False)
        assert got[1] == want[1] and np.float64(got[0]).tobytes() == np.float64(want[0]).tobytes(), (a, v)
        ties += sum(np.isclose(v @ np.eye(n)[i], 0.0) for i in range(n))
    assert ties > 0


@pytest.mark.parametrize("name", sorted(NOT_BOXED))
def test_tables_that_are_not_a_box_take_the_general_loop(name):
    table, n = NOT_BOXED[name]
    geom = geometry(table, n)
    assert geom.axis_box is None
    t = engine.make_table(geom, 1e-12)
    assert t.box.shape == (0,) and sorted(t.others.tolist()) == list(range(len(geom.codes)))
    assert t.first_hit == (name in CONVEX_BOUNDARY)
    if not t.first_hit:
        assert t.others.tolist() == list(range(len(geom.codes)))


#: 2D tables bounded by one convex curve of segments and focusing arcs: the first primitive hit is the collision
CONVEX_BOUNDARY = {
    "stadium": NOT_BOXED["stadium"],
    # an egg of pieces: a floor, arcs of radius 1 and 2 − √3 … tangent to it and to a slanted roof
    "custom-egg": ({"kind": "custom", "boundary": [
        {"name": "floor", "from": [0.0, 0.0], "to": [2.0, 0.0]},
        {"name": "bend", "from": [2.0, 0.0], "to": [1.5000000000000002, 1.8660254037844388], "center": [2.0, 1.0],
         "turn": "ccw"},
        {"name": "roof", "from": [1.5000000000000002, 1.8660254037844388], "to": [-0.23205080756887728,
                                                                                 0.866025403784439]},
        {"name": "nose", "from": [-0.23205080756887728, 0.866025403784439], "to": [0.0, 0.0],
         "center": [0.0, 0.4641016151377548], "turn": "ccw"}]}, 2),
}
#: convex too, with corners: a piece's shrunk line runs past the corner (outside the free region) and can report
#: a hit there before the other piece's true one, so the kernel takes the smallest
CORNERED = {"kind": "custom", "boundary": [
    {"name": "floor", "from": [0.0, 0.0], "to": [2.0, 0.0]},
    {"name": "bend", "from": [2.0, 0.0], "to": [2.0, 1.0], "center": [2.0, 0.5], "turn": "ccw"},
    {"name": "slope", "from": [2.0, 1.0], "to": [0.5, 0.9]},
    {"name": "nose", "from": [0.5, 0.9], "to": [0.0, 0.0], "center": [0.7, 0.2], "turn": "ccw"}]}
NOT_CONVEX_BOUNDARY = {
    "mushroom": ({"kind": "mushroom", "cap_radius": 1.0, "stem_width": 0.6, "stem_height": 1.0}, 2),
    "stadium-obstacle": ({"kind": "stadium", "radius": 0.5, "length": 1.0,
                          "obstacles": [{"name": "post", "disc": {"center": [0.5, 0.0], "radius": 0.1}}]}, 2),
    "sinai": BOXED["sinai"], "L-polygon": BOXED["L-polygon"], "circle": NOT_BOXED["circle"],
    "lorentz": NOT_BOXED["lorentz"], "cylinder": ({"kind": "cylinder", "radius": 1.0, "height": 1.5}, 3),
    "custom-cornered": (CORNERED, 2),
}


@pytest.mark.parametrize("name", sorted(CONVEX_BOUNDARY))
def test_on_a_convex_boundary_the_first_hit_is_the_smallest(name):
    """The kernel stops at the first primitive that reports a hit (segments asked first): the same primitive and
    flight time, bit for bit, as the smallest over all, for flights from everywhere in the free region, from the
    walls (just hit) and into the joints; at a joint two pieces may both report a hit within the tolerance, and
    then the two contacts are a tolerance apart."""
    table, n = CONVEX_BOUNDARY[name]
    geom = geometry(table, n)
    assert geom.convex_boundary
    t = engine.make_table(geom, 1e-12)
    codes = geom.codes[t.others]
    assert t.first_hit and sorted(t.others.tolist()) == list(range(len(geom.codes)))
    assert list(codes) == sorted(codes, key=lambda c: c != SEGMENT) and SEGMENT in codes and FOCUS_ARC in codes
    rng = np.random.default_rng(3)
    lo, hi = geom.outline.min(axis=0), geom.outline.max(axis=0)
    pts = lo + (hi - lo) * rng.uniform(size=(20000, 2))
    starts = list(pts[geom.clearance(pts) > 0][:4000])
    dirs = [rng.normal(size=2) for _ in starts]
    # from the contact points of flights (on a wall, moving in) and straight at the ends of every piece
    # (a segment's end: start [0:2] + length [12] × tangent [8:10]; an arc's: centre + radius × last normal)
    joints = [geom.params[k, :2] + geom.params[k, 12] * geom.params[k, 8:10] for k in range(len(geom.codes))]
    for a, v in list(zip(starts[:500], dirs[:500])):
        tau, k = next_collision(geom.codes, geom.params, a, v, 1e-12, n)
        starts.append(a + tau * v)
        dirs.append(rng.normal(size=2))
    aimed = len(starts)                          # the flights aimed at a joint come last
    for a in list(starts[:500]):
        for q in joints:
            starts.append(a)
            dirs.append(q - a)
    near, same = 0, 0
    for i, (a, v) in enumerate(zip(starts, dirs)):
        want = next_collision(geom.codes, geom.params, a, v, 1e-12, n)
        got = box_collision(geom.codes, geom.params, a, v, 1e-12, n, t.box, t.others, False, True)
        assert np.isfinite(got[0]) and got[1] >= 0, (a, v)
        if got[1] == want[1]:
            assert np.float64(got[0]).tobytes() == np.float64(want[0]).tobytes(), (a, v)
            same += 1
        else:       # both pieces of a joint: contact points a tolerance apart
            assert i >= aimed and np.linalg.norm((got[0] - want[0]) * v) < 1e-9 * geom.size, (a, v, got, want)
            near += 1
    assert same > aimed and near > 0, (same, near)


@pytest.mark.parametrize("name", sorted(NOT_CONVEX_BOUNDARY))
def test_other_tables_take_the_smallest_hit(name):
    table, n = NOT_CONVEX_BOUNDARY[name]
    geom = geometry(table, n)
    assert not geom.convex_boundary and not engine.make_table(geom, 1e-12).first_hit


def test_at_a_corner_the_first_hit_would_be_wrong():
    """Why a cornered table takes the smallest (the case that showed it): the floor's shrunk line runs on past its
    corner with the nose, outside the free region, and a flight into the corner reports it 0.0063 beyond the
    nose's true contact."""
    geom = geometry(CORNERED, 2)
    assert geom.corners == 3 and not geom.convex_boundary
    a, v = np.array([2.19128472, 0.46395152]), np.array([-2.74142495, -0.52280489])
    t_floor = collision_time(SEGMENT, geom.params, 0, a, v, 1e-12, 2)
    t_min, k = next_collision(geom.codes, geom.params, a, v, 1e-12, 2)
    assert k == 3 and t_floor - t_min > 0.006


def full_update(v, W, nu, R, kappa):
    """The completely rough map with every entry of W updated (the form before the antisymmetric update).

    Every sum is written out in the order :func:`rbx.physics.collide` takes it, so that the two agree bit for bit
    on any CPU: the same operations in the same order, and Numba contracts no multiply-add without fastmath.
    (``v @ nu`` here went to the BLAS, whose dot-product kernel OpenBLAS chooses per CPU: on an AVX-512 Xeon its
    SkylakeX kernel gave a result one ulp away; ``OPENBLAS_CORETYPE=SkylakeX`` shows it on any x86-64 machine.)"""
    n = len(v)
    vn = 0.0
    for i in range(n):
        vn += v[i] * nu[i]
    u = np.array([(v[i] - vn * nu[i]) - R * sum(W[i, j] * nu[j] for j in range(n)) for i in range(n)])
    a2 = 2.0 * kappa / (1.0 + kappa)
    sc = 2.0 / ((1.0 + kappa) * R)
    v2 = np.array([(v[i] - 2.0 * vn * nu[i]) - a2 * u[i] for i in range(n)])
    w2 = np.array([sc * nu[i] for i in range(n)])
    W2 = W.copy()
    for i in range(n):
        for j in range(n):
            W2[i, j] += u[i] * w2[j] - w2[i] * u[j]
    return v2, W2


@pytest.mark.parametrize("n", (2, 3, 4))
def test_the_antisymmetric_spin_update_is_the_full_update(n):
    rng = np.random.default_rng(n)
    for _ in range(500):
        v = rng.normal(size=n)
        X = rng.normal(size=(n, n))
        W = X - X.T
        nu = rng.normal(size=n)
        nu /= np.linalg.norm(nu)
        R, kappa = rng.uniform(0.05, 2.0), rng.uniform(0.01, 1.0)
        want_v, want_W = full_update(v, W, nu, R, kappa)
        v1, W1 = v.copy(), W.copy()
        collide(v1, W1, nu, R, kappa, n - 1, np.zeros((1, 1, max(n - 1, 1), n)), 0, 0, np.empty((3, n)), n, False)
        np.testing.assert_array_equal(v1, want_v)
        np.testing.assert_array_equal(W1, want_W)
        np.testing.assert_array_equal(W1, -W1.T)


#: tables with flat walls of normal ±e_i (the axis map) and walls without one (the general map), 2D and 3D
AXIS_TABLES = {"sinai": BOXED["sinai"], "box-obstacles": BOXED["box-obstacles"], "L-polygon": BOXED["L-polygon"],
               "stadium": NOT_BOXED["stadium"], "cylinder": NOT_CONVEX_BOUNDARY["cylinder"],
               "custom-egg": CONVEX_BOUNDARY["custom-egg"]}


@pytest.mark.parametrize("name", sorted(AXIS_TABLES))
def test_flat_walls_of_an_axis_normal_are_found(name):
    from rbx.geometry import HALFSPACE
    table, n = AXIS_TABLES[name]
    geom = geometry(table, n)
    axis = engine.make_table(geom, 1e-12).axis
    for k, code in enumerate(geom.codes):
        nu = geom.params[k, 4:4 + n]
        if code in (HALFSPACE, SEGMENT) and sorted(np.abs(nu).tolist()) == [0.0] * (n - 1) + [1.0]:
            assert axis[k] == int(np.argmax(np.abs(nu))), (k, nu)
        else:
            assert axis[k] == -1, (k, code, nu)
    expected = {"sinai": 4, "box-obstacles": 6, "L-polygon": 6, "stadium": 2, "cylinder": 2, "custom-egg": 1}
    assert np.count_nonzero(axis >= 0) == expected[name]


@pytest.mark.parametrize("name", sorted(AXIS_TABLES))
def test_the_axis_map_in_the_kernel_gives_the_general_maps_records(name, monkeypatch):
    # every field of 3000 completely rough collisions, with the axis map and with the general map on every wall
    # (flat_axes says −1 everywhere): the same numbers, bit for bit (the rank-1 basis: tests/test_physics.py)
    from rbx.simulation import MemorySink, Simulation
    table, n = AXIS_TABLES[name]
    rule = {"rule": "constant", "rank": n - 1}
    d = {"table": table, "ball": {"radius": R}, "boundary": {"default": rule},
         "initial": {"sample": "billiard"}, "run": {"collisions": 3000, "trajectories": 3, "seed": 5},
         "output": {"record": ["time", "position", "velocity", "angular_velocity", "wall"]}}
    cfg = config.from_dict(d, "<test>")
    runs = []
    for general in (False, True):
        if general:
            monkeypatch.setattr(engine, "flat_axes", lambda geom: np.full(len(geom.codes), -1, dtype=np.int64))
        sim = Simulation(cfg)
        if not general:
            assert np.any(sim.kernel_groups()[0].axis >= 0)
        sink = MemorySink()
        sim.run(sink)
        runs.append(sink.records)
    assert runs[0]["time"].shape == (3, 3001)       # the initial state and 3000 collisions
    for f in runs[0]:
        np.testing.assert_array_equal(runs[0][f], runs[1][f], err_msg=f)


# ---- setting up many trajectories at once ---------------------------------------------------------------------------

def test_the_stream_keys_at_once_are_the_keys_one_by_one():
    from rbx.rng import PURPOSE_INITIAL, PURPOSE_RULES, stream_key
    from rbx.sampling import stream_keys
    for seed, first in ((0, 0), (12345, 0), (2 ** 62 + 7, 10 ** 9)):
        for purpose in (PURPOSE_RULES, PURPOSE_INITIAL):
            rows = np.arange(first, first + 500)
            want = np.array([stream_key(seed, int(j), purpose) for j in rows], dtype=np.uint64)
            np.testing.assert_array_equal(stream_keys(seed, rows, purpose), want)


@pytest.mark.parametrize("n,shape", [(2, (9,)), (3, (9, 3)), (3, (9, 3, 3)), (2, (9, 2, 2))])
def test_the_spin_matrices_at_once_are_the_matrices_one_by_one(n, shape):
    from rbx.physics import spin_matrix
    from rbx.simulation import spin_matrices
    w = np.random.default_rng(1).normal(size=shape)
    want = np.array([spin_matrix(x, n) for x in w]).reshape(9, n, n)
    got = spin_matrices(w, 9, n)
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(np.signbit(got), np.signbit(want))     # the zeros too
