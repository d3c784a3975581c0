"""``jaxgaze concurrences`` on one person per frame (issue 34, bug 2): 0 concurrences, exit 0.

The README's own path gives such files: ``jaxgaze convert`` of one OpenFace face, one Aria
wearer or one Pupil/Neon export. A two-line CSV used to end in an ``IndexError`` in the tracker.
"""

import csv

from tests.cli.helpers import run_main

from jaxgaze.io.concurrences import MEMBER_COLUMNS, OUTPUT_COLUMNS
from jaxgaze.io.rays import CSV_COLUMNS


def _write(path, rows):
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(CSV_COLUMNS)
        writer.writerows(rows)
    return path


def test_a_two_line_csv_has_no_concurrence(tmp_path, capsys):
    src = _write(tmp_path / "one.csv", [[0, "ann", 0.0, 0.0, 1.6, 1.0, 0.0, 0.0]])
    out = tmp_path / "out.csv"
    status, stdout, stderr = run_main(capsys, ["concurrences", src, "--out", out])
    assert (status, stdout) == (0, "")
    assert stderr == f"jaxgaze: 0 concurrence(s) in 1 frame(s) written to {out}\n"
    assert out.read_text().splitlines() == [",".join(OUTPUT_COLUMNS)]


def test_one_wearer_over_frames_with_members_and_figure(tmp_path, capsys):
    rows = [[frame, "wearer", 0.1 * frame, 0.0, 1.6, 1.0, 0.2, -0.1] for frame in range(6)]
    src = _write(tmp_path / "wearer.csv", rows)
    out, members, figure = tmp_path / "out.csv", tmp_path / "members.csv", tmp_path / "figure.png"
    status, stdout, stderr = run_main(capsys, ["concurrences", src, "--out", out, "--members", members,
                                               "--figure", figure, "-q"])
    assert (status, stdout, stderr) == (0, "", "")
    assert out.read_text().splitlines() == [",".join(OUTPUT_COLUMNS)]
    lines = members.read_text().splitlines()
    assert lines[0] == ",".join(MEMBER_COLUMNS)
    assert lines[1:] == [f"{frame},wearer,-1,-1," for frame in range(6)]
    assert figure.stat().st_size > 1000
