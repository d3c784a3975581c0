"""Command-line interface: ``jaxgaze demo``, ``concurrences``, ``calibrate``, ``bias``, ``attend`` and ``fit-gaze``.

``jaxgaze concurrences INPUT.csv --out OUT.csv`` finds the gaze concurrences
(Park et al. 2012) of every frame of a recording of primary gaze rays;
``jaxgaze demo`` runs the same pipeline on a simulated meeting and compares
it with the truth; ``jaxgaze calibrate POSES_A POSES_B --out calib.json``
calibrates wearer A's primary gaze ray (camera frame) from a calibration
session in which A looks at B's camera, and ``jaxgaze concurrences POSES.csv
--calibration calib.json ...`` turns raw camera poses into gaze rays with such
calibrations. ``jaxgaze bias GAZE.csv --speech SEGMENTS.rttm --out bias.json``
estimates a person's gaze bias from the frames where their conversation
partner speaks (Siegfried, Odobez et al. 2017) and writes per-frame
looking-at probabilities. ``jaxgaze attend VIDEO --model gp.json --output
attend.csv`` finds the object a person attends to in each window of a video
from their head pose (Yücel et al. 2013), with a model written by ``jaxgaze
fit-gaze --output gp.json`` (fitted on simulated table-top sessions). Errors
in the input are reported as one line on stderr, ``jaxgaze: error: <what>
(<file>:<line>)``, with exit status 2, and never leave a partial output file
behind.
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
import time
import typing
import warnings

from jaxgaze.io.text import atomic_path, header_problem

__all__ = ["main", "read_rays_csv", "read_calibration_json", "read_camera_poses_csv", "read_gaze_csv",
           "read_targets_csv", "CSV_COLUMNS", "CAMERA_POSE_COLUMNS", "OUTPUT_COLUMNS", "CALIBRATION_KEYS",
           "GAZE_COLUMNS", "TARGET_COLUMNS", "BIAS_FRAME_COLUMNS", "ATTEND_COLUMNS"]

#: Required input columns (a ``bandwidth`` column is optional).
CSV_COLUMNS = ("frame", "person", "ox", "oy", "oz", "dx", "dy", "dz")
#: Input columns of ``concurrences --calibration``: raw camera poses, one row per (frame, person);
#: ``q`` is the unit quaternion (w, x, y, z) of R_camera_from_world in our camera convention.
CAMERA_POSE_COLUMNS = ("frame", "person", "qw", "qx", "qy", "qz", "cx", "cy", "cz")
#: Keys a calibration JSON must have (written by ``jaxgaze calibrate``).
CALIBRATION_KEYS = ("wearer", "frame", "eye_center", "direction", "bandwidth")
#: Output columns, one row per (frame, mode).
OUTPUT_COLUMNS = ("frame", "mode", "x", "y", "z", "var_x", "var_y", "var_z", "num_rays", "field_value")
#: Required columns of ``bias``'s own gaze CSV (GAZE.csv when it is not an OpenFace file), one row per
#: frame: ``yaw, tilt`` the estimated gaze in the head frame (radians, uncorrected), ``q`` the unit
#: quaternion (w, x, y, z) of R_world_from_head, ``e`` the eye midpoint (world, metres). Optional:
#: ``timestamp`` (seconds) and the target (the partner's eye midpoint) :data:`TARGET_COLUMNS`.
GAZE_COLUMNS = ("frame", "yaw", "tilt", "qw", "qx", "qy", "qz", "ex", "ey", "ez")
#: Target position columns (metres), in GAZE.csv or, with ``frame``, in a ``--targets`` CSV.
TARGET_COLUMNS = ("tx", "ty", "tz")
#: The per-window table of ``attend``.
ATTEND_COLUMNS = ("window", "start_frame", "start_time", "valid", "pitch", "yaw", "roll", "direction", "depth_y",
                  "head_x", "head_y", "target_x", "target_y", "attended_x", "attended_y", "region_x_min",
                  "region_y_min", "region_x_max", "region_y_max", "probability", "reason")
#: The per-frame table of ``bias`` (JSON ``"frames"``, one list per column, and ``--per-frame`` CSV).
BIAS_FRAME_COLUMNS = ("frame", "time", "partner_speaking", "head_target_angle_deg", "selected",
                      "error_uncorrected_deg", "error_deg", "looking", "probability")

_DEFAULT_BANDWIDTH = 0.05
_DEFAULT_SAMPLES = 500
_BIAS_SILENT_FRAMES = 256  # at most this many silent-partner frames for the Bayes contrast
#: ``bias --frames`` defaults: the paper's N (Mean 20, Med 40); the mixture uses more.
_BIAS_FRAMES = {"bayes": 60, "lmeds": 40, "mean": 20}
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


_BIAS_DESCRIPTION = """\
Speaker-prior gaze bias adaptation (Siegfried, Odobez et al. 2017). A gaze
estimator's output g = (yaw, tilt) carries a person-specific bias b: the
corrected gaze is g + b. People mostly look at a partner who speaks, so the
frames of the first --window seconds where the partner speaks (SEGMENTS,
--partner) and the head is within --max-head-angle-deg of the partner are
candidates; --frames of them are drawn at random (--seed) and b is estimated
(--method) from their offsets o = angles(target direction) - g. Every frame
is then labelled "looking at the partner" when the corrected gaze is within
--threshold-deg of the direction from the eyes to the target (the partner's
eye midpoint).

GAZE.csv is one of
  * an OpenFace 2 FeatureExtraction CSV, recognised by its gaze_angle_x and
    pose_Rx columns (--face-id, --min-confidence). Its gaze and head pose are
    converted to our camera frame (+x forward along the optical axis, +y left,
    +z up; metres), and the eyes are taken at OpenFace's head position pose_T.
    --targets is required and is in that camera frame.
  * a CSV with a header row and one row per frame (columns in any order,
    case-insensitive; other columns ignored):
      frame            integer frame id
      yaw, tilt        estimated gaze in the head frame (+x forward, +y left,
                       +z up), radians: yaw positive to the left, tilt up
      qw, qx, qy, qz   unit quaternion (w, x, y, z) of R_world_from_head
                       (v_world = R_world_from_head v_head)
      ex, ey, ez       eye midpoint, world frame, metres
      tx, ty, tz       optional: the partner's eye midpoint, world, metres
      timestamp        optional: seconds
Frame times are the timestamps, else frame / --fps; SEGMENTS uses the same
clock (seconds). A --targets CSV (frame, tx, ty, tz) must cover every frame.

BIAS.json holds method, bias and bias_deg ([yaw, tilt]; radians, degrees),
covariance (radians^2) and std_deg (null when unknown), partner, fps, the
selection (num_candidates, num_selected, selected_frames, inliers; for bayes
responsibilities and posterior diagnostics), dropped (OpenFace frames dropped,
per reason) and "frames", the per-frame table with one list per column:
  frame, time (s), partner_speaking, head_target_angle_deg, selected,
  error_uncorrected_deg and error_deg (angle between the target direction and
  the gaze before / after correction), looking (error_deg < threshold) and
  probability (bayes: the share of the posterior draws of b with which the
  frame is looking; otherwise looking as 0/1).
