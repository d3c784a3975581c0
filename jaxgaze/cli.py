"""Command-line interface: ``jaxgaze demo``, ``jaxgaze concurrences`` and ``jaxgaze calibrate``.

``jaxgaze concurrences INPUT.csv --out OUT.csv`` finds the gaze concurrences
(Park et al. 2012) of every frame of a recording of primary gaze rays;
``jaxgaze demo`` runs the same pipeline on a simulated meeting and compares
it with the truth; ``jaxgaze calibrate POSES_A POSES_B --out calib.json``
calibrates wearer A's primary gaze ray (camera frame) from a calibration
session in which A looks at B's camera, and ``jaxgaze concurrences POSES.csv
--calibration calib.json ...`` turns raw camera poses into gaze rays with such
calibrations. Errors in the input are reported as one line on stderr,
``jaxgaze: error: <what> (<file>:<line>)``, with exit status 2, and never
leave a partial output file behind.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import json
import logging
import math
import os
import sys
import tempfile
import time

__all__ = ["main", "read_rays_csv", "read_calibration_json", "read_camera_poses_csv", "CSV_COLUMNS",
           "CAMERA_POSE_COLUMNS", "OUTPUT_COLUMNS", "CALIBRATION_KEYS"]

#: Required input columns (a ``bandwidth`` column is optional).
CSV_COLUMNS = ("frame", "person", "ox", "oy", "oz", "dx", "dy", "dz")
#: Input columns of ``concurrences --calibration``: raw camera poses, one row per (frame, person);
#: ``q`` is the unit quaternion (w, x, y, z) of R_camera_from_world in our camera convention.
CAMERA_POSE_COLUMNS = ("frame", "person", "qw", "qx", "qy", "qz", "cx", "cy", "cz")
#: Keys a calibration JSON must have (written by ``jaxgaze calibrate``).
CALIBRATION_KEYS = ("wearer", "frame", "eye_center", "direction", "bandwidth")
#: Output columns, one row per (frame, mode).
OUTPUT_COLUMNS = ("frame", "mode", "x", "y", "z", "var_x", "var_y", "var_z", "num_rays", "field_value")

_DEFAULT_BANDWIDTH = 0.05
_DEFAULT_CHUNK = 32
_DEFAULT_SAMPLES = 500
_MIN_DIRECTION_NORM = 1e-9
_FLOAT32_MAX = 3.4028234e38


class CLIError(Exception):
    """An error to report as ``jaxgaze: error: <what> (<file>:<line>)`` with exit status 2."""

    def __init__(self, what: str, file: str | None = None, line: int | None = None):
        super().__init__(what)
        self.what = " ".join(str(what).split())  # always one line
        self.file = file
        self.line = line

    def __str__(self) -> str:
        if self.file is None:
            return self.what
        where = self.file if self.line is None else f"{self.file}:{self.line}"
        return f"{self.what} ({where})"


# ---------------------------------------------------------------------------
# Argument parsing


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a positive finite number, got {text!r}")
    return value


def _int_at_least(minimum: int):
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be at least {minimum}, got {value}")
        return value

    parse.__name__ = f"integer >= {minimum}"
    return parse


def build_parser() -> argparse.ArgumentParser:
    from jaxgaze import __version__

    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("-q", "--quiet", action="store_true",
                        help="no progress bar (it is also off when stderr is not a terminal)")
    common.add_argument("--chunk", type=_int_at_least(1), default=_DEFAULT_CHUNK, metavar="F",
                        help=f"frames per compiled batch; shorter recordings are padded to F "
                             f"(default {_DEFAULT_CHUNK})")

    parser = argparse.ArgumentParser(
        prog="jaxgaze",
        description="Gaze concurrences (joint attention) from primary gaze rays, in JAX.",
        epilog="Run 'jaxgaze <command> -h' for the options of a command.",
    )
    parser.add_argument("--version", action="version", version=f"jaxgaze {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="<command>", required=True)

    demo = sub.add_parser(
        "demo", parents=[common],
        help="simulate a meeting, find and track its concurrences, compare with the truth",
        description="Simulate the 'meeting' scene, find the gaze concurrences of every frame, track them, "
                    "print a per-frame table against the truth and write a figure.",
    )
    demo.add_argument("--frames", type=_int_at_least(1), default=None, metavar="N",
                      help="number of frames (default: the preset's)")
    demo.add_argument("--seed", type=int, default=0, metavar="S", help="random seed (default 0)")
    demo.add_argument("--figure", default="jaxgaze_demo.png", metavar="PATH",
                      help="where to write the figure (default jaxgaze_demo.png)")
    demo.set_defaults(func=_cmd_demo)

    conc = sub.add_parser(
        "concurrences", parents=[common],
        help="find the gaze concurrences of every frame of a CSV of primary gaze rays",
        description="Read primary gaze rays from INPUT (CSV with header columns "
                    + ", ".join(CSV_COLUMNS)
                    + " and optionally bandwidth; world frame, metres, radians) and write one row per "
                      "(frame, mode) to OUT: " + ", ".join(OUTPUT_COLUMNS) + ". "
                    "Frames without a concurrence give no row.",
    )
    conc.add_argument("input", metavar="INPUT.csv", help="primary gaze rays, one row per (frame, person)")
    conc.add_argument("--out", required=True, metavar="OUT.csv", help="output CSV (replaced only on success)")
    conc.add_argument("--min-rays", type=_int_at_least(2), default=2, metavar="R",
                      help="fewest rays a concurrence must claim (default 2)")
    conc.add_argument("--bounds", type=float, nargs=6, default=None,
                      metavar=("XMIN", "YMIN", "ZMIN", "XMAX", "YMAX", "ZMAX"),
                      help="world box (m) where points of regard can lie; modes outside it are rejected "
                           "(use inf/-inf for open sides)")
    conc.add_argument("--bandwidth", type=_positive_float, default=_DEFAULT_BANDWIDTH, metavar="H",
                      help=f"cone bandwidth h (rad) of every ray when INPUT has no bandwidth column "
                           f"(default {_DEFAULT_BANDWIDTH}; not used with --calibration)")
    conc.add_argument("--calibration", nargs="+", default=None, metavar="CALIB.json",
                      help="calibrations written by 'jaxgaze calibrate', one per wearer; INPUT is then a CSV "
                           "of raw camera poses with columns " + ", ".join(CAMERA_POSE_COLUMNS)
                           + " (q: unit quaternion w, x, y, z of R_camera_from_world in the camera frame "
                             "+x forward, +y left, +z up; c: camera centre, world, metres), and each person's "
                             "gaze ray is p = R_world_from_camera eye_center + c, v = R_world_from_camera "
                             "direction, with the calibration's bandwidth (person = the JSON's 'wearer')")
    conc.set_defaults(func=_cmd_concurrences)

    calib = sub.add_parser(
        "calibrate",
        help="calibrate a wearer's primary gaze ray from a session of two people looking at each other's camera",
        description="Calibrate the primary gaze ray (cone model, Park et al. 2012, Sec. 3.2) of wearer A from a "
                    "session in which A looks at B's head-mounted camera. POSES_A and POSES_B are COLMAP "
                    "images.txt files (.txt) or pose CSVs (.csv: frame, qw, qx, qy, qz, cx, cy, cz, with q "
                    "the quaternion of R_camera_from_world in the camera frame +x forward, +y left, +z up); "
                    "frames are matched by frame id. Writes a JSON with the eye centre (metres) and unit "
                    "gaze direction in A's camera frame (+x forward, +y left, +z up) and the bandwidth h "
                    "(radians): wearer, frame, eye_center, direction, bandwidth, num_points, num_inliers, "
                    "method.",
    )
    calib.add_argument("poses_a", metavar="POSES_A", help="camera poses of the wearer (images.txt or .csv)")
    calib.add_argument("poses_b", metavar="POSES_B", help="camera poses of the partner A looks at")
    calib.add_argument("--out", required=True, metavar="CALIB.json", help="output JSON (replaced only on success)")
    calib.add_argument("--posterior", default=None, metavar="POSTERIOR.nc",
                       help="also sample the Bayesian posterior (NUTS, started at the point estimate), write "
                            "its arviz InferenceData to this NetCDF file and a summary into the JSON")
    calib.add_argument("--samples", type=_int_at_least(1), default=_DEFAULT_SAMPLES, metavar="N",
                       help=f"NUTS warm-up steps and draws for --posterior (default {_DEFAULT_SAMPLES})")
    calib.add_argument("--seed", type=int, default=0, metavar="S", help="random seed (default 0)")
    calib.add_argument("--wearer", default=None, metavar="NAME",
                       help="name of the wearer, matched to the 'person' column by 'concurrences "
                            "--calibration' (default: the file name of POSES_A without its extension)")
    calib.add_argument("-q", "--quiet", action="store_true", help="no summary line on stderr")
    calib.set_defaults(func=_cmd_calibrate)
    return parser


def main(argv=None) -> int:
    """Entry point of the ``jaxgaze`` command; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)  # usage errors: argparse prints them and exits 2
    try:
        return int(args.func(args) or 0)
    except CLIError as error:
        print(f"jaxgaze: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("jaxgaze: interrupted", file=sys.stderr)
        return 130


def _progress(args) -> bool:
    if args.quiet:
        return False
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):
        return False


