"""The joint model: the summed-out likelihood against brute-force enumeration, gradients, and the door checks."""

from __future__ import annotations

import itertools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.flatten_util import ravel_pytree
from numpyro import handlers
from numpyro.infer.util import potential_energy

from jaxgaze.cone import cone_direction_log_density
from jaxgaze.geometry import head_pose_to_rotation
from jaxgaze.joint import BLOCK_FRAMES, JointPrior, joint_data, target_marginals
from jaxgaze.joint.model import candidate_log_probabilities, joint_model, marginal_log_likelihood
from jaxgaze.joint.infer import _arrays, _drop_masked
from jaxgaze.joint import model
from jaxgaze.joint.model import MAX_HELD_CONE_SHARE, ModelArrays, _candidate_terms


def _tiny(seed=0, T=2, P=3, K=1):
    rng = np.random.default_rng(seed)
    angles = np.linspace(0, 2 * np.pi, P, endpoint=False)
    eyes = np.stack([np.cos(angles), np.sin(angles), np.full(P, 1.2)], -1)[None] + 0.02 * rng.normal(size=(T, P, 3))
    yaw = angles[None] + np.pi + 0.3 * rng.normal(size=(T, P))
    R = np.asarray(head_pose_to_rotation(jnp.asarray(yaw), jnp.asarray(0.1 * rng.normal(size=(T, P))),
                                         jnp.zeros((T, P))))
    gaze = 0.3 * rng.normal(size=(T, P, 2))
    speaking = rng.random((T, P)) < 0.4
    data = joint_data(eyes, R, gaze, speaking=speaking, measurement_scale=0.01 + 0.02 * rng.random((T, P)), fps=5.0)
    centres = rng.normal(size=(1, K, 3)) * 0.3 + np.array([0.0, 0.0, 0.8])
    params = {"bias": 0.1 * rng.normal(size=(P, 2)), "cone_width": 0.05 + 0.1 * rng.random(P),
              "alpha_person": 0.4, "alpha_object": -0.3, "speaker_effect": 1.8, "stay": 0.7,
              "locations": centres + 0.1 * rng.normal(size=centres.shape)}
    return data, centres, params


def _per_gazer(data, params):
    """For every frame and person: ``{candidate: (log prior of a new target, log likelihood)}``, written out in numpy."""
    T, P = data.present.shape
    K = params["locations"].shape[1]

    def log_fisher(cosine, h):
        kappa = 1.0 / h**2
        return math.log(kappa) - math.log(2 * math.pi) - math.log(1 - math.exp(-2 * kappa)) + kappa * (cosine - 1)

    out, rays = {}, {}
    for t in range(T):
        for i in range(P):
            yaw, tilt = data.gaze_angles[t, i] + params["bias"][i]
            head = np.array([math.cos(tilt) * math.cos(yaw), math.cos(tilt) * math.sin(yaw), math.sin(tilt)])
            world = data.R_world_from_head[t, i] @ head
            h = math.sqrt(params["cone_width"][i] ** 2 + data.measurement_scale[t, i] ** 2)
            logits, liks = {}, {}
            residuals = {}
            for j in range(P):
                if j != i and data.present[t, j]:
                    logits[j] = params["alpha_person"] + params["speaker_effect"] * data.speaking[t, j]
                    u = data.eye_positions[t, j] - data.eye_positions[t, i]
                    liks[j] = log_fisher(world @ u / np.linalg.norm(u), h)
                    residuals[j] = world - u / np.linalg.norm(u)
            for k in range(K):
                logits[P + k] = params["alpha_object"]
                u = params["locations"][0, k] - data.eye_positions[t, i]
                liks[P + k] = log_fisher(world @ u / np.linalg.norm(u), h)
                residuals[P + k] = world - u / np.linalg.norm(u)
            logits["e"] = 0.0
            liks["e"] = log_fisher(head[0], JointPrior().elsewhere_spread)  # around the head's +x
            norm = math.log(sum(math.exp(v) for v in logits.values()))
            out[t, i] = {c: (logits[c] - norm, liks[c]) for c in logits}
            rays[t, i] = (world, h, residuals)
    return out, rays, log_fisher


