"""The XLA:CPU LAPACK deadlock (docs/runtime.md): compiled programs stay clear of it, and nothing hangs.

Two kinds of evidence. The audit reads every program a piece of code compiles
and applies jaxlib's own rule for splitting a batched LAPACK call over the
thread pool (the precondition of the deadlock): no program of the long-recording
path or of the posteriors may have such a call. The stress test runs the
long-recording path in fresh processes, several calls each, and fails on a run
that stops making progress; on the code before the guard most runs hung.
"""

from __future__ import annotations

import os
import sys
import textwrap

import pytest

from tests import helpers as zoo
from tests.concurrence.deadlock_tools import audit, run_until_stalled

pytestmark = pytest.mark.skipif(sys.platform != "linux", reason="the audit and the stress test use Linux processes")

# A recording long enough that one vmapped program over all of it had 8,000 LU
# factorisations in one LAPACK call (jaxlib splits above 7,408): the stress
# test's scene. Short mean-shift and refinement keep each call to a few seconds.
_RECORDING = """
import jax, numpy as np
from jaxgaze.simulate import simulate_scene
from jaxgaze import ConcurrenceOptions, find_concurrences_over_frames
scene = simulate_scene(jax.random.key(4), "meeting", num_frames=1600)
options = ConcurrenceOptions(seed_depths=(1.0, 3.0), max_iter=60, refine_steps=16)
"""


def _splitting(calls):
    return sorted({c for c in calls if c.splits}, key=lambda c: -c.batch * c.cost)


def test_audit_flags_a_call_that_jaxlib_splits():
    """The audit can fail: 10,000 batched 3×3 inverses are split (10,000 > ⌈200,000 / 27⌉)."""
    calls = audit("import jax, jax.numpy as jnp\n"
                  "jax.jit(jax.vmap(jnp.linalg.inv))(jnp.tile(jnp.eye(3), (10000, 1, 1))).block_until_ready()\n"
                  "jax.jit(jax.vmap(jnp.linalg.inv))(jnp.tile(jnp.eye(3), (7000, 1, 1))).block_until_ready()")
    lu = {c.batch: c.splits for c in calls if c.routine == "getrf"}
    assert lu == {10000: True, 7000: False}


def test_long_recording_programs_cannot_split_lapack_calls():
    """Every program of find_concurrences_over_frames, for the meeting and for a 120-person crowd."""
    calls = audit(_RECORDING + textwrap.dedent("""
        find_concurrences_over_frames(scene.rays, options)
        rng = np.random.default_rng(0)
        eyes = rng.uniform(-5, 5, (3, 120, 3))
        crowd = jax.numpy.asarray(rng.normal(0, 0.5, (3, 120, 3)) - eyes)
        from jaxgaze import GazeRays
        find_concurrences_over_frames(GazeRays(eyes, crowd), options)
    """))
    routines = {c.routine for c in calls}
    assert {"geqrf", "syevd"} <= routines  # the refinement and covariance (QR) and the region (eigh) were audited
    assert max(c.batch * c.cost for c in calls if c.routine == "geqrf") > 200_000 / 4  # batches are not tiny
    assert _splitting(calls) == []


def test_posterior_programs_cannot_split_lapack_calls():
    """The NUTS program of the bias posteriors (the calibration's shares it) constrains draws one at a time.

    (The GP fit and prediction factor one matrix per call, batch 1, which never splits;
    audited by hand, see docs/runtime.md.)"""
    calls = audit(textwrap.dedent("""
        import jax, numpy as np
        from jaxgaze.bias.estimators import sample_bias_posterior
        offsets = np.random.default_rng(0).normal(0, 0.1, (2, 200, 2))
        sample_bias_posterior(offsets, key=jax.random.key(0), num_warmup=5, num_samples=500)
    """))
    assert any(c.routine == "trsm" and c.cost * 500 > 200_000 for c in calls)  # vmapped over draws, it would split
    assert _splitting(calls) == []


