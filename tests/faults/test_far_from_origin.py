"""Issue 35, item 3: a scene far from the world origin gives the concurrences it gives at the origin.

UTM-sized world coordinates (what georeferenced COLMAP or GNSS-aligned trajectories give)
used to change the count in 12 of 30 frames and move locations by up to 5.9 m: float32 has a
0.5 m grid at 5,000 km. The search now measures the eyes from their mean (whole metres) and
adds it back in float64; the rays CSV reader does so in float64 before float32 rounds anything.

Tolerance: the recentred scene is the origin's scene moved by a whole number of metres, so
the two runs differ only by float32 rounding at the scene's own scale (10 m: about 1 µm);
the mean-shift stops at steps of 0.1 mm (``tol``), so locations must agree within 0.1 mm.
"""

import csv

import numpy as np
import pytest

from jaxgaze import ConcurrenceStream, GazeRays, find_concurrences, find_concurrences_over_frames
from jaxgaze.io.rays import read_rays_csv, write_rays_csv
from tests.cli.helpers import run_main

SHIFT = np.array([500_000.0, 5_000_000.0, 0.0])  # UTM: 500 km easting, 5,000 km northing
LOCATION_TOLERANCE = 1e-4  # m: the mean-shift's stopping step (see the module docstring)
TARGETS = np.array([[2.0, 0.0, 1.0], [-3.0, 4.0, 1.2]])


def _scene(frames=3, seed=0):
    """Two groups of three people, each looking at its target with 0.02 rad of noise; eyes on a 0.5 m grid
    (so that float32 holds them exactly at 5,000 km, too) plus a person looking away."""
    rng = np.random.default_rng(seed)
    eyes, directions = [], []
    for _ in range(frames):
        e = np.array([[0, 0, 1.5], [2, 2.5, 1.5], [4, -1, 2], [-5, 3, 1.5], [-1.5, 6, 2], [-4, 7, 1.5],
                      [1, -4, 1.5]], float)
        e[:, :2] += rng.integers(-2, 3, size=(len(e), 2)) * 0.5
        d = np.r_[TARGETS[[0, 0, 0, 1, 1, 1]] - e[:6], [[0.0, -1.0, 0.0]]]
        d = d / np.linalg.norm(d, axis=1, keepdims=True) + rng.normal(scale=0.02, size=d.shape)
        eyes.append(e)
        directions.append(d)
    return np.array(eyes), np.array(directions)


def _same(near, far, shift=SHIFT):
    """The concurrences of the far scene are those of the near one, moved by ``shift``."""
    assert np.array_equal(np.asarray(near.valid), np.asarray(far.valid))
    assert np.array_equal(np.asarray(near.membership), np.asarray(far.membership))
    valid = np.asarray(near.valid)
    moved = np.asarray(far.locations, np.float64)[valid] - shift
    np.testing.assert_allclose(moved, np.asarray(near.locations, np.float64)[valid], rtol=0, atol=LOCATION_TOLERANCE)
    np.testing.assert_allclose(np.asarray(far.covariances)[valid], np.asarray(near.covariances)[valid], rtol=1e-3,
                               atol=1e-9)


def test_library_gives_the_same_concurrences_5000_km_away():
    eyes, directions = _scene()
    for t in range(len(eyes)):
        near = find_concurrences(GazeRays(eyes[t], directions[t], 0.03))
        far = find_concurrences(GazeRays(eyes[t] + SHIFT, directions[t], 0.03))
        assert len(near.locations) == 2
        gaps = np.linalg.norm(np.asarray(near.locations)[:, None] - TARGETS[None], axis=-1)
        assert np.all(gaps.min(axis=0) < 0.3)  # one concurrence at each target
        _same(near, far)


def test_recording_and_stream_give_the_same_concurrences_5000_km_away():
    eyes, directions = _scene(frames=4, seed=1)
    near = find_concurrences_over_frames(GazeRays(eyes, directions, 0.03))
    far = find_concurrences_over_frames(GazeRays(eyes + SHIFT, directions, 0.03))
    assert np.asarray(near.count).tolist() == [2, 2, 2, 2]
    _same(near, far)
    stream = ConcurrenceStream(num_people=eyes.shape[1])
    state_near, state_far = stream.init(), stream.init()
    for t in range(len(eyes)):
        found_near, state_near = stream.update(state_near, GazeRays(eyes[t], directions[t], 0.03))
        found_far, state_far = stream.update(state_far, GazeRays(eyes[t] + SHIFT, directions[t], 0.03))
        _same(found_near.concurrences, found_far.concurrences)
        assert np.array_equal(np.asarray(found_near.track_ids), np.asarray(found_far.track_ids))