def _held_spot(terms, rays, observed, i, t, c, rho, share, cone_width):
    """The held spot's log density ratio for person ``i``'s frame ``t`` held at ``c`` from ``t − 1``, frame by frame.

    The earlier frames weigh ``γ_{t−1} = 1``, ``γ_{s} = γ_{s+1} ρ q_s / (ρ q_s + (1 − ρ) π_{s+1}(c))``, ``q`` the
    one-frame posterior, ``π`` the prior of a new target.
    """
    v0 = share * cone_width**2
    A, S, gamma = 0.0, 0.0, 1.0  # S: a residual of any dimension (3-D world, 2-D angles)
    for s in range(t - 1, -1, -1):
        if s < t - 1:  # frame s is of the fixation if c was kept from s to s + 1, not chosen anew
            joint = {k: sum(v) for k, v in terms[s, i].items()}
            q = math.exp(joint.get(c, -np.inf) - np.logaddexp.reduce(list(joint.values()))) if observed[s] else 1.0
            gamma *= rho * q / (rho * q + (1 - rho) * math.exp(terms[s + 1, i][c][0]))
        if gamma == 0.0:  # c was no candidate at frame s (absent): no earlier frame is of this fixation
            break
        if observed[s]:
            e = rays[s, i][1] ** 2 - v0
            A, S = A + gamma / e, S + gamma * rays[s, i][2][c] / e
    w2 = rays[t, i][1] ** 2
    e = w2 - v0
    V = v0 / (1 + v0 * A)
    r = rays[t, i][2][c]
    return (-0.5 * np.sum((r - V * S) ** 2) / (V + e) - math.log(V + e)) - (-0.5 * np.sum(r**2) / w2 - math.log(w2))


def _brute_force(data, params):
    """``log Σ_z p(g, z)`` and ``P(z_ti = j | g)`` by enumerating every target sequence of every person.

    A glance elsewhere held from frame ``t − 1`` scatters around the previous direction; with ``held_cone_share``
    in ``params``, a person or concurrence held from ``t − 1`` scatters around the fixation's spot (:func:`_held_spot`),
    and a glance elsewhere by the frames' scatter without it (the spot moves its point for the whole fixation).
    The densities are of the measured angles: the cones' on the sphere times each frame's area element ``|cos θ|``.
    """
    T, P = data.present.shape
    terms, rays, log_fisher = _per_gazer(data, params)
    rho = params["stay"]
    share = params.get("held_cone_share")
    total, marginals = 0.0, {}
    for i in range(P):
        names = list(dict.fromkeys(c for t in range(T) for c in terms[t, i]))  # every candidate of any frame
        weights = {}
        for seq in itertools.product(names, repeat=T):
            if any(c not in terms[t, i] for t, c in enumerate(seq)):
                continue
            observed = data.present[:, i]
            lp = terms[0, i][seq[0]][0] + (terms[0, i][seq[0]][1] if observed[0] else 0.0)
            for t in range(1, T):
                c = seq[t]
                new = terms[t, i][c][1] if observed[t] else 0.0
                held = new
                if c == "e" and observed[t] and observed[t - 1]:
                    (d1, h1, _), (d0, h0, _) = rays[t, i], rays[t - 1, i]
                    v0 = 0.0 if share is None else share * params["cone_width"][i] ** 2  # the spot cancels
                    held = log_fisher(d1 @ d0, math.sqrt(h1**2 + h0**2 - 2 * v0))
                elif c != "e" and c == seq[t - 1] and observed[t] and share is not None:
                    held = new + _held_spot(terms, rays, observed, i, t, c, rho, share, params["cone_width"][i])
                lp += math.log(rho * (c == seq[t - 1]) * math.exp(held) + (1 - rho) * math.exp(terms[t, i][c][0] + new))
            weights[seq] = lp
        norm = np.logaddexp.reduce(list(weights.values()))
        total += norm
        for t in range(T):
            for c in names:
                marginals[t, i, c] = sum(math.exp(w - norm) for seq, w in weights.items() if seq[t] == c)
    return total + _angles_log_jacobian(data, params), terms, marginals


def _angles_log_jacobian(data, params):
    """``Σ log |cos(θ + b_θ)|`` over the observed frames: the measured angles' area element, which turns the cones'
    densities on the sphere into densities of the angles."""
    tilt = np.nan_to_num(data.gaze_angles[..., 1]) + np.asarray(params["bias"])[:, 1]
    return float(np.sum(np.where(data.present, np.log(np.abs(np.cos(tilt))), 0.0)))


