"""A simulated table-top session rendered as a video, with its ground truth (Yücel et al. 2013, Sec. VI).

:func:`render_tabletop_video` draws the table-top scene of
:func:`~jaxgaze.simulate.render.render_tabletop_scene` with the textured cylinder
head of :func:`~jaxgaze.vision.head_model.render_head` at the session's head
position and pose in every frame, so that the whole attention pipeline runs on a
synthetic video whose truth is known.
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np

from jaxgaze._checks import check_int
from jaxgaze.simulate.render import render_tabletop_scene
from jaxgaze.simulate.tabletop import IMAGE_HEIGHT, IMAGE_WIDTH, TabletopSession
from jaxgaze.geometry import head_pose_to_rotation, rotation_to_head_pose
from jaxgaze.vision.head_model import CylinderHead, frontal_rotation, render_head

__all__ = ["VideoTruth", "render_tabletop_video"]



class VideoTruth(NamedTuple):
    """Ground truth of :func:`render_tabletop_video`, one row per frame (NumPy arrays).

    Pixel quantities are in the rendered (scaled) image: ``scale`` times those of the
    session (the image frame's origin is the top-left pixel corner, so scaling is exact).

    Attributes:
        head_pose: ``(T, 3)`` the rendered (pitch, yaw, roll), radians, relative to
            ``R_optical_from_frontal``.
        head_position_optical: ``(T, 3)`` the session's head position, the eye midpoint, optical
            frame, metres: the front of the rendered face at the cylinder's mid-height.
        head_centre_image: ``(T, 2)`` its projection, px (what the regression's ``f1`` starts from).
        cylinder_centre_optical: ``(T, 3)`` the rendered cylinder's centre (axis, mid-height),
            ``head.half_depth_m`` behind the eye midpoint along the facing direction.
        target: ``(T,)`` the attended object, or ``-1`` in the lead-in frames.
        gaze_direction_image: ``(T,)`` f1, radians (NaN in the lead-in).
        target_depth_image: ``(T,)`` f2, image row of the attended object's centre, px (NaN in the lead-in).
        object_centres_image: ``(K, 2)`` px.
        object_boxes_image: ``(K, 4)`` ``(x_min, y_min, x_max, y_max)`` px.
        object_labels: ``(H, W)`` int16 object seen at each pixel or ``-1`` (the scene without the head).
        head_masks: ``(T, H, W)`` bool, where the head was drawn.
        R_optical_from_frontal: ``(3, 3)`` the frontal frame the poses are relative to.
        focal_px: the focal length of the rendered images (``scale × session.focal_px``).
        image_size: ``(W, H)`` px.
        scale: the image scale relative to the simulator's 320 × 240.
        fps: the session's frame rate.
        lead_in: number of frames before the session's first (eye contact, then turning).
        session_frame: ``(T,)`` the session frame each video frame shows (``-1`` in the lead-in).
    """

    head_pose: np.ndarray
    head_position_optical: np.ndarray
    head_centre_image: np.ndarray
    cylinder_centre_optical: np.ndarray
    target: np.ndarray
    gaze_direction_image: np.ndarray
    target_depth_image: np.ndarray
    object_centres_image: np.ndarray
    object_boxes_image: np.ndarray
    object_labels: np.ndarray
    head_masks: np.ndarray
    R_optical_from_frontal: np.ndarray
    focal_px: float
    image_size: tuple[int, int]
    scale: int
    fps: float
    lead_in: int
    session_frame: np.ndarray


def render_tabletop_video(
    session,
    *,
    key,
    condition: str = "natural",
    scale: int = 2,
    pose: str = "true",
    lead_in: int = 10,
    num_frames: int | None = None,
    head=None,
) -> tuple[list[np.ndarray], VideoTruth]:
    """Render a simulated table-top session as video frames, with its ground truth.

    Every frame is the session's scene (:func:`~jaxgaze.simulate.render.render_tabletop_scene`
    with ``key`` and ``condition``: the same background in every frame) with the textured
    cylinder head (:func:`~jaxgaze.vision.head_model.render_head`) in the session's pose
    (relative to its ``R_optical_from_frontal``) with the front of the face at mid-height on
    the session's ``head_position_optical`` (the eye midpoint; the cylinder's centre is
    ``head.half_depth_m`` behind it), which is the point
    :func:`jaxgaze.vision.attend.attend_frames` projects as the head centre. The cubes are
    nearer to the camera than the head, so their pixels stay in front of it. The ``condition``
    (colour cast, dimming and noise, motion blur) is applied to the scene, not to the head.

    **Scale.** At the simulator's 320 × 240 (``scale=1``) the head is about
    ``0.15 m · 316 px / 1.5 m ≈ 32 px`` wide, too small for
    :func:`~jaxgaze.vision.tracker.track_head`. At ``scale=2`` (640 × 480, a head of
    about 60–64 px) it tracks, and the OpenCV face detector finds the face in the first
    frame; hence the defaults (rotation errors at both scales: ``benchmarks/RESULTS.md``).

    Args:
        session: a :class:`~jaxgaze.simulate.tabletop.TabletopSession`.
        key: ``jax.random`` key of the scene's layout, clutter and condition.
        condition: one of :data:`jaxgaze.simulate.render.CONDITIONS`.
        scale: integer 1 to 16; the images are ``320·scale × 240·scale`` px with focal
            length ``scale · session.focal_px`` (the scene is resized with ``cv2.INTER_CUBIC``,
            the head is ray-cast at full resolution); see above.
        pose: ``"true"`` renders ``head_pose_true``, ``"reported"`` the noisy ``head_pose``.
        lead_in: frames shown before the session's first: the head at the first frame's
            position in eye contact (looking at the camera), then turning smoothly (cosine
            ramp) to the first frame's pose over the remaining lead-in frames. The head
            tracker needs a frontal first frame; the session's own first frame looks at an
            object (without a lead-in the tracked pose is off by that first pose, ~20°).
        num_frames: render only the session's first ``num_frames`` frames (default all).
        head: a :class:`~jaxgaze.vision.head_model.CylinderHead` (default the standard one).

    Returns:
        ``(frames, truth)``: a list of ``(H, W, 3)`` RGB uint8 images and a :class:`VideoTruth`.
    """
    if not isinstance(session, TabletopSession):
        raise TypeError(f"session must be a TabletopSession, got {type(session).__name__}")
    scale = check_int("scale", scale, lo=1, hi=16)
    if pose not in ("true", "reported"):
        raise ValueError(f"pose must be 'true' or 'reported', got {pose!r}")
    lead_in = check_int("lead_in", lead_in, lo=0)
    total = session.num_frames
    if num_frames is not None:
        total = min(total, check_int("num_frames", num_frames))
    head = CylinderHead() if head is None else head

    scene = render_tabletop_scene(session, key=key, condition=condition)
    width, height = IMAGE_WIDTH * scale, IMAGE_HEIGHT * scale
    background = scene.image
    labels = np.asarray(scene.object_labels)
    if scale != 1:
        background = cv2.resize(background, (width, height), interpolation=cv2.INTER_CUBIC)
        labels = cv2.resize(labels, (width, height), interpolation=cv2.INTER_NEAREST)
    focal = float(session.focal_px) * scale
    Rf = np.asarray(session.R_optical_from_frontal, dtype=np.float64)

    poses = np.asarray(session.head_pose_true if pose == "true" else session.head_pose, dtype=np.float64)[:total]
    eyes = np.asarray(session.head_position_optical, dtype=np.float64)[:total]
    if lead_in:
        # Eye contact at the first frame's position: pose 0 relative to the frontal frame there.
        yaw, pitch, roll = rotation_to_head_pose(Rf.T @ frontal_rotation(eyes[0]))
        eye_contact = np.array([pitch, yaw, roll], dtype=np.float64)  # (pitch, yaw, roll), as the session's poses
        ramp = 0.5 - 0.5 * np.cos(np.pi * np.arange(lead_in) / lead_in)  # 0 ... < 1
        poses = np.concatenate([eye_contact + ramp[:, None] * (poses[0] - eye_contact), poses])
        eyes = np.concatenate([np.repeat(eyes[:1], lead_in, axis=0), eyes])
    # The session's head position is the eye midpoint: the front of the face at mid-height, half a head
    # depth in front of the cylinder's centre along the facing direction.
    R_frontal_from_head = head_pose_to_rotation(yaw=poses[:, 1], pitch=poses[:, 0], roll=poses[:, 2])
    R_optical_from_head = Rf @ np.asarray(R_frontal_from_head, dtype=np.float64)
    centres = eyes - head.half_depth_m * R_optical_from_head[:, :, 0]

    in_front = labels >= 0
    frames, masks = [], []
    for p, t in zip(poses, centres):
        image, mask = render_head(p, head=head, focal_px=focal, image_size=(width, height), position_optical=t,
                                  background=background, R_optical_from_frontal=Rf)
        mask &= ~in_front
        image[in_front] = background[in_front]
        frames.append(image)
        masks.append(mask)

    nan = np.full(lead_in, np.nan)
    session_frame = np.concatenate([np.full(lead_in, -1), np.arange(total)])
    eyes_image = np.stack([focal * eyes[:, 0] / eyes[:, 2] + width / 2.0,
                           focal * eyes[:, 1] / eyes[:, 2] + height / 2.0], axis=-1)
    truth = VideoTruth(
        head_pose=poses,
        head_position_optical=eyes,
        head_centre_image=eyes_image,
        cylinder_centre_optical=centres,
        target=np.concatenate([np.full(lead_in, -1), np.asarray(session.target)[:total]]).astype(np.int64),
        gaze_direction_image=np.concatenate([nan, np.asarray(session.gaze_direction_image, np.float64)[:total]]),
        target_depth_image=np.concatenate([nan, scale * np.asarray(session.target_depth_image, np.float64)[:total]]),
        object_centres_image=scale * np.asarray(scene.object_centres, np.float64),
        object_boxes_image=scale * np.asarray(scene.object_boxes, np.float64),
        object_labels=labels.astype(np.int16),
        head_masks=np.stack(masks),
        R_optical_from_frontal=Rf,
        focal_px=focal,
        image_size=(width, height),
        scale=scale,
        fps=float(session.fps),
        lead_in=lead_in,
        session_frame=session_frame.astype(np.int64),
    )
    return frames, truth
