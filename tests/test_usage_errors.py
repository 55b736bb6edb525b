"""One voice on the command line: every usage mistake of every command is exactly one line
``rbx: <file, option, argument or command>: <problem>`` on stderr, exit 2, nothing on stdout, never click's
usage block nor a traceback. Real ``rbx`` processes (the console script), a table of command × mistake. And what a
command says when it works: a progress bar on a terminal only, then one summary line."""
import os
import pty
import re
import shlex
import subprocess
import sys

import pytest

from tests.test_interrupt import RBX

#: (command line, what the line names first). Files named here do not exist, except the folder ``folder``.
MISTAKES = {
    "rbx": [
        (["--bogus"], "--bogus"),                               # unknown option
        (["simlate", "x.yaml"], "simlate"),                     # unknown command (did you mean simulate?)
        (["bogus"], "bogus"),
    ],
    "simulate": [
        (["simulate"], "CONFIG"),                               # missing argument
        (["simulate", "x.yaml", "y.yaml"], "simulate"),          # extra argument
        (["simulate", "--bogus"], "--bogus"),                   # unknown option
        (["simulate", "x.yaml", "--colisions", "9"], "--colisions"),
        (["simulate", "x.yaml", "--collisions"], "--collisions"),   # option without its value
        (["simulate", "x.yaml", "--collisions", "abc"], "--collisions"),   # bad value
        (["simulate", "x.yaml", "--slices", "0"], "--slices"),  # out of range
        (["simulate", "x.yaml", "--slices", "2"], "--slices"),  # only with --scheduler
        (["simulate", "x.yaml"], "x.yaml"),                     # missing file
        (["simulate", "folder"], "folder"),                     # a folder for a file
        (["simulate", "--resume"], "--resume"),
        (["simulate", "--resume", "x.h5"], "x.h5"),
        (["simulate", "--resume", "folder"], "folder"),
        (["simulate", "x.yaml", "--resume", "x.h5"], "--resume"),   # both
        (["simulate", "x.yaml", "--set"], "--set"),             # --set without its KEY=VALUE
        (["simulate", "x.yaml", "--set", "ball.inertia"], "--set"),  # no '='
        (["simulate", "x.yaml", "--set", "ball.inertia=[0.2"], "--set ball.inertia"),   # not YAML
        (["simulate", "x.yaml", "--set", "a=1", "--set", "a=2"], "--set"),   # a key set twice
        (["simulate", "--resume", "x.h5", "--set", "run.seed=1"], "--set"),  # the run's settings are its file's
    ],
    "plot": [
        (["plot"], "OUT.h5"),
        (["plot", "x.h5"], "--kind"),                           # a required option (its choices on one line)
        (["plot", "--bogus"], "--bogus"),
        (["plot", "x.h5", "--kind"], "--kind"),
        (["plot", "x.h5", "--kind", "orbt"], "--kind"),
        (["plot", "x.h5", "--kind", "orbit", "--dpi", "abc"], "--dpi"),
        (["plot", "x.h5", "--kind", "orbit", "--dpi", "100000"], "--dpi"),
        (["plot", "x.h5", "--kind", "orbit"], "x.h5"),
        (["plot", "folder", "--kind", "orbit"], "folder"),
        (["plot", "x.h5", "y.h5", "z.h5", "--kind", "orbit"], "plot"),
    ],
    "histogram": [
        (["histogram"], "CONFIG"),
        (["histogram", "--bogus"], "--bogus"),
        (["histogram", "x.yaml", "y.yaml"], "histogram"),
        (["histogram", "x.yaml", "--trajectories", "abc"], "--trajectories"),
        (["histogram", "x.yaml", "--seed"], "--seed"),
        (["histogram", "x.yaml", "--task-collisions", "0"], "--task-collisions"),
        (["histogram", "x.yaml"], "x.yaml"),
        (["histogram", "folder"], "folder"),                   # the file given, not the placeholder
        (["histogram", "x.yaml", "--set", "=0.2"], "--set"),
        (["histogram", "x.yaml", "--data"], "--data"),
    ],
    "lyapunov": [
        (["lyapunov"], "CONFIG"),
        (["lyapunov", "--bogus"], "--bogus"),
        (["lyapunov", "x.yaml", "y.yaml"], "lyapunov"),
        (["lyapunov", "x.yaml", "--segments", "0"], "--segments"),
        (["lyapunov", "x.yaml", "--warmup", "-1"], "--warmup"),
        (["lyapunov", "x.yaml", "--collisions", "1e3"], "--collisions"),
        (["lyapunov", "x.yaml", "--json", "yes"], "lyapunov"),
        (["lyapunov", "x.yaml"], "x.yaml"),
        (["lyapunov", "folder"], "folder"),
        (["lyapunov", "x.yaml", "--set", "ball.inertia"], "--set"),
    ],
    "sweep": [
        (["sweep"], "STUDY.yaml"),
        (["sweep", "x.yaml"], "-o, --output"),                  # a required option
        (["sweep", "--bogus"], "--bogus"),
        (["sweep", "x.yaml", "y.yaml", "-o", "r.nc"], "sweep"),
        (["sweep", "x.yaml", "-o"], "-o"),
        (["sweep", "x.yaml", "-o", "r.nc"], "x.yaml"),
        (["sweep", "folder", "-o", "r.nc"], "folder"),
    ],
    "animate": [
        (["animate"], "RUN.h5"),
        (["animate", "x.h5"], "-o, --output"),
        (["animate", "--bogus"], "--bogus"),
        (["animate", "x.h5", "-o"], "-o"),
        (["animate", "x.h5", "-o", "a.gif", "--fps", "0"], "--fps"),
        (["animate", "x.h5", "-o", "a.gif", "--trajectory", "one"], "--trajectory"),
        (["animate", "x.h5", "-o", "a.gif"], "x.h5"),
        (["animate", "folder", "-o", "a.gif"], "folder"),
        (["animate", "x.h5", "-o", "a.txt"], "a.txt"),
    ],
}

