"""Numba device helpers for kernels that work with a :class:`~softshadows.raster.view.View`.

All helpers take the flat parameter array ``vp = View.params()``::

    vp[0:3]  origin      vp[3:6]  right      vp[6:9]  up      vp[9:12] forward
    vp[12] l  vp[13] r  vp[14] b  vp[15] t  vp[16] near  vp[17] far  vp[18] W  vp[19] H  vp[20] ortho

and implement exactly the math of ``View.project`` / ``View.unproject``: pixel coordinates are
continuous, row 0 at the top, pixel (i, j) has its center at ``(j + 0.5, i + 0.5)``; depth is the
view-space z (distance along ``forward``, world units).

They are compiled with ``error_model="numpy"``: a division by zero gives inf/NaN instead of raising,
so a perspective projection of a point at depth 0 yields non-finite screen coordinates.
"""

from __future__ import annotations

import math

import numpy as np

from .._jit import kernel


@kernel
def view_coords(vp, px, py, pz):
    """World point -> view coordinates (x, y, z) (x along right, y along up, z = depth)."""
    dx = px - vp[0]
    dy = py - vp[1]
    dz = pz - vp[2]
    x = dx * vp[3] + dy * vp[4] + dz * vp[5]
    y = dx * vp[6] + dy * vp[7] + dz * vp[8]
    z = dx * vp[9] + dy * vp[10] + dz * vp[11]
    return x, y, z


@kernel
def view_coords_to_screen(vp, x, y, z):
    """View coordinates -> continuous pixel coordinates (sx, sy) (perspective divides by z)."""
    if vp[20] == 0.0:
        x = x / z
        y = y / z
    sx = (x - vp[12]) / (vp[13] - vp[12]) * vp[18]
    sy = (vp[15] - y) / (vp[15] - vp[14]) * vp[19]
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
    xw = vp[12] + sx / vp[18] * (vp[13] - vp[12])
    yw = vp[15] - sy / vp[19] * (vp[15] - vp[14])
    return xw, yw


@kernel
def view_unproject(vp, sx, sy, depth):
    """Continuous pixel coordinates and view depth -> world point (x, y, z), same as ``View.unproject``."""
    x, y = view_ray(vp, sx, sy)
    if vp[20] == 0.0:
        x = x * depth
        y = y * depth
    wx = vp[0] + x * vp[3] + y * vp[6] + depth * vp[9]
    wy = vp[1] + x * vp[4] + y * vp[7] + depth * vp[10]
    wz = vp[2] + x * vp[5] + y * vp[8] + depth * vp[11]
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
