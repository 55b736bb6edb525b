"""The billiard-measure sampler on its own, before any dynamics (paper §2.7, docs/reference.md §4).

The billiard measure on a wall of Q = shrunk table × SO(n): position uniform on the shrunk wall, orientation
uniform (Haar), and the unit velocity in the metric-orthonormal coordinates (v, R√κ·ω) (d = n + n(n−1)/2 of them)
with density ∝ cos φ on the hemisphere around the inward normal. Equivalently its d−1 tangential coordinates are
uniform in the unit (d−1)-ball, so each one alone has density ∝ (1 − u²)^((d−2)/2): a semicircle for a disc
(d = 3), ∝ (1 − u²)² for a ball (d = 6). These laws are checked with Kolmogorov–Smirnov tests at fixed seeds.
"""
import math

import numpy as np
import pytest
from scipy import stats

from rbx import analysis, config
from rbx.sampling import sample_billiard

M = 20_000
P_MIN = 1e-3          # fixed seeds: deterministic; a correct sampler passes far above this


def geometry(table, radius=0.1):
    dim = 3 if table["kind"] in ("plates", "box") else 2
    rule = {"rule": "constant", "rank": dim - 1}
    cfg = config.from_dict({"table": table, "boundary": {"default": rule}, "ball": {"radius": radius},
                            "initial": {"sample": "billiard"}, "run": {"trajectories": 1}})
    return cfg, cfg.geometry()


def draw(table, wall, seed=11, count=M, radius=0.1):
    cfg, geom = geometry(table, radius)
    w = None if wall is None else cfg.wall_names.index(wall)
    return cfg, geom, sample_billiard(geom, cfg.ball.kappa, cfg.ball.radius, seed, w, 0, count)


def ks(sample, cdf):
    return stats.kstest(sample, cdf).pvalue


def coordinate_cdf(d):
    """CDF of one coordinate of a point uniform in the unit (d−1)-ball: density ∝ (1 − u²)^((d−2)/2)."""
    if d == 3:
        return lambda u: 0.5 + (u * np.sqrt(1 - u * u) + np.arcsin(u)) / np.pi
    if d == 6:
        return lambda u: (8 + 15 * u - 10 * u ** 3 + 3 * u ** 5) / 16
    raise ValueError(d)


def metric_coordinates(s, R, kappa):
    """(M, d) velocity in (v, R√κ·ω) coordinates."""
    w = np.asarray(s["angular_velocity"], float)
    return np.column_stack([s["velocity"], R * math.sqrt(kappa) * w.reshape(len(w), -1)])


# ---- 2D: a disc on the bottom wall of a rectangle --------------------------------------------------------------

RECT = {"kind": "rectangle", "width": 2.0, "height": 1.0}


def test_disc_positions_uniform_on_the_shrunk_wall():
    cfg, geom, s = draw(RECT, "bottom")
    R = cfg.ball.radius
    np.testing.assert_allclose(s["position"][:, 1], R, atol=1e-15)
    assert ks(s["position"][:, 0], stats.uniform(R, 2.0 - 2 * R).cdf) > P_MIN
    np.testing.assert_array_equal(s["normal"], np.tile([0.0, 1.0], (M, 1)))


def test_disc_angles_follow_the_cos_law_in_three_dimensions():
    cfg, geom, s = draw(RECT, "bottom")
    R, kappa = cfg.ball.radius, cfg.ball.kappa
    np.testing.assert_allclose(np.linalg.norm(metric_coordinates(s, R, kappa), axis=1), 1.0, rtol=1e-13)
    phi = analysis.normal_angle(s["velocity"], s["angular_velocity"], s["normal"], R, kappa)
    assert phi.max() < np.pi / 2
    assert ks(phi, lambda x: np.sin(x) ** 2) > P_MIN
    # and not the 2D-billiard law of a point particle (density cos φ on [0, π/2]): the test can tell them apart
    assert ks(phi, lambda x: np.sin(x)) < 1e-6


