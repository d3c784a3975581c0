"""Every file reader under hypothesis: random bytes, and valid small files of each format mutated (cut
lines, wrong separators, BOMs and other encodings, unicode, huge, tiny and non-finite numbers,
duplicated headers and lines, JSON values of the wrong kind or shape). Each input must end in a
parse whose numbers are finite, or in ONE :class:`~jaxgaze.io.text.InputFileError` that names the
file (``path, line N: what``, the line within the file), never in another exception; warnings stay
one short line.

1,000 inputs per reader, derandomised (the same inputs in every run, so CI is reproducible). Hypothesis
draws one integer per input and the input is built from it with :mod:`random` (the mutations in
Python are about 4x cheaper than drawing each of them from hypothesis, which keeps 18,000 inputs fast);
a failure prints the input.
"""

import contextlib
import copy
import json
import os
import random
import tempfile
import warnings
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, note, settings
from hypothesis import strategies as st

from jaxgaze.io.calibration import read_calibration_json
from jaxgaze.io.gaze import read_gaze, read_gaze_csv, read_openface_gaze, read_targets_csv
from jaxgaze.io.joint import read_joint_gaze, read_speech
from jaxgaze.io.models import load_gaze_regression, read_model_metadata, save_gaze_regression
from jaxgaze.io.tools.openface import read_openface
from jaxgaze.io.poses import read_camera_poses_csv, read_colmap_images, read_pose_csv, read_poses
from jaxgaze.io.rays import read_rays_csv
from jaxgaze.io.speech import read_rttm, read_segments_csv
from jaxgaze.io.text import InputFileError
from jaxgaze.io.video import read_frames, write_video

EXAMPLES = 1000
FUZZ = settings(max_examples=EXAMPLES, deadline=None, derandomize=True, database=None, print_blob=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                       HealthCheck.filter_too_much, HealthCheck.large_base_example])
DATA = os.path.join(os.path.dirname(os.path.dirname(__file__)), "data")

# ---------------------------------------------------------------------------
# Valid small files of each format (the seeds the mutations start from)

RAYS = ("frame,person,ox,oy,oz,dx,dy,dz,bandwidth\n0,ann,0,0,1.6,1,0,0,0.05\n0,ben,2,0,1.6,-1,0.1,0,0.05\n"
        "1,ann,0,0,1.6,1,0.1,-0.1,0.04\n")
POSES = ("frame,qw,qx,qy,qz,cx,cy,cz,timestamp\n0,1,0,0,0,0,0,1.5,0.0\n"
         "1,0.9950041652780258,0,0,0.09983341664682815,0.1,0,1.5,0.1\n")
CAMERA_POSES = ("frame,person,qw,qx,qy,qz,cx,cy,cz\n0,ann,1,0,0,0,0,0,1.6\n0,ben,0,0,0,1,2,0,1.6\n"
                "1,ann,1,0,0,0,0.1,0,1.6\n")
with open(os.path.join(DATA, "colmap_images.txt"), encoding="utf-8") as _f:
    COLMAP = "".join(line for line in _f if not line.startswith("# ") or "IMAGE_ID" in line)
CALIBRATION = json.dumps({"wearer": "ann", "frame": "camera", "eye_center": [-0.05, 0.0, -0.08],
                          "direction": [1.0, 0.0, 0.0], "bandwidth": 0.05, "alpha": 0.1, "xi": 0.2}, indent=1)
OPENFACE = ("frame, face_id, timestamp, confidence, success, gaze_0_x, gaze_angle_x, gaze_angle_y, pose_Tx, pose_Ty, "
            "pose_Tz, pose_Rx, pose_Ry, pose_Rz, AU01_r\n"
            "1, 0, 0.000, 0.98, 1, 0.1, 0.05, -0.02, 10.0, -5.0, 600.0, 0.1, -0.05, 0.01, 0.3\n"
            "2, 0, 0.033, 0.20, 0, 0.1, 0.00, 0.00, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0\n"
            "3, 0, 0.067, 0.97, 1, 0.1, 0.06, -0.01, 11.0, -5.0, 601.0, 0.1, -0.04, 0.01, 0.3\n")