def _column(c, P):
    return 4 if c == "e" else c  # the tiny scene: P = 3 people, K = 1 concurrence


# Compiled once per shape: op-by-op (eager) calls of the model compile every primitive
# anew for each shape, which costs seconds.
_marginal_log_likelihood = jax.jit(marginal_log_likelihood)
_candidate_log_probabilities = jax.jit(candidate_log_probabilities)
_target_marginals = jax.jit(target_marginals)


def test_a_frames_likelihood_is_a_density_of_the_measured_angles(x64):
    """One frame's likelihood, a density of the measured angles ``(yaw, tilt)``, integrates to 1 over them (a
    Riemann sum over a 1° grid, one frame a point): the cones' densities on the sphere times the area element
    ``|cos θ|`` (:func:`~jaxgaze.joint.model.measured_gaze_log_jacobian`). Without it the integral is
    ``E[1/|cos θ|]``, about 1.3 for a neighbour 40° up."""
    step = math.radians(1.0)
    yaw, tilt = np.meshgrid(np.arange(-180, 180) + 0.5, np.arange(-90, 90) + 0.5, indexing="ij")
    g = np.radians(np.stack([yaw.ravel(), tilt.ravel()], axis=-1))  # (T, 2), every grid point a frame
    T = g.shape[0]
    eyes = np.broadcast_to(np.array([[0.0, 0.0, 1.2], [1.0, 0.3, 1.2 + math.tan(math.radians(40.0))]]), (T, 2, 3))
    R = np.broadcast_to(np.eye(3), (T, 2, 3, 3))
    data = joint_data(eyes, R, np.stack([g, np.zeros_like(g)], axis=1), measurement_scale=np.zeros((T, 2)),
                      fps=10.0)
    centres = np.zeros((1, 0, 3))
    params = {"bias": jnp.asarray([[0.2, -0.3], [0.0, 0.0]]), "cone_width": jnp.asarray([0.15, 0.15]),
              "alpha_person": jnp.asarray(0.5), "alpha_object": jnp.asarray(0.0), "speaker_effect": jnp.asarray(0.0),
              "stay": jnp.asarray(0.0), "locations": jnp.asarray(centres)}  # stay 0: the frames are independent
    frames = np.asarray(jax.jit(model.frame_log_likelihood)(params, _arrays(data, centres, jnp.float64)))[:, 0]
    assert np.sum(np.exp(frames)) * step**2 == pytest.approx(1.0, abs=2e-3)


def test_marginal_matches_brute_force_enumeration(x64):
    data, centres, params = _tiny(T=3)
    arrays = _arrays(data, centres, jnp.float64)
    jparams = jax.tree_util.tree_map(jnp.asarray, params)
    expected, terms, marginals = _brute_force(data, params)
    assert float(jnp.sum(_marginal_log_likelihood(jparams, arrays))) == pytest.approx(expected, rel=1e-10)
    # one frame's candidates, order: people, concurrences, elsewhere
    lp = np.asarray(_candidate_log_probabilities(jparams, arrays))
    g = terms[0, 1]  # frame 0, person 1
    assert lp[0, 1, 1] == -np.inf
    for c in (0, 3, "e"):
        assert lp[0, 1, _column(c, 3)] == pytest.approx(sum(g[c]), rel=1e-10)
    # the smoothed target posterior
    m = np.asarray(_target_marginals(jparams, arrays))
    for (t, i, c), value in marginals.items():
        assert m[t, i, _column(c, 3)] == pytest.approx(value, rel=1e-8, abs=1e-12)
    # the model's factor is the same sum
    latent = {"bias": params["bias"], "cone_width": params["cone_width"], "alpha_person": params["alpha_person"],
              "alpha_object": params["alpha_object"], "speaker_effect": params["speaker_effect"],
              "stay": params["stay"],
              "concurrence_offset": (params["locations"][0] - centres[0]) / JointPrior().location_scale}
    factor = jax.jit(lambda z: handlers.trace(handlers.substitute(_without_spots, z)).get_trace(*arrays)["gaze"]["fn"]
                     .log_factor.sum())(latent)
    assert float(factor) == pytest.approx(expected, rel=1e-10)