CASES = [pytest.param(args, first, id=f"{command}:{' '.join(args) or '(nothing)'}")
         for command, cases in MISTAKES.items() for args, first in cases]


def test_every_command_is_in_the_table():
    from rbx.cli.main import cli
    assert set(MISTAKES) == {"rbx", *cli.commands}


@pytest.mark.long
@pytest.mark.parametrize("args, first", CASES)
def test_a_usage_mistake_is_one_line_and_exit_2(args, first, tmp_path):
    (tmp_path / "folder").mkdir()
    res = subprocess.run([RBX, *args], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert "Traceback" not in res.stderr, res.stderr
    assert res.returncode == 2, res.stderr
    assert res.stdout == "", res.stdout
    assert res.stderr.endswith("\n") and res.stderr.count("\n") == 1, res.stderr      # exactly one line
    line = res.stderr.rstrip("\n")
    assert line.strip() and line.startswith(f"rbx: {first}: "), line
    assert "Usage:" not in line and "Error:" not in line, line


def test_a_near_miss_is_named(tmp_path):
    """An unknown command or option close to one that exists says which."""
    res = subprocess.run([RBX, "simlate"], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert "did you mean simulate" in res.stderr, res.stderr
    res = subprocess.run([RBX, "simulate", "x.yaml", "--colisions", "9"], cwd=tmp_path, capture_output=True,
                         text=True, timeout=300)
    assert "did you mean --collisions" in res.stderr, res.stderr


# ---- progress and summary ---------------------------------------------------------------------------------------

#: ``python -c`` running the CLI with small blocks and a progress bar that may appear at once (delay 0), so that a
#: short run calls it many times
PROGRESS_AT_ONCE = ("import sys, rbx.simulation as s, rbx.cli.common as c; s.BLOCK_WORK = 3000; s.CHECKPOINT_SECONDS = 0\n"
                    "init = c.Progress.__init__\n"
                    "def at_once(self, *a, **k):\n"
                    "    init(self, *a, **k); self.delay = 0\n"
                    "c.Progress.__init__ = at_once\n"
                    "from rbx.cli.main import main; sys.argv[0] = 'rbx'; main()")

SUMMARY = re.compile(r"rbx: wrote run\.h5: 3 trajectories × 20000 collisions in [0-9.]+ (s|min)[^\n]*"
                     r"(setting up|compiling kernels for this scene, once: [^)]*)\)")


def progress_config(folder):
    from tests.test_interrupt import strip_random, write_config
    write_config(folder, strip_random(20_000, trajectories=3, every=7, record=("time", "position")))


@pytest.mark.long
def test_a_redirected_run_logs_no_progress_bar_and_one_summary_line(tmp_path):
    """stderr to a file (a batch job's log): no progress bar at all (it wrote a \\r line per update: the run here
    updates it dozens of times), and the run ends with its one summary line; --quiet leaves that out too."""
    progress_config(tmp_path)
    with open(tmp_path / "log", "w") as log:
        res = subprocess.run([sys.executable, "-c", PROGRESS_AT_ONCE, "simulate", "exp.yaml", "-o", "run.h5"],
                             cwd=tmp_path, stdout=subprocess.PIPE, stderr=log, text=True, timeout=900)
    text = (tmp_path / "log").read_text()
    assert res.returncode == 0, text
    assert "\r" not in text and "collisions/s" not in text, text
    assert SUMMARY.fullmatch(text.rstrip("\n")) and text.count("\n") == 1, text
    assert res.stdout == ""
    res = subprocess.run([RBX, "simulate", "exp.yaml", "-o", "run.h5", "--force", "--quiet"], cwd=tmp_path,
                         capture_output=True, text=True, timeout=900)
    assert res.returncode == 0 and res.stderr == "" and res.stdout == "", res.stderr


@pytest.mark.long
def test_on_a_terminal_the_progress_bar_shows_rate_and_time_left(tmp_path):
    """stderr a terminal (a pseudo-terminal here): the bar, redrawn in place, with the collisions per second and
    the time left, then the summary on its own line."""
    progress_config(tmp_path)
    leader, follower = pty.openpty()
    try:
        proc = subprocess.Popen([sys.executable, "-c", PROGRESS_AT_ONCE, "simulate", "exp.yaml", "-o", "run.h5"],
                                cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=follower)
        os.close(follower)
        chunks = []
        while True:
            try:
                chunk = os.read(leader, 4096)
            except OSError:         # the terminal's other end closed: the process ended
                break
            if not chunk:
                break
            chunks.append(chunk)
        assert proc.wait(timeout=900) == 0
    finally:
        os.close(leader)
    text = b"".join(chunks).decode().replace("\r\n", "\n")
    bars = [part for part in text.split("\r") if part.startswith("simulate [")]
    assert bars, text
    assert re.search(r"\d+(\.\d+)?[kMG]? collisions/s .* eta [0-9]", bars[-1]) and "100.0%" in bars[-1], bars[-1]
    assert SUMMARY.fullmatch(text.rsplit("\n", 2)[-2]), text


def test_the_bar_is_drawn_on_terminals_and_notebooks_only():
    """A captured stream gets nothing; a Jupyter notebook's stderr (rbx.simulate(progress=True)) is drawn on, as it
    shows \\r updates in place."""
    import io

    from rbx.cli.common import Progress

    class OutStream(io.StringIO):      # what ipykernel puts in sys.stderr
        pass
    OutStream.__module__ = "ipykernel.iostream"
    for stream, drawn in ((io.StringIO(), False), (OutStream(), True)):
        bar = Progress("simulate", delay=0, stream=stream, trajectories=3)
        bar(5, 10)
        bar(10, 10)
        bar.close()
        assert ("\r" in stream.getvalue() and "eta" in stream.getvalue()) == drawn, stream.getvalue()
    # a run done within the delay shows no bar, even at its end (it drew "100.0% ? collisions/s eta ?")
    stream = OutStream()
    bar = Progress("simulate", delay=60, stream=stream, trajectories=3)
    bar(5, 10)
    bar(10, 10)
    bar.close()
    assert stream.getvalue() == ""


@pytest.mark.parametrize("words,cword,expected", [
    ("rbx sim", 1, "plain,simulate"),
    ("rbx simulate --col", 2, "plain,--collisions"),
    ("rbx plot x.h5 --ki", 3, "plain,--kind"),
])
def test_shell_completion_names_commands_and_options(words, cword, expected):
    """README: `eval "$(_RBX_COMPLETE=bash_source rbx)"` completes commands and options (click's completion, through
    rbx's own group and commands)."""
    source = subprocess.run([RBX], env=dict(os.environ, _RBX_COMPLETE="bash_source"), capture_output=True,
                            text=True, timeout=120)
    assert source.returncode == 0 and "_rbx_completion()" in source.stdout, source.stderr
    env = dict(os.environ, COMP_WORDS=words, COMP_CWORD=str(cword), _RBX_COMPLETE="bash_complete")
    res = subprocess.run([RBX], env=env, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0 and expected in res.stdout.split(), (res.stdout, res.stderr)


def test_the_readme_says_the_compile_notice_is_for_terminals_only():
    """The line said before a first compile is printed only when stderr is a terminal (a program reading stderr
    gets the summary line, which says how long the compile took); the README said it is printed, without that."""
    from pathlib import Path
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    text = " ".join(readme.split())
    start = text.index("Before a first compile")
    sentence = text[start:text.index("Results go to stdout", start)]
    assert "only when stderr is a terminal" in sentence, sentence
    quick = text[text.index("The first `rbx simulate` of a table compiles"):]
    quick = quick[:quick.index("`make reproduce-figures`")]
    assert "on a terminal" in quick, quick


def test_a_command_stopped_by_sigterm_says_sigterm_and_exits_143():
    """rbx plot and rbx animate said 'interrupted by SIGINT' and exited 130 for a SIGTERM: the one line names the
    signal that came (noted by the handler main() installs), and the exit is 128 + its number."""
    code = ("import os, signal\n"
            "from rbx.cli.common import interrupted_exit, note_interrupt\n"
            "signal.signal(signal.SIGTERM, note_interrupt)\n"
            "try:\n    os.kill(os.getpid(), signal.SIGTERM)\n    signal.pause()\n"
            "except KeyboardInterrupt:\n    interrupted_exit()\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == 143 and res.stderr == "rbx: interrupted by SIGTERM; nothing written\n", res.stderr


def test_a_noted_interrupt_lost_in_a_callback_is_not_reported_as_a_traceback():
    """SIGTERM at the instant an import ran its module-lock callback: Python printed "Exception ignored in …
    Traceback … KeyboardInterrupt" before rbx's one line (the signal was noted, and said by the command)."""
    code = ("import weakref\n"
            "from rbx.cli.common import quiet_noted_interrupts\n"
            "class A: pass\n"
            "def cb(_):\n    raise KeyboardInterrupt\n"
            "def run():\n    a = A(); r = weakref.ref(a, cb); del a\n"
            "run()\n"                                   # reported by Python, as before
            "quiet_noted_interrupts()\n"
            "run()\n"                                   # left out
            "def other(_):\n    raise ValueError('kept')\n"
            "a = A(); r = weakref.ref(a, other); del a\n")   # anything else still reported
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert res.stderr.count("Exception ignored") == 2 and res.stderr.count("KeyboardInterrupt") == 1 \
        and "ValueError: kept" in res.stderr, res.stderr


def test_a_stdout_that_cannot_be_written_is_one_line_and_exit_1(tmp_path):
    """`rbx --help >/dev/full` gave a 40-line traceback through click, and a command run with stdout closed lost
    what it printed with exit 0."""
    rbx = os.path.join(os.path.dirname(sys.executable), "rbx")
    if os.path.exists("/dev/full"):
        with open("/dev/full", "w") as full:
            res = subprocess.run([rbx, "--help"], stdout=full, stderr=subprocess.PIPE, text=True, timeout=120)
        assert res.returncode == 1 and res.stderr == "rbx: stdout: cannot write: No space left on device\n", \
            res.stderr
    res = subprocess.run(["bash", "-c", f"exec {shlex.quote(rbx)} --version >&-"], stderr=subprocess.PIPE,
                         text=True, timeout=120)
    assert res.returncode == 1 and res.stderr == "rbx: stdout: cannot write: it was closed before rbx started\n", \
        res.stderr
    res = subprocess.run([rbx, "--version"], capture_output=True, text=True, timeout=120)     # and as before
    assert res.returncode == 0 and res.stdout.startswith("rbx, version ") and res.stderr == ""
