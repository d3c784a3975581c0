"""The Bayesian bias estimator (defaults) against LMedS on a grid of contaminated offsets (Siegfried et al. 2017).

Offset sets with a known bias (:func:`jaxgaze.simulate.offsets.simulate_offsets`):
a share of glances elsewhere, uniform within ± the glance spread of the partner,
and the rest on target with a Gaussian spread. Per cell the median angular error of
LMedS (eq. 2) and of the Bayes posterior mean, and the coverage of the Bayes 90%
intervals (:func:`jaxgaze.papers.bias_grid.bias_grid`).
"""

from __future__ import annotations

import argparse
import time

import jax

from jaxgaze.papers.bias_grid import GRID, bias_grid, format_bias_grid


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sets", type=int, default=40, help="offset sets per cell")
    parser.add_argument("--samples", type=int, default=300, help="NUTS warm-up and draws per set")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    start = time.time()
    rows = bias_grid(jax.random.key(args.seed), GRID, num_sets=args.sets, num_warmup=args.samples,
                     num_samples=args.samples)
    print(format_bias_grid(rows))
    print(f"{args.sets} sets per cell, NUTS {args.samples} + {args.samples}, {time.time() - start:.0f} s")


if __name__ == "__main__":
    main()