# ---------------------------------------------------------------------------
# Input


def _parse_float(cell: str, column: str, path: str, line: int) -> float:
    text = cell.strip()
    if not text:
        raise CLIError(f"empty cell in column '{column}'", path, line)
    try:
        value = float(text)
    except ValueError:
        raise CLIError(f"column '{column}' is not a number: {cell!r}", path, line) from None
    if not math.isfinite(value):
        raise CLIError(f"column '{column}' is not finite: {cell!r}", path, line)
    if abs(value) > _FLOAT32_MAX:
        raise CLIError(f"column '{column}' is out of range (beyond float32): {cell!r}", path, line)
    return value


def _parse_frame(cell: str, path: str, line: int) -> int:
    value = _parse_float(cell, "frame", path, line)
    if not value.is_integer():
        raise CLIError(f"column 'frame' must be an integer frame id, got {cell!r}", path, line)
    return int(value)


def _read_header(reader, path: str, columns) -> tuple[list, list, dict, int]:
    """First non-blank row as the header: ``(header, lower-case names, {column: index}, its line)``; checks
    that it has every required column once."""
    header = None
    for row in reader:
        if any(cell.strip() for cell in row):
            header = row
            break
    if header is None:
        raise CLIError("input is empty: expected a header row with columns " + ", ".join(columns),
                       path, max(reader.line_num, 1))
    header_line = reader.line_num
    names = [cell.strip().lower() for cell in header]
    duplicated = sorted({n for n in names if names.count(n) > 1 and n})
    if duplicated:
        raise CLIError(f"duplicate column '{duplicated[0]}' in the header", path, header_line)
    missing = [c for c in columns if c not in names]
    if missing:
        raise CLIError(
            "missing column" + ("s " if len(missing) > 1 else " ") + ", ".join(f"'{c}'" for c in missing)
            + " in the header (need " + ", ".join(columns) + ")", path, header_line)
    return header, names, {name: names.index(name) for name in columns}, header_line


