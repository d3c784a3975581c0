"""Simulated social scenes with ground truth (after Park, Jain & Sheikh 2012, Sec. 4).

Every scene is a set of people (eye centres moving smoothly over time) and a set
of *foci* (points that people look at: static markers, a presenter, a table
tennis ball, ...). At frame ``t`` person ``n`` looks at focus ``focus[t, n]``;
that point is their true point of regard. A focus is a **gaze concurrence**
when at least two people look at it (Park et al., Sec. 3.3).

Each person's observed *primary* gaze ray follows the cone model (Sec. 3.1)
plus head-pose error:

1. The true gaze direction is ``g = unit(target − p)``.
2. Eye-in-head deviation: ``v' = unit(g + d1 u1 + d2 u2)``, ``d1, d2 ~ N(0, h_e²)``
   with ``(g, u1, u2)`` orthonormal. The perspective distance (eq. 4) of the
   target from the ray ``(p, v')`` is then exactly ``‖d‖ = ‖(d1, d2)‖``, i.e. the
   target lies in the ray's cone with bandwidth ``h_e``.
3. Head-pose error (the camera pose from structure from motion, Sec. 3):
   ``v = R(ω) v'`` with ``ω ~ N(0, σ_h² I₃)``. The component of ω along ``v'``
   does not move the ray, so each perpendicular component gains variance σ_h².

The bandwidth reported on the rays is therefore
``h = sqrt(h_e² + σ_h²)``, the per-axis spread of ``d(l, target)`` that the
calibration of Sec. 3.2 would measure, so the downstream likelihood is
calibrated (``E‖d‖² = 2h²``). Both noises are drawn independently per frame
and person.

All positions are world frame (z up, metres), angles in radians, and all
randomness comes from the ``jax.random`` key. Motion and noise for all frames
are generated in one vectorised pass (no loop over frames).

Presets (``PRESETS``), defaults in :func:`scene_config`:

===========  =====  ======  ====  =========  ======================================
preset       N      foci    T     h_e, σ_h   story
===========  =====  ======  ====  =========  ======================================
``mocap``    6      2       120   .02, .01   Sec. 4.1: 2 static markers, 3 people
                                             each, walking 2–4.5 m around them in an
                                             8.3 × 17.7 × 4.3 m volume; one person
                                             at a time briefly looks at the other
                                             marker. Count 2 throughout.
``meeting``  11     3       150   .02, .01   Sec. 4.2: seated groups of 6 and 5
                                             (2) → presenter in the middle (1) →
                                             groups (2); thirds of the frames.
``party``    11     4       120   .02, .01   Sec. 4.2: couch 3, bar table 3, table
                                             tennis 3, pool 2 (4) → everyone walks
                                             over to watch table tennis (1).
``musical``  7      2       120   .02, .01   Sec. 4.2: a seated row 8–12 m from the
                                             stage; attention alternates between
                                             two groups of actors (quarters).
===========  =====  ======  ====  =========  ======================================

The default noise, ``h_e = 0.02`` rad (1.15°, eye-in-head) and
``σ_h = 0.01`` rad (0.57°, head pose), gives ``h ≈ 0.022`` rad, i.e. a lateral
spread of about 7 cm per ray and axis at 3.3 m (the median viewing distance
in ``mocap``). Triangulating three such rays gives errors of about
10 ± 7 cm, the scale of the 10.1 ± 5.73 cm that Park et al. report on their
motion-capture evaluation. Frame rate 10 fps for every preset.
"""

from __future__ import annotations

import math
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from jaxgaze._checks import check_int, check_key, check_number
from jaxgaze.geometry import axis_angle_to_rotation_matrix, orthonormal_basis, unit
from jaxgaze.rays import GazeRays
from jaxgaze.simulate._random import Pool, smooth

__all__ = ["PRESETS", "Scene", "SceneConfig", "scene_config", "simulate_scene", "primary_rays"]

PRESETS = ("mocap", "meeting", "party", "musical")

