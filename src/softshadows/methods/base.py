"""The one interface every method implements, and the registry.

A method is a subclass of :class:`Method` with a ``name``, the light shapes it supports, its
parameters (:class:`Param`, with the paper's defaults) and ``run(ctx, **params)``, which returns a
:class:`MethodOutput` with V per eye pixel. :func:`softshadows.render` builds the eye G-buffer,
calls the method, shades, and times every phase.
"""

from __future__ import annotations

import itertools
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import SoftShadowsError
from ..raster.gbuffer import flat_true, gather_points


@dataclass(frozen=True)
class Param:
    name: str
    default: Any
    help: str = ""
    choices: tuple | None = None
    min: float | None = None
    max: float | None = None
    #: optional extra rule: ``check(value)`` returns None when valid, else what is expected
    check: Any = None

    @property
    def type(self) -> type:
        return type(self.default)

    def coerce(self, value, method: str):
        """Convert a value (possibly a string from the CLI) and validate it."""
        t = self.type
        try:
            if isinstance(value, (bool, np.bool_)) and t is not bool:  # True is not a size or a count
                raise ValueError(value)
            if isinstance(value, str) and t is bool:
                low = value.strip().lower()
                if low in ("1", "true", "yes", "on"):
                    v = True
                elif low in ("0", "false", "no", "off"):
                    v = False
                else:
                    raise ValueError(value)
            elif t is bool:
                if not isinstance(value, (bool, np.bool_, int)):
                    raise ValueError(value)
                v = bool(value)
            elif t is int:
                fv = float(value)
                if fv != int(fv):
                    raise ValueError(value)
                v = int(fv)
            elif t is float:
                v = float(value)
                if not np.isfinite(v):
                    raise ValueError(value)
            else:
                v = t(value)
        except (TypeError, ValueError):
            raise SoftShadowsError(
                f"method '{method}': parameter '{self.name}' expects {t.__name__}, got {value!r}"
            ) from None
        if self.choices is not None and v not in self.choices:
            raise SoftShadowsError(
                f"method '{method}': parameter '{self.name}' must be one of {', '.join(map(str, self.choices))}, got {v!r}"
            )
        if self.min is not None and v < self.min:
            raise SoftShadowsError(f"method '{method}': parameter '{self.name}' must be >= {self.min}, got {v!r}")
        if self.max is not None and v > self.max:
            raise SoftShadowsError(f"method '{method}': parameter '{self.name}' must be <= {self.max}, got {v!r}")
        if self.check is not None and (why := self.check(v)) is not None:
            raise SoftShadowsError(f"method '{method}': parameter '{self.name}' must be {why}, got {v!r}")
        return v

    def describe(self) -> str:
        s = f"{self.name}={self.default!r}"
        if self.choices:
            s += f" ({'|'.join(map(str, self.choices))})"
        return s


class Timer:
    """Accumulates named phase times (seconds)."""

    def __init__(self):
        self.times: dict[str, float] = {}

    @contextmanager
    def phase(self, name: str):
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.times[name] = self.times.get(name, 0.0) + time.perf_counter() - t0