Reader warnings (dropped frames, merged speech segments) go to stderr as
'jaxgaze: warning: ...' lines and do not fail the command.
"""


_ATTEND_DESCRIPTION = """\
The attended object per window of frames of a video (Yücel et al. 2013,
T-CYB Sec. IV-VI): the head is tracked with a cylindrical head model (the
first frame must show the face frontally, looking at the camera), the gaze
regression of --model predicts from the head pose the image angle of the gaze
(f1) and the image row of the target (f2) with their variances, each window of
--window frames pools the target points, and bottom-up saliency (--method)
around them picks the attended location, with a posterior probability.

The model's f2 is a row of the images it was trained on (metadata image_size);
for a video of another size it is scaled by the ratio of the image heights,
and so is the default focal length.

OUT.csv has one row per window (a trailing incomplete window is dropped):
  window, start_frame   window index and its first frame (from 0)
  start_time            start_frame / fps, seconds (empty when no fps is known)
  valid                 1 where a location was attended, else 0 (see reason)
  pitch, yaw, roll      pooled head pose, radians, relative to the first frame's
                        eye-contact head frame (yaw > 0 to the person's left,
                        pitch > 0 up, roll > 0 left ear up)
  direction             pooled f1, radians (atan2(dy, dx) in the image: +pi/2 down)
  depth_y               pooled f2, image row, px
  head_x, head_y        pooled head centre in the image, px
  target_x, target_y    pooled regression target point, px
  attended_x, attended_y  the attended location, px
  region_x_min, region_y_min, region_x_max, region_y_max
                        the salient region there, px
  probability           the attended location's posterior probability
  reason                why a window is not valid: "tracker lost" or "no location
                        stands out" (empty when valid)
