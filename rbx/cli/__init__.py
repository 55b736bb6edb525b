"""The click layer: one module per command, heavy imports inside the command bodies so ``--help`` is instant.

Ctrl-C while the command line is still being imported (the first tenth of a second) ends the process with exit
code 130 and one line instead of a KeyboardInterrupt traceback; :func:`rbx.cli.main.main` puts Python's own
handler back once everything is imported, and the commands install theirs.
"""
import os as _os
import signal as _signal
import sys as _sys


def _interrupted_while_starting(signum, frame):
    _sys.stderr.write("rbx: interrupted\n")
    _os._exit(128 + signum)


if _signal.getsignal(_signal.SIGINT) is _signal.default_int_handler:
    _signal.signal(_signal.SIGINT, _interrupted_while_starting)