def _read_rows(path: str, default_bandwidth: float):
    """Parse and check the CSV; returns ``{frame: [(person, origin, direction, bandwidth, line), ...]}``."""
    try:
        with open(path, "rb") as handle:
            data = handle.read()
    except FileNotFoundError:
        raise CLIError("input file not found", path) from None
    except IsADirectoryError:
        raise CLIError("input is a directory, not a CSV file", path) from None
    except OSError as error:
        raise CLIError(f"cannot read input: {error.strerror or error}", path) from None
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as error:
        line = data[: error.start].count(b"\n") + 1
        raise CLIError(f"input is not UTF-8 text: {error.reason} at byte {error.start}", path, line) from None

    frames: dict[int, list] = {}
    seen: dict[tuple[int, str], int] = {}
    reader = csv.reader(io.StringIO(text, newline=""), strict=True)
    try:
        header, names, index, header_line = _read_header(reader, path, CSV_COLUMNS)
        bw_index = names.index("bandwidth") if "bandwidth" in names else None

        for row in reader:
            line = reader.line_num
            if not any(cell.strip() for cell in row):
                continue  # blank line
            if len(row) != len(header):
                raise CLIError(f"expected {len(header)} fields as in the header, got {len(row)}", path, line)
            frame = _parse_frame(row[index["frame"]], path, line)
            person = row[index["person"]].strip()
            if not person:
                raise CLIError("empty cell in column 'person'", path, line)
            origin = tuple(_parse_float(row[index[c]], c, path, line) for c in ("ox", "oy", "oz"))
            direction = tuple(_parse_float(row[index[c]], c, path, line) for c in ("dx", "dy", "dz"))
            if bw_index is None:
                bandwidth = default_bandwidth
            else:
                bandwidth = _parse_float(row[bw_index], "bandwidth", path, line)
                if bandwidth <= 0:
                    raise CLIError(f"bandwidth must be positive (radians), got {row[bw_index].strip()}",
                                   path, line)
            if math.sqrt(sum(x * x for x in direction)) < _MIN_DIRECTION_NORM:
                raise CLIError("direction (dx, dy, dz) has zero length", path, line)
            first = seen.setdefault((frame, person), line)
            if first != line:
                raise CLIError(f"duplicate ray for frame {frame}, person '{person}' (first on line {first})",
                               path, line)
            frames.setdefault(frame, []).append((person, origin, direction, bandwidth, line))
    except csv.Error as error:
        raise CLIError(f"malformed CSV: {error}", path, reader.line_num) from None
    if not frames:
        raise CLIError("no data rows after the header", path, header_line)
    return frames


def read_rays_csv(path: str, default_bandwidth: float = _DEFAULT_BANDWIDTH):
    """Read a CSV of primary gaze rays into a padded recording.

    Returns ``(frame_ids, persons, rays)``: the sorted frame ids ``(T,)``, the
    person labels of each frame (in file order), and :class:`~jaxgaze.GazeRays`
    of shape ``(T, N)`` with ``N`` the most people in any frame and the missing
    slots masked, exactly as :meth:`GazeRays.stack` pads. Raises
    :class:`CLIError` naming the file and line of the first bad row.
    """
    return _rays_from_rows(_read_rows(path, default_bandwidth), path)


def _rays_from_rows(frames, path: str):
    """``{frame: [(person, origin, direction, bandwidth, line), ...]}`` → ``(frame_ids, persons, rays)``."""
    import numpy as np

    from jaxgaze.rays import GazeRays

    frame_ids = sorted(frames)
    t, n = len(frame_ids), max(len(rows) for rows in frames.values())
    origins = np.zeros((t, n, 3))
    directions = np.zeros((t, n, 3))
    directions[..., 0] = 1.0
    bandwidth = np.ones((t, n))
    mask = np.zeros((t, n), dtype=bool)
    persons = []
    for i, frame in enumerate(frame_ids):
        rows = frames[frame]
        persons.append([r[0] for r in rows])
        k = len(rows)
        origins[i, :k] = [r[1] for r in rows]
        directions[i, :k] = [r[2] for r in rows]
        bandwidth[i, :k] = [r[3] for r in rows]
        mask[i, :k] = True
    # One constructor call (the same padding as GazeRays.stack, without its per-frame cost).
    try:
        rays = GazeRays(origins, directions, bandwidth, mask)
    except ValueError as error:
        raise CLIError(str(error), path) from None
    return frame_ids, persons, rays


