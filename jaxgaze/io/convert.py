"""One entry point for every gaze tool's output: ``read_gaze_tool(tool, paths)`` → a world :class:`RayRecording`.

``GAZE_TOOLS`` names the tools ``jaxgaze convert --from`` accepts and what each reads; the conventions
of each are in ``docs/conventions.md`` ("Other gaze tools") and in its module's docstring.
"""

from __future__ import annotations

import os
from typing import Optional, Sequence

from jaxgaze.io.aria import read_aria
from jaxgaze.io.gaze360 import read_gaze360
from jaxgaze.io.l2cs import read_l2cs
from jaxgaze.io.mediapipe import read_mediapipe
from jaxgaze.io.openface import read_openface_rays
from jaxgaze.io.pupil import read_neon, read_pupil
from jaxgaze.io.rays import RayRecording
from jaxgaze.io.text import InputFileError, read_text
from jaxgaze.io.xgaze import read_xgaze
from jaxgaze.poses import CameraPoses

__all__ = ["GAZE_TOOLS", "WEARER_TOOLS", "read_gaze_tool"]

#: ``--from`` name → what it reads.
GAZE_TOOLS = {
    "gaze360": "Gaze360 dump CSV (frame, person_identity, yaw, pitch, var, person_eyes3d_x/y/z)",
    "l2cs": "L2CS-Net dump CSV (frame, face, pitch, yaw, eye_x/y/z)",
    "xgaze": "ETH-XGaze / MPIIFaceGaze / ptgaze dump CSV (frame, person, pitch, yaw, center_x/y/z, normalising rotation)",
    "mediapipe": "MediaPipe Face Landmarker JSON Lines (frame, facial_transformation_matrixes)",
    "pupil": "Pupil Core gaze_positions.csv export, or a Neon gaze.csv (azimuth [deg], elevation [deg])",
    "aria": "Project Aria MPS folders, one per wearer (general_eye_gaze.csv + closed_loop_trajectory.csv)",
    "openface": "OpenFace 2 CSV, one face or several (FaceLandmarkVidMulti)",
}


def _is_neon(path) -> bool:
    """Whether a Pupil Labs CSV is Neon's export (its header names ``azimuth [deg]``), not Pupil Core's."""
    text = read_text(path)
    header = next((line for line in text.splitlines() if line.strip()), "")
    return "azimuth [deg]" in header.lower()


#: The tools whose files are one wearer each, named by ``persons`` (the others name people in their rows).
WEARER_TOOLS = ("pupil", "aria")


def read_gaze_tool(tool: str, paths, *, camera: Optional[CameraPoses] = None,
                   fps: Optional[float] = None, persons: Optional[Sequence[str]] = None) -> RayRecording:
    """The world-frame rays of one tool's output files (``paths``: one or several, as the tool's reader takes).

    ``camera`` places a camera-based tool's camera (or a wearer's scene camera) in the world; ``fps`` is the
    frame rate of the time grid of the tools that have timestamps but no frames (Aria, Neon). A ``pupil`` file
    is read as Neon's export when its header names ``azimuth [deg]``. ``persons``: one name per file of a
    wearer tool (:data:`WEARER_TOOLS`; default :func:`~jaxgaze.io.pupil.wearer_names`).
    """
    if tool not in GAZE_TOOLS:
        raise ValueError(f"unknown gaze tool {tool!r}: choose from {', '.join(GAZE_TOOLS)}")
    paths = [paths] if isinstance(paths, (str, os.PathLike)) else list(paths)
    if not paths:
        raise ValueError("no input files")
    if persons is not None and tool not in WEARER_TOOLS:
        raise ValueError(f"persons= names the wearers of {' and '.join(WEARER_TOOLS)} files; {tool} files name "
                         "their people in their rows")
    timed = {} if fps is None else {"fps": fps}
    if tool == "pupil":
        neon = [_is_neon(path) for path in paths]
        if any(neon) and not all(neon):
            raise InputFileError("Pupil Core and Neon exports mixed: convert them separately", paths[neon.index(False)])
        reader = read_neon if neon[0] else read_pupil
        return reader(paths, camera=camera, persons=persons, **(timed if neon[0] else {}))
    if tool == "aria":
        return read_aria(paths, camera=camera, persons=persons, **timed)
    readers = {"gaze360": read_gaze360, "l2cs": read_l2cs, "xgaze": read_xgaze, "mediapipe": read_mediapipe,
               "openface": read_openface_rays}
    return readers[tool](paths if len(paths) > 1 else paths[0], camera=camera)
