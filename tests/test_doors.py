"""Small doors, and no import past them (issue 36).

Each model family's door (``jaxgaze/<family>/__init__.py``) exports its entry points, result
types and options: at most 15 names (``io``, the readers of eight formats and seven tools: 50).
Everything else stays importable from the public module that defines it. Outside its own
family (other families, ``cli/``, ``experiments/``, ``benchmarks/``, ``notebooks/``), code imports
a family's names from its door or its public modules, never a private module (``_frame``) or a
private name (``_refine``). Tests may look inside.
"""

import ast
import importlib
import json
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent
FAMILIES = ("calibration", "concurrence", "bias", "gp", "headpose", "vision", "facial", "joint")
DOOR_LIMITS = {**dict.fromkeys(FAMILIES, 15), "io": 50}


@pytest.mark.parametrize("family", sorted(DOOR_LIMITS))
def test_every_door_is_small(family):
    door = importlib.import_module(f"jaxgaze.{family}")
    names = list(door.__all__)
    assert len(names) == len(set(names)), f"jaxgaze.{family}.__all__ repeats a name"
    assert len(names) <= DOOR_LIMITS[family], f"jaxgaze.{family} exports {len(names)} names: {sorted(names)}"
    missing = [name for name in names if not hasattr(door, name)]
    assert not missing, f"jaxgaze.{family}.__all__ names what it does not define: {missing}"


def _sources():
    """(path, python source) of every file whose imports the rule covers."""
    for folder in ("jaxgaze", "experiments", "benchmarks", "examples"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            yield path, path.read_text()
    for path in sorted((ROOT / "notebooks").glob("*.ipynb")):
        cells = json.loads(path.read_text())["cells"]
        code = "\n".join("".join(c["source"]) for c in cells if c["cell_type"] == "code")
        yield path, "\n".join(line for line in code.splitlines() if not line.lstrip().startswith(("%", "!")))


def _family_of(path: pathlib.Path):
    parts = path.relative_to(ROOT).parts
    return parts[1] if len(parts) > 2 and parts[0] == "jaxgaze" else None


def imports_past_a_door(path: pathlib.Path, source: str) -> list[str]:
    """The imports in ``source`` (from file ``path``) that reach past another family's door."""
    own = _family_of(path)
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            modules, names = [node.module], [alias.name for alias in node.names]
        elif isinstance(node, ast.Import):
            modules, names = [alias.name for alias in node.names], []
        else:
            continue
        for module in modules:
            parts = module.split(".")
            if parts[0] != "jaxgaze" or len(parts) < 2 or parts[1] not in DOOR_LIMITS or parts[1] == own:
                continue
            private = [p for p in parts[2:] if p.startswith("_")] + [n for n in names if n.startswith("_")]
            if private:
                found.append(f"{path.relative_to(ROOT)}:{node.lineno}: {module} ({', '.join(private)})")
    return found


def test_no_import_past_a_door():
    found = [line for path, source in _sources() for line in imports_past_a_door(path, source)]
    assert not found, "imports past a family's door:\n" + "\n".join(found)


def test_the_rule_sees_a_planted_import():
    """The check itself: a private module or name of another family is caught; the door, a public
    module, and a family's own private modules are not."""
    cli = ROOT / "jaxgaze" / "cli" / "x.py"
    inside = ROOT / "jaxgaze" / "gp" / "x.py"
    assert imports_past_a_door(cli, "from jaxgaze.concurrence._frame import frame_modes")
    assert imports_past_a_door(cli, "from jaxgaze.gp.kernels import _stationary")
    assert imports_past_a_door(cli, "import jaxgaze.io._csv")
    assert not imports_past_a_door(cli, "from jaxgaze.gp import fit\nfrom jaxgaze.gp.kernels import RBF")
    assert not imports_past_a_door(inside, "from jaxgaze.gp._fit import fit")
