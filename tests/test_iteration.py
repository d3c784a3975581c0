"""Frame-indexed results stop at their length (issue 34, bug 1).

JAX clamps an index past the end of an array instead of raising, so a type with
``__getitem__`` and no ``__iter__`` iterates forever under Python's old protocol
(``for rays_t in scene.rays:`` in the README). Every type indexed by frame has a
length, iterates its frames and raises ``IndexError`` past the end.
"""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxgaze as jg
from jaxgaze.concurrence import Concurrences
from jaxgaze.poses import camera_poses


def _recording(num_frames=5, num_people=3):
    rng = np.random.default_rng(0)
    origins = rng.normal(size=(num_frames, num_people, 3))
    directions = rng.normal(size=(num_frames, num_people, 3))
    return jg.GazeRays(origins, directions, 0.05), origins


def test_gaze_rays_iterate_their_frames_and_stop():
    rays, origins = _recording()
    assert len(rays) == 5
    # islice bounds the loop on code that never stops: more than 5 items is the bug.
    frames = list(itertools.islice(iter(rays), 10))
    assert len(frames) == 5
    for t, frame in enumerate(frames):
        assert frame.batch_shape == ()
        np.testing.assert_allclose(np.asarray(frame.origins), origins[t], rtol=1e-6)
    assert [len(a) for a in (rays[1:4], rays[::2])] == [3, 3]


def test_a_stacked_recording_iterates_its_frames():
    frames = [jg.GazeRays(np.zeros((n, 3)), np.tile([1.0, 0.0, 0.0], (n, 1))) for n in (1, 3, 2)]
    recording = jg.GazeRays.stack(frames)
    assert [int(np.sum(f.mask)) for f in itertools.islice(recording, 10)] == [1, 3, 2]


@pytest.mark.parametrize("index", [5, 6, 10**6, -6, -(10**6), np.int64(5), jnp.int32(5)])
def test_an_index_past_the_end_raises(index):
    rays, _ = _recording()
    with pytest.raises(IndexError, match="out of range"):
        rays[index]


def test_negative_indices_count_from_the_end():
    rays, origins = _recording()
    np.testing.assert_allclose(np.asarray(rays[-1].origins), origins[4], rtol=1e-6)
    np.testing.assert_allclose(np.asarray(rays[-5].origins), origins[0], rtol=1e-6)
    np.testing.assert_allclose(np.asarray(rays[np.int64(-2)].origins), origins[3], rtol=1e-6)
    np.testing.assert_allclose(np.asarray(rays[2, :2].origins), origins[2, :2], rtol=1e-6)
    with pytest.raises(IndexError, match="out of range"):
        rays[5, :2]


def test_a_single_frame_has_no_length_and_no_frames():
    frame = _recording()[0][0]
    with pytest.raises(TypeError, match="single frame"):
        len(frame)
    with pytest.raises(TypeError, match="single frame"):
        iter(frame)
    with pytest.raises(IndexError):
        frame[0]
    assert frame and _recording()[0][:0]  # truth is not the number of frames (`if rays:` keeps working)


def test_traced_indices_still_work_under_jit_and_vmap():
    rays, origins = _recording()
    first_origin = jax.jit(lambda r, t: r[t].origins[0])
    np.testing.assert_allclose(np.asarray(first_origin(rays, 3)), origins[3, 0], rtol=1e-6)
    # A concrete index inside jit is checked too (shapes are static there).
    with pytest.raises(IndexError, match="out of range"):
        jax.jit(lambda r: r[7].origins)(rays)
    per_frame = jax.vmap(lambda r: r.origins.sum())(rays)
    np.testing.assert_allclose(np.asarray(per_frame), origins.sum(axis=(1, 2)), rtol=1e-5)
    # A pytree: tree maps and scans over the frames are untouched by __len__/__iter__.
    _, summed = jax.lax.scan(lambda c, r: (c, r.origins.sum()), 0.0, rays)
    np.testing.assert_allclose(np.asarray(summed), origins.sum(axis=(1, 2)), rtol=1e-5)


def test_concurrences_of_a_recording_are_indexed_by_frame_with_a_range_check():
    T, K, N = 3, 2, 4
    valid = np.array([[True, False], [True, True], [False, False]])
    found = Concurrences(
        locations=np.arange(T * K * 3, dtype=float).reshape(T, K, 3), covariances=np.tile(np.eye(3), (T, K, 1, 1)),
        field_values=np.ones((T, K)), num_rays=np.full((T, K), 2), membership=np.full((T, N), -1),
        region_axes=np.tile(np.eye(3), (T, K, 1, 1)), region_semi_axes=np.ones((T, K, 3)),
        converged=np.ones((T, K), bool), valid=valid)
    assert [found.frame(t).locations.shape[0] for t in range(T)] == [1, 2, 0]
    np.testing.assert_array_equal(found.frame(-2).locations, found.locations[1])
    with pytest.raises(IndexError):
        found.frame(T)


def test_camera_poses_select_checks_the_range():
    poses = camera_poses(np.tile(np.eye(3), (4, 1, 1)), np.zeros((4, 3)), np.arange(4))
    assert poses.select(3).frame_ids == 3
    with pytest.raises(IndexError):
        poses.select(4)