Image coordinates: x right, y down, origin at the top-left pixel's outer corner.
Missing values are empty cells.
"""


def build_parser() -> argparse.ArgumentParser:
    from jaxgaze import __version__

    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("-q", "--quiet", action="store_true",
                        help="no progress bar (it is also off when stderr is not a terminal)")
    common.add_argument("--chunk", type=_int_at_least(1), default=None, metavar="F",
                        help="frames per compiled batch; shorter recordings are padded to F (default: the "
                             "largest that keeps XLA:CPU clear of its LAPACK deadlock, at most 64)")

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

    bias = sub.add_parser(
        "bias",
        help="estimate a person's gaze bias from the frames where their partner speaks, and label the frames "
             "where they look at the partner",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=_BIAS_DESCRIPTION,
    )
    bias.add_argument("gaze", metavar="GAZE.csv",
                      help="per-frame gaze and head pose of the person: an OpenFace 2 FeatureExtraction CSV or "
                           "the CSV described above")
    bias.add_argument("--speech", required=True, metavar="SEGMENTS",
                      help="who speaks when: RTTM (.rttm) or CSV (.csv: start, end, speaker; seconds); another "
                           "extension is read as RTTM if it has SPEAKER lines, else as CSV")
    bias.add_argument("--out", required=True, metavar="BIAS.json", help="output JSON (replaced only on success)")
    bias.add_argument("--targets", default=None, metavar="X,Y,Z|TARGETS.csv",
                      help="the partner's eye midpoint (metres; camera frame for OpenFace input, else world "
                           "frame): a constant point X,Y,Z (write --targets=-1,0,0 when it starts with '-') or a "
                           "CSV with columns frame, tx, ty, tz covering every frame of GAZE.csv; replaces "
                           "GAZE.csv's tx, ty, tz columns")
    bias.add_argument("--partner", default=None, metavar="SPEAKER",
                      help="speaker id of the partner in SEGMENTS (required unless SEGMENTS has one speaker)")
    bias.add_argument("--speech-file-id", default=None, metavar="ID",
                      help="recording (file id, 2nd field) to use from an RTTM that holds several")
    bias.add_argument("--method", choices=("bayes", "lmeds", "mean"), default="bayes",
                      help="bias estimator: bayes (mixture posterior, NUTS; looking probabilities from its "
                           "draws), lmeds (the paper's Spk-Med, eq. 2) or mean (Spk-Mean) (default bayes)")
    bias.add_argument("--frames", type=_int_at_least(1), default=None, metavar="N",
                      help="frames drawn at random from the candidates (default: "
                           + ", ".join(f"{n} for {m}" for m, n in _BIAS_FRAMES.items()) + ")")
    bias.add_argument("--window", type=_positive_float, default=60.0, metavar="SECONDS",
                      help="candidates come from the first SECONDS of GAZE.csv (default 60)")
    bias.add_argument("--max-head-angle-deg", type=_positive_float, default=30.0, metavar="DEG",
                      help="candidates have the head direction within DEG degrees of the target (default 30)")
    bias.add_argument("--threshold-deg", type=_positive_float, default=10.0, metavar="DEG",
                      help="looking at the partner: corrected gaze within DEG degrees of the target (default 10)")
    bias.add_argument("--fps", type=_positive_float, default=None, metavar="FPS",
                      help="frame rate; required when GAZE.csv has no timestamp column (frame f is then at "
                           "f / FPS seconds); with timestamps it defaults to their rate and must agree with it")
    bias.add_argument("--samples", type=_int_at_least(1), default=_DEFAULT_SAMPLES, metavar="N",
                      help=f"NUTS warm-up steps and draws for --method bayes (default {_DEFAULT_SAMPLES})")
    bias.add_argument("--seed", type=int, default=0, metavar="S",
                      help="random seed of the frame draw and of NUTS (default 0)")
    bias.add_argument("--face-id", type=int, default=None, metavar="ID",
                      help="OpenFace input: the face_id to use when the file has several faces")
    bias.add_argument("--min-confidence", type=float, default=0.75, metavar="C",
                      help="OpenFace input: drop frames with confidence < C (default 0.75)")
    bias.add_argument("--per-frame", default=None, metavar="PER_FRAME.csv",
                      help="also write the per-frame table as CSV (columns " + ", ".join(BIAS_FRAME_COLUMNS)
                           + "; booleans as 0/1)")
    bias.add_argument("-q", "--quiet", action="store_true",
                      help="no progress bar and no summary line on stderr (warnings and errors still go there)")
    bias.set_defaults(func=_cmd_bias)

    attend = sub.add_parser(
        "attend",
        help="the object a person attends to in a video, per window of frames, from their head pose (Yücel et al. "
             "2013)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=_ATTEND_DESCRIPTION,
    )
    attend.add_argument("video", metavar="VIDEO",
                        help="a video file OpenCV can read, or a folder of frames (.png, .jpg, ...; natural order)")
    attend.add_argument("--model", required=True, metavar="GP.json",
                        help="gaze regression written by 'jaxgaze fit-gaze' or jaxgaze.io.models.save_gaze_regression")
    attend.add_argument("--output", "--out", dest="out", default="attend.csv", metavar="OUT.csv",
                        help="output CSV, one row per window (default attend.csv; replaced only on success)")
    attend.add_argument("--method", choices=("itti", "spectral_residual"), default="itti",
                        help="bottom-up saliency: itti (Itti-Koch-Niebur) or spectral_residual (Hou & Zhang) "
                             "(default itti)")
    attend.add_argument("--window", type=_int_at_least(1), default=None, metavar="N",
                        help="frames pooled per window (default: the model's 'window', else 4; T-CYB: 4 at 10 fps)")
    attend.add_argument("--focal-px", type=_positive_float, default=None, metavar="F",
                        help="focal length of the video's camera in pixels (default: the model's 'focal_px', scaled "
                             "to the video's image size)")
    attend.add_argument("--fps", type=_positive_float, default=None, metavar="FPS",
                        help="frame rate for the start_time column (default: the video's, else the model's)")
    attend.add_argument("--initial-box", type=float, nargs=4, default=None, metavar=("X", "Y", "W", "H"),
                        help="the face box in the first frame, pixels (x right, y down from the top-left corner); "
                             "default: detected")
    attend.add_argument("--max-frames", type=_int_at_least(1), default=None, metavar="N",
                        help="read at most N frames")
    attend.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                        help="show progress bars (default: when stderr is a terminal)")
    attend.add_argument("-q", "--quiet", action="store_true",
                        help="no progress bar and no summary line on stderr")
    attend.set_defaults(func=_cmd_attend)

    fit_gaze = sub.add_parser(
        "fit-gaze",
        help="fit the gaze regression (f1 direction, f2 depth from head pose) on simulated table-top sessions",
        description="Simulate table-top sessions (jaxgaze.simulate.tabletop: PEOPLE experimenters, SESSIONS "
                    "sessions each, one table and camera), fit the gaze regression of Yücel et al. 2013 on their "
                    "head poses (pitch, yaw, roll, radians, relative to the eye-contact head frame) and write it "
                    "to OUTPUT for 'jaxgaze attend', with metadata focal_px, fps, window and image_size. "
                    "--demo-video also renders a session of one more experimenter (not in the training data) as "
                    "a video to try 'jaxgaze attend' on.",
    )
    fit_gaze.add_argument("--output", "--out", dest="out", required=True, metavar="GP.json",
                          help="model file (replaced only on success)")
    fit_gaze.add_argument("--seed", type=int, default=0, metavar="S", help="random seed (default 0)")
    fit_gaze.add_argument("--method", choices=("gp", "nn"), default="gp",
                          help="gp: the paper's two Gaussian processes; nn: the CogSci neural-network baseline "
                               "(default gp)")
    fit_gaze.add_argument("--people", type=_int_at_least(1), default=4, metavar="N",
                          help="simulated experimenters (default 4)")
    fit_gaze.add_argument("--sessions", type=_int_at_least(1), default=2, metavar="N",
                          help="sessions per experimenter (default 2)")
    fit_gaze.add_argument("--duration", type=_positive_float, default=30.0, metavar="SECONDS",
                          help="length of a session (default 30)")
    fit_gaze.add_argument("--fps", type=_positive_float, default=10.0, metavar="FPS",
                          help="frame rate of the sessions (default 10, as T-CYB)")
    fit_gaze.add_argument("--window", type=_int_at_least(1), default=4, metavar="N",
                          help="pooling window stored in the model for 'attend' (default 4)")
    fit_gaze.add_argument("--max-frames", type=_int_at_least(2), default=600, metavar="N",
                          help="thin the training frames evenly to at most N (default 600; a GP costs O(N^3))")
    fit_gaze.add_argument("--demo-video", default=None, metavar="VIDEO",
                          help="also render a held-out session as a video (.mp4, .avi or .mkv): 640 x 480 (the "
                               "simulator's camera at twice its 320 x 240), 10 lead-in frames of eye contact first")
    fit_gaze.add_argument("--demo-frames", type=_int_at_least(1), default=100, metavar="N",
                          help="session frames in --demo-video after the lead-in, at most a session's (default 100)")
    fit_gaze.add_argument("-q", "--quiet", action="store_true",
                          help="no progress bar and no summary line on stderr (the bar is also off when stderr is "
                               "not a terminal)")
    fit_gaze.set_defaults(func=_cmd_fit_gaze)
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
    problem = header_problem(names, columns, hint="need " + ", ".join(columns))
    if problem:
        raise CLIError(problem, path, header_line)
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
    from jaxgaze.concurrence.modes import find_concurrences_over_frames

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
        result = find_concurrences_over_frames(rays, frames_per_batch=args.chunk, progress=_progress(args),
                                               min_rays=args.min_rays, bounds=bounds)
    except ValueError as error:
        raise CLIError(str(error).replace("frames_per_batch", "--chunk"), args.input) from None
    with _atomic_output(args.out) as handle:
        rows = write_concurrences_csv(handle, frame_ids, result)
    if not args.quiet:
        print(f"jaxgaze: {rows} concurrence(s) in {len(frame_ids)} frame(s) written to {args.out}",
              file=sys.stderr)
    return 0


@contextlib.contextmanager
def _atomic_path(path: str, what: str = "output"):
    """:func:`jaxgaze.io.text.atomic_path`, with an ``OSError`` as a one-line :class:`CLIError`."""
    try:
        with atomic_path(path) as tmp:
            yield tmp
    except OSError as error:
        raise CLIError(f"cannot write {what}: {error.strerror or error}", path) from None


def _finite_extreme(values, pick):
    """``pick`` (min or max) of the finite values, or ``None`` when there are none (r-hat of one chain)."""
    finite = [float(v) for v in values if math.isfinite(float(v))]
    return pick(finite) if finite else None


def _cmd_calibrate(args) -> int:
    import jax
    import numpy as np

    from jaxgaze.calibration.cone_fit import calibrate_cone
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
        from jaxgaze.calibration.posterior import calibrate_cone_posterior

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

    from jaxgaze.concurrence.modes import find_concurrences_over_frames, track_concurrences
    from jaxgaze.concurrence.metrics import evaluate, match_concurrences
    from jaxgaze.simulate.scenes import simulate_scene

    fmt = _figure_format(args.figure)
    progress = _progress(args)
    clock = time.perf_counter()
    scene = simulate_scene(jax.random.key(args.seed), "meeting", num_frames=args.frames)
    t_sim = time.perf_counter() - clock

    clock = time.perf_counter()
    # People look at things above the floor (z = 0 in the simulated world frame).
    above_floor = [[-math.inf, -math.inf, 0.0], [math.inf, math.inf, math.inf]]
    try:
        concurrences = find_concurrences_over_frames(scene.rays, frames_per_batch=args.chunk, progress=progress,
                                                     bounds=above_floor)
    except ValueError as error:
        raise CLIError(str(error).replace("frames_per_batch", "--chunk")) from None
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


# ---------------------------------------------------------------------------
# bias (Siegfried, Odobez et al. 2017)


class _GazeInput(typing.NamedTuple):
    """GAZE.csv of ``jaxgaze bias``, sorted by frame, in one frame of reference ("world" or "camera")."""

    format: str  # "openface" or "csv"
    frame: object  # (T,) int64
    time: object  # (T,) float64 seconds, or None
    gaze: object  # (T, 2) yaw, tilt in the head frame, radians
    R_world_from_head: object  # (T, 3, 3) (R_camera_from_head for OpenFace)
    eye: object  # (T, 3) metres
    target: object  # (T, 3) metres, or None
    lines: object  # (T,) line of each frame in the file, or None (OpenFace)
    dropped: dict
    reference: str  # "world" or "camera"


def _error_from_file_error(error) -> CLIError:
    """A reader's ``path, line N: what`` ValueError (PoseFileError, OpenFaceFileError, ...) as a CLIError."""
    return CLIError(_pose_error_text(error), error.path, error.line)