# Capture volume of the motion-capture evaluation (Park et al. Sec. 4.1), centred on x, y.
MOCAP_VOLUME = (8.3, 17.7, 4.3)

_DEFAULTS = {
    #           frames, eye_in_head, head_noise
    "mocap": (120, 0.02, 0.01),
    "meeting": (150, 0.02, 0.01),
    "party": (120, 0.02, 0.01),
    "musical": (120, 0.02, 0.01),
}
_DEFAULT_FPS = 10.0


class SceneConfig(NamedTuple):
    """Settings of a simulated scene: which preset, how long, how noisy.

    ``eye_in_head`` (h_e) and ``head_noise`` (σ_h) are standard deviations in
    radians; ``fps`` sets the time step of the people's motion.
    """

    preset: str
    num_frames: int
    eye_in_head: float
    head_noise: float
    fps: float = _DEFAULT_FPS


class Scene(NamedTuple):
    """A simulated recording with ground truth (``T`` frames, ``N`` people, ``M`` foci).

    Attributes:
        rays: observed primary gaze rays, batch shape ``(T, N)``; bandwidth
            ``sqrt(eye_in_head² + head_noise²)`` on every ray.
        targets: ``(T, N, 3)`` true point of regard of each person.
        attending: ``(T, N)`` index of the true concurrence the person looks at,
            or −1 when their focus is shared by nobody else in that frame.
        concurrences: ``(T, M, 3)`` location of every focus; a true concurrence
            where ``concurrence_valid``. Invalid entries keep the focus position.
        concurrence_valid: ``(T, M)`` focus attended by ≥ 2 people.
        focus: ``(T, N)`` focus each person looks at, shared or not.
        phase: ``(T,)`` nominal phase of the story (individual switches are
            staggered by a few frames around the phase boundaries).
        name: preset name.
        eye_in_head, head_noise: noise standard deviations (radians).
        fps: frames per second.
    """

    rays: GazeRays
    targets: Float[Array, "T N 3"]
    attending: Int[Array, "T N"]
    concurrences: Float[Array, "T M 3"]
    concurrence_valid: Bool[Array, "T M"]
    focus: Int[Array, "T N"]
    phase: Int[Array, " T"]
    name: str
    eye_in_head: float
    head_noise: float
    fps: float

    @property
    def true_count(self) -> Int[Array, " T"]:
        """Number of true concurrences per frame."""
        return jnp.sum(self.concurrence_valid, axis=-1)

    @property
    def num_frames(self) -> int:
        return self.targets.shape[0]

    @property
    def num_people(self) -> int:
        return self.targets.shape[1]

    @property
    def bandwidth(self) -> float:
        """``sqrt(eye_in_head² + head_noise²)`` (radians), the bandwidth on the rays."""
        return math.hypot(self.eye_in_head, self.head_noise)


# ---------------------------------------------------------------------------
# Configuration


def scene_config(preset: str) -> SceneConfig:
    """Default :class:`SceneConfig` of a preset (see the module docstring)."""
    if preset not in _DEFAULTS:
        raise ValueError(f"unknown scene preset {preset!r}; choose one of {PRESETS}")
    frames, eye, head = _DEFAULTS[preset]
    return SceneConfig(preset, frames, eye, head, _DEFAULT_FPS)


def _resolve(preset, num_frames, eye_in_head, head_noise) -> SceneConfig:
    if isinstance(preset, SceneConfig):
        config = preset
        if config.preset not in _DEFAULTS:
            raise ValueError(f"SceneConfig.preset {config.preset!r} is not a preset; choose one of {PRESETS}")
    elif isinstance(preset, str):
        config = scene_config(preset)
    else:
        raise ValueError(f"preset must be a preset name {PRESETS} or a SceneConfig, got {type(preset).__name__}")
    if num_frames is not None:
        config = config._replace(num_frames=num_frames)
    if eye_in_head is not None:
        config = config._replace(eye_in_head=eye_in_head)
    if head_noise is not None:
        config = config._replace(head_noise=head_noise)

    frames = check_int("num_frames", config.num_frames)
    values = {field: check_number(field, getattr(config, field), lo=0.0) for field in ("eye_in_head", "head_noise")}
    values["fps"] = check_number("fps", config.fps, lo=0.5)
    if math.hypot(values["eye_in_head"], values["head_noise"]) <= 0:
        raise ValueError(
            "eye_in_head and head_noise are both 0: the ray bandwidth sqrt(eye_in_head² + head_noise²) "
            "must be positive"
        )
    return config._replace(num_frames=frames, **values)


