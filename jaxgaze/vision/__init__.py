"""The image side of joint attention (Yücel et al., T-CYB 2013 and CogSci 2009):
face detection, cylindrical head-model tracking,
bottom-up saliency and the attended object.

* :mod:`~jaxgaze.vision.images` — checks and conversions (RGB, uint8 or [0, 1] floats);
* :mod:`~jaxgaze.vision.faces` — Viola–Jones faces and eyes (OpenCV's Haar cascades);
* :mod:`~jaxgaze.vision.head_model`, :mod:`~jaxgaze.vision.tracker` — the elliptic
  cylinder head, its renderer, and the 6-DoF Lucas–Kanade tracker (optimistix);
* :mod:`~jaxgaze.vision.saliency_maps` — Itti–Koch–Niebur and spectral-residual maps,
  Gaussian masks, winner-take-all with inhibition of return, salient regions;
* :mod:`~jaxgaze.vision.attend` — the posterior over attended locations and objects,
  per window of a session or a video;
* :mod:`~jaxgaze.simulate.render`, :mod:`~jaxgaze.io.video` — rendered table-top
  scenes and videos with ground truth, and video input/output.

Image conventions are in :mod:`jaxgaze.vision.images` and ``docs/conventions.md``. The door holds
the entry points, their result types and options; the rest stays in its module (``module.name`` below).

Where each equation and section lives:

| equation or section | function | file |
|---|---|---|
| T-CYB Sec. IV: Viola–Jones face and eyes | ``detect_faces``, ``faces.detect_eyes`` | ``vision/faces.py`` |
| T-CYB Sec. IV: the cylindrical head model and its rendering | ``CylinderHead``, ``head_model.render_head`` | ``vision/head_model.py`` |
| T-CYB Sec. IV, eq. 1–4: 6-DoF Lucas–Kanade tracking | ``track_head`` | ``vision/tracker.py`` |
| T-CYB Sec. VI: target points and their covariances | ``attend.target_points_and_covariances``, ``target_point_covariance`` | ``vision/attend.py`` |
| Itti, Koch & Niebur 1998, Sec. 2, Fig. 2: map normalisation | ``saliency_maps.itti_normalize`` | ``vision/saliency_maps.py`` |
| T-CYB Sec. VI: saliency, Gaussian mask, winner-take-all with inhibition of return | ``saliency``, ``saliency_maps.gaussian_mask``, ``winner_take_all``, ``saliency_maps.salient_region`` | ``vision/saliency_maps.py`` |
| T-CYB Sec. VI–VII: the attended location of one window | ``attend_window`` | ``vision/attend.py`` |
| T-CYB Sec. IV–VI: video → tracking → regression → pooling → attention | ``attend_frames`` | ``vision/attend.py`` |
| the result drawn on the frames (attended point, region, head centre, target) | ``draw_attention``, ``attend.attention_overlay`` | ``vision/attend.py`` |
"""

from jaxgaze.vision.attend import Attention, AttentionWindows, attend_frames, attend_window, draw_attention, target_point_covariance
from jaxgaze.vision.faces import FaceBox, detect_faces
from jaxgaze.vision.head_model import CylinderHead
from jaxgaze.vision.saliency_maps import SALIENCY_METHODS, Fixations, saliency, winner_take_all
from jaxgaze.vision.tracker import HeadTrack, track_head

__all__ = [
    # entry points
    "detect_faces",
    "track_head",
    "saliency",
    "winner_take_all",
    "attend_window",
    "attend_frames",
    "target_point_covariance",
    "draw_attention",
    # result types
    "FaceBox",
    "HeadTrack",
    "Fixations",
    "Attention",
    "AttentionWindows",
    # options
    "CylinderHead",
    "SALIENCY_METHODS",
]
