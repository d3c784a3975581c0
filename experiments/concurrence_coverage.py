"""Coverage of the concurrence covariances when the bandwidth is right, too small or too large.

Scenes come from :mod:`jaxgaze.simulate.coverage`, a generator independent of the other
simulators (the one ``tests/concurrence/test_covariance_coverage.py`` uses): 1–3 groups
of 4–8 people, each 1.5–4 m from the group's target, every gaze direction turned
away from the target by a rotation whose angle components perpendicular to it
are ``N(0, σ²)``. Each cell of the grid (noise ``σ`` × the bandwidth the user
gives, as a multiple of ``σ``) runs ``--frames`` scenes through
``find_concurrences_over_frames``. Printed per cell: the count accuracy, and over
the frames whose count is right, the number of matched modes, the median error,
the coverage of the ``--level`` region of the reported covariance (a Student-t,
``region_threshold``) with its standard error, and, for comparison, the coverage
of the Laplace covariance at the user's bandwidth alone (Gaussian, what
``covariances`` was before the noise scale).

Usage::

    python experiments/concurrence_coverage.py [--frames 600] [--seed 0] [--level 0.9]
"""

from __future__ import annotations

import argparse
import time

import jax
import numpy as np
from scipy.stats import chi2

import jaxgaze as jg
from jaxgaze.concurrence.metrics import coverage, localisation_errors
from jaxgaze.simulate.coverage import group_frames


def laplace_only(found, origins, directions, bandwidth):
    """``(JᵀJ + I/s²)⁻¹`` of every mode's members at the user's bandwidth: the covariance without noise scale."""
    covariances = np.broadcast_to(np.eye(3), np.shape(found.covariances)).copy()
    membership = np.asarray(found.membership)
    for t, k in zip(*np.nonzero(np.asarray(found.valid))):
        x, members = np.asarray(found.locations[t, k], float), membership[t] == k
        p, v = origins[t, members], directions[t, members]
        depth = np.sum((x - p) * v, axis=1)
        offset = (x - p) - depth[:, None] * v
        jac = (np.eye(3)[None] - v[:, :, None] * v[:, None, :]) / depth[:, None, None]
        jac = (jac - offset[:, :, None] * v[:, None, :] / depth[:, None, None] ** 2) / bandwidth
        covariances[t, k] = np.linalg.inv(np.einsum("nij,nik->jk", jac, jac) + np.eye(3) / 100.0**2)
    return covariances


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=600, help="scenes per cell (default 600)")
    parser.add_argument("--seed", type=int, default=0, help="numpy seed (default 0)")
    parser.add_argument("--level", type=float, default=0.9, help="credible level (default 0.9)")
    parser.add_argument("--noises", type=float, nargs="+", default=[0.02, 0.05, 0.08], help="σ, radians")
    parser.add_argument("--factors", type=float, nargs="+", default=[1.0, 0.5, 2.0],
                        help="bandwidth given to jaxgaze, in multiples of σ")
    args = parser.parse_args(argv)

    rng = np.random.default_rng(args.seed)
    cells = [(sigma, factor) for sigma in args.noises for factor in args.factors]
    data = [group_frames(rng, sigma, args.frames) for sigma, _ in cells]
    bandwidth = np.concatenate([np.full(d[2].shape, sigma * factor) for d, (sigma, factor) in zip(data, cells)])
    rays = jg.GazeRays(np.concatenate([d[0] for d in data]).astype(np.float32),
                       np.concatenate([d[1] for d in data]).astype(np.float32),
                       bandwidth.astype(np.float32), np.concatenate([d[2] for d in data]))
    start = time.perf_counter()
    found = jg.find_concurrences_over_frames(rays, warm_start=False)  # independent scenes, not a recording
    elapsed = time.perf_counter() - start

    print("Coverage of the concurrence covariances (independent scene generator, count right only)")
    print(f"  {args.frames} scenes per cell, seed {args.seed}, {len(cells) * args.frames} frames in "
          f"{elapsed:.0f} s (incl. compilation); 1-3 groups of 4-8 people, 1.5-4 m from the target")
    print()
    header = (f"  {'σ (rad)':>7}  {'h/σ':>4}  {'count ok':>8}  {'modes':>5}  {'median cm':>9}  "
              f"{f'{100 * args.level:g} % coverage':>16}  {'Laplace only':>12}  {'median ν':>8}")
    print(header)
    print("  " + "-" * (len(header) - 2))
    rows = {}
    first = 0
    for (sigma, factor), (origins, directions, _, targets, target_mask) in zip(cells, data):
        span = np.arange(first, first + len(origins))
        first += len(origins)
        right = np.asarray(found.count)[span] == target_mask.sum(1)
        part = jax.tree_util.tree_map(lambda a: np.asarray(a)[span[right]], found)
        truth, truth_mask = targets[right], target_mask[right]
        errors = localisation_errors(part, truth, truth_mask)
        share = coverage(part, truth, truth_mask, level=args.level)
        old = part._replace(covariances=laplace_only(part, origins[right], directions[right], sigma * factor),
                            degrees_of_freedom=None)
        old_share = coverage(old, truth, truth_mask, level=args.level)
        dof = np.asarray(part.degrees_of_freedom)[np.asarray(part.valid)]
        se = np.sqrt(share * (1 - share) / max(errors.size, 1))
        print(f"  {sigma:>7g}  {factor:>4g}  {100 * right.mean():>7.1f}%  {errors.size:>5d}  "
              f"{100 * np.median(errors):>9.1f}  {100 * share:>9.1f} ± {100 * se:3.1f}  {100 * old_share:>11.1f}%  "
              f"{np.median(dof):>8.1f}")
        rows[(sigma, factor)] = {"count_accuracy": float(right.mean()), "modes": int(errors.size),
                                 "coverage": share, "laplace_only": old_share}
    print()
    print(f"  Laplace only: the Gaussian (JᵀJ)⁻¹ at the user's bandwidth, region χ²₃ ≤ {chi2.ppf(args.level, 3):.2f}.")
    return rows


if __name__ == "__main__":
    main()
