"""One option vocabulary across the commands, and outputs checked before any work.

Every subcommand of :func:`jaxgaze.cli.build_parser` writes its main output to ``--out`` and
has ``-q/--quiet`` with one meaning (no progress bar, no progress lines, no summary; warnings
still shown). Every output option (declared with ``add_output``) that names a directory, or a
file in a missing directory, fails with status 2 and one line before the command runs at all.
"""

import argparse
import sys

import pytest
from tests.cli.helpers import assert_failed, run_main

from jaxgaze import cli
from jaxgaze.cli import _common, build_parser
from jaxgaze.cli._common import QUIET_HELP, negative_values_joined


def _commands() -> dict:
    parser = build_parser()
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(sub.choices)


COMMANDS = _commands()


def _options(parser) -> dict:
    return {s: a for a in parser._actions for s in a.option_strings}


def _required_argv(parser, tmp_path) -> list:
    """The command's positionals and required options, each a path that does not exist (or, for an
    option with choices, its first choice)."""
    argv = [str(tmp_path / f"{a.dest}.in") for a in parser._actions if not a.option_strings]
    for a in parser._actions:
        if a.option_strings and a.required:
            argv += [a.option_strings[0], sorted(a.choices)[0] if a.choices else str(tmp_path / f"{a.dest}.x")]
    return argv


def test_every_command_has_out_and_quiet():
    assert set(COMMANDS) == {"demo", "concurrences", "convert", "calibrate", "bias", "joint", "attend",
                             "fit-gaze"}
    for name, parser in COMMANDS.items():
        options = _options(parser)
        assert "--out" in options, name
        assert parser.get_default("outputs")[options["--out"].dest][0] == "--out", name  # checked before work
        quiet = options.get("-q")
        assert quiet is not None and quiet is options["--quiet"], name
        assert (quiet.dest, quiet.nargs, quiet.const, quiet.default, quiet.help) == ("quiet", 0, True, False,
                                                                                      QUIET_HELP), name


@pytest.mark.parametrize("name", list(COMMANDS))
def test_quiet_means_no_progress_and_no_summary_but_warnings(name, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True, raising=False)
    parser = COMMANDS[name]
    argv = _required_argv(parser, tmp_path)
    for quiet in (False, True):
        args = parser.parse_args(argv + ["-q"] * quiet)
        assert _common.show_progress(args) is not quiet
        _common.summary(args, "the summary")
        _common.warn("a warning")
        lines = capsys.readouterr().err.splitlines()
        assert lines == ["jaxgaze: the summary"] * (not quiet) + ["jaxgaze: warning: a warning"]


def _outputs():
    return [(name, flag, what) for name, parser in COMMANDS.items()
            for flag, what in parser.get_default("outputs").values()]


@pytest.mark.parametrize("name, flag, what", _outputs())
def test_a_bad_output_fails_before_any_work(name, flag, what, tmp_path, capsys, monkeypatch):
    calls = []
    for module in cli.COMMANDS:
        monkeypatch.setattr(module, "run", lambda args: calls.append(args))
    directory = tmp_path / "taken.out"
    directory.mkdir()
    base = _required_argv(COMMANDS[name], tmp_path)
    if flag in base:  # a required output: replaced below
        i = base.index(flag)
        del base[i:i + 2]
    for path, words in ((directory, "it is a directory"), (f"{tmp_path}/new/", "it is a directory"),
                        (tmp_path / "missing" / "x.out", "directory does not exist")):
        status, stdout, stderr = run_main(capsys, [name, *base, flag, path])
        assert_failed(status, stdout, stderr, f"cannot write {what}: {words}", str(path))
    assert calls == []  # nothing ran
    assert sorted(p.name for p in tmp_path.iterdir()) == ["taken.out"]


def test_two_outputs_on_one_file_fail(tmp_path, capsys):
    out = tmp_path / "b.json"
    status, stdout, stderr = run_main(capsys, ["bias", "g.csv", "--speech", "s.rttm", "--out", out,
                                               "--per-frame", out])
    assert_failed(status, stdout, stderr, "--out and --per-frame must be different files")


def test_old_spellings_are_hidden_aliases(capsys):
    args = COMMANDS["demo"].parse_args(["--figure", "old.png"])
    assert args.figure == "old.png" and COMMANDS["demo"].parse_args([]).figure == "jaxgaze_demo.png"
    assert "--figure" not in COMMANDS["demo"].format_help()


def test_negative_numbers_are_values():
    argv = ["bias", "g.csv", "--speech", "s.rttm", "--out", "b.json", "--targets", "-1.7,0,2", "--seed", "-3",
            "--min-confidence", "-1e-3"]
    assert negative_values_joined(argv)[-5:] == ["--targets=-1.7,0,2", "--seed", "-3", "--min-confidence", "-1e-3 "]
    args = build_parser().parse_args(negative_values_joined(argv))
    assert (args.targets, args.seed, args.min_confidence) == ("-1.7,0,2", -3, -1e-3)
    bounds = ["concurrences", "r.csv", "--out", "o.csv", "--bounds", "-5", "-5", "0", "5", "5.5", "inf"]
    assert negative_values_joined(bounds) == bounds  # plain negative numbers: argparse reads them (nargs=6)
    assert build_parser().parse_args(bounds).bounds == [-5, -5, 0, 5, 5.5, float("inf")]
    open_sides = ["concurrences", "r.csv", "--out", "o.csv", "--bounds", "-inf", "-inf", "0", "inf", "inf", "-1e-3"]
    assert build_parser().parse_args(negative_values_joined(open_sides)).bounds == [
        -float("inf"), -float("inf"), 0, float("inf"), float("inf"), -1e-3]
    with pytest.raises(SystemExit):  # without the pre-pass argparse takes -inf for an option
        build_parser().parse_args(open_sides)
    assert negative_values_joined(["joint", "--", "--out", "-1,2"]) == ["joint", "--", "--out", "-1,2"]
    with pytest.raises(SystemExit):  # without the pre-pass argparse takes the point for an option
        build_parser().parse_args(argv)
