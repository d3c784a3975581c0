"""Joint inference against the two-step pipelines on simulated ``conversation`` scenes.

30 scenes (3–8 people, seated or standing, 1–3 shared objects, speaking turns,
per-person biases of 5–15° and cone widths of 2–6°), 60 s at 10 fps, fixed keys.
Rows:

1. **pipeline, raw**: mean-shift (Park et al. 2012) on the uncorrected rays; a gaze's
   target is the person or mode within 10° of it (Siegfried et al. 2017, eq. 1).
2. **pipeline, Spk-LMedS**: the same after each person's Spk-LMedS bias (eq. 2).
3. **joint**: :func:`jaxgaze.joint.fit_joint` (NUTS), started from row 2.
4. **oracle**: the true memberships; biases by GT-Mean (20 truly-looking frames);
   locations by the weighted least-squares intersection of the members' true-bias rays.

Figures: median bias error (°); concurrence count right (share of frames; a
concurrence is a person or object that ≥ 2 people look at); median localisation
error of object concurrences (cm); frame accuracy of the target; expected
calibration error of the target probability; 90% coverage of biases, cone widths
and object locations.

Usage::

    python experiments/joint_conversation.py [--scenes 30] [--warmup 500] [--draws 500] [--no-spot] [--cache out.json]
        [--part I/N]

``--no-spot`` fits the joint model without a fixation's spot (``_runs.NO_SPOT``; issue 37, item 5), as before it.

With ``--part I/N`` a process fits only the scenes whose index is I modulo N (one process per core, each with its
own ``--cache``); ``--cache`` may be given several times, and the table is printed once every scene has a result.
"""

from __future__ import annotations

import argparse
import math
import time

import jax
import numpy as np

from _runs import NO_SPOT, confidently_wrong, distance_sd, read_caches, write_cache
from jaxgaze.bias import gaze_offsets, target_direction_head
from jaxgaze.bias.looking import gaze_angles_to_direction, head_to_world
from jaxgaze.concurrence import find_concurrences_over_frames
from jaxgaze.joint import (JointPrior, JointStart, expected_calibration_error, fit_joint, joint_data, nearest_target,
                           ray_intersection)
from jaxgaze.joint.init import DEFAULT_CONCURRENCE_OPTIONS, corrected_rays, initial_concurrences, speaker_rule_bias
from jaxgaze.results import name, succeeded
from jaxgaze.simulate import simulate_conversations

CHI2_3_90 = 6.251388631170325  # 90% quantile of χ² with 3 degrees of freedom
MATCH_M = 0.75  # a mode or concurrence within this of an object is that object


def _truth_counts(target, present, C):
    counts = np.stack([((target == c) & present).sum(1) for c in range(C)], 1)
    return (counts >= 2).sum(1), counts


def _object_ids(points, valid, objects, P):
    """Map points (T, M, 3) to object target ids ``P + k`` (nearest within MATCH_M), else −1."""
    if points.shape[1] == 0:
        return np.full(points.shape[:2], -1)
    d = np.linalg.norm(points[:, :, None] - objects[None, None], axis=-1)
    k = np.argmin(d, -1)
    return np.where(valid & (np.min(d, -1) < MATCH_M), P + k, -1)


def _category(raw, P, point_ids):
    """Pipeline target ids (people < P, points ≥ P) → truth categories (people, P + object, −1)."""
    T = raw.shape[0]
    out = raw.copy()
    is_point = raw >= P
    idx = np.clip(raw - P, 0, max(point_ids.shape[1] - 1, 0))
    mapped = point_ids[np.arange(T)[:, None], idx] if point_ids.shape[1] else np.full(raw.shape, -1)
    out[is_point] = mapped[is_point]
    return out