GAZE = ("frame,timestamp,yaw,tilt,qw,qx,qy,qz,ex,ey,ez,tx,ty,tz\n0,0.0,0.1,-0.05,1,0,0,0,0,0,1.6,1,0,1.6\n"
        "1,0.1,0.12,-0.04,0.9950041652780258,0,0,0.09983341664682815,0,0,1.6,1,0,1.6\n")
OTHER_GAZE_NAME = "other_gaze.csv"
OTHER_GAZE = "frame,yaw,tilt,qw,qx,qy,qz,ex,ey,ez\n0,0.0,0.0,1,0,0,0,2,0,1.6\n1,0,0,1,0,0,0,2,0,1.6\n3,0,0,1,0,0,0,2,0,1.6\n"
TARGETS = "frame,tx,ty,tz\n0,1,0,1.2\n1,1,0.1,1.2\n"
RTTM = (";; a diarisation\nSPEAKER meet 1 0.00 1.50 <NA> <NA> ann <NA> <NA>\n"
        "SPEAKER meet 1 1.20 0.80 <NA> <NA> ben <NA> <NA>\nSPKR-INFO meet 1 <NA> <NA> <NA> unknown ann <NA> <NA>\n"
        "SPEAKER meet 1 1.40 0.50 <NA> <NA> ann <NA> <NA>\n")
SEGMENTS = "# who speaks\nstart,end,speaker\n0.0,1.5,ann\n1.2,2.0,ben\n1.4,1.9,ann\n"


def _tiny_model_json(directory) -> str:
    """A saved GP gaze regression on 3 training points (the file format, not a fit)."""
    from jaxgaze.gp.exact import fitted_gp
    from jaxgaze.gp.kernels import RBF, White
    from jaxgaze.headpose.regression import GazeRegression, Scaling
    from jaxgaze.results import RESULTS

    dtype = jnp.asarray(np.zeros(1)).dtype
    pose = np.array([[0.1, -0.2, 0.0], [-0.3, 0.1, 0.2], [0.2, 0.3, -0.1]])
    direction, depth = pose @ [0.2, 1.0, 0.1], 150.0 - 60.0 * pose[:, 0]
    features, s1, s2 = Scaling.of(pose), Scaling.of(direction), Scaling.of(depth)

    def gp(y):
        return fitted_gp(RBF(1.0, 1.0) + White(0.1), jnp.asarray(features.apply(pose), dtype), jnp.asarray(y, dtype),
                         None, RESULTS.successful, jnp.asarray([-1.0], dtype), ((1, "float32", 1),), False)

    path = os.path.join(directory, "model.json")
    save_gaze_regression(path, GazeRegression(gp(s1.apply(direction)), gp(s2.apply(depth)), features, s1, s2),
                         metadata={"focal_px": 320.0, "window": 4, "image_size": [32, 24]})
    with open(path, encoding="utf-8") as handle:
        return handle.read()


def _tiny_video(directory) -> bytes:
    """A lossless 3-frame 16x12 video (FFV1 in Matroska)."""
    path = os.path.join(directory, "tiny.mkv")
    rng = np.random.default_rng(0)
    write_video(path, [rng.integers(0, 256, (12, 16, 3), dtype=np.uint8) for _ in range(3)], 10.0)
    with open(path, "rb") as handle:
        return handle.read()


# ---------------------------------------------------------------------------
# Checks of a parse: its numbers are finite


def _finite(*arrays):
    for array in arrays:
        if array is not None:
            assert np.all(np.isfinite(np.asarray(array, dtype=np.float64)))


def _check_poses(poses):
    poses = poses.poses if hasattr(poses, "frame_ids_from") else poses  # read_poses's PoseTrack
    _finite(poses.R_camera_from_world, poses.centers, poses.timestamps)


def _check_gaze(track):
    _finite(track.time, track.gaze_angles, track.R_world_from_head, track.eye, track.target)


def _check_speech(segments):
    _finite(segments.start, segments.end)
    assert np.all(segments.end >= segments.start)


