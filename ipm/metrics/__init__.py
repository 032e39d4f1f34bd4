"""Mitsuba-independent evaluation metrics: silhouette IoU, volumetric IoU, Chamfer, triangle quality."""

from .evaluate import chamfer, evaluate_meshes, preview_png, triangle_quality
from .silhouette import fibonacci_cameras, raycast_masks, silhouette_iou, silhouette_masks
from .volume import occupancy, volumetric_iou

__all__ = [
    "chamfer", "evaluate_meshes", "fibonacci_cameras", "occupancy", "preview_png", "raycast_masks",
    "silhouette_iou", "silhouette_masks", "triangle_quality", "volumetric_iou",
]
