"""Reading the text inputs: one error type (:class:`InputFileError`), one text reader
(:func:`read_text`), one CSV table reader (:func:`read_csv_table`); and :func:`atomic_path`,
the one way jaxgaze writes an output file (:func:`atomic_outputs`: several of them together),
and :func:`csv_writer`, the one way it writes CSV (no spreadsheet formulas).

Every reader reports a malformed file as an :class:`InputFileError` (a ``ValueError``)
whose message is ``path, line N: what`` (or ``path: what`` when no line applies), so that
the command line can print it as one line.
"""

from __future__ import annotations

import contextlib
import csv
import decimal
import math
import os
import shutil
import stat
import tempfile
import threading
import warnings
from typing import NamedTuple, Optional

from jaxgaze._temporary import remove_stale_temporaries, temporary_prefix

__all__ = [
    "is_number",
    "InputFileError",
    "CsvRow",
    "CsvTable",
    "atomic_path",
    "atomic_outputs",
    "replace_with_the_others",
    "remove_stale_temporaries",
    "csv_writer",
    "spreadsheet_safe",
    "write_csv_rows",
    "read_text",
    "read_lines",
    "read_csv_table",
    "parse_number",
    "parse_integer",
    "format_float",
    "header_problem",
    "first_few",
]


class InputFileError(ValueError):
    """A malformed input file. The message is ``path, line N: what``; ``path``, ``line``
    (or ``None``) and ``what`` (the message without the place) are attributes."""

    def __init__(self, message: str, path, line: Optional[int] = None):
        self.path = os.fspath(path)
        self.line = line
        self.what = " ".join(str(message).split())  # always one line
        where = self.path if line is None else f"{self.path}, line {line}"
        super().__init__(f"{where}: {self.what}")


#: Largest text input jaxgaze reads (bytes): checked before reading, so that a huge file fails at once.
MAX_INPUT_BYTES = 1 << 30
#: Longest line of a text input (bytes): checked while reading, so that a file with no newline fails early.
MAX_LINE_BYTES = 1 << 20
_READ_CHUNK = 1 << 20


def read_text(path, error: type[InputFileError] = InputFileError, what: str = "input") -> str:
    """The contents of a UTF-8 text file (a BOM is dropped); ``error`` for a missing or
    unreadable file or bad bytes, naming the file by ``what`` ("model file not found").

    Bounded on hostile input: only a regular file is read (a FIFO, a device such as
    ``/dev/zero`` or a socket is refused without blocking), one larger than
    :data:`MAX_INPUT_BYTES` is refused before reading, and the reading stops at a NUL byte
    (a binary file) or a line longer than :data:`MAX_LINE_BYTES`.
    """
    try:
        # O_NONBLOCK: opening a FIFO that has no writer would otherwise block forever.
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0))
    except FileNotFoundError:
        raise error(f"{what} file not found", path) from None
    except IsADirectoryError:
        raise error(f"{what} is a directory, not a file", path) from None
    except OSError as exc:
        raise error(f"cannot read the {what} file: {exc.strerror or exc}", path) from None
    with contextlib.ExitStack() as stack:
        stack.callback(os.close, fd)
        info = os.fstat(fd)
        if stat.S_ISDIR(info.st_mode):
            raise error(f"{what} is a directory, not a file", path)
        if not stat.S_ISREG(info.st_mode):
            kind = ("a FIFO (named pipe)" if stat.S_ISFIFO(info.st_mode) else "a device"
                    if stat.S_ISCHR(info.st_mode) or stat.S_ISBLK(info.st_mode) else "not a regular file")
            raise error(f"{what} is {kind}: jaxgaze reads regular files only", path)
        if info.st_size > MAX_INPUT_BYTES:
            raise error(f"{what} file is {_bytes(info.st_size)}, larger than the {_bytes(MAX_INPUT_BYTES)} jaxgaze "
                        "reads (split the recording)", path)
        data = _bounded_read(open(fd, "rb", closefd=False), path, error, what)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise error(f"{what} is not UTF-8 text: {exc.reason} at byte {exc.start}", path,
                    data[: exc.start].count(b"\n") + 1) from None


