"""How a NUTS posterior went, as a JSON record: its result, mixing diagnostics and per-parameter summary."""

from __future__ import annotations

import math

import numpy as np

from jaxgaze.results import NAMES, code

__all__ = ["sampler_record", "finite_or_none"]


def finite_or_none(value):
    """A finite float, or ``None`` (JSON has no NaN): e.g. the r-hat of a chain that never moved."""
    return float(value) if value is not None and math.isfinite(float(value)) else None


def sampler_record(result, diagnostics: dict, summary) -> dict:
    """The record of one posterior: ``result`` (its :class:`~jaxgaze.results.RESULTS` name), the
    mixing diagnostics of :func:`jaxgaze.nuts.mixing_diagnostics` (``r_hat_max``, ``ess_bulk_min``,
    ``ess_tail_min``, ``divergences``, ``acceptance_rate``, ``chains``) and under ``"parameters"``
    each row of the :func:`jaxgaze.nuts.posterior_summary` table (mean, sd, 90% HDI, bulk and tail
    ESS, split r-hat); ``null`` where a value is undefined.
    """
    return {
        "result": NAMES[int(np.asarray(code(result)))],
        "r_hat_max": finite_or_none(diagnostics["max_rhat"]),
        "ess_bulk_min": finite_or_none(diagnostics["min_ess_bulk"]),
        "ess_tail_min": finite_or_none(diagnostics["min_ess_tail"]),
        "divergences": int(diagnostics["divergences"]),
        "acceptance_rate": finite_or_none(diagnostics["acceptance_rate"]),
        "chains": int(diagnostics["chains"]),
        "parameters": {str(row): {str(column): finite_or_none(value) for column, value in values.items()}
                       for row, values in summary.to_dict(orient="index").items()},
    }
