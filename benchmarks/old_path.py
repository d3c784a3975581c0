"""The long-recording path as it was before issue 16: one vmapped program over the whole recording.

Kept for ``hang_repro.py`` and ``bench_long_recording.py`` only. On XLA:CPU its batched
LAPACK calls are large enough to deadlock (docs/runtime.md).
"""

from jaxgaze.concurrence import ConcurrenceOptions, modes


def compile_old_path(rays, options=ConcurrenceOptions()):
    """``run()`` of the compiled single-vmap program over ``rays`` with ``options``."""
    depths, box, static = modes._prepare(rays, options)
    static["modes_per_batch"] = static["max_modes"]  # every mode in one batch, as before
    program = modes._over_frames_jit.lower(rays, depths, box, **static).compile()
    return lambda: program(rays, depths, box)
