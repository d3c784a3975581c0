"""Speed of the long-recording path: batched frames (now) against one vmap over the recording (before).

Both run in one child process on the same simulated ``meeting`` recording with
the default options, after compilation: ``old`` is the former
``find_concurrences_over_frames``, one vmapped program over all ``T`` frames;
``new`` is the shipped one, batches of frames small enough for XLA:CPU's LAPACK
bound, on one host thread per core. The old program can deadlock on XLA:CPU
(docs/runtime.md), so the child is watched: a child that stops printing for
``--stall`` seconds is killed, counted as a hang and started again, until
``--old-runs`` children have timed the old program. Each child times the new path
``--repeats`` times, then the old program once.

    python benchmarks/bench_long_recording.py [--frames 3000] [--repeats 2] [--old-runs 2]
"""

from __future__ import annotations

import argparse
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests", "concurrence"))
from deadlock_tools import run_until_stalled  # noqa: E402

CHILD = r"""
import sys, time
import jax, numpy as np
from jaxgaze.simulate import simulate_scene
from jaxgaze import concurrence

frames, repeats = int(sys.argv[1]), int(sys.argv[2])
scene = simulate_scene(jax.random.key(4), "meeting", num_frames=frames)
rays = scene.rays
sys.path.insert(0, sys.argv[3])
from old_path import compile_old_path
start = time.perf_counter()
old_run = compile_old_path(rays)
print(f"compiled old {time.perf_counter() - start:.1f}", flush=True)
start = time.perf_counter()
concurrence.find_concurrences_over_frames(rays[:1])
print(f"compiled new {time.perf_counter() - start:.1f}", flush=True)
# The old program last: a child that hangs there has already timed the new path.
for path in ["new"] * repeats + ["old"]:
    start = time.perf_counter()
    found = concurrence.find_concurrences_over_frames(rays) if path == "new" else old_run()
    count = int(np.sum(np.asarray(found.valid)))
    print(f"time {path} {time.perf_counter() - start:.3f} {count}", flush=True)
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=3000)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--stall", type=float, default=150.0)
    parser.add_argument("--old-runs", type=int, default=2, help="timings of the old program to collect (one per child)")
    parser.add_argument("--tries", type=int, default=8, help="children to start before giving up on the old path")
    args = parser.parse_args()
    times = {"new": [], "old": []}
    counts, hangs = {}, 0
    for _ in range(args.tries):
        hung, lines = run_until_stalled(CHILD, [str(args.frames), str(args.repeats), os.path.dirname(os.path.abspath(__file__))], args.stall)
        for line in lines:
            if line.startswith(("time", "compiled")):
                print("  " + line, flush=True)
            if line.startswith("time"):
                _, path, seconds, count = line.split()
                times[path].append(float(seconds))
                counts[path] = int(count)
        hangs += hung
        if hung:
            print(f"  child hung ({hangs}); starting another", flush=True)
        if len(times["old"]) >= args.old_runs:
            break
    new, old = min(times["new"], default=float("nan")), min(times["old"], default=float("nan"))
    t = args.frames
    print(f"\n| path | best of {len(times['new'])}/{len(times['old'])} (s) | ms/frame | concurrences |")
    print("|---|---|---|---|")
    print(f"| new: batches, one thread per core | {new:.2f} | {1000 * new / t:.2f} | {counts.get('new')} |")
    print(f"| old: one vmap over {t} frames | {old:.2f} | {1000 * old / t:.2f} | {counts.get('old')} |")
    print(f"\nall times (s): new {times['new']}, old {times['old']}")
    print(f"old / new = {old / new:.2f}× ; children that hung: {hangs}")


if __name__ == "__main__":
    main()
