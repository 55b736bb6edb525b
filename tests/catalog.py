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
    c = copy.deepcopy(SCENES[name])
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
