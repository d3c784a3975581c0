"""Long recordings and live streams (issue 21): batch cold and warm starts, today's implementation, the
10-minute meeting, the online stream and ``jaxgaze concurrences`` on a 100,000-row rays CSV.

Everything runs in one process, on simulated ``meeting`` recordings (11 people; the simulator's 10 fps,
so consecutive frames differ three times as much as at 30 fps: a harder case for the warm start), with the
default :class:`~jaxgaze.ConcurrenceOptions`. Each program is compiled first on a short recording
(the first call's time is reported on its own, as "compile"); the timed runs after it compile
nothing (counted through ``jax.monitoring`` and printed).

1. **Batch**, ``--frames`` frames (default 1,280): ms per frame of ``find_concurrences_over_frames``
   with ``warm_start=False`` (cold: every frame from the full seed set), with ``warm_start=True``,
   and of today's implementation: ``jaxgaze/concurrence/modes.py`` at commit ``44e7cd5`` (before
   issue 21), read with ``git show`` and loaded into this process as a module of its own (on top of
   the current helpers, ``jaxgaze._batching`` included). Best of ``--repeats``. Agreement of warm
   with cold (and of cold with today's): the share of frames with the same count, and in those
   frames the share of the reference's modes with a mode of the other run within 1 cm.
2. **The 10-minute meeting**: ``simulate_scene(key, "meeting", num_frames=--long-frames)`` (default
   18,000); the wall time of ``find_concurrences_over_frames`` + ``track_concurrences`` (target < 60 s
   on 2 CPU cores), and the process's peak RSS after it (``ru_maxrss``; target < 2 GB). It runs right
   after compilation, before the other parts, so that the peak is its own.
3. **Online**: ``ConcurrenceStream(num_people=11).update`` over the first ``--stream-frames`` frames
   of the batch recording, each frame timed until its answer is on the host (``np.asarray(found.valid)``);
   p50, p99 (targets 5 ms, 10 ms) and the maximum, the share of frames searched from all seeds, and
   the agreement with the batch (warm and cold) on those frames.
4. **CSV**: a rays CSV of ``--csv-rows`` rows (default 100,000: a simulated meeting of ⌈rows / 11⌉
   frames, the last one short), then ``jaxgaze concurrences IN.csv --out OUT.csv`` in a child
   process whose stderr is a pseudo-terminal (the command draws progress bars only on a terminal).
   Reported: whether a tqdm bar appeared on its stderr and when, its last state, the child's wall
   time and peak RSS (``os.wait4``; bound 2 GB). The child uses the command's defaults (its
   persistent compilation cache included).

Usage::

    python benchmarks/bench_recording.py              # full size (minutes on 2 cores)
    python benchmarks/bench_recording.py --quick      # everything small: a smoke check
    python benchmarks/bench_recording.py --long-frames 3000 --csv-rows 0   # shorter; no CSV check
    python benchmarks/bench_recording.py --parts csv  # only the 100,000-row CSV through the command
"""

from __future__ import annotations

import argparse
import fcntl
import importlib.util
import os
import pty
import re
import resource
import select
import shutil
import struct
import subprocess
import sys
import tempfile
import termios
import time

import jax
import jax.monitoring
import numpy as np

from jaxgaze import GazeRays, enable_compilation_cache
from jaxgaze.concurrence import ConcurrenceStream, find_concurrences_over_frames, track_concurrences
from jaxgaze.concurrence.recording import LANE_FRAMES, batch_plan
from jaxgaze.io.rays import RayRecording, write_rays_csv
from jaxgaze.simulate import simulate_scene

REPO = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
TODAY = "44e7cd5"  # the last commit before issue 21
PARTS = ("long", "batch", "stream", "crowded", "csv")
COMPILED = [0]


def _count_compile(event, duration_secs, **kwargs):
    if event == "/jax/core/compile/backend_compile_duration":
        COMPILED[0] += 1


jax.monitoring.register_event_duration_secs_listener(_count_compile)


