"""Primary gaze rays: the validated input type of the cone and concurrence models."""

from __future__ import annotations

import math
import warnings
from typing import Iterator, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from jaxgaze.geometry import unit

__all__ = ["GazeRays", "UnitWarning", "check_units", "check_bandwidth", "check_distance", "MAX_BANDWIDTH", "MIN_BANDWIDTH",
           "PLAUSIBLE_BANDWIDTH", "PLAUSIBLE_SCENE_EXTENT"]

_MIN_DIRECTION_NORM = 1e-9

#: No gaze cone is this wide (radians, 57°): a bandwidth this large is an error (degrees given as radians?).
MAX_BANDWIDTH = 1.0
#: No gaze cone is this narrow (radians, 0.2″; the best eye trackers reach about 0.005): below it float32, whose
#: unit directions carry a rounding of 2⁻²⁴ ≈ 6e-8, cannot resolve the cone, and ``1/h³`` overflows near 1e-13.
MIN_BANDWIDTH = 1e-6
#: A gaze cone wider than this (radians, 29°; head pose alone gives about 0.2–0.3) is implausible: a warning.
PLAUSIBLE_BANDWIDTH = 0.5
#: The eyes of one frame spread over more than this (metres) are implausible for one scene: a warning (millimetres?).
PLAUSIBLE_SCENE_EXTENT = 100.0


class UnitWarning(UserWarning):
    """A value outside its plausible range, most likely given in the wrong unit (degrees? millimetres?).

    The unit rule of the library: a value that **cannot** be right in its documented unit (a
    bandwidth of a radian or more, an angle beyond π) is a ``ValueError``; a value that is only
    **implausible** (one scene over :data:`PLAUSIBLE_SCENE_EXTENT` across, a cone wider than
    :data:`PLAUSIBLE_BANDWIDTH`) is this warning, so that an unusual but real setup still runs.
    The command line turns every ``UnitWarning`` into an error (exit 2) unless ``--trust-units``;
    a library user may do the same with ``warnings.simplefilter("error", UnitWarning)``.
    """


def check_bandwidth(bandwidth, what: str = "bandwidth") -> None:
    """Raise ``ValueError`` if a bandwidth ``h`` (radians) reaches :data:`MAX_BANDWIDTH`: a cone whose
    angular standard deviation is a radian or more says nothing about where a person looks,
    and the likely mistake is degrees (``3`` meant as 3° is 0.0524 rad). Also if a positive ``h``
    is below :data:`MIN_BANDWIDTH`, narrower than float32 resolves (the field's ``1/h³`` and
    ``1/2h²`` overflow, and one such ray turns its whole frame's field into NaN)."""
    h = np.asarray(bandwidth, dtype=float)
    tiny = (h > 0) & (h < float(np.float32(MIN_BANDWIDTH)))  # float32(1e-6) is just below 1e-6
    if tiny.any():
        first = tuple(np.argwhere(tiny)[0])
        where = f" of ray {_first_bad(tiny)}" if h.ndim else ""
        raise ValueError(f"{what}{where} is {float(h[first]):g} rad: narrower than float32 can resolve in the field "
                         f"(a gaze bandwidth must be at least {MIN_BANDWIDTH:g} rad)")
    if h.size and np.nanmax(h) >= MAX_BANDWIDTH:
        top = float(np.nanmax(h))
        raise ValueError(
            f"{what} {top:g} rad ({math.degrees(top):.0f}°) is no gaze cone width: it is in radians "
            f"(degrees? {top:g}° is {math.radians(top):.3g} rad)"
        )


def check_distance(distances, what: str, labels=None) -> None:
    """A :class:`UnitWarning` when the largest finite distance (metres) exceeds :data:`PLAUSIBLE_SCENE_EXTENT`
    (100 m): positions in millimetres? ``what`` names the distance, ``labels`` (one per distance, e.g. frame
    ids) the place of the largest."""
    d = np.asarray(distances, dtype=float).reshape(-1)
    d = np.where(np.isfinite(d), d, -np.inf)
    if d.size and d.max() > PLAUSIBLE_SCENE_EXTENT:
        i = int(np.argmax(d))
        where = "" if labels is None else f" (frame {np.asarray(labels).reshape(-1)[i]})"
        warnings.warn(f"{what} reaches {d[i]:.4g} m{where}, implausibly far for one scene (more than "
                      f"{PLAUSIBLE_SCENE_EXTENT:g} m): positions are in metres (millimetres?)", UnitWarning,
                      stacklevel=3)


