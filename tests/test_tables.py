"""The registry of table kinds (rbx.tables): every kind has every facet, the facets agree with each other (the
walls as data against the engine's shrunk table), and a kind added by one registration works everywhere — the
config, the engine, the plots, the reference loop — without naming it anywhere else."""
import dataclasses

import matplotlib
import numpy as np
import pytest
from matplotlib.figure import Figure

from rbx import config, tables
from rbx.model import RECORD_FIELDS
from rbx.simulation import run_in_memory

from catalog import SCENES, ZOO
from reference import reference_run

matplotlib.use("Agg")
KINDS = sorted(tables.KINDS)


def _experiment(kind, params, R=0.05):
    n = tables.dimension(kind, params)
    return {"table": {"kind": kind, **params}, "boundary": {"default": {"rule": "constant", "rank": n - 1}},
            "ball": {"radius": R}, "initial": {"sample": "billiard"} if kind != "wedge" else
            {"position": [1.0, 0.3], "velocity": [-0.7, 0.2]}, "run": {"collisions": 50, "trajectories": 2}}


@pytest.mark.parametrize("name", KINDS)
def test_every_kind_has_every_facet(name):
    k = tables.kind(name)
    for f in dataclasses.fields(tables.TableKind):
        if f.name == "optional":                   # optional parameters: a kind may have none
            continue
        value = getattr(k, f.name)
        assert value is not None and value != "", f"{name}: facet {f.name} missing"
        if f.name in ("walls", "build", "fits", "scale", "phrase", "draw"):
            assert callable(value), f"{name}: facet {f.name} is not a function"
    assert tables.dimension(name, k.example) in (2, 3) and set(k.example) == set(k.params)
    assert name in {s["table"]["kind"] for s in list(SCENES.values()) + list(ZOO.values())}, \
        f"{name}: no scene in tests/catalog.py"


@pytest.mark.parametrize("name", KINDS)
def test_facets_agree(name):
    k = tables.kind(name)
    cfg = config.from_dict(_experiment(name, k.example))           # the example passes the kind's own checks
    geom = cfg.geometry()
    pieces = tables.walls(name, k.example)
    assert tables.wall_names(pieces) == geom.wall_names == list(cfg.wall_names)
    assert geom.dimension == tables.dimension(name, k.example) == cfg.dimension and geom.kind == name
    assert geom.table == dict(cfg.table)                            # the geometry keeps its parameters
    assert k.scale(k.example) > 0 and k.phrase(k.example).startswith(("in ", "between "))
    # every flat wall piece is the engine's wall moved inward by R: same inward normal
    R = cfg.ball.radius
    for piece, wall in zip([p for p in pieces if not isinstance(p, tables.Polygon)], geom.wall_list):
        if isinstance(piece, (tables.Line, tables.Plane)):
            patch = wall.patches[0]
            np.testing.assert_allclose(patch[2], tables.unit(piece.normal), atol=1e-15)
            np.testing.assert_allclose((np.asarray(patch[1]) - np.asarray(piece.point, float)) @ patch[2], R,
                                       rtol=1e-12)
    # a ball too big for the table is refused by the kind's own check, naming ball.radius
    big = _experiment(name, k.example, R=100.0)
    if name != "wedge":                                            # any ball fits in a wedge (it escapes instead)
        with pytest.raises(config.ConfigError) as info:
            config.from_dict(big)
        assert info.value.key == "ball.radius" and "does not fit" in info.value.problem
    # the kind draws itself on 2D axes (a 3D table: its horizontal projection) without error
    ax = Figure().add_subplot()
    tables.draw(ax, geom, np.array([-1.0, -1.0]), np.array([1.0, 1.0]))


def test_unknown_kind_lists_the_registered_ones():
    with pytest.raises(config.ConfigError) as info:
        config.from_dict({**_experiment("strip", {"width": 1.0}), "table": {"kind": "stadum"}})
    assert info.value.key == "table.kind" and "unknown table kind" in info.value.problem
    with pytest.raises(config.ConfigError) as info:
        config.from_dict({**_experiment("strip", {"width": 1.0}), "table": {"kind": "strp", "width": 1}})
    assert "did you mean 'strip'" in info.value.problem


def test_a_new_kind_is_one_registration(monkeypatch):
    # an equilateral triangle of a given side, registered here and nowhere else: config, engine and the reference
    # loop take it from the registry, and the engine agrees with the reference record by record
    def triangle_vertices(p):
        s = p["side"]
        return [[0.0, 0.0], [s, 0.0], [0.5 * s, 0.5 * 3 ** 0.5 * s]]

    kind = tables.TableKind(
        "triangle", 2, "an equilateral triangle", {"side": tables.positive},
        walls=lambda p: [tables.Polygon(("a", "b", "c"), tuple(map(tuple, triangle_vertices(p))))],
        build=lambda p, R: tables.geometry.polygon({"vertices": triangle_vertices(p)}, R, kind="triangle",
                                                   names=["a", "b", "c"]),
        fits=tables.KINDS["polygon"].fits, scale=lambda p: p["side"], phrase=lambda p: "in a triangle",
        draw=tables.KINDS["polygon"].draw, example={"side": 1.0})
    monkeypatch.setitem(tables.KINDS, "triangle", kind)
    c = {"table": {"kind": "triangle", "side": 1.0}, "boundary": {"default": {"rule": "constant", "rank": 1}},
         "ball": {"radius": 0.1}, "initial": {"position": [0.5, 0.3], "velocity": [0.31, 0.77],
                                              "angular_velocity": 2.0},
         "run": {"collisions": 60}, "output": {"record": list(RECORD_FIELDS)}}
    cfg = config.from_dict(c)
    assert cfg.wall_names == ("a", "b", "c")
    rec, count, _ = run_in_memory(cfg)
    ref = reference_run(c)
    assert count[0] == len(ref) == 61
    for i, r in enumerate(ref):
        np.testing.assert_allclose(rec["position"][0, i], r["position"], atol=1e-10)
        assert rec["wall"][0, i] == r["wall"]
    with pytest.raises(config.ConfigError) as info:
        config.from_dict({**c, "table": {"kind": "triangle", "side": -1}})
    assert info.value.key == "table.side"


def test_scene_titles_name_table_and_rules_from_the_model():
    from rbx.analysis import scene_title
    base = {"table": {"kind": "rectangle", "width": 2, "height": 1}, "ball": {"radius": 0.1},
            "initial": {"sample": "billiard"}}
    rough = {"rule": "constant", "rank": 1}
    assert scene_title(config.from_dict({**base, "boundary": {"default": rough}})) == \
        "disc (R = 0.1, κ = 0.5) in a 2 × 1 rectangle · rough"
    mixed = {"default": rough, "walls": {"top": {"rule": "constant", "rank": 0}}}
    assert scene_title(config.from_dict({**base, "boundary": mixed})).endswith("· top: specular, others: rough")
    plates = config.from_dict({"table": {"kind": "plates", "gap": 1}, "ball": {"radius": 0.1},
                               "initial": {"sample": "billiard"},
                               "boundary": {"default": {"rule": "constant", "rank": 2},
                                            "walls": {"bottom": {"rule": "constant", "rank": 1, "direction_deg": 30}}}})
    assert scene_title(plates).endswith("· bottom: rank 1 at 30°, top: rough (rank 2)")
