"""Who looks at whom from head pose and speech alone (issue 38): the joint model with the head–gaze coupling inside.

Each scene is a ``simulate.conversation`` group whose heads turn a person-specific
share ``κ`` (0.4–0.8) of the line of sight, lag the eyes (0.25 s) and carry sway and
tracker noise. The fit sees only the head poses, the eye positions and who speaks
(``joint_data(..., gaze_angles=None)``). Figures, side by side with the baseline that
takes the person nearest to the head's forward ray:

- gazes at a person: the share of frames whose true target is a person that the
  fit's most probable target gets right;
- ECE of ``looks_at`` over all ordered pairs (the event "i looks at j" per frame);
- ``κ`` (yaw and tilt) within ±0.1 of the truth, and its 90% intervals' coverage;
- issue 37's "confidently wrong" people (bias more than 3° off, truth more than 5 sd
  away, fit ``successful``), with the true bias ``λ (ref − rest)``, ``λ = 1/κ − 1``,
  ``ref`` the data's mean head direction and ``rest`` the body's direction; and the people as far off and as narrow
  in any fit, whatever its result code;
- seconds per fit, and the same scene fitted with its gaze measured (``--compare``).

Usage::

    python experiments/joint_head_only.py [--scenes 30] [--people 3 8] [--duration 60] [--warmup 300]
        [--draws 300] [--seed 38] [--compare] [--no-spot] [--coupling-shape RADIANS] [--head-turn-limit DEG]
        [--tracker-tilt-factor F] [--isotropic]
        [--cache out.json] [--part I/N]
"""

from __future__ import annotations

import argparse
import time

import jax
import numpy as np

from _runs import NO_SPOT, confidently_wrong, distance_sd, read_caches, write_cache
from jaxgaze.joint import JointPrior, expected_calibration_error, fit_joint, joint_data
from jaxgaze.results import name
from jaxgaze.simulate import ConversationConfig, simulate_conversation


def _nearest_to_head_ray(data) -> np.ndarray:
    """``(T, P)``: the present person nearest in angle to each head's forward ray."""
    P = data.num_people
    forward = data.R_world_from_head[..., :, 0]
    toward = data.eye_positions[:, None] - data.eye_positions[:, :, None]
    toward = toward / np.maximum(np.linalg.norm(toward, axis=-1, keepdims=True), 1e-9)
    cosine = np.einsum("tik,tijk->tij", forward, toward)
    others = data.present[:, None, :] & ~np.eye(P, dtype=bool)[None]
    return np.where(others, cosine, -2.0).argmax(-1)


