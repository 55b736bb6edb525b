"""One entry per scene (and the rules worth telling apart): the invariant tests run over all of them."""
import copy

ROUGH = {"default": {"rule": "constant", "rank": 1}}
ROUGH3 = {"default": {"rule": "constant", "rank": 2}}
HEMI = {"default": {"rule": "hemisphere", "axis": [0, 1], "rough": {"rule": "constant", "rank": 1},
                    "smooth": {"rule": "constant", "rank": 0}}}
RANDOM01 = {"default": {"rule": "random", "choices": [{"rule": "constant", "rank": 0},
                                                       {"rule": "constant", "rank": 1}],
                        "probabilities": [0.5, 0.5]}}
RANK1_RANDOM_DIR = {"default": {"rule": "random", "probabilities": [1 / 3, 1 / 3, 1 / 3], "choices": [
    {"rule": "constant", "rank": 1, "direction_deg": a} for a in (0, 60, 120)]}}
MIXED_PLATES = {"default": {"rule": "constant", "rank": 2},
                "walls": {"bottom": {"rule": "constant", "rank": 1, "direction_deg": 30}}}
HEMI3 = {"default": {"rule": "hemisphere", "axis": [0, 0, 1], "rough": {"rule": "constant", "rank": 2},
                     "smooth": {"rule": "constant", "rank": 0}}}

L_SHAPE = [[0, 0], [2, 0], [2, 2], [1, 2], [1, 1], [0, 1]]
STAR = [[0, 0], [3, 0], [3, 3], [2, 1.2], [1.5, 3], [1, 1.2], [0, 3]]


def _cfg(table, boundary, position, velocity, spin, ball=None):
    return {"table": table, "boundary": boundary, "ball": ball or {"radius": 0.1, "inertia": "uniform"},
            "initial": {"position": position, "velocity": velocity, "angular_velocity": spin,
                        "orientation": 0.3 if len(position) == 2 else [0.1, 0.2, 0.3]},
            "run": {"collisions": 1000, "seed": 1}}


SCENES = {
    "strip-rough": _cfg({"kind": "strip", "width": 1.0}, ROUGH, [0, 0.5], [0.6, 0.8], 1.5),
    "strip-hemisphere": _cfg({"kind": "strip", "width": 1.0}, HEMI, [0, 0.5], [0.6, 0.8], 1.5),
    "strip-random": _cfg({"kind": "strip", "width": 1.0}, RANDOM01, [0, 0.5], [0.6, 0.8], 1.5),
    "circle-rough": _cfg({"kind": "circle", "radius": 1.0}, ROUGH, [0.1, -0.2], [-0.3, 0.9], -2.0),
    "circle-hemisphere": _cfg({"kind": "circle", "radius": 1.0}, HEMI, [0.1, -0.2], [-0.3, 0.9], -2.0),
    "wedge-rough": _cfg({"kind": "wedge", "angle_deg": 50}, ROUGH, [1.0, 0.3], [-0.7, 0.2], 0.4),
    "rectangle-rough": _cfg({"kind": "rectangle", "width": 2.0, "height": 1.0}, ROUGH, [0.5, 0.5], [0.6, 0.3], 1.0),
    "rectangle-random": _cfg({"kind": "rectangle", "width": 2.0, "height": 1.0}, RANDOM01, [0.5, 0.5], [0.6, 0.3],
                             1.0),
    "triangle-rough": _cfg({"kind": "polygon", "vertices": [[0, 0], [1, 0], [0.5, 0.8660254037844386]]}, ROUGH,
                           [0.5, 0.3], [0.31, 0.77], 2.0),
    "L-polygon-rough": _cfg({"kind": "polygon", "vertices": L_SHAPE}, ROUGH, [0.5, 0.5], [0.83, 0.31], 0.7),
    "star-polygon-hemisphere": _cfg({"kind": "polygon", "vertices": STAR}, HEMI, [1.5, 0.5], [0.3, 0.9], -1.0),
    # the horizontal spin is not perpendicular to the horizontal velocity: with (1, 0.5) the orbit would stay in
    # one vertical plane, a 2D problem
    "plates-rank2": _cfg({"kind": "plates", "gap": 1.0}, ROUGH3, [0, 0, 0.5], [0.2, -0.4, 0.7], [1.0, -2.0, -0.3]),
    "plates-mixed": _cfg({"kind": "plates", "gap": 1.0}, MIXED_PLATES, [0, 0, 0.5], [0.2, -0.4, 0.7],
                         [1.0, -2.0, -0.3]),
    "plates-random-direction": _cfg({"kind": "plates", "gap": 1.0}, RANK1_RANDOM_DIR, [0, 0, 0.5],
                                    [0.2, -0.4, 0.7], [1.0, 0.5, -0.3]),
    "box-rough": _cfg({"kind": "box", "size": [1.0, 1.3, 0.8]}, ROUGH3, [0.5, 0.5, 0.4], [0.3, -0.5, 0.6],
                      [0.4, 0.1, -0.9]),
    "box-hemisphere": _cfg({"kind": "box", "size": [1.0, 1.3, 0.8]}, HEMI3, [0.5, 0.5, 0.4], [0.3, -0.5, 0.6],
                           [0.4, 0.1, -0.9]),
}


