"""Issue 35, item 5: frame ids are 64-bit integers end to end, never rounded through float64.

Nanosecond timestamps (about 1.7e18, above 2^53) used as frame ids used to come back
rounded (``…033333334`` → ``…033333248``); two consecutive frames then merged, and people
of different frames were reported in mutual gaze.
"""

import csv

import numpy as np

from jaxgaze.io.poses import read_camera_poses_csv, read_pose_csv
from jaxgaze.io.rays import read_rays_csv, write_rays_csv
from jaxgaze.io.text import InputFileError
from tests.cli.helpers import run_main

import pytest

FIRST = 1700000000033333334  # a nanosecond timestamp: 2^60 < FIRST < 2^63, far above 2^53
SECOND = FIRST + 1  # the next nanosecond: the same float64 as FIRST


def _rays_csv(path):
    """Two frames one nanosecond apart. Frame FIRST: three people look at a point (2, 0, 1) and
    "a" looks at the eyes of "x". Frame SECOND: only "x", looking back at where "a" stood. Merged,
    "a" and "x" would be in mutual gaze; kept apart, they never are."""
    target = np.array([2.0, 0.0, 1.0])
    rows = [["frame", "person", "ox", "oy", "oz", "dx", "dy", "dz", "bandwidth"]]
    for name, eye in (("p", [0.0, 0.0, 1.6]), ("q", [2.0, 2.5, 1.6]), ("r", [4.0, -1.0, 1.6])):
        rows.append([FIRST, name, *eye, *(target - eye), 0.03])
    a, x = np.array([0.0, -2.0, 1.6]), np.array([3.0, -3.0, 1.6])
    rows.append([FIRST, "a", *a, *(x - a), 0.03])
    rows.append([SECOND, "x", *x, *(a - x), 0.03])
    with open(path, "w", newline="") as handle:
        csv.writer(handle).writerows(rows)


def _column(path, name):
    with open(path, newline="") as handle:
        return [row[name] for row in csv.DictReader(handle)]


def test_rays_csv_frame_ids_round_trip_exactly(tmp_path):
    _rays_csv(tmp_path / "rays.csv")
    recording = read_rays_csv(tmp_path / "rays.csv")
    assert recording.frame_ids == [FIRST, SECOND]
    assert recording.persons == [["p", "q", "r", "a"], ["x"]]
    write_rays_csv(tmp_path / "again.csv", recording)
    assert read_rays_csv(tmp_path / "again.csv").frame_ids == [FIRST, SECOND]
    assert _column(tmp_path / "again.csv", "frame") == [str(FIRST)] * 4 + [str(SECOND)]


def test_concurrences_cli_keeps_64_bit_frames_apart(tmp_path, capsys):
    _rays_csv(tmp_path / "rays.csv")
    status, _, err = run_main(capsys, ["concurrences", tmp_path / "rays.csv", "--out", tmp_path / "out.csv",
                                       "--members", tmp_path / "members.csv", "-q"])
    assert status == 0, err
    assert _column(tmp_path / "out.csv", "frame") == [str(FIRST)]  # the one concurrence, in its own frame
    assert _column(tmp_path / "members.csv", "frame") == [str(FIRST)] * 4 + [str(SECOND)]
    assert _column(tmp_path / "members.csv", "mutual_gaze") == [""] * 5  # a and x are never in one frame


def test_pose_csvs_keep_64_bit_frames(tmp_path):
    (tmp_path / "poses.csv").write_text(
        "frame,qw,qx,qy,qz,cx,cy,cz\n" f"{SECOND},1,0,0,0,0,0,0\n" f"{FIRST},1,0,0,0,1,0,0\n")
    assert read_pose_csv(tmp_path / "poses.csv").frame_ids.tolist() == [FIRST, SECOND]
    (tmp_path / "cams.csv").write_text(
        "frame,person,qw,qx,qy,qz,cx,cy,cz\n" f"{FIRST},a,1,0,0,0,0,0,0\n" f"{SECOND},a,1,0,0,0,1,0,0\n")
    assert read_camera_poses_csv(tmp_path / "cams.csv").poses["a"].frame_ids.tolist() == [FIRST, SECOND]


@pytest.mark.parametrize("text, ok", [("1700000000033333334", True), ("12.0", True), ("1e3", True),
                                      ("9223372036854775807", True), ("9223372036854775808", False),
                                      ("-9223372036854775808", True), ("12.5", False), ("1e400", False)])
def test_frame_cells_are_parsed_as_exact_integers(tmp_path, text, ok):
    (tmp_path / "rays.csv").write_text(f"frame,person,ox,oy,oz,dx,dy,dz\n{text},a,0,0,1.6,1,0,0\n")
    if ok:
        assert read_rays_csv(tmp_path / "rays.csv").frame_ids == [int(float(text)) if "." in text or "e" in text
                                                                  else int(text)]
    else:
        with pytest.raises(InputFileError, match="line 2: column 'frame'"):
            read_rays_csv(tmp_path / "rays.csv")
