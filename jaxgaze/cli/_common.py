"""What the commands share: argument types, output checks, the one-line summary, and the
mapping of errors to exit statuses (0 ok, 2 bad input with one line on stderr, 130 on Ctrl-C).
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import sys

from jaxgaze.io.text import InputFileError

__all__ = ["CommandError", "positive_float", "int_at_least", "add_batch_options", "show_progress", "check_output",
           "writing", "summary", "warn", "run_command", "error_line"]


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
    """``command(args)`` → its exit status; file and argument errors → 2, Ctrl-C → 130, one line on stderr."""
    try:
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


def add_batch_options(parser) -> None:
    """``-q/--quiet`` and ``--chunk F`` (frames per compiled batch), for the commands that run frames in batches."""
    parser.add_argument("-q", "--quiet", action="store_true",
                        help="no progress bar (it is also off when stderr is not a terminal) and no summary line")
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
    """Fail before any work if ``path``'s directory does not exist."""
    if not os.path.isdir(os.path.dirname(os.path.abspath(os.fspath(path)))):
        raise CommandError(f"cannot write {what}: directory does not exist", path)


@contextlib.contextmanager
def writing(path, what: str = "output", also: dict | None = None):
    """Around (atomic) writers of ``path`` (and of the paths of ``also``, ``{path: what}``): an
    ``OSError`` becomes ``cannot write <what>: ...`` naming the file it concerns (default ``path``)."""
    try:
        yield
    except OSError as error:
        targets = {os.path.abspath(os.fspath(p)): (w, p) for p, w in (also or {}).items() if p is not None}
        what, path = targets.get(os.path.abspath(os.fspath(error.filename or path)), (what, path))
        raise CommandError(f"cannot write {what}: {error.strerror or error}", path) from None


def summary(args, text: str) -> None:
    """The command's one summary line on stderr (not with ``-q``)."""
    if not getattr(args, "quiet", False):
        print(f"jaxgaze: {text}", file=sys.stderr)


def warn(text: str) -> None:
    """A ``jaxgaze: warning: ...`` line on stderr (also with ``-q``)."""
    print(f"jaxgaze: warning: {' '.join(str(text).split())}", file=sys.stderr)