# ---------------------------------------------------------------------------
# Vectorised building blocks


class _Layout(NamedTuple):
    origins: Float[Array, "T N 3"]  # eye centres
    foci: Float[Array, "T M 3"]  # points that may be looked at
    focus: Int[Array, "T N"]  # which focus each person looks at
    phase: Int[Array, " T"]


def _pool_size(num_frames: int) -> int:
    return 2048 + 3 * num_frames


def _staggered_phase(pool: Pool, num_frames: int, fractions, num_people: int, stagger: int) -> Int[Array, "T N"]:
    """Per-person phase index: person ``n`` enters phase ``j+1`` at frame
    ``round(fractions[j] T) + δ_nj``, ``δ_nj`` uniform in ``[−stagger, stagger]``."""
    bounds = jnp.round(jnp.asarray(fractions) * num_frames).astype(jnp.int32)
    delta = pool.randint((num_people, len(fractions)), -stagger, stagger + 1)
    starts = bounds[None, :] + delta  # (N, P-1)
    t = jnp.arange(num_frames)[:, None, None]
    return jnp.sum(t >= starts[None], axis=-1).astype(jnp.int32)


def _nominal_phase(num_frames: int, fractions) -> Int[Array, " T"]:
    bounds = jnp.round(jnp.asarray(fractions) * num_frames).astype(jnp.int32)
    return jnp.sum(jnp.arange(num_frames)[:, None] >= bounds[None], axis=-1).astype(jnp.int32)


def _ring(pool: Pool, center_xy, radius, count: int, jitter: float = 0.2):
    """``count`` positions evenly around a circle with a random rotation and jitter."""
    angles = 2 * math.pi * jnp.arange(count) / count + pool.uniform((), 0.0, 2 * math.pi)
    angles = angles + pool.uniform((count,), -jitter, jitter)
    return jnp.asarray(center_xy) + radius * jnp.stack([jnp.cos(angles), jnp.sin(angles)], axis=-1)


def _with_height(xy, z):
    return jnp.concatenate([xy, z[..., None]], axis=-1)


def _stagger(num_frames: int) -> int:
    return max(1, round(0.02 * num_frames))


# ---------------------------------------------------------------------------
# Presets


