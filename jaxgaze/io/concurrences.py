"""Gaze concurrences as CSV, one row per (frame, mode) (Park et al. 2012, Sec. 4): the
output of ``jaxgaze concurrences``. The writer is atomic.
"""

from __future__ import annotations

import csv

import numpy as np

from jaxgaze.io.text import atomic_path, format_float

__all__ = ["OUTPUT_COLUMNS", "write_concurrences_csv"]

#: Columns of a concurrences CSV, one row per (frame, mode).
OUTPUT_COLUMNS = ("frame", "mode", "x", "y", "z", "var_x", "var_y", "var_z", "num_rays", "field_value")


def write_concurrences_csv(path, frame_ids, concurrences) -> int:
    """Write :data:`OUTPUT_COLUMNS`, one row per (frame, valid mode) of a padded ``(T, K)``
    result of :func:`~jaxgaze.concurrence.modes.find_concurrences_over_frames` (atomically):
    the location (m), the diagonal of its covariance (m²), the rays it claims and the field
    value there. Returns the number of rows."""
    valid = np.asarray(concurrences.valid)
    locations = np.asarray(concurrences.locations)
    variances = np.diagonal(np.asarray(concurrences.covariances), axis1=-2, axis2=-1)
    num_rays = np.asarray(concurrences.num_rays)
    values = np.asarray(concurrences.field_values)
    rows = 0
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8", newline="") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(OUTPUT_COLUMNS)
        for t, frame in enumerate(frame_ids):
            for mode in np.flatnonzero(valid[t]):
                writer.writerow([frame, int(mode), *map(format_float, locations[t, mode]), *map(format_float, variances[t, mode]),
                                 int(num_rays[t, mode]), format_float(values[t, mode])])
                rows += 1
    return rows
