"""``jaxgaze bias``: read the gaze, targets and speech files → :func:`jaxgaze.bias.adapt_bias` → write the report."""

from __future__ import annotations

import argparse
import os
import sys
import warnings

import jax

from jaxgaze.bias.adapt import DEFAULT_NUM_FRAMES, BIAS_FRAME_COLUMNS, BiasInputError, adapt_bias
from jaxgaze.bias.speech import choose_partner
from jaxgaze.cli._common import (CommandError, add_output, add_quiet, add_trust_units, declare_inputs, int_at_least,
                                 positive_float, sampler_figures, show_progress, stage, summary, unit_rule, warn,
                                 writing)
from jaxgaze.io.bias_report import BIAS_JSON_FORMAT, bias_record, write_bias_report
from jaxgaze.io.gaze import REFERENCE_AXES, GazeFileError, parse_point, read_gaze, read_targets_csv
from jaxgaze.io.joint import read_speech
from jaxgaze.io.text import InputFileError
from jaxgaze.rays import UnitWarning
from jaxgaze.results import RESULTS, succeeded

_DESCRIPTION = """\
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
    --targets is required and is in that camera frame: e.g. -0.2,0,0.4 is
    0.2 m behind the camera and 0.4 m above it.
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

""" + BIAS_JSON_FORMAT + """\
A bayes posterior that did not mix (posterior.result not_mixed) is written, and
the command exits 1 with one line on stderr. Reader warnings (dropped frames, merged speech segments) go to stderr as
'jaxgaze: warning: ...' lines and do not fail the command; if it then fails, its one error line ends with them.
"""
_SAMPLES = 500


def add_parser(subparsers) -> argparse.ArgumentParser:
    """The ``bias`` subcommand (its arguments and help)."""
    p = subparsers.add_parser("bias", formatter_class=argparse.RawDescriptionHelpFormatter, description=_DESCRIPTION,
                              help="estimate a person's gaze bias from the frames where their partner speaks, and "
                                   "label the frames where they look at the partner")
    a = p.add_argument
    a("gaze", metavar="GAZE.csv", help="per-frame gaze and head pose of the person: an OpenFace 2 FeatureExtraction "
                                       "CSV or the CSV described above")
    a("--speech", required=True, metavar="SEGMENTS", help="who speaks when: RTTM (.rttm) or CSV (.csv: start, end, "
      "speaker; seconds); another extension is read as RTTM if it has SPEAKER lines, else as CSV")
    add_output(p, "--out", required=True, metavar="BIAS.json", help="output JSON (replaced only on success)")
    a("--targets", default=None, metavar="X,Y,Z|TARGETS.csv", help="the partner's eye midpoint in metres: for OpenFace "
      "input in our camera frame (+x forward along the optical axis, +y left, +z up; not OpenCV's x right, y down, z "
      "forward), else in the world frame of GAZE.csv's ex, ey, ez: a constant point X,Y,Z (e.g. -0.2,0,0.4) or a "
      "CSV with columns frame, tx, ty, tz covering every frame of GAZE.csv; replaces GAZE.csv's tx, ty, tz columns")
    a("--partner", default=None, metavar="SPEAKER",
      help="speaker id of the partner in SEGMENTS (required unless SEGMENTS has one speaker)")
    a("--speech-file-id", default=None, metavar="ID",
      help="recording (file id, 2nd field) to use from an RTTM that holds several")
    a("--method", choices=("bayes", "lmeds", "mean"), default="bayes", help="bias estimator: bayes (mixture "
      "posterior, NUTS; looking probabilities from its draws), lmeds (the paper's Spk-Med, eq. 2) or mean (Spk-Mean) "
      "(default bayes)")
    a("--frames", type=int_at_least(1), default=None, metavar="N", help="frames drawn at random from the candidates "
      "(default: " + ", ".join(f"{n} for {m}" for m, n in DEFAULT_NUM_FRAMES.items()) + ")")
    a("--window", type=positive_float, default=60.0, metavar="SECONDS",
      help="candidates come from the first SECONDS of GAZE.csv (default 60)")
    a("--max-head-angle-deg", type=positive_float, default=30.0, metavar="DEG",
      help="candidates have the head direction within DEG degrees of the target (default 30)")
    a("--threshold-deg", type=positive_float, default=10.0, metavar="DEG",
      help="looking at the partner: corrected gaze within DEG degrees of the target (default 10)")
    a("--fps", type=positive_float, default=None, metavar="FPS", help="frame rate; required when GAZE.csv has no "
      "timestamp column (frame f is then at f / FPS seconds); with timestamps it defaults to their rate and must "
      "agree with it")
    a("--samples", type=int_at_least(1), default=_SAMPLES, metavar="N",
      help=f"NUTS warm-up steps and draws for --method bayes (default {_SAMPLES})")
    a("--seed", type=int, default=0, metavar="S", help="random seed of the frame draw and of NUTS (default 0)")
    a("--face-id", type=int, default=None, metavar="ID",
      help="OpenFace input: the face_id to use when the file has several faces")
    a("--min-confidence", type=float, default=0.75, metavar="C",
      help="OpenFace input: drop frames with confidence < C (default 0.75)")
    add_output(p, "--per-frame", what="per-frame table", default=None, metavar="PER_FRAME.csv", help="also write "
               "the per-frame table as CSV (columns " + ", ".join(BIAS_FRAME_COLUMNS) + "; booleans as 0/1)")
    add_trust_units(p)
    add_quiet(p)
    declare_inputs(p, "gaze", "speech", "targets")
    return p


