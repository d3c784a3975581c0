"""Pupil Labs (Core, Neon) and Project Aria MPS readers: fixtures in the tools' own formats against
the tools' published conversions, round trips, timestamp matching, filtering and errors."""

import math
import os
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from jaxgaze.io.tools import aria, pupil
from jaxgaze.io.tools.common import MissingExtraError
from jaxgaze.io.rays import Sampling, stack_rays
from jaxgaze.io.text import InputFileError
from jaxgaze.poses import camera_poses
from jaxgaze.rays import GazeRays

DATA = Path(__file__).resolve().parents[1] / "data"
S10, C10 = math.sin(math.radians(10)), math.cos(math.radians(10))
AHEAD, LEFT_10, UP_10 = np.array([1.0, 0, 0]), np.array([C10, S10, 0]), np.array([C10, 0, S10])


def rows_of(recording, person):
    """``{frame: (origin, direction, bandwidth)}`` of one person's rays."""
    frames, origins, directions, bandwidth = pupil.person_rays(recording, person, "<test>")
    return {int(f): (o, d, h) for f, o, d, h in zip(frames, origins, directions, bandwidth)}


def assert_same_rays(a, b, atol=1e-6):
    assert a.frame_ids == b.frame_ids and a.persons == b.persons
    for field in ("origins", "directions", "bandwidth", "mask"):
        np.testing.assert_allclose(np.asarray(getattr(a.rays, field), float), np.asarray(getattr(b.rays, field), float),
                                   atol=atol, err_msg=field)