def test_disc_spin_and_tangential_velocity_are_exchangeable():
    """In (v, R√κ·ω) the tangential velocity and the scaled spin are two coordinates of one uniform 2-ball point:
    each is semicircle-distributed. Spin scaled by 2 breaks it (the check can fail)."""
    cfg, geom, s = draw(RECT, "bottom")
    R, kappa = cfg.ball.radius, cfg.ball.kappa
    x = metric_coordinates(s, R, kappa)
    cdf = coordinate_cdf(3)
    assert ks(x[:, 0], cdf) > P_MIN                     # v·t (t = x axis on the bottom wall)
    assert ks(x[:, 2], cdf) > P_MIN                     # v₀ = R√κ·ω
    assert ks(np.clip(2 * x[:, 2], -1, 1), cdf) < 1e-6  # a sampler with the wrong spin scaling
    # radius in the tangent plane: |x_t|² uniform on [0, 1] for the (d−1) = 2-ball
    assert ks(x[:, 0] ** 2 + x[:, 2] ** 2, stats.uniform(0, 1).cdf) > P_MIN


def test_disc_orientation_uniform():
    cfg, geom, s = draw(RECT, "bottom")
    assert ks(s["orientation"], stats.uniform(0, 2 * np.pi).cdf) > P_MIN


def test_circle_positions_uniform_along_the_arc_and_normals_inward():
    cfg, geom, s = draw({"kind": "circle", "radius": 1.0}, "rim")
    p = s["position"]
    np.testing.assert_allclose(np.linalg.norm(p, axis=1), 0.9, rtol=1e-13)
    np.testing.assert_allclose(s["normal"], -p / 0.9, atol=1e-13)
    assert ks(np.mod(np.arctan2(p[:, 1], p[:, 0]), 2 * np.pi), stats.uniform(0, 2 * np.pi).cdf) > P_MIN
    phi = analysis.normal_angle(s["velocity"], s["angular_velocity"], s["normal"], 0.1, cfg.ball.kappa)
    assert ks(phi, lambda x: np.sin(x) ** 2) > P_MIN


def test_whole_boundary_walls_weighted_by_length_including_reflex_arcs():
    """An L-shaped polygon: the centre's boundary has six segments and one arc of radius R at the reflex vertex
    (part of edge3). Walls are drawn in proportion to their measure, and the arc uniformly along its length."""
    L = {"kind": "polygon", "vertices": [[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]]}
    cfg, geom, s = draw(L, None)
    _, total = analysis.table_measure(geom)
    offsets = [0.0] + analysis.wall_joints(geom) + [total]
    expected = np.diff(offsets) / total
    # every sample lies on the shrunk boundary; wall w's samples have its normal and an arc length in its range
    dist = np.abs(geom.clearance(s["position"]))
    assert dist.max() < 1e-12
    counts = np.zeros(6)
    for w in range(6):
        s_w, nu_w = analysis.locate(geom, np.full(M, w), s["position"])
        on = np.all(np.isclose(nu_w, s["normal"], atol=1e-12), axis=1) & \
            (s_w >= offsets[w] - 1e-12) & (s_w <= offsets[w + 1] + 1e-12)
        counts[w] = on.sum()
    assert counts.sum() == M
    assert stats.chisquare(counts, expected * M).pvalue > P_MIN
    # samples on the arc around the reflex vertex (1, 1): uniform in angle over the quarter circle
    r = np.linalg.norm(s["position"] - [1.0, 1.0], axis=1)
    on_arc = np.isclose(r, 0.1, atol=1e-12) & np.all(s["position"] < 1.0 + 1e-12, axis=1)  # in the free region
    ang = np.arctan2(s["position"][on_arc, 1] - 1, s["position"][on_arc, 0] - 1)
    assert on_arc.sum() > 50
    assert ks(ang, stats.uniform(-np.pi, np.pi / 2).cdf) > P_MIN
    np.testing.assert_allclose(s["normal"][on_arc], (s["position"][on_arc] - 1.0) / 0.1, atol=1e-12)


def test_strip_walls_are_infinite_so_the_position_along_them_is_zero():
    cfg, geom, s = draw({"kind": "strip", "width": 1.0}, None, count=2000)
    np.testing.assert_array_equal(s["position"][:, 0], 0.0)
    on_top = s["position"][:, 1] > 0.5
    assert abs(on_top.mean() - 0.5) < 0.05