def scene(name, collisions=None, record=None, trajectories=None, every=None):
    """A copy of a catalog config, with the run and output settings changed as asked."""
    return _settings(copy.deepcopy(SCENES[name]), collisions, record, trajectories, every)


def _settings(c, collisions, record, trajectories, every):
    """Config ``c`` with the run and output settings changed as asked (None: left as it is) -> c."""
    if collisions is not None:
        c["run"]["collisions"] = collisions
    if trajectories is not None:
        c["run"]["trajectories"] = trajectories
    out = c.setdefault("output", {})
    if record is not None:
        out["record"] = list(record)
    if every is not None:
        out["every"] = every
    return c


# ---- the table zoo (docs/reference.md §8): tests/test_zoo.py runs these (the tests above compare whole orbits,
# and most of the zoo is chaotic: rounding differences grow e-fold every few collisions, so the zoo is compared one
# collision at a time from the engine's own states) -------------------------------------------------------------

RANDOM3 = {"default": {"rule": "random", "choices": [{"rule": "constant", "rank": 0}, {"rule": "constant", "rank": 2}],
                       "probabilities": [0.5, 0.5]}}
SMOOTH = {"default": {"rule": "constant", "rank": 0}}

#: a custom boundary with both arc turns, a reflex joint between an arc and a segment (cap → slope), a tangent
#: joint (floor → cap), convex corners between a segment and an arc (roof → dent → roof2) and between segments
CUSTOM_BOUNDARY = [
    {"name": "floor", "from": [0.0, 0.0], "to": [3.0, 0.0]},
    {"name": "cap", "from": [3.0, 0.0], "to": [3.0, 2.0], "center": [3.0, 1.0], "turn": "ccw"},
    {"name": "slope", "from": [3.0, 2.0], "to": [2.4, 2.4]},
    {"name": "roof", "from": [2.4, 2.4], "to": [1.8, 2.4]},
    {"name": "dent", "from": [1.8, 2.4], "to": [1.0, 2.4], "center": [1.4, 2.7], "turn": "cw"},
    {"name": "roof2", "from": [1.0, 2.4], "to": [0.0, 2.4]},
    {"name": "west", "from": [0.0, 2.4], "to": [0.0, 0.0]},
]
#: a dispersing arc spanning more than 180° (a bump on a stalk hanging from the roof), reflex joints between arcs and
#: segments on both of its ends
BULB_BOUNDARY = [
    {"name": "floor", "from": [0.0, 0.0], "to": [3.0, 0.0]},
    {"name": "east", "from": [3.0, 0.0], "to": [3.0, 2.0]},
    {"name": "roof", "from": [3.0, 2.0], "to": [1.7, 2.0]},
    {"name": "stalk_right", "from": [1.7, 2.0], "to": [1.7, 1.6]},
    {"name": "bulb", "from": [1.7, 1.6], "to": [1.3, 1.6], "center": [1.5, 1.2], "turn": "cw"},
    {"name": "stalk_left", "from": [1.3, 1.6], "to": [1.3, 2.0]},
    {"name": "roof2", "from": [1.3, 2.0], "to": [0.0, 2.0]},
    {"name": "west", "from": [0.0, 2.0], "to": [0.0, 0.0]},
]
DISCS = [{"name": "small", "disc": {"center": [0.3, 0.25], "radius": 0.2}},
         {"name": "big", "disc": {"center": [-0.35, -0.3], "radius": 0.25}}]
SPHERES = [{"name": "one", "sphere": {"center": [0.5, 0.5, 0.5], "radius": 0.2}},
           {"name": "two", "sphere": {"center": [1.4, 0.9, 0.7], "radius": 0.25}}]

