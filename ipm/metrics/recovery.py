"""Parameter recovery: how close a reconstruction's generator parameters and pose are to the truth.

Only for in-family cases (the ground truth made by the generator the method fitted, ``params.json``
naming the same generator). Parameters are compared in the generator's unit cube over those that
shape either object (``Generator.active``, without ``distance_ignores``); the pose by yaw,
translation of the object's origin (its base) and size. The pose's scale trades against the
generator's own size parameters (a cup's radii and height, a tree's ``height``; the GA path leaves
the latter inert), so size is compared as the world height of the two meshes, not as the scale.
The world-frame and shape IoUs stay the measures of the result; these numbers say which
parameters came back.
"""
from __future__ import annotations

import math

import numpy as np

from ipm.pose import yaw_matrix

RECOVERY_COLUMNS = ("param_err", "param_err_max", "discrete_match", "counts_exact", "yaw_err_deg", "trans_err_rel",
                    "size_err_pct")


def seen_counts(gen, case: dict, views=None) -> list[str]:
    """The generator's count parameters that the input view of ``case`` shows: with ``views`` (the
    case's input views, with semantic images naming ``gen.mask_class``), the counts their class
    masks show on the truth (``ipm.facades.shown_counts``); otherwise those whose side faces the
    case's camera (``Generator.seen_counts`` at the true yaw)."""
    from ipm.render.cameras import orbit_direction

    pose = case.get("pose", {})
    yaw = math.radians(pose.get("yaw_deg", 0.0))
    if views is not None and views.semantics is not None and gen.mask_class in (views.semantic_labels or {}):
        from ipm.facades import shown_counts

        x = true_parameters(case)[1]
        rot = yaw_matrix(yaw)
        t, scale = np.asarray(pose.get("translation", [0.0, 0.0, 0.0]), float), float(pose.get("scale", 1.0))
        masks = (views.semantics == int(views.semantic_labels[gen.mask_class])).astype(np.float32)
        return shown_counts(gen, x, lambda v: scale * np.asarray(v, float) @ rot.T + t, views, masks)
    cam = case.get("camera", {})
    to_camera = orbit_direction(cam.get("azimuth_deg", 0.0), cam.get("elevation_deg", 22.0))
    return gen.seen_counts(yaw, to_camera)


def facade_match(gen, yaw_true: float, yaw_fit: float) -> dict[str, str]:
    """For each side count of the truth (``Generator.facing``) turned by ``yaw_true``, the fit's
    side count that faces the same way in the world at ``yaw_fit`` (radians): a fit turned a
    quarter with its sides traded is the same house, its right side the truth's front."""
    fit = {m: yaw_matrix(yaw_fit) @ np.asarray(normal, float) for m, normal in gen.facing.items()}
    return {n: max(fit, key=lambda m: float(fit[m] @ (yaw_matrix(yaw_true) @ np.asarray(normal, float))))
            for n, normal in gen.facing.items()}


def true_parameters(case: dict):
    """``(generator, physical parameters)`` of an in-family case's ground truth, else ``None``."""
    from ipm.generators import get_generator

    src = case["source"]
    if "generator" not in src:
        return None
    gen = get_generator(src["generator"])
    base = gen.presets[src["preset"]] if "preset" in src else None
    return gen, gen.spec.clip(gen.spec.from_dict(src.get("params", {}), base))


CAMERA_COLUMNS = ("camera_pitch_err_deg", "camera_fov_err_pct", "mask_iou")


def camera_recovery(params: dict | None) -> dict:
    """For a fit whose camera was withheld (the ``photo`` row: ``camera_error`` in its params.json,
    ``ipm.photo.camera_errors``): the absolute pitch error in degrees and the absolute field-of-view
    error in percent, judged against 3 degrees and 10 %; empty otherwise. A pitch error moves
    the object along the ground and scales it in the world (``ipm.photo.registration``), so this
    tells a misplaced good shape (``shape_iou`` high, ``iou_mean`` low) from a bad one. A fit whose
    mask was segmented from the photo (``segmentation`` in params.json) adds that mask's IoU with
    the true one (``mask_iou``)."""
    err = (params or {}).get("camera_error")
    if not err:
        return {}
    out = {"camera_pitch_err_deg": abs(float(err["pitch_deg"])),
           "camera_fov_err_pct": 100.0 * abs(float(err["fov_rel"]))}
    segmented = (params or {}).get("segmentation")
    return {**out, "mask_iou": float(segmented["mask_iou"])} if segmented else out


def parameter_recovery(case: dict, params: dict | None, reference_height: float, mesh_height: float,
                       views=None) -> dict:
    """Recovery numbers of ``params`` (a reconstruction's params.json) against ``case`` (its
    ground_truth.json): mean and largest unit-cube error of the continuous parameters, share of
    discrete parameters recovered exactly, whether every count the input ``views`` show came back
    exactly (:func:`seen_counts`; a side's count against the fit's side facing the same way,
    :func:`facade_match`; NaN for generators without counts), yaw error in degrees (NaN
    for objects that look the same turned, ``Generator.yaw_symmetric``), translation error over
    the reference's height, size error in percent (the world heights of reconstruction and
    reference). Empty for out-of-family cases, baselines and other generators."""
    made_by = case["source"].get("generator")
    if not params or made_by is None or params.get("generator") != made_by:  # before importing the generators
        return {}
    gen, x_true = true_parameters(case)
    spec = gen.spec
    x_rec = spec.clip(spec.from_dict(params["params"]))
    on = gen.active(x_true) | gen.active(x_rec)
    for name in gen.distance_ignores:
        on[spec.index[name]] = False
    cont, disc = on & ~spec.discrete, on & spec.discrete
    err = np.abs(spec.to_unit(x_true) - spec.to_unit(x_rec))[cont]
    pose, rec = case.get("pose", {}), params["pose"]
    yaw_err = float("nan")
    if not gen.yaw_symmetric(x_true):
        d = math.radians(pose.get("yaw_deg", 0.0)) - float(rec["yaw"])
        yaw_err = abs(math.degrees(math.atan2(math.sin(d), math.cos(d))))
    match = facade_match(gen, math.radians(pose.get("yaw_deg", 0.0)), float(rec["yaw"]))
    t_true = np.asarray(pose.get("translation", [0.0, 0.0, 0.0]), float)
    t_rec = np.asarray(rec["translation"], float)
    return {
        "param_err": float(err.mean()) if err.size else float("nan"),
        "param_err_max": float(err.max()) if err.size else float("nan"),
        "discrete_match": float(np.mean(x_true[disc] == x_rec[disc])) if disc.any() else float("nan"),
        "counts_exact": float(all(x_true[spec.index[n]] == x_rec[spec.index[match.get(n, n)]]
                                  for n in seen_counts(gen, case, views))) if gen.counts else float("nan"),
        "yaw_err_deg": yaw_err,
        "trans_err_rel": float(np.linalg.norm(t_rec - t_true) / max(reference_height, 1e-9)),
        "size_err_pct": float(100.0 * (mesh_height / max(reference_height, 1e-9) - 1.0)),
    }
