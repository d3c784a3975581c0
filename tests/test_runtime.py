"""The persistent compilation cache: a second process compiles nothing (jaxgaze.runtime)."""

import os
import subprocess
import sys

import jax
import pytest

from jaxgaze.runtime import CACHE_DIR_VARIABLE, default_cache_dir, enable_compilation_cache

#: A fresh process: the cache on ``sys.argv[1]``, then one small jitted program, its answer printed.
PROGRAM = ("import sys, jax, jax.numpy as jnp, jaxgaze; jaxgaze.enable_compilation_cache(sys.argv[1]); "
           "print(float(jax.jit(lambda x: jnp.sum(jnp.sin(x) ** 2))(jnp.arange(7.0))))")


def _fresh_process(cache):
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    done = subprocess.run([sys.executable, "-c", PROGRAM, str(cache)], env=env, stdin=subprocess.DEVNULL,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_a_second_process_compiles_nothing(tmp_path):
    cache = tmp_path / "cache"
    first = _fresh_process(cache)
    entries = sorted(os.listdir(cache))
    assert entries  # the first process stored its program
    assert _fresh_process(cache) == first
    assert sorted(os.listdir(cache)) == entries  # the second read it back: nothing new was stored


def test_the_command_turns_the_cache_on(monkeypatch, tmp_path):
    """``console_main`` enables the cache before the command runs (here: its --help, exit 0)."""
    from jaxgaze import cli

    calls = []
    monkeypatch.setattr(cli, "enable_compilation_cache", lambda: calls.append("cache"))
    monkeypatch.setattr(cli, "handle_interrupts", lambda: None)
    monkeypatch.setattr(cli.sys, "argv", ["jaxgaze", "--version"])
    with pytest.raises(SystemExit) as exit_info:
        cli.console_main()
    assert calls == ["cache"] and exit_info.value.code == 0


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