def _note_warnings(caught, notes: list) -> None:
    notes.extend(" ".join(str(w.message).split()) for w in caught)


def _is_openface_header(text: str) -> bool:
    """Whether the first non-blank line names OpenFace's ``gaze_angle_x`` or ``pose_Rx`` column (with
    only one of them, :func:`jaxgaze.io.openface.read_openface` reports the other as missing)."""
    for line in text.splitlines():
        if line.strip():
            names = {cell.strip().lower() for cell in line.split(",")}
            return bool({"gaze_angle_x", "pose_rx"} & names)
    return False


def read_gaze_csv(path: str) -> _GazeInput:
    """Read ``bias``'s own per-frame gaze CSV (columns :data:`GAZE_COLUMNS`, optional ``timestamp`` and
    :data:`TARGET_COLUMNS`), sorted by frame.

    ``yaw`` must lie in [−π, π] and ``tilt`` in [−π/2, π/2] (radians: degrees are caught here), the
    quaternion must be unit as for the pose readers, and timestamps must increase with the frame.
    Raises :class:`CLIError` naming the file and line.
    """
    import numpy as np

    from jaxgaze import poses as poses_module

    text = _read_input_text(path, "gaze")
    reader = csv.reader(io.StringIO(text, newline=""), strict=True)
    rows = []
    try:
        header, names, index, header_line = _read_header(reader, path, GAZE_COLUMNS)
        present = [c for c in TARGET_COLUMNS if c in names]
        if present and len(present) < len(TARGET_COLUMNS):
            missing = [c for c in TARGET_COLUMNS if c not in names]
            raise CLIError("missing column" + ("s " if len(missing) > 1 else " ")
                           + ", ".join(f"'{c}'" for c in missing) + " in the header (the target columns "
                           + ", ".join(TARGET_COLUMNS) + " go together)", path, header_line)
        target_index = [names.index(c) for c in present]
        time_index = names.index("timestamp") if "timestamp" in names else None
        seen: dict[int, int] = {}
        for row in reader:
            line = reader.line_num
            if not any(cell.strip() for cell in row):
                continue
            if len(row) != len(header):
                raise CLIError(f"expected {len(header)} fields as in the header, got {len(row)}", path, line)
            frame = _parse_frame(row[index["frame"]], path, line)
            yaw = _parse_float(row[index["yaw"]], "yaw", path, line)
            tilt = _parse_float(row[index["tilt"]], "tilt", path, line)
            if abs(yaw) > math.pi + 1e-9:
                raise CLIError(f"column 'yaw' must be an angle in radians within [-pi, pi], got "
                               f"{row[index['yaw']].strip()} (degrees?)", path, line)
            if abs(tilt) > math.pi / 2 + 1e-9:
                raise CLIError(f"column 'tilt' must be an angle in radians within [-pi/2, pi/2], got "
                               f"{row[index['tilt']].strip()} (degrees?)", path, line)
            q = [_parse_float(row[index[c]], c, path, line) for c in ("qw", "qx", "qy", "qz")]
            try:
                poses_module.check_quaternion(q, path, line)
            except poses_module.PoseFileError as error:
                raise _error_from_file_error(error) from None
            eye = [_parse_float(row[index[c]], c, path, line) for c in ("ex", "ey", "ez")]
            target = [_parse_float(row[k], c, path, line) for k, c in zip(target_index, present)]
            time_s = None if time_index is None else _parse_float(row[time_index], "timestamp", path, line)
            first = seen.setdefault(frame, line)
            if first != line:
                raise CLIError(f"duplicate frame {frame} (first on line {first})", path, line)
            rows.append((frame, time_s, (yaw, tilt), q, eye, target, line))
    except csv.Error as error:
        raise CLIError(f"malformed CSV: {error}", path, reader.line_num) from None
    if not rows:
        raise CLIError("no data rows after the header", path, header_line)
    rows.sort(key=lambda r: r[0])
    lines = np.array([r[6] for r in rows], dtype=np.int64)
    time = None
    if time_index is not None:
        time = np.array([r[1] for r in rows], dtype=np.float64)
        bad = np.flatnonzero(np.diff(time) <= 0)
        if bad.size:
            i = int(bad[0])
            raise CLIError(f"timestamps must increase with the frame: frame {rows[i + 1][0]} at {time[i + 1]:g} s "
                           f"is not after frame {rows[i][0]} at {time[i]:g} s", path, int(lines[i + 1]))
    q = np.array([r[3] for r in rows], dtype=np.float64)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return _GazeInput(
        format="csv",
        frame=np.array([r[0] for r in rows], dtype=np.int64),
        time=time,
        gaze=np.array([r[2] for r in rows], dtype=np.float64),
        R_world_from_head=poses_module.quaternions_to_matrices(q),
        eye=np.array([r[4] for r in rows], dtype=np.float64),
        target=np.array([r[5] for r in rows], dtype=np.float64) if present else None,
        lines=lines,
        dropped={},
        reference="world",
    )


def _read_openface_gaze(path: str, face_id, min_confidence: float, notes: list) -> _GazeInput:
    import warnings

    import numpy as np

    from jaxgaze.io.openface import OpenFaceFileError, read_openface

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            track = read_openface(path, min_confidence=min_confidence, face_id=face_id)
        except OpenFaceFileError as error:
            raise _error_from_file_error(error) from None
        gaze = np.asarray(track.gaze_angles_head, dtype=np.float64)
    _note_warnings(caught, notes)
    time = np.asarray(track.timestamp, dtype=np.float64)
    bad = np.flatnonzero(np.diff(time) <= 0)
    if bad.size:
        i = int(bad[0])
        raise CLIError(f"timestamps must increase with the frame: frame {track.frame[i + 1]} at {time[i + 1]:g} s "
                       f"is not after frame {track.frame[i]} at {time[i]:g} s", path)
    return _GazeInput(format="openface", frame=np.asarray(track.frame, dtype=np.int64), time=time, gaze=gaze,
                      R_world_from_head=np.asarray(track.R_camera_from_head, dtype=np.float64),
                      eye=np.asarray(track.head_position_camera, dtype=np.float64), target=None, lines=None,
                      dropped=dict(track.dropped), reference="camera")


