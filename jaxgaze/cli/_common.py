"""What the commands share: argument types, the options every command has (``--out`` and the other
outputs, checked before any work, also against the inputs; ``-q``), the one-line summary, and the
mapping of errors to exit statuses (0 ok, 2 bad input with one line on stderr, 130 on Ctrl-C and 143 on
SIGTERM: see :mod:`jaxgaze.cli._interrupt`). Everything it prints is one line: control characters in
names and paths are escaped (:func:`printable`).
"""

from __future__ import annotations

import argparse
import contextlib
import re
import sys
import warnings

from jaxgaze.cli._arguments import CommandError, int_at_least, negative_values_joined, positive_float
from jaxgaze.cli._files import check_output, check_outputs, declare_inputs, writing
from jaxgaze.cli._interrupt import STATE, interrupt_status
from jaxgaze.io.text import InputFileError
from jaxgaze.rays import UnitWarning

__all__ = ["CommandError", "positive_float", "int_at_least", "QUIET_HELP", "add_quiet", "add_output",
           "add_batch_options", "negative_values_joined", "show_progress", "check_output", "check_outputs", "writing",
           "summary", "stage", "warn", "run_command", "error_line", "TRUST_UNITS_HELP", "add_trust_units", "unit_rule",
           "declare_inputs", "printable"]


#: Characters that would break a line or reach the terminal as a command: C0/C1 controls, line and
#: paragraph separators, and the bidirectional overrides that reorder what is shown.
_UNPRINTABLE = re.compile("[\x00-\x1f\x7f-\x9f\u2028\u2029\u200e\u200f\u202a-\u202e\u2066-\u2069]")


def printable(text) -> str:
    """``text`` with every control character escaped as Python writes it (``\\n``, ``\\x1b``): a name
    or path from a file stays on one line and sends no escape sequence to the terminal."""
    return _UNPRINTABLE.sub(lambda m: repr(m[0])[1:-1], str(text))


def error_line(error) -> str:
    """``what (path:line)``, ``what (path)`` or ``what``: the one line for an error (:func:`printable`)."""
    if error.path is None:
        return printable(error.what)
    where = error.path if error.line is None else f"{error.path}:{error.line}"
    return printable(f"{error.what} ({where})")


def run_command(command, args) -> int:
    """``command(args)`` → its exit status, once :func:`check_outputs` passed; file and argument errors → 2,
    Ctrl-C → 130 (SIGTERM in the console script: 143), one line on stderr."""
    STATE["interrupted"] = False
    try:
        check_outputs(args)
        return int(command(args) or 0)
    except (InputFileError, CommandError) as error:
        print(f"jaxgaze: error: {error_line(error)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        status, line = interrupt_status()
        print(line, file=sys.stderr)
        return status


#: What ``-q`` means in every command.
QUIET_HELP = ("quiet: no progress bar (it is also off when stderr is not a terminal), no progress lines and no "
              "summary; warnings and errors are still shown")


def sampler_figures(diagnostics) -> str:
    """The figures behind a sampler's verdict (``nuts.MixingDiagnostics``), for a command's failure line: each one
    that :func:`jaxgaze.nuts.mixing_result` checks."""
    d = diagnostics
    return (f"split r-hat {d.max_rhat:.3g}, bulk ESS {d.min_ess_bulk:.0f}, tail ESS {d.min_ess_tail:.0f}, "
            f"{d.divergences} of {d.draws} draws divergent, acceptance {d.acceptance_rate:.2f}")


def add_quiet(parser) -> None:
    """``-q/--quiet`` (:data:`QUIET_HELP`), the same in every command."""
    parser.add_argument("-q", "--quiet", action="store_true", help=QUIET_HELP)


def add_output(parser, flag: str, *, what: str = "output", aliases=(), **kwargs):
    """An output file option (``--out`` for a command's main output): before the command runs,
    :func:`run_command` checks it (:func:`check_output`) and that no two outputs share a path.
    ``aliases``: old spellings, still accepted and not shown in the help. ``kwargs`` go to ``add_argument``."""
    action = parser.add_argument(flag, **kwargs)
    for alias in aliases:
        parser.add_argument(alias, dest=action.dest, default=argparse.SUPPRESS, help=argparse.SUPPRESS)
    parser.set_defaults(outputs={**(parser.get_default("outputs") or {}), action.dest: (flag, what)})
    return action


def add_batch_options(parser) -> None:
    """``-q/--quiet`` and ``--chunk F`` (frames per compiled batch), for the commands that run frames in batches."""
    add_quiet(parser)
    parser.add_argument("--chunk", type=int_at_least(1), default=None, metavar="F",
                        help="frames per compiled batch; shorter recordings are padded to F (default: the "
                             "largest that keeps XLA:CPU clear of its LAPACK deadlock, at most 64)")


# ---------------------------------------------------------------------------
# Outputs and stderr


def show_progress(args) -> bool:
    """Progress bars: not with ``-q``, and only when stderr is a terminal."""
    if getattr(args, "quiet", False):
        return False
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):
        return False


