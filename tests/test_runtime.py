"""The persistent compilation cache: a second process compiles nothing (jaxgaze.runtime)."""

import os
import subprocess
import sys
import warnings

import jax
import pytest
from jax.experimental.compilation_cache import compilation_cache

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


#: A fresh process that only imports jaxgaze and runs one small jitted program: what a library user does.
LIBRARY_USER = ("import jax, jax.numpy as jnp, jaxgaze; print(jax.config.jax_compilation_cache_dir); "
                "print(float(jax.jit(lambda x: jnp.sum(jnp.cos(x) ** 3))(jnp.arange(5.0))))")


def _library_user(**env):
    clean = {k: v for k, v in os.environ.items() if k not in ("JAX_COMPILATION_CACHE_DIR", CACHE_DIR_VARIABLE)}
    done = subprocess.run([sys.executable, "-c", LIBRARY_USER], env=dict(clean, JAX_PLATFORMS="cpu", **env),
                          stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return done.stdout.splitlines()[0]


def test_import_turns_the_cache_on_and_off_switches_it_off(tmp_path):
    """Issue 34: ``import jaxgaze`` alone keeps the programs in $JAXGAZE_CACHE_DIR; ``off`` writes nothing anywhere."""
    cache = tmp_path / "cache"
    assert _library_user(JAXGAZE_CACHE_DIR=str(cache)) == str(cache)
    assert os.listdir(cache)  # the import's cache stored the program
    home = tmp_path / "xdg"
    home.mkdir()
    assert _library_user(JAXGAZE_CACHE_DIR="off", XDG_CACHE_HOME=str(home)) == "None"
    assert os.listdir(home) == []  # nor in the default folder


def test_import_leaves_a_cache_of_the_users_own(monkeypatch, tmp_path):
    """JAX's cache configured before ``import jaxgaze`` (folder or switch) is left as it is; a default
    folder that cannot be made leaves the cache off without a word."""
    from jaxgaze.runtime import enable_default_compilation_cache

    names = ("jax_compilation_cache_dir", "jax_persistent_cache_min_compile_time_secs",
             "jax_persistent_cache_min_entry_size_bytes", "jax_enable_compilation_cache")
    before = {name: getattr(jax.config, name) for name in names}
    monkeypatch.setenv(CACHE_DIR_VARIABLE, str(tmp_path / "ours"))
    try:
        jax.config.update("jax_compilation_cache_dir", str(tmp_path / "theirs"))
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 2.0)
        assert enable_default_compilation_cache() is None
        assert jax.config.jax_compilation_cache_dir == str(tmp_path / "theirs")
        assert jax.config.jax_persistent_cache_min_compile_time_secs == 2.0
        jax.config.update("jax_compilation_cache_dir", None)
        jax.config.update("jax_enable_compilation_cache", False)
        assert enable_default_compilation_cache() is None and jax.config.jax_compilation_cache_dir is None
        jax.config.update("jax_enable_compilation_cache", True)
        (tmp_path / "file").write_text("not a folder")
        monkeypatch.delenv(CACHE_DIR_VARIABLE)
        monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "file"))  # the default folder cannot be made
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            assert enable_default_compilation_cache() is None
        assert jax.config.jax_compilation_cache_dir is None
        monkeypatch.setenv(CACHE_DIR_VARIABLE, str(tmp_path / "file" / "xla"))  # a folder the user named: a warning
        with pytest.warns(UserWarning, match="cannot make it"):
            assert enable_default_compilation_cache() is None
        monkeypatch.setenv(CACHE_DIR_VARIABLE, str(tmp_path / "ours"))
        assert enable_default_compilation_cache() == str(tmp_path / "ours")
        assert jax.config.jax_compilation_cache_dir == str(tmp_path / "ours")
    finally:
        for name, value in before.items():
            jax.config.update(name, value)
        compilation_cache.reset_cache()  # the next program opens the cache of the restored settings
