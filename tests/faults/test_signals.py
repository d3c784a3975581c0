"""Signals at any time: the ``jaxgaze`` console script ends with one line, outputs untouched, no litter.

Before issue 35 the SIGINT handler came only after ``import jaxgaze.cli`` (about 3 s): a Ctrl-C
earlier was swallowed (the run went on, replaced the output and exited 0) or gave a traceback;
SIGTERM ended every command silently and left a temporary file while writing; and the outputs of a
run were renamed one by one, so an interrupt could leave a new figure beside old CSVs.
"""

import os
import select
import signal
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
RAYS = os.path.join(ROOT, "examples", "concurrences", "rays.csv")
#: The installed console script (``pip install -e .`` puts it beside the interpreter).
SCRIPT = os.path.join(os.path.dirname(sys.executable), "jaxgaze")
OLD = {"out.csv": "old out\n", "members.csv": "old members\n", "figure.png": "old figure\n"}

#: The console script with the last CSV's writing slowed down: once its first row is written a
#: marker file appears, and the writer waits for a signal (the test sends it).
SLOW_WRITER = """
import os, sys, time
import jaxgaze.io.concurrences as concurrences
from jaxgaze.cli import console_main

write_csv_rows, out, marker = concurrences.write_csv_rows, sys.argv[1], sys.argv[2]

def slow_rows(rows):
    for index, row in enumerate(rows):
        if index == 1:
            open(marker, "w").close()
            time.sleep(600)
        yield row

def slowed(path, columns, rows):
    return write_csv_rows(path, columns, slow_rows(rows) if os.fspath(path) == out else rows)

concurrences.write_csv_rows = slowed
sys.argv = ["jaxgaze", *sys.argv[3:]]
console_main()
"""


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """One compilation cache for the runs that reach the writing: the command compiles once."""
    return tmp_path_factory.mktemp("cache")


def _env(**extra):
    return dict(os.environ, JAX_PLATFORMS="cpu", **extra)


def _old_outputs(directory):
    for name, text in OLD.items():
        (directory / name).write_text(text)


def _contents(directory):
    return {name: (directory / name).read_text() if name.endswith(".csv") else (directory / name).read_bytes()[:12]
            for name in sorted(os.listdir(directory))}


@pytest.mark.parametrize("signum, delay, status, line", [
    (signal.SIGINT, 0.5, 130, "jaxgaze: interrupted"),
    (signal.SIGINT, 1.0, 130, "jaxgaze: interrupted"),
    (signal.SIGINT, 2.0, 130, "jaxgaze: interrupted"),
    (signal.SIGTERM, 1.0, 143, "jaxgaze: terminated"),
])
def test_a_signal_in_the_first_seconds_ends_the_command_cleanly(tmp_path, signum, delay, status, line):
    """Sent while Python imports JAX (0.5, 1 s) or while it compiles (2 s, uncached): the status, one
    line, and the old output untouched."""
    assert os.path.exists(SCRIPT), f"the console script {SCRIPT} is not installed: pip install -e ."
    out = tmp_path / "out.csv"
    out.write_text("keep me\n")
    process = subprocess.Popen([SCRIPT, "concurrences", RAYS, "--out", str(out)], stdin=subprocess.DEVNULL,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               env=_env(JAXGAZE_CACHE_DIR="off"), start_new_session=True)
    try:
        try:
            process.wait(timeout=delay)
        except subprocess.TimeoutExpired:
            pass
        # an uncached run compiles for several seconds after its imports: still running
        assert process.poll() is None, process.communicate()
        process.send_signal(signum)
        stdout, stderr = process.communicate(timeout=300)
    finally:
        if process.poll() is None:
            process.kill()
    assert (process.returncode, stdout, stderr) == (status, "", line + "\n")
    assert os.listdir(tmp_path) == ["out.csv"] and out.read_text() == "keep me\n"


def _start_slow_run(tmp_path, cache):
    """The console script on the example with --members and --figure, paused in the writing of OUT."""
    _old_outputs(tmp_path)
    marker = tmp_path.parent / f"{tmp_path.name}.marker"
    argv = ["concurrences", RAYS, "--out", tmp_path / "out.csv", "--members", tmp_path / "members.csv",
            "--figure", tmp_path / "figure.png"]
    process = subprocess.Popen([sys.executable, "-c", SLOW_WRITER, str(tmp_path / "out.csv"), str(marker),
                                *map(str, argv)], stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True, env=_env(JAXGAZE_CACHE_DIR=str(cache)),
                               start_new_session=True)
    while not marker.exists():  # the wait ends when the marker appears or the process ends
        if process.poll() is not None:
            pytest.fail(f"the run ended before writing: {process.communicate()}")
        select.select([], [], [], 0.2)
    return process


@pytest.mark.parametrize("signum, status, line", [(signal.SIGINT, 130, "jaxgaze: interrupted"),
                                                  (signal.SIGTERM, 143, "jaxgaze: terminated")])
def test_a_signal_while_writing_keeps_every_old_output_and_no_temporary_file(tmp_path, cache, signum, status, line):
    """SIGINT or SIGTERM while the last of three outputs is written: all three old ones, nothing else."""
    out = tmp_path / "out"
    out.mkdir()
    process = _start_slow_run(out, cache)
    try:
        process.send_signal(signum)
        stdout, stderr = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            process.kill()
    assert (process.returncode, stderr) == (status, line + "\n")
    assert _contents(out) == {name: text if name.endswith(".csv") else text.encode()[:12]
                              for name, text in OLD.items()}


def test_sigkill_while_writing_leaves_no_mixed_set_and_the_next_run_removes_the_litter(tmp_path, cache):
    """SIGKILL cannot be caught: the old outputs must all still be there (no new figure beside old
    CSVs), and the temporary files it leaves are removed by the next run that writes those outputs."""
    out = tmp_path / "out"
    out.mkdir()
    process = _start_slow_run(out, cache)
    process.kill()
    process.communicate(timeout=60)
    assert {name: _contents(out)[name] for name in OLD} == {
        name: text if name.endswith(".csv") else text.encode()[:12] for name, text in OLD.items()}
    litter = sorted(set(os.listdir(out)) - set(OLD))
    assert litter and all("jaxgaze-tmp" in name for name in litter), litter  # recognisable, removed later

    again = subprocess.run([SCRIPT, "concurrences", RAYS, "--out", out / "out.csv", "--members", out / "members.csv",
                            "--figure", out / "figure.png", "-q"], stdin=subprocess.DEVNULL, capture_output=True,
                           text=True, env=_env(JAXGAZE_CACHE_DIR=str(cache)), timeout=600)
    assert (again.returncode, again.stderr) == (0, "")
    assert sorted(os.listdir(out)) == sorted(OLD)
    new = _contents(out)
    assert new["out.csv"].startswith("frame,") and new["members.csv"].startswith("frame,")
    assert new["figure.png"].startswith(b"\x89PNG")
