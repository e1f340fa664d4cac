"""Soft-shadow methods, one module each, registered by name (see base.py)."""

from __future__ import annotations

import importlib

from .base import FrameContext, Method, MethodOutput, Param, get_method, methods, register

# Modules are imported in this order; "list" shows methods in registration order.
_MODULES = [
    "ground_truth",
    "hard",
    "pcss",
    "penumbra_map",
    "soft_shadow_map",
    "occlusion_textures",
    "coherent_raytrace",
]
_loaded = False


def _load_all() -> None:
    global _loaded
    if _loaded:
        return
    _loaded = True
    for m in _MODULES:
        try:
            importlib.import_module(f"{__name__}.{m}")
        except ModuleNotFoundError as exc:
            if exc.name != f"{__name__}.{m}":
                raise


__all__ = ["FrameContext", "Method", "MethodOutput", "Param", "get_method", "methods", "register"]
