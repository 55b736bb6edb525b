"""scripts/bench.py runs at tiny sizes (--quick) in a subprocess and writes every section, table and plot of its
document, so that it cannot rot; no timing is judged. The hand-written loops and the minimal program
(scripts/minimal_loop.py) it compares rbx with must simulate the same orbits, or their ratio means nothing."""
import os
import re
import subprocess
import sys

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "scripts"))

import bench  # noqa: E402

NUMBER = re.compile(r"^-?\d[\d,]*(\.\d+)?(e[+-]\d+)?( \(\d+(\.\d+)? ns\))?$")


def tables(text):
    """Markdown tables of a document -> list of (header cells, [row cells])."""
    out, block = [], []
    for line in text.splitlines() + [""]:
        if line.startswith("|"):
            block.append([c.strip() for c in line.strip().strip("|").split("|")])
        elif block:
            out.append((block[0], block[2:]))
            block = []
    return out


def is_number(cell):
    return bool(NUMBER.match(cell))


@pytest.mark.heavy
def test_bench_writes_its_document(tmp_path):
    out = tmp_path / "b.md"
    proc = subprocess.run([sys.executable, os.path.join(ROOT, "scripts", "bench.py"), "--quick", "--out", str(out)],
                          capture_output=True, text=True, timeout=900, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-3000:]
    text = out.read_text()
    assert "scripts/bench.py --quick" in text and "Machine:" in text and "numba" in text and "Engine:" in text
    # the tangent loop against the engine, and many short orbits against one long one
    assert "## The tangent loop against the engine, and many short orbits" in text
    assert "| sinai | 6 |" in text and "| sampled starts | 1,000 × 100 |" in text and "| explicit states |" in text
    titles = ["## 1. Collisions per second", "## 2. Against a minimal hand-written loop", "## 3. Whole processes",
              "## 4. The cost of recording", "## 5. Ensembles and threads", "## 6. Compilation",
              "## 7. Numerical variants", "## 8. A public peer", "## 9. What each skip saves", "## What stands out"]
    positions = [text.index(t) for t in titles]
    assert positions == sorted(positions)
    for stem in ("rates", "fields", "scaling"):
        assert f"](b-{stem}.png)" in text and (tmp_path / f"b-{stem}.png").stat().st_size > 1000

    found = tables(text)
    for header, rows in found:
        assert rows and all(len(r) == len(header) for r in rows), header
    by_first = {}
    for header, rows in found:
        by_first.setdefault(tuple(header[:2]), []).append(rows)

    # 1: every scene × rule, a rate or an escape
    (rates,), = [v for k, v in by_first.items() if k == ("scene", "dim")]
    assert [r[0] for r in rates] == list(bench.SCENES)
    for r in rates:
        assert all(is_number(c) or c.startswith("escapes after ") or c == "not expressible" for c in r[3:]), r
        assert is_number(r[4]), r                  # the rough rule never escapes in these scenes
    # 2: each hand-written loop, with its ratio
    hand, skip = by_first[("scene", "rule")]      # sections 2 and 9, in that order
    assert [(r[0], r[1]) for r in hand] == list(bench.HAND)
    assert all(is_number(r[2]) and is_number(r[4]) and is_number(r[5]) for r in hand)
    # 2, the rows with a second hand loop that keeps the whole orientation
    (keeping,), = [v for k, v in by_first.items() if k == ("keeping the orientation", "hand-written collisions/s")]
    assert [r[0] for r in keeping] == [f"{s} {r}" for s, r in bench.HAND_KEEPING_A]
    assert all(is_number(r[1]) and is_number(r[2]) for r in keeping)
    # 3: rbx simulate against the minimal program, whole processes: N collisions and one (start-up)
    (proc,), = [v for k, v in by_first.items() if k == ("scene", "collisions")]
    assert [r[0] for r in proc] == list(bench.PROCESS_SCENES)
    assert all(is_number(c) for r in proc for c in r[1:]), proc
    # 4: two scenes, every field, `every`, memory always, HDF5 where run
    fields = by_first[("recorded", "bytes/record")]
    assert len(fields) == len(bench.FIELD_SCENES)
    for rows in fields:
        assert [r[0] for r in rows] == [c[0] for c in bench.FIELD_CASES]
        assert all(is_number(r[2]) and is_number(r[3]) for r in rows)
        run = [r for r in rows if r[0] in bench.QUICK_H5_CASES]
        assert all(is_number(r[4]) and is_number(r[5]) and is_number(r[6]) for r in run)
    # 5: 1 … 1000 trajectories on 1 and 2 threads
    (ens,), = [v for k, v in by_first.items() if k == ("scene", "M")]
    assert [int(r[1]) for r in ens] == list(bench.ENSEMBLE_SIZES) * len(bench.ENSEMBLE_SCENES)
    assert all(is_number(r[3]) and is_number(r[4]) for r in ens)
    # 6: compile against cached start-up, 2D and 3D
    (jit,), = [v for k, v in by_first.items() if k == ("scene", "first run, empty cache (s)")]
    assert [r[0] for r in jit] == list(bench.JIT_SCENES) and all(is_number(c) for r in jit for c in r[1:])
    # 7: every variant on strip and circle
    (var,), = [v for k, v in by_first.items() if k == ("scene", "variant")]
    assert len(var) == len(bench.VARIANTS) * len(bench.VARIANT_SCENES)
    assert all(is_number(r[2]) for r in var)
    # 8: the peer, measured or said to be missing
    (peer,), = [v for k, v in by_first.items() if k == ("scene", "billiards collisions/s")]
    assert [r[0] for r in peer] == list(bench.PEER_SCENES)
    assert all(is_number(r[1]) or r[1].startswith("not installed") for r in peer)
    # 9: every skip, with and without it
    assert [(r[0], r[1], r[2]) for r in skip] == [s[:3] for s in bench.SKIPS]
    assert all(is_number(r[3]) and is_number(r[4]) for r in skip)