def _bounded_read(handle, path, error, what) -> bytes:
    """The bytes of an open regular file, read in chunks up to :data:`MAX_INPUT_BYTES` (it may grow
    while read); ``error`` at the first NUL byte or a line longer than :data:`MAX_LINE_BYTES`."""
    chunks, size, lines_before, current = [], 0, 0, 0  # current: bytes of the line not yet ended
    while True:
        try:
            chunk = handle.read(_READ_CHUNK)
        except OSError as exc:
            raise error(f"cannot read the {what} file: {exc.strerror or exc}", path) from None
        if not chunk:
            return b"".join(chunks)
        nul = chunk.find(b"\0")
        if nul >= 0:
            line = lines_before + chunk.count(b"\n", 0, nul) + 1
            raise error(f"{what} is not a text file: a NUL byte at byte {size + nul} (binary data?)", path, line)
        parts = chunk.split(b"\n")
        lengths = [current + len(parts[0])] + [len(part) for part in parts[1:]]
        long = next((k for k, length in enumerate(lengths) if length > MAX_LINE_BYTES), None)
        if long is not None:
            raise error(f"{what} has a line longer than {_bytes(MAX_LINE_BYTES)} (not a text table?)", path,
                        lines_before + long + 1)
        current = lengths[-1]
        lines_before += len(parts) - 1
        size += len(chunk)
        if size > MAX_INPUT_BYTES:
            raise error(f"{what} file is larger than the {_bytes(MAX_INPUT_BYTES)} jaxgaze reads", path)
        chunks.append(chunk)


