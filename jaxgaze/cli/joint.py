"""``jaxgaze joint``: read one gaze file per person and the speech → :func:`jaxgaze.joint.fit_joint` → netCDF and CSV."""

from __future__ import annotations

import argparse
import os
import re
import sys
import warnings


from jaxgaze.cli._common import (CommandError, add_output, add_quiet, add_trust_units, declare_inputs, int_at_least,
                                 positive_float, show_progress, stage, unit_rule, warn, writing)
from jaxgaze.io.joint import (JOINT_FRAMES_FORMAT, JOINT_INPUTS_FORMAT, joint_frame_columns, read_joint_gaze, read_speech,
                              speaking_by_person, write_joint_frames, write_joint_netcdf)
from jaxgaze.cli._joint_summary import summary

_DESCRIPTION = """\
Joint inference of a group recording (Park et al. 2012; Siegfried, Odobez et al.
2017): each person's gaze bias and cone width, a speaker prior, who looks at whom,
mutual gaze and the shared gaze concurrences, in one model.

""" + JOINT_INPUTS_FORMAT + """\
OUT.nc is the posterior (arviz InferenceData as netCDF: arviz.from_netcdf).
""" + JOINT_FRAMES_FORMAT + """\
Exit 0; 1 the fit did not succeed (files written; one line on stderr says why: e.g. the
sampler did not mix, or two explanations of someone's gaze); 2 bad input; 130 Ctrl-C.
"""

_DEFAULT_FPS = 10.0
_RESERVED = re.compile(r"^(elsewhere|concurrence[\s_]*\d+)$", re.IGNORECASE)


def add_parser(subparsers) -> argparse.ArgumentParser:
    """The ``joint`` subcommand (its arguments and help)."""
    p = subparsers.add_parser("joint", formatter_class=argparse.RawDescriptionHelpFormatter, description=_DESCRIPTION,
                              help="infer gaze biases, cone widths, who looks at whom and the shared gaze "
                                   "concurrences of a group recording together (one gaze file per person)")
    a = p.add_argument
    a("gaze", nargs="+", metavar="GAZE", help="gaze and head pose per frame: a file per person, or an OpenFace file "
      "of a group filmed by one camera (see above)")
    a("--speech", default=None, metavar="SPEECH", help="who speaks when: RTTM (.rttm) or CSV (.csv: start, end, "
      "speaker; seconds); another extension is read as RTTM if it has SPEAKER lines, else as CSV")
    a("--speech-file-id", default=None, metavar="ID", help="the recording (2nd field) of an RTTM that holds several")
    a("--speaker-map", default=None, metavar="NAME=SPEAKER,...",
      help="the speaker id of a person in SPEECH when it is not the person's name, e.g. ann=spk1,ben=spk2")
    a("--people", default=None, metavar="A,B,...", help="one name per GAZE file, in order (default: file stems)")
    a("--same-camera", action="store_true",
      help="the OpenFace files come from one camera, so they share its frame (needed for several OpenFace files)")
    add_output(p, "--out", required=True, metavar="OUT.nc", help="the posterior as netCDF (replaced only on success)")
    add_output(p, "--per-frame", what="per-frame table", default=None, metavar="PER_FRAME.csv",
               help="also write the per-frame table described above")
    a("--fps", default=None, metavar="FPS", help=f"frame rate (default: the timestamps' rate, else "
      f"{_DEFAULT_FPS:g}); with timestamps it must agree with them")
    a("--method", choices=("nuts", "svi"), default="nuts", help="nuts (exact; a minute or two of recording) or "
      "svi (mean-field variational, frames subsampled; long recordings) (default nuts)")
    a("--warmup", default="500", metavar="N", help="NUTS warm-up steps (default 500)")
    a("--draws", default="500", metavar="N", help="posterior draws, at least 8 (default 500)")
    a("--steps", default="3000", metavar="N", help="SVI optimisation steps, at least 10 (default 3000)")
    a("--window-s", default="60", metavar="S", help="a concurrence stays put within windows of S s (default 60)")
    a("--seed", default="0", metavar="S", help="random seed (default 0)")
    a("--head-only", action="store_true", help="no eye tracker: the gaze from head pose alone, with each person's "
      "head-gaze coupling learnt (gaze columns are ignored and may be absent)")
    a("--head-gaze-gp", default=None, metavar="RADIANS", help="with --head-only: add to each person's linear "
      "head-gaze map a Gaussian process of this amplitude (gaze radians, e.g. 0.2), for heads whose turn "
      "saturates; slower (2-14 times in our runs), and the linear map is as good where heads turn in proportion")
    a("--min-confidence", default="0.75", metavar="C", help="OpenFace: drop frames with confidence < C (default 0.75)")
    add_trust_units(p)
    add_quiet(p)
    declare_inputs(p, "gaze", "speech")
    return p


