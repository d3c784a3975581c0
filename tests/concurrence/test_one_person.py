"""One person per frame (issue 34, bug 2): no concurrence, and no crash anywhere on the way.

A concurrence needs at least ``min_rays`` (2) rays, so a recording of one person per
frame has ``K = 0`` modes in every frame. Tracking, the live stream, the writers and
the figure must all take that empty answer.
"""

from __future__ import annotations

import numpy as np
import pytest

from jaxgaze import GazeRays
from jaxgaze.concurrence import (
    ConcurrenceOptions,
    ConcurrenceStream,
    find_concurrences,
    find_concurrences_over_frames,
    track_concurrences,
)

T = 5


def one_person(num_frames=T):
    """One wearer walking along +x, looking ahead."""
    origins = np.zeros((num_frames, 1, 3))
    origins[:, 0, 0] = np.arange(num_frames) * 0.1
    origins[:, 0, 2] = 1.6
    return GazeRays(origins, np.tile([1.0, 0.0, 0.0], (num_frames, 1, 1)), 0.05)


def test_one_person_per_frame_has_no_concurrence_and_no_track():
    found = find_concurrences_over_frames(one_person())
    np.testing.assert_array_equal(np.asarray(found.count), np.zeros(T))
    assert found.locations.shape == (T, 0, 3)
    np.testing.assert_array_equal(found.membership, np.full((T, 1), -1))
    tracks = track_concurrences(found)
    assert tracks.track_ids.shape == (T, 0)
    assert int(tracks.num_tracks) == 0
    assert tracks.trajectories(found) == {}


def test_a_recording_whose_frames_hold_one_person_or_none():
    rays = one_person()
    mask = np.array(rays.mask)
    mask[1] = False  # nobody in frame 1
    rays = GazeRays(rays.origins, rays.directions, rays.bandwidth, mask)
    found = find_concurrences_over_frames(rays)
    assert int(np.sum(found.count)) == 0
    assert track_concurrences(found).track_ids.shape == (T, 0)


def test_fewer_people_than_min_rays_track_to_nothing():
    """Two people per frame with min_rays 3: K = 0 as for one person."""
    origins = np.array([[[0.0, 0.0, 1.6], [2.0, 0.0, 1.6]]] * T)
    directions = np.array([[[1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]]] * T)
    found = find_concurrences_over_frames(GazeRays(origins, directions), ConcurrenceOptions(min_rays=3))
    assert found.locations.shape == (T, 0, 3)
    assert int(track_concurrences(found).num_tracks) == 0


@pytest.mark.parametrize("num_rays", [0, 1])
def test_find_concurrences_with_one_ray_or_none(num_rays):
    rays = GazeRays(np.zeros((num_rays, 3)), np.tile([1.0, 0.0, 0.0], (num_rays, 1)))
    found = find_concurrences(rays)
    assert int(found.count) == 0
    assert found.locations.shape == (0, 3)
    np.testing.assert_array_equal(found.membership, np.full(num_rays, -1))


def test_a_stream_of_one_person_gives_no_concurrence_each_frame():
    rays = one_person()
    stream = ConcurrenceStream(num_people=1)
    state = stream.init()
    for t, frame in enumerate(rays):
        found, state = stream.update(state, frame)
        assert found.locations.shape == (0, 3) and found.track_ids.shape == (0,)
        np.testing.assert_array_equal(found.concurrences.membership, [-1])
        assert int(state.frame) == t + 1


def test_writers_and_figure_take_no_concurrence(tmp_path):
    from jaxgaze.io.concurrences import MEMBER_COLUMNS, OUTPUT_COLUMNS, write_concurrences_csv, write_members_csv
    from jaxgaze.io.rays import RayRecording
    from jaxgaze.plotting import plot_recording

    rays = one_person()
    found = find_concurrences_over_frames(rays)
    tracks = track_concurrences(found)
    frame_ids = list(range(10, 10 + T))
    assert write_concurrences_csv(tmp_path / "out.csv", frame_ids, found, tracks) == 0
    assert (tmp_path / "out.csv").read_text().splitlines() == [",".join(OUTPUT_COLUMNS)]
    recording = RayRecording(frame_ids, [["ann"]] * T, rays)
    assert write_members_csv(tmp_path / "members.csv", recording, found, tracks) == T
    lines = (tmp_path / "members.csv").read_text().splitlines()
    assert lines[0] == ",".join(MEMBER_COLUMNS) and lines[1] == "10,ann,-1,-1,"
    fig = plot_recording(rays, found, tracks, frame_ids)
    assert fig.axes
