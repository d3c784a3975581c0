"""What the joint-model experiments share: issue 37's "confidently wrong" rule and their resumable per-scene caches.

Imported by the scripts beside it (``python experiments/<name>.py`` puts this folder on the path).
"""

from __future__ import annotations

import json
import os

import numpy as np

from jaxgaze.joint import JointPrior

#: The joint model without a fixation's spot (issue 37, item 5; the spot is the default where the data need it):
#: what every experiment's ``--no-spot`` fits, for the figures before it.
NO_SPOT = JointPrior(held_scale=None)


def distance_sd(draws, truth) -> np.ndarray:
    """``(P,)``: the distance of each true bias from its posterior draws ``(S, P, 2)``, in posterior sd (Mahalanobis)."""
    out = []
    for i in range(truth.shape[0]):
        x = np.asarray(draws)[:, i]
        d = truth[i] - x.mean(0)
        out.append(float(np.sqrt(d @ np.linalg.solve(np.cov(x.T) + 1e-12 * np.eye(2), d))))
    return np.asarray(out)


def confidently_wrong(result: str, error_deg, distance) -> list[bool]:
    """Issue 37's rule, per person: the fit says ``successful``, the bias is more than 3° off, and the truth lies more
    than 5 posterior sd away."""
    return [bool(result == "successful" and e > 3.0 and m > 5.0) for e, m in zip(error_deg, distance)]


def read_caches(paths) -> dict:
    """Per-scene results from every JSON cache in ``paths`` that exists (later files win)."""
    done = {}
    for path in paths:
        if path and os.path.exists(path):
            with open(path) as f:
                done.update(json.load(f))
    return done


def write_cache(path, done: dict) -> None:
    """Write ``done`` to ``path`` atomically (a temporary file, then a rename); nothing without a path."""
    if path:
        with open(path + ".tmp", "w") as f:
            json.dump({str(k): v for k, v in done.items()}, f, default=float)
        os.replace(path + ".tmp", path)