def _targets(args, track):
    """``((T, 3) targets, {"targets": their file or None, "targets_from": what in it})``: --targets (a point
    or a CSV), else GAZE.csv's columns."""
    if args.targets is None and track.target is None:
        raise CommandError(("an OpenFace file has no target positions" if track.format == "openface" else "no target "
                            "positions: GAZE.csv has no tx, ty, tz columns") + "; pass --targets X,Y,Z or a CSV of "
                           f"frame, tx, ty, tz (the partner's eye midpoint, metres, {REFERENCE_AXES[track.reference]})",
                           args.gaze)
    if args.targets is None:
        return track.target, {"targets": args.gaze, "targets_from": "the gaze file's columns tx, ty, tz"}
    try:
        point = parse_point(args.targets)
    except ValueError as error:
        raise CommandError(f"--targets: {error}") from None
    if point is None:
        return read_targets_csv(args.targets, track.frame), {"targets": args.targets,
                                                             "targets_from": "a targets CSV: frame, tx, ty, tz"}
    return point, {"targets": None, "targets_from": "--targets " + ",".join(repr(float(x)) for x in point)
                   + " (one point for every frame)"}


def _times(args, track):
    """``((T,) frame times in seconds, fps)``: the timestamps, else frame / --fps."""
    if track.time is None and args.fps is None:
        raise CommandError("GAZE.csv has no timestamp column: pass --fps to time frame f at f / FPS seconds", args.gaze)
    if track.time is None:
        return track.frame / args.fps, args.fps
    rate = track.timestamp_rate
    if args.fps is not None and rate is not None and abs(args.fps - rate) > 0.01 * rate:
        raise CommandError(f"--fps {args.fps:g} disagrees with the timestamps of GAZE.csv ({rate:.3f} frames per "
                           "second); leave --fps out to use the timestamps", args.gaze)
    return track.time, (args.fps if args.fps is not None else rate)


def _speech(args):
    """``(segments, partner)`` from an RTTM or a CSV (by extension, else by content) and --partner."""
    segments = read_speech(args.speech, file_id=args.speech_file_id)
    try:
        return segments, choose_partner(segments, args.partner, option="--partner")
    except ValueError as error:
        raise CommandError(str(error), args.speech) from None