def _with_spots(*arrays):
    return joint_model(*arrays, prior=SPOTS)


def _without_spots(*arrays):
    return joint_model(*arrays, prior=JointPrior(held_scale=None))


#: The prior with a fixation's spot (``held_cone_share`` learnt).
SPOTS = JointPrior(held_scale=1.0)


def test_held_spot_matches_brute_force_enumeration(x64):
    """A fixation's spot (``held_cone_share``): the forward pass against every target and branch sequence,
    with the spot's statistics from the earlier frames written out frame by frame; an absent frame inside."""
    data, centres, params = _tiny(seed=7, T=4)
    present = np.ones((4, 3), bool)
    present[1, 0] = False
    data = joint_data(data.eye_positions, data.R_world_from_head, data.gaze_angles, present=present,
                      speaking=data.speaking, measurement_scale=data.measurement_scale, fps=5.0)
    params = {**params, "stay": 0.8, "held_cone_share": 0.6}
    # gazes close to one target for two frames in a row, so the spot's term matters
    arrays = _arrays(data, centres, jnp.float64)
    jparams = jax.tree_util.tree_map(jnp.asarray, params)
    expected, _, marginals = _brute_force(data, params)
    without, _, _ = _brute_force(data, {k: v for k, v in params.items() if k != "held_cone_share"})
    assert abs(expected - without) > 0.1  # the spot changes the likelihood here
    assert float(jnp.sum(_marginal_log_likelihood(jparams, arrays))) == pytest.approx(expected, rel=1e-10)
    m = np.asarray(_target_marginals(jparams, arrays))
    for (t, i, c), value in marginals.items():
        if present[t, i]:  # an absent gazer's row is 0
            assert m[t, i, _column(c, 3)] == pytest.approx(value, rel=1e-8, abs=1e-12)
    latent = {"bias": params["bias"], "cone_width": params["cone_width"], "alpha_person": params["alpha_person"],
              "alpha_object": params["alpha_object"], "speaker_effect": params["speaker_effect"], "stay": 0.8,
              "held_spread": math.sqrt(0.6 / (MAX_HELD_CONE_SHARE - 0.6)),  # c = 0.6
              "concurrence_offset": (params["locations"][0] - centres[0]) / JointPrior().location_scale}
    factor = jax.jit(lambda z: handlers.trace(handlers.substitute(_with_spots, z)).get_trace(*arrays)["gaze"]["fn"]
                     .log_factor.sum())(latent)
    assert float(factor) == pytest.approx(expected, rel=1e-10)


def test_held_spot_stays_bounded_as_the_cone_narrows(x64):
    """A cone far narrower than the residuals makes every emission floored; the spot's held frames must not gain
    from it (they once subtracted an unfloored density: the likelihood grew without bound as ``h → 0`` and a fit
    sent the cone widths to 0 and the biases hundreds of degrees off)."""
    data, centres, params = _tiny(seed=7, T=6)
    gaze = data.gaze_angles.copy()  # person 0 holds one point 1 rad from where they face, 1 mrad of scatter
    gaze[:, 0] = [1.0, 0.2] + 1e-3 * np.random.default_rng(0).standard_normal((6, 2))
    data = joint_data(data.eye_positions, data.R_world_from_head, gaze, speaking=data.speaking, fps=5.0)  # w = h
    arrays = _arrays(data, centres, jnp.float64)
    values = []
    for width in (0.05, 1e-3, 1e-5):
        p = {**jax.tree_util.tree_map(jnp.asarray, params), "stay": jnp.asarray(0.99),
             "held_cone_share": jnp.asarray(MAX_HELD_CONE_SHARE), "cone_width": jnp.full(3, width)}
        values.append(float(jnp.sum(_marginal_log_likelihood(p, arrays))))
    assert np.all(np.isfinite(values)) and values[0] > values[1] >= values[2], values


