"""The ``jaxgaze`` command line: ``concurrences`` on CSV input, its error handling, and ``demo``.

Commands run in-process through ``main([...])`` (sharing compiled work across
tests), and once through ``python -m jaxgaze.cli`` to check the entry point.
"""

import csv
import math
import os
import subprocess
import sys

import numpy as np
import pytest
from tests.cli.helpers import assert_failed, run_main

import jaxgaze.rays
from jaxgaze.cli import main
from jaxgaze.io.concurrences import OUTPUT_COLUMNS
from jaxgaze.io.rays import CSV_COLUMNS

# Points looked at by groups of people (world frame, metres).
POINT_A = np.array([1.0, 0.5, 1.0])
POINT_B = np.array([-1.5, 2.0, 0.8])
POINT_C = np.array([0.5, -3.0, 1.2])

# Eye centres around each point; every person looks exactly at their point.
_EYES_A = [(2.6, 0.3, 1.6), (1.2, -1.2, 1.7), (-0.3, -0.4, 1.5), (2.4, 1.8, 1.65)]
_EYES_B = [(-3.2, 1.6, 1.2), (-1.0, 3.6, 1.3), (-2.4, 3.5, 1.6), (-0.2, 2.9, 1.25)]
_EYES_C = [(2.0, -4.0, 1.6), (-1.2, -4.2, 1.5), (0.4, -5.0, 1.7)]
# People who look away from everyone: one ray each, no concurrence.
_LONERS = [((0.0, 4.5, 1.6), (0.0, 9.0, 1.6)), ((4.5, -1.0, 1.6), (9.0, -1.5, 1.7))]

# frame id -> {point: eyes looking at it}, number of loners. Frame 11 has 11
# people, as many as the demo's meeting, so that every in-process run below
# uses one compiled (CHUNK, 11) computation.
SCENE = {
    10: ({"a": _EYES_A[:3], "b": _EYES_B[:3]}, 0),
    11: ({"a": _EYES_A[:2], "b": _EYES_B[:4], "c": _EYES_C}, 2),
    13: ({"b": _EYES_B[1:4]}, 1),
}
POINTS = {"a": POINT_A, "b": POINT_B, "c": POINT_C}
EXPECTED = {
    10: [(POINT_A, 3), (POINT_B, 3)],
    11: [(POINT_A, 2), (POINT_B, 4), (POINT_C, 3)],
    13: [(POINT_B, 3)],
}
CHUNK = ["--chunk", "12"]  # frames per compiled batch in-process (3 frames: padded)
DEMO_FRAMES = 20  # with CHUNK: two batches, the second padded


def scene_rows():
    """CSV rows (frame, person, ox, oy, oz, dx, dy, dz), frames deliberately out of order."""
    rows = []
    for frame in (11, 13, 10):
        groups, loners = SCENE[frame]
        people = [(f"{g}{i}", e, POINTS[g]) for g, eyes in groups.items() for i, e in enumerate(eyes)]
        people += [(f"loner{i}", eye, np.array(t)) for i, (eye, t) in enumerate(_LONERS[:loners])]
        for person, eye, target in people:
            d = (target - np.asarray(eye)) * 1.7  # any length: the reader normalises
            rows.append([frame, person, *eye, *(f"{x:.9f}" for x in d)])
    return rows


def write_csv(path, rows, header=CSV_COLUMNS):
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        if header is not None:
            writer.writerow(header)
        writer.writerows(rows)
    return path


def read_output(path):
    with open(path, newline="") as f:
        reader = csv.reader(f)
        header = next(reader)
        return header, list(reader)


@pytest.fixture
def scene_csv(tmp_path):
    return write_csv(tmp_path / "rays.csv", scene_rows())


