"""Shared fixtures. Tests run on CPU in float32 unless they ask for ``x64``."""

import jax
import pytest


@pytest.fixture
def x64():
    """Run the test body with ``jax_enable_x64`` on, restoring it afterwards."""
    with jax.enable_x64(True):
        yield
