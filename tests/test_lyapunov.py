"""The tangent map and the Lyapunov spectrum (docs/reference.md §10; rbx/tangent.py, rbx/dynamics.py,
docs/tangent-map.md).

- The tangent map is the derivative of the engine's flow: central finite differences of ``rbx``'s own event loop
  (several steps) agree with :func:`rbx.dynamics.flow_jacobian` on every primitive the tables use (each registered
  table kind at its example parameters, plus the 3D Sinai table), for specular, rough, random and hemisphere rules.
- The orbit the tangent loop follows is the engine's.
- Known spectra: a specular dispersing table gives the classic billiard's largest exponent, computed here by the
  independent wavefront-curvature recursion; flat-walled 2D tables and the rough circle give exponents tending to
  0; the exponents sum to 0 (the flow preserves the Liouville measure) on every table.
"""
import json
import os
from pathlib import Path

import numpy as np
import pytest
import yaml

import rbx
from rbx import geometry, tables
from rbx.dynamics import flow_jacobian, lyapunov
from rbx.physics import rotation_from_vector, spin_matrix
from rbx.simulation import MemorySink, Simulation

from reference import wavefront_sums

R = 0.1
def _rule(name, n, flat=True):
    if name == "specular":
        return {"rule": "constant", "rank": 0}
    if name == "rough":
        return {"rule": "constant", "rank": n - 1}
    if name == "hemisphere":      # completely rough on one hemisphere of the ball, specular on the other
        return {"rule": "hemisphere", "axis": [0.3, 1.0] if n == 2 else [0.3, 0.2, 1.0],
                "rough": {"rule": "constant", "rank": n - 1}, "smooth": {"rule": "constant", "rank": 0}}
    # a random choice among specular, completely rough and (3D) rank 1 along a fixed direction
    choices = [{"rule": "constant", "rank": 0}, {"rule": "constant", "rank": n - 1}]
    if n == 3 and flat:     # a fixed roughness direction needs the walls' tangent axes
        choices.append({"rule": "constant", "rank": 1, "direction": [1.0, 0.7, 0.2]})
    return {"rule": "random", "choices": choices, "probabilities": [1.0 / len(choices)] * len(choices)}


def _scenes():
    """(name, table) for every registered table kind that can be sampled, at its example parameters; and the 3D
    Sinai table (a sphere obstacle)."""
    out = [(name, dict(k.example)) for name, k in tables.KINDS.items()]
    out.append(("sinai3d", {"kind": "sinai", "size": [2.0, 1.5, 1.5], "radius": 0.3}))
    scenes = []
    for name, params in out:
        params = dict(params)
        kind = params.pop("kind", name)
        if kind == "wedge":     # the billiard measure cannot be normalised on a wedge: an explicit start
            continue
        scenes.append((name, dict(params, kind=kind)))
    return scenes


SCENES = _scenes()


def _config(table, rule, n, initial=None, collisions=8):
    params = {k: v for k, v in table.items() if k != "kind"}
    flat = all(w.tangents is not None for w in tables.build(table["kind"], params, R).wall_list)
    return {"table": table, "boundary": {"default": _rule(rule, n, flat)}, "ball": {"radius": R, "inertia": "uniform"},
            "initial": initial or {"sample": "billiard"}, "run": {"collisions": collisions, "seed": 5},
            "output": {"record": ["time", "position", "velocity", "angular_velocity", "orientation"]}}


def _start(cfg, n):
    """A start inside the table (halfway along the first flight of a state drawn from the billiard measure) and a
    time T in the middle of the flight after the third collision from there -> (state dict, T)."""
    run = rbx.simulate(cfg, collisions=6)
    t = run.time[0]
    tau = t[1] / 2
    a = run.position[0, 0] + tau * run.velocity[0, 0]
    w = run.angular_velocity[0, 0]
    if n == 2:
        orient = np.array([run.orientation[0, 0] + tau * w])
    else:
        orient = (rotation_from_vector(tau * np.asarray(w)) @ run.orientation[0, 0])[None]
    state = {"position": a[None], "velocity": run.velocity[0, 0][None], "angular_velocity": np.asarray(w)[None],
             "orientation": orient}
    return state, (t[3] + t[4]) / 2 - tau


def _vee(M):
    return np.array([M[2, 1] - M[1, 2], M[0, 2] - M[2, 0], M[1, 0] - M[0, 1]]) / 2


def _engine_states(cfg, states, T, n):
    """Run the engine from each of ``states`` (all on trajectory 0's random stream) and fly freely to time T ->
    (positions, velocities, spins, orientations) at T."""
    exp = rbx.load(cfg)
    M = len(states["position"])
    exp = exp.replace(run=exp.run.__class__(**{**exp.run.__dict__, "trajectories": M}))
    sim = Simulation(exp, state=states)
    sim.keys[:] = sim.keys[0]       # the same draws for every perturbed copy
    sink = MemorySink()
    sim.run(sink)
    rec = sink.records
    out = []
    for j in range(M):
        k = int(np.searchsorted(rec["time"][j], T, side="right")) - 1
        dt = T - rec["time"][j, k]
        a = rec["position"][j, k] + dt * rec["velocity"][j, k]
        w = rec["angular_velocity"][j, k]
        if n == 2:
            orient = rec["orientation"][j, k] + dt * w
        else:
            orient = rotation_from_vector(dt * np.asarray(w)) @ rec["orientation"][j, k]
        out.append((a, rec["velocity"][j, k], w, orient))
    return out


