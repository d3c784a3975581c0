"""The output files of a command: checked before any work (writable, distinct, none of them an input
file) and written together (:func:`writing`)."""

from __future__ import annotations

import contextlib
import os

from jaxgaze.cli._arguments import CommandError
from jaxgaze.cli._interrupt import STATE
from jaxgaze.io.text import atomic_outputs

__all__ = ["check_output", "check_outputs", "declare_inputs", "writing"]


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


def declare_inputs(parser, *dests: str, outputs: dict | None = None) -> None:
    """The arguments (``dest`` names) of ``parser`` that name input files: no output may be one of
    them (:func:`check_outputs`). A value that names no existing file (``--targets 0,0,1``) is no file.
    ``outputs``: ``{dest: flag}`` of outputs not declared with ``add_output`` (a folder is allowed, the
    command checks them itself), compared with the inputs all the same."""
    parser.set_defaults(input_dests=(*(parser.get_default("input_dests") or ()), *dests),
                        unchecked_outputs={**(parser.get_default("unchecked_outputs") or {}), **(outputs or {})})


def _same_file(a, b) -> bool:
    """Whether the paths ``a`` and ``b`` name one file: the same path once links are resolved, or
    the same file on disk (a hard link)."""
    if os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        return os.path.samefile(a, b)
    except (OSError, ValueError):
        return False


def check_outputs(args) -> None:
    """:func:`check_output` for every output option given (declared with :func:`add_output`), no two
    of them the same file, and none of them an input file (declared with :func:`declare_inputs`)."""
    outputs = [(flag, what, getattr(args, dest, None)) for dest, (flag, what) in
               (getattr(args, "outputs", None) or {}).items()]
    outputs = [(flag, what, path) for flag, what, path in outputs if path is not None]
    inputs = []
    for dest in getattr(args, "input_dests", None) or ():
        value = getattr(args, dest, None)
        inputs += [v for v in (value if isinstance(value, (list, tuple)) else [value]) if v is not None]
    for dest, flag in (getattr(args, "unchecked_outputs", None) or {}).items():
        for source in inputs if getattr(args, dest, None) is not None else ():
            if _same_file(getattr(args, dest), source):
                raise CommandError(f"{flag} would overwrite an input file; write it to another path", getattr(args, dest))
    for index, (flag, what, path) in enumerate(outputs):
        check_output(path, what)
        for other, _, earlier in outputs[:index]:
            if _same_file(path, earlier):
                raise CommandError(f"{other} and {flag} must be different files", path)
        for source in inputs:
            if _same_file(path, source):
                raise CommandError(f"{flag} would overwrite an input file; write the {what} to another file", path)


def _before_commit() -> None:
    """Just before a command's outputs are renamed into place: a Ctrl-C that a callback swallowed
    cancels them; from here a signal waits until the renames are done (:mod:`jaxgaze.cli._interrupt`)."""
    if STATE["interrupted"]:
        raise KeyboardInterrupt
    STATE["committing"] = True


@contextlib.contextmanager
def writing(path, what: str = "output", also: dict | None = None):
    """Around (atomic) writers of ``path`` (and of the paths of ``also``, ``{path: what}``): the outputs
    written inside replace the old ones together at the end, or none of them
    (:func:`~jaxgaze.io.text.atomic_outputs`); an ``OSError`` becomes ``cannot write <what>: ...``
    naming the file it concerns (default ``path``)."""
    STATE["writing"] += 1
    try:
        with atomic_outputs(before_commit=_before_commit):
            yield
    except OSError as error:
        targets = {os.path.abspath(os.fspath(p)): (w, p) for p, w in (also or {}).items() if p is not None}
        what, path = targets.get(os.path.abspath(os.fspath(error.filename or path)), (what, path))
        raise CommandError(f"cannot write {what}: {error.strerror or error}", path) from None
    finally:
        STATE["writing"] -= 1
        STATE["committing"] = STATE["committing"] and STATE["writing"] > 0
