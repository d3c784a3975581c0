"""Ctrl-C (SIGINT) and SIGTERM in the ``jaxgaze`` console script: status 130 or 143, one line on
stderr (``jaxgaze: interrupted`` or ``jaxgaze: terminated``), the old outputs untouched, no temporary file.

A ``KeyboardInterrupt`` is not enough there. The interpreter's shutdown while XLA's threads
still run the interrupted computation can segfault (exit -11), and the exception can be lost
in a callback (the garbage collector's) so that the run goes on. So, outside the writing of the
outputs, the handler ends the process at once (``os._exit``): no output exists yet. While the
outputs are written (:func:`jaxgaze.cli._common.writing`) it raises ``KeyboardInterrupt``, and
the writers delete their temporary files and keep the old outputs; should a callback swallow it,
the outputs are not renamed into place all the same. Once the renames have begun, a signal waits
for them to end, so that the outputs are all old or all new. The console script
(:mod:`jaxgaze_console`) installs a first handler of the same effect before anything is imported.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys

__all__ = ["STATE", "SIGNALS", "handle_interrupts", "interrupt_status", "exit_status"]

#: ``writing``: how many :func:`~jaxgaze.cli._common.writing` blocks are open; ``committing``: their
#: outputs are being renamed into place; ``interrupted``: a signal came, ``signal``: which one.
STATE = {"writing": 0, "committing": False, "interrupted": False, "signal": signal.SIGINT}

#: The signals handled: their exit status and their one line.
SIGNALS = {signal.SIGINT: (130, "jaxgaze: interrupted"), signal.SIGTERM: (143, "jaxgaze: terminated")}


def interrupt_status() -> tuple[int, str]:
    """``(exit status, line)`` of the signal that came (Ctrl-C when none did: a ``KeyboardInterrupt``)."""
    return SIGNALS.get(STATE["signal"], SIGNALS[signal.SIGINT])


def _exit(say: bool) -> None:
    """(The signal's line on stderr,) flush stdout and stderr, and end the process at once with its status."""
    status, line = interrupt_status()
    for stream, text in ((sys.stderr, line + "\n" if say else ""), (sys.stdout, ""), (sys.stderr, "")):
        with contextlib.suppress(OSError, ValueError, AttributeError):
            stream.write(text)
            stream.flush()
    os._exit(status)


def _on_interrupt(signum, frame) -> None:
    """The console script's SIGINT and SIGTERM handler: nothing while the outputs are renamed,
    ``KeyboardInterrupt`` while they are written, else the end of the process (see the module's docstring)."""
    STATE["interrupted"], STATE["signal"] = True, signum
    if STATE["committing"]:
        return
    if STATE["writing"]:
        raise KeyboardInterrupt
    _exit(say=True)


def handle_interrupts() -> None:
    """From now on SIGINT and SIGTERM end the process (:func:`_on_interrupt`); for the console script only."""
    for signum in SIGNALS:
        signal.signal(signum, _on_interrupt)


def exit_status(status: int) -> int:
    """The console script's exit: after a signal (status 130 or 143, or one the command lost) the process
    ends at once through ``os._exit``, without the interpreter's shutdown; else ``status``."""
    if status in (130, 143) or STATE["interrupted"]:
        _exit(say=status not in (130, 143))
    return status