#: the skips make test undoes (each undone skip is a loop of its own to compile): spin arithmetic and the slab's
#: closed form; make stress undoes every one
QUICK_SKIPS = (2, 6)


@pytest.mark.parametrize("i", [pytest.param(i, marks=() if i in QUICK_SKIPS else pytest.mark.heavy)
                               for i in range(len(bench.SKIPS))])
def test_undoing_a_skip_keeps_the_orbit(i):
    # section 9 compares the kernel with and without each skip: only the work may differ, not the orbit
    from rbx import config, engine
    from rbx.simulation import MemorySink, Simulation
    scene, rule, _, attr, bit = bench.SKIPS[i]
    d = bench.scene_dict(scene, rule)
    d["run"]["collisions"] = 2000
    finals = []
    for undo in (False, True):
        sim = Simulation(config.from_dict(d, "<bench>"), **({attr: getattr(engine, bit)} if undo else {}))
        sink = MemorySink()
        sim.run(sink)
        finals.append(sink.final)
    for f in ("time", "position", "velocity", "angular_velocity", "collisions"):
        np.testing.assert_allclose(finals[1][f], finals[0][f], rtol=1e-9, atol=1e-12, err_msg=f)


#: the hand loops make test checks (each compiles a loop of its own, and rbx's for the scene): a rule tree, a random
#: rule, a dispersing arc, periodic cells, a 3D box; make stress checks every one
QUICK_HAND = (("strip", "hemisphere"), ("plates", "random"), ("sinai", "rough"), ("lorentz", "rough"), ("box", "rough"))


@pytest.mark.parametrize("scene,rule", [pytest.param(*pair, marks=() if pair in QUICK_HAND else pytest.mark.heavy)
                                        for pair in bench.HAND])
def test_hand_written_loops_agree_with_rbx(scene, rule):
    from rbx.simulation import run_in_memory
    N = bench.HAND_CHECK_COLLISIONS.get(scene, 1000)
    _, _, final = run_in_memory(bench.rbx_config(scene, N, rule))
    s = final["time"][0] + final["position"][0].sum() + final["velocity"][0].sum()
    if rule != "specular":      # the specular loops carry no spin
        s += np.sum(final["angular_velocity"][0])
    assert bench.HAND[scene, rule](N) == pytest.approx(s, rel=1e-9, abs=1e-9)
    # and it is not a coincidence of the sum: one collision more or less changes it
    assert bench.HAND[scene, rule](N + 1) != pytest.approx(s, rel=1e-9, abs=1e-9)