def _number(option: str, text, parse):  # parse(text); its error as a one-line CommandError naming option
    try:
        return None if text is None else parse(str(text))
    except argparse.ArgumentTypeError as error:
        raise CommandError(f"{option}: {error}") from None
    except ValueError:
        raise CommandError(f"{option}: not a number: {text!r}") from None


def _people(args, gaze) -> list[str]:
    """One unique name per person: --people, else the file stems (``<stem>_<k>`` in an OpenFace file of several)."""
    source = "--people" if args.people else "file stems"
    names = [n.strip() for n in args.people.split(",")] if args.people else list(gaze.people)
    if len(names) != len(gaze.people):
        raise CommandError(f"--people names {len(names)} people for the {len(gaze.people)} in the GAZE files "
                           f"({', '.join(gaze.people)}); one name each, in that order")
    for name in names:
        if not name or _RESERVED.match(name):
            raise CommandError(f"{source}: the person name {name!r} is empty or reserved for a target of the model")
    duplicated = [n for n in dict.fromkeys(names) if names.count(n) > 1]
    if duplicated:
        raise CommandError(f"two people are named {duplicated[0]!r} ({source}); name them with --people A,B,...")
    try:
        joint_frame_columns(names + ["elsewhere"])
    except ValueError as error:
        raise CommandError(f"{source}: {error}") from None
    return names


def _speaker_map(args, people) -> dict:
    """``{person: speaker id}`` of --speaker-map."""
    if args.speech is None and (args.speaker_map or args.speech_file_id):
        raise CommandError("--speaker-map and --speech-file-id need --speech")
    mapping = {}
    for item in args.speaker_map.split(",") if args.speaker_map else []:
        name, sep, speaker = (s.strip() for s in item.partition("="))
        if not (sep and name and speaker) or name in mapping:
            raise CommandError(f"--speaker-map: expected NAME=SPEAKER items, one per person, got {item!r}")
        if name not in people:
            raise CommandError(f"--speaker-map: unknown person {name!r} (people: {', '.join(people)})")
        mapping[name] = speaker
    return mapping


def _check_inputs(args, gaze) -> None:
    """One frame of reference for every file; --fps agrees with the timestamps."""
    openface = list(dict.fromkeys(p for p, f in zip(gaze.paths, gaze.formats) if f == "openface"))
    if openface and len(openface) < len(args.gaze):
        raise CommandError("cannot mix OpenFace files (camera frame) with gaze CSVs (world frame): convert them "
                           "all to one world frame", openface[0])
    if len(openface) > 1 and not args.same_camera:
        raise CommandError(f"{len(openface)} OpenFace files, each in its own camera frame: pass --same-camera if one "
                           "camera filmed everyone, else convert them to gaze CSVs in one world frame")
    rate = gaze.timestamp_rate
    if args.fps is not None and rate is not None and abs(args.fps - rate) > 0.01 * rate:
        raise CommandError(f"--fps {args.fps:g} disagrees with the timestamps of the GAZE files ({rate:.3f} frames "
                           "per second); leave --fps out to use the timestamps")


def _file_of(gaze, people, message: str):
    """The GAZE file of the person a message names (``person 'ann'``), else None."""
    named = re.search(r"person '([^']*)'", message)
    return gaze.paths[people.index(named[1])] if named and named[1] in people else None


