"""Yücel et al. 2013, Tables I–II on simulated sessions: regression alone vs regression + saliency.

:func:`attend_session` attends every pooling window of a simulated table-top session
on its rendered scene and scores Q1/Q2 (T-CYB eq. 14–15) against the truth;
:func:`evaluate_attention` runs the self- and cross-referencing splits;
:func:`format_attention_table` prints the table.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import jax
import numpy as np
from tqdm.auto import tqdm

from jaxgaze.headpose import target as tg
from jaxgaze.papers.yucel2013 import fit_regressor, training_data
from jaxgaze.simulate.render import render_tabletop_scene
from jaxgaze.simulate.tabletop import TabletopSession, session_features
from jaxgaze.vision.attend import NO_LOCATION, SIGMA_PX, attend_window, target_points_and_covariances
from jaxgaze.vision.saliency_maps import SALIENCY_METHODS, saliency

__all__ = ["AttentionScores", "SessionAttention", "attend_session", "evaluate_attention", "format_attention_table"]


def _features(regression, session: TabletopSession):
    width = getattr(getattr(regression, "features", None), "mean", np.zeros(3)).shape[0]
    return session_features(session, include_position=width == 6)


class SessionAttention(NamedTuple):
    """Attention per pooling window of a simulated session, and its scores.

    Attributes:
        start_frame: ``(B,)`` first frame of each window (``B = T // window``).
        labels: ``(B,)`` the attended object if constant over the window, else −1.
        valid: ``(B,)`` windows with one label: the ones scored.
        attended: ``(B,)`` saliency found a location (else the pooled estimate is used).
        target_xy: ``(B, 2)`` the pooled regression estimate (mean target point).
        attended_xy: ``(B, 2)`` the chosen location.
        probability: ``(B,)`` its posterior probability (0 where not attended).
        chosen_object: ``(B,)`` the box of the chosen location, or −1.
        object_probabilities: ``(B, K)``; none_probability: ``(B,)``.
        region_box: ``(B, 4)`` the salient region (NaN where not attended).
        q1, q2: T-CYB eq. 14–15 (mean over objects) of ``attended_xy`` on the valid windows.
        q1_regression, q2_regression: the same for ``target_xy`` (regression alone, pooled).
        q1_frames, q2_frames: regression alone per frame (all frames, as :mod:`jaxgaze.papers.yucel2013`).
    """

    start_frame: np.ndarray
    labels: np.ndarray
    valid: np.ndarray
    attended: np.ndarray
    target_xy: np.ndarray
    attended_xy: np.ndarray
    probability: np.ndarray
    chosen_object: np.ndarray
    object_probabilities: np.ndarray
    none_probability: np.ndarray
    region_box: np.ndarray
    q1: float
    q2: float
    q1_regression: float
    q2_regression: float
    q1_frames: float
    q2_frames: float


def attend_session(
    session: TabletopSession,
    regression,
    scene_image,
    *,
    window: int = 4,
    method: str = "itti",
    sigma_px: float = SIGMA_PX,
    num_candidates: int = 5,
    saliency_map=None,
) -> SessionAttention:
    """Attend every pooling window of a simulated session on its (static) scene picture.

    The regression (:class:`~jaxgaze.headpose.regression.GazeRegression` or the NN baseline)
    predicts ``f1``, ``f2`` from the session's reported head pose; the target points
    start at ``head_centre_image``; windows are ``window`` consecutive frames (T-CYB: 4
    at 10 fps); :func:`attend_window` runs on ``scene_image`` (an image or a
    :class:`~jaxgaze.simulate.render.RenderedScene`, whose saliency is computed once)
    with the session's object boxes. Q1/Q2 after saliency use the chosen location;
    the regression-alone scores use the pooled estimate on the same windows.
    """
    if not isinstance(session, TabletopSession):
        raise TypeError(f"session must be a TabletopSession, got {type(session).__name__}")
    image = getattr(scene_image, "image", scene_image)
    smap = saliency(image, method) if saliency_map is None else np.asarray(saliency_map)
    head = np.asarray(session.head_centre_image, np.float64)
    _, _, points, cov = target_points_and_covariances(regression, _features(regression, session), head)
    boxes = np.asarray(session.object_boxes_image, np.float64)
    centres = np.asarray(session.object_centres_image, np.float64)
    pooled = tg.pool(points, window, labels=session.target)
    n = len(pooled.valid)
    K = len(boxes)
    out = dict(attended=np.zeros(n, bool), attended_xy=pooled.values.copy(), probability=np.zeros(n),
               chosen_object=np.full(n, -1), object_probabilities=np.zeros((n, K)), none_probability=np.ones(n),
               region_box=np.full((n, 4), np.nan))
    for b in range(n):
        rows = slice(b * window, (b + 1) * window)
        try:
            a = attend_window(None, points[rows], cov[rows], method=method, sigma_px=sigma_px,
                              num_candidates=num_candidates, object_boxes=boxes, saliency_map=smap)
        except ValueError as err:
            if NO_LOCATION not in str(err):
                raise
            continue  # flagged: attended False, the pooled estimate stands
        out["attended"][b] = True
        out["attended_xy"][b], out["probability"][b], out["chosen_object"][b] = a.xy, a.probability, a.chosen_object
        out["object_probabilities"][b], out["none_probability"][b], out["region_box"][b] = (
            a.object_probabilities, a.none_probability, a.region_box)

    def scores(p):
        return (tg.q1(p, boxes, pooled.labels, valid=pooled.valid).mean,
                tg.q2(p, centres, pooled.labels, valid=pooled.valid).mean)

    return SessionAttention(
        start_frame=np.arange(n) * window, labels=pooled.labels, valid=pooled.valid, target_xy=pooled.values,
        **out, **dict(zip(("q1", "q2"), scores(out["attended_xy"]))),
        **dict(zip(("q1_regression", "q2_regression"), scores(pooled.values))),
        q1_frames=tg.q1(points, boxes, session.target).mean, q2_frames=tg.q2(points, centres, session.target).mean,
    )


class AttentionScores(NamedTuple):
    """T-CYB Table I/II entries for one regression method, split kind and picture condition.

    ``q1_frames``/``q2_frames``: regression alone per frame; ``q1_pooled``/``q2_pooled``:
    regression alone, pooled; ``q1_saliency``/``q2_saliency``: ``{saliency method: score}``
    after saliency. Means over test sessions, then over splits.
    """

    method: str
    split: str
    condition: str
    q1_frames: float
    q2_frames: float
    q1_pooled: float
    q2_pooled: float
    q1_saliency: dict
    q2_saliency: dict


def evaluate_attention(
    sessions: Sequence[TabletopSession],
    *,
    key,
    render_key,
    splits: Sequence[str] = ("self", "cross"),
    methods: Sequence[str] = ("gpr", "nn"),
    saliency_methods: Sequence[str] = SALIENCY_METHODS,
    conditions: Sequence[str] = ("natural",),
    window: int = 4,
    max_splits: int | None = None,
    max_train_frames: int | None = 600,
    progress: bool = False,
) -> list[AttentionScores]:
    """T-CYB Tables I–II on simulated sessions: regression alone vs regression + saliency.

    For each split kind (``"self"``: another session of the same person; ``"cross"``: train
    on the other people, test on one; :mod:`jaxgaze.headpose.target`) and regression method,
    the model is fitted as :func:`jaxgaze.papers.yucel2013.evaluate_split` fits it (same
    training-frame thinning) on the head poses, then every test session is rendered
    (:func:`~jaxgaze.simulate.render.render_tabletop_scene`, one key per session from
    ``render_key``, so a session looks the same under every condition but for the
    condition) and attended with each saliency method. Pictures do not enter the
    regression, so the regression-alone scores do not depend on the condition.
    Returns one :class:`AttentionScores` per (method, split, condition), in that order.
    """
    makers = {"self": tg.self_referencing_splits, "cross": tg.cross_referencing_splits}
    unknown = [s for s in splits if s not in makers]
    if unknown:
        raise ValueError(f"splits must be 'self' and/or 'cross', got {unknown}")
    jobs = [(kind, m, tr, te) for kind in splits for m in methods
            for tr, te in makers[kind](sessions)[: max_splits or None]]
    keys = jax.random.split(key, len(jobs))
    maps: dict = {}

    def smap(i, condition, sal):
        if (i, condition, sal) not in maps:
            scene = render_tabletop_scene(sessions[i], key=jax.random.fold_in(render_key, i), condition=condition)
            maps[(i, condition, sal)] = saliency(scene.image, sal)
        return maps[(i, condition, sal)]

    results: dict = {}
    for (kind, m, tr, te), k in zip(tqdm(jobs, desc="splits", disable=not progress), keys):
        model = fit_regressor(m, *training_data(sessions, tr, max_train_frames), k)
        for condition in conditions:
            rows = []
            for i in te:
                per = {sal: attend_session(sessions[i], model, None, window=window, method=sal,
                                           saliency_map=smap(i, condition, sal)) for sal in saliency_methods}
                first = next(iter(per.values()))
                rows.append([first.q1_frames, first.q2_frames, first.q1_regression, first.q2_regression]
                            + [v for sal in saliency_methods for v in (per[sal].q1, per[sal].q2)])
            results.setdefault((kind, m, condition), []).append(np.mean(rows, axis=0))
    out = []
    order = sorted(results, key=lambda r: (list(methods).index(r[1]), list(splits).index(r[0]),
                                          list(conditions).index(r[2])))
    for kind, m, condition in order:
        values = results[(kind, m, condition)]
        v = np.mean(values, axis=0)
        sal = {s: (float(v[4 + 2 * j]), float(v[5 + 2 * j])) for j, s in enumerate(saliency_methods)}
        out.append(AttentionScores(m, kind, condition, *(float(x) for x in v[:4]),
                                   {s: q[0] for s, q in sal.items()}, {s: q[1] for s, q in sal.items()}))
    return out


_SHORT = {"itti": "Itti", "spectral_residual": "SR"}


def format_attention_table(scores: Sequence[AttentionScores], *, by: str = "split") -> str:
    """A markdown table: Q1 / Q2 for Regr. (frames), Regr. pooled and Regr. + each saliency method.

    ``by="split"`` labels rows by method and split (Table I), ``by="condition"`` by
    condition (Table II).
    """
    sal = list(scores[0].q1_saliency) if scores else []
    head = ["method", "split"] if by == "split" else ["condition"]
    cols = ["Regr.", "Regr. pooled"] + [f"Regr.+{_SHORT.get(s, s)}" for s in sal]
    lines = ["| " + " | ".join(head + cols) + " |", "|" + "---|" * (len(head) + len(cols))]
    for s in scores:
        label = [s.method.upper(), s.split] if by == "split" else [s.condition]
        cells = [(s.q1_frames, s.q2_frames), (s.q1_pooled, s.q2_pooled)]
        cells += [(s.q1_saliency[m], s.q2_saliency[m]) for m in sal]
        lines.append("| " + " | ".join(label + [f"{a:.2f} / {b:.2f}" for a, b in cells]) + " |")
    return "\n".join(lines)


