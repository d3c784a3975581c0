"""Table I of Yücel et al. (T-CYB 2013): regression alone vs regression + saliency, on simulated, rendered scenes.

``--people`` experimenters each record ``--sessions`` table-top sessions of
``--duration`` s at 10 fps (:func:`jaxgaze.simulate.tabletop.simulate_tabletop_sessions`:
5–7 objects 20–30 cm apart, about 1.5 m from the robot camera, head pose
under-rotating against gaze, tracker noise 0.02–0.04 rad). Each session's camera
picture is rendered under natural light (:func:`jaxgaze.simulate.render.render_tabletop_scene`:
a cluttered wall, a wooden table, textured cubes at the session's boxes).

The regressors ``f1`` (gaze direction) and ``f2`` (target depth) are fitted on the
head poses (pitch, yaw, roll) of the training sessions (at most ``--train-frames``
frames, thinned evenly, as :mod:`jaxgaze.papers.yucel2013`) by GPR and by the NN baseline,
for every self-referencing split (another session of the same person) and every
cross-referencing split (train on the other people, test on one). On each test
session the target points are pooled over ``--window`` frames and the attended
location is chosen by :func:`jaxgaze.vision.attend.attend_window`: candidates from the
winner-take-all inside the σ = 10 px Gaussian mask, weighted by saliency × the
regression's predictive density (:func:`jaxgaze.vision.attend.evaluate_attention`).

Printed: Table I's layout, Q1 / Q2 (T-CYB eq. 14–15, mean over objects) for the
regression per frame (the paper's "Regr."), pooled, and pooled + saliency with
Itti–Koch–Niebur and spectral residual (Hou & Zhang; stands in for the paper's Judd
and Bruce–Tsotsos maps, which are not implemented), per method and split, and the
paper's numbers beside them.
"""

from __future__ import annotations

import argparse
import time

import jax

from jaxgaze.simulate.tabletop import simulate_tabletop_sessions
from jaxgaze.papers.yucel2013_attention import evaluate_attention, format_attention_table

PAPER_TABLE_I = """paper, T-CYB Table I (Q1 / Q2), real videos, 4 people x 2 sessions:
| method | split | Regr. | Regr.+Itti | Regr.+Judd | Regr.+Bruce |
|---|---|---|---|---|---|
| GPR | self | .24 / .39 | .37 / .56 | .45 / .52 | .40 / .50 |
| GPR | cross | .15 / .36 | .29 / .51 | .36 / .46 | .32 / .43 |
| NN | self | .18 / .36 | .33 / .52 | .44 / .53 | .38 / .52 |
| NN | cross | .19 / .40 | .29 / .45 | .37 / .47 | .35 / .46 |"""


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--people", type=int, default=4, help="experimenters (T-CYB set 1: 4)")
    parser.add_argument("--sessions", type=int, default=2, help="sessions per experimenter (T-CYB set 1: 2)")
    parser.add_argument("--duration", type=float, default=30.0, help="seconds per session")
    parser.add_argument("--train-frames", type=int, default=300, help="most training frames per fit (thinned evenly)")
    parser.add_argument("--window", type=int, default=4, help="pooling bin in frames (T-CYB: 4 at 10 fps)")
    parser.add_argument("--methods", default="gpr,nn", help="regression methods, comma-separated (gpr, nn)")
    parser.add_argument("--max-splits", type=int, default=None, help="first few splits of each kind only")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    start = time.time()
    key_sim, key_fit, key_render = jax.random.split(jax.random.key(args.seed), 3)
    sessions = simulate_tabletop_sessions(key_sim, num_people=args.people, sessions_per_person=args.sessions,
                                          duration_s=args.duration)
    scores = evaluate_attention(sessions, key=key_fit, render_key=key_render,
                                methods=tuple(m.strip() for m in args.methods.split(",")),
                                window=args.window, max_splits=args.max_splits,
                                max_train_frames=args.train_frames, progress=True)
    elapsed = time.time() - start

    print("Yücel et al. (T-CYB 2013) Table I on the table-top simulator, natural light (Q1 / Q2)")
    print(f"settings: {args.people} people x {args.sessions} sessions of {args.duration:g} s at 10 fps, seed "
          f"{args.seed}; training frames <= {args.train_frames}; pooling {args.window} frames; mask sigma 10 px; "
          "Regr. = per frame, Regr. pooled and +saliency = per window; SR = spectral residual")
    print()
    print(format_attention_table(scores))
    print()
    print(PAPER_TABLE_I)
    print()
    print(f"wall time {elapsed:.0f} s")


if __name__ == "__main__":
    main()
