"""One progress hook for compiled loops: a tqdm bar on stderr, fed from inside ``jax.jit`` by ``jax.debug.callback``.

A fit opens the bar with :func:`progress_bar`; while it is open, the host callbacks
:func:`advance` (one more step) and :func:`reach` (``count`` steps done in the running
compiled call, after :func:`set_offset`'s steps before it) move it. With no bar open
(``progress=False``) the callbacks do nothing, so one compiled program serves both.
Used by :func:`jaxgaze.nuts.sample_nuts` and :func:`jaxgaze.gp.fit`.
"""

from __future__ import annotations

import contextlib
import sys

import numpy as np
from tqdm.auto import tqdm

__all__ = ["progress_bar", "set_offset", "advance", "reach"]

_current = None  # [bar, steps before the running call] while a shown bar is open, else None


@contextlib.contextmanager
def progress_bar(show: bool, **options):
    """Open a tqdm bar on stderr (``tqdm(**options)``, hidden unless ``show``, cleared when done) and feed
    it from :func:`advance` and :func:`reach` until the ``with`` block ends; yields the bar."""
    global _current
    bar = tqdm(disable=not show, file=sys.stderr, leave=False, **options)
    _current = [bar, 0] if show else None
    try:
        yield bar
    finally:
        _current = None
        bar.close()


def set_offset(steps: int) -> None:
    """Steps done before the compiled call that runs next (:func:`reach` counts from them)."""
    if _current is not None:
        _current[1] = int(steps)


def advance() -> None:
    """Host callback: one more step."""
    if _current is not None:
        _current[0].update(1)


def reach(count) -> None:
    """Host callback: ``count`` steps done in the running call (the largest, for a batch); the bar moves
    to the offset plus ``count``, never back."""
    if _current is not None:
        bar, offset = _current
        bar.update(max(0, offset + int(np.max(count)) - bar.n))
