"""``jaxgaze fit-gaze --out gp.json``: the gaze regression of Yücel et al. 2013 (f1 direction, f2 depth
from head pose), fitted on simulated table-top sessions, for ``jaxgaze attend``."""

from __future__ import annotations

import argparse
import os
import time

from jaxgaze.cli._common import add_output, add_quiet
from jaxgaze.cli._common import CommandError, check_output, int_at_least, positive_float, show_progress, summary
from jaxgaze.cli._common import stage, writing


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "fit-gaze",
        help="fit the gaze regression (f1 direction, f2 depth from head pose) on simulated table-top sessions",
        description="Simulate table-top sessions (jaxgaze.simulate.tabletop: PEOPLE experimenters, SESSIONS "
                    "sessions each, one table and camera), fit the gaze regression of Yücel et al. 2013 on their "
                    "head poses (pitch, yaw, roll, radians, relative to the eye-contact head frame) and write it "
                    "to OUT for 'jaxgaze attend', with metadata focal_px, fps, window and image_size. "
                    "--demo-video also renders a session of one more experimenter (not in the training data) as "
                    "a video to try 'jaxgaze attend' on.",
    )
    add_output(parser, "--out", what="model", required=True, metavar="GP.json",
               help="model file (replaced only on success)")
    parser.add_argument("--seed", type=int, default=0, metavar="S", help="random seed (default 0)")
    parser.add_argument("--method", choices=("gp", "nn"), default="gp",
                        help="gp: the paper's two Gaussian processes; nn: the CogSci neural-network baseline "
                             "(default gp)")
    parser.add_argument("--people", type=int_at_least(1), default=4, metavar="N",
                        help="simulated experimenters (default 4)")
    parser.add_argument("--sessions", type=int_at_least(1), default=2, metavar="N",
                        help="sessions per experimenter (default 2)")
    parser.add_argument("--duration", type=positive_float, default=30.0, metavar="SECONDS",
                        help="length of a session (default 30)")
    parser.add_argument("--fps", type=positive_float, default=10.0, metavar="FPS",
                        help="frame rate of the sessions (default 10, as T-CYB)")
    parser.add_argument("--window", type=int_at_least(1), default=4, metavar="N",
                        help="pooling window stored in the model for 'attend' (default 4)")
    parser.add_argument("--max-frames", type=int_at_least(2), default=600, metavar="N",
                        help="thin the training frames evenly to at most N (default 600; a GP costs O(N^3))")
    add_output(parser, "--demo-video", what="demo video", default=None, metavar="VIDEO",
                        help="also render a held-out session as a video (.mp4, .avi or .mkv): 640 x 480 (the "
                             "simulator's camera at twice its 320 x 240), 10 lead-in frames of eye contact first")
    parser.add_argument("--demo-frames", type=int_at_least(1), default=100, metavar="N",
                        help="session frames in --demo-video after the lead-in, at most a session's (default 100)")
    add_quiet(parser)
    return parser


def _check_demo_video(args) -> None:
    from jaxgaze.io.video import VIDEO_CODECS

    ext = os.path.splitext(args.demo_video)[1].lower()
    if ext not in VIDEO_CODECS:
        raise CommandError(f"--demo-video must end in {', '.join(VIDEO_CODECS)}, got {ext or 'no extension'!r}",
                           args.demo_video)
    check_output(args.demo_video, "demo video")
    if os.path.abspath(args.demo_video) == os.path.abspath(args.out):
        raise CommandError("--demo-video and --out must be different files", args.out)


