"""Joint inference wall time: NUTS on a minute of a 6-person conversation, SVI on a 10-minute 11-person one.

Both on simulated ``conversation`` scenes (:func:`jaxgaze.simulate.simulate_conversation`)
at 10 fps, in one process, each timed twice: the first call (the start — Spk-LMedS
biases and mean-shift — compilation and inference) and a second call on another
scene of the same size (compiled programs reused). The ratio of the two is the
share of compilation. Also printed: the gradient of the model's log density per
second (the unit of NUTS's work) and the median bias error against the truth.

Targets (2-core CPU): NUTS on 60 s × 6 people under 2 minutes; SVI on 10 min ×
11 people under 3 minutes.

    python benchmarks/bench_joint.py [--nuts-draws 500] [--svi-steps 3000] [--skip-svi] [--no-spot]

``--no-spot`` fits the model without a fixation's spot (``JointPrior(held_scale=None)``; issue 37's
item 5 made it the default where the data need it), for that item's cost ratio.
"""

from __future__ import annotations

import argparse
import time

import jax
import numpy as np

from jaxgaze.joint import JointPrior, fit_joint, joint_data
from jaxgaze.results import succeeded
from jaxgaze.simulate import simulate_conversation


def _data(scene):
    return joint_data(scene.eye_positions, scene.R_world_from_head, scene.gaze_angles, present=scene.present,
                      speaking=scene.speaking, measurement_scale=scene.measurement_scale, fps=scene.fps)


def _run(label, scenes, **options):
    rows = []
    for n, scene in enumerate(scenes):
        data = _data(scene)
        start = time.perf_counter()
        post = fit_joint(data, key=jax.random.key(n), **options)
        seconds = time.perf_counter() - start
        error = np.median(np.degrees(np.linalg.norm(post.bias - scene.bias, axis=-1)))
        idata = post.sampler.idata
        steps = idata.sample_stats["n_steps"].values.mean() if "n_steps" in idata.get("sample_stats", {}) \
            else float("nan")
        rows.append((seconds, error, succeeded(post), steps))
        print(f"{label}, call {n + 1}: {seconds:.1f} s, median bias error {error:.2f}°, "
              f"succeeded {succeeded(post)}, mean leapfrog steps {steps:.1f}", flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--nuts-draws", type=int, default=500, help="NUTS warm-up and draws (default 500 each)")
    parser.add_argument("--svi-steps", type=int, default=3000)
    parser.add_argument("--skip-svi", action="store_true")
    parser.add_argument("--no-spot", action="store_true", help="no fixation's spot (JointPrior(held_scale=None))")
    args = parser.parse_args()
    prior = JointPrior(held_scale=None) if args.no_spot else JointPrior()
    print(f"jax {jax.__version__} on {jax.devices()[0].device_kind}")

    short = [simulate_conversation(jax.random.key(100 + k), num_people=6, num_objects=2, duration_s=60.0, fps=10.0)
             for k in range(2)]
    nuts = _run("NUTS 60 s × 6 people", short, num_warmup=args.nuts_draws, num_samples=args.nuts_draws, prior=prior)
    table = [("NUTS, 60 s × 6 people, 10 fps", nuts, 120.0)]
    if not args.skip_svi:
        long = [simulate_conversation(jax.random.key(200 + k), num_people=11, num_objects=2, duration_s=600.0,
                                      fps=10.0) for k in range(2)]
        svi = _run("SVI 10 min × 11 people", long, method="svi", num_steps=args.svi_steps, num_samples=500, prior=prior)
        table.append(("SVI, 10 min × 11 people, 10 fps", svi, 180.0))

    print("\n| run | first call | second call | compile share | median bias error | target |")
    print("|---|---|---|---|---|---|")
    for label, rows, target in table:
        first, second = rows[0][0], rows[1][0]
        print(f"| {label} | {first:.1f} s | {second:.1f} s | {1 - second / first:.0%} | "
              f"{np.mean([r[1] for r in rows]):.2f}° | < {target:.0f} s |")


if __name__ == "__main__":
    main()
