"""The joint model's gradient as NUTS and BFGS run it, and a whole fit, with the gaze measured and from head pose only.

A gradient of the potential timed inside a compiled loop (``jax.lax.fori_loop`` of value-and-gradient steps), where
XLA hoists what depends on the data alone, as it does inside NUTS and BFGS; a gradient called on its own times that
work too and misleads. Four models of one scene (``simulate_conversation(key(5))``, 60 s × 6 people, 10 fps): the gaze
measured or head pose only, each without and with a fixation's spot, in one process, best of ``--rounds``, printed
as ratios to the gaze model without the spot. ``--fits`` also times ``fit_joint`` twice on each input (NUTS 300 +
300; the persistent compilation cache off; the second call reuses the compiled programs), the figure of issue 38's
bound (head pose only within 1.5× of the gaze measured). Its first calls come after the gradients' compilations in
the same process (the start's programs among them), so they are shorter than a fresh process's. Pin it to one core
for figures (``taskset -c 0``); ``benchmarks/RESULTS.md`` has them. ``--no-spot`` fits both without a fixation's spot
(``JointPrior(held_scale=None)``), the same model on both inputs: the gaze-measured fit drops the spot on this scene
by its Bayes factor and head pose only keeps it, whose gradient costs 1.8 times as much. ``--laplace`` times the
Laplace parts (``nuts.laplace_parts``: ``2d`` gradients, one after the other on CPU) of each model at the start
against the same gradients in one ``vmap``, the way they were taken before 2026-12-07.

    python benchmarks/bench_joint_gradient.py [--steps 50] [--rounds 5] [--fits] [--no-spot] [--laplace]
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
from jax.flatten_util import ravel_pytree
from numpyro.infer.util import potential_energy

from jaxgaze.joint import JointPrior, fit_joint, joint_data, joint_start
from jaxgaze.joint import infer
from jaxgaze.nuts import HESSIAN_STEP, laplace_parts
from jaxgaze.simulate import simulate_conversation


def _data(scene, head_only: bool):
    return joint_data(scene.eye_positions, scene.R_world_from_head, None if head_only else scene.gaze_angles,
                      present=scene.present, speaking=scene.speaking, fps=scene.fps,
                      **({} if head_only else {"measurement_scale": scene.measurement_scale}))


def _looped_gradient(data, prior: JointPrior, steps: int):
    start = joint_start(data, key=jax.random.key(1))
    arrays = infer._arrays(data, start.concurrence_centres, jnp.float32)
    values = {k: jnp.asarray(v, jnp.float32)
              for k, v in infer._unconstrained(infer._start_values(start, prior, data.num_people)).items()}
    gradient = jax.value_and_grad(lambda v, a: potential_energy(infer._model(prior, None), tuple(a), {}, v))

    @jax.jit
    def loop(values, arrays):
        def body(_, carry):
            values, total = carry
            energy, grad = gradient(values, arrays)
            return jax.tree.map(lambda x, g: x - 1e-7 * g, values, grad), total + energy

        return jax.lax.fori_loop(0, steps, body, (values, 0.0))[1]

    jax.block_until_ready(loop(values, arrays))
    return lambda: jax.block_until_ready(loop(values, arrays))


def _laplace_times(data, prior: JointPrior, rounds: int) -> tuple[float, float]:
    """Seconds of :func:`jaxgaze.nuts.laplace_parts` at the start, and of the same ``2d`` gradients in one ``vmap``
    (best of ``rounds``, each compiled first)."""
    start = joint_start(data, key=jax.random.key(1))
    arrays = infer._arrays(data, start.concurrence_centres, jnp.float32)
    values = {k: jnp.asarray(v, jnp.float32)
              for k, v in infer._unconstrained(infer._start_values(start, prior, data.num_people)).items()}
    potential = infer._potential(arrays, prior)
    flat, unravel = ravel_pytree(values)
    steps = HESSIAN_STEP * jnp.eye(flat.shape[0], dtype=flat.dtype)
    gradient = jax.grad(lambda x: potential(unravel(x)))
    library = jax.jit(lambda v: laplace_parts(potential, v, 1e-3))
    batched = jax.jit(lambda x: jax.vmap(gradient)(x + jnp.concatenate([steps, -steps])))
    out = []
    for run, argument in ((library, values), (batched, flat)):
        jax.block_until_ready(run(argument))
        best = float("inf")
        for _ in range(rounds):
            t = time.perf_counter()
            jax.block_until_ready(run(argument))
            best = min(best, time.perf_counter() - t)
        out.append(best)
    return out[0], out[1]


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=50, help="gradients per timed call")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--fits", action="store_true", help="also time fit_joint twice on each input")
    parser.add_argument("--no-spot", action="store_true", help="fit both without a fixation's spot")
    parser.add_argument("--laplace", action="store_true",
                        help="also time the Laplace parts against the same gradients in one vmap")
    args = parser.parse_args(argv)
    jax.config.update("jax_enable_compilation_cache", False)  # the first call compiles, as in a fresh install
    scene = simulate_conversation(jax.random.key(5), num_people=6, duration_s=60.0)
    runs = {}
    for head_only in (False, True):
        for spot in (False, True):
            prior = JointPrior() if spot else JointPrior(held_scale=None)
            label = ("head pose only" if head_only else "gaze measured") + (", spot" if spot else "")
            runs[label] = _looped_gradient(_data(scene, head_only), prior, args.steps)
    best = dict.fromkeys(runs, float("inf"))
    for _ in range(args.rounds):
        for label, run in runs.items():
            t = time.perf_counter()
            run()
            best[label] = min(best[label], (time.perf_counter() - t) / args.steps)
    base = best["gaze measured"]
    for label, seconds in best.items():
        print(f"gradient, {label}: {seconds * 1e3:.2f} ms ({seconds / base:.2f}×)")
    if args.laplace:
        for head_only in (False, True):
            for spot in (False, True):
                label = ("head pose only" if head_only else "gaze measured") + (", spot" if spot else "")
                one_by_one, in_one_vmap = _laplace_times(_data(scene, head_only),
                                                         JointPrior() if spot else JointPrior(held_scale=None),
                                                         args.rounds)
                print(f"Laplace, {label}: {one_by_one:.3f} s, in one vmap {in_one_vmap:.3f} s "
                      f"({in_one_vmap / one_by_one:.2f}×)")
    if not args.fits:
        return
    times = {}
    for head_only in (False, True):
        data = _data(scene, head_only)
        for call in (0, 1):
            t = time.perf_counter()
            post = fit_joint(data, key=jax.random.key(0), num_warmup=300, num_samples=300,
                             prior=JointPrior(held_scale=None) if args.no_spot else JointPrior())
            times[head_only, call] = time.perf_counter() - t
            print(f"fit, {'head pose only' if head_only else 'gaze measured'}, call {call + 1}: "
                  f"{times[head_only, call]:.1f} s, spot {'kept' if 'held_cone_share' in post.samples else 'dropped'}, "
                  f"{post.result}")
    for call in (0, 1):
        print(f"fit, call {call + 1}: head pose only / gaze measured = {times[True, call] / times[False, call]:.2f}×")


if __name__ == "__main__":
    main()
