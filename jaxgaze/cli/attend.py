"""``jaxgaze attend VIDEO --model gp.json --out attend.csv``: the object a person attends to in each
window of a video, from their head pose (Yücel et al. 2013, T-CYB Sec. IV-VI)."""

from __future__ import annotations

import argparse
import os
import re
import warnings

from jaxgaze.cli._common import add_output, add_quiet
from jaxgaze.cli._common import CommandError, check_output, int_at_least, positive_float, show_progress, summary, warn
from jaxgaze.cli._common import declare_inputs, writing
from jaxgaze.io.attend import ATTEND_COLUMNS
from jaxgaze.io.text import InputFileError

_DESCRIPTION = """\
The attended object per window of frames of a video (Yücel et al. 2013,
T-CYB Sec. IV-VI): the head is tracked with a cylindrical head model (the
first frame must show the face frontally, looking at the camera), the gaze
regression of --model predicts from the head pose the image angle of the gaze
(f1) and the image row of the target (f2) with their variances, each window of
--window frames pools the target points, and bottom-up saliency (--method)
around them picks the attended location, with a posterior probability.

The model's f2 is a row of the images it was trained on (metadata image_size);
for a video of another size jaxgaze.vision.attend_frames scales it by the
ratio of the image heights, and the default focal length is scaled alike.

--overlay draws each window on its frames: the attended point (red disc), the
salient region (green box), the head centre (blue disc) and the regression's
target (yellow cross on the gaze line from the head centre).

OUT.csv has one row per window (a trailing incomplete window is dropped), columns
  """ + ", ".join(ATTEND_COLUMNS) + """:
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


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "attend", formatter_class=argparse.RawDescriptionHelpFormatter, description=_DESCRIPTION,
        help="the object a person attends to in a video, per window of frames, from their head pose (Yücel et al. "
             "2013)",
    )
    parser.add_argument("video", metavar="VIDEO",
                        help="a video file OpenCV can read, or a folder of frames (.png, .jpg, ...; natural order)")
    parser.add_argument("--model", required=True, metavar="GP.json",
                        help="gaze regression written by 'jaxgaze fit-gaze' or jaxgaze.io.models.save_gaze_regression")
    add_output(parser, "--out", default="attend.csv", metavar="OUT.csv",
                        help="output CSV, one row per window (default attend.csv; replaced only on success)")
    parser.add_argument("--method", choices=("itti", "spectral_residual"), default="itti",
                        help="bottom-up saliency: itti (Itti-Koch-Niebur) or spectral_residual (Hou & Zhang) "
                             "(default itti)")
    parser.add_argument("--window", type=int_at_least(1), default=None, metavar="N",
                        help="frames pooled per window (default: the model's 'window', else 4; T-CYB: 4 at 10 fps)")
    parser.add_argument("--focal-px", type=positive_float, default=None, metavar="F",
                        help="focal length of the video's camera in pixels (default: the model's 'focal_px', scaled "
                             "to the video's image size)")
    parser.add_argument("--fps", type=positive_float, default=None, metavar="FPS",
                        help="frame rate for the start_time column (default: the video's, else the model's)")
    parser.add_argument("--initial-box", type=float, nargs=4, default=None, metavar=("X", "Y", "W", "H"),
                        help="the face box in the first frame, pixels (x right, y down from the top-left corner); "
                             "default: detected")
    parser.add_argument("--max-frames", type=int_at_least(1), default=None, metavar="N", help="read at most N frames")
    parser.add_argument("--overlay", default=None, metavar="PATH",
                        help="also write the frames with each window drawn: a video (.mp4, .avi, .mkv; at the frame "
                             "rate, default 10 fps) or, for a path without extension, a new or empty folder of PNG "
                             "images (replaced only on success)")
    parser.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                        help="show progress bars (default: when stderr is a terminal)")
    add_quiet(parser)
    declare_inputs(parser, "video", "model", outputs={"overlay": "--overlay"})
    return parser


def _option_names(message: str) -> str:
    """The library's argument names as the command's options."""
    return re.sub(r"\binitial_box\b", "--initial-box", message.replace("frames[0]", "the first frame"))


def run(args) -> int:
    import jax
    import numpy as np

    from jaxgaze.headpose.regression import training_image_scale
    from jaxgaze.io.attend import write_attend_csv
    from jaxgaze.io.models import load_gaze_regression, metadata_number
    from jaxgaze.io.text import atomic_path
    from jaxgaze.io.video import VideoFrames, check_frames_output, frame_count, iter_frames, video_fps, write_frames
    from jaxgaze.vision.attend import attend_frames, attention_overlay

    progress = (not args.quiet and args.progress) if args.progress is not None else show_progress(args)
    check_output(args.out)
    if args.overlay is not None:
        if os.path.abspath(args.overlay) == os.path.abspath(args.out):
            raise CommandError("--overlay and --out must be different files", args.out)
        try:
            check_frames_output(args.overlay)
        except ValueError as error:  # the message names the path
            raise CommandError(f"--overlay: {error}") from None
    height, width = next(iter(iter_frames(args.video, max_frames=1))).shape[:2]
    count, fps_video = frame_count(args.video), video_fps(args.video)
    with jax.enable_x64(True):  # a float32 fit is rebuilt in float64 (its Cholesky factor stays positive definite)
        regression, metadata = load_gaze_regression(args.model, with_metadata=True)
    focal = args.focal_px
    if focal is None:
        model_focal = metadata_number(metadata, "focal_px", args.model)
        if model_focal is None:
            raise CommandError("no focal length: pass --focal-px (the model file has no metadata 'focal_px')",
                               args.model)
        focal = model_focal * training_image_scale(regression, (width, height))
    window = args.window or metadata_number(metadata, "window", args.model, integer=True) or 4
    fps = args.fps or fps_video or metadata_number(metadata, "fps", args.model)
    if args.max_frames is not None and count is not None:
        count = min(count, args.max_frames)
    if count is not None and count < window:
        raise CommandError(f"the video has {count} frame(s), fewer than one window of {window}", args.video)

    frames = VideoFrames(args.video, max_frames=args.max_frames, count=count or None)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            windows = attend_frames(frames, regression, focal_px=focal, window=window, method=args.method,
                                    initial_box=args.initial_box, progress=progress)
        except InputFileError:  # a VideoFileError while reading the frames
            raise
        except ValueError as error:
            raise CommandError(_option_names(str(error)), args.video) from None
    for note in dict.fromkeys(str(w.message) for w in caught if issubclass(w.category, UserWarning)
                              and "jaxgaze" in os.path.normpath(w.filename).split(os.sep)):
        warn(note)
    with writing(args.out, also={args.overlay: "overlay"}), atomic_path(args.out) as tmp:  # both or neither
        rows = write_attend_csv(tmp, windows, fps)
        if args.overlay is not None:
            try:
                drawn = write_frames(args.overlay, attention_overlay(frames, windows), fps or 10.0)
            except InputFileError:
                raise
            except ValueError as error:
                raise CommandError(f"cannot write overlay: {error}", args.overlay) from None

    valid = np.asarray(windows.valid, bool)
    timing = f", {rows * window / fps:.1f} s at {fps:g} fps" if fps else ""
    mean_p = f"; mean probability {float(np.mean(windows.probability[valid])):.2f}" if valid.any() else ""
    scale = windows.image_scale
    rescaled = "model image rows" + (" and focal length" if args.focal_px is None else "")
    scaled = f"; {rescaled} scaled x {scale:g} to the {width}x{height} px video" if scale != 1 else ""
    overlay = f"; overlay of {drawn} frames written to {args.overlay}" if args.overlay is not None else ""
    summary(args, f"{int(valid.sum())} of {rows} window(s) of {window} frames attended ({rows * window} frames{timing}, "
                  f"focal length {focal:.1f} px, {args.method} saliency){mean_p}{scaled}; written to {args.out}{overlay}")
    return 0
