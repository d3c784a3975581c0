"""Gaze-ray calibration on simulated wearers (Park et al. 2012, Sec. 3.2).

For each of ``--wearers`` simulated pair sessions, wearer A's points of regard
``y = R_A (C_B − C_A)`` (camera frame) are calibrated two ways:

* **RANSAC + cone**: :func:`jaxgaze.calibrate_cone` (2-point RANSAC, eq. 1, eq. 2);
* **posterior mean**: :func:`jaxgaze.calibrate_cone_posterior` (NUTS, outlier mixture),
  started at the RANSAC estimate.

Printed: median and 90th-percentile direction error (degrees) and eye-centre error
perpendicular to the gaze axis (cm), and the coverage of the posterior's 90 %
credible regions (direction: angle to the posterior mean within the 90th
percentile of the draws' angles; eye centre: the same for its offset
perpendicular to the axis). Run with ``--outliers 0.2`` for 20 % outlier frames.
"""

from __future__ import annotations

import argparse
import time

import jax
import numpy as np

import jaxgaze as jg
from jaxgaze.simulate_calibration import simulate_wearers


def angle_deg(a, b):
    return float(np.degrees(np.asarray(jg.geometry.angle_between(np.asarray(a), np.asarray(b)))))


def perpendicular(offset, axis):
    return offset - (offset @ axis) * axis


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--wearers", type=int, default=50)
    parser.add_argument("--frames", type=int, default=150)
    parser.add_argument("--outliers", type=float, default=0.0, help="fraction of frames looking elsewhere")
    parser.add_argument("--eye-in-head", type=float, default=0.03, help="radians")
    parser.add_argument("--samples", type=int, default=300, help="NUTS warm-up and draws per wearer")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    start = time.time()
    sessions = simulate_wearers(jax.random.key(args.seed), args.wearers, num_frames=args.frames,
                                eye_in_head=args.eye_in_head, outlier_fraction=args.outliers)
    rows = []
    for i in range(args.wearers):
        s = sessions.take(i)
        y = np.asarray(s.points_of_regard_a())
        truth_eye, truth_dir = np.asarray(s.eye_center_a), np.asarray(s.direction_a)
        point = jg.calibrate_cone(y, key=jax.random.key(i), throw=False)
        post = jg.calibrate_cone_posterior(
            y, key=jax.random.key(10_000 + i), num_warmup=args.samples, num_samples=args.samples,
            init_eye_center=point.eye_center if point.succeeded else None,
            init_direction=point.direction if point.succeeded else None,
        )
        draws_dir, draws_eye = post.samples["direction"], post.samples["eye_center"]
        spread_dir = np.degrees(np.asarray(jg.geometry.angle_between(draws_dir, post.direction[None])))
        spread_eye = np.linalg.norm([perpendicular(e - post.eye_center, post.direction) for e in draws_eye], axis=1)
        rows.append(
            (
                angle_deg(point.direction, truth_dir) if point.succeeded else np.nan,
                np.linalg.norm(perpendicular(np.asarray(point.eye_center) - truth_eye, truth_dir))
                if point.succeeded else np.nan,
                angle_deg(post.direction, truth_dir),
                np.linalg.norm(perpendicular(post.eye_center - truth_eye, truth_dir)),
                angle_deg(post.direction, truth_dir) <= np.percentile(spread_dir, 90),
                np.linalg.norm(perpendicular(truth_eye - post.eye_center, post.direction))
                <= np.percentile(spread_eye, 90),
            )
        )
    r = np.array(rows, dtype=float)
    print(f"Park et al. (2012) Sec. 3.2 calibration — {args.wearers} simulated wearers, {args.frames} frames each")
    print(f"  eye-in-head h = {args.eye_in_head} rad, outliers {100 * args.outliers:.0f} %, "
          f"NUTS {args.samples}+{args.samples} draws, wall time {time.time() - start:.0f} s")
    print()
    print(f"  {'method':<16} {'dir err median':>15} {'dir err p90':>12} {'eye ⊥ median':>13} {'eye ⊥ p90':>10}")
    for name, d, e in (("RANSAC + cone", r[:, 0], r[:, 1]), ("posterior mean", r[:, 2], r[:, 3])):
        print(f"  {name:<16} {np.nanmedian(d):>13.2f} ° {np.nanpercentile(d, 90):>10.2f} ° "
              f"{100 * np.nanmedian(e):>10.1f} cm {100 * np.nanpercentile(e, 90):>7.1f} cm")
    print()
    print(f"  90 % credible coverage: direction {100 * r[:, 4].mean():.0f} %, "
          f"eye centre (⊥ axis) {100 * r[:, 5].mean():.0f} %  (target 80–98 %)")
    print(f"  RANSAC failures: {int(np.isnan(r[:, 0]).sum())}")


if __name__ == "__main__":
    main()