def _check_rays(recording):
    mask = np.asarray(recording.rays.mask, dtype=bool)
    _finite(np.asarray(recording.rays.origins)[mask], np.asarray(recording.rays.directions)[mask],
            np.asarray(recording.rays.bandwidth)[mask])


def _check_openface(track):
    _finite(track.timestamp, track.confidence, track.gaze_direction_camera, track.R_camera_from_head,
            track.head_position_camera)


def _check_calibration(calibration):
    _finite(calibration.cone.eye_center, calibration.cone.direction, calibration.cone.bandwidth)


def _check_joint(gaze):
    present = np.asarray(gaze.present, dtype=bool)
    _finite(gaze.time, np.asarray(gaze.eye_positions)[present], np.asarray(gaze.gaze_angles)[present])


def _check_metadata(metadata):
    assert isinstance(metadata, dict)


def _check_model(regression):
    assert type(regression).__name__ in ("GazeRegression", "NNGazeRegression")


def _read_joint_gaze(path):
    """The file aligned with a valid gaze CSV of another person (``other_gaze.csv`` next to it)."""
    return read_joint_gaze([path, os.path.join(os.path.dirname(path), OTHER_GAZE_NAME)])


# name: (reader of one path, seed names (suffix, text or bytes key), check of a parse)
READERS = {
    "read_rays_csv": (read_rays_csv, [(".csv", "rays")], _check_rays),
    "read_pose_csv": (read_pose_csv, [(".csv", "poses")], _check_poses),
    "read_colmap_images": (read_colmap_images, [(".txt", "colmap")], _check_poses),
    "read_poses": (read_poses, [(".txt", "colmap"), (".csv", "poses")], _check_poses),
    "read_camera_poses_csv": (read_camera_poses_csv, [(".csv", "camera_poses")],
                              lambda w: [_check_poses(p) for p in w.poses.values()]),
    "read_calibration_json": (read_calibration_json, [(".json", "calibration")], _check_calibration),
    "read_openface": (read_openface, [(".csv", "openface")], _check_openface),
    "read_gaze": (read_gaze, [(".csv", "gaze"), (".csv", "openface")], _check_gaze),
    "read_gaze_csv": (read_gaze_csv, [(".csv", "gaze")], _check_gaze),
    "read_openface_gaze": (read_openface_gaze, [(".csv", "openface")], _check_gaze),
    "read_targets_csv": (read_targets_csv, [(".csv", "targets")], lambda r: _finite(r[1])),
    "read_rttm": (read_rttm, [(".rttm", "rttm")], _check_speech),
    "read_segments_csv": (read_segments_csv, [(".csv", "segments")], _check_speech),
    "read_speech": (read_speech, [(".rttm", "rttm"), (".csv", "segments"), (".txt", "rttm")], _check_speech),
    "read_joint_gaze": (_read_joint_gaze, [(".csv", "gaze"), (".csv", "openface")], _check_joint),
    "read_model_metadata": (read_model_metadata, [(".json", "model")], _check_metadata),
    "load_gaze_regression": (load_gaze_regression, [(".json", "model")], _check_model),
    "read_frames": (read_frames, [(".mkv", "video")], lambda frames: [_finite(f) for f in frames]),
}


# ---------------------------------------------------------------------------
# Mutations

TOKENS = ["1e308", "-1e308", "1e309", "1e-320", "5e-324", "inf", "-inf", "nan", "NaN", "-0", "-0.0", "0", "1", "-1",
          "2", "0.5", "3.5", "-3.5", "1000", "1e9", "9" * 30, "", " ", "x", "1.2e", "1,5", "0x1A", "1_000", "+1",
          "\uff11", "\u0663", "\u00bd", "\u221e", "True", "null", '"', '""', '"1"', "\u00e9", "\u2028", "\x00",
          "\ufeff", ";", "\t", "#", ";;", "SPEAKER", "<NA>", "frame", "person", "speaker", "\r", "\n"]
SEPARATORS = [";", "\t", " ", ", ", "|", ",,"]
OPS = ["token", "truncate", "separator", "insert", "duplicate_line", "delete_line", "swap_lines", "duplicate_column",
       "line_endings", "no_final_newline", "empty"]