def check_units(rays: "GazeRays") -> None:
    """Catch unit mistakes at the door of the concurrence search (concrete rays only).

    * A bandwidth of :data:`MAX_BANDWIDTH` (1 rad) or more, or below :data:`MIN_BANDWIDTH`, is an error
      naming the ray (:func:`check_bandwidth`).
    * A bandwidth over :data:`PLAUSIBLE_BANDWIDTH` (0.5 rad) is a :class:`UnitWarning` (degrees?).
    * Eyes of one frame spread over more than :data:`PLAUSIBLE_SCENE_EXTENT` (100 m, the largest
      coordinate range of the frame's real rays) is a :class:`UnitWarning` (millimetres?): in
      millimetres a room is thousands of "metres" across and no concurrence is found.
    These are warnings, not errors (the rule: :class:`UnitWarning`); ``jaxgaze`` commands stop on them.
    """
    if not _is_concrete(rays.origins, rays.bandwidth, rays.mask):
        return
    mask = np.asarray(rays.mask, dtype=bool)
    if not mask.any():
        return
    check_bandwidth(np.where(mask, np.asarray(rays.bandwidth, dtype=float), np.nan))
    h = np.asarray(rays.bandwidth, dtype=float)[mask]
    if h.max() > PLAUSIBLE_BANDWIDTH:
        warnings.warn(f"bandwidth reaches {h.max():g} rad ({math.degrees(h.max()):.0f}°), implausibly wide for a "
                      f"gaze cone: it is in radians (degrees? {h.max():g}° is {math.radians(h.max()):.3g} rad)",
                      UnitWarning, stacklevel=3)
    origins = np.asarray(rays.origins, dtype=float).reshape(-1, mask.shape[-1], 3)
    frames = mask.reshape(-1, mask.shape[-1])
    high = np.where(frames[..., None], origins, -np.inf).max(axis=1)
    low = np.where(frames[..., None], origins, np.inf).min(axis=1)
    spread = np.where(frames.any(axis=1), (high - low).max(axis=1), 0.0)
    if spread.max() > PLAUSIBLE_SCENE_EXTENT:
        frame = int(np.argmax(spread))
        where = f"frame {frame}" if len(spread) > 1 else "the frame"
        warnings.warn(f"the eyes of {where} spread over {spread.max():.4g} m, implausibly far for one scene: "
                      "origins are in metres (millimetres?)", UnitWarning, stacklevel=3)


def _is_concrete(*arrays) -> bool:
    return not any(isinstance(a, jax.core.Tracer) for a in arrays)


def _first_bad(bad: np.ndarray) -> str:
    index = tuple(int(i) for i in np.argwhere(bad)[0])
    return str(index[0]) if len(index) == 1 else str(index)