def _read_input_text(path: str, what: str = "input") -> str:
    try:
        with open(path, "rb") as handle:
            data = handle.read()
    except FileNotFoundError:
        raise CLIError(f"{what} file not found", path) from None
    except IsADirectoryError:
        raise CLIError(f"{what} is a directory, not a file", path) from None
    except OSError as error:
        raise CLIError(f"cannot read {what}: {error.strerror or error}", path) from None
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as error:
        line = data[: error.start].count(b"\n") + 1
        raise CLIError(f"{what} is not UTF-8 text: {error.reason} at byte {error.start}", path, line) from None


def _json_line(text: str, key: str) -> int | None:
    """Line of the first ``"key"`` in a JSON text (for error messages), or ``None``."""
    index = text.find(json.dumps(key))
    return None if index < 0 else text.count("\n", 0, index) + 1


def read_calibration_json(path: str) -> dict:
    """Read a calibration JSON written by ``jaxgaze calibrate``.

    Returns ``{"wearer", "eye_center" (3,), "direction" (3,) unit, "bandwidth", "path"}``
    (camera frame: +x forward, +y left, +z up; metres and radians). Raises
    :class:`CLIError` naming the file (and line where known) for malformed JSON,
    a missing key, a wrong shape, a non-finite value, a zero direction, a
    non-positive bandwidth or a frame other than ``"camera"``.
    """
    import numpy as np

    text = _read_input_text(path, "calibration")
    try:
        data = json.loads(text)
    except json.JSONDecodeError as error:
        raise CLIError(f"calibration is not valid JSON: {error.msg}", path, error.lineno) from None
    if not isinstance(data, dict):
        raise CLIError("calibration must be a JSON object with keys " + ", ".join(CALIBRATION_KEYS), path, 1)
    missing = [k for k in CALIBRATION_KEYS if k not in data]
    if missing:
        raise CLIError("calibration is missing key" + ("s " if len(missing) > 1 else " ")
                       + ", ".join(f"'{k}'" for k in missing), path)
    wearer = data["wearer"]
    if not isinstance(wearer, str) or not wearer.strip():
        raise CLIError("calibration 'wearer' must be a non-empty string", path, _json_line(text, "wearer"))
    if data["frame"] != "camera":
        raise CLIError(f"calibration 'frame' must be \"camera\", got {data['frame']!r}", path,
                       _json_line(text, "frame"))

    def vector(key: str):
        value = data[key]
        ok = (isinstance(value, list) and len(value) == 3
              and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in value))
        if not ok:
            raise CLIError(f"calibration '{key}' must be a list of 3 numbers, got {json.dumps(value)}", path,
                           _json_line(text, key))
        array = np.asarray(value, dtype=np.float64)
        if not np.all(np.isfinite(array)):
            raise CLIError(f"calibration '{key}' is not finite", path, _json_line(text, key))
        return array

    eye_center = vector("eye_center")
    direction = vector("direction")
    norm = float(np.linalg.norm(direction))
    if norm < _MIN_DIRECTION_NORM:
        raise CLIError("calibration 'direction' has zero length", path, _json_line(text, "direction"))
    bandwidth = data["bandwidth"]
    if (not isinstance(bandwidth, (int, float)) or isinstance(bandwidth, bool) or not math.isfinite(bandwidth)
            or bandwidth <= 0):
        raise CLIError(f"calibration 'bandwidth' must be a positive number (radians), got {json.dumps(bandwidth)}",
                       path, _json_line(text, "bandwidth"))
    return {"wearer": wearer.strip(), "eye_center": eye_center, "direction": direction / norm,
            "bandwidth": float(bandwidth), "path": path}


def read_camera_poses_csv(path: str) -> dict:
    """Read raw camera poses, one row per (frame, person), columns :data:`CAMERA_POSE_COLUMNS`.

    Returns ``{frame: [(person, R_world_from_camera (3, 3), centre (3,), line), ...]}``.
    ``(qw, qx, qy, qz)`` is the unit quaternion of ``R_camera_from_world`` in our
    camera convention (+x forward, +y left, +z up), checked as by
    :func:`jaxgaze.poses.read_pose_csv` (``|‖q‖ − 1| ≤ 1e-3``); ``(cx, cy, cz)``
    is the camera centre in the world (metres). Raises :class:`CLIError`.
    """
    import numpy as np

    from jaxgaze import poses as poses_module

    text = _read_input_text(path)
    reader = csv.reader(io.StringIO(text, newline=""), strict=True)
    rows = []
    try:
        header, names, index, header_line = _read_header(reader, path, CAMERA_POSE_COLUMNS)
        seen: dict[tuple[int, str], int] = {}
        for row in reader:
            line = reader.line_num
            if not any(cell.strip() for cell in row):
                continue
            if len(row) != len(header):
                raise CLIError(f"expected {len(header)} fields as in the header, got {len(row)}", path, line)
            frame = _parse_frame(row[index["frame"]], path, line)
            person = row[index["person"]].strip()
            if not person:
                raise CLIError("empty cell in column 'person'", path, line)
            q = [_parse_float(row[index[c]], c, path, line) for c in ("qw", "qx", "qy", "qz")]
            centre = [_parse_float(row[index[c]], c, path, line) for c in ("cx", "cy", "cz")]
            try:
                poses_module.check_quaternion(q, path, line)
            except poses_module.PoseFileError as error:
                raise CLIError(_pose_error_text(error), path, line) from None
            first = seen.setdefault((frame, person), line)
            if first != line:
                raise CLIError(f"duplicate pose for frame {frame}, person '{person}' (first on line {first})",
                               path, line)
            rows.append((frame, person, q, centre, line))
    except csv.Error as error:
        raise CLIError(f"malformed CSV: {error}", path, reader.line_num) from None
    if not rows:
        raise CLIError("no data rows after the header", path, header_line)
    q = np.asarray([r[2] for r in rows], dtype=np.float64)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    R_world_from_camera = np.swapaxes(poses_module.quaternions_to_matrices(q), -1, -2)
    frames: dict[int, list] = {}
    for (frame, person, _, centre, line), R in zip(rows, R_world_from_camera):
        frames.setdefault(frame, []).append((person, R, np.asarray(centre), line))
    return frames


