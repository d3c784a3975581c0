"""Long recordings and live streams: warm-started frames agree with the full search (issue 21).

The warm start seeds each frame from the previous frame's modes plus a few fresh
seeds per ray; the answer must be the one the full seed set gives: the same count
in ≥ 99 % of frames and, where the counts agree, ≥ 99 % of the locations within
1 cm. (Not all: in a frame where a ray is about as close to two groups, the full
search and the warm start can group it differently; on the simulated party and
mocap recordings that is 0.1–0.2 % of the modes, benchmarks/RESULTS.md.) The online
stream must give the batch's answer in the same sense, and its track ids are those
of ``track_concurrences`` on its own concurrences.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxgaze import GazeRays
from jaxgaze.concurrence import (
    ConcurrenceStream,
    find_concurrences_over_frames,
    track_concurrences,
)
from jaxgaze.concurrence import frame, recording
from jaxgaze.concurrence.options import ConcurrenceOptions
from tests import helpers as zoo

FRAMES = 2 * recording.LANE_FRAMES  # the shortest recording that can be warm-started: two lanes


def agreement(found, reference):
    """``(share of frames with the same count, share of their locations within 1 cm of the reference's)``."""
    counts, reference_counts = np.sum(found.valid, axis=1), np.sum(reference.valid, axis=1)
    same = counts == reference_counts
    distances = [np.zeros(0)]
    for t in np.flatnonzero(same & (counts > 0)):
        a = np.asarray(reference.locations[t])[np.asarray(reference.valid[t])]
        b = np.asarray(found.locations[t])[np.asarray(found.valid[t])]
        distances.append(np.linalg.norm(a[:, None] - b[None], axis=-1).min(axis=1))
    distances = np.concatenate(distances)
    assert distances.size > FRAMES  # a recording with concurrences to find
    return float(np.mean(same)), float(np.mean(distances < 0.01))


@pytest.fixture(scope="module")
def meeting():
    return zoo.saliency_scene("meeting", FRAMES, seed=21).rays


@pytest.fixture(scope="module")
def cold(meeting):
    return find_concurrences_over_frames(meeting, warm_start=False)


@pytest.fixture(scope="module")
def warm(meeting, monkeypatch_module):
    calls = []
    lanes = recording._warm_lanes_jit

    def spy(*args, **kwargs):
        calls.append(args[0].batch_shape)
        return lanes(*args, **kwargs)

    monkeypatch_module.setattr(recording, "_warm_lanes_jit", spy)
    return find_concurrences_over_frames(meeting, warm_start=True), calls


@pytest.fixture(scope="module")
def monkeypatch_module():
    with pytest.MonkeyPatch.context() as mp:
        yield mp


def test_warm_start_agrees_with_the_full_seed_set(warm, cold):
    found, calls = warm
    assert calls and calls[0][1] == recording.LANE_FRAMES - 1  # the lanes ran, warm-started
    same, close = agreement(found, cold)
    assert same >= 0.99, same
    assert close >= 0.99, close
    lane_starts = np.arange(0, FRAMES, recording.LANE_FRAMES)
    np.testing.assert_array_equal(found.valid[lane_starts], cold.valid[lane_starts])


def test_warm_start_is_the_default_for_long_recordings(meeting, monkeypatch):
    """By default a recording shorter than WARM_START_MIN_FRAMES gets the full search (compiling the warm
    program would cost more than it saves), a longer one the warm start."""
    called = []
    monkeypatch.setattr(recording, "_warm_started", lambda *args: called.append(True) or "warm")
    monkeypatch.setattr(recording, "WARM_START_MIN_FRAMES", FRAMES)
    assert find_concurrences_over_frames(meeting) == "warm"
    monkeypatch.setattr(recording, "WARM_START_MIN_FRAMES", FRAMES + 1)
    assert find_concurrences_over_frames(meeting) != "warm" and len(called) == 1


def test_warm_start_keeps_the_result_layout(warm, cold):
    found, _ = warm
    for name in found._fields:
        assert np.shape(getattr(found, name)) == np.shape(getattr(cold, name)), name
    membership = np.asarray(found.membership)
    assert np.all(membership < np.sum(found.valid, axis=1, keepdims=True))  # points at valid modes only


def test_unexplained_rays_are_two_unclaimed_rays_crossing():
    """Two free rays meeting in front of both eyes ask for the full search; claimed, parallel,
    diverging or mutual-gaze pairs do not."""
    eyes = np.array([[0.0, 0.0, 1.7], [2.0, 0.0, 1.7], [0.0, 3.0, 1.7]])
    target = np.array([1.0, 2.0, 1.2])
    directions = target - eyes
    directions[2] = [0.0, 1.0, 0.0]  # the third looks away
    rays = GazeRays(eyes, directions, np.full(3, 0.02))
    box = jnp.array([[-np.inf] * 3, [np.inf] * 3])
    free = recording.empty_concurrences(rays, ConcurrenceOptions())._replace(membership=jnp.full(3, -1, jnp.int32))

    def unexplained(r, found):
        return bool(frame.unexplained(r, found, box, 6.0))

    assert unexplained(rays, free)
    assert not unexplained(rays, free._replace(membership=jnp.array([0, 0, -1], jnp.int32)))
    assert not unexplained(rays, free._replace(membership=jnp.array([0, -1, -1], jnp.int32)))  # 1, 2 miss
    backwards = directions * np.array([[-1.0], [-1.0], [1.0]])
    assert not unexplained(GazeRays(eyes, backwards, np.full(3, 0.02)), free)  # they meet behind the eyes
    assert not unexplained(rays, free._replace(mutual_gaze=jnp.array([1, 0, -1], jnp.int32)))
    below = jnp.array([[-np.inf, -np.inf, 1.5], [np.inf, np.inf, np.inf]])
    assert not bool(frame.unexplained(rays, free, below, 6.0))  # the crossing is outside the box


@pytest.fixture(scope="module")
def streamed(meeting):
    stream = ConcurrenceStream(num_people=meeting.num_rays)
    state = stream.init()
    frames = []
    for t in range(FRAMES):
        found, state = stream.update(state, meeting[t])
        frames.append(found)
    return jax.tree_util.tree_map(lambda *a: np.stack(a), *frames)


def test_stream_agrees_with_the_batch(streamed, warm):
    found, _ = warm
    same, close = agreement(streamed.concurrences, found)
    assert same >= 0.99, same
    assert close >= 0.99, close
    assert bool(streamed.searched_all_seeds[0])  # the first frame has no previous modes
    assert np.mean(streamed.searched_all_seeds) < 0.25  # the others are warm-started


def test_stream_track_ids_are_the_trackers(streamed):
    tracks = track_concurrences(streamed.concurrences)
    np.testing.assert_array_equal(streamed.track_ids, tracks.track_ids)
    assert 1 <= int(tracks.num_tracks) < np.sum(streamed.concurrences.valid)


def test_stream_masks_absent_people(meeting, cold):
    """A frame of 8 people in a stream made for 11: the full search's answer with the 3 others masked."""
    stream = ConcurrenceStream(num_people=meeting.num_rays)
    frame = meeting[5]
    few = GazeRays(frame.origins[:8], frame.directions[:8], frame.bandwidth[:8])
    found, state = stream.update(stream.init(), few)
    masked = GazeRays(frame.origins, frame.directions, frame.bandwidth, np.arange(meeting.num_rays) < 8)
    alone = find_concurrences_over_frames(jax.tree_util.tree_map(lambda a: a[None], masked), warm_start=False)
    valid = np.asarray(found.valid)
    np.testing.assert_array_equal(valid, alone.valid[0])
    assert valid.sum() > 0
    np.testing.assert_allclose(np.asarray(found.locations)[valid], alone.locations[0][valid], atol=1e-4)
    np.testing.assert_array_equal(np.asarray(found.concurrences.membership)[:8], alone.membership[0][:8])
    assert int(state.frame) == 1
    # One person in the frame (issue 34): no concurrence, no track, the same compiled program.
    one = GazeRays(frame.origins[:1], frame.directions[:1], frame.bandwidth[:1])
    found, state = stream.update(state, one)
    assert not np.asarray(found.valid).any()
    np.testing.assert_array_equal(np.asarray(found.track_ids), -1)
    assert int(state.frame) == 2


def test_stream_refuses_what_it_cannot_take(meeting):
    stream = ConcurrenceStream(num_people=4)
    with pytest.raises(ValueError, match="num_people=4"):
        stream.update(stream.init(), meeting[0])
    with pytest.raises(ValueError, match="one frame"):
        stream.update(stream.init(), meeting[:2, :4])
    with pytest.raises(ValueError, match="num_people"):
        ConcurrenceStream(num_people=0)