ENCODINGS = ["utf-8"] * 6 + ["utf-8-sig", "utf-16", "latin-1", "cp1252"]
JSON_VALUES = [None, True, False, 0, -1, 2, 0.5, 1e308, -1e308, 5e-324, -0.0, 2 ** 70, float("nan"), float("inf"),
               "", "x", "camera", "float32", "float64", "gp", "nn", "RBF", "Sum", [], {}, [1.0, 2.0, 3.0], [[1.0]],
               [[1.0, 2.0], [3.0, 4.0]], [1.0, "a"], [None], {"type": "RBF"}, {"a": 1}]


def _mutate_text(text: str, op: str, a: int, b: int, token: str) -> str:
    lines = text.split("\n")
    if op == "token":
        parts = text.replace(",", "\x01,\x01").replace(" ", "\x01 \x01").replace("\n", "\x01\n\x01").split("\x01")
        values = [k for k, p in enumerate(parts) if p not in (",", " ", "\n", "")]
        if values:
            parts[values[a % len(values)]] = token
        return "".join(parts)
    if op == "truncate":
        return text[: a % (len(text) + 1)]
    if op == "separator":
        old = "," if "," in text else " "
        return text.replace(old, SEPARATORS[b % len(SEPARATORS)])
    if op == "insert":
        k = a % (len(text) + 1)
        return text[:k] + token + text[k:]
    if op in ("duplicate_line", "delete_line", "swap_lines"):
        i, j = a % len(lines), b % len(lines)
        if op == "duplicate_line":
            lines.insert(j, lines[i])
        elif op == "delete_line":
            del lines[i]
        else:
            lines[i], lines[j] = lines[j], lines[i]
        return "\n".join(lines)
    if op == "duplicate_column":
        cells = lines[0].split(",")
        lines[0] = ",".join(cells + [cells[a % len(cells)]])
        return "\n".join(lines)
    if op == "line_endings":
        return text.replace("\n", ["\r\n", "\r", "\n\n", "\u2028"][b % 4])
    if op == "no_final_newline":
        return text.rstrip("\n")
    return ["", " ", "\n\n", "\ufeff"][b % 4]  # empty


def _mutate_json(value, path: list, op: int, new):
    """Replace (op 0), delete (op 1, a dict key or list item) or duplicate (op 2, a list item) the node
    that ``path`` (indices, taken modulo) leads to; op 3 adds a key."""
    if not path or not isinstance(value, (dict, list)) or not value:
        return new if op == 0 else value
    keys = list(value) if isinstance(value, dict) else list(range(len(value)))
    key = keys[path[0] % len(keys)]
    if len(path) > 1 and isinstance(value[key], (dict, list)) and value[key]:
        value[key] = _mutate_json(value[key], path[1:], op, new)
    elif op == 0:
        value[key] = new
    elif op == 1:
        del value[key]
    elif op == 2 and isinstance(value, list):
        value.insert(key, value[key])
    elif isinstance(value, dict):
        value[f"extra{path[0]}"] = new
    return value


def corrupted(seed: int, sources, texts) -> tuple:
    """``(suffix, bytes)`` of a corrupted file, a function of ``seed``: random bytes (1 in 8), or a
    valid file of the reader's format mutated 1-4 times (a video: bytes cut, flipped or inserted;
    a JSON file: also values replaced, deleted or duplicated deep inside it)."""
    rng = random.Random(seed)
    suffix, name = rng.choice(sources)
    source = texts[name]
    if rng.randrange(8) == 0:
        return suffix, rng.randbytes(rng.randrange(300))
    if isinstance(source, bytes):
        data = bytearray(source)
        for _ in range(rng.randint(1, 3)):
            at, kind = rng.randrange(len(data) + 1), rng.randrange(3)
            if kind == 0:
                del data[at:]
            elif kind == 1 and at < len(data):
                data[at] ^= rng.randint(1, 255)
            else:
                data[at:at] = rng.randbytes(rng.randint(1, 16))
        return suffix, bytes(data)
    text = source
    if suffix == ".json" and rng.randrange(4) > 0:
        value = json.loads(source)
        for _ in range(rng.randint(1, 3)):
            path = [rng.randrange(40) for _ in range(rng.randint(1, 7))]
            value = _mutate_json(value, path, rng.randrange(4), copy.deepcopy(rng.choice(JSON_VALUES)))
        text = json.dumps(value)
        if rng.randrange(2):
            return suffix, text.encode()
    for _ in range(rng.randint(1, 4)):
        text = _mutate_text(text, rng.choice(OPS), rng.randrange(10 ** 6), rng.randrange(50), rng.choice(TOKENS))
    return suffix, text.encode(rng.choice(ENCODINGS), errors="replace")


