"""The benchmark script runs at a tiny size (so it cannot rot) and writes its table; no timing is asserted."""
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "scripts"))

import bench  # noqa: E402


def test_bench_writes_its_table(tmp_path):
    out = tmp_path / "b.md"
    rows = bench.main(["--collisions", "2000", "--repeats", "1", "--out", str(out)])
    assert [r[0] for r in rows] == ["strip", "circle", "plates"]
    assert all(r[1] > 0 and r[2] > 0 for r in rows)
    text = out.read_text()
    assert "| strip |" in text and "Machine:" in text and "scripts/bench.py" in text


def test_hand_written_loops_agree_with_rbx():
    # the reference loops must simulate the same physics, or the ratio means nothing
    import numpy as np
    from rbx.simulate import run_in_memory
    for name, (_, _, _, _, hand) in bench.SCENES.items():
        _, _, final = run_in_memory(bench.rbx_config(name, 1000))
        s = final["time"][0] + final["position"][0].sum() + final["velocity"][0].sum() \
            + np.sum(final["angular_velocity"][0])
        assert hand(1000) == __import__("pytest").approx(s, rel=1e-9, abs=1e-9), name
