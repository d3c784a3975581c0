"""Simulated HRI table-top sessions with ground truth (Yücel et al., T-CYB 2013, Sec. VII).

An experimenter sits about 1.5 m in front of a robot camera (320 × 240 px,
10 fps) and looks, in random order and for a few seconds each, at ``K = 5 … 7``
objects on the table between them, 20–30 cm apart centre to centre. The
robot sees only the experimenter's head pose; the regressors of
:mod:`jaxgaze.gp` learn from it ``f1`` (the image-plane gaze direction) and
``f2`` (the image row of the attended object), T-CYB eq. 6–13, Fig. 9.

Frames and signs (radians inside; ``_deg`` names hold degrees, ``_m`` metres,
``_s`` seconds, ``_px`` pixels):

* **optical** (the robot camera's optical frame, ``docs/conventions.md``): the
  optical centre, **+x right, +y down, +z forward** along the optical axis,
  metres, as in OpenCV. It is *not* the x-forward/y-left/z-up camera frame
  of the pose files; the ``_optical`` fields below use it. The optical
  axis is horizontal; the table top is the plane ``y = camera_above_table_m``.
* **image**: pixels, origin at the top-left corner, x right, y down; a pinhole
  ``u = f X / Z + c_x``, ``v = f Y / Z + c_y`` with the principal point at the
  image centre (160, 120) and ``f`` ≈ 300–350 px.
* **frontal head frame**: the head frame of ``docs/conventions.md`` (+x
  forward, +y left, +z up) in the *frontal* pose, the eye-contact pose that
  faces the camera from the experimenter's rest position: +x points from the
  rest eye midpoint to the camera centre, +y is the experimenter's left (the
  image's right), +z is up (``R_optical_from_frontal``). Yaw and pitch follow
  ``yaw_pitch_to_direction``: **yaw > 0 turns to the experimenter's left**
  (towards the image's right), **pitch > 0 is up** (objects on the table are
  at pitch < 0); **roll > 0 turns about the forward axis from +y to +z**
  (the left ear goes up, the head tilts to its right). The head orientation is
  ``R_frontal_from_head = R_z(yaw) R_y(−pitch) R_x(roll)``; eye contact is
  ``(pitch, yaw, roll) = 0``, which is how the tracker of T-CYB Sec. IV is
  initialised.

Generative model, one session:

1. **Layout.** By default all sessions share one table (``shared_layout``): the
   camera, its focal length and the objects, placed for the mean ``distance_m``.
   Per session, the experimenter's rest eye midpoint is ``distance_m`` in front
   of the camera, ``head_lateral_m`` to the side and ``head_above_table_m``
   above the table top, which is ``camera_above_table_m`` below the camera.
   Cube-shaped objects of edge ``object_size_m`` stand on the table; they are
   placed one by one, each ``object_spacing_m`` (centre to centre, horizontal)
   from an earlier one in a random direction and at least ``object_spacing_m[0]``
   from all, at horizontal distance ``object_distance_m`` from the
   experimenter (along the optical axis) and with its whole projected box at
   least ``image_margin_px`` inside the image. So every object's nearest
   neighbour is 20–30 cm away. ``object_boxes_image`` is the bounding box of
   the 8 projected cube corners.
2. **Attention.** The objects are attended in random order: concatenated
   random permutations (no object twice in a row), each for a dwell uniform
   in ``dwell_s``. The true gaze jumps (a saccade) to the new object's centre
   at the switch frame; ``gaze_angles`` are its (yaw, pitch) in the frontal
   frame, from the current eye position.
3. **Head.** Each person has fixed idiosyncrasies (:class:`PersonTraits`):
   gains ``κ_yaw``, ``κ_pitch`` (< 1: the head under-rotates, the eyes do the
   rest), offsets of a few degrees and a resting pitch, a roll that follows
   the yaw a little, a lag time constant and the tracker noise level. The
   head's target pose is::

       yaw   = yaw_offset   + κ_yaw   · s(gaze_yaw)
       pitch = pitch_offset + κ_pitch · s(gaze_pitch)
       roll  = roll_offset  + roll_coupling · yaw
       s(u)  = u − w · tanh(u / w),   w = dead_zone

   ``s`` is a smooth dead zone: ``s(u) ≈ u³ / (3 w²)`` for ``|u| ≲ w`` (inside the
   customary ocular motor range, ≈ 0.1 rad, the eyes move and the head barely
   does: T-CYB Sec. VII-C, Fig. 8) and ``s(u) ≈ u − w`` beyond. The head follows
   this target through a first-order lag, ``h_t = h_{t−1} + α (target_t − h_{t−1})``,
   ``α = 1 − exp(−1 / (head_lag_s · fps))``, starting at the first target, plus a
   smooth sway of ``head_sway_deg`` per angle: ``head_pose_true``.
4. **Tracker.** The reported ``head_pose`` adds i.i.d. Gaussian noise of the
   person's ``tracker_noise`` (0.02–0.04 rad) per angle. The eye midpoint sways
   smoothly by up to ``head_sway_m`` per axis (``head_position_optical``).
5. **Image quantities.** ``head_centre_image`` projects the eye midpoint;
   ``gaze_direction_image`` (f1) is ``atan2(dy, dx)`` of the image vector from
   the head centre to the attended object's centre (pointing down the image is
   +π/2); ``target_depth_image`` (f2) is that centre's image row;
   ``head_direction_image`` is the image angle of the reported facing
   direction, the derivative of the projection along the facing ray at the
   head centre (the CogSci "only head" baseline; it degenerates only when the
   head faces the camera exactly, never on the table).

Groups of the CogSci paper: an object is **near** when its horizontal distance
from the experimenter's rest eye position (along the optical axis) is below
``near_threshold_m`` = 0.5 m, and **central** when ``|yaw|`` of the direction
to it in the frontal frame is below ``central_threshold`` = 0.3 rad. With the
defaults these split the objects roughly in half (``benchmarks/RESULTS.md``).

All randomness comes from the ``jax.random`` key: the key's data seed a NumPy
``SeedSequence`` whose children draw each person's traits and each session.
Same key, same sessions. The host code is vectorised over frames except for
the lag filter (``scipy.signal.lfilter``).
"""

