"""The joint model on conversations with a rival explanation (issue 37): is it ever confidently wrong?

Scenes of :data:`jaxgaze.simulate.rivals.RIVAL_CONFIG` (seated, 5–8 people, one frequent
object near the table centre, biases of 5–30°, two quiet people), 60 s at 10 fps, fixed
keys. Each scene is fitted twice by :func:`jaxgaze.joint.fit_joint` (NUTS):

* **pipeline start**: from the Spk-LMedS start, as a user would;
* **rival start**: the same, with the bias of the person who looks at the object most set
  to :func:`~jaxgaze.simulate.rivals.rival_bias` (their object looks mapped onto a neighbour).

With ``--search off`` the rival-mode search is switched off (``PROFILE_MARGIN = −∞``: no
rival is refined), which is the fit before issue 37 (the same start, refinement and mass
matrix), and so is the pruning of the start's redundant concurrences.

A person is **confidently wrong** when the fit says ``successful``, their bias is more than
3° off and the truth lies more than 5 posterior sd away (Mahalanobis, from the draws).
A person whose start is more than 10° off is **recovered** below 1.5°, or **reported** when
the fit says ``ambiguous`` or ``not_mixed``.

Usage::

    python experiments/joint_rivals.py [--scenes 30] [--warmup 500] [--draws 500] [--duration 60] [--method nuts|svi] [--search on|off] [--no-spot] [--cache out.json] [--part I/N]

``--no-spot`` fits the model without a fixation's spot (``_runs.NO_SPOT``; issue 37, item 5), as before it.
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import numpy as np

from _runs import NO_SPOT, confidently_wrong, distance_sd, read_caches, write_cache
from jaxgaze.joint import JointPrior, fit_joint, infer, joint_data, joint_start, rivals
from jaxgaze.results import name
from jaxgaze.simulate import simulate_conversation
from jaxgaze.simulate.rivals import RIVAL_CONFIG, rival_bias


def _errors_deg(estimate, truth):
    d = np.asarray(estimate) - np.asarray(truth)
    d[..., 0] = np.angle(np.exp(1j * d[..., 0]))
    return np.degrees(np.linalg.norm(d, axis=-1))


def _fit(data, scene, start, key, warmup, draws, method="nuts", prior=JointPrior()):
    t0 = time.time()
    post = fit_joint(data, key=key, method=method, num_warmup=warmup, num_samples=draws, num_steps=300, start=start,
                     prior=prior)
    seconds = time.time() - t0
    error = _errors_deg(post.bias, scene.bias)
    distance = distance_sd(post.samples["bias"], scene.bias)
    start_error = _errors_deg(start.bias, scene.bias)
    result = name(post.result)
    return {"result": result, "seconds": seconds, "error": error.tolist(), "start_error": start_error.tolist(),
            "distance_sd": distance.tolist(),
            "confidently_wrong": confidently_wrong(result, error, distance),
            "moved": list(post.modes.moved) if post.modes else [],
            "rivals_tried": post.modes.rivals_tried if post.modes else 0,
            "spot_log_bayes_factor": post.spot_log_bayes_factor, "spot": "held_cone_share" in post.samples,
            "alternatives": [{"person": a.person, "weight": a.weight, "gap": a.log_evidence_gap}
                             for a in post.alternatives]}


def evaluate_scene(key, warmup, draws, duration_s=60.0, method="nuts", prior=JointPrior()):
    k_scene, k_start, k_fit = jax.random.split(key, 3)
    scene = simulate_conversation(k_scene, duration_s=duration_s, config=RIVAL_CONFIG)
    P = scene.num_people
    data = joint_data(scene.eye_positions, scene.R_world_from_head, scene.gaze_angles, present=scene.present,
                      speaking=scene.speaking, measurement_scale=scene.measurement_scale, fps=scene.fps)
    start = joint_start(data, key=k_start)
    person = max(range(P), key=lambda i: int(np.sum(scene.present[:, i] & (scene.target[:, i] >= P))))
    rival = rival_bias(scene, person)
    bias = start.bias.copy()
    bias[person] = rival.bias
    return {"people": P, "rival_person": person, "rival_shift_deg": rival.shift_deg,
            "pipeline": _fit(data, scene, start, k_fit, warmup, draws, method, prior),
            "rival": _fit(data, scene, start._replace(bias=bias), k_fit, warmup, draws, method, prior)}


def _summary(results):
    table = {}
    for label in ("pipeline", "rival"):
        fits = [r[label] for r in results]
        wrong = sum(sum(f["confidently_wrong"]) for f in fits)
        far = [(e, f["result"]) for f in fits for e, s in zip(f["error"], f["start_error"]) if s > 10.0]
        recovered = sum(e < 1.5 for e, _ in far)
        reported = sum(e >= 1.5 and r in ("ambiguous", "not_mixed") for e, r in far)
        table[label] = {"fits": len(fits), "confidently_wrong_people": wrong,
                        "fits_with_one": sum(any(f["confidently_wrong"]) for f in fits),
                        "start_off_10": len(far), "recovered": recovered, "reported": reported,
                        "median_error_deg": float(np.median(np.concatenate([f["error"] for f in fits]))),
                        "results": {k: sum(f["result"] == k for f in fits) for k in sorted({f["result"] for f in fits})},
                        "seconds": float(np.mean([f["seconds"] for f in fits]))}
    return table


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", type=int, default=30)
    parser.add_argument("--warmup", type=int, default=500)
    parser.add_argument("--draws", type=int, default=500)
    parser.add_argument("--seed", type=int, default=37)
    parser.add_argument("--duration", type=float, default=60.0, help="seconds per scene")
    parser.add_argument("--method", choices=("nuts", "svi"), default="nuts",
                        help="svi: 300 steps, a mean-field posterior (narrower than NUTS's: a stricter test of "
                             "'confidently wrong')")
    parser.add_argument("--search", choices=("on", "off"), default="on")
    parser.add_argument("--no-spot", action="store_true",
                        help="the model without a fixation's spot (JointPrior(held_scale=None))")
    parser.add_argument("--cache", default=None, help="JSON file of per-scene results (resumes)")
    parser.add_argument("--part", default="0/1", help="I/N: only the scenes whose index is I modulo N (one "
                        "process per core, each with its own --cache; merge the caches and run again to summarise)")
    args = parser.parse_args(argv)
    if args.search == "off":
        rivals.PROFILE_MARGIN = -np.inf
        infer._prune_concurrences = lambda values, arrays, prior, progress: (
            values, arrays, list(range(arrays.location_centres.shape[1])), None)
    keys = jax.random.split(jax.random.key(args.seed), args.scenes)
    done = {int(k): v for k, v in read_caches([args.cache]).items()}
    part, parts = (int(x) for x in args.part.split("/"))
    for i in range(args.scenes):
        if i in done or i % parts != part:
            continue
        t0 = time.time()
        done[i] = evaluate_scene(keys[i], args.warmup, args.draws, args.duration, args.method,
                                 NO_SPOT if args.no_spot else JointPrior())
        jax.clear_caches()  # each scene's shapes compile their own programs: 6.7 GB after 28 scenes otherwise
        r = done[i]
        print(f"scene {i}: {r['people']} people, rival {r['rival_shift_deg']:.0f}° for person {r['rival_person']}; "
              f"pipeline {r['pipeline']['result']} max error {max(r['pipeline']['error']):.1f}°, "
              f"rival {r['rival']['result']} error {r['rival']['error'][r['rival_person']]:.1f}° "
              f"({time.time() - t0:.0f} s)", flush=True)
        write_cache(args.cache, done)
    if len(done) < args.scenes:
        return {}
    table = _summary([done[i] for i in range(args.scenes)])
    print(json.dumps(table, indent=1))
    return table


if __name__ == "__main__":
    main()