@pytest.mark.parametrize("scene,rule", list(bench.HAND_KEEPING_A))
def test_the_hand_loop_keeping_the_orientation_follows_rbxs_orbit_and_orientation(scene, rule):
    # the yardstick that turns all of A: rbx's orbit, and rbx's orientation (its sum is in the checksum)
    from rbx.simulation import run_in_memory
    N = 1000
    cfg = bench.rbx_config(scene, N, rule)
    _, _, final = run_in_memory(cfg)
    s = (final["time"][0] + final["position"][0].sum() + final["velocity"][0].sum()
         + np.sum(final["angular_velocity"][0]))
    A = np.asarray(final["orientation"][0]).reshape(3, 3)
    assert bench.HAND_KEEPING_A[scene, rule](N) == pytest.approx(s + A.sum(), rel=1e-9, abs=1e-9)
    # the axis loop's checksum, without A: the two differ by A's sum, which is not a constant of the motion
    assert bench.HAND[scene, rule](N) == pytest.approx(s, rel=1e-9, abs=1e-9)
    assert abs(A.sum() - 3.0) > 1e-3


@pytest.mark.parametrize("scene", bench.PROCESS_SCENES)
def test_the_minimal_program_runs_the_hand_loop(scene):
    # section 3 times scripts/minimal_loop.py against rbx simulate: it must be section 2's loop, the same orbit
    import minimal_loop
    for N in (1000, 1001):
        assert minimal_loop.run(scene, N) == pytest.approx(bench.HAND[scene, "rough"](N), rel=1e-12)
    dt, checksum = bench.minimal_run(scene, 1000)      # as the bench runs it: a process printing its checksum
    assert checksum == minimal_loop.run(scene, 1000)


@pytest.mark.parametrize("args,key", [(["strip", "x"], "N"), (["strip", "-5"], "N"), (["cube", "3"], "scene"),
                                      (["strip"], "usage")])
def test_the_minimal_program_refuses_bad_arguments_in_one_line(args, key):
    import subprocess
    res = subprocess.run([sys.executable, bench.MINIMAL_PROGRAM, *args], capture_output=True, text=True)
    assert res.returncode == 2 and res.stdout == "", res
    assert res.stderr.count("\n") == 1 and res.stderr.startswith(f"minimal_loop.py: {key}"), res.stderr


def test_a_missing_peer_is_reported_not_fatal(monkeypatch):
    monkeypatch.setitem(sys.modules, "billiards", None)      # as if not installed: `import billiards` fails
    version, reason, measured = bench.section_peer(None, {})
    assert version is None and reason.startswith("not installed") and measured == {}


def test_a_section_run_again_replaces_its_table_in_the_document(tmp_path):
    """`--studies-only` / `--tangent-only` put their section in place of the one the document holds, so that a
    re-run leaves one table per section, the newest."""
    doc = tmp_path / "b.md"
    doc.write_text("# Bench\n\n## 1. Collisions per second\n\n| a |\n\n## Studies and explicit states\n\nold\n\n"
                   "## The tangent loop against the engine, and many short orbits\n\nold tangent\n")
    bench.append_section(str(doc), ["", "## Studies and explicit states", "", "new", ""])
    text = doc.read_text()
    assert text.count("## Studies and explicit states") == 1 and "\nnew\n" in text and "\nold\n" not in text
    assert "## 1. Collisions per second\n\n| a |" in text and "old tangent" in text
    assert text.index("old tangent") < text.index("\nnew\n")      # the section moved to the end


def test_the_tangent_yardstick_follows_rbxs_orbit():
    # the bench's hand-written tangent loop and rbx's, on the same orbit: λ₁ after every collision's QR agrees
    # (rbx's default puts the speed back every 16 collisions of a specular table: the yardstick turns that off)
    from rbx.dynamics import _Tangent
    exp, hand = bench.yardstick()
    N = 400
    ls, T = hand(N)
    tan = _Tangent(exp)
    tan.Y[:] = np.eye(tan.d)                # as the hand loop starts (rbx's own start is in general position)
    tan.advance(N, ortho=1)
    assert tan.state.time[0] == pytest.approx(T, rel=1e-12)
    assert tan.sums[0, 0] / tan.state.time[0] == pytest.approx(ls / T, rel=1e-9)
    assert ls / T > 0.5                     # a chaotic table: the exponent is not a trivial zero
