"""Helpers shared by the CLI tests."""

from jaxgaze.cli import main


def run_main(capsys, argv):
    """Run the CLI in-process; returns ``(status, stdout, stderr)``."""
    status = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return status, out, err


def assert_failed(status, stdout, stderr, *words):
    """Exit status 2, nothing on stdout, one ``jaxgaze: error:`` line naming ``words``, no traceback."""
    assert status == 2
    assert stdout == ""
    lines = stderr.splitlines()
    assert len(lines) == 1, stderr
    assert lines[0].startswith("jaxgaze: error: ")
    for word in words:
        assert word in lines[0], (word, lines[0])
    assert "Traceback" not in stderr
