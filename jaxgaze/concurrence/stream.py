"""Concurrences of a live stream, one frame at a time, with track ids (Park et al. 2012, Sec. 3.3).

A robot or a live demo gets its frames one by one and needs each answer before
the next frame. :class:`ConcurrenceStream` carries, from frame to frame, the
previous frame's modes and the tracker's live tracks. Each frame is searched from
seeds at the previous modes plus a few fresh seeds per ray (the warm start of
:func:`~jaxgaze.concurrence.find_concurrences_over_frames`), and again from the
full seed set when that leaves two unclaimed rays crossing (a concurrence the
warm seeds may have missed) and on the first frame. The update is one compiled
program for a fixed number of people; fewer people in a frame are masked rays.

    stream = ConcurrenceStream(num_people=11)
    state = stream.init()
    for rays_t in frames:
        found, state = stream.update(state, rays_t)
        found.locations[found.valid], found.track_ids[found.valid]
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from jaxgaze.concurrence.frame import concurrences_one_frame, warm_frame
from jaxgaze.concurrence.options import ConcurrenceOptions
from jaxgaze.concurrence.recentre import moved_back, recentred
from jaxgaze.concurrence.recording import empty_concurrences, prepare
from jaxgaze.concurrence.tracking import TrackerState, track_frame, tracker_init
from jaxgaze.concurrence.types import Concurrences
from jaxgaze.rays import GazeRays, check_units

__all__ = ["ConcurrenceStream", "StreamState", "StreamFrame"]


class StreamState(NamedTuple):
    """What :class:`ConcurrenceStream` carries from one frame to the next."""

    locations: Float[Array, "K 3"]  # the previous frame's modes: seeds of the next frame
    valid: Bool[Array, " K"]
    frame: Int[Array, ""]  # frames seen so far
    tracker: TrackerState
    # The world point the locations above are measured from: None before the first frame, zeros when
    # the scene lies near the world origin, else the first frame's mean eye (float64, host; see
    # docs/conventions.md, "Far from the origin").
    reference: np.ndarray | None = None


class StreamFrame(NamedTuple):
    """The answer for one frame: its concurrences (padded to ``K`` modes; ``valid`` marks the real
    ones), the track id of each mode (−1 for padding), and whether the frame was searched from
    the full seed set (the first frame, or rays left unexplained by the warm start)."""

    concurrences: Concurrences
    track_ids: Int[Array, " K"]
    searched_all_seeds: Bool[Array, ""]

    @property
    def locations(self) -> Float[Array, "K 3"]:
        return self.concurrences.locations

    @property
    def valid(self) -> Bool[Array, " K"]:
        return self.concurrences.valid


def _stream_step(state: StreamState, rays: GazeRays, depths, region, *, options, max_modes, modes_per_batch,
                 max_distance, max_gap):
    static = dict(options=options, max_modes=max_modes, modes_per_batch=modes_per_batch)
    warm, unexplained = warm_frame(rays, (state.locations, state.valid), state.frame, depths, region, **static)
    again = (state.frame == 0) | unexplained
    found = jax.lax.cond(again, lambda: concurrences_one_frame(rays, depths, region, **static), lambda: warm)
    tracker, track_ids = track_frame(state.tracker, (found.locations, found.valid, found.field_values),
                                      max_distance=max_distance, max_gap=max_gap)
    return StreamFrame(found, track_ids, again), StreamState(found.locations, found.valid, state.frame + 1, tracker)


_stream_step_jit = jax.jit(
    _stream_step, static_argnames=("options", "max_modes", "modes_per_batch", "max_distance", "max_gap")
)


@dataclasses.dataclass(frozen=True)
class ConcurrenceStream:
    """Online gaze concurrences with track ids, one compiled update per frame (Park et al. 2012, Sec. 3.3).

    Args:
        num_people: most people (rays) in one frame; a frame with fewer is padded with
            masked rays, so every frame runs the same compiled program.
        options: the search options, as for :func:`~jaxgaze.concurrence.find_concurrences`.
        max_distance, max_gap: the tracker's rules, as for
            :func:`~jaxgaze.concurrence.track_concurrences`.
        dtype: float dtype of the rays and the state (float32 by default).

    ``state = stream.init()``, then ``found, state = stream.update(state, rays_t)`` for each
    frame's :class:`~jaxgaze.GazeRays` (``(N, 3)``, ``N ≤ num_people``, world frame, metres).
    ``found`` is a :class:`StreamFrame`. A stream for fewer people than ``options.min_rays``
    (e.g. one wearer) has ``K = 0``: every frame has no concurrence (mutual gaze is still
    reported). The answers agree with
    :func:`~jaxgaze.concurrence.find_concurrences_over_frames` followed by
    :func:`~jaxgaze.concurrence.track_concurrences` on the same recording (the same count in
    ≥ 99 % of frames; locations within 1 cm where the counts agree).
    """

    num_people: int
    options: ConcurrenceOptions = ConcurrenceOptions()
    max_distance: float = 0.5
    max_gap: int = 2
    dtype: type = jnp.float32

    def __post_init__(self):
        if isinstance(self.num_people, bool) or int(self.num_people) != self.num_people or self.num_people < 1:
            raise ValueError(f"num_people must be an integer ≥ 1, got {self.num_people!r}")
        object.__setattr__(self, "num_people", int(self.num_people))
        if not isinstance(self.options, ConcurrenceOptions):
            raise TypeError(f"options must be a jaxgaze.ConcurrenceOptions, got {type(self.options).__name__}")
        if not self.max_distance > 0 or int(self.max_gap) != self.max_gap or self.max_gap < 0:
            raise ValueError("max_distance must be positive and max_gap a non-negative integer")
        object.__setattr__(self, "dtype", jnp.dtype(self.dtype).type)
        empty = self._padded(GazeRays(np.zeros((1, 3)), np.array([[1.0, 0.0, 0.0]]), np.ones(1)))
        depths, region, static = prepare(empty, self.options)
        object.__setattr__(self, "_program", (depths, region, static))

    @property
    def max_modes(self) -> int:
        """``K``: modes per frame (padded)."""
        return self._program[2]["max_modes"]

    def init(self) -> StreamState:
        """The state before the first frame."""
        k = self.max_modes
        return StreamState(jnp.zeros((k, 3), self.dtype), jnp.zeros(k, bool), jnp.int32(0),
                           tracker_init(k, self.dtype))

    def _padded(self, rays: GazeRays) -> GazeRays:
        extra = self.num_people - rays.num_rays
        if extra == 0 and rays.origins.dtype == self.dtype:
            return rays
        host = [np.asarray(a) for a in (rays.origins, rays.directions, rays.bandwidth, rays.mask)]
        origins, directions, bandwidth = (a.astype(self.dtype) for a in host[:3])
        mask = host[3]
        if extra:
            directions = np.concatenate([directions, np.tile(np.array([[1.0, 0.0, 0.0]], self.dtype), (extra, 1))])
            origins = np.concatenate([origins, np.zeros((extra, 3), self.dtype)])
            bandwidth = np.concatenate([bandwidth, np.ones(extra, self.dtype)])
            mask = np.concatenate([mask, np.zeros(extra, bool)])
        return GazeRays(origins, directions, bandwidth, mask)

    def update(self, state: StreamState, rays: GazeRays) -> tuple[StreamFrame, StreamState]:
        """The concurrences and track ids of the next frame, and the new state."""
        if not isinstance(rays, GazeRays):
            raise TypeError(f"expected jaxgaze.GazeRays for one frame, got {type(rays).__name__}")
        if rays.batch_shape:
            raise ValueError(f"update takes one frame of rays, (N, 3); got batch shape {rays.batch_shape}")
        if rays.num_rays > self.num_people:
            raise ValueError(f"{rays.num_rays} rays in this frame, but the stream was made for num_people="
                             f"{self.num_people}")
        check_units(rays)
        depths, region, static = self._program
        # Far from the world origin the frames are measured from the first frame's mean eye (whole metres).
        if state.reference is None:  # the first frame decides
            rays, options, reference = recentred(rays, self.options)
        elif state.reference.any():
            rays, options, reference = recentred(rays, self.options, state.reference)
        else:
            options, reference = self.options, None
        if reference is not None and options.bounds is not None:
            region = (jax.device_put(np.asarray(options.bounds, np.asarray(region[0]).dtype)), region[1])
        kept = reference if reference is not None else (
            np.zeros(3) if state.reference is not None or np.asarray(rays.mask).any() else None)
        if static["max_modes"] == 0:  # fewer people than min_rays (one person): no concurrence, nothing to track
            found = empty_concurrences(self._padded(rays), self.options)
            return (StreamFrame(found, jnp.zeros(0, jnp.int32), jnp.asarray(False)),
                    state._replace(frame=state.frame + 1, reference=kept))
        found, new_state = _stream_step_jit(state._replace(reference=None), self._padded(rays), depths, region,
                                            **static, max_distance=float(self.max_distance),
                                            max_gap=int(self.max_gap))
        found = found._replace(concurrences=moved_back(found.concurrences, reference))
        return found, new_state._replace(reference=kept)
