"""Result types of the shared rasterizer."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class GBuffer:
    """Nearest-surface buffer of one view. Row 0 is the top.

    position: (H,W,3) float32 world position, NaN where no surface
    normal:   (H,W,3) float32 unit geometric (face) normal as wound, NaN where no surface
    depth:    (H,W)   float32 view depth (distance along the view axis, world units), +inf where none
    tri_id:   (H,W)   int32 index into the ``faces`` array that was rasterized, -1 where none
    bary:     (H,W,2) float32 perspective-correct barycentrics (b1, b2) of vertices 1 and 2
    mask:     (H,W)   bool, True where a surface was hit
    """

    position: np.ndarray
    normal: np.ndarray
    depth: np.ndarray
    tri_id: np.ndarray
    bary: np.ndarray
    mask: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        return self.depth.shape


@dataclass
class Fragments:
    """Every fragment (not only the nearest) of a rasterization, grouped by tile.

    pixel: (K,) int64 flat pixel index (row * W + col)
    tri:   (K,) int32 triangle index
    bary:  (K,2) float32 perspective-correct barycentrics (b1, b2)
    depth: (K,) float32 view depth
    """

    pixel: np.ndarray
    tri: np.ndarray
    bary: np.ndarray
    depth: np.ndarray
    width: int
    height: int

    def __len__(self) -> int:
        return len(self.pixel)
