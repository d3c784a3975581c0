"""Reading the text inputs (pose files, OpenFace CSV, speech segments): one error type, one reader;
and :func:`atomic_path`, the one way jaxgaze writes an output file.

Every reader reports a malformed file as a ``ValueError`` whose message starts with
``path, line N:`` (or ``path:`` when no line applies), so that the command line can
print it as one line.
"""

from __future__ import annotations

import contextlib
import math
import os
import tempfile
from typing import Optional

__all__ = ["InputFileError", "atomic_path", "read_text", "read_lines", "parse_number", "header_problem"]


class InputFileError(ValueError):
    """A malformed input file. The message starts with ``path, line N:``."""

    def __init__(self, message: str, path, line: Optional[int] = None):
        self.path = os.fspath(path)
        self.line = line
        where = self.path if line is None else f"{self.path}, line {line}"
        super().__init__(f"{where}: {message}")


def read_text(path, error: type[InputFileError] = InputFileError, what: str = "file") -> str:
    """The contents of a UTF-8 text file (a BOM is dropped); ``error`` for a missing or
    unreadable file or bad bytes, naming the file as ``what`` ("model file not found")."""
    try:
        with open(path, "rb") as handle:
            data = handle.read()
    except FileNotFoundError:
        raise error(f"{what} not found", path) from None
    except IsADirectoryError:
        raise error(f"is a directory, not a {what}", path) from None
    except OSError as exc:
        raise error(f"cannot read the {what}: {exc.strerror or exc}", path) from None
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise error(f"not UTF-8 text: {exc.reason}", path, data[: exc.start].count(b"\n") + 1) from None


def read_lines(path, error: type[InputFileError] = InputFileError) -> list[str]:
    """The lines of a UTF-8 text file (a BOM is dropped); ``error`` for a missing file or bad bytes."""
    return read_text(path, error).splitlines()


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path next to ``path`` and ``os.replace`` it onto ``path`` only on success.

    The temporary file keeps ``path``'s extension (writers such as OpenCV's pick the
    format from it) and gets the permissions an existing ``path`` has (else the
    umask's). On any failure it is deleted and an existing ``path`` is left untouched,
    so no half-written output is ever seen. ``OSError`` propagates.
    """
    target = os.path.abspath(os.fspath(path))
    stem, ext = os.path.splitext(os.path.basename(target))
    fd, tmp = tempfile.mkstemp(dir=os.path.dirname(target), prefix=f".{stem}.", suffix=f".tmp{ext}")
    os.close(fd)
    try:
        try:
            file_mode = os.stat(target).st_mode & 0o7777
        except OSError:
            umask = os.umask(0)
            os.umask(umask)
            file_mode = 0o666 & ~umask
        os.chmod(tmp, file_mode)
        yield tmp
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def parse_number(text: str, what: str, path, line: int, error: type[InputFileError] = InputFileError) -> float:
    """``float(text)``, finite, or ``error`` naming ``what`` at ``path, line``."""
    try:
        value = float(text)
    except ValueError:
        raise error(f"{what} is not a number: {text!r}", path, line) from None
    if not math.isfinite(value):
        raise error(f"{what} is not finite: {text!r}", path, line)
    return value


def header_problem(names: list[str], required, *, hint: str, watched=None) -> Optional[str]:
    """What is wrong with a CSV header, in one line, or ``None``.

    A column of ``watched`` (default: every non-empty name) that appears twice, or
    columns of ``required`` that are missing (``hint`` says what is needed). The
    caller raises its own error type at the header line.
    """
    watched = [n for n in names if n] if watched is None else list(watched)
    duplicated = [n for n in dict.fromkeys(watched) if names.count(n) > 1]
    if duplicated:
        return f"duplicate column '{duplicated[0]}' in the header"
    missing = [c for c in required if c not in names]
    if missing:
        return ("missing column" + ("s " if len(missing) > 1 else " ") + ", ".join(f"'{c}'" for c in missing)
                + f" in the header ({hint})")
    return None
