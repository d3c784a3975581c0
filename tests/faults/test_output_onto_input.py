"""An output path that is an input file is refused by every command, before any work.

Before issue 35 only ``joint`` checked: ``concurrences --out/--members``, ``calibrate --out`` and
``bias --out`` (also onto the speech file) replaced their input and exited 0.
"""

import os
import shutil

import pytest

from tests.cli.helpers import assert_failed, run_main

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
EXAMPLES = os.path.join(ROOT, "examples")
DATA = os.path.join(ROOT, "tests", "data")

#: (command line with {names} of files copied into the test's folder, the input the output lands on)
CASES = {
    "concurrences --out": ("concurrences {rays} --out {rays}", "rays"),
    "concurrences --members": ("concurrences {rays} --out {x}.csv --members {rays}", "rays"),
    "calibrate --out": ("calibrate {poses_a} {poses_b} --out {poses_b}", "poses_b"),
    "bias --out gaze": ("bias {gaze} --speech {speech} --partner ben --method lmeds --out {gaze}", "gaze"),
    "bias --out speech": ("bias {gaze} --speech {speech} --partner ben --method lmeds --out {speech}", "speech"),
    "bias --per-frame": ("bias {gaze} --speech {speech} --partner ben --method lmeds --out {x}.json "
                         "--per-frame {gaze}", "gaze"),
    "bias --out targets": ("bias {openface} --speech {speech} --partner ben --method lmeds --targets {targets} "
                           "--out {targets}", "targets"),
    "joint --out": ("joint {ann} {ben} --speech {rttm} --method svi --out {ben}", "ben"),
    "joint --per-frame": ("joint {ann} {ben} --speech {rttm} --method svi --out {x}.nc --per-frame {rttm}", "rttm"),
    "convert --out": ("convert --from l2cs {l2cs} --out {l2cs}", "l2cs"),
    "concurrences --calibration": ("concurrences {poses_a} --calibration {calib} --out {calib}", "calib"),
    "attend --out model": ("attend {video} --model {model} --out {model}", "model"),
    "attend --overlay video": ("attend {video} --model {model} --out {x}.csv --overlay {video}", "video"),
}
FILES = {
    "rays": os.path.join(EXAMPLES, "concurrences", "rays.csv"),
    "poses_a": os.path.join(EXAMPLES, "calibrate", "wearer_a.csv"),
    "poses_b": os.path.join(EXAMPLES, "calibrate", "wearer_b.csv"),
    "gaze": os.path.join(EXAMPLES, "bias", "ann_gaze.csv"),
    "openface": os.path.join(EXAMPLES, "bias", "ann_openface.csv"),
    "targets": os.path.join(EXAMPLES, "bias", "ann_targets_camera.csv"),
    "speech": os.path.join(EXAMPLES, "bias", "dyad_segments.csv"),
    "ann": os.path.join(EXAMPLES, "joint", "ann.csv"),
    "ben": os.path.join(EXAMPLES, "joint", "ben.csv"),
    "rttm": os.path.join(EXAMPLES, "joint", "speech.rttm"),
    "l2cs": os.path.join(DATA, "l2cs_dump.csv"),
}


def _files(folder):
    """The inputs copied into ``folder`` (and stand-ins for a calibration, a model and a video,
    which an output must not replace whatever their content)."""
    paths = {name: folder / os.path.basename(path) for name, path in FILES.items()}
    for name, path in FILES.items():
        shutil.copy(path, paths[name])
    for name, file_name in (("calib", "calib.json"), ("model", "gp.json"), ("video", "video.mkv")):
        paths[name] = folder / file_name
        paths[name].write_text(f"precious {name}\n")
    paths["x"] = folder / "new"
    return paths


@pytest.mark.parametrize("case", sorted(CASES))
@pytest.mark.parametrize("link", ["same path", "hard link", "symlink", "another spelling"])
def test_an_output_onto_an_input_is_refused(capsys, tmp_path, case, link):
    template, victim = CASES[case]
    paths = _files(tmp_path)
    before = paths[victim].read_bytes()
    target = paths[victim]
    if link == "hard link":
        target = tmp_path / "sub" / paths[victim].name
        target.parent.mkdir()
        os.link(paths[victim], target)
    elif link == "symlink":
        target = tmp_path / ("link" + paths[victim].suffix)
        target.symlink_to(paths[victim])
    elif link == "another spelling":
        target = tmp_path / "." / ".." / tmp_path.name / paths[victim].name
    tokens = template.split()
    last = len(tokens) - 1 - tokens[::-1].index("{" + victim + "}")  # the output: the input spelled another way
    argv = [str(target) if i == last else token.format(**paths) for i, token in enumerate(tokens)]
    status, stdout, stderr = run_main(capsys, argv)
    assert_failed(status, stdout, stderr, "would overwrite an input file")
    assert paths[victim].read_bytes() == before
    assert not (tmp_path / "new.csv").exists() and not (tmp_path / "new.json").exists()
