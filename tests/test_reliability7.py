"""Seventh round: a reader finishes a journal only under the run's lock, a run that fits a small disk finishes there,
``rbx histogram`` keeps the size limits, and a run moved to its ``.partial`` is named where it is. Each test was
seen to fail on the code before its change."""
import os
import subprocess
import sys
import threading

import pytest

import rbx
from rbx import journal
from tests.test_interrupt import assert_same_records, read_run, strip_random, write_config
from tests.test_reliability5 import KILL_MID_APPLY

#: a guard against a hang, not a bound
HANG = 600


def _killed_inside_a_commit(folder, at=5):
    """A run of the strip SIGKILLed halfway through copying its ``at``-th checkpoint's journal into the file:
    ``o.h5.partial`` torn, its journal beside it; and the uninterrupted run's records."""
    write_config(folder, strip_random(30_000, trajectories=3, every=7, record=("time", "position", "wall")))
    rbx.simulate(str(folder / "exp.yaml"), output=str(folder / "ref.h5")).close()
    killed = subprocess.run([sys.executable, "-c", KILL_MID_APPLY.replace("{at}", str(at)), "simulate", "exp.yaml",
                             "-o", "o.h5", "--quiet"], cwd=folder, capture_output=True, text=True, timeout=900)
    assert killed.returncode == -9, killed.stderr
    assert journal.pending(folder / "o.h5.partial")
    return read_run(folder / "ref.h5")


def test_a_reader_finishing_a_journal_holds_the_run_lock_so_a_resume_cannot_finish_under_it(tmp_path, monkeypatch):
    """A reader (``rbx.open``, ``rbx plot``) finished a killed run's pending journal without the run's lock: a
    resume started while the reader copied the pages in (a reader stalled by Ctrl-Z or a loaded machine) applied
    the journal itself, finished the run, and the reader's late pages, of the older checkpoint, were written over
    the complete file. The reader is held inside its copying-in here (an event, no timing) while a resume starts:
    the resume is now refused naming the lock, and once the reader is done it resumes bit for bit."""
    reference = _killed_inside_a_commit(tmp_path)
    partial = tmp_path / "o.h5.partial"
    inside, go = threading.Event(), threading.Event()
    real = journal._apply
    reader_thread = []

    def held(fd, pages, overlay):
        if threading.current_thread() is reader_thread[0] and not inside.is_set():
            inside.set()
            assert go.wait(HANG)
        return real(fd, pages, overlay)
    monkeypatch.setattr(journal, "_apply", held)
    read = {}

    def reader():
        try:
            with rbx.open(partial) as run:
                read["complete"] = run.complete
        except Exception as exc:    # noqa: BLE001 - reported by the main thread
            read["error"] = exc
    thread = threading.Thread(target=reader)
    reader_thread.append(thread)
    thread.start()
    try:
        assert inside.wait(HANG)
        try:
            rbx.resume(tmp_path / "o.h5").close()
            resumed = True
        except rbx.FileError as exc:
            assert "another rbx run is writing it" in str(exc), exc
            resumed = False
    finally:
        go.set()
        thread.join(HANG)
    assert "error" not in read and read["complete"] is False, read
    if not resumed:
        rbx.resume(tmp_path / "o.h5").close()
    assert_same_records(read_run(tmp_path / "o.h5"), reference)
    assert not resumed, "the resume ran while the reader copied its journal in"
