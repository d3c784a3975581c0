"""The long-recording path as it was before issue 16: one vmapped program over the whole recording.

Kept for ``hang_repro.py`` and ``bench_long_recording.py`` only. On XLA:CPU its batched
LAPACK calls are large enough to deadlock (docs/runtime.md).
"""

from jaxgaze.concurrence import ConcurrenceOptions
from jaxgaze.concurrence.recording import prepare, search_frames


def compile_old_path(rays, options=ConcurrenceOptions()):
    """``run()`` of the compiled single-vmap program over ``rays`` with ``options``."""
    depths, box, static = prepare(rays, options)
    static["modes_per_batch"] = static["max_modes"]  # every mode in one batch, as before
    program = search_frames.lower(rays, depths, box, **static).compile()
    return lambda: program(rays, depths, box)
