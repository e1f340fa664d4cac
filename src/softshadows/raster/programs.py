"""Fragment programs for :func:`~softshadows.raster.rasterize_min_blend` (the rasterizer's
equivalent of a GPU fragment program followed by MIN blending / a depth test on the output).

A program maps one fragment to a value, or NaN to discard it:
``value = run_program(program, params, a, s, z)`` with

* ``a`` the fragment's perspective-correct interpolation of a per-triangle-corner attribute,
* ``s`` the value of a per-pixel input image at the fragment's pixel (a texture read),
* ``z`` the fragment's view depth,
* ``params`` a small float64 array of uniforms.

Programs are selected by an integer so that the tile kernel stays cacheable (Numba cannot cache
kernels that take functions as arguments). Add a program here, give it a code, and dispatch it in
:func:`run_program`.
"""

from __future__ import annotations

import numpy as np

from .._jit import kernel

#: value = a (MIN-blend of an interpolated attribute); params unused
PROGRAM_ATTRIBUTE = 0
#: Wyman & Hansen 2003 penumbra intensity; params = (bias_texels, texel_scale, bernstein 0/1)
PROGRAM_PENUMBRA = 1
#: every program code (the rasterizer compiles one min-blend kernel per program)
PROGRAMS = (PROGRAM_ATTRIBUTE, PROGRAM_PENUMBRA)


@kernel
def smoothstep_bernstein(i):
    """Parker et al.'s Bernstein interpolant 3 I^2 - 2 I^3."""
    return i * i * (3.0 - 2.0 * i)


@kernel
def penumbra_intensity(zf, zv, zp, eps, bernstein):
    """The penumbra map's fragment program (Wyman & Hansen 2003, Sec. 3) for one fragment:
    I = (Z_F - Z_V) / (Z_P - Z_V) with ``zf`` the fragment depth, ``zv`` the interpolated silhouette
    depth and ``zp`` the shadow-map surface depth (world-space view depths); clamped to [0, 1] and
    optionally smoothstepped. Fragments on or behind the surface (tolerance ``eps``) are discarded:
    the return value is then NaN. Written without branches (selects only), so that the rasterizer's
    row loop vectorizes."""
    den = zp - zv
    # kept: in front of the surface (tolerance eps; False for zp = +inf/NaN) with Z_P beyond Z_V
    kept = (zf < zp - eps) & (den > 0.0)
    # the reciprocal does not depend on Z_F: it starts without waiting for the fragment depth's
    # division (two independent divisions instead of a chain: half the latency per fragment)
    i = (zf - zv) * (1.0 / (den if kept else 1.0))
    i = i if i > 0.0 else 0.0
    i = i if i < 1.0 else 1.0
    i = smoothstep_bernstein(i) if bernstein else i
    return i if kept else np.nan


@kernel
def discard_depth(program, params, s):
    """The depth from which ``program`` discards every fragment at a pixel whose input image value is
    ``s``: a fragment with ``z >= discard_depth(...)`` is discarded there (-inf or NaN: every fragment
    is; +inf: no depth is known to discard). The rasterizer's hierarchical culling takes the max over
    a tile or a row. For the penumbra program this is exactly its test ``z < Z_P - eps``."""
    if program == PROGRAM_PENUMBRA:
        return s - params[0] * params[1] * s
    return np.inf


@kernel
def value_lower_bound(program, params, a, z_min, s_max):
    """A lower bound of the value ``program`` returns for a fragment with attribute ``a``, depth
    ``z >= z_min`` and input image value ``s <= s_max`` (finite), or -inf where none is known: the
    rasterizer's coarse value test skips a piece when this bound is at least the largest value
    already stored in the tile (MIN blending: it could change no texel). For the penumbra program
    the intensity (Z_F - Z_V) / (Z_P - Z_V) grows with Z_F and, in front of the surface, falls with
    Z_P; the smoothstep is monotonic. The bound subtracts 1e-9, far above the few units of roundoff
    by which the fragment's own evaluation can differ."""
    if program == PROGRAM_PENUMBRA:
        den = s_max - a
        if not (den > 0.0 and z_min > a):
            return -np.inf
        i = (z_min - a) * (1.0 / den)
        i = i if i < 1.0 else 1.0
        i = smoothstep_bernstein(i) if params[2] != 0.0 else i
        return i - 1e-9
    return -np.inf


@kernel
def run_program(program, params, a, s, z):
    if program == PROGRAM_PENUMBRA:
        eps = params[0] * params[1] * s
        return penumbra_intensity(z, a, s, eps, params[2] != 0.0)
    return a