def _finite_differences(cfg, state, T, n, h):
    """Central differences of the engine's time-T map in the tangent coordinates [a, c·θ or c·φ, v, c·ω], c = R√κ
    -> (d, d): column i is the derivative along coordinate i."""
    c = R * np.sqrt(rbx.load(cfg).ball.kappa)
    m = n * (n - 1) // 2
    d = 2 * (n + m)
    states = {k: [] for k in state}
    for i in range(d):
        for sign in (1.0, -1.0):
            a = state["position"][0].copy()
            v = state["velocity"][0].copy()
            w = np.array(state["angular_velocity"][0], float).copy()
            o = np.array(state["orientation"][0], float).copy()
            e = sign * h
            if i < n:
                a[i] += e
            elif i < n + m:
                if n == 2:
                    o = o + e / c
                else:
                    o = rotation_from_vector(np.eye(3)[i - n] * e / c) @ o
            elif i < 2 * n + m:
                v[i - n - m] += e
            else:
                w = w + (e / c if n == 2 else np.eye(3)[i - 2 * n - m] * e / c)
            for k, x in zip(("position", "velocity", "angular_velocity", "orientation"), (a, v, w, o)):
                states[k].append(x)
    states = {k: np.array(x) for k, x in states.items()}
    finals = _engine_states(cfg, states, T, n)
    F = np.zeros((d, d))
    for i in range(d):
        (ap, vp, wp, op), (am, vm, wm, om) = finals[2 * i], finals[2 * i + 1]
        if n == 2:
            dphi = c * (op - om)
        else:
            dphi = c * _vee(op @ om.T)      # the rotation from one to the other: 2hJ + O(h³)
        F[:, i] = np.concatenate([ap - am, np.atleast_1d(dphi), vp - vm, c * (np.atleast_1d(wp) - np.atleast_1d(wm))])
    return F / (2 * h)


def _covered_codes():
    codes = set()
    for _, table in SCENES:
        params = {k: v for k, v in table.items() if k != "kind"}
        codes |= set(tables.build(table["kind"], params, R).codes.tolist())
    return codes


def test_the_scenes_cover_every_primitive():
    known = {v for k, v in vars(geometry).items() if k.isupper() and isinstance(v, int) and v >= 0
             and k not in ("NPARAM",) and k in ("HALFSPACE", "SEGMENT", "CONCAVE_ARC", "CONVEX_ARC", "SPHERE_OUT",
                                               "FOCUS_ARC", "CYLINDER")}
    assert known <= _covered_codes(), known - _covered_codes()


RULES = ("specular", "rough", "random", "hemisphere")
#: the scenes make test takes, each with one rule: a slab, a concave and a focusing arc, segments, an axis box, a
#: dispersing arc, periodic cells and a 3D sphere, and every rule kind (each pair is a loop of its own to compile;
#: where it could, the pair is one whose loop other tests compile too); make stress takes every scene with every
#: rule, which covers every primitive
QUICK_FD = {"strip": "random", "circle": "rough", "rectangle": "random", "stadium": "hemisphere", "sinai": "specular",
            "lorentz": "rough", "sphere": "hemisphere"}
assert set(QUICK_FD.values()) == set(RULES)
FD_CASES = [pytest.param(name, table, rule, id=f"{name}-{rule}",
                         marks=() if QUICK_FD.get(name) == rule else pytest.mark.heavy)
            for name, table in SCENES for rule in RULES]


@pytest.mark.parametrize("name,table,rule", FD_CASES)
def test_tangent_map_equals_finite_differences_of_the_engine(name, table, rule):
    n = tables.dimension(table["kind"], table)
    cfg = _config(table, rule, n)
    state, T = _start(cfg, n)
    J, final = flow_jacobian(cfg, T, state=state)
    J = J[0]
    assert final["collisions"][0] == 3 and final["time"][0] == pytest.approx(T)
    scale = max(1.0, np.abs(J).max())
    errors = {}
    for h in (1e-4, 1e-5, 1e-6):
        errors[h] = np.abs(_finite_differences(cfg, state, T, n, h) - J).max() / scale
    # central differences: error ~ h² (curvature of the map) + ε/h (rounding); the best step must match the tangent
    # to ~1e-6 of its size, and the errors must behave like finite differences (not a fixed offset)
    assert min(errors.values()) < 2e-6, errors
    assert errors[1e-5] < 0.05 * errors[1e-4] or errors[1e-4] < 1e-7, errors


# ---- the orbit, and known spectra ------------------------------------------------------------------------------

def _scene(table, rule, collisions, trajectories=1, seed=3,
           record=("time", "position", "velocity", "angular_velocity", "orientation")):
    return {"table": table, "boundary": {"default": rule}, "ball": {"radius": R, "inertia": "uniform"},
            "initial": {"sample": "billiard"}, "run": {"collisions": collisions, "trajectories": trajectories,
                                                      "seed": seed},
            "output": {"record": list(record)}}


SMOOTH = {"rule": "constant", "rank": 0}
ROUGH2 = {"rule": "constant", "rank": 1}
SINAI = {"kind": "sinai", "size": [2.0, 1.5], "radius": 0.4}


