"""Mitsuba-independent evaluation metrics: silhouette IoU (world frame and after alignment), volumetric IoU,
Chamfer, triangle quality, parameter recovery."""

from .align import align_similarity, shape_iou
from .evaluate import chamfer, evaluate_meshes, preview_png, triangle_quality
from .silhouette import fibonacci_cameras, raycast_masks, silhouette_iou, silhouette_masks
from .volume import occupancy, volumetric_iou

__all__ = [
    "align_similarity", "chamfer", "evaluate_meshes", "fibonacci_cameras", "occupancy", "preview_png", "raycast_masks",
    "shape_iou", "silhouette_iou", "silhouette_masks", "triangle_quality", "volumetric_iou",
]
