"""Time to first answer in a fresh process, with JAX's persistent compilation cache off, cold and warm.

Issue 21 item 2: most of the time to a first answer is XLA compilation. Each workload
runs in a new ``python`` process (``JAX_PLATFORMS=cpu``) three times:

* **off**: no persistent cache (``JAXGAZE_CACHE_DIR=off`` for the command);
* **cold**: ``jaxgaze.enable_compilation_cache(folder)`` on a new, empty temporary folder;
* **warm**: the same folder again, now filled by the cold run.

Workloads:

1. ``find_concurrences`` on ``--scenes`` scenes of 4–24 people (numpy seed fixed): people
   on a circle of radius 2 m at eye height 1.6 m, half looking at one of two points,
   half elsewhere; ``GazeRays(origins, directions, bandwidth=0.05)``. Reported: the total
   for all scenes, and the first call alone.
2. ``jaxgaze.gp.fit`` at ``--gp-n`` points of a 1-D ``sin`` toy set (float64), the call of
   ``bench_gp.py``: ``RationalQuadratic + Linear + White``, ``jitter=1e-10``.
3. ``jaxgaze demo -q --out <tmp>.png`` through ``jaxgaze.cli.console_main`` (its cache is on
   by default; the folder comes from ``JAXGAZE_CACHE_DIR``).
4. ``library``: what a library user who changed no setting waits for (issue 34): ``import
   jaxgaze``, the rays of one 11-person scene (the scene generator of 1, seed 0) and
   ``jaxgaze.find_concurrences``, with no call of ``enable_compilation_cache``. **off**:
   ``JAXGAZE_CACHE_DIR=off``; **cold**: ``JAXGAZE_CACHE_DIR`` names a new empty folder;
   **warm**: the same folder again. Whether the cache is used is the library's default at
   import; run it with ``PYTHONPATH`` on an older ``jaxgaze`` for the figures before a change.

Timing (wall, and the CPU seconds of each process, which a loaded machine inflates less): for 1, 2 and 4 the child measures ``time.perf_counter`` from before ``import jaxgaze``
(and numpy) to after ``block_until_ready`` of the answer and prints it; the parent also
reports the whole-process wall time (interpreter start and exit included). For 3 only the
whole-process time exists; the child runs ``jaxgaze.cli.console_main``, what the ``jaxgaze``
console script runs, so that it can count programs.

Programs: every child counts, through ``jax.monitoring``, the XLA programs it asked for
(``/jax/core/compile/backend_compile_duration``) and how many of them came from the
persistent cache (``/jax/compilation_cache/cache_hits``); the rest were compiled.

Usage::

    python benchmarks/bench_first_answer.py            # 30 scenes, n = 1000, the demo (~2 min on 2 cores)
    python benchmarks/bench_first_answer.py --scenes 10 --gp-n 500
    python benchmarks/bench_first_answer.py --workloads gp,demo
    python benchmarks/bench_first_answer.py --workloads library --repeat 3   # a library user's first answer
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time

# Counts the programs a child asks XLA for, and those the persistent cache supplied.
COUNTER = r"""
import jax.monitoring
PROGRAMS = {"programs": 0, "cached": 0}


def _count_program(event, duration_secs, **kwargs):
    if event == "/jax/core/compile/backend_compile_duration":
        PROGRAMS["programs"] += 1


def _count_hit(event, **kwargs):
    if event == "/jax/compilation_cache/cache_hits":
        PROGRAMS["cached"] += 1


jax.monitoring.register_event_duration_secs_listener(_count_program)
jax.monitoring.register_event_listener(_count_hit)


def programs_line():
    return f"PROGRAMS {PROGRAMS['programs']} CACHED {PROGRAMS['cached']}"
"""

CONCURRENCES_CHILD = r"""
import time
t0 = time.perf_counter()
""" + COUNTER + r"""
import sys
import numpy as np
import jax
import jaxgaze
folder, num_scenes = sys.argv[1], int(sys.argv[2])
if folder != "off":
    jaxgaze.enable_compilation_cache(folder)
rng = np.random.default_rng(0)
targets = np.array([[0.5, 0.0, 1.0], [-0.6, 0.4, 1.2]])
scenes = []
for _ in range(num_scenes):
    n = int(rng.integers(4, 25))
    angle = rng.uniform(0.0, 2 * np.pi, n)
    origins = np.column_stack([2.0 * np.cos(angle), 2.0 * np.sin(angle), np.full(n, 1.6)])
    looking = rng.permutation(n) < n // 2
    goal = targets[rng.integers(0, 2, n)]
    directions = goal - origins
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    directions += rng.normal(0.0, 0.02, (n, 3))
    elsewhere = rng.normal(size=(n, 3))
    directions[~looking] = elsewhere[~looking]
    scenes.append((origins, directions))
