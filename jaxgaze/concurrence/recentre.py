"""Scenes far from the world origin, searched around their mean eye (docs/conventions.md, "Far from the origin").

Far from the world origin (UTM or ECEF coordinates) float32 sums cancel, so the search
runs in coordinates centred on the scene (:func:`recentred`) and the locations are moved
back in float64 (:func:`moved_back`).
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxgaze.concurrence.options import ConcurrenceOptions
from jaxgaze.concurrence.types import Concurrences
from jaxgaze.rays import GazeRays

__all__ = ["recentred", "moved_back", "RECENTRE_DISTANCE", "FLOAT32_SCENE_RADIUS"]

#: Rays whose eyes lie farther than this from the world origin (metres) are recentred before the search.
RECENTRE_DISTANCE = 1024.0
#: Farthest eye from the reference point (metres) float32 resolves to 1 mm (its grid is 2 mm from 2¹⁴ m on).
FLOAT32_SCENE_RADIUS = 2.0**14


def recentred(rays: GazeRays, options: ConcurrenceOptions, reference=None):
    """``(rays, options, reference)`` with the world origin moved to ``reference`` (docs/conventions.md).

    Far from the world origin (UTM or ECEF coordinates: 5,000 km, where float32's grid is
    0.5 m) the search's float32 sums cancel. When a real eye lies farther than
    :data:`RECENTRE_DISTANCE`, ``reference`` is the mean of the real eyes rounded to whole
    metres (float64, ``(3,)``), every origin and ``options.bounds`` have it subtracted
    (exactly: a float32 coordinate minus a whole number of metres is a float32), and
    :func:`moved_back` adds it back to the locations; covariances do not change. Otherwise
    ``reference`` is ``None`` and nothing changes. A given ``reference`` (a stream's, fixed by its
    first frame) is used as it is. Float32 rays spread over more than
    :data:`FLOAT32_SCENE_RADIUS` around the reference cannot be recentred: ``ValueError``.
    """
    if not isinstance(rays, GazeRays) or not _concrete(rays.origins, rays.mask):
        return rays, options, None
    mask = np.asarray(rays.mask, dtype=bool)
    origins = np.asarray(rays.origins, dtype=np.float64)
    if reference is None:
        if not mask.any() or np.abs(origins[mask]).max() <= RECENTRE_DISTANCE:
            return rays, options, None
        reference = np.round(origins[mask].mean(axis=0))
    local = np.where(mask[..., None], origins - reference, 0.0)
    farthest = np.abs(local).max()
    if jnp.finfo(rays.origins.dtype).bits < 64 and farthest > FLOAT32_SCENE_RADIUS:
        raise ValueError(
            f"the eyes spread {farthest / 1e3:.4g} km around their mean ({', '.join(f'{v:.0f}' for v in reference)}) m: "
            f"float32 resolves positions only to 1 mm within {FLOAT32_SCENE_RADIUS / 1e3:.4g} km (split the recording, "
            "or enable float64)")
    rays = eqx.tree_at(lambda r: r.origins, rays, jax.device_put(local.astype(rays.origins.dtype)))
    if options.bounds is not None:
        options = dataclasses.replace(options, bounds=np.asarray(options.bounds) - reference)
    return rays, options, reference


def _concrete(*arrays) -> bool:
    return not any(isinstance(a, jax.core.Tracer) for a in arrays)


def moved_back(found: Concurrences, reference) -> Concurrences:
    """``found`` with ``reference`` (see :func:`recentred`) added back to the valid locations, which are then
    float64 host arrays, so that the offset does not round them (float32 has a 0.5 m grid at 5,000 km)."""
    if reference is None:
        return found
    valid = np.asarray(found.valid)[..., None]
    return found._replace(locations=np.where(valid, np.asarray(found.locations, np.float64) + reference, 0.0))