EXAMPLES = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "configs", "examples")
BOUNDARY = os.path.join(os.path.dirname(EXAMPLES), "boundary")
#: variants beside the examples as they are: every rule kind (a 2D hemisphere on curved walls, 3D random
#: directions, exits) and every numerical option
VARIANTS = {
    "circle-hemisphere": ("circle", {"boundary": os.path.join(BOUNDARY, "hemisphere.yaml")}),
    "plates-random-directions": ("plates", {"boundary": os.path.join(BOUNDARY, "plates-random-directions.yaml")}),
    "sinai-compensated-snap": ("sinai", {"numerics": {"compensated": True, "snap": True, "renormalize": 1}}),
    "strip-compensated": ("strip", {"numerics": {"compensated": True, "renormalize": 0}}),
    "lorentz-snap": ("lorentz", {"numerics": {"snap": True, "compensated": True}}),
    # a hemisphere rule: the loop of the sphere's finite-difference case, compiled once for both
    "sphere-snap-compensated": ("sphere", {"numerics": {"snap": True, "compensated": True, "renormalize": 3},
                                           "boundary": {"default": _rule("hemisphere", 3)}}),
    "escape-sinai-compensated": ("escape-sinai", {"numerics": {"compensated": True}}),
}
PARITY = sorted([name[:-5] for name in os.listdir(EXAMPLES) if name.endswith(".yaml")]) + sorted(VARIANTS)
#: the cases make test runs (each a loop of its own to compile): every rule kind, every numerical option, 2D and 3D,
#: slabs, periodic cells, boxes; make stress runs all of PARITY
QUICK_PARITY = ("strip-compensated", "escape-sinai", "circle-hemisphere", "plates-random-directions",
                "sinai-compensated-snap", "lorentz-snap", "sphere-snap-compensated")


def _parity_experiment(name):
    from rbx import config
    base, changes = VARIANTS.get(name, (name, {}))
    path = os.path.join(EXAMPLES, base + ".yaml")
    with open(path) as f:
        data = yaml.safe_load(f)
    data.update(changes)
    trajectories = 3
    if "sample" not in data["initial"]:
        if base in ("wedge", "strip", "plates"):    # infinite walls: no billiard measure; one trajectory
            trajectories = 1
        else:                                       # three different ones (copies of one are warned about)
            data["initial"] = {"sample": "billiard"}
    data["run"] = {"collisions": 400, "trajectories": trajectories, "seed": 5}
    data["output"] = {"record": []}
    return config.from_dict(data, path)


@pytest.mark.parametrize("name", [pytest.param(name, marks=() if name in QUICK_PARITY else pytest.mark.heavy)
                                  for name in PARITY])
def test_the_orbit_is_the_engines(name):
    """The tangent vectors ride on the engine's own loop: ``rbx lyapunov`` follows the orbit ``rbx simulate``
    records, bit for bit — every example, every rule kind (exits and hemispheres too), every numerical option."""
    exp = _parity_experiment(name)
    run = rbx.simulate(exp)
    _, final = flow_jacobian(exp, np.inf)   # to the run's collision count
    want = run.final
    np.testing.assert_array_equal(final["collisions"], want["collisions"])
    np.testing.assert_array_equal(final["alive"], want["alive"])
    for key, theirs in (("position", "position"), ("velocity", "velocity"), ("time", "time"), ("draws", "draws"),
                        ("last_wall", "last_wall"), ("last_rank", "last_rank"),
                        ("angular_velocity", "angular_velocity")):
        np.testing.assert_array_equal(final[key], want[theirs], err_msg=key)
    if exp.numerics.compensated:
        np.testing.assert_array_equal(final["compensation"], want["compensation"])


def test_the_parity_covers_every_rule_kind_and_option():
    from rbx import rules
    kinds, options = set(), set()
    for name in PARITY:
        exp = _parity_experiment(name)
        compiled = rules.compile_rules(exp.wall_rules, exp.geometry())
        kinds |= {int(k) for k in compiled.kind}
        options |= {k for k in ("compensated", "snap") if getattr(exp.numerics, k)}
        if exp.numerics.renormalize == 0:
            options.add("no renormalisation")
    assert {rules.CONSTANT, rules.HEMISPHERE, rules.RANDOM, rules.EXIT} <= kinds
    assert options == {"compensated", "snap", "no renormalisation"}
    # and the cases of make test alone cover them too
    quick = [_parity_experiment(name) for name in QUICK_PARITY]
    assert {rules.CONSTANT, rules.HEMISPHERE, rules.RANDOM, rules.EXIT} <= {
        int(k) for exp in quick for k in rules.compile_rules(exp.wall_rules, exp.geometry()).kind}
    assert all(any(getattr(exp.numerics, k) for exp in quick) for k in ("compensated", "snap"))
    assert any(exp.numerics.renormalize == 0 for exp in quick) and {exp.dimension for exp in quick} == {2, 3}


def _wavefront_exponent(run, centre, rho, first):
    """The classic 2D billiard's largest exponent from trajectory 0 of a specular run (tests/reference.py)."""
    S, T = wavefront_sums(run.position[0], run.velocity[0], run.time[0], centre, rho, first)
    return S / T


@pytest.mark.parametrize("table,centre,rho,collisions", [
    (SINAI, (1.0, 0.75), 0.4 + R, 3000),
    # the L-shaped polygon: its reflex corner (1, 1) becomes a dispersing arc of radius R for the centre
    ({"kind": "polygon", "vertices": [[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]]}, (1.0, 1.0), R, 20000),
])
def test_specular_dispersing_table_gives_the_classic_exponent(table, centre, rho, collisions):
    cfg = _scene(table, SMOOTH, collisions)
    result = lyapunov(cfg)
    expected = _wavefront_exponent(rbx.simulate(cfg), np.array(centre), rho, result.warmup)
    assert expected > 0.01
    assert result.exponents[0] == pytest.approx(expected, rel=2e-3)
    # the rest of the classic spectrum: its mirror image, and zeros for the flow, the energy and the spin, whose
    # finite-time values fall off as log T / T (the vectors start in general position, so the neutral ones carry
    # the flow's shear, growing as T: here about 1.5e-3 at T ≈ 2000 and 1e-4 at T ≈ 20 000)
    assert result.exponents[-1] == pytest.approx(-expected, rel=2e-3)
    T = float(np.sum(result.time))
    assert np.all(np.abs(result.exponents[1:-1]) < np.log(T) / T), (result.exponents, T)


