"""``jaxgaze convert --from TOOL IN... --out rays.csv``: another gaze tool's output as our world-frame
rays CSV, with each ray's bandwidth from the tool's own uncertainty (``jaxgaze.io.tools``)."""

from __future__ import annotations

import argparse
import re

import numpy as np

from jaxgaze.cli._common import CommandError, add_output, add_quiet, positive_float, summary, warn, writing
from jaxgaze.cli._common import add_trust_units, declare_inputs, unit_rule
from jaxgaze.io.tools import GAZE_TOOLS
from jaxgaze.io.rays import CSV_COLUMNS


def add_parser(subparsers) -> argparse.ArgumentParser:
    tools = "; ".join(f"{name}: {tool.reads}" for name, tool in GAZE_TOOLS.items())
    parser = subparsers.add_parser(
        "convert",
        help="turn another gaze tool's output into a rays CSV (world frame, with bandwidths)",
        description="Read the output of a gaze tool and write our rays CSV (columns " + ", ".join(CSV_COLUMNS)
                    + ", bandwidth; world frame, metres, radians), ready for 'jaxgaze concurrences'. "
                      "Camera-based tools give rays in our camera frame (+x the optical axis, +y left, +z up) "
                      "unless --camera-poses places the camera in a world. Tools: " + tools + ". "
                      "docs/conventions.md ('Other gaze tools') gives each tool's frame, units and angle order.",
    )
    parser.add_argument("--from", dest="tool", required=True, choices=sorted(GAZE_TOOLS), metavar="TOOL",
                        help="the tool that wrote the inputs: " + ", ".join(GAZE_TOOLS))
    parser.add_argument("inputs", nargs="+", metavar="IN",
                        help="the tool's output files (aria: wearer folders as downloaded, or their gaze CSVs; "
                             "pupil: CSV exports or native Neon recording folders)")
    add_output(parser, "--out", required=True, metavar="OUT.csv", help="output rays CSV (replaced only on success)")
    parser.add_argument("--camera-poses", nargs="+", default=None, metavar="POSES",
                        help="the camera's poses in the world: a COLMAP images.txt or a pose CSV (frame, qw, qx, "
                             "qy, qz, cx, cy, cz); one pose serves every frame. Several pupil exports: one POSES "
                             "per IN, in order, each placing that wearer's scene camera")
    parser.add_argument("--fps", type=positive_float, default=None, metavar="F",
                        help="frame rate of the time grid of the timed tools (aria, pupil, Neon): default the "
                             "files' own rate, each sample its own frame; a rate puts wearers on one clock; samples "
                             "dropped are counted on stderr")
    parser.add_argument("--people", default=None, metavar="A,B,...",
                        help="pupil and aria: one person name per IN, in order, as for 'jaxgaze joint' (default: "
                             "each file's name, or its recording folder's: ann for ann/exports/000/gaze_positions.csv)")
    aria = parser.add_argument_group("aria")
    aria.add_argument("--frame", choices=("world", "cpf"), default=None,
                      help="world (default: the trajectory's world, z up) or cpf: each wearer's head frame")
    aria.add_argument("--up", choices=("z", "y", "x", "-z", "-y", "-x"), default=None, metavar="AXIS",
                      help="the trajectory world's up axis, turned onto +z (default: from its gravity columns, "
                           "else z; the Aria Digital Twin's is y)")
    aria.add_argument("--eye-gaze", choices=("general", "personalized"), default=None,
                      help="which eye gaze CSV of a folder holding both")
    aria.add_argument("--device-calibration", nargs="+", default=None, metavar="FILE",
                      help="the device calibration's T_device_cpf (default the identity, with a warning): the "
                           "recording's .vrs (pip install 'jaxgaze[aria]'), a JSON 4x4 matrix (a list of 4 rows, or "
                           "{\"T_device_cpf\": rows}) or text of 4 rows of 4 numbers; one for all IN, or one per IN")
    tool = parser.add_argument_group("other tool options (refused for a tool that does not take them)")
    tool.add_argument("--fov", type=positive_float, default=None, metavar="DEG",
                      help="mediapipe: the camera's vertical field of view in degrees (default 63, MediaPipe's)")
    tool.add_argument("--order", choices=("pitch,yaw", "yaw,pitch"), default=None,
                      help="l2cs: the dump's angle fields, horizontal first (default pitch,yaw: L2CS-Net's own)")
    tool.add_argument("--min-confidence", type=float, default=None, metavar="C",
                      help="pupil (Core): drop gaze below this confidence (default 0.6); openface: faces below this "
                           "tracking confidence (default 0.75); the drops are counted")
    tool.add_argument("--bandwidth", type=positive_float, default=None, metavar="H",
                      help="any tool: every ray's cone width h in radians (default the tool's documented one, or "
                           "its per-ray uncertainty: gaze360's var, aria's intervals, openface's)")
    add_trust_units(parser)
    add_quiet(parser)
    declare_inputs(parser, "inputs", "camera_poses", "device_calibration")
    return parser


#: Each tool option's destination → the reader's keyword (``GAZE_TOOLS[tool].options``).
_TOOL_OPTIONS = {"frame": "frame", "up": "up", "eye_gaze": "eye_gaze", "device_calibration": "T_device_cpf",
                 "fov": "vertical_fov_deg", "order": "order", "min_confidence": "min_confidence",
                 "bandwidth": "bandwidth"}


