"""A wearer's calibration as JSON (Park et al. 2012, Sec. 3.2), written by ``jaxgaze calibrate``,
and the gaze rays of a camera-pose CSV through such calibrations.

The JSON holds the cone model in the wearer's **camera** frame (+x forward along the
optical axis, +y left, +z up): ``eye_center`` (metres), unit ``direction`` and
``bandwidth`` h (radians), keys :data:`CALIBRATION_KEYS`, with ``"frame": "camera"``.
Errors raise :class:`~jaxgaze.io.text.InputFileError` (``path, line N: what``, the line
where known); the writer is atomic.
"""

from __future__ import annotations

import json
import math
import os
from typing import NamedTuple, Optional, Sequence

import numpy as np

from jaxgaze.calibration.cone_fit import ConeCalibration
from jaxgaze.io.poses import WearerPoses
from jaxgaze.io.rays import RayRecording, stack_rays
from jaxgaze.io.sampler import finite_or_none, sampler_record
from jaxgaze.io.text import InputFileError, atomic_path, read_text
from jaxgaze.results import RESULTS

__all__ = ["CALIBRATION_KEYS", "WearerCalibration", "read_calibration_json", "write_calibration_json",
           "calibrated_rays"]

#: Keys a calibration JSON must have.
CALIBRATION_KEYS = ("wearer", "frame", "eye_center", "direction", "bandwidth")

_UNITS = ("metres (eye_center), unit vector (direction), radians (bandwidth); camera frame of the wearer: +x forward "
          "(optical axis), +y left, +z up")
_MIN_DIRECTION_NORM = 1e-9


class WearerCalibration(NamedTuple):
    """A calibration read from ``path``: the ``wearer``'s name and their :class:`ConeCalibration`
    (``inliers`` empty, ``alpha``/``xi`` NaN when the file does not hold them)."""

    wearer: str
    cone: ConeCalibration
    path: str


def _json_line(text: str, key: str) -> Optional[int]:
    """Line of the first ``"key"`` in a JSON text, or ``None``."""
    index = text.find(json.dumps(key))
    return None if index < 0 else text.count("\n", 0, index) + 1


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def read_calibration_json(path) -> WearerCalibration:
    """Read a calibration JSON written by :func:`write_calibration_json` (or by hand).

    Raises :class:`InputFileError` naming the file (and the line where known) for
    malformed JSON, a missing key, a wrong shape, a non-finite value, a zero direction,
    a non-positive bandwidth or a ``frame`` other than ``"camera"``. The direction is
    normalised.
    """
    path = os.fspath(path)
    text = read_text(path, InputFileError, "calibration")
    try:
        data = json.loads(text)
    except json.JSONDecodeError as error:
        raise InputFileError(f"calibration is not valid JSON: {error.msg}", path, error.lineno) from None
    if not isinstance(data, dict):
        raise InputFileError("calibration must be a JSON object with keys " + ", ".join(CALIBRATION_KEYS), path, 1)
    missing = [k for k in CALIBRATION_KEYS if k not in data]
    if missing:
        raise InputFileError("calibration is missing key" + ("s " if len(missing) > 1 else " ")
                             + ", ".join(f"'{k}'" for k in missing), path)

    def fail(message: str, key: str) -> InputFileError:
        return InputFileError(f"calibration {message}", path, _json_line(text, key))

    wearer = data["wearer"]
    if not isinstance(wearer, str) or not wearer.strip():
        raise fail("'wearer' must be a non-empty string", "wearer")
    if data["frame"] != "camera":
        raise fail(f"'frame' must be \"camera\", got {data['frame']!r}", "frame")

    def vector(key: str) -> np.ndarray:
        value = data[key]
        if not (isinstance(value, list) and len(value) == 3 and all(_is_number(x) for x in value)):
            raise fail(f"'{key}' must be a list of 3 numbers, got {json.dumps(value)}", key)
        array = np.asarray(value, dtype=np.float64)
        if not np.all(np.isfinite(array)):
            raise fail(f"'{key}' is not finite", key)
        return array

    def scalar(key: str, positive: bool) -> float:
        value = data.get(key)
        if value is None and not positive:
            return math.nan
        if not (_is_number(value) and math.isfinite(value) and (value > 0 or not positive)):
            kind = "a positive number (radians)" if positive else "a finite number"
            raise fail(f"'{key}' must be {kind}, got {json.dumps(value)}", key)
        return float(value)

    eye_center, direction = vector("eye_center"), vector("direction")
    norm = float(np.linalg.norm(direction))
    if norm < _MIN_DIRECTION_NORM:
        raise fail("'direction' has zero length", "direction")
    cone = ConeCalibration(eye_center=eye_center, direction=direction / norm,
                           bandwidth=np.float64(scalar("bandwidth", True)), alpha=np.float64(scalar("alpha", False)),
                           xi=np.float64(scalar("xi", False)), inliers=np.zeros(0, dtype=bool),
                           result=RESULTS.successful)
    return WearerCalibration(wearer.strip(), cone, path)


def _cone_record(cone: ConeCalibration) -> dict:
    direction = np.asarray(cone.direction, dtype=np.float64)
    return {"eye_center": [float(x) for x in np.asarray(cone.eye_center, dtype=np.float64)],
            "direction": [float(x) for x in direction / np.linalg.norm(direction)],
            "bandwidth": float(cone.bandwidth), "alpha": finite_or_none(cone.alpha), "xi": finite_or_none(cone.xi)}


