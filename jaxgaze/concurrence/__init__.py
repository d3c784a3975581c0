"""Gaze concurrences: the modes of the 3D social saliency field (Park, Jain & Sheikh 2012, Sec. 4).

Where each equation and section lives:

| equation or section | function | file |
|---|---|---|
| eq. 3: the social saliency field | ``jaxgaze.cone.saliency_field`` (ground floor) | ``cone.py`` |
| eq. 5–6: mean-shift on the field | ``meanshift``, ``ray_projector`` | ``concurrence/modes.py`` |
| eq. 6 as one fused GPU kernel (Pallas) | ``fused_meanshift`` | ``concurrence/meanshift_pallas.py`` |
| Sec. 3.3: exclusive support, ML location, Laplace covariance | ``find_concurrences``, ``find_concurrences_over_frames`` | ``concurrence/modes.py`` |
| Sec. 3.3: concurrences linked over frames | ``track_concurrences`` | ``concurrence/modes.py`` |
| Sec. 3.3: a live stream, frame by frame, with track ids | ``ConcurrenceStream`` | ``concurrence/stream.py`` |
| Sec. 3.2 and 4: calibration uncertainty in the concurrences | ``propagate_to_concurrences`` | ``concurrence/propagate.py`` |
| Sec. 4.1: error against the truth, confidence regions | ``match_concurrences``, ``evaluate``, ``region_coverage`` | ``concurrence/metrics.py`` |
"""

from jaxgaze.concurrence.modes import (
    MeanShiftResult,
    Concurrences,
    Tracks,
    ConcurrenceOptions,
    meanshift,
    find_concurrences,
    find_concurrences_over_frames,
    track_concurrences,
    DEFAULT_SEED_DEPTHS,
)
from jaxgaze.concurrence.stream import ConcurrenceStream, StreamFrame, StreamState
from jaxgaze.concurrence.propagate import (
    ConcurrenceEnsemble,
    propagate_to_concurrences,
)
from jaxgaze.concurrence.metrics import (
    Matching,
    FrameMatches,
    Evaluation,
    match_concurrences,
    match_over_frames,
    localisation_errors,
    count_accuracy,
    mahalanobis_squared,
    region_threshold,
    coverage,
    region_coverage,
    evaluate,
)

__all__ = [
    "MeanShiftResult",
    "Concurrences",
    "Tracks",
    "ConcurrenceOptions",
    "meanshift",
    "find_concurrences",
    "find_concurrences_over_frames",
    "track_concurrences",
    "DEFAULT_SEED_DEPTHS",
    "ConcurrenceStream",
    "StreamFrame",
    "StreamState",
    "ConcurrenceEnsemble",
    "propagate_to_concurrences",
    "Matching",
    "FrameMatches",
    "Evaluation",
    "match_concurrences",
    "match_over_frames",
    "localisation_errors",
    "count_accuracy",
    "mahalanobis_squared",
    "region_threshold",
    "coverage",
    "region_coverage",
    "evaluate",
]