def _calibrated_rows(path: str, calibrations: dict) -> dict:
    """Gaze rays ``{frame: [(person, origin, direction, bandwidth, line), ...]}`` from raw camera poses.

    ``origin = R_world_from_camera @ eye_center + c`` and
    ``direction = R_world_from_camera @ direction`` with the person's calibration.
    """
    frames = {}
    for frame, poses in read_camera_poses_csv(path).items():
        rays = []
        for person, R, centre, line in poses:
            calibration = calibrations.get(person)
            if calibration is None:
                known = ", ".join(f"'{w}'" for w in sorted(calibrations))
                raise CLIError(f"no calibration for person '{person}' (calibrated wearers: {known})", path, line)
            origin = R @ calibration["eye_center"] + centre
            direction = R @ calibration["direction"]
            rays.append((person, tuple(origin.tolist()), tuple(direction.tolist()), calibration["bandwidth"], line))
        frames[frame] = rays
    return frames


def _pose_error_text(error) -> str:
    """The message of a :class:`~jaxgaze.poses.PoseFileError` without its ``path, line N: `` prefix."""
    text = str(error)
    where = error.path if error.line is None else f"{error.path}, line {error.line}"
    return text[len(where) + 2:] if text.startswith(where + ": ") else text


def _read_poses(path: str):
    """Camera poses from a COLMAP ``images.txt`` (``.txt``) or a pose CSV (``.csv``)."""
    from jaxgaze.poses import PoseFileError, read_colmap_images, read_pose_csv

    ext = os.path.splitext(path)[1].lower()
    if ext not in (".txt", ".csv"):
        raise CLIError(f"unknown pose file type '{ext}': expected a COLMAP images.txt (.txt) or a pose CSV (.csv)",
                       path)
    if not os.path.exists(path):
        raise CLIError("pose file not found", path)
    if os.path.isdir(path):
        raise CLIError("pose file is a directory, not a file", path)
    try:
        return read_colmap_images(path) if ext == ".txt" else read_pose_csv(path)
    except PoseFileError as error:
        raise CLIError(_pose_error_text(error), error.path, error.line) from None
    except OSError as error:
        raise CLIError(f"cannot read pose file: {error.strerror or error}", path) from None


# ---------------------------------------------------------------------------
# Computation


def _pad_frames(rays, size: int):
    """Pad a ``(T, N)`` recording to ``size`` frames with empty (fully masked) frames."""
    import equinox as eqx
    import jax
    import jax.numpy as jnp

    extra = size - rays.batch_shape[0]
    padded = jax.tree_util.tree_map(lambda a: jnp.concatenate([a, jnp.repeat(a[-1:], extra, axis=0)]), rays)
    mask = padded.mask.at[-extra:].set(False)
    return eqx.tree_at(lambda r: r.mask, padded, mask)


def find_concurrences_in_chunks(rays, *, chunk: int = _DEFAULT_CHUNK, progress: bool = False,
                                desc: str = "concurrences", **options):
    """:func:`~jaxgaze.find_concurrences_over_frames` over a long recording, ``chunk`` frames at a time.

    Every call sees the same ``(chunk, N)`` shape (the last or only chunk is
    padded with empty frames), so the vmapped computation compiles once per
    ``(chunk, N)`` and options, whatever the length of the recording. Returns a
    :class:`~jaxgaze.Concurrences` of host (numpy) arrays, ``(T, K)``.
    """
    import numpy as np
    from tqdm import tqdm

    from jaxgaze.concurrence import Concurrences, find_concurrences_over_frames

    total = rays.batch_shape[0]
    size = max(1, int(chunk))
    parts = []
    with tqdm(total=total, unit="frame", desc=desc, disable=not progress, file=sys.stderr) as bar:
        for start in range(0, total, size):
            part = rays[start:start + size]
            count = part.batch_shape[0]
            if count < size:
                part = _pad_frames(part, size)
            result = find_concurrences_over_frames(part, **options)
            parts.append(Concurrences(*(np.asarray(a)[:count] for a in result)))
            bar.update(count)
    return Concurrences(*(np.concatenate(fields, axis=0) for fields in zip(*parts)))


# ---------------------------------------------------------------------------
# Output