def run(args) -> int:
    """``jaxgaze bias``: the files → :func:`~jaxgaze.bias.adapt_bias` → BIAS.json (and --per-frame)."""
    if args.method == "lmeds" and args.frames is not None and args.frames < 3:
        raise CommandError(f"--method lmeds needs --frames 3 or more, got {args.frames}: with fewer it cannot tell "
                           "the frames that look at the partner from the others")
    try:
        with warnings.catch_warnings(record=True) as caught:  # printed once every input has been checked
            warnings.simplefilter("always")
            track = read_gaze(args.gaze, face_id=args.face_id, min_confidence=args.min_confidence)
            target, target_source = _targets(args, track)
            times, fps = _times(args, track)
            segments, partner = _speech(args)
        nuts = f": NUTS, {args.samples} warm-up steps and {args.samples} draws; compiles first"
        stage(args, f"estimating the gaze bias from {len(track.frame)} frames ({args.method}{nuts * (args.method == 'bayes')})")
        with warnings.catch_warnings(record=True) as fitting:  # the unit rule: an error unless --trust-units
            warnings.simplefilter("always")
            with unit_rule(args, args.targets if args.targets and os.path.isfile(args.targets) else args.gaze):
                result = adapt_bias(track.gaze_angles, track.R_world_from_head, track.eye, target, times, segments,
                                    partner=partner, frames=track.frame, method=args.method, num_frames=args.frames,
                                    window_s=args.window, max_head_angle_deg=args.max_head_angle_deg,
                                    threshold_deg=args.threshold_deg, key=jax.random.key(args.seed), num_warmup=
                                    args.samples, num_samples=args.samples, progress=show_progress(args))
        caught += [w for w in fitting if issubclass(w.category, UnitWarning)]  # with --trust-units: ours
        for w in (w for w in fitting if not issubclass(w.category, UnitWarning)):  # any other as it was
            warnings.showwarning(w.message, w.category, w.filename, w.lineno)
    except BiasInputError as error:  # every input was read: the one line keeps their warnings (dropped frames)
        frame_hint = error.argument == "target" or "the head within" in str(error)
        hint = f": is the target in the {REFERENCE_AXES[track.reference]}, in metres?" if frame_hint else ""
        notes = "".join(f"; reader warning: {w.message}" for w in caught)
        raise GazeFileError(f"{error}{hint}{notes}", args.gaze, track.line_of(error.index)) from None
    except InputFileError:
        raise
    except ValueError as error:
        raise CommandError(str(error), args.gaze) from None
    selection = result.selection
    partial = [f"only {selection.num_candidates} selectable frame(s) for --frames {selection.num_requested}: using all "
               "of them"] if selection.partial else []
    for note in [str(w.message) for w in caught] + partial:
        warn(note)
    record = bias_record(result, fps=fps, seed=args.seed, dropped=track.dropped,
                         inputs={"gaze": args.gaze, "format": track.format, "frame_of_reference": track.reference,
                                 "speech": args.speech, **target_source})
    with writing(args.out):
        write_bias_report(args.out, record, args.per_frame)
    if not succeeded(result.estimate):
        print(f"jaxgaze bias: the posterior failed: {RESULTS[result.estimate.result]} "
              f"({sampler_figures(result.estimate.sampler.diagnostics)}); written to {args.out}; try more --samples or "
              "--method lmeds", file=sys.stderr)
        return 1
    spread = "" if record["std_deg"] is None else " ± ({:.2f}°, {:.2f}°)".format(*record["std_deg"])
    summary(args, f"bias (yaw, tilt) = ({record['bias_deg'][0]:+.2f}°, {record['bias_deg'][1]:+.2f}°){spread} "
                  f"({args.method}, {selection.num_selected} of {selection.num_candidates} candidate frames); looking "
                  f"at '{partner}' in {record['num_looking']} of {record['num_frames']} frames; targets in the "
                  f"{REFERENCE_AXES[track.reference]}; written to {args.out}"
                  + (f" and {args.per_frame}" if args.per_frame else ""))
    return 0
