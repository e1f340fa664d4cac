"""Soft-shadow methods, one module each, registered by name (see base.py)."""

from __future__ import annotations

import importlib
import threading

from .base import FrameContext, Method, MethodOutput, Param, get_method, methods, register

# Modules are imported in this order; "list" shows methods in registration order.
_MODULES = [
    "ground_truth",
    "hard",
    "pcss",
    "penumbra_map",
    "soft_shadow_map",
    "occlusion_textures",
    "irregular",
    "layered_attenuation",
    "coherent_raytrace",
]
_loaded = False
_load_lock = threading.RLock()


def _load_all() -> None:
    """Import every method module once; thread-safe (a second thread waits for the first one
    instead of seeing a half-filled registry)."""
    global _loaded
    if _loaded:
        return
    with _load_lock:
        if _loaded:
            return
        for m in _MODULES:
            try:
                importlib.import_module(f"{__name__}.{m}")
            except ModuleNotFoundError as exc:
                if exc.name != f"{__name__}.{m}":
                    raise
        _loaded = True


__all__ = ["FrameContext", "Method", "MethodOutput", "Param", "get_method", "methods", "register"]
