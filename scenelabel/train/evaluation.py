"""Held-out evaluation of a trained field: PSNR, SSIM, mIoU and depth error per view and per class,
and the captioned panels a build writes to ``renders/<view>.png``."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from scenelabel.codes import FREE
from scenelabel.config import render_background
from scenelabel.data.scene import UNLABELLED_NAME, Scene
from scenelabel.geometry.cameras import Cameras
from scenelabel.metrics import (
    COMMON_CLASS_SHARE,
    confusion_matrix,
    depth_error,
    miou,
    no_hit_as_free,
    psnr,
    spurious_classes,
    ssim,
)
from scenelabel.query.field import SemanticField
from scenelabel.query.postprocess import smooth_class_probs
from scenelabel.train.losses import composite_target
from scenelabel.viz.pictures import evaluation_panels, view_title, write_panels

__all__ = ["evaluate", "expected_finish_seconds", "panel_views", "PANEL_VIEWS"]

PANEL_VIEWS = 8
"""A build draws the panels of at most this many held-out views, spread evenly over them: the
pictures are for looking, and drawing one takes about as long as rendering it."""

# What a build does after training, on 2 cores: rebuild the density grid, save the checkpoint, load
# the field, render and score the held-out views, draw their panels (PANEL_SECONDS each). The two
# constants are tools/fit_time_plan.py's fit to what the suite's builds with depth took after
# training (docs/time_plan.md: two runs of docs/suite.md), its fixed part raised so that every one of
# them is covered: a 160x120 view renders in about 0.1-0.2 s (docs/suite.md, "render s"); the rest
# is most of it and varies with the machine's load.
FINISH_SECONDS = 8.5
RENDER_SECONDS_PER_MEGAPIXEL = 6.2
PANEL_SECONDS = 0.3


def expected_finish_seconds(held_out: Cameras, with_panels: bool) -> float:
    """Seconds a build is expected to take after training: FINISH_SECONDS, rendering and scoring
    the ``held_out`` views (RENDER_SECONDS_PER_MEGAPIXEL) and, ``with_panels``, drawing the
    :func:`panel_views` of them (PANEL_SECONDS each)."""
    megapixels = float(np.sum(held_out.width.astype(np.float64) * held_out.height)) / 1e6
    n_panels = min(len(held_out), PANEL_VIEWS) if with_panels else 0  # len(panel_views(...))
    return FINISH_SECONDS + RENDER_SECONDS_PER_MEGAPIXEL * megapixels + PANEL_SECONDS * n_panels


def panel_views(test: list[int], n: int = PANEL_VIEWS) -> list[int]:
    """At most ``n`` of the held-out views ``test``, evenly spread from the first to the last."""
    if len(test) <= n:
        return list(test)
    return [test[j] for j in np.linspace(0, len(test) - 1, n).round().astype(int)]


def evaluate(field: SemanticField, scene: Scene, test: list[int], smooth_sigma: float | None, renders_dir: Path | None) -> dict:
    """Held-out metrics (and renders): PSNR, SSIM, mIoU, depth error, per view and per class, and
    each view's render time. A ground-truth image with alpha (``scene.image_alphas``) is composited on the
    colour the render composites on (:func:`scenelabel.config.render_background`: white after
    "random" training). With ``renders_dir``, the panels of :func:`panel_views` of ``test``.

    Where the held-out labels hold FREE (classes.json's ``free_index``: the ray meets nothing), FREE is
    scored as one more class (``per_class_iou["-1"]``), and a render's rays without a hit (FREE, or
    UNKNOWN for a ray that never enters the modelled bounds) predict it."""
    scores_free = any(scene.labels[i] is not None and bool(np.any(scene.labels[i] == FREE)) for i in test)
    class_ids = np.concatenate([[FREE], field.class_ids]) if scores_free else field.class_ids
    background = render_background(field.config.train.background)
    background, ignore = None if background is None else np.asarray(background, np.float32), scene.ignore_index
    conf = np.zeros((len(class_ids), len(class_ids) + 1), dtype=np.int64)
    conf_smooth = np.zeros_like(conf)
    per_view, depth_errs = [], []
    colors = field.meta.get("class_colors") or {}
    drawn = set(panel_views(test)) if renders_dir is not None else set()
    for i in test:
        t0 = time.perf_counter()
        out = field.render_camera(scene.cameras, i)
        render_seconds = time.perf_counter() - t0
        # the smoothing is post-processing of the rendered class probabilities: no second render
        smooth_ids = field.class_map.ids_from_channels(smooth_class_probs(out.probs, smooth_sigma).argmax(-1))
        smoothed_label = np.where(out.label >= 0, smooth_ids, out.label)
        gt = composite_target(scene.images[i], None if scene.image_alphas is None else scene.image_alphas[i], background)
        view = {"view": scene.names[i], "psnr": psnr(out.rgb, gt), "ssim": ssim(out.rgb, gt), "render_seconds": render_seconds}
        label = scene.labels[i]
        if label is not None:
            # a ray without a hit predicts FREE (without FREE among class_ids: outside them, wrong either way)
            view_conf = confusion_matrix(no_hit_as_free(out.label), label, class_ids, ignore)
            conf += view_conf
            conf_smooth += confusion_matrix(no_hit_as_free(smoothed_label), label, class_ids, ignore)
            view["miou"] = miou(view_conf)[0]
        depth = scene.depths[i]
        if depth is not None:
            err = depth_error(out.depth, depth, depth > 0)
            view["depth_error"] = err
            depth_errs.append(err)
        per_view.append(view)
        if i in drawn:  # captioned panels, a legend of the classes shown, the view's metrics
            labelled = field.class_map.names != (UNLABELLED_NAME,)  # a build without labels: colour and depth
            panels = evaluation_panels(gt, out, smoothed_label, label, depth, ignore, labelled)
            write_panels(renders_dir / f"{scene.names[i]}.png", panels, {**scene.classes, **field.classes}, colors,
                         view_title(scene.names[i], view), ignore)
    metrics: dict = {"n_test_views": len(test)}
    if per_view:
        metrics["psnr"] = float(np.mean([v["psnr"] for v in per_view]))
        metrics["ssim"] = float(np.mean([v["ssim"] for v in per_view]))
    if conf.sum():
        mean_iou, per_class = miou(conf)
        metrics["miou"] = float(mean_iou)
        metrics["miou_common"] = miou(conf, COMMON_CLASS_SHARE)[0]  # classes with >= 0.1 % of the pixels
        metrics["miou_smoothed"] = float(miou(conf_smooth)[0])
        metrics["per_class_iou"] = {
            str(cid): (None if not np.isfinite(v) else float(v)) for cid, v in zip(class_ids.tolist(), per_class)
        }
        # held-out pixels of each true class (labelled, not ignored): how much a class's IoU rests on
        metrics["per_class_pixels"] = {str(cid): int(n) for cid, n in zip(class_ids.tolist(), conf.sum(1))}
        metrics["spurious_classes"] = {  # predicted on held-out views that do not show them: not in the mean
            str(cid): int(n) for cid, n in zip(class_ids.tolist(), spurious_classes(conf)) if n > 0
        }
    if depth_errs:
        metrics["depth_error"] = float(np.mean([e["abs_rel"] for e in depth_errs]))
        metrics["depth_error_details"] = {
            k: float(np.mean([e[k] for e in depth_errs])) for k in depth_errs[0]
        }
    metrics["per_view"] = per_view
    return metrics
