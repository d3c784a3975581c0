"""Every file format jaxgaze reads or writes, and other gaze tools' outputs.

Readers raise one error type, :class:`InputFileError` (``path, line N: what``; each format has its
subclass in its module), and every CSV goes through :func:`~jaxgaze.io.text.read_csv_table`; writers
are atomic (:func:`~jaxgaze.io.text.atomic_path`). The door holds the readers and writers; column
tuples, format constants and helpers stay in their modules:

=========================================  ======================================================
module                                     format
=========================================  ======================================================
:mod:`jaxgaze.io.text`                     CSV tables, atomic writes, :class:`InputFileError`
:mod:`jaxgaze.io.rays`                     rays CSV (:func:`read_rays_csv`, :func:`write_rays_csv`)
:mod:`jaxgaze.io.concurrences`             concurrences and members CSV
:mod:`jaxgaze.io.figures`                  figures (format from the extension)
:mod:`jaxgaze.io.poses`                    COLMAP ``images.txt``, pose CSV, camera-poses CSV
:mod:`jaxgaze.io.calibration`              wearer calibration JSON
:mod:`jaxgaze.io.speech`                   RTTM and speech segments CSV
:mod:`jaxgaze.io.gaze`                     gaze CSV (or OpenFace), targets CSV
:mod:`jaxgaze.io.bias_report`              bias report JSON
:mod:`jaxgaze.io.attend`                   attend CSV
:mod:`jaxgaze.io.joint`                    joint-model inputs and outputs (CSV, netCDF)
:mod:`jaxgaze.io.models`                   gaze-regression model JSON
:mod:`jaxgaze.io.video`                    videos and image folders
:mod:`jaxgaze.io.sampler`                  sampler reports
:mod:`jaxgaze.io.tools`                    other gaze tools (:data:`GAZE_TOOLS`, :func:`read_gaze_tool`),
                                           one module each under ``jaxgaze.io.tools``
=========================================  ======================================================
"""

from jaxgaze.io.text import InputFileError
from jaxgaze.io.rays import RayRecording, read_rays_csv, write_rays_csv
from jaxgaze.io.concurrences import write_concurrences_csv, write_members_csv
from jaxgaze.io.figures import write_figure
from jaxgaze.io.poses import (
    PoseTrack,
    read_poses,
    read_colmap_images,
    write_colmap_images,
    read_pose_csv,
    write_pose_csv,
    read_camera_poses_csv,
    write_camera_poses_csv,
)
from jaxgaze.io.calibration import WearerCalibration, read_calibration_json, write_calibration_json, calibrated_rays
from jaxgaze.io.gaze import GazeTrack, read_gaze, read_targets_csv
from jaxgaze.io.bias_report import write_bias_report
from jaxgaze.io.attend import write_attend_csv
from jaxgaze.io.joint import (
    JointGaze,
    read_joint_gaze,
    read_speech,
    speaking_by_person,
    write_joint_frames,
    write_joint_netcdf,
)
from jaxgaze.io.models import save_gaze_regression, load_gaze_regression
from jaxgaze.io.video import iter_frames, read_frames, write_frames
from jaxgaze.io.tools import GAZE_TOOLS, read_gaze_tool
from jaxgaze.io.tools.gaze360 import read_gaze360
from jaxgaze.io.tools.l2cs import read_l2cs
from jaxgaze.io.tools.xgaze import read_xgaze
from jaxgaze.io.tools.mediapipe import read_mediapipe
from jaxgaze.io.tools.pupil import read_neon, read_pupil
from jaxgaze.io.tools.aria import read_aria
from jaxgaze.io.tools.openface import read_openface_rays

__all__ = [
    "InputFileError",
    "RayRecording",
    "read_rays_csv",
    "write_rays_csv",
    "write_concurrences_csv",
    "write_members_csv",
    "write_figure",
    "PoseTrack",
    "read_poses",
    "read_colmap_images",
    "write_colmap_images",
    "read_pose_csv",
    "write_pose_csv",
    "read_camera_poses_csv",
    "write_camera_poses_csv",
    "WearerCalibration",
    "read_calibration_json",
    "write_calibration_json",
    "calibrated_rays",
    "GazeTrack",
    "read_gaze",
    "read_targets_csv",
    "write_bias_report",
    "write_attend_csv",
    "JointGaze",
    "read_joint_gaze",
    "read_speech",
    "speaking_by_person",
    "write_joint_frames",
    "write_joint_netcdf",
    "save_gaze_regression",
    "load_gaze_regression",
    "iter_frames",
    "read_frames",
    "write_frames",
    "GAZE_TOOLS",
    "read_gaze_tool",
    "read_gaze360",
    "read_l2cs",
    "read_xgaze",
    "read_mediapipe",
    "read_pupil",
    "read_neon",
    "read_aria",
    "read_openface_rays",
]
