"""Many small calibration posteriors: ``jaxgaze.nuts.sample_nuts`` against numpyro's ``MCMC``.

Both run numpyro's NUTS (dense mass matrix, target acceptance 0.9) on
:func:`jaxgaze.calibration.posterior.calibration_model` for ``--wearers`` simulated
wearers (:func:`jaxgaze.simulate.calibration.simulate_wearers`), one after the
other, in the same process:

* reference: ``numpyro.infer.MCMC(NUTS(...), progress_bar=False, jit_model_args=True)``,
  one object reused for every wearer (numpyro 0.22 recompiles its sampling loop on
  each ``run`` with the progress bar off);
* ours: :func:`jaxgaze.nuts.sample_nuts`, one compiled single-chain program
  reused for every wearer.

Printed: wall time of the whole batch for each (first wearer's compilation
included), seconds per wearer after the first, and the ratio. Both draw the same
number of iterations; no arviz summaries are timed.

    python benchmarks/bench_posterior.py [--wearers 10] [--frames 300] [--samples 300]
"""

from __future__ import annotations

import argparse
import functools
import time

import jax
import jax.numpy as jnp
import numpy as np
from numpyro.infer import MCMC, NUTS

from jaxgaze.calibration.posterior import calibration_model
from jaxgaze.nuts import sample_nuts
from jaxgaze.simulate.calibration import simulate_wearers


def init_params(y):
    return {"eye_center": jnp.zeros(3), "direction_raw": jnp.array([1.0, 0.0, 0.0]),
            "bandwidth": jnp.log(0.05), "outlier_share": jax.scipy.special.logit(0.05)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--wearers", type=int, default=10)
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--samples", type=int, default=300, help="NUTS warm-up and draws per wearer")
    args = parser.parse_args()

    y = jnp.asarray(np.asarray(simulate_wearers(jax.random.key(0), args.wearers,
                                                num_frames=args.frames).points_of_regard_a()))
    mask = jnp.ones(y.shape[:2], bool)
    model = functools.partial(calibration_model)

    mcmc = MCMC(NUTS(model, dense_mass=True, target_accept_prob=0.9), num_warmup=args.samples,
                num_samples=args.samples, progress_bar=False, jit_model_args=True)
    reference = []
    for w in range(args.wearers):
        start = time.perf_counter()
        mcmc.run(jax.random.key(w), y[w], mask[w], init_params=init_params(y[w]))
        jax.block_until_ready(mcmc.get_samples())
        reference.append(time.perf_counter() - start)

    ours = []
    for w in range(args.wearers):
        start = time.perf_counter()
        values, _ = sample_nuts(model, jax.random.key(w), (y[w:w + 1], mask[w:w + 1]),
                                jax.tree_util.tree_map(lambda a: a[None], init_params(y[w])),
                                num_warmup=args.samples, num_samples=args.samples, dense_mass=True,
                                target_accept_prob=0.9)
        ours.append(time.perf_counter() - start)

    ref, own = np.array(reference), np.array(ours)
    print(f"{args.wearers} wearers × {args.frames} points, NUTS {args.samples}+{args.samples}, "
          f"device {jax.devices()[0]}")
    print("| sampler | total s | first wearer s | later wearers s/wearer |")
    print("|---|---|---|---|")
    print(f"| numpyro MCMC (reference) | {ref.sum():.1f} | {ref[0]:.1f} | {np.median(ref[1:]):.2f} |")
    print(f"| jaxgaze sample_nuts | {own.sum():.1f} | {own[0]:.1f} | {np.median(own[1:]):.2f} |")
    print(f"ratio (reference / ours): total {ref.sum() / own.sum():.1f}x, "
          f"per later wearer {np.median(ref[1:]) / np.median(own[1:]):.1f}x")


if __name__ == "__main__":
    main()
