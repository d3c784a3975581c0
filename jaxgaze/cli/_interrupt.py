"""Ctrl-C in the ``jaxgaze`` console script: status 130, one line on stderr, no output file.

A ``KeyboardInterrupt`` is not enough there. The interpreter's shutdown while XLA's threads
still run the interrupted computation can segfault (exit -11), and the exception can be lost
in a callback (the garbage collector's) so that the run goes on. So, outside the writing of an
output, the handler ends the process at once (``os._exit(130)``): no output exists yet. While
an output is written (:func:`jaxgaze.cli._common.writing`) it raises ``KeyboardInterrupt``,
and the atomic writer deletes its temporary file and keeps the old one.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys

__all__ = ["STATE", "handle_interrupts", "exit_status"]

#: ``writing``: how many :func:`~jaxgaze.cli._common.writing` blocks are open; ``interrupted``: Ctrl-C was pressed.
STATE = {"writing": 0, "interrupted": False}


def _exit_130(say: bool) -> None:
    """(``jaxgaze: interrupted`` on stderr,) flush stdout and stderr, and end the process at once with status 130."""
    for stream, text in ((sys.stderr, "jaxgaze: interrupted\n" if say else ""), (sys.stdout, ""), (sys.stderr, "")):
        with contextlib.suppress(OSError, ValueError, AttributeError):
            stream.write(text)
            stream.flush()
    os._exit(130)


def _on_interrupt(signum, frame) -> None:
    """The console script's SIGINT handler: ``KeyboardInterrupt`` while an output is written, else
    the end of the process (see the module's docstring)."""
    STATE["interrupted"] = True
    if STATE["writing"]:
        raise KeyboardInterrupt
    _exit_130(say=True)


def handle_interrupts() -> None:
    """From now on Ctrl-C ends the process with status 130 (:func:`_on_interrupt`); for the console script only."""
    signal.signal(signal.SIGINT, _on_interrupt)


def exit_status(status: int) -> int:
    """The console script's exit: after a Ctrl-C (status 130, or one the command lost) the process
    ends at once through ``os._exit(130)``, without the interpreter's shutdown; else ``status``."""
    if status == 130 or STATE["interrupted"]:
        _exit_130(say=status != 130)
    return status