from __future__ import annotations

import math
from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int
from scipy.signal import lfilter

from jaxgaze._checks import check_frames, check_int, check_int_pair, check_key, check_number, check_pair
from jaxgaze.geometry import direction_to_yaw_pitch, yaw_pitch_to_direction
from jaxgaze.headpose.features import head_pose_features

__all__ = [
    "IMAGE_WIDTH",
    "IMAGE_HEIGHT",
    "TabletopConfig",
    "PersonTraits",
    "TabletopSession",
    "tabletop_config",
    "session_features",
    "project_optical_to_image",
    "simulate_tabletop_sessions",
]

IMAGE_WIDTH = 320
IMAGE_HEIGHT = 240


class TabletopConfig(NamedTuple):
    """Parameters of the table-top generative model (see the module docstring).

    Pairs ``(lo, hi)`` are ranges of uniform draws.

    Attributes:
        focal_px: focal length of the pinhole camera (per session).
        distance_m: rest eye midpoint's distance in front of the camera (per session).
        head_lateral_m: rest eye midpoint's offset to the side (image x), per session.
        head_above_table_m: eye height above the table top (per session).
        camera_above_table_m: camera height above the table top (per session).
        object_size_m: edge of the cube-shaped objects (per object).
        object_spacing_m: centre-to-centre distance to an earlier object.
        object_distance_m: horizontal distance of objects from the experimenter,
            along the optical axis.
        image_margin_px: every object's box keeps this far inside the image.
        dwell_s: time spent looking at one object.
        yaw_gain: range of ``κ_yaw`` (per person).
        pitch_gain: range of ``κ_pitch`` (per person).
        dead_zone: width ``w`` of the smooth dead zone (radians).
        yaw_offset_deg: ``|yaw_offset|`` at most this (per person).
        pitch_offset_deg: range of the resting pitch offset (per person).
        roll_offset_deg: ``|roll_offset|`` at most this (per person).
        roll_coupling: ``|roll_coupling|`` at most this (per person).
        head_lag_s: range of the lag time constant (per person).
        head_sway_deg: amplitude of the smooth sway of each head angle.
        head_sway_m: amplitude of the smooth eye-midpoint sway per axis.
        tracker_noise: range of the tracker noise std (radians, per person).
        near_threshold_m: objects nearer than this to the experimenter are "near".
        central_threshold: objects with ``|yaw|`` below this (radians) are "central".
    """

    focal_px: tuple[float, float]
    distance_m: tuple[float, float]
    head_lateral_m: tuple[float, float]
    head_above_table_m: tuple[float, float]
    camera_above_table_m: tuple[float, float]
    object_size_m: tuple[float, float]
    object_spacing_m: tuple[float, float]
    object_distance_m: tuple[float, float]
    image_margin_px: float
    dwell_s: tuple[float, float]
    yaw_gain: tuple[float, float]
    pitch_gain: tuple[float, float]
    dead_zone: float
    yaw_offset_deg: float
    pitch_offset_deg: tuple[float, float]
    roll_offset_deg: float
    roll_coupling: float
    head_lag_s: tuple[float, float]
    head_sway_deg: float
    head_sway_m: float
    tracker_noise: tuple[float, float]
    near_threshold_m: float
    central_threshold: float


