"""Every command given a corrupt input file: exit 2, one ``jaxgaze: error:`` line on stderr that names
the file, nothing on stdout, and no output file.

For each command and each of its input-file arguments (the others valid), a handful of corrupt files:
random bytes, the file cut in its first line, a BOM before garbage, and the wrong separator. In-process
(``jaxgaze.cli.main``); every case fails while reading, before any computation, so they are cheap.
``fit-gaze`` and ``demo`` read no input file.
"""

import json
import os

import numpy as np
import pytest

from jaxgaze.io.video import write_video
from tests.cli.helpers import assert_failed, run_main

RAYS = "frame,person,ox,oy,oz,dx,dy,dz\n0,ann,0,0,1.6,1,0,0\n0,ben,2,0,1.6,-1,0.1,0\n1,ann,0,0,1.6,1,0.1,-0.1\n"
POSES = "frame,qw,qx,qy,qz,cx,cy,cz\n" + "".join(f"{f},1,0,0,0,0,{0.1 * f},1.5\n" for f in range(5))
COLMAP = "".join(f"{k + 1} 1 0 0 0 0 0 {2 + 0.1 * k} 1 frame_{k:06d}.jpg\n\n" for k in range(5))
CAMERA_POSES = ("frame,person,qw,qx,qy,qz,cx,cy,cz\n0,ann,1,0,0,0,0,0,1.6\n0,ben,0,0,0,1,2,0,1.6\n"
                "1,ann,1,0,0,0,0.1,0,1.6\n1,ben,0,0,0,1,2,0.1,1.6\n")
CALIBRATION = {"frame": "camera", "eye_center": [-0.05, 0.0, -0.08], "direction": [1.0, 0.0, 0.0], "bandwidth": 0.05}
GAZE_HEADER = "frame,timestamp,yaw,tilt,qw,qx,qy,qz,ex,ey,ez\n"
TARGETS = "frame,tx,ty,tz\n" + "".join(f"{f},1.0,0.0,1.6\n" for f in range(10))
RTTM = "SPEAKER meet 1 0.00 0.40 <NA> <NA> ann <NA> <NA>\nSPEAKER meet 1 0.50 0.40 <NA> <NA> ben <NA> <NA>\n"


def _gaze(eye_y):
    return GAZE_HEADER + "".join(f"{f},{f / 10},0.05,-0.02,1,0,0,0,0,{eye_y},1.6\n" for f in range(10))


def _corruptions(valid: bytes, kind: str) -> dict:
    """The corrupt versions of a valid file: ``kind`` "table" (CSV), "rttm", "colmap", "json" or "video"."""
    first = valid.split(b"\n", 1)[0]
    cases = {
        "random bytes": bytes(np.random.default_rng(0).integers(0, 256, 200, dtype=np.uint8)) + b"\xff\xfe",
        "cut in its first line": (first[: len(first) // 2] if kind != "video" else valid[:200]),
        "BOM and garbage": "\ufeff@@ 0x1F;;;\u00e9\u2028 not what was asked for ###\n".encode(),
    }
    separator = {"table": (b",", b";"), "rttm": (b" ", b","), "colmap": (b" ", b","), "json": (b":", b"=")}
    if kind in separator:
        cases["wrong separator"] = valid.replace(*separator[kind])
    return cases


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """Valid small inputs of every command (each corrupt case replaces one of them)."""
    d = tmp_path_factory.mktemp("valid")
    texts = {"rays.csv": RAYS, "alice.csv": POSES, "bob.txt": COLMAP, "cameras.csv": CAMERA_POSES,
             "ann.json": json.dumps({"wearer": "ann", **CALIBRATION}),
             "ben.json": json.dumps({"wearer": "ben", **CALIBRATION}),
             "ann.csv": _gaze(0.0), "ben.csv": _gaze(2.0), "targets.csv": TARGETS, "speech.rttm": RTTM,
             "model.json": json.dumps({"format": "jaxgaze.gaze_regression", "version": 1})}
    paths = {}
    for name, text in texts.items():
        (d / name).write_text(text)
        paths[name] = str(d / name)
    rng = np.random.default_rng(0)
    paths["video.mkv"] = str(d / "video.mkv")
    write_video(paths["video.mkv"], [rng.integers(0, 256, (24, 32, 3), dtype=np.uint8) for _ in range(6)], 10.0)
    return paths


# (command, the argument made corrupt, its valid file, its kind, argv given the inputs and the corrupt file)
ARGUMENTS = [
    ("calibrate", "POSES_A", "alice.csv", "table", lambda f, x: ["calibrate", x, f["bob.txt"]]),
    ("calibrate", "POSES_B", "bob.txt", "colmap", lambda f, x: ["calibrate", f["alice.csv"], x]),
    ("concurrences", "INPUT", "rays.csv", "table", lambda f, x: ["concurrences", x]),
    ("concurrences", "INPUT with --calibration", "cameras.csv", "table",
     lambda f, x: ["concurrences", x, "--calibration", f["ann.json"], f["ben.json"]]),
    ("concurrences", "--calibration", "ann.json", "json",
     lambda f, x: ["concurrences", f["cameras.csv"], "--calibration", x, f["ben.json"]]),
    ("bias", "GAZE", "ann.csv", "table",
     lambda f, x: ["bias", x, "--speech", f["speech.rttm"], "--targets", f["targets.csv"], "--partner", "ben"]),
    ("bias", "--targets", "targets.csv", "table",
     lambda f, x: ["bias", f["ann.csv"], "--speech", f["speech.rttm"], "--targets", x, "--partner", "ben"]),
    ("bias", "--speech", "speech.rttm", "rttm",
     lambda f, x: ["bias", f["ann.csv"], "--speech", x, "--targets", f["targets.csv"], "--partner", "ben"]),
    ("joint", "GAZE", "ben.csv", "table", lambda f, x: ["joint", f["ann.csv"], x, "--people", "ann,ben"]),
    ("joint", "--speech", "speech.rttm", "rttm", lambda f, x: ["joint", f["ann.csv"], f["ben.csv"], "--speech", x]),
    ("attend", "VIDEO", "video.mkv", "video", lambda f, x: ["attend", x, "--model", f["model.json"]]),
    ("attend", "--model", "model.json", "json", lambda f, x: ["attend", f["video.mkv"], "--model", x]),
]
CASES = [(command, argument, variant) for command, argument, _, kind, _ in ARGUMENTS
         for variant in _corruptions(b"x", kind)]


@pytest.mark.parametrize("command, argument, variant", CASES)
def test_corrupt_input_exits_2_with_one_line_and_no_output(inputs, tmp_path, capsys, command, argument, variant):
    (_, _, valid, kind, argv) = next(a for a in ARGUMENTS if a[:2] == (command, argument))
    with open(inputs[valid], "rb") as handle:
        data = _corruptions(handle.read(), kind)[variant]
    corrupt = tmp_path / f"corrupt{os.path.splitext(valid)[1]}"
    corrupt.write_bytes(data)
    out = tmp_path / ("out.nc" if command == "joint" else "out.json" if command in ("calibrate", "bias")
                      else "out.csv")
    per_frame = tmp_path / "per_frame.csv"
    extra = ["--per-frame", str(per_frame)] if command in ("bias", "joint") else []
    status, stdout, stderr = run_main(capsys, argv(inputs, str(corrupt)) + ["--out", str(out)] + extra)
    assert_failed(status, stdout, stderr, str(corrupt))
    assert sorted(os.listdir(tmp_path)) == [corrupt.name]  # no output file, no temporary left