def check_rows(header, rows):
    assert tuple(header) == OUTPUT_COLUMNS
    by_frame = {}
    for row in rows:
        record = dict(zip(header, row))
        by_frame.setdefault(int(record["frame"]), []).append(record)
    assert sorted(by_frame) == sorted(EXPECTED)
    for frame, expected in EXPECTED.items():
        got = by_frame[frame]
        assert [int(r["mode"]) for r in got] == list(range(len(expected)))
        assert len(got) == len(expected)
        for point, num_rays in expected:
            loc = np.array([[float(r[c]) for c in ("x", "y", "z")] for r in got])
            k = int(np.argmin(np.linalg.norm(loc - point, axis=1)))
            assert np.linalg.norm(loc[k] - point) < 5e-3, (frame, loc[k], point)
            assert int(got[k]["num_rays"]) == num_rays
            variances = [float(got[k][c]) for c in ("var_x", "var_y", "var_z")]
            assert all(0 < v < 1.0 for v in variances)
            assert float(got[k]["field_value"]) > 0


@pytest.fixture(scope="module")
def entry_point_run(tmp_path_factory):
    """``python -m jaxgaze.cli concurrences ... --min-rays 3``, started in the background.

    The first test asks for it so that the subprocess compiles while the
    in-process tests run; :func:`test_entry_point_subprocess_and_min_rays` waits for it.
    """
    directory = tmp_path_factory.mktemp("entry_point")
    src = write_csv(directory / "rays.csv", scene_rows())
    out, kept = directory / "out.csv", directory / "kept.csv"
    kept.write_text("precious\n")
    cli = [sys.executable, "-m", "jaxgaze.cli", "concurrences"]
    procs = [
        subprocess.Popen(cli + [str(src), "--out", str(out), "--min-rays", "3"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True),
        subprocess.Popen(cli + [str(directory / "nope.csv"), "--out", str(kept)],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True),
    ]
    yield procs, directory
    for proc in procs:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()


def test_concurrences_known_scene(tmp_path, scene_csv, capsys, entry_point_run):
    out = tmp_path / "out.csv"
    status, stdout, stderr = run_main(capsys, ["concurrences", scene_csv, "--out", out, *CHUNK])
    assert status == 0, stderr
    assert stdout == ""
    # stderr is not a terminal here: no progress bar, only the one-line summary.
    assert stderr.strip().splitlines() == [f"jaxgaze: 6 concurrence(s) in 3 frame(s) written to {out}"]
    header, rows = read_output(out)
    check_rows(header, rows)
    assert sorted(os.listdir(tmp_path)) == ["out.csv", "rays.csv"]  # no temporary file left


def test_concurrences_bandwidth_column_and_quiet(tmp_path, capsys):
    rows = scene_rows()
    bandwidths = [0.02 + 0.01 * (i % 3) for i in range(len(rows))]
    src = write_csv(tmp_path / "bw.csv", [r + [h] for r, h in zip(rows, bandwidths)], CSV_COLUMNS + ("bandwidth",))
    out = tmp_path / "out.csv"
    status, stdout, stderr = run_main(capsys, ["concurrences", src, "--out", out, "--quiet", *CHUNK])
    assert status == 0 and stdout == "" and stderr == ""
    header, with_bandwidth = read_output(out)
    check_rows(header, with_bandwidth)
    # The same rays with the default bandwidth (0.05): the per-row bandwidths were used.
    plain = write_csv(tmp_path / "plain.csv", rows)
    status, _, _ = run_main(capsys, ["concurrences", plain, "--out", tmp_path / "plain_out.csv", "-q", *CHUNK])
    _, with_default = read_output(tmp_path / "plain_out.csv")
    assert status == 0 and len(with_default) == len(with_bandwidth)
    x, var = OUTPUT_COLUMNS.index("x"), OUTPUT_COLUMNS.index("var_x")

    def variances(rows):  # rows in the same order: by frame, then x
        rows = sorted(rows, key=lambda r: (int(r[0]), float(r[x])))
        return np.array([[float(v) for v in r[var:var + 3]] for r in rows])

    assert np.all(variances(with_bandwidth) < variances(with_default))


def test_concurrences_replaces_existing_output_and_progress_bar_on_tty(tmp_path, scene_csv, capsys, monkeypatch):
    out = tmp_path / "out.csv"
    out.write_text("old contents\n")
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True, raising=False)
    status, _, stderr = run_main(capsys, ["concurrences", scene_csv, "--out", out, *CHUNK])
    assert status == 0
    assert "frame" in stderr and "3/3" in stderr  # the tqdm bar
    check_rows(*read_output(out))
    status, _, stderr = run_main(capsys, ["concurrences", scene_csv, "--out", out, "-q", *CHUNK])
    assert status == 0 and stderr == ""


