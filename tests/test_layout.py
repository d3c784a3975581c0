"""The house rules that import-linter cannot see: what ``import jaxgaze`` loads, and a thin CLI."""

import ast
import json
import pathlib
import subprocess
import sys

import jaxgaze

PACKAGE = pathlib.Path(jaxgaze.__file__).parent


def test_import_jaxgaze_loads_no_opencv_and_no_simulator():
    code = ("import json, sys, jaxgaze; "
            "print(json.dumps(sorted(m for m in sys.modules if m == 'cv2' or m.startswith('cv2.') "
            "or m.startswith('jaxgaze.simulate') or m.startswith('jaxgaze.io') or m.startswith('jaxgaze.papers'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=300)
    assert json.loads(out.stdout.strip().splitlines()[-1]) == []


def test_subpackages_that_need_opencv_load_on_first_use():
    code = ("import sys, jaxgaze; assert 'jaxgaze.vision' not in sys.modules; "
            "jaxgaze.vision.detect_faces; assert 'cv2' in sys.modules; print('ok')")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr


def _cli_modules():
    return sorted((PACKAGE / "cli").glob("*.py"))


def test_every_command_has_its_own_small_module():
    names = {p.stem for p in _cli_modules()}
    assert {"demo", "concurrences", "calibrate", "bias", "attend", "fit_gaze"} <= names
    sizes = {p.name: len(p.read_text().splitlines()) for p in _cli_modules()}
    # "About 150 lines": the bias command's help text alone is about 90.
    assert max(sizes.values()) <= 210, sizes


def test_the_cli_parses_no_csv_and_computes_nothing():
    forbidden_modules = {"csv", "numpyro", "optimistix", "scipy"}
    for path in _cli_modules():
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                assert not {a.name.split(".")[0] for a in node.names} & forbidden_modules, (path.name, node.lineno)
            if isinstance(node, ast.ImportFrom) and node.module:
                assert node.module.split(".")[0] not in forbidden_modules, (path.name, node.lineno)
            if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in ("jnp", "np"):
                assert node.attr in {"asarray", "mean", "isfinite", "sum", "full", "nan"}, \
                    (path.name, node.lineno, node.attr)
