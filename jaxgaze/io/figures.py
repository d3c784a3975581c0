"""Figures as files: the format from the path's extension, written atomically."""

from __future__ import annotations

import os

from jaxgaze.io.text import atomic_path

__all__ = ["figure_format", "write_figure"]


def figure_format(path) -> str:
    """The image format of a figure path, from its extension; ``ValueError`` for one matplotlib cannot write."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # matplotlib loads only when a figure is asked for

    ext = os.path.splitext(os.fspath(path))[1].lstrip(".").lower()
    supported = FigureCanvasAgg.get_supported_filetypes()
    if ext not in supported:
        raise ValueError(f"unsupported figure format '.{ext}'; use one of " + ", ".join(f".{e}" for e in supported))
    return ext


def _disk_error(error: BaseException):
    """The ``OSError`` behind ``error`` (itself, or what it was raised from or during), or ``None``."""
    seen = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, OSError):
            return error
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return None


def write_figure(path, figure, dpi: int = 100) -> None:
    """Save a matplotlib ``figure`` to ``path`` (atomically) in the format of its extension (:func:`figure_format`).

    A write that fails (a full disk) raises the ``OSError`` in every format, also where a back-end
    trips over it (the PDF writer's ``AttributeError`` or ``zlib.error`` while it closes the file)."""
    fmt = figure_format(path)
    with atomic_path(path) as tmp:
        try:
            figure.savefig(tmp, format=fmt, dpi=dpi)
        except Exception as error:
            cause = _disk_error(error)
            if cause is None or cause is error:
                raise
            raise OSError(cause.errno, cause.strerror or str(cause), os.fspath(path)) from None
