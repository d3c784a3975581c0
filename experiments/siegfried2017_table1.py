"""Table 1, Fig. 5 and Fig. 6 of Siegfried, Odobez et al. (2017) on simulated dyads.

``--sessions`` two-person sessions per scenario (``interview``, ``desk``) are simulated
(:func:`jaxgaze.simulate.dyadic.simulate_dyadic_sessions`) and every person's gaze
bias is estimated from the first minute by the paper's methods (Baseline, Spk-Mean
N = 20, Spk-Med N = 40, the oracles GT-Mean and GT-Med) and by the Bayesian mixture
(ours, NUTS on the Spk candidates thinned to ≥ 1/3 s apart, ≤ 64 frames), then scored
on every frame after the first minute (:func:`jaxgaze.papers.siegfried2017.evaluate_bias_methods`):
the mean angular error (°) on the ground-truth looking frames and the accuracy of the
looking decision ``e < τ`` (τ = 10°), both averaged per person and then over people.

Printed: Table 1 per scenario and overall (the paper's figures in brackets), the
Bayes decision ``P(e < τ) > 0.5`` and the coverage of its 90% credible region of the
bias, then Fig. 5 (error by 20 s bin after the window) and Fig. 6 (accuracy against τ).
"""

from __future__ import annotations

import argparse
import time

import jax
import numpy as np

from jaxgaze.papers.siegfried2017 import evaluate_bias_methods, format_figure_tables, format_table1
from jaxgaze.simulate.dyadic import PRESETS, simulate_dyadic_sessions


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sessions", type=int, default=20, help="sessions per scenario (2 people each)")
    parser.add_argument("--duration", type=float, default=180.0, help="seconds per session (the first 60 adapt)")
    parser.add_argument("--window", type=float, default=60.0, help="adaptation window, seconds")
    parser.add_argument("--samples", type=int, default=300, help="NUTS warm-up and draws per person")
    parser.add_argument("--time-bin", type=float, default=20.0, help="Fig. 5 bin width, seconds")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    start = time.time()
    key_sim, key_eval = jax.random.split(jax.random.key(args.seed))
    recordings = [simulate_dyadic_sessions(k, args.sessions, preset, duration_s=args.duration)
                  for k, preset in zip(jax.random.split(key_sim, len(PRESETS)), PRESETS)]
    evaluation = evaluate_bias_methods(recordings, key_eval, window_s=args.window, time_bin_s=args.time_bin,
                                       num_warmup=args.samples, num_samples=args.samples)
    elapsed = time.time() - start

    s = evaluation.settings
    print("Siegfried, Odobez et al. (2017), Table 1 on the dyadic simulator")
    print(f"settings: {args.sessions} sessions x 2 people per scenario ({evaluation.num_people} people), "
          f"{args.duration:g} s at 30 fps, seed {args.seed}; window {s['window_s']:g} s, head-target <= "
          f"{s['max_head_angle_deg']:g} deg; Mean N={s['num_mean']}, Med N={s['num_med']}; Bayes: Spk candidates "
          f"thinned to >= {s['bayes_spacing_s']:.2f} s apart, <= {s['num_bayes']} frames "
          f"(used {int(evaluation.num_bayes_frames.min())}-{int(evaluation.num_bayes_frames.max())}), NUTS "
          f"{s['num_warmup']}+{s['num_samples']}, model options {s['bayes_options']}")
    print(f"evaluated: every frame from {s['window_start_s'] + s['window_s']:g} s to the end; error on the "
          f"ground-truth looking frames, accuracy on all of them (tau = {s['threshold_deg']:g} deg)")
    print("paper, overall: Baseline 23.62 deg / 0.56, Lm + Spk-Med 7.64 deg / 0.82, Lm + GT-Mean 7.23 deg / 0.84")
    print()
    print(format_table1(evaluation))
    print()
    agg = evaluation.aggregate()
    low = evaluation.spk_precision < 0.5
    print(f"Spk candidates truly looking: median {np.median(evaluation.spk_precision):.2f}; below 0.5 (where "
          f"LMedS cannot work) for {int(low.sum())} of {evaluation.num_people} people")
    print("mean bias error (deg): " + ", ".join(
        f"{m} {e:.2f}" for m, e in zip(evaluation.methods, agg["overall"]["bias_error_deg"])))
    print(f"NUTS divergences: {int(evaluation.divergences.sum())} in total")
    print()
    print(format_figure_tables(evaluation))
    print()
    print(f"wall time {elapsed:.1f} s")


if __name__ == "__main__":
    main()