def rotation_z(angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


# ---------------------------------------------------------------------------
# Pupil Core


def test_pupil_known_gaze_filtering_and_frames():
    # gaze_timestamp 1000.000, .008, .033, .066 (confidence 0.3), .070 (2D only), .100 s: steps 8, 25, 33, 4, 30 ms,
    # median 25 ms, so the stream's own rate is 40 Hz; frames round((t − 1000 s) · 40) = 0, 0.32 → 0, 1.32 → 1, 4
    with pytest.warns(UserWarning, match=r"pupil_gaze_positions\.csv: dropped 3 of 6 gaze samples \(kept 3\): 1 of "
                                         r"confidence < 0\.6, 1 without 3D gaze \(2D gaze mapper\?\), 1 sharing a "
                                         r"frame of the 40 fps grid"):
        recording = pupil.read_pupil(DATA / "pupil_gaze_positions.csv", persons=["ann"])
    assert recording.frame_ids == [0, 1, 4]
    assert recording.sampling == Sampling(fps=40.0, start_ns=1000 * 10**9, read=6, kept=3, merged=1, filtered=2)
    rays = rows_of(recording, "ann")
    # OpenCV (x right, y down, z forward) mm → ours (x forward, y left, z up) m: (z, −x, −y) / 1000
    binocular_origin = np.array([-0.010, 0.010, -0.015])  # midpoint of (20, 15, −10) and (−40, 15, −10) mm
    np.testing.assert_allclose(rays[0][0], binocular_origin, atol=1e-9)
    np.testing.assert_allclose(rays[0][1], AHEAD, atol=1e-9)  # the nearest to frame 0's time (0 ms, not 8 ms)
    np.testing.assert_allclose(rays[1][1], LEFT_10, atol=1e-9)  # normal (−sin 10°, 0, cos 10°): to the left
    np.testing.assert_allclose(rays[4][0], [-0.010, 0.040, -0.015], atol=1e-9)  # monocular: eye 1's centre
    np.testing.assert_allclose(rays[4][1], UP_10, atol=1e-9)  # normal (0, −sin 10°, cos 10°): up
    assert all(h == pytest.approx(pupil.DEFAULT_BANDWIDTH_PUPIL) for _, _, h in rays.values())


def test_pupil_round_trip_and_camera_pose(tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        first = pupil.read_pupil(DATA / "pupil_gaze_positions.csv", persons=["ann"])
    pupil.write_pupil(tmp_path / "gaze_positions.csv", first)  # the times of the frames on first's 40 Hz grid
    grid = {"fps": first.sampling.fps, "start_ns": first.sampling.start_ns}
    again = pupil.read_pupil(tmp_path / "gaze_positions.csv", persons=["ann"], **grid)
    assert_same_rays(first, again)
    assert again.sampling == Sampling(read=3, kept=3, **grid)
    # the same file seen through a scene camera turned 90° left and lifted 1.5 m
    pose = camera_poses(rotation_z(math.pi / 2).T, [0.0, 0.0, 1.5], [0])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        placed = pupil.read_pupil(DATA / "pupil_gaze_positions.csv", persons=["ann"], camera=pose)
    np.testing.assert_allclose(rows_of(placed, "ann")[0][1], [0, 1, 0], atol=1e-9)  # ahead of the camera = world +y
    np.testing.assert_allclose(rows_of(placed, "ann")[0][0], [-0.010, -0.010, 1.485], atol=1e-9)
    # one pose per scene frame: each datum is placed by the pose of its world_index (0, 1, 3 for grid frames
    # 0, 1, 4), not of its frame on the time grid
    poses = camera_poses(np.stack([rotation_z(a * math.pi / 2).T for a in range(4)]), np.zeros((4, 3)), [0, 1, 2, 3])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        per_frame = rows_of(pupil.read_pupil(DATA / "pupil_gaze_positions.csv", persons=["ann"], camera=poses), "ann")
    np.testing.assert_allclose(per_frame[0][1], AHEAD, atol=1e-9)
    np.testing.assert_allclose(per_frame[1][1], rotation_z(math.pi / 2) @ LEFT_10, atol=1e-9)
    np.testing.assert_allclose(per_frame[4][1], rotation_z(3 * math.pi / 2) @ UP_10, atol=1e-9)


def test_pupil_several_wearers_need_poses(tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(ValueError, match="camera="):
            pupil.read_pupil([DATA / "pupil_gaze_positions.csv"] * 2, persons=["a", "b"])
        pose = camera_poses(np.eye(3), [0, 0, 0], [0])
        both = pupil.read_pupil([DATA / "pupil_gaze_positions.csv"] * 2, persons=["a", "b"], camera={"a": pose,
                                                                                                      "b": pose})
    assert both.persons[0] == ["a", "b"]


def test_pupil_bad_cell_names_file_and_line(tmp_path):
    text = (DATA / "pupil_gaze_positions.csv").read_text().splitlines()
    text[3] = text[3].replace("0.90", "high", 1)
    (tmp_path / "bad.csv").write_text("\n".join(text) + "\n")
    with pytest.raises(InputFileError, match=r"bad\.csv, line 4: column 'confidence' is not a number"):
        pupil.read_pupil(tmp_path / "bad.csv")
    (tmp_path / "no3d.csv").write_text("world_index,confidence\n0,1.0\n")
    with pytest.raises(InputFileError, match=r"no3d\.csv, line 1: missing columns 'gaze_timestamp', 'gaze_point_3d_x'"):
        pupil.read_pupil(tmp_path / "no3d.csv")


# ---------------------------------------------------------------------------
# Neon


def cart_to_spherical(points_opencv):
    """Pupil Labs' ``cart_to_spherical`` (Neon Player / pl-neon-recording export), degrees."""
    x, y, z = points_opencv[:, 0], points_opencv[:, 1], points_opencv[:, 2]
    radius = np.sqrt(x**2 + y**2 + z**2)
    elevation = np.arccos(y / radius) - np.pi / 2
    azimuth = np.pi / 2 - np.arctan2(z, x)
    return np.rad2deg(azimuth), np.rad2deg(elevation)


def test_neon_known_gaze_and_published_formula():
    # times 0, 5, 33.3, 66.7, 100, 133.3 ms: the stream's own rate is 30 Hz (median step 33.3 ms); the 5 ms
    # sample shares frame 0 with the 0 ms one
    with pytest.warns(UserWarning, match=r"dropped 3 of 6 gaze samples \(kept 3\): 1 not worn \(worn = 0\), 1 in a "
                                         r"blink, 1 sharing a frame of the 30 fps grid"):
        recording = pupil.read_neon(DATA / "neon_gaze.csv")
    assert recording.frame_ids == [0, 1, 2] and recording.persons[0] == ["neon_gaze"]  # the file names the wearer
    s = recording.sampling
    assert s.fps == pytest.approx(30.0, rel=1e-7) and (s.read, s.kept, s.filtered, s.merged, s.dropped) == (6, 3, 2, 1, 3)
    rays = rows_of(recording, "neon_gaze")
    np.testing.assert_allclose(rays[0][1], AHEAD, atol=1e-12)  # the sample nearest frame 0's time
    np.testing.assert_allclose(rays[1][1], LEFT_10, atol=1e-12)  # azimuth −10°: positive azimuth is right
    np.testing.assert_allclose(rays[2][1], UP_10, atol=1e-12)
    assert all(np.allclose(o, 0) for o, _, _ in rays.values())  # from the scene camera
    # against Pupil Labs' own formula, on unprojected OpenCV points (z = 1)
    points = np.array([[0.3, -0.2, 1.0], [-0.5, 0.4, 1.0], [0.0, 0.0, 1.0]])
    azimuth, elevation = cart_to_spherical(points)
    ours = pupil.neon_angles_to_direction(azimuth, elevation)
    expected = (points / np.linalg.norm(points, axis=1, keepdims=True)) @ np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0.0]]).T
    np.testing.assert_allclose(ours, expected, atol=1e-12)
    np.testing.assert_allclose(np.stack(pupil.direction_to_neon_angles(ours), axis=-1),
                               np.stack([azimuth, elevation], axis=-1), atol=1e-9)


