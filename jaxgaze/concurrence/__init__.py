"""Gaze concurrences: the modes of the 3D social saliency field (Park, Jain & Sheikh 2012, Sec. 4).

Where each equation and section lives:

| equation or section | function | file |
|---|---|---|
| eq. 3: the social saliency field | ``jaxgaze.cone.saliency_field`` (ground floor); ``field_value`` | ``cone.py``; ``concurrence/field.py`` |
| eq. 5–6: mean-shift on the field | ``meanshift``, ``ray_projector`` | ``concurrence/field.py`` |
| eq. 6: the search's two-stage ascent | ``two_stage_meanshift`` | ``concurrence/climb.py`` |
| eq. 6 as one fused GPU kernel (Pallas) | ``fused_meanshift`` | ``concurrence/meanshift_pallas.py`` |
| Sec. 3.3: exclusive support, mutual gaze, robust noise ratio | ``claim``, ``mutual_gaze``, ``robust_noise_ratio`` | ``concurrence/claims.py`` |
| Sec. 3.3: ML location, Laplace covariance, noise scale | ``refine_and_laplace``, ``laplace_covariance``, ``noise_scale`` | ``concurrence/laplace.py`` |
| Sec. 3.3: one frame's pipeline (seeds → modes → claims → refinement) | ``concurrences_from_seeds``, ``warm_frame`` | ``concurrence/frame.py`` |
| Sec. 3.3: a frame or a recording | ``find_concurrences``, ``find_concurrences_over_frames`` | ``concurrence/recording.py`` |
| Sec. 3.3: scenes far from the world origin | ``recentred``, ``moved_back`` | ``concurrence/recentre.py`` |
| Sec. 3.3: concurrences linked over frames | ``track_concurrences`` | ``concurrence/tracking.py`` |
| Sec. 3.3: a live stream, frame by frame, with track ids | ``ConcurrenceStream`` | ``concurrence/stream.py`` |
| Sec. 3.2 and 4: calibration uncertainty in the concurrences | ``propagate_to_concurrences`` | ``concurrence/propagate.py`` |
| Sec. 4.1: error against the truth, confidence regions | ``match_concurrences``, ``evaluate``, ``region_coverage`` | ``concurrence/metrics.py`` |

The result types are in ``concurrence/types.py`` and the options in ``concurrence/options.py``.
This door holds the entry points, their result types and the options; everything else is
imported from its module (``from jaxgaze.concurrence.metrics import coverage``).
"""

from jaxgaze.concurrence.metrics import Evaluation, evaluate
from jaxgaze.concurrence.options import ConcurrenceOptions
from jaxgaze.concurrence.propagate import ConcurrenceEnsemble, propagate_to_concurrences
from jaxgaze.concurrence.field import meanshift
from jaxgaze.concurrence.recording import find_concurrences, find_concurrences_over_frames
from jaxgaze.concurrence.stream import ConcurrenceStream, StreamFrame, StreamState
from jaxgaze.concurrence.tracking import track_concurrences
from jaxgaze.concurrence.types import Concurrences, MeanShiftResult, Tracks

__all__ = [
    "find_concurrences",
    "find_concurrences_over_frames",
    "track_concurrences",
    "meanshift",
    "ConcurrenceStream",
    "propagate_to_concurrences",
    "evaluate",
    "Concurrences",
    "Tracks",
    "MeanShiftResult",
    "StreamFrame",
    "StreamState",
    "ConcurrenceEnsemble",
    "Evaluation",
    "ConcurrenceOptions",
]