_DEFAULT_CONFIG = TabletopConfig(
    focal_px=(300.0, 350.0),
    distance_m=(1.4, 1.6),
    head_lateral_m=(-0.05, 0.05),
    head_above_table_m=(0.38, 0.48),
    camera_above_table_m=(0.12, 0.18),
    object_size_m=(0.06, 0.10),
    object_spacing_m=(0.20, 0.30),
    object_distance_m=(0.25, 0.8),
    image_margin_px=2.0,
    dwell_s=(2.0, 5.0),
    yaw_gain=(0.4, 0.55),  # the head turns less than the eyes sideways ...
    pitch_gain=(0.75, 0.9),  # ... than down to the table, so its image direction is biased to the vertical
    dead_zone=0.1,
    yaw_offset_deg=2.0,
    pitch_offset_deg=(-3.0, 2.0),
    roll_offset_deg=3.0,
    roll_coupling=0.15,
    head_lag_s=(0.15, 0.35),
    head_sway_deg=1.0,
    head_sway_m=0.015,
    tracker_noise=(0.02, 0.04),
    near_threshold_m=0.5,
    central_threshold=0.3,
)


def tabletop_config() -> TabletopConfig:
    """The default :class:`TabletopConfig` (change fields with ``._replace``)."""
    return _DEFAULT_CONFIG


class PersonTraits(NamedTuple):
    """One experimenter's idiosyncrasies, fixed across their sessions (radians, seconds)."""

    yaw_gain: float
    pitch_gain: float
    yaw_offset: float
    pitch_offset: float
    roll_offset: float
    roll_coupling: float
    head_lag_s: float
    tracker_noise: float


