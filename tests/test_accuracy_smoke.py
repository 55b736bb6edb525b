"""scripts/accuracy.py and scripts/stress.py run at tiny sizes (--quick) and write their documents with their
tables, so that they cannot rot. No number is judged here (tests/test_precise.py and tests/test_stress.py do)."""
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def run(script, out):
    proc = subprocess.run([sys.executable, os.path.join(ROOT, "scripts", script), "--quick", "--out", str(out)],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return out.read_text()


def test_accuracy_writes_its_document(tmp_path):
    text = run("accuracy.py", tmp_path / "accuracy.md")
    assert "scripts/accuracy.py --quick" in text and "Machine:" in text
    assert "## Recommended defaults" in text and "| variant | time | energy drift |" in text
    for scene in ("strip", "circle", "rectangle", "L-polygon", "plates", "box"):
        assert f"## {scene}" in text and (tmp_path / f"accuracy-{scene}.png").stat().st_size > 1000
    rows = [line for line in text.splitlines() if line.startswith("| renormalize | 100 |")]
    assert len(rows) == 6 and all(len(r.split("|")) == 10 for r in rows)
    assert "| plain | 10 |" in text


def test_stress_writes_its_document(tmp_path):
    text = run("stress.py", tmp_path / "stress.md")
    assert "scripts/stress.py --quick" in text and "Machine:" in text and "## Summary" in text
    for title in ("Grazing flights", "Exact corner hits", "Wedges", "Tiny and huge tables", "A ball that barely fits",
                  "κ → 0 and κ = 1", "Far along the strip", "Extreme speeds", "A long run"):
        assert f"## {title}" in text, title
    rows = [line for line in text.splitlines() if line.startswith("| ") and not line.startswith("| case")
            and not line.startswith("| variant")]
    assert len(rows) > 50
    # every row has its ten cells (a '|' inside a cell would break the table)
    assert all(len(r.replace("\\|", "").split("|")) == 12 for r in rows if "(collisions/s)" not in r
               and not r.startswith("| plain") and not r.startswith("| renormalize")), \
        [r for r in rows if len(r.replace("\\|", "").split("|")) != 12][:3]
