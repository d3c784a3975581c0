"""Why do the joint model's 90% bias intervals cover less than 90% on recordings it was not built on (issue 37, item 5)?

The joint model scores every frame's gaze independently given its target: the cone's
residuals are i.i.d. per frame. Real eyes rest on one spot of a face or an object for a
whole fixation, so residuals are correlated within a fixation, and a posterior that
counts every frame as new evidence is too narrow. This experiment measures that: the
same ``conversation`` scenes with a share ``c`` of the cone's variance held for each
fixation segment (``ConversationConfig.held_cone_share``; 0 is the simulator of every
other experiment), each fitted by NUTS from the pipeline's start.

Figures per share: 90% coverage of the bias components and of the cone widths, the sd of
the bias z-scores ``(b̂ − b)/sd`` (1 for an honest posterior; their spread shows
coverage with fewer scenes), the median bias error, the result codes.

Usage::

    python experiments/joint_bias_coverage.py [--scenes 12] [--shares 0 0.5] [--people 5 5] [--duration 30]
        [--warmup 300] [--draws 300] [--no-spot] [--cache out.json] [--part I/N]

``--no-spot`` fits the model without a fixation's spot (``JointPrior(held_scale=None)``).
"""

from __future__ import annotations

import argparse
import json
import os
import time

import jax
import numpy as np

from _runs import NO_SPOT, read_caches, write_cache
from jaxgaze.joint import JointPrior, fit_joint, joint_data
from jaxgaze.results import name
from jaxgaze.simulate import ConversationConfig, simulate_conversation


def _wrapped(d):
    d = np.array(d, dtype=float)
    d[..., 0] = np.angle(np.exp(1j * d[..., 0]))
    return d


def evaluate_scene(key, share, people, duration_s, warmup, draws, prior=JointPrior()):
    k_scene, k_fit = jax.random.split(key)
    P = int(jax.random.randint(k_scene, (), people[0], people[1] + 1))
    scene = simulate_conversation(k_scene, num_people=P, duration_s=duration_s,
                                  config=ConversationConfig(held_cone_share=share))
    data = joint_data(scene.eye_positions, scene.R_world_from_head, scene.gaze_angles, present=scene.present,
                      speaking=scene.speaking, measurement_scale=scene.measurement_scale, fps=scene.fps)
    t0 = time.time()
    post = fit_joint(data, key=k_fit, num_warmup=warmup, num_samples=draws, prior=prior)
    seconds = time.time() - t0
    draws_b = post.samples["bias"]  # (S, P, 2)
    error = _wrapped(draws_b.mean(0) - scene.bias)
    bias_iv, h_iv = post.interval("bias"), post.interval("cone_width")
    held = post.samples.get("held_cone_share")
    return {"people": P, "result": name(post.result), "seconds": seconds,
            "held_share": None if held is None else float(np.mean(held)),
            "spot_log_bayes_factor": post.spot_log_bayes_factor,
            "z": (error / draws_b.std(0)).ravel().tolist(),
            "error_deg": np.degrees(np.linalg.norm(error, axis=-1)).tolist(),
            "bias_cover": ((scene.bias >= bias_iv[..., 0]) & (scene.bias <= bias_iv[..., 1])).ravel().tolist(),
            "h_cover": ((scene.cone_width >= h_iv[..., 0]) & (scene.cone_width <= h_iv[..., 1])).tolist()}


def _summary(results):
    table = {}
    for share, rs in sorted(results.items()):
        z = np.concatenate([r["z"] for r in rs])
        table[share] = {"scenes": len(rs), "bias_cover": float(np.mean(np.concatenate([r["bias_cover"] for r in rs]))),
                        "h_cover": float(np.mean(np.concatenate([r["h_cover"] for r in rs]))),
                        "z_sd": float(np.sqrt(np.mean(z ** 2))),
                        "median_error_deg": float(np.median(np.concatenate([r["error_deg"] for r in rs]))),
                        "results": {k: sum(r["result"] == k for r in rs) for k in sorted({r["result"] for r in rs})},
                        "seconds": float(np.mean([r["seconds"] for r in rs]))}
    return table


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", type=int, default=12)
    parser.add_argument("--shares", type=float, nargs="+", default=[0.0, 0.5])
    parser.add_argument("--people", type=int, nargs=2, default=[5, 5], help="range (one size compiles once)")
    parser.add_argument("--duration", type=float, default=30.0)
    parser.add_argument("--warmup", type=int, default=300)
    parser.add_argument("--draws", type=int, default=300)
    parser.add_argument("--seed", type=int, default=375)
    parser.add_argument("--no-spot", action="store_true",
                        help="the model without a fixation's spot (JointPrior(held_scale=None))")
    parser.add_argument("--cache", action="append", default=[],
                        help="JSON file of per-scene results (resumes; written to the first, all are read)")
    parser.add_argument("--part", default="0/1", help="I/N: only the runs whose index is I modulo N")
    args = parser.parse_args(argv)
    keys = jax.random.split(jax.random.key(args.seed), args.scenes)  # the same scenes for every share
    done = read_caches(args.cache)
    part, parts = (int(x) for x in args.part.split("/"))
    runs = [(share, i) for share in args.shares for i in range(args.scenes)]
    for n, (share, i) in enumerate(runs):
        label = f"{share:g}/{i}"
        if label in done or n % parts != part:
            continue
        done[label] = evaluate_scene(keys[i], share, args.people, args.duration, args.warmup, args.draws,
                                     NO_SPOT if args.no_spot else JointPrior())
        if os.path.exists("/proc/self/maps") and sum(1 for _ in open("/proc/self/maps")) > 30_000:
            jax.clear_caches()  # each shape compiles its own programs: the process's memory maps would run out
        r = done[label]
        print(f"share {share:g} scene {i}: {r['people']} people, {r['result']}, |z| max {np.max(np.abs(r['z'])):.1f}, "
              f"bias covered {np.mean(r['bias_cover']):.2f} ({r['seconds']:.0f} s)", flush=True)
        write_cache(args.cache[0] if args.cache else None, done)
    if any(f"{share:g}/{i}" not in done for share, i in runs):
        return {}
    table = _summary({share: [done[f"{share:g}/{i}"] for i in range(args.scenes)] for share in args.shares})
    print(json.dumps(table, indent=1))
    return table


if __name__ == "__main__":
    main()
