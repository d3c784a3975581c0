"""Command-line interface: ``jaxgaze demo``, ``concurrences``, ``convert``, ``calibrate``, ``bias``, ``joint``, ``attend`` and ``fit-gaze``.

One module per command, each ``read (jaxgaze.io) → library call → write (jaxgaze.io) → one
summary line``: :mod:`~jaxgaze.cli.demo` (a simulated scene, ``--scene``, against the truth),
:mod:`~jaxgaze.cli.concurrences` (gaze concurrences, Park et al. 2012), :mod:`~jaxgaze.cli.convert`
(another gaze tool's output as rays),
:mod:`~jaxgaze.cli.calibrate` (a wearer's gaze ray), :mod:`~jaxgaze.cli.bias` (speaker-prior
gaze bias, Siegfried et al. 2017), :mod:`~jaxgaze.cli.joint` (biases, cone widths, who looks at whom
and concurrences of a group, inferred together), :mod:`~jaxgaze.cli.attend` and
:mod:`~jaxgaze.cli.fit_gaze` (attention from head pose, Yücel et al. 2013). Exit status 0 on
success (``joint`` and ``calibrate --posterior``: 1 when the fit did not succeed, files written); 2 for bad input, with one line
``jaxgaze: error: <what> (<file>:<line>)`` on stderr and no partial output file; 130 on Ctrl-C, 143 on
SIGTERM (the old outputs untouched: a command's outputs change together or not at all). An output that is
an input file is refused. Names and paths on stderr have their control characters escaped.
"""

from __future__ import annotations

import argparse
import sys
import warnings

from jaxgaze.cli import attend, bias, calibrate, concurrences, convert, demo, fit_gaze, joint
from jaxgaze.cli._common import negative_values_joined, run_command, warn
from jaxgaze.cli._interrupt import exit_status, handle_interrupts
from jaxgaze.runtime import CompilationCacheWarning, enable_compilation_cache

__all__ = ["main", "console_main", "build_parser"]

#: The command modules, in the order of ``jaxgaze --help``.
COMMANDS = (demo, concurrences, convert, calibrate, bias, joint, attend, fit_gaze)


def build_parser() -> argparse.ArgumentParser:
    """The ``jaxgaze`` parser: each module of :data:`COMMANDS` adds its subcommand, run by its ``run``."""
    from jaxgaze import __version__

    parser = argparse.ArgumentParser(
        prog="jaxgaze",
        description="Gaze concurrences (joint attention), calibration, gaze bias and attention targets, in JAX.",
        epilog="Run 'jaxgaze <command> -h' for the options of a command.",
    )
    parser.add_argument("--version", action="version", version=f"jaxgaze {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="<command>", required=True)
    for module in COMMANDS:
        before = set(sub.choices)
        module.add_parser(sub)
        for name in set(sub.choices) - before:
            sub.choices[name].set_defaults(run=module.run)
    return parser


def main(argv=None) -> int:
    """Entry point of the ``jaxgaze`` command; returns the exit status (usage errors: argparse exits 2).
    A value such as ``--targets -1.7,0,2`` is read as the option's value (:func:`negative_values_joined`)."""
    args = build_parser().parse_args(negative_values_joined(sys.argv[1:] if argv is None else argv))
    return run_command(args.run, args)


_SHOWN_WARNINGS = set()


def _warning_line(message, category, filename, lineno, file=None, line=None) -> None:
    """A warning no command caught, as one ``jaxgaze: warning: ...`` line, each text once (JAX's
    complaints about its compilation cache: once in all). A ``ResourceWarning`` (a file another library left
    open, as pupil-labs-neon-recording does) says nothing about the data and is not shown."""
    if issubclass(category, ResourceWarning):
        return
    text = str(message)
    key = "cache" if "persistent compilation cache" in text or category is CompilationCacheWarning else text
    if key not in _SHOWN_WARNINGS:
        _SHOWN_WARNINGS.add(key)
        warn(text)


def console_main() -> None:
    """The ``jaxgaze`` console script: :func:`main` on ``sys.argv``, exit with its status.

    JAX's persistent compilation cache is on (:func:`jaxgaze.runtime.enable_compilation_cache`;
    ``JAXGAZE_CACHE_DIR`` names its folder, ``off`` switches it off). Ctrl-C ends it with status
    130 (SIGTERM: 143) and the old outputs untouched (:mod:`~jaxgaze.cli._interrupt`), through ``os._exit``: the interpreter's normal shutdown, with XLA's threads still running the
    interrupted computation, can crash. :func:`main`, run in-process, returns 130 instead. Warnings
    that no command caught are one line each. The console script itself is :mod:`jaxgaze_console`,
    which handles the signals before this package is imported.
    """
    handle_interrupts()
    warnings.showwarning = _warning_line
    try:
        enable_compilation_cache()  # a second run pays no compilation; JAXGAZE_CACHE_DIR=off switches it off
    except OSError as error:  # an unwritable cache folder costs speed, not the answer
        print(f"jaxgaze: warning: no compilation cache: {error}", file=sys.stderr)
    raise SystemExit(exit_status(main()))
