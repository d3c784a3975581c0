"""A figure that cannot be written, in any format, is one error line (exit 2) and no file.

Before issue 35 a ``.pdf`` on a full disk gave a 50-line traceback (``zlib.error``, exit 1); the
other formats gave one line. The full disk here is a file-size limit (RLIMIT_FSIZE: writes fail
with EFBIG, as they fail with ENOSPC on a full disk), in a fresh process.
"""

import json
import os
import subprocess
import sys

#: In a fresh process: a figure written through the command's ``writing`` block to every format
#: matplotlib writes, first without a limit, then with files limited to 2 kB. Prints, per format,
#: what came out: "ok", "error: <the one line>" or the exception's type, and what the folder holds.
PROGRAM = r"""
import json, os, resource, signal, sys
import matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot as plt
from matplotlib.backends.backend_agg import FigureCanvasAgg
from jaxgaze.cli._common import CommandError, error_line, writing
from jaxgaze.io.figures import write_figure

folder = sys.argv[1]
figure, ax = plt.subplots()
ax.plot(range(1000), [i ** 0.5 for i in range(1000)])
ax.set_title("a figure with some text " * 3)
report = {}
for limited in (False, True):
    if limited:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (2048, 2048))
    for fmt in sorted(FigureCanvasAgg.get_supported_filetypes()):
        path = os.path.join(folder, f"{'full' if limited else 'free'}.{fmt}")
        try:
            with writing(path, "figure"):
                write_figure(path, figure)
            outcome = "ok"
        except CommandError as error:
            outcome = "error: " + error_line(error)
        except BaseException as error:
            outcome = type(error).__module__ + "." + type(error).__name__
        report.setdefault(fmt, []).append(outcome)
report["files"] = sorted(os.listdir(folder))
print(json.dumps(report))
"""


def test_a_full_disk_gives_one_line_for_every_figure_format(tmp_path):
    done = subprocess.run([sys.executable, "-c", PROGRAM, str(tmp_path)], capture_output=True, text=True,
                          timeout=300, env=dict(os.environ, JAX_PLATFORMS="cpu"))
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout.strip().splitlines()[-1])
    files = report.pop("files")
    writable = {fmt for fmt, (free, _) in report.items() if free == "ok"}
    assert {"png", "pdf", "svg", "ps", "eps"} <= writable, report
    for fmt in writable:
        full = report[fmt][1]
        # too big for 2 kB (raw, rgba, png, pdf, ...): one line naming the figure; else written whole
        assert full == "ok" or (full.startswith("error: cannot write figure: ") and "\n" not in full
                                and full.endswith(f"full.{fmt})")), (fmt, full)
    assert sum(report[fmt][1] != "ok" for fmt in writable) >= 5, report
    assert all(not name.startswith(".") for name in files), files  # no temporary file left
    assert {f"full.{fmt}" for fmt in writable if report[fmt][1] != "ok"}.isdisjoint(files)
