"""The concurrence search of one frame or a whole recording (Park et al. 2012, Sec. 3.3).

:func:`find_concurrences` pads a frame's rays to a shared size and runs the compiled
per-frame pipeline (:mod:`jaxgaze.concurrence.frame`); :func:`find_concurrences_over_frames`
runs it over batches of frames, sized to keep XLA:CPU's batched LAPACK calls safe
(:func:`batch_plan`), cold or warm-started in lanes of consecutive frames.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxgaze._batching import (
    lapack_eigh_cost,
    lapack_guard_applies,
    lapack_qr_cost,
    lapack_safe_batch,
    map_in_batches,
    repeat_last,
)
from jaxgaze._checks import bucket_size
from jaxgaze.concurrence.claims import mutual_gaze
from jaxgaze.concurrence.field import ray_projector
from jaxgaze.concurrence.frame import concurrences_one_frame, warm_frame
from jaxgaze.concurrence.options import ConcurrenceOptions
from jaxgaze.concurrence.recentre import moved_back, recentred
from jaxgaze.concurrence.types import PER_RAY, Concurrences
from jaxgaze.rays import GazeRays, check_units
from jaxgaze.results import RESULTS

__all__ = [
    "find_concurrences",
    "find_concurrences_over_frames",
    "prepare",
    "empty_concurrences",
    "batch_plan",
    "search_frames",
    "MAX_RAYS_PER_FRAME",
    "MAX_FRAMES_PER_BATCH",
    "WARM_START_MIN_FRAMES",
    "LANE_FRAMES",
]

_STATIC = ("options", "max_modes", "modes_per_batch")
_one_frame_jit = jax.jit(concurrences_one_frame, static_argnames=_STATIC)
#: The compiled search of a batch of frames, ``search_frames(rays (B, N), depths, region, **static)`` with the
#: arguments of :func:`prepare`. jax.vmap does not forward keyword arguments to in_axes, so wrap explicitly.
search_frames = jax.jit(
    lambda rays, depths, bounds, **kw: jax.vmap(lambda r: concurrences_one_frame(r, depths, bounds, **kw))(rays),
    static_argnames=_STATIC,
)


def prepare(rays, options):
    """``(seed depths, (bounds box, floor below the eyes), static keywords)`` of the compiled programs
    for ``rays``. The box and the floor are arguments, not part of the static options, so that
    changing them does not compile the program again."""
    if not isinstance(rays, GazeRays):
        raise TypeError(f"expected jaxgaze.GazeRays, got {type(rays).__name__}")
    if not isinstance(options, ConcurrenceOptions):
        raise TypeError(f"options must be a jaxgaze.ConcurrenceOptions, got {type(options).__name__}")
    if rays.num_rays > MAX_RAYS_PER_FRAME:
        raise ValueError(
            f"{rays.num_rays} people in one frame: the concurrence search handles at most {MAX_RAYS_PER_FRAME} "
            f"(its memory grows with the square of the people, {_search_gib(rays.num_rays):.0f} GiB here)")
    dtype = rays.origins.dtype
    box = np.array([[-np.inf] * 3, [np.inf] * 3]) if options.bounds is None else np.asarray(options.bounds)
    floor = np.inf if options.floor_below_eyes is None else options.floor_below_eyes
    n = rays.num_rays
    k = n // options.min_rays if options.max_modes is None else min(options.max_modes, n // options.min_rays)
    program_options = dataclasses.replace(options, bounds=None, floor_below_eyes=None)
    static = dict(options=program_options, max_modes=k, modes_per_batch=batch_plan(n, k)[1])
    # device_put of host arrays compiles nothing (jnp.asarray would compile a conversion per process).
    host = lambda a: jax.device_put(np.asarray(a, dtype=dtype))  # noqa: E731
    return host(options.seed_depths), (host(box), host(floor)), static


#: Most rays (people) in one frame: the search holds several ``(seeds, rays)`` arrays, ``16 N × N``
#: floats each, so its memory grows as ``N²`` (3,000 people took 6.1 GB and 275 s; 10,000 would need 46 GB).
MAX_RAYS_PER_FRAME = 2048


def _search_gib(n: int) -> float:
    """Rough peak memory (GiB) of one frame's search with ``n`` rays: 46 GB measured at 10,000, as ``n²``."""
    return 46e9 / 2**30 * (n / 10_000) ** 2