#: name -> (config, the rules to compare with the reference: rough, smooth, random)
ZOO = {
    "stadium": _cfg({"kind": "stadium", "radius": 0.5, "length": 1.0}, ROUGH, [0.3, 0.1], [0.6, 0.8], 1.0),
    "mushroom": _cfg({"kind": "mushroom", "cap_radius": 1.0, "stem_width": 0.6, "stem_height": 1.0}, ROUGH,
                     [0.0, -0.5], [0.3, 0.9], 1.0),
    "sinai-2d": _cfg({"kind": "sinai", "size": [2.0, 1.5], "radius": 0.4}, ROUGH, [0.2, 0.2], [0.6, 0.8], 1.0),
    "lorentz-2d": _cfg({"kind": "lorentz", "cell": [1.0, 1.0], "radius": 0.3}, ROUGH, [0.05, 0.1], [0.6, 0.8], 1.0),
    # a triangular lattice (the cell [1, √3], two scatterers) of finite horizon: grown by R each scatterer (0.46)
    # crosses the cell's sides and blocks every corridor (≥ √3/4)
    "lorentz-centred": _cfg({"kind": "lorentz", "cell": [1.0, 3 ** 0.5], "radius": 0.36, "lattice": "centred"}, ROUGH,
                            [0.75, 0.72], [0.6, 0.8], 1.0),
    "custom": _cfg({"kind": "custom", "boundary": CUSTOM_BOUNDARY}, ROUGH, [0.5, 0.5], [0.83, 0.31], 1.0),
    "custom-bulb": _cfg({"kind": "custom", "boundary": BULB_BOUNDARY}, ROUGH, [0.5, 0.5], [0.83, 0.31], 1.0),
    "circle-obstacles": _cfg({"kind": "circle", "radius": 1.0, "obstacles": DISCS}, ROUGH, [0.6, -0.5],
                             [-0.3, 0.9], -2.0),
    "periodic-rectangle": _cfg({"kind": "rectangle", "width": 2.0, "height": 1.0, "periodic": True,
                                "obstacles": [{"name": "left", "disc": {"center": [0.5, 0.4], "radius": 0.25}},
                                              {"name": "right", "disc": {"center": [1.5, 0.6], "radius": 0.3}}]},
                               ROUGH, [1.0, 0.05], [0.6, 0.8], 1.0),
    "sinai-3d": _cfg({"kind": "sinai", "size": [2.0, 1.5, 1.2], "radius": 0.3}, ROUGH3, [0.2, 0.2, 0.2],
                     [0.6, 0.8, 0.3], [0.0, 0.5, 1.0]),
    "lorentz-3d": _cfg({"kind": "lorentz", "cell": [1.0, 1.0, 1.0], "radius": 0.3}, ROUGH3, [0.05, 0.1, 0.1],
                       [0.6, 0.8, 0.3], [0.0, 0.5, 1.0]),
    "sphere": _cfg({"kind": "sphere", "radius": 1.0}, ROUGH3, [0.2, 0.1, 0.0], [0.6, 0.8, 0.3], [0.0, 0.5, 1.0]),
    "cylinder": _cfg({"kind": "cylinder", "radius": 1.0, "height": 1.5}, ROUGH3, [0.2, 0.1, 0.5], [0.6, 0.8, 0.3],
                     [0.0, 0.5, 1.0]),
    "box-obstacles": _cfg({"kind": "box", "size": [2.0, 1.5, 1.2], "obstacles": SPHERES}, ROUGH3, [1.0, 0.2, 0.2],
                          [0.6, 0.8, 0.3], [0.0, 0.5, 1.0]),
    "periodic-box": _cfg({"kind": "box", "size": [1.0, 1.2, 1.0], "periodic": True,
                          "obstacles": [{"name": "ball", "sphere": {"center": [0.5, 0.6, 0.5], "radius": 0.35}}]},
                         ROUGH3, [0.05, 0.05, 0.1], [0.6, 0.8, 0.3], [0.0, 0.5, 1.0]),
}


def zoo(name, rules="rough", collisions=None, record=None, trajectories=None, every=None):
    """A copy of a zoo config with the rule ``rough`` (rank n − 1), ``smooth`` or ``random`` (rank 0 or n − 1,
    p = ½) on every wall, and the run and output settings changed as asked."""
    c = _settings(copy.deepcopy(ZOO[name]), collisions, record, trajectories, every)
    n = len(c["initial"]["position"])
    c["boundary"] = copy.deepcopy({"rough": ROUGH if n == 2 else ROUGH3, "smooth": SMOOTH,
                                   "random": RANDOM01 if n == 2 else RANDOM3}[rules])
    return c
