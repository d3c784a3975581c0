"""Gaze concurrences as CSV (Park et al. 2012, Sec. 4): the outputs of
``jaxgaze concurrences``. Every writer is atomic.

* The concurrences, one row per (frame, mode): :data:`OUTPUT_COLUMNS`.
* Who supports what, one row per (frame, person): :data:`MEMBER_COLUMNS`.
"""

from __future__ import annotations


import numpy as np

from jaxgaze.io.text import format_float, write_csv_rows

__all__ = ["OUTPUT_COLUMNS", "MEMBER_COLUMNS", "write_concurrences_csv", "write_members_csv"]

#: Columns of a concurrences CSV, one row per (frame, mode): the frame, the mode's index in the frame,
#: its track over frames, its location (m), the six unique entries of its covariance (m²),
#: the degrees of freedom of its Student-t, its number of rays and the field value there.
OUTPUT_COLUMNS = ("frame", "mode", "track", "x", "y", "z", "var_x", "var_y", "var_z", "cov_xy", "cov_xz", "cov_yz",
                  "degrees_of_freedom", "num_rays", "field_value")
#: Columns of a members CSV, one row per (frame, person): the mode and track the person's ray
#: supports (−1 for none) and the person they are in mutual gaze with (empty for none).
MEMBER_COLUMNS = ("frame", "person", "mode", "track", "mutual_gaze")

_COVARIANCE_ENTRIES = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))


def write_concurrences_csv(path, frame_ids, concurrences, tracks) -> int:
    """Write :data:`OUTPUT_COLUMNS`, one row per (frame, valid mode) of a padded ``(T, K)`` result of
    :func:`~jaxgaze.concurrence.modes.find_concurrences_over_frames` with its
    :class:`~jaxgaze.concurrence.modes.Tracks` (atomically). Returns the number of rows."""
    valid = np.asarray(concurrences.valid)
    locations = np.asarray(concurrences.locations)
    covariances = np.asarray(concurrences.covariances)
    dof = np.asarray(concurrences.degrees_of_freedom)
    num_rays = np.asarray(concurrences.num_rays)
    values = np.asarray(concurrences.field_values)
    track_ids = np.asarray(tracks.track_ids)

    def rows():
        for t, frame in enumerate(frame_ids):
            for mode in np.flatnonzero(valid[t]):
                cov = covariances[t, mode]
                yield [frame, int(mode), int(track_ids[t, mode]), *map(format_float, locations[t, mode]),
                       *(format_float(cov[i, j]) for i, j in _COVARIANCE_ENTRIES),
                       format_float(dof[t, mode]), int(num_rays[t, mode]), format_float(values[t, mode])]

    return write_csv_rows(path, OUTPUT_COLUMNS, rows())


def write_members_csv(path, recording, concurrences, tracks) -> int:
    """Write :data:`MEMBER_COLUMNS`, one row per (frame, person) of a
    :class:`~jaxgaze.io.rays.RayRecording`, for its padded ``(T, K)`` concurrences and their
    tracks (atomically): which mode and track each person's ray supports, and whom they look
    at in mutual gaze (``Concurrences.mutual_gaze``). Returns the number of rows."""
    membership = np.asarray(concurrences.membership)
    partner = np.asarray(concurrences.mutual_gaze)
    track_ids = np.asarray(tracks.track_ids)

    def rows():
        for t, (frame, persons) in enumerate(zip(recording.frame_ids, recording.persons)):
            for n, person in enumerate(persons):
                mode = int(membership[t, n])
                yield [frame, person, mode, int(track_ids[t, mode]) if mode >= 0 else -1,
                       persons[partner[t, n]] if partner[t, n] >= 0 else ""]

    return write_csv_rows(path, MEMBER_COLUMNS, rows())
