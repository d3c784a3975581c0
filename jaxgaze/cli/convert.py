"""``jaxgaze convert --from TOOL IN... --out rays.csv``: another gaze tool's output as our world-frame
rays CSV, with each ray's bandwidth from the tool's own uncertainty (``jaxgaze.io.convert``)."""

from __future__ import annotations

import argparse

from jaxgaze.cli._common import CommandError, add_output, add_quiet, positive_float, summary, warn, writing
from jaxgaze.io.convert import GAZE_TOOLS
from jaxgaze.io.rays import CSV_COLUMNS


def add_parser(subparsers) -> argparse.ArgumentParser:
    tools = "; ".join(f"{name}: {what}" for name, what in GAZE_TOOLS.items())
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
    parser.add_argument("inputs", nargs="+", metavar="IN", help="the tool's output files (Aria: MPS folders)")
    add_output(parser, "--out", required=True, metavar="OUT.csv", help="output rays CSV (replaced only on success)")
    parser.add_argument("--camera-poses", default=None, metavar="POSES",
                        help="the camera's poses in the world: a COLMAP images.txt or a pose CSV (frame, qw, qx, "
                             "qy, qz, cx, cy, cz); one pose serves every frame")
    parser.add_argument("--fps", type=positive_float, default=None, metavar="F",
                        help="frame rate of the time grid for tools with timestamps only (aria: 10, pupil/Neon: 30)")
    add_quiet(parser)
    return parser


def run(args) -> int:
    import warnings

    from jaxgaze.io.convert import read_gaze_tool
    from jaxgaze.io.gaze_tools import MissingExtraError
    from jaxgaze.io.poses import read_poses
    from jaxgaze.io.rays import write_rays_csv

    camera = None if args.camera_poses is None else read_poses(args.camera_poses).poses
    with warnings.catch_warnings(record=True) as caught:  # printed once the input has been read
        warnings.simplefilter("always")
        try:
            recording = read_gaze_tool(args.tool, args.inputs, camera=camera, fps=args.fps)
        except MissingExtraError as error:
            raise CommandError(str(error)) from None
        except ValueError as error:
            if hasattr(error, "path"):
                raise
            raise CommandError(str(error), args.inputs[0]) from None
    for note in dict.fromkeys(str(w.message) for w in caught):
        warn(note)
    with writing(args.out):
        rows = write_rays_csv(args.out, recording)
    summary(args, f"{rows} ray(s) of {len(recording.frame_ids)} frame(s) from {args.tool} written to {args.out}")
    return 0
