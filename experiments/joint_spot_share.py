"""How well does the joint model's fixation spot learn its share ``c`` when every target is known?

The spot (``held_cone_share``; :func:`jaxgaze.joint.model._held_spot`) predicts a held frame's residual from the
earlier frames of its fixation, each weighed by the chance that it belongs to it: one Gaussian for the spot. After a
possible re-draw on the same target the truth is a mixture of the old spot and a new one. This study takes the
scenes of ``joint_bias_coverage.py`` (share 0.5), the true targets, cone widths and residuals, and profiles the
likelihood of ``c`` at the true widths three ways:

1. **oracle**: the true fixation segments (``Conversation.fixation_segment``), each segment's residuals jointly
   Gaussian: exact.
2. **model**: the model's held term on the runs of frames on one target (a re-draw on the same target unseen),
   each frame continuing the fixation with probability ``a`` and mixed with a new glance as the forward pass mixes
   them (``a`` is ``ρ q / (ρ q + (1 − ρ) π)`` in a fit).
3. **linear filter**: the same runs and mixing, the spot carried from frame to frame as a first-order
   autoregression of coefficient ``a`` (a Kalman filter). Its autocovariance, ``c h² aᵏ``, is the re-draw
   process's, so a Gaussian likelihood built from it is consistent for ``c``.

Only frames on a person or an object count (a glance elsewhere has its own held term). Printed: the likeliest ``c``
per scene and method, then each method's mean and spread over the scenes.

Usage::

    python experiments/joint_spot_share.py [--scenes 12] [--share 0.5] [--persistence 0.9 0.95 0.974 0.99]
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import numpy as np

from jaxgaze.geometry import unit
from jaxgaze.joint import model
from jaxgaze.simulate import ConversationConfig, simulate_conversation

GRID = np.linspace(0.2, 0.8, 121)


def residuals(scene) -> np.ndarray:
    """``(T, P, 2)`` the true gaze about the target direction on the simulator's tangent basis (radians)."""
    u = np.asarray(unit(np.nan_to_num(scene.target_positions) - scene.eye_positions))
    e1 = np.asarray(unit(np.cross(np.array([0.0, 0.0, 1.0]), u)))
    e2 = np.cross(u, e1)
    v = np.nan_to_num(scene.true_gaze_directions)
    return np.stack([np.sum(v * e1, -1), np.sum(v * e2, -1)], -1)


def _runs(labels: np.ndarray, keep: np.ndarray) -> list[np.ndarray]:
    """Frame indices of each maximal run of one label among the ``keep`` frames."""
    runs, start = [], None
    for t in range(labels.size + 1):
        if start is not None and (t == labels.size or not keep[t] or labels[t] != labels[start]):
            runs.append(np.arange(start, t))
            start = None
        if start is None and t < labels.size and keep[t]:
            start = t
    return runs


def oracle(r, w2, h2, runs) -> np.ndarray:
    """``log p`` over :data:`GRID` with each segment's residuals jointly Gaussian: per component
    ``N(0, diag(w² − c h²) + c h² 11ᵀ)`` (the matrix determinant lemma)."""
    total = np.zeros_like(GRID)
    for run in runs:
        e = w2[run][None] - GRID[:, None] * h2  # (G, n)
        spot = GRID * h2
        inv = 1.0 / e
        A = inv.sum(1)
        for k in range(2):
            S = (inv * r[run, k][None]).sum(1)
            quad = (inv * r[run, k][None] ** 2).sum(1) - spot * S**2 / (1.0 + spot * A)
            total += -0.5 * (quad + np.log(e).sum(1) + np.log1p(spot * A))
    return total


def _new_glance(r, w2):
    return -0.5 * np.sum(r**2, -1) / w2 - np.log(w2)  # the model's 2-D density, without its constant


