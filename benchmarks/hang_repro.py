"""Count hangs of the long-recording path on XLA:CPU (the LAPACK thread-pool deadlock).

Each run is a fresh ``python`` process that simulates a ``meeting`` recording and
calls the long-recording path ``--calls`` times, printing a line per call. A run
*hangs* when no line arrives for ``--stall`` seconds; it is then killed.

``--path new`` is :func:`jaxgaze.find_concurrences_over_frames` as shipped;
``--path old`` is what it did before: one vmapped program over the whole
recording, whose batched LAPACK calls (15 000 3×3 LU factorisations at 3,000
frames) are large enough for jaxlib to split over the thread pool.

    python benchmarks/hang_repro.py --path old --runs 20
    python benchmarks/hang_repro.py --path new --runs 20
    python benchmarks/hang_repro.py --path new --runs 20 --frames 3000 --calls 1 --full

``--full`` uses the default options (the issue's script); without it the
mean-shift and refinement are cut short so that a call takes a few seconds and
the LAPACK calls keep their size. A hung run's native stacks can be read with
``py-spy dump --native --pid PID`` before ``--stall`` runs out.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests", "concurrence"))
from deadlock_tools import run_until_stalled  # noqa: E402

CHILD = r"""
import sys, time
import jax, numpy as np
from jaxgaze.simulate import simulate_scene
from jaxgaze import concurrence

path, frames, calls, full, benchmarks = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4] == "1", sys.argv[5]
scene = simulate_scene(jax.random.key(4), "meeting", num_frames=frames)
options = concurrence.ConcurrenceOptions() if full else concurrence.ConcurrenceOptions(seed_depths=(1.0, 3.0), max_iter=60, refine_steps=16)
if path == "old":
    sys.path.insert(0, benchmarks)
    from old_path import compile_old_path
    run = compile_old_path(scene.rays, options)
else:
    run = lambda: concurrence.find_concurrences_over_frames(scene.rays, options)
print("ready", flush=True)
for call in range(calls):
    start = time.perf_counter()
    found = run()
    count = int(np.sum(np.asarray(found.valid)))
    print(f"call {call} {time.perf_counter() - start:.2f} s {count} concurrences", flush=True)
"""


def one_run(path: str, frames: int, calls: int, full: bool, stall: float) -> tuple[bool, int, float, list[str]]:
    """``(hung, calls finished, wall seconds, output lines)`` of one child process."""
    start = time.perf_counter()
    hung, lines = run_until_stalled(CHILD, [path, str(frames), str(calls), "1" if full else "0", os.path.dirname(os.path.abspath(__file__))], stall)
    finished = sum(line.startswith("call ") for line in lines)
    return hung, finished, time.perf_counter() - start, lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--path", choices=("old", "new"), default="new")
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--frames", type=int, default=1600)
    parser.add_argument("--calls", type=int, default=3)
    parser.add_argument("--full", action="store_true", help="the default options (slower calls)")
    parser.add_argument("--stall", type=float, default=60.0, help="seconds without a finished call that count as a hang")
    args = parser.parse_args()
    hangs = 0
    for run in range(args.runs):
        hung, finished, wall, lines = one_run(args.path, args.frames, args.calls, args.full, args.stall)
        hangs += hung
        times = [line.split()[2] for line in lines if line.startswith("call ")]
        print(f"run {run + 1:2d}: {'HANG' if hung else 'ok  '} after {finished}/{args.calls} calls "
              f"({wall:.0f} s; call times {', '.join(times) or '-'} s)", flush=True)
    print(f"{args.path} path, {args.frames} frames, {args.calls} call(s) per run: {hangs} hang(s) in {args.runs} runs")


if __name__ == "__main__":
    main()
