"""Other gaze tools' outputs → world-frame rays: one adapter module per tool, behind one registry.

``read_gaze_tool(tool, paths)`` reads any of them into a world :class:`~jaxgaze.io.rays.RayRecording`;
:data:`GAZE_TOOLS` maps each ``--from`` name of ``jaxgaze convert`` to its :class:`GazeTool` entry (what
it reads and its reader). The conventions of each tool are in ``docs/conventions.md`` ("Other gaze
tools") and in its module's docstring:

=============  ==========================================  ===================================
tool           files                                       module
=============  ==========================================  ===================================
``gaze360``    Gaze360 dump CSV                            :mod:`jaxgaze.io.tools.gaze360`
``l2cs``       L2CS-Net dump CSV                           :mod:`jaxgaze.io.tools.l2cs`
``xgaze``      ETH-XGaze / MPIIFaceGaze / ptgaze dump CSV  :mod:`jaxgaze.io.tools.xgaze`
``mediapipe``  MediaPipe Face Landmarker JSON Lines        :mod:`jaxgaze.io.tools.mediapipe`
``pupil``      Pupil Core or Neon CSV exports              :mod:`jaxgaze.io.tools.pupil`
``aria``       Project Aria MPS folders                    :mod:`jaxgaze.io.tools.aria`
``openface``   OpenFace 2 CSV                              :mod:`jaxgaze.io.tools.openface`
=============  ==========================================  ===================================

The pieces every adapter shares (camera frame → world, bandwidth from a mean angular error, optional
extras) are in :mod:`jaxgaze.io.tools.common`.
"""

from __future__ import annotations

import os
from typing import Callable, NamedTuple, Optional, Sequence

from jaxgaze.io.rays import RayRecording
from jaxgaze.io.tools.aria import read_aria
from jaxgaze.io.tools.common import tool_bandwidth, with_bandwidth
from jaxgaze.io.tools.gaze360 import read_gaze360
from jaxgaze.io.tools.l2cs import read_l2cs
from jaxgaze.io.tools.mediapipe import read_mediapipe
from jaxgaze.io.tools.openface import read_openface_rays
from jaxgaze.io.tools.pupil import read_pupil_labs
from jaxgaze.io.tools.xgaze import read_xgaze
from jaxgaze.poses import CameraPoses

__all__ = ["GazeTool", "GAZE_TOOLS", "read_gaze_tool"]


class GazeTool(NamedTuple):
    """One tool :func:`read_gaze_tool` (and ``jaxgaze convert --from``) reads.

    ``reader(paths, *, camera, ...)`` returns a world :class:`~jaxgaze.io.rays.RayRecording`; ``wearer``:
    its files are one wearer each, named by ``persons=`` (the others name people in their rows);
    ``timed``: timestamps without frames, put on a time grid of ``fps=`` frames per second;
    ``camera_frame``: without ``camera=`` its rays are in the camera's frame (Aria's are in its world);
    ``camera_per_file``: ``camera=`` may hold one pose track per file (one per wearer's scene camera);
    ``options``: the reader's own keyword options that :func:`read_gaze_tool` passes on (``bandwidth``
    is taken by every tool: see there); ``own_width``: the tool reports each ray's uncertainty (the others'
    rays get the reader's documented default cone width, docs/conventions.md).
    """

    reads: str
    reader: Callable[..., RayRecording]
    wearer: bool = False
    timed: bool = False
    camera_frame: bool = True
    camera_per_file: bool = False
    options: tuple = ()
    own_width: bool = False


