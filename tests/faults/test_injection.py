"""Hostile names: no spreadsheet formula in a CSV jaxgaze writes, no control character on stderr.

Before issue 35 person names went into ``--members`` (and ``joint --per-frame``, ``convert``'s rays)
as they were, so a spreadsheet ran ``=HYPERLINK(...)``; and names and paths were echoed raw to
stderr, so a newline split the one error line and escape sequences reached the terminal.
"""

import ast
import csv
import os
import pathlib

import pytest

import jaxgaze
from jaxgaze.io.rays import read_rays_csv, write_rays_csv
from jaxgaze.io.text import read_csv_table, write_csv_rows
from tests.cli.helpers import run_main

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
RAYS = os.path.join(ROOT, "examples", "concurrences", "rays.csv")
#: Names that a spreadsheet would read as a formula (OWASP, "CSV Injection").
HOSTILE = {"p00": '=HYPERLINK("http://x","y")', "p01": "+1+cmd|' /C calc'!A0", "p02": "-2+3", "p03": "@SUM(A1)",
           "p04": "\tx", "p05": "\r=x"}
SPREADSHEET_TRIGGERS = ("=", "+", "-", "@", "\t", "\r")


def _hostile_rays(path):
    text = pathlib.Path(RAYS).read_text()
    for plain, hostile in HOSTILE.items():
        quoted = '"' + hostile.replace('"', '""') + '"'
        text = text.replace(f",{plain},", f",{quoted},")
    path.write_text(text)
    return path


def _cells(path):
    with open(path, newline="", encoding="utf-8") as handle:
        return [cell for row in csv.reader(handle) for cell in row]


def _is_number(text):
    try:
        float(text)
    except ValueError:
        return False
    return True


def _assert_safe(path):
    cells = _cells(path)
    unsafe = [c for c in cells if c.startswith(SPREADSHEET_TRIGGERS) and not _is_number(c)]
    assert not unsafe, unsafe
    return cells


def test_the_csv_writer_neutralises_formulas_and_keeps_numbers(tmp_path):
    path = tmp_path / "t.csv"
    write_csv_rows(path, ["=head", "name", "x"], [[name, name, -0.5] for name in HOSTILE.values()]
                   + [["-0.5", "-inf", "+3"], ["ok", "-1e-3", 2]])
    cells = _assert_safe(path)
    assert cells[0] == "'=head" and "'-2+3" in cells and "'@SUM(A1)" in cells and "'\tx" in cells
    assert cells[-6:] == ["-0.5", "-inf", "+3", "ok", "-1e-3", "2"]  # numbers stay numbers
    assert cells.count("-0.5") == len(HOSTILE) + 1
    # jaxgaze's readers take its own cells back as they were
    table = read_csv_table(path, ["name"], lower=False)
    assert [row.cell("name") for row in table.rows][:3] == [HOSTILE["p00"], HOSTILE["p01"], HOSTILE["p02"]]


def test_rays_written_by_convert_neutralise_names_and_read_back_the_same(tmp_path):
    recording = read_rays_csv(_hostile_rays(tmp_path / "in.csv"))
    write_rays_csv(tmp_path / "out.csv", recording)
    _assert_safe(tmp_path / "out.csv")
    again = read_rays_csv(tmp_path / "out.csv")
    assert list(map(list, again.persons)) == list(map(list, recording.persons))


def test_members_csv_of_hostile_names_is_safe(capsys, tmp_path):
    rays = _hostile_rays(tmp_path / "rays.csv")
    status, _, _ = run_main(capsys, ["concurrences", rays, "--out", tmp_path / "c.csv", "--members",
                                     tmp_path / "m.csv", "-q"])
    assert status == 0
    cells = _assert_safe(tmp_path / "m.csv")
    assert "'" + HOSTILE["p00"] in cells and "'-2+3" in cells
    _assert_safe(tmp_path / "c.csv")


def test_every_csv_writer_of_jaxgaze_goes_through_the_one_neutralising_writer():
    """No module but jaxgaze.io.text makes a ``csv.writer`` of its own."""
    package = pathlib.Path(jaxgaze.__file__).parent
    offenders = []
    for path in package.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Attribute) and node.attr in ("writer", "DictWriter") \
                    and isinstance(node.value, ast.Name) and node.value.id == "csv":
                offenders.append(f"{path.relative_to(package)}:{node.lineno}")
    assert offenders and all(o.startswith("io/text.py:") for o in offenders), offenders


@pytest.mark.parametrize("name", ["bad\nname.csv", "bad\x1b[31mred.csv", "bad\rname.csv", "bad\u2028line.csv"])
def test_a_path_with_control_characters_gives_one_escaped_line(capsys, tmp_path, name):
    status, stdout, stderr = run_main(capsys, ["concurrences", tmp_path / name, "--out", tmp_path / "o.csv"])
    assert status == 2 and stdout == ""
    assert stderr.endswith("\n") and stderr.count("\n") == 1, repr(stderr)
    assert not any(ord(c) < 32 or c in "\x7f\u2028\u2029" for c in stderr[:-1]), repr(stderr)
    assert stderr.startswith("jaxgaze: error: ") and "bad" in stderr


def test_a_summary_naming_a_path_with_a_newline_is_one_line(capsys, tmp_path):
    out = tmp_path / "two\nlines.csv"
    status, stdout, stderr = run_main(capsys, ["concurrences", RAYS, "--out", out])
    assert status == 0 and out.exists()
    assert stderr.count("\n") == 1 and "two\\nlines.csv" in stderr, repr(stderr)
