"""Issue 35, item 8: hostile inputs end in bounded time and memory with one line and exit 2.

Before: ``/dev/zero`` as input read 4 GB in 6.5 s; a FIFO with no writer blocked forever; a
2 GB file of zero bytes needed 4.4 GB; 10,000 people in one frame ended in a 44-line
``RESOURCE_EXHAUSTED`` traceback. Each command here runs in a child process with a 4 GiB
address-space limit and a wall-clock timeout: a reader that blocks or slurps fails the test.
"""

import csv
import os
import subprocess
import sys

import numpy as np
import pytest

from jaxgaze import ConcurrenceStream
from jaxgaze.concurrence import recording
from jaxgaze.io import text
from tests.cli.helpers import assert_failed, run_main

ADDRESS_SPACE = 4 << 30  # bytes; a child that reads /dev/zero or a 2 GiB file whole would exceed it
TIMEOUT_S = 120  # far above the few seconds these take; a blocked read never ends


# The child limits its own address space (a preexec_fn would run Python in a fork of this JAX process).
_LIMITED_CLI = ("import resource, runpy; resource.setrlimit(resource.RLIMIT_AS, ({0}, {0})); "
                "runpy.run_module('jaxgaze.cli', run_name='__main__')").format(ADDRESS_SPACE)


def _cli(*argv, cwd):
    """Run ``jaxgaze`` in a child process (memory-limited, timed out); ``(status, stdout, stderr)``."""
    done = subprocess.run([sys.executable, "-c", _LIMITED_CLI, *map(str, argv)], cwd=cwd, capture_output=True,
                          text=True, timeout=TIMEOUT_S)
    return done.returncode, done.stdout, done.stderr


@pytest.fixture
def fifo(tmp_path):
    path = tmp_path / "rays.csv"
    os.mkfifo(path)
    return path


def test_dev_zero_is_refused(tmp_path):
    assert_failed(*_cli("concurrences", "/dev/zero", "--out", "out.csv", cwd=tmp_path), "device", "/dev/zero")
    assert not (tmp_path / "out.csv").exists()


def test_fifo_without_writer_is_refused_without_blocking(tmp_path, fifo):
    assert_failed(*_cli("concurrences", fifo, "--out", "out.csv", cwd=tmp_path), "FIFO", "rays.csv")


def test_file_over_the_size_limit_is_refused_before_reading(tmp_path):
    path = tmp_path / "rays.csv"
    with open(path, "wb") as handle:  # a sparse file of 2 GiB of zero bytes: no disk, no time
        handle.truncate(2 << 30)
    assert_failed(*_cli("concurrences", path, "--out", "out.csv", cwd=tmp_path), "2 GiB", "larger than")


def test_huge_single_line_is_refused(tmp_path):
    path = tmp_path / "rays.csv"
    path.write_bytes(b"frame,person,ox,oy,oz,dx,dy,dz\n" + b"1" * (3 * text.MAX_LINE_BYTES))  # no newline
    assert_failed(*_cli("concurrences", path, "--out", "out.csv", cwd=tmp_path), "rays.csv:2", "longer than")


def test_nul_bytes_are_refused(tmp_path):
    path = tmp_path / "rays.csv"
    with open(path, "wb") as handle:
        handle.write(b"frame,person,ox,oy,oz,dx,dy,dz\n0,a,0,0,1.6,1,0,0\n")
        handle.truncate(64 << 20)  # then 64 MiB of zero bytes
    assert_failed(*_cli("concurrences", path, "--out", "out.csv", cwd=tmp_path), "NUL byte", "rays.csv:3")


def _crowd_csv(path, people):
    """One frame of ``people`` people on a circle, all looking at its centre."""
    angle = np.linspace(0.0, 2.0 * np.pi, people, endpoint=False)
    eyes = np.c_[5.0 * np.cos(angle), 5.0 * np.sin(angle), np.full(people, 1.6)]
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["frame", "person", "ox", "oy", "oz", "dx", "dy", "dz"])
        for k, eye in enumerate(eyes):
            writer.writerow([0, f"p{k}", *eye, *(np.array([0.0, 0.0, 1.0]) - eye)])


def test_too_many_people_in_a_frame_is_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(recording, "MAX_RAYS_PER_FRAME", 40, raising=False)  # the bound, made small for CI
    _crowd_csv(tmp_path / "rays.csv", 41)
    out = tmp_path / "out.csv"
    assert_failed(*run_main(capsys, ["concurrences", tmp_path / "rays.csv", "--out", out]), "41 people in one frame",
                  "at most 40")
    assert not out.exists()


def test_the_people_bound_holds_for_every_entry_point():
    people = getattr(recording, "MAX_RAYS_PER_FRAME", 2048) + 1
    with pytest.raises(ValueError, match=f"{people} people in one frame"):
        ConcurrenceStream(num_people=people)