#: Frames per compiled batch on XLA:CPU when the LAPACK bound allows more.
MAX_FRAMES_PER_BATCH = 64


def _lapack_cost_per_mode(n: int) -> int:
    """Largest LAPACK flop estimate that one mode adds to a batched call.

    The Levenberg–Marquardt step solves the damped ``(3n + 3) × 3`` least-squares
    system by QR, the covariance takes the QR of ``[J; I/s]`` (the same shape) and the
    region an ``eigh`` of a ``3 × 3``.
    """
    return max(lapack_qr_cost(3 * n + 3, 3), lapack_eigh_cost(3))


def batch_plan(n: int, k: int) -> tuple[int, int]:
    """``(frames, modes)`` per batched LAPACK call that keep XLA:CPU clear of its deadlock.

    On other backends every frame and mode go in one batch (frames ``0`` means all).
    """
    if k == 0 or not lapack_guard_applies():
        return 0, max(k, 1)
    per_mode = _lapack_cost_per_mode(n)
    modes = lapack_safe_batch(per_mode, k)
    frames = lapack_safe_batch(k * per_mode, MAX_FRAMES_PER_BATCH) if modes == k else 1
    return frames, modes


def _masked_padding(rays: GazeRays, size: int) -> GazeRays:
    """Pad a ``(B, N)`` slice to ``size`` frames with empty frames (every ray masked)."""
    padded = repeat_last(rays, size)
    mask = np.array(padded.mask)
    mask[rays.batch_shape[0]:] = False
    return eqx.tree_at(lambda r: r.mask, padded, mask)


@functools.partial(jax.jit, static_argnames=("radius",))
def _mutual_gaze_over_frames(rays: GazeRays, radius: float):
    return jax.vmap(lambda r: mutual_gaze(ray_projector(r), radius))(rays)


def empty_concurrences(rays: GazeRays, options: ConcurrenceOptions) -> Concurrences:
    """No mode (too few rays for ``min_rays``); people may still look at each other."""
    batch_shape, n, dtype = rays.batch_shape, rays.num_rays, rays.origins.dtype
    # Host arrays sent to the device once: eager jnp.zeros/full would compile a program per shape.
    z = lambda *s, dt=dtype: np.zeros(batch_shape + (0,) + s, dt)  # noqa: E731
    partner = np.full(batch_shape + (n,), -1, np.int32)
    if n >= 2 and math.prod(batch_shape) > 0:
        flat = jax.tree_util.tree_map(lambda a: np.asarray(a).reshape((-1,) + a.shape[len(batch_shape):]), rays)
        radius = options.claim_bandwidths * options.search_scale
        partner = np.asarray(_mutual_gaze_over_frames(flat, radius)).reshape(batch_shape + (n,))
    return Concurrences(**jax.device_put(dict(
        locations=z(3), covariances=z(3, 3), field_values=z(), num_rays=z(dt=np.int32),
        membership=np.full(batch_shape + (n,), -1, np.int32), region_axes=z(3, 3),
        region_semi_axes=z(3), converged=z(dt=bool), valid=z(dt=bool), degrees_of_freedom=z(),
        mutual_gaze=partner, result=jax.tree_util.tree_map(lambda _: z(dt=np.int32), RESULTS.successful),
    )))


