"""``jaxgaze convert --from TOOL``: each tool's fixture becomes the rays its reader gives, written atomically;
bad input exits 2 with one line and no output file."""

from pathlib import Path

import numpy as np
import pytest

from jaxgaze.io import read_gaze_tool, read_rays_csv
from jaxgaze.io.tools.aria import read_aria
from jaxgaze.io.tools.gaze360 import read_gaze360
from jaxgaze.io.tools.l2cs import read_l2cs
from jaxgaze.io.tools.mediapipe import read_mediapipe
from jaxgaze.io.tools.pupil import read_neon, read_pupil
from jaxgaze.io.tools.xgaze import read_xgaze
from jaxgaze.poses import camera_poses
from jaxgaze.io.poses import write_pose_csv
from tests.cli.helpers import assert_failed, run_main

DATA = Path(__file__).resolve().parents[1] / "data"

FIXTURES = {
    "gaze360": (["gaze360_dump.csv"], read_gaze360),
    "l2cs": (["l2cs_dump.csv"], read_l2cs),
    "xgaze": (["xgaze_ptgaze_dump.csv"], read_xgaze),
    "mediapipe": (["mediapipe_face_landmarker.jsonl"], read_mediapipe),
    "pupil": (["pupil_gaze_positions.csv"], read_pupil),
    "neon": (["neon_gaze.csv"], read_neon),
    "aria": (["aria_wearer"], read_aria),
}


def _same(a, b):
    assert a.frame_ids == b.frame_ids
    mask = np.asarray(a.rays.mask)
    np.testing.assert_array_equal(mask, np.asarray(b.rays.mask))
    for field in ("origins", "directions", "bandwidth"):
        np.testing.assert_allclose(np.asarray(getattr(a.rays, field))[mask], np.asarray(getattr(b.rays, field))[mask],
                                   atol=1e-6, err_msg=field)


@pytest.mark.parametrize("name", sorted(FIXTURES))
def test_convert_writes_what_the_tools_reader_reads(tmp_path, capsys, name):
    files, reader = FIXTURES[name]
    paths = [DATA / f for f in files]
    tool = "pupil" if name == "neon" else name
    status, out, err = run_main(capsys, ["convert", "--from", tool, *paths, "--out", tmp_path / "rays.csv"])
    assert status == 0, err
    assert "written to" in err.splitlines()[-1]
    expected = reader(paths[0])
    _same(read_rays_csv(tmp_path / "rays.csv"), expected)
    _same(read_gaze_tool(tool, paths), expected)


def test_convert_openface_several_faces(tmp_path, capsys):
    from jaxgaze.io.tools.openface import read_openface_rays

    path = DATA / "openface_sample.csv"
    status, _, err = run_main(capsys, ["convert", "--from", "openface", path, "--out", tmp_path / "rays.csv"])
    assert status == 0, err
    _same(read_rays_csv(tmp_path / "rays.csv"), read_openface_rays(path))


def test_convert_places_the_camera_with_a_pose_file(tmp_path, capsys):
    R = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # camera +x along world +y
    write_pose_csv(tmp_path / "pose.csv", camera_poses(R[None], [[1.0, 2.0, 1.5]], [0]))
    path = DATA / "gaze360_dump.csv"
    status, _, err = run_main(capsys, ["convert", "--from", "gaze360", path, "--camera-poses", tmp_path / "pose.csv",
                                       "--out", tmp_path / "rays.csv"])
    assert status == 0, err
    placed, local = read_rays_csv(tmp_path / "rays.csv"), read_gaze360(path)
    mask = np.asarray(local.rays.mask)
    np.testing.assert_allclose(np.asarray(placed.rays.directions)[mask], np.asarray(local.rays.directions)[mask] @ R,
                               atol=1e-6)
    np.testing.assert_allclose(np.asarray(placed.rays.origins)[mask],
                               np.asarray(local.rays.origins)[mask] @ R + [1.0, 2.0, 1.5], atol=1e-6)


