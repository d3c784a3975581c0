"""``jaxgaze concurrences INPUT.csv --out OUT.csv``: the gaze concurrences (Park et al. 2012) of
every frame of a recording of primary gaze rays, or of raw camera poses with ``--calibration``."""

from __future__ import annotations

import argparse

from jaxgaze.cli._common import (CommandError, add_batch_options, check_output, int_at_least, positive_float,
                                 show_progress, summary, writing)
from jaxgaze.io.concurrences import OUTPUT_COLUMNS
from jaxgaze.io.poses import CAMERA_POSE_COLUMNS
from jaxgaze.io.rays import CSV_COLUMNS, DEFAULT_BANDWIDTH


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "concurrences",
        help="find the gaze concurrences of every frame of a CSV of primary gaze rays",
        description="Read primary gaze rays from INPUT (CSV with header columns " + ", ".join(CSV_COLUMNS)
                    + " and optionally bandwidth; world frame, metres, radians) and write one row per (frame, mode) "
                      "to OUT: " + ", ".join(OUTPUT_COLUMNS) + ". Frames without a concurrence give no row.",
    )
    parser.add_argument("input", metavar="INPUT.csv", help="primary gaze rays, one row per (frame, person)")
    parser.add_argument("--out", required=True, metavar="OUT.csv", help="output CSV (replaced only on success)")
    parser.add_argument("--min-rays", type=int_at_least(2), default=2, metavar="R",
                        help="fewest rays a concurrence must claim (default 2)")
    parser.add_argument("--bounds", type=float, nargs=6, default=None,
                        metavar=("XMIN", "YMIN", "ZMIN", "XMAX", "YMAX", "ZMAX"),
                        help="world box (m) where points of regard can lie; modes outside it are rejected "
                             "(use inf/-inf for open sides)")
    parser.add_argument("--bandwidth", type=positive_float, default=DEFAULT_BANDWIDTH, metavar="H",
                        help=f"cone bandwidth h (rad) of every ray when INPUT has no bandwidth column "
                             f"(default {DEFAULT_BANDWIDTH}; not used with --calibration)")
    parser.add_argument("--calibration", nargs="+", default=None, metavar="CALIB.json",
                        help="calibrations written by 'jaxgaze calibrate', one per wearer; INPUT is then a CSV "
                             "of raw camera poses with columns " + ", ".join(CAMERA_POSE_COLUMNS)
                             + " (q: unit quaternion w, x, y, z of R_camera_from_world in the camera frame "
                               "+x forward, +y left, +z up; c: camera centre, world, metres), and each person's "
                               "gaze ray is p = R_world_from_camera eye_center + c, v = R_world_from_camera "
                               "direction, with the calibration's bandwidth (person = the JSON's 'wearer')")
    add_batch_options(parser)
    return parser


def run(args) -> int:
    from jaxgaze.concurrence.modes import ConcurrenceOptions, find_concurrences_over_frames
    from jaxgaze.io.calibration import calibrated_rays, read_calibration_json
    from jaxgaze.io.concurrences import write_concurrences_csv
    from jaxgaze.io.poses import read_camera_poses_csv
    from jaxgaze.io.rays import read_rays_csv

    if args.calibration:
        calibrations = [read_calibration_json(path) for path in args.calibration]
        recording = calibrated_rays(read_camera_poses_csv(args.input), calibrations)
    else:
        recording = read_rays_csv(args.input, args.bandwidth)
    check_output(args.out)
    bounds = None if args.bounds is None else [args.bounds[:3], args.bounds[3:]]
    try:
        options = ConcurrenceOptions(min_rays=args.min_rays, bounds=bounds)
        result = find_concurrences_over_frames(recording.rays, options, frames_per_batch=args.chunk,
                                               progress=show_progress(args))
    except ValueError as error:
        raise CommandError(str(error).replace("frames_per_batch", "--chunk"), args.input) from None
    with writing(args.out):
        rows = write_concurrences_csv(args.out, recording.frame_ids, result)
    summary(args, f"{rows} concurrence(s) in {len(recording.frame_ids)} frame(s) written to {args.out}")
    return 0