def test_a_glance_elsewhere_held_with_a_spot_recovers_the_cone(x64):
    """A long glance elsewhere whose frames carry a fixation's spot (share ``c = 0.5`` of ``h²``, one offset for the
    whole glance) and the rest of the cone: the held term's likeliest width is the simulated ``h``. The spot moves
    the glance's point and cancels in the frame-to-frame differences, so they scatter by ``2 (1 − c) h²``; scored with
    ``2 h²`` (the term before the spot was taken out of it) the likeliest width is ``h √(1 − c)``, 29% short."""
    rng = np.random.default_rng(3)
    h, c, L = 0.06, 0.5, 4000
    point = np.array([0.4, -0.1]) + math.sqrt(c) * h * rng.standard_normal(2)  # the glance's point and its spot
    directions = point + math.sqrt(1 - c) * h * rng.standard_normal((1, L, 1, 2))  # (B, L, P, 2): angles
    log_lik = jnp.zeros((1, L, 1, 2))  # the new glance's density: a constant
    observed = jnp.ones((1, L, 1), bool)

    def held(width):
        spot = jnp.asarray([c * width**2])
        return float(jnp.sum(model._held_elsewhere(log_lik, jnp.asarray(directions), jnp.full((1, L, 1), width),
                                                   observed, spot)))

    widths = h * np.linspace(0.5, 1.5, 201)
    best = widths[np.argmax([held(w) for w in widths])]
    assert best == pytest.approx(h, rel=0.04)


def test_blocks_restart_the_chain(x64):
    """Two closed forms over two blocks (T = 70 > BLOCK_FRAMES): ρ = 0 is independent frames, ρ = 1 one target per block."""
    data, centres, params = _tiny(seed=5, T=BLOCK_FRAMES + 6)
    arrays = _arrays(data, centres, jnp.float64)
    jparams = jax.tree_util.tree_map(jnp.asarray, params)
    lp = np.asarray(_candidate_log_probabilities(jparams, arrays))
    loose = float(jnp.sum(_marginal_log_likelihood({**jparams, "stay": jnp.asarray(0.0)}, arrays)))
    jacobian = _angles_log_jacobian(data, params)
    assert loose == pytest.approx(float(np.sum(jax.scipy.special.logsumexp(lp, axis=-1))) + jacobian, rel=1e-9)
    prior, lik, d, w, _ = (np.asarray(a) for a in jax.jit(_candidate_terms)(jparams, arrays, JointPrior()))
    # a glance elsewhere held over the block: its first frame's density, then each frame around the last
    held = np.asarray(cone_direction_log_density(np.sum(d[1:] * d[:-1], -1), np.sqrt(w[1:] ** 2 + w[:-1] ** 2)))
    expected = jacobian
    for start in (0, BLOCK_FRAMES):
        block = slice(start, start + BLOCK_FRAMES)
        total = lik[block].sum(0)
        total[:, -1] = lik[start, :, -1] + held[start: start + BLOCK_FRAMES - 1].sum(0)
        expected += float(np.sum(jax.scipy.special.logsumexp(prior[start] + total, axis=-1)))
    held = float(jnp.sum(_marginal_log_likelihood({**jparams, "stay": jnp.asarray(1.0)}, arrays)))
    assert held == pytest.approx(expected, rel=1e-6)


def test_absent_people_are_no_candidates_and_add_nothing(x64):
    data, centres, params = _tiny(seed=1, T=3, P=4)
    present = np.ones((3, 4), bool)
    present[0, 2] = False
    gaze = data.gaze_angles.copy()
    gaze[0, 2] = np.nan  # absent: may be NaN
    masked = joint_data(data.eye_positions, data.R_world_from_head, gaze, present=present,
                        speaking=data.speaking, measurement_scale=data.measurement_scale, fps=5.0)
    arrays = _arrays(masked, centres, jnp.float64)
    jparams = jax.tree_util.tree_map(jnp.asarray, params)
    lp = np.asarray(_candidate_log_probabilities(jparams, arrays))
    assert np.all(lp[0, [0, 1, 3], 2] == -np.inf)  # nobody looks at the absent person
    m = np.asarray(_target_marginals(jparams, arrays))
    assert np.all(m[0, 2] == 0.0) and np.all(m[0, [0, 1, 3], 2] == 0.0)
    np.testing.assert_allclose(m[present].sum(-1), 1.0, rtol=1e-10)
    # the absent frame moves the chain on without an observation: the brute force agrees
    expected, _, marginals = _brute_force(masked, {**params})
    assert float(jnp.sum(_marginal_log_likelihood(jparams, arrays))) == pytest.approx(expected, rel=1e-10)
    assert m[1, 2, 0] == pytest.approx(marginals[1, 2, 0], rel=1e-8)


