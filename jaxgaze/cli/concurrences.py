"""``jaxgaze concurrences INPUT.csv --out OUT.csv``: the gaze concurrences (Park et al. 2012) of
every frame of a recording of primary gaze rays, or of raw camera poses with ``--calibration``,
tracked over frames; optionally who supports which (``--members``) and a figure (``--figure``)."""

from __future__ import annotations

import argparse

from jaxgaze.cli._common import (CommandError, add_batch_options, add_output, int_at_least, positive_float,
                                 show_progress, summary, warn, writing)
from jaxgaze.cli._common import add_trust_units, declare_inputs, stage, unit_rule
from jaxgaze.io.concurrences import MEMBER_COLUMNS, OUTPUT_COLUMNS
from jaxgaze.io.poses import CAMERA_POSE_COLUMNS
from jaxgaze.io.rays import CSV_COLUMNS, DEFAULT_BANDWIDTH


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "concurrences",
        help="find the gaze concurrences of every frame of a CSV of primary gaze rays",
        description="Read primary gaze rays from INPUT (CSV with header columns " + ", ".join(CSV_COLUMNS)
                    + " and optionally bandwidth; world frame with +z up, metres, radians), find the gaze "
                      "concurrences of every frame with the library's defaults (no mode more than 2.5 m under the "
                      "lowest eye; two people looking at each other are mutual gaze, not a concurrence), track them "
                      "over the rows' frames and write one row per (frame, mode) to OUT: "
                    + ", ".join(OUTPUT_COLUMNS) + " (location in m; the covariance's six unique entries in m², "
                      "of a Student-t with degrees_of_freedom). Frames without a concurrence give no row. "
                      "A bandwidth of 1 rad or more is an error, and so is one over 0.5 rad or eyes of one frame "
                      "more than 100 m apart (degrees? millimetres?) unless --trust-units.",
    )
    parser.add_argument("input", metavar="INPUT.csv", help="primary gaze rays, one row per (frame, person)")
    add_output(parser, "--out", required=True, metavar="OUT.csv", help="output CSV (replaced only on success)")
    add_output(parser, "--members", what="members table", default=None, metavar="MEMBERS.csv",
               help="also write one row per (frame, person): " + ", ".join(MEMBER_COLUMNS)
                    + " (the mode and track the person's ray supports, -1 for none; the person they are "
                      "in mutual gaze with, empty for none)")
    add_output(parser, "--figure", what="figure", default=None, metavar="PATH",
               help="also draw a figure (format from the extension, e.g. .png, .pdf): top views of three "
                    "frames, the tracks and the count per frame")
    parser.add_argument("--min-rays", type=int_at_least(2), default=2, metavar="R",
                        help="fewest rays a concurrence must claim (default 2)")
    parser.add_argument("--bounds", type=float, nargs=6, default=None,
                        metavar=("XMIN", "YMIN", "ZMIN", "XMAX", "YMAX", "ZMAX"),
                        help="world box (m) where points of regard can lie; modes outside it are rejected "
                             "(use inf/-inf for open sides)")
    parser.add_argument("--no-floor", action="store_true",
                        help="keep modes more than 2.5 m under the lowest eye (e.g. a stand looking down at a field)")
    parser.add_argument("--bandwidth", type=positive_float, default=DEFAULT_BANDWIDTH, metavar="H",
                        help=f"cone bandwidth h in radians (not degrees) of every ray when INPUT has no bandwidth "
                             f"column (default {DEFAULT_BANDWIDTH}; not used with --calibration)")
    parser.add_argument("--calibration", nargs="+", default=None, metavar="CALIB.json",
                        help="calibrations written by 'jaxgaze calibrate', one per wearer; INPUT is then a CSV "
                             "of raw camera poses with columns " + ", ".join(CAMERA_POSE_COLUMNS)
                             + " (q: unit quaternion w, x, y, z of R_camera_from_world in the camera frame "
                               "+x forward, +y left, +z up; c: camera centre, world, metres), and each person's "
                               "gaze ray is p = R_world_from_camera eye_center + c, v = R_world_from_camera "
                               "direction, with the calibration's bandwidth (person = the JSON's 'wearer')")
    add_trust_units(parser)
    add_batch_options(parser)
    declare_inputs(parser, "input", "calibration")
    return parser


def _check_figure(args) -> None:
    """Before any work (run_command has checked every output's directory and that they differ):
    the figure's format is one matplotlib writes."""
    from jaxgaze.io.figures import figure_format

    if args.figure is not None:
        try:
            figure_format(args.figure)
        except ValueError as error:
            raise CommandError(str(error), args.figure) from None


def run(args) -> int:
    import warnings

    from jaxgaze.concurrence import ConcurrenceOptions, find_concurrences_over_frames, track_concurrences
    from jaxgaze.io.calibration import calibrated_rays, read_calibration_json
    from jaxgaze.io.concurrences import write_concurrences_csv, write_members_csv
    from jaxgaze.io.figures import write_figure
    from jaxgaze.plotting import plot_recording
    from jaxgaze.io.poses import read_camera_poses_csv
    from jaxgaze.io.rays import read_rays_csv
    from jaxgaze.rays import check_bandwidth

    _check_figure(args)
    if not args.calibration:
        try:
            check_bandwidth(args.bandwidth, "--bandwidth")
        except ValueError as error:
            raise CommandError(str(error)) from None
    bounds = None if args.bounds is None else [args.bounds[:3], args.bounds[3:]]
    with warnings.catch_warnings(record=True) as caught:  # printed once the input has been checked
        warnings.simplefilter("always")
        with unit_rule(args, args.input):
            if args.calibration:
                calibrations = [read_calibration_json(path) for path in args.calibration]
                recording = calibrated_rays(read_camera_poses_csv(args.input), calibrations)
            else:
                recording = read_rays_csv(args.input, args.bandwidth)
        try:
            options = ConcurrenceOptions(min_rays=args.min_rays, bounds=bounds,
                                         **({"floor_below_eyes": None} if args.no_floor else {}))
            with unit_rule(args, args.input, recording.frame_ids):
                result = find_concurrences_over_frames(recording.rays, options, frames_per_batch=args.chunk,
                                                       progress=show_progress(args))
        except ValueError as error:
            raise CommandError(str(error).replace("frames_per_batch", "--chunk"), args.input) from None
    for note in dict.fromkeys(str(w.message) for w in caught):
        warn(note)
    stage(args, "tracking the concurrences" + (f" and drawing the figure {args.figure}" if args.figure else ""))
    tracks = track_concurrences(result)
    with writing(args.out, also={args.members: "members table", args.figure: "figure"}):
        if args.figure is not None:  # first: the slowest to write and the likeliest to fail
            title = f"jaxgaze concurrences: {args.input}"
            write_figure(args.figure, plot_recording(recording.rays, result, tracks, recording.frame_ids, title=title))
        if args.members is not None:
            write_members_csv(args.members, recording, result, tracks)
        rows = write_concurrences_csv(args.out, recording.frame_ids, result, tracks, reference=recording.reference)
    pairs = len(result.mutual_gaze_pairs())
    listed = f" (in {args.members})" if args.members else " (listed with --members)"
    mutual = f"; {pairs} mutual-gaze pair(s){listed}" if pairs else ""
    summary(args, f"{rows} concurrence(s) in {len(recording.frame_ids)} frame(s) written to {args.out}{mutual}")
    return 0
