"""The shared scene zoo: every simulated data set the tests use outside ``tests/simulate/``.

Each entry is simulated once per test session (memoised) and shared by every test
that asks for it by name, so the simulators run once and their programs compile
once. The simulators' own tests (``tests/simulate/``) keep calling the simulators
directly, since there the simulator is what is tested.

Entries are plain functions of a few named arguments; the defaults are the zoo's
standard sizes. Add a scene here rather than simulating in a test file.
"""

from __future__ import annotations

import functools

import jax

from jaxgaze import simulate

__all__ = [
    "saliency_scene",
    "calibration_session",
    "wearers",
    "dyad",
    "bias_evaluation_dyads",
    "tabletop_sessions",
    "tabletop_scene",
    "faces",
    "conversation",
    "held_conversation",
]


@functools.cache
def saliency_scene(preset: str, num_frames: int, seed: int = 0) -> simulate.Scene:
    """A social-saliency scene of :data:`jaxgaze.simulate.PRESETS` (people, gaze rays, truth)."""
    return simulate.simulate_scene(jax.random.key(seed), preset, num_frames)


@functools.cache
def calibration_session(num_frames: int = 80, seed: int = 0) -> simulate.CalibrationSession:
    """One wearer looking at a partner's camera: points of regard with the true gaze ray."""
    return simulate.simulate_calibration_session(jax.random.key(seed), num_frames=num_frames)


@functools.cache
def wearers(num_wearers: int, num_frames: int, seed: int, outlier_fraction: float | None = None) -> list:
    """``num_wearers`` calibration sessions of different wearers (with outliers if asked)."""
    extra = {} if outlier_fraction is None else {"outlier_fraction": outlier_fraction}
    return simulate.simulate_wearers(jax.random.key(seed), num_wearers, num_frames=num_frames, **extra)


@functools.cache
def dyad(preset: str, duration_s: float, seed: int = 3, fps: float | None = None) -> simulate.DyadicRecording:
    """One dyadic conversation (``"interview"`` or ``"desk"``) with speaking status and true bias."""
    extra = {} if fps is None else {"fps": fps}
    return simulate.simulate_dyadic(jax.random.key(seed), preset, duration_s=duration_s, **extra)


@functools.cache
def bias_evaluation_dyads(num_sessions: int, duration_s: float, seed: int = 2017) -> tuple[list, list, jax.Array]:
    """The speaker-prior evaluation set: ``num_sessions`` interview and ``num_sessions`` desk
    dyads, and the key left for the evaluation (the three keys split from ``seed``)."""
    k_interview, k_desk, k_eval = jax.random.split(jax.random.key(seed), 3)
    return (simulate.simulate_dyadic_sessions(k_interview, num_sessions, "interview", duration_s=duration_s),
            simulate.simulate_dyadic_sessions(k_desk, num_sessions, "desk", duration_s=duration_s),
            k_eval)


@functools.cache
def tabletop_sessions(seed: int, num_people: int, sessions_per_person: int, duration_s: float,
                      fps: float | None = None) -> list:
    """Table-top sessions (robot camera, head pose, attended object), one person after another."""
    extra = {} if fps is None else {"fps": fps}
    return simulate.simulate_tabletop_sessions(jax.random.key(seed), num_people=num_people,
                                               sessions_per_person=sessions_per_person, duration_s=duration_s,
                                               **extra)


@functools.cache
def tabletop_scene(session_args: tuple, index: int, seed: int) -> simulate.RenderedScene:
    """The rendered scene picture of session ``index`` of ``tabletop_sessions(*session_args)``."""
    return simulate.render_tabletop_scene(tabletop_sessions(*session_args)[index], key=jax.random.key(seed))


@functools.cache
def faces(seed: int, num_faces: int, **options) -> simulate.SimulatedFaces:
    """Simulated faces at known poses with noisy, partly missing feature hypotheses."""
    return simulate.simulate_faces(jax.random.key(seed), num_faces, **options)


@functools.cache
def conversation(num_people: int = 4, num_objects: int = 1, duration_s: float = 30.0, fps: float = 5.0,
                 num_wearers: int = 2, seed: int = 3) -> simulate.Conversation:
    """A group conversation with speaking turns, shared objects and known biases (the joint model's scene).

    The first ``num_wearers`` people wear head-mounted cameras with calibration sessions; cone
    widths of 1.5–2.5° keep Park's calibration walk informative at this size.
    """
    return simulate.simulate_conversation(
        jax.random.key(seed), num_people=num_people, num_objects=num_objects, duration_s=duration_s, fps=fps,
        num_wearers=num_wearers, config=simulate.conversation_config(cone_width_deg=(1.5, 2.5)))


@functools.cache
def held_conversation(held_cone_share: float, num_people: int = 4, duration_s: float = 20.0, seed: int = 5
                      ) -> simulate.Conversation:
    """A seated conversation at 10 fps, no wearers, where a share ``held_cone_share`` of the cone's variance is one
    offset held through each fixation (a fixation's spot; 0: every frame's scatter independent)."""
    return simulate.simulate_conversation(
        jax.random.key(seed), num_people=num_people, duration_s=duration_s,
        config=simulate.ConversationConfig(held_cone_share=held_cone_share))