def find_concurrences(
    rays: GazeRays,
    options: ConcurrenceOptions = ConcurrenceOptions(),
) -> Concurrences:
    """Number, locations and uncertainty of the gaze concurrences in one frame (Park et al. 2012, Sec. 3.3).

    Args:
        rays: one frame of primary gaze rays, ``(N, 3)``, world frame, metres.
        options: the search options, a :class:`ConcurrenceOptions` (seeds, bounds,
            ``min_rays``, claim and merge radii, stopping rules, prior, ``max_modes``).

    Returns:
        :class:`Concurrences` with exactly the ``K`` modes found, ordered by
        decreasing field value. One ray or none gives ``K = 0``.

    What is not a concurrence (the defaults, documented in ``docs/index.md``):

    * **Under the floor.** Modes more than ``options.floor_below_eyes`` (2.5 m) below
      the lowest eye of the frame (world +z up) are rejected.
    * **Mutual gaze.** Two people whose eyes each lie in the other's ray's claim
      radius (``claim_bandwidths · search_scale · h``) look at each other. Their two
      rays alone make a flat ridge between the eyes, not a point of regard: a mode
      supported only by such a pair is rejected, and the pair is reported in
      ``mutual_gaze`` (each person's partner, or −1). Either may still support a
      concurrence with others, e.g. a third person looking at the same face.
    * **Unbounded.** A mode whose rays leave it unbounded in some direction (the
      weak prior, not the rays, holds it: ``tr Σ_L ≥ prior_scale²/2``) is rejected,
      so a reported covariance always comes from the rays.

    Units are checked at the door (:func:`jaxgaze.rays.check_units`): a bandwidth of
    1 rad or more is an error, one over 0.5 rad or eyes of one frame spread over more
    than 100 m a :class:`~jaxgaze.rays.UnitWarning` (degrees? millimetres?).

    Precision: float32 and float64 rays give the same modes and memberships and agree
    to within 10 µm on the locations (below the mean-shift stopping step of 0.1 mm;
    scenes within tens of metres of the origin) and 1e-5 relative on the covariances
    and field values. A scene farther than ``RECENTRE_DISTANCE`` (1 km) from the world
    origin is searched around its mean eye and its locations come back in float64
    (docs/conventions.md, "Far from the origin"): 5,000 km away it gives the same answer.
    More than ``MAX_RAYS_PER_FRAME`` (2,048) rays in a frame is a ``ValueError``.
    """
    if isinstance(rays, GazeRays) and rays.batch_shape:
        raise ValueError(
            f"find_concurrences takes one frame; rays have batch shape {rays.batch_shape}. "
            "Use find_concurrences_over_frames for a recording."
        )
    rays, options, reference = recentred(rays, options)
    if prepare(rays, options)[2]["max_modes"] == 0:
        check_units(rays)
        return empty_concurrences(rays, options)
    n = rays.num_rays
    # Pad to at least 24 rays, and above that to a multiple of 8, so that scenes of
    # similar size share one compilation: every scene of up to 24 people runs one
    # program (one compilation of ~5 s; a 4-person frame then takes ~50 ms, not ~10).
    # Padded rays are masked and can never be claimed, so K stays ≤ n // min_rays.
    padded = _pad_rays(rays, bucket_size(n, minimum=24, multiple=_RAY_BUCKET))
    check_units(rays)
    depths, box, static = prepare(padded, options)
    # The kept modes are selected on the host: eager indexing of device arrays would
    # compile small programs for every new (N, K) pair.
    result = jax.device_get(_one_frame_jit(padded, depths, box, **static))
    keep = result.valid
    found = Concurrences(
        **jax.device_put({
            name: jax.tree_util.tree_map(lambda a: a[:n] if name in PER_RAY else a[keep], value)
            for name, value in result._asdict().items()
        })
    )
    return moved_back(found, reference)


_RAY_BUCKET = 8


def _pad_rays(rays: GazeRays, n: int) -> GazeRays:
    extra = n - rays.num_rays
    if extra == 0:
        return rays
    # On the host (the rays are concrete here), so that no program is compiled per size.
    pad = lambda a: np.concatenate([np.asarray(a), np.zeros((extra,) + a.shape[1:], a.dtype)])  # noqa: E731
    return GazeRays(pad(rays.origins), pad(rays.directions), pad(rays.bandwidth), pad(rays.mask))


