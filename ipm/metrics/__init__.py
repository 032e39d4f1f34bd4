"""Mitsuba-independent evaluation metrics: silhouette IoU (world frame and after alignment), volumetric IoU,
Chamfer, triangle quality, parameter recovery. The names below load their module on first use, so that
a module of the package (``ipm.metrics.silhouette``'s mask IoU) is read without the others' meshes
library (trimesh; absent on the GPU machine)."""
from __future__ import annotations

from ipm.io.lazy import lazy_names

_WHERE = {"align_similarity": "align", "shape_iou": "align", "chamfer": "evaluate", "evaluate_meshes": "evaluate",
          "preview_png": "evaluate", "triangle_quality": "evaluate", "fibonacci_cameras": "silhouette",
          "raycast_masks": "silhouette", "silhouette_iou": "silhouette", "silhouette_masks": "silhouette",
          "occupancy": "volume", "volumetric_iou": "volume"}

__all__ = sorted(_WHERE)

__getattr__, __dir__ = lazy_names(__name__, _WHERE)
