"""First-run help: tell the user when the JIT cache is cold, and compile in a second process.

Numba holds the GIL while it compiles, so a cold ``compare`` compiles its ~100 kernels one after
the other on one core. :func:`start_warmup` starts a helper process (``python -m softshadows._warm``)
that compiles the rasterizer's tile kernels the main process needs only after the eye G-buffer
(:func:`warm_raster_modes`), then renders the same methods, slow frames then costliest first
(:func:`helper_order`), while the main process takes them from the front; a method goes to
whichever process claims it first (:class:`Claims`). The helper writes its kernels into the
on-disk cache (the package's normal ``__pycache__``/user cache or ``NUMBA_CACHE_DIR``: the helper
inherits the environment and so the same locator); the main process renders a helper's method
once the helper has marked it done, between its own methods or at the end (waiting for it), and
Numba loads what the helper compiled instead of compiling it again. Nothing changes in the results (the same kernels, from the same cache). The helper is only
started when the cache is cold, writable and there is more than one core; ``SOFTSHADOWS_WARMUP=0``
turns it off. Measured in docs/results/cold-start.md.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time

COLD_MESSAGE = "softshadows: compiling kernels, first run only (cached afterwards) ..."
_said = False


def _index_ok(d) -> bool:
    try:
        return bool(d._cache._cache_file._load_index())
    except Exception:  # an unreadable index is a cold one
        return False


def cache_state() -> tuple[bool, bool]:
    """(cold, writable) of the kernels' on-disk cache: cold when fewer than 80% of the kernels
    imported so far have a fresh cached overload (a few never run in a given command)."""
    from ._jit import KERNELS

    if not KERNELS:
        return False, False
    ok = sum(_index_ok(d) for d in KERNELS)
    cold = ok < 0.8 * len(KERNELS)
    try:
        path = KERNELS[0]._cache._cache_path
        writable = os.path.isdir(path) and os.access(path, os.W_OK)
    except Exception:
        writable = False
    return cold, writable


def say_if_cold(stream=None) -> bool:
    """Print :data:`COLD_MESSAGE` once per process when the cache is cold; returns cold."""
    global _said
    cold, _ = cache_state()
    if cold and not _said:
        _said = True
        print(COLD_MESSAGE, file=stream or sys.stderr, flush=True)
    return cold


# Rough compile CPU seconds of each method's own kernels on a cold cache (2-core x86_64,
# 2026-12-02, a compile event log of a cold ``compare bunny``; docs/results/cold-start.md). Only
# the order matters: the helper takes the costliest method first (longest job first), so that the
# last method to finish compiling is a small one and neither process waits long for the other.
COMPILE_COST = {
    "irregular": 36.0,
    "coherent-raytrace": 11.0,
    "occlusion-textures": 8.0,
    "penumbra-map": 7.0,
    "layered-attenuation": 5.5,
    "pcss": 5.0,
    "soft-shadow-map": 5.0,
    "hard": 1.0,
}


#: Methods whose frames take about a second or more at ``compare``'s size (``coherent-raytrace``:
#: ~1 s at 320x240 on 2 cores). The helper claims them before the others: it renders a method once
#: after compiling it, and the main process renders it twice once it is cached. Claimed first, a
#: slow method's three frames fall while both processes are still compiling (the main process
#: renders it between its own methods); claimed last, they fell at the end of the run, with one
#: core idle (a cold compare waited 2.6 s for the helper's frame, then rendered for 3.0 s).
SLOW_FRAMES = ("coherent-raytrace",)


def helper_order(names) -> list:
    """The order in which the helper claims ``names`` (the main process's order): the slow-frame
    methods (:data:`SLOW_FRAMES`) first, then the costliest to compile first (:data:`COMPILE_COST`,
    unknown methods 5 s); ties from the end of the list."""
    names = list(names)
    return sorted(reversed(names), key=lambda m: (m not in SLOW_FRAMES, -COMPILE_COST.get(m, 5.0)))


class Claims:
    """Which process renders (so compiles) which method first: a file ``claim-<method>`` made with
    O_EXCL in a folder both processes know; the one whose create succeeds renders it, the other
    does not compile it a second time. The helper marks a method ``done-<method>`` when its
    kernels are in the cache."""

    def __init__(self, folder: str):
        self.folder = folder

    def _path(self, kind: str, name: str) -> str:
        return os.path.join(self.folder, f"{kind}-{name}")

    def claim(self, name: str) -> bool:
        try:
            os.close(os.open(self._path("claim", name), os.O_CREAT | os.O_EXCL | os.O_WRONLY))
            return True
        except FileExistsError:
            return False
        except OSError:  # an unusable folder: everyone renders everything (the old behaviour)
            return True

    def done(self, name: str) -> None:
        with contextlib.suppress(OSError):
            os.close(os.open(self._path("done", name), os.O_CREAT | os.O_WRONLY))

    def is_done(self, name: str) -> bool:
        return os.path.exists(self._path("done", name))


class Warmup:
    """The helper process and the claims shared with it (see :func:`start_warmup`)."""

    def __init__(self, proc, claims: Claims, folder: str):
        self.proc = proc
        self.claims = claims
        self.folder = folder

    def claim(self, name: str) -> bool:
        """True: this (main) process renders ``name`` now; False: the helper has taken it."""
        return self.claims.claim(name)

    def cached(self, name: str) -> bool:
        """Whether the helper has rendered ``name`` (so claimed it) and cached its kernels."""
        return self.claims.is_done(name)

    def wait(self, name: str, timeout: float = 600.0) -> None:
        """Wait until the helper has cached ``name``'s kernels, or has ended, or ``timeout``."""
        end = time.monotonic() + timeout
        while not self.claims.is_done(name) and self.proc.poll() is None and time.monotonic() < end:
            time.sleep(0.05)


def start_warmup(scene, light_shape: str, width: int, height: int, names, params: dict):
    """Start the helper (a :class:`Warmup`) when worth it, else None. ``names`` in the main
    process's order; the helper claims them in :func:`helper_order`, the main process from the
    front (:class:`Claims`), so no method is compiled by both. ``scene``: a built-in name or file
    path (any other Scene: the built-in ``bunny``; kernel types do not depend on the scene)."""
    if os.environ.get("SOFTSHADOWS_WARMUP", "1") == "0" or (os.cpu_count() or 1) < 2 or not names:
        return None
    cold, writable = cache_state()
    if not (cold and writable):
        return None
    try:
        folder = tempfile.mkdtemp(prefix="softshadows-warm-")
    except OSError:  # no usable temporary folder: no helper (compare compiles alone)
        return None
    job = {
        "claims": folder,
        "scene": scene if isinstance(scene, str) else "bunny",
        "light": light_shape,
        "width": int(width),
        "height": int(height),
        "methods": helper_order(names),
        "params": {m: params.get(m, {}) for m in names},
    }
    env = dict(os.environ)
    # the helper only compiles: one thread, no OpenMP spinning that would steal the main's core
    env.setdefault("NUMBA_NUM_THREADS", "1")
    env.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    pkg_root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env["PYTHONPATH"] = pkg_root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    try:
        proc = subprocess.Popen(
            [sys.executable, "-m", "softshadows._warm", json.dumps(job, default=str)],
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
    except OSError:
        shutil.rmtree(folder, ignore_errors=True)
        return None
    return Warmup(proc, Claims(folder), folder)


def stop_warmup(warm) -> None:
    """End the helper started by :func:`start_warmup` (its finished kernels stay cached)."""
    if warm is None:
        return
    proc = warm.proc
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    shutil.rmtree(warm.folder, ignore_errors=True)


def warm_raster_modes() -> None:
    """Compile the rasterizer's tile kernels of every mode but the G-buffer one (depth, fragment
    count and write, min-blend with the one program the methods use: penumbra-map's) without the
    front end: each is called once on a 1x1 view with no triangle, its inputs built with the dtypes
    and layouts of the real ones (the kernels' types do not depend on the data;
    ``tests/test_warm.py`` checks that a real call adds no signature). The main process compiles
    the front end and the G-buffer kernel first (every render starts with the eye G-buffer), so the
    helper begins with these and the two processes do not compile the same kernels at once."""
    import numpy as np

    from ._jit import run_slots
    from .raster import View
    from .raster import rasterizer as r
    from .raster.programs import PROGRAM_PENUMBRA

    view = View.frame((0, 0, 0), (0, 0, 1), (0, 1, 0), (-1, 1, -1, 1), 0.1, 10.0, 1, 1)
    vp, W, H, _v, _f, _c, near = r._prepare(view, np.zeros((0, 3)), np.zeros((0, 3), np.int64), "none")
    fe = r.FrontEnd(
        vp,
        r.TILE,
        1,
        1,
        near,
        np.zeros(2, dtype=np.int64),
        np.empty(0, dtype=np.int32),
        np.empty((0, 4), dtype=np.int32),
        np.empty((0, 3, r.E_WIDTH), dtype=np.float64),
        np.empty((0, 3), dtype=np.float64),
        np.zeros((1, r.PL_WIDTH), dtype=np.float64),
        np.zeros((1, 3), dtype=np.float32),
        r._E2I64,
        0,
        np.zeros(1, dtype=np.int32),
        r.view_kind(vp),
    )
    r._tiles_depth(
        fe, r._scratch(fe.tile), np.empty((H, W), np.float32), np.empty((H, W), np.int32), r._NO_ZT, r._NO_FT
    )
    r._fragments(fe, W, H)
    out = np.zeros((H, W), np.float32)
    stats = np.zeros((1, 6), dtype=np.int64)
    mb = r._Blend(
        np.zeros(3), np.zeros((0, 3)), np.zeros((H, W), np.float32), out, stats, 0, False, r._texel_scratch(), 0
    )
    sc = r._scratch(fe.tile)
    run_slots(r._MIN_BLEND_KERNELS[PROGRAM_PENUMBRA], sc.nslot, fe, sc, mb)


def _main(argv) -> int:
    job = json.loads(argv[0])
    from . import render
    from .compare import load

    parent = os.getppid()
    # first what the main process needs last among what every render shares (see warm_raster_modes)
    with contextlib.suppress(Exception):
        warm_raster_modes()
    sc = load(job["scene"], job["light"])
    claims = Claims(job["claims"])
    for m in job["methods"]:
        if os.getppid() != parent:  # the main process is gone (killed): stop warming for nobody
            return 0
        if not claims.claim(m):
            continue  # the main process has it
        # the main process reports failures; the helper only warms the cache
        with contextlib.suppress(Exception):
            render(sc, m, job["width"], job["height"], **job["params"].get(m, {}))
        claims.done(m)
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