class TabletopSession(NamedTuple):
    """One simulated session: ``T`` frames, ``K`` objects, all with ground truth.

    Attributes:
        person: experimenter id, ``0 … num_people − 1``.
        session: index of the session among the person's sessions.
        fps: frames per second.
        head_pose: ``(T, 3)`` reported (noisy) ``(pitch, yaw, roll)`` in the frontal frame.
        head_pose_true: ``(T, 3)`` the same without tracker noise.
        head_position_optical: ``(T, 3)`` eye midpoint (the head centre) in the optical frame (m).
        head_centre_image: ``(T, 2)`` its projection (px).
        gaze_angles: ``(T, 2)`` true gaze ``(yaw, pitch)`` in the frontal frame.
        target: ``(T,)`` index of the attended object.
        object_centres_optical: ``(K, 3)`` cube centres in the optical frame (m).
        object_centres_image: ``(K, 2)`` their projections (px).
        object_boxes_image: ``(K, 4)`` ``(x_min, y_min, x_max, y_max)`` of the projected cubes (px).
        object_sizes_m: ``(K,)`` cube edges; each cube stands on the table, its bottom at
            ``y = centre_y + size / 2`` (the table plane).
        gaze_direction_image: ``(T,)`` f1, image angle from the head centre to the attended centre.
        target_depth_image: ``(T,)`` f2, image y of the attended centre (px).
        head_direction_image: ``(T,)`` image angle of the reported facing direction at the head centre.
        object_is_near: ``(K,)`` near the experimenter (CogSci groups).
        object_is_central: ``(K,)`` near the frontal direction in yaw (CogSci groups).
        R_optical_from_frontal: ``(3, 3)`` the frontal head frame's axes in the optical frame.
        head_rest_optical: ``(3,)`` rest eye midpoint (the frontal frame's origin; the sway is around it).
        focal_px: the camera's focal length (principal point at the image centre).
        traits: the person's :class:`PersonTraits`.
    """

    person: int
    session: int
    fps: float
    head_pose: Float[Array, "T 3"]
    head_pose_true: Float[Array, "T 3"]
    head_position_optical: Float[Array, "T 3"]
    head_centre_image: Float[Array, "T 2"]
    gaze_angles: Float[Array, "T 2"]
    target: Int[Array, " T"]
    object_centres_optical: Float[Array, "K 3"]
    object_centres_image: Float[Array, "K 2"]
    object_boxes_image: Float[Array, "K 4"]
    object_sizes_m: Float[Array, " K"]
    gaze_direction_image: Float[Array, " T"]
    target_depth_image: Float[Array, " T"]
    head_direction_image: Float[Array, " T"]
    object_is_near: Bool[Array, " K"]
    object_is_central: Bool[Array, " K"]
    R_optical_from_frontal: Float[Array, "3 3"]
    head_rest_optical: Float[Array, "3"]
    focal_px: float
    traits: PersonTraits

    @property
    def num_frames(self) -> int:
        return int(self.target.shape[0])

    @property
    def num_objects(self) -> int:
        return int(self.object_centres_optical.shape[0])

    @property
    def times(self) -> Float[Array, " T"]:
        """Frame times in seconds, ``t / fps``."""
        return jnp.arange(self.num_frames) / self.fps


def session_features(session: TabletopSession, *, include_position: bool = False) -> Float[Array, "T D"]:
    """:func:`jaxgaze.headpose.features.head_pose_features` of a session's reported pose, ``(T, 3)``.

    ``include_position`` appends the head position ``(x, y, z)`` in the optical
    frame (metres), T-CYB's full pose, ``(T, 6)``. Off by default: a regressor
    trained on one session extrapolates badly in those columns.
    """
    if not isinstance(session, TabletopSession):
        raise TypeError(f"session must be a TabletopSession, got {type(session).__name__}")
    return head_pose_features(session.head_pose, session.head_position_optical if include_position else None)


