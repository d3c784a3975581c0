"""How a NUTS posterior went, as a JSON record: its result, mixing diagnostics and per-parameter summary."""

from __future__ import annotations

import math

import numpy as np

from jaxgaze.results import NAMES, code

__all__ = ["sampler_record", "finite_or_none"]


def finite_or_none(value):
    """A finite float, or ``None`` (JSON has no NaN): e.g. the r-hat of a chain that never moved."""
    return float(value) if value is not None and math.isfinite(float(value)) else None


def sampler_record(report, result=None) -> dict:
    """The record of one posterior from its :class:`~jaxgaze.nuts.SamplerReport` ``report``: ``result``
    (the name of ``result`` when given, the overall result of a posterior that adds checks beyond
    mixing, e.g. ``implausible``; else of ``report.result``), the mixing diagnostics
    (:class:`~jaxgaze.nuts.MixingDiagnostics`: ``r_hat_max``, ``ess_bulk_min``, ``ess_tail_min``,
    ``divergences``, ``acceptance_rate``, ``chains``) and under ``"parameters"`` each row of its
    summary table (mean, sd, 90% HDI, bulk and tail ESS, split r-hat); ``null`` where a value is
    undefined.
    """
    d = report.diagnostics
    return {
        "result": NAMES[int(np.asarray(code(report.result if result is None else result)))],
        "r_hat_max": finite_or_none(d.max_rhat),
        "ess_bulk_min": finite_or_none(d.min_ess_bulk),
        "ess_tail_min": finite_or_none(d.min_ess_tail),
        "divergences": int(d.divergences),
        "acceptance_rate": finite_or_none(d.acceptance_rate),
        "chains": int(d.chains),
        "parameters": {str(row): {str(column): finite_or_none(value) for column, value in values.items()}
                       for row, values in report.summary.to_dict(orient="index").items()},
    }