def test_gradients_match_finite_differences(x64):
    data, centres, params = _tiny(seed=2)
    arrays = tuple(_arrays(data, centres, jnp.float64))
    rng = np.random.default_rng(3)
    u = {"bias": jnp.asarray(0.1 * rng.normal(size=(3, 2))), "cone_width": jnp.asarray(np.log([0.05, 0.08, 0.1])),
         "alpha_person": jnp.asarray(0.2), "alpha_object": jnp.asarray(-0.1), "speaker_effect": jnp.asarray(1.7),
         "stay": jnp.asarray(0.8), "held_spread": jnp.asarray(1.0),
         "concurrence_offset": jnp.asarray(0.1 * rng.normal(size=(1, 3)))}
    energy = jax.jit(lambda z: potential_energy(_with_spots, arrays, {}, z))
    grad = jax.jit(jax.grad(energy))(u)
    flat, unravel = jax.flatten_util.ravel_pytree(u)
    g, _ = jax.flatten_util.ravel_pytree(grad)
    eps = 1e-6
    numeric = np.array([(energy(unravel(flat.at[k].add(eps))) - energy(unravel(flat.at[k].add(-eps)))) / (2 * eps)
                        for k in range(flat.size)])
    np.testing.assert_allclose(np.asarray(g), numeric, rtol=1e-5, atol=1e-5)



def test_the_written_out_adjoint_matches_autodiff_of_the_scan(x64):
    """The forward recursion is differentiated by its adjoint written out (``model._log_normalisers``): against JAX's
    transpose of the plain scan, in float64, with a frame whose normaliser sits at its floor."""
    rng = np.random.default_rng(7)
    L, B, P, C = 9, 2, 3, 4
    new, kept = (jnp.asarray(rng.random((L, B, P, C))).at[3, 0, 1].set(0.0) for _ in range(2))
    bar = jnp.asarray(rng.normal(size=(L, B, P)))
    plain = lambda n, k: jnp.sum(bar * jnp.log(model._sticky_recursion(n, k)[1]))  # noqa: E731
    written = lambda n, k: jnp.sum(bar * model._log_normalisers(n, k))  # noqa: E731
    assert float(jnp.min(model._sticky_recursion(new, kept)[1])) == model._NORM_FLOOR  # the floor is reached
    np.testing.assert_allclose(written(new, kept), plain(new, kept), rtol=1e-12)
    for ours, reference in zip(jax.grad(written, (0, 1))(new, kept), jax.grad(plain, (0, 1))(new, kept)):
        np.testing.assert_allclose(ours, reference, rtol=1e-10, atol=1e-12)


def test_the_spots_discounted_sums_are_the_closed_form(x64):
    """``y_t = Σ_{s<t} x_s Π_{s<u<t} decay_u`` (``model._discounted_sums``), against the double sum written out, with
    the decay broadcast over the sums' components as ``_held_spot`` passes it."""
    rng = np.random.default_rng(8)
    L = 7
    x, decay = rng.normal(size=(L, 3, 2)), rng.random((L, 1, 2))
    expected = np.zeros_like(x)
    for t in range(L):
        for s in range(t):
            expected[t] += x[s] * np.prod(decay[s + 1:t], axis=0)
    np.testing.assert_allclose(model._discounted_sums(jnp.asarray(x), jnp.asarray(decay)), expected, rtol=1e-12)


def _valid():
    data, _, _ = _tiny(seed=4, T=3, P=3)
    return dict(eye_positions=data.eye_positions, R_world_from_head=data.R_world_from_head,
                gaze_angles=data.gaze_angles)


