"""Runtime settings: JAX's persistent compilation cache, so that a second process pays no compilation.

Most of the time to a first answer is XLA compilation (``jaxgaze demo``: about 15 s in a
fresh process, 10 s when every program comes from the cache). :func:`enable_compilation_cache`
turns on JAX's own persistent cache (``jax_compilation_cache_dir``) for every program,
however quick to compile. ``import jaxgaze`` calls it (:func:`enable_default_compilation_cache`)
unless ``JAXGAZE_CACHE_DIR=off`` or JAX's cache is already configured, and so does the
``jaxgaze`` command at start; ``docs/runtime.md`` says why.

The cache repairs itself: an entry that does not decompress (cut short by a full disk) is deleted
and written again once compiled, entries are written whole or not at all (a temporary file renamed
into place), and a folder that cannot be read or written costs one :class:`CompilationCacheWarning`
per process, never the answer.
"""

from __future__ import annotations

import contextlib
import os
import pathlib
import tempfile
import warnings

import jax
from jax._src import compilation_cache as _jax_cache  # no public door to the cache's files
from jax._src.compilation_cache_interface import CacheInterface

from jaxgaze._temporary import remove_stale_temporaries, temporary_prefix

__all__ = ["CACHE_DIR_VARIABLE", "CompilationCacheWarning", "default_cache_dir", "enable_compilation_cache",
           "enable_default_compilation_cache"]


class CompilationCacheWarning(UserWarning):
    """The compilation cache cannot be read or written: programs are compiled again (once per process)."""


_WARNED = []


def _cache_problem(path, problem: str) -> None:
    """One :class:`CompilationCacheWarning` per process, whatever the number of programs."""
    if not _WARNED:
        _WARNED.append(problem)
        warnings.warn(f"compilation cache {path}: {problem}; programs are compiled again in each run",
                      CompilationCacheWarning, stacklevel=1)


class _RepairingCache(CacheInterface):
    """JAX's file cache (``KEY-cache`` files in one folder, no size limit) that replaces damaged
    entries, writes atomically and complains once (see the module's docstring)."""

    def __init__(self, path):
        self._path = self.path = pathlib.Path(path)
        self._unwritable = False
        remove_stale_temporaries(self.path)  # left by killed processes of this machine

    def get(self, key: str):
        entry = self.path / f"{key}-cache"
        try:
            data = entry.read_bytes()
        except FileNotFoundError:
            return None
        except OSError as error:
            _cache_problem(self.path, f"cannot read it: {error.strerror or error}")
            return None
        try:
            _jax_cache.extract_executable_and_time(_jax_cache.decompress_executable(data))
        except Exception:  # cut short or damaged: compiled again, and put() writes it anew
            with contextlib.suppress(OSError):
                entry.unlink()
            return None
        return data

    def put(self, key: str, value: bytes) -> None:
        if self._unwritable:
            return
        tmp = None
        try:
            fd, tmp = tempfile.mkstemp(dir=self.path, prefix=temporary_prefix(f"{key}-cache"))
            with os.fdopen(fd, "wb") as handle:
                handle.write(value)
            os.replace(tmp, self.path / f"{key}-cache")
        except OSError as error:
            if tmp is not None:
                with contextlib.suppress(OSError):
                    os.unlink(tmp)
            self._unwritable = True
            _cache_problem(self.path, f"cannot write to it: {error.strerror or error}")


def _use_repairing_cache(path: str) -> None:
    """Make JAX's persistent cache a :class:`_RepairingCache` on ``path``, unless JAX was asked for a
    size limit or a content check (its own cache then), or its internals are not the ones known."""
    if jax.config.jax_compilation_cache_max_size != -1 or getattr(jax.config, "jax_compilation_cache_check_contents",
                                                                   False):
        return
    if not all(hasattr(_jax_cache, name) for name in ("reset_cache", "_cache", "_cache_initialized",
                                                      "decompress_executable", "extract_executable_and_time")):
        return
    _jax_cache.reset_cache()
    _jax_cache._cache = _RepairingCache(path)
    _jax_cache._cache_initialized = True

#: Environment variable for the cache folder of ``import jaxgaze`` and the ``jaxgaze`` command; ``off`` (or
#: empty) disables it.
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
    _use_repairing_cache(path)
    return path


def enable_default_compilation_cache() -> str | None:
    """What ``import jaxgaze`` does: :func:`enable_compilation_cache` in :func:`default_cache_dir`, so
    that a library user's second process compiles nothing. Returns the folder, or ``None`` where it
    leaves the cache off:

    * ``JAXGAZE_CACHE_DIR=off`` (or empty);
    * JAX's cache is configured already, by ``jax_compilation_cache_dir`` (``JAX_COMPILATION_CACHE_DIR``,
      or ``jax.config.update`` before the import) or ``jax_enable_compilation_cache=False``
      (``JAX_ENABLE_COMPILATION_CACHE=false``): JAX's settings are left as they are;
    * the folder cannot be made (a read-only home): silently for the default folder, with one
      :class:`CompilationCacheWarning` for a folder named by ``JAXGAZE_CACHE_DIR``.
    """
    if jax.config.jax_compilation_cache_dir is not None or not jax.config.jax_enable_compilation_cache:
        return None
    try:
        return enable_compilation_cache()
    except OSError as error:
        if os.environ.get(CACHE_DIR_VARIABLE):
            warnings.warn(f"compilation cache {default_cache_dir()}: cannot make it: {error.strerror or error}; "
                          "programs are compiled again in each run", CompilationCacheWarning, stacklevel=2)
        return None