def _parse():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=1280, help="frames of the batch recording (≥ 128 to warm-start)")
    parser.add_argument("--long-frames", type=int, default=18000, help="frames of the long meeting (18,000 = 10 min)")
    parser.add_argument("--stream-frames", type=int, default=1000, help="frames fed to the online stream (≤ --frames)")
    parser.add_argument("--csv-rows", type=int, default=100_000, help="rows of the rays CSV for the CLI; 0 skips it")
    parser.add_argument("--csv-timeout", type=float, default=1800.0, help="seconds before the CLI child is killed")
    parser.add_argument("--repeats", type=int, default=1, help="timed runs of each batch path (best is shown)")
    parser.add_argument("--seed", type=int, default=21)
    parser.add_argument("--parts", default=",".join(PARTS), help="comma-separated: " + ", ".join(PARTS))
    parser.add_argument("--quick", action="store_true",
                        help="all small (--frames 128 --long-frames 256 --stream-frames 128 --csv-rows 2200), "
                             "with the persistent compilation cache on")
    args = parser.parse_args()
    if args.quick:
        args.frames, args.long_frames, args.stream_frames, args.csv_rows = 128, 256, 128, 2200
    if args.frames < 128:
        parser.error("--frames must be at least 128 (two 64-frame lanes), or the warm start does not run")
    args.stream_frames = min(args.stream_frames, args.frames)
    args.parts = [p for p in args.parts.split(",") if p]
    if set(args.parts) - set(PARTS):
        parser.error(f"--parts: unknown {sorted(set(args.parts) - set(PARTS))}; choose from {', '.join(PARTS)}")
    return args


def load_today():
    """``jaxgaze/concurrence/modes.py`` at :data:`TODAY`, as the module ``jaxgaze.concurrence._modes_at_<commit>``."""
    source = subprocess.run(["git", "show", f"{TODAY}:jaxgaze/concurrence/modes.py"], capture_output=True,
                            text=True, cwd=REPO, check=True).stdout
    name = f"jaxgaze.concurrence._modes_at_{TODAY}"
    module = importlib.util.module_from_spec(importlib.util.spec_from_loader(name, loader=None))
    sys.modules[name] = module  # dataclasses look their module up while the source runs
    exec(compile(source, f"{TODAY}:jaxgaze/concurrence/modes.py", "exec"), module.__dict__)
    return module


def agreement(found, reference):
    """``(share of frames with the reference's count, share of the reference's modes in those frames with a
    mode of ``found`` within 1 cm, number of those modes)``."""
    valid, reference_valid = np.asarray(found.valid), np.asarray(reference.valid)
    same = valid.sum(axis=1) == reference_valid.sum(axis=1)
    distances = [np.zeros(0)]
    for t in np.flatnonzero(same & (reference_valid.sum(axis=1) > 0)):
        a = np.asarray(reference.locations[t])[reference_valid[t]]
        b = np.asarray(found.locations[t])[valid[t]]
        distances.append(np.linalg.norm(a[:, None] - b[None], axis=-1).min(axis=1))
    distances = np.concatenate(distances)
    return float(np.mean(same)), float(np.mean(distances < 0.01)) if distances.size else float("nan"), distances.size


def timed(fn, repeats=1):
    """``(best seconds, last result, programs compiled during the runs)``."""
    compiled, best, result = COMPILED[0], float("inf"), None
    for _ in range(repeats):
        start = time.perf_counter()
        result = fn()
        jax.block_until_ready(jax.tree_util.tree_map(np.asarray, result))
        best = min(best, time.perf_counter() - start)
    return best, result, COMPILED[0] - compiled