def _pipeline(scene, data, bias, h):
    rays = corrected_rays(data, bias, h)
    found = find_concurrences_over_frames(rays, DEFAULT_CONCURRENCE_OPTIONS)
    valid = np.asarray(found.valid)
    locations = np.asarray(found.locations)
    directions = np.asarray(rays.directions)
    P = data.num_people
    raw = nearest_target(directions, data.eye_positions, data.present, locations, valid)
    point_ids = _object_ids(locations, valid, scene.object_positions, P)
    return {"count": valid.sum(1), "targets": _category(raw, P, point_ids), "locations": locations, "valid": valid,
            "covariances": np.asarray(found.covariances), "point_ids": point_ids}


def _gt_mean_bias(scene, key):
    P = scene.num_people
    out = np.zeros((P, 2))
    keys = jax.random.split(key, P)
    for i in range(P):
        frames = np.flatnonzero(scene.present[:, i] & (scene.target[:, i] >= 0) & (scene.target[:, i] < P))
        pick = frames[np.asarray(jax.random.choice(keys[i], frames.size, (min(20, frames.size),), replace=False))]
        u = target_direction_head(scene.eye_positions[pick, i], scene.target_positions[pick, i],
                                  scene.R_world_from_head[pick, i])
        out[i] = np.asarray(gaze_offsets(scene.gaze_angles[pick, i], u)).mean(0)
    return out


def _angle_error_deg(a, b):
    return np.degrees(np.linalg.norm(np.stack([np.angle(np.exp(1j * (a[..., 0] - b[..., 0]))), a[..., 1] - b[..., 1]],
                                              -1), axis=-1))