def _write_json(path, record: dict) -> None:
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8", newline="\n") as handle:
        handle.write(json.dumps(record, indent=2, allow_nan=False) + "\n")


def write_calibration_json(path, wearer: str, cone: ConeCalibration, *, posterior=None, posterior_path=None,
                           num_warmup: Optional[int] = None, choice=None) -> dict:
    """Write a successful :class:`ConeCalibration` of ``wearer`` as a calibration JSON; returns the record.

    Keys: :data:`CALIBRATION_KEYS`, ``units``, ``alpha``, ``xi`` (``null`` when eq. 2 was not
    solved), ``num_points`` and ``num_inliers`` (from ``cone.inliers``) and ``method``. With
    ``choice`` (a :class:`~jaxgaze.calibration.posterior.CalibrationChoice`) its cone is written
    instead of ``cone``, ``method`` is its method, and ``"point_estimate"`` holds ``cone`` (the
    RANSAC + eq. 2 estimate), whether it ``disagrees`` with the posterior, its ``region_level``
    and its ``distance_to_posterior_mean`` (m). With ``posterior`` (a
    :class:`~jaxgaze.calibration.posterior.CalibrationPosterior`) a summary goes under
    ``"posterior"`` (its ``result`` name, means, the mixing diagnostics — largest split r-hat,
    smallest bulk and tail ESS, divergences, acceptance — and under ``"parameters"`` each
    parameter's mean, sd, 90% HDI, ESS and r-hat; ``null`` where undefined; draws per chain,
    ``num_warmup``) and its InferenceData is written to ``posterior_path`` (NetCDF; with
    ``posterior_path=None`` none is written and ``"file"`` is ``null``). A posterior that failed
    is written all the same: the caller reports its ``result``.
    Both files are written atomically, and the NetCDF only together with the JSON.
    A NetCDF back-end failure is an ``OSError`` naming ``posterior_path``.
    """
    point_estimate = cone
    if choice is not None:
        cone = choice.cone
    inliers = np.asarray(cone.inliers, dtype=bool)
    record = {
        "wearer": wearer,
        "frame": "camera",
        "units": _UNITS,
        **_cone_record(cone),
        "num_points": int(inliers.size),
        "num_inliers": int(inliers.sum()),
        "method": "ransac+cone" if choice is None else choice.method,
    }
    if choice is not None:
        record["point_estimate"] = {"method": "ransac+cone", **_cone_record(point_estimate),
                                    "disagrees": bool(choice.disagrees), "region_level": float(choice.region_level),
                                    "distance_to_posterior_mean": float(choice.distance)}
    if posterior is None:
        _write_json(path, record)
        return record
    record["posterior"] = {
        "eye_center_mean": [float(x) for x in posterior.eye_center],
        "direction_mean": [float(x) for x in posterior.direction],
        "bandwidth_mean": float(posterior.bandwidth),
        **sampler_record(posterior.sampler, posterior.result),
        "num_samples": len(posterior.samples["bandwidth"]) // int(posterior.sampler.diagnostics.chains),
        "num_warmup": None if num_warmup is None else int(num_warmup),
        "file": None if posterior_path is None else os.path.basename(os.fspath(posterior_path)),
    }
    if posterior_path is None:
        _write_json(path, record)
        return record
    with atomic_path(posterior_path) as netcdf:
        try:
            posterior.sampler.idata.to_netcdf(netcdf)
        except (ValueError, RuntimeError) as error:  # netCDF back-end errors
            raise OSError(0, str(error), os.fspath(posterior_path)) from None
        _write_json(path, record)
    return record


def calibrated_rays(poses: WearerPoses, calibrations: Sequence[WearerCalibration]) -> RayRecording:
    """The gaze rays of several wearers' camera poses through their calibrations.

    Each person's rays are :meth:`ConeCalibration.to_gaze_rays` of their poses:
    ``p = R_world_from_camera @ eye_center + c`` and ``v = R_world_from_camera @ direction``,
    with their calibration's bandwidth; rows keep the file's order within a frame.
    Raises :class:`InputFileError` for two calibrations of one wearer (naming the second
    file) or a person without a calibration (naming the pose file and line).
    """
    by_wearer: dict[str, WearerCalibration] = {}
    for calibration in calibrations:
        first = by_wearer.setdefault(calibration.wearer, calibration)
        if first is not calibration:
            raise InputFileError(f"two calibrations for wearer '{calibration.wearer}' (the other is {first.path})",
                                 calibration.path)
    rows = []
    for person, camera in poses.poses.items():
        calibration = by_wearer.get(person)
        if calibration is None:
            known = ", ".join(f"'{w}'" for w in sorted(by_wearer))
            raise InputFileError(f"no calibration for person '{person}' (calibrated wearers: {known})", poses.path,
                                 int(poses.lines[person].min()))
        rays = calibration.cone.to_gaze_rays(camera.R_world_from_camera, camera.centers)
        origins, directions = np.asarray(rays.origins)[:, 0], np.asarray(rays.directions)[:, 0]
        bandwidth = np.asarray(rays.bandwidth)[:, 0]
        for k, line in enumerate(poses.lines[person]):
            rows.append((int(line), int(camera.frame_ids[k]), person, origins[k], directions[k], bandwidth[k]))
    rows.sort(key=lambda r: r[0])
    return stack_rays([r[1] for r in rows], [r[2] for r in rows], [r[3] for r in rows], [r[4] for r in rows],
                      [r[5] for r in rows], path=poses.path)
