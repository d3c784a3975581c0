"""Table I (regression-only columns) of Yücel et al. (T-CYB 2013) and the CogSci table, on simulated sessions.

``--people`` experimenters each record ``--sessions`` table-top sessions of
``--duration`` s at 10 fps (:func:`jaxgaze.simulate.tabletop.simulate_tabletop_sessions`:
5–7 objects 20–30 cm apart, about 1.5 m from the robot camera, head pose
under-rotating against gaze, tracker noise 0.02–0.04 rad). The regressors
``f1`` (gaze direction) and ``f2`` (target depth) are fitted on the head poses
(pitch, yaw, roll) of the training sessions (at most ``--train-frames`` frames,
thinned evenly) by GPR (type-II ML) and by the NN baseline, for every
self-referencing split (another session of the same person) and every
cross-referencing split (train on the other people, test on one)
(:func:`jaxgaze.papers.yucel2013.evaluate_regression`).

Printed: Table I's layout (Q1, Q2 per method and split, plus pooled scores, the
head-pose baseline, the mean angular deviation of ``f1`` and GPR's 90 %
interval coverage), the CogSci table (Q1 deviation, Q2(h / hg / hgd) for near,
far, central and peripheral objects) per method and split, and the CMC curve
at a few tolerances. The saliency columns belong to the image-side issue.
"""

from __future__ import annotations

import argparse
import math
import time

import jax
import numpy as np

from jaxgaze.papers.yucel2013 import evaluate_regression, format_cogsci_table, format_table_i
from jaxgaze.headpose.target import TOLERANCE, cmc_curve
from jaxgaze.simulate.tabletop import simulate_tabletop_sessions


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--people", type=int, default=4, help="experimenters (T-CYB set 1: 4)")
    parser.add_argument("--sessions", type=int, default=2, help="sessions per experimenter (T-CYB set 1: 2)")
    parser.add_argument("--duration", type=float, default=60.0, help="seconds per session")
    parser.add_argument("--train-frames", type=int, default=600, help="most training frames per fit (thinned evenly)")
    parser.add_argument("--window", type=int, default=4, help="pooling bin in frames (T-CYB: 4 at 10 fps)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    start = time.time()
    key_sim, key_fit = jax.random.split(jax.random.key(args.seed))
    sessions = simulate_tabletop_sessions(key_sim, num_people=args.people, sessions_per_person=args.sessions,
                                          duration_s=args.duration)
    scores = evaluate_regression(sessions, key=key_fit, window=args.window, max_train_frames=args.train_frames,
                                 progress=True)
    elapsed = time.time() - start

    print("Yücel et al. (T-CYB 2013) Table I, regression-only columns, on the table-top simulator")
    print(f"settings: {args.people} people x {args.sessions} sessions of {args.duration:g} s at 10 fps, seed "
          f"{args.seed}; training frames <= {args.train_frames}; pooling {args.window} frames; features: "
          "head (pitch, yaw, roll); Q2 head pose = raw head direction with the GPR/NN depth")
    print("paper, GPR regression only: self Q1 .24 / Q2 .39, cross Q1 .15 / Q2 .36; NN: self .18 / .36, "
          "cross .19 / .40")
    print()
    print(format_table_i(scores))
    print()
    for s in scores:
        print(format_cogsci_table(s))
        print()
    print("paper (CogSci, NN, 10-fold): Q1 .04-.06 rad; Q2(h) .00-.33, Q2(hg) .16-.55, Q2(hgd) .72-.87")
    print()
    thresholds = np.array([1, 2, 3, 4, 6, 8]) * math.pi / 64
    print("CMC: fraction of frames with |f1 error| <= tau (tau in units of pi/64; 3 = the CogSci tolerance)")
    print("| method | split | " + " | ".join(f"{round(t / (math.pi / 64))}" for t in thresholds) + " |")
    print("|---|---|" + "---|" * len(thresholds))
    for s in scores:
        print(f"| {s.method.upper()} | {s.split} | " + " | ".join(f"{v:.2f}" for v in cmc_curve(s.angular_errors, thresholds)) + " |")
    for split in ("self", "cross"):
        head = next(s for s in scores if s.split == split)
        print(f"| head pose | {split} | " + " | ".join(f"{v:.2f}" for v in cmc_curve(head.head_angular_errors, thresholds)) + " |")
    print()
    print(f"tolerance 3pi/64 = {TOLERANCE:.4f} rad; wall time {elapsed:.0f} s")


if __name__ == "__main__":
    main()
