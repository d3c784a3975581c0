"""The attended location per window of a video as CSV (Yücel et al. 2013, T-CYB Sec. IV-VI):
the output of ``jaxgaze attend``, one row per window. The writer is atomic.

Image coordinates are pixels, x right, y down, origin at the top-left pixel's outer corner;
angles are radians. Missing values are empty cells.
"""

from __future__ import annotations

import math

from jaxgaze.io.text import atomic_path, csv_writer

__all__ = ["ATTEND_COLUMNS", "write_attend_csv"]

#: Columns of the attend CSV, one row per window.
ATTEND_COLUMNS = ("window", "start_frame", "start_time", "valid", "pitch", "yaw", "roll", "direction", "depth_y",
                  "head_x", "head_y", "target_x", "target_y", "attended_x", "attended_y", "region_x_min",
                  "region_y_min", "region_x_max", "region_y_max", "probability", "reason")


def _cell(value, digits: int = 6) -> str:
    """Empty for NaN, else the number rounded to ``digits`` decimals (shortest form)."""
    value = float(value)
    return "" if not math.isfinite(value) else repr(round(value, digits))


def write_attend_csv(path, windows, fps=None) -> int:
    """Write :data:`ATTEND_COLUMNS`, one row per window of an
    :class:`~jaxgaze.vision.attend.AttentionWindows` (atomically); ``start_time`` is
    ``start_frame / fps`` (empty without ``fps``). Returns the number of rows."""
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8", newline="") as handle:
        writer = csv_writer(handle)
        writer.writerow(ATTEND_COLUMNS)
        for i in range(len(windows.start_frame)):
            start = int(windows.start_frame[i])
            writer.writerow([
                i, start, "" if fps is None else _cell(start / fps),
                int(bool(windows.valid[i])),
                *(_cell(v) for v in windows.pose[i]),
                _cell(windows.direction[i]), _cell(windows.depth_y[i], 3),
                *(_cell(v, 3) for v in windows.head_xy[i]),
                *(_cell(v, 3) for v in windows.target_xy[i]),
                *(_cell(v, 3) for v in windows.attended_xy[i]),
                *(_cell(v, 3) for v in windows.region_box[i]),
                _cell(windows.probability[i]),
                windows.reason[i],
            ])
    return len(windows.start_frame)