def evaluate_scene(scene, key, warmup, draws, prior=JointPrior()):
    k_spk, k_gt, k_fit = jax.random.split(key, 3)
    data = joint_data(scene.eye_positions, scene.R_world_from_head, scene.gaze_angles, present=scene.present,
                      speaking=scene.speaking, measurement_scale=scene.measurement_scale, fps=scene.fps)
    P, K_obj = scene.num_people, scene.num_objects
    present = scene.present
    truth = np.where(present, scene.target, -1)
    true_count, true_members = _truth_counts(truth, present, P + K_obj)
    obj_frames = [(t, k) for t in range(scene.num_frames) for k in range(K_obj) if true_members[t, P + k] >= 2]
    h0 = 0.07
    rows = {}

    # 1–2: pipelines
    spk_bias, used = speaker_rule_bias(data, k_spk)
    for label, bias in (("pipeline, raw", np.zeros((P, 2))), ("pipeline, Spk-LMedS", spk_bias)):
        t0 = time.time()
        r = _pipeline(scene, data, bias, h0)
        errors, covered = [], []
        for t, k in obj_frames:
            hit = np.flatnonzero(r["point_ids"][t] == P + k)
            if hit.size:
                j = hit[np.argmin(np.linalg.norm(r["locations"][t, hit] - scene.object_positions[k], axis=-1))]
                e = r["locations"][t, j] - scene.object_positions[k]
                errors.append(np.linalg.norm(e))
                covered.append(e @ np.linalg.solve(r["covariances"][t, j], e) <= CHI2_3_90)
        rows[label] = {"bias_error": _angle_error_deg(bias, scene.bias).tolist(),
                       "count_right": float(np.mean(r["count"] == true_count)),
                       "loc_errors": errors, "loc_cover": [bool(c) for c in covered],
                       "accuracy": float(np.mean(r["targets"][present] == truth[present])),
                       "seconds": time.time() - t0}

    # 3: joint
    t0 = time.time()
    rays = corrected_rays(data, spk_bias, h0)
    stride = max(1, data.num_frames // 300)
    centres, support = initial_concurrences(data, rays, stride=stride)
    start = JointStart(spk_bias, used, centres, support)
    post = fit_joint(data, key=k_fit, num_warmup=warmup, num_samples=draws, start=start, prior=prior)
    seconds = time.time() - t0
    slots = post.concurrence_locations()
    K = post.num_concurrences
    map_t = post.map_targets()
    slot_mean = post.samples["concurrence_locations"].mean(0) if K else np.zeros((data.num_windows, 0, 3))
    slot_obj = _object_ids(slot_mean[data.window], np.ones((scene.num_frames, K), bool), scene.object_positions, P)
    cat = _category(map_t, P, slot_obj)
    conf = post.membership.max(-1)
    correct = cat == truth  # objects through the slot's nearest object
    errors, covered = [], []
    for t, k in obj_frames:
        members = np.flatnonzero(truth[t] == P + k)
        if K == 0:
            continue
        j = int(np.argmax(post.membership[t, members, P: P + K].sum(0)))
        if slot_obj[t, j] != P + k:
            continue
        e = slots["mean"][t, j] - scene.object_positions[k]
        errors.append(np.linalg.norm(e))
        covered.append(e @ np.linalg.solve(slots["covariance"][t, j], e) <= CHI2_3_90)
    bias_iv = post.interval("bias")
    h_iv = post.interval("cone_width")
    bias_error = _angle_error_deg(post.bias, scene.bias)
    distance = distance_sd(post.samples["bias"], scene.bias)
    rows["joint"] = {"bias_error": bias_error.tolist(),
                     "count_right": float(np.mean(post.concurrence_counts() == true_count)),
                     "loc_errors": errors, "loc_cover": [bool(c) for c in covered],
                     "accuracy": float(np.mean(cat[present] == truth[present])),
                     "confidence": conf[present].tolist(), "correct": correct[present].tolist(),
                     "bias_cover": ((scene.bias >= bias_iv[..., 0]) & (scene.bias <= bias_iv[..., 1])).ravel().tolist(),
                     "h_cover": ((scene.cone_width >= h_iv[..., 0]) & (scene.cone_width <= h_iv[..., 1])).tolist(),
                     "seconds": seconds, "result": str(succeeded(post)), "result_name": name(post.result),
                     "confidently_wrong": int(sum(confidently_wrong(name(post.result), bias_error, distance))),
                     "diagnostics": post.sampler.diagnostics._asdict(),
                     "flagged": post.predictive_check["flagged"].tolist(), "alternatives": len(post.alternatives),
                     "num_concurrences": K, "spot_log_bayes_factor": post.spot_log_bayes_factor,
                     "spot": "held_cone_share" in post.samples}

    # 4: oracle
    gt_bias = _gt_mean_bias(scene, k_gt)
    v_true = np.asarray(head_to_world(gaze_angles_to_direction(np.nan_to_num(scene.gaze_angles) + scene.bias[None]),
                                      scene.R_world_from_head))
    errors = []
    for t, k in obj_frames:
        members = np.flatnonzero(truth[t] == P + k)
        w = np.sqrt(scene.cone_width[members] ** 2 + scene.measurement_scale[t, members] ** 2)
        x = ray_intersection(scene.eye_positions[t, members], v_true[t, members], w)
        errors.append(np.linalg.norm(x - scene.object_positions[k]))
    rows["oracle"] = {"bias_error": _angle_error_deg(gt_bias, scene.bias).tolist(), "count_right": 1.0,
                      "loc_errors": errors, "accuracy": 1.0}
    return rows


def _summary(results):
    table = {}
    for label in ("pipeline, raw", "pipeline, Spk-LMedS", "joint", "oracle"):
        rs = [r[label] for r in results]
        row = {"bias_deg": float(np.median(np.concatenate([r["bias_error"] for r in rs]))),
               "count_right": float(np.mean([r["count_right"] for r in rs])),
               "loc_cm": 100 * float(np.median(np.concatenate([r["loc_errors"] for r in rs] + [[np.nan]])[:-1]))
               if any(r["loc_errors"] for r in rs) else math.nan,
               "accuracy": float(np.mean([r["accuracy"] for r in rs]))}
        if "confidence" in rs[0]:
            row["ece"] = expected_calibration_error(np.concatenate([r["confidence"] for r in rs]),
                                                    np.concatenate([r["correct"] for r in rs]))
            row["bias_cover"] = float(np.mean(np.concatenate([r["bias_cover"] for r in rs])))
            row["h_cover"] = float(np.mean(np.concatenate([r["h_cover"] for r in rs])))
            row["mixed"] = int(sum(r["result"] == "True" for r in rs))
            row["confidently_wrong"] = int(sum(r.get("confidently_wrong", 0) for r in rs))
            row["flagged_people"] = int(sum(sum(r.get("flagged", [])) for r in rs))
            row["results"] = {k: sum(r.get("result_name") == k for r in rs) for k in sorted({r.get("result_name", "?")
                                                                                          for r in rs})}
            row["seconds"] = float(np.mean([r["seconds"] for r in rs]))
        if "loc_cover" in rs[0]:
            covers = np.concatenate([r["loc_cover"] for r in rs] + [[]])
            row["loc_cover"] = float(np.mean(covers)) if covers.size else math.nan
        table[label] = row
    return table


def _print(table, n):
    print(f"\nJoint inference vs pipelines on {n} conversation scenes (60 s, 10 fps)\n")
    head = (f"{'method':<22}{'bias °':>8}{'count ok':>10}{'loc cm':>8}{'target acc':>11}{'ECE':>7}"
            f"{'cov b':>7}{'cov h':>7}{'cov x':>7}")
    print(head)
    print("-" * len(head))
    f = lambda v, fmt: (format(v, fmt) if isinstance(v, float) and not math.isnan(v) else "—")  # noqa: E731
    for label, r in table.items():
        print(f"{label:<22}{f(r['bias_deg'], '.2f'):>8}{f(r['count_right'], '.3f'):>10}{f(r['loc_cm'], '.1f'):>8}"
              f"{f(r['accuracy'], '.3f'):>11}{f(r.get('ece', math.nan), '.3f'):>7}{f(r.get('bias_cover', math.nan), '.2f'):>7}"
              f"{f(r.get('h_cover', math.nan), '.2f'):>7}{f(r.get('loc_cover', math.nan), '.2f'):>7}")
    j = table["joint"]
    print(f"\njoint: {j['mixed']}/{n} runs passed the diagnostics; {j['seconds']:.0f} s per scene on average; "
          f"results {j['results']}; confidently wrong people {j['confidently_wrong']}; "
          f"people flagged by the predictive check {j['flagged_people']}")


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", type=int, default=30)
    parser.add_argument("--warmup", type=int, default=500)
    parser.add_argument("--draws", type=int, default=500)
    parser.add_argument("--seed", type=int, default=2026)
    parser.add_argument("--cache", action="append", default=[],
                        help="JSON file of per-scene results (resumes; written to the first, all are read)")
    parser.add_argument("--part", default="0/1", help="I/N: only the scenes whose index is I modulo N")
    parser.add_argument("--no-spot", action="store_true",
                        help="the model without a fixation's spot (JointPrior(held_scale=None))")
    args = parser.parse_args(argv)
    scenes = simulate_conversations(jax.random.key(args.seed), args.scenes)
    keys = jax.random.split(jax.random.key(args.seed + 1), args.scenes)
    done = {int(k): v for k, v in read_caches(args.cache).items()}
    part, parts = (int(x) for x in args.part.split("/"))
    for i, scene in enumerate(scenes):
        if i in done or i % parts != part:
            continue
        t0 = time.time()
        done[i] = evaluate_scene(scene, keys[i], args.warmup, args.draws, NO_SPOT if args.no_spot else JointPrior())
        jax.clear_caches()  # each scene's shapes compile their own programs (the process's memory maps run out)
        print(f"scene {i}: {scene.num_people} people, {scene.num_objects} objects, {time.time() - t0:.0f} s; "
              f"joint acc {done[i]['joint']['accuracy']:.3f} vs Spk {done[i]['pipeline, Spk-LMedS']['accuracy']:.3f}",
              flush=True)
        write_cache(args.cache[0] if args.cache else None, done)
    if len(done) < args.scenes:
        return {}
    table = _summary([done[i] for i in range(args.scenes)])
    _print(table, args.scenes)
    return table


if __name__ == "__main__":
    main()
