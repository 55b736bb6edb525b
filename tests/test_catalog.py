"""Invariants over every scene of the catalog: the centre never leaves the shrunk table, never misses a wall,
every collision happens on the wall it names, and the energy is kept (docs/reference.md §2, §7)."""
import numpy as np
import pytest

from rbx import config
from rbx.geometry import CONCAVE_ARC, CONVEX_ARC, HALFSPACE, SEGMENT
from rbx.model import RECORD_FIELDS
from rbx.physics import energy, spin_matrix
from rbx.simulation import run_in_memory

from catalog import SCENES, scene

N = 100_000
ALL = RECORD_FIELDS


def run(name, collisions=N, record=ALL):
    cfg = config.from_dict(scene(name, collisions=collisions, record=record))
    rec, count, final = run_in_memory(cfg)
    return cfg, {k: v[0, :count[0]] for k, v in rec.items()}, final


def wall_distance(geom, wall, pts):
    """Distance of centre positions to the primitives of one wall of the shrunk table (smallest over them)."""
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
                inside = (row[4] * m[:, 1] - row[5] * m[:, 0] >= -1e-9) & (m[:, 0] * row[9] - m[:, 1] * row[8] >= -1e-9)
                d = np.where(inside, d, np.inf)
        best = np.minimum(best, d)
    return best


@pytest.mark.parametrize("name", sorted(SCENES))
def test_scene_invariants(name):
    cfg, r, _ = run(name)
    geom = cfg.geometry()
    size = geom.size
    pos, wall = r["position"], r["wall"]
    count = len(pos)
    escaped = count < N + 1
    assert not escaped or name.startswith("wedge"), f"{name} ended after {count - 1} collisions"
    # never outside the shrunk table
    assert geom.clearance(pos).min() >= -1e-12 * size
    # the flights between collisions stay inside too (sampled; for convex tables the ends already imply it)
    if np.any((geom.codes == SEGMENT) | (geom.codes == CONVEX_ARC)):
        s = np.linspace(0, 1, 9)[1:-1]
        mids = pos[:-1, None, :] + s[None, :, None] * (pos[1:] - pos[:-1])[:, None, :]
        assert geom.clearance(mids).min() >= -1e-12 * size
    # every collision on the wall it names
    for w in range(len(geom.wall_list)):
        sel = np.nonzero(wall == w)[0]
        if len(sel):
            assert wall_distance(geom, w, pos[sel]).max() <= 1e-12 * size, geom.wall_names[w]
    assert wall[0] == -1 and np.all(wall[1:] >= 0)
    # times increase, flights are straight: velocity between records is the displacement over the time
    dt = np.diff(r["time"])
    assert np.all(dt >= 0)
    # (the recorded times carry an absolute rounding error of ~eps·t, which grows along the run)
    slack = 1e-12 * size + 4e-16 * r["time"][-1] * np.abs(r["velocity"]).max()
    np.testing.assert_allclose(pos[1:] - pos[:-1], r["velocity"][:-1] * dt[:, None], rtol=0, atol=slack)
    # energy drift
    n = cfg.dimension
    W = np.array([spin_matrix(w, n) for w in r["angular_velocity"][:: max(1, count // 2000)]])
    e = energy(r["velocity"][:: max(1, count // 2000)], W, cfg.ball.radius, cfg.ball.kappa)
    assert np.max(np.abs(e - e[0])) <= 1e-12 * e[0]
    # every wall of a bounded table gets hit
    if cfg.table_kind not in ("wedge",):
        assert set(np.unique(wall[1:])) == set(range(len(geom.wall_list)))


@pytest.mark.parametrize("name", sorted(SCENES))
def test_nothing_recorded_gives_the_same_final_state(name):
    _, r, final = run(name, collisions=3000)
    _, _, final0 = run(name, collisions=3000, record=())
    np.testing.assert_array_equal(final0["position"], final["position"])
    np.testing.assert_array_equal(final0["velocity"], final["velocity"])
    np.testing.assert_array_equal(final0["collisions"], final["collisions"])
    np.testing.assert_array_equal(r["position"][-1], final["position"][0])