class GazeRays(eqx.Module):
    """Primary gaze rays ``l_i = (p_i, v_i)`` in the **world** frame (metres).

    Park et al. (2012), Sec. 3.1: ``p`` is the centre of the eyes, ``v`` the
    primary gaze direction, and the bandwidth ``h`` the standard deviation of
    the eye-in-head deviation on the plane at unit depth (radians, small-angle).

    Shapes carry any number of leading batch axes (e.g. frames):
    ``origins (..., N, 3)``, ``directions (..., N, 3)``, ``bandwidth`` scalar or
    ``(..., N)``, ``mask (..., N)`` (``True`` = a real ray; ``False`` = padding).

    On construction directions are normalised, the bandwidth is broadcast to
    ``(..., N)``, and concrete inputs are validated: a ``ValueError`` names the
    field and the first offending ray for NaN/inf, a zero-length direction, a
    non-positive bandwidth or mismatched shapes. Padded rays are not checked
    and are replaced by a harmless placeholder so that no NaN can leak. Host
    inputs (numpy arrays, lists) are prepared in numpy and sent to the device
    once, so that a new number of rays compiles nothing.
    """

    origins: Float[Array, "... N 3"]
    directions: Float[Array, "... N 3"]
    bandwidth: Float[Array, "... N"]
    mask: Bool[Array, "... N"]

    def __init__(self, origins, directions, bandwidth=0.05, mask=None):
        # Host inputs (numpy, lists, numbers) are checked and normalised in numpy and sent to
        # the device once: eager jnp ops here would compile a few small programs for every
        # new number of rays (issue 21, time to first answer). Device arrays and tracers
        # stay on the device, where they are.
        on_host = not any(isinstance(a, jax.Array) for a in (origins, directions, bandwidth, mask))
        xp = np if on_host else jnp
        if on_host:
            _check_float32_rounding(origins)
        origins = _as_canonical(origins, xp)
        directions = _as_canonical(directions, xp)
        if not jnp.issubdtype(origins.dtype, jnp.floating):
            origins = origins.astype(jnp.result_type(float))
        dtype = jnp.result_type(origins.dtype, directions.dtype, jnp.float32)
        origins = origins.astype(dtype)
        directions = directions.astype(dtype)
        bandwidth = xp.asarray(bandwidth, dtype=dtype)

        if origins.ndim < 2 or origins.shape[-1] != 3:
            raise ValueError(f"GazeRays: origins must have shape (..., N, 3), got {origins.shape}")
        if directions.shape != origins.shape:
            raise ValueError(
                f"GazeRays: directions shape {directions.shape} does not match origins shape {origins.shape}"
            )
        ray_shape = origins.shape[:-1]
        mask = xp.ones(ray_shape, dtype=bool) if mask is None else xp.asarray(mask)
        if mask.shape != ray_shape:
            raise ValueError(f"GazeRays: mask shape {mask.shape} must be {ray_shape} (one entry per ray)")
        mask = mask.astype(bool)
        try:
            bandwidth = xp.broadcast_to(bandwidth, ray_shape)
        except ValueError:
            raise ValueError(
                f"GazeRays: bandwidth shape {bandwidth.shape} must be a scalar or {ray_shape} (one per ray)"
            ) from None

        if not on_host:
            if _is_concrete(origins, directions, bandwidth, mask):
                _validate(np.asarray(origins), np.asarray(directions), np.asarray(bandwidth), np.asarray(mask))
            placeholder = jnp.zeros_like(directions).at[..., 0].set(1.0)
            self.origins = jnp.where(mask[..., None], origins, 0.0)
            self.directions = jnp.where(mask[..., None], unit(directions), placeholder)
            self.bandwidth = jnp.where(mask, bandwidth, 1.0)
            self.mask = mask
            return
        _validate(origins, directions, bandwidth, mask)
        placeholder = np.zeros_like(directions)
        placeholder[..., 0] = 1.0
        fields = (
            np.where(mask[..., None], origins, origins.dtype.type(0.0)),
            np.where(mask[..., None], _unit_host(directions), placeholder),
            np.where(mask, bandwidth, bandwidth.dtype.type(1.0)),
            mask,
        )
        self.origins, self.directions, self.bandwidth, self.mask = jax.device_put(fields)

    @property
    def num_rays(self) -> int:
        """Number of ray slots ``N`` (padding included)."""
        return self.origins.shape[-2]

    @property
    def batch_shape(self) -> tuple[int, ...]:
        """Leading batch axes, e.g. ``(T,)`` for a recording of T frames."""
        return self.origins.shape[:-2]

    def __len__(self) -> int:
        """Number of frames ``T``: the length of the leading batch axis."""
        if not self.batch_shape:
            raise TypeError("GazeRays: a single frame (no batch axis) has no length")
        return self.batch_shape[0]

    def __bool__(self) -> bool:
        """Always true, a single frame or an empty recording too (``len`` counts frames, not truth)."""
        return True

    def __iter__(self) -> Iterator["GazeRays"]:
        """The frames ``rays[0], …, rays[T − 1]`` (``for rays_t in recording.rays``)."""
        if not self.batch_shape:
            raise TypeError("GazeRays: a single frame (no batch axis) has no frames to iterate")
        return (self[t] for t in range(len(self)))

    def __getitem__(self, index) -> "GazeRays":
        """Index the batch axes, e.g. ``rays[t]`` is frame ``t``.

        A concrete integer index of the leading axis (Python, NumPy or a concrete JAX integer)
        past its end raises ``IndexError`` (``-T ≤ t < T``, negative from the end), where JAX
        alone would clamp it to the last frame; a traced index (inside ``jit``) is not checked.
        """
        if not self.batch_shape:
            raise IndexError("GazeRays: a single frame has no batch axis to index")
        _check_frame_index(index[0] if isinstance(index, tuple) and index else index, self.batch_shape[0])
        return jax.tree_util.tree_map(lambda a: a[index], self)

    @classmethod
    def stack(cls, frames: Sequence["GazeRays"]) -> "GazeRays":
        """Stack single-frame rays into a padded recording ``(T, N_max)``.

        Frames may hold different numbers of people; missing slots are masked.
        """
        if len(frames) == 0:
            raise ValueError("GazeRays.stack: no frames given")
        for i, f in enumerate(frames):
            if f.batch_shape:
                raise ValueError(f"GazeRays.stack: frame {i} already has batch shape {f.batch_shape}")
        n_max = max(max(f.num_rays for f in frames), 1)

        def padded(field, dtype):
            out = np.zeros((len(frames), n_max) + getattr(frames[0], field).shape[1:], dtype)
            for t, f in enumerate(frames):  # host-side copies; one device transfer at the end
                out[t, : f.num_rays] = np.asarray(getattr(f, field))
            return out

        dtype = np.result_type(*[np.asarray(f.origins).dtype for f in frames])
        return cls(
            padded("origins", dtype), padded("directions", dtype), padded("bandwidth", dtype), padded("mask", bool)
        )

    @classmethod
    def from_rows(cls, row_frames, origins, directions, bandwidth=0.05) -> tuple[np.ndarray, "GazeRays"]:
        """Rays given one per row with the frame of each row → ``(frame_ids, rays)``.

        ``frame_ids`` are the sorted distinct frames ``(T,)``; ``rays`` is ``(T, N_max)``
        padded and masked as by :meth:`stack`, the rows of a frame in their given order.
        ``origins``, ``directions`` ``(M, 3)``, ``bandwidth`` scalar or ``(M,)``.
        """
        row_frames = np.asarray(row_frames).reshape(-1)
        origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
        directions = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
        count = row_frames.shape[0]
        if count == 0:
            raise ValueError("GazeRays.from_rows: no rows given")
        if origins.shape[0] != count or directions.shape[0] != count:
            raise ValueError(f"GazeRays.from_rows: {count} frames but {origins.shape[0]} origins and "
                             f"{directions.shape[0]} directions")
        bandwidth = np.broadcast_to(np.asarray(bandwidth, dtype=np.float64), (count,))
        length = np.linalg.norm(directions, axis=-1, keepdims=True)
        directions = np.where(length > 0, directions / np.where(length > 0, length, 1.0), directions)  # float64
        frame_ids, frame_of_row, per_frame = np.unique(row_frames, return_inverse=True, return_counts=True)
        order = np.argsort(frame_of_row, kind="stable")
        first_row = np.concatenate([[0], np.cumsum(per_frame)[:-1]])
        slot = np.empty(count, dtype=np.int64)
        slot[order] = np.arange(count) - np.repeat(first_row, per_frame)

        def padded(values, fill):
            out = np.full((len(frame_ids), int(per_frame.max())) + values.shape[1:], fill, dtype=values.dtype)
            out[frame_of_row, slot] = values
            return out

        rays = cls(padded(origins, 0.0), padded(directions, 1.0), padded(bandwidth, 1.0),
                   padded(np.ones(count, dtype=bool), False))
        return frame_ids, rays