#: the scenes make test runs the sum on: flat walls, a dispersing and a focusing arc, periodic cells, 3D, each with
#: the random, rough or hemisphere rule (a loop that other tests compile too); make stress runs every scene with the
#: random rule
QUICK_SUM = {"polygon": "random", "stadium": "rough", "sinai": "random", "lorentz": "rough", "sphere": "hemisphere"}


@pytest.mark.parametrize("name,table,rule", [pytest.param(name, table, QUICK_SUM.get(name, "random"), id=name,
                                                          marks=() if name in QUICK_SUM else pytest.mark.heavy)
                                             for name, table in SCENES])
def test_exponents_sum_to_zero(name, table, rule):
    """Every collision map and every flight keeps phase-space volume (det = 1): the exponents sum to zero."""
    n = tables.dimension(table["kind"], table)
    result = lyapunov(_config(table, rule, n, collisions=1500))
    assert np.all(np.isfinite(result.exponents))
    assert abs(result.exponents.sum()) < 1e-9 * max(1.0, np.abs(result.exponents).max())


def test_rough_sinai_spectrum_is_symmetric():
    """2D rough maps are parallel (paper, Theorem 2.7 and its corollary): the flow is symplectic and each orbit's
    spectrum comes in pairs ±λ. The rough Sinai table is not ergodic: of these two orbits one is chaotic and the
    other regular (λ₁ ≈ 0), and the error of the pooled exponent says so."""
    result = lyapunov(_scene(SINAI, ROUGH2, 8000, trajectories=2))
    for j in range(2):
        w = result.segment_times[j]
        pairs = result.segment_exponents[j] + result.segment_exponents[j][:, ::-1]
        mean = w @ pairs / w.sum()
        err = np.sqrt(np.sum(((w / w.mean())[:, None] * (pairs - mean)) ** 2, axis=0) / (len(w) * (len(w) - 1)))
        np.testing.assert_allclose(mean, 0.0, atol=4 * err.max() + 2e-3)
    lam1 = np.sort(result.per_trajectory[:, 0])
    assert lam1[0] < 0.02 and lam1[1] > 0.2
    assert result.stderr[0] > 0.25 * (lam1[1] - lam1[0]) / 2   # the spread of the orbits, not of the segments


@pytest.mark.parametrize("table,rule", [
    ({"kind": "circle", "radius": 1.0}, ROUGH2),              # integrable: caustics (paper, figures circle)
    ({"kind": "rectangle", "width": 2.0, "height": 1.0}, ROUGH2),
    ({"kind": "rectangle", "width": 2.0, "height": 1.0}, SMOOTH),
    ({"kind": "polygon", "vertices": [[0, 0], [3, 0], [1, 2]]}, ROUGH2),
])
def test_integrable_and_flat_tables_have_zero_exponents(table, rule):
    """Polynomial growth of the tangent vectors: the finite-time exponents fall like log(T)/T."""
    short = lyapunov(_scene(table, rule, 1000, trajectories=2))
    long = lyapunov(_scene(table, rule, 16000, trajectories=2))
    scale = np.mean(np.linalg.norm(rbx.simulate(_scene(table, rule, 1)).velocity[:, 0], axis=-1))
    assert np.abs(long.exponents).max() < 0.01 * scale
    assert np.abs(long.exponents).max() < 0.3 * np.abs(short.exponents).max() + 1e-12


def test_lyapunov_command_prints_json(tmp_path):
    from click.testing import CliRunner

    from rbx.cli.main import cli
    path = tmp_path / "sinai.yaml"
    path.write_text(json.dumps(_scene(SINAI, SMOOTH, 100)))
    result = CliRunner().invoke(cli, ["lyapunov", str(path), "--collisions", "600", "--json"])
    assert result.exit_code == 0, result.output
    data = json.loads(result.output)
    api = lyapunov(str(path), collisions=600)
    assert data["exponents"] == pytest.approx(list(api.exponents), rel=1e-12)
    assert len(data["stderr"]) == 6 and data["exponents"][0] > 0.5
    # each trajectory's own exponents, per collision as well as per unit time, and the regular share
    assert np.array(data["per_trajectory"]) == pytest.approx(api.per_trajectory, rel=1e-12)
    rate = float(np.sum(api.collisions)) / float(np.sum(api.time))          # collisions per unit time
    assert data["per_collision"] == pytest.approx(list(api.exponents / rate), rel=1e-12)
    assert data["per_collision_stderr"] == pytest.approx(list(api.stderr / rate), rel=1e-12)
    text = CliRunner().invoke(cli, ["lyapunov", str(path), "--collisions", "600"])
    lines = text.output.splitlines()
    at = lines.index(f"per collision (× the mean time between collisions, {1 / rate:.6g}):")
    assert lines[at + 1] == f"  λ1  = {api.exponents[0] / rate: .6f} ± {api.stderr[0] / rate:.6f}", text.output
    share = data["regular_share"]
    assert share["threshold"] == 0.02 and share["share"] == float(np.mean(api.per_trajectory[:, 0] < 0.02))
    assert share["low"] <= share["share"] <= share["high"]
    bad = CliRunner().invoke(cli, ["lyapunov", str(path), "--collisions", "-3"])
    assert bad.exit_code == 2 and bad.output.count("\n") == 1
    # the threshold is a rate in the table's units: --threshold sets it (a table 100 times larger needs 0.0002)
    lam1 = np.sort(api.per_trajectory[:, 0])
    middle = float(0.5 * (lam1[0] + lam1[-1]))
    given = CliRunner().invoke(cli, ["lyapunov", str(path), "--collisions", "600", "--json", "--threshold",
                                     repr(middle)])
    share = json.loads(given.output)["regular_share"]
    assert share["threshold"] == middle and share["share"] == float(np.mean(api.per_trajectory[:, 0] < middle))
    text = CliRunner().invoke(cli, ["lyapunov", str(path), "--collisions", "600", "--trajectories", "3",
                                    "--threshold", repr(middle)])
    assert f"own λ1 < {middle:g} per unit time" in text.output, text.output
    for wrong in ("0", "-1", "nan", "inf"):
        bad = CliRunner().invoke(cli, ["lyapunov", str(path), "--collisions", "600", "--threshold", wrong])
        assert bad.exit_code == 2 and "--threshold" in bad.output and bad.output.count("\n") == 1, bad.output


