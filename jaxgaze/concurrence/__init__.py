"""Gaze concurrences: the modes of the 3D social saliency field (Park, Jain & Sheikh 2012, Sec. 4).
"""

from jaxgaze.concurrence.modes import (
    MeanShiftResult,
    Concurrences,
    Tracks,
    meanshift,
    find_concurrences,
    find_concurrences_over_frames,
    track_concurrences,
    DEFAULT_SEED_DEPTHS,
)
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
    coverage,
    region_coverage,
    evaluate,
)

__all__ = [
    "MeanShiftResult",
    "Concurrences",
    "Tracks",
    "meanshift",
    "find_concurrences",
    "find_concurrences_over_frames",
    "track_concurrences",
    "DEFAULT_SEED_DEPTHS",
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
    "coverage",
    "region_coverage",
    "evaluate",
]