@contextlib.contextmanager
def _atomic_output(path: str, mode: str = "w", what: str = "output"):
    """Yield a temporary file next to ``path``; ``os.replace`` it onto ``path`` only on success.

    On any failure the temporary file is deleted and an existing ``path`` is
    left untouched; an ``OSError`` becomes a :class:`CLIError` (see :func:`_atomic_path`).
    """
    with _atomic_path(path, what) as tmp:
        text = {} if "b" in mode else {"newline": "", "encoding": "utf-8"}
        with open(tmp, mode, **text) as handle:
            yield handle


def _fmt(value) -> str:
    """Shortest text that round-trips the value at its own precision (float32 by default)."""
    import numpy as np

    return str(value) if isinstance(value, np.floating) else repr(float(value))


def write_concurrences_csv(handle, frame_ids, concurrences) -> int:
    """Write one row per (frame, mode) of a padded ``(T, K)`` result; returns the number of rows."""
    import numpy as np

    writer = csv.writer(handle, lineterminator="\n")
    writer.writerow(OUTPUT_COLUMNS)
    valid = np.asarray(concurrences.valid)
    locations = np.asarray(concurrences.locations)
    variances = np.diagonal(np.asarray(concurrences.covariances), axis1=-2, axis2=-1)
    num_rays = np.asarray(concurrences.num_rays)
    values = np.asarray(concurrences.field_values)
    rows = 0
    for t, frame in enumerate(frame_ids):
        for mode in np.flatnonzero(valid[t]):
            writer.writerow(
                [frame, int(mode), *map(_fmt, locations[t, mode]), *map(_fmt, variances[t, mode]),
                 int(num_rays[t, mode]), _fmt(values[t, mode])]
            )
            rows += 1
    return rows


# ---------------------------------------------------------------------------
# Commands


def _check_output_directory(path: str, what: str = "output") -> None:
    """Fail before any work if the output's directory does not exist."""
    if not os.path.isdir(os.path.dirname(os.path.abspath(path))):
        raise CLIError(f"cannot write {what}: directory does not exist", path)


def _cmd_concurrences(args) -> int:
    if args.calibration:
        calibrations = {}
        for path in args.calibration:
            calibration = read_calibration_json(path)
            first = calibrations.setdefault(calibration["wearer"], calibration)
            if first is not calibration:
                raise CLIError(f"two calibrations for wearer '{calibration['wearer']}' (the other is "
                               f"{first['path']})", path)
        frame_ids, _, rays = _rays_from_rows(_calibrated_rows(args.input, calibrations), args.input)
    else:
        frame_ids, _, rays = read_rays_csv(args.input, args.bandwidth)
    _check_output_directory(args.out)
    try:
        bounds = None if args.bounds is None else [args.bounds[:3], args.bounds[3:]]
        result = find_concurrences_in_chunks(rays, chunk=args.chunk, progress=_progress(args),
                                             min_rays=args.min_rays, bounds=bounds)
    except ValueError as error:
        raise CLIError(str(error), args.input) from None
    with _atomic_output(args.out) as handle:
        rows = write_concurrences_csv(handle, frame_ids, result)
    if not args.quiet:
        print(f"jaxgaze: {rows} concurrence(s) in {len(frame_ids)} frame(s) written to {args.out}",
              file=sys.stderr)
    return 0


@contextlib.contextmanager
def _atomic_path(path: str, what: str = "output"):
    """Yield a temporary path next to ``path`` (same permissions) and ``os.replace`` it onto
    ``path`` only on success; on failure delete it and leave ``path`` untouched."""
    target = os.path.abspath(path)
    try:
        fd, tmp = tempfile.mkstemp(dir=os.path.dirname(target), prefix=f".{os.path.basename(target)}.",
                                   suffix=".tmp")
        os.close(fd)
    except OSError as error:
        raise CLIError(f"cannot write {what}: {error.strerror or error}", path) from None
    try:
        try:
            file_mode = os.stat(target).st_mode & 0o7777
        except OSError:
            umask = os.umask(0)
            os.umask(umask)
            file_mode = 0o666 & ~umask
        os.chmod(tmp, file_mode)
        yield tmp
        os.replace(tmp, target)
    except OSError as error:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise CLIError(f"cannot write {what}: {error.strerror or error}", path) from None
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def _finite_extreme(values, pick):
    """``pick`` (min or max) of the finite values, or ``None`` when there are none (r-hat of one chain)."""
    finite = [float(v) for v in values if math.isfinite(float(v))]
    return pick(finite) if finite else None