@pytest.mark.parametrize("change, message", [
    (lambda a: a.update(eye_positions=a["eye_positions"][:, :2]), "eye_positions must have shape"),
    (lambda a: a.update(R_world_from_head=a["R_world_from_head"][..., :2]), "R_world_from_head must have shape"),
    (lambda a: a.update(gaze_angles=a["gaze_angles"][..., :1]), r"gaze_angles must have shape \(T, P, 2\)"),
    (lambda a: a.update(present=np.ones((3, 2), bool)), "present must have shape"),
    (lambda a: a["eye_positions"].__setitem__((1, 2, 0), np.nan), "eye_positions is not finite .* frame 1, person '2'"),
    (lambda a: a["gaze_angles"].__setitem__((2, 0, 1), np.inf), "gaze_angles is not finite .* frame 2, person '0'"),
    (lambda a: a.update(present=np.array([[1, 1, 0]] * 3, bool)), "person '2' is never present"),
    (lambda a: a.update(speaking={"3": np.zeros(3)}), "speaking flags for an unknown person '3'"),
    (lambda a: a.update(speaking=np.zeros((3, 4))), "speaking has flags for 4 people, but there are 3"),
    (lambda a: a.update(gaze_angles=np.degrees(a["gaze_angles"]) * 10), r"radians \(degrees\?\)"),
    (lambda a: a["R_world_from_head"].__setitem__((0, 1), 2 * np.eye(3)), "frame 0, person '1' is not a rotation"),
    (lambda a: a.update(measurement_scale=-np.ones((3, 3))), "measurement_scale must be finite and ≥ 0"),
    (lambda a: a.update(people=["a", "a", "b"]), "names must be unique"),
])
def test_bad_input_names_what_and_where(change, message):
    arrays = {k: np.array(v, copy=True) for k, v in _valid().items()}
    change(arrays)
    with pytest.raises(ValueError, match=message):
        joint_data(**arrays)


def test_millimetres_are_a_unit_warning_naming_person_and_frame():
    """Implausible, not impossible (the unit rule, issue 34): a UnitWarning, and the data still built."""
    from jaxgaze.rays import UnitWarning

    arrays = {k: np.array(v, copy=True) for k, v in _valid().items()}
    arrays["eye_positions"] = arrays["eye_positions"] * 1000
    with pytest.warns(UnitWarning, match=r"eye_positions of person '\d' at frame \d are .* m from the scene centre, "
                                         r"beyond 50 m: they must be metres \(millimetres\?\)"):
        data = joint_data(**arrays)
    np.testing.assert_allclose(data.eye_positions, arrays["eye_positions"])


def test_speaking_by_name_and_windows():
    a = _valid()
    data = joint_data(**a, speaking={"1": [0, 1, 1]}, people=None, fps=1.0, window_s=2.0)
    np.testing.assert_array_equal(data.speaking[:, 1], [0, 1, 1])
    assert data.speaking[:, [0, 2]].sum() == 0
    np.testing.assert_array_equal(data.window, [0, 0, 1])
    assert data.num_windows == 2 and data.has_speech


@pytest.mark.parametrize("share", [0.0, 0.5])
def test_the_likelihood_finds_the_share_a_fixation_holds(share):
    """Known truth: on conversations whose cone draws hold a share ``c`` for each fixation segment (the
    simulator's ``held_cone_share``), the likelihood at the true biases, widths and objects is highest at that
    share among 0, 0.25, 0.5 and 0.75 (the model before issue 37 counts such frames as independent)."""
    from jaxgaze.simulate import ConversationConfig, simulate_conversation

    scene = simulate_conversation(jax.random.key(5), num_people=5, num_objects=1, duration_s=30.0,
                                  config=ConversationConfig(held_cone_share=share))
    data = joint_data(scene.eye_positions, scene.R_world_from_head, scene.gaze_angles, present=scene.present,
                      speaking=scene.speaking, measurement_scale=scene.measurement_scale, fps=scene.fps)
    centres = np.broadcast_to(scene.object_positions, (data.num_windows,) + scene.object_positions.shape)
    arrays = _arrays(data, centres, jnp.float32)
    params = {"bias": jnp.asarray(scene.bias, jnp.float32), "cone_width": jnp.asarray(scene.cone_width, jnp.float32),
              "alpha_person": jnp.float32(0.0), "alpha_object": jnp.float32(0.0), "speaker_effect": jnp.float32(1.8),
              "stay": jnp.float32(0.9), "locations": jnp.asarray(centres, jnp.float32)}
    shares = (0.0, 0.25, 0.5, 0.75)
    values = [float(jnp.sum(_marginal_log_likelihood({**params, "held_cone_share": jnp.float32(c)}, arrays)))
              for c in shares]
    assert shares[int(np.argmax(values))] == share, values


