"""Runtime settings: JAX's persistent compilation cache, so that a second process pays no compilation.

Most of the time to a first answer is XLA compilation (``jaxgaze demo``: about 15 s in a
fresh process, 10 s when every program comes from the cache). :func:`enable_compilation_cache`
turns on JAX's own persistent cache (``jax_compilation_cache_dir``) for every program,
however quick to compile. The ``jaxgaze`` command calls it at start; library users call it
once, before their first computation.
"""

from __future__ import annotations

import os

import jax

__all__ = ["CACHE_DIR_VARIABLE", "default_cache_dir", "enable_compilation_cache"]

#: Environment variable for the cache folder of the ``jaxgaze`` command; ``off`` (or empty) disables it.
CACHE_DIR_VARIABLE = "JAXGAZE_CACHE_DIR"


def default_cache_dir() -> str | None:
    """``$JAXGAZE_CACHE_DIR`` (``None`` when it is ``off`` or empty), else ``$XDG_CACHE_HOME/jaxgaze/xla``
    (``~/.cache/jaxgaze/xla``)."""
    value = os.environ.get(CACHE_DIR_VARIABLE)
    if value is not None:
        return None if value.strip().lower() in ("", "off", "0", "no") else os.path.expanduser(value)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "jaxgaze", "xla")


def enable_compilation_cache(path=None) -> str | None:
    """Keep every compiled program in ``path`` (default :func:`default_cache_dir`) and read it back in
    later processes: JAX's persistent compilation cache with no minimum compile time or size.
    Returns the folder, or ``None`` when the cache is switched off (``JAXGAZE_CACHE_DIR=off``).
    Call it before the first computation: programs compiled earlier in the process are not stored.
    """
    path = default_cache_dir() if path is None else os.fspath(path)
    if path is None:
        return None
    os.makedirs(path, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", path)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return path