def peak_rss_bytes() -> int:
    """This process's peak resident set size so far."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # KiB on Linux


def _say(text):
    print(text, flush=True)


def stream_run(rays, frames):
    """Latencies (s) of ``stream.update`` over ``frames`` frames, the stacked answers, compile seconds,
    and programs compiled during the timed loop."""
    stream = ConcurrenceStream(num_people=rays.num_rays)
    inputs = [rays[t] for t in range(frames)]  # the frames as they would arrive, sliced before the clock
    start = time.perf_counter()
    found, _ = stream.update(stream.init(), inputs[0])
    np.asarray(found.valid)
    compile_s = time.perf_counter() - start
    compiled, state, latencies, answers = COMPILED[0], stream.init(), [], []
    for frame in inputs:
        start = time.perf_counter()
        found, state = stream.update(state, frame)
        np.asarray(found.valid)
        latencies.append(time.perf_counter() - start)
        answers.append(found)
    stacked = jax.tree_util.tree_map(lambda *a: np.stack([np.asarray(x) for x in a]), *answers)
    return np.array(latencies), stacked, compile_s, COMPILED[0] - compiled


def write_csv(path, rows, seed):
    """A rays CSV of exactly ``rows`` rows from a simulated meeting; returns (rows, frames, seconds)."""
    start = time.perf_counter()
    people = simulate_scene(jax.random.key(seed), "meeting", num_frames=1).rays.num_rays
    frames = -(-rows // people)
    rays = simulate_scene(jax.random.key(seed), "meeting", num_frames=frames).rays
    mask = np.asarray(rays.mask).copy()
    mask[-1, people - (frames * people - rows):] = False  # the last frame is short
    rays = GazeRays(np.asarray(rays.origins), np.asarray(rays.directions), np.asarray(rays.bandwidth), mask)
    names = [f"p{n:02d}" for n in range(people)]
    written = write_rays_csv(path, RayRecording(list(range(frames)), [names] * frames, rays))
    return written, frames, time.perf_counter() - start


def run_cli_on_a_terminal(args, timeout):
    """``jaxgaze *args`` with stderr on a pseudo-terminal (120 columns), killed after ``timeout`` s: (exit
    status, stderr text, seconds to the first progress bar or None, wall seconds, the child's peak RSS in
    bytes, whether it was killed)."""
    exe = shutil.which("jaxgaze")
    cmd = ([exe] if exe else [sys.executable, "-m", "jaxgaze.cli"]) + list(args)
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 40, 120, 0, 0))
    start = time.perf_counter()
    child = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=slave, cwd=REPO)
    os.close(slave)
    chunks, first_bar, killed = [], None, False
    while True:
        if time.perf_counter() - start > timeout and not killed:
            child.kill()
            killed = True
        ready, _, _ = select.select([master], [], [], 1.0)
        if not ready:
            continue
        try:
            data = os.read(master, 65536)
        except OSError:  # EIO: the child closed the terminal
            break
        if not data:
            break
        chunks.append(data)
        if first_bar is None and b"%|" in data:
            first_bar = time.perf_counter() - start
    _, status, usage = os.wait4(child.pid, 0)
    child.returncode = os.waitstatus_to_exitcode(status)
    wall = time.perf_counter() - start
    os.close(master)
    text = b"".join(chunks).decode("utf-8", "replace")
    return child.returncode, text, first_bar, wall, usage.ru_maxrss * 1024, killed


def csv_check(args):
    _say(f"\n## CSV: jaxgaze concurrences on {args.csv_rows:,} rows")
    with tempfile.TemporaryDirectory(prefix="jaxgaze-bench-recording-") as tmp:
        source, out = os.path.join(tmp, "rays.csv"), os.path.join(tmp, "concurrences.csv")
        rows, frames, seconds = write_csv(source, args.csv_rows, args.seed + 1)
        _say(f"  wrote {rows:,} rows ({frames:,} frames, {os.path.getsize(source) / 2**20:.1f} MiB) in {seconds:.1f} s")
        status, text, first_bar, wall, rss, killed = run_cli_on_a_terminal(["concurrences", source, "--out", out],
                                                                           args.csv_timeout)
        written = None
        if os.path.exists(out):
            with open(out, encoding="utf-8") as handle:
                written = sum(1 for _ in handle) - 1
    plain = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", text)
    states = [s.strip() for s in re.split(r"[\r\n]", plain) if "%|" in s]
    others = [s.strip() for s in re.split(r"[\r\n]", plain) if s.strip() and "%|" not in s]
    percents = [int(p) for p in re.findall(r"(\d+)%\|", plain)]
    _say(f"  exit status {status}{' (killed after --csv-timeout)' if killed else ''}; wall {wall:.1f} s; "
         f"peak RSS {rss / 2**20:,.0f} MiB; output rows {written}")
    _say(f"  progress bar: {'yes' if states else 'NO'}; {len(states)} updates; first after "
         f"{first_bar if first_bar is None else f'{first_bar:.1f} s'}; last: {states[-1] if states else '-'}")
    for line in others[-5:]:
        _say(f"  stderr: {line}")
    return {"rows": rows, "status": status, "bar": bool(states), "max_percent": max(percents, default=None),
            "first_bar": first_bar, "wall": wall, "rss": rss, "last_bar": states[-1] if states else None}


def compile_programs(short, today, compile_s):
    _say("\n## compile (first call on 64 or 128 frames; the stream's on one frame; the tracker's at the long length)")
    for name, fn in [("batch cold", lambda: find_concurrences_over_frames(short[:64], warm_start=False)),
                     ("batch warm", lambda: find_concurrences_over_frames(short, warm_start=True)),
                     (f"today ({TODAY})", lambda: today.find_concurrences_over_frames(short[:64]))]:
        compile_s[name], _, programs = timed(fn)
        _say(f"  {name:<18} {compile_s[name]:6.1f} s  ({programs} programs)")


def long_meeting(args, compile_s, table):
    """The 10-minute meeting: wall time of concurrences + tracks, and the process's peak RSS after it."""
    rss_before = peak_rss_bytes()
    _say(f"\n## long meeting: {args.long_frames:,} frames")
    start = time.perf_counter()
    rays = simulate_scene(jax.random.key(args.seed), "meeting", num_frames=args.long_frames).rays
    jax.block_until_ready(rays)
    simulate_s = time.perf_counter() - start
    find_s, found, programs = timed(lambda: find_concurrences_over_frames(rays, warm_start=True))
    # track_concurrences runs chunks of 512 frames: one program for any length, compiled here.
    compile_s[f"tracker, {args.long_frames:,} frames"], _, programs_track = timed(lambda: track_concurrences(found))
    track_s, tracks, programs_retrack = timed(lambda: track_concurrences(found))
    seconds, rss = find_s + track_s, peak_rss_bytes()
    _say(f"  simulated in {simulate_s:.1f} s (not counted); concurrences {find_s:.1f} s + tracks {track_s:.2f} s = "
         f"{seconds:.1f} s; {int(np.sum(found.valid)):,} concurrences, {int(tracks.num_tracks)} tracks; programs "
         f"compiled {programs} (tracker: {programs_track}, then {programs_retrack}); peak RSS {rss / 2**20:,.0f} MiB "
         f"(before: {rss_before / 2**20:,.0f} MiB)")
    table.append((f"{args.long_frames:,}-frame meeting: concurrences + tracks", f"{seconds:.1f} s ({find_s:.1f} + "
                  f"{track_s:.2f}; {1000 * seconds / args.long_frames:.2f} ms/frame)", "< 60 s"))
    table.append(("peak RSS after it (process)", f"{rss / 2**20:,.0f} MiB", "< 2,048 MiB"))