def _mocap(pool: Pool, num_frames: int, fps: float) -> _Layout:
    """Park et al. Sec. 4.1: 6 people, 2 static markers, 8.3 × 17.7 × 4.3 m volume.

    Markers at different heights (a low one on a stand, a high one on a wall)
    so that a ray continuing past one marker does not graze the other. Each
    person walks around their home marker: polar angle a smooth wander
    (±0.8 rad) about evenly spread starting angles, radius oscillating in
    2–4.5 m. Occasionally someone glances at the other marker: in every 10 s
    one random person does so for 1–2 s (about 15 % of the frames have a
    marker with only 2 viewers). At most one person glances at a time, so each
    marker keeps at least 2 viewers and the true count is 2 in every frame.
    """
    t = jnp.arange(num_frames) / fps
    markers = jnp.array([[-0.6, -4.0, 1.0], [0.6, 4.0, 2.2]])
    home = jnp.array([0, 0, 0, 1, 1, 1])
    start = jnp.concatenate([_ring(pool, (0.0, 0.0), 1.0, 3), _ring(pool, (0.0, 0.0), 1.0, 3)])
    start_angle = jnp.arctan2(start[:, 1], start[:, 0])
    angle = start_angle + 0.8 * smooth(pool, t, (6,), periods=(8.0, 24.0))
    radius = 3.25 + 1.25 * smooth(pool, t, (6,), periods=(6.0, 18.0))
    xy = markers[home, :2] + radius[..., None] * jnp.stack([jnp.cos(angle), jnp.sin(angle)], axis=-1)
    half = jnp.array(MOCAP_VOLUME[:2]) / 2 - 0.3
    xy = jnp.clip(xy, -half, half)
    eye = pool.uniform((6,), 1.55, 1.75)
    z = eye + 0.02 * smooth(pool, t, (6,), periods=(0.8, 1.6))  # walking bob
    origins = _with_height(xy, z)

    slot_len = max(1, round(10 * fps))  # one glance per 10 s
    num_slots = -(-num_frames // slot_len)
    who = pool.randint((num_slots,), 0, 6)
    length = jnp.round(pool.uniform((num_slots,), 1.0, 2.0) * fps)  # lasting 1–2 s
    begin = jnp.floor(pool.uniform((num_slots,)) * (slot_len - length))
    frame = jnp.arange(num_frames)
    slot = frame // slot_len
    offset = frame - slot * slot_len
    switching = (offset >= begin[slot]) & (offset < begin[slot] + length[slot])
    switched = switching[:, None] & (jnp.arange(6)[None, :] == who[slot][:, None])
    focus = jnp.where(switched, 1 - home[None, :], home[None, :]).astype(jnp.int32)
    foci = jnp.broadcast_to(markers, (num_frames, 2, 3))
    return _Layout(origins, foci, focus, jnp.zeros(num_frames, jnp.int32))


def _meeting(pool: Pool, num_frames: int, fps: float) -> _Layout:
    """Park et al. Sec. 4.2, meeting: groups of 6 and 5 → presenter → groups.

    Seated people (eye height 1.15–1.28 m) around two tables 5.2 m apart, each
    group looking at a point on its own table (0.8 m high, wandering ±0.2 m:
    the document or object under discussion). A standing presenter (head at
    1.65 m) paces ±0.6 m between the tables. Foci: 0, 1 the tables, 2 the presenter.
    """
    t = jnp.arange(num_frames) / fps
    c1, c2 = jnp.array([-2.6, -0.3]), jnp.array([2.6, 0.4])
    xy = jnp.concatenate([_ring(pool, c1, 1.15, 6), _ring(pool, c2, 1.05, 5)])
    xy = xy + 0.08 * smooth(pool, t, (11, 2), periods=(3.0, 8.0))
    eye = pool.uniform((11,), 1.15, 1.28)
    z = eye + 0.02 * smooth(pool, t, (11,), periods=(2.0, 6.0))
    origins = _with_height(xy, z)

    tables = jnp.stack([c1, c2]) + 0.2 * smooth(pool, t, (2, 2), periods=(4.0, 12.0))
    tables = _with_height(tables, jnp.full((num_frames, 2), 0.8))
    presenter = jnp.stack(
        [0.6 * smooth(pool, t, (), periods=(5.0, 15.0)), jnp.full_like(t, 2.6), 1.65 + 0.02 * jnp.sin(t)], axis=-1
    )
    foci = jnp.concatenate([tables, presenter[:, None, :]], axis=1)

    fractions = (1 / 3, 2 / 3)
    table = jnp.array([[0] * 6 + [1] * 5, [2] * 11, [0] * 6 + [1] * 5], jnp.int32)  # (phase, person)
    person_phase = _staggered_phase(pool, num_frames, fractions, 11, _stagger(num_frames))
    focus = table[person_phase, jnp.arange(11)[None, :]]
    return _Layout(origins, foci, focus, _nominal_phase(num_frames, fractions))


def _party(pool: Pool, num_frames: int, fps: float) -> _Layout:
    """Park et al. Sec. 4.2, party: 4 groups (3, 3, 3, 2) → all watch table tennis.

    Couch (3 seated around a coffee table), bar table (3 standing), table tennis
    (1 vs 2 players at the ends of a 2.74 m table, watching the ball) and pool
    (2 players on opposite sides watching the cue ball). At half time the 8
    non-players switch to the ball (staggered) and walk (2–3 s, smoothstep) to
    spectator spots 2–2.6 m beside the table tennis table, standing up.
    Foci: 0 couch, 1 bar table, 2 ball, 3 cue ball.
    """
    t = jnp.arange(num_frames) / fps
    couch_c, bar_c = jnp.array([-3.0, -2.5]), jnp.array([-2.5, 2.5])
    tt_c, pool_c = jnp.array([2.5, -2.0]), jnp.array([2.8, 2.8])
    sway = 0.1 * smooth(pool, t, (11, 2), periods=(3.0, 9.0))
    tt_players = tt_c + jnp.array([[-1.37 - 0.7, 0.0], [1.37 + 0.7, -0.5], [1.37 + 0.7, 0.5]])
    tt_players = tt_players + jnp.array([0.0, 0.3]) * smooth(pool, t, (3, 1), periods=(1.0, 3.0))
    pool_players = pool_c + jnp.array([[0.2, -1.1], [-0.3, 1.1]])
    xy_before = jnp.concatenate(
        [
            jnp.broadcast_to(_ring(pool, couch_c, 1.0, 3), (num_frames, 3, 2)) + sway[:, 0:3],
            jnp.broadcast_to(_ring(pool, bar_c, 0.8, 3), (num_frames, 3, 2)) + sway[:, 3:6],
            tt_players,
            jnp.broadcast_to(pool_players, (num_frames, 2, 2)) + sway[:, 9:11],
        ],
        axis=1,
    )
    eye_seated = pool.uniform((11,), 1.1, 1.2)
    eye_standing = pool.uniform((11,), 1.55, 1.75)
    seated = jnp.arange(11) < 3
    z_before = jnp.where(seated, eye_seated, eye_standing)

    # Spectator spots along both long sides of the table tennis table.
    side = jnp.array([-1.0, 1.0] * 4)
    along = jnp.repeat(jnp.linspace(-1.8, 1.8, 4), 2)
    spots = tt_c + jnp.stack([along, side * 2.3], axis=-1)
    spots = spots + pool.uniform((8, 2), -0.3, 0.3)
    spectators = jnp.array([0, 1, 2, 3, 4, 5, 9, 10])
    xy_after = xy_before.at[:, spectators].set(spots + sway[:, spectators] * 0.5)
    z_after = eye_standing

    fractions = (0.5,)
    person_phase = _staggered_phase(pool, num_frames, fractions, 11, _stagger(num_frames))
    switch = jnp.argmax(person_phase >= 1, axis=0)  # first frame of phase 1 per person
    switch = jnp.where(jnp.any(person_phase >= 1, axis=0), switch, num_frames)
    walk = pool.uniform((11,), 2.0, 3.0) * fps
    s = jnp.clip((jnp.arange(num_frames)[:, None] - switch[None, :]) / walk[None, :], 0.0, 1.0)
    s = s * s * (3 - 2 * s)  # smoothstep
    xy = (1 - s[..., None]) * xy_before + s[..., None] * xy_after
    z = (1 - s) * z_before + s * z_after + 0.015 * smooth(pool, t, (11,), periods=(1.0, 4.0))
    origins = _with_height(xy, z)

    couch_f = _with_height(couch_c + 0.15 * smooth(pool, t, (2,)), jnp.full(num_frames, 0.95))
    bar_f = _with_height(bar_c + 0.1 * smooth(pool, t, (2,)), jnp.full(num_frames, 1.1))
    rally = pool.uniform((3,), 0.0, 2 * math.pi)
    ball = jnp.stack(
        [
            tt_c[0] + 1.1 * jnp.sin(2 * math.pi * 0.6 * t + rally[0]),
            tt_c[1] + 0.4 * jnp.sin(2 * math.pi * 0.37 * t + rally[1]),
            0.95 + 0.15 * jnp.abs(jnp.sin(2 * math.pi * 1.2 * t + rally[2])),
        ],
        axis=-1,
    )
    cue = _with_height(pool_c + jnp.array([0.6, 0.3]) * smooth(pool, t, (2,)), jnp.full(num_frames, 0.85))
    foci = jnp.stack([couch_f, bar_f, ball, cue], axis=1)

    table = jnp.array([[0, 0, 0, 1, 1, 1, 2, 2, 2, 3, 3], [2] * 11], jnp.int32)
    focus = table[person_phase, jnp.arange(11)[None, :]]
    return _Layout(origins, foci, focus, _nominal_phase(num_frames, fractions))


def _musical(pool: Pool, num_frames: int, fps: float) -> _Layout:
    """Park et al. Sec. 4.2, musical: 7 seated audience members, stage 8–12 m away.

    A row of seats 0.55 m apart (eye height 1.1–1.2 m). Two groups of actors on
    a 0.7 m stage (heads at 2.3 m): "pink ladies" around (−2.2, 10) and
    "T-birds" around (2.4, 9), each wandering ±0.6 m. The audience watches
    pink ladies → T-birds → pink ladies → T-birds (quarters, staggered).
    Seen from the row the rays to one group span only about 18°.
    """
    t = jnp.arange(num_frames) / fps
    x = jnp.linspace(-1.65, 1.65, 7) + pool.uniform((7,), -0.05, 0.05)
    xy = jnp.stack([x, jnp.zeros(7)], axis=-1) + 0.05 * smooth(pool, t, (7, 2), periods=(3.0, 9.0))
    eye = pool.uniform((7,), 1.1, 1.2)
    z = eye + 0.01 * smooth(pool, t, (7,), periods=(2.0, 6.0))
    origins = _with_height(xy, z)

    groups = jnp.array([[-2.2, 10.0], [2.4, 9.0]])
    actors = groups + jnp.array([0.6, 0.6]) * smooth(pool, t, (2, 2), periods=(3.0, 10.0))
    actors = jnp.clip(actors, jnp.array([-6.0, 8.0]), jnp.array([6.0, 12.0]))
    foci = _with_height(actors, jnp.full((num_frames, 2), 2.3))

    fractions = (0.25, 0.5, 0.75)
    person_phase = _staggered_phase(pool, num_frames, fractions, 7, _stagger(num_frames))
    focus = (person_phase % 2).astype(jnp.int32)
    return _Layout(origins, foci, focus, _nominal_phase(num_frames, fractions))


_BUILDERS = {"mocap": _mocap, "meeting": _meeting, "party": _party, "musical": _musical}
_NUM_PEOPLE = {"mocap": 6, "meeting": 11, "party": 11, "musical": 7}


# ---------------------------------------------------------------------------
# Observation model


def primary_rays(
    key,
    origins: Float[Array, "... 3"],
    targets: Float[Array, "... 3"],
    eye_in_head: float,
    head_noise: float,
) -> Float[Array, "... 3"]:
    """Observed primary gaze directions for people at ``origins`` looking at ``targets``.

    Cone model (Park et al. Sec. 3.1): ``v' = unit(g + d1 u1 + d2 u2)`` with
    ``g = unit(target − origin)``, ``d ~ N(0, eye_in_head² I₂)``; then head-pose
    error ``v = R(ω) v'`` with ``ω ~ N(0, head_noise² I₃)`` (axis-angle).
    Vectorised over any leading shape.
    """
    origins = jnp.asarray(origins)
    targets = jnp.asarray(targets)
    if origins.shape != targets.shape or origins.shape[-1:] != (3,):
        raise ValueError(f"primary_rays: origins {origins.shape} and targets {targets.shape} must both be (..., 3)")
    z = jax.random.normal(key, origins.shape[:-1] + (5,), jnp.result_type(origins, jnp.float32))
    return _perturb(origins, targets, z, eye_in_head, head_noise)


def _perturb(origins, targets, z, eye_in_head, head_noise):
    """:func:`primary_rays` given standard normals ``z (..., 5)``: 2 eye-in-head, 3 head."""
    shape = origins.shape
    g = unit(targets - origins).reshape(-1, 3)
    z = z.reshape(-1, 5)
    u1, u2 = jax.vmap(orthonormal_basis)(g)
    d = eye_in_head * z[:, :2]
    v = unit(g + d[:, :1] * u1 + d[:, 1:] * u2)
    omega = head_noise * z[:, 2:]
    v = jnp.einsum("nij,nj->ni", axis_angle_to_rotation_matrix(omega), v)
    return unit(v).reshape(shape)


@partial(jax.jit, static_argnames=("preset", "num_frames", "fps"))
def _simulate_arrays(key, eye_in_head, head_noise, *, preset: str, num_frames: int, fps: float):
    """All frames of a preset in one compiled pass: layout, ground truth and noisy rays.

    The layout takes its uniforms from one ``jax.random.uniform`` draw (each
    extra ``jax.random`` call adds a threefry kernel and compile time); the ray
    noise is one ``jax.random.normal`` draw from a separate key.
    """
    n_people = _NUM_PEOPLE[preset]
    n_layout = _pool_size(num_frames)
    layout_key, noise_key = jax.random.split(key)
    pool = Pool(layout_key, n_layout)
    layout = _BUILDERS[preset](pool, num_frames, fps)
    if layout.focus.shape[1] != n_people:
        raise RuntimeError("simulate: _NUM_PEOPLE out of date (internal error)")
    z = jax.random.normal(noise_key, (num_frames, n_people, 5))
    M = layout.foci.shape[1]
    targets = jnp.take_along_axis(layout.foci, layout.focus[..., None], axis=1)  # (T, N, 3)
    counts = jnp.sum(layout.focus[:, :, None] == jnp.arange(M)[None, None, :], axis=1)  # (T, M)
    valid = counts >= 2
    attending = jnp.where(jnp.take_along_axis(valid, layout.focus, axis=1), layout.focus, -1).astype(jnp.int32)
    directions = _perturb(layout.origins, targets, z, eye_in_head, head_noise)
    return layout.origins, directions, targets, attending, layout.foci, valid, layout.focus, layout.phase


def simulate_scene(
    key,
    preset: str | SceneConfig,
    num_frames: int | None = None,
    *,
    eye_in_head: float | None = None,
    head_noise: float | None = None,
) -> Scene:
    """Simulate a social scene with ground-truth concurrences.

    Args:
        key: ``jax.random`` key; the same key gives the same scene.
        preset: one of :data:`PRESETS` or a :class:`SceneConfig`.
        num_frames: number of frames ``T`` (default per preset).
        eye_in_head: eye-in-head standard deviation ``h_e`` (radians).
        head_noise: head-pose error, std of each axis of a small rotation (radians).

    Returns:
        :class:`Scene` whose rays carry bandwidth ``sqrt(h_e² + σ_h²)``.
    """
    check_key(key)
    config = _resolve(preset, num_frames, eye_in_head, head_noise)
    origins, directions, targets, attending, foci, valid, focus, phase = _simulate_arrays(
        key, config.eye_in_head, config.head_noise, preset=config.preset, num_frames=config.num_frames, fps=config.fps
    )
    bandwidth = math.hypot(config.eye_in_head, config.head_noise)
    T, N = focus.shape
    rays = GazeRays(origins, directions, jnp.full((T, N), bandwidth), jnp.ones((T, N), bool))
    return Scene(
        rays=rays,
        targets=targets,
        attending=attending,
        concurrences=foci,
        concurrence_valid=valid,
        focus=focus,
        phase=phase,
        name=config.preset,
        eye_in_head=config.eye_in_head,
        head_noise=config.head_noise,
        fps=config.fps,
    )
