"""Gaze concurrences as CSV (Park et al. 2012, Sec. 4): the outputs of
``jaxgaze concurrences``. Every writer is atomic.

* The concurrences, one row per (frame, mode): :data:`OUTPUT_COLUMNS`.
* Who supports what, one row per (frame, person): :data:`MEMBER_COLUMNS`.
"""

from __future__ import annotations


import numpy as np

from jaxgaze.io.text import InputFileError, format_float, write_csv_rows

__all__ = ["OUTPUT_COLUMNS", "MEMBER_COLUMNS", "NotWrittenError", "write_concurrences_csv", "write_members_csv"]

#: Columns of a concurrences CSV, one row per (frame, mode): the frame, the mode's index in the frame,
#: its track over frames, its location (m), the six unique entries of its covariance (m²),
#: the degrees of freedom of its Student-t, its number of rays and the field value there.
OUTPUT_COLUMNS = ("frame", "mode", "track", "x", "y", "z", "var_x", "var_y", "var_z", "cov_xy", "cov_xz", "cov_yz",
                  "degrees_of_freedom", "num_rays", "field_value")
#: Columns of a members CSV, one row per (frame, person): the mode and track the person's ray
#: supports (−1 for none) and the person they are in mutual gaze with (empty for none).
MEMBER_COLUMNS = ("frame", "person", "mode", "track", "mutual_gaze")

_COVARIANCE_ENTRIES = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))


def write_concurrences_csv(path, frame_ids, concurrences, tracks, *, reference=None) -> int:
    """Write :data:`OUTPUT_COLUMNS`, one row per (frame, valid mode) of a padded ``(T, K)`` result of
    :func:`~jaxgaze.concurrence.find_concurrences_over_frames` with its
    :class:`~jaxgaze.concurrence.Tracks` (atomically). Returns the number of rows.

    ``reference`` (float64 ``(3,)`` m, e.g. :attr:`~jaxgaze.io.rays.RayRecording.reference`) is added
    to the locations, in float64, when they were found from rays measured from it. A valid mode whose
    location is not finite or whose covariance is not a finite, symmetric positive semi-definite
    matrix is never written: :class:`NotWrittenError` names it and no file is written."""
    valid = np.asarray(concurrences.valid)
    locations = np.asarray(concurrences.locations)
    if reference is not None:
        locations = locations.astype(np.float64) + np.asarray(reference, dtype=np.float64)
    covariances = np.asarray(concurrences.covariances)
    _check_covariances(path, frame_ids, valid, locations, covariances)
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


class NotWrittenError(InputFileError):
    """A result that must not be written (a NaN location, a covariance that is no covariance):
    ``path: frame F, mode K: what``, so that the command line prints it as one line."""


def _check_covariances(path, frame_ids, valid, locations, covariances) -> None:
    """The writer's last guard: every valid mode has a finite location and a finite, symmetric covariance
    whose eigenvalues are ≥ 0 (up to float rounding, ``−1e-6 · λ_max``) and whose variances are > 0."""
    t, k = np.nonzero(valid)
    if t.size == 0:
        return
    cov = covariances[t, k].astype(np.float64)
    finite = np.isfinite(locations[t, k]).all(axis=-1) & np.isfinite(cov).all(axis=(-2, -1))
    safe = np.where(finite[:, None, None], cov, 0.0)
    scale = np.abs(safe).max(axis=(-2, -1))
    symmetric = np.abs(safe - np.swapaxes(safe, -1, -2)).max(axis=(-2, -1)) <= 1e-5 * scale
    low = np.linalg.eigvalsh(0.5 * (safe + np.swapaxes(safe, -1, -2)))[:, 0]
    variances = np.diagonal(safe, axis1=-2, axis2=-1)
    ok = finite & symmetric & (low >= -1e-6 * np.maximum(scale, np.finfo(float).tiny)) & (variances > 0).all(-1)
    if not ok.all():
        bad = int(np.argmin(ok))
        what = ("its location or covariance is not finite" if not finite[bad] else
                f"its covariance is not positive semi-definite (smallest eigenvalue {low[bad]:.3g} m², variances "
                + ", ".join(f"{v:.3g}" for v in variances[bad]) + " m²)")
        raise NotWrittenError(f"frame {frame_ids[t[bad]]}, mode {k[bad]}: {what}; nothing written", path)


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