def find_concurrences_over_frames(
    rays: GazeRays,
    options: ConcurrenceOptions = ConcurrenceOptions(),
    *,
    frames_per_batch: int | None = None,
    progress: bool = False,
    warm_start: bool | None = None,
) -> Concurrences:
    """:func:`find_concurrences` for a whole recording, vmapped over batches of frames (Park et al. 2012, Sec. 3.3).

    ``rays`` has shape ``(T, N, 3)`` with ``rays.mask`` marking the people
    present in each frame (see :meth:`GazeRays.stack`); ``options`` is a
    :class:`ConcurrenceOptions`. The result is padded to
    ``K = options.max_modes`` (default ``N // min_rays``) modes per frame; ``valid``
    marks the real ones and ``count`` gives K per frame. Its arrays are numpy
    arrays on the host.

    **Warm start** (by default for recordings of at least
    ``WARM_START_MIN_FRAMES`` (1,024) frames, whose time it saves exceeds the
    compilation of its program; ``warm_start=True`` for any of at least
    ``2 · LANE_FRAMES``). Consecutive frames are nearly equal, so the
    recording is cut into lanes of ``LANE_FRAMES`` (64) consecutive frames; each
    lane's first frame is searched from the full seed set, and every later frame
    from the previous frame's modes plus ``FRESH_SEEDS_PER_RAY`` (4) fresh seeds per
    ray, at depths that rotate through ``seed_depths`` from frame to frame, with at
    most ``WARM_MAX_ITER`` mean-shift steps. A frame where two rays that support no
    mode still cross within each other's claim radius (a concurrence the warm seeds
    may have missed) is searched again from the full seed set. On the simulated
    recordings this gives the full search's count in every frame and its locations
    to within 1 cm for ≥ 99.8 % of the modes (the others: a ray about as close to two
    groups, grouped differently), at a fraction of the cost. ``warm_start=False``
    searches every frame from the full seed set, e.g. for frames that are not
    consecutive in time. Lanes start at fixed frames, so the answer does not depend
    on the batching.

    The frames (lanes) go through one compiled program of ``frames_per_batch``
    frames (lanes; the last batch is padded with empty frames), so recordings of
    any length share one compilation. On CPU the default is the largest batch, at
    most ``MAX_FRAMES_PER_BATCH``, whose batched LAPACK calls stay below the size
    at which XLA:CPU splits them over its thread pool and can deadlock (see
    ``docs/runtime.md``); a larger ``frames_per_batch`` is refused there. Batches
    run on one host thread per core. On GPU every frame goes in one batch.
    With several local devices each batch is split over them (a ``Mesh`` and a
    ``NamedSharding`` over the frame axis); under ``jax.distributed.initialize`` each
    process computes a contiguous share of the batches and every process returns the
    whole result. The answer does not depend on the number of devices or processes
    (``docs/runtime.md``, "Many devices and many machines").
    ``progress`` shows a bar of frames (lanes) done on stderr. What is not a concurrence, the
    unit checks and scenes far from the world origin: as for :func:`find_concurrences`.
    """
    if not isinstance(rays, GazeRays) or len(rays.batch_shape) != 1:
        shape = rays.batch_shape if isinstance(rays, GazeRays) else None
        raise ValueError(f"find_concurrences_over_frames needs rays of shape (T, N, 3); batch shape is {shape}")
    rays, options, reference = recentred(rays, options)
    depths, box, static = prepare(rays, options)
    check_units(rays)
    total = rays.batch_shape[0]
    if static["max_modes"] == 0 or total == 0:
        return jax.tree_util.tree_map(np.asarray, empty_concurrences(rays, options))
    safe, _ = batch_plan(rays.num_rays, static["max_modes"])
    if frames_per_batch is None:
        batch = safe or total
    else:
        if int(frames_per_batch) != frames_per_batch or frames_per_batch < 1:
            raise ValueError(f"frames_per_batch must be a positive integer, got {frames_per_batch!r}")
        batch = int(frames_per_batch)
        if safe and batch > safe:
            raise ValueError(
                f"frames_per_batch={batch} is too large on CPU for {rays.num_rays} rays: at most {safe} frames keep "
                "XLA:CPU's batched LAPACK calls from deadlocking (see docs/runtime.md)"
            )
    cold = functools.partial(_cold_frames, depths=depths, box=box, static=static)
    if warm_start is None:
        warm_start = total >= WARM_START_MIN_FRAMES
    if not warm_start or total < 2 * LANE_FRAMES:
        found = map_in_batches(cold, rays, batch, pad=_masked_padding, progress=progress, desc="concurrences")
    else:
        found = _warm_started(rays, cold, depths, box, static, batch, progress)
    return moved_back(found, reference)


