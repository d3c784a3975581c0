"""Throughput of jaxgaze's mean-shift kernel against a plain vectorised numpy version.

The figure of merit is *pair-iterations per second*: seeds × rays × iterations
divided by wall time. Both implementations run the same equations (Park et al.
2012, eq. 5–6; see ``/work/shared/METHODS.md`` §1 and
``jaxgaze.concurrence.field.meanshift_step``) in float32 in the same process.

* **JAX** is the public ``jaxgaze.meanshift(rays, seeds, tol=0.0, max_iter=I)``
  under ``jax.jit``. ``tol=0`` means no step is ever "short enough", so every
  seed runs exactly ``I`` iterations (checked through ``result.iterations``).
  The timed call also includes ``meanshift``'s one final evaluation of the field
  at every point, i.e. about one extra pass over the pairs that is *not* counted,
  so the JAX rate is slightly conservative. Compile time is excluded (warm-up
  call) and the result is ``block_until_ready``-ed.
* **numpy** is the obvious broadcast over ``(seeds, rays)`` that someone would
  write: build ``x[:, None] - p[None]`` and reduce it. For big sizes it may run
  fewer iterations than JAX to bound the time (``--numpy-max-pairs``); since the
  cost is linear in the iteration count and the rate is per pair-iteration, the
  comparison stays fair. The table says how many iterations each side ran.

Before timing, both are run for the same number of iterations from the same
seeds and the largest absolute difference of the resulting points is printed.

Usage::

    python benchmarks/bench_meanshift.py                      # default sizes (< 3 min on 2 CPU cores)
    python benchmarks/bench_meanshift.py --quick              # smoke test, a few seconds
    python benchmarks/bench_meanshift.py --sizes 1000x100000  # the GPU target size
    python benchmarks/bench_meanshift.py --sizes 11x220,200x4000 --iterations 100 --repeats 7

Sizes are ``RAYSxSEEDS``.
"""

from __future__ import annotations

import argparse
import inspect
import os
import platform
import statistics
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import jaxgaze
from jaxgaze import GazeRays

DEFAULT_SIZES = "11x220,200x4000,1000x20000"
DTYPE = np.float32


# ---------------------------------------------------------------------------
# Scene


