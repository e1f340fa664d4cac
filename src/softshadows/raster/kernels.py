"""Numba device helpers for kernels that work with a :class:`~softshadows.raster.view.View`.

All helpers take the flat parameter array ``vp = View.params()``, indexed with the ``VP_*``
constants of :mod:`softshadows.raster.view` (origin, right, up, forward: 3 components each from
``VP_ORIGIN``, ``VP_RIGHT``, ``VP_UP``, ``VP_FORWARD``; window ``VP_L``, ``VP_R``, ``VP_B``, ``VP_T``;
``VP_NEAR``, ``VP_FAR``, image size ``VP_W``, ``VP_H``; ``VP_ORTHO``), and implement exactly the math of ``View.project`` / ``View.unproject``: pixel coordinates are
continuous, row 0 at the top, pixel (i, j) has its center at ``(j + 0.5, i + 0.5)``; depth is the
view-space z (distance along ``forward``, world units).

They are compiled with ``error_model="numpy"``: a division by zero gives inf/NaN instead of raising,
so a perspective projection of a point at depth 0 yields non-finite screen coordinates.
"""

from __future__ import annotations

import math

import numpy as np

from .._jit import kernel
from .view import VP_B, VP_FORWARD, VP_H, VP_L, VP_ORIGIN, VP_ORTHO, VP_R, VP_RIGHT, VP_T, VP_UP, VP_W


@kernel
def view_coords(vp, px, py, pz):
    """World point -> view coordinates (x, y, z) (x along right, y along up, z = depth)."""
    dx = px - vp[VP_ORIGIN]
    dy = py - vp[VP_ORIGIN + 1]
    dz = pz - vp[VP_ORIGIN + 2]
    x = dx * vp[VP_RIGHT] + dy * vp[VP_RIGHT + 1] + dz * vp[VP_RIGHT + 2]
    y = dx * vp[VP_UP] + dy * vp[VP_UP + 1] + dz * vp[VP_UP + 2]
    z = dx * vp[VP_FORWARD] + dy * vp[VP_FORWARD + 1] + dz * vp[VP_FORWARD + 2]
    return x, y, z


@kernel
def view_coords_to_screen(vp, x, y, z):
    """View coordinates -> continuous pixel coordinates (sx, sy) (perspective divides by z)."""
    if vp[VP_ORTHO] == 0.0:
        x = x / z
        y = y / z
    sx = (x - vp[VP_L]) / (vp[VP_R] - vp[VP_L]) * vp[VP_W]
    sy = (vp[VP_T] - y) / (vp[VP_T] - vp[VP_B]) * vp[VP_H]
    return sx, sy


@kernel
def view_project(vp, px, py, pz):
    """World point -> (sx, sy, depth), same as ``View.project``."""
    x, y, z = view_coords(vp, px, py, pz)
    sx, sy = view_coords_to_screen(vp, x, y, z)
    return sx, sy, z


@kernel
def view_ray(vp, sx, sy):
    """Continuous pixel coordinates -> (x', y') window coordinates: view-space ``x/z, y/z``
    (perspective) or ``x, y`` (orthographic)."""
    xw = vp[VP_L] + sx / vp[VP_W] * (vp[VP_R] - vp[VP_L])
    yw = vp[VP_T] - sy / vp[VP_H] * (vp[VP_T] - vp[VP_B])
    return xw, yw


@kernel
def view_unproject(vp, sx, sy, depth):
    """Continuous pixel coordinates and view depth -> world point (x, y, z), same as ``View.unproject``."""
    x, y = view_ray(vp, sx, sy)
    if vp[VP_ORTHO] == 0.0:
        x = x * depth
        y = y * depth
    wx = vp[VP_ORIGIN] + x * vp[VP_RIGHT] + y * vp[VP_UP] + depth * vp[VP_FORWARD]
    wy = vp[VP_ORIGIN + 1] + x * vp[VP_RIGHT + 1] + y * vp[VP_UP + 1] + depth * vp[VP_FORWARD + 1]
    wz = vp[VP_ORIGIN + 2] + x * vp[VP_RIGHT + 2] + y * vp[VP_UP + 2] + depth * vp[VP_FORWARD + 2]
    return wx, wy, wz


@kernel
def sample_nearest(img2d, sx, sy, default):
    """Nearest-pixel lookup at continuous pixel coordinates (centers at half-integers), clamp-to-edge.

    ``default`` is returned only when ``sx`` or ``sy`` is not finite or the image is empty; coordinates
    outside the image are clamped to the edge pixels. Returns float64.
    """
    h = img2d.shape[0]
    w = img2d.shape[1]
    if h == 0 or w == 0 or not (math.isfinite(sx) and math.isfinite(sy)):
        return float(default)
    fx = math.floor(sx)
    fy = math.floor(sy)
    # clamp in float first so huge coordinates never overflow the int conversion
    if fx < 0.0:
        fx = 0.0
    elif fx > w - 1.0:
        fx = w - 1.0
    if fy < 0.0:
        fy = 0.0
    elif fy > h - 1.0:
        fy = h - 1.0
    return float(img2d[int(fy), int(fx)])


@kernel
def sample_bilinear(img2d, sx, sy):
    """Bilinear lookup at continuous pixel coordinates (centers at half-integers), clamp-to-edge.

    Returns float64; NaN if ``sx``/``sy`` is not finite or the image is empty. A NaN texel propagates
    only when it has a non-zero weight (texels with zero weight are not read).
    """
    h = img2d.shape[0]
    w = img2d.shape[1]
    if h == 0 or w == 0 or not (math.isfinite(sx) and math.isfinite(sy)):
        return np.nan
    u = sx - 0.5
    v = sy - 0.5
    # clamp the continuous coordinate to the centers' range (clamp-to-edge)
    if u < 0.0:
        u = 0.0
    elif u > w - 1.0:
        u = w - 1.0
    if v < 0.0:
        v = 0.0
    elif v > h - 1.0:
        v = h - 1.0
    j0 = int(math.floor(u))
    i0 = int(math.floor(v))
    fx = u - j0
    fy = v - i0
    j1 = j0 + 1 if (fx > 0.0 and j0 + 1 < w) else j0
    i1 = i0 + 1 if (fy > 0.0 and i0 + 1 < h) else i0
    a = img2d[i0, j0] * (1.0 - fx) + img2d[i0, j1] * fx
    b = img2d[i1, j0] * (1.0 - fx) + img2d[i1, j1] * fx
    return float(a * (1.0 - fy) + b * fy)