def test_convert_bad_input_exits_2_with_one_line_and_no_output(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    text = (DATA / "gaze360_dump.csv").read_text().splitlines()
    header, row = text[0], text[1].split(",")
    columns = header.split(",")
    row[columns.index("yaw")] = "nan"
    bad.write_text("\n".join([header, ",".join(row)]) + "\n")
    out = tmp_path / "rays.csv"
    status, stdout, stderr = run_main(capsys, ["convert", "--from", "gaze360", bad, "--out", out])
    assert_failed(status, stdout, stderr, "bad.csv:2")
    assert not out.exists()
    status, stdout, stderr = run_main(capsys, ["convert", "--from", "l2cs", tmp_path / "missing.csv", "--out", out])
    assert_failed(status, stdout, stderr, "missing.csv")
    assert not out.exists()


def test_convert_refuses_mixed_pupil_exports(tmp_path, capsys):
    out = tmp_path / "rays.csv"
    status, stdout, stderr = run_main(capsys, ["convert", "--from", "pupil", DATA / "neon_gaze.csv",
                                               DATA / "pupil_gaze_positions.csv", "--out", out])
    assert_failed(status, stdout, stderr, "mixed", "pupil_gaze_positions.csv")
    assert not out.exists()


def _pupil_exports(root, *recordings):
    """Pupil Player's export layout, ``<recording>/exports/000/gaze_positions.csv``, for each recording path."""
    paths = []
    for recording in recordings:
        folder = root / recording / "exports" / "000"
        folder.mkdir(parents=True)
        (folder / "gaze_positions.csv").write_text((DATA / "pupil_gaze_positions.csv").read_text())
        paths.append(folder / "gaze_positions.csv")
    write_pose_csv(root / "pose.csv", camera_poses(np.eye(3)[None], [[0.0, 0.0, 1.5]], [0]))
    return paths


def test_convert_names_pupil_exports_by_their_recordings(tmp_path, capsys):
    # Issue 34 item 6: two exports in the standard layout were both named '000', and the error
    # pointed to persons=[...], which the command did not have.
    paths = _pupil_exports(tmp_path, "ann", "ben")
    out = tmp_path / "rays.csv"
    poses = ["--camera-poses", tmp_path / "pose.csv", tmp_path / "pose.csv"]
    status, _, err = run_main(capsys, ["convert", "--from", "pupil", *paths, *poses, "--out", out])
    assert status == 0, err
    assert sorted({p for frame in read_rays_csv(out).persons for p in frame}) == ["ann", "ben"]
    status, _, err = run_main(capsys, ["convert", "--from", "pupil", *paths, *poses, "--people", "cat,dan",
                                       "--out", out])
    assert status == 0, err
    assert read_rays_csv(out).persons[0] == ["cat", "dan"]
    # two recordings of one name (Pupil Capture's <day>/000) are named by the folders above them
    same = _pupil_exports(tmp_path / "more", "eve/2024_05_01/000", "fay/2024_05_01/000")
    status, _, err = run_main(capsys, ["convert", "--from", "pupil", *same, *poses, "--out", out])
    assert status == 0, err
    assert read_rays_csv(out).persons[0] == ["eve", "fay"]


def test_convert_pupil_name_and_pose_errors_name_the_options(tmp_path, capsys):
    path, = _pupil_exports(tmp_path, "ann")
    out = tmp_path / "rays.csv"
    status, stdout, stderr = run_main(capsys, ["convert", "--from", "pupil", path, path, "--camera-poses",
                                               tmp_path / "pose.csv", tmp_path / "pose.csv", "--out", out])
    assert_failed(status, stdout, stderr, "'ann'", "--people A,B,...")
    assert "persons=" not in stderr
    status, stdout, stderr = run_main(capsys, ["convert", "--from", "pupil", path, path, "--people", "a,b",
                                               "--out", out])
    assert_failed(status, stdout, stderr, "--camera-poses")
    assert "camera=" not in stderr and "CameraPoses" not in stderr
    status, stdout, stderr = run_main(capsys, ["convert", "--from", "pupil", path, "--people", "a,b", "--out", out])
    assert_failed(status, stdout, stderr, "--people has 2 names for 1 files")
    status, stdout, stderr = run_main(capsys, ["convert", "--from", "gaze360", DATA / "gaze360_dump.csv",
                                               "--people", "a", "--out", out])
    assert_failed(status, stdout, stderr, "--people", "gaze360")
    assert not out.exists()
