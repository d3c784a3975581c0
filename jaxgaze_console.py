"""The ``jaxgaze`` console script: signals are handled from its first instant.

Importing the ``jaxgaze`` package imports JAX (about 3 s), and a Ctrl-C in that time was lost or
gave a traceback. This module, outside the package, imports only the standard library: it makes
SIGINT end the process with status 130 and SIGTERM with 143, each with one line on stderr (no
output exists yet), and only then imports :mod:`jaxgaze.cli`, whose
:func:`~jaxgaze.cli.console_main` takes over (:mod:`jaxgaze.cli._interrupt`).
"""

import os
import signal
import sys

#: The signals handled before jaxgaze is imported: their exit status and their one line.
EARLY_SIGNALS = {signal.SIGINT: (130, "jaxgaze: interrupted\n"), signal.SIGTERM: (143, "jaxgaze: terminated\n")}


def _on_early_signal(signum, frame) -> None:
    status, line = EARLY_SIGNALS[signum]
    try:
        sys.stderr.write(line)
        sys.stderr.flush()
    except (OSError, ValueError, AttributeError):
        pass
    os._exit(status)


def main() -> None:
    """Handle SIGINT and SIGTERM, then run :func:`jaxgaze.cli.console_main`."""
    for signum in EARLY_SIGNALS:
        signal.signal(signum, _on_early_signal)
    from jaxgaze.cli import console_main  # after the handlers: this import takes seconds

    console_main()


if __name__ == "__main__":
    main()
