"""A fixation's spot where the data need it (issue 37, item 5): its Bayes factor against the model without, and the
descent to its mode through the mode without it."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from numpyro.infer.util import potential_energy
from scipy import integrate

from jaxgaze.joint import JointPrior, joint_data, joint_start
from jaxgaze.joint.infer import (SPOT_MIN_LOG_FACTOR, _arrays, _choose_spot, _model, _refine_start, _spot_log_bayes_factor, _start_values,
                                 _unconstrained)
from tests.helpers import held_conversation

SPOT = JointPrior()  # the default asks for a spot
PLAIN = JointPrior(held_scale=None)


def _plain_mode(share, dtype=jnp.float32):
    """The scene's start moved to the mode of the model without the spot, as :func:`fit_joint` does."""
    scene = held_conversation(share)
    data = joint_data(scene.eye_positions, scene.R_world_from_head, scene.gaze_angles, present=scene.present,
                      speaking=scene.speaking, measurement_scale=scene.measurement_scale, fps=scene.fps)
    start = joint_start(data, key=jax.random.key(0))
    arrays = _arrays(data, start.concurrence_centres, dtype)
    values = {k: jnp.asarray(v, dtype) for k, v in _unconstrained(_start_values(start, PLAIN, data.num_people)).items()}
    mode = _refine_start(values, arrays, PLAIN, True)
    return scene, arrays, mode


@pytest.mark.parametrize("share", [0.0, 0.5])
def test_the_spot_is_kept_where_fixations_hold_one_and_dropped_where_not(share):
    scene, arrays, mode = _plain_mode(share)
    prior, values, log_factor = _choose_spot(mode, arrays, SPOT)
    if share == 0.0:  # every frame's scatter independent: the simpler model
        assert log_factor < SPOT_MIN_LOG_FACTOR and prior.held_scale is None and values is mode
    else:
        assert log_factor > 20 and prior == SPOT
        share_at_mode = 0.8 * float(values["held_spread"]) ** 2 / (1 + float(values["held_spread"]) ** 2)
        assert share_at_mode == pytest.approx(share, abs=0.15)
        # the spot's descent starts from the mode without it and stays in its basin (20 s of 4 people, c = 0.5:
        # the biases' posterior sd is about 1°)
        errors = np.degrees(np.linalg.norm(np.asarray(values["bias"]) - scene.bias, axis=-1))
        moved = np.degrees(np.linalg.norm(np.asarray(values["bias"]) - np.asarray(mode["bias"]), axis=-1))
        assert errors.max() < 3.0 and moved.max() < 3.0


def test_the_spots_bayes_factor_against_adaptive_quadrature(x64):
    """The trapezoid rule over 48 squared-spaced points against scipy's adaptive quadrature of the same integrand,
    ``p(g | θ*, s) p(s) / p(g | θ*)`` over the whole line (float64)."""
    _, arrays, mode = _plain_mode(0.5, jnp.float64)
    potential = jax.jit(lambda s: potential_energy(_model(SPOT, None), tuple(arrays), {}, {**mode, "held_spread": s}))
    at_zero = float(potential(0.0))
    log_factor, best = (float(x) for x in _spot_log_bayes_factor(mode, arrays, SPOT))
    peak = at_zero - float(potential(best))
    integrand = lambda s: math.exp(at_zero - float(potential(s)) - peak)  # noqa: E731
    value, _ = integrate.quad(integrand, -6.0, 6.0, points=[-best, best], limit=200)
    expected = peak + math.log(value) - 0.5 * math.log(2 * math.pi)  # p(s = 0) of N(0, 1) undone
    assert log_factor == pytest.approx(expected, abs=0.05)