def project_optical_to_image(points_optical, focal_px: float) -> np.ndarray:
    """Pinhole projection of camera-frame points ``(..., 3)`` (x right, y down, z
    forward; ``z > 0``) to image pixels ``(..., 2)``, principal point at the centre."""
    p = np.asarray(points_optical, dtype=np.float64)
    if p.shape[-1:] != (3,):
        raise ValueError(f"points_optical must have shape (..., 3), got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError("points_optical contains NaN or inf")
    if np.any(p[..., 2] <= 0):
        raise ValueError("points_optical must lie in front of the camera (z > 0)")
    f = check_number("focal_px", focal_px, lo=0.0, lo_open=True)
    return np.stack(
        [f * p[..., 0] / p[..., 2] + IMAGE_WIDTH / 2, f * p[..., 1] / p[..., 2] + IMAGE_HEIGHT / 2], axis=-1
    )


# ---------------------------------------------------------------------------
# Validation


def _check_config(config) -> TabletopConfig:
    if config is None:
        return _DEFAULT_CONFIG
    if not isinstance(config, TabletopConfig):
        raise TypeError(f"config must be a TabletopConfig or None, got {type(config).__name__}")
    c = {}
    c["focal_px"] = check_pair("focal_px", config.focal_px, lo=50.0, hi=5000.0)
    c["distance_m"] = check_pair("distance_m", config.distance_m, lo=0.5, hi=5.0)
    c["head_lateral_m"] = check_pair("head_lateral_m", config.head_lateral_m, lo=-1.0, hi=1.0)
    c["head_above_table_m"] = check_pair("head_above_table_m", config.head_above_table_m, lo=0.1, hi=1.5)
    c["camera_above_table_m"] = check_pair("camera_above_table_m", config.camera_above_table_m, lo=0.01, hi=1.5)
    c["object_size_m"] = check_pair("object_size_m", config.object_size_m, lo=0.005, hi=0.5)
    c["object_spacing_m"] = check_pair("object_spacing_m", config.object_spacing_m, lo=0.01, hi=2.0)
    c["object_distance_m"] = check_pair("object_distance_m", config.object_distance_m, lo=0.05)
    c["image_margin_px"] = check_number("image_margin_px", config.image_margin_px, lo=0.0, hi=100.0)
    c["dwell_s"] = check_pair("dwell_s", config.dwell_s, lo=0.01)
    c["yaw_gain"] = check_pair("yaw_gain", config.yaw_gain, lo=0.0, hi=1.5)
    c["pitch_gain"] = check_pair("pitch_gain", config.pitch_gain, lo=0.0, hi=1.5)
    c["dead_zone"] = check_number("dead_zone", config.dead_zone, lo=0.0, hi=1.0)
    c["yaw_offset_deg"] = check_number("yaw_offset_deg", config.yaw_offset_deg, lo=0.0, hi=30.0)
    c["pitch_offset_deg"] = check_pair("pitch_offset_deg", config.pitch_offset_deg, lo=-30.0, hi=30.0)
    c["roll_offset_deg"] = check_number("roll_offset_deg", config.roll_offset_deg, lo=0.0, hi=30.0)
    c["roll_coupling"] = check_number("roll_coupling", config.roll_coupling, lo=0.0, hi=1.0)
    c["head_lag_s"] = check_pair("head_lag_s", config.head_lag_s, lo=0.0, hi=5.0)
    c["head_sway_deg"] = check_number("head_sway_deg", config.head_sway_deg, lo=0.0, hi=20.0)
    c["head_sway_m"] = check_number("head_sway_m", config.head_sway_m, lo=0.0, hi=0.3)
    c["tracker_noise"] = check_pair("tracker_noise", config.tracker_noise, lo=0.0, hi=0.5)
    c["near_threshold_m"] = check_number("near_threshold_m", config.near_threshold_m, lo=0.0)
    c["central_threshold"] = check_number("central_threshold", config.central_threshold, lo=0.0, hi=math.pi)
    if c["camera_above_table_m"][1] >= c["head_above_table_m"][0]:
        raise ValueError(
            f"camera_above_table_m {config.camera_above_table_m!r} must stay below head_above_table_m "
            f"{config.head_above_table_m!r} (the head is seen from below its eyes)"
        )
    if c["object_distance_m"][1] >= c["distance_m"][0] - 0.1:
        raise ValueError(
            f"object_distance_m {config.object_distance_m!r} must end at least 0.1 m before the camera "
            f"(distance_m {config.distance_m!r})"
        )
    return TabletopConfig(**c)


def _check_num_objects(num_objects) -> tuple[int, int]:
    if isinstance(num_objects, (tuple, list)):
        return check_int_pair("num_objects", num_objects, lo=2, hi=12)
    n = check_int("num_objects", num_objects, lo=2, hi=12)
    return n, n


# ---------------------------------------------------------------------------
# Building blocks (NumPy, host)


def _dead_zone(u, w):
    """``s(u) = u − w tanh(u / w)``: flat (≈ u³/3w²) inside ``|u| ≲ w``, slope → 1 outside."""
    if w == 0:
        return u
    return u - w * np.tanh(u / w)


def _smooth(rng: np.random.Generator, times, count: int, periods=(2.0, 10.0), components: int = 3):
    """``count`` smooth zero-mean signals ``(T, count)`` in about [−1, 1]: sums of sines."""
    period = rng.uniform(*periods, size=(components, count))
    phase = rng.uniform(0, 2 * math.pi, size=(components, count))
    amp = rng.uniform(0.5, 1.0, size=(components, count))
    amp = amp / amp.sum(axis=0, keepdims=True)
    return np.einsum("ck,tck->tk", amp, np.sin(2 * math.pi * times[:, None, None] / period + phase))


def _yaw_pitch(d):
    """:func:`jaxgaze.geometry.direction_to_yaw_pitch` in float64 NumPy (the simulator's precision)."""
    with jax.enable_x64(True):
        yaw, pitch = direction_to_yaw_pitch(jnp.asarray(d, jnp.float64))
        return np.asarray(yaw, np.float64), np.asarray(pitch, np.float64)


def _draw_traits(rng: np.random.Generator, c: TabletopConfig) -> PersonTraits:
    deg = math.pi / 180
    return PersonTraits(
        yaw_gain=float(rng.uniform(*c.yaw_gain)),
        pitch_gain=float(rng.uniform(*c.pitch_gain)),
        yaw_offset=float(rng.uniform(-1, 1) * c.yaw_offset_deg * deg),
        pitch_offset=float(rng.uniform(*c.pitch_offset_deg) * deg),
        roll_offset=float(rng.uniform(-1, 1) * c.roll_offset_deg * deg),
        roll_coupling=float(rng.uniform(-1, 1) * c.roll_coupling),
        head_lag_s=float(rng.uniform(*c.head_lag_s)),
        tracker_noise=float(rng.uniform(*c.tracker_noise)),
    )


def _cube_corners(centres, sizes):
    """The 8 corners ``(K, 8, 3)`` of axis-aligned cubes."""
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64)
    return centres[:, None, :] + 0.5 * sizes[:, None, None] * signs[None]


