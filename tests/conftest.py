"""Shared fixtures. Tests run on CPU in float32 unless they ask for ``x64``.

The slow tier: ``pytest -m "not slow"`` leaves out the notebooks and the files and tests named in
:data:`SLOW_FILES` and :data:`SLOW_TESTS` (the README runner, command-line runs in fresh processes,
NUTS posteriors, coverage studies): under 5 minutes on 2 cores, for everyday work. ``pytest`` runs all.
"""

import pathlib

import jax
import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent
#: Test files whose every test is slow (paths relative to the repository).
SLOW_FILES = frozenset()
#: Single slow tests (pytest node ids) in files that are otherwise quick.
SLOW_TESTS = frozenset()


def pytest_collection_modifyitems(config, items):
    """Mark the slow tier: the notebooks, :data:`SLOW_FILES` and :data:`SLOW_TESTS`."""
    for item in items:
        path = pathlib.Path(str(item.path)).resolve()
        relative = path.relative_to(ROOT).as_posix() if path.is_relative_to(ROOT) else str(path)
        base = item.nodeid.split("[")[0]
        if relative.startswith("notebooks/") or relative in SLOW_FILES or base in SLOW_TESTS:
            item.add_marker(pytest.mark.slow)

# No persistent compilation cache inside the test processes (``import jaxgaze`` would turn it on): a
# worker compiles what it runs, as it did before issue 34, and never loads programs another worker
# is writing. The commands the tests start as subprocesses keep it (the environment is untouched),
# and tests/test_runtime.py and tests/faults/test_cache.py check the cache in fresh processes.
jax.config.update("jax_enable_compilation_cache", False)


@pytest.fixture
def x64():
    """Run the test body with ``jax_enable_x64`` on, restoring it afterwards."""
    with jax.enable_x64(True):
        yield
