"""The click layer: one module per command, heavy imports inside the command bodies so ``--help`` is instant.

Ctrl-C (or SIGTERM, SIGHUP) while the command line is still being imported (the first tenth of a second; seconds on a
loaded machine) ends the process with exit code 128 + the signal and the one line a command's set-up phase gives
("interrupted by SIGINT; nothing written") instead of a KeyboardInterrupt traceback; :func:`rbx.cli.main.main`
puts its own handler for both in place once everything is imported, and the
commands install theirs.
"""
import os as _os
import signal as _signal
import sys as _sys


def _interrupted_while_starting(signum, frame):
    _sys.stderr.write(f"rbx: interrupted by {_signal.Signals(signum).name}; nothing written\n")
    _os._exit(128 + signum)


if _signal.getsignal(_signal.SIGINT) is _signal.default_int_handler:
    _signal.signal(_signal.SIGINT, _interrupted_while_starting)
# SIGTERM and SIGHUP only in the command itself (`rbx`, `python -m rbx`), not in a process that imports the CLI to
# call it (a SIGHUP there killed `rbx --help` with no line, where SIGTERM at the same instant gave the line)
if _os.path.basename(_sys.argv[0] if _sys.argv else "") in ("rbx", "__main__.py"):
    for _s in (_signal.SIGTERM, _signal.SIGHUP):
        if _signal.getsignal(_s) == _signal.SIG_DFL:
            _signal.signal(_s, _interrupted_while_starting)