def evaluate_scene(key, people, duration_s, warmup, draws, compare, prior=JointPrior(), config=None):
    k_scene, k_fit = jax.random.split(key)
    P = int(jax.random.randint(k_scene, (), people[0], people[1] + 1))
    scene = simulate_conversation(k_scene, num_people=P, duration_s=duration_s, config=config)
    data = joint_data(scene.eye_positions, scene.R_world_from_head, None, present=scene.present,
                      speaking=scene.speaking, fps=scene.fps)
    t0 = time.time()
    post = fit_joint(data, key=k_fit, num_warmup=warmup, num_samples=draws, prior=prior)
    seconds = time.time() - t0
    target = np.asarray(scene.target)
    at_person = data.present & (target >= 0) & (target < P)
    looks = np.asarray(post.looks_at)  # (T, P, P)
    pairs = data.present[:, :, None] & data.present[:, None, :] & ~np.eye(P, dtype=bool)[None]
    event = target[:, :, None] == np.arange(P)[None, None]
    kappa = np.asarray(post.samples["coupling"])  # (S, P, 2)
    lo, hi = np.quantile(kappa, [0.05, 0.95], axis=0)
    truth = np.repeat(np.asarray(scene.head_fraction)[:, None], 2, axis=1)
    lam = 1.0 / truth - 1.0
    rest = np.stack([np.asarray(scene.body_yaw), np.zeros(P)], axis=-1)
    offset = data.head_reference - rest
    offset[:, 0] = np.angle(np.exp(1j * offset[:, 0]))
    bias = lam * offset
    error = np.asarray(post.bias) - bias
    error[:, 0] = np.angle(np.exp(1j * error[:, 0]))
    error_deg = np.degrees(np.linalg.norm(error, axis=-1))
    offsets = np.asarray(post.samples["bias"]) - bias  # (S, P, 2): the draws about the truth, yaw wrapped
    offsets[..., 0] = np.angle(np.exp(1j * offsets[..., 0]))
    b_lo, b_hi = np.quantile(offsets, [0.05, 0.95], axis=0)
    result = name(post.result)
    row = {"people": P, "result": result, "seconds": seconds, "spot_log_bayes_factor": post.spot_log_bayes_factor,
           "shape_log_bayes_factor": post.shape_log_bayes_factor, "shape": "coupling_shape" in post.samples,
           "spot": "held_cone_share" in post.samples,
           "right": int(np.sum(post.map_targets()[at_person] == target[at_person])), "at_person": int(at_person.sum()),
           "baseline_right": int(np.sum(_nearest_to_head_ray(data)[at_person] == target[at_person])),
           "pair_p": looks[pairs].tolist(), "pair_event": event[pairs].tolist(),
           "kappa_error": (kappa.mean(0) - truth).ravel().tolist(),
           "kappa_cover": ((truth >= lo) & (truth <= hi)).ravel().tolist(),
           "lag": np.asarray(post.samples["head_lag"]).mean(0).tolist(),
           "tilt_width_ratio": (float(np.mean(post.samples["tilt_width_ratio"]))
                                if "tilt_width_ratio" in post.samples else None),
           "bias_error_deg": error_deg.tolist(), "bias_cover": ((b_lo <= 0) & (b_hi >= 0)).ravel().tolist(),
           "bias_sd_distance": distance_sd(post.samples["bias"], bias).tolist()}
    row["confidently_wrong"] = confidently_wrong(result, error_deg, row["bias_sd_distance"])
    if compare:
        measured = joint_data(scene.eye_positions, scene.R_world_from_head, scene.gaze_angles, present=scene.present,
                              speaking=scene.speaking, measurement_scale=scene.measurement_scale, fps=scene.fps)
        t0 = time.time()
        gaze_post = fit_joint(measured, key=k_fit, num_warmup=warmup, num_samples=draws)
        row["gaze_seconds"] = time.time() - t0
        row["gaze_right"] = int(np.sum(gaze_post.map_targets()[at_person] == target[at_person]))
    return row