def _tool_options(args) -> dict:
    """The tool options given, as the reader's keywords (files not read yet); one the tool does not take is
    a :class:`CommandError` naming the tools that do."""
    options = {}
    for dest, keyword in _TOOL_OPTIONS.items():
        value = getattr(args, dest)
        if value is None:
            continue
        if keyword != "bandwidth" and keyword not in GAZE_TOOLS[args.tool].options:
            takers = [name for name, entry in GAZE_TOOLS.items() if keyword in entry.options]
            raise CommandError(f"--{dest.replace('_', '-')} is an option of {' and '.join(takers)}, not of "
                               f"{args.tool}")
        options[keyword] = tuple(value.split(",")) if dest == "order" else value
    return options


def _option_names(message: str) -> str:
    """The library's argument names as the command's options."""
    message = message.replace("pass persons=[...], one name per file", "pass --people A,B,..., one name per IN")
    message = re.sub(r"pass camera= with one CameraPoses per wearer \([^)]*\)",
                     "pass --camera-poses with one POSES file per IN", message)
    message = re.sub(r"one CameraPoses for (\d+) wearers' files: pass one per wearer",
                     r"one POSES for \1 wearers' files: pass --camera-poses with one POSES file per IN", message)
    message = re.sub(r"\bcamera= has (\d+) CameraPoses", r"--camera-poses has \1 POSES", message)
    message = re.sub(r"\bno camera=", "no --camera-poses", message)
    message = message.replace("or the path of the one to read", "or the path of the one to read as IN")
    message = re.sub(r"pass camera= with", "pass --camera-poses with", message)
    message = re.sub(r"frame='(\w+)'", r"--frame \1", message)
    message = re.sub(r"\bup='(-?\w)'", r"--up \1", message)
    message = message.replace("eye_gaze='general' or 'personalized'", "--eye-gaze general or personalized")
    message = re.sub(r"T_device_cpf has (\d+) transforms for (\d+) wearers",
                     r"--device-calibration has \1 FILEs for \2 IN", message)
    message = re.sub(r"\bmin_confidence=? ?", "--min-confidence ", message)
    message = re.sub(r"\bvertical_fov_deg\b", "--fov", message)
    return re.sub(r"\bpersons=?", "--people", message)


def run(args) -> int:
    import warnings

    from jaxgaze.io.tools import read_gaze_tool
    from jaxgaze.io.tools.aria import read_device_calibration
    from jaxgaze.io.tools.common import MissingExtraError, check_camera_distances
    from jaxgaze.io.poses import read_poses
    from jaxgaze.io.rays import write_rays_csv
    from jaxgaze.io.text import InputFileError
    from jaxgaze.rays import check_units

    options = _tool_options(args)
    camera = None
    if args.camera_poses is not None:
        if len(args.camera_poses) > 1 and not GAZE_TOOLS[args.tool].camera_per_file:
            raise CommandError(f"--camera-poses: one POSES for {args.tool} (several only for pupil exports, one "
                               f"per IN), got {len(args.camera_poses)}")
        camera = [read_poses(path).poses for path in args.camera_poses]
        camera = camera[0] if len(camera) == 1 else camera
    with warnings.catch_warnings(record=True) as caught:  # printed once the input has been read
        warnings.simplefilter("always")
        warnings.simplefilter("ignore", ResourceWarning)  # files another library left open say nothing of the data
        try:
            if "T_device_cpf" in options:
                calibrations = [read_device_calibration(path) for path in options["T_device_cpf"]]
                options["T_device_cpf"] = calibrations[0] if len(calibrations) == 1 else calibrations
            people = None if args.people is None else [name.strip() for name in args.people.split(",")]
            recording = read_gaze_tool(args.tool, args.inputs, camera=camera, fps=args.fps, persons=people, **options)
        except MissingExtraError as error:
            raise CommandError(str(error)) from None
        except ValueError as error:
            if hasattr(error, "path"):
                if _option_names(error.what) == error.what:
                    raise
                raise InputFileError(_option_names(error.what), error.path, error.line) from None
            raise CommandError(_option_names(str(error)), args.inputs[0]) from None
        # Units at the door of 'concurrences', checked here too; in the camera's frame also each eye's distance
        # from the camera, which catches millimetres with one face per frame.
        with unit_rule(args, args.inputs[0], recording.frame_ids):
            check_units(recording.rays)
            if camera is None and GAZE_TOOLS[args.tool].camera_frame:
                check_camera_distances(recording)
    for note in dict.fromkeys(str(w.message) for w in caught):
        warn(note)
    with writing(args.out):
        rows = write_rays_csv(args.out, recording)
    kept = recording.sampling
    kept = "" if kept is None else f" (kept {kept.kept} of {kept.read} samples at {kept.fps:.6g} fps)"
    up = "" if recording.up in (None, "z") else f", the input's {recording.up} axis turned up to +z"
    if args.bandwidth is None and not GAZE_TOOLS[args.tool].own_width:  # said, not silent (docs/conventions.md)
        widths = sorted({f"{h:.4f}" for h in np.asarray(recording.rays.bandwidth)[np.asarray(recording.rays.mask)]})
        summary(args, f"bandwidth: {args.tool} reports no uncertainty; every ray has its documented default "
                      f"{', '.join(widths)} rad (--bandwidth sets another)")
    summary(args, f"{rows} ray(s) of {len(recording.frame_ids)} frame(s) from {args.tool}{kept}{up} written to "
                  f"{args.out}")
    return 0