@pytest.fixture(scope="module")
def compilation_cache(tmp_path_factory):
    """A persistent compilation cache shared by the stress runs: only the first one compiles."""
    return dict(os.environ, JAX_PLATFORMS="cpu", JAX_COMPILATION_CACHE_DIR=str(tmp_path_factory.mktemp("jax_cache")),
                JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0")


@pytest.mark.parametrize("run", range(2))
def test_long_recording_never_hangs(run, compilation_cache):
    """Stress: the long-recording path, three calls in a fresh process, none silent for 150 s."""
    code = _RECORDING + textwrap.dedent("""
        for call in range(3):
            found = find_concurrences_over_frames(scene.rays, options)
            print("call", call, int(np.sum(found.valid)), flush=True)
    """)
    # A stall, not a slow start: the first call compiles two programs (cold and warm-started frames),
    # which on a loaded 2-core machine can take over a minute.
    stalled, lines = run_until_stalled(code, [], stall_s=150.0, env=compilation_cache)
    assert not stalled, f"run {run} hung after {sum(line.startswith('call') for line in lines)} of 3 calls"
    counts = {line.split()[2] for line in lines if line.startswith("call")}
    assert len(counts) == 1 and int(counts.pop()) > 1000  # three calls, the same concurrences each time


# ---------------------------------------------------------------------------
# The batching itself, in process


@pytest.fixture(scope="module")
def short_meeting():
    return zoo.saliency_scene("meeting", 12, seed=5).rays


def test_batching_does_not_change_the_concurrences(short_meeting):
    """Batches of 5 (the last padded with empty frames) find what one batch of 12 finds."""
    import numpy as np

    from jaxgaze import find_concurrences_over_frames

    whole = find_concurrences_over_frames(short_meeting, frames_per_batch=12)
    batched = find_concurrences_over_frames(short_meeting, frames_per_batch=5)
    assert isinstance(batched.locations, np.ndarray) and batched.locations.shape == whole.locations.shape
    np.testing.assert_array_equal(batched.valid, whole.valid)
    np.testing.assert_array_equal(batched.membership, whole.membership)
    assert whole.valid.sum() >= 12  # every frame has concurrences
    np.testing.assert_allclose(batched.locations[whole.valid], whole.locations[whole.valid], atol=1e-3)


def test_frames_per_batch_above_the_cpu_bound_is_refused(short_meeting):
    from jaxgaze import find_concurrences_over_frames

    with pytest.raises(ValueError, match="deadlocking"):
        find_concurrences_over_frames(short_meeting, frames_per_batch=1000)
    for bad in (0, -3, 2.5):
        with pytest.raises(ValueError, match="frames_per_batch"):
            find_concurrences_over_frames(short_meeting, frames_per_batch=bad)


def test_cli_refuses_a_chunk_above_the_bound(tmp_path, capsys, short_meeting):
    import csv

    import numpy as np
    from tests.cli.helpers import assert_failed, run_main

    src = tmp_path / "rays.csv"
    with open(src, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["frame", "person", "ox", "oy", "oz", "dx", "dy", "dz"])
        for t in range(2):
            for i in range(11):
                writer.writerow([t, f"p{i}", *np.asarray(short_meeting.origins[t, i]),
                                 *np.asarray(short_meeting.directions[t, i])])
    out = tmp_path / "out.csv"
    assert_failed(*run_main(capsys, ["concurrences", src, "--out", out, "--chunk", "1000"]), "deadlock", "--chunk")
    assert not out.exists()


def test_map_in_batches_matches_one_call_and_sees_one_shape():
    import numpy as np

    from jaxgaze._batching import map_in_batches

    seen = set()

    def double(part):
        seen.add(part["x"].shape)
        return {"y": part["x"] * 2.0, "s": part["x"].sum(axis=1)}

    x = np.arange(23 * 3, dtype=float).reshape(23, 3)
    out = map_in_batches(double, {"x": x}, 5)
    np.testing.assert_array_equal(out["y"], 2 * x)
    np.testing.assert_array_equal(out["s"], x.sum(axis=1))
    assert seen == {(5, 3)}
    with pytest.raises(ValueError, match="at least one entry"):
        map_in_batches(double, {"x": x[:0]}, 5)
