"""The compilation cache repairs itself and speaks once (jaxgaze.runtime).

Before issue 35 an entry truncated by a full disk warned and recompiled in every later run (JAX
never writes over an entry it has), and a cache folder on a full disk printed 7 to 14 warning
lines, some of them raw two-line ``UserWarning``s.
"""

import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
RAYS = os.path.join(ROOT, "examples", "concurrences", "rays.csv")
SCRIPT = os.path.join(os.path.dirname(sys.executable), "jaxgaze")
#: A fresh process: the cache on ``sys.argv[1]``, one jitted program, its answer printed.
PROGRAM = ("import sys, jax, jax.numpy as jnp, jaxgaze; jaxgaze.enable_compilation_cache(sys.argv[1]); "
           "print(float(jax.jit(lambda x: jnp.sum(jnp.cos(x) ** 3))(jnp.arange(9.0))))")


def _run(cache):
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    return subprocess.run([sys.executable, "-c", PROGRAM, str(cache)], env=env, stdin=subprocess.DEVNULL,
                          capture_output=True, text=True, timeout=300)


def _entries(cache):
    return {name: os.path.getsize(cache / name) for name in os.listdir(cache) if name.endswith("-cache")}


def test_a_truncated_entry_is_replaced_and_warns_no_more(tmp_path):
    cache = tmp_path / "cache"
    first = _run(cache)
    assert first.returncode == 0 and first.stderr == "", first.stderr
    sizes = _entries(cache)
    assert sizes
    for name, size in sizes.items():
        with open(cache / name, "r+b") as handle:  # what a full disk leaves
            handle.truncate(size // 2)
    second = _run(cache)
    assert second.returncode == 0 and second.stdout == first.stdout
    assert second.stderr.count("\n") <= 1, second.stderr
    assert _entries(cache) == sizes  # the damaged entry was written again, whole
    third = _run(cache)
    assert (third.returncode, third.stdout, third.stderr) == (0, first.stdout, "")
    assert _entries(cache) == sizes


#: Runs the command of ``sys.argv[1:]`` with files limited to 4 kB (EFBIG, as on a nearly full disk).
LIMITED = ("import os, resource, signal, sys; signal.signal(signal.SIGXFSZ, signal.SIG_IGN); "
           "resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096)); os.execv(sys.argv[1], sys.argv[1:])")


def test_a_cache_on_a_full_disk_gives_one_warning_line(tmp_path):
    """The command still runs and writes its (small) output; the cache costs one line."""
    rays, out = tmp_path / "rays.csv", tmp_path / "out.csv"
    rays.write_text("".join(line for line in open(RAYS) if not line[:2].isdigit() or line[:2] in ("0,", "1,")))
    env = dict(os.environ, JAX_PLATFORMS="cpu", JAXGAZE_CACHE_DIR=str(tmp_path / "cache"))
    done = subprocess.run([sys.executable, "-c", LIMITED, SCRIPT, "concurrences", rays, "--out", out, "-q"], env=env,
                          stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    lines = done.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("jaxgaze: warning: ") and "cache" in lines[0], done.stderr
    assert out.read_text().startswith("frame,")
    assert not [name for name in os.listdir(tmp_path / "cache") if "tmp" in name]