@pytest.mark.long
def test_no_measurement_is_refused_not_reported_as_zero_or_nan(tmp_path):
    """Nothing to measure is said in one line, exit 2: every trajectory leaving at its first contact (the spectrum
    was 0 ± 0 with exit 0), and one trajectory in one segment (the error was NaN, and --json wrote NaN, not JSON)."""
    import subprocess
    import sys
    exe = os.path.join(os.path.dirname(sys.executable), "rbx")
    with open(os.path.join(EXAMPLES, "escape-sinai.yaml")) as f:     # its table with every wall a hole (its loop is
        gone = yaml.safe_load(f)                                      # the escape example's: compiled once)
    gone["boundary"] = {"default": {"rule": "exit"}}
    gone["run"] = {"collisions": 200, "trajectories": 3, "seed": 1}
    del gone["output"]
    path = tmp_path / "gone.yaml"
    path.write_text(json.dumps(gone))
    one = tmp_path / "one.yaml"
    one.write_text(json.dumps(_scene(SINAI, SMOOTH, 100)))
    for args, words in (([str(path), "--warmup", "0", "--json"], "no collision after the warm-up"),
                        ([str(one), "--collisions", "300", "--segments", "1", "--json"], "no error estimate")):
        r = subprocess.run([exe, "lyapunov", *args], capture_output=True, text=True, timeout=300)
        lines = r.stderr.strip().splitlines()
        assert r.returncode == 2 and len(lines) == 1 and words in lines[0], (r.returncode, r.stderr)
        assert "NaN" not in r.stdout and r.stdout.strip() == ""


# ---- the leading exponents alone, and the re-orthonormalisation every few collisions -------------------------------

ROUGH_SINAI = _scene(SINAI, ROUGH2, 3000, trajectories=2)


# the 3D case is the sum test's sphere scene (its loop is compiled once for both)
@pytest.mark.parametrize("scene,K", [(ROUGH_SINAI, 1),
                                     (_config(dict(SCENES)["sphere"], "random", 3, collisions=1500), 2)],
                         ids=["sinai-rough-1", "sphere-random-2"])
def test_the_leading_exponents_alone_are_the_first_of_the_whole_spectrum(scene, K, monkeypatch):
    """K tangent vectors give the K leading exponents of the whole basis, bit for bit: Benettin's k-th vector
    depends only on the ones before it, and the re-orthonormalisation is triggered by the first vector alone. One
    vector alone is normalised less often (nothing to keep apart): λ₁ to 1e-12, and bit for bit on the whole
    basis's schedule."""
    from rbx import dynamics
    whole = lyapunov(scene)
    lead = lyapunov(scene, exponents=K)
    # something to compare: λ₁ > 0 (the sphere's 0.052 ± 0.003 with Numba 0.68 and NumPy 2, 0.044 ± 0.004 with
    # Numba 0.59 and NumPy 1.26, whose orbit parts from it by an ulp of the time by the third collision)
    assert len(lead.exponents) == K and lead.exponents[0] > 0.02
    np.testing.assert_array_equal(lead.time, whole.time)
    if K == 1:
        assert lead.exponents[0] == pytest.approx(whole.exponents[0], rel=1e-12)
        np.testing.assert_allclose(lead.per_trajectory, whole.per_trajectory[:, :1], rtol=1e-12)
        monkeypatch.setattr(dynamics, "ORTHO_GROWTH_ONE", dynamics.ORTHO_GROWTH)
        lead = lyapunov(scene, exponents=K)
    np.testing.assert_array_equal(lead.exponents, whole.exponents[:K])
    np.testing.assert_array_equal(lead.stderr, whole.stderr[:K])
    np.testing.assert_array_equal(lead.per_trajectory, whole.per_trajectory[:, :K])


def test_reorthonormalising_every_few_collisions_gives_the_same_exponents(monkeypatch):
    """Gram–Schmidt every few collisions (at most ORTHO_EVERY, and as soon as the first vector grew by 16) against
    after every collision: the same orbit and, in exact arithmetic, the same sums (the diagonal of a product of
    triangular factors is the product of their diagonals). In floating point λ₁ and the sum of the spectrum agree
    to 1e-12; the exponents of the nearly neutral directions move by what any change of rounding moves them (a
    third Gram–Schmidt pass moves them as much; docs/tangent-map.md): here 5e-7 of λ₁, a thousandth of their
    standard errors."""
    from rbx import dynamics
    few = lyapunov(ROUGH_SINAI)
    monkeypatch.setattr(dynamics, "ORTHO_EVERY", 1)
    monkeypatch.setattr(dynamics, "ORTHO_GROWTH", np.inf)
    each = lyapunov(ROUGH_SINAI)
    np.testing.assert_array_equal(few.time, each.time)
    assert few.exponents[0] == pytest.approx(each.exponents[0], rel=1e-12)
    assert np.all(np.abs(few.exponents - each.exponents) < 1e-3 * each.stderr)
    assert abs(np.sum(few.exponents) - np.sum(each.exponents)) < 1e-12 * each.exponents[0]