def model_held(r, w2, h2, runs, a) -> np.ndarray:
    """``log p`` over :data:`GRID` with the model's held term (:func:`~jaxgaze.joint.model._held_spot`) on each run:
    the first frame a new glance, each later one ``log(a e^{held} + 1 − a)`` plus the new glance's density."""
    L = max(len(run) for run in runs)
    index = np.stack([np.pad(run, (0, L - len(run)), mode="edge") for run in runs])  # (B, L)
    observed = np.arange(L)[None] < np.array([len(run) for run in runs])[:, None]
    G = GRID.size
    grid_axis = lambda x: jnp.asarray(np.broadcast_to(x[..., None], x.shape + (G,)))  # noqa: E731
    log_prior = jnp.broadcast_to(jnp.asarray([0.0, model._LOG_FLOOR]), (len(runs), L, G, 2))  # π = 1: a = ρ
    log_lik = jnp.broadcast_to(jnp.asarray([0.0, model._LOG_FLOOR]), (len(runs), L, G, 2))  # q = 1 for the target
    parts = tuple(grid_axis(r[index, k])[..., None] for k in range(2))
    held = model._held_spot(log_prior, log_lik, parts, jnp.sqrt(grid_axis(w2[index])), grid_axis(observed),
                            jnp.asarray(a), jnp.asarray(GRID * h2))[..., 0]  # (B, L, G)
    held = np.asarray(held, np.float64)
    new = _new_glance(r[index], w2[index])[..., None]  # (B, L, 1)
    later = np.log(a * np.exp(held) + 1.0 - a)
    later[:, 0] = 0.0
    return np.sum(np.where(observed[..., None], new + later, 0.0), axis=(0, 1))


def linear_filter(r, w2, h2, runs, a) -> np.ndarray:
    """``log p`` over :data:`GRID` with the spot a first-order autoregression of coefficient ``a`` (Kalman filter);
    a held frame's residual is predicted from the filter's spot ``N(m, P)`` as ``N(m, P + e)``."""
    total = np.zeros_like(GRID)
    spot = GRID * h2
    for run in runs:
        m, P = np.zeros((GRID.size, 2)), spot.copy()
        for n, t in enumerate(run):
            e = w2[t] - spot
            new = _new_glance(r[t], w2[t])
            if n == 0:
                total += new
                phi = 0.0
            else:
                held = -0.5 * np.sum((r[t] - m) ** 2, -1) / (P + e) - np.log(P + e)
                total += np.logaddexp(np.log(a) + held, np.log1p(-a) + new)
                phi = a
            m, P = phi * m, phi**2 * P + (1.0 - phi**2) * spot  # the spot of frame t before its residual
            gain = P / (P + e)
            m, P = m + gain[:, None] * (r[t] - m), (1.0 - gain) * P
    return total


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=12)
    parser.add_argument("--share", type=float, default=0.5)
    parser.add_argument("--persistence", type=float, nargs="+", default=[0.9, 0.95, 0.974, 0.99],
                        help="the chance a that a frame continues its fixation")
    parser.add_argument("--people", type=int, default=5)
    parser.add_argument("--duration", type=float, default=30.0)
    parser.add_argument("--seed", type=int, default=375, help="joint_bias_coverage.py's scenes")
    args = parser.parse_args(argv)
    jax.config.update("jax_enable_x64", True)  # profiles compared to a few nats: float64 throughout
    keys = jax.random.split(jax.random.key(args.seed), args.scenes)
    found = {"oracle": []} | {f"{method} a={a:g}": [] for a in args.persistence for method in ("model", "linear filter")}
    for i in range(args.scenes):
        scene = simulate_conversation(jax.random.split(keys[i])[0], num_people=args.people, duration_s=args.duration,
                                      config=ConversationConfig(held_cone_share=args.share))
        r, target = residuals(scene), scene.target
        w2 = scene.cone_width[None] ** 2 + scene.measurement_scale**2
        profiles = {name: np.zeros_like(GRID) for name in found}
        for p in range(scene.num_people):
            keep = scene.present[:, p] & (target[:, p] >= 0)
            h2 = scene.cone_width[p] ** 2
            profiles["oracle"] += oracle(r[:, p], w2[:, p], h2, _runs(scene.fixation_segment[:, p], keep))
            runs = _runs(target[:, p], keep)
            for a in args.persistence:
                profiles[f"model a={a:g}"] += model_held(r[:, p], w2[:, p], h2, runs, a)
                profiles[f"linear filter a={a:g}"] += linear_filter(r[:, p], w2[:, p], h2, runs, a)
        for name, profile in profiles.items():
            found[name].append(float(GRID[np.argmax(profile)]))
        print(f"scene {i}: " + ", ".join(f"{name} {values[-1]:.3f}" for name, values in found.items()), flush=True)
    print(f"likeliest c over {args.scenes} scenes (truth {args.share:g}): mean and sd")
    for name, values in found.items():
        print(f"  {name:<24}{np.mean(values):.3f}  {np.std(values):.3f}")
    return found


if __name__ == "__main__":
    main()
