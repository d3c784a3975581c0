"""The one CSV table reader and the file formats of the command line: rays, concurrences,
camera poses of several wearers, calibrations and the attend table (round trips, and errors
that name the file and the line)."""

import csv
import json
import os
from types import SimpleNamespace

import numpy as np
import pytest

from jaxgaze.calibration.cone_fit import ConeCalibration
from jaxgaze.results import succeeded
from jaxgaze.io.attend import ATTEND_COLUMNS, write_attend_csv
from jaxgaze.io.calibration import (CALIBRATION_KEYS, WearerCalibration, calibrated_rays, read_calibration_json,
                                    write_calibration_json)
from jaxgaze.io.concurrences import OUTPUT_COLUMNS, write_concurrences_csv
from jaxgaze.io.models import ModelFileError, metadata_image_size, metadata_number
from jaxgaze.io.poses import (CAMERA_POSE_COLUMNS, PoseFileError, read_camera_poses_csv, read_poses,
                              write_camera_poses_csv)
from jaxgaze.io.speech import read_segments_csv
from jaxgaze.io.rays import CSV_COLUMNS, read_rays_csv, stack_rays, write_rays_csv
from jaxgaze.io.text import InputFileError, read_csv_table
from jaxgaze.poses import CameraPoses
from jaxgaze.results import RESULTS


def _write(path, text):
    path.write_text(text)
    return path