#: ``--from`` name → its :class:`GazeTool` entry.
GAZE_TOOLS: dict[str, GazeTool] = {
    "gaze360": GazeTool("Gaze360 dump CSV (frame, person_identity, yaw, pitch, var, person_eyes3d_x/y/z)",
                        read_gaze360, own_width=True),
    "l2cs": GazeTool("L2CS-Net dump CSV (frame, face, pitch, yaw, eye_x/y/z)", read_l2cs,
                     options=("order", "bandwidth")),
    "xgaze": GazeTool("ETH-XGaze / MPIIFaceGaze / ptgaze dump CSV (frame, person, pitch, yaw, center_x/y/z, "
                      "normalising rotation)", read_xgaze, options=("bandwidth",)),
    "mediapipe": GazeTool("MediaPipe Face Landmarker JSON Lines (frame, facial_transformation_matrixes)",
                          read_mediapipe, options=("vertical_fov_deg", "bandwidth")),
    "pupil": GazeTool("Pupil Core gaze_positions.csv export, or a Neon gaze.csv (azimuth [deg], elevation [deg])",
                      read_pupil_labs, wearer=True, timed=True, camera_per_file=True,
                      options=("min_confidence", "bandwidth", "start_ns")),
    "aria": GazeTool("Project Aria folders as downloaded, one per wearer: MPS (eye_gaze/ with general_eye_gaze.csv "
                     "or its other names, slam/ or trajectory/ with closed_loop_trajectory.csv) or an Aria Digital "
                     "Twin sequence (eyegaze.csv + aria_trajectory.csv)",
                     read_aria, wearer=True, timed=True, camera_frame=False, own_width=True,
                     options=("T_device_cpf", "frame", "up", "eye_gaze", "start_ns", "clock", "max_pose_gap_s")),
    "openface": GazeTool("OpenFace 2 CSV, one face or several (FaceLandmarkVidMulti)", read_openface_rays,
                         options=("min_confidence", "link_gate_m")),
}


def read_gaze_tool(tool: str, paths, *, camera: Optional[CameraPoses] = None,
                   fps: Optional[float] = None, persons: Optional[Sequence[str]] = None, **options) -> RayRecording:
    """The world-frame rays of one tool's output files (``paths``: one or several, as the tool's reader takes).

    ``camera`` places a camera-based tool's camera (or a wearer's scene camera) in the world; ``fps`` is the
    frame rate of the time grid of the tools that have timestamps but no frames (Aria, Neon). A ``pupil`` file
    is read as Neon's export when its header names ``azimuth [deg]``. ``persons``: one name per file of a
    wearer tool (``GAZE_TOOLS[tool].wearer``; default :func:`~jaxgaze.io.tools.pupil.wearer_names`).
    ``options``: the tool's own reader's keyword options (``GAZE_TOOLS[tool].options``), passed on: aria's
    ``T_device_cpf``, ``frame``, ``up``, ``eye_gaze`` (:func:`~jaxgaze.io.tools.aria.read_aria`), mediapipe's
    ``vertical_fov_deg``, l2cs's ``order``, pupil's and openface's ``min_confidence``…; one the tool does not
    take is a ``ValueError`` naming the tool's. ``bandwidth`` (radians, :func:`~.common.tool_bandwidth`) is
    every tool's: the readers with a default cone width take it, and for those that estimate each ray's
    (gaze360's ``var``, aria's intervals) and openface it replaces every ray's bandwidth.
    """
    if tool not in GAZE_TOOLS:
        raise ValueError(f"unknown gaze tool {tool!r}: choose from {', '.join(GAZE_TOOLS)}")
    entry = GAZE_TOOLS[tool]
    paths = [paths] if isinstance(paths, (str, os.PathLike)) else list(paths)
    if not paths:
        raise ValueError("no input files")
    unknown = [name for name in options if name not in entry.options and name != "bandwidth"]
    if unknown:
        takes = ", ".join(f"{name}=" for name in entry.options) or "none but bandwidth="
        raise ValueError(f"{unknown[0]}= is not an option of {tool}'s reader (its options: {takes})")
    if "bandwidth" in options and "bandwidth" not in entry.options:
        h = tool_bandwidth(options.pop("bandwidth"), tool)
        return with_bandwidth(read_gaze_tool(tool, paths, camera=camera, fps=fps, persons=persons, **options), h)
    if not entry.wearer:
        if persons is not None:
            wearer_tools = [name for name, other in GAZE_TOOLS.items() if other.wearer]
            raise ValueError(f"persons= names the wearers of {' and '.join(wearer_tools)} files; {tool} files name "
                             "their people in their rows")
        return entry.reader(paths if len(paths) > 1 else paths[0], camera=camera, **options)
    timed = {"fps": fps} if entry.timed and fps is not None else {}
    return entry.reader(paths, camera=camera, persons=persons, **timed, **options)
