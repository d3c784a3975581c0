"""The bias adaptation report (Siegfried et al. 2017): a JSON record of a
:class:`~jaxgaze.bias.adapt.BiasAdaptation` and its per-frame table as CSV, written atomically.
"""

from __future__ import annotations

import json
import math
from typing import Optional

import numpy as np

from jaxgaze.bias.adapt import BIAS_FRAME_COLUMNS, BiasAdaptation
from jaxgaze.io.sampler import sampler_record
from jaxgaze.io.text import atomic_path, csv_writer

__all__ = ["BIAS_JSON_FORMAT", "BIAS_UNITS", "bias_record", "write_bias_report"]

#: The report in words (the ``jaxgaze bias`` help shows it).
BIAS_JSON_FORMAT = """\
BIAS.json holds method, bias and bias_deg ([yaw, tilt]; radians, degrees),
covariance (radians^2) and std_deg (null when unknown), "input" (the files: gaze,
speech, targets, the file the targets came from (null for one --targets point), and
targets_from, what in it), partner, fps, the
selection (num_candidates, num_selected, selected_frames, inliers), for bayes
"posterior": the responsibilities, whether the sampler mixed (result:
successful or not_mixed; r_hat_max, the largest split r-hat, ess_bulk_min,
ess_tail_min, divergences, acceptance_rate) and "parameters", each with mean,
sd, 90% HDI (hdi_5%, hdi_95%), bulk and tail ESS and r_hat; dropped (OpenFace frames dropped,
per reason) and "frames", the per-frame table with one list per column:
  frame, time (s), partner_speaking, head_target_angle_deg, selected,
  error_uncorrected_deg and error_deg (angle between the target direction and
  the gaze before / after correction), looking (error_deg < threshold) and
  probability (bayes: the share of the posterior draws of b with which the
  frame is looking; otherwise looking as 0/1).
"""
#: The record's ``"units"``.
BIAS_UNITS = ("bias [yaw, tilt] in the head frame (+x forward, +y left, +z up): radians (bias, covariance in "
              "radians^2) and degrees (_deg); corrected gaze = gaze + bias; time in seconds")


def _round_list(values, digits: int = 4) -> list:
    return [round(float(v), digits) for v in values]


def _frames(adaptation: BiasAdaptation) -> dict:
    """The per-frame table as JSON lists: ids as int, flags as bool, angles to 4 decimals, probability to 6."""
    table = adaptation.frame_table()
    columns = {}
    for name in BIAS_FRAME_COLUMNS:
        values = table[name]
        if name == "frame":
            columns[name] = [int(f) for f in values]
        elif name == "time":
            columns[name] = [float(t) for t in values]
        elif np.asarray(values).dtype == bool:
            columns[name] = [bool(x) for x in values]
        else:
            columns[name] = _round_list(values, 6 if name == "probability" else 4)
    return columns


def bias_record(adaptation: BiasAdaptation, *, inputs: Optional[dict] = None, fps=None, seed=None,
                dropped: Optional[dict] = None) -> dict:
    """The JSON record of ``adaptation`` (``jaxgaze bias``'s BIAS.json, :data:`BIAS_JSON_FORMAT`).

    ``inputs`` (file names and formats), ``fps``, ``seed`` and ``dropped`` describe where
    the arrays came from and are stored as given.
    """
    estimate, selection, options = adaptation.estimate, adaptation.selection, adaptation.options
    bias = adaptation.bias
    covariance = None if estimate.covariance is None else np.asarray(estimate.covariance, dtype=np.float64)
    posterior = None
    if estimate.method == "bayes":
        posterior = {
            "num_warmup": int(options["num_warmup"]),
            "num_samples": int(options["num_samples"]),
            "num_divergent": int(estimate.sampler.idata.sample_stats["diverging"].sum()),
            "looking_share_mean": float(np.mean(estimate.samples["looking_share"])),
            "responsibilities": _round_list(estimate.responsibilities),
            **sampler_record(estimate.sampler, estimate.result),
        }
    frames = np.asarray(adaptation.frames)
    return {
        "method": estimate.method,
        "units": BIAS_UNITS,
        "bias": [float(x) for x in bias],
        "bias_deg": [float(math.degrees(x)) for x in bias],
        "covariance": None if covariance is None else [[float(x) for x in r] for r in covariance],
        "std_deg": None if covariance is None else [float(math.degrees(math.sqrt(max(v, 0.0))))
                                                   for v in np.diag(covariance)],
        "input": dict(inputs or {}),
        "partner": adaptation.partner,
        "fps": fps,
        "seed": seed,
        "window_s": options["window_s"],
        "max_head_angle_deg": options["max_head_angle_deg"],
        "threshold_deg": options["threshold_deg"],
        "num_frames": int(len(frames)),
        "num_candidates": int(selection.num_candidates),
        "num_requested": int(selection.num_requested),
        "num_selected": int(selection.num_selected),
        "selected_frames": [int(frames[i]) for i in np.asarray(selection.indices)],
        "selected_offsets_deg": [_round_list(np.degrees(o)) for o in adaptation.offsets],
        "inliers": [bool(x) for x in np.asarray(estimate.inliers, dtype=bool)],
        "posterior": posterior,
        "dropped": dict(dropped or {}),
        "num_looking": int(np.sum(adaptation.looking)),
        "mean_probability": float(np.mean(adaptation.probability)),
        "frames": _frames(adaptation),
    }


def write_bias_report(path, record: dict, per_frame_path=None) -> None:
    """Write ``record`` as JSON to ``path`` and, given ``per_frame_path``, its ``"frames"`` as CSV
    (columns :data:`~jaxgaze.bias.adapt.BIAS_FRAME_COLUMNS`, booleans as 0/1).

    Both are written atomically (:func:`~jaxgaze.io.text.atomic_path`): on any failure
    neither file is replaced. ``OSError`` propagates.
    """
    text = json.dumps(record, indent=1, allow_nan=False) + "\n"
    if per_frame_path is None:
        with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8", newline="") as handle:
            handle.write(text)
        return
    table = record["frames"]
    with atomic_path(per_frame_path) as frames_tmp:
        with open(frames_tmp, "w", encoding="utf-8", newline="") as handle:
            writer = csv_writer(handle)
            writer.writerow(BIAS_FRAME_COLUMNS)
            for row in zip(*(table[c] for c in BIAS_FRAME_COLUMNS)):
                writer.writerow([int(x) if isinstance(x, bool) else x for x in row])
        with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8", newline="") as handle:
            handle.write(text)
