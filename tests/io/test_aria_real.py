"""Project Aria recordings as people download them (tests/data/real/aria, PROVENANCE.md): the Aria Digital
Twin test sequence, the Gen1 and Gen2 MPS samples, read from their folders by read_aria, read_gaze_tool and
``jaxgaze convert``, with every sample counted, the ADT's points of regard on the objects the wearer looks at
and its y-up world turned z-up."""

import csv
import json
import math
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jaxgaze.io import read_gaze_tool, read_rays_csv
from jaxgaze.io.tools import aria
from jaxgaze.io.text import InputFileError
from tests.cli.helpers import run_main

REAL = Path(__file__).resolve().parents[1] / "data" / "real" / "aria"
ADT = REAL / "gen1" / "aria_digital_twin_test_data"
GEN1 = REAL / "gen1" / "mps_sample"
GEN2 = REAL / "gen2" / "mps_sample"
#: projectaria_tools' default T_device_cpf of the ADT device: its video.vrs calibration names a DVT-L.
T_ADT = aria.aria_cad_device_cpf("DVT-L")


def rows(path):
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def quiet_read(*args, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return aria.read_aria(*args, **kwargs)


def angle(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    cos = np.sum(a * b, -1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.arccos(np.clip(cos, -1, 1))


# ---------------------------------------------------------------------------
# The Aria Digital Twin sequence


def test_adt_calibration_is_a_dvt_l_and_the_cad_transform_is_projectaria_tools():
    assert b'"DeviceClassInfo":{"BuildVersion":"DVT-L"' in (ADT / "video.vrs").read_bytes()
    # ConfigData.cpp, DVT-L camera-slam-left: t = (0.071351, 0.002372, 0.008454), Y, Z axes; T_device_cpf = its inverse
    T_cpf_device = np.linalg.inv(T_ADT)
    np.testing.assert_allclose(T_cpf_device[:3, 3], [0.071351, 0.002372, 0.008454], atol=1e-12)
    np.testing.assert_allclose(T_cpf_device[:3, 1], np.array([0.793353, 0, -0.608761]) / 0.99999969, atol=2e-6)
    np.testing.assert_allclose(T_cpf_device[:3, 2], [0.607927, -0.052336, 0.792266], atol=2e-6)
    assert np.linalg.det(T_ADT[:3, :3]) == pytest.approx(1.0)


def test_adt_sequence_read_from_its_folder_every_sample_kept():
    recording = quiet_read(ADT, T_device_cpf=T_ADT)
    # eyegaze.csv: 6 rows 33,328 µs apart; the first is 3 µs before aria_trajectory.csv's first pose (POSE_EDGE_S)
    assert recording.frame_ids == [0, 1, 2, 3, 4, 5] and recording.persons == [["aria_digital_twin_test_data"]] * 6
    s = recording.sampling
    assert (s.read, s.kept, s.outside, s.merged, s.dropped) == (6, 6, 0, 0, 0)
    assert s.fps == pytest.approx(1e6 / 33328) and s.start_ns == 87551170907000
    assert recording.up == "y"  # gravity_y_world = −9.81
    same = read_gaze_tool("aria", ADT, T_device_cpf=T_ADT)  # the registry passes the reader's options on
    np.testing.assert_array_equal(np.asarray(same.rays.directions), np.asarray(recording.rays.directions))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        aria.read_aria(ADT, T_device_cpf=T_ADT)
    assert not caught  # nothing dropped, nothing guessed: nothing to say


def _adt_boxes(time_ns):
    """``{name: (R_world_object, t_world_object, [[min, max]] × 3)}`` of the ADT objects at ``time_ns``
    (static objects: timestamp −1; dynamic: the nearest pose), in the ADT world (y up)."""
    names = {uid: item["instance_name"] for uid, item in json.loads((ADT / "instances.json").read_text()).items()}
    boxes = {r["object_uid"]: np.array([[float(r[f"p_local_obj_{a}min[m]"]), float(r[f"p_local_obj_{a}max[m]"])]
                                        for a in "xyz"]) for r in rows(ADT / "3d_bounding_box.csv")}
    poses = {}
    for r in rows(ADT / "scene_objects.csv"):
        t = int(r["timestamp[ns]"])
        best = poses.get(r["object_uid"])
        if best is None or (t != -1 and abs(t - time_ns) < abs(best[0] - time_ns)):
            q = [float(r[f"q_wo_{a}"]) for a in "xyzw"]
            poses[r["object_uid"]] = (t, Rotation.from_quat(q).as_matrix(),
                                      np.array([float(r[f"t_wo_{a}[m]"]) for a in "xyz"]))
    return {names[uid]: (R, t, boxes[uid]) for uid, (_, R, t) in poses.items() if uid in boxes}


def _box_distance(point, R, t, box):
    """Signed distance (m) of a point from the surface of an oriented box: negative inside."""
    local = R.T @ (point - t)
    outside = np.maximum(np.maximum(box[:, 0] - local, local - box[:, 1]), 0)
    if outside.any():
        return float(np.linalg.norm(outside))
    return -float(min(np.min(local - box[:, 0]), np.min(box[:, 1] - local)))


def test_adt_points_of_regard_lie_on_the_fork_and_the_bowl():
    """ADT's depth_m is the ground-truth gaze depth from the CPF (getEyeGazePointAtDepth): eye origin +
    depth · direction, in the world of aria_trajectory.csv through T_device_cpf, lands within 2 cm of the
    surface of the 3D box of the object looked at: the wooden fork, then the wooden bowl."""
    recording = quiet_read(ADT, T_device_cpf=T_ADT)
    depth = recording.depth[:, 0]
    assert math.isnan(depth[0])  # depth_m 0: not available
    np.testing.assert_allclose(depth[1:], [float(r["depth_m"]) for r in rows(ADT / "eyegaze.csv")][1:], atol=1e-12)
    assert np.all(recording.depth_sd[1:, 0] == 0.0)  # the digital twin's ground truth
    points = recording.points_of_regard()[:, 0] @ aria.up_rotation("y")  # back to the ADT world (y up)
    looked_at = []
    for k, time_ns in enumerate(1000 * np.array([int(r["tracking_timestamp_us"]) for r in rows(ADT / "eyegaze.csv")])):
        if k == 0:
            continue
        boxes = _adt_boxes(time_ns)
        distances = {name: _box_distance(points[k], *box) for name, box in boxes.items() if name != "ApartmentEnv"}
        name = min(distances, key=lambda n: abs(distances[n]))
        assert abs(distances[name]) < 0.02, (k, name, distances[name])
        looked_at.append(name)
    assert looked_at == ["WoodenFork"] + ["WoodenBowl"] * 4
    # the device-to-CPF transform matters: with the identity, the points miss the boxes by more than 2 cm
    wrong = quiet_read(ADT).points_of_regard()[:, 0] @ aria.up_rotation("y")
    boxes = _adt_boxes(1000 * 87551237563)
    assert min(abs(_box_distance(wrong[2], *box)) for name, box in boxes.items() if name != "ApartmentEnv") > 0.02


def test_adt_world_is_turned_z_up():
    """aria_trajectory.csv's gravity is (0, −9.81, 0): the reader turns y up onto +z, so gravity ends along −z,
    the eyes stand 1.5–1.6 m above the floor, and the fork and bowl (on a table) lie below the eyes."""
    recording = quiet_read(ADT, T_device_cpf=T_ADT)
    R = aria.up_rotation(recording.up)
    gravity = np.array([[float(r[f"gravity_{a}_world"]) for a in "xyz"] for r in rows(ADT / "aria_trajectory.csv")])
    np.testing.assert_allclose(gravity @ R.T, np.tile([0, 0, -9.81], (6, 1)), atol=1e-12)
    trajectory_y = [float(r["ty_world_device"]) for r in rows(ADT / "aria_trajectory.csv")]
    eyes = recording.world_origins()[:, 0]
    np.testing.assert_allclose(eyes[:, 2], trajectory_y, atol=0.06)  # device height ≈ eye height (CPF ≈ 5 cm off)
    assert np.all((eyes[:, 2] > 1.45) & (eyes[:, 2] < 1.65))
    points = recording.points_of_regard()[1:, 0]
    assert np.all(points[:, 2] < eyes[1:, 2] - 0.3) and np.all(points[:, 2] > 0.7)  # a table top, not the floor
    # the floor is z = 0 of the turned world: the bottoms of the furniture standing on it are within 4 cm of it
    boxes = _adt_boxes(0)
    for name in ("Fridge", "KitchIsland", "ExtendableTable", "RedArmChair", "BlackArmChair", "WhiteDressingTable"):
        R_o, t, b = boxes[name]
        corners = np.array([t + R_o @ [x, y, z] for x in b[0] for y in b[1] for z in b[2]]) @ R.T
        assert abs(corners[:, 2].min()) < 0.04, name
    explicit = quiet_read(ADT, T_device_cpf=T_ADT, up="y")
    np.testing.assert_array_equal(np.asarray(explicit.rays.origins), np.asarray(recording.rays.origins))
    as_read = quiet_read(ADT, T_device_cpf=T_ADT, up="y").world_origins() @ R  # the turn is a rotation: undo it
    with pytest.raises(InputFileError, match=r"aria_trajectory\.csv: up='z', but .*gravity .* its y axis .*up='y'"):
        aria.read_aria(ADT, T_device_cpf=T_ADT, up="z")
    assert np.all(np.abs(as_read[:, 0, 1] - np.array(trajectory_y)) < 0.06)


def test_adt_mps_folder_uses_the_sequence_trajectory(tmp_path):
    """The ADT ``mps/`` folder has MPS's gaze (same angles, no depth) and no trajectory: the sequence's
    aria_trajectory.csv above it serves, and the rays equal those of eyegaze.csv."""
    mps = quiet_read(ADT / "mps", T_device_cpf=T_ADT)
    adt = quiet_read(ADT, T_device_cpf=T_ADT)
    assert mps.frame_ids == adt.frame_ids and mps.sampling.kept == 6 and mps.up == "y"
    assert np.all(np.isnan(mps.depth))  # MPS general_eye_gaze.csv: depth_m empty
    np.testing.assert_allclose(angle(np.asarray(mps.rays.directions), np.asarray(adt.rays.directions)), 0, atol=1e-6)
    lone = tmp_path / "eye_gaze"  # the same file outside its ADT sequence: no world to put it in
    lone.mkdir()
    (lone / "general_eye_gaze.csv").write_bytes((ADT / "mps" / "eye_gaze" / "general_eye_gaze.csv").read_bytes())
    with pytest.raises(InputFileError, match=r"eye_gaze: no trajectory for this wearer .*world rays need one"):
        aria.read_aria(lone, T_device_cpf=T_ADT)
    cpf = aria.read_aria(ADT / "mps", frame="cpf")  # the head frame, asked for: no trajectory, no transform, no warning
    assert cpf.up == "z" and cpf.sampling.kept == 6


# ---------------------------------------------------------------------------
# The Gen1 MPS sample


def _outside(gaze_csv, trajectory_csv):
    """Gaze samples more than POSE_EDGE_S outside the trajectory's span (known from the files alone)."""
    t = np.array([int(r["tracking_timestamp_us"]) for r in rows(trajectory_csv)])
    g = np.array([int(r["tracking_timestamp_us"]) for r in rows(gaze_csv)])
    return len(g), int(np.sum((g < t[0] - 1000) | (g > t[-1] + 1000)))


@pytest.mark.parametrize("gaze", ["eye_gaze/eyegaze.csv", "eye_gaze/generalized_eye_gaze.csv",
                                  "eye_gaze_vergence/generalized_gaze.csv"])
def test_gen1_sample_every_schema_finds_trajectory_and_counts(gaze):
    read, outside = _outside(GEN1 / gaze, GEN1 / "trajectory" / aria.TRAJECTORY_FILE)
    assert (read, outside) == (123, 9)  # 7 gaze rows before the trajectory, 2 after it
    with pytest.warns(UserWarning, match=r"dropped 9 of 123 gaze samples \(kept 114\): 9 without a pose .* 0 sharing"):
        recording = aria.read_aria(GEN1 / gaze, T_device_cpf=np.eye(4))
    s = recording.sampling
    assert (s.read, s.kept, s.outside, s.merged, s.fps) == (123, 114, 9, 0, 10.0)
    assert recording.frame_ids == list(range(114)) and recording.up == "z"  # gravity (0, 0, −9.81)
    depth = recording.depth[:, 0]
    if "vergence" in gaze:  # depth_m of the vergence schema, from the CPF origin (eyes at ±31.5 mm: the same)
        table = rows(GEN1 / gaze)[7:-2]
        expected = [float(r["depth_m"]) for r in table]
        np.testing.assert_allclose(depth, expected, rtol=1e-9)
        # σ_d = √2 h d² / b: the vergence angle's error through the eyes' baseline b, from the file's eye origins
        baseline = [math.dist(*([float(r[f"t{a}_{eye}_eye_cpf"]) for a in "xyz"] for eye in ("left", "right")))
                    for r in table]
        h = np.asarray(recording.rays.bandwidth)[:, 0]
        np.testing.assert_allclose(recording.depth_sd[:, 0], math.sqrt(2) * h * np.square(expected) / baseline,
                                   rtol=1e-5)
        assert 0.05 < np.median(recording.depth_sd[:, 0] / depth) < 1.0  # metres of doubt at metres of depth
    else:
        assert np.all(np.isnan(depth)) and np.all(np.isnan(recording.depth_sd))  # an empty depth_m


def test_gen1_legacy_and_generalized_schemas_give_the_same_rays():
    legacy = quiet_read(GEN1 / "eye_gaze" / "eyegaze.csv", T_device_cpf=T_ADT)
    general = quiet_read(GEN1 / "eye_gaze" / "generalized_eye_gaze.csv", T_device_cpf=T_ADT)
    np.testing.assert_allclose(np.asarray(legacy.rays.directions), np.asarray(general.rays.directions), atol=1e-6)


def test_gen1_sample_fps_merges_and_says_how_many():
    with pytest.warns(UserWarning, match=r"dropped 66 of 123 gaze samples \(kept 57\): 9 without .* 57 sharing a frame "
                                         r"of the 5 fps grid"):
        recording = aria.read_aria(GEN1 / "eye_gaze" / "eyegaze.csv", T_device_cpf=np.eye(4), fps=5)
    s = recording.sampling
    assert (s.read, s.kept, s.outside, s.merged, s.dropped) == (123, 57, 9, 57, 66)
    assert len(recording.frame_ids) == 57


def test_gen1_sample_folder_as_downloaded_reads_the_newest_schema_and_says_so():
    """The Gen1 sample holds one model in two schemas (generalized_eye_gaze.csv, legacy eyegaze.csv): the folder as
    downloaded is read, from the newer file, with a warning naming both; its rays are that file's."""
    with pytest.warns(UserWarning, match=r"mps_sample: several general eye gaze CSVs \(eye_gaze/generalized_eye_gaze"
                                         r"\.csv \(general\), eye_gaze/eyegaze\.csv \(general\)\): reading "
                                         r"eye_gaze/generalized_eye_gaze\.csv"):
        folder = aria.read_aria(GEN1, T_device_cpf=np.eye(4))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        file = aria.read_aria(GEN1 / "eye_gaze" / "generalized_eye_gaze.csv", T_device_cpf=np.eye(4))
    assert folder.sampling == file.sampling and folder.persons == file.persons == [["mps_sample"]] * 114
    np.testing.assert_array_equal(np.asarray(folder.rays.directions), np.asarray(file.rays.directions))


# ---------------------------------------------------------------------------
# The Gen2 MPS sample


def test_gen2_general_and_personalized():
    with pytest.raises(InputFileError, match=r"general_eye_gaze\.csv \(general\), eye_gaze/personalized_eye_gaze\.csv "
                                             r"\(personalized\); pass eye_gaze='general' or 'personalized'"):
        aria.read_aria(GEN2, frame="cpf")
    with pytest.raises(InputFileError, match="no trajectory for this wearer.*frame='cpf'"):
        aria.read_aria(GEN2, eye_gaze="general")  # no trajectory in the sample: no world, and it says so
    general = aria.read_aria(GEN2, eye_gaze="general", frame="cpf")
    personal = aria.read_aria(GEN2 / "eye_gaze" / "personalized_eye_gaze.csv", frame="cpf")
    for recording in (general, personal):  # 5 rows 11,111 µs apart: 90 Hz, each its own frame
        s = recording.sampling
        assert recording.frame_ids == [0, 1, 2, 3, 4] and (s.read, s.kept, s.dropped) == (5, 5, 0)
        assert s.fps == pytest.approx(90.0, abs=0.01)
    # the per-wearer bias: from the files' yaw/pitch (getUnitVectorFromYawPitch), 6.8° mostly in pitch
    def cpf(path):
        r = rows(path)
        return aria.aria_gaze_to_direction([float(x["yaw_rads_cpf"]) for x in r], [float(x["pitch_rads_cpf"]) for x in r])
    expected = angle(cpf(GEN2 / "eye_gaze" / "general_eye_gaze.csv"), cpf(GEN2 / "eye_gaze" / "personalized_eye_gaze.csv"))
    got = angle(np.asarray(general.rays.directions)[:, 0], np.asarray(personal.rays.directions)[:, 0])
    np.testing.assert_allclose(got, expected, atol=1e-6)
    assert np.all((np.degrees(got) > 6.0) & (np.degrees(got) < 7.5))


# ---------------------------------------------------------------------------
# The command line


def test_convert_adt_folder_writes_the_readers_rays_with_depth(tmp_path, capsys):
    status, _, err = run_main(capsys, ["convert", "--from", "aria", ADT, "--out", tmp_path / "rays.csv"])
    assert status == 0, err
    assert "kept 6 of 6 samples at 30.0048 fps), the input's y axis turned up to +z" in err.splitlines()[-1]
    written = read_rays_csv(tmp_path / "rays.csv")
    expected = quiet_read(ADT)  # no --device-calibration: both take the identity, with a warning
    assert written.frame_ids == expected.frame_ids
    np.testing.assert_allclose(np.asarray(written.rays.origins), np.asarray(expected.rays.origins), atol=1e-6)
    np.testing.assert_allclose(np.asarray(written.rays.directions), np.asarray(expected.rays.directions), atol=1e-6)
    np.testing.assert_allclose(written.depth, expected.depth, atol=1e-6)  # NaN where depth_m was 0
    assert math.isnan(written.depth[0, 0])


def test_convert_gen2_options(tmp_path, capsys):
    status, _, err = run_main(capsys, ["convert", "--from", "aria", GEN2, "--out", tmp_path / "rays.csv"])
    assert status == 2 and "--eye-gaze general or personalized, or the path of the one to read as IN" in err
    status, _, err = run_main(capsys, ["convert", "--from", "aria", GEN2, "--eye-gaze", "personalized",
                                       "--out", tmp_path / "rays.csv"])
    assert status == 2 and "or --frame cpf for rays in the head frame" in err and not (tmp_path / "rays.csv").exists()
    status, _, err = run_main(capsys, ["convert", "--from", "aria", GEN2, "--eye-gaze", "personalized", "--frame",
                                       "cpf", "--out", tmp_path / "rays.csv"])
    assert status == 0, err
    assert len(read_rays_csv(tmp_path / "rays.csv").frame_ids) == 5
    status, _, err = run_main(capsys, ["convert", "--from", "aria", ADT, "--up", "z", "--out", tmp_path / "r.csv"])
    assert status == 2 and "(pass --up y)" in err