# ---------------------------------------------------------------------------
# The fuzzers


@pytest.fixture(scope="module")
def seeds(tmp_path_factory):
    """The seed texts, and a folder for the corrupted files: in memory (/dev/shm) where there is one,
    where writing and reading a file costs some 30 µs instead of a millisecond on a busy disk."""
    with contextlib.ExitStack() as stack:
        memory = "/dev/shm"
        if os.path.isdir(memory) and os.access(memory, os.W_OK):
            fuzz_dir = Path(stack.enter_context(tempfile.TemporaryDirectory(dir=memory, prefix="jaxgaze-fuzz-")))
        else:
            fuzz_dir = tmp_path_factory.mktemp("fuzz")
        yield _seeds(tmp_path_factory, fuzz_dir)


def _seeds(tmp_path_factory, fuzz_dir):
    directory = tmp_path_factory.mktemp("seeds")
    (fuzz_dir / OTHER_GAZE_NAME).write_text(OTHER_GAZE)
    texts = {"rays": RAYS, "poses": POSES, "camera_poses": CAMERA_POSES, "colmap": COLMAP,
             "calibration": CALIBRATION, "openface": OPENFACE, "gaze": GAZE, "targets": TARGETS, "rttm": RTTM,
             "segments": SEGMENTS, "model": _tiny_model_json(directory), "video": _tiny_video(directory)}
    return {"texts": texts, "dir": fuzz_dir}


def _line_count(data: bytes) -> int:
    count = data.count(b"\n") + 1
    try:
        return max(count, len(data.decode("utf-8-sig").splitlines()))
    except UnicodeDecodeError:
        return count


def test_the_seeds_parse(seeds):
    """Each unmutated seed is a valid file of its format (so the mutations start deep inside the readers)."""
    for name, (reader, sources, check) in READERS.items():
        for suffix, key in sources:
            path = seeds["dir"] / f"seed_{name}{suffix}"
            seed = seeds["texts"][key]
            path.write_bytes(seed if isinstance(seed, bytes) else seed.encode())
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                check(reader(str(path)))


@pytest.mark.parametrize("name", list(READERS))
def test_reader_parses_or_names_the_file(seeds, name):
    reader, sources, check = READERS[name]
    other = str(seeds["dir"] / OTHER_GAZE_NAME)  # the joint reader's valid second file
    paths = {suffix: str(seeds["dir"] / f"{name}{suffix}") for suffix, _ in sources}

    @FUZZ
    @given(st.integers(0, 2 ** 32 - 1))
    def fuzz(seed):
        suffix, data = corrupted(seed, sources, seeds["texts"])
        note(f"{suffix} file: {data[:2000]!r}")
        path = paths[suffix]
        with open(path, "wb") as handle:
            handle.write(data)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                result = reader(path)
            except InputFileError as error:
                message = str(error)
                assert "\n" not in message and "\r" not in message
                where = error.path if error.line is None else f"{error.path}, line {error.line}"
                assert message.startswith(f"{where}: ")
                assert error.path in ((path, other) if reader is _read_joint_gaze else (path,))
                if error.path == path:
                    assert error.line is None or 1 <= error.line <= _line_count(data), (error.line, message)
            else:
                check(result)
        for warning in caught:
            text = str(warning.message)
            assert "\n" not in text and len(text) < len(path) + 400, text

    fuzz()
