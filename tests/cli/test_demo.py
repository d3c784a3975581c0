"""``jaxgaze demo``: its scenes, its progress lines, the library's default options and its table.

In-process runs share the compiled concurrence search of the other CLI tests: 11 people
(the meeting and the party) in batches of ``--chunk 12`` frames.
"""

import contextlib
import io
import os

import pytest
from tests.cli.helpers import run_main

import jaxgaze.concurrence
import jaxgaze.plotting
from jaxgaze.cli import demo, main
from jaxgaze.concurrence import ConcurrenceOptions
from jaxgaze.simulate.scenes import PRESETS

CHUNK = ["--chunk", "12"]
STAGES = ("simulating", "finding the concurrences", "tracking", "drawing the figure")


def _table(stdout):
    """The table's lines (header first) and its rows split into cells."""
    lines = stdout.splitlines()
    start = next(i for i, line in enumerate(lines) if line.split()[:2] == ["frame", "time_s"])
    end = lines.index("summary:")
    return lines[start:end], [line.split() for line in lines[start + 1:end]]


def _column_ends(line):
    """Where each cell of a line ends (the columns are right-aligned)."""
    ends, inside = [], False
    for i, char in enumerate(line + " "):
        if char != " " and not inside:
            inside = True
        elif char == " " and inside:
            ends.append(i)
            inside = False
    return ends


@pytest.fixture(scope="module")
def party(tmp_path_factory):
    """One run on the party scene, with a spy on the options the demo gives the concurrence search."""
    figure = tmp_path_factory.mktemp("demo") / "party.png"
    calls = []
    search = jaxgaze.concurrence.find_concurrences_over_frames

    def spy(rays, *args, **kwargs):
        calls.append((args, kwargs))
        return search(rays, *args, **kwargs)

    out, err = io.StringIO(), io.StringIO()
    with pytest.MonkeyPatch.context() as mp, contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        mp.setattr(jaxgaze.concurrence, "find_concurrences_over_frames", spy)
        status = main(["demo", "--scene", "party", "--frames", "14", "--seed", "2", "--out", str(figure),
                       *CHUNK])
    return {"status": status, "stdout": out.getvalue(), "stderr": err.getvalue(), "figure": figure, "calls": calls}


def test_demo_scene_option_and_stage_lines(party):
    assert party["status"] == 0, party["stderr"]
    assert "'party' scene, 14 frames" in party["stdout"].splitlines()[0]
    lines = party["stderr"].splitlines()
    assert len(lines) == len(STAGES)
    for line, stage in zip(lines, STAGES):
        assert line.startswith(f"jaxgaze: {stage}"), lines
    assert "'party'" in lines[0] and str(party["figure"]) in lines[3]
    with open(party["figure"], "rb") as f:
        assert f.read(8) == b"\x89PNG\r\n\x1a\n"


def test_demo_uses_the_default_concurrence_options(party):
    """The demo passes no options of its own (no private bounds): the library's defaults."""
    ((args, kwargs),) = party["calls"]
    assert args in ((), (ConcurrenceOptions(),)) and kwargs.get("options", ConcurrenceOptions()) == ConcurrenceOptions()


def test_demo_table_in_track_order_with_aligned_columns(party):
    lines, rows = _table(party["stdout"])
    header = lines[0].split()
    assert header == ["frame", "time_s", "K", "true_K", "track", "x_m", "y_m", "z_m", "error_cm"]
    ends = _column_ends(lines[0])
    for line in lines[1:]:
        assert _column_ends(line) == ends, (lines[0], line)  # every cell ends under its header
    frames = [int(r[0]) for r in rows]
    assert frames == sorted(frames) and sorted(set(frames)) == list(range(14))
    tracks_seen, errors = 0, []
    for t in range(14):
        mine = [r for r in rows if int(r[0]) == t]
        k = int(mine[0][2])
        assert all(int(r[2]) == k for r in mine) and len(mine) == max(k, 1)  # one row per concurrence
        if k == 0:
            assert mine[0][4:] == ["-"] * 5
            continue
        ids = [int(r[4]) for r in mine]
        assert ids == sorted(ids) and len(set(ids)) == k  # in track order, each track once
        tracks_seen = max(tracks_seen, max(ids) + 1)
        errors += [float(r[8]) for r in mine if r[8] != "-"]
    assert tracks_seen >= 1 and all(e >= 0 for e in errors)
    assert sorted(errors)[len(errors) // 2] < 20.0  # median error against the matched truth, cm


def test_demo_quiet_has_no_stage_lines(tmp_path, capsys, monkeypatch):
    from matplotlib.figure import Figure

    monkeypatch.setattr(jaxgaze.plotting, "plot_scene_story", lambda *args: Figure())  # the figure is tested above
    figure = tmp_path / "quiet.png"
    argv = ["demo", "--frames", "20", "--seed", "1", "--out", figure, "-q", *CHUNK]  # as test_concurrences_demo
    status, stdout, stderr = run_main(capsys, argv)
    assert status == 0 and stderr == ""
    assert "'meeting' scene, 20 frames" in stdout  # the default scene
    assert os.listdir(tmp_path) == ["quiet.png"]


def test_demo_scenes_are_the_presets(capsys):
    assert set(demo.SCENES) == set(PRESETS)
    with pytest.raises(SystemExit) as info:
        main(["demo", "--scene", "office"])
    assert info.value.code == 2
    assert "invalid choice: 'office'" in capsys.readouterr().err