def _boxes(centres, sizes, focal):
    corners = project_optical_to_image(_cube_corners(centres, sizes), focal)
    return np.concatenate([corners.min(axis=1), corners.max(axis=1)], axis=-1)


def _layout(rng, c: TabletopConfig, num_objects: int, head_z: float, table_y: float, focal: float):
    """Sequential placement: each object ``spacing`` from an earlier one, ≥ spacing_min from all, in the image."""
    s_lo, s_hi = c.object_spacing_m
    d_lo, d_hi = c.object_distance_m
    margin = c.image_margin_px

    def in_image(box):
        return (
            box[0] >= margin
            and box[1] >= margin
            and box[2] <= IMAGE_WIDTH - margin
            and box[3] <= IMAGE_HEIGHT - margin
        )

    for _ in range(50):
        xz, sizes = [], []
        tries = 0
        while len(xz) < num_objects and tries < 100 * num_objects:
            tries += 1
            size = rng.uniform(*c.object_size_m)
            if not xz:
                z = head_z - rng.uniform(d_lo, d_hi)
                x = rng.uniform(-0.3, 0.3)
                cand = np.array([x, z])
            else:
                base = xz[rng.integers(len(xz))]
                ang = rng.uniform(0, 2 * math.pi)
                cand = base + rng.uniform(s_lo, s_hi) * np.array([math.cos(ang), math.sin(ang)])
                if min(np.linalg.norm(cand - p) for p in xz) < s_lo:
                    continue
            if not (d_lo <= head_z - cand[1] <= d_hi):
                continue
            centre = np.array([[cand[0], table_y - size / 2, cand[1]]])
            if not in_image(_boxes(centre, np.array([size]), focal)[0]):
                continue
            xz.append(cand)
            sizes.append(size)
        if len(xz) == num_objects:
            xz, sizes = np.array(xz), np.array(sizes)
            centres = np.stack([xz[:, 0], table_y - sizes / 2, xz[:, 1]], axis=-1)
            return centres, sizes
    raise ValueError(
        f"could not place {num_objects} objects {c.object_spacing_m} m apart inside the image; "
        "widen object_distance_m, reduce num_objects or the spacing"
    )


def _attention(rng, num_objects: int, num_frames: int, fps: float, dwell_s) -> np.ndarray:
    """Attended object per frame: concatenated random permutations, no immediate repeats."""
    order: list[int] = []
    frames: list[int] = []
    total = 0
    while total < num_frames:
        perm = list(rng.permutation(num_objects))
        if order and perm[0] == order[-1]:
            perm[0], perm[-1] = perm[-1], perm[0]
        for k in perm:
            n = max(1, int(round(rng.uniform(*dwell_s) * fps)))
            order.append(int(k))
            frames.append(n)
            total += n
            if total >= num_frames:
                break
    return np.repeat(np.array(order), np.array(frames))[:num_frames]