@pytest.mark.parametrize("K", [0, 7, -1, 2.5, True])
def test_the_number_of_exponents_is_checked(K):
    with pytest.raises(ValueError, match="from 1 to 6"):
        lyapunov(_scene(SINAI, SMOOTH, 100), exponents=K)


@pytest.mark.parametrize("option, value", [("warmup", -1000), ("warmup", 0.5), ("warmup", True),
                                           ("warmup", float("nan")), ("segments", 0), ("segments", 2.5)])
def test_the_warm_up_and_the_segments_are_checked(option, value):
    """As the CLI's --warmup and --segments: warmup=-1000 measured over more collisions than the run made (with an
    error bar half the right one), 0.5 became 0, True 1, NaN a raw ValueError of int()."""
    with pytest.raises(ValueError, match=f"^{option} must be an integer ≥ [01], not "):
        lyapunov(_scene(SINAI, SMOOTH, 100), **{option: value})


def test_an_ensemble_too_large_for_memory_is_refused_before_it_is_set_up():
    """rbx.lyapunov(…, trajectories=10**12) raised NumPy's MemoryError (7.28 TiB asked) after setting up; now a
    ConfigError naming trajectories, as rbx.simulate refuses it."""
    from rbx.model import ConfigError
    with pytest.raises(ConfigError, match="^trajectories: 1000000000000 trajectories need about .* GiB of memory"):
        lyapunov(_scene(SINAI, SMOOTH, 100), trajectories=10**12)