@dataclass
class FrameContext:
    """What a method receives: the scene, its flattened geometry, the eye G-buffer, a timer."""

    scene: Any
    eye: Any  # raster.GBuffer of the eye view
    eye_view: Any  # raster.View
    timer: Timer
    seed: int = 0
    progress: bool = False
    cache: dict = field(default_factory=dict)

    @property
    def light(self):
        return self.scene.light

    @property
    def flat(self):
        return self.scene.flat

    def points(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(positions (K,3) f64, unit normals turned toward the eye (K,3) f64, flat pixel indices
        (K,) i64) of the eye pixels with a surface, in row-major order. Computed once per frame."""
        if "points" not in self.cache:
            self.cache["points"] = gather_points(
                self.eye.position, self.eye.normal, self.eye.mask, np.asarray(self.scene.camera.eye, np.float64)
            )
        return self.cache["points"]

    def pixels(self) -> np.ndarray:
        """The flat pixel indices (K,) i64 of the eye pixels with a surface, in row-major order:
        :meth:`points`' third array, without gathering the positions and normals when they are
        not made yet. Computed once per frame."""
        if "points" in self.cache:
            return self.cache["points"][2]
        if "pixels" not in self.cache:
            self.cache["pixels"] = flat_true(self.eye.mask)
        return self.cache["pixels"]

    def scatter(self, values: np.ndarray, idx: np.ndarray, fill: float = 1.0) -> np.ndarray:
        """Per-point values at flat pixel indices ``idx`` -> (H,W) float32 image of the eye view;
        pixels not in ``idx`` get ``fill`` (render() sets pixels without a surface to NaN)."""
        H, W = self.eye.mask.shape
        out = np.full(H * W, fill, np.float32)
        out[idx] = values
        return out.reshape(H, W)


@dataclass
class MethodOutput:
    """What a method returns.

    visibility:      (H,W) float32 V; only pixels with a surface are read.
    stats:           method statistics (JSON-able numbers, strings, small lists).
    direct_shadowed: optional (H,W) float32 shadowed direct light computed by the method itself
                     (ground truth's ``shading=physical``); shading uses it instead of
                     unshadowed light x V.
    """

    visibility: np.ndarray
    stats: dict = field(default_factory=dict)
    direct_shadowed: np.ndarray | None = None


class Method:
    name: str = ""
    light_shapes: tuple = ("rect", "sphere")
    params: tuple = ()
    summary: str = ""
    paper: str = ""
    #: quality settings ``softshadows pareto`` measures: ``{param: [values, ...]}`` (every
    #: combination) or a list of ``{param: value}`` settings; parameters not named keep their
    #: defaults. ``None``: the defaults only. Declared beside ``params`` in each method's class.
    sweep: dict | list | None = None
    #: renders the occluders into map(s) from the light's centre (or the light plane): cannot cover
    #: occluders around or touching the light (render() warns; softshadows.limits)
    light_view: bool = False
    #: True for methods that by design shade only receivers (faces of role receiver|both; e.g. no
    #: self-shadowing): render() warns when a scene has none, and comparisons also report their
    #: error over receiver pixels only
    receivers_only: bool = False

    def run(self, ctx: FrameContext, **params) -> MethodOutput:  # pragma: no cover - abstract
        raise NotImplementedError

    def resolve_params(self, given: dict) -> dict:
        known = {p.name: p for p in self.params}
        out = {p.name: p.default for p in self.params}
        for k, v in given.items():
            if k not in known:
                valid = ", ".join(sorted(known)) or "(none)"
                raise SoftShadowsError(f"method '{self.name}': unknown parameter '{k}'; valid: {valid}")
            out[k] = known[k].coerce(v, self.name)
        return out

    def sweep_settings(self, sweep: dict | list | None = None) -> list[dict]:
        """The settings of ``sweep`` (default: the class's ``sweep``) as a list of ``{param: value}``
        dicts, each value coerced and validated by its Param; duplicates dropped, order kept."""
        sw = self.sweep if sweep is None else sweep
        if sw is None:
            raw = [{}]
        elif isinstance(sw, dict):
            keys = list(sw)
            for k in keys:
                if isinstance(sw[k], (str, bytes)) or not hasattr(sw[k], "__iter__"):
                    raise SoftShadowsError(f"method '{self.name}': sweep of '{k}' must be a list of values")
            raw = [dict(zip(keys, combo)) for combo in itertools.product(*(list(sw[k]) for k in keys))]
        else:
            raw = [dict(d) for d in sw]
        out, seen = [], set()
        for d in raw:
            full = self.resolve_params(d)  # validates names and values
            setting = {k: full[k] for k in d}
            key = tuple(sorted((k, repr(v)) for k, v in setting.items()))
            if key not in seen:
                seen.add(key)
                out.append(setting)
        return out

    def check_light(self, light) -> None:
        if light.shape not in self.light_shapes:
            raise SoftShadowsError(
                f"method '{self.name}' supports {' and '.join(self.light_shapes)} lights, not '{light.shape}'"
            )


_REGISTRY: dict[str, Method] = {}


def register(cls):
    """Class decorator: instantiate and register a method under ``cls.name``."""
    inst = cls()
    if not inst.name:
        raise RuntimeError(f"{cls.__name__} has no name")
    _REGISTRY[inst.name] = inst
    return cls


def get_method(name: str) -> Method:
    from . import _load_all

    _load_all()
    if name not in _REGISTRY:
        raise SoftShadowsError(f"unknown method '{name}'; valid: {', '.join(_REGISTRY)}")
    return _REGISTRY[name]


def methods() -> dict[str, Method]:
    from . import _load_all

    _load_all()
    return dict(_REGISTRY)