def summary(args, text: str) -> None:
    """The command's one summary line on stderr (not with ``-q``; :func:`printable`)."""
    if not getattr(args, "quiet", False):
        print(f"jaxgaze: {printable(text)}", file=sys.stderr)


def stage(args, text: str) -> None:
    """A progress line ``jaxgaze: <stage>…`` on stderr when :func:`show_progress`: between the progress
    bars of a long command, and where a bar cannot be drawn (a terminal of unknown size)."""
    if show_progress(args):
        print(f"jaxgaze: {printable(text)}…", file=sys.stderr, flush=True)


def warn(text: str) -> None:
    """A ``jaxgaze: warning: ...`` line on stderr (also with ``-q``; :func:`printable`)."""
    print(f"jaxgaze: warning: {printable(' '.join(str(text).split()))}", file=sys.stderr)


# ---------------------------------------------------------------------------
# The unit rule


#: What ``--trust-units`` means in every command that reads positions or angles.
TRUST_UNITS_HELP = ("the inputs' units are right although they look implausible (e.g. a scene over 100 m across): "
                    "report them as a warning and go on; without it, implausible units (millimetres for metres, "
                    "degrees for radians) are an error")


def add_trust_units(parser) -> None:
    """``--trust-units`` (:data:`TRUST_UNITS_HELP`), the same in every command that reads positions or angles."""
    parser.add_argument("--trust-units", action="store_true", help=TRUST_UNITS_HELP)


@contextlib.contextmanager
def unit_rule(args, path, frame_ids=None):
    """The one unit rule of the command line. Inside, a :class:`~jaxgaze.rays.UnitWarning` (a value in an
    implausible unit: the library warns) is a :class:`CommandError` naming ``path`` and the override; with
    ``--trust-units`` it stays a warning (passed on to the command's own ``catch_warnings``: enter this one
    inside it, after its ``simplefilter``). ``path`` may be a function of the message (the file it concerns);
    ``frame_ids`` (row → frame id) turn a message's ``frame <row>`` into the file's frame id."""

    def named(what: str) -> str:
        if frame_ids is None:
            return what
        return re.sub(r"\bframe (\d+)\b", lambda m: f"frame {frame_ids[int(m[1])]}"
                      if int(m[1]) < len(frame_ids) else m[0], what)

    if getattr(args, "trust_units", False):
        with warnings.catch_warnings(record=True) as seen:
            warnings.simplefilter("always")
            try:
                yield
            finally:
                passed_on = list(seen)
        for w in passed_on:  # after catch_warnings restored the command's own handler
            message = named(str(w.message)) if issubclass(w.category, UnitWarning) else w.message
            warnings.warn_explicit(message, w.category, w.filename, w.lineno)
        return
    with warnings.catch_warnings():
        warnings.simplefilter("error", UnitWarning)
        try:
            yield
        except UnitWarning as error:
            what = named(str(error))
            raise CommandError(f"{what}; pass --trust-units if they are right",
                               path(what) if callable(path) else path) from None