def batch_paths(args, rays, today, table):
    """Cold, warm and today's on the same recording: ``{name: (seconds, result, programs)}``."""
    _say(f"\n## batch: {args.frames:,} frames, best of {args.repeats}")
    lanes, batch = -(-args.frames // LANE_FRAMES), batch_plan(rays.num_rays, rays.num_rays // 2)[0]
    calls = -(-lanes // batch)
    _say(f"  warm start: {lanes} lanes of {LANE_FRAMES} frames in {calls} call(s) of {batch} lanes "
         f"({100 * (1 - lanes / (calls * batch)):.0f} % of the lane work is padding); cold: {batch} frames a call")
    runs = {}
    for name, fn in [("cold", lambda: find_concurrences_over_frames(rays, warm_start=False)),
                     ("warm", lambda: find_concurrences_over_frames(rays, warm_start=True)),
                     ("today", lambda: today.find_concurrences_over_frames(rays))]:
        runs[name] = timed(fn, args.repeats)
        seconds, found, programs = runs[name]
        _say(f"  {name:<6} {seconds:7.2f} s  {1000 * seconds / args.frames:7.2f} ms/frame  "
             f"{int(np.sum(np.asarray(found.valid))):,} concurrences; programs compiled {programs}")
    ms = {name: 1000 * run[0] / args.frames for name, run in runs.items()}
    warm_same, warm_close, warm_modes = agreement(runs["warm"][1], runs["cold"][1])
    today_same, today_close, _ = agreement(runs["cold"][1], runs["today"][1])
    _say(f"  warm vs cold: same count in {100 * warm_same:.2f} % of frames; {100 * warm_close:.2f} % of "
         f"{warm_modes:,} modes within 1 cm")
    _say(f"  cold vs today: same count in {100 * today_same:.2f} % of frames; {100 * today_close:.2f} % within 1 cm")
    f = f"{args.frames:,} frames"
    table += [
        (f"batch cold start, {f}", f"{ms['cold']:.2f} ms/frame", ""),
        (f"batch warm start, {f}", f"{ms['warm']:.2f} ms/frame (cold / warm {ms['cold'] / ms['warm']:.1f}×)", ""),
        (f"today's implementation ({TODAY}), {f}", f"{ms['today']:.2f} ms/frame (today / warm "
         f"{ms['today'] / ms['warm']:.1f}×, today / cold {ms['today'] / ms['cold']:.2f}×)", ""),
        ("warm vs cold: frames with the same count", f"{100 * warm_same:.2f} %", "≥ 99 %"),
        ("warm vs cold: modes within 1 cm (same-count frames)", f"{100 * warm_close:.2f} %", "all"),
        ("cold vs today: same count / within 1 cm", f"{100 * today_same:.2f} % / {100 * today_close:.2f} %", ""),
    ]
    return {name: run[1] for name, run in runs.items()}


def online(args, rays, batch, compile_s, table):
    """The stream's latencies, and its agreement with the batch (``batch``: warm and cold results)."""
    _say(f"\n## online: ConcurrenceStream over {args.stream_frames:,} frames")
    latencies, streamed, compile_s["stream update"], programs = stream_run(rays, args.stream_frames)
    p50, p99, worst = (1000 * np.percentile(latencies, q) for q in (50, 99, 100))
    full = np.asarray(streamed.searched_all_seeds)
    split = {name: 1000 * np.median(latencies[which]) if which.any() else float("nan")
             for name, which in (("warm", ~full), ("full", full))}
    if batch is None:  # the batch part did not run: its answers, untimed
        batch = {"warm": find_concurrences_over_frames(rays, warm_start=True), "cold": find_concurrences_over_frames(rays,
                                                                                                   warm_start=False)}
    head = {name: jax.tree_util.tree_map(lambda a: np.asarray(a)[:args.stream_frames], found)
            for name, found in batch.items() if name in ("warm", "cold")}
    warm_same, warm_close, _ = agreement(streamed.concurrences, head["warm"])
    cold_same, cold_close, _ = agreement(streamed.concurrences, head["cold"])
    _say(f"  compile {compile_s['stream update']:.1f} s; p50 {p50:.2f} ms, p99 {p99:.2f} ms, max {worst:.2f} ms; "
         f"searched from all seeds in {100 * full.mean():.1f} % of frames; programs compiled in the loop {programs}")
    _say(f"  median latency of the warm-started frames {split['warm']:.2f} ms, of those searched from all seeds "
         f"{split['full']:.2f} ms (when more than 1 % of frames need the full search, it sets the p99)")
    _say(f"  vs batch warm: same count {100 * warm_same:.2f} %, within 1 cm {100 * warm_close:.2f} %; "
         f"vs batch cold: {100 * cold_same:.2f} %, {100 * cold_close:.2f} %")
    table += [
        (f"online update, {rays.num_rays} people: p50 / p99 (max)", f"{p50:.2f} / {p99:.2f} ({worst:.2f}) ms",
         "5 / 10 ms"),
        ("online: median of warm-started / full-search frames", f"{split['warm']:.2f} / {split['full']:.2f} ms", ""),
        ("online: frames searched from all seeds", f"{100 * full.mean():.1f} %", ""),
        ("online vs batch warm: same count / within 1 cm", f"{100 * warm_same:.2f} % / {100 * warm_close:.2f} %",
         "≥ 99 % / all"),
        ("online vs batch cold: same count / within 1 cm", f"{100 * cold_same:.2f} % / {100 * cold_close:.2f} %", ""),
    ]


def crowded(args, today, table):
    """One crowded frame of 200 rays (~33 groups): ``find_concurrences`` against the numpy mean-shift a user
    would write (20 seeds per ray, 50 steps of eq. 6; ``bench_meanshift.py``) and today's ``find_concurrences``."""
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from bench_meanshift import make_scene, numpy_meanshift
    from jaxgaze import find_concurrences

    origins, directions, bandwidth, seeds = make_scene(200, 4000)
    rays = GazeRays(origins, directions, bandwidth)
    _say("\n## crowded frame: 200 rays, best of 5 (wall and CPU)")
    runs = {}
    for name, fn in [("find_concurrences", lambda: find_concurrences(rays)),
                     (f"today ({TODAY})", lambda: today.find_concurrences(rays)),
                     ("numpy mean-shift, 4,000 seeds × 50 steps", lambda: numpy_meanshift(origins, directions,
                                                                                           bandwidth, seeds, 50))]:
        first, result, _ = timed(fn)
        walls, cpus = [], []
        for _ in range(5):
            start, cpu = time.perf_counter(), time.process_time()
            jax.block_until_ready(fn())
            walls.append(time.perf_counter() - start)
            cpus.append(time.process_time() - cpu)
        runs[name] = (min(walls), min(cpus), result)
        _say(f"  {name:<42} {min(walls):6.3f} s wall, {min(cpus):6.3f} s CPU (first call {first:.1f} s)")
    new, old, numpy_run = runs.values()
    a, b = np.asarray(new[2].locations), np.asarray(old[2].locations)
    same = len(a) == len(b)
    gap = float(np.linalg.norm(a[:, None] - b[None], axis=-1).min(axis=1).max()) if same and len(a) else float("nan")
    _say(f"  {len(a)} concurrences (today {len(b)}); largest location difference {1000 * gap:.2f} mm")
    table += [
        ("crowded 200-ray frame: numpy / find_concurrences (wall; CPU)",
         f"{numpy_run[0] / new[0]:.1f}× ({numpy_run[0]:.2f} / {new[0]:.3f} s; CPU {numpy_run[1] / new[1]:.1f}×)", "≥ 10×"),
        ("the same, today's find_concurrences", f"{numpy_run[0] / old[0]:.1f}× ({old[0]:.2f} s)", ""),
        ("crowded: count, today / now; largest location difference", f"{len(b)} / {len(a)}; {1000 * gap:.2f} mm",
         "same"),
    ]


def main() -> None:
    args = _parse()
    _say(f"python {sys.version.split()[0]}, jax {jax.__version__} on {jax.default_backend()} "
         f"({jax.device_count()} device(s)), {os.cpu_count()} CPUs, load {os.getloadavg()[0]:.1f}; parts "
         f"{','.join(args.parts)}; frames {args.frames}, long {args.long_frames}, stream {args.stream_frames}, "
         f"csv rows {args.csv_rows}")
    if args.quick:  # a smoke check: a second run takes its programs from JAX's persistent cache
        _say(f"--quick: persistent compilation cache on ({enable_compilation_cache()}); compile times may be cache loads")
    compile_s, table, batch = {}, [], None
    if {"long", "batch", "stream", "crowded"} & set(args.parts):
        today = load_today()
        rays = simulate_scene(jax.random.key(args.seed), "meeting", num_frames=args.frames).rays
        if {"long", "batch", "stream"} & set(args.parts):
            compile_programs(rays[:128], today, compile_s)
        if "long" in args.parts:  # first after compiling, so that the peak RSS is its own
            long_meeting(args, compile_s, table)
        if "batch" in args.parts:
            batch = batch_paths(args, rays, today, table)
        if "stream" in args.parts:
            online(args, rays, batch, compile_s, table)
        if "crowded" in args.parts:
            crowded(args, today, table)
    if "csv" in args.parts and args.csv_rows > 0:
        csv = csv_check(args)
        bar = "yes" if csv["bar"] else "**no**"
        table.append((f"`jaxgaze concurrences`, {csv['rows']:,}-row CSV: progress bar on a terminal", f"{bar} (max "
                      f"{csv['max_percent']} %, first after {csv['first_bar'] and round(csv['first_bar'], 1)} s)",
                      "shown"))
        table.append((f"the same: child wall / peak RSS (exit {csv['status']})",
                      f"{csv['wall']:.1f} s / {csv['rss'] / 2**20:,.0f} MiB", "< 2,048 MiB"))
    if compile_s:
        _say("\n| compile (first call) | s |\n|---|---|")
        for name, seconds in compile_s.items():
            _say(f"| {name} | {seconds:.1f} |")
    _say("\n| measure | value | target |\n|---|---|---|")
    for row in table:
        _say("| " + " | ".join(row) + " |")


if __name__ == "__main__":
    main()