@pytest.mark.long
def test_lyapunov_command_follows_k_vectors(tmp_path):
    import subprocess
    import sys
    exe = os.path.join(os.path.dirname(sys.executable), "rbx")
    path = tmp_path / "sinai.yaml"
    path.write_text(json.dumps(ROUGH_SINAI))
    r = subprocess.run([exe, "lyapunov", str(path), "--collisions", "600", "--exponents", "1", "--json"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    data = json.loads(r.stdout)
    api = lyapunov(str(path), collisions=600, exponents=1)
    assert data["exponents"] == [float(api.exponents[0])] and len(data["per_collision"]) == 1
    assert "warm-up excluded" in data["counted"]
    assert "regular and chaotic alike" in data["mean_over"]    # the pooled mean says what it pools
    for bad in ("0", "7"):
        r = subprocess.run([exe, "lyapunov", str(path), "--exponents", bad], capture_output=True, text=True,
                           timeout=300)
        lines = r.stderr.strip().splitlines()
        assert r.returncode == 2 and len(lines) == 1 and "--exponents" in lines[0] and "from 1 to 6" in lines[0], r.stderr


@pytest.mark.long
def test_trajectories_that_left_during_their_warm_up_are_said_apart_from_those_measured():
    """The escape example, a few trajectories: some leave by its gate during their warm-up and measure nothing;
    the output said '4 trajectories, 147 collisions measured' and 'regular orbits: 0 of 1', which did not add up.
    (Six: with four, the orbits of this seed leave one measured, too few for an error, which is refused.)"""
    import subprocess
    import sys
    exe = os.path.join(os.path.dirname(sys.executable), "rbx")
    example = os.path.join(EXAMPLES, "escape-sinai.yaml")
    M = 6
    args = [exe, "lyapunov", example, "--collisions", "500", "--trajectories", str(M)]
    r = subprocess.run([*args, "--json", "--quiet"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    measured = sum(row[0] is not None for row in out["per_trajectory"])
    assert out["measured"] == measured and 1 < measured < M and out["ended_early"] == M
    r = subprocess.run([*args, "--quiet"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[1].startswith(f"{M} trajectories ({M - measured} of them left the table during their warm-up and "
                               "measured nothing), "), lines[1]
    regular = [x for x in lines if x.startswith("regular orbits")]
    assert len(regular) == 1 and f"of the {measured} measured (the other {M - measured} left the table during " \
                                 "their warm-up)" in regular[0], regular
    # what ± and the interval cover is said, as on a study's figure
    assert lines[2] == "  (±: one standard error, about 68 %)", lines
    assert "(Wilson interval, z = 1, about 68 %: " in regular[0], regular


def test_copies_of_one_orbit_give_one_orbits_error_and_an_exit_is_no_regular_orbit():
    """Eight copies of the circle example's one orbit gave an error 2.96 times smaller than the orbit alone (the
    copies counted as samples); an orbit that leaves through an exit is not a trapped one (those leaving just after
    their warm-up have λ₁ = 0: the specular Sinai table with a hole was 2.2 % regular)."""
    import warnings
    circle = os.path.join(EXAMPLES, "circle.yaml")
    one = lyapunov(circle, collisions=100)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)      # copies of one orbit: warned about
        eight = lyapunov(rbx.load(circle, {"run.trajectories": 8}), collisions=100)
        with pytest.raises(ValueError, match="copies of one orbit, and one orbit in one segment"):
            lyapunov(rbx.load(circle, {"run.trajectories": 8}), collisions=100, segments=1)
    assert np.array_equal(eight.exponents, one.exponents) and np.array_equal(eight.stderr, one.stderr)
    # copies count once in the value too, as a study counts them: [A, A, A, B] is [A, B]
    a = {"position": [0.1, -0.2], "velocity": [-0.3, 0.9], "angular_velocity": -2.0}
    b = {"position": [0.3, 0.1], "velocity": [0.8, 0.6], "angular_velocity": 1.0}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        four = lyapunov(rbx.load(circle, {"initial": [a, a, a, b], "run.trajectories": 4}), collisions=300)
    two = lyapunov(rbx.load(circle, {"initial": [a, b], "run.trajectories": 2}), collisions=300)
    assert np.array_equal(four.exponents, two.exponents) and np.array_equal(four.stderr, two.stderr)
    gate = rbx.load(os.path.join(EXAMPLES, "escape-sinai.yaml"), {"run.trajectories": 400, "run.collisions": 300})
    ly = lyapunov(gate, warmup=2)
    lam1 = ly.per_trajectory[:, 0]
    left = np.isfinite(lam1) & ly.ended & (lam1 < 0.02)
    assert left.sum() >= 3            # orbits that left with a small λ₁: the count below tells them apart
    assert ly.regular() == (int(np.sum(np.isfinite(lam1) & ~ly.ended & (lam1 < 0.02))), ly.measured())


def test_an_integrable_tables_exponent_is_said_to_be_finite_time():
    """The specular circle's λ₁ of 3.6e-4 ± 0.5e-4 read as a positive exponent 7 standard errors above 0: when every
    orbit is regular the command says the values are finite-time ones, and the ± their spread. Here the specular
    rectangle, integrable too (its loop is the specular Sinai table's, compiled for other tests)."""
    from click.testing import CliRunner

    from rbx.cli.main import cli
    rectangle = os.path.join(EXAMPLES, "rectangle.yaml")
    result = CliRunner().invoke(cli, ["lyapunov", rectangle, "--set", "boundary={default: {rule: constant, rank: 0}}",
                                      "--set", "initial={sample: billiard}", "--trajectories", "8", "--collisions",
                                      "2000", "--exponents", "1"])
    assert result.exit_code == 0, result.output
    assert "every orbit is regular: their λ1 falls as log t / t, so the values above are finite-time ones" in \
        result.output
    chaotic = CliRunner().invoke(cli, ["lyapunov", os.path.join(EXAMPLES, "lyapunov-sinai.yaml"), "--trajectories",
                                       "4", "--collisions", "600", "--exponents", "1"])
    assert chaotic.exit_code == 0 and "every orbit is regular" not in chaotic.output, chaotic.output
    # the specular Sinai table 100 times larger: below the threshold per unit time, not regular (0.73 per collision)
    large = CliRunner().invoke(cli, ["lyapunov", os.path.join(EXAMPLES, "lyapunov-sinai.yaml"), "--set",
                                     "boundary.default.rank=0", "--set", "table={kind: sinai, size: [200, 150], "
                                     "radius: 40}", "--set", "ball.radius=10", "--trajectories", "8", "--collisions",
                                     "3000", "--exponents", "1"])
    assert large.exit_code == 0 and "every orbit is regular" not in large.output, large.output
    assert "every orbit is below the threshold, but λ1 per collision is 0.7" in large.output, large.output


def test_a_result_prints_as_a_summary():
    """print(rbx.lyapunov(...)) gave the dataclass's repr with every segment's array, 7.7 kB for a short run."""
    ly = lyapunov(_scene(SINAI, SMOOTH, 300, trajectories=2))
    text = repr(ly)
    assert len(text) < 800 and text.startswith("Lyapunov(") and "segment" not in text, text
    assert f"exponents per unit time [{ly.exponents[0]:.4g}, " in text and f"± [{ly.stderr[0]:.4g}, " in text
    assert f"per collision [{ly.per_collision()[0]:.4g}, " in text and "2 trajectories" in text


@pytest.mark.parametrize("d, condition", [(6, 1e2), (6, 1e9), (12, 1e2), (12, 1e9)])
def test_gram_schmidt_gives_numpys_qr_and_keeps_the_rows_orthonormal(d, condition):
    """The re-orthonormalisation against NumPy's QR of Yᵀ: the same Q (up to signs: R_kk > 0 here) and log|R_kk|.
    Rows nearly parallel (condition 1e9) need the second pass, which is taken only where the first cancelled
    more than half of a row's squared length: with one pass alone Q is orthogonal to about 1e-8 there, not 1e-15.
    The stretches are multiplied into ``prod`` and their logarithms added to the sums when the product leaves
    [1e-150, 1e150] (row 0's here, started at 1e149 and stretched by 100) and by ``fold``."""
    from rbx import tangent
    rng = np.random.default_rng(d)
    U, _ = np.linalg.qr(rng.normal(size=(d, d)))
    V, _ = np.linalg.qr(rng.normal(size=(d, d)))
    Y = U @ np.diag(np.geomspace(3.0, 3.0 / condition, d)) @ V
    Y[0] *= 100.0 / np.linalg.norm(Y[0])
    Qr, Rr = np.linalg.qr(Y.T)
    signs = np.sign(np.diag(Rr))
    sums = np.zeros((2, d))
    prod = np.ones(12)
    prod[0] = 1e149
    work = Y.copy()
    (tangent.orthonormalise2 if d == 6 else tangent.orthonormalise3)(work, sums, prod, 1)
    assert np.abs(work @ work.T - np.eye(d)).max() < 1e-14
    np.testing.assert_allclose(work, (Qr * signs).T, atol=1e-14 * condition)
    assert sums[0].tolist() == [0.0] * d and sums[1, 0] != 0.0 and prod[0] == 1.0   # folded: out of range
    logs = np.log(np.abs(np.diag(Rr)))
    logs[0] += np.log(1e149)
    tangent.fold(sums, prod, 1, d)
    assert prod[:d].tolist() == [1.0] * d
    np.testing.assert_allclose(sums[1], logs, rtol=1e-12, atol=1e-12 * condition)


def test_the_leading_exponents_of_a_table_with_a_block_that_never_feeds_back_are_the_leading_ones():
    """The 3D rough box's orientation never feeds back. From the coordinate axes, Benettin's first 8 vectors held
    the orientation's three zeros and, in their place, the most contracting exponent (−0.095 where the whole
    spectrum, sorted, had λ₈ ≈ 0), and `--exponents K` was not the first K of the whole. From a basis in general
    position both agree bit for bit, and the first 8 are the 8 largest but for nearly equal ones."""
    exp = rbx.load(str(Path(__file__).resolve().parents[1] / "configs" / "examples" / "box.yaml"),
                   {"run.collisions": 1000, "run.trajectories": 2})
    whole = lyapunov(exp)
    lead = lyapunov(exp, exponents=8)
    np.testing.assert_array_equal(lead.exponents, whole.exponents[:8])
    np.testing.assert_array_equal(lead.stderr, whole.stderr[:8])
    assert whole.exponents[0] > 0.05 and whole.exponents[-1] < -0.05
    assert lead.exponents.min() > whole.exponents[-1] / 2           # the contracting exponent is the last
    # the order is the decreasing one to within the errors
    assert np.all(np.diff(whole.exponents) < 3 * (whole.stderr[1:] + whole.stderr[:-1]))


# ---- units: the spectrum does not depend on them, and a spectrum that does not sum to 0 is refused --------------

def _scaled_sinai(time, size=1.0, collisions=2000):
    """The lyapunov example's table and a fixed start, in units where its times are ``time`` times and its lengths
    ``size`` times the example's: the same orbit, up to the scale (one trajectory)."""
    with open(os.path.join(EXAMPLES, "lyapunov-sinai.yaml")) as f:
        d = yaml.safe_load(f)
    speed = size / time
    d["initial"] = {"position": [0.3 * size, 0.2 * size], "velocity": [0.6 * speed, 0.8 * speed],
                    "angular_velocity": 3.0 / time}
    d["table"] = {k: (np.multiply(v, size).tolist() if k in ("size", "radius") else v) for k, v in d["table"].items()}
    d["ball"] = {**d["ball"], "radius": d["ball"]["radius"] * size}
    d["run"] = {"collisions": collisions, "trajectories": 1, "seed": 1}
    d.pop("output", None)
    return d


def _per_collision(r):
    return r.exponents * float(np.sum(r.time)) / float(np.sum(r.collisions))


def test_the_exponents_per_collision_do_not_depend_on_the_units():
    """Times 2^±100 (speeds and spins 2^∓100 times) and lengths with times 2^60 change no exponent per collision:
    the tangent vectors are re-orthonormalised in a time unit of the orbit (rbx.dynamics.time_unit), a power of
    two, so the two runs of scaled time are the same arithmetic, bit for bit. In the config's own units the Gram–Schmidt had added a
    velocity to a length 1e30 times larger: at speeds times 2^-100 the two contracting exponents came out at
    +2.9 and +5.9 per collision, with the spectrum summing to 43 λ₁. Each sums to 0."""
    plain = lyapunov(_scaled_sinai(1.0))
    slow, fast = lyapunov(_scaled_sinai(2.0 ** 100)), lyapunov(_scaled_sinai(2.0 ** -100))
    large = lyapunov(_scaled_sinai(2.0 ** 60, size=2.0 ** 60))
    np.testing.assert_array_equal(_per_collision(slow), _per_collision(fast))
    for r in (plain, slow, fast, large):
        pc = _per_collision(r)
        assert abs(np.sum(r.exponents)) < 1e-10 * np.sum(np.abs(r.exponents))
        # the same orbit: the expanding and contracting exponents agree, the near-neutral ones within the finite
        # time's log T / T (the metric moves them: only the limit is independent of it)
        np.testing.assert_allclose(pc[[0, -1]], _per_collision(plain)[[0, -1]], rtol=2e-3)
        assert np.all(np.abs(pc[1:-1]) < 0.01)
        assert pc[0] > 0.15 and pc[-1] < -0.15


def test_a_spectrum_that_does_not_sum_to_zero_is_refused_and_a_frozen_time_is_said(monkeypatch):
    """Without the time unit (its threshold set out of reach) the slow orbit's spectrum no longer sums to 0, and
    lyapunov refuses it in words, where it returned it. A start whose flights vanish against the time reached (a
    velocity of 1e-150 with a spin of 3: the first flight lasts ~1e149) said 'no trajectory moved' before,
    blaming an exit the closed table does not have."""
    from rbx import dynamics
    monkeypatch.setattr(dynamics, "TIME_UNIT_BITS", 10 ** 6)
    with pytest.raises(dynamics.NothingMeasured, match="the spectrum sums to .*, not 0"):
        lyapunov(_scaled_sinai(2.0 ** 100))
    monkeypatch.undo()
    frozen = _scaled_sinai(1.0)
    frozen["initial"]["velocity"] = [1e-150, 1e-150]
    with pytest.raises(dynamics.NothingMeasured, match="the time did not advance over the 1800 collisions"):
        lyapunov(frozen)