def test_entry_point_subprocess_and_min_rays(entry_point_run):
    (proc, failing), directory = entry_point_run
    out = directory / "out.csv"
    stdout, stderr = proc.communicate(timeout=300)
    assert proc.returncode == 0, stderr
    assert stdout == ""
    assert stderr.splitlines() == [f"jaxgaze: 5 concurrence(s) in 3 frame(s) written to {out}"]
    header, rows = read_output(out)
    assert tuple(header) == OUTPUT_COLUMNS
    # Only concurrences of at least 3 rays remain: frame 11's pair looking at A is dropped.
    rays, x = OUTPUT_COLUMNS.index("num_rays"), OUTPUT_COLUMNS.index("x")
    assert sorted((int(r[0]), int(r[rays])) for r in rows) == [(10, 3), (10, 3), (11, 3), (11, 4), (13, 3)]
    expected = {(10, 3): (POINT_A, POINT_B), (11, 3): (POINT_C,), (11, 4): (POINT_B,), (13, 3): (POINT_B,)}
    for r in rows:
        loc = np.array([float(v) for v in r[x:x + 3]])
        assert min(np.linalg.norm(loc - p) for p in expected[(int(r[0]), int(r[rays]))]) < 5e-3

    stdout, stderr = failing.communicate(timeout=300)
    assert failing.returncode == 2 and stdout == ""
    assert stderr.splitlines() == [f"jaxgaze: error: input file not found ({directory / 'nope.csv'})"]
    assert (directory / "kept.csv").read_text() == "precious\n"  # untouched
    assert sorted(os.listdir(directory)) == ["kept.csv", "out.csv", "rays.csv"]  # no temporary file


# ---------------------------------------------------------------------------
# Failure modes: status 2, one stderr line, no output file (an existing one untouched)


def _rows_with(change):
    rows = [list(map(str, r)) for r in scene_rows()]
    change(rows)
    return rows


def _set(row, column, value):
    def change(rows):
        rows[row][CSV_COLUMNS.index(column)] = value

    return change


def _duplicate(rows):
    rows.insert(4, list(rows[1]))


FAILURES = {
    # name: (file contents or None for a missing file, expected words, line or None)
    "missing file": (None, "input file not found", None),
    "empty file": ("", "input is empty", 1),
    "blank file": ("\n  \n", "input is empty", 2),
    "header only": (",".join(CSV_COLUMNS) + "\n", "no data rows", 1),
    "missing column": (["frame", "person", "ox", "oy", "oz", "dx", "dy"], "missing column 'dz'", 1),
    "missing columns": (["frame", "person", "ox", "oy", "dx", "dy"], "missing columns 'oz', 'dz'", 1),
    "duplicate column": (list(CSV_COLUMNS) + ["ox"], "duplicate column 'ox'", 1),
    "non-numeric": (_set(2, "oy", "abc"), "column 'oy' is not a number: 'abc'", 4),
    "empty cell": (_set(0, "dz", " "), "empty cell in column 'dz'", 2),
    "nan": (_set(3, "dx", "nan"), "column 'dx' is not finite", 5),
    "inf": (_set(5, "oz", "-inf"), "column 'oz' is not finite", 7),
    "float32 overflow": (_set(5, "ox", "1e39"), "column 'ox' is out of range", 7),
    "zero direction": (lambda rows: [_set(6, c, "0")(rows) for c in ("dx", "dy", "dz")],
                       "direction (dx, dy, dz) has zero length", 8),
    "duplicate person": (_duplicate, "duplicate ray for frame 11, person 'a1' (first on line 3)", 6),
    "non-integer frame": (_set(1, "frame", "11.5"), "column 'frame' must be an integer", 3),
    "non-numeric frame": (_set(1, "frame", "x"), "column 'frame' is not a number", 3),
    "ragged row": (lambda rows: rows[2].pop(), "expected 8 fields as in the header, got 7", 4),
    "zero bandwidth": ("bandwidth=0", "bandwidth must be positive (radians), got 0", 3),
    "negative bandwidth": ("bandwidth=-0.1", "bandwidth must be positive (radians), got -0.1", 3),
    "nan bandwidth": ("bandwidth=nan", "column 'bandwidth' is not finite", 3),
    "bandwidth in degrees": ("bandwidth=3", "bandwidth 3 rad (172°) is no gaze cone width: it is in radians "
                             "(degrees? 3° is 0.0524 rad)", 3),
    "not utf-8": (",".join(CSV_COLUMNS).encode() + b"\n1,a,0,0,1,1,0,0\n1,caf\xe9,0,0,1,1,0,0\n",
                  "input is not UTF-8 text", 3),
    "bad quoting": (",".join(CSV_COLUMNS) + '\n1,a,0,0,1,1,0,0\n1,"b"x,0,0,1,1,0,0\n', "malformed CSV", 3),
}


