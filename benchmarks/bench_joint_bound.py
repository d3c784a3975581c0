"""Issue 38's cost bound over several 60-s, 6-person scenes: ``fit_joint`` from head pose only against the same scene
with its gaze measured, scene by scene, as the ratio of the two fits' times.

The scenes are those of ``experiments/joint_head_only.py`` (seed 38, 60 s): scene ``i`` is
``jax.random.split(key(38), 30)[i]``, and the default list holds the eight of its 30 with 6 people. Every scene is
fitted twice on each input and the second call reported, so that no reported fit compiles: a scene whose concurrence
count or spot choice the process met for the first time compiled (or read from the persistent cache) those programs,
and single scenes came out up to twice as slow as their second call (``benchmarks/RESULTS.md``, 2026-12-07).
``--spot`` picks the models:

- ``defaults``: each fit as ``fit_joint`` chooses (the spot kept where its Bayes factor exceeds 3: head pose only
  keeps it on every such scene, the gaze measured on few);
- ``none``: both without a fixation's spot (``JointPrior(held_scale=None)``);
- ``both``: both keep the spot whatever its factor (``infer.SPOT_MIN_LOG_FACTOR`` set to ``−∞`` for the run).

Split the scenes over the cores, one process each, for figures::

    taskset -c 0 python benchmarks/bench_joint_bound.py --scenes 0,3,4,6 [--spot defaults]
    taskset -c 1 python benchmarks/bench_joint_bound.py --scenes 10,11,19,21 [--spot defaults]
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

import jax

from jaxgaze.joint import JointPrior, fit_joint, joint_data
from jaxgaze.joint import infer
from jaxgaze.results import name
from jaxgaze.simulate import simulate_conversation

SIX_PEOPLE = (0, 3, 4, 6, 10, 11, 19, 21)


def _inputs(index: int):
    """The experiment's scene ``index`` as head pose only and with its gaze measured, and the fit's key."""
    k_scene, k_fit = jax.random.split(jax.random.split(jax.random.key(38), 30)[index])
    people = int(jax.random.randint(k_scene, (), 3, 9))
    scene = simulate_conversation(k_scene, num_people=people, duration_s=60.0)
    common = dict(present=scene.present, speaking=scene.speaking, fps=scene.fps)
    head = joint_data(scene.eye_positions, scene.R_world_from_head, None, **common)
    gaze = joint_data(scene.eye_positions, scene.R_world_from_head, scene.gaze_angles,
                      measurement_scale=scene.measurement_scale, **common)
    return people, head, gaze, k_fit


def _timed(data, key, prior, warmup, draws):
    start = time.perf_counter()
    post = fit_joint(data, key=key, prior=prior, num_warmup=warmup, num_samples=draws)
    return time.perf_counter() - start, "held_cone_share" in post.samples, name(post.result)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", default=",".join(map(str, SIX_PEOPLE)), help="comma-separated scene indices")
    parser.add_argument("--spot", choices=("defaults", "none", "both"), default="defaults")
    parser.add_argument("--warmup", type=int, default=500)
    parser.add_argument("--draws", type=int, default=500)
    args = parser.parse_args()
    scenes = [int(s) for s in args.scenes.split(",")]
    prior = JointPrior(held_scale=None) if args.spot == "none" else JointPrior()
    if args.spot == "both":
        infer.SPOT_MIN_LOG_FACTOR = -math.inf
    rows = []
    for index in scenes:
        people, head, gaze, key = _inputs(index)
        (t_head, spot_head, res_head), (t_gaze, spot_gaze, res_gaze) = (
            [_timed(data, key, prior, args.warmup, args.draws) for _ in range(2)][1] for data in (head, gaze))
        rows.append((t_head, t_gaze))
        print(f"scene {index} ({people} people): head pose only {t_head:.1f} s (spot {spot_head}, {res_head}), "
              f"gaze measured {t_gaze:.1f} s (spot {spot_gaze}, {res_gaze}): {t_head / t_gaze:.2f}x", flush=True)
    head_mean = sum(h for h, _ in rows) / len(rows)
    gaze_mean = sum(g for _, g in rows) / len(rows)
    print(f"--spot {args.spot}, {len(rows)} scenes: head pose only {head_mean:.1f} s, gaze measured {gaze_mean:.1f} s "
          f"a fit; ratio of the means {head_mean / gaze_mean:.2f}x, median ratio "
          f"{statistics.median(h / g for h, g in rows):.2f}x (issue 38's bound: 1.5x)")


if __name__ == "__main__":
    main()
