"""Ctrl-C: the ``jaxgaze`` console script ends with status 130, one line on stderr and no output file.

The console script (``jaxgaze.cli:console_main``) is run in a subprocess on a long NUTS
fit and sent SIGINT while it computes. A normal interpreter shutdown with XLA's threads
still running crashed it (exit -11); a lost ``KeyboardInterrupt`` let it run on (exit 0).
In-process, :func:`jaxgaze.cli.main` returns 130 (tests/cli/test_joint_cli.py).
"""

import os
import select
import signal
import subprocess
import sys
import time
import tomllib

import numpy as np
import pytest

from jaxgaze.cli._common import writing
from jaxgaze.cli._interrupt import _on_interrupt

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
#: What the generated console script runs, with a line on stderr once the imports are done.
CONSOLE = ("import sys; from jaxgaze.cli import console_main; print('imported', file=sys.stderr, flush=True); "
           "console_main()")


def _bias_inputs(directory):
    """A person facing the partner 1.5 m ahead for 60 s at 10 fps while the partner speaks."""
    rng = np.random.default_rng(0)
    rows = ["frame,timestamp,yaw,tilt,qw,qx,qy,qz,ex,ey,ez,tx,ty,tz"]
    for t in range(600):
        yaw, tilt = -0.1 + 0.02 * rng.normal(), 0.05 + 0.02 * rng.normal()
        rows.append(f"{t},{t / 10:.1f},{yaw!r},{tilt!r},1,0,0,0,0,0,1.2,1.5,0,1.2")
    gaze, speech = directory / "gaze.csv", directory / "speech.csv"
    gaze.write_text("\n".join(rows) + "\n")
    speech.write_text("start,end,speaker\n0,60,ben\n")
    return gaze, speech


def test_the_console_script_is_console_main():
    with open(os.path.join(ROOT, "pyproject.toml"), "rb") as f:
        assert tomllib.load(f)["project"]["scripts"]["jaxgaze"] == "jaxgaze_console:main"


def test_ctrl_c_during_nuts_exits_130_and_leaves_no_file(tmp_path):
    gaze, speech = _bias_inputs(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    kept = out / "bias.json"
    kept.write_text("precious\n")
    argv = ["bias", gaze, "--speech", speech, "--out", kept, "--per-frame", out / "frames.csv", "--samples", "20000"]
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    process = subprocess.Popen([sys.executable, "-c", CONSOLE, *map(str, argv)], stdin=subprocess.DEVNULL,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                               start_new_session=True)
    try:
        ready, _, _ = select.select([process.stderr], [], [], 120)
        assert ready and process.stderr.readline() == "imported\n"
        time.sleep(4.0)  # reading the files, compiling and sampling (20,000 NUTS steps take far longer)
        assert process.poll() is None, process.communicate()
        process.send_signal(signal.SIGINT)
        stdout, stderr = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
    assert (process.returncode, stdout, stderr) == (130, "", "jaxgaze: interrupted\n")
    assert sorted(os.listdir(out)) == ["bias.json"] and kept.read_text() == "precious\n"


def test_ctrl_c_while_writing_raises_so_that_the_writer_cleans_up(tmp_path):
    """While an output is written the handler raises (the atomic writer deletes its temporary file)."""
    with pytest.raises(KeyboardInterrupt), writing(tmp_path / "x.json"):
        _on_interrupt(signal.SIGINT, None)
