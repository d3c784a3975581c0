"""The text ``jaxgaze joint`` prints when a fit is written: each person's bias, cone width and (head pose only)
head-gaze coupling, the concurrences, the sampler's diagnostics and the predictive check's flags."""

from __future__ import annotations

import math

import numpy as np


def summary(posterior, data, written) -> str:
    """The lines ``jaxgaze joint`` prints after writing ``written`` (the output paths)."""
    bias, width = (np.asarray(a) * (180.0 / math.pi) for a in (posterior.bias, posterior.cone_width))
    stats = ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in posterior.sampler.diagnostics._asdict().items())
    check = (posterior.predictive_check[k] for k in ("elsewhere_observed", "elsewhere_predicted", "flagged"))
    return "\n".join([
        f"people: {', '.join(posterior.people)} ({data.num_frames} frames at {data.fps:g} fps, "
        + ("with speech)" if data.has_speech else "no speech)"),
        "bias (yaw, tilt) deg: " + "; ".join(f"{n} ({b[0]:+.2f}, {b[1]:+.2f})" for n, b in zip(posterior.people, bias)),
        "cone width deg: " + "; ".join(f"{n} {w:.2f}" for n, w in zip(posterior.people, width))] + _held(posterior)
        + _coupling(posterior) + [
        f"concurrences: {posterior.num_concurrences}; diagnostics ({posterior.method}): {stats}"] + [
        f"predictive check: {n}'s gaze goes elsewhere in {o:.0%} of frames, the fit predicts {e:.0%} (a wrong mode?)"
        for n, o, e, f in zip(posterior.people, *check) if f] + [
        f"written to {' and '.join(written)}"])


def _held(posterior) -> list[str]:
    """The share of the cone's variance held through a fixation (a fixation's spot), with its 90% interval."""
    if "held_cone_share" not in posterior.samples:
        factor = posterior.spot_log_bayes_factor
        return [] if factor is None else [f"held through a fixation: none (the data favour a fixation's spot by a "
                                          f"factor of {math.exp(factor):.2g}, under the 3 that keeps it)"]
    low, high = posterior.interval("held_cone_share")
    return [f"held through a fixation: {np.mean(posterior.samples['held_cone_share']):.0%} of the cone's variance "
            f"(90% interval {low:.0%}-{high:.0%})"]


def _coupling(posterior) -> list[str]:
    """Head pose only: each person's head-gaze coupling κ (yaw, tilt) with its 90% interval, and the head's lag."""
    if "coupling" not in posterior.samples:
        return []
    kappa, low_high = posterior.samples["coupling"].mean(axis=0), posterior.interval("coupling")
    lag = posterior.samples["head_lag"].mean(axis=0)
    factor = getattr(posterior, "shape_log_bayes_factor", None)
    shape = [] if factor is None else [
        f"head-gaze map: {'a Gaussian process on the linear map' if 'coupling_shape' in posterior.samples else 'linear'}"
        f" (the data favour the Gaussian process by a factor of {math.exp(min(factor, 700.0)):.2g}; 3 keeps it)"]
    return shape + ["head-gaze coupling (share of the gaze's turn the head makes; yaw, tilt; 90% interval): " + "; ".join(
        f"{n} {k[0]:.2f} ({i[0, 0]:.2f}-{i[0, 1]:.2f}), {k[1]:.2f} ({i[1, 0]:.2f}-{i[1, 1]:.2f})"
        for n, k, i in zip(posterior.people, kappa, low_high)),
        "head lag s: " + "; ".join(f"{n} {t:.2f}" for n, t in zip(posterior.people, lag))] + _tilt_width(posterior)


def _tilt_width(posterior) -> list[str]:
    """Head pose only: how much wider the gaze scatters in tilt than in yaw (a tracker reading pitch worse)."""
    if "tilt_width_ratio" not in posterior.samples:
        return []
    low, high = posterior.interval("tilt_width_ratio")
    return [f"tilt scatter / yaw scatter: {np.mean(posterior.samples['tilt_width_ratio']):.2f} "
            f"(90% interval {low:.2f}-{high:.2f})"]
