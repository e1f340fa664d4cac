"""The shared software rasterizer (eye and light views)."""
from .gbuffer import Fragments, GBuffer
from .rasterizer import (cull_mask, face_normals, facing, rasterize, rasterize_depth, rasterize_fragments,
                         rasterize_min_blend)
from .view import View, fit_window, light_frame, light_view

__all__ = [
    "View", "light_view", "fit_window", "light_frame",
    "GBuffer", "Fragments",
    "rasterize", "rasterize_depth", "rasterize_fragments", "rasterize_min_blend",
    "face_normals", "cull_mask", "facing",
]
