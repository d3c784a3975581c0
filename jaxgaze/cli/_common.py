"""What the commands share: argument types, the options every command has (``--out`` and the other
outputs, checked before any work; ``-q``), the one-line summary, and the mapping of errors to exit
statuses (0 ok, 2 bad input with one line on stderr, 130 on Ctrl-C: see :mod:`jaxgaze.cli._interrupt`).
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import re
import sys

from jaxgaze.cli._interrupt import STATE
from jaxgaze.io.text import InputFileError

__all__ = ["CommandError", "positive_float", "int_at_least", "QUIET_HELP", "add_quiet", "add_output",
           "add_batch_options", "negative_values_joined", "show_progress", "check_output", "check_outputs", "writing",
           "summary", "warn", "run_command", "error_line"]


class CommandError(Exception):
    """A bad argument or an output that cannot be written (input files raise
    :class:`~jaxgaze.io.text.InputFileError`): ``what`` and the ``path`` it concerns, if any."""

    def __init__(self, what: str, path=None):
        self.what = " ".join(str(what).split())  # always one line
        self.path = None if path is None else os.fspath(path)
        self.line = None
        super().__init__(self.what)


def error_line(error) -> str:
    """``what (path:line)``, ``what (path)`` or ``what``: the one line for an error."""
    if error.path is None:
        return error.what
    return f"{error.what} ({error.path})" if error.line is None else f"{error.what} ({error.path}:{error.line})"


def run_command(command, args) -> int:
    """``command(args)`` → its exit status, once :func:`check_outputs` passed; file and argument errors → 2,
    Ctrl-C → 130, one line on stderr."""
    try:
        check_outputs(args)
        return int(command(args) or 0)
    except (InputFileError, CommandError) as error:
        print(f"jaxgaze: error: {error_line(error)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("jaxgaze: interrupted", file=sys.stderr)
        return 130


# ---------------------------------------------------------------------------
# Argument types


def positive_float(text: str) -> float:
    """A positive finite number."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a positive finite number, got {text!r}")
    return value


def int_at_least(minimum: int):
    """An argument type: an integer ≥ ``minimum``."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be at least {minimum}, got {value}")
        return value

    parse.__name__ = f"integer >= {minimum}"
    return parse


#: What ``-q`` means in every command.
QUIET_HELP = ("quiet: no progress bar (it is also off when stderr is not a terminal), no progress lines and no "
              "summary; warnings and errors are still shown")


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


def negative_values_joined(argv) -> list:
    """``argv`` made readable to argparse, which takes a value that starts with '-' and is not a plain
    negative number (``-2``, ``-0.5``) for an option. A point ``--opt -1.7,0,2`` becomes
    ``--opt=-1.7,0,2``; a single number such as ``-inf`` or ``-1e-3`` (also one of several values,
    ``--bounds -inf -inf 0 inf inf inf``) gets a trailing space, which argparse reads as a value
    and ``float`` ignores. Plain negative numbers, and everything after ``--``, are left as they are."""
    joined, tokens = [], iter(argv)
    for token in tokens:
        if token == "--":
            return joined + [token, *tokens]
        number_like = token.startswith("-") and not re.fullmatch(r"-\d+|-\d*\.\d+", token) \
            and all(_is_number(x) for x in token.split(","))
        if number_like and "," not in token:
            joined.append(token + " ")
        elif number_like and joined and re.fullmatch(r"--[a-z][\w-]*", joined[-1]):
            joined[-1] = f"{joined[-1]}={token}"
        else:
            joined.append(token)
    return joined


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


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


def check_output(path, what: str = "output") -> None:
    """Fail before any work if the file ``path`` cannot be written: it is (or names) a directory,
    or its directory does not exist or is not writable."""
    text = os.fspath(path)
    full = os.path.abspath(text)
    directory = os.path.dirname(full)
    if os.path.isdir(full) or text.endswith((os.sep, "/")):
        raise CommandError(f"cannot write {what}: it is a directory; give a file name", path)
    if not os.path.isdir(directory):
        raise CommandError(f"cannot write {what}: directory does not exist", path)
    if not os.access(directory, os.W_OK | os.X_OK):
        raise CommandError(f"cannot write {what}: directory is not writable", path)


def check_outputs(args) -> None:
    """:func:`check_output` for every output option given (declared with :func:`add_output`), and
    no two of them the same file."""
    seen = {}
    for dest, (flag, what) in (getattr(args, "outputs", None) or {}).items():
        path = getattr(args, dest, None)
        if path is None:
            continue
        check_output(path, what)
        other = seen.setdefault(os.path.abspath(os.fspath(path)), flag)
        if other != flag:
            raise CommandError(f"{other} and {flag} must be different files", path)


@contextlib.contextmanager
def writing(path, what: str = "output", also: dict | None = None):
    """Around (atomic) writers of ``path`` (and of the paths of ``also``, ``{path: what}``): an
    ``OSError`` becomes ``cannot write <what>: ...`` naming the file it concerns (default ``path``)."""
    STATE["writing"] += 1
    try:
        yield
    except OSError as error:
        targets = {os.path.abspath(os.fspath(p)): (w, p) for p, w in (also or {}).items() if p is not None}
        what, path = targets.get(os.path.abspath(os.fspath(error.filename or path)), (what, path))
        raise CommandError(f"cannot write {what}: {error.strerror or error}", path) from None
    finally:
        STATE["writing"] -= 1


def summary(args, text: str) -> None:
    """The command's one summary line on stderr (not with ``-q``)."""
    if not getattr(args, "quiet", False):
        print(f"jaxgaze: {text}", file=sys.stderr)


def warn(text: str) -> None:
    """A ``jaxgaze: warning: ...`` line on stderr (also with ``-q``)."""
    print(f"jaxgaze: warning: {' '.join(str(text).split())}", file=sys.stderr)