class _Scene(NamedTuple):
    focal: float
    cam_above: float
    centres: np.ndarray
    sizes: np.ndarray


def _scene(rng, c: TabletopConfig, num_objects: int) -> _Scene:
    """The robot camera and the objects on the table (placed for the nominal experimenter distance)."""
    focal = rng.uniform(*c.focal_px)
    cam_above = rng.uniform(*c.camera_above_table_m)
    centres, sizes = _layout(rng, c, num_objects, float(np.mean(c.distance_m)), cam_above, focal)
    return _Scene(focal, cam_above, centres, sizes)


def _session(rng, c: TabletopConfig, traits: PersonTraits, scene: _Scene, *, person, index, num_frames, fps):
    deg = math.pi / 180
    times = np.arange(num_frames) / fps
    focal, cam_above, centres, sizes = scene
    num_objects = len(sizes)
    head_above = rng.uniform(*c.head_above_table_m)
    head0 = np.array([rng.uniform(*c.head_lateral_m), cam_above - head_above, rng.uniform(*c.distance_m)])

    # Frontal frame: +x from the rest eye midpoint to the camera, +y the person's left (image right), +z up.
    fwd = -head0 / np.linalg.norm(head0)
    left = np.array([1.0, 0.0, 0.0]) - fwd[0] * fwd
    left /= np.linalg.norm(left)
    up = np.cross(fwd, left)
    R = np.stack([fwd, left, up], axis=1)  # R_optical_from_frontal

    boxes = _boxes(centres, sizes, focal)
    centres_image = project_optical_to_image(centres, focal)

    target = _attention(rng, num_objects, num_frames, fps, c.dwell_s)
    head = head0 + c.head_sway_m * _smooth(rng, times, 3, periods=(3.0, 15.0))  # (T, 3)
    head_image = project_optical_to_image(head, focal)

    # True gaze: eye midpoint -> attended centre, in the frontal frame.
    sight = centres[target] - head
    gaze_yaw, gaze_pitch = _yaw_pitch(sight @ R)

    # Head: gains on a smooth dead zone, offsets, roll coupling, first-order lag, sway.
    w = c.dead_zone
    yaw_t = traits.yaw_offset + traits.yaw_gain * _dead_zone(gaze_yaw, w)
    pitch_t = traits.pitch_offset + traits.pitch_gain * _dead_zone(gaze_pitch, w)
    goal = np.stack([pitch_t, yaw_t], axis=0)  # (2, T)
    frames = traits.head_lag_s * fps
    if frames > 1e-6:
        alpha = 1.0 - math.exp(-1.0 / frames)
        zi = (1 - alpha) * goal[:, :1]
        goal = lfilter([alpha], [1.0, -(1.0 - alpha)], goal, axis=1, zi=zi)[0]
    sway = c.head_sway_deg * deg * _smooth(rng, times, 3, periods=(2.0, 8.0))
    pitch = goal[0] + sway[:, 0]
    yaw = goal[1] + sway[:, 1]
    roll = traits.roll_offset + traits.roll_coupling * yaw + sway[:, 2]
    pose_true = np.stack([pitch, yaw, roll], axis=-1)
    pose = pose_true + traits.tracker_noise * rng.standard_normal((num_frames, 3))

    # Image quantities.
    attended = centres_image[target]
    delta = attended - head_image
    f1 = np.arctan2(delta[:, 1], delta[:, 0])
    f2 = attended[:, 1].copy()
    with jax.enable_x64(True):
        forward = np.asarray(yaw_pitch_to_direction(jnp.asarray(pose[:, 1]), jnp.asarray(pose[:, 0])), np.float64)
    facing = forward @ R.T  # optical frame
    X, Y, Z = head[:, 0], head[:, 1], head[:, 2]
    du = focal * (facing[:, 0] * Z - X * facing[:, 2]) / Z**2
    dv = focal * (facing[:, 1] * Z - Y * facing[:, 2]) / Z**2
    head_dir = np.arctan2(dv, du)

    # Groups (CogSci): distance from the rest eye along the optical axis; |yaw| in the frontal frame.
    obj_yaw, _ = _yaw_pitch((centres - head0) @ R)
    near = (head0[2] - centres[:, 2]) < c.near_threshold_m
    central = np.abs(obj_yaw) < c.central_threshold

    f = lambda a: jnp.asarray(a, dtype=jnp.result_type(float))  # noqa: E731
    return TabletopSession(
        person=int(person),
        session=int(index),
        fps=float(fps),
        head_pose=f(pose),
        head_pose_true=f(pose_true),
        head_position_optical=f(head),
        head_centre_image=f(head_image),
        gaze_angles=f(np.stack([gaze_yaw, gaze_pitch], axis=-1)),
        target=jnp.asarray(target, dtype=jnp.int32),
        object_centres_optical=f(centres),
        object_centres_image=f(centres_image),
        object_boxes_image=f(boxes),
        object_sizes_m=f(sizes),
        gaze_direction_image=f(f1),
        target_depth_image=f(f2),
        head_direction_image=f(head_dir),
        object_is_near=jnp.asarray(near),
        object_is_central=jnp.asarray(central),
        R_optical_from_frontal=f(R),
        head_rest_optical=f(head0),
        focal_px=float(focal),
        traits=traits,
    )


