"""The Bayesian bias estimator against LMedS on a grid of contaminated offset sets (Siegfried et al. 2017, eq. 2).

Each cell of the grid (outlier share, glance spread, on-target spread, frames per
set) holds ``num_sets`` offset sets from :func:`jaxgaze.simulate.offsets.simulate_offsets`,
each with its own known bias. Both estimators see the same sets. Per cell:

* the median over sets of the angular error ``‖b̂ − b‖`` (degrees) of LMedS and of
  ``estimate_bias(method="bayes")``'s model with its defaults (the posterior mean);
* the coverage of the Bayes 90% intervals: the share of (set, axis) whose true bias
  lies between the 5% and 95% posterior quantiles.
"""

from __future__ import annotations

import itertools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxgaze.bias.estimators import lmeds_bias, sample_bias_posterior
from jaxgaze.geometry import rad_to_deg
from jaxgaze.simulate.offsets import simulate_offsets

__all__ = ["GridCell", "BiasGridRow", "bias_grid", "format_bias_grid", "GRID"]

#: The full grid: outlier shares, glance spreads (°), on-target spreads (°), frames per set.
GRID = ((0.0, 0.3, 0.6), (10.0, 35.0, 60.0), (1.0, 3.5, 6.0), (20, 60, 200))


class GridCell(NamedTuple):
    outlier_share: float
    outlier_spread_deg: float
    on_target_spread_deg: float
    num_frames: int


class BiasGridRow(NamedTuple):
    """One cell: its settings, the median errors (°) of LMedS and Bayes, and the Bayes 90% coverage."""

    cell: GridCell
    lmeds_error_deg: float
    bayes_error_deg: float
    coverage: float


def _cells(grid) -> list[GridCell]:
    return [GridCell(*c) for c in itertools.product(*grid)]


def bias_grid(key, grid=GRID, *, num_sets: int = 20, num_warmup: int = 300, num_samples: int = 300,
              level: float = 0.9) -> list[BiasGridRow]:
    """Score LMedS and the Bayes default on every cell of ``grid`` (see the module); one row per cell.

    ``grid`` is four sequences (outlier shares, glance spreads in degrees, on-target
    spreads in degrees, frames per set), crossed. All sets with the same number of
    frames go through one NUTS program (one chain per set, fixed keys).
    """
    cells = _cells(grid)
    rows: list[BiasGridRow | None] = [None] * len(cells)
    for n in sorted({c.num_frames for c in cells}):
        picked = [i for i, c in enumerate(cells) if c.num_frames == n]
        sims = [simulate_offsets(jax.random.fold_in(key, i), num_sets, n, outlier_share=cells[i].outlier_share,
                                 outlier_spread_deg=cells[i].outlier_spread_deg,
                                 on_target_spread_deg=cells[i].on_target_spread_deg) for i in picked]
        offsets = jnp.concatenate([s.offsets for s in sims])
        truth = np.concatenate([np.asarray(s.bias) for s in sims])
        lmeds = np.asarray(jax.vmap(lambda o: lmeds_bias(o)[0])(offsets))
        values, stats = sample_bias_posterior(offsets, key=jax.random.fold_in(key, 10_000 + n), num_warmup=num_warmup,
                                              num_samples=num_samples)
        draws = np.asarray(values["bias"][:, 0])  # (sets, draws, 2)
        lo, hi = np.quantile(draws, [(1 - level) / 2, (1 + level) / 2], axis=1)
        covered = (truth >= lo) & (truth <= hi)
        error = lambda b: np.asarray(rad_to_deg(np.linalg.norm(b - truth, axis=-1)))  # noqa: E731
        lmeds_error, bayes_error = error(lmeds), error(draws.mean(1))
        for j, i in enumerate(picked):
            s = slice(j * num_sets, (j + 1) * num_sets)
            rows[i] = BiasGridRow(cells[i], float(np.median(lmeds_error[s])), float(np.median(bayes_error[s])),
                                  float(covered[s].mean()))
    return rows


def format_bias_grid(rows: list[BiasGridRow]) -> str:
    """The grid as a text table: one line per cell, then the worst cell and the coverage range."""
    lines = ["share  glances°  on-target°  frames   LMedS°   Bayes°   Bayes−LMedS°  cover90",
             "-----  --------  ----------  ------   ------   ------   ------------  -------"]
    for r in rows:
        c = r.cell
        lines.append(f"{c.outlier_share:5.2f}  {c.outlier_spread_deg:8.0f}  {c.on_target_spread_deg:10.1f}  "
                     f"{c.num_frames:6d}   {r.lmeds_error_deg:6.2f}   {r.bayes_error_deg:6.2f}   "
                     f"{r.bayes_error_deg - r.lmeds_error_deg:+12.2f}  {r.coverage:7.2f}")
    excess = [r.bayes_error_deg - r.lmeds_error_deg for r in rows]
    cover = [r.coverage for r in rows]
    lines.append(f"worst Bayes − LMedS: {max(excess):+.2f}° ({sum(e > 0.1 for e in excess)} of {len(rows)} cells "
                 f"above +0.1°); coverage {min(cover):.2f}–{max(cover):.2f}, mean {np.mean(cover):.3f}")
    return "\n".join(lines)
