"""Calibration uncertainty carried into the concurrences (Park et al. 2012, Sec. 3.2 and 4).

Each posterior draw of the wearers' calibrations gives one set of gaze rays; the
spread of the concurrences found from those rays is the calibration's share of the
location uncertainty.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from jaxgaze.concurrence.options import ConcurrenceOptions
from jaxgaze.concurrence.recording import find_concurrences, find_concurrences_over_frames
from jaxgaze.geometry import unit
from jaxgaze.rays import GazeRays

__all__ = ["ConcurrenceEnsemble", "propagate_to_concurrences"]


class ConcurrenceEnsemble(NamedTuple):
    """Concurrence locations under an ensemble of calibrations (one per posterior draw).

    Attributes:
        reference: the concurrences of the reference rays (e.g. the posterior means).
        locations: ``(S, K, 3)`` location of each reference mode under each draw
            (matched to the nearest mode of that draw; NaN where none is within reach).
        found: ``(S, K)`` whether draw ``s`` has a mode matched to reference mode ``k``.
        mean: ``(K, 3)`` ensemble mean location.
        covariance: ``(K, 3, 3)`` ensemble covariance: the calibration's share of the
            location uncertainty, to be added to the per-frame Laplace covariance.
    """

    reference: object
    locations: np.ndarray
    found: np.ndarray
    mean: np.ndarray
    covariance: np.ndarray


def propagate_to_concurrences(
    eye_centers: Float[Array, "S N 3"],
    directions: Float[Array, "S N 3"],
    bandwidths: Float[Array, "S N"],
    R_world_from_camera: Float[Array, "N 3 3"],
    camera_centers: Float[Array, "N 3"],
    *,
    max_distance: float = 0.5,
    options: ConcurrenceOptions = ConcurrenceOptions(),
) -> ConcurrenceEnsemble:
    """Carry calibration uncertainty into the concurrences of one frame (Park et al. 2012, Sec. 3.2 and 4).

    Draw ``s`` gives person ``i`` the ray ``p = R_i e_s,i + C_i``, ``v = R_i d_s,i``
    (camera frame → world). All draws go through
    :func:`jaxgaze.find_concurrences_over_frames` at once, the draws playing the role
    of frames, and each reference mode (from the mean calibration) is matched to the
    nearest mode of every draw within ``max_distance`` metres. ``options`` (a
    :class:`~jaxgaze.concurrence.ConcurrenceOptions`) go to both searches.
    """
    eye = jnp.asarray(eye_centers)
    d = jnp.asarray(directions)
    R = jnp.asarray(R_world_from_camera)
    C = jnp.asarray(camera_centers)
    if eye.ndim != 3 or eye.shape[-1] != 3 or d.shape != eye.shape:
        raise ValueError(f"eye_centers and directions must both be (S, N, 3), got {eye.shape} and {d.shape}")
    if R.shape != (eye.shape[1], 3, 3) or C.shape != (eye.shape[1], 3):
        raise ValueError(f"need one camera pose per person: R {R.shape}, centres {C.shape} for N = {eye.shape[1]}")
    origins = jnp.einsum("nij,snj->sni", R, eye) + C
    world_directions = jnp.einsum("nij,snj->sni", R, d)
    # The draws are not frames in time: each is searched from the full seed set.
    ensemble = find_concurrences_over_frames(GazeRays(origins, world_directions, bandwidths), options,
                                             warm_start=False)
    mean_direction = unit(world_directions.mean(0))
    reference = find_concurrences(GazeRays(origins.mean(0), mean_direction, jnp.asarray(bandwidths).mean(0)), options)

    ref = np.asarray(reference.locations)  # (K, 3)
    locs = np.asarray(ensemble.locations)  # (S, K', 3)
    valid = np.asarray(ensemble.valid)
    dist = np.linalg.norm(locs[:, None, :, :] - ref[None, :, None, :], axis=-1)  # (S, K, K')
    dist = np.where(valid[:, None, :], dist, np.inf)
    nearest = np.argmin(dist, axis=-1) if dist.shape[-1] else np.zeros(dist.shape[:2], int)
    best = np.take_along_axis(dist, nearest[..., None], axis=-1)[..., 0] if dist.shape[-1] else np.full(
        dist.shape[:2], np.inf)
    found = best <= max_distance
    matched = np.where(found[..., None], np.take_along_axis(locs, nearest[..., None], axis=1), np.nan)
    mean = np.nanmean(matched, axis=0) if len(ref) else np.zeros((0, 3))
    centred = np.where(found[..., None], matched - mean, 0.0)
    counts = np.maximum(found.sum(0) - 1, 1)
    covariance = np.einsum("ski,skj->kij", centred, centred) / counts[:, None, None]
    return ConcurrenceEnsemble(reference, matched, found, mean, covariance)