# ---------------------------------------------------------------------------
# Public API


def simulate_tabletop_sessions(
    key,
    *,
    num_people: int = 4,
    sessions_per_person: int = 2,
    duration_s: float = 60.0,
    fps: float = 10.0,
    num_objects: int | Sequence[int] = (5, 7),
    shared_layout: bool = True,
    config: TabletopConfig | None = None,
) -> list[TabletopSession]:
    """Simulate T-CYB-style table-top sessions (Sec. VII-A) with ground truth.

    Args:
        key: a single ``jax.random`` key; the same key gives the same sessions.
        num_people: experimenters (≥ 1); each keeps their :class:`PersonTraits`.
        sessions_per_person: sessions per experimenter (≥ 1).
        duration_s: length of a session in seconds; ``T = round(duration_s · fps) ≥ 2``.
        fps: frames per second (T-CYB: 10; CogSci: 25).
        num_objects: objects per session, an integer or an inclusive range ``(lo, hi)`` in [2, 12].
        shared_layout: one table for all sessions (the robot camera, its focal length and
            the objects stay; the experimenter's rest position varies per session), as in a
            T-CYB recording set. ``False`` draws a new table for every session, which asks
            a regressor to generalise to object positions it never saw.
        config: a :class:`TabletopConfig` (default :func:`tabletop_config`).

    Returns:
        ``num_people · sessions_per_person`` :class:`TabletopSession`, person-major
        (person 0's sessions first).

    Raises:
        ValueError: bad key, counts, timing or configuration; TypeError for a
            config of the wrong type.
    """
    seed = check_key(key)
    num_people = check_int("num_people", num_people, hi=10_000)
    sessions_per_person = check_int("sessions_per_person", sessions_per_person, hi=10_000)
    num_frames, fps = check_frames(duration_s, fps)
    k_lo, k_hi = _check_num_objects(num_objects)
    c = _check_config(config)

    if not isinstance(shared_layout, (bool, np.bool_)):
        raise TypeError(f"shared_layout must be True or False, got {shared_layout!r}")
    root = np.random.SeedSequence([int(x) for x in seed])
    scene_seed, *person_seeds = root.spawn(1 + num_people)

    def new_scene(rng):
        return _scene(rng, c, int(rng.integers(k_lo, k_hi + 1)))

    shared = new_scene(np.random.default_rng(scene_seed)) if shared_layout else None
    sessions = []
    for p, ps in enumerate(person_seeds):
        trait_seed, *session_seeds = ps.spawn(1 + sessions_per_person)
        traits = _draw_traits(np.random.default_rng(trait_seed), c)
        for s, ss in enumerate(session_seeds):
            rng = np.random.default_rng(ss)
            scene = shared if shared_layout else new_scene(rng)
            sessions.append(_session(rng, c, traits, scene, person=p, index=s, num_frames=num_frames, fps=fps))
    return sessions
