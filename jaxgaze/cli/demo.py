"""``jaxgaze demo``: simulate a scene, find and track its gaze concurrences (Park et al. 2012),
print a per-frame table against the truth and write a figure."""

from __future__ import annotations

import argparse
import time

from jaxgaze.cli._common import (CommandError, add_batch_options, add_output, int_at_least,
                                 show_progress, summary, writing)

# The presets of jaxgaze.simulate.scenes.PRESETS, listed here so that `jaxgaze --help` loads no simulator.
SCENES = ("meeting", "party", "musical", "mocap")
# The table: one row per (frame, concurrence), concurrences in track order; every column right-aligned.
COLUMNS = (("frame", 5), ("time_s", 6), ("K", 2), ("true_K", 6), ("track", 5), ("x_m", 7), ("y_m", 7), ("z_m", 7),
           ("error_cm", 8))


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "demo",
        help="simulate a scene, find and track its concurrences, compare with the truth",
        description="Simulate a scene of jaxgaze.simulate (Park et al. 2012, Sec. 4), find the gaze concurrences "
                    "of every frame with the default options, track them, print a table with one row per frame "
                    "and concurrence (in track order; error_cm: distance to the matched true concurrence, '-' "
                    "for none) and write a figure. Progress goes to stderr, one line per stage (not with -q).",
    )
    parser.add_argument("--scene", choices=SCENES, default="meeting",
                        help="meeting: two groups, a presenter, two groups (11 people); party: four groups, then "
                             "everyone watches table tennis (11); musical: a seated audience, two groups of actors "
                             "(7); mocap: two markers, three people each (6) (default meeting)")
    parser.add_argument("--frames", type=int_at_least(1), default=None, metavar="N",
                        help="number of frames (default: the preset's)")
    parser.add_argument("--seed", type=int, default=0, metavar="S", help="random seed (default 0)")
    add_output(parser, "--out", dest="figure", what="figure", aliases=("--figure",), default="jaxgaze_demo.png",
               metavar="PATH", help="where to write the figure (default jaxgaze_demo.png)")
    add_batch_options(parser)
    return parser


def _figure_format(path: str) -> None:
    """The figure's format (from its extension) is one matplotlib writes; checked before any work."""
    from jaxgaze.io.figures import figure_format

    try:
        figure_format(path)
    except ValueError as error:
        raise CommandError(str(error), path) from None


def _row(*cells) -> str:
    """One table line: every cell right-aligned in its column's width, so columns line up."""
    return " ".join(f"{cell:>{width}}" for cell, (_, width) in zip(cells, COLUMNS))


def _table(scene, concurrences, tracks) -> list[str]:
    """The table lines: each frame's concurrences sorted by track id, errors against the matched truth."""
    import numpy as np

    from jaxgaze.concurrence.metrics import match_concurrences

    truth, truth_valid = np.asarray(scene.concurrences), np.asarray(scene.concurrence_valid)
    valid, locations, ids = (np.asarray(a) for a in (concurrences.valid, concurrences.locations, tracks.track_ids))
    lines = [_row(*(name for name, _ in COLUMNS))]
    for t in range(scene.num_frames):
        slots = sorted((int(k) for k in range(valid.shape[1]) if valid[t, k]), key=lambda k: int(ids[t, k]))
        match = match_concurrences(locations[t, slots].reshape(-1, 3), truth[t][truth_valid[t]])  # Hungarian
        errors = dict(zip(match.estimated.tolist(), (100.0 * match.distances).tolist()))
        frame = (t, f"{t / scene.fps:.1f}", len(slots), int(truth_valid[t].sum()))
        for i, k in enumerate(slots):
            error = f"{errors[i]:.1f}" if i in errors else "-"
            lines.append(_row(*frame, int(ids[t, k]), *(f"{x:.2f}" for x in locations[t, k]), error))
        if not slots:
            lines.append(_row(*frame, *"-" * 5))
    return lines


def run(args) -> int:
    import jax
    import numpy as np

    from jaxgaze.concurrence import evaluate, find_concurrences_over_frames, track_concurrences
    from jaxgaze.simulate.scenes import simulate_scene

    _figure_format(args.figure)
    clock = time.perf_counter()
    summary(args, f"simulating the '{args.scene}' scene (seed {args.seed})…")
    scene = simulate_scene(jax.random.key(args.seed), args.scene, num_frames=args.frames)
    t_sim, clock = time.perf_counter() - clock, time.perf_counter()
    summary(args, f"finding the concurrences of {scene.num_frames} frames (default options)…")
    try:  # the library's default options, as for `jaxgaze concurrences` and find_concurrences
        concurrences = find_concurrences_over_frames(scene.rays, frames_per_batch=args.chunk,
                                                     progress=show_progress(args))
    except ValueError as error:
        raise CommandError(str(error).replace("frames_per_batch", "--chunk")) from None
    summary(args, "tracking…")
    tracks = track_concurrences(concurrences)
    t_find = time.perf_counter() - clock

    print(f"jaxgaze demo: '{scene.name}' scene, {scene.num_frames} frames at {scene.fps:g} fps, "
          f"{scene.num_people} people, seed {args.seed}, bandwidth {scene.bandwidth:.3f} rad")
    print("\n".join(_table(scene, concurrences, tracks)))

    summary(args, f"drawing the figure {args.figure}…")
    clock = time.perf_counter()
    from jaxgaze.io.figures import write_figure
    from jaxgaze.plotting import plot_scene_story

    with writing(args.figure, "figure"):
        write_figure(args.figure, plot_scene_story(scene, concurrences, tracks))
    t_fig = time.perf_counter() - clock

    result = evaluate(concurrences, scene, level=0.9)
    trajectories = tracks.trajectories(concurrences)
    counts, true_counts = np.asarray(concurrences.count), np.asarray(scene.true_count)
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