def _rotation(angle):
    """R_camera_from_world: a turn of ``angle`` about +z."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


# ---------------------------------------------------------------------------
# read_csv_table


def test_csv_table_rows_cells_and_numbers(tmp_path):
    path = _write(tmp_path / "t.csv", "# note\n\n Frame , X,extra\n1,2.5,a\n\n2, 3 ,b\n")
    table = read_csv_table(path, ("frame", "x"), ("y",), comments=True)
    assert table.header_line == 3 and table.names == ("frame", "x", "extra")
    assert table.has("x") and not table.has("y")
    assert [row.line for row in table.rows] == [4, 6]
    assert [(row.integer("frame"), row.number("x")) for row in table.rows] == [(1, 2.5), (2, 3.0)]
    assert table.rows[1].cell("x") == "3"


@pytest.mark.parametrize(
    "text, kwargs, message, line",
    [
        ("", {}, "empty file: expected a header row with columns a, b", 1),
        ("\n \n\n", {}, "empty file", 1),
        ("\n \n\n", {"empty_at_end": True, "empty": "nothing here"}, "nothing here", 3),
        ("# only\n", {"comments": True}, "empty file", 1),
        ("a\n1\n", {}, "missing column 'b' in the header (need a, b)", 1),
        ("a,b,a\n1,2,3\n", {}, "duplicate column 'a'", 1),
        ("a,b\n", {}, "no data rows after the header", 1),
        ("a,b\n1,2\n1\n", {}, "expected 2 fields as in the header, got 1", 3),
        ('a,b\n1,"2"x\n', {}, "malformed CSV", 2),
        ("A,b\n1,2\n", {"lower": False}, "missing column 'a'", 1),
    ],
)
def test_csv_table_file_errors_name_path_and_line(tmp_path, text, kwargs, message, line):
    path = _write(tmp_path / "t.csv", text)
    with pytest.raises(InputFileError) as info:
        read_csv_table(path, ("a", "b"), **kwargs)
    assert str(info.value) == f"{path}, line {line}: {info.value.what}"
    assert message in info.value.what
    assert (info.value.path, info.value.line) == (str(path), line)


@pytest.mark.parametrize(
    "cells, call, message",
    [
        ("1, ", lambda r: r.number("b"), "empty cell in column 'b'"),
        ("1,x", lambda r: r.number("b"), "column 'b' is not a number: 'x'"),
        ("1,inf", lambda r: r.number("b"), "column 'b' is not finite: 'inf'"),
        ("1.5,2", lambda r: r.integer("a"), "column 'a' must be an integer, got '1.5'"),
        ("1e19,2", lambda r: r.integer("a"), "column 'a' is out of range for a 64-bit integer: '1e19'"),
    ],
)
def test_csv_row_errors_name_column_path_and_line(tmp_path, cells, call, message):
    path = _write(tmp_path / "t.csv", f"a,b\n0,0\n{cells}\n")
    row = read_csv_table(path, ("a", "b")).rows[1]
    with pytest.raises(InputFileError, match=message) as info:
        call(row)
    assert str(info.value).startswith(f"{path}, line 3: ")


def test_csv_row_number_may_allow_nan_and_inf(tmp_path):
    row = read_csv_table(_write(tmp_path / "t.csv", "a,b\nnan,-inf\n"), ("a", "b")).rows[0]
    assert np.isnan(row.number("a", finite=False)) and row.number("b", finite=False) == -np.inf


def test_csv_table_drops_a_last_row_cut_off_mid_write(tmp_path):
    """Only a last line with too few fields AND no newline at the end is a cut-off recording."""
    path = _write(tmp_path / "t.csv", "a,b,c\n1,2,3\n\n4,5,6\n7,8")
    with pytest.warns(UserWarning) as record:
        table = read_csv_table(path, ("a", "b"))
    assert [str(w.message) for w in record] == [
        f"{path}: dropped the last row: line 5 is cut off (2 of 3 fields and no newline at the end of the file); "
        "read the 2 complete row(s) before it"]
    assert [row.line for row in table.rows] == [2, 4]
    assert [row.cells for row in table.rows] == [["1", "2", "3"], ["4", "5", "6"]]


@pytest.mark.parametrize(
    "text, message, line",
    [
        ("a,b,c\n1,2,3\n7,8\n", "expected 3 fields as in the header, got 2", 3),  # ends in a newline
        ("a,b,c\n1,2\n7,8,9", "expected 3 fields as in the header, got 2", 2),  # short in the middle
        ("a,b,c\n1,2,3\n7,8,9,10", "expected 3 fields as in the header, got 4", 3),  # too long is not cut off
        ("a,b,c\n7,8", "no data rows after the header: line 2 is cut off (2 of 3 fields and no newline at the end "
         "of the file)", 1),
    ],
)
def test_csv_table_short_rows_that_are_not_cut_off_stay_errors(tmp_path, text, message, line):
    path = _write(tmp_path / "t.csv", text)
    with pytest.raises(InputFileError) as info:
        read_csv_table(path, ("a", "b"))
    assert str(info.value) == f"{path}, line {line}: {message}"


def test_every_csv_reader_drops_a_cut_off_last_row(tmp_path):
    """The speech segments CSV (one of the readers built on read_csv_table) keeps the complete rows."""
    path = _write(tmp_path / "speech.csv", "start,end,speaker\n0.0,1.0,A\n1.5,2.0,B\n2.5,")
    with pytest.warns(UserWarning, match=r"line 4 is cut off \(2 of 3 fields"):
        segments = read_segments_csv(path)
    np.testing.assert_array_equal(segments.start, [0.0, 1.5])
    assert segments.speaker == ("A", "B")


def test_csv_table_missing_file_uses_the_error_type_and_name(tmp_path):
    with pytest.raises(PoseFileError, match="pose file not found"):
        read_csv_table(tmp_path / "nope.csv", ("a",), error=PoseFileError, what="pose")


# ---------------------------------------------------------------------------
# Rays and concurrences


def _recording():
    return stack_rays([3, 1, 3, 1, 3], ["a", "b", "b", "a", "c"],
                      [[0, 0, 1], [1, 0, 1], [0, 1, 1], [2, 2, 1.5], [1, 1, 1]],
                      [[1, 0, 0], [0, 2, 0], [0, 0, 1], [1, 1, 0], [-1, 0, 0]],
                      [0.05, 0.04, 0.03, 0.02, 0.01], path="here.csv")


def test_stack_rays_pads_frames_in_row_order():
    rec = _recording()
    assert rec.frame_ids == [1, 3] and rec.persons == [["b", "a"], ["a", "b", "c"]]
    assert rec.rays.batch_shape == (2,) and rec.rays.num_rays == 3
    np.testing.assert_array_equal(np.asarray(rec.rays.mask), [[True, True, False], [True, True, True]])
    np.testing.assert_allclose(np.asarray(rec.rays.directions)[0, 0], [0, 1, 0])  # normalised
    np.testing.assert_allclose(np.asarray(rec.rays.bandwidth)[1], [0.05, 0.03, 0.01])


def test_rays_csv_round_trip(tmp_path):
    rec = _recording()
    path = tmp_path / "rays.csv"
    assert write_rays_csv(path, rec) == 5
    again = read_rays_csv(path, default_bandwidth=9.0)
    assert again.frame_ids == rec.frame_ids and again.persons == rec.persons
    for field in ("origins", "directions", "bandwidth", "mask"):
        np.testing.assert_array_equal(np.asarray(getattr(again.rays, field)), np.asarray(getattr(rec.rays, field)))
    assert os.listdir(tmp_path) == ["rays.csv"]


def test_rays_csv_depth_round_trip_and_points_of_regard(tmp_path):
    """A ``depth`` (metres to the point of regard along the ray) is padded with NaN by stack_rays, written as a
    column (empty where unknown) and read back; a recording without depths writes no such column."""
    rec = stack_rays([3, 1, 3, 1, 3], ["a", "b", "b", "a", "c"], np.arange(15.0).reshape(5, 3),
                     [[2, 0, 0], [0, 1, 0], [0, 0, 1], [1, 0, 0], [0, 3, 0]], 0.05, path="<t>",
                     depth=[1.5, np.nan, 0.25, 2.0, 0.0])
    np.testing.assert_array_equal(rec.depth, [[np.nan, 2.0, np.nan], [1.5, 0.25, 0.0]])  # row order; padding NaN
    points = rec.points_of_regard()
    np.testing.assert_allclose(points[1, 0], [0 + 1.5, 1, 2])  # origin (0, 1, 2) + 1.5 · (1, 0, 0)
    np.testing.assert_allclose(points[0, 1], [9 + 2.0, 10, 11])
    assert np.isnan(points[0, 0]).all() and np.isnan(points[0, 2]).all()
    path = tmp_path / "rays.csv"
    write_rays_csv(path, rec)
    lines = path.read_text().splitlines()
    assert lines[0].endswith(",bandwidth,depth") and lines[1].endswith(",") and lines[2].endswith(",0.05,2.0")
    np.testing.assert_array_equal(read_rays_csv(path).depth, rec.depth)
    write_rays_csv(path, _recording())
    assert "depth" not in path.read_text().splitlines()[0] and read_rays_csv(path).depth is None
    header = ",".join(CSV_COLUMNS) + ",depth\n"
    _write(path, header + "1,a,0,0,1,1,0,0,-0.5\n")
    with pytest.raises(InputFileError, match=r"line 2: depth must be zero or more"):
        read_rays_csv(path)
    _write(path, header + "1,a,0,0,1,1,0,0,far\n")
    with pytest.raises(InputFileError, match=r"line 2: column 'depth' is not a number"):
        read_rays_csv(path)


def test_rays_csv_depth_sd_round_trip_and_errors(tmp_path):
    """``depth_sd`` (the point of regard's sd along the ray) travels beside ``depth``: padded with NaN, written
    empty where unknown, read back; without a depth it is refused, and it must be metres ≥ 0."""
    rec = stack_rays([1, 1, 2], ["a", "b", "a"], np.zeros((3, 3)), [[1, 0, 0]] * 3, 0.05, path="<t>",
                     depth=[1.0, 2.0, np.nan], depth_sd=[0.07, 0.0, np.nan])
    np.testing.assert_array_equal(rec.depth_sd, [[0.07, 0.0], [np.nan, np.nan]])
    path = tmp_path / "rays.csv"
    write_rays_csv(path, rec)
    lines = path.read_text().splitlines()
    assert lines[0].endswith(",bandwidth,depth,depth_sd") and lines[1].endswith(",1.0,0.07") and lines[3].endswith(",,")
    back = read_rays_csv(path)
    np.testing.assert_array_equal(back.depth_sd, rec.depth_sd)
    np.testing.assert_array_equal(back.depth, rec.depth)
    header = ",".join(CSV_COLUMNS)
    _write(path, header + ",depth_sd\n1,a,0,0,1,1,0,0,0.1\n")
    with pytest.raises(InputFileError, match=r"a depth_sd column without a depth column"):
        read_rays_csv(path)
    _write(path, header + ",depth,depth_sd\n1,a,0,0,1,1,0,0,1.0,-0.1\n")
    with pytest.raises(InputFileError, match=r"line 2: depth_sd must be zero or more"):
        read_rays_csv(path)


def test_rays_csv_default_bandwidth_and_errors(tmp_path):
    header = ",".join(CSV_COLUMNS) + "\n"
    path = _write(tmp_path / "r.csv", header + "1,a,0,0,1,1,0,0\n")
    np.testing.assert_allclose(np.asarray(read_rays_csv(path, 0.07).rays.bandwidth), [[0.07]])
    _write(path, header + "1,a,0,0,1,1,0,0\n\n1,a,0,0,1,0,1,0\n")
    with pytest.raises(InputFileError, match=r"duplicate ray for frame 1, person 'a' \(first on line 2\)") as info:
        read_rays_csv(path)
    assert (info.value.path, info.value.line) == (str(path), 4)


def test_rays_writer_is_atomic(tmp_path, monkeypatch):
    path = _write(tmp_path / "rays.csv", "precious\n")

    def full(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", full)
    with pytest.raises(OSError) as info:
        write_rays_csv(path, _recording())
    assert info.value.filename == str(path)
    monkeypatch.undo()
    assert path.read_text() == "precious\n" and os.listdir(tmp_path) == ["rays.csv"]


def test_concurrences_csv_writes_the_valid_modes(tmp_path):
    cov = np.zeros((2, 2, 3, 3), np.float32)
    cov[..., [0, 1, 2], [0, 1, 2]] = [1e-3, 2e-3, 3e-3]
    cov[1, 1, 0, 1] = cov[1, 1, 1, 0] = 5e-4
    result = SimpleNamespace(valid=np.array([[True, False], [False, True]]),
                             locations=np.arange(12, dtype=np.float32).reshape(2, 2, 3) / 10, covariances=cov,
                             degrees_of_freedom=np.array([[4.0, 0], [0, 6.0]]),
                             num_rays=np.array([[2, 0], [0, 3]]), field_values=np.array([[0.5, 0], [0, 0.25]]))
    tracks = SimpleNamespace(track_ids=np.array([[0, -1], [-1, 3]]))
    path = tmp_path / "c.csv"
    assert write_concurrences_csv(path, [7, 9], result, tracks) == 2
    with open(path, newline="") as handle:
        rows = list(csv.reader(handle))
    assert tuple(rows[0]) == OUTPUT_COLUMNS
    assert rows[1] == ["7", "0", "0", "0.0", "0.1", "0.2", "0.001", "0.002", "0.003", "0.0", "0.0", "0.0", "4.0", "2",
                       "0.5"]
    assert rows[2][:3] == ["9", "1", "3"] and [float(x) for x in rows[2][3:6]] == pytest.approx([0.9, 1.0, 1.1])
    assert float(rows[2][9]) == pytest.approx(5e-4)  # cov_xy


# ---------------------------------------------------------------------------
# Camera poses of several wearers, calibrations


def _wearer_poses():
    return {
        "ann": CameraPoses(np.stack([_rotation(0.1), _rotation(-0.2)]), np.array([[0, 0, 1.6], [0.1, 0, 1.6]]),
                           np.array([4, 5])),
        "ben": CameraPoses(_rotation(2.0)[None], np.array([[2.0, 1.0, 1.7]]), np.array([5])),
    }


def test_camera_poses_csv_round_trip(tmp_path):
    path = tmp_path / "poses.csv"
    write_camera_poses_csv(path, _wearer_poses())
    table = read_camera_poses_csv(path)
    assert list(table.poses) == ["ann", "ben"] and table.path == str(path)
    assert {p: table.lines[p].tolist() for p in table.lines} == {"ann": [2, 3], "ben": [4]}
    for person, truth in _wearer_poses().items():
        np.testing.assert_array_equal(table.poses[person].frame_ids, truth.frame_ids)
        np.testing.assert_allclose(table.poses[person].R_camera_from_world, truth.R_camera_from_world, atol=1e-12)
        np.testing.assert_allclose(table.poses[person].centers, truth.centers, atol=1e-12)


@pytest.mark.parametrize(
    "row, message",
    [
        ("4,ann,1,0,0,0,0,0,0", r"duplicate pose for frame 4, person 'ann' \(first on line 2\)"),
        ("6,ann,2,0,0,0,0,0,0", "is not unit"),
        ("6, ,1,0,0,0,0,0,0", "empty cell in column 'person'"),
    ],
)
def test_camera_poses_csv_errors(tmp_path, row, message):
    path = _write(tmp_path / "p.csv", ",".join(CAMERA_POSE_COLUMNS) + "\n4,ann,1,0,0,0,0,0,0\n" + row + "\n")
    with pytest.raises(PoseFileError, match=message) as info:
        read_camera_poses_csv(path)
    assert str(info.value).startswith(f"{path}, line 3: ")


def test_read_poses_by_extension(tmp_path):
    with pytest.raises(PoseFileError, match=r"unknown pose file type '\.dat'") as info:
        read_poses(tmp_path / "poses.dat")
    assert info.value.line is None


def _cone(eye, direction, h):
    return ConeCalibration(np.asarray(eye, float), np.asarray(direction, float), np.float64(h), np.float64(0.02),
                           np.float64(0.1), np.array([True, True, False]), RESULTS.successful)


def test_calibration_json_round_trip(tmp_path):
    path = tmp_path / "ann.json"
    cone = _cone([0.06, 0.0, -0.08], [3.0, 0.0, 4.0], 0.03)
    record = write_calibration_json(path, "ann", cone)
    assert set(CALIBRATION_KEYS) <= set(record) and record["num_points"] == 3 and record["num_inliers"] == 2
    assert json.loads(path.read_text()) == record
    read = read_calibration_json(path)
    assert isinstance(read, WearerCalibration) and read.wearer == "ann" and read.path == str(path)
    np.testing.assert_allclose(read.cone.eye_center, cone.eye_center)
    np.testing.assert_allclose(read.cone.direction, [0.6, 0.0, 0.8])
    assert float(read.cone.bandwidth) == 0.03 and float(read.cone.alpha) == 0.02 and bool(succeeded(read.cone))


def test_calibration_json_errors_name_the_line(tmp_path):
    path = _write(tmp_path / "c.json", '{\n "wearer": "ann",\n "frame": "camera",\n "eye_center": [0, 0, 0],\n'
                                       ' "direction": [1, 0, 0],\n "bandwidth": -1\n}\n')
    with pytest.raises(InputFileError, match="'bandwidth' must be a positive number") as info:
        read_calibration_json(path)
    assert info.value.line == 6


def test_calibrated_rays_are_the_cones_rays(tmp_path):
    path = tmp_path / "poses.csv"
    write_camera_poses_csv(path, _wearer_poses())
    cones = {"ann": _cone([0.06, 0, -0.08], [1, 0.05, 0.03], 0.03), "ben": _cone([0.04, 0.02, -0.1], [1, 0, 0], 0.04)}
    calibrations = [WearerCalibration(w, c, f"{w}.json") for w, c in cones.items()]
    rec = calibrated_rays(read_camera_poses_csv(path), calibrations)
    assert rec.frame_ids == [4, 5] and rec.persons == [["ann"], ["ann", "ben"]]
    for t, frame in enumerate(rec.frame_ids):
        for n, person in enumerate(rec.persons[t]):
            poses = _wearer_poses()[person]
            k = int(np.flatnonzero(poses.frame_ids == frame)[0])
            truth = cones[person].to_gaze_rays(poses.R_world_from_camera[k], poses.centers[k])
            np.testing.assert_allclose(np.asarray(rec.rays.origins)[t, n], np.asarray(truth.origins)[0], atol=1e-6)
            np.testing.assert_allclose(np.asarray(rec.rays.directions)[t, n], np.asarray(truth.directions)[0],
                                       atol=1e-6)
    with pytest.raises(InputFileError, match="no calibration for person 'ben'") as info:
        calibrated_rays(read_camera_poses_csv(path), calibrations[:1])
    assert (info.value.path, info.value.line) == (str(path), 4)
    with pytest.raises(InputFileError, match="two calibrations for wearer 'ann'") as info:
        calibrated_rays(read_camera_poses_csv(path), calibrations + [calibrations[0]._replace(path="again.json")])
    assert info.value.path == "again.json"


# ---------------------------------------------------------------------------
# attend table, model metadata


def test_attend_csv_has_empty_cells_for_missing_values(tmp_path):
    nan = np.nan
    windows = SimpleNamespace(
        start_frame=np.array([0, 4]), valid=np.array([True, False]), pose=np.array([[0.1, 0.2, 0.3], [nan] * 3]),
        direction=np.array([1.5, nan]), depth_y=np.array([120.25, nan]), head_xy=np.array([[10.0, 20.0], [nan, nan]]),
        target_xy=np.array([[30.0, 40.0], [nan, nan]]), attended_xy=np.array([[31.0, 41.0], [nan, nan]]),
        region_box=np.array([[25.0, 35.0, 37.0, 47.0], [nan] * 4]), probability=np.array([0.75, 0.0]),
        reason=["", "tracker lost"])
    path = tmp_path / "a.csv"
    assert write_attend_csv(path, windows, fps=10.0) == 2
    with open(path, newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert tuple(rows[0]) == ATTEND_COLUMNS
    assert rows[0]["start_time"] == "0.0" and rows[1]["start_time"] == "0.4" and rows[0]["valid"] == "1"
    assert rows[0]["depth_y"] == "120.25" and rows[1]["pitch"] == "" and rows[1]["reason"] == "tracker lost"


def test_model_metadata_checks(tmp_path):
    meta = {"focal_px": 300, "window": 4.0, "image_size": [320, 240], "bad": -1, "size": [1]}
    assert metadata_number(meta, "focal_px", "m.json") == 300.0
    assert metadata_number(meta, "window", "m.json", integer=True) == 4
    assert metadata_number(meta, "fps", "m.json") is None
    assert metadata_image_size(meta, "m.json") == (320, 240)
    with pytest.raises(ModelFileError, match="'bad' must be a positive number") as info:
        metadata_number(meta, "bad", "m.json")
    assert str(info.value).startswith("m.json: ")
    with pytest.raises(ModelFileError, match="image_size"):
        metadata_image_size({"image_size": [1]}, "m.json")