def make_scene(num_rays: int, num_seeds: int, seed: int = 0, bandwidth: float = 0.05):
    """People in a room looking at a few shared targets; seeds along their rays.

    About six people per target, origins at head height spread over a floor
    whose area grows with the number of people, directions to the target plus
    0.03 rad of noise. Seeds sit at geometrically spaced depths along the rays,
    like ``find_concurrences`` places them.
    """
    rng = np.random.default_rng(seed)
    groups = max(1, num_rays // 6)
    half = 2.0 * max(1.0, np.sqrt(num_rays / 6.0))  # half-width of the room (m)
    targets = np.column_stack(
        [rng.uniform(-half, half, groups), rng.uniform(-half, half, groups), rng.uniform(0.5, 2.0, groups)]
    )
    member = rng.integers(0, groups, num_rays)
    angle = rng.uniform(0, 2 * np.pi, num_rays)
    radius = rng.uniform(1.0, 4.0, num_rays)
    origins = targets[member] + np.column_stack([radius * np.cos(angle), radius * np.sin(angle), np.zeros(num_rays)])
    origins[:, 2] = rng.uniform(1.5, 1.8, num_rays)
    directions = targets[member] - origins
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    directions = directions + rng.normal(0, 0.03, directions.shape)
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)

    if num_seeds % num_rays == 0:
        depths = np.geomspace(0.4, 16.0, num_seeds // num_rays)
        seeds = origins[:, None, :] + depths[None, :, None] * directions[:, None, :]
        seeds = seeds.reshape(-1, 3)
    else:
        ray = rng.integers(0, num_rays, num_seeds)
        depth = np.exp(rng.uniform(np.log(0.4), np.log(16.0), num_seeds))
        seeds = origins[ray] + depth[:, None] * directions[ray]
    h = np.full(num_rays, bandwidth)
    return origins.astype(DTYPE), directions.astype(DTYPE), h.astype(DTYPE), seeds.astype(DTYPE)


# ---------------------------------------------------------------------------
# numpy reference: eq. 5–6 broadcast over (seeds, rays)


def numpy_meanshift(origins, directions, bandwidth, seeds, iterations):
    """``iterations`` mean-shift steps from every seed, vectorised over (S, N)."""
    p, v, h = origins, directions, bandwidth
    h2 = h * h
    h3 = h2 * h
    x = seeds.copy()
    for _ in range(iterations):
        diff = x[:, None, :] - p[None, :, :]  # (S, N, 3)
        t = np.einsum("snk,nk->sn", diff, v)  # depth along each ray
        dist2 = np.einsum("snk,snk->sn", diff, diff)  # |x - p|^2
        ok = t > 0
        t_safe = np.where(ok, t, DTYPE(1))
        t2 = t_safe * t_safe
        r2 = np.maximum(dist2 - t * t, DTYPE(0))  # |x - x_hat|^2
        w = np.where(ok, np.exp(-r2 / (2 * h2 * t2)) / (h3 * t2), DTYPE(0))
        total = w.sum(axis=1)
        target = w @ p + (w * dist2 / t_safe) @ v
        x = np.where(total[:, None] > 0, target / np.where(total > 0, total, DTYPE(1))[:, None], x)
    return x


# ---------------------------------------------------------------------------
# Timing


def _meanshift_options(max_stretch: int) -> dict:
    """Extra keyword arguments for ``jaxgaze.meanshift``.

    Newer versions of ``meanshift`` take ``max_stretch`` (try stretched steps
    ``x + s (m(x) − x)``, ``s = 1, 2, …, max_stretch``, each costing one more
    evaluation of the field per iteration). ``max_stretch=1`` is the plain eq. 6
    iteration that the numpy reference implements, so that is the default here.
    """
    if "max_stretch" in inspect.signature(jaxgaze.meanshift).parameters:
        return {"max_stretch": max_stretch}
    if max_stretch != 1:
        raise SystemExit("--max-stretch: this version of jaxgaze.meanshift has no max_stretch argument")
    return {}


def _jax_runner(iterations: int, max_stretch: int = 1):
    options = _meanshift_options(max_stretch)
    return jax.jit(lambda rays, seeds: jaxgaze.meanshift(rays, seeds, tol=0.0, max_iter=iterations, **options))


def _xla_runner(iterations: int, max_stretch: int = 1):
    """The unfused XLA loop (what ``meanshift`` runs on CPU), for comparison with the fused GPU kernel."""
    from jaxgaze.concurrence.field import ray_projector, xla_meanshift

    return jax.jit(lambda rays, seeds: xla_meanshift(ray_projector(rays), seeds, 0.0, iterations, max_stretch))


def tune_fused(rays, seeds, iterations: int, max_stretch: int, shapes: str) -> None:
    """Print the fused kernel's rate for tile shapes ``SEEDSxRAYSxWARPS,...`` (GPU only).

    Each shape is compiled and timed in a child process, so one that crashes the
    compiler costs only its own line.
    """
    import subprocess

    n, s = rays.origins.shape[0], seeds.shape[0]
    for shape in shapes.split(","):
        child = subprocess.run(
            [sys.executable, "-W", "ignore", __file__, "--tune-one", shape, "--sizes", f"{n}x{s}",
             "--iterations", str(iterations), "--max-stretch", str(max_stretch)],
            capture_output=True, text=True, env=dict(os.environ, XLA_PYTHON_CLIENT_PREALLOCATE="false"),
        )
        lines = (child.stdout + child.stderr).strip().splitlines()
        print(f"  tune {shape}: " + (lines[-1] if child.returncode == 0 and lines else
                                     f"failed (exit {child.returncode}): {(lines or ['?'])[-1][:200]}"))
        sys.stdout.flush()


def tune_one(shape: str, size: tuple[int, int], iterations: int, max_stretch: int) -> None:
    from jaxgaze.concurrence.field import ray_projector
    from jaxgaze.concurrence.meanshift_pallas import fused_meanshift

    block_seeds, block_rays, warps = (int(v) for v in shape.split("x")[:3])
    approximate = not shape.endswith("exact")
    origins, directions, h, seeds = make_scene(*size)
    proj = ray_projector(GazeRays(origins, directions, h))
    seeds = jnp.asarray(seeds)

    def run():
        return jax.block_until_ready(fused_meanshift(proj, seeds, 0.0, max_iter=iterations, max_stretch=max_stretch,
                                                     block_seeds=block_seeds, block_rays=block_rays, num_warps=warps,
                                                     approximate=approximate))

    run()
    best = min(_timed(run) for _ in range(3))
    print(f"{size[0] * size[1] * iterations / best:.3e} pair-it/s ({best * 1e3:.1f} ms)")


def _timed(fn) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def time_interleaved(fns: dict, repeats: int, max_seconds: float) -> dict[str, list[float]]:
    """Time each callable up to ``repeats`` times, alternating between them.

    Alternating means a burst of load from other processes on a shared machine
    hits both sides alike. A side stops repeating (after at least 2 repeats)
    once it has spent ``max_seconds`` in total.
    """
    times = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            spent = times[name]
            if len(spent) >= 2 and sum(spent) >= max_seconds:
                continue
            start = time.perf_counter()
            fn()
            spent.append(time.perf_counter() - start)
    return times


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def parse_sizes(text: str) -> list[tuple[int, int]]:
    sizes = []
    for item in text.split(","):
        item = item.strip().lower()
        if not item:
            continue
        try:
            n, s = item.split("x")
            sizes.append((int(n), int(s)))
        except ValueError:
            raise SystemExit(f"--sizes: cannot read {item!r}; expected RAYSxSEEDS, e.g. 200x4000") from None
    if not sizes:
        raise SystemExit("--sizes: no sizes given")
    return sizes


def fmt_rate(r: float) -> str:
    return f"{r:.3e}"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", default=None, help=f"comma-separated RAYSxSEEDS (default {DEFAULT_SIZES})")
    parser.add_argument("--iterations", type=int, default=None, help="mean-shift iterations for JAX (default 20; 10 with --quick)")
    parser.add_argument("--repeats", type=int, default=None, help="timed repeats per size and side (default 5; 2 with --quick)")
    parser.add_argument(
        "--numpy-max-pairs",
        type=float,
        default=5e7,
        help="cap numpy at this many pair-iterations per repeat by running fewer iterations (default 5e7)",
    )
    parser.add_argument("--max-seconds", type=float, default=20.0,
                        help="stop repeating a side (after at least 2 repeats) once it has spent this long on one size (default 20)")
    parser.add_argument("--skip-numpy-above", type=float, default=1e9,
                        help="skip the numpy reference when seeds*rays exceeds this (memory; default 1e9)")
    parser.add_argument("--check-iterations", type=int, default=10,
                        help="iterations for the JAX-vs-numpy agreement check (default 10)")
    parser.add_argument("--max-stretch", type=int, default=1,
                        help="passed to jaxgaze.meanshift when it accepts it (default 1 = plain eq. 6, as numpy); "
                             "K > 1 times the stretched-step variant, which does log2(K)+1 extra field evaluations per "
                             "iteration that the pair-iteration count does not include, and skips the agreement check")
    parser.add_argument("--tune", default=None, metavar="SEEDSxRAYSxWARPS,...",
                        help="on a GPU, also time the fused kernel with these tile shapes, e.g. 32x64x4,64x32x4; a suffix xexact divides exactly instead of rcp.approx")
    parser.add_argument("--tune-one", default=None, help=argparse.SUPPRESS)
    parser.add_argument("--quick", action="store_true", help="small sizes, few iterations and repeats (smoke test)")
    args = parser.parse_args(argv)

    if args.quick:
        sizes = parse_sizes(args.sizes or "11x220,200x4000")
        iterations = args.iterations or 10
        repeats = args.repeats or 2
    else:
        sizes = parse_sizes(args.sizes or DEFAULT_SIZES)
        iterations = args.iterations or 20
        repeats = args.repeats or 5
    if iterations < 1 or repeats < 1:
        raise SystemExit("--iterations and --repeats must be positive")

    if args.tune and jax.default_backend() == "gpu" and os.environ.get("XLA_PYTHON_CLIENT_PREALLOCATE") != "false":
        raise SystemExit("--tune: set XLA_PYTHON_CLIENT_PREALLOCATE=false so the child processes get GPU memory")
    if args.tune_one:
        tune_one(args.tune_one, sizes[0], iterations, args.max_stretch)
        return 0

    devices = jax.devices()
    on_gpu = jax.default_backend() == "gpu"
    device_text = ", ".join(f"{d.platform}:{d.device_kind}" for d in devices)
    print(f"jax {jax.__version__}, numpy {np.__version__}, python {platform.python_version()}")
    print(f"host: {cpu_model()}, {os.cpu_count()} CPUs")
    print(f"jax devices: {devices}")
    print(f"dtype float32, JAX iterations {iterations}, repeats {repeats} (best and median reported)")

    runner = _jax_runner(iterations, args.max_stretch)
    options = _meanshift_options(args.max_stretch)
    print(f"jaxgaze.meanshift(rays, seeds, tol=0.0, max_iter={iterations}"
          + "".join(f", {k}={v}" for k, v in options.items()) + ")")
    print()
    rows = []
    for n, s in sizes:
        pairs = n * s
        origins, directions, h, seeds_np = make_scene(n, s)
        rays = GazeRays(origins, directions, h)
        seeds = jnp.asarray(seeds_np)
        assert rays.origins.dtype == jnp.float32 and seeds.dtype == jnp.float32
        do_numpy = pairs <= args.skip_numpy_above
        np_iters = max(1, min(iterations, int(args.numpy_max_pairs // pairs))) if do_numpy else 0

        # --- agreement: same seeds, same number of iterations
        check_iters = min(args.check_iterations, np_iters) if do_numpy else 0
        max_diff = float("nan")
        if do_numpy and args.max_stretch != 1:
            print(f"[{n} rays x {s} seeds] agreement: not checked (--max-stretch {args.max_stretch} is not the "
                  "plain eq. 6 iteration of the numpy reference)")
            numpy_meanshift(origins, directions, h, seeds_np, 1)  # warm-up in place of the check
        elif do_numpy:
            ref = numpy_meanshift(origins, directions, h, seeds_np, check_iters)
            res = _jax_runner(check_iters)(rays, seeds)
            assert int(jnp.min(res.iterations)) == int(jnp.max(res.iterations)) == check_iters
            max_diff = float(np.max(np.abs(np.asarray(res.points) - ref)))
            print(f"[{n} rays x {s} seeds] agreement after {check_iters} iterations: "
                  f"max |x_jax - x_numpy| = {max_diff:.2e} m (points span {np.ptp(ref):.1f} m)")

        # --- JAX warm-up (compile excluded from timing); exact iteration count checked
        res = runner(rays, seeds)
        jax.block_until_ready(res)
        its = np.asarray(res.iterations)
        assert its.min() == its.max() == iterations, (its.min(), its.max())

        # --- timed repeats, JAX and numpy alternating
        # (numpy needs no warm-up beyond the agreement check that already ran it on these arrays)
        fns = {"jax": lambda: jax.block_until_ready(runner(rays, seeds))}
        if on_gpu:  # the unfused XLA loop, to show what the fused kernel gains
            xla = _xla_runner(iterations, args.max_stretch)
            jax.block_until_ready(xla(rays, seeds))
            fns["xla"] = lambda: jax.block_until_ready(xla(rays, seeds))
            if args.tune:
                tune_fused(rays, seeds, iterations, args.max_stretch, args.tune)
        if do_numpy:
            fns["numpy"] = lambda: numpy_meanshift(origins, directions, h, seeds_np, np_iters)
        times = time_interleaved(fns, repeats, args.max_seconds)
        jt = times["jax"]
        jax_rate = pairs * iterations / min(jt)
        jax_med = pairs * iterations / statistics.median(jt)
        print(f"[{n} rays x {s} seeds] jax  : {iterations} it x {len(jt)} repeats, best {min(jt)*1e3:9.2f} ms, "
              f"median {statistics.median(jt)*1e3:9.2f} ms -> {fmt_rate(jax_rate)} pair-it/s")
        if on_gpu:
            xt = times["xla"]
            print(f"[{n} rays x {s} seeds] xla  : unfused loop, best {min(xt)*1e3:9.2f} ms -> "
                  f"{fmt_rate(pairs * iterations / min(xt))} pair-it/s; fused kernel is {min(xt) / min(jt):.1f}x faster")
        np_rate = np_med = float("nan")
        if do_numpy:
            nt = times["numpy"]
            np_rate = pairs * np_iters / min(nt)
            np_med = pairs * np_iters / statistics.median(nt)
            note = "" if np_iters == iterations else "  (fewer iterations to bound time; rate is per pair-iteration)"
            print(f"[{n} rays x {s} seeds] numpy: {np_iters} it x {len(nt)} repeats, best {min(nt)*1e3:9.2f} ms, "
                  f"median {statistics.median(nt)*1e3:9.2f} ms -> {fmt_rate(np_rate)} pair-it/s{note}")
        else:
            print(f"[{n} rays x {s} seeds] numpy: skipped (seeds*rays > --skip-numpy-above)")
        rows.append((n, s, iterations, jax_rate, jax_med, np_iters, np_rate, np_med, max_diff))
        print()
        sys.stdout.flush()

    print("Results (pair-iterations per second = seeds x rays x iterations / s; best of repeats, median in brackets)")
    header = (f"| {'rays x seeds':>14} | {'jax it':>6} | {'jax pair-it/s':>24} | {'np it':>5} | "
              f"{'numpy pair-it/s':>24} | {'ratio':>7} | {'max abs diff m':>14} | device")
    print(header)
    print("|" + "|".join("-" * (len(c)) for c in header.split("|")[1:-1]) + "|--------|")
    for n, s, it, jr, jm, ni, nr, nm, d in rows:
        ratio = jr / nr if nr == nr else float("nan")
        ni_text = str(ni) if ni else "-"
        jax_cell = f"{fmt_rate(jr)} ({fmt_rate(jm)})"
        np_cell = f"{fmt_rate(nr)} ({fmt_rate(nm)})" if ni else "skipped"
        ratio_cell = f"{ratio:.1f}x" if ni else "-"
        diff_cell = f"{d:.2e}" if ni and d == d else "-"
        print(f"| {f'{n}x{s}':>14} | {it:>6} | {jax_cell:>24} | {ni_text:>5} | "
              f"{np_cell:>24} | {ratio_cell:>7} | {diff_cell:>14} | {device_text}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