first = None
for origins, directions in scenes:
    found = jaxgaze.find_concurrences(jaxgaze.GazeRays(origins, directions, bandwidth=0.05))
    jax.block_until_ready(found)
    if first is None:
        first = time.perf_counter() - t0
print(f"ANSWER {time.perf_counter() - t0:.3f} FIRST {first:.3f} {programs_line()}")
"""

GP_CHILD = r"""
import time
t0 = time.perf_counter()
""" + COUNTER + r"""
import sys
import numpy as np
import jax
import jaxgaze
import jaxgaze.gp as gp
folder, n = sys.argv[1], int(sys.argv[2])
if folder != "off":
    jaxgaze.enable_compilation_cache(folder)
jax.config.update("jax_enable_x64", True)
rng = np.random.default_rng(0)
X = rng.uniform(-3.0, 3.0, (n, 1))
y = np.sin(X[:, 0]) + rng.normal(0.0, 0.1, n)
kernel = gp.RationalQuadratic(1.0, 1.0, 1.0) + gp.Linear(1.0, 1.0, fixed=("variance",)) + gp.White(1.0)
fitted = gp.fit(kernel, jax.numpy.asarray(X), jax.numpy.asarray(y), key=jax.random.key(0), jitter=1e-10)
jax.block_until_ready(fitted.alpha)
print(f"ANSWER {time.perf_counter() - t0:.3f} {programs_line()}")
"""

LIBRARY_CHILD = r"""
import time
t0 = time.perf_counter()
""" + COUNTER + r"""
import numpy as np
import jax
import jaxgaze
imported = time.perf_counter() - t0
rng = np.random.default_rng(0)
targets = np.array([[0.5, 0.0, 1.0], [-0.6, 0.4, 1.2]])
n = 11
angle = rng.uniform(0.0, 2 * np.pi, n)
origins = np.column_stack([2.0 * np.cos(angle), 2.0 * np.sin(angle), np.full(n, 1.6)])
looking = rng.permutation(n) < 8
directions = targets[rng.integers(0, 2, n)] - origins
directions /= np.linalg.norm(directions, axis=1, keepdims=True)
directions += rng.normal(0.0, 0.02, (n, 3))
directions[~looking] = rng.normal(size=(n, 3))[~looking]
found = jaxgaze.find_concurrences(jaxgaze.GazeRays(origins, directions, bandwidth=0.05))
jax.block_until_ready(found)
print(f"ANSWER {time.perf_counter() - t0:.3f} IMPORT {imported:.3f} K {int(found.locations.shape[0])} "
      f"{programs_line()}")
"""

DEMO_CHILD = COUNTER + r"""
import sys
from jaxgaze.cli import console_main
sys.argv = ["jaxgaze"] + sys.argv[1:]
try:
    console_main()
finally:
    print(f"ANSWER nan {programs_line()}")
