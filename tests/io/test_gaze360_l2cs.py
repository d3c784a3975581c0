"""Gaze360 and L2CS-Net adapters: known gazes from each tool's published conversion, round trips
of the dump CSVs, camera placement, bad input, and honest Gaze360 bandwidths on simulated outputs."""

import math
from pathlib import Path

import jax
import numpy as np
import pytest

from jaxgaze.io.tools.gaze360 import (
    GAZE360_COLUMNS,
    MAX_BANDWIDTH_GAZE360,
    R_90,
    Z_90,
    bandwidth_from_gaze360_var,
    gaze360_to_rays,
    gaze360_var_from_bandwidth,
    read_gaze360,
    write_gaze360,
)
from jaxgaze.io.tools.l2cs import DEFAULT_BANDWIDTH_L2CS, l2cs_to_rays, read_l2cs, write_l2cs
from jaxgaze.io.rays import stack_rays
from jaxgaze.io.text import InputFileError
from jaxgaze.poses import camera_poses
from jaxgaze.simulate.gaze_tools import simulate_gaze360_outputs

DATA = Path(__file__).parent.parent / "data"
GAZE360 = DATA / "gaze360_dump.csv"
L2CS = DATA / "l2cs_dump.csv"
TEN = math.radians(10.0)

# Both fixtures, eyes 2 m in front of the camera (OpenCV (0, 0, 2) = ours (2, 0, 0)) unless said:
#   frame 1: straight into the camera       -> (−1, 0, 0)
#   frame 2: 10° to the person's left       -> (−cos 10°, −sin 10°, 0)  (the camera's right, our −y)
#   frame 3: 10° up                         -> (−cos 10°, 0, sin 10°)
#   frame 3, 2nd person at OpenCV (−1, 0, 2) = ours (2, 1, 0), into the camera -> −(2, 1, 0)/√5
# Gaze360 (yaw, pitch): frame 2 yaw = −10°, frame 3 pitch = +10°. L2CS-Net's container holds the
# horizontal angle in `pitch` (issue #32): frame 2 pitch = −10°, frame 3 yaw = +10°.
EXPECTED = {
    (1, 0): [-1.0, 0.0, 0.0],
    (2, 0): [-math.cos(TEN), -math.sin(TEN), 0.0],
    (3, 0): [-math.cos(TEN), 0.0, math.sin(TEN)],
    (3, 1): list(-np.array([2.0, 1.0, 0.0]) / math.sqrt(5.0)),
}
EYES = {(1, 0): [2, 0, 0], (2, 0): [2, 0, 0], (3, 0): [2, 0, 0], (3, 1): [2, 1, 0]}


def _rows(recording):
    """{(frame, slot): (origin, direction, bandwidth)} of the real rays."""
    rays = recording.rays
    out = {}
    for t, frame in enumerate(recording.frame_ids):
        for n in np.flatnonzero(np.asarray(rays.mask[t])):
            out[(frame, int(n))] = (np.asarray(rays.origins[t, n]), np.asarray(rays.directions[t, n]),
                                    float(rays.bandwidth[t, n]))
    return out


def _same_recordings(a, b):
    assert a.frame_ids == b.frame_ids and a.persons == b.persons
    for name in ("origins", "directions", "bandwidth", "mask"):
        np.testing.assert_allclose(np.asarray(getattr(a.rays, name)), np.asarray(getattr(b.rays, name)), atol=1e-6)


# ---------------------------------------------------------------------------
# Known gazes, from the tools' own conversions


@pytest.mark.parametrize("read", [read_gaze360, read_l2cs], ids=["gaze360", "l2cs"])
def test_fixture_known_gazes_come_out_as_world_directions(read):
    recording = read(GAZE360 if read is read_gaze360 else L2CS)
    assert recording.frame_ids == [1, 2, 3]
    rows = _rows(recording)
    assert set(rows) == set(EXPECTED)
    for key, direction in EXPECTED.items():
        origin, got, _ = rows[key]
        np.testing.assert_allclose(got, direction, atol=1e-6)
        np.testing.assert_allclose(origin, EYES[key], atol=1e-6)


def test_gaze360_bandwidth_from_var_in_the_fixture():
    recording = read_gaze360(GAZE360)
    assert recording.persons == [["alice"], ["alice"], ["alice", "bob"]]
    got = [h for _, _, h in _rows(recording).values()]
    expected = [math.tan(R_90 * var / Z_90) / R_90 for var in (0.1, 0.2, 0.05, 0.3)]
    np.testing.assert_allclose(got, expected, rtol=1e-6)
    assert abs(Z_90 - 1.2815515655) < 1e-9 and abs(R_90 - 2.1459660263) < 1e-9  # N(0,1) 0.9 quantile; √(2 ln 10)


