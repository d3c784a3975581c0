"""The error of a bad argument (:class:`CommandError`), the argument types of the commands (a positive
number, an integer at least N) and the reading of negative numbers as option values."""

from __future__ import annotations

import argparse
import math
import os
import re

from jaxgaze.io.text import is_number

__all__ = ["CommandError", "positive_float", "int_at_least", "negative_values_joined"]


class CommandError(Exception):
    """A bad argument or an output that cannot be written (input files raise
    :class:`~jaxgaze.io.text.InputFileError`): ``what`` and the ``path`` it concerns, if any."""

    def __init__(self, what: str, path=None):
        self.what = " ".join(str(what).split())  # always one line
        self.path = None if path is None else os.fspath(path)
        self.line = None
        super().__init__(self.what)


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
            and all(is_number(x) for x in token.split(","))
        if number_like and "," not in token:
            joined.append(token + " ")
        elif number_like and joined and re.fullmatch(r"--[a-z][\w-]*", joined[-1]):
            joined[-1] = f"{joined[-1]}={token}"
        else:
            joined.append(token)
    return joined

