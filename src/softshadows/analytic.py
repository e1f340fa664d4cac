"""Closed-form visibility for the analytic test cases (docs/design.md, "Habits").

* :func:`rect_occluder_visibility` — a rectangle light and an axis-aligned rectangular occluder in
  parallel planes: V = 1 - area(projection of the occluder through p onto the light plane,
  intersected with the light) / area(light).
* :func:`disk_halfplane_visibility` — a disk light (the sphere light's facing disk) and a
  half-plane occluder: V = 1 - circular segment / disk area.
"""

from __future__ import annotations

import numpy as np


def _overlap_1d(a0, a1, b0, b1):
    return np.clip(np.minimum(a1, b1) - np.maximum(a0, b0), 0.0, None)


def rect_occluder_visibility(points, occ_center, occ_half, light_center, light_half, axis: int = 1):
    """V at ``points`` (K,3) for a rectangle light and a rectangular occluder, both perpendicular to
    world ``axis`` (default y) and axis-aligned in the other two axes.

    occ_center/light_center: (3,) centers; occ_half/light_half: (2,) half extents along the two other
    axes (in increasing axis order). Points must lie on the far side of the occluder from the light
    for it to block; otherwise V = 1.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    oc = np.asarray(occ_center, float)
    lc = np.asarray(light_center, float)
    oh = np.asarray(occ_half, float)
    lh = np.asarray(light_half, float)
    others = [i for i in range(3) if i != axis]
    hp = p[:, axis]
    ho, hl = oc[axis], lc[axis]
    # occluder strictly between p and the light along the axis
    between = ((hp - ho) * (hl - ho) < 0) & (np.abs(hl - hp) > 1e-12)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (hl - hp) / (ho - hp)  # scale from occluder plane to light plane, centered at p
    area = np.ones(len(p))
    for j, ax in enumerate(others):
        c = p[:, ax] + (oc[ax] - p[:, ax]) * t
        h = oh[j] * np.abs(t)
        area = area * _overlap_1d(c - h, c + h, lc[ax] - lh[j], lc[ax] + lh[j])
    frac = area / (4.0 * lh[0] * lh[1])
    return np.where(between, 1.0 - np.clip(frac, 0.0, 1.0), 1.0)


def circular_segment(d, R):
    """Area of the part of a disk of radius R beyond a chord at signed distance d from the center."""
    d = np.clip(np.asarray(d, float), -R, R)
    return R * R * np.arccos(d / R) - d * np.sqrt(np.maximum(R * R - d * d, 0.0))


def disk_halfplane_visibility(points, light_center, radius, edge_point, edge_dir, inside_point):
    """V at ``points`` for a disk light of ``radius`` at ``light_center`` facing each point, and a
    planar half-plane occluder bounded by the line (edge_point, edge_dir); ``inside_point`` is any
    point of the occluder off that line. Assumes the whole light is on the far side of the occluder's
    plane from the points."""
    p = np.asarray(points, float).reshape(-1, 3)
    c = np.asarray(light_center, float)
    e0 = np.asarray(edge_point, float)
    ed = np.asarray(edge_dir, float) / np.linalg.norm(edge_dir)
    q = np.asarray(inside_point, float)
    out = np.empty(len(p))
    for k, pk in enumerate(p):
        w = c - pk
        w /= np.linalg.norm(w)
        n = np.cross(ed, e0 - pk)  # normal of the plane through p and the edge line
        n /= np.linalg.norm(n)
        # orient n toward the occluded side: the side of the occluder's interior as seen from p
        if np.dot(n, q - pk) < 0:
            n = -n
        m = n - np.dot(n, w) * w  # n projected into the disk plane
        mn = np.linalg.norm(m)
        if mn < 1e-12:
            out[k] = 1.0 if np.dot(n, c - pk) < 0 else 0.0
            continue
        s = np.dot(n, c - pk) / mn  # signed in-plane distance from the disk center to the boundary line
        # occluded part: the side where n.(x - p) > 0; its area is the segment beyond distance -s
        occluded = circular_segment(-s, radius)
        out[k] = 1.0 - occluded / (np.pi * radius * radius)
    return out
