"""Warnings for frames a method cannot get right, said once per :func:`softshadows.render` call.

* A method that renders the occluders into maps from the light's centre (``Method.light_view``:
  the shadow-map family) cannot see occluders that reach the plane of the light's centre or lie at
  more than :data:`MAX_VIEW_DEGREES` / 2 from its view axis: a light inside, touching or surrounded
  by occluders. Its V is then too bright there; ground truth is exact.
* A method that shadows receivers only (``Method.receivers_only``) on a scene without receiver
  faces gives V = 1 everywhere.
* A light that reaches no surface the camera sees (a rect light facing away, a light behind or
  below everything in view) gives an image of ambient light only, whatever V is.

Each check returns one-line messages; :func:`softshadows.render` emits them with ``warnings.warn``
(the CLI prints ``softshadows: warning: ...``). See docs/reliability.md.
"""

from __future__ import annotations

import numpy as np

from .raster.view import light_frame
from .shading import facing_normals, unshadowed

#: widest view (full angle, degrees) a single map from the light's centre is trusted to cover
MAX_VIEW_DEGREES = 170.0


def light_view_problem(scene) -> str | None:
    """Why a map from the light's centre cannot cover the occluders, or None when it can (cached
    per scene geometry and light)."""
    light = scene.light
    key = ("light_view_problem", light.shape, *light.center, *getattr(light, "normal", ()))
    cache = scene.flat._cache
    if key not in cache:
        cache[key] = _light_view_problem(scene)
    return cache[key]


def _light_view_problem(scene) -> str | None:
    flat = scene.flat
    if not flat.occluder.any():
        return None
    light = scene.light
    faces = flat.faces[flat.occluder]
    pts = flat.vertices[flat.face_vertices("occluder")]
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    _r, _u, f = light_frame(light, toward=(lo + hi) / 2)
    d = flat.vertices - light.center
    z = d @ f
    lat = np.linalg.norm(d - z[:, None] * f, axis=1)
    ext = float(np.max(hi - lo))
    tol = 1e-9 * max(ext, float(np.linalg.norm(light.center - (lo + hi) / 2)))
    zf = z[faces]
    zmax, zmin = zf.max(axis=1), zf.min(axis=1)
    crossing = (zmax > tol) & (zmin <= tol)
    if crossing.any():
        return "occluders reach the plane of the light's centre (the light is inside, touching or surrounded by them)"
    front = np.unique(faces[zmax > tol])
    if len(front):
        half = np.degrees(np.arctan2(lat[front], z[front])).max()
        if 2 * half > MAX_VIEW_DEGREES:
            return f"the occluders span {2 * half:.0f} degrees around the light (over {MAX_VIEW_DEGREES:.0f})"
    return None


def _any_lit(scene, res) -> bool:
    """True when the light's unshadowed direct term is > 0 at some visible pixel (a sparse sample
    first: the common case costs a few hundred points, not the whole frame)."""
    idx = np.flatnonzero(res.mask.ravel())
    for sel in (idx[:: max(1, len(idx) // 256)], idx):
        pos = res.position.reshape(-1, 3)[sel].astype(np.float64)
        nrm = facing_normals(res.normal.reshape(-1, 3)[sel].astype(np.float64), pos, scene.camera.eye)
        if np.any(unshadowed(scene.light, pos, nrm) > 0):
            return True
    return False


def frame_warnings(scene, method, res) -> list[str]:
    """The warnings for one frame of ``method`` on ``scene`` (the scene the kernels saw)."""
    out = []
    flat = scene.flat
    if getattr(method, "light_view", False):
        why = light_view_problem(scene)
        if why:
            out.append(
                f"{method.name}: {why}; its maps from the light's centre cannot cover them, "
                "so V is too bright where they should shadow (ground-truth is exact)"
            )
    if getattr(method, "receivers_only", False) and not flat.receiver.any():
        out.append(
            f"{method.name}: the scene has no receiver faces (role receiver or both) and this method "
            "shadows receivers only, so V = 1 everywhere"
        )
    if res.mask is not None and res.mask.any() and not _any_lit(scene, res):
        out.append(
            "the light reaches no surface the camera sees (it faces away from them, or is behind or "
            "below them): the image is ambient light only"
        )
    return out