def _make_input(path, spec):
    if spec is None:
        return
    if isinstance(spec, bytes):
        path.write_bytes(spec)
        return
    if isinstance(spec, str) and spec.startswith("bandwidth="):
        rows = [list(map(str, r)) + ["0.05"] for r in scene_rows()]
        rows[1][-1] = spec.split("=", 1)[1]
        write_csv(path, rows, CSV_COLUMNS + ("bandwidth",))
    elif isinstance(spec, str):
        path.write_text(spec)
    elif isinstance(spec, list):
        write_csv(path, [r[: len(spec)] for r in scene_rows()], spec)
    else:
        write_csv(path, _rows_with(spec))


@pytest.mark.parametrize("existing", [False, True], ids=["no-out", "existing-out"])
@pytest.mark.parametrize("name", list(FAILURES))
def test_concurrences_failure_modes(tmp_path, capsys, name, existing):
    spec, words, line = FAILURES[name]
    src = tmp_path / "in.csv"
    _make_input(src, spec)
    out = tmp_path / "out.csv"
    if existing:
        out.write_text("precious\n")
    before = sorted(os.listdir(tmp_path))
    status, stdout, stderr = run_main(capsys, ["concurrences", src, "--out", out])
    where = f"({src})" if line is None else f"({src}:{line})"
    assert_failed(status, stdout, stderr, words, where)
    assert stderr.rstrip("\n").endswith(where)
    assert sorted(os.listdir(tmp_path)) == before  # no OUT, no temporary file
    if existing:
        assert out.read_text() == "precious\n"


def test_gazerays_validation_error_is_one_line(tmp_path, scene_csv, capsys, monkeypatch):
    """A ValueError from GazeRays' own checks becomes one line and status 2, not a traceback."""

    def reject(*args):
        raise ValueError("GazeRays: origins of ray (0, 1) is not finite (NaN or inf)")

    monkeypatch.setattr(jaxgaze.rays, "_validate", reject)
    out = tmp_path / "out.csv"
    status, stdout, stderr = run_main(capsys, ["concurrences", scene_csv, "--out", out, *CHUNK])
    assert_failed(status, stdout, stderr, "GazeRays: origins of ray (0, 1) is not finite", str(scene_csv))
    assert not out.exists()


def test_unwritable_output(tmp_path, scene_csv, capsys):
    out = tmp_path / "no such dir" / "out.csv"
    status, stdout, stderr = run_main(capsys, ["concurrences", scene_csv, "--out", out, *CHUNK])
    assert_failed(status, stdout, stderr, "cannot write output: directory does not exist", str(out))