def run(args) -> int:
    """``jaxgaze joint``: GAZE files and speech → :func:`~jaxgaze.joint.fit_joint` → OUT.nc (and --per-frame)."""
    import jax
    from jaxgaze.joint import JointPrior, fit_joint, joint_data
    from jaxgaze.results import succeeded

    warmup, draws, steps, seed, window_s, min_confidence, args.fps, gp = (_number(o, v, t) for o, v, t in (
        ("--warmup", args.warmup, int_at_least(1)), ("--draws", args.draws, int_at_least(8)),
        ("--steps", args.steps, int_at_least(10)), ("--seed", args.seed, int), ("--window-s", args.window_s,
        positive_float), ("--min-confidence", args.min_confidence, float), ("--fps", args.fps, positive_float),
        ("--head-gaze-gp", args.head_gaze_gp, positive_float)))
    if gp is not None and not args.head_only:
        raise CommandError("--head-gaze-gp is a head-gaze map: it needs --head-only")
    if gp is not None and gp > 1.0:
        raise CommandError(f"--head-gaze-gp {gp:g}: the amplitude is in radians (0.1-0.5 is typical), not degrees")
    prior = JointPrior(coupling_shape_scale=gp)
    with warnings.catch_warnings(record=True) as caught:  # printed once every input has been checked
        warnings.simplefilter("always")
        gaze = read_joint_gaze(args.gaze, min_confidence=min_confidence, head_only=args.head_only)
        people = _people(args, gaze)
        speaker_map = _speaker_map(args, people)
        _check_inputs(args, gaze)
        fps = args.fps or gaze.timestamp_rate or _DEFAULT_FPS
        times = gaze.times(fps)
        speaking, unmatched = None, []
        if args.speech is not None:
            segments = read_speech(args.speech, file_id=args.speech_file_id)
            try:
                speaking, unmatched = speaking_by_person(segments, people, times, speaker_map)
            except ValueError as error:
                raise CommandError(f"--speaker-map: {error}", args.speech) from None
    for note in [str(w.message) for w in caught] + ([f"{args.speech}: speaker(s) {', '.join(map(repr, unmatched))} "
                                                     f"match no person (people: {', '.join(people)}) and are "
                                                     "ignored; map them with --speaker-map NAME=SPEAKER"]
                                                    if unmatched else []):
        warn(note)
    try:
        with warnings.catch_warnings(record=True) as caught:  # the unit rule: an error unless --trust-units
            warnings.simplefilter("always")
            with unit_rule(args, lambda what: _file_of(gaze, people, what), gaze.frames):
                data = joint_data(gaze.eye_positions, gaze.R_world_from_head, None if args.head_only else
                                  gaze.gaze_angles, present=gaze.present, measurement_scale=gaze.measurement_scale,
                                  speaking=speaking, people=people, fps=fps, window_s=window_s)
        for note in dict.fromkeys(str(w.message) for w in caught):
            warn(note)
        fit = f"NUTS, {warmup} warm-up steps and {draws} draws" if args.method == "nuts" else f"SVI, {steps} steps"
        stage(args, f"fitting the joint model to {data.num_frames} frames of {len(people)} people: a start from the "
                    f"concurrences of each frame, its mode, then {fit} (each stage compiles first; a minute or more)")
        with warnings.catch_warnings(record=True) as caught:  # NumPy's and arviz's numerical noise is dropped
            warnings.simplefilter("always")
            posterior = fit_joint(data, key=jax.random.key(seed), method=args.method, num_warmup=warmup,
                                  num_samples=draws, num_steps=steps, prior=prior, progress=show_progress(args),
                                  throw=False)
    except ValueError as error:  # joint_data counts frames from 0: name them by their ids in the files
        raise CommandError("the recording is not usable: " + re.sub(r"\bframe (\d+)\b", lambda m: (
            f"frame {gaze.frames[min(int(m[1]), gaze.frames.size - 1)]}"), str(error))) from None
    for w in caught:
        if issubclass(w.category, UserWarning) and "jaxgaze" in os.path.normpath(w.filename).split(os.sep):
            warn(str(w.message))
    stage(args, f"writing {' and '.join([args.out] + ([args.per_frame] if args.per_frame else []))}")
    with writing(args.out, also={args.per_frame: "per-frame table"}):  # both replaced together, or neither
        if args.per_frame is not None:
            write_joint_frames(args.per_frame, posterior, gaze.frames, times)
        write_joint_netcdf(args.out, posterior)
    if not args.quiet:
        print(summary(posterior, data, [args.out] + ([args.per_frame] if args.per_frame else [])))
    if not succeeded(posterior):
        print(f"jaxgaze joint: {posterior.message}", file=sys.stderr)
        return 1
    return 0