def test_neon_round_trip(tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        first = pupil.read_neon(DATA / "neon_gaze.csv", persons=["ben"], start_ns=0)
    pupil.write_neon(tmp_path / "gaze.csv", first)  # on first's grid (its sampling)
    again = pupil.read_neon(tmp_path / "gaze.csv", persons=["ben"], start_ns=0, fps=first.sampling.fps)
    assert_same_rays(first, again, atol=1e-9)
    moved = first._replace(rays=GazeRays(np.asarray(first.rays.origins) + 0.1, first.rays.directions,
                                         first.rays.bandwidth, first.rays.mask))
    with pytest.raises(ValueError, match="no gaze origin"):
        pupil.write_neon(tmp_path / "moved.csv", moved)


def test_neon_bad_angle_names_file_and_line(tmp_path):
    text = (DATA / "neon_gaze.csv").read_text().replace(",0.0,10.0\n", ",0.0,100.0\n")
    (tmp_path / "gaze.csv").write_text(text)
    with pytest.raises(InputFileError, match=r"gaze\.csv, line 5: azimuth 0°, elevation 100° out of range"):
        pupil.read_neon(tmp_path / "gaze.csv")


# ---------------------------------------------------------------------------
# Project Aria MPS


def test_aria_known_gaze_timestamp_matching_and_bandwidth():
    with pytest.warns(UserWarning, match="dropped 1 of 4 gaze samples"):
        recording = aria.read_aria(DATA / "aria_wearer", T_device_cpf=np.eye(4))
    assert recording.frame_ids == [0, 1, 2] and recording.persons[0] == ["aria_wearer"]
    rays = rows_of(recording, "aria_wearer")
    # the device faces world +y (CPF X left → world −x, Y up → +z, Z forward → +y), moving 1 m/s along +x;
    # gaze at 1000, 101000, 201000 µs between poses 2 ms apart: the origin is interpolated halfway
    for frame, x in ((0, 1.001), (1, 1.101), (2, 1.201)):
        np.testing.assert_allclose(rays[frame][0], [x, 2.0, 1.6], atol=1e-9)
    # getUnitVectorFromYawPitch: normalise(tan yaw, tan pitch, 1) in CPF (X left, Y up, Z forward)
    np.testing.assert_allclose(rays[0][1], [0, 1, 0], atol=1e-9)
    np.testing.assert_allclose(rays[1][1], [-S10, C10, 0], atol=1e-9)  # yaw +10°: the wearer's left, world −x
    np.testing.assert_allclose(rays[2][1], [0, C10, S10], atol=1e-9)  # pitch +10°: up
    # intervals [yaw − 0.04, yaw + 0.06], [pitch ± 0.03] read as central 80 %: sd = width / (2 · 1.2816)
    expected_h = math.sqrt(((0.10 / 2.563103131089201) ** 2 + (0.06 / 2.563103131089201) ** 2) / 2)
    assert all(h == pytest.approx(expected_h, rel=1e-6) for _, _, h in rays.values())


def test_aria_vergence_schema_matches_projectaria_tools():
    with pytest.raises(InputFileError, match=r"aria_vergence: no trajectory .* world rays need one; .*frame='cpf'"):
        aria.read_aria(DATA / "aria_vergence")  # no trajectory: world rays cannot be had, and it says so
    with pytest.warns(UserWarning, match="1 of 2 gaze rows have no usable"):
        recording = aria.read_aria(DATA / "aria_vergence", frame="cpf")  # the head frame, asked for: the CPF, our axes
    assert recording.up == "z" and recording.sampling.dropped == 0
    _, direction, h = rows_of(recording, "aria_vergence")[0]
    # TestEyeGaze.cpp: computeDepthAndCombinedGazeDirection(−0.1264797, −0.07706982, −0.26359045) → yaw −0.10183712
    combined = aria.aria_gaze_to_direction(-0.10183712, -0.26359045)
    np.testing.assert_allclose(direction, combined, atol=1e-7)
    # TestEyeGaze.cpp: getEyeGazePointAtDepth(−0.10291049, −0.28885189, 1.17952664) = (−0.11620133, −0.33435595, 1.12516063)
    point_cpf = aria.R_OURS_FROM_CPF.T @ (1.179526637404006 * aria.aria_gaze_to_direction(-0.10291049001666,
                                                                                         -0.288851886987686))
    np.testing.assert_allclose(point_cpf, [-0.116201334110103, -0.334355951558995, 1.12516063], atol=1e-6)
    np.testing.assert_allclose(rows_of(recording, "aria_vergence")[0][0], [0, 0, 0.002], atol=1e-9)  # eyes' midpoint
    sd_yaw = (0.08 / 2 + 0.06 / 2) / 2 / 1.2815515655446004  # mean of the two eyes' sds
    assert h == pytest.approx(math.sqrt((sd_yaw**2 + (0.08 / 2 / 1.2815515655446004) ** 2) / 2), rel=1e-6)
    assert rows_of(recording, "aria_vergence")[1][2] == pytest.approx(aria.DEFAULT_BANDWIDTH_ARIA)


def test_aria_round_trip(tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        first = aria.read_aria(DATA / "aria_wearer", T_device_cpf=np.eye(4), start_ns=0)
    aria.write_aria(tmp_path / "w", first)
    again = aria.read_aria(tmp_path / "w", persons=["aria_wearer"], T_device_cpf=np.eye(4), start_ns=0)
    assert_same_rays(first, again)


def test_aria_several_wearers_share_a_clock_and_a_world(tmp_path):
    """Two devices with clocks days apart and a tilted device-to-CPF calibration: read on the UTC
    clock, both wearers' frames line up and the world rays come back."""
    rng = np.random.default_rng(4)
    T_device_cpf = np.eye(4)
    T_device_cpf[:3, :3] = rotation_z(0.3) @ np.array([[1, 0, 0], [0, math.cos(0.2), -math.sin(0.2)],
                                                       [0, math.sin(0.2), math.cos(0.2)]])
    T_device_cpf[:3, 3] = [0.04, -0.01, 0.02]
    frames = np.arange(5)
    truth = {}
    for k, name in enumerate(["anna", "bert"]):
        origins = rng.normal(size=(5, 3))
        directions = np.c_[rng.normal(size=(5, 2)), np.full(5, 0.3)]
        recording = stack_rays(frames.tolist(), [name] * 5, origins, directions, np.full(5, 0.02), path=name)
        # head poses at half-frame times, the CPF on the eyes and turned toward each ray
        R, _ = aria._upright_poses(origins, directions)
        poses = camera_poses(np.swapaxes(R, 1, 2), origins, frames, timestamps=1.0 + frames / 10.0)
        aria.write_aria(tmp_path / name, recording, poses=poses, T_device_cpf=T_device_cpf, start_ns=10**9,
                        device_offset_ns=(k + 1) * 86_400 * 10**9)
        truth[name] = recording
    both = aria.read_aria([tmp_path / "anna", tmp_path / "bert"], T_device_cpf=T_device_cpf)
    assert both.frame_ids == frames.tolist() and both.persons[0] == ["anna", "bert"]
    for name in truth:
        for frame, (o, d, h) in rows_of(both, name).items():
            o0, d0, h0 = rows_of(truth[name], name)[frame]
            np.testing.assert_allclose(o, o0, atol=1e-6)
            np.testing.assert_allclose(d, d0, atol=1e-6)
            assert h == pytest.approx(h0, rel=1e-5)
    with pytest.warns(UserWarning, match="no T_device_cpf"):  # the identity is a guess, said aloud
        aria.read_aria([tmp_path / "anna", tmp_path / "bert"])


def test_aria_bad_input_names_file_and_line(tmp_path):
    folder = tmp_path / "w"
    folder.mkdir()
    (folder / aria.TRAJECTORY_FILE).write_text((DATA / "aria_wearer" / aria.TRAJECTORY_FILE).read_text())
    text = (DATA / "aria_wearer" / aria.GAZE_FILE).read_text().splitlines()
    (folder / aria.GAZE_FILE).write_text("\n".join(text[:2] + [text[2].replace(",0.0,", ",nan?,", 1)] + text[3:]))
    with pytest.raises(InputFileError, match=r"general_eye_gaze\.csv, line 3: column 'pitch_rads_cpf' is not a number"):
        aria.read_aria(folder, T_device_cpf=np.eye(4))
    (folder / aria.GAZE_FILE).write_text("tracking_timestamp_us,pitch_rads_cpf\n1,0.0\n")
    with pytest.raises(InputFileError, match=r"line 1: missing column 'yaw_rads_cpf'"):
        aria.read_aria(folder, T_device_cpf=np.eye(4))
    (folder / aria.GAZE_FILE).write_text("\n".join(text))
    trajectory = (DATA / "aria_wearer" / aria.TRAJECTORY_FILE).read_text().replace(",0.0,0.7071", ",0.5,0.7071", 1)
    (folder / aria.TRAJECTORY_FILE).write_text(trajectory)
    with pytest.raises(InputFileError, match=r"closed_loop_trajectory\.csv, line 2: quaternion .* is not unit"):
        aria.read_aria(folder, T_device_cpf=np.eye(4))
    with pytest.raises(InputFileError, match=r"no eye gaze CSV \(general_eye_gaze\.csv, .*eyegaze\.csv"):
        aria.read_aria(tmp_path, T_device_cpf=np.eye(4))


# ---------------------------------------------------------------------------
# Optional extras


@pytest.mark.parametrize("read, module, extra", [
    (aria.read_aria_device_cpf, "projectaria_tools.core.data_provider", "aria"),
    (pupil.read_neon_recording, "pupil_labs.neon_recording", "neon"),
])
def test_missing_extra_says_what_to_install(monkeypatch, read, module, extra):
    monkeypatch.setitem(sys.modules, module, None)  # as if not installed
    with pytest.raises(MissingExtraError, match=rf"pip install 'jaxgaze\[{extra}\]'") as info:
        read(os.devnull)
    assert "\n" not in str(info.value)


# ---------------------------------------------------------------------------
# Simulated wearers


def test_simulated_aria_wearers_read_back_with_their_truth(tmp_path):
    """Three people of a hand-made scene written as MPS folders come back as the scene's rays, and the
    truth counts only the foci that two *wearers* look at."""
    import jax

    from jaxgaze.simulate import Scene, write_aria_wearers

    T, rng = 4, np.random.default_rng(7)
    foci = np.broadcast_to(np.array([[2.0, 0.0, 1.2], [0.0, 3.0, 1.0]]), (T, 2, 3))
    focus = np.tile([0, 0, 1, 1], (T, 1))
    origins = rng.normal(scale=0.5, size=(T, 4, 3)) + [0.0, 0.0, 1.6]
    targets = np.take_along_axis(foci, focus[..., None], axis=1)
    directions = targets - origins + rng.normal(scale=0.02, size=(T, 4, 3))
    rays = GazeRays(origins, directions, np.full((T, 4), 0.02), np.ones((T, 4), bool))
    scene = Scene(rays, targets, focus.astype(np.int32), foci, np.ones((T, 2), bool), focus, np.zeros(T, np.int32),
                  "hand-made", 0.02, 0.0, 10.0)
    wearers = write_aria_wearers(jax.random.key(0), scene, tmp_path, people=[0, 1, 2])
    assert wearers.scene.concurrence_valid.tolist() == [[True, False]] * T  # person 3 (focus 1) wears none
    assert wearers.scene.attending[0].tolist() == [0, 0, -1]
    recording = aria.read_aria(wearers.folders, T_device_cpf=wearers.T_device_cpf, fps=wearers.fps)
    assert recording.frame_ids == list(range(T)) and recording.persons[0] == wearers.persons
    np.testing.assert_allclose(np.asarray(recording.rays.origins), origins[:, :3], atol=1e-5)
    np.testing.assert_allclose(np.asarray(recording.rays.directions), np.asarray(wearers.scene.rays.directions),
                               atol=1e-6)


def test_wearer_names_from_the_export_layout():
    # Issue 34 item 6: Pupil Player's <recording>/exports/000/ named every wearer '000'.
    core = ("gaze_positions",)
    assert pupil.wearer_names(["/d/ann/exports/000/gaze_positions.csv", "/d/ben/exports/000/gaze_positions.csv"],
                              None, core) == ["ann", "ben"]
    assert pupil.wearer_names(["/d/ann/neon_player/exports/000/gaze.csv"], None, ("gaze",)) == ["ann"]
    # Pupil Capture names recordings <day>/000: clashing names go to the nearest folders that differ
    assert pupil.wearer_names(["/d/ann/2024_05_01/000/exports/000/gaze_positions.csv",
                               "/d/ben/2024_05_01/000/exports/000/gaze_positions.csv"], None, core) == ["ann", "ben"]
    assert pupil.wearer_names(["/d/2024_05_01/000/exports/000/gaze_positions.csv",
                               "/d/2024_05_01/001/exports/000/gaze_positions.csv"], None, core) == ["000", "001"]
    assert pupil.wearer_names(["/d/ann.csv", "/e/ben.csv"], None, core) == ["ann", "ben"]
    with pytest.raises(ValueError, match="person name 'ann'"):
        pupil.wearer_names(["/d/ann/gaze_positions.csv"] * 2, None, core)
    with pytest.raises(ValueError, match="empty name"):
        pupil.wearer_names(["/d/a.csv", "/d/b.csv"], ["ann", " "], core)
