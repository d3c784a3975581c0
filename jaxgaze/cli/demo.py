"""``jaxgaze demo``: simulate a meeting, find and track its gaze concurrences (Park et al. 2012),
print a per-frame table against the truth and write a figure."""

from __future__ import annotations

import argparse
import math
import os
import time

from jaxgaze.cli._common import CommandError, add_batch_options, check_output, int_at_least, show_progress, writing


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "demo",
        help="simulate a meeting, find and track its concurrences, compare with the truth",
        description="Simulate the 'meeting' scene, find the gaze concurrences of every frame, track them, "
                    "print a per-frame table against the truth and write a figure.",
    )
    parser.add_argument("--frames", type=int_at_least(1), default=None, metavar="N",
                        help="number of frames (default: the preset's)")
    parser.add_argument("--seed", type=int, default=0, metavar="S", help="random seed (default 0)")
    parser.add_argument("--figure", default="jaxgaze_demo.png", metavar="PATH",
                        help="where to write the figure (default jaxgaze_demo.png)")
    add_batch_options(parser)
    return parser


def _figure_format(path: str) -> str:
    """Image format from the figure path's extension; checked before any work is done."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    ext = os.path.splitext(path)[1].lstrip(".").lower()
    supported = FigureCanvasAgg.get_supported_filetypes()
    if ext not in supported:
        raise CommandError(f"unsupported figure format '.{ext}'; use one of "
                           + ", ".join(f".{e}" for e in supported), path)
    check_output(path, "figure")
    return ext


def _write_figure(scene, concurrences, tracks, fmt: str, path: str) -> None:
    from jaxgaze.io.text import atomic_path
    from jaxgaze.plotting import plot_scene_story

    fig = plot_scene_story(scene, concurrences, tracks)
    with writing(path, "figure"), atomic_path(path) as tmp:
        fig.savefig(tmp, format=fmt, dpi=100)


def run(args) -> int:
    import jax
    import numpy as np

    from jaxgaze.concurrence.metrics import evaluate, match_concurrences
    from jaxgaze.concurrence.modes import ConcurrenceOptions, find_concurrences_over_frames, track_concurrences
    from jaxgaze.simulate.scenes import simulate_scene

    fmt = _figure_format(args.figure)
    clock = time.perf_counter()
    scene = simulate_scene(jax.random.key(args.seed), "meeting", num_frames=args.frames)
    t_sim, clock = time.perf_counter() - clock, time.perf_counter()
    above_floor = [[-math.inf, -math.inf, 0.0], [math.inf, math.inf, math.inf]]  # the floor is z = 0
    try:
        concurrences = find_concurrences_over_frames(scene.rays, ConcurrenceOptions(bounds=above_floor),
                                                     frames_per_batch=args.chunk, progress=show_progress(args))
    except ValueError as error:
        raise CommandError(str(error).replace("frames_per_batch", "--chunk")) from None
    tracks = track_concurrences(concurrences)
    t_find = time.perf_counter() - clock

    truth, truth_valid = np.asarray(scene.concurrences), np.asarray(scene.concurrence_valid)
    valid, locations = np.asarray(concurrences.valid), np.asarray(concurrences.locations)
    counts, true_counts = valid.sum(axis=1), truth_valid.sum(axis=1)
    print(f"jaxgaze demo: '{scene.name}' scene, {scene.num_frames} frames at {scene.fps:g} fps, "
          f"{scene.num_people} people, seed {args.seed}, bandwidth {scene.bandwidth:.3f} rad")
    print(f"{'frame':>5} {'time_s':>6} {'K':>2} {'true_K':>6}  {'error_cm':<16} locations_m (x, y, z)")
    for t in range(scene.num_frames):
        est = locations[t][valid[t]]
        match = match_concurrences(est, truth[t][truth_valid[t]])  # Hungarian
        err = np.full(len(est), np.nan)
        err[match.estimated] = 100.0 * match.distances
        err_text = " ".join("-" if not np.isfinite(e) else f"{e:.1f}" for e in err) or "-"
        loc_text = " ".join("({:.2f}, {:.2f}, {:.2f})".format(*x) for x in est) or "-"
        print(f"{t:>5} {t / scene.fps:>6.1f} {counts[t]:>2} {true_counts[t]:>6}  {err_text:<16} {loc_text}")

    clock = time.perf_counter()
    _write_figure(scene, concurrences, tracks, fmt, args.figure)
    t_fig = time.perf_counter() - clock

    result = evaluate(concurrences, scene, level=0.9)
    trajectories = tracks.trajectories(concurrences)
    print("summary:")
    print(f"  count accuracy: {int(np.sum(counts == true_counts))}/{scene.num_frames} frames "
          f"({result.count_accuracy:.1%}) with K = true K")
    if result.num_matched:
        print(f"  localisation error: median {100 * result.median_error:.1f} cm, mean {100 * result.mean_error:.1f}"
              f" ± {100 * result.std_error:.1f} cm over {result.num_matched} matched concurrences")
        print(f"  coverage: {result.coverage:.1%} of true locations inside the 90% Laplace ellipsoid")
    else:
        print("  localisation error: no concurrence matched")
    births = ", ".join(str(tr["birth"]) for tr in trajectories.values())
    print(f"  tracks: {len(trajectories)} (born at frames {births or '-'})")
    print(f"  figure: {args.figure}")
    print(f"  time: simulate {t_sim:.1f} s, concurrences + tracking {t_find:.1f} s, figure {t_fig:.1f} s")
    return 0