# ---- 3D: a ball on the bottom wall of a box --------------------------------------------------------------------

BOX = {"kind": "box", "size": [1.0, 1.2, 0.8]}


def test_ball_positions_uniform_on_the_shrunk_face():
    cfg, geom, s = draw(BOX, "bottom")
    R = cfg.ball.radius
    p = s["position"]
    np.testing.assert_allclose(p[:, 2], R, atol=1e-15)
    assert ks(p[:, 0], stats.uniform(R, 1.0 - 2 * R).cdf) > P_MIN
    assert ks(p[:, 1], stats.uniform(R, 1.2 - 2 * R).cdf) > P_MIN
    assert abs(np.corrcoef(p[:, 0], p[:, 1])[0, 1]) < 0.03


def test_ball_angles_follow_the_cos_law_in_six_dimensions():
    cfg, geom, s = draw(BOX, "bottom")
    R, kappa = cfg.ball.radius, cfg.ball.kappa
    x = metric_coordinates(s, R, kappa)
    np.testing.assert_allclose(np.linalg.norm(x, axis=1), 1.0, rtol=1e-13)
    phi = analysis.normal_angle(s["velocity"], s["angular_velocity"], s["normal"], R, kappa)
    assert ks(phi, lambda u: np.sin(u) ** 5) > P_MIN
    assert ks(phi, lambda u: np.sin(u) ** 2) < 1e-6    # the disc's law is rejected
    cdf = coordinate_cdf(6)
    for k in (0, 1, 3, 4, 5):                           # v_x, v_y, and the three scaled spin components
        assert ks(x[:, k], cdf) > P_MIN, k
    assert ks(np.clip(2 * x[:, 3], -1, 1), cdf) < 1e-6  # wrong spin scaling is caught


def test_ball_orientation_haar():
    """Haar measure on SO(3): A·e is uniform on the sphere, and the rotation angle α has density (1 − cos α)/π."""
    cfg, geom, s = draw(BOX, "bottom")
    A = s["orientation"]
    np.testing.assert_allclose(np.einsum("mij,mkj->mik", A, A), np.broadcast_to(np.eye(3), A.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(A), 1.0, atol=1e-12)
    assert ks(A[:, 2, 2], stats.uniform(-1, 2).cdf) > P_MIN
    assert ks(A[:, 0, 1], stats.uniform(-1, 2).cdf) > P_MIN
    alpha = np.arccos(np.clip((np.trace(A, axis1=1, axis2=2) - 1) / 2, -1, 1))
    assert ks(alpha, lambda a: (a - np.sin(a)) / np.pi) > P_MIN


def test_every_box_face_is_sampled_with_the_cos_law():
    cfg, geom, s = draw(BOX, None)
    R, kappa = cfg.ball.radius, cfg.ball.kappa
    phi = analysis.normal_angle(s["velocity"], s["angular_velocity"], s["normal"], R, kappa)
    assert ks(phi, lambda u: np.sin(u) ** 5) > P_MIN
    faces = {tuple(n) for n in s["normal"]}
    assert len(faces) == 6
    _, area = analysis.table_measure(geom)
    bottom = np.all(s["normal"] == [0, 0, 1], axis=1).mean()
    assert abs(bottom - 0.8 * 1.0 / area) < 4 * math.sqrt(0.8 / area / M)


# ---- streams ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("table,wall", [(RECT, "bottom"), (BOX, "top")])
def test_each_trajectory_draws_from_its_own_stream(table, wall):
    """Trajectory j's state depends only on (seed, j): not on how many are drawn or from where."""
    _, _, a = draw(table, wall, seed=5, count=8)
    cfg, geom = geometry(table)
    b = sample_billiard(geom, cfg.ball.kappa, cfg.ball.radius, 5, cfg.wall_names.index(wall), 5, 3)
    for k in a:
        np.testing.assert_array_equal(a[k][5:], b[k])
    _, _, c = draw(table, wall, seed=6, count=8)
    assert not np.array_equal(a["velocity"], c["velocity"])