def _spherical2cartesial(yaw, pitch):
    """Gaze360's code/run.py, as published: eye frame x left, y up, z away from the camera."""
    return np.stack([np.cos(pitch) * np.sin(yaw), np.sin(pitch), -np.cos(pitch) * np.cos(yaw)], axis=-1)


def test_gaze360_matches_spherical2cartesial_on_the_optical_axis():
    rng = np.random.default_rng(0)
    yaw, pitch = rng.uniform(-math.pi, math.pi, 50), rng.uniform(-1.5, 1.5, 50)
    recording = gaze360_to_rays(yaw, pitch, np.full(50, 0.1), np.tile([3.0, 0.0, 0.0], (50, 1)))
    g = _spherical2cartesial(yaw, pitch)
    # on the axis, E = (our y, our z, our x): x left, y up, z away from the camera
    np.testing.assert_allclose(np.asarray(recording.rays.directions)[:, 0], g[:, [2, 0, 1]], atol=1e-6)


def test_gaze360_zero_angles_look_into_the_camera_wherever_the_person_stands():
    rng = np.random.default_rng(1)
    eyes = rng.uniform([0.5, -3.0, -1.0], [5.0, 3.0, 1.0], (40, 3))
    recording = gaze360_to_rays(np.zeros(40), np.zeros(40), np.full(40, 0.1), eyes)
    np.testing.assert_allclose(np.asarray(recording.rays.directions)[:, 0],
                               -eyes / np.linalg.norm(eyes, axis=-1, keepdims=True), atol=1e-6)
    up = gaze360_to_rays(np.zeros(40), np.full(40, 0.3), np.full(40, 0.1), eyes)
    assert (np.asarray(up.rays.directions)[:, 0, 2] > np.asarray(recording.rays.directions)[:, 0, 2]).all()


def test_l2cs_matches_its_draw_gaze_and_gazeto3d():
    """L2CS-Net's render draws draw_gaze(…, (pitch, yaw)): dx = −sin(p0) cos(p1), dy = −sin(p1) in the
    image (x right, y down = our −y, −z); gazeto3d([pitch, yaw]) is in axes right, down, away."""
    rng = np.random.default_rng(2)
    pitch, yaw = rng.uniform(-1.2, 1.2, 50), rng.uniform(-1.2, 1.2, 50)
    d = np.asarray(l2cs_to_rays(pitch, yaw, np.tile([2.0, 0.0, 0.0], (50, 1))).rays.directions)[:, 0]
    np.testing.assert_allclose(-d[:, 1], -np.sin(pitch) * np.cos(yaw), atol=1e-6)
    np.testing.assert_allclose(-d[:, 2], -np.sin(yaw), atol=1e-6)
    gazeto3d = np.stack([-np.cos(yaw) * np.sin(pitch), -np.sin(yaw), -np.cos(yaw) * np.cos(pitch)], axis=-1)
    np.testing.assert_allclose(d, np.stack([gazeto3d[:, 2], -gazeto3d[:, 0], -gazeto3d[:, 1]], axis=-1), atol=1e-6)


def test_l2cs_order_names_the_horizontal_field():
    eyes = np.tile([2.0, 0.0, 0.0], (2, 1))
    default = l2cs_to_rays([-TEN, 0.0], [0.0, TEN], eyes)
    swapped = l2cs_to_rays([0.0, TEN], [-TEN, 0.0], eyes, order=("yaw", "pitch"))
    _same_recordings(default, swapped)
    np.testing.assert_allclose(np.asarray(default.rays.directions)[0, 0], EXPECTED[(2, 0)], atol=1e-6)
    with pytest.raises(ValueError, match="order"):
        l2cs_to_rays([0.0], [0.0], eyes[:1], order=("yaw", "roll"))


def test_l2cs_default_bandwidth_is_its_published_gaze360_error():
    assert DEFAULT_BANDWIDTH_L2CS == pytest.approx(math.radians(10.41) / math.sqrt(math.pi / 2))
    np.testing.assert_allclose([h for _, _, h in _rows(read_l2cs(L2CS)).values()], DEFAULT_BANDWIDTH_L2CS, rtol=1e-6)
    np.testing.assert_allclose([h for _, _, h in _rows(read_l2cs(L2CS, bandwidth=0.05)).values()], 0.05, rtol=1e-6)


# ---------------------------------------------------------------------------
# Round trips and camera placement


