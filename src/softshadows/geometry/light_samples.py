"""Stratified, jittered sample positions on an area light (Agrawala et al. 2000, Section 3).

The unit square is split into N x N cells with one uniformly jittered point per cell
(:func:`stratified_jittered`); the square is mapped onto the light so that a uniform sampling of
the square samples the light uniformly: the rectangle ``center + (a - 1/2) u + (b - 1/2) v``, or
for a sphere light the disk of its radius through its center (Shirley-Chiu concentric map, so
strata stay equal-area) in a plane given by two unit vectors (:func:`light_sample_points`).
One call gives one fixed set: methods that use the same set for every shaded point (layered
attenuation maps) reproduce its banding; methods that decorrelate draw a set per point.
"""

from __future__ import annotations

import numpy as np


def stratified_jittered(n: int, seed: int = 0) -> np.ndarray:
    """(n*n, 2) points in [0,1)^2, one uniformly jittered point in each cell of an n x n grid,
    cells in row-major order (b slowest). Deterministic for a given ``seed``."""
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    rng = np.random.default_rng(seed)
    jit = rng.random((n * n, 2))
    b, a = np.divmod(np.arange(n * n), n)
    return np.stack([(a + jit[:, 0]) / n, (b + jit[:, 1]) / n], axis=1)


def concentric_disk(ab: np.ndarray) -> np.ndarray:
    """Shirley-Chiu concentric map of points in [0,1)^2 (K,2) to the unit disk (K,2)."""
    x = 2.0 * np.asarray(ab, float)[:, 0] - 1.0
    y = 2.0 * np.asarray(ab, float)[:, 1] - 1.0
    big_x = np.abs(x) > np.abs(y)
    r = np.where(big_x, x, y)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = np.where(big_x, (np.pi / 4.0) * (y / x), np.pi / 2.0 - (np.pi / 4.0) * (x / y))
    phi = np.where((x == 0.0) & (y == 0.0), 0.0, phi)
    return np.stack([r * np.cos(phi), r * np.sin(phi)], axis=1)


def light_sample_points(light, n: int, seed: int = 0, right=None, up=None) -> np.ndarray:
    """(n*n, 3) world positions of stratified jittered samples on ``light``.

    rect: ``center + (a - 1/2) u + (b - 1/2) v``. sphere: ``center + radius (x right + y up)`` with
    (x, y) the concentric map of (a, b): the disk through the center spanned by the unit vectors
    ``right`` and ``up`` (required for a sphere light)."""
    ab = stratified_jittered(n, seed)
    c = np.asarray(light.center, float)
    if light.shape == "rect":
        return c + (ab[:, :1] - 0.5) * light.u + (ab[:, 1:] - 0.5) * light.v
    if right is None or up is None:
        raise ValueError("a sphere light needs the disk's 'right' and 'up' vectors")
    d = concentric_disk(ab) * light.radius
    return c + d[:, :1] * np.asarray(right, float) + d[:, 1:] * np.asarray(up, float)
