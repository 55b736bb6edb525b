"""scripts/accuracy.py and scripts/stress.py run at tiny sizes (--quick) and write their documents with their
tables, so that they cannot rot. No number is judged here (tests/test_precise.py and tests/test_stress.py do)."""
import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def run(script, out):
    proc = subprocess.run([sys.executable, os.path.join(ROOT, "scripts", script), "--quick", "--out", str(out)],
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return out.read_text()


def tables(text):
    """Markdown tables of a document -> list of (header cells, [row cells]); an escaped '\\|' stays in its cell."""
    out, block = [], []
    for line in text.splitlines() + [""]:
        if line.startswith("|"):
            block.append([c.strip() for c in line.replace("\\|", "¦").strip("|").split("|")])
        elif block:
            out.append((block[0], block[2:]))
            block = []
    return out


def assert_well_formed(text):
    for header, rows in tables(text):
        assert rows, header
        for r in rows:
            assert len(r) == len(header), (header, r)


@pytest.mark.heavy
def test_accuracy_writes_its_document(tmp_path):
    text = run("accuracy.py", tmp_path / "accuracy.md")
    assert "scripts/accuracy.py --quick" in text and "Machine:" in text
    assert "## Recommended defaults" in text and "**Recommended default" in text
    for scene in ("strip", "circle", "rectangle", "L-polygon", "plates", "box"):
        assert f"## {scene}" in text and (tmp_path / f"accuracy-{scene}.png").stat().st_size > 1000
    assert_well_formed(text)
    found = tables(text)
    assert found[0][0][:2] == ["variant", "collisions/s"]
    per_scene = [rows for header, rows in found if header[:2] == ["variant", "N"]]
    assert len(per_scene) == 6
    for rows in per_scene:
        assert {r[0] for r in rows} >= {"plain", "default"} and {r[1] for r in rows} == {"10", "100"}


@pytest.mark.heavy
def test_stress_writes_its_document(tmp_path):
    text = run("stress.py", tmp_path / "stress.md")
    assert "scripts/stress.py --quick" in text and "Machine:" in text and "## Summary" in text
    for title in ("Grazing flights", "Exact corner hits", "Wedges", "Tiny and huge tables", "A ball that barely fits",
                  "κ → 0 and κ = 1", "Far along the strip", "Extreme speeds", "A long run"):
        assert f"## {title}" in text, title
    assert_well_formed(text)
    cases = [r for header, rows in tables(text) if header[0] == "case" for r in rows]
    assert len(cases) > 50 and all(r[-1].startswith(("ok", "BROKEN")) for r in cases)
