"""Options of the concurrence search (Park et al. 2012, Sec. 3.3): :class:`ConcurrenceOptions`."""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np

__all__ = ["ConcurrenceOptions", "DEFAULT_SEED_DEPTHS"]

#: Depths (metres) at which seeds are placed along each primary ray.
DEFAULT_SEED_DEPTHS = tuple(float(x) for x in np.geomspace(0.4, 16.0, 16))


@dataclasses.dataclass(frozen=True)
class ConcurrenceOptions:
    """Options of the concurrence search (Park et al. 2012, Sec. 3.3); frozen, validated, hashable.

    One object serves :func:`~jaxgaze.concurrence.find_concurrences`, :func:`~jaxgaze.concurrence.find_concurrences_over_frames`
    and :func:`~jaxgaze.concurrence.propagate_to_concurrences`, and is the static
    argument of their compiled programs. Vary one field with
    ``dataclasses.replace(options, min_rays=3)``.

    Attributes:
        seed_depths: depths (m) of the mean-shift seeds along every ray.
        bounds: optional world-frame box ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]``
            (m; ``±inf`` allowed) where points of regard can lie, e.g. above the
            floor of the room. Modes outside it are rejected — a flat prior on the
            scene volume that removes chance crossings of two rays behind a wall or
            under the floor, which otherwise compete with real two-ray concurrences.
        floor_below_eyes: the floor is taken to lie at most this far (m) below the
            lowest eye of the frame (world +z up): modes lower than that are rejected,
            as if ``bounds`` had ``zmin = min_i p_i,z − floor_below_eyes`` (with
            ``bounds`` too, the higher floor counts). The default 2.5 m holds for
            standing adults (eyes 1.5–1.9 m above the floor they stand on) with room
            for the location's error; it removes two rays crossing under the floor by
            chance (on the simulated meeting, 3.5 m below the eyes). ``None`` turns it
            off, e.g. for spectators in a stand looking down at a field.
        min_rays: fewest rays a mode must claim to count (≥ 2).
        claim_bandwidths: a ray supports a mode if ``‖d(l, x)‖ < claim_bandwidths · search_scale · h``.
        search_scale: the mode search and the claims use the field smoothed with
            bandwidth ``search_scale · h``; locations and covariances use ``h``.
        dominance: reject a mode if one ray carries more than this share of ``Σ w``.
        merge_radius: seeds converging within this distance (m) of a mode merge into it.
        tol, max_iter: mean-shift stopping rule (step length in m, iteration cap).
        max_modes: cap on the number of modes (default ``N // min_rays``).
        prior_scale: standard deviation (m) of the weak Gaussian prior on a location.
        refine_steps: Levenberg–Marquardt steps for the location refinement (a refinement that
            runs out of them is ``max_steps_reached`` in :attr:`Concurrences.result`).

    Sequences are stored as tuples of floats and numbers as ``int``/``float``, so
    equal options hash equal. Bad values raise ``ValueError`` naming the field.
    """

    seed_depths: tuple[float, ...] = DEFAULT_SEED_DEPTHS
    bounds: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    floor_below_eyes: float | None = 2.5
    min_rays: int = 2
    claim_bandwidths: float = 3.0
    search_scale: float = 2.0
    dominance: float = 0.9
    merge_radius: float = 0.3
    tol: float = 1e-4
    max_iter: int = 500
    max_modes: int | None = None
    prior_scale: float = 100.0
    refine_steps: int = 64

    def __post_init__(self):
        def integer(name, value, least, what=""):
            real = not isinstance(value, bool) and isinstance(value, (int, np.integer, float, np.floating))
            if not (real and math.isfinite(value) and int(value) == value and value >= least):
                raise ValueError(f"{name} must be an integer ≥ {least}{what}, got {value}")
            return int(value)

        def number(name, value):
            try:
                return float(value)
            except (TypeError, ValueError):
                raise ValueError(f"{name} must be a number, got {value!r}") from None

        set_ = functools.partial(object.__setattr__, self)
        set_("min_rays", integer("min_rays", self.min_rays, 2, " (a concurrence needs two people)"))
        set_("dominance", number("dominance", self.dominance))
        if not 0 < self.dominance <= 1:
            raise ValueError(f"dominance must lie in (0, 1], got {self.dominance}")
        for name in ("claim_bandwidths", "search_scale", "merge_radius", "tol", "prior_scale"):
            value = number(name, getattr(self, name))
            if not value > 0:
                raise ValueError(f"{name} must be positive, got {value}")
            set_(name, value)
        if self.floor_below_eyes is not None:
            value = number("floor_below_eyes", self.floor_below_eyes)
            if not (value > 0 and math.isfinite(value)):
                raise ValueError(f"floor_below_eyes must be a positive number of metres or None, got {value}")
            set_("floor_below_eyes", value)
        set_("max_iter", integer("max_iter", self.max_iter, 1))
        set_("refine_steps", integer("refine_steps", self.refine_steps, 1))
        if self.max_modes is not None:
            set_("max_modes", integer("max_modes", self.max_modes, 0, " or None"))
        try:
            depths = np.asarray(self.seed_depths, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            depths = np.zeros(0)
        if depths.size == 0 or not np.all(np.isfinite(depths)) or np.any(depths <= 0):
            raise ValueError("seed_depths must be a non-empty list of positive, finite depths (metres)")
        set_("seed_depths", tuple(float(d) for d in depths))
        if self.bounds is not None:
            try:
                box = np.asarray(self.bounds, dtype=float)
            except (TypeError, ValueError):
                box = np.zeros(0)
            if box.shape != (2, 3) or np.any(np.isnan(box)) or not np.all(box[0] < box[1]):
                raise ValueError(
                    f"bounds must be [[xmin, ymin, zmin], [xmax, ymax, zmax]] with min < max, got {self.bounds!r}"
                )
            set_("bounds", tuple(tuple(float(v) for v in row) for row in box))