def _cold_frames(part: GazeRays, *, depths, box, static) -> Concurrences:
    return search_frames(part, depths, box, **static)


def _empty_lanes(part, size: int):
    """Pad a batch of lanes ``(rays, first locations, first valid, first frame)`` with empty lanes
    (every ray masked, no previous mode), whose mean-shift stops at once."""
    rays, locations, valid, frames = repeat_last(part, size)
    count = part[0].batch_shape[0]
    mask, valid = np.array(rays.mask), np.array(valid)
    mask[count:], valid[count:] = False, False
    return eqx.tree_at(lambda r: r.mask, rays, mask), locations, valid, frames


def _warm_started(rays: GazeRays, cold, depths, box, static, batch: int, progress: bool) -> Concurrences:
    """The recording in lanes of ``LANE_FRAMES`` consecutive frames: each lane's first frame from the full
    seed set, the others warm-started (:func:`_warm_lanes`), and the frames left with unexplained rays
    searched again from the full seed set. Lanes start at fixed frames, so the answer does not depend on
    how the lanes are batched or spread over devices."""
    total = rays.batch_shape[0]
    lanes = -(-total // LANE_FRAMES)
    host = _masked_padding(jax.tree_util.tree_map(np.asarray, rays), lanes * LANE_FRAMES)
    starts = np.arange(lanes) * LANE_FRAMES
    first = map_in_batches(cold, jax.tree_util.tree_map(lambda a: a[starts], host), batch, pad=_masked_padding,
                           progress=progress, desc="concurrences, first frame of each lane")
    in_lanes = jax.tree_util.tree_map(lambda a: a.reshape((lanes, LANE_FRAMES) + a.shape[1:])[:, 1:], host)
    warm, unexplained = map_in_batches(
        lambda part: _warm_lanes_jit(*part, depths, box, **static),
        (in_lanes, first.locations, first.valid, starts.astype(np.int32)), batch, pad=_empty_lanes,
        progress=progress, desc=f"concurrences, {LANE_FRAMES}-frame lanes", unit="lane",
    )
    joined = jax.tree_util.tree_map(
        lambda a, b: np.concatenate([a[:, None], b], axis=1).reshape((lanes * LANE_FRAMES,) + a.shape[1:])[:total],
        first, warm,
    )
    again = np.flatnonzero(np.concatenate([np.zeros((lanes, 1), bool), unexplained], axis=1).reshape(-1)[:total])
    if again.size:
        searched = map_in_batches(cold, jax.tree_util.tree_map(lambda a: np.asarray(a)[again], rays), batch,
                                  pad=_masked_padding)
        for full, part in zip(jax.tree_util.tree_leaves(joined), jax.tree_util.tree_leaves(searched)):
            full[again] = part
    return joined


# ---------------------------------------------------------------------------
# Warm starts: a frame's seeds from the previous frame's modes


#: Shortest recording warm-started by default: shorter ones cost less than compiling the warm program.
WARM_START_MIN_FRAMES = 1024
#: Frames per lane of the warm-started batch path; every lane starts cold.
LANE_FRAMES = 64


def _warm_lanes(rays, first_locations, first_valid, first_frame, seed_depths, region, **static):
    """Frames ``1 … L−1`` of ``B`` lanes, each warm-started from the one before: a ``lax.scan`` over
    time of the frames vmapped over lanes. Returns ``(Concurrences (B, L−1, …), unexplained (B, L−1))``."""
    time_major = jax.tree_util.tree_map(lambda a: jnp.swapaxes(a, 0, 1), rays)
    one = functools.partial(warm_frame, seed_depths=seed_depths, region=region, **static)

    def step(carry, frame_rays):
        locations, valid, frame = carry
        found, unexplained = jax.vmap(lambda r, loc, ok, t: one(r, (loc, ok), t))(frame_rays, locations, valid, frame)
        return (found.locations, found.valid, frame + 1), (found, unexplained)

    _, (found, unexplained) = jax.lax.scan(step, (first_locations, first_valid, first_frame + 1), time_major)
    return jax.tree_util.tree_map(lambda a: jnp.swapaxes(a, 0, 1), (found, unexplained))


_warm_lanes_jit = jax.jit(_warm_lanes, static_argnames=_STATIC)