def _read_bias_gaze(args, notes: list) -> _GazeInput:
    """GAZE.csv as OpenFace (by its header) or our gaze CSV."""
    text = _read_input_text(args.gaze, "gaze")
    if _is_openface_header(text):
        if not math.isfinite(args.min_confidence):
            raise CLIError(f"--min-confidence must be finite, got {args.min_confidence}")
        return _read_openface_gaze(args.gaze, args.face_id, args.min_confidence, notes)
    if args.face_id is not None:
        raise CLIError("--face-id is only for OpenFace input (no gaze_angle_x and pose_Rx columns here)", args.gaze)
    return read_gaze_csv(args.gaze)


def read_targets_csv(path: str) -> dict:
    """Read a ``bias --targets`` CSV: columns ``frame, tx, ty, tz`` (metres). Returns ``{frame: (3,)}``."""
    import numpy as np

    columns = ("frame",) + TARGET_COLUMNS
    text = _read_input_text(path, "targets")
    reader = csv.reader(io.StringIO(text, newline=""), strict=True)
    targets: dict[int, object] = {}
    lines: dict[int, int] = {}
    try:
        header, _, index, header_line = _read_header(reader, path, columns)
        for row in reader:
            line = reader.line_num
            if not any(cell.strip() for cell in row):
                continue
            if len(row) != len(header):
                raise CLIError(f"expected {len(header)} fields as in the header, got {len(row)}", path, line)
            frame = _parse_frame(row[index["frame"]], path, line)
            point = np.array([_parse_float(row[index[c]], c, path, line) for c in TARGET_COLUMNS])
            first = lines.setdefault(frame, line)
            if first != line:
                raise CLIError(f"duplicate frame {frame} (first on line {first})", path, line)
            targets[frame] = point
    except csv.Error as error:
        raise CLIError(f"malformed CSV: {error}", path, reader.line_num) from None
    if not targets:
        raise CLIError("no data rows after the header", path, header_line)
    return targets


def _constant_point(text: str):
    """``"x,y,z"`` → ``(3,)`` array, or ``None`` when ``text`` is not three numbers (then it is a path)."""
    import numpy as np

    parts = text.split(",")
    if len(parts) != 3:
        return None
    try:
        point = np.array([float(p) for p in parts])
    except ValueError:
        return None
    if not np.all(np.isfinite(point)):
        raise CLIError(f"--targets point must be finite, got {text!r}")
    return point


def _bias_targets(args, gaze: _GazeInput):
    """``((T, 3) target positions, description)`` from --targets or GAZE.csv's tx, ty, tz columns."""
    import numpy as np

    if args.targets is None:
        if gaze.target is not None:
            return gaze.target, "GAZE.csv columns tx, ty, tz"
        if gaze.format == "openface":
            raise CLIError("an OpenFace file has no target positions: pass --targets X,Y,Z or a CSV of frame, tx, "
                           "ty, tz (the partner's eye midpoint, camera frame +x forward, +y left, +z up, metres)",
                           args.gaze)
        raise CLIError("no target positions: GAZE.csv has no tx, ty, tz columns; pass --targets X,Y,Z or a CSV of "
                       "frame, tx, ty, tz (the partner's eye midpoint, world frame, metres)", args.gaze)
    point = _constant_point(args.targets)
    if point is not None:
        return np.broadcast_to(point, gaze.eye.shape).copy(), "constant " + ",".join(repr(float(x)) for x in point)
    table = read_targets_csv(args.targets)
    missing = [int(f) for f in gaze.frame if int(f) not in table]
    if missing:
        raise CLIError(f"frames of GAZE.csv and the targets do not match: no target for frame {missing[0]} "
                       f"({len(missing)} of {len(gaze.frame)} frames of {args.gaze} missing)", args.targets)
    return np.stack([table[int(f)] for f in gaze.frame]), args.targets


def _bias_times(args, gaze: _GazeInput):
    """``((T,) frame times in seconds, fps)``: the timestamps, else frame / --fps."""
    import numpy as np

    if gaze.time is None:
        if args.fps is None:
            raise CLIError("GAZE.csv has no timestamp column: pass --fps to time frame f at f / FPS seconds",
                           args.gaze)
        return gaze.frame / args.fps, args.fps
    estimate = None
    if len(gaze.frame) >= 2:
        estimate = round(float(1.0 / np.median(np.diff(gaze.time) / np.diff(gaze.frame))), 6)
    if args.fps is not None and estimate is not None and abs(args.fps - estimate) > 0.01 * estimate:
        raise CLIError(f"--fps {args.fps:g} disagrees with the timestamps of GAZE.csv ({estimate:.3f} frames per "
                       "second); leave --fps out to use the timestamps", args.gaze)
    return gaze.time, (args.fps if args.fps is not None else estimate)


def _rttm_file_ids(text: str) -> list:
    ids = []
    for line in text.splitlines():
        fields = line.split()
        if len(fields) >= 2 and fields[0] == "SPEAKER" and fields[1] not in ids:
            ids.append(fields[1])
    return ids


def _read_speech(args, notes: list):
    """Speech segments from an RTTM or a CSV (by extension, else by content)."""
    import warnings

    from jaxgaze.io.openface import SpeechFileError, read_rttm, read_segments_csv

    path = args.speech
    text = _read_input_text(path, "speech")
    ext = os.path.splitext(path)[1].lower()
    rttm = ext == ".rttm" or (ext != ".csv" and bool(_rttm_file_ids(text)))
    if args.speech_file_id is not None and not rttm:
        raise CLIError("--speech-file-id is only for RTTM speech files", path)
    if rttm and args.speech_file_id is None:
        ids = _rttm_file_ids(text)
        if len(ids) > 1:
            raise CLIError("the RTTM holds several recordings (file ids " + ", ".join(ids) + "); choose one with "
                           "--speech-file-id", path)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            segments = read_rttm(path, file_id=args.speech_file_id) if rttm else read_segments_csv(path)
        except SpeechFileError as error:
            raise _error_from_file_error(error) from None
    _note_warnings(caught, notes)
    return segments


def _bias_partner(args, segments) -> str:
    speakers = segments.speakers
    listed = ", ".join(f"'{s}'" for s in speakers)
    if args.partner is None:
        if len(speakers) == 1:
            return speakers[0]
        raise CLIError(f"several speakers ({listed}): name the partner (the person looked at) with --partner",
                       args.speech)
    if args.partner not in speakers:
        raise CLIError(f"unknown partner speaker '{args.partner}' (speakers in the file: {listed})", args.speech)
    return args.partner


def _where_frame(gaze: _GazeInput, i: int, path: str):
    return (path, None if gaze.lines is None else int(gaze.lines[i]))


def _round_list(values, digits: int = 4) -> list:
    return [round(float(v), digits) for v in values]


