"""The long-recording path as it was before issue 16: one vmapped program over the whole recording.

Kept for ``hang_repro.py`` and ``bench_long_recording.py`` only. On XLA:CPU its batched
LAPACK calls are large enough to deadlock (docs/runtime.md).
"""

from jaxgaze import concurrence


def compile_old_path(rays, seed_depths=concurrence.DEFAULT_SEED_DEPTHS, max_iter=500, refine_steps=64):
    """``run()`` of the compiled single-vmap program over ``rays`` (default options otherwise)."""
    depths, box, static = concurrence._options(rays, seed_depths, None, 2, 3.0, 2.0, 0.9, 0.3, 1e-4, max_iter, None,
                                               100.0, refine_steps)
    static["modes_per_batch"] = static["max_modes"]  # every mode in one batch, as before
    program = concurrence._over_frames_jit.lower(rays, depths, box, **static).compile()
    return lambda: program(rays, depths, box)