@pytest.mark.parametrize("spot", [None, 0.6])
def test_a_masked_slot_is_the_model_without_it(x64, spot):
    """``ModelArrays.slot_active``: a masked concurrence is no candidate, and the others' priors are as if it were
    gone (the fit's pruning tries fewer slots with the same programs). Against the arrays with the slot removed: the
    likelihood and every target's posterior, with and without a fixation's spot, one slot masked or both."""
    data, centres, params = _tiny(seed=5, T=5, K=2)
    params = {**params, "locations": params["locations"] + np.array([0.0, 0.0, 0.3]) * np.arange(2)[:, None],
              **({} if spot is None else {"held_cone_share": spot})}
    arrays = _arrays(data, centres, jnp.float64)
    for active in ([True, False], [False, True], [False, False]):
        keep = np.flatnonzero(active)
        masked = arrays._replace(slot_active=jnp.asarray(active))
        smaller = arrays._replace(location_centres=arrays.location_centres[:, keep], slot_active=None)
        removed = {**params, "locations": params["locations"][:, keep],
                   "alpha_object": params["alpha_object"] if keep.size else 0.0}  # no slot: α_object is 0
        masked_p, removed_p = (jax.tree_util.tree_map(jnp.asarray, p) for p in (params, removed))
        expected = np.asarray(_marginal_log_likelihood(removed_p, smaller))
        np.testing.assert_allclose(np.asarray(_marginal_log_likelihood(masked_p, masked)), expected, rtol=1e-12)
        posterior = np.asarray(_target_marginals(masked_p, masked))  # (T, P, P + 2 + 1)
        columns = np.concatenate([np.arange(3), 3 + keep, [5]])
        np.testing.assert_allclose(posterior[..., columns], np.asarray(_target_marginals(removed_p, smaller)),
                                   atol=1e-12)
        assert np.all(posterior[..., 3 + np.flatnonzero(~np.asarray(active))] == 0.0)
    # the slot matters: removing it changes the likelihood, far beyond the tolerances above
    full = np.asarray(_marginal_log_likelihood(jax.tree_util.tree_map(jnp.asarray, params), arrays)).sum()
    assert abs(full - expected.sum()) > 1e-3


def test_masked_slots_leave_the_values_and_the_inverse_hessian():
    """``_drop_masked``: a masked slot's offsets and drift, their rows and columns of the inverse Hessian (in
    ``jax.tree_util``'s order, the mass matrix's) and its centre go; ``α_object`` too when no slot is left."""
    W, K = 2, 3
    values = {"bias": jnp.zeros((2, 2)), "alpha_object": jnp.zeros(()), "concurrence_offset": jnp.zeros((K, 3)),
              "concurrence_drift": jnp.zeros((W, K, 3)), "stay": jnp.zeros(())}
    flat, unravel = ravel_pytree(values)
    named = unravel(jnp.arange(flat.size, dtype=flat.dtype))  # each entry's index in the flat order
    inverse = np.arange(flat.size)[:, None] * 1000.0 + np.arange(flat.size)[None, :]
    arrays = ModelArrays(*([jnp.zeros(1)] * 9), jnp.arange(W * K * 3.0).reshape(W, K, 3), jnp.zeros(1),
                               jnp.zeros(1), jnp.zeros(0, jnp.int32), jnp.asarray([True, False, True]))
    kept, smaller, kept_inverse = _drop_masked(named, arrays, inverse)
    rows = np.concatenate([np.ravel(kept[k]) for k in sorted(kept)]).astype(int)
    np.testing.assert_array_equal(np.asarray(kept_inverse), inverse[np.ix_(rows, rows)])
    np.testing.assert_array_equal(np.asarray(kept["concurrence_offset"]), np.asarray(named["concurrence_offset"])[[0, 2]])
    np.testing.assert_array_equal(np.asarray(kept["concurrence_drift"]), np.asarray(named["concurrence_drift"])[:, [0, 2]])
    np.testing.assert_array_equal(np.asarray(smaller.location_centres), np.asarray(arrays.location_centres)[:, [0, 2]])
    assert np.asarray(smaller.slot_active).tolist() == [True, True] and kept_inverse.shape == (rows.size, rows.size)
    none, empty, _ = _drop_masked(named, arrays._replace(slot_active=jnp.zeros(K, bool)), inverse)
    assert sorted(none) == ["bias", "stay"] and empty.location_centres.shape == (W, 0, 3)