"""

MODES = ("off", "cold", "warm")


def _parse():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", type=int, default=30, help="scenes of 4-24 people for find_concurrences")
    parser.add_argument("--gp-n", type=int, default=1000, help="training points for gp.fit")
    parser.add_argument("--workloads", default="concurrences,gp,demo,library",
                        help="comma-separated: concurrences, gp, demo, library")
    parser.add_argument("--repeat", type=int, default=1,
                        help="run each workload's off, cold and warm processes this many times (a new cold folder "
                             "each time) and report the median")
    return parser.parse_args()


def _run(cmd, env_extra):
    env = dict(os.environ, JAX_PLATFORMS="cpu", **env_extra)
    env.pop("JAX_COMPILATION_CACHE_DIR", None)  # the cache is the one each mode sets
    t, used = time.perf_counter(), resource.getrusage(resource.RUSAGE_CHILDREN)
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall, now = time.perf_counter() - t, resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        sys.exit(f"{' '.join(cmd[:3])}... failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
    fields = {}
    for line in proc.stdout.splitlines():
        if line.startswith("ANSWER"):
            words = line.split()
            fields = {words[i]: float(words[i + 1]) for i in range(0, len(words), 2)}
    # CPU seconds of the whole process: less inflated than wall time when other work shares the cores.
    fields["CPU"] = now.ru_utime + now.ru_stime - used.ru_utime - used.ru_stime
    return wall, fields


def measure(workload, args, tmp, repeat=0):
    """``{mode: (whole-process wall, {"ANSWER": s, "FIRST": s, "PROGRAMS": k, "CACHED": k})}`` for off, cold, warm."""
    folder = os.path.join(tmp, f"cache-{workload}-{repeat}")
    out = {}
    for mode in MODES:
        where = "off" if mode == "off" else folder
        if workload == "library":
            cmd, env = [sys.executable, "-c", LIBRARY_CHILD], {"JAXGAZE_CACHE_DIR": where}
        elif workload == "concurrences":  # JAXGAZE_CACHE_DIR too: `import jaxgaze` turns the cache on
            cmd, env = [sys.executable, "-c", CONCURRENCES_CHILD, where, str(args.scenes)], {"JAXGAZE_CACHE_DIR": where}
        elif workload == "gp":
            cmd, env = [sys.executable, "-c", GP_CHILD, where, str(args.gp_n)], {"JAXGAZE_CACHE_DIR": where}
        else:
            png = os.path.join(tmp, f"demo-{mode}.png")
            cmd, env = [sys.executable, "-c", DEMO_CHILD, "demo", "-q", "--out", png], {"JAXGAZE_CACHE_DIR": where}
        out[mode] = _run(cmd, env)
        wall, fields = out[mode]
        shown = " ".join(f"{k.lower()} {v:.1f} s" for k, v in fields.items()
                         if k in ("ANSWER", "FIRST", "IMPORT", "CPU") and v == v)
        print(f"  {workload:<12} {mode:<5} process {wall:6.1f} s  {shown}  programs {fields['PROGRAMS']:.0f}, "
              f"{fields['CACHED']:.0f} from the cache", flush=True)
    return out


def _median(results):
    """The median of each figure over repeated ``(wall, fields)`` results."""
    import statistics

    return (statistics.median(r[0] for r in results),
            {k: statistics.median(r[1][k] for r in results) for k in results[0][1]})


def main() -> None:
    args = _parse()
    print(f"python {sys.version.split()[0]}, {os.cpu_count()} CPUs, JAX_PLATFORMS=cpu; "
          f"{args.scenes} scenes, gp n = {args.gp_n}; load average {os.getloadavg()[0]:.1f}", flush=True)
    rows = []
    with tempfile.TemporaryDirectory(prefix="jaxgaze-first-answer-") as tmp:
        for workload in [w for w in args.workloads.split(",") if w]:
            runs = [measure(workload, args, tmp, r) for r in range(args.repeat)]
            res = {m: _median([run[m] for run in runs]) for m in MODES}
            if workload == "library":
                rows.append(("library user: import jaxgaze + find_concurrences, 11 people",
                             [res[m][1]["ANSWER"] for m in MODES]))
                rows.append(("library user: import jaxgaze alone", [res[m][1]["IMPORT"] for m in MODES]))
            elif workload == "concurrences":
                rows.append((f"find_concurrences, {args.scenes} scenes of 4-24 people: all",
                             [res[m][1]["ANSWER"] for m in MODES]))
                rows.append(("find_concurrences: the first scene alone", [res[m][1]["FIRST"] for m in MODES]))
            elif workload == "gp":
                rows.append((f"gp.fit, n = {args.gp_n}", [res[m][1]["ANSWER"] for m in MODES]))
            rows.append((f"{'jaxgaze demo -q' if workload == 'demo' else workload}: whole process",
                         [res[m][0] for m in MODES]))
            rows.append((f"{workload}: whole process, CPU seconds (user + system)", [res[m][1]["CPU"] for m in MODES]))
            # Programs compiled (asked for − taken from the persistent cache) of the whole process.
            rows.append((f"{workload}: programs compiled (of those asked for)",
                         [(res[m][1]["PROGRAMS"] - res[m][1]["CACHED"], res[m][1]["PROGRAMS"]) for m in MODES]))
    width = max(len(r[0]) for r in rows)
    print()
    print(f"{'workload (seconds)':<{width}} | {'cache off':>9} | {'cold cache':>10} | {'warm cache':>10}")
    print("-" * (width + 39))
    for name, cells in rows:
        shown = [f"{c[0]:.0f} ({c[1]:.0f})" if isinstance(c, tuple) else f"{c:.1f}" for c in cells]
        print(f"{name:<{width}} | {shown[0]:>9} | {shown[1]:>10} | {shown[2]:>10}")
    print(f"load average at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