def _check_frame_index(index, length: int) -> None:
    """``IndexError`` for a concrete integer ``index`` outside ``[-length, length)``."""
    if isinstance(index, (bool, np.bool_)) or isinstance(index, jax.core.Tracer):
        return
    if isinstance(index, (jax.Array, np.ndarray)):
        if index.ndim != 0 or not jnp.issubdtype(index.dtype, jnp.integer):
            return
        index = int(index)
    if isinstance(index, (int, np.integer)) and not -length <= index < length:
        raise IndexError(f"GazeRays: frame index {int(index)} is out of range for {length} frame(s)")


def _as_canonical(values, xp):
    """``values`` as an array of ``xp`` (numpy or jax.numpy) with the dtype ``jnp.asarray`` would give it."""
    if xp is jnp:
        return jnp.asarray(values)
    values = np.asarray(values)
    return values.astype(jax.dtypes.canonicalize_dtype(values.dtype), copy=False)


#: Most float32 may round a float64 origin (metres) when GazeRays are made: 1 mm, reached 16 km from the world origin.
_MAX_ORIGIN_ROUNDING = 1e-3


def _check_float32_rounding(origins) -> None:
    """Refuse float64 host origins that float32 (JAX's default) would round by more than 1 mm: far from the
    world origin (UTM or ECEF coordinates: 5,000 km, where float32's grid is 0.5 m) every eye would move."""
    values = np.asarray(origins)
    if values.dtype != np.float64 or jax.dtypes.canonicalize_dtype(np.float64) == np.float64 or values.ndim < 2:
        return
    with np.errstate(over="ignore", invalid="ignore"):
        error = np.abs(values.astype(np.float32).astype(np.float64) - values)
    error = np.where(np.isfinite(error), error, 0.0).max(axis=-1)  # NaN and inf are _validate's
    if error.size and error.max() > _MAX_ORIGIN_ROUNDING:
        ray = np.unravel_index(np.argmax(error), error.shape)
        where = str(ray[0]) if len(ray) == 1 else str(tuple(int(i) for i in ray))
        raise ValueError(
            f"GazeRays: origins of ray {where} lie {np.linalg.norm(values[ray]) / 1e3:.4g} km from the world origin, "
            f"where float32 rounds them by {error.max():.2g} m: subtract a reference point (e.g. the mean eye) in "
            "float64 first, as the jaxgaze.io readers do, or enable float64 (jax_enable_x64)")