def _camera():
    """One pose: centre (1, 2, 1.5), optical axis along world +y (our camera x → world y, y → −x)."""
    R_world_from_camera = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    return camera_poses(R_world_from_camera.T[None], [[1.0, 2.0, 1.5]], [0])


@pytest.mark.parametrize("camera", [None, _camera()], ids=["camera-frame", "placed"])
@pytest.mark.parametrize("tool", ["gaze360", "l2cs", "l2cs-swapped"])
def test_round_trip_tool_file_rays_tool_file(tmp_path, tool, camera):
    kwargs = {"order": ("yaw", "pitch")} if tool == "l2cs-swapped" else {}
    read, write, fixture = (read_gaze360, write_gaze360, GAZE360) if tool == "gaze360" else (read_l2cs, write_l2cs, L2CS)
    first = read(fixture, camera=camera, **kwargs)
    assert write(tmp_path / "out.csv", first, camera=camera, **kwargs) == 4
    second = read(tmp_path / "out.csv", camera=camera, **kwargs)
    _same_recordings(first, second)
    if tool == "gaze360":  # the written numbers are the fixture's
        written = np.genfromtxt(tmp_path / "out.csv", delimiter=",", names=True, dtype=None, encoding="utf-8")
        original = np.genfromtxt(fixture, delimiter=",", names=True, dtype=None, encoding="utf-8")
        for column in GAZE360_COLUMNS[2:]:
            np.testing.assert_allclose(written[column], original[column], atol=1e-6)


def test_camera_places_the_rays_in_the_world():
    rows = _rows(read_gaze360(GAZE360, camera=_camera()))
    origin, direction, _ = rows[(1, 0)]
    np.testing.assert_allclose(origin, [1.0, 4.0, 1.5], atol=1e-6)  # 2 m along world +y from (1, 2, 1.5)
    np.testing.assert_allclose(direction, [0.0, -1.0, 0.0], atol=1e-6)  # back into the camera
    _, left, _ = rows[(2, 0)]
    np.testing.assert_allclose(left, [math.sin(TEN), -math.cos(TEN), 0.0], atol=1e-6)  # our −y is world +x


def test_writer_refuses_eyes_behind_the_camera(tmp_path):
    behind = stack_rays([0], ["a"], [[-1.0, 0.0, 0.0]], [[1.0, 0.0, 0.0]], [0.1], path="<arrays>")
    with pytest.raises(ValueError, match="person 'a' in frame 0 are not in front of the camera"):
        write_gaze360(tmp_path / "out.csv", behind)
    assert not (tmp_path / "out.csv").exists()


# ---------------------------------------------------------------------------
# Bad input and clipping

HEADER = ",".join(GAZE360_COLUMNS)


@pytest.mark.parametrize("text, line, message", [
    (f"{HEADER}\n1,a,nan,0,0.1,0,0,2\n", 2, "not finite"),
    ("frame,person_identity,yaw,pitch,person_eyes3d_x,person_eyes3d_y,person_eyes3d_z\n1,a,0,0,0,0,2\n", 1,
     "missing column 'var'"),
    (f"{HEADER}\n1,a,0,0,0.1,0,0,2\n2,a,0,0,0,0,0,2\n", 3, "var must be positive"),
    (f"{HEADER}\n1,a,0,0,-0.2,0,0,2\n", 2, "var must be positive"),
    (f"{HEADER}\n1,a,0,0,12,0,0,2\n", 2, "beyond π"),
    (f"{HEADER}\n1,a,30,0,0.1,0,0,2\n", 2, "degrees"),
    (f"{HEADER}\n1,a,0,0,0.1,0,0,-2\n", 2, "not in front of the camera"),
    (f"{HEADER}\n1,a,0,0,0.1,0,0,2\n1,a,0,0,0.1,0,0,3\n", 3, "duplicate ray for frame 1, person 'a'"),
    (f"{HEADER}\n1,a,zero,0,0.1,0,0,2\n", 2, "not a number"),
])
def test_gaze360_bad_input_names_file_and_line(tmp_path, text, line, message):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(InputFileError, match=message) as caught:
        read_gaze360(path)
    assert caught.value.path == str(path) and caught.value.line == line


@pytest.mark.parametrize("text, line, message", [
    ("frame,face,pitch,yaw,eye_x,eye_y,eye_z\n1,0,0,inf,0,0,2\n", 2, "not finite"),
    ("frame,face,pitch,eye_x,eye_y,eye_z\n1,0,0,0,0,2\n", 1, "missing column 'yaw'"),
    ("frame,face,pitch,yaw,eye_x,eye_y,eye_z\n1,0,0,0,0,0,2\n2,0,-45,0,0,0,2\n", 3, "degrees"),
])
def test_l2cs_bad_input_names_file_and_line(tmp_path, text, line, message):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(InputFileError, match=message) as caught:
        read_l2cs(path)
    assert caught.value.path == str(path) and caught.value.line == line