def run(args) -> int:
    import jax

    from jaxgaze.headpose import regression
    from jaxgaze.io.models import save_gaze_regression
    from jaxgaze.io.video import write_video
    from jaxgaze.papers.yucel2013 import training_data
    from jaxgaze.results import succeeded
    from jaxgaze.simulate.tabletop import IMAGE_HEIGHT, IMAGE_WIDTH, simulate_tabletop_sessions
    from jaxgaze.simulate.video import render_tabletop_video

    check_output(args.out, "model")
    if args.demo_video is not None:
        _check_demo_video(args)
    if round(args.duration * args.fps) < 2:
        raise CommandError(f"--duration {args.duration:g} s at --fps {args.fps:g} gives fewer than 2 frames per session")
    clock = time.perf_counter()
    key_sim, key_fit, key_render = jax.random.split(jax.random.key(args.seed), 3)
    demo_people = 1 if args.demo_video is not None else 0  # one more experimenter, held out
    stage(args, f"simulating {(args.people + demo_people) * args.sessions} table-top session(s) of {args.duration:g} s "
                f"at {args.fps:g} fps")
    try:
        sessions = simulate_tabletop_sessions(key_sim, num_people=args.people + demo_people,
                                              sessions_per_person=args.sessions, duration_s=args.duration, fps=args.fps)
    except ValueError as error:
        raise CommandError(str(error)) from None
    num_train = args.people * args.sessions
    X, f1, f2 = training_data(sessions, range(num_train), args.max_frames)
    size = (IMAGE_WIDTH, IMAGE_HEIGHT)  # f2 is a row of the simulator's images
    stage(args, f"fitting the {args.method} gaze regression on {len(X)} frames"
                + (": a Gaussian process for the direction f1, then one for the depth f2 (each compiles first)"
                   if args.method == "gp" else ""))
    if args.method == "gp":
        model = regression.fit_gaze_regression(X, f1, f2, key=key_fit, progress=show_progress(args), image_size=size)
    else:
        model = regression.fit_gaze_regression_nn(X, f1, f2, key=key_fit, image_size=size)
    converged = succeeded(model) if args.method == "gp" else True
    metadata = {
        "focal_px": float(sessions[0].focal_px), "fps": float(args.fps),  # + the model's image_size
        "window": int(args.window), "features": ["pitch", "yaw", "roll"],
        "units": "features: head pose (pitch, yaw, roll) in radians relative to the eye-contact (frontal) head "
                 "frame; direction f1: image angle atan2(dy, dx) in radians; depth f2: image row in pixels of "
                 "image_size images with focal length focal_px",
        "source": "jaxgaze fit-gaze: simulated table-top sessions (jaxgaze.simulate.tabletop)",
        "method": args.method, "seed": int(args.seed), "people": int(args.people),
        "sessions_per_person": int(args.sessions), "duration_s": float(args.duration),
        "num_training_frames": int(len(X)), "converged": converged,
    }
    demo_text = ""
    if args.demo_video is not None:
        demo = sessions[num_train]
        stage(args, f"rendering the demo video {args.demo_video}")
        frames, _ = render_tabletop_video(demo, key=key_render, num_frames=args.demo_frames)
        demo_text = (f"; demo video {args.demo_video}: {len(frames)} frames at {demo.fps:g} fps, "
                     f"{frames[0].shape[1]}x{frames[0].shape[0]} px (10 lead-in frames of eye contact), focal "
                     f"length {2 * demo.focal_px:.1f} px")
    with writing(args.out, "model", also={args.demo_video: "demo video"}):
        if args.demo_video is None:
            save_gaze_regression(args.out, model, metadata=metadata)
        else:
            from jaxgaze.io.text import atomic_path

            with atomic_path(args.out) as tmp:  # the model only together with the video
                save_gaze_regression(tmp, model, metadata=metadata)
                try:
                    write_video(args.demo_video, frames, demo.fps)  # atomic itself
                except ValueError as error:
                    raise CommandError(f"cannot write demo video: {error}", args.demo_video) from None
    state = "" if converged else " (the fit did not converge: see the model's GP results)"
    summary(args, f"{args.method} gaze regression fitted on {len(X)} frames of {num_train} simulated session(s)"
                  f"{state} in {time.perf_counter() - clock:.1f} s; written to {args.out}{demo_text}")
    return 0
