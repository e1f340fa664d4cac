"""``render(scene, method, width, height, **params) -> Result``: the one entry point of a frame.

Phases timed (seconds, JIT compile excluded: the first call of a method in a process is preceded
by a tiny warm-up render of the same scene): ``eye_gbuffer``, the method's own phases, ``shading``,
and ``total``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from . import shading
from .errors import SoftShadowsError
from .methods.base import FrameContext, Timer, get_method
from .raster import View, rasterize

_WARM: set = set()


@dataclass
class Result:
    visibility: np.ndarray  # (H,W) float32, NaN where no surface
    image: np.ndarray  # (H,W,3) linear float32
    position: np.ndarray  # (H,W,3) float32, NaN where no surface
    timings: dict = field(default_factory=dict)
    stats: dict = field(default_factory=dict)
    method: str = ""
    params: dict = field(default_factory=dict)
    normal: np.ndarray | None = None
    mask: np.ndarray | None = None


def eye_view(scene, width: int, height: int) -> View:
    lo, hi = scene.bounds()
    diag = float(np.linalg.norm(hi - lo)) + float(np.linalg.norm(scene.camera.eye - (lo + hi) / 2))
    return View.from_camera(scene.camera, width, height, near=max(1e-4, diag * 1e-5), far=diag * 4 + 1.0)


def _check_size(width, height):
    for nm, v in (("width", width), ("height", height)):
        if not isinstance(v, (int, np.integer)) or v <= 0:
            raise SoftShadowsError(f"image {nm} must be a positive integer, got {v!r}")
        if v > 16384:
            raise SoftShadowsError(f"image {nm} {v} is too large (max 16384)")


def render(
    scene,
    method: str,
    width: int = 512,
    height: int = 512,
    *,
    seed: int = 0,
    progress: bool = False,
    warmup: bool = True,
    **params,
) -> Result:
    """Render V and the shaded image of ``scene`` with ``method`` at ``width`` x ``height``."""
    _check_size(width, height)
    m = get_method(method)
    resolved = m.resolve_params(params)
    m.check_light(scene.light)
    if warmup and (m.name, scene.light.shape) not in _WARM:
        _WARM.add((m.name, scene.light.shape))
        _render(scene, m, 24, 24, resolved, seed, False)
    return _render(scene, m, width, height, resolved, seed, progress)


def _render(scene, m, width, height, resolved, seed, progress) -> Result:
    timer = Timer()
    t0 = time.perf_counter()
    view = eye_view(scene, width, height)
    flat = scene.flat
    with timer.phase("eye_gbuffer"):
        g = rasterize(view, flat.vertices, flat.faces, cull="none")
    ctx = FrameContext(scene=scene, eye=g, eye_view=view, timer=timer, seed=seed, progress=progress)
    out = m.run(ctx, **resolved)
    v = np.asarray(out.visibility, dtype=np.float32)
    if v.shape != (height, width):
        raise RuntimeError(f"method {m.name} returned V of shape {v.shape}, expected {(height, width)}")
    v = np.where(g.mask, v, np.float32(np.nan)).astype(np.float32)
    with timer.phase("shading"):
        img = shading.shade(scene, g, v, shadowed=out.direct_shadowed)
    timings = dict(timer.times)
    timings["total"] = time.perf_counter() - t0
    return Result(
        visibility=v,
        image=img,
        position=g.position,
        timings=timings,
        stats=out.stats,
        method=m.name,
        params=dict(resolved),
        normal=g.normal,
        mask=g.mask,
    )