def test_bounds_are_world_coordinates_far_from_the_origin():
    from jaxgaze import ConcurrenceOptions

    eyes, directions = _scene(frames=1)
    box = [[-1.0, -1.0, 0.0], [3.0, 1.0, 3.0]]  # holds the first target only
    near = find_concurrences(GazeRays(eyes[0], directions[0], 0.03), ConcurrenceOptions(bounds=box))
    far_box = (np.asarray(box) + SHIFT).tolist()
    far = find_concurrences(GazeRays(eyes[0] + SHIFT, directions[0], 0.03), ConcurrenceOptions(bounds=far_box))
    assert len(near.locations) == 1
    _same(near, far)


def test_float32_rounding_far_from_the_origin_is_refused():
    eyes, directions = _scene(frames=1)
    off_grid = eyes[0] + SHIFT + 0.123456  # float32 would move every eye by up to 0.25 m
    with pytest.raises(ValueError, match=r"ray 0 lie 5025 km from the world origin, where float32 rounds them"):
        GazeRays(off_grid, directions[0], 0.03)


def _write_rays(path, eyes, directions):
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["frame", "person", "ox", "oy", "oz", "dx", "dy", "dz", "bandwidth"])
        for t in range(len(eyes)):
            for n in range(eyes.shape[1]):
                writer.writerow([t, f"p{n}", *map(repr, eyes[t, n].tolist()), *map(repr, directions[t, n].tolist()),
                                 0.03])


def _rows(path):
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def test_cli_gives_the_same_concurrences_5000_km_away(tmp_path, capsys):
    eyes, directions = _scene(frames=3, seed=2)
    eyes = eyes + np.random.default_rng(3).uniform(-0.2, 0.2, size=eyes.shape)  # off the grid: any float64
    _write_rays(tmp_path / "near.csv", eyes, directions)
    _write_rays(tmp_path / "far.csv", eyes + SHIFT, directions)
    for name in ("near", "far"):
        status, _, err = run_main(capsys, ["concurrences", tmp_path / f"{name}.csv", "--out",
                                           tmp_path / f"{name}_out.csv", "--members", tmp_path / f"{name}_members.csv",
                                           "-q"])
        assert status == 0, err
    near, far = _rows(tmp_path / "near_out.csv"), _rows(tmp_path / "far_out.csv")
    assert len(near) == 6 and [r["frame"] for r in near] == [r["frame"] for r in far]
    for a, b in zip(near, far):
        moved = np.array([float(b[c]) for c in "xyz"]) - SHIFT
        np.testing.assert_allclose(moved, [float(a[c]) for c in "xyz"], rtol=0, atol=LOCATION_TOLERANCE)
        for column in ("var_x", "var_y", "var_z", "cov_xy", "cov_xz", "cov_yz"):
            assert float(b[column]) == pytest.approx(float(a[column]), rel=1e-3, abs=1e-9)
        assert a["num_rays"] == b["num_rays"]
    assert _rows(tmp_path / "near_members.csv") == _rows(tmp_path / "far_members.csv")


def test_rays_csv_round_trip_keeps_world_coordinates_far_from_the_origin(tmp_path):
    eyes, directions = _scene(frames=2)
    eyes = eyes + SHIFT + 0.123456
    _write_rays(tmp_path / "far.csv", eyes, directions)
    recording = read_rays_csv(tmp_path / "far.csv")
    np.testing.assert_allclose(recording.world_origins(), eyes, rtol=0, atol=1e-6)
    write_rays_csv(tmp_path / "again.csv", recording)
    again = np.array([[float(r[c]) for c in ("ox", "oy", "oz")] for r in _rows(tmp_path / "again.csv")])
    np.testing.assert_allclose(again, eyes.reshape(-1, 3), rtol=0, atol=1e-6)
