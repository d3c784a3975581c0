"""The persistent compilation cache: a second process compiles nothing (jaxgaze.runtime)."""

import os
import subprocess
import sys

import jax

from jaxgaze.runtime import CACHE_DIR_VARIABLE, default_cache_dir, enable_compilation_cache

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RAYS = os.path.join(ROOT, "examples", "concurrences", "rays.csv")


def _concurrences(cache, out):
    """``jaxgaze concurrences`` on the example rays, in a fresh process (the console script's entry)."""
    env = dict(os.environ, JAX_PLATFORMS="cpu", **{CACHE_DIR_VARIABLE: str(cache)})
    code = "from jaxgaze.cli import console_main; console_main()"
    done = subprocess.run([sys.executable, "-c", code, "concurrences", RAYS, "--out", str(out), "-q"], env=env,
                          stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return out.read_text()


def test_a_second_process_compiles_nothing(tmp_path):
    cache = tmp_path / "cache"
    first = _concurrences(cache, tmp_path / "first.csv")
    entries = sorted(os.listdir(cache))
    assert len(entries) >= 3  # the programs of the first run are stored
    second = _concurrences(cache, tmp_path / "second.csv")
    assert sorted(os.listdir(cache)) == entries  # every program came from the cache: nothing new was stored
    assert second == first


def test_cache_folder_from_the_environment(monkeypatch, tmp_path):
    monkeypatch.setenv(CACHE_DIR_VARIABLE, "off")
    assert default_cache_dir() is None and enable_compilation_cache() is None
    monkeypatch.setenv(CACHE_DIR_VARIABLE, str(tmp_path / "c"))
    assert default_cache_dir() == str(tmp_path / "c")
    monkeypatch.delenv(CACHE_DIR_VARIABLE)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert default_cache_dir() == os.path.join(str(tmp_path), "jaxgaze", "xla")
    names = ("jax_compilation_cache_dir", "jax_persistent_cache_min_compile_time_secs",
             "jax_persistent_cache_min_entry_size_bytes")
    before = {name: getattr(jax.config, name) for name in names}
    try:
        assert enable_compilation_cache(tmp_path / "x") == str(tmp_path / "x") and (tmp_path / "x").is_dir()
        assert jax.config.jax_compilation_cache_dir == str(tmp_path / "x")
    finally:
        for name, value in before.items():
            jax.config.update(name, value)
