"""``jaxgaze calibrate POSES_A POSES_B --out calib.json``: wearer A's primary gaze ray (cone model,
Park et al. 2012, Sec. 3.2) from a session in which A looks at B's head-mounted camera."""

from __future__ import annotations

import argparse
import math
import os
import sys
import warnings

from jaxgaze.cli._common import add_output, add_quiet, sampler_figures
from jaxgaze.cli._common import CommandError, check_output, int_at_least, show_progress, summary, warn, writing
from jaxgaze.cli._common import add_trust_units, declare_inputs, stage, unit_rule

DEFAULT_SAMPLES = 500


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "calibrate",
        help="calibrate a wearer's primary gaze ray from a session of two people looking at each other's camera",
        description="Calibrate the primary gaze ray (cone model, Park et al. 2012, Sec. 3.2) of wearer A from a "
                    "session in which A looks at B's head-mounted camera. POSES_A and POSES_B are COLMAP "
                    "images.txt files (.txt) or pose CSVs (.csv: frame, qw, qx, qy, qz, cx, cy, cz, with q "
                    "the quaternion of R_camera_from_world in the camera frame +x forward, +y left, +z up); "
                    "frames are matched by frame id (the summary says how each file's were found). Writes a "
                    "JSON with the eye centre (metres) and unit "
                    "gaze direction in A's camera frame (+x forward, +y left, +z up) and the bandwidth h "
                    "(radians): wearer, frame, eye_center, direction, bandwidth, alpha, xi, num_points, "
                    "num_inliers, method. Park's apex is loose along the ray: one more than 0.3 m from the camera, "
                    "or outside the posterior's 90% region, is said and replaced by the posterior mean (sampled "
                    "then; method 'posterior mean', the RANSAC estimate under 'point_estimate').",
    )
    parser.add_argument("poses_a", metavar="POSES_A", help="camera poses of the wearer (images.txt or .csv)")
    parser.add_argument("poses_b", metavar="POSES_B", help="camera poses of the partner A looks at")
    add_output(parser, "--out", required=True, metavar="CALIB.json", help="output JSON (replaced only on success)")
    add_output(parser, "--posterior", what="posterior", default=None, metavar="POSTERIOR.nc",
                        help="also sample the Bayesian posterior (NUTS, started at the point estimate), write "
                             "its arviz InferenceData to this NetCDF file and into the JSON each parameter's mean, sd, "
                             "90%% HDI, ESS and split r-hat; exit status 1 "
                             "when the sampler did not mix or the eye centre is implausible (files written)")
    parser.add_argument("--samples", type=int_at_least(1), default=DEFAULT_SAMPLES, metavar="N",
                        help=f"NUTS warm-up steps and draws for --posterior (default {DEFAULT_SAMPLES})")
    parser.add_argument("--seed", type=int, default=0, metavar="S", help="random seed (default 0)")
    parser.add_argument("--wearer", default=None, metavar="NAME",
                        help="name of the wearer, matched to the 'person' column by 'concurrences "
                             "--calibration' (default: the file name of POSES_A without its extension; when POSES_A "
                             "and POSES_B are one file, e.g. a joint COLMAP model, 'camera_A' after --camera-id A, "
                             "else --name-prefix A without its trailing '/')")
    parser.add_argument("--frame-pattern", default=None, metavar="REGEX",
                        help="COLMAP files: the frame id is the one group of this regular expression, searched for "
                             "in each image name, e.g. '_(\\d+)_leftImg8bit' (default: the number in the names, or "
                             "the one number that changes between them, or IMAGE_ID when they hold no digits)")
    parser.add_argument("--camera-id", nargs=2, type=_camera_id, default=(None, None), metavar=("A", "B"),
                        help="keep only the images of COLMAP CAMERA_ID A in POSES_A and B in POSES_B ('any': all), "
                             "e.g. two wearers in one joint reconstruction")
    parser.add_argument("--name-prefix", nargs=2, default=("", ""), metavar=("A", "B"),
                        help="keep only the images whose names start with A in POSES_A and with B in POSES_B "
                             "('': all)")
    add_trust_units(parser)
    add_quiet(parser)
    declare_inputs(parser, "poses_a", "poses_b")
    return parser


def _camera_id(text: str):
    """A COLMAP CAMERA_ID (an integer ≥ 1), or None for 'any'."""
    return None if text == "any" else int_at_least(1)(text)


def _read(args):
    """POSES_A and POSES_B as :class:`~jaxgaze.io.poses.PoseTrack` (images selected, frame ids by the rule)."""
    from jaxgaze.io.poses import compile_frame_pattern, read_poses

    if args.frame_pattern is not None:
        try:
            compile_frame_pattern(args.frame_pattern)
        except ValueError as error:
            raise CommandError(f"--frame-pattern: {error}") from None
    return [read_poses(path, frame_pattern=args.frame_pattern, camera_id=camera, name_prefix=prefix or None)
            for path, camera, prefix in zip((args.poses_a, args.poses_b), args.camera_id, args.name_prefix)]