def _unit_host(v: np.ndarray) -> np.ndarray:
    """:func:`jaxgaze.geometry.unit` in numpy, in ``v``'s dtype: ``v / ‖v‖``, zero vectors stay zero."""
    with np.errstate(invalid="ignore", over="ignore"):  # NaN in padded rays, overflow as in jnp
        sq = np.sum(v * v, axis=-1, keepdims=True)
        nonzero = sq > np.finfo(v.dtype).tiny
        return np.where(nonzero, v / np.sqrt(np.where(nonzero, sq, v.dtype.type(1.0))), v.dtype.type(0.0))


def _validate(origins: np.ndarray, directions: np.ndarray, bandwidth: np.ndarray, mask: np.ndarray) -> None:
    for name, values in (("origins", origins), ("directions", directions)):
        bad = ~np.all(np.isfinite(values), axis=-1) & mask
        if bad.any():
            raise ValueError(f"GazeRays: {name} of ray {_first_bad(bad)} is not finite (NaN or inf)")
    bad = ~np.isfinite(bandwidth) & mask
    if bad.any():
        raise ValueError(f"GazeRays: bandwidth of ray {_first_bad(bad)} is not finite (NaN or inf)")
    bad = (np.linalg.norm(directions, axis=-1) < _MIN_DIRECTION_NORM) & mask
    if bad.any():
        raise ValueError(f"GazeRays: directions of ray {_first_bad(bad)} has zero length")
    bad = (bandwidth <= 0) & mask
    if bad.any():
        raise ValueError(
            f"GazeRays: bandwidth of ray {_first_bad(bad)} is {float(bandwidth[bad][0])}; it must be positive (radians)"
        )
