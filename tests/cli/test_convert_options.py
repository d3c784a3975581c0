"""Every reader option on the command line (``jaxgaze convert``) and in ``read_gaze_tool``: each flag gives what
the tool's reader gives with that option (and differs from the default, so the flag is not ignored), and a flag
the tool does not take is refused with one line."""

import json
import math
import warnings
from pathlib import Path

import numpy as np
import pytest

from jaxgaze.io import read_gaze_tool, read_rays_csv
from jaxgaze.io.text import InputFileError
from jaxgaze.io.tools import aria
from jaxgaze.io.tools.l2cs import DEFAULT_BANDWIDTH_L2CS, read_l2cs
from jaxgaze.io.tools.mediapipe import read_mediapipe
from tests.cli.helpers import assert_failed, run_main

DATA = Path(__file__).resolve().parents[1] / "data"
ADT = DATA / "real" / "aria" / "gen1" / "aria_digital_twin_test_data"
T_DVT_L = aria.aria_cad_device_cpf("DVT-L")


def convert(capsys, tmp_path, *argv):
    out = tmp_path / "rays.csv"
    status, _, err = run_main(capsys, ["convert", *map(str, argv), "--out", out])
    assert status == 0, err
    return read_rays_csv(out), err


def quiet(read, *args, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read(*args, **kwargs)


def directions(recording):
    return np.asarray(recording.rays.directions, np.float64)[np.asarray(recording.rays.mask)]


def angles_deg(a, b):
    return np.degrees(np.arccos(np.clip(np.sum(a * b, -1) / np.linalg.norm(a, axis=-1) / np.linalg.norm(b, axis=-1),
                                        -1, 1)))


def test_device_calibration_text_gives_the_readers_world_rays(tmp_path, capsys):
    """Must show: convert --from aria ADT --device-calibration 4x4.txt --up y = read_aria(T_device_cpf, up='y')."""
    matrix = tmp_path / "T_device_cpf.txt"
    matrix.write_text("# T_device_cpf of a DVT-L\n" + "\n".join(" ".join(repr(float(v)) for v in row) for row in T_DVT_L))
    written, err = convert(capsys, tmp_path, "--from", "aria", ADT, "--device-calibration", matrix, "--up", "y")
    assert "no T_device_cpf" not in err  # the calibration was used: no identity guess announced
    expected = quiet(aria.read_aria, ADT, T_device_cpf=T_DVT_L, up="y")
    assert written.frame_ids == expected.frame_ids and written.persons == expected.persons
    np.testing.assert_allclose(written.world_origins(), expected.world_origins(), atol=1e-6)
    np.testing.assert_allclose(np.asarray(written.rays.directions), np.asarray(expected.rays.directions), atol=1e-6)
    np.testing.assert_allclose(written.depth, expected.depth, atol=1e-6)
    # and it matters: the identity (the default) is 20° and more off on this device
    identity, err = convert(capsys, tmp_path, "--from", "aria", ADT, "--up", "y")
    assert "no T_device_cpf" in err and angles_deg(directions(identity), directions(written)).min() > 20


def test_device_calibration_json_and_csv_forms_and_bad_files(tmp_path, capsys):
    forms = {"rows.json": json.dumps(T_DVT_L.tolist()), "named.json": json.dumps({"T_device_cpf": T_DVT_L.tolist()}),
             "comma.csv": "\n".join(",".join(map(repr, row)) for row in T_DVT_L.tolist())}
    for name, text in forms.items():
        (tmp_path / name).write_text(text)
        np.testing.assert_array_equal(aria.read_device_calibration(tmp_path / name), T_DVT_L, err_msg=name)
    (tmp_path / "three.txt").write_text("1 0 0 0\n0 1 0 0\n0 0 1 0\n")
    (tmp_path / "scaled.txt").write_text("2 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n")
    for name, words in (("three.txt", ("three.txt", "no 4×4 matrix", "4 rows of 4 numbers", ".vrs", "JSON")),
                        ("scaled.txt", ("scaled.txt", "not a rigid transform"))):
        with pytest.raises(InputFileError, match=words[1]):
            aria.read_device_calibration(tmp_path / name)
        status, stdout, stderr = run_main(capsys, ["convert", "--from", "aria", ADT, "--device-calibration",
                                                   tmp_path / name, "--out", tmp_path / "out.csv"])
        assert_failed(status, stdout, stderr, *words)
        assert not (tmp_path / "out.csv").exists()


def test_device_calibration_from_the_real_vrs(tmp_path, capsys):
    pytest.importorskip("projectaria_tools.core.data_provider")  # the optional 'aria' extra
    np.testing.assert_allclose(aria.read_device_calibration(ADT / "video.vrs"), T_DVT_L, atol=1e-9)
    written, _ = convert(capsys, tmp_path, "--from", "aria", ADT, "--device-calibration", ADT / "video.vrs",
                         "--up", "y")
    expected = quiet(aria.read_aria, ADT, T_device_cpf=T_DVT_L, up="y")
    np.testing.assert_allclose(np.asarray(written.rays.directions), np.asarray(expected.rays.directions), atol=1e-6)


def test_fov_and_order_give_the_readers_rays(tmp_path, capsys):
    path = DATA / "mediapipe_face_landmarker.jsonl"
    written, _ = convert(capsys, tmp_path, "--from", "mediapipe", path, "--fov", 55)
    expected, default = read_mediapipe(path, vertical_fov_deg=55.0), read_mediapipe(path)
    np.testing.assert_allclose(written.world_origins(), expected.world_origins(), atol=1e-6)
    # a narrower field of view puts the faces farther: depth scales by tan(31.5°) / tan(27.5°)
    depth_ratio = np.asarray(written.rays.origins)[..., 0] / np.asarray(default.rays.origins)[..., 0]
    mask = np.asarray(written.rays.mask)
    np.testing.assert_allclose(depth_ratio[mask], math.tan(math.radians(31.5)) / math.tan(math.radians(27.5)),
                               rtol=1e-5)
    path = DATA / "l2cs_dump.csv"
    written, _ = convert(capsys, tmp_path, "--from", "l2cs", path, "--order", "yaw,pitch")
    swapped = read_l2cs(path, order=("yaw", "pitch"))
    np.testing.assert_allclose(directions(written), directions(swapped), atol=1e-6)
    assert angles_deg(directions(written), directions(read_l2cs(path))).max() > 1


def test_min_confidence_counts_what_it_drops(tmp_path, capsys):
    # confidences 0.95, 0.80, 0.90, 0.30, 0.99 (2D only), 0.85: at 0.9, 0.80, 0.30 and 0.85 go, and the 2D row
    written, err = convert(capsys, tmp_path, "--from", "pupil", DATA / "pupil_gaze_positions.csv",
                           "--min-confidence", 0.9)
    assert "dropped 4 of 6 gaze samples (kept 2): 3 of confidence < 0.9, 1 without 3D gaze" in err
    assert "kept 2 of 6 samples at 40 fps" in err.splitlines()[-1] and written.frame_ids == [0, 1]
    with warnings.catch_warnings(record=True):
        warnings.simplefilter("always")
        recording = read_gaze_tool("pupil", [DATA / "pupil_gaze_positions.csv"], min_confidence=0.9)
    assert (recording.sampling.read, recording.sampling.filtered, recording.sampling.kept) == (6, 4, 2)
    status, stdout, stderr = run_main(capsys, ["convert", "--from", "pupil", DATA / "neon_gaze.csv",
                                               "--min-confidence", 0.9, "--out", tmp_path / "n.csv"])
    assert_failed(status, stdout, stderr, "--min-confidence filters Pupil Core", "no confidence column")


@pytest.mark.parametrize("tool, path", [("xgaze", "xgaze_ptgaze_dump.csv"), ("gaze360", "gaze360_dump.csv"),
                                        ("pupil", "neon_gaze.csv"), ("aria", "aria_wearer")])
def test_bandwidth_sets_every_rays_cone_width(tmp_path, capsys, tool, path):
    written, _ = convert(capsys, tmp_path, "--from", tool, DATA / path, "--bandwidth", 0.03)
    mask = np.asarray(written.rays.mask)
    np.testing.assert_allclose(np.asarray(written.rays.bandwidth)[mask], 0.03, rtol=1e-6)
    default = quiet(read_gaze_tool, tool, [DATA / path])
    assert not np.allclose(np.asarray(default.rays.bandwidth)[mask], 0.03)  # the tool's own width differs
    with pytest.raises(ValueError, match="bandwidth"):
        quiet(read_gaze_tool, tool, [DATA / path], bandwidth=1.5)  # degrees? refused


@pytest.mark.parametrize("tool, path, flag, words", [
    ("l2cs", "l2cs_dump.csv", ["--fov", "55"], ("--fov is an option of mediapipe, not of l2cs",)),
    ("pupil", "pupil_gaze_positions.csv", ["--order", "yaw,pitch"], ("--order is an option of l2cs, not of pupil",)),
    ("xgaze", "xgaze_ptgaze_dump.csv", ["--min-confidence", "0.5"],
     ("--min-confidence is an option of pupil and openface, not of xgaze",)),
    ("pupil", "pupil_gaze_positions.csv", ["--device-calibration", "x.txt"],
     ("--device-calibration is an option of aria, not of pupil",)),
    ("mediapipe", "mediapipe_face_landmarker.jsonl", ["--up", "y"], ("--up is an option of aria, not of mediapipe",)),
])
def test_a_flag_the_tool_does_not_take_is_refused(tmp_path, capsys, tool, path, flag, words):
    status, stdout, stderr = run_main(capsys, ["convert", "--from", tool, DATA / path, *flag,
                                               "--out", tmp_path / "rays.csv"])
    assert_failed(status, stdout, stderr, *words)
    assert not (tmp_path / "rays.csv").exists()


def test_read_gaze_tool_refuses_an_option_the_reader_does_not_take():
    with pytest.raises(ValueError, match=r"vertical_fov_deg= is not an option of l2cs's reader \(its options: "
                                         r"order=, bandwidth=\)"):
        read_gaze_tool("l2cs", [DATA / "l2cs_dump.csv"], vertical_fov_deg=55.0)


def test_a_tool_without_uncertainty_says_its_rays_have_the_documented_default(tmp_path, capsys):
    """L2CS reports no uncertainty: the summary names the default cone width every ray got (l2cs's
    DEFAULT_BANDWIDTH_L2CS), and says nothing of it once --bandwidth is given; gaze360's own var says nothing."""
    out = tmp_path / "rays.csv"
    status, _, err = run_main(capsys, ["convert", "--from", "l2cs", str(DATA / "l2cs_dump.csv"), "--out", str(out)])
    assert status == 0 and (f"bandwidth: l2cs reports no uncertainty; every ray has its documented default "
                            f"{DEFAULT_BANDWIDTH_L2CS:.4f} rad (--bandwidth sets another)") in err
    np.testing.assert_allclose(np.asarray(read_rays_csv(out).rays.bandwidth)[0, 0], DEFAULT_BANDWIDTH_L2CS, rtol=1e-6)
    for argv in (["--from", "l2cs", DATA / "l2cs_dump.csv", "--bandwidth", "0.05"],
                 ["--from", "gaze360", DATA / "gaze360_dump.csv"]):
        status, _, err = run_main(capsys, ["convert", *map(str, argv), "--out", str(out)])
        assert status == 0 and "reports no uncertainty" not in err