def _cmd_bias(args) -> int:
    import jax
    import jax.numpy as jnp
    import numpy as np

    from jaxgaze.bias.estimators import estimate_bias
    from jaxgaze.io.openface import speaking_at
    from jaxgaze.bias.looking import (
        angular_error,
        candidate_frames,
        gaze_offsets,
        head_target_angle,
        is_looking_at,
        looking_probability,
        select_frames,
        target_direction_head,
    )

    method = args.method
    requested = args.frames if args.frames is not None else _BIAS_FRAMES[method]
    if method == "lmeds" and requested < 3:
        raise CLIError(f"--method lmeds needs --frames 3 or more, got {requested}: with fewer it cannot tell the "
                       "frames that look at the partner from the others")
    _check_output_directory(args.out)
    if args.per_frame is not None:
        _check_output_directory(args.per_frame, "per-frame table")
        if os.path.abspath(args.per_frame) == os.path.abspath(args.out):
            raise CLIError("--per-frame and --out must be different files", args.out)
    notes: list[str] = []  # reader warnings, printed once every input has been checked

    gaze = _read_bias_gaze(args, notes)
    target, target_source = _bias_targets(args, gaze)
    times, fps = _bias_times(args, gaze)
    segments = _read_speech(args, notes)
    partner = _bias_partner(args, segments)

    distance = np.linalg.norm(target - gaze.eye, axis=1)
    close = np.flatnonzero(distance < 1e-3)
    if close.size:
        i = int(close[0])
        raise CLIError(f"the target is at the eyes (closer than 1 mm) in frame {gaze.frame[i]}: is --targets in the "
                       f"{gaze.reference} frame, in metres?", *_where_frame(gaze, i, args.gaze))

    u = np.asarray(target_direction_head(jnp.asarray(gaze.eye), jnp.asarray(target),
                                         jnp.asarray(gaze.R_world_from_head)))
    head_angle = np.asarray(head_target_angle(jnp.asarray(u)))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        speaking = speaking_at(segments, [partner], times)[0]
    notes.extend(str(w.message) for w in caught)
    in_window = (times - times[0]) < args.window
    # The window is applied here on the frame times (frames may be missing); select_frames sees it as open.
    open_window = dict(fps=fps or 1.0, max_head_angle_deg=args.max_head_angle_deg, window_s=math.inf)
    candidates = np.asarray(candidate_frames(jnp.asarray(speaking & in_window), jnp.asarray(head_angle),
                                             **open_window))
    if not candidates.any():
        n_window = int(in_window.sum())
        n_speaking = int((speaking & in_window).sum())
        raise CLIError(f"no selectable frames: in the first {args.window:g} s of GAZE.csv ({n_window} frames, "
                       f"{times[0]:g}-{times[in_window][-1]:g} s) partner '{partner}' speaks in {n_speaking}, and in "
                       f"none of those is the head within {args.max_head_angle_deg:g} degrees of the target "
                       f"(speech from {float(np.min(segments.start)):g} to {float(np.max(segments.end)):g} s)",
                       args.gaze)
    num_candidates = int(candidates.sum())
    if method == "lmeds" and num_candidates < 3:
        raise CLIError(f"lmeds needs at least 3 selectable frames, found {num_candidates}: use --method mean or "
                       "bayes, or a longer --window", args.gaze)
    if num_candidates < requested:
        notes.append(f"only {num_candidates} selectable frame(s) for --frames {requested}: using all of them")
    for note in notes:
        print(f"jaxgaze: warning: {note}", file=sys.stderr)

    key_select, key_fit = jax.random.split(jax.random.key(args.seed))
    try:
        selection = select_frames(key_select, speaking & in_window, head_angle, num_frames=requested, **open_window)
    except ValueError as error:
        raise CLIError(str(error), args.gaze) from None
    chosen = np.asarray(selection.indices)
    offsets = np.asarray(gaze_offsets(jnp.asarray(gaze.gaze[chosen]), jnp.asarray(u[chosen])))

    extra = {}
    if method == "bayes":  # the contrast: same window and head filter while the partner is silent
        silent = np.flatnonzero(np.asarray(candidate_frames(jnp.asarray(~speaking & in_window),
                                                            jnp.asarray(head_angle), **open_window)))
        silent = silent[:: max(1, -(-len(silent) // _BIAS_SILENT_FRAMES))]
        if len(silent):
            extra["silent_offsets"] = np.asarray(gaze_offsets(jnp.asarray(gaze.gaze[silent]), jnp.asarray(u[silent])))
    try:
        estimate = estimate_bias(offsets, method, key=key_fit, num_warmup=args.samples, num_samples=args.samples,
                                 progress_bar=_progress(args) and method == "bayes", **extra)
    except ValueError as error:
        raise CLIError(str(error), args.gaze) from None
    bias = np.asarray(estimate.bias, dtype=np.float64)
    covariance = None if estimate.covariance is None else np.asarray(estimate.covariance, dtype=np.float64)
    inliers = np.asarray(estimate.inliers, dtype=bool)
    posterior = None
    draws = None
    if method == "bayes":
        draws = np.asarray(estimate.samples["bias"], dtype=np.float64)
        if not np.all(np.isfinite(draws)):
            raise CLIError("posterior sampling failed: non-finite draws of the bias", args.gaze)
        posterior = {
            "num_warmup": int(args.samples),
            "num_samples": int(args.samples),
            "num_divergent": int(estimate.posterior.sample_stats["diverging"].sum()),
            "looking_share_mean": float(np.mean(estimate.samples["looking_share"])),
            "responsibilities": _round_list(estimate.responsibilities),
        }

    g, uu, b = jnp.asarray(gaze.gaze), jnp.asarray(u), jnp.asarray(bias)
    error_raw = np.degrees(np.asarray(angular_error(g, uu), dtype=np.float64))
    error = np.degrees(np.asarray(angular_error(g, uu, b), dtype=np.float64))
    looking = np.asarray(is_looking_at(g, uu, b, threshold_deg=args.threshold_deg), dtype=bool)
    if draws is not None:
        probability = np.asarray(looking_probability(g, uu, jnp.asarray(draws), threshold_deg=args.threshold_deg),
                                 dtype=np.float64)
    else:
        probability = looking.astype(np.float64)
    selected = np.zeros(len(gaze.frame), dtype=bool)
    selected[chosen] = True

    table = {
        "frame": [int(f) for f in gaze.frame],
        "time": [float(t) for t in times],
        "partner_speaking": [bool(x) for x in speaking],
        "head_target_angle_deg": _round_list(np.degrees(head_angle)),
        "selected": [bool(x) for x in selected],
        "error_uncorrected_deg": _round_list(error_raw),
        "error_deg": _round_list(error),
        "looking": [bool(x) for x in looking],
        "probability": _round_list(probability, 6),
    }
    record = {
        "method": method,
        "units": "bias [yaw, tilt] in the head frame (+x forward, +y left, +z up): radians (bias, covariance in "
                 "radians^2) and degrees (_deg); corrected gaze = gaze + bias; time in seconds",
        "bias": [float(x) for x in bias],
        "bias_deg": [float(math.degrees(x)) for x in bias],
        "covariance": None if covariance is None else [[float(x) for x in r] for r in covariance],
        "std_deg": None if covariance is None else [float(math.degrees(math.sqrt(max(v, 0.0))))
                                                   for v in np.diag(covariance)],
        "input": {"gaze": args.gaze, "format": gaze.format, "frame_of_reference": gaze.reference,
                  "speech": args.speech, "targets": target_source},
        "partner": partner,
        "fps": fps,
        "seed": args.seed,
        "window_s": args.window,
        "max_head_angle_deg": args.max_head_angle_deg,
        "threshold_deg": args.threshold_deg,
        "num_frames": int(len(gaze.frame)),
        "num_candidates": int(selection.num_candidates),
        "num_requested": int(requested),
        "num_selected": int(selection.num_selected),
        "selected_frames": [int(gaze.frame[i]) for i in chosen],
        "selected_offsets_deg": [_round_list(np.degrees(o)) for o in offsets],
        "inliers": [bool(x) for x in inliers],
        "posterior": posterior,
        "dropped": gaze.dropped,
        "num_looking": int(looking.sum()),
        "mean_probability": float(probability.mean()),
        "frames": table,
    }
    text = json.dumps(record, indent=1, allow_nan=False) + "\n"
    if args.per_frame is None:
        with _atomic_output(args.out) as handle:
            handle.write(text)
    else:
        with _atomic_output(args.per_frame, what="per-frame table") as frames_handle:
            writer = csv.writer(frames_handle, lineterminator="\n")
            writer.writerow(BIAS_FRAME_COLUMNS)
            for row in zip(*(table[c] for c in BIAS_FRAME_COLUMNS)):
                writer.writerow([int(x) if isinstance(x, bool) else x for x in row])
            with _atomic_output(args.out) as handle:
                handle.write(text)
    if not args.quiet:
        spread = "" if covariance is None else " ± ({:.2f}°, {:.2f}°)".format(*record["std_deg"])
        print(f"jaxgaze: bias (yaw, tilt) = ({record['bias_deg'][0]:+.2f}°, {record['bias_deg'][1]:+.2f}°){spread} "
              f"({method}, {selection.num_selected} of {selection.num_candidates} candidate frames); looking at "
              f"'{partner}' in {int(looking.sum())} of {len(gaze.frame)} frames; written to {args.out}"
              + (f" and {args.per_frame}" if args.per_frame else ""), file=sys.stderr)
    return 0


# ---------------------------------------------------------------------------
# attend and fit-gaze (Yücel et al. 2013)


class _VideoRegression:
    """A loaded gaze regression as :func:`~jaxgaze.vision.attend.attend_frames` uses it.

    ``predict`` runs in float64 (the model's Cholesky factor is rebuilt in float64 when it
    is loaded, so a float64 fit stays positive definite; the tracker runs in float32, so
    the command does not switch x64 on globally) and scales the depth row ``f2`` (and its
    variance) from the model's training images to the video's by ``depth_scale``.
    """

    def __init__(self, regression, depth_scale: float):
        self.regression = regression
        self.depth_scale = float(depth_scale)

    @property
    def features(self):
        features = getattr(self.regression, "features", None)
        if features is not None:
            return features
        import numpy as np

        from jaxgaze.headpose.regression import Scaling

        width = self.regression.direction_net.params.W1.shape[0]  # the NN baseline
        return Scaling(np.zeros(width), np.ones(width))

    def predict(self, features):
        import jax
        import numpy as np

        from jaxgaze.headpose.regression import GazePrediction

        with jax.enable_x64(True):
            pred = self.regression.predict(np.asarray(features, np.float64))
            d, y = np.asarray(pred.direction, np.float64), np.asarray(pred.depth, np.float64)
            vd = None if pred.direction_variance is None else np.asarray(pred.direction_variance, np.float64)
            vy = None if pred.depth_variance is None else np.asarray(pred.depth_variance, np.float64)
        k = self.depth_scale
        return GazePrediction(d, y * k, vd, None if vy is None else vy * k * k)


def _metadata_number(metadata: dict, key: str, path: str, integer: bool = False):
    """``metadata[key]`` checked as a positive number (or integer), or ``None`` when absent."""
    if metadata.get(key) is None:
        return None
    value = metadata[key]
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and value > 0
    if integer:
        ok = ok and float(value).is_integer()
    if not ok:
        kind = "positive integer" if integer else "positive number"
        raise CLIError(f"model metadata '{key}' must be a {kind}, got {json.dumps(value)}", path)
    return int(value) if integer else float(value)


def _metadata_image_size(metadata: dict, path: str):
    value = metadata.get("image_size")
    if value is None:
        return None
    if not (isinstance(value, list) and len(value) == 2
            and all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in value)):
        raise CLIError(f"model metadata 'image_size' must be [width, height] in pixels, got {json.dumps(value)}", path)
    return int(value[0]), int(value[1])


def _load_model(path: str):
    """``(regression, metadata)`` from a model file, loaded in float64; errors as :class:`CLIError`."""
    import jax

    from jaxgaze.io.models import ModelFileError, load_gaze_regression

    try:
        with jax.enable_x64(True):
            return load_gaze_regression(path, with_metadata=True)
    except ModelFileError as error:
        raise _error_from_file_error(error) from None


def _cell(value, digits: int = 6) -> str:
    """A CSV cell: empty for NaN, else the number rounded to ``digits`` decimals (shortest form)."""
    value = float(value)
    return "" if not math.isfinite(value) else repr(round(value, digits))


def write_attend_csv(handle, windows, fps) -> int:
    """Write :data:`ATTEND_COLUMNS`, one row per window of an ``AttentionWindows``; returns the rows."""
    writer = csv.writer(handle, lineterminator="\n")
    writer.writerow(ATTEND_COLUMNS)
    for i in range(len(windows.start_frame)):
        start = int(windows.start_frame[i])
        writer.writerow([
            i, start, "" if fps is None else _cell(start / fps),
            int(bool(windows.valid[i])),
            *(_cell(v) for v in windows.pose[i]),
            _cell(windows.direction[i]), _cell(windows.depth_y[i], 3),
            *(_cell(v, 3) for v in windows.head_xy[i]),
            *(_cell(v, 3) for v in windows.target_xy[i]),
            *(_cell(v, 3) for v in windows.attended_xy[i]),
            *(_cell(v, 3) for v in windows.region_box[i]),
            _cell(windows.probability[i]),
            windows.reason[i],
        ])
    return len(windows.start_frame)


class _VideoFrames:
    """The frames of VIDEO, read lazily each time it is iterated; ``len`` when the count is known."""

    def __init__(self, path: str, max_frames, count):
        self.path, self.max_frames, self.count = path, max_frames, count

    def __iter__(self):
        from jaxgaze.io.video import iter_frames

        return iter_frames(self.path, max_frames=self.max_frames)


class _CountedVideoFrames(_VideoFrames):
    def __len__(self) -> int:
        return self.count


def _cmd_attend(args) -> int:
    from jaxgaze.vision.attend import attend_frames
    from jaxgaze.io.video import VideoFileError, frame_count, iter_frames, video_fps

    progress = (not args.quiet and args.progress) if args.progress is not None else _progress(args)
    _check_output_directory(args.out)
    try:
        first = next(iter(iter_frames(args.video, max_frames=1)))
        count = frame_count(args.video)
        fps_video = video_fps(args.video)
    except VideoFileError as error:
        raise _error_from_file_error(error) from None
    height, width = first.shape[:2]
    regression, metadata = _load_model(args.model)

    size = _metadata_image_size(metadata, args.model)
    scale = 1.0 if size is None else height / size[1]
    notes = []
    if size is not None and abs(width / size[0] - scale) > 0.01 * scale:
        notes.append(f"the video is {width}x{height} px but the model was trained on {size[0]}x{size[1]} px images "
                     f"(another aspect ratio): its depth rows are scaled by the heights, x {scale:.4g}")
    if args.focal_px is not None:
        focal = args.focal_px
    else:
        model_focal = _metadata_number(metadata, "focal_px", args.model)
        if model_focal is None:
            raise CLIError("no focal length: pass --focal-px (the model file has no metadata 'focal_px')", args.model)
        focal = model_focal * scale
    window = args.window or _metadata_number(metadata, "window", args.model, integer=True) or 4
    fps = args.fps or fps_video or _metadata_number(metadata, "fps", args.model)
    if args.max_frames is not None and count is not None:
        count = min(count, args.max_frames)
    frames = (_CountedVideoFrames if count else _VideoFrames)(args.video, args.max_frames, count)
    if count is not None and count < window:
        raise CLIError(f"the video has {count} frame(s), fewer than one window of {window}", args.video)
    for note in notes:
        print(f"jaxgaze: warning: {note}", file=sys.stderr)

    try:
        windows = attend_frames(frames, _VideoRegression(regression, scale), focal_px=focal, window=window,
                                method=args.method, initial_box=args.initial_box, progress=progress)
    except VideoFileError as error:
        raise _error_from_file_error(error) from None
    except ValueError as error:
        raise CLIError(str(error), args.video) from None

    with _atomic_output(args.out) as handle:
        rows = write_attend_csv(handle, windows, fps)
    if not args.quiet:
        import numpy as np

        valid = np.asarray(windows.valid, bool)
        num_frames = rows * window
        timing = f", {num_frames / fps:.1f} s at {fps:g} fps" if fps else ""
        mean_p = f"; mean probability {float(np.mean(windows.probability[valid])):.2f}" if valid.any() else ""
        scaled = (f"; model image rows and focal length scaled x {scale:g} to the {width}x{height} px video"
                  if scale != 1.0 else "")
        print(f"jaxgaze: {int(valid.sum())} of {rows} window(s) of {window} frames attended ({num_frames} "
              f"frames{timing}, focal length {focal:.1f} px, {args.method} saliency){mean_p}{scaled}; written to "
              f"{args.out}", file=sys.stderr)
    return 0


def _cmd_fit_gaze(args) -> int:
    import jax

    from jaxgaze.papers.yucel2013 import training_data
    from jaxgaze.io.models import save_gaze_regression
    from jaxgaze.headpose.regression import fit_gaze_regression, fit_gaze_regression_nn
    from jaxgaze.simulate.tabletop import IMAGE_HEIGHT, IMAGE_WIDTH, simulate_tabletop_sessions

    _check_output_directory(args.out, "model")
    if args.demo_video is not None:
        from jaxgaze.io.video import VIDEO_CODECS

        demo_ext = os.path.splitext(args.demo_video)[1].lower()
        if demo_ext not in VIDEO_CODECS:
            raise CLIError(f"--demo-video must end in {', '.join(VIDEO_CODECS)}, got {demo_ext or 'no extension'!r}",
                           args.demo_video)
        _check_output_directory(args.demo_video, "demo video")
        if os.path.abspath(args.demo_video) == os.path.abspath(args.out):
            raise CLIError("--demo-video and --output must be different files", args.out)
    if round(args.duration * args.fps) < 2:
        raise CLIError(f"--duration {args.duration:g} s at --fps {args.fps:g} gives fewer than 2 frames per session")
    clock = time.perf_counter()
    key_sim, key_fit, key_render = jax.random.split(jax.random.key(args.seed), 3)
    demo_people = 1 if args.demo_video is not None else 0  # one more experimenter, held out
    try:
        sessions = simulate_tabletop_sessions(key_sim, num_people=args.people + demo_people,
                                              sessions_per_person=args.sessions, duration_s=args.duration,
                                              fps=args.fps)
    except ValueError as error:
        raise CLIError(str(error)) from None
    num_train = args.people * args.sessions
    X, f1, f2 = training_data(sessions, range(num_train), args.max_frames)
    if args.method == "gp":
        model = fit_gaze_regression(X, f1, f2, key=key_fit, progress=_progress(args))
    else:
        model = fit_gaze_regression_nn(X, f1, f2, key=key_fit)
    converged = bool(model.converged) if args.method == "gp" else True
    metadata = {
        "focal_px": float(sessions[0].focal_px),
        "image_size": [IMAGE_WIDTH, IMAGE_HEIGHT],
        "fps": float(args.fps),
        "window": int(args.window),
        "features": ["pitch", "yaw", "roll"],
        "units": "features: head pose (pitch, yaw, roll) in radians relative to the eye-contact (frontal) head "
                 "frame; direction f1: image angle atan2(dy, dx) in radians; depth f2: image row in pixels of "
                 "image_size images with focal length focal_px",
        "source": "jaxgaze fit-gaze: simulated table-top sessions (jaxgaze.simulate.tabletop)",
        "method": args.method,
        "seed": int(args.seed),
        "people": int(args.people),
        "sessions_per_person": int(args.sessions),
        "duration_s": float(args.duration),
        "num_training_frames": int(len(X)),
        "converged": converged,
    }
    with _atomic_path(args.out, "model") as tmp:
        save_gaze_regression(tmp, model, metadata=metadata)
        if args.demo_video is not None:
            from jaxgaze.io.video import render_tabletop_video, write_video

            demo = sessions[num_train]
            frames, _ = render_tabletop_video(demo, key=key_render, num_frames=args.demo_frames)
            try:
                write_video(args.demo_video, frames, demo.fps)  # atomic itself
            except (OSError, ValueError) as error:
                raise CLIError(f"cannot write demo video: {error}", args.demo_video) from None
    if not args.quiet:
        demo_text = ""
        if args.demo_video is not None:
            demo_text = (f"; demo video {args.demo_video}: {len(frames)} frames at {demo.fps:g} fps, "
                         f"{frames[0].shape[1]}x{frames[0].shape[0]} px (10 lead-in frames of eye contact), focal "
                         f"length {2 * demo.focal_px:.1f} px")
        state = "" if converged else " (the fit did not converge: see the model's GP results)"
        print(f"jaxgaze: {args.method} gaze regression fitted on {len(X)} frames of {num_train} simulated session(s)"
              f"{state} in {time.perf_counter() - clock:.1f} s; written to {args.out}{demo_text}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
