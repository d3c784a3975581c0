"""Concurrences linked over frames into tracks with birth and death (Park et al. 2012, Sec. 3.3).

:func:`track_concurrences` links a recording's modes; :func:`track_frame` is one frame
of it, with the :class:`TrackerState` it carries (also the tracker of
:class:`~jaxgaze.concurrence.ConcurrenceStream`).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from jaxgaze.concurrence.types import Concurrences, Tracks

__all__ = ["track_concurrences", "TrackerState", "tracker_init", "track_frame"]


def track_concurrences(concurrences: Concurrences, *, max_distance: float = 0.5, max_gap: int = 2) -> Tracks:
    """Link the modes of consecutive frames into trajectories with birth and death (Park et al. 2012, Sec. 3.3).

    A ``lax.scan`` over frames. In each frame the modes, strongest first, take
    the nearest live track within ``max_distance`` metres that is not yet taken;
    a mode with none starts a new track (birth). A track not seen for more than
    ``max_gap`` frames ends (death) and is never revived. A recording with no mode
    slot (``K = 0``: one person per frame, or fewer than ``min_rays``) has no track.
    """
    if concurrences.locations.ndim != 3:
        raise ValueError("track_concurrences needs the padded (T, K) result of find_concurrences_over_frames")
    if not max_distance > 0 or max_gap < 0:
        raise ValueError("max_distance must be positive and max_gap non-negative")
    locations, valid, values = (np.asarray(a) for a in (concurrences.locations, concurrences.valid,
                                                        concurrences.field_values))
    total = locations.shape[0]
    carry = tracker_init(locations.shape[1], locations.dtype)
    ids = []
    for start in range(0, total, _TRACK_CHUNK):
        # Chunks of one length (the last padded with empty frames): one compilation for any recording.
        part = [np.concatenate([a[start:start + _TRACK_CHUNK],
                                np.zeros((max(0, start + _TRACK_CHUNK - total),) + a.shape[1:], a.dtype)])
                for a in (locations, valid, values)]
        carry, chunk = _track_chunk(carry, *part, max_distance=float(max_distance), max_gap=int(max_gap))
        ids.append(np.asarray(chunk))
    ids = np.concatenate(ids)[:total] if ids else np.zeros((0, locations.shape[1]), np.int32)
    return Tracks(track_ids=jax.device_put(ids), num_tracks=carry.next_id)


_TRACK_CHUNK = 512  # frames per compiled tracking program


@functools.partial(jax.jit, static_argnames=("max_distance", "max_gap"))
def _track_chunk(carry, locations, valid, values, *, max_distance, max_gap):
    step = functools.partial(track_frame, max_distance=max_distance, max_gap=max_gap)
    return jax.lax.scan(step, carry, (locations, valid, values))


class TrackerState(NamedTuple):
    """What :func:`track_concurrences` carries from frame to frame: ``2K`` slots of live tracks."""

    track_id: Int[Array, " S"]  # −1: empty slot
    location: Float[Array, "S 3"]  # last location of the slot's track
    unseen: Int[Array, " S"]  # frames since the track was last seen
    next_id: Int[Array, ""]


def tracker_init(max_modes: int, dtype) -> TrackerState:
    """The state before the first frame, for ``max_modes`` modes per frame: no live track."""
    slots = 2 * max_modes  # live tracks at once: this frame's and those waiting out a gap
    return TrackerState(jnp.full(slots, -1, jnp.int32), jnp.zeros((slots, 3), dtype), jnp.zeros(slots, jnp.int32),
                        jnp.int32(0))


def track_frame(carry: TrackerState, inputs, *, max_distance: float, max_gap: int):
    """One frame of :func:`track_concurrences`: ``(new state, track id of each of the frame's K modes or −1)``."""
    track_id, track_loc, unseen, next_id = carry
    locations, valid, values = inputs
    k = locations.shape[0]
    if k == 0:  # no mode can be found (fewer rays than min_rays, e.g. one person): nothing to link
        return carry, jnp.zeros(0, jnp.int32)
    big = jnp.asarray(jnp.inf, locations.dtype)
    order = jnp.argsort(jnp.where(valid, -values, jnp.inf))
    live = (track_id >= 0) & (unseen <= max_gap)

    def assign(j, state):
        ids_out, taken, track_id, track_loc, next_id = state
        m = order[j]
        dist = jnp.linalg.norm(track_loc - locations[m], axis=-1)
        dist = jnp.where(live & ~taken & (dist <= max_distance), dist, big)
        best = jnp.argmin(dist)
        matched = valid[m] & jnp.isfinite(dist[best])
        free = jnp.argmax(~live & ~taken)  # a dead or empty slot for a newborn
        slot = jnp.where(matched, best, free)
        born = valid[m] & ~matched
        new_id = jnp.where(matched, track_id[slot], next_id)
        ids_out = ids_out.at[m].set(jnp.where(valid[m], new_id, -1))
        taken = taken.at[slot].set(taken[slot] | valid[m])
        track_id = track_id.at[slot].set(jnp.where(valid[m], new_id, track_id[slot]))
        track_loc = track_loc.at[slot].set(jnp.where(valid[m], locations[m], track_loc[slot]))
        return ids_out, taken, track_id, track_loc, next_id + born.astype(jnp.int32)

    ids_out = jnp.full(k, -1, jnp.int32)
    ids_out, taken, track_id, track_loc, next_id = jax.lax.fori_loop(
        0, k, assign, (ids_out, jnp.zeros(track_id.shape[0], bool), track_id, track_loc, next_id)
    )
    unseen = jnp.where(taken, 0, unseen + 1)
    track_id = jnp.where(unseen > max_gap, -1, track_id)
    return TrackerState(track_id, track_loc, unseen, next_id), ids_out