def summarise(done: dict) -> str:
    rows = list(done.values())
    right = sum(r["right"] for r in rows) / sum(r["at_person"] for r in rows)
    base = sum(r["baseline_right"] for r in rows) / sum(r["at_person"] for r in rows)
    ece = expected_calibration_error(np.concatenate([r["pair_p"] for r in rows]),
                                     np.concatenate([r["pair_event"] for r in rows]))
    k_err = np.abs(np.concatenate([r["kappa_error"] for r in rows]))
    k_cover = np.concatenate([r["kappa_cover"] for r in rows])
    wrong = sum(sum(r["confidently_wrong"]) for r in rows)
    results = {}
    for r in rows:
        results[r["result"]] = results.get(r["result"], 0) + 1
    lines = [f"{len(rows)} scenes, head pose + speech only",
             f"gazes at a person right: joint {right:.3f}   nearest person to the head ray {base:.3f}",
             f"ECE of looks_at over all ordered pairs: {ece:.3f}",
             f"kappa within 0.1: {np.mean(k_err <= 0.1):.2f} of {k_err.size} (yaw and tilt); 90% coverage "
             f"{np.mean(k_cover):.2f} (yaw {np.mean(k_cover[0::2]):.2f}, tilt {np.mean(k_cover[1::2]):.2f}); "
             f"median error {np.median(k_err):.3f}",
             f"confidently wrong people: {wrong}; results {results}",
             *([f"far off and narrow whatever the result (bias > 3 deg and > 5 sd off): "
                f"{sum(sum(confidently_wrong('successful', r['bias_error_deg'], r['bias_sd_distance'])) for r in rows)}"]
               if all("bias_sd_distance" in r for r in rows) else []),
             *([f"bias 90% coverage {np.mean(np.concatenate([r['bias_cover'] for r in rows])):.2f} "
                f"(yaw and tilt, {sum(len(r['bias_cover']) for r in rows)})"] if all("bias_cover" in r for r in rows) else []),
             f"seconds per fit: mean {np.mean([r['seconds'] for r in rows]):.0f}"]
    compared = [r for r in rows if "gaze_seconds" in r]
    if compared:
        ratio = np.mean([r["seconds"] for r in compared]) / np.mean([r["gaze_seconds"] for r in compared])
        gaze_right = sum(r["gaze_right"] for r in compared) / sum(r["at_person"] for r in compared)
        lines.append(f"with the gaze measured (same scenes): right {gaze_right:.3f}, seconds ratio head-only / "
                     f"measured {ratio:.2f} over {len(compared)} scenes")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=30)
    parser.add_argument("--people", type=int, nargs=2, default=(3, 8))
    parser.add_argument("--duration", type=float, default=60.0, help="seconds per scene")
    parser.add_argument("--warmup", type=int, default=300)
    parser.add_argument("--draws", type=int, default=300)
    parser.add_argument("--seed", type=int, default=38)
    parser.add_argument("--compare", action="store_true", help="also fit each scene with its gaze measured")
    parser.add_argument("--no-spot", action="store_true",
                        help="the model without a fixation's spot (JointPrior(held_scale=None))")
    parser.add_argument("--coupling-shape", type=float, default=None, metavar="RADIANS",
                        help="a non-linear head-gaze map: JointPrior(coupling_shape_scale=RADIANS)")
    parser.add_argument("--head-turn-limit", type=float, default=0.0, metavar="DEG",
                        help="simulated heads whose turn saturates, L tanh(kappa theta / L) (0: linear)")
    parser.add_argument("--tracker-tilt-factor", type=float, default=1.0, metavar="F",
                        help="simulated head trackers whose pitch error is F times their yaw error (1: the same)")
    parser.add_argument("--isotropic", action="store_true", help="the model whose gaze scatters as widely in tilt as "
                        "in yaw (JointPrior(tilt_width_ratio_log_sd=None))")
    parser.add_argument("--cache", action="append", default=[], help="JSON file(s) of per-scene results (resumes; "
                        "the last one is written)")
    parser.add_argument("--part", default="0/1", help="I/N: only the scenes whose index is I modulo N")
    args = parser.parse_args()
    part, parts = (int(x) for x in args.part.split("/"))
    done = read_caches(args.cache)
    keys = jax.random.split(jax.random.key(args.seed), args.scenes)
    for i in range(args.scenes):
        if str(i) in done or i % parts != part:
            continue
        prior = (NO_SPOT if args.no_spot else JointPrior())._replace(coupling_shape_scale=args.coupling_shape)
        if args.isotropic:
            prior = prior._replace(tilt_width_ratio_log_sd=None)
        config = ConversationConfig()._replace(head_turn_limit_deg=args.head_turn_limit,
                                               tracker_tilt_factor=args.tracker_tilt_factor)
        done[str(i)] = evaluate_scene(keys[i], args.people, args.duration, args.warmup, args.draws, args.compare,
                                      prior, config)
        r = done[str(i)]
        print(f"scene {i}: {r['people']} people, {r['result']}, right {r['right'] / max(r['at_person'], 1):.3f} "
              f"(baseline {r['baseline_right'] / max(r['at_person'], 1):.3f}), max |kappa error| "
              f"{max(abs(e) for e in r['kappa_error']):.3f} ({r['seconds']:.0f} s)"
              + (f", GP map {'kept' if r['shape'] else 'dropped'} (log factor {r['shape_log_bayes_factor']:.1f})"
                 if r["shape_log_bayes_factor"] is not None else ""), flush=True)
        write_cache(args.cache[-1] if args.cache else None, done)
        jax.clear_caches()
    if done:
        print(summarise(done))


if __name__ == "__main__":
    main()