def _bytes(count: int) -> str:
    """``count`` bytes in words: "2 GiB", "1 MiB", "10 bytes"."""
    for unit, size in (("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if count >= size:
            return f"{count / size:.3g} {unit}"
    return f"{count} bytes"


def read_lines(path, error: type[InputFileError] = InputFileError, what: str = "input") -> list[str]:
    """The lines of a UTF-8 text file (a BOM is dropped); ``error`` for a missing file or bad bytes."""
    return read_text(path, error, what).splitlines()


_TRANSACTIONS = threading.local()


@contextlib.contextmanager
def atomic_outputs(before_commit=None):
    """Write several outputs together: every :func:`atomic_path` inside renames its temporary file
    onto its output only when the outermost block ends without an error, all in a row; on any
    error or interrupt every temporary file is deleted and no output changes (no new figure beside
    old tables). ``before_commit()`` runs just before the renames and may raise to cancel them."""
    stack = getattr(_TRANSACTIONS, "stack", None)
    if stack is not None:  # nested: the outermost block commits
        yield
        return
    pending = _TRANSACTIONS.stack = []
    try:
        yield
        if before_commit is not None:
            before_commit()
    except BaseException:
        _TRANSACTIONS.stack = None
        for tmp, _, _ in pending:
            with contextlib.suppress(OSError):
                shutil.rmtree(tmp) if os.path.isdir(tmp) and not os.path.islink(tmp) else os.unlink(tmp)
        raise
    _TRANSACTIONS.stack = None
    for index, (tmp, target, path) in enumerate(pending):
        try:
            os.replace(tmp, target)
        except OSError as error:
            for later, _, _ in pending[index:]:
                with contextlib.suppress(OSError):
                    os.unlink(later)
            if error.errno is not None and error.filename in (None, tmp):
                error.filename = os.fspath(path)
            raise


def replace_with_the_others(tmp, path) -> bool:
    """Inside :func:`atomic_outputs`: rename the complete temporary file or folder ``tmp`` onto ``path``
    together with the other outputs (an empty folder ``path`` is replaced), and return ``True``;
    outside, do nothing and return ``False`` (the caller renames it)."""
    stack = getattr(_TRANSACTIONS, "stack", None)
    if stack is None:
        return False
    stack.append((os.fspath(tmp), os.path.abspath(os.fspath(path)), path))
    return True


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path next to ``path`` and ``os.replace`` it onto ``path`` only on success.

    The temporary file (``.NAME.jaxgaze-tmp-HOST-PID-RANDOM.EXT``, :mod:`jaxgaze._temporary`) keeps
    ``path``'s extension (writers such as OpenCV's pick the format from it) and gets the
    permissions an existing ``path`` has (else the umask's). On any failure it is deleted and an
    existing ``path`` is left untouched, so no half-written output is ever seen. Inside
    :func:`atomic_outputs` (and inside another ``atomic_path``) the rename waits for the outermost
    block, so that the outputs change together. Temporary files of ``path`` left by a killed
    process are deleted first (:func:`remove_stale_temporaries`). ``OSError`` propagates, with
    ``filename`` set to ``path`` when it has an errno and named no file or the temporary one.
    """
    target = os.path.abspath(os.fspath(path))
    name = os.path.basename(target)
    remove_stale_temporaries(os.path.dirname(target), os.path.basename(target))
    with atomic_outputs():
        try:
            fd, tmp = tempfile.mkstemp(dir=os.path.dirname(target), suffix=os.path.splitext(name)[1],
                                       prefix=temporary_prefix(name))
        except OSError as error:
            if error.errno is not None and error.filename in (None, os.path.dirname(target)):
                error.filename = os.fspath(path)
            raise
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
            _TRANSACTIONS.stack.append((tmp, target, path))
        except BaseException as error:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            if isinstance(error, OSError) and error.errno is not None and error.filename in (None, tmp):
                error.filename = os.fspath(path)
            raise


#: What makes a spreadsheet read a cell as a formula (OWASP, "CSV Injection").
SPREADSHEET_TRIGGERS = ("=", "+", "-", "@", "\t", "\r")


def is_number(text: str) -> bool:
    """Whether ``float`` reads ``text`` (``-0.5``, ``-inf``, ``1e-3``)."""
    try:
        float(text)
    except ValueError:
        return False
    return True


def spreadsheet_safe(cell):
    """``cell``, with a ``'`` in front when it is text a spreadsheet would run as a formula (it
    begins with ``=``, ``+``, ``-``, ``@``, a tab or a carriage return and is not a number:
    ``-0.5`` stays). :meth:`CsvRow.cell` takes the ``'`` off again."""
    if isinstance(cell, str) and cell.startswith(SPREADSHEET_TRIGGERS) and not is_number(cell):
        return "'" + cell
    return cell


class _SafeCsvWriter:
    """A ``csv.writer`` whose rows pass through :func:`spreadsheet_safe`; a row with a carriage return
    in a cell has every cell quoted (``csv`` quotes only the ``\\n`` of the line end, and a bare
    ``\\r`` would end the row for a reader)."""

    def __init__(self, handle):
        self._writer = csv.writer(handle, lineterminator="\n")
        self._quoted = csv.writer(handle, lineterminator="\n", quoting=csv.QUOTE_ALL)

    def writerow(self, row):
        cells = [spreadsheet_safe(cell) for cell in row]
        writer = self._quoted if any(isinstance(c, str) and "\r" in c for c in cells) else self._writer
        return writer.writerow(cells)

    def writerows(self, rows):
        for row in rows:
            self.writerow(row)


def csv_writer(handle) -> _SafeCsvWriter:
    """The CSV writer of every CSV jaxgaze writes (``\\n`` line ends): text cells that a spreadsheet
    would run as a formula get a leading ``'`` (:func:`spreadsheet_safe`), numbers stay as they are."""
    return _SafeCsvWriter(handle)


def write_csv_rows(path, columns, rows) -> int:
    """Write a header of ``columns`` and the iterable ``rows`` (lists of cells) as CSV, atomically
    (:func:`atomic_path`) and with no spreadsheet formula (:func:`csv_writer`); returns the number of
    rows written."""
    count = 0
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8", newline="") as handle:
        writer = csv_writer(handle)
        writer.writerow(columns)
        for row in rows:
            writer.writerow(row)
            count += 1
    return count


def parse_number(text: str, what: str, path, line: int, error: type[InputFileError] = InputFileError,
                 *, finite: bool = True) -> float:
    """``float(text)`` (finite unless ``finite=False``), or ``error`` naming ``what`` at ``path, line``."""
    try:
        value = float(text)
    except ValueError:
        raise error(f"{what} is not a number: {text!r}", path, line) from None
    if finite and not math.isfinite(value):
        raise error(f"{what} is not finite: {text!r}", path, line)
    return value


def parse_integer(text: str, what: str, path, line: int, error: type[InputFileError] = InputFileError) -> int:
    """``text`` as an exact signed 64-bit integer (``3``, ``3.0`` or ``3e2``), or ``error`` naming ``what``
    at ``path, line``. Parsed as a decimal, never through float64, so that ids above 2^53 such as
    nanosecond timestamps come back exactly."""
    try:
        value = decimal.Decimal(text.strip())
    except decimal.InvalidOperation:
        raise error(f"{what} is not a number: {text!r}", path, line) from None
    if not value.is_finite():
        raise error(f"{what} is not finite: {text!r}", path, line)
    if value.adjusted() > 18:  # |value| ≥ 1e19 > 2^63, tested first: 1e999999999 is a finite decimal
        raise error(f"{what} is out of range for a 64-bit integer: {text!r}", path, line)
    if value != value.to_integral_value():
        raise error(f"{what} must be an integer, got {text!r}", path, line)
    value = int(value)
    if not -(2**63) <= value < 2**63:
        raise error(f"{what} is out of range for a 64-bit integer: {text!r}", path, line)
    return value


def format_float(value) -> str:
    """The shortest text that reads back as ``value`` at its own precision (a NumPy float32
    as float32, anything else as a Python float)."""
    import numpy as np

    return str(value) if isinstance(value, np.floating) else repr(float(value))


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


def first_few(items, limit: int = 3, sep: str = ", ") -> str:
    """The first ``limit`` of ``items`` joined by ``sep``, then "… and N more": a list of any
    length kept short enough for one line of a message or warning."""
    items = [str(item) for item in items]
    shown = sep.join(items[:limit])
    return shown if len(items) <= limit else f"{shown} … and {len(items) - limit} more"


# ---------------------------------------------------------------------------
# CSV tables


class CsvRow:
    """One data row of a :class:`CsvTable`: its ``line`` in the file and its text ``cells``.

    The accessors name the column and ``path, line N`` in their errors.
    """

    __slots__ = ("table", "line", "cells")

    def __init__(self, table: "CsvTable", line: int, cells: list[str]):
        self.table, self.line, self.cells = table, line, cells

    def error(self, message: str) -> InputFileError:
        """The table's error type at this row's line (to ``raise``)."""
        return self.table.error(message, self.table.path, self.line)

    def cell(self, column: str) -> str:
        """The stripped text of ``column`` (possibly empty); the ``'`` that jaxgaze's writers put
        in front of a would-be formula (:func:`spreadsheet_safe`) is taken off."""
        text = self.cells[self.table.index[column]].strip()
        return text[1:] if text.startswith("'") and text[1:2] in SPREADSHEET_TRIGGERS else text

    def text(self, column: str) -> str:
        """The stripped text of ``column``; an error if it is empty."""
        text = self.cell(column)
        if not text:
            raise self.error(f"empty cell in column '{column}'")
        return text

    def number(self, column: str, *, finite: bool = True) -> float:
        """``column`` as a float (finite unless ``finite=False``), via :func:`parse_number`."""
        return parse_number(self.text(column), f"column '{column}'", self.table.path, self.line, self.table.error,
                            finite=finite)

    def integer(self, column: str) -> int:
        """``column`` as an exact integer (``3``, ``3.0`` or ``3e2``; not ``3.5``, nor beyond 64 bits), via
        :func:`parse_integer`."""
        return parse_integer(self.text(column), f"column '{column}'", self.table.path, self.line, self.table.error)


class CsvTable(NamedTuple):
    """A CSV file read by :func:`read_csv_table`.

    ``names`` are the header's column names (stripped, lower-case unless read with
    ``lower=False``), ``index`` maps each required and present optional column to its
    position, ``rows`` are the data rows (:class:`CsvRow`, blank lines skipped) and
    ``error`` is the error type the rows raise.
    """

    path: str
    header_line: int
    names: tuple
    index: dict
    rows: tuple
    error: type

    def has(self, column: str) -> bool:
        """Whether the header has ``column`` (a required or optional one)."""
        return column in self.index

    def fail(self, message: str, line: Optional[int] = None) -> InputFileError:
        """The table's error type at ``line`` (default: the header's), to ``raise``."""
        return self.error(message, self.path, self.header_line if line is None else line)


def read_csv_table(path, required, optional=(), *, error: type[InputFileError] = InputFileError,
                   what: str = "input", hint=None, empty: Optional[str] = None,
                   comments: bool = False, lower: bool = True, empty_at_end: bool = False) -> CsvTable:
    """Read a CSV file with a header row into a :class:`CsvTable` of text cells.

    The first non-blank line is the header (names stripped, lower-cased unless
    ``lower=False``); it must name every ``required`` column, and no column of
    ``required`` or ``optional`` twice (:func:`header_problem`; ``hint``, a text or a
    function of the header's names, says what is needed). Blank lines, and with
    ``comments=True`` lines starting with ``#``, are skipped. Every data row must have
    as many fields as the header, and there must be at least one; the one exception is
    a recording cut off mid-write: a last line with too few fields and no newline at the
    end of the file is dropped, with a warning naming its line. Raises ``error``
    (``path, line N: what``) for a missing or unreadable file (named by ``what``), bad
    bytes, an empty file (message ``empty``, at line 1, or at the file's last line with
    ``empty_at_end=True``), malformed CSV, a header problem, a ragged row, or no data rows.
    """
    path = os.fspath(path)
    required, optional = tuple(required), tuple(optional)
    text = read_text(path, error, what)
    lines = text.splitlines()
    numbers, content = [], []
    for n, line in enumerate(lines, start=1):
        stripped = line.strip()
        if stripped and not (comments and stripped.startswith("#")):
            numbers.append(n)
            content.append(line)
    if not content:
        if empty is None:
            empty = "empty file: expected a header row with columns " + ", ".join(required)
        raise error(empty, path, max(len(lines), 1) if empty_at_end else 1)
    records = []
    reader = csv.reader(content, strict=True)
    consumed = 0
    try:
        for cells in reader:
            records.append((numbers[consumed], cells))
            consumed = reader.line_num
    except csv.Error as exc:
        raise error(f"malformed CSV: {exc}", path, numbers[min(consumed, len(numbers) - 1)]) from None
    header_line, header = records[0]
    names = tuple(cell.strip().lower() if lower else cell.strip() for cell in header)
    if hint is None:
        hint = "need " + ", ".join(required) + (", optionally " + ", ".join(optional) if optional else "")
    elif callable(hint):
        hint = hint(names)
    problem = header_problem(list(names), required, hint=hint, watched=[n for n in names if n in required + optional])
    if problem:
        raise error(problem, path, header_line)
    index = {c: names.index(c) for c in required + optional if c in names}
    cut = None
    if len(records) > 1 and len(records[-1][1]) < len(header) and records[-1][0] == len(lines) \
            and not text.endswith(("\n", "\r")):
        # A recording cut off mid-write: the last line is short and has no newline.
        line, cells = records.pop()
        cut = f"line {line} is cut off ({len(cells)} of {len(header)} fields and no newline at the end of the file)"
    if len(records) == 1:
        raise error("no data rows after the header" + (f": {cut}" if cut else ""), path, header_line)
    table = CsvTable(path, header_line, names, index, (), error)
    rows = []
    for line, cells in records[1:]:
        if len(cells) != len(header):
            raise error(f"expected {len(header)} fields as in the header, got {len(cells)}", path, line)
        rows.append(CsvRow(table, line, cells))
    if cut:
        warnings.warn(f"{path}: dropped the last row: {cut}; read the {len(rows)} complete row(s) before it",
                      stacklevel=3)
    return table._replace(rows=tuple(rows))