def _cmd_calibrate(args) -> int:
    import jax
    import numpy as np

    from jaxgaze.calibration import calibrate_cone
    from jaxgaze.poses import match_frames, points_of_regard

    wearer = args.wearer if args.wearer is not None else os.path.splitext(os.path.basename(args.poses_a))[0]
    if not wearer.strip():
        raise CLIError("--wearer must not be empty")
    _check_output_directory(args.out)
    if args.posterior is not None:
        _check_output_directory(args.posterior, "posterior")
        if os.path.abspath(args.posterior) == os.path.abspath(args.out):
            raise CLIError("--posterior and --out must be different files", args.out)
    poses_a = _read_poses(args.poses_a)
    poses_b = _read_poses(args.poses_b)
    try:
        poses_a, poses_b = match_frames(poses_a, poses_b, by="frame")
    except ValueError:
        raise CLIError(f"no matching frames: POSES_A and POSES_B share no frame id "
                       f"({poses_a.num_frames} and {poses_b.num_frames} poses; other file: {args.poses_b})",
                       args.poses_a) from None
    if poses_a.num_frames < 3:
        raise CLIError(f"only {poses_a.num_frames} frame(s) in common with {args.poses_b}; calibration needs "
                       f"at least 3", args.poses_a)
    points = points_of_regard(poses_a, poses_b)
    key = jax.random.key(args.seed)
    try:
        fit = calibrate_cone(points, key=key, throw=False)
    except ValueError as error:
        raise CLIError(f"calibration failed: {error}", args.poses_a) from None
    if not bool(fit.succeeded):
        raise CLIError(f"calibration failed: {fit.message}", args.poses_a)
    eye_center = np.asarray(fit.eye_center, dtype=np.float64)
    direction = np.asarray(fit.direction, dtype=np.float64)
    direction = direction / np.linalg.norm(direction)
    record = {
        "wearer": wearer.strip(),
        "frame": "camera",
        "units": "metres (eye_center), unit vector (direction), radians (bandwidth); camera frame of the "
                 "wearer: +x forward (optical axis), +y left, +z up",
        "eye_center": [float(x) for x in eye_center],
        "direction": [float(x) for x in direction],
        "bandwidth": float(fit.bandwidth),
        "num_points": int(points.shape[0]),
        "num_inliers": int(np.sum(np.asarray(fit.inliers))),
        "method": "ransac+cone",
    }
    if args.posterior is None:
        with _atomic_output(args.out) as handle:
            handle.write(json.dumps(record, indent=2, allow_nan=False) + "\n")
    else:
        from jaxgaze.calibration_posterior import calibrate_cone_posterior

        import arviz

        # With one chain arviz logs that it cannot compute r-hat (null in the JSON): keep stderr to one line.
        arviz_log = getattr(arviz, "_log", None) or logging.getLogger("arviz")
        level = arviz_log.level
        arviz_log.setLevel(logging.ERROR)
        try:
            post = calibrate_cone_posterior(points, key=jax.random.fold_in(key, 1), num_warmup=args.samples,
                                            num_samples=args.samples, init_eye_center=eye_center,
                                            init_direction=direction)
        except ValueError as error:
            raise CLIError(f"posterior sampling failed: {error}", args.poses_a) from None
        finally:
            arviz_log.setLevel(level)
        summary = post.summary
        record["posterior"] = {
            "eye_center_mean": [float(x) for x in post.eye_center],
            "direction_mean": [float(x) for x in post.direction],
            "bandwidth_mean": float(post.bandwidth),
            "r_hat_max": _finite_extreme(np.asarray(summary["r_hat"], dtype=float), max),
            "ess_bulk_min": _finite_extreme(np.asarray(summary["ess_bulk"], dtype=float), min),
            "num_samples": int(args.samples),
            "num_warmup": int(args.samples),
            "file": os.path.basename(args.posterior),
        }
        with _atomic_path(args.posterior, "posterior") as tmp:
            try:
                post.idata.to_netcdf(tmp)
            except (ValueError, RuntimeError) as error:  # netCDF back-end errors
                raise CLIError(f"cannot write posterior: {error}", args.posterior) from None
            with _atomic_output(args.out) as handle:
                handle.write(json.dumps(record, indent=2, allow_nan=False) + "\n")
    if not args.quiet:
        angle = math.degrees(math.atan2(math.hypot(direction[1], direction[2]), direction[0]))
        print(f"jaxgaze: calibrated '{record['wearer']}' from {record['num_points']} frame(s), "
              f"{record['num_inliers']} inlier(s): eye centre ({', '.join(f'{x:.3f}' for x in eye_center)}) m, "
              f"{angle:.1f}° off the optical axis, h = {record['bandwidth']:.4f} rad; written to {args.out}"
              + (f" and {args.posterior}" if args.posterior else ""), file=sys.stderr)
    return 0