def _points(args):
    """A's points of regard looking at B's camera, and how each file's frame ids were found; the readers' and
    the unit checks' warnings go to stderr once both files were read."""
    from jaxgaze.io.text import InputFileError
    from jaxgaze.poses import match_frames, points_of_regard

    caught = []
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            tracks = _read(args)
            poses_a, poses_b = tracks[0].poses, tracks[1].poses
            sources = "; ".join(track.describe() for track in tracks)
            try:
                poses_a, poses_b = match_frames(poses_a, poses_b, by="frame")
            except ValueError:
                raise CommandError(f"no matching frames: POSES_A and POSES_B share no frame id ({poses_a.num_frames} "
                                   f"and {poses_b.num_frames} poses; {sources}; other file: {args.poses_b})",
                                   args.poses_a) from None
            if poses_a.num_frames < 3:
                raise CommandError(f"only {poses_a.num_frames} frame(s) in common with {args.poses_b}; calibration "
                                   "needs at least 3", args.poses_a)
            with unit_rule(args, args.poses_a):  # millimetres: an error unless --trust-units
                points = points_of_regard(poses_a, poses_b)
    except InputFileError:
        raise
    except (ValueError, CommandError) as error:  # both files were read: their warnings first
        for note in caught:
            warn(note.message)
        raise (error if isinstance(error, CommandError) else CommandError(str(error), args.poses_a)) from None
    for note in caught:
        warn(note.message)
    return points, sources


def _wearer(args) -> str:
    """--wearer, or after the selection of POSES_A in a joint model (one file), else POSES_A's file name."""
    if args.wearer is not None:
        return args.wearer.strip()
    camera, prefix = args.camera_id[0], args.name_prefix[0]
    if os.path.abspath(args.poses_a) == os.path.abspath(args.poses_b):
        if camera is not None:
            return f"camera_{camera}"
        if prefix:
            return prefix.rstrip("/\\_-. ") or prefix
    return os.path.splitext(os.path.basename(args.poses_a))[0].strip()


def _posterior(args, points, fit, key):
    """NUTS from the point estimate (its diagnostics and summaries keep arviz's messages off stderr); a
    progress bar on a terminal."""
    import jax
    import numpy as np

    from jaxgaze.calibration.posterior import calibrate_cone_posterior

    try:
        return calibrate_cone_posterior(points, key=jax.random.fold_in(key, 1), num_warmup=args.samples,
                                        num_samples=args.samples, init_eye_center=np.asarray(fit.eye_center),
                                        init_direction=np.asarray(fit.direction), progress=show_progress(args))
    except ValueError as error:
        raise CommandError(f"posterior sampling failed: {error}", args.poses_a) from None


def _vector(values) -> str:
    return "(" + ", ".join(f"{float(x):.3f}" for x in values) + ") m"


def run(args) -> int:
    import jax

    from jaxgaze.calibration import MAX_APEX_DISTANCE, MAX_EYE_OFFSET, calibrate_cone, choose_calibration, needs_posterior
    from jaxgaze.io.calibration import write_calibration_json
    from jaxgaze.results import RESULTS, succeeded

    wearer = _wearer(args)
    if not wearer:
        raise CommandError("--wearer must not be empty")
    check_output(args.out)
    if args.posterior is not None:
        check_output(args.posterior, "posterior")
        if os.path.abspath(args.posterior) == os.path.abspath(args.out):
            raise CommandError("--posterior and --out must be different files", args.out)
    points, sources = _points(args)
    key = jax.random.key(args.seed)
    stage(args, f"calibrating from {len(points)} frame(s): RANSAC, then the refinement (each compiles first)")
    try:
        fit = calibrate_cone(points, key=key, throw=False)
    except ValueError as error:
        raise CommandError(f"calibration failed: {error}", args.poses_a) from None
    if fit.result == RESULTS.implausible:
        distance = float(fit.eye_distance)
        raise CommandError(f"calibration failed: the eye centre is {distance:.3g} m from the camera, more than "
                           f"{MAX_APEX_DISTANCE:g} m (positions in millimetres, or pose files that do not belong "
                           "together?)", args.poses_a)
    if not succeeded(fit):
        raise CommandError(f"calibration failed: {fit.message}", args.poses_a)
    posterior = choice = None
    if args.posterior is not None or needs_posterior(fit):
        stage(args, "sampling the posterior (NUTS; it compiles first)" if args.posterior else
              f"the RANSAC eye centre is {float(fit.eye_distance):.2f} m from the camera (more than "
              f"{MAX_EYE_OFFSET:g} m): sampling the posterior to place it")
        posterior = _posterior(args, points, fit, key)
        choice = choose_calibration(fit, posterior)
        if choice.disagrees:
            warn(choice.message)

    with writing(args.out, also={args.posterior: "posterior"}):
        record = write_calibration_json(args.out, wearer, fit, posterior=posterior, posterior_path=args.posterior,
                                        num_warmup=args.samples, choice=choice)
    if posterior is not None and not succeeded(posterior):
        files = args.out if args.posterior is None else f"{args.out} and {args.posterior}"
        print(f"jaxgaze calibrate: the posterior failed: {RESULTS[posterior.result]} "
              f"({sampler_figures(posterior.sampler.diagnostics)}); written to {files} for inspection", file=sys.stderr)
        return 1
    d = record["direction"]
    estimate = " (posterior mean)" if record["method"] == "posterior mean" else ""
    summary(args, f"calibrated '{wearer}' from {record['num_points']} frame(s), {record['num_inliers']} inlier(s): "
                  f"eye centre{estimate} {_vector(record['eye_center'])}, "
                  f"{math.degrees(math.atan2(math.hypot(d[1], d[2]), d[0])):.1f}° off the optical axis, "
                  f"h = {record['bandwidth']:.4f} rad; {sources}; written to {args.out}"
                  + (f" and {args.posterior}" if args.posterior else ""))
    return 0
