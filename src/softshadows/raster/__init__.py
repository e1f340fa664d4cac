"""The shared software rasterizer (eye and light views)."""

from .gbuffer import Fragments, GBuffer
from .rasterizer import (
    cull_mask,
    face_normals,
    facing,
    rasterize,
    rasterize_depth,
    rasterize_fragments,
    rasterize_min_blend,
)
from .view import View, fit_window, light_frame, light_view

__all__ = [
    "Fragments",
    "GBuffer",
    "View",
    "cull_mask",
    "face_normals",
    "facing",
    "fit_window",
    "light_frame",
    "light_view",
    "rasterize",
    "rasterize_depth",
    "rasterize_fragments",
    "rasterize_min_blend",
]
