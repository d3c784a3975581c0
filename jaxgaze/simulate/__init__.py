"""Every simulator of jaxgaze, with ground truth: scenes for the social saliency field,
calibration sessions, dyadic and multi-party conversations, table-top sessions, faces, rendered
scenes and videos, small groups who look at each other. Models never import this package.
"""

from jaxgaze.simulate.scenes import (
    PRESETS,
    Scene,
    SceneConfig,
    scene_config,
    simulate_scene,
    primary_rays,
)
from jaxgaze.simulate.calibration import (
    Mounting,
    CalibrationSession,
    random_mounting,
    simulate_calibration_session,
    simulate_wearers,
)
from jaxgaze.simulate.dyadic import (
    DyadicConfig,
    DyadicRecording,
    dyadic_config,
    simulate_dyadic,
    simulate_dyadic_sessions,
    PartnerCameraView,
    partner_camera_view,
)
from jaxgaze.simulate.openface_tracks import (
    OpenFaceTracks,
    simulate_openface_tracks,
)
from jaxgaze.simulate.offsets import (
    ContaminatedOffsets,
    simulate_offsets,
)
from jaxgaze.simulate.conversation import (
    ConversationConfig,
    Conversation,
    conversation_config,
    simulate_conversation,
    simulate_conversations,
)
from jaxgaze.simulate.tabletop import (
    TabletopConfig,
    PersonTraits,
    TabletopSession,
    tabletop_config,
    session_features,
    project_optical_to_image,
    simulate_tabletop_sessions,
)
from jaxgaze.simulate.faces import (
    SimulatedFaces,
    simulate_faces,
)
from jaxgaze.simulate.render import (
    CONDITIONS,
    RenderedScene,
    composite,
    render_tabletop_scene,
)
from jaxgaze.simulate.video import (
    VideoTruth,
    render_tabletop_video,
)
from jaxgaze.simulate.wearables import (
    SIMULATED_T_DEVICE_CPF,
    AriaWearers,
    write_aria_wearers,
)
from jaxgaze.simulate.gaze_tools import (
    Gaze360Outputs,
    simulate_gaze360_outputs,
)
from jaxgaze.simulate.mutual import (
    MutualGaze,
    simulate_mutual_gaze,
)

__all__ = [
    "PRESETS",
    "Scene",
    "SceneConfig",
    "scene_config",
    "simulate_scene",
    "primary_rays",
    "Mounting",
    "CalibrationSession",
    "random_mounting",
    "simulate_calibration_session",
    "simulate_wearers",
    "DyadicConfig",
    "DyadicRecording",
    "dyadic_config",
    "simulate_dyadic",
    "simulate_dyadic_sessions",
    "PartnerCameraView",
    "partner_camera_view",
    "OpenFaceTracks",
    "simulate_openface_tracks",
    "ContaminatedOffsets",
    "simulate_offsets",
    "ConversationConfig",
    "Conversation",
    "conversation_config",
    "simulate_conversation",
    "simulate_conversations",
    "TabletopConfig",
    "PersonTraits",
    "TabletopSession",
    "tabletop_config",
    "session_features",
    "project_optical_to_image",
    "simulate_tabletop_sessions",
    "SimulatedFaces",
    "simulate_faces",
    "CONDITIONS",
    "RenderedScene",
    "composite",
    "render_tabletop_scene",
    "VideoTruth",
    "render_tabletop_video",
    "SIMULATED_T_DEVICE_CPF",
    "AriaWearers",
    "write_aria_wearers",
    "Gaze360Outputs",
    "simulate_gaze360_outputs",
    "MutualGaze",
    "simulate_mutual_gaze",
]
