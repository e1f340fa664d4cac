"""``render(scene, method, width, height, **params) -> Result``: the one entry point of a frame.

Phases timed (seconds, JIT compile excluded: the first call of a method in a process is preceded
by a tiny warm-up render of the same scene): ``eye_gbuffer``, the method's own phases, ``shading``,
and ``total``.
"""

from __future__ import annotations

import threading
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from . import limits, shading
from .errors import SoftShadowsError
from .methods.base import FrameContext, Timer, get_method
from .raster import View, rasterize
from .scene.types import Scene

_WARM: set = set()

#: seeds are 64-bit counters in the kernels
SEED_MAX = 2**63 - 1
#: rough peak memory of one frame per eye pixel (G-buffer, points, V, image, method buffers), bytes;
#: measured peak RSS growth is 96-172 B/pixel at 1024x1024 (docs/reliability.md): 1.5x margin
BYTES_PER_PIXEL = 256
#: serialises renders when the active Numba threading layer is not thread-safe (workqueue)
_RENDER_LOCK = threading.RLock()


@dataclass
class Result:
    visibility: np.ndarray  # (H,W) float32, NaN where no surface
    image: np.ndarray  # (H,W,3) linear float32
    #: (H,W,3) NaN where no surface, in the scene's own coordinates: float32, or float64 when the
    #: scene was recentred/rescaled for the kernels (Scene.normalized: far from the origin, tiny, huge)
    position: np.ndarray
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


def check_size(width, height) -> None:
    """Image sizes: positive ints (not bool), <= 16384, and the frame's memory estimate available."""
    for nm, v in (("width", width), ("height", height)):
        if not isinstance(v, (int, np.integer)) or isinstance(v, (bool, np.bool_)) or v <= 0:
            raise SoftShadowsError(f"image {nm} must be a positive integer, got {v!r}")
        if v > 16384:
            raise SoftShadowsError(f"image {nm} {v} is too large (max 16384)")
    need = int(width) * int(height) * BYTES_PER_PIXEL
    avail = available_memory()
    if avail is not None and need > avail:
        raise SoftShadowsError(
            f"image {width}x{height} needs about {need / 2**30:.1f} GiB, more than the "
            f"{avail / 2**30:.1f} GiB of memory available; use a smaller size"
        )


def available_memory() -> int | None:
    """Bytes of memory available to a new allocation (Linux MemAvailable), or None if unknown."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def check_seed(seed) -> int:
    """A seed is an integer in [0, 2**63 - 1] (not a bool, not a float)."""
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, (bool, np.bool_)):
        raise SoftShadowsError(f"seed must be an integer in [0, {SEED_MAX}], got {seed!r}")
    if not 0 <= int(seed) <= SEED_MAX:
        raise SoftShadowsError(f"seed must be an integer in [0, {SEED_MAX}], got {seed}")
    return int(seed)


def _check_scene(scene) -> None:
    if not isinstance(scene, Scene):
        hint = f" (use softshadows.load_scene({scene!r}))" if isinstance(scene, str) else ""
        raise SoftShadowsError(f"scene must be a softshadows.Scene, got {type(scene).__name__}{hint}")


def _threading_layer_is_safe() -> bool:
    """True when the active Numba threading layer allows parallel kernels from several threads at
    once (tbb, omp). Unknown (no parallel kernel has run yet) counts as unsafe."""
    try:
        import numba

        return numba.threading_layer() in ("tbb", "omp")
    except ValueError:
        return False


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
    """Render V and the shaded image of ``scene`` with ``method`` at ``width`` x ``height``.

    Arguments are checked first (:class:`SoftShadowsError` naming the field). The kernels see the
    scene recentred/rescaled in float64 when it is far from the origin or of extreme size
    (:meth:`Scene.normalized`); ``Result.position`` is given back in the scene's own coordinates.
    Safe to call from several threads: with a Numba threading layer that is not thread-safe
    (workqueue) renders are serialised. Warnings (``warnings.warn``) say when a method cannot
    produce what was asked (its documented limits)."""
    _check_scene(scene)
    if not isinstance(method, str):
        raise SoftShadowsError(f"method must be a method name (str), got {type(method).__name__}")
    check_size(width, height)
    seed = check_seed(seed)
    m = get_method(method)
    resolved = m.resolve_params(params)
    m.check_light(scene.light)
    work, shift, scale = scene.normalized()
    if _threading_layer_is_safe():
        res = _render_warm(work, m, width, height, resolved, seed, progress, warmup)
    else:
        with _RENDER_LOCK:
            res = _render_warm(work, m, width, height, resolved, seed, progress, warmup)
    for msg in limits.frame_warnings(work, m, res):
        warnings.warn(msg, stacklevel=2)
    if work is not scene:  # back to the user's coordinates (float64: no precision lost)
        res.position = res.position.astype(np.float64) / scale + shift
    return res


def _render_warm(scene, m, width, height, resolved, seed, progress, warmup) -> Result:
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
    v = np.where(g.mask, v, np.float32(np.nan))  # float32: both operands are
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