def test_write_failure_leaves_existing_output(tmp_path, scene_csv, capsys, monkeypatch):
    out = tmp_path / "out.csv"
    out.write_text("precious\n")

    def full_disk(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", full_disk)
    status, stdout, stderr = run_main(capsys, ["concurrences", scene_csv, "--out", out, *CHUNK])
    monkeypatch.undo()
    assert_failed(status, stdout, stderr, "cannot write output: No space left on device", str(out))
    assert out.read_text() == "precious\n"
    assert sorted(os.listdir(tmp_path)) == ["out.csv", "rays.csv"]


def test_input_is_a_directory(tmp_path, capsys):
    status, stdout, stderr = run_main(capsys, ["concurrences", tmp_path, "--out", tmp_path / "o.csv"])
    assert_failed(status, stdout, stderr, "directory")


@pytest.mark.parametrize(
    "argv",
    [
        [],
        ["frobnicate"],
        ["concurrences", "in.csv"],  # --out is required
        ["concurrences", "in.csv", "--out", "o.csv", "--bandwidth", "0"],
        ["concurrences", "in.csv", "--out", "o.csv", "--bandwidth", "nan"],
        ["concurrences", "in.csv", "--out", "o.csv", "--min-rays", "1"],
        ["demo", "--frames", "0"],
    ],
)
def test_usage_errors_exit_2(argv, capsys):
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    assert "usage: jaxgaze" in capsys.readouterr().err


def test_help_and_version(capsys):
    for argv in (["--help"], ["concurrences", "--help"], ["demo", "--help"], ["--version"]):
        with pytest.raises(SystemExit) as info:
            main(argv)
        assert info.value.code == 0
    assert "jaxgaze" in capsys.readouterr().out


# ---------------------------------------------------------------------------
# Outputs a user can use: full covariance, tracks, members, mutual gaze, a figure (issue 20)

# Frame 14: m0 and m1 look at each other, three people look at A. At most 11 people in a
# frame, so that these runs share the compiled (CHUNK, 11) program of the tests above.
_MUTUAL = [("m0", (0.0, 6.0, 1.6), (2.0, 6.0, 1.6)), ("m1", (2.0, 6.0, 1.6), (0.0, 6.0, 1.6))]


def mutual_rows():
    rows = scene_rows()
    for person, eye, target in _MUTUAL:
        rows.append([14, person, *eye, *(np.subtract(target, eye))])
    for i, eye in enumerate(_EYES_A[:3]):
        rows.append([14, f"a{i}", *eye, *(f"{x:.9f}" for x in POINT_A - np.asarray(eye))])
    return rows


def _table(path):
    header, rows = read_output(path)
    return header, [dict(zip(header, r)) for r in rows]


def test_concurrences_full_covariance_tracks_members_mutual_gaze_and_figure(tmp_path, capsys):
    from jaxgaze.concurrence import find_concurrences_over_frames, track_concurrences
    from jaxgaze.io.concurrences import MEMBER_COLUMNS
    from jaxgaze.io.rays import read_rays_csv

    src = write_csv(tmp_path / "rays.csv", mutual_rows())
    out, members, figure = tmp_path / "out.csv", tmp_path / "members.csv", tmp_path / "top.png"
    status, stdout, stderr = run_main(capsys, ["concurrences", src, "--out", out, "--members", members,
                                               "--figure", figure, *CHUNK])
    assert status == 0 and stdout == "", stderr
    assert stderr.splitlines() == [f"jaxgaze: 7 concurrence(s) in 4 frame(s) written to {out}; "
                                   f"1 mutual-gaze pair(s) (in {members})"]
    assert sorted(os.listdir(tmp_path)) == ["members.csv", "out.csv", "rays.csv", "top.png"]
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    # The library on the same file: the CSV holds its covariances (6 unique entries) and tracks.
    recording = read_rays_csv(src)
    found = find_concurrences_over_frames(recording.rays, frames_per_batch=12)
    tracks = np.asarray(track_concurrences(found).track_ids)
    header, rows = _table(out)
    assert tuple(header) == OUTPUT_COLUMNS
    slots = np.argwhere(np.asarray(found.valid))
    assert len(rows) == len(slots) == 7
    for row, (t, k) in zip(rows, slots):
        assert (int(row["frame"]), int(row["mode"]), int(row["track"])) == (recording.frame_ids[t], k, tracks[t, k])
        v = {c: float(row[c]) for c in header[6:12]}
        cov = np.array([[v["var_x"], v["cov_xy"], v["cov_xz"]], [v["cov_xy"], v["var_y"], v["cov_yz"]],
                        [v["cov_xz"], v["cov_yz"], v["var_z"]]])
        np.testing.assert_allclose(cov, np.asarray(found.covariances[t, k]), rtol=1e-5, atol=1e-12)
        assert np.all(np.linalg.eigvalsh(cov) > 0)  # symmetric by construction, positive definite
        assert float(row["degrees_of_freedom"]) > 4
    assert {int(r["frame"]) for r in rows if r["frame"] == "14"} == {14}
    frame14 = [r for r in rows if r["frame"] == "14"]
    assert len(frame14) == 1 and int(frame14[0]["num_rays"]) == 3  # A's group; the mutual pair is no concurrence

    # Members: one row per (frame, person); each group supports the mode at its point.
    header, people = _table(members)
    assert tuple(header) == MEMBER_COLUMNS and len(people) == len(mutual_rows())
    modes = {(r["frame"], r["mode"]): r for r in rows}
    for person in people:
        group = person["person"].rstrip("0123456789")
        mode = int(person["mode"])
        if group in POINTS:
            if mode >= 0:  # frame 11's pair looking at A is a concurrence too
                located = modes[(person["frame"], person["mode"])]
                point = np.array([float(located[c]) for c in ("x", "y", "z")])
                assert np.linalg.norm(point - POINTS[group]) < 5e-3
                assert person["track"] == located["track"]
            else:
                pytest.fail(f"{person} supports no concurrence")
        else:  # loners and the mutual pair
            assert mode == -1 and person["track"] == "-1"
        expected_partner = {"m0": "m1", "m1": "m0"}.get(person["person"], "")
        assert person["mutual_gaze"] == expected_partner


def test_concurrences_units_caught_at_the_door(tmp_path, capsys):
    """The unit rule (issue 34): origins in millimetres are exit 2 with one line naming the file, the frame id
    and the unit, and no output (an existing one kept); with --trust-units, no concurrence and one warning line.
    --bandwidth 3 (degrees meant): exit 2 before any work, always; 0.7 rad: exit 2 unless --trust-units."""
    mm = [[r[0], r[1], *(1000.0 * float(x) for x in r[2:5]), *r[5:]] for r in scene_rows()]
    src, out = write_csv(tmp_path / "mm.csv", mm), tmp_path / "out.csv"
    out.write_text("precious\n")
    status, stdout, stderr = run_main(capsys, ["concurrences", src, "--out", out, *CHUNK])
    assert_failed(status, stdout, stderr, "the eyes of frame 11 spread over", "(millimetres?)",
                  "pass --trust-units if they are right", f"({src})")
    assert out.read_text() == "precious\n"
    status, _, stderr = run_main(capsys, ["concurrences", src, "--out", out, "--trust-units", *CHUNK])
    assert status == 0
    warning, done = stderr.splitlines()
    assert warning.startswith("jaxgaze: warning: the eyes of frame ") and warning.endswith("(millimetres?)")
    assert done == f"jaxgaze: 0 concurrence(s) in 3 frame(s) written to {out}"
    out.unlink()
    status, stdout, stderr = run_main(capsys, ["concurrences", src, "--out", out, "--bandwidth", "3"])
    assert_failed(status, stdout, stderr, "--bandwidth 3 rad (172°)", "degrees? 3° is 0.0524 rad")
    assert not out.exists()
    metres = write_csv(tmp_path / "m.csv", scene_rows())
    status, stdout, stderr = run_main(capsys, ["concurrences", metres, "--out", out, "--bandwidth", "0.7", *CHUNK])
    assert_failed(status, stdout, stderr, "bandwidth reaches 0.7 rad (40°), implausibly wide", "--trust-units")
    assert not out.exists()
    status, _, stderr = run_main(capsys, ["concurrences", metres, "--out", out, "--bandwidth", "0.7", "--trust-units",
                                          *CHUNK])
    assert status == 0 and stderr.splitlines()[0] == ("jaxgaze: warning: bandwidth reaches 0.7 rad (40°), implausibly "
                                                      "wide for a gaze cone: it is in radians (degrees? 0.7° is "
                                                      "0.0122 rad)")


@pytest.mark.parametrize("option, name, words", [
    ("--figure", "top.xyz", "unsupported figure format '.xyz'"),
    ("--figure", "missing/top.png", "cannot write figure: directory does not exist"),
    ("--members", "missing/members.csv", "cannot write members table: directory does not exist"),
    ("--members", "out.csv", "--out and --members must be different files"),
])
def test_concurrences_bad_output_paths_fail_before_work(tmp_path, capsys, monkeypatch, option, name, words):
    import jaxgaze.concurrence

    def no_work(*args, **kwargs):
        raise AssertionError("computed before checking the outputs")

    monkeypatch.setattr(jaxgaze.concurrence, "find_concurrences_over_frames", no_work)
    src = write_csv(tmp_path / "rays.csv", scene_rows())
    status, stdout, stderr = run_main(capsys, ["concurrences", src, "--out", tmp_path / "out.csv",
                                               option, tmp_path / name])
    assert_failed(status, stdout, stderr, words)
    assert sorted(os.listdir(tmp_path)) == ["rays.csv"]


# ---------------------------------------------------------------------------
# demo


def test_demo_writes_table_and_figure(tmp_path, capsys):
    figure = tmp_path / "demo.png"
    frames = DEMO_FRAMES
    status, stdout, stderr = run_main(
        capsys, ["demo", "--frames", frames, "--seed", "1", "--figure", figure, "-q", *CHUNK]
    )
    assert status == 0, stderr
    assert stderr == ""  # -q: no stage lines (and no progress bar: stderr is not a terminal)
    with open(figure, "rb") as f:
        assert f.read(8) == b"\x89PNG\r\n\x1a\n"
    assert sorted(os.listdir(tmp_path)) == ["demo.png"]
    lines = stdout.splitlines()
    header = next(i for i, line in enumerate(lines) if line.split()[:4] == ["frame", "time_s", "K", "true_K"])
    table = [line.split() for line in lines[header + 1: lines.index("summary:")]]  # a row per (frame, concurrence)
    assert sorted({int(row[0]) for row in table}) == list(range(frames))
    for row in table:
        k, true_k = int(row[2]), int(row[3])
        assert 0 <= k <= 5 and true_k >= 1
        assert sum(other[0] == row[0] for other in table) == max(k, 1)  # one row per concurrence
    summary = "\n".join(lines[lines.index("summary:"):])
    assert "count accuracy" in summary and "median" in summary and "cm" in summary
    median = float(summary.split("median ")[1].split(" cm")[0])
    assert math.isfinite(median) and median < 20.0


def test_demo_bad_figure_path_fails_before_work(tmp_path, capsys):
    for figure, words in ((tmp_path / "demo.xyz", "unsupported figure format '.xyz'"),
                          (tmp_path / "missing" / "demo.png", "directory does not exist")):
        status, stdout, stderr = run_main(capsys, ["demo", "--frames", "3", "--figure", figure])
        assert_failed(status, stdout, stderr, words, str(figure))
    assert os.listdir(tmp_path) == []


def test_concurrences_bounds(tmp_path, scene_csv, capsys):
    """A box that excludes every known meeting point leaves no rows; a reversed box is an error."""
    out = tmp_path / "out.csv"
    box = ["--bounds", "-100", "-100", "50", "100", "100", "60"]
    status, _, stderr = run_main(capsys, ["concurrences", scene_csv, "--out", out, "--quiet", *CHUNK, *box])
    assert status == 0, stderr
    header, rows = read_output(out)
    assert rows == []
    out.unlink()
    reversed_box = ["--bounds", "0", "0", "0", "-1", "1", "1"]
    status, stdout, stderr = run_main(capsys, ["concurrences", scene_csv, "--out", out, *CHUNK, *reversed_box])
    assert_failed(status, stdout, stderr, "bounds")
    assert not out.exists()