def test_several_files_are_one_recording_and_duplicates_name_both(tmp_path):
    lines = GAZE360.read_text().splitlines()
    (tmp_path / "a.csv").write_text("\n".join(lines[:3]) + "\n")
    (tmp_path / "b.csv").write_text("\n".join([lines[0], *lines[3:]]) + "\n")
    _same_recordings(read_gaze360([tmp_path / "a.csv", tmp_path / "b.csv"]), read_gaze360(GAZE360))
    (tmp_path / "c.csv").write_text("\n".join([lines[0], lines[1]]) + "\n")
    with pytest.raises(InputFileError, match=r"duplicate ray for frame 1.*a\.csv") as caught:
        read_gaze360([tmp_path / "a.csv", tmp_path / "c.csv"])
    assert caught.value.path == str(tmp_path / "c.csv") and caught.value.line == 2


def test_arrays_errors_name_the_row():
    with pytest.raises(InputFileError, match=r"row 1: var must be positive"):
        gaze360_to_rays([0.0, 0.0], [0.0, 0.0], [0.1, 0.0], [[2, 0, 0], [2, 0, 0.1]])
    with pytest.raises(ValueError, match="one value per ray"):
        gaze360_to_rays([0.0, 0.0], [0.0], [0.1, 0.1], [[2, 0, 0], [2, 0, 0]])


def test_wide_var_is_clipped_with_a_warning():
    with pytest.warns(UserWarning, match=r"1 of 2 Gaze360 rays .* clipped to 0.5 rad"):
        recording = gaze360_to_rays([0.0, 0.0], [0.0, 0.0], [0.1, 2.5], [[2, 0, 0], [2, 0.5, 0]], frames=[0, 0],
                                    persons=["a", "b"])
    assert float(recording.rays.bandwidth[0, 1]) == pytest.approx(MAX_BANDWIDTH_GAZE360)
    h, clipped = bandwidth_from_gaze360_var(gaze360_var_from_bandwidth([0.01, 0.2, MAX_BANDWIDTH_GAZE360]))
    np.testing.assert_allclose(h, [0.01, 0.2, MAX_BANDWIDTH_GAZE360])
    assert not clipped.any()


# ---------------------------------------------------------------------------
# Honest bandwidths on simulated Gaze360 outputs


@pytest.fixture(scope="module")
def simulated():
    """3000 Gaze360-style rays whose errors follow their own var (2°–25°), read by the adapter."""
    outputs = simulate_gaze360_outputs(jax.random.key(22), 1000, 3)
    recording = gaze360_to_rays(outputs.yaw, outputs.pitch, outputs.var, np.asarray(outputs.eyes_camera),
                                frames=np.asarray(outputs.frames), persons=np.asarray(outputs.persons))
    directions = np.asarray(recording.rays.directions, dtype=np.float64).reshape(-1, 3)  # frame-major, as simulated
    truth = np.asarray(outputs.true_directions, dtype=np.float64)
    cosine = np.sum(directions * truth, axis=-1) / np.linalg.norm(directions, axis=-1) / np.linalg.norm(truth, axis=-1)
    tan_error = np.tan(np.arccos(np.clip(cosine, -1.0, 1.0)))
    return tan_error, np.asarray(recording.rays.bandwidth).reshape(-1), np.asarray(outputs.var)


def _coverage_by_var_third(tan_error, h, var):
    """Share of true directions inside the 90% cone (tangent radius h √(−2 ln 0.1)) per third of var."""
    inside = tan_error <= h * math.sqrt(-2.0 * math.log(0.1))
    third = np.searchsorted(np.quantile(var, [1 / 3, 2 / 3]), var)
    return [float(inside[third == k].mean()) for k in range(3)] + [float(inside.mean())]


def test_gaze360_90_percent_cone_holds_90_percent_of_true_directions(simulated):
    tan_error, h, var = simulated
    coverage = _coverage_by_var_third(tan_error, h, var)
    assert all(0.85 <= c <= 0.95 for c in coverage), coverage


def test_coverage_check_fails_when_var_is_ignored(simulated):
    """One width for every ray, even the right one on average, misses: too wide for small var, too narrow for large."""
    tan_error, h, var = simulated
    low, middle, high, _ = _coverage_by_var_third(tan_error, np.full_like(h, h.mean()), var)
    assert low > 0.95 and high < 0.85, (low, middle, high)
