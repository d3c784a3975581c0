"""What the concurrence search returns: :class:`MeanShiftResult`, :class:`Concurrences`, :class:`Tracks`."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from jaxgaze.results import RESULTS

__all__ = ["MeanShiftResult", "Concurrences", "Tracks", "PER_RAY"]

class MeanShiftResult(NamedTuple):
    """Output of :func:`meanshift` for ``S`` seeds."""

    points: Float[Array, "S 3"]
    field_values: Float[Array, " S"]
    iterations: Int[Array, " S"]
    converged: Bool[Array, " S"]


class Concurrences(NamedTuple):
    """Gaze concurrences of one frame (``K`` modes) or of many (``(T, K)``, padded).

    Attributes:
        locations: ``(…, K, 3)`` world-frame points (m).
        covariances: ``(…, K, 3, 3)`` covariance of each location (m²): the Laplace
            covariance scaled by the noise its member rays show, i.e. the covariance
            of a Student-t with ``degrees_of_freedom`` (:mod:`jaxgaze.concurrence.laplace`, **Noise scale**).
        field_values: ``(…, K)`` social saliency ``f`` at each location.
        num_rays: ``(…, K)`` number of member rays.
        membership: ``(…, N)`` index of the mode each ray supports, or −1.
        region_axes: ``(…, K, 3, 3)`` columns are the principal directions of the
            paper's confidence region ``{f ≥ 0.8 f(mode)}`` (Park et al., Sec. 4.1): a
            level set of the field, not a confidence region for the location.
        region_semi_axes: ``(…, K, 3)`` its semi-axis lengths (m), from the
            quadratic approximation of ``log f``; ``inf`` along a flat direction.
        converged: ``(…, K)`` whether the mean-shift seed converged within ``tol``.
        valid: ``(…, K)`` mask of real modes (all ``True`` for a single frame).
        degrees_of_freedom: ``(…, K)`` degrees of freedom ``ν`` of the location's
            Student-t: its ``level`` region is ``(x − x̂)ᵀ Σ⁻¹ (x − x̂) ≤
            3 (ν − 2)/ν · F⁻¹(level; 3, ν)`` with ``Σ`` = ``covariances``.
            ``None`` (results built by hand) means Gaussian (``ν = ∞``).
        mutual_gaze: ``(…, N)`` the person each ray's person is in mutual gaze with,
            or −1 (``mutual_gaze[i] = j`` exactly when ``mutual_gaze[j] = i``; see
            :func:`~jaxgaze.concurrence.find_concurrences`). ``None`` in results built by hand.
        result: ``(…, K)`` a :class:`~jaxgaze.results.RESULTS` code per concurrence: ``successful``,
            or why the Levenberg–Marquardt refinement of its location failed (``max_steps_reached``:
            it ran out of ``refine_steps`` short of its tolerance, the best point reached is kept;
            ``optimiser_failed``: it diverged or did not fit the members better than its start,
            which is kept; :func:`~jaxgaze.concurrence.laplace.refine_and_laplace`). Padding and
            rejected slots are ``successful`` (nothing was refined there). ``jaxgaze.succeeded(c)``
            is the per-concurrence bool array. ``None`` in results built by hand.
    """

    locations: Float[Array, "... K 3"]
    covariances: Float[Array, "... K 3 3"]
    field_values: Float[Array, "... K"]
    num_rays: Int[Array, "... K"]
    membership: Int[Array, "... N"]
    region_axes: Float[Array, "... K 3 3"]
    region_semi_axes: Float[Array, "... K 3"]
    converged: Bool[Array, "... K"]
    valid: Bool[Array, "... K"]
    degrees_of_freedom: Float[Array, "... K"] | None = None
    mutual_gaze: Int[Array, "... N"] | None = None
    result: RESULTS | None = None

    @property
    def count(self) -> Int[Array, "..."]:
        """Number of concurrences (per frame for a recording)."""
        return jnp.sum(self.valid, axis=-1)

    def members(self, k: int) -> np.ndarray:
        """Indices of the rays that support mode ``k`` (single frame)."""
        return np.flatnonzero(np.asarray(self.membership) == k)

    def frame(self, t: int) -> "Concurrences":
        """Frame ``t`` of a recording, with the padding removed."""
        one = jax.tree_util.tree_map(lambda a: np.asarray(a)[t], self)
        keep = np.asarray(one.valid)
        return one._replace(**{
            name: jax.tree_util.tree_map(lambda a: a[keep], getattr(one, name))
            for name in one._fields if name not in PER_RAY
        })

    def mutual_gaze_pairs(self) -> np.ndarray:
        """``(P, 2)`` person indices ``i < j`` of the pairs in mutual gaze (single frame), or,
        for a recording, ``(P, 3)`` rows ``(frame index, i, j)``."""
        partner = np.full(np.shape(self.membership), -1) if self.mutual_gaze is None else np.asarray(self.mutual_gaze)
        index = np.argwhere(np.arange(partner.shape[-1]) < partner)
        return np.concatenate([index, partner[tuple(index.T)][:, None]], axis=1).astype(np.int64)


#: Fields of :class:`Concurrences` with one entry per ray, not per mode.
PER_RAY = ("membership", "mutual_gaze")


class Tracks(NamedTuple):
    """Concurrences linked over frames. ``track_ids[t, k]`` is −1 for padding."""

    track_ids: Int[Array, "T K"]
    num_tracks: Int[Array, ""]

    def trajectories(self, concurrences: Concurrences) -> dict[int, dict[str, np.ndarray]]:
        """``{track id: {"frames", "locations", "birth", "death"}}`` on the host."""
        ids = np.asarray(self.track_ids)
        locations = np.asarray(concurrences.locations)
        out = {}
        for track in range(int(self.num_tracks)):
            frames, slots = np.nonzero(ids == track)
            if len(frames) == 0:
                continue
            order = np.argsort(frames)
            frames, slots = frames[order], slots[order]
            out[track] = {
                "frames": frames,
                "locations": locations[frames, slots],
                "birth": int(frames[0]),
                "death": int(frames[-1]),
            }
        return out