def _figure_format(path: str) -> str:
    """Image format from the figure path's extension; checked before any work is done."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    ext = os.path.splitext(path)[1].lstrip(".").lower()
    supported = FigureCanvasAgg.get_supported_filetypes()
    if ext not in supported:
        raise CLIError(f"unsupported figure format '.{ext}'; use one of " + ", ".join(f".{e}" for e in supported),
                       path)
    _check_output_directory(path, "figure")
    return ext


def _phase_frames(phase) -> list[tuple[int, int]]:
    """``[(phase, middle frame of its longest run)]`` for every phase of the story, in order."""
    import numpy as np

    phase = np.asarray(phase)
    out = []
    for p in dict.fromkeys(phase.tolist()):
        frames = np.flatnonzero(phase == p)
        out.append((int(p), int(frames[len(frames) // 2])))
    return out


def _demo_figure(scene, concurrences, tracks, frames_to_show, fmt: str, path: str) -> None:
    import numpy as np
    from matplotlib.figure import Figure

    from jaxgaze.plotting import plot_counts, plot_top_view, plot_trajectories, top_view_bounds

    truth = np.asarray(scene.concurrences)
    truth_valid = np.asarray(scene.concurrence_valid)
    lower, upper = top_view_bounds(scene.rays, truth.reshape(-1, 3), margin=0.6)
    extent = (lower[0], upper[0], lower[1], upper[1])
    top = len(frames_to_show)
    fig = Figure(figsize=(4.6 * max(top, 2), 8.6), layout="constrained")
    grid = fig.add_gridspec(2, max(top, 2) * 2)
    for i, (p, t) in enumerate(frames_to_show):
        ax = fig.add_subplot(grid[0, 2 * i:2 * i + 2])
        one = concurrences.frame(t)
        plot_top_view(
            scene.rays[t], one, truth=truth[t][truth_valid[t]], ax=ax, extent=extent,
            z_range=(lower[2], upper[2]), grid_shape=(96, 64, 24), colorbar=True,
            title=f"phase {p}: frame {t} (t = {t / scene.fps:.1f} s)\n"
                  f"K = {len(one.locations)}, true K = {int(truth_valid[t].sum())}",
        )
    half = max(top, 2)
    ax = fig.add_subplot(grid[1, :half])
    plot_trajectories(concurrences, tracks, ax=ax, fps=scene.fps)
    ax = fig.add_subplot(grid[1, half:])
    plot_counts(np.asarray(concurrences.count), np.asarray(scene.true_count), ax=ax, fps=scene.fps)
    fig.suptitle(f"jaxgaze demo: simulated '{scene.name}' scene, {scene.num_frames} frames, "
                 f"{scene.num_people} people")
    with _atomic_output(path, "wb", what="figure") as handle:
        fig.savefig(handle, format=fmt, dpi=100)


def _cmd_demo(args) -> int:
    import jax
    import numpy as np

    from jaxgaze.concurrence import track_concurrences
    from jaxgaze.metrics import evaluate, match_concurrences
    from jaxgaze.simulate import simulate_scene

    fmt = _figure_format(args.figure)
    progress = _progress(args)
    clock = time.perf_counter()
    scene = simulate_scene(jax.random.key(args.seed), "meeting", num_frames=args.frames)
    t_sim = time.perf_counter() - clock

    clock = time.perf_counter()
    # People look at things above the floor (z = 0 in the simulated world frame).
    above_floor = [[-math.inf, -math.inf, 0.0], [math.inf, math.inf, math.inf]]
    concurrences = find_concurrences_in_chunks(scene.rays, chunk=args.chunk, progress=progress, desc=scene.name,
                                               bounds=above_floor)
    tracks = track_concurrences(concurrences)
    t_find = time.perf_counter() - clock

    truth = np.asarray(scene.concurrences)
    truth_valid = np.asarray(scene.concurrence_valid)
    valid = np.asarray(concurrences.valid)
    locations = np.asarray(concurrences.locations)
    counts = valid.sum(axis=1)
    true_counts = truth_valid.sum(axis=1)

    print(f"jaxgaze demo: '{scene.name}' scene, {scene.num_frames} frames at {scene.fps:g} fps, "
          f"{scene.num_people} people, seed {args.seed}, bandwidth {scene.bandwidth:.3f} rad")
    print(f"{'frame':>5} {'time_s':>6} {'K':>2} {'true_K':>6}  {'error_cm':<16} locations_m (x, y, z)")
    for t in range(scene.num_frames):
        est = locations[t][valid[t]]
        match = match_concurrences(est, truth[t][truth_valid[t]])  # Hungarian
        err = np.full(len(est), np.nan)
        err[match.estimated] = 100.0 * match.distances
        err_text = " ".join("-" if not np.isfinite(e) else f"{e:.1f}" for e in err) or "-"
        loc_text = " ".join("({:.2f}, {:.2f}, {:.2f})".format(*x) for x in est) or "-"
        print(f"{t:>5} {t / scene.fps:>6.1f} {counts[t]:>2} {true_counts[t]:>6}  {err_text:<16} {loc_text}")

    clock = time.perf_counter()
    _demo_figure(scene, concurrences, tracks, _phase_frames(scene.phase), fmt, args.figure)
    t_fig = time.perf_counter() - clock

    summary = evaluate(concurrences, scene, level=0.9)
    correct = int(np.sum(counts == true_counts))
    trajectories = tracks.trajectories(concurrences)
    print("summary:")
    print(f"  count accuracy: {correct}/{scene.num_frames} frames ({summary.count_accuracy:.1%}) "
          "with K = true K")
    if summary.num_matched:
        print(f"  localisation error: median {100 * summary.median_error:.1f} cm, mean {100 * summary.mean_error:.1f}"
              f" ± {100 * summary.std_error:.1f} cm over {summary.num_matched} matched concurrences")
        print(f"  coverage: {summary.coverage:.1%} of true locations inside the 90% Laplace ellipsoid")
    else:
        print("  localisation error: no concurrence matched")
    births = ", ".join(str(tr["birth"]) for tr in trajectories.values())
    print(f"  tracks: {len(trajectories)} (born at frames {births or '-'})")
    print(f"  figure: {args.figure}")
    print(f"  time: simulate {t_sim:.1f} s, concurrences + tracking {t_find:.1f} s, figure {t_fig:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
