"""Issue 34 item 4: every long command shows progress when stderr is a terminal, and nothing with -q.

``joint`` (a minute or more) and ``fit-gaze`` printed nothing until they finished, although the
library drew bars: stretches of a minute passed between them (the start's mode, compiling NUTS,
rendering the video), and a terminal of unknown size draws no tqdm bar at all. They now print a
line per stage. Here stderr is a terminal (``isatty`` patched) and the long library call is replaced
by one that records its ``progress`` flag and stops the command (exit 2): fast, and what was printed
before it is what a user sees while the fit runs. The other commands' bars are tested with them
(``test_concurrences_demo``, ``test_bias``, ``test_attend``, ``test_calibrate``); ``calibrate`` has
no bar of its own, only its stage line.
"""

import sys
from pathlib import Path

import pytest
from tests.cli.helpers import run_main

import jaxgaze.calibration
import jaxgaze.headpose.regression
import jaxgaze.joint
from jaxgaze.cli._common import CommandError

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def _stopping(calls):
    def fake(*args, progress=False, **kwargs):
        calls.append(progress)
        raise CommandError("stopped by the test")

    return fake


COMMANDS = {
    "joint": (jaxgaze.joint, "fit_joint", [str(EXAMPLES / "joint" / f"{name}.csv") for name in ("ann", "ben", "cat")]
              + ["--speech", str(EXAMPLES / "joint" / "speech.rttm"), "--out", "{tmp}/joint.nc"]),
    "fit-gaze": (jaxgaze.headpose.regression, "fit_gaze_regression",
                 ["--people", "1", "--sessions", "1", "--duration", "3", "--out", "{tmp}/gp.json"]),
    "calibrate": (jaxgaze.calibration, "calibrate_cone",  # RANSAC: no bar of its own
                  [str(EXAMPLES / "calibrate" / f"wearer_{w}.csv") for w in "ab"] + ["--out", "{tmp}/calib.json"]),
}
#: The first words of the stage line just before the long call.
STAGES = {"joint": "jaxgaze: fitting the joint model to 50 frames of 3 people",
          "fit-gaze": "jaxgaze: fitting the gp gaze regression on", "calibrate": "jaxgaze: calibrating from 80 frame(s)"}


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_long_commands_show_progress_on_a_terminal_and_nothing_with_q(command, tmp_path, capsys, monkeypatch):
    module, name, argv = COMMANDS[command]
    calls = []
    monkeypatch.setattr(module, name, _stopping(calls))
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True, raising=False)
    argv = [command] + [a.format(tmp=tmp_path) for a in argv]
    for quiet in ([], ["-q"]):
        status, stdout, stderr = run_main(capsys, argv + quiet)
        assert status == 2 and stdout == "", stderr
        lines = stderr.splitlines()
        assert lines[-1] == "jaxgaze: error: stopped by the test"
        stages = [line for line in lines[:-1] if line.startswith("jaxgaze: ") and line.endswith("…")]
        if quiet:
            assert lines[:-1] == []
        else:
            assert stages and stages[-1].startswith(STAGES[command]), lines
    if command != "calibrate":
        assert calls == [True, False]  # the library's own bars: on a terminal, not with -q
